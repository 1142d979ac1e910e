//! epoll(7), eventfd(2) and timerfd_create(2): one descriptor that is readable when
//! there is work, for the event-driven client (a context's `modbus_get_pollfd`, the
//! multi handle's `modbus_multi_get_fd`: [`WakeSet`]) and the server runner.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use crate::error::Result;
use crate::transport::last_error;

/// `epoll_create1(EPOLL_CLOEXEC)`.
pub fn create() -> Result<i32> {
    // SAFETY: plain system call with an integer argument.
    let fd = unsafe { libc::epoll_create1(libc::EPOLL_CLOEXEC) };
    if fd == -1 { Err(last_error()) } else { Ok(fd) }
}

/// `epoll_ctl`: `op` on `fd` with `events` (poll(2) bits: `POLLIN` and `POLLOUT` are
/// `EPOLLIN` and `EPOLLOUT`) and `key` as the event's data.
pub fn control(epfd: i32, op: i32, fd: i32, events: i16, key: u64) -> Result<()> {
    let mut ev = libc::epoll_event { events: events as u16 as u32, u64: key };
    // SAFETY: `ev` is a live epoll_event for the call.
    let rc = unsafe { libc::epoll_ctl(epfd, op, fd, &mut ev) };
    if rc == -1 { Err(last_error()) } else { Ok(()) }
}

/// `epoll_wait` into `events` for at most `timeout_ms` (-1: no end); the events
/// that came. EINTR is no event.
pub fn wait(epfd: i32, events: &mut [libc::epoll_event], timeout_ms: i32) -> Result<usize> {
    // SAFETY: `events` is a live, writable array of its length.
    let n = unsafe { libc::epoll_wait(epfd, events.as_mut_ptr(), events.len() as i32, timeout_ms) };
    if n >= 0 {
        return Ok(n as usize);
    }
    let e = last_error();
    if e.0 == libc::EINTR { Ok(0) } else { Err(e) }
}

/// `eventfd(0, EFD_CLOEXEC | EFD_NONBLOCK)`: a descriptor another thread (or a signal
/// handler) makes readable with [`signal`].
pub fn eventfd() -> Result<i32> {
    // SAFETY: plain system call with integer arguments.
    let fd = unsafe { libc::eventfd(0, libc::EFD_CLOEXEC | libc::EFD_NONBLOCK) };
    if fd < 0 { Err(last_error()) } else { Ok(fd) }
}

/// `timerfd_create(CLOCK_MONOTONIC)`, non-blocking: readable once [`arm`]ed time comes.
pub fn timerfd() -> Result<i32> {
    // SAFETY: plain system call with integer arguments.
    let fd = unsafe { libc::timerfd_create(libc::CLOCK_MONOTONIC, libc::TFD_CLOEXEC | libc::TFD_NONBLOCK) };
    if fd < 0 { Err(last_error()) } else { Ok(fd) }
}

/// Arms the timerfd `fd` for the monotonic time `at` (`None`: disarms).
pub fn arm(fd: i32, at: Option<Duration>) {
    let value = match at {
        // A zero value would disarm: the earliest instant instead.
        Some(t) => super::to_timespec(t.max(Duration::from_nanos(1))),
        None => libc::timespec { tv_sec: 0, tv_nsec: 0 },
    };
    let spec = libc::itimerspec { it_interval: libc::timespec { tv_sec: 0, tv_nsec: 0 }, it_value: value };
    // SAFETY: `spec` is a live itimerspec; the old value is not asked for.
    unsafe { libc::timerfd_settime(fd, libc::TFD_TIMER_ABSTIME, &spec, std::ptr::null_mut()) };
}

/// Makes the eventfd `fd` readable. Safe in a signal handler (one `write`).
pub fn signal(fd: i32) {
    let one: u64 = 1;
    // SAFETY: writes 8 bytes from a live local to the eventfd.
    unsafe { libc::write(fd, (&one as *const u64).cast(), 8) };
}

/// Reads an eventfd's or a timerfd's count: no longer readable until the next
/// [`signal`] or expiry.
pub fn drain(fd: i32) {
    let mut count = [0u8; 8];
    let _ = super::read(fd, &mut count);
}

/// [`WakeSet`]'s timerfd is not armed.
const NOT_ARMED: u64 = u64::MAX;

