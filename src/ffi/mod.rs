//! The exported C ABI of libmodbus 3.1.12, one file per header area.
//!
//! Every export is a thin shim: it turns raw pointers into references or slices,
//! checks the arguments libmodbus checks, calls the engine, and maps the result to the
//! C convention here, in one place ([`with_ctx`], [`fail`]).

pub mod client;
pub mod context;
pub mod data;
pub mod event;
pub mod extensions;
pub mod multi;
pub mod rtu;
pub mod server;
pub mod tcp;
pub mod tls;
pub mod version;

use std::ffi::{CStr, c_char, c_int};
use std::sync::Arc;

use crate::context::Context;
use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::handle::{self, Closable, Handle};
use crate::stop::Stop;
use crate::transport::set_errno;

/// The opaque `modbus_t`: a [`Handle`] over a context. The context sits behind a lock,
/// so one context may be used from several threads (libmodbus contexts are not
/// thread-safe); calls on it are serialised. `modbus_close` and `modbus_free` from a
/// signal handler or another thread never wait for a call that waits on the line.
/// Its lifetime (references, closes, frees) is `crate::handle`'s.
pub type Modbus = Handle<Context>;

/// The context's part of a handle's lifetime: its close is the engine's.
impl Closable for Context {
    fn stop(&self) -> &Arc<Stop> {
        &self.stop
    }

    fn close(&mut self) {
        crate::event::close(self);
    }

    /// The descriptor the handler closed is released and its number closed; when the
    /// handler found none (the call was opening one), the context gets a whole close.
    fn finish_handler_close(&mut self, handled: i32) {
        if self.fd() >= 0 && self.fd() == handled {
            let fd = self.release_descriptor();
            crate::transport::close(fd);
        } else {
            crate::event::close(self);
        }
        self.rx.clear();
    }
}

/// Boxes a new context for C; NULL with errno on failure.
pub fn into_handle(ctx: Result<Context>) -> *mut Modbus {
    match ctx {
        Ok(ctx) => Handle::new(ctx),
        Err(e) => {
            fail(e);
            std::ptr::null_mut()
        }
    }
}

/// Sets errno (unless the error says to leave it) and returns -1.
pub fn fail(e: Error) -> c_int {
    if e != Error::UNCHANGED {
        set_errno(e.errno());
    }
    -1
}

/// Maps a result to the C convention.
pub fn status(r: Result<c_int>) -> c_int {
    r.unwrap_or_else(fail)
}

/// Runs `f` on the locked context behind `ctx` ([`handle::call`]) and maps the result
/// to the C convention: NULL gives -1/EINVAL; from a signal handler that interrupted a
/// call of its thread on the same context, -1/EDEADLK at once; a call under which a
/// signal handler closed the context fails with EBADF.
///
/// # Safety
/// `ctx` must be NULL or a pointer returned by a `modbus_new_*` function and not yet
/// freed. The export calling it may own nothing with a destructor outside `f` (a
/// pending `pthread_cancel` may end the thread at the call's start: see
/// [`handle::call`]).
pub unsafe fn with_ctx(ctx: *mut Modbus, f: impl FnOnce(&mut Guard<'_>) -> Result<c_int>) -> c_int {
    // SAFETY: forwarded caller contract.
    status(unsafe { handle::call(ctx, f) })
}

/// A C string argument that may be NULL.
///
/// # Safety
/// `p` must be NULL or point at a NUL-terminated string that outlives `'a`.
pub unsafe fn opt_cstr<'a>(p: *const c_char) -> Option<&'a CStr> {
    // SAFETY: guaranteed by the caller.
    (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) })
}
