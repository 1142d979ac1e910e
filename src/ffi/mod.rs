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
            crate::event::shut_pending(self);
        } else {
            crate::event::close(self);
        }
        self.rx.clear();
    }

    /// A `modbus_free` that closed the context under a call (a signal handler's, or
    /// another thread's): the event-driven client's requests complete with EIDRM,
    /// their callbacks run here, as `modbus_free` does them from normal code.
    unsafe fn finish_free(g: &mut Guard<'_>, ptr: *mut Modbus) {
        // SAFETY: `ptr` is the live handle `g` locks (the trait's contract).
        unsafe { crate::ffi::event::complete_on_free(ptr, g, true) }
    }
}

/// A new context for C: the Rust API's (`api::Modbus`), its handle handed out (taken
/// back by `modbus_free`); NULL with errno on failure.
pub fn into_handle(ctx: Result<Context>) -> *mut Modbus {
    match crate::api::Modbus::from_context(ctx) {
        Ok(m) => m.into_raw(),
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

/// The largest `struct_size` read (a page, as the callers of Linux's
/// `copy_struct_from_user` take): beyond, EINVAL without reading.
pub const STRUCT_SIZE_MAX: usize = 4096;

/// The `struct_size` rules of every versioned struct the application passes in
/// (`modbus_server_callbacks_t`, and any struct that starts with a `size_t
/// struct_size`), the rule of Linux's `copy_struct_from_user`: `size` must be at
/// least `first` (the struct's first published size) and, up to what this library
/// knows, end where a member ends (`ends`: each member's end offset, in order, the
/// struct's `size_of` last, so that its trailing padding counts); past what this
/// library knows (the last of `ends`), every byte must be zero: a member set that
/// this library does not know is refused rather than ignored. Returns how many
/// bytes to copy (at most the struct as this library knows it), or EINVAL.
///
/// # Safety
/// `p` must be valid for `size` bytes.
pub unsafe fn struct_size_ok(p: *const u8, size: usize, first: usize, ends: &[usize]) -> Result<usize> {
    let known = ends.last().copied().unwrap_or(0);
    if size < first || size > STRUCT_SIZE_MAX {
        return Err(Error::INVALID);
    }
    if size <= known {
        return if ends.contains(&size) { Ok(size) } else { Err(Error::INVALID) };
    }
    // SAFETY: the caller's `size` readable bytes, of which `known` come first.
    let tail = unsafe { std::slice::from_raw_parts(p.add(known), size - known) };
    if tail.iter().any(|&b| b != 0) { Err(Error::INVALID) } else { Ok(known) }
}

/// The end offsets of the members of a `#[repr(C)]` struct, in order, then its
/// size: what [`struct_size_ok`] takes.
#[macro_export]
macro_rules! member_ends {
    ($t:ty: $($field:ident),+ $(,)?) => {{
        const fn end_of<F>(offset: usize, _: fn(&$t) -> &F) -> usize {
            offset + ::std::mem::size_of::<F>()
        }
        [$(end_of(::std::mem::offset_of!($t, $field), |s: &$t| &s.$field),)+ ::std::mem::size_of::<$t>()]
    }};
}

/// A C string argument that may be NULL.
///
/// # Safety
/// `p` must be NULL or point at a NUL-terminated string that outlives `'a`.
pub unsafe fn opt_cstr<'a>(p: *const c_char) -> Option<&'a CStr> {
    // SAFETY: guaranteed by the caller.
    (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A struct of 4 (size), 4, 8 (padding before it), 2 bytes: ends 8, 12, 24, 26,
    /// size 32.
    #[repr(C)]
    struct V {
        size: usize,
        a: u32,
        b: u64,
        c: u16,
    }

    fn ok(bytes: &[u8], first: usize) -> Result<usize> {
        let ends = crate::member_ends!(V: size, a, b, c);
        assert_eq!(ends, [8, 12, 24, 26, 32]);
        // SAFETY: `bytes` holds its length.
        unsafe { struct_size_ok(bytes.as_ptr(), bytes.len(), first, &ends) }
    }

    #[test]
    fn struct_size_rules() {
        let buf = [0u8; 64];
        assert_eq!(ok(&buf[..7], 12), Err(Error::INVALID), "below the first published size");
        assert_eq!(ok(&buf[..8], 12), Err(Error::INVALID), "below the first published size");
        assert_eq!(ok(&buf[..12], 12), Ok(12), "the first published size");
        assert_eq!(ok(&buf[..16], 12), Err(Error::INVALID), "inside member b");
        assert_eq!(ok(&buf[..24], 12), Ok(24), "up to b");
        assert_eq!(ok(&buf[..26], 12), Ok(26), "up to c");
        assert_eq!(ok(&buf[..32], 12), Ok(32), "the whole struct, padding too");
        assert_eq!(ok(&buf[..40], 12), Ok(32), "larger, zero tail: what is known");
        assert_eq!(ok(&buf[..33], 12), Ok(32), "larger by a byte, zero");
        let mut tail = buf;
        tail[39] = 1;
        assert_eq!(ok(&tail[..40], 12), Err(Error::INVALID), "larger, a member this library does not know");
        assert_eq!(ok(&tail[..39], 12), Ok(32), "the set byte is past the size");
        let big = vec![0u8; STRUCT_SIZE_MAX + 8];
        assert_eq!(ok(&big[..STRUCT_SIZE_MAX], 12), Ok(32), "a page, zero tail");
        assert_eq!(ok(&big, 12), Err(Error::INVALID), "more than a page: not read");
    }
}
