//! `pthread_cancel` of a thread inside a call: deferred over the call.
//!
//! glibc acts on a cancellation at a cancellation point (`recv`, `ppoll`, `read`,
//! `send`, `close`...) by unwinding the thread's stack. Through this library's frames
//! that would skip the release of the handle's lock (the library is built with
//! `panic = "abort"`: no cleanup runs), leaving the handle locked by a thread that no
//! longer exists, so that every later call on it, `modbus_close` from another thread
//! included, would wait for ever; and unwinding over Rust frames that own values is
//! undefined behaviour. So no cancellation acts inside a call: each call (in a process
//! with more than one thread; see [`single_threaded`]) disables cancellation first and
//! enables it again as it returns, if it was enabled. A cancellation requested before
//! the call acts at its start, before it does anything (not for `modbus_close`,
//! `modbus_free`, nor a call whose closure owns something, such as a setter keeping a
//! callback: nothing may be left undone or leaked); one requested during the call
//! acts at the thread's next cancellation point after it, which is at the latest the
//! start of its next call into this library. A wait is therefore not cut short by
//! `pthread_cancel`: it ends as it would (its timeout, its message, or a
//! `modbus_close` from any thread, which ends it at once).
//!
//! The cost: one test of glibc's `__libc_single_threaded` per call in a process that
//! never made a thread; in the others, the two `pthread_setcancelstate` calls (about
//! fifty instructions).

use std::ffi::{c_char, c_int};

unsafe extern "C" {
    /// glibc (2.32 and later): non-zero while the process has never had a second
    /// thread. Only the process's single thread could then cancel a call, and only
    /// itself, before the call (see the libmodbus(7) manual page).
    static __libc_single_threaded: c_char;
    fn pthread_setcancelstate(state: c_int, oldstate: *mut c_int) -> c_int;
    fn pthread_testcancel();
}

/// glibc's values (`<pthread.h>`).
const PTHREAD_CANCEL_ENABLE: c_int = 0;
const PTHREAD_CANCEL_DISABLE: c_int = 1;

/// The process has only ever had one thread: no other thread can cancel this one
/// during a call, nothing to defer.
#[inline(always)]
pub(super) fn single_threaded() -> bool {
    // SAFETY: a byte of glibc's, written by glibc when a thread is made (before the
    // new thread runs); a volatile read of one byte.
    unsafe { std::ptr::read_volatile(&raw const __libc_single_threaded) != 0 }
}

/// Disables cancellation for a call; true when it was enabled (the call then ends
/// with [`resume`]). With `act_first`, a cancellation already requested acts first:
/// the thread ends here, before the call does anything. Only where no frame between
/// the application and this call owns a value with a destructor (then the frames
/// skipped are plain: nothing is leaked or left undone).
#[cold]
#[inline(never)]
pub(super) fn defer(act_first: bool) -> bool {
    if act_first {
        // SAFETY: no precondition; see above for the frames it may unwind.
        unsafe { pthread_testcancel() };
    }
    let mut old = PTHREAD_CANCEL_DISABLE;
    // SAFETY: `old` is a live local the function writes.
    unsafe { pthread_setcancelstate(PTHREAD_CANCEL_DISABLE, &mut old) };
    old == PTHREAD_CANCEL_ENABLE
}

/// Enables cancellation again after a call that [`defer`] disabled it for. A
/// cancellation requested meanwhile acts at the thread's next cancellation point.
#[cold]
#[inline(never)]
pub(super) fn resume() {
    let mut old = PTHREAD_CANCEL_DISABLE;
    // SAFETY: `old` is a live local the function writes.
    unsafe { pthread_setcancelstate(PTHREAD_CANCEL_ENABLE, &mut old) };
}

/// [`defer`] for the rare calls (close, free, a wait without the lock), which keep
/// the answer themselves: false in a single-threaded process.
pub(super) fn defer_rare(act_first: bool) -> bool {
    !single_threaded() && defer(act_first)
}
