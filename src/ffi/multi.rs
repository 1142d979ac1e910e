//! modbus.h extensions: the multi handle of the event-driven client. Thousands of
//! contexts behind one descriptor (an epoll instance): the application puts
//! `modbus_multi_get_fd` in its own loop, or lets `modbus_multi_perform` wait, and
//! every context with work is processed as `modbus_process` would (callbacks
//! included). Before each wait the handle asks each context what it waits for and
//! brings the epoll registrations up to date; a context leaves the handle when it is
//! removed or freed, wherever that happens (a callback may do it).

use std::cmp::Reverse;
use std::collections::{BinaryHeap, HashMap, HashSet};
use std::ffi::c_int;
use std::sync::Arc;
use std::time::Duration;

use crate::error::{Error, Result};
use crate::event;
use crate::ffi::event::modbus_completion_t;
use crate::ffi::{Modbus, fail, status};
use crate::handle::lock::OwnerMutex;
use crate::outstanding::{Member, Members};
use crate::transport;
use crate::transport::epoll::{self, WakeSet};

/// The opaque `modbus_multi_t`.
pub struct Multi {
    members: Arc<Members>,
    /// The members' deadlines, earliest first: a wait and the contexts due are found
    /// without looking at every member.
    timers: OwnerMutex<Timers>,
}

/// Deadlines by member, as a heap of `(deadline, handle address)`. An entry holds
/// while the member's [`Member::until`] is that deadline; others are stale, dropped
/// as they come to the top, and all at once when they outnumber the members.
#[derive(Default)]
struct Timers {
    heap: BinaryHeap<Reverse<(Duration, usize)>>,
}

impl Timers {
    /// The earliest deadline that holds.
    fn earliest(&mut self, list: &HashMap<usize, Member>) -> Option<Duration> {
        while let Some(&Reverse((t, key))) = self.heap.peek() {
            if holds(list, key, t) {
                return Some(t);
            }
            self.heap.pop();
        }
        None
    }

    /// Takes out the members whose deadline passed at `now` (their `until` is
    /// consumed: the next ask sets it again).
    fn take_due(&mut self, list: &mut HashMap<usize, Member>, now: Duration) -> Vec<usize> {
        let mut due = Vec::new();
        while let Some(&Reverse((t, key))) = self.heap.peek() {
            if t > now {
                break;
            }
            self.heap.pop();
            if holds(list, key, t) {
                if let Some(mb) = list.get_mut(&key) {
                    mb.until = None;
                }
                due.push(key);
            }
        }
        due
    }

    fn push(&mut self, list: &HashMap<usize, Member>, t: Duration, key: usize) {
        self.heap.push(Reverse((t, key)));
        if self.heap.len() > 2 * list.len() + 64 {
            self.heap.retain(|&Reverse((t, key))| holds(list, key, t));
        }
    }
}

/// The deadline `t` of member `key` is current.
fn holds(list: &HashMap<usize, Member>, key: usize, t: Duration) -> bool {
    list.get(&key).is_some_and(|mb| mb.until == Some(t))
}

/// Makes a multi handle; NULL with errno on failure.
///
/// Linux only (epoll).
#[unsafe(no_mangle)]
pub extern "C" fn modbus_multi_new() -> *mut Multi {
    match WakeSet::new() {
        Ok(set) => {
            let members = Members {
                set,
                list: OwnerMutex::new(Default::default()),
                dirty: OwnerMutex::new(Default::default()),
                closed: Default::default(),
                ready: OwnerMutex::new(Default::default()),
            };
            Box::into_raw(Box::new(Multi { members: Arc::new(members), timers: OwnerMutex::new(Timers::default()) }))
        }
        Err(e) => {
            fail(e);
            std::ptr::null_mut()
        }
    }
}

