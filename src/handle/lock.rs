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
//! The word: the owner's thread id (a pointer, aligned far beyond 16, so its four low
//! bits are free), bit 0 set when threads may be sleeping on the word (a futex on its
//! low 32 bits), bits 1 to 3 flags that the owner, or its own signal handler, raises
//! for the owner's release to find ([`OwnerGuard::release_unless`]; what they mean
//! is the handle's). Locking and unlocking are one atomic instruction each when nobody waits
//! and no flag is up (the unlock is a compare-and-swap of the owner's id with 0, which
//! fails, sending the holder to the slow release, as soon as anything was added), and
//! unlocking touches no memory after the instruction that frees the lock, so the lock
//! may be freed by whoever takes it next.
//!
//! A word with flags and no owner is free too: the child of a `fork` gets one when
//! the thread that held the lock does not exist in it ([`OwnerMutex::forget_dead_holder`]);
//! the next holder takes the flags with the lock.

use std::cell::UnsafeCell;
use std::marker::PhantomData;
use std::ops::{Deref, DerefMut};
use std::sync::atomic::{AtomicU32, AtomicUsize, Ordering::SeqCst};

/// The calling thread's id: its thread pointer, the address of its thread control
/// block (no system call, usable in a signal handler), never 0 for a live thread and
/// aligned far beyond 16. Any value unique among live threads would do; this one is
/// also the same in a fork child for the forking thread, whose copy it is.
///
/// On x86-64 one load: the TLS ABI (the one compilers use for local-exec thread
/// locals) makes the first word of the control block point to the block itself, so
/// `fs:[0]` is the thread pointer (glibc's and musl's `pthread_self` return it too).
/// Elsewhere, `pthread_self`.
#[inline]
pub fn current_thread() -> usize {
    #[cfg(target_arch = "x86_64")]
    let me = {
        let tp: usize;
        // SAFETY: reads the first word of this thread's control block, which every
        // thread has for its whole life; no memory of ours is touched.
        unsafe {
            std::arch::asm!("mov {}, qword ptr fs:[0]", out(reg) tp, options(nostack, readonly, preserves_flags, pure))
        };
        tp
    };
    #[cfg(not(target_arch = "x86_64"))]
    // SAFETY: pthread_self has no preconditions.
    let me = unsafe { libc::pthread_self() } as usize;
    debug_assert!(me != 0 && me & LOW_BITS == 0);
    me
}

