//! The context's lock: a mutex whose lock word is its owner.
//!
//! A call that finds the lock taken must know, without waiting, whether the holder is
//! a call of its own thread that a signal handler interrupted (waiting would then be a
//! deadlock: the holder cannot run again before the handler returns). Mutexes that
//! record their owner after taking the lock leave a window in which a handler sees the
//! lock taken and no owner; here taking the lock and naming the owner are one
//! compare-and-swap of the owner's thread id, so the answer is exact at every
//! instruction.
//!
//! The word: the owner's thread id (a pointer, so its two low bits are free), bit 0
//! set when threads may be sleeping on the word (a futex on its low 32 bits), bit 1 a
//! flag the owner's own signal handler may raise for the owner to find when it
//! unlocks ([`OwnerGuard::release`]). Locking and unlocking are one atomic
//! instruction each when nobody waits, and unlocking touches no memory after the
//! swap that frees the lock, so the lock may be freed by whoever takes it next.
//!
//! A word with flags and no owner is free too: the child of a `fork` gets one when
//! the thread that held the lock does not exist in it ([`OwnerMutex::forget_dead_holder`]);
//! the next holder takes the flags with the lock.

use std::cell::UnsafeCell;
use std::marker::PhantomData;
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering::SeqCst};

/// The calling thread's id: `pthread_self`, a read of the thread pointer in glibc
/// (no system call, usable in a signal handler), never 0 for a live thread and
/// aligned far beyond 4.
#[inline]
pub fn current_thread() -> usize {
    // SAFETY: pthread_self has no preconditions.
    let me = unsafe { libc::pthread_self() } as usize;
    debug_assert!(me != 0 && me & LOW_BITS == 0);
    me
}

/// Threads may sleep on the word: the unlock wakes one.
const CONTENDED: usize = 1;
/// Raised by the owner's signal handler (see [`OwnerMutex::raise_flag`]).
const FLAG: usize = 2;
const LOW_BITS: usize = CONTENDED | FLAG;

/// A mutual-exclusion lock over `T` that knows which thread holds it.
pub struct OwnerMutex<T> {
    word: AtomicUsize,
    /// The references to the handle this lock is part of (see `crate::handle`), kept
    /// here so that a guard alone can hold one; 1 (the owner's) when made.
    refs: AtomicU32,
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
    /// A call of this very thread holds it: we run inside a signal handler that
    /// interrupted that call.
    HeldByThisThread,
}

impl<T> OwnerMutex<T> {
    pub const fn new(value: T) -> Self {
        OwnerMutex { word: AtomicUsize::new(0), refs: AtomicU32::new(1), value: UnsafeCell::new(value) }
    }

    pub fn get_mut(&mut self) -> &mut T {
        self.value.get_mut()
    }

    /// The references to the handle (see `crate::handle`).
    pub(super) fn refs(&self) -> &AtomicU32 {
        &self.refs
    }

