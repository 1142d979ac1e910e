//! Stopping a context while a call waits on it: from a signal handler of the waiting
//! thread, or from another thread.
//!
//! The context itself sits behind its lock, which the waiting call holds; what a
//! stopper needs lives here instead, in atomics shared by the handle and the context:
//! - the context's descriptor, kept current by every change of it, so that a stopper
//!   can shut it down or close it without the lock;
//! - `stoppers`: closes from other threads waiting for the lock; while there are any,
//!   every wait and every error path of a call ends with EBADF at once;
//! - `closed_by_handler`: a signal handler closed the descriptor under an interrupted
//!   call of its thread, which finishes the close when it unwinds;
//! - a wake-up descriptor (an eventfd, made by the first wait that watches it and
//!   closed by `modbus_free`) that the waits on a serial line, the sleeps and
//!   `modbus_tcp_accept` poll beside their own descriptor: a socket is woken by
//!   shutting it down, a serial line has no such thing. Made on first use, so that a
//!   context that never waits that way (a client of the event-driven API, a TCP
//!   client without error recovery) holds one descriptor, not two; a stopper that
//!   finds none made has no waiter to wake, since a waiter makes it before it
//!   looks at the stop state;
//! - a copy of the serial line's saved settings, for a handler to restore them.
//!
//! Everything a signal handler does here is async-signal-safe: atomics and system
//! calls, no allocation, no lock. The module uses no other of the library (it sits
//! below the context, which holds it); what stops and closes a call is the handle's
//! (`crate::handle`), the rest is for the engine's waits.

use std::cell::UnsafeCell;
use std::sync::atomic::{AtomicBool, AtomicI32, AtomicU32, Ordering::SeqCst};

/// [`Stop::wake`] before a wait made it.
const UNMADE: i32 = -2;

/// The stop state of one context (see the module documentation).
pub struct Stop {
    fd: AtomicI32,
    /// Stoppers shutting `fd` down right now: the descriptor may not be closed or
    /// replaced until they are done (its number could be reused under them).
    shutting: AtomicU32,
    stoppers: AtomicU32,
    closed_by_handler: AtomicBool,
    /// The descriptor a handler closed; the number is kept open on /dev/null until the
    /// interrupted call unwinds and closes it.
    handled: AtomicI32,
    /// Closes of the context so far (`modbus_tcp_accept` waits unlocked and watches it).
    closes: AtomicU32,
    /// Calls of `modbus_tcp_accept` waiting: a close wakes them.
    accepting: AtomicU32,
    wake: AtomicI32,
    line: UnsafeCell<libc::termios>,
    line_saved: AtomicBool,
}

// SAFETY: `line` is written only while `line_saved` is false, by the thread holding
// the context's lock, and read only after a swap of `line_saved` from true to false,
// which happens-after the write (SeqCst store after it). Everything else is atomic.
unsafe impl Sync for Stop {}
// SAFETY: as above; the termios is plain data.
unsafe impl Send for Stop {}

impl Default for Stop {
    fn default() -> Self {
        Stop {
            fd: AtomicI32::new(-1),
            shutting: AtomicU32::new(0),
            stoppers: AtomicU32::new(0),
            closed_by_handler: AtomicBool::new(false),
            handled: AtomicI32::new(-1),
            closes: AtomicU32::new(0),
            accepting: AtomicU32::new(0),
            wake: AtomicI32::new(UNMADE),
            // SAFETY: all-zero is a valid termios.
            line: UnsafeCell::new(unsafe { std::mem::zeroed() }),
            line_saved: AtomicBool::new(false),
        }
    }
}

impl Stop {
    /// The context's descriptor (`modbus_get_socket`), -1 when none.
    #[inline]
    pub fn fd(&self) -> i32 {
        self.fd.load(SeqCst)
    }

    /// Makes `fd` the context's descriptor. Waits for stoppers shutting the old one
    /// down, so that none of them acts on its number after the caller lets it go.
    #[inline]
    pub fn set_fd(&self, fd: i32) {
        self.fd.store(fd, SeqCst);
        while self.shutting.load(SeqCst) != 0 {
            std::thread::yield_now();
        }
    }