/// Threads may sleep on the word: the unlock wakes one.
const CONTENDED: usize = 1;
/// The flags: raised by the holder or its signal handler ([`OwnerMutex::raise_flag`])
/// or set as the lock is taken ([`OwnerMutex::enter_flagged`]), returned by the
/// release.
pub(super) const FLAGS: usize = 0b1110;
const LOW_BITS: usize = CONTENDED | FLAGS;

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
                Ok(_) => return Some(OwnerGuard::new(self, me)),
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

    /// Raises `flags` (within [`FLAGS`]) for the holder's release
    /// ([`OwnerGuard::release_unless`]) to return; true when raised. Only the holding thread may (a signal handler of that
    /// thread included):
    /// for any other caller, and on a free lock, it refuses and changes nothing. (A
    /// flag on a free lock would make its word non-zero with no owner: no locker
    /// could take it again, each would sleep on it for ever.)
    ///
    /// The holder cannot change between the check and the raise: only the holder's
    /// thread releases the lock, and that is the thread running here (a handler
    /// interrupts its thread's release either before the swap, which then waits
    /// for the handler, or after it, when the check refuses).
    pub(super) fn raise_flag(&self, flags: usize) -> bool {
        debug_assert!(flags & !FLAGS == 0);
        if self.word.load(SeqCst) & !LOW_BITS != current_thread() {
            return false;
        }
        self.word.fetch_or(flags & FLAGS, SeqCst);
        true
    }

    /// Takes the lock, waiting for another thread to release it; never waits for this
    /// thread (see [`Entry::HeldByThisThread`]).
    #[inline]
    pub fn enter(&self) -> Entry<'_, T> {
        self.enter_flagged(0)
    }

    /// [`OwnerMutex::enter`], with `flags` (within [`FLAGS`]) up from the start.
    #[inline]
    pub(super) fn enter_flagged(&self, flags: usize) -> Entry<'_, T> {
        let me = current_thread();
        match self.word.compare_exchange(0, me | flags, SeqCst, SeqCst) {
            Ok(_) => Entry::Locked(OwnerGuard::new(self, me)),
            Err(word) if word & !LOW_BITS == me => Entry::HeldByThisThread,
            Err(_) => {
                self.lock_slow(me | flags);
                Entry::Locked(OwnerGuard::new(self, me))
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

    /// Waits for another thread to release the lock and takes it as `me` (the thread
    /// and the flags it starts with), marked contended: others may still wait, and
    /// its unlock must wake them.
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
    /// another thread (its call does not go on here) becomes free, with the flags of
    /// that call in `keep` left for the next holder. Only for a handler of
    /// `pthread_atfork` (the child has one thread, and nobody waits on the word).
    pub(super) fn forget_dead_holder(&self, keep: usize) {
        let word = self.word.load(SeqCst);
        let holder = word & !LOW_BITS;
        if holder != 0 && holder != current_thread() {
            self.word.store(word & keep & FLAGS, SeqCst);
        }
    }

    /// A guard for the lock this thread holds with no guard (taken by a
    /// `pthread_atfork` handler before the fork, whose guard it forgot).
    ///
    /// # Safety
    /// This thread holds the lock, and no guard of it exists.
    pub(super) unsafe fn adopt(&self) -> OwnerGuard<'_, T> {
        debug_assert_eq!(self.holder(), current_thread());
        OwnerGuard::new(self, current_thread())
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
    /// The holder: the word it put in, flags aside.
    me: usize,
    /// Not `Send`, not `Sync` by default (see the `Sync` impl below).
    _owner_thread: PhantomData<*const ()>,
}

// SAFETY: through `&OwnerGuard` another thread reaches `&T` (Deref), which `T: Sync`
// allows, and the lock word, whose `&self` operations are atomic and refuse any
// thread but the holder. The guard never moves to another thread (not `Send`).
unsafe impl<T: Sync> Sync for OwnerGuard<'_, T> {}

impl<'a, T> OwnerGuard<'a, T> {
    /// The guard of a lock this thread (`me`) has just taken.
    fn new(lock: &'a OwnerMutex<T>, me: usize) -> Self {
        OwnerGuard { lock, me, _owner_thread: PhantomData }
    }

    /// Releases the lock if nothing was added to the word since it was taken (no
    /// flag, nobody waiting): one compare-and-swap. Otherwise the guard comes back,
    /// for [`OwnerGuard::release_unless`].
    #[inline]
    pub(super) fn try_release(self) -> Result<(), Self> {
        match self.lock.word.compare_exchange(self.me, 0, SeqCst, SeqCst) {
            Ok(_) => {
                std::mem::forget(self);
                Ok(())
            }
            Err(_) => Err(self),
        }
    }

    /// Releases the lock unless one of `flags` is up (then the guard comes back, the
    /// holder acts on it, and tries again); returns the flags it had. A flag raised by
    /// a signal handler is never lost: it is either seen here, or raised after the
    /// lock was freed, when the handler's raise is refused.
    pub(super) fn release_unless(self, flags: usize) -> Result<usize, Self> {
        let mut word = self.lock.word.load(SeqCst);
        loop {
            if word & flags != 0 {
                return Err(self);
            }
            match self.lock.word.compare_exchange(word, 0, SeqCst, SeqCst) {
                Ok(_) => {
                    let lock = self.lock;
                    std::mem::forget(self);
                    if word & CONTENDED != 0 {
                        futex_wake(&lock.word);
                    }
                    return Ok(word & FLAGS);
                }
                Err(now) => word = now,
            }
        }
    }

    /// The flags up now.
    pub(super) fn flags(g: &Self) -> usize {
        g.lock.word.load(SeqCst) & FLAGS
    }

    /// Takes `flags` down; returns those of them that were up.
    pub(super) fn take_flags(g: &mut Self, flags: usize) -> usize {
        g.lock.word.fetch_and(!(flags & FLAGS), SeqCst) & flags & FLAGS
    }

    /// The lock this guard holds.
    pub(super) fn mutex(g: &Self) -> &'a OwnerMutex<T> {
        g.lock
    }

    /// Runs `f` with the lock released (so that `f` may call back into the library
    /// with the same context), and takes it again afterwards, also when `f` unwinds
    /// (the guard must hold the lock whenever it exists). The flags up before are up
    /// again after, for the final release.
    pub fn unlocked<R>(g: &mut Self, f: impl FnOnce() -> R) -> R {
        /// Takes the lock back when dropped: after `f` returns or while it unwinds.
        struct Relock<'b, T> {
            lock: &'b OwnerMutex<T>,
            /// The holder and its flags.
            word: usize,
        }
        impl<T> Drop for Relock<'_, T> {
            fn drop(&mut self) {
                if self.lock.word.compare_exchange(0, self.word, SeqCst, SeqCst).is_err() {
                    self.lock.lock_slow(self.word);
                }
            }
        }
        let _relock = Relock { lock: g.lock, word: g.me | (g.lock.unlock() & FLAGS) };
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

    impl<T> OwnerGuard<'_, T> {
        /// Releases the lock; the flags it had.
        fn release(self) -> usize {
            self.release_unless(0).ok().expect("no flag refused")
        }
    }

    #[test]
    fn the_thread_id_is_unique_and_stable() {
        let me = current_thread();
        assert_eq!(current_thread(), me);
        // SAFETY: no preconditions.
        assert_eq!(me, unsafe { libc::pthread_self() } as usize, "glibc returns the thread pointer");
        let other = std::thread::spawn(current_thread).join().unwrap();
        assert_ne!(other, me);
        assert_eq!(other & LOW_BITS, 0);
    }

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

    const F: usize = 0b0010;
    const G: usize = 0b1000;

    #[test]
    fn the_flags_reach_the_release_only() {
        let m = OwnerMutex::new(());
        let g = m.lock();
        assert!(m.raise_flag(F));
        assert_eq!(m.holder(), current_thread());
        assert_eq!(g.release(), F);
        assert_eq!(m.lock().release(), 0);
        // Set as the lock is taken; carried across `unlocked`; the fast release
        // refuses while any is up.
        let Entry::Locked(mut g) = m.enter_flagged(G) else { panic!("free") };
        assert!(m.raise_flag(F));
        OwnerGuard::unlocked(&mut g, || assert_eq!(m.holder(), 0));
        let g = g.try_release().expect_err("flags up");
        assert_eq!(g.release(), F | G);
        assert!(m.lock().try_release().is_ok());
        assert_eq!(m.word.load(SeqCst), 0);
    }

    #[test]
    fn release_unless_leaves_no_flag_behind() {
        let m = OwnerMutex::new(());
        let mut g = m.lock();
        assert!(m.raise_flag(F | G));
        let mut g2 = g.release_unless(F).expect_err("F is up");
        assert_eq!(OwnerGuard::take_flags(&mut g2, F), F);
        assert_eq!(OwnerGuard::take_flags(&mut g2, F), 0);
        g = g2;
        assert_eq!(g.release_unless(F).ok(), Some(G));
        assert_eq!(m.word.load(SeqCst), 0);
    }

    #[test]
    fn a_word_with_flags_and_no_owner_is_free() {
        // A fork child's view of a lock whose holder (with a raised flag) is another
        // thread, which does not exist there.
        let elsewhere = current_thread() ^ 0x1000;
        let m = OwnerMutex::new(());
        m.word.store(elsewhere | CONTENDED | F | G, SeqCst);
        m.forget_dead_holder(F);
        assert_eq!(m.word.load(SeqCst), F, "free, F kept, G dropped, nobody waiting");
        let g = m.try_lock().expect("try_lock takes a free word with flags");
        assert_eq!(g.release(), F, "the flag goes to the next holder");
        m.word.store(elsewhere | F, SeqCst);
        m.forget_dead_holder(F);
        assert_eq!(m.lock().release(), F, "enter takes a free word with flags too");
        assert_eq!(m.lock().release(), 0);
        // The forking thread's own lock is kept.
        let g = m.lock();
        m.forget_dead_holder(F);
        assert_eq!(m.holder(), current_thread());
        assert_eq!(g.release(), 0);
    }

    #[test]
    fn a_non_holder_cannot_break_the_lock() {
        let m = OwnerMutex::new(());
        // On a free lock: refused, and the lock stays free (it used to become a word
        // with no owner that nobody could take again).
        assert!(!m.raise_flag(F));
        assert_eq!(m.word.load(SeqCst), 0);
        let g = m.try_lock().expect("a refused flag leaves the lock free");
        // From another thread while this one holds it, on the lock or through the
        // shared guard: refused, the holder's release finds no flag.
        std::thread::scope(|s| {
            s.spawn(|| {
                assert!(!m.raise_flag(F));
                assert!(!OwnerGuard::mutex(&g).raise_flag(F));
            })
            .join()
            .unwrap()
        });
        assert_eq!(g.release(), 0);
        assert!(m.try_lock().is_some_and(|g| g.release() == 0));
    }
}