    /// Takes the lock if it is free.
    #[inline]
    pub fn try_lock(&self) -> Option<OwnerGuard<'_, T>> {
        let me = current_thread();
        let mut word = 0;
        loop {
            match self.word.compare_exchange(word, word | me, SeqCst, SeqCst) {
                Ok(_) => return Some(OwnerGuard::new(self)),
                // Free, with flags left for the next holder (after a fork).
                Err(now) if now & !LOW_BITS == 0 => word = now,
                Err(_) => return None,
            }
        }
    }

    /// The thread holding the lock, or 0.
    pub fn holder(&self) -> usize {
        self.word.load(SeqCst) & !LOW_BITS
    }

    /// Raises the flag that the holder's [`OwnerGuard::release`] returns; true when
    /// raised. Only the holding thread may (a signal handler of that thread included):
    /// for any other caller, and on a free lock, it refuses and changes nothing. (A
    /// flag on a free lock would make its word non-zero with no owner: no locker
    /// could take it again, each would sleep on it for ever.)
    ///
    /// The holder cannot change between the check and the raise: only the holder's
    /// thread releases the lock, and that is the thread running here (a handler
    /// interrupts its thread's release either before the swap, which then waits
    /// for the handler, or after it, when the check refuses).
    pub(super) fn raise_flag(&self) -> bool {
        if self.word.load(SeqCst) & !LOW_BITS != current_thread() {
            return false;
        }
        self.word.fetch_or(FLAG, SeqCst);
        true
    }

    /// Takes the lock, waiting for another thread to release it; never waits for this
    /// thread (see [`Entry::HeldByThisThread`]).
    #[inline]
    pub fn enter(&self) -> Entry<'_, T> {
        let me = current_thread();
        match self.word.compare_exchange(0, me, SeqCst, SeqCst) {
            Ok(_) => Entry::Locked(OwnerGuard::new(self)),
            Err(word) if word & !LOW_BITS == me => Entry::HeldByThisThread,
            Err(_) => {
                self.lock_slow(me);
                Entry::Locked(OwnerGuard::new(self))
            }
        }
    }

    /// Takes the lock, waiting as long as it takes. Only for code that cannot run
    /// while this thread holds the lock (tests).
    pub fn lock(&self) -> OwnerGuard<'_, T> {
        match self.enter() {
            Entry::Locked(g) => g,
            Entry::HeldByThisThread => panic!("context lock taken twice by one thread"),
        }
    }

    /// Waits for another thread to release the lock and takes it (marked contended:
    /// others may still wait, and its unlock must wake them).
    #[cold]
    fn lock_slow(&self, me: usize) {
        let mut word = self.word.load(SeqCst);
        loop {
            if word & !LOW_BITS == 0 {
                // Free (with the flags a fork left, if any: see the module doc).
                match self.word.compare_exchange(word, word | me | CONTENDED, SeqCst, SeqCst) {
                    Ok(_) => return,
                    Err(now) => word = now,
                }
                continue;
            }
            if word & CONTENDED == 0 {
                if let Err(now) = self.word.compare_exchange(word, word | CONTENDED, SeqCst, SeqCst) {
                    word = now;
                    continue;
                }
                word |= CONTENDED;
            }
            futex_wait(&self.word, word);
            word = self.word.load(SeqCst);
        }
    }

    /// In the child of a `fork`, where only the forking thread exists: a lock held by
    /// another thread (its call does not go on here) becomes free, with the flags
    /// that call had, for the next holder. Only for a handler of `pthread_atfork`
    /// (the child has one thread, and nobody waits on the word).
    pub(super) fn forget_dead_holder(&self) {
        let word = self.word.load(SeqCst);
        let holder = word & !LOW_BITS;
        if holder != 0 && holder != current_thread() {
            self.word.store(word & FLAG, SeqCst);
        }
    }

    /// A guard for the lock this thread holds with no guard (taken by a
    /// `pthread_atfork` handler before the fork, whose guard it forgot).
    ///
    /// # Safety
    /// This thread holds the lock, and no guard of it exists.
    pub(super) unsafe fn adopt(&self) -> OwnerGuard<'_, T> {
        debug_assert_eq!(self.holder(), current_thread());
        OwnerGuard::new(self)
    }

    /// Releases the lock; returns the word it had.
    #[inline]
    fn unlock(&self) -> usize {
        let word = self.word.swap(0, SeqCst);
        if word & CONTENDED != 0 {
            futex_wake(&self.word);
        }
        word
    }
}

/// The address of the word's low 32 bits, which the futex calls watch.
fn futex_addr(word: &AtomicUsize) -> *mut u32 {
    let base = word.as_ptr().cast::<u32>();
    if cfg!(target_endian = "big") && size_of::<usize>() == 8 { base.wrapping_add(1) } else { base }
}

/// Sleeps while the low 32 bits of `word` hold those of `expected` (or until a wake
/// or a signal).
fn futex_wait(word: &AtomicUsize, expected: usize) {
    // SAFETY: FUTEX_WAIT_PRIVATE reads the live, aligned u32 inside `word`; no timeout.
    unsafe {
        libc::syscall(
            libc::SYS_futex,
            futex_addr(word),
            libc::FUTEX_WAIT | libc::FUTEX_PRIVATE_FLAG,
            expected as u32,
            std::ptr::null::<libc::timespec>(),
        )
    };
}

/// Wakes one thread sleeping on `word`. The kernel only uses the address as a key
/// (a private futex), so the word may already be freed by the next owner.
fn futex_wake(word: &AtomicUsize) {
    // SAFETY: FUTEX_WAKE_PRIVATE does not access the memory at the address.
    unsafe { libc::syscall(libc::SYS_futex, futex_addr(word), libc::FUTEX_WAKE | libc::FUTEX_PRIVATE_FLAG, 1) };
}

/// The locked value; dropping it releases the lock.
///
/// Never `Send`: the lock word names the thread that took it, and only that thread
/// may release it (another thread's unlock would free a lock its owner still uses,
/// and leave the owner's signal handlers answering for a thread that no longer holds
/// it). `Sync` only when `T` is: a shared guard hands out `&T`, and its other `&self`
/// operations refuse any thread but the holder. (std's `MutexGuard` once got this
/// wrong: rust-lang/rust#41622.)
pub struct OwnerGuard<'a, T> {
    lock: &'a OwnerMutex<T>,
    /// Not `Send`, not `Sync` by default (see the `Sync` impl below).
    _owner_thread: PhantomData<*const ()>,
}

// SAFETY: through `&OwnerGuard` another thread reaches `&T` (Deref), which `T: Sync`
// allows, and the lock word, whose `&self` operations are atomic and refuse any
// thread but the holder. The guard never moves to another thread (not `Send`).
unsafe impl<T: Sync> Sync for OwnerGuard<'_, T> {}

impl<'a, T> OwnerGuard<'a, T> {
    /// The guard of a lock this thread has just taken.
    fn new(lock: &'a OwnerMutex<T>) -> Self {
        OwnerGuard { lock, _owner_thread: PhantomData }
    }

