//! The context's lock: a mutex whose lock word is its owner.
//!
//! A call that finds the lock taken must know, without waiting, whether the holder is
//! a call of its own thread that a signal handler interrupted (waiting would then be a
//! deadlock: the holder cannot run again before the handler returns). Mutexes that
//! record their owner after taking the lock leave a window in which a handler sees the
//! lock taken and no owner; here taking the lock and naming the owner are one
//! compare-and-swap of the owner's thread id, so the answer is exact at every
//! instruction. Waiting threads sleep on a futex sequence word.

use std::cell::UnsafeCell;
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering::SeqCst};

/// The calling thread's id: `pthread_self`, a read of the thread pointer in glibc
/// (no system call, usable in a signal handler), never 0 for a live thread.
#[inline]
pub fn current_thread() -> usize {
    // SAFETY: pthread_self has no preconditions.
    unsafe { libc::pthread_self() as usize }
}

/// A mutual-exclusion lock over `T` that knows which thread holds it.
pub struct OwnerMutex<T> {
    /// 0 when free, else the holder's [`current_thread`].
    owner: AtomicUsize,
    /// Threads sleeping (or about to) in [`OwnerMutex::lock_slow`].
    waiters: AtomicU32,
    /// The futex word the waiters sleep on; bumped by each unlock that finds waiters.
    seq: AtomicU32,
    value: UnsafeCell<T>,
}

// SAFETY: the value is only reached through a guard, and one guard exists at a time
// (the owner word is taken by compare-and-swap), so `T: Send` suffices, as for
// `std::sync::Mutex`.
unsafe impl<T: Send> Send for OwnerMutex<T> {}
// SAFETY: as above.
unsafe impl<T: Send> Sync for OwnerMutex<T> {}

/// What [`OwnerMutex::enter`] found.
pub enum Entry<'a, T> {
    /// The lock is ours now.
    Locked(OwnerGuard<'a, T>),
    /// A call of this very thread holds it: we run inside a signal handler (or a
    /// callback) that interrupted that call.
    HeldByThisThread,
}

impl<T> OwnerMutex<T> {
    pub const fn new(value: T) -> Self {
        OwnerMutex {
            owner: AtomicUsize::new(0),
            waiters: AtomicU32::new(0),
            seq: AtomicU32::new(0),
            value: UnsafeCell::new(value),
        }
    }

    pub fn get_mut(&mut self) -> &mut T {
        self.value.get_mut()
    }

    /// Takes the lock if it is free.
    #[inline]
    pub fn try_lock(&self) -> Option<OwnerGuard<'_, T>> {
        let me = current_thread();
        self.owner.compare_exchange(0, me, SeqCst, SeqCst).ok().map(|_| OwnerGuard { lock: self })
    }

    /// The thread holding the lock, or 0.
    pub fn holder(&self) -> usize {
        self.owner.load(SeqCst)
    }

    /// Takes the lock, waiting for another thread to release it; never waits for this
    /// thread (see [`Entry::HeldByThisThread`]).
    #[inline]
    pub fn enter(&self) -> Entry<'_, T> {
        let me = current_thread();
        match self.owner.compare_exchange(0, me, SeqCst, SeqCst) {
            Ok(_) => Entry::Locked(OwnerGuard { lock: self }),
            Err(holder) if holder == me => Entry::HeldByThisThread,
            Err(_) => self.lock_slow(me),
        }
    }

    /// Takes the lock, waiting as long as it takes. Only for code that cannot run
    /// while this thread holds the lock (tests, and `modbus_free` of a context no call
    /// is inside).
    pub fn lock(&self) -> OwnerGuard<'_, T> {
        match self.enter() {
            Entry::Locked(g) => g,
            Entry::HeldByThisThread => panic!("context lock taken twice by one thread"),
        }
    }

    #[cold]
    fn lock_slow(&self, me: usize) -> Entry<'_, T> {
        self.waiters.fetch_add(1, SeqCst);
        loop {
            let seen = self.seq.load(SeqCst);
            match self.owner.compare_exchange(0, me, SeqCst, SeqCst) {
                Ok(_) => break,
                // Only possible when a signal handler of this thread runs while this
                // very wait is interrupted and took the lock itself: impossible, as
                // a handler never keeps a context locked; checked all the same.
                Err(holder) if holder == me => {
                    self.waiters.fetch_sub(1, SeqCst);
                    return Entry::HeldByThisThread;
                }
                Err(_) => futex_wait(&self.seq, seen),
            }
        }
        self.waiters.fetch_sub(1, SeqCst);
        Entry::Locked(OwnerGuard { lock: self })
    }

    #[inline]
    fn unlock(&self) {
        self.owner.store(0, SeqCst);
        if self.waiters.load(SeqCst) != 0 {
            self.seq.fetch_add(1, SeqCst);
            futex_wake(&self.seq);
        }
    }
}