/// Adds `ctx` to `m`; a context is in one multi handle at most (EBUSY).
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle; `ctx` NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_add(m: *mut Multi, ctx: *mut Modbus) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(m) = (unsafe { m.as_ref() }) else { return fail(Error::INVALID) };
    let members = Arc::clone(&m.members);
    // SAFETY: forwarded caller contract.
    status(unsafe {
        crate::handle::call(ctx, |g| {
            let o = event::state(g)?;
            if o.multi.is_some() {
                return Err(Error(libc::EBUSY));
            }
            let key = ctx as usize;
            members.list.lock().insert(key, Member::default());
            members.mark(key);
            o.multi = Some((members, key));
            Ok(0)
        })
    })
}

/// Takes `ctx` out of `m` (EINVAL when it is not in it).
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle; `ctx` NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_remove(m: *mut Multi, ctx: *mut Modbus) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(m) = (unsafe { m.as_ref() }) else { return fail(Error::INVALID) };
    // SAFETY: forwarded caller contract.
    status(unsafe {
        crate::handle::call(ctx, |g| {
            let o = g.async_state()?.ok_or(Error::INVALID)?;
            match &o.multi {
                Some((own, key)) if Arc::ptr_eq(own, &m.members) => {
                    // Its completions not read yet come back to it.
                    let ready = m.members.remove(*key);
                    o.ready.extend(ready);
                    o.multi = None;
                    Ok(0)
                }
                _ => Err(Error::INVALID),
            }
        })
    })
}

/// The descriptor (an epoll set) that is readable when a context of `m` has I/O
/// ready, when a request is given to one (from any thread), when the earliest
/// deadline comes and after `modbus_multi_wakeup`: put it in the application's loop, wait at most `modbus_multi_timeout` (which brings it up to
/// date: call it before each wait), then call `modbus_multi_perform(m, 0)`. -1 with
/// EINVAL for NULL.
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_get_fd(m: *mut Multi) -> c_int {
    // SAFETY: guaranteed by the caller.
    match unsafe { m.as_ref() } {
        Some(m) => m.members.set.epfd,
        None => fail(Error::INVALID),
    }
}

/// Wakes `m`: the `modbus_multi_perform` that waits returns (or the next returns at
/// once), and `modbus_multi_get_fd` becomes readable. Safe from any thread and in a
/// signal handler. Returns 0, or -1 with EINVAL for NULL.
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_wakeup(m: *mut Multi) -> c_int {
    // SAFETY: guaranteed by the caller.
    match unsafe { m.as_ref() } {
        Some(m) => {
            m.members.set.wake();
            0
        }
        None => fail(Error::INVALID),
    }
}

/// Milliseconds until a context of `m` has something due without I/O (a timeout, a
/// connect, a request to send): 0 at once, -1 none. Brings the registrations up to
/// date, and from then on a request given to a context of `m` makes
/// `modbus_multi_get_fd` readable.
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_timeout(m: *mut Multi) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(m) = (unsafe { m.as_ref() }) else { return fail(Error::INVALID) };
    // Before the registrations are read: a request given after that wakes the wait.
    m.members.set.watch();
    // SAFETY: the members are live contexts (a context leaves the list as it is freed).
    match unsafe { sync(m) } {
        Ok(earliest) => ms_until(earliest),
        Err(e) => fail(e),
    }
}