    /// Releases the lock; true when the holder's signal handler raised the flag
    /// ([`OwnerMutex::raise_flag`]) meanwhile. The lock is not touched afterwards.
    pub(super) fn release(self) -> bool {
        let lock = self.lock;
        std::mem::forget(self);
        lock.unlock() & FLAG != 0
    }

    /// The lock this guard holds.
    pub(super) fn mutex(g: &Self) -> &'a OwnerMutex<T> {
        g.lock
    }

    /// Runs `f` with the lock released (so that `f` may call back into the library
    /// with the same context), and takes it again afterwards, also when `f` unwinds
    /// (the guard must hold the lock whenever it exists). A flag raised before is kept
    /// for the final release.
    pub fn unlocked<R>(g: &mut Self, f: impl FnOnce() -> R) -> R {
        /// Takes the lock back when dropped: after `f` returns or while it unwinds.
        struct Relock<'b, T> {
            lock: &'b OwnerMutex<T>,
            flag: usize,
        }
        impl<T> Drop for Relock<'_, T> {
            fn drop(&mut self) {
                let me = current_thread();
                if self.lock.word.compare_exchange(0, me, SeqCst, SeqCst).is_err() {
                    self.lock.lock_slow(me);
                }
                if self.flag != 0 {
                    self.lock.word.fetch_or(self.flag, SeqCst);
                }
            }
        }
        let _relock = Relock { lock: g.lock, flag: g.lock.unlock() & FLAG };
        f()
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

/// Compile-time checks of the guard's auto traits: each expression below is ambiguous,
/// so the build fails, if the type it names has the trait it must not have.
#[cfg(test)]
mod auto_traits {
    use super::OwnerGuard;
    use std::cell::Cell;

    /// Two candidate impls for a `Send` type (markers `()` and `u8`), one otherwise:
    /// `<X as LacksSend<_>>::check` only infers its marker when `X` is not `Send`.
    trait LacksSend<Marker> {
        fn check() {}
    }
    impl<X: ?Sized> LacksSend<()> for X {}
    impl<X: ?Sized + Send> LacksSend<u8> for X {}

    /// The same for `Sync`.
    trait LacksSync<Marker> {
        fn check() {}
    }
    impl<X: ?Sized> LacksSync<()> for X {}
    impl<X: ?Sized + Sync> LacksSync<u8> for X {}

    fn has_sync<X: ?Sized + Sync>() {}

    // Never `Send`, even over a `Send + Sync` value; `Sync` exactly when the value is
    // (`Cell` is `Send` but not `Sync`).
    const _: fn() = || {
        <OwnerGuard<'static, u32> as LacksSend<_>>::check();
        <OwnerGuard<'static, Cell<u32>> as LacksSend<_>>::check();
        <OwnerGuard<'static, Cell<u32>> as LacksSync<_>>::check();
        has_sync::<OwnerGuard<'static, u32>>();
    };
}

#[cfg(test)]
mod tests {
    use super::*;

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
    fn the_flag_reaches_the_release_only() {
        let m = OwnerMutex::new(());
        let g = m.lock();
        assert!(m.raise_flag());
        assert_eq!(m.holder(), current_thread());
        assert!(g.release());
        assert!(!m.lock().release());
    }

    #[test]
    fn a_word_with_flags_and_no_owner_is_free() {
        // A fork child's view of a lock whose holder (with a raised flag) is another
        // thread, which does not exist there.
        let elsewhere = current_thread() ^ 0x1000;
        let m = OwnerMutex::new(());
        m.word.store(elsewhere | CONTENDED | FLAG, SeqCst);
        m.forget_dead_holder();
        assert_eq!(m.word.load(SeqCst), FLAG, "free, the flag kept, nobody waiting");
        let g = m.try_lock().expect("try_lock takes a free word with flags");
        assert!(g.release(), "the flag goes to the next holder");
        m.word.store(elsewhere | FLAG, SeqCst);
        m.forget_dead_holder();
        assert!(m.lock().release(), "enter takes a free word with flags too");
        assert!(!m.lock().release());
        // The forking thread's own lock is kept.
        let g = m.lock();
        m.forget_dead_holder();
        assert_eq!(m.holder(), current_thread());
        assert!(!g.release());
    }

    #[test]
    fn a_non_holder_cannot_break_the_lock() {
        let m = OwnerMutex::new(());
        // On a free lock: refused, and the lock stays free (it used to become a word
        // with no owner that nobody could take again).
        assert!(!m.raise_flag());
        assert_eq!(m.word.load(SeqCst), 0);
        let g = m.try_lock().expect("a refused flag leaves the lock free");
        // From another thread while this one holds it, on the lock or through the
        // shared guard: refused, the holder's release finds no flag.
        std::thread::scope(|s| {
            s.spawn(|| {
                assert!(!m.raise_flag());
                assert!(!OwnerGuard::mutex(&g).raise_flag());
            })
            .join()
            .unwrap()
        });
        assert!(!g.release());
        assert!(m.try_lock().is_some_and(|g| !g.release()));
    }
}