/// The epoll key of a [`WakeSet`]'s eventfd.
pub const KEY_WAKE: u64 = u64::MAX;
/// The epoll key of a [`WakeSet`]'s timerfd.
pub const KEY_TIMER: u64 = u64::MAX - 1;
/// The epoll key of the line in a context's [`WakeSet`].
pub const KEY_LINE: u64 = 0;

/// An epoll set that a waiter sleeps on, and that three things make readable: I/O on
/// the descriptors registered in it, its eventfd ([`WakeSet::notify`]: a new request
/// from any thread, a wake-up) and its timerfd (the earliest deadline,
/// [`WakeSet::arm_by`]). The event-driven client's descriptor (`modbus_get_pollfd`)
/// and the multi handle's (`modbus_multi_get_fd`) are one each.
///
/// Few system calls: the eventfd is written only when someone may be asleep on the
/// set without knowing of the latest request ([`WakeSet::watch`], then at most once
/// until the next watch), and the timerfd armed only when a deadline comes before
/// the one armed (an expiry that finds nothing due is re-armed then).
pub struct WakeSet {
    pub epfd: i32,
    event: i32,
    timer: i32,
    /// The timerfd's expiry as armed, in nanoseconds of the monotonic clock
    /// ([`NOT_ARMED`]: not armed, or it expired).
    armed: AtomicU64,
    /// A waiter may sleep on the set with what it was last told: the next
    /// [`WakeSet::notify`] writes the eventfd.
    watched: AtomicBool,
    /// The eventfd was written and not drained since.
    signalled: AtomicBool,
}

impl WakeSet {
    /// The epoll set with its eventfd and timerfd.
    pub fn new() -> Result<WakeSet> {
        let epfd = create()?;
        let mut w = WakeSet {
            epfd,
            event: -1,
            timer: -1,
            armed: AtomicU64::new(NOT_ARMED),
            watched: AtomicBool::new(false),
            signalled: AtomicBool::new(false),
        };
        w.event = eventfd()?;
        w.timer = timerfd()?;
        control(epfd, libc::EPOLL_CTL_ADD, w.event, libc::POLLIN, KEY_WAKE)?;
        control(epfd, libc::EPOLL_CTL_ADD, w.timer, libc::POLLIN, KEY_TIMER)?;
        Ok(w)
    }

    /// A waiter sleeps on the set from now on: the next [`WakeSet::notify`] wakes it.
    pub fn watch(&self) {
        self.watched.store(true, Ordering::SeqCst);
    }

    /// No waiter needs waking: whoever calls this looks at the requests next.
    pub fn unwatch(&self) {
        self.watched.store(false, Ordering::SeqCst);
    }

    /// Something new (a request): wakes a waiter that may sleep without knowing of it;
    /// one `write` at most between two [`WakeSet::watch`]es.
    pub fn notify(&self) {
        if self.watched.load(Ordering::Relaxed) && self.watched.swap(false, Ordering::SeqCst) {
            self.signalled.store(true, Ordering::SeqCst);
            signal(self.event);
        }
    }

    /// Wakes a waiter, whether or not one sleeps now (the next wait ends at once).
    /// Safe in a signal handler and from any thread.
    pub fn wake(&self) {
        self.signalled.store(true, Ordering::SeqCst);
        signal(self.event);
    }

    /// The set becomes readable by `at` at the latest: the timerfd is armed when `at`
    /// is in the future and before what it is armed for (a deadline due now is the
    /// caller's timeout of 0, not an expiry).
    #[inline]
    pub fn arm_by(&self, at: Duration, now: Duration) {
        if at <= now {
            return;
        }
        let nanos = at.as_secs().saturating_mul(1_000_000_000).saturating_add(u64::from(at.subsec_nanos()));
        if nanos < self.armed.load(Ordering::Relaxed) {
            self.armed.store(nanos, Ordering::Relaxed);
            arm(self.timer, Some(at));
        }
    }

    /// The set may be readable for its eventfd or its timerfd (written since the last
    /// [`WakeSet::take`], or expired by `now`, read only when the timer is armed):
    /// when not, a readable set means that what is registered in it is ready.
    pub fn may_have_woken(&self, now: impl FnOnce() -> Duration) -> bool {
        if self.signalled.load(Ordering::SeqCst) {
            return true;
        }
        let armed = self.armed.load(Ordering::Relaxed);
        armed != NOT_ARMED && {
            let now = now();
            armed <= now.as_secs().saturating_mul(1_000_000_000).saturating_add(u64::from(now.subsec_nanos()))
        }
    }

