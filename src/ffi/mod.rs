//! The exported C ABI of libmodbus 3.1.12, one file per header area.
//!
//! Every export is a thin shim: it turns raw pointers into references or slices,
//! checks the arguments libmodbus checks, calls the engine, and maps the result to the
//! C convention here, in one place ([`with_ctx`], [`fail`]).

pub mod client;
pub mod context;
pub mod data;
pub mod extensions;
pub mod rtu;
pub mod server;
pub mod tcp;
pub mod version;

use std::ffi::{CStr, c_char, c_int};
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicI32, Ordering};

use parking_lot::Mutex;

use crate::context::Context;
use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::transport::set_errno;

/// The opaque `modbus_t`. The context sits behind a mutex, so one context may be
/// used from several threads (libmodbus contexts are not thread-safe); calls on it
/// are serialised.
pub struct Modbus {
    ctx: Mutex<Context>,
    /// The context's descriptor as the last call left it (see [`ContextLock`]):
    /// `modbus_get_socket` reads it without waiting for a call another thread is
    /// blocked in (libmodbus reads its field directly), so that a thread can, say,
    /// `shutdown()` the socket a receive waits on.
    socket: AtomicI32,
}

impl Modbus {
    /// Locks the context; the descriptor is published again when the lock ends.
    pub fn lock(&self) -> ContextLock<'_> {
        ContextLock { guard: self.ctx.lock(), socket: &self.socket }
    }

    /// The descriptor published by the last call that released the context.
    pub fn socket(&self) -> c_int {
        self.socket.load(Ordering::Acquire)
    }
}

/// The locked context of a [`Modbus`]; dropping it publishes the descriptor.
pub struct ContextLock<'a> {
    guard: Guard<'a>,
    socket: &'a AtomicI32,
}

impl<'a> Deref for ContextLock<'a> {
    type Target = Guard<'a>;
    fn deref(&self) -> &Guard<'a> {
        &self.guard
    }
}

impl<'a> DerefMut for ContextLock<'a> {
    fn deref_mut(&mut self) -> &mut Guard<'a> {
        &mut self.guard
    }
}

impl Drop for ContextLock<'_> {
    fn drop(&mut self) {
        self.socket.store(self.guard.s, Ordering::Release);
    }
}

/// Boxes a new context for C; NULL with errno on failure.
pub fn into_handle(ctx: Result<Context>) -> *mut Modbus {
    match ctx {
        Ok(ctx) => {
            let socket = AtomicI32::new(ctx.s);
            let raw = Box::into_raw(Box::new(Modbus { ctx: Mutex::new(ctx), socket }));
            // SAFETY: `raw` was just created from a Box and is uniquely owned here.
            unsafe { (*raw).ctx.get_mut().handle_addr = raw as usize };
            raw
        }
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

/// Runs `f` on the locked context behind `ctx`; NULL gives -1/EINVAL.
///
/// # Safety
/// `ctx` must be NULL or a pointer returned by a `modbus_new_*` function and not yet
/// freed.
pub unsafe fn with_ctx(ctx: *mut Modbus, f: impl FnOnce(&mut Guard<'_>) -> Result<c_int>) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ctx.as_ref() }) else {
        return fail(Error::INVALID);
    };
    let mut guard = handle.lock();
    let r = f(&mut guard);
    drop(guard);
    status(r)
}

/// A C string argument that may be NULL.
///
/// # Safety
/// `p` must be NULL or point at a NUL-terminated string that outlives `'a`.
pub unsafe fn opt_cstr<'a>(p: *const c_char) -> Option<&'a CStr> {
    // SAFETY: guaranteed by the caller.
    (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) })
}