    /// A call must end with EBADF: the context is being closed under it.
    #[inline]
    pub fn stopping(&self) -> bool {
        self.stoppers.load(SeqCst) != 0 || self.closed_by_handler.load(SeqCst)
    }

    /// The number of closes so far (see `accepting`).
    pub(super) fn closes(&self) -> u32 {
        self.closes.load(SeqCst)
    }

    /// Remembers the serial settings found at connect, for a handler's close.
    pub fn save_line(&self, saved: &libc::termios) {
        self.line_saved.store(false, SeqCst);
        // SAFETY: see the Sync impl: `line_saved` is false, and only the lock holder
        // (this thread) writes; a handler of this thread reads only after a true swap.
        unsafe { *self.line.get() = *saved };
        self.line_saved.store(true, SeqCst);
    }

    /// The settings need no restoring by a handler any more (a close is under way).
    pub fn forget_line(&self) {
        self.line_saved.store(false, SeqCst);
    }

    /// The wake-up descriptor, made now if no wait made it yet (-1 if the kernel
    /// refused one: the waits on a serial line then notice a stop only when they
    /// end). A waiter calls this before it looks at the stop state (see the module
    /// documentation).
    #[inline]
    pub fn wake_fd(&self) -> i32 {
        let fd = self.wake.load(SeqCst);
        if fd != UNMADE {
            return fd;
        }
        // SAFETY: plain system call with integer arguments (-1 on failure).
        let fresh = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
        if fresh < 0 {
            return -1;
        }
        match self.wake.compare_exchange(UNMADE, fresh, SeqCst, SeqCst) {
            Ok(_) => fresh,
            Err(other) => {
                // Another thread made one first.
                // SAFETY: the descriptor made above, not shared.
                unsafe { libc::close(fresh) };
                other
            }
        }
    }

    /// Empties the wake-up descriptor after a wake that was not a stop.
    pub fn drain_wake(&self) {
        let fd = self.wake.load(SeqCst);
        if fd >= 0 {
            let mut count = [0u8; 8];
            // SAFETY: the kernel writes at most 8 bytes into the live array.
            unsafe { libc::read(fd, count.as_mut_ptr().cast(), count.len()) };
        }
    }

    fn wake_waiters(&self) {
        let fd = self.wake.load(SeqCst);
        if fd >= 0 {
            let one = 1u64.to_ne_bytes();
            // SAFETY: the kernel reads the 8 bytes of the live array.
            unsafe { libc::write(fd, one.as_ptr().cast(), one.len()) };
        }
    }

    /// Another thread is about to close the context while a call holds it: every
    /// wait of that call ends now (the socket is shut down, the wake-up descriptor
    /// written), and the calls fail with EBADF until [`Stop::end_stop`].
    ///
    /// Signals are blocked while `shutting` is raised: a handler of this thread that
    /// closed the context itself would otherwise wait in [`Stop::set_fd`] for this
    /// very frame, which cannot run before the handler returns.
    pub(super) fn begin_stop(&self) {
        self.stoppers.fetch_add(1, SeqCst);
        // SAFETY: sigset_t is plain data, filled by sigfillset; pthread_sigmask reads
        // `all` and writes the old mask into `old`, both live locals.
        let mut old: libc::sigset_t = unsafe { std::mem::zeroed() };
        // SAFETY: as above.
        let mut all: libc::sigset_t = unsafe { std::mem::zeroed() };
        // SAFETY: as above.
        unsafe {
            libc::sigfillset(&mut all);
            libc::pthread_sigmask(libc::SIG_BLOCK, &all, &mut old);
        }
        self.shutting.fetch_add(1, SeqCst);
        let fd = self.fd.load(SeqCst);
        if fd >= 0 {
            // SAFETY: shutdown on a descriptor number has no memory preconditions; the
            // number stays the context's until `shutting` drops (see `set_fd`).
            unsafe { libc::shutdown(fd, libc::SHUT_RDWR) };
        }
        self.shutting.fetch_sub(1, SeqCst);
        // SAFETY: restores the mask saved above.
        unsafe { libc::pthread_sigmask(libc::SIG_SETMASK, &old, std::ptr::null_mut()) };
        self.wake_waiters();
    }