/// Waits up to `timeout_ms` (0: not at all; -1: until something is due) for I/O on
/// the contexts of `m`, a request given to one of them (from another thread) or
/// `modbus_multi_wakeup`, then processes each context with I/O ready, a deadline
/// passed or a request to start (as `modbus_process`, callbacks included). With
/// nothing pending, -1 waits for a request or a wake-up. Returns the number of
/// requests completed, or -1 with errno.
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_perform(m: *mut Multi, timeout_ms: c_int) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(m) = (unsafe { m.as_ref() }) else { return fail(Error::INVALID) };
    // Before the registrations are read: a request given after that wakes the wait.
    m.members.set.watch();
    // SAFETY: as in `modbus_multi_timeout`.
    let earliest = match unsafe { sync(m) } {
        Ok(s) => s,
        Err(e) => return fail(e),
    };
    let until_due = ms_until(earliest);
    let wait = match (timeout_ms, until_due) {
        (0, _) => 0,
        (t, -1) => t.max(-1),
        (t, d) if t < 0 => d,
        (t, d) => t.min(d),
    };
    let mut events = [libc::epoll_event { events: 0, u64: 0 }; 512];
    let mut completed = 0;
    let mut processed = HashSet::new();
    let mut seen = HashSet::new(); // every key a batch reported
    let mut wait = wait;
    let mut woken = false;
    loop {
        let (n, woke) = match m.members.set.take(wait, &mut events) {
            Ok(r) => r,
            Err(e) => return fail(e),
        };
        // The wait is over: what the contexts do from now on (their requests given
        // by the callbacks below) is asked before the next.
        m.members.set.unwatch();
        woken |= woke;
        let mut fresh = 0;
        for ev in &events[..n] {
            if matches!({ ev.u64 }, epoll::KEY_WAKE | epoll::KEY_TIMER) {
                continue;
            }
            let key = ev.u64 as usize;
            // (`ev` is a copy: the packed field is read by value.)
            let revents = { ev.events } as u16 as i16;
            if seen.insert(key) {
                fresh += 1;
            }
            if processed.contains(&key) {
                continue;
            }
            // Not a member (any more): nothing to do. Waiting for nothing: its kept
            // registration reported (a stray byte, a hang-up) and goes; the next
            // request finds what happened (a deadline of its own still counts below).
            if idle_registration(m, key) == Some(false) {
                processed.insert(key);
                // SAFETY: a member is a live context.
                completed += unsafe { crate::ffi::event::process_member(key as *mut Modbus, revents) }.max(0);
            }
        }
        // A full batch: more may be ready now; take them without waiting. A batch of
        // keys reported already ends it: level-triggered, a descriptor processed
        // stays ready until the next `sync` registers what it waits for now (a
        // connected socket still registered for POLLOUT), and with more of them than
        // `events` holds the batches would never get shorter.
        if n < events.len() || fresh == 0 {
            break;
        }
        wait = 0;
    }
    if woken {
        // A request given (or a wake-up): the contexts it marked are asked now, so
        // that one due at once (a connect, a request to send) is processed below.
        // SAFETY: as in `modbus_multi_timeout`.
        if let Err(e) = unsafe { sync(m) } {
            return fail(e);
        }
    }
    let now = transport::now();
    let due = {
        let mut list = m.members.list.lock();
        m.timers.lock().take_due(&mut list, now)
    };
    for key in due {
        if processed.insert(key) && is_member(m, key) {
            // SAFETY: a member is a live context.
            completed += unsafe { crate::ffi::event::process_member(key as *mut Modbus, 0) }.max(0);
        }
    }
    completed
}

