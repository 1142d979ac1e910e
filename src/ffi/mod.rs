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
pub mod tls;
pub mod version;

use std::ffi::{CStr, c_char, c_int};
use std::sync::Arc;
use std::sync::atomic::Ordering::SeqCst;

use crate::context::Context;
use crate::engine::{self, Guard};
use crate::error::{Error, Result};
use crate::lock::{Entry, OwnerMutex, current_thread};
use crate::stop::Stop;
use crate::transport::set_errno;

/// The opaque `modbus_t`. The context sits behind a lock, so one context may be used
/// from several threads (libmodbus contexts are not thread-safe); calls on it are
/// serialised. What stopping a waiting call needs lives outside the lock, in
/// [`Stop`]: `modbus_close` and `modbus_free` from a signal handler or another thread
/// never wait for a call that waits on the line (see [`close_handle`]).
///
/// The handle is freed when the last reference goes (`Stop::refs`): the
/// application's, given up by `modbus_free`, and those of calls that run without the
/// lock for a while. A `modbus_free` from a signal handler that interrupted a call on
/// the context hands the application's reference to that call, through the lock
/// word's flag (see [`unlock_call`]).
pub struct Modbus {
    ctx: OwnerMutex<Context>,
    stop: Arc<Stop>,
}

impl Modbus {
    /// Locks the context, waiting as long as it takes (tests; the exports go through
    /// [`with_ctx`]).
    pub fn lock(&self) -> Guard<'_> {
        self.ctx.lock()
    }

    /// The context's descriptor, read without the lock (`modbus_get_socket` answers
    /// at once, even while another call waits, and in a signal handler).
    pub fn socket(&self) -> c_int {
        self.stop.fd()
    }

    /// The stop state shared with the context.
    pub fn stop(&self) -> &Stop {
        &self.stop
    }
}

/// Boxes a new context for C; NULL with errno on failure.
pub fn into_handle(ctx: Result<Context>) -> *mut Modbus {
    match ctx {
        Ok(ctx) => {
            let stop = Arc::clone(&ctx.stop);
            Box::into_raw(Box::new(Modbus { ctx: OwnerMutex::new(ctx), stop }))
        }
        Err(e) => {
            fail(e);
            std::ptr::null_mut()
        }
    }
}

/// Takes a reference to the handle, for a call that waits without the lock.
///
/// # Safety
/// `ctx` must be NULL or a live handle.
pub unsafe fn acquire<'a>(ctx: *mut Modbus) -> Option<&'a Modbus> {
    // SAFETY: guaranteed by the caller.
    let handle = unsafe { ctx.as_ref() }?;
    handle.stop.refs.fetch_add(1, SeqCst);
    Some(handle)
}

/// Drops a reference; the last one frees the handle.
///
/// # Safety
/// `ctx` must be a live handle on which the caller holds a reference, not used by the
/// caller afterwards.
pub unsafe fn release(ctx: *mut Modbus) {
    // SAFETY: the caller's reference keeps the handle alive up to this decrement.
    // SAFETY: as above.
    let handle = unsafe { &*ctx };
    if handle.stop.refs.fetch_sub(1, SeqCst) == 1 {
        // SAFETY: no reference is left: the application freed it and no call is in.
        drop(unsafe { Box::from_raw(ctx) });
    }
}

/// Releases the lock a call took on `ctx`; when a `modbus_free` handed the
/// application's reference to this call meanwhile (the lock word's flag), gives it up,
/// which may free the handle. Nothing of the handle is touched afterwards.
///
/// # Safety
/// `g` must be the lock of the live handle `ctx`.
unsafe fn unlock_call(ctx: *mut Modbus, g: Guard<'_>) {
    if g.release() {
        // SAFETY: the reference handed over with the flag.
        unsafe { release(ctx) };
    }
}

/// The close itself, with the lock. A signal handler may close the context under it
/// too: what it leaves is finished here, so that no later call fails for it.
fn close_locked(g: &mut Guard<'_>) {
    engine::close(g);
    if let Some(handled) = g.stop.take_handled() {
        finish_handler_close(g, handled);
    }
}

/// Closes the context of a handle whose lock another thread holds: stops its waits,
/// then closes with the lock, which the waiting call gives up at once.
///
/// # Safety
/// `ctx` must be a live handle.
unsafe fn close_under_other_thread(ctx: *mut Modbus) {
    // SAFETY: guaranteed by the caller.
    let handle = unsafe { &*ctx };
    handle.stop.begin_stop();
    match handle.ctx.enter() {
        Entry::Locked(mut g) => {
            close_locked(&mut g);
            handle.stop.note_close();
            handle.stop.end_stop();
            // SAFETY: `g` is the lock of `ctx`.
            unsafe { unlock_call(ctx, g) };
        }
        // Cannot happen (the holder was another thread, and a handler of ours never
        // keeps the lock); a handler's close all the same.
        Entry::HeldByThisThread => {
            handle.stop.end_stop();
            handle.stop.close_in_handler();
        }
    }
}