    /// Waits up to `timeout_ms` (0: not at all) for the set, into `events`; drains
    /// the eventfd and the timerfd if they are among them (an expired timer is armed
    /// again by the next [`WakeSet::arm_by`]), whose keys the caller skips. Returns
    /// the number of events and whether the eventfd was readable.
    pub fn take(&self, timeout_ms: i32, events: &mut [libc::epoll_event]) -> Result<(usize, bool)> {
        let n = wait(self.epfd, events, timeout_ms)?;
        let mut woken = false;
        for ev in &events[..n] {
            // (A copy: the packed field is read by value.)
            let key = ev.u64;
            match key {
                KEY_WAKE => {
                    self.signalled.store(false, Ordering::SeqCst);
                    drain(self.event);
                    woken = true;
                }
                KEY_TIMER => {
                    drain(self.timer);
                    self.armed.store(NOT_ARMED, Ordering::Relaxed);
                }
                _ => {}
            }
        }
        Ok((n, woken))
    }
}

impl Drop for WakeSet {
    fn drop(&mut self) {
        for fd in [self.timer, self.event, self.epfd] {
            if fd >= 0 {
                super::close(fd);
            }
        }
    }
}

/// What an epoll set holds for one line: the descriptor and which of the line's it
/// was (its generation: a number closed and reused is another), and the events.
#[derive(Clone, Copy, Debug)]
pub struct Registered {
    pub fd: i32,
    pub generation: u32,
    /// The poll(2) events registered (0: none). A line that waits for nothing keeps
    /// its registration (most wait again soon: two `epoll_ctl` calls per request
    /// saved); [`Registered::idle_report`] drops it if it reports anyway.
    pub events: i16,
    /// What the line waits for, as last told.
    pub wants: i16,
}

impl Default for Registered {
    fn default() -> Self {
        Registered { fd: -1, generation: 0, events: 0, wants: 0 }
    }
}

impl Registered {
    /// Brings the registration in `epfd` up to date: the line's descriptor `fd` (-1:
    /// none) of `generation`, waiting for `events`, reported under `key`.
    #[inline]
    pub fn update(&mut self, epfd: i32, fd: i32, generation: u32, events: i16, key: u64) -> Result<()> {
        if events != 0 && events == self.events && fd == self.fd && generation == self.generation {
            // Registered as it is to be (the usual case: nothing to do).
            self.wants = events;
            return Ok(());
        }
        self.change(epfd, fd, generation, events, key)
    }

    fn change(&mut self, epfd: i32, fd: i32, generation: u32, events: i16, key: u64) -> Result<()> {
        let active = fd >= 0 && events != 0;
        // What is registered is still this descriptor (a closed one left the epoll
        // set by itself; its number may be another's now: left alone).
        let registered = self.events != 0 && self.fd == fd && self.generation == generation;
        match (registered, active) {
            (true, true) if self.events == events => {}
            (true, true) => control(epfd, libc::EPOLL_CTL_MOD, fd, events, key)?,
            (false, true) => match control(epfd, libc::EPOLL_CTL_ADD, fd, events, key) {
                Err(e) if e.0 == libc::EEXIST => control(epfd, libc::EPOLL_CTL_MOD, fd, events, key)?,
                r => r?,
            },
            // Waiting for nothing: the registration stays.
            (_, false) => {}
        }
        *self = match (active, registered) {
            (true, _) => Registered { fd, generation, events, wants: events },
            (false, true) => Registered { wants: 0, ..*self },
            (false, false) => Registered { fd: -1, generation, events: 0, wants: 0 },
        };
        Ok(())
    }

    /// The line reported while it waits for nothing (a stray byte, a hang-up): its
    /// kept registration goes, so that it does not report again. True when it did.
    pub fn idle_report(&mut self, epfd: i32) -> bool {
        if self.wants != 0 || self.events == 0 {
            return false;
        }
        let _ = control(epfd, libc::EPOLL_CTL_DEL, self.fd, 0, 0);
        *self = Registered::default();
        true
    }
}
