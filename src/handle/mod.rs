//! A handle's lifetime, in one place: the `modbus_t` of the C API is a [`Handle`] over
//! a context. Making one ([`Handle::new`]), a call ([`call`]: lock, run, finish what a
//! signal handler's close left, unlock, maybe free), a wait without the lock
//! ([`wait_unlocked`], `modbus_tcp_accept`), a user callback run with the lock
//! released ([`call_unlocked`], the RTS and TLS authorization callbacks), the close
//! ([`close`]) and the free ([`free`]).
//!
//! A handle is freed when its last reference goes: the application's, given up by
//! `modbus_free`, and one per call that runs without the lock for a while (a wait, a
//! callback). A `modbus_free` from a signal handler that interrupted a call on the
//! handle hands the application's reference to that call, through a flag of the lock
//! word ([`FREED`]): the call gives it up as it releases the lock. A `modbus_close`
//! from such a handler raises [`CLOSED`], for the call to finish that close as it
//! ends; a call that deferred cancellation ([`cancel`]) carries [`DEFERRED`]. So a call
//! ends with one compare-and-swap when none of this happened, and acts on the flags
//! otherwise ([`release_slow`]). The reference count and the flags are private to this
//! module ([`lock`] is its child).
//!
//! A `fork` child gets working handles even when another thread was inside a call
//! at the fork ([`fork`]); `pthread_cancel` never acts inside a call ([`cancel`]).
//!
//! The module is generic over the value behind the lock ([`Closable`]), so that it
//! sits below the context with the lock and the stop state, and the engine may run
//! callbacks unlocked without an import cycle; the C layer instantiates it over the
//! context (`ffi::Modbus`).

mod cancel;
mod fork;
pub mod lock;
pub(crate) mod stop;

use std::mem::needs_drop;
use std::sync::Arc;
use std::sync::atomic::Ordering::SeqCst;

use crate::error::{Error, Result};
use lock::{Entry, FLAGS, OwnerGuard, OwnerMutex, current_thread};
use stop::Stop;

/// The lock word's flags, as the handle uses them (see the module documentation).
/// A `modbus_free` from a signal handler handed the application's reference to the
/// interrupted call (or a callback's reference turned out to be the last one).
const FREED: usize = 0b0010;
/// A signal handler closed the handle under the interrupted call.
const CLOSED: usize = 0b0100;
/// The call disabled cancellation; it enables it again as it ends.
const DEFERRED: usize = 0b1000;
const _: () = assert!((FREED | CLOSED | DEFERRED) & !FLAGS == 0);

/// What a handle needs of the value behind its lock.
pub trait Closable {
    /// The stop state the value shares with its handle.
    fn stop(&self) -> &Arc<Stop>;
    /// `modbus_close`, with the lock.
    fn close(&mut self);
    /// The rest of a close a signal handler made under the call that just ended
    /// (`Stop::close_in_handler`): `handled` is the descriptor it closed (kept open
    /// on /dev/null), or -1 when it found none.
    fn finish_handler_close(&mut self, handled: i32);
    /// What the value finishes before it is freed, with the lock, when `modbus_free`
    /// had to close it under a call: a signal handler freed it under the call that
    /// just ended (after [`Closable::finish_handler_close`], on that call's thread,
    /// outside the handler), or another thread freed it while a call held it (on
    /// that thread, once the call let go). `ptr` is its handle, kept allocated until
    /// this returns (the event-driven client's callbacks run here).
    ///
    /// # Safety
    /// `ptr` is the live handle whose lock `g` is.
    unsafe fn finish_free(g: &mut OwnerGuard<'_, Self>, ptr: *mut Handle<Self>)
    where
        Self: Sized;
}

/// A value behind its lock, with what stopping a call on it needs without the lock.
/// Handed to C as a raw pointer ([`Handle::new`]); every function taking one requires
/// it to be NULL or live (made by `new`, not freed yet).
pub struct Handle<T> {
    value: OwnerMutex<T>,
    stop: Arc<Stop>,
}

impl<T: Closable> Handle<T> {
    /// Boxes a handle over `value`, holding the application's reference.
    pub fn new(value: T) -> *mut Handle<T> {
        let stop = Arc::clone(value.stop());
        let ptr = Box::into_raw(Box::new(Handle { value: OwnerMutex::new(value), stop }));
        fork::register(ptr as usize, Self::after_fork_in_child);
        ptr
    }