    /// The close that [`Stop::begin_stop`] announced is done.
    pub(super) fn end_stop(&self) {
        self.drain_wake();
        self.stoppers.fetch_sub(1, SeqCst);
    }

    /// Counts a close and wakes `modbus_tcp_accept` if one waits.
    pub(super) fn note_close(&self) {
        self.closes.fetch_add(1, SeqCst);
        if self.accepting.load(SeqCst) != 0 {
            self.wake_waiters();
        }
    }

    /// `modbus_tcp_accept` starts (true) or stops (false) waiting.
    pub(super) fn set_accepting(&self, waiting: bool) {
        if waiting {
            self.accepting.fetch_add(1, SeqCst);
        } else {
            self.accepting.fetch_sub(1, SeqCst);
        }
    }

    /// In a fork child (one thread, the forking one): the stops, shutdowns and
    /// accepts other threads were making do not go on there, so they are forgotten
    /// (else every call would fail with EBADF, or a change of descriptor wait for
    /// ever); and the child gets a wake-up descriptor of its own (the inherited one
    /// is the parent's too: a wake of one would be read by the other).
    pub(super) fn after_fork_in_child(&self) {
        self.stoppers.store(0, SeqCst);
        self.shutting.store(0, SeqCst);
        self.accepting.store(0, SeqCst);
        if self.wake.load(SeqCst) == UNMADE {
            return;
        }
        // SAFETY: plain system calls with integer arguments.
        let fresh = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
        if fresh >= 0 {
            let inherited = self.wake.swap(fresh, SeqCst);
            if inherited >= 0 {
                // SAFETY: the child's copy of the descriptor this value owned.
                unsafe { libc::close(inherited) };
            }
        }
    }

    /// `modbus_close` from a signal handler that interrupted a call of its thread on
    /// this context: what libmodbus's close does to the line (the saved serial
    /// settings restored, a socket shut down, the descriptor closed), without the
    /// lock. The number is kept open on /dev/null, so that nothing else can get it
    /// while the interrupted call may still use it; that call ends with EBADF and
    /// closes it (see [`Stop::take_handled`]).
    pub(super) fn close_in_handler(&self) {
        self.closed_by_handler.store(true, SeqCst);
        self.note_close();
        let fd = self.fd.swap(-1, SeqCst);
        if fd < 0 {
            return;
        }
        self.handled.store(fd, SeqCst);
        if self.line_saved.swap(false, SeqCst) {
            // SAFETY: the swap from true makes the write of `line` visible (see the
            // Sync impl); tcsetattr reads one termios.
            unsafe { libc::tcsetattr(fd, libc::TCSANOW, self.line.get()) };
        }
        // SAFETY: plain system calls on descriptor numbers; the path is a C string.
        unsafe {
            libc::shutdown(fd, libc::SHUT_RDWR);
            let null = libc::open(c"/dev/null".as_ptr(), libc::O_RDWR | libc::O_CLOEXEC);
            if null >= 0 {
                // Closes the line (its last reference in this process: the tty's
                // hang-up on close happens now) and keeps the number.
                libc::dup3(null, fd, libc::O_CLOEXEC);
                libc::close(null);
            }
        }
    }

    /// After a call: `Some(fd)` when a handler closed the context under it, `fd` being
    /// the descriptor the handler closed (-1: it found none). Clears the state.
    pub(super) fn take_handled(&self) -> Option<i32> {
        if !self.closed_by_handler.load(SeqCst) {
            return None;
        }
        let fd = self.handled.swap(-1, SeqCst);
        self.drain_wake();
        self.closed_by_handler.store(false, SeqCst);
        Some(fd)
    }
}

impl Drop for Stop {
    fn drop(&mut self) {
        let fd = *self.wake.get_mut();
        if fd >= 0 {
            // SAFETY: closing the eventfd this value owns.
            unsafe { libc::close(fd) };
        }
    }
}