/// Pull-style completion on a multi handle: the oldest completion of a request given
/// without a callback by any of its contexts, into `*c` (`c->ctx` says which): 1, 0
/// when none is waiting, or -1 with errno (EINVAL: `m` or `c` NULL, or
/// `c->struct_size` refused). Completions of a context that leaves the handle go
/// back to it (`modbus_completion_read`), or with it when it is freed.
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle; `c` NULL or valid for `c->struct_size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_completion_read(m: *mut Multi, c: *mut modbus_completion_t) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(m) = (unsafe { m.as_ref() }) else { return fail(Error::INVALID) };
    // SAFETY: forwarded caller contract.
    if let Err(e) = unsafe { modbus_completion_t::check(c) } {
        return fail(e);
    }
    let next = m.members.ready.lock().pop_front();
    match next {
        Some((key, r)) => {
            // SAFETY: checked above; `key` is a member's handle (its completions
            // leave the queue with it).
            unsafe { modbus_completion_t::fill(c, key as *mut Modbus, r) };
            1
        }
        None => 0,
    }
}

/// Frees `m`; its contexts leave it (they are not closed or freed).
///
/// Linux only (epoll).
///
/// # Safety
/// `m` NULL or a live multi handle, not used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_multi_free(m: *mut Multi) {
    if m.is_null() {
        return;
    }
    // SAFETY: the caller hands back a handle made by `modbus_multi_new`.
    let m = unsafe { Box::from_raw(m) };
    let keys: Vec<usize> = m.members.list.lock().keys().copied().collect();
    for key in keys {
        // SAFETY: a member is a live context.
        let _ = unsafe {
            crate::handle::call(key as *mut Modbus, |g| {
                if let Ok(Some(o)) = g.async_state() {
                    o.multi = None;
                    // Its completions not read yet come back to it.
                    let ready = m.members.remove(key);
                    o.ready.extend(ready);
                }
                Ok::<(), Error>(())
            })
        };
        m.members.remove(key);
    }
    // The epoll set closes with the last reference to the members.
}

/// `None` when `key` is not a member; `Some(true)` when it waits for nothing (its
/// registration, kept, is dropped now), `Some(false)` otherwise.
fn idle_registration(m: &Multi, key: usize) -> Option<bool> {
    {
        let list = m.members.list.lock();
        let line = list.get(&key)?.line;
        if line.wants != 0 || line.events == 0 {
            return Some(false);
        }
    }
    // Dropped under the context's lock, as `sync` registers (see there); a line
    // closed since left the set by itself (its number may be another's now).
    // SAFETY: a member is a live context.
    let dropped = unsafe {
        crate::handle::call(key as *mut Modbus, |g| {
            let current = (g.fd(), g.line.generation());
            let mut list = m.members.list.lock();
            let Some(mb) = list.get_mut(&key) else { return Ok(true) };
            if (mb.line.fd, mb.line.generation) != current {
                mb.line = Default::default();
                return Ok(true);
            }
            Ok(mb.line.idle_report(m.members.set.epfd))
        })
    };
    Some(dropped.unwrap_or(true))
}

fn is_member(m: &Multi, key: usize) -> bool {
    m.members.list.lock().contains_key(&key)
}

/// Milliseconds until `t`, rounded up; -1 for none.
fn ms_until(t: Option<Duration>) -> c_int {
    match t {
        None => -1,
        Some(t) => t.saturating_sub(transport::now()).as_nanos().div_ceil(1_000_000).min(i32::MAX as u128) as c_int,
    }
}

/// Asks each context whose interest may have changed (`Members::dirty`) what it waits
/// for and brings its epoll registration up to date. Returns the earliest deadline of
/// all members.
///
/// # Safety
/// The members of `m` are live contexts.
unsafe fn sync(m: &Multi) -> Result<Option<Duration>> {
    let mut dirty = std::mem::take(&mut *m.members.dirty.lock());
    if m.members.closed.swap(false, std::sync::atomic::Ordering::SeqCst) {
        // A member was closed, maybe by a signal handler: which one is not known.
        dirty.extend(m.members.list.lock().keys());
    }
    dirty.sort_unstable();
    dirty.dedup();
    for key in dirty {
        if !is_member(m, key) {
            continue;
        }
        // Registered under the context's lock: a close from another thread (which
        // takes it) cannot close the descriptor, nor its number be reused, between
        // the asking and the registration.
        // SAFETY: guaranteed by the caller.
        let registered = unsafe {
            crate::handle::call(key as *mut Modbus, |g| {
                let interest = event::interest(g);
                let mut list = m.members.list.lock();
                let Some(member) = list.get_mut(&key) else { return Ok(Ok(())) };
                let r = member.line.update(
                    m.members.set.epfd,
                    interest.fd,
                    g.line.generation(),
                    interest.events,
                    key as u64,
                );
                let changed = member.until != interest.until;
                member.until = interest.until;
                if let (true, Some(t)) = (changed, interest.until) {
                    m.timers.lock().push(&list, t, key);
                }
                Ok(r)
            })
        };
        // (A context that could not be asked: skipped.)
        if let Ok(r) = registered {
            r?;
        }
    }
    let list = m.members.list.lock();
    let earliest = m.timers.lock().earliest(&list);
    if let Some(t) = earliest {
        // The descriptor wakes for it (an application waiting without the timeout).
        m.members.set.arm_by(t, transport::now());
    }
    Ok(earliest)
}