    /// In a fork child (see [`fork`]): what the threads that do not exist there left
    /// in the handle at `addr` is forgotten: the lock one of them held, the stops and
    /// waits they were making.
    ///
    /// # Safety
    /// `addr` is a live `Handle<T>`; the child has one thread (a `pthread_atfork`
    /// child handler).
    unsafe fn after_fork_in_child(addr: usize) {
        // SAFETY: guaranteed by the caller.
        let handle = unsafe { &*(addr as *const Handle<T>) };
        // What the dead holder's call had to do for the handle stays for the next
        // holder; its cancellation state was its own thread's.
        handle.value.forget_dead_holder(FREED | CLOSED);
        handle.stop.after_fork_in_child();
    }
}

impl<T> Handle<T> {
    /// Locks the value, waiting as long as it takes (tests; the exports go through
    /// [`call`]).
    pub fn lock(&self) -> OwnerGuard<'_, T> {
        self.value.lock()
    }

    /// The value's descriptor, read without the lock (`modbus_get_socket` answers at
    /// once, even while another call waits, and in a signal handler).
    pub fn socket(&self) -> i32 {
        self.stop.fd()
    }
}

/// Takes a reference: the handle stays allocated until [`give_back`].
fn hold<T>(handle: &Handle<T>) {
    handle.value.refs().fetch_add(1, SeqCst);
}

/// Gives a reference back; the last one frees the handle.
///
/// # Safety
/// `ptr` must be a live handle on which the caller holds a reference, not used by the
/// caller afterwards.
unsafe fn give_back<T>(ptr: *mut Handle<T>) {
    // SAFETY: the caller's reference keeps the handle alive up to this decrement.
    let handle = unsafe { &*ptr };
    if handle.value.refs().fetch_sub(1, SeqCst) == 1 {
        fork::unregister(ptr as usize);
        // SAFETY: no reference is left: the application freed it and no call is in.
        drop(unsafe { Box::from_raw(ptr) });
    }
}

/// Releases the lock a call took on `ptr`: one compare-and-swap when no flag is up,
/// else [`release_slow`]. True when a signal handler's close was finished here (the
/// call fails with EBADF). Nothing of the handle is touched afterwards.
///
/// # Safety
/// `g` must be the lock of the live handle `ptr`.
#[inline]
unsafe fn unlock_call<T: Closable>(ptr: *mut Handle<T>, g: OwnerGuard<'_, T>) -> bool {
    match g.try_release() {
        Ok(()) => false,
        // SAFETY: forwarded.
        Err(g) => unsafe { release_slow(ptr, g) },
    }
}