/// Sleeps while `word` holds `expected` (or until a wake or a signal).
fn futex_wait(word: &AtomicU32, expected: u32) {
    // SAFETY: FUTEX_WAIT_PRIVATE reads the live, aligned u32 behind `word`; no timeout.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            word.as_ptr(),
            libc::FUTEX_WAIT | libc::FUTEX_PRIVATE_FLAG,
            expected,
            std::ptr::null::<libc::timespec>(),
        )
    };
}

/// Wakes one thread sleeping on `word`.
fn futex_wake(word: &AtomicU32) {
    // SAFETY: FUTEX_WAKE_PRIVATE only uses the address of the live u32 as a key.
    unsafe { libc::syscall(libc::SYS_futex, word.as_ptr(), libc::FUTEX_WAKE | libc::FUTEX_PRIVATE_FLAG, 1) };
}

/// The locked value; dropping it releases the lock.
pub struct OwnerGuard<'a, T> {
    lock: &'a OwnerMutex<T>,
}

impl<T> OwnerGuard<'_, T> {
    /// Runs `f` with the lock released (so that `f` may call back into the library
    /// with the same context), and takes it again afterwards.
    pub fn unlocked<R>(g: &mut Self, f: impl FnOnce() -> R) -> R {
        g.lock.unlock();
        let r = f();
        let me = current_thread();
        match g.lock.owner.compare_exchange(0, me, SeqCst, SeqCst) {
            Ok(_) => {}
            Err(_) => {
                if let Entry::HeldByThisThread = g.lock.lock_slow(me) {
                    // `f` returned with the lock taken by a call of this thread:
                    // a call left it locked, which no call does.
                    panic!("context lock left taken by a callback");
                }
            }
        }
        r
    }
}

impl<T> Deref for OwnerGuard<'_, T> {
    type Target = T;
    fn deref(&self) -> &T {
        // SAFETY: the guard holds the lock, so no other reference to the value exists.
        unsafe { &*self.lock.value.get() }
    }
}

impl<T> DerefMut for OwnerGuard<'_, T> {
    fn deref_mut(&mut self) -> &mut T {
        // SAFETY: the guard holds the lock, so no other reference to the value exists.
        unsafe { &mut *self.lock.value.get() }
    }
}

impl<T> Drop for OwnerGuard<'_, T> {
    fn drop(&mut self) {
        self.lock.unlock();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    #[test]
    fn owner_is_known_and_reentry_is_refused() {
        let m = OwnerMutex::new(5);
        assert_eq!(m.holder(), 0);
        let g = m.lock();
        assert_eq!(m.holder(), current_thread());
        assert!(matches!(m.enter(), Entry::HeldByThisThread));
        assert!(m.try_lock().is_none());
        drop(g);
        assert_eq!(m.holder(), 0);
        assert!(matches!(m.enter(), Entry::Locked(_)));
    }

    #[test]
    fn unlocked_lets_another_thread_in() {
        let m = Arc::new(OwnerMutex::new(0u32));
        let mut g = m.lock();
        let m2 = Arc::clone(&m);
        OwnerGuard::unlocked(&mut g, move || {
            std::thread::spawn(move || *m2.lock() += 1).join().unwrap();
        });
        assert_eq!(*g, 1);
    }

    #[test]
    fn many_threads_count_exactly() {
        let m = Arc::new(OwnerMutex::new(0u64));
        let threads: Vec<_> = (0..8)
            .map(|_| {
                let m = Arc::clone(&m);
                std::thread::spawn(move || {
                    for _ in 0..20_000 {
                        let mut g = m.lock();
                        *g += 1;
                        if *g % 1000 == 0 {
                            std::thread::yield_now();
                        }
                    }
                })
            })
            .collect();
        for t in threads {
            t.join().unwrap();
        }
        assert_eq!(*m.lock(), 160_000);
        assert_eq!(m.waiters.load(SeqCst), 0);
    }
}
