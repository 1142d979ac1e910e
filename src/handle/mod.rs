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
//! handle hands the application's reference to that call, through the lock word's
//! flag: the call gives it up as it releases the lock. The reference count and the
//! flag are private to this module ([`lock`] is its child).
//!
//! A `fork` child gets working handles even when another thread was inside a call
//! at the fork ([`fork`]).
//!
//! The module is generic over the value behind the lock ([`Closable`]), so that it
//! sits below the context with the lock and the stop state, and the engine may run
//! callbacks unlocked without an import cycle; the C layer instantiates it over the
//! context (`ffi::Modbus`).

mod fork;
pub mod lock;
pub(crate) mod stop;

use std::sync::Arc;
use std::sync::atomic::Ordering::SeqCst;

use crate::error::{Error, Result};
use lock::{Entry, OwnerGuard, OwnerMutex, current_thread};
use stop::Stop;

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
        handle.value.forget_dead_holder();
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

/// Releases the lock a call took on `ptr`; when a `modbus_free` handed the
/// application's reference to this call meanwhile (the lock word's flag), gives it
/// up, which may free the handle. Nothing of the handle is touched afterwards.
///
/// # Safety
/// `g` must be the lock of the live handle `ptr`.
unsafe fn unlock_call<T>(ptr: *mut Handle<T>, g: OwnerGuard<'_, T>) {
    if g.release() {
        // SAFETY: the reference handed over with the flag.
        unsafe { give_back(ptr) };
    }
}

/// Runs `f` on the locked value behind `ptr`: NULL gives EINVAL; from a signal
/// handler that interrupted a call of its thread on the same handle, EDEADLK at once
/// (waiting for the lock would never end). A call under which a signal handler closed
/// the value finishes that close and fails with EBADF.
///
/// # Safety
/// `ptr` must be NULL or a live handle.
pub unsafe fn call<T: Closable, R>(
    ptr: *mut Handle<T>,
    f: impl FnOnce(&mut OwnerGuard<'_, T>) -> Result<R>,
) -> Result<R> {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ptr.as_ref() }) else {
        return Err(Error::INVALID);
    };
    match handle.value.enter() {
        Entry::Locked(mut g) => {
            let r = f(&mut g);
            let r = match handle.stop.take_handled() {
                None => r,
                Some(handled) => {
                    g.finish_handler_close(handled);
                    Err(Error::STOPPED)
                }
            };
            // SAFETY: `g` is the lock of `ptr`; `handle` is not used after this.
            unsafe { unlock_call(ptr, g) };
            r
        }
        Entry::HeldByThisThread => Err(Error::REENTERED),
    }
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
                let raised = self.0.raise_flag();
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

/// Closes a handle whose lock another thread holds: stops its waits, then closes
/// with the lock, which the waiting call gives up at once.
///
/// # Safety
/// `ptr` must be a live handle.
unsafe fn close_under_other_thread<T: Closable>(ptr: *mut Handle<T>) {
    // SAFETY: guaranteed by the caller.
    let handle = unsafe { &*ptr };
    handle.stop.begin_stop();
    match handle.value.enter() {
        Entry::Locked(mut g) => {
            close_locked(handle, &mut g);
            handle.stop.note_close();
            handle.stop.end_stop();
            // SAFETY: `g` is the lock of `ptr`.
            unsafe { unlock_call(ptr, g) };
        }
        // Cannot happen (the holder was another thread, and a handler of ours never
        // keeps the lock); a handler's close all the same.
        Entry::HeldByThisThread => {
            handle.stop.end_stop();
            handle.stop.close_in_handler();
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
    match handle.value.try_lock() {
        Some(mut g) => {
            close_locked(handle, &mut g);
            handle.stop.note_close();
            // SAFETY: `g` is the lock of `ptr`.
            unsafe { unlock_call(ptr, g) };
        }
        None if handle.value.holder() == current_thread() => handle.stop.close_in_handler(),
        // SAFETY: `ptr` is live.
        None => unsafe { close_under_other_thread(ptr) },
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
    match handle.value.try_lock() {
        Some(g) => {
            drop(g);
            // Not closed, as libmodbus; a `modbus_tcp_accept` waiting unlocked still
            // ends (EBADF), and frees the handle as it leaves.
            handle.stop.note_close();
        }
        None if handle.value.holder() == current_thread() => {
            handle.stop.close_in_handler();
            // This thread holds the lock: the raise cannot be refused.
            let raised = handle.value.raise_flag();
            debug_assert!(raised);
            return;
        }
        // SAFETY: `ptr` is live.
        None => unsafe { close_under_other_thread(ptr) },
    }
    // SAFETY: the application's reference, given up here.
    unsafe { give_back(ptr) };
}