/// Releases the lock a call took on `ptr`, acting on the flags raised meanwhile: a
/// signal handler's close is finished with the lock (see [`Closable`]), until none is
/// left up; then the lock is freed; cancellation is enabled again if the call
/// disabled it; a reference handed over is given up, which may free the handle. True
/// when a handler's close was finished.
///
/// # Safety
/// `g` must be the lock of the live handle `ptr`; nothing of the handle is used by the
/// caller afterwards.
#[cold]
#[inline(never)]
unsafe fn release_slow<T: Closable>(ptr: *mut Handle<T>, mut g: OwnerGuard<'_, T>) -> bool {
    // SAFETY: guaranteed by the caller, until the release below.
    let handle = unsafe { &*ptr };
    let mut closed = false;
    let mut freed = false;
    let flags = loop {
        if OwnerGuard::take_flags(&mut g, CLOSED) != 0 {
            if let Some(handled) = handle.stop.take_handled() {
                g.finish_handler_close(handled);
            }
            closed = true;
            // A handler's `modbus_free` (it raised both): what the value does before
            // it goes, now that no handler runs.
            if !freed && OwnerGuard::flags(&g) & FREED != 0 {
                freed = true;
                // SAFETY: `g` is the lock of the live `ptr` (the caller's contract).
                unsafe { T::finish_free(&mut g, ptr) };
            }
        }
        match g.release_unless(CLOSED) {
            Ok(flags) => break flags,
            // A handler closed it again meanwhile.
            Err(again) => g = again,
        }
    };
    if flags & DEFERRED != 0 {
        cancel::resume();
    }
    if flags & FREED != 0 {
        // SAFETY: the reference handed over with the flag.
        unsafe { give_back(ptr) };
    }
    closed
}

/// Runs `f` on the locked value behind `ptr`: NULL gives EINVAL; from a signal
/// handler that interrupted a call of its thread on the same handle, EDEADLK at once
/// (waiting for the lock would never end). A call under which a signal handler closed
/// the value finishes that close and fails with EBADF. Cancellation is deferred over
/// the call (see [`cancel`]); one requested before it acts at its start when `f` owns
/// nothing.
///
/// # Safety
/// `ptr` must be NULL or a live handle. No frame between the application and this
/// call may own a value with a destructor, apart from `f`: a cancellation may end the
/// thread at the call's start.
pub unsafe fn call<T: Closable, R, F>(ptr: *mut Handle<T>, f: F) -> Result<R>
where
    F: FnOnce(&mut OwnerGuard<'_, T>) -> Result<R>,
{
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ptr.as_ref() }) else {
        return Err(Error::INVALID);
    };
    let (entry, deferred) = if cancel::single_threaded() {
        (handle.value.enter(), false)
    } else {
        let deferred = cancel::defer(!needs_drop::<F>());
        (handle.value.enter_flagged(if deferred { DEFERRED } else { 0 }), deferred)
    };
    match entry {
        Entry::Locked(mut g) => {
            let r = f(&mut g);
            // SAFETY: `g` is the lock of `ptr`; `handle` is not used after this.
            if unsafe { unlock_call(ptr, g) } { Err(Error::STOPPED) } else { r }
        }
        Entry::HeldByThisThread => {
            // (The interrupted call deferred cancellation already, if it could be.)
            if deferred {
                cancel::resume();
            }
            Err(Error::REENTERED)
        }
    }
}

/// Runs `f` on the value behind `ptr` when its lock is free now; `None` (and `f` not
/// run) when a call holds it: another thread's, or the one a signal handler of this
/// thread interrupted. Nothing is waited for (`modbus_close` and `modbus_free` use it
/// for what they do besides the close, which never waits either).
///
/// # Safety
/// `ptr` must be NULL or a live handle.
pub unsafe fn try_call<T: Closable, R>(ptr: *mut Handle<T>, f: impl FnOnce(&mut OwnerGuard<'_, T>) -> R) -> Option<R> {
    // SAFETY: guaranteed by the caller.
    let handle = unsafe { ptr.as_ref() }?;
    let deferred = cancel::defer_rare(false);
    let r = handle.value.try_lock().map(|mut g| {
        let r = f(&mut g);
        // SAFETY: `g` is the lock of `ptr`; the handle is not used after this.
        unsafe { release_slow(ptr, g) };
        r
    });
    if deferred {
        cancel::resume();
    }
    r
}

/// What a wait without the lock may look at (see [`wait_unlocked`]).
pub struct Waiting<'a> {
    stop: &'a Stop,
    closes: u32,
}