/// `modbus_close`. When no call is inside the context, an ordinary close; when a call
/// of this thread is (we run in a signal handler that interrupted it), the close
/// without the lock of `Stop::close_in_handler`, finished by that call as it unwinds;
/// when another thread's call is, see [`close_under_other_thread`].
///
/// # Safety
/// `ctx` must be NULL or a live handle.
pub unsafe fn close_handle(ctx: *mut Modbus) {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ctx.as_ref() }) else { return };
    match handle.ctx.try_lock() {
        Some(mut g) => {
            close_locked(&mut g);
            handle.stop.note_close();
            // SAFETY: `g` is the lock of `ctx`.
            unsafe { unlock_call(ctx, g) };
        }
        None if handle.ctx.holder() == current_thread() => handle.stop.close_in_handler(),
        // SAFETY: `ctx` is live.
        None => unsafe { close_under_other_thread(ctx) },
    }
}

/// `modbus_free`: when no call is inside, frees without closing, as libmodbus; when
/// one is, closes first (as [`close_handle`]) and leaves the freeing to the last
/// reference: from a signal handler, the interrupted call frees as it unwinds.
///
/// # Safety
/// `ctx` must be NULL or a live handle, not used by the caller afterwards.
pub unsafe fn free_handle(ctx: *mut Modbus) {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ctx.as_ref() }) else { return };
    match handle.ctx.try_lock() {
        Some(g) => {
            drop(g);
            // Not closed, as libmodbus; a `modbus_tcp_accept` waiting unlocked still
            // ends (EBADF), and frees the handle as it leaves.
            handle.stop.note_close();
        }
        None if handle.ctx.holder() == current_thread() => {
            handle.stop.close_in_handler();
            // This thread holds the lock: the raise cannot be refused.
            let raised = handle.ctx.raise_flag();
            debug_assert!(raised);
            return;
        }
        // SAFETY: `ctx` is live.
        None => unsafe { close_under_other_thread(ctx) },
    }
    // SAFETY: the application's reference, given up here.
    unsafe { release(ctx) };
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

/// Runs `f` on the locked context behind `ctx`; NULL gives -1/EINVAL. From a signal
/// handler that interrupted a call of its thread on the same context, -1/EDEADLK at
/// once (waiting for the lock would never end). A call under which a signal handler
/// closed the context finishes that close and fails with EBADF.
///
/// # Safety
/// `ctx` must be NULL or a pointer returned by a `modbus_new_*` function and not yet
/// freed.
pub unsafe fn with_ctx(ctx: *mut Modbus, f: impl FnOnce(&mut Guard<'_>) -> Result<c_int>) -> c_int {
    // SAFETY: forwarded caller contract.
    status(unsafe { with_ctx_result(ctx, f) })
}

/// [`with_ctx`] before the C convention: the result, for a caller with more to do
/// before it sets errno.
///
/// # Safety
/// As [`with_ctx`].
pub unsafe fn with_ctx_result(ctx: *mut Modbus, f: impl FnOnce(&mut Guard<'_>) -> Result<c_int>) -> Result<c_int> {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ctx.as_ref() }) else {
        return Err(Error::INVALID);
    };
    match handle.ctx.enter() {
        Entry::Locked(mut g) => {
            let r = f(&mut g);
            let r = match g.stop.take_handled() {
                None => r,
                Some(handled) => {
                    finish_handler_close(&mut g, handled);
                    Err(Error::STOPPED)
                }
            };
            // SAFETY: `g` is the lock of `ctx`; `handle` is not used after this.
            unsafe { unlock_call(ctx, g) };
            r
        }
        Entry::HeldByThisThread => Err(Error::REENTERED),
    }
}

/// The rest of a close a signal handler made under the call that just ended:
/// `handled` is the descriptor it closed (kept open on /dev/null), or -1 when it found
/// none (the call was opening one): that one gets a whole close.
fn finish_handler_close(g: &mut Guard<'_>, handled: i32) {
    if g.s >= 0 && g.s == handled {
        let fd = g.release_descriptor();
        crate::transport::close(fd);
    } else {
        engine::close(g);
    }
    g.rx.clear();
}

/// A C string argument that may be NULL.
///
/// # Safety
/// `p` must be NULL or point at a NUL-terminated string that outlives `'a`.
pub unsafe fn opt_cstr<'a>(p: *const c_char) -> Option<&'a CStr> {
    // SAFETY: guaranteed by the caller.
    (!p.is_null()).then(|| unsafe { CStr::from_ptr(p) })
}