impl Waiting<'_> {
    /// The descriptor a close writes to, for the wait to poll beside its own.
    pub fn wake_fd(&self) -> i32 {
        self.stop.wake_fd()
    }

    /// The handle was closed (or freed) since the wait began: it must end.
    pub fn closed(&self) -> bool {
        self.stop.closes() != self.closes
    }
}

/// A call that waits without the lock (`modbus_tcp_accept`): `check` runs with the
/// lock, then `wait` without it (a close of the handle, from a signal handler or
/// another thread, wakes it: see [`Waiting`]), then `then` with the lock again, given
/// what the wait returned and whether the handle was closed meanwhile. A reference
/// held throughout keeps the handle allocated even if it is freed meanwhile; the last
/// one out frees it, before this returns.
///
/// # Safety
/// `ptr` must be NULL or a live handle.
pub unsafe fn wait_unlocked<T: Closable, W, R>(
    ptr: *mut Handle<T>,
    check: impl FnOnce(&mut OwnerGuard<'_, T>) -> Result<()>,
    wait: impl FnOnce(&Waiting<'_>) -> W,
    then: impl FnOnce(&mut OwnerGuard<'_, T>, W, bool) -> Result<R>,
) -> Result<R> {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ptr.as_ref() }) else {
        return Err(Error::INVALID);
    };
    // Cancellation deferred over the whole call (the calls inside then find it
    // disabled, and leave it so); one requested before acts first.
    let deferred = cancel::defer_rare(true);
    hold(handle);
    let waited = (|| {
        // SAFETY: `ptr` is live (our reference).
        unsafe { call(ptr, check) }?;
        let waiting = Waiting { stop: &handle.stop, closes: handle.stop.closes() };
        handle.stop.set_accepting(true);
        let w = wait(&waiting);
        handle.stop.set_accepting(false);
        // SAFETY: as above.
        unsafe { call(ptr, |g| then(g, w, waiting.closed())) }
    })();
    // SAFETY: the reference taken above; `handle` is not used after this.
    unsafe { give_back(ptr) };
    if deferred {
        cancel::resume();
    }
    waited
}

/// Runs an application's callback with the lock released, so that it may call the
/// library on the same handle (`modbus_get_socket` and friends), and takes the lock
/// back afterwards (also when `f` unwinds). The handle must outlive the callback,
/// which may free it (or a signal handler may, meanwhile): a reference is held
/// across it; when it turns out to be the last one, the call keeps it and gives it up
/// as it releases the lock (the flag, as for a handler's `modbus_free`).
pub fn call_unlocked<T, R>(g: &mut OwnerGuard<'_, T>, f: impl FnOnce() -> R) -> R {
    /// Gives the reference back once the lock is ours again.
    struct Reference<'b, T>(&'b OwnerMutex<T>);
    impl<T> Drop for Reference<'_, T> {
        fn drop(&mut self) {
            if self.0.refs().fetch_sub(1, SeqCst) == 1 {
                // `modbus_free` came meanwhile: the handle is this call's to free.
                self.0.refs().store(1, SeqCst);
                let raised = self.0.raise_flag(FREED);
                debug_assert!(raised, "the lock is taken back before the reference");
            }
        }
    }
    let lock = OwnerGuard::mutex(g);
    lock.refs().fetch_add(1, SeqCst);
    let _reference = Reference(lock);
    OwnerGuard::unlocked(g, f)
}

/// The close itself, with the lock. A signal handler may close the value under it
/// too: what it leaves is finished here, so that no later call fails for it.
fn close_locked<T: Closable>(handle: &Handle<T>, g: &mut OwnerGuard<'_, T>) {
    g.close();
    if let Some(handled) = handle.stop.take_handled() {
        g.finish_handler_close(handled);
    }
}

/// `modbus_close` or `modbus_free` from a signal handler that interrupted a call of
/// its thread on the handle (this thread holds the lock): the close without the lock
/// of `Stop::close_in_handler`, which the interrupted call finishes as it releases the
/// lock ([`CLOSED`]); with `freed`, the application's reference goes to that call too
/// ([`FREED`]).
fn close_in_handler<T>(handle: &Handle<T>, freed: bool) {
    handle.stop.close_in_handler();
    let flags = if freed { CLOSED | FREED } else { CLOSED };
    // This thread holds the lock: the raise cannot be refused.
    let raised = handle.value.raise_flag(flags);
    debug_assert!(raised);
}

/// Closes a handle whose lock another thread holds: stops its waits, then closes
/// with the lock, which the waiting call gives up at once; `freeing`: for
/// `modbus_free`, which then finishes what the value does before it goes
/// ([`Closable::finish_free`]).
///
/// # Safety
/// `ptr` must be a live handle.
unsafe fn close_under_other_thread<T: Closable>(ptr: *mut Handle<T>, freeing: bool) {
    // SAFETY: guaranteed by the caller.
    let handle = unsafe { &*ptr };
    handle.stop.begin_stop();
    match handle.value.enter() {
        Entry::Locked(mut g) => {
            close_locked(handle, &mut g);
            handle.stop.note_close();
            handle.stop.end_stop();
            if freeing {
                // SAFETY: `g` is the lock of the live `ptr`.
                unsafe { T::finish_free(&mut g, ptr) };
            }
            // SAFETY: `g` is the lock of `ptr`.
            unsafe { release_slow(ptr, g) };
        }
        // Cannot happen (the holder was another thread, and a handler of ours never
        // keeps the lock); a handler's close all the same.
        Entry::HeldByThisThread => {
            handle.stop.end_stop();
            close_in_handler(handle, false);
        }
    }
}

/// `modbus_close`. When no call is inside the handle, an ordinary close; when a call
/// of this thread is (we run in a signal handler that interrupted it), the close
/// without the lock of `Stop::close_in_handler`, finished by that call as it unwinds;
/// when another thread's call is, see [`close_under_other_thread`].
///
/// # Safety
/// `ptr` must be NULL or a live handle.
pub unsafe fn close<T: Closable>(ptr: *mut Handle<T>) {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ptr.as_ref() }) else { return };
    let deferred = cancel::defer_rare(false);
    match handle.value.try_lock() {
        Some(mut g) => {
            close_locked(handle, &mut g);
            handle.stop.note_close();
            // SAFETY: `g` is the lock of `ptr`.
            unsafe { release_slow(ptr, g) };
        }
        None if handle.value.holder() == current_thread() => close_in_handler(handle, false),
        // SAFETY: `ptr` is live.
        None => unsafe { close_under_other_thread(ptr, false) },
    }
    if deferred {
        cancel::resume();
    }
}

/// `modbus_free`: when no call is inside, frees without closing, as libmodbus; when
/// one is, closes first (as [`close`]) and leaves the freeing to the last reference:
/// from a signal handler, the interrupted call frees as it unwinds.
///
/// # Safety
/// `ptr` must be NULL or a live handle, not used by the caller afterwards.
pub unsafe fn free<T: Closable>(ptr: *mut Handle<T>) {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ptr.as_ref() }) else { return };
    let deferred = cancel::defer_rare(false);
    let handed_over = match handle.value.try_lock() {
        Some(g) => {
            // Not closed, as libmodbus; a `modbus_tcp_accept` waiting unlocked still
            // ends (EBADF), and frees the handle as it leaves.
            handle.stop.note_close();
            // SAFETY: `g` is the lock of `ptr`.
            unsafe { release_slow(ptr, g) };
            false
        }
        None if handle.value.holder() == current_thread() => {
            close_in_handler(handle, true);
            true
        }
        None => {
            // SAFETY: `ptr` is live.
            unsafe { close_under_other_thread(ptr, true) };
            false
        }
    };
    if !handed_over {
        // SAFETY: the application's reference, given up here.
        unsafe { give_back(ptr) };
    }
    if deferred {
        cancel::resume();
    }
}
