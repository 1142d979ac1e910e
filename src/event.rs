//! The event-driven client: the same receive machine as the blocking calls, on the
//! same line, driven by readiness instead of blocking waits. The application owns the
//! loop: it asks what to wait for ([`interest`]), waits (its `poll`, `epoll`, libuv...),
//! and hands what happened to [`process`], which does the I/O that is ready without
//! ever blocking on it, and completes requests. The requests and their matching are
//! `proto::session::pipeline`'s; the state between calls is the context's
//! [`Outstanding`].
//!
//! Rules: a request's response timeout runs from the moment it goes out; the byte
//! timeout as usual; an answer that comes after its request timed out is dropped
//! (TCP: by its transaction id); a failure of the line completes everything in flight
//! and queued with its error and closes the line, which the next request opens again.
//! No recovery sleeps here: where the blocking calls sleep and flush, the line is
//! flushed at once.

use std::time::Duration;

use crate::context::{Context, Shut};
use crate::engine::{self, AduBuf, Guard};
use crate::error::{Error, Result};
use crate::outstanding::{Completion, Deliver, Done, Outstanding, Ready, Receiving, Wake};
use crate::proto::confirm::{self, Rejection};
use crate::proto::decode::counted_data;
use crate::proto::frame::{Framing, MsgKind};
use crate::proto::request::Request;
use crate::proto::session::client::answer_length;
use crate::proto::session::pipeline::{Answer, End, Entry, MAX_PENDING};
use crate::proto::session::receive::{Finished, Outcome, Receiver, Step};
use crate::proto::session::{Recovery, Timeout};
use crate::proto::{Diag, ascii};
use crate::session::{self, Driver, Received, Recovered};
use crate::transport;
use crate::transport::epoll::{self, Registered, WakeSet};

/// What to wait for before the next [`process`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Interest {
    /// The descriptor (-1: none yet).
    pub fd: i32,
    /// `POLLIN` and/or `POLLOUT`.
    pub events: i16,
    /// Call [`process`] by then at the latest (`None`: no deadline).
    pub until: Option<Duration>,
    /// The time `until` was reckoned at (zero when it is `None` for want of requests).
    pub now: Duration,
}

/// The context's event-driven state, made on first use; `EBUSY` while
/// `modbus_process` has it (from the RTS hook it calls: [`Context::lend_async`]).
pub fn state(ctx: &mut Context) -> Result<&mut Outstanding> {
    ctx.async_state_made()
}

/// Requests given and not completed.
pub fn pending(ctx: &Context) -> usize {
    ctx.pending()
}

/// `modbus_set_max_in_flight`.
pub fn set_max_in_flight(ctx: &mut Context, n: i32) -> Result<()> {
    if n < 1 || !state(ctx)?.pipeline.set_max_in_flight(n as usize) {
        return Err(Error::INVALID);
    }
    Ok(())
}

/// `modbus_get_max_in_flight`: the requests that may be on the wire at once (1 on a
/// serial line, whatever was set).
pub fn max_in_flight(ctx: &mut Context) -> Result<i32> {
    Ok(match ctx.async_state()? {
        Some(o) => o.pipeline.max_in_flight() as i32,
        None => 1,
    })
}

/// The completion of a request given without a callback, for the application to read:
/// the multi handle's queue while the context is in one (`key`: the context's), else
/// the context's own.
pub fn ready(ctx: &mut Context, r: Ready) {
    if let Ok(Some(o)) = ctx.async_state() {
        match &o.multi {
            Some((members, key)) => members.ready.lock().push_back((*key, r)),
            None => o.ready.push_back(r),
        }
    }
}

/// `modbus_completion_read`: the oldest completion not read yet.
pub fn take_ready(ctx: &mut Context) -> Result<Option<Ready>> {
    Ok(ctx.async_state()?.and_then(|o| o.ready.pop_front()))
}

/// Queues `req`; returns its id. `EINVAL` without a slave (serial), `EAGAIN` when the
/// queue is full.
pub fn submit(ctx: &mut Context, req: &Request<'_>, completion: Completion) -> Result<i32> {
    submit_expecting(ctx, req, completion, true)
}

/// [`submit`]; `answered`: false for a request no device answers (Force Listen Only
/// Mode), which completes once it is out, as a broadcast does.
pub fn submit_expecting(ctx: &mut Context, req: &Request<'_>, completion: Completion, answered: bool) -> Result<i32> {
    queue(ctx, req, completion, answered, None)
}

/// The next request of a call that takes several (device identification objects
/// that "more follow"), under the id of the request `id` that just completed, ahead
/// of the queue, with that request's response timeout.
pub fn resubmit(
    ctx: &mut Context,
    id: i32,
    req: &Request<'_>,
    completion: Completion,
    timeout: Duration,
) -> Result<i32> {
    queue(ctx, req, completion, true, Some((id, timeout)))
}

fn queue(
    ctx: &mut Context,
    req: &Request<'_>,
    completion: Completion,
    answered: bool,
    continuing: Option<(i32, Duration)>,
) -> Result<i32> {
    match ctx.shut() {
        Shut::Open => {}
        // A close left requests to complete (their callbacks not run yet).
        Shut::Closing => return Err(Error(libc::ESHUTDOWN)),
        // A callback run by `modbus_free`.
        Shut::Freed => return Err(Error(libc::EIDRM)),
    }
    if ctx.session.slave < 0 && req.own_unit().is_none() {
        ctx.diag().err(format_args!("ERROR The slave is not set (call modbus_set_slave)\n"));
        return Err(Error::INVALID);
    }
    if state(ctx)?.pending() >= MAX_PENDING {
        return Err(Error(libc::EAGAIN));
    }
    let mut buf = AduBuf::new();
    let n = engine::build_request(ctx, req, &mut buf);
    let framing = ctx.framing();
    let len = framing.seal(&mut buf, n);
    let mut chars = [0u8; ascii::MAX_ENCODED];
    let wire: &[u8] = if framing == Framing::Ascii {
        let k = ascii::encode(&buf[..len], &mut chars);
        &chars[..k]
    } else {
        &[]
    };
    let unit = req.own_unit().map_or(ctx.session.slave, i32::from);
    let broadcast = (framing != Framing::Tcp && unit == 0) || !answered;
    let tid = ctx.client.tid();
    // The slave is in the ADU already; the response timeout too is the context's
    // now, whatever it is when the request goes out (`modbus_set_request_timeout`
    // changes it).
    let timeout = ctx.session.timeouts.response.duration();
    let o = state(ctx)?;
    let id = match continuing {
        Some((id, timeout)) => o.pipeline.resubmit(id, &buf[..len], wire, tid, timeout, completion),
        None => o.pipeline.submit(&buf[..len], wire, tid, broadcast, timeout, completion),
    };
    mark(o);
    id.ok_or(Error(libc::EAGAIN))
}

/// A context of a multi handle is to be asked again what it waits for; a waiter on
/// the context's own descriptor that may not know of the change is woken.
fn mark(o: &Outstanding) {
    if let Some((members, key)) = &o.multi {
        members.mark(*key);
    }
    if let Some(w) = &o.wake {
        w.set.notify();
    }
}

/// `modbus_set_request_timeout`: request `id`'s response timeout, counted from its
/// send. EINVAL for a request not pending, or a timeout libmodbus's
/// `modbus_set_response_timeout` refuses (usec of a second or more, or zero).
pub fn set_request_timeout(ctx: &mut Context, id: i32, sec: u32, usec: u32) -> Result<()> {
    if usec >= 1_000_000 || (sec == 0 && usec == 0) {
        return Err(Error::INVALID);
    }
    let o = ctx.async_state()?.ok_or(Error::INVALID)?;
    let timeout = Duration::from_secs(u64::from(sec)) + Duration::from_micros(u64::from(usec));
    if !o.pipeline.set_timeout(id, timeout) {
        return Err(Error::INVALID);
    }
    mark(o);
    Ok(())
}

/// `modbus_cancel`: completes request `id` with ECANCELED.
pub fn cancel(ctx: &mut Context, id: i32) -> Result<()> {
    let (o, client) = ctx.async_with_client()?.ok_or(Error::INVALID)?;
    mark(o);
    let e = o.pipeline.cancel(id, client.late()).ok_or(Error::INVALID)?;
    if o.pipeline.in_flight() == 0 {
        // Nothing to receive for any more (a late answer is dropped by its id).
        o.receiving = None;
    }
    o.complete(Done {
        id: e.id,
        timeout: e.timeout,
        completion: e.payload,
        result: Err(libc::ECANCELED),
        data: Vec::new(),
    });
    Ok(())
}

/// `modbus_close`: the line closes; what is pending stays, to complete with
/// ESHUTDOWN on the loop's thread ([`complete_close`]). A signal handler may be
/// running this (with the lock free, or through `finish_handler_close`): nothing
/// here calls back, allocates or takes a lock but the context's.
pub fn close(ctx: &mut Context) {
    shut_pending(ctx);
    session::close_line(ctx);
}

/// A close with requests pending: they are to complete with ESHUTDOWN, and
/// submissions wait for that (see [`Shut::Closing`]). A multi handle learns it
/// without a lock (`Members::closed`); a thread waiting on either wake descriptor
/// wakes.
pub fn shut_pending(ctx: &mut Context) {
    if ctx.pending() == 0 || ctx.shut() != Shut::Open {
        return;
    }
    ctx.set_shut(Shut::Closing);
    let Some(o) = ctx.async_view() else { return };
    // A thread asleep on the wake descriptor (the context's, or its multi handle's)
    // is woken to complete them: one `write` each, safe in a signal handler.
    if let Some((members, _)) = o.multi.as_ref() {
        members.closed();
        members.set.wake();
    }
    if let Some(w) = o.wake.as_ref() {
        w.set.wake();
    }
}

/// What a close left pending completes now with ESHUTDOWN (their callbacks run when
/// the C layer next fires the completed ones): on the loop's thread, from
/// `modbus_process` and `modbus_free`. Also what a free left while `modbus_process`
/// had the requests (it freed from that call's RTS hook, or while the hook ran):
/// EIDRM, and the context leaves its multi handle.
pub fn complete_close(ctx: &mut Context) {
    let shut = ctx.shut();
    if shut == Shut::Open {
        return;
    }
    if let Ok(Some(o)) = ctx.async_state() {
        if shut == Shut::Freed {
            if let Some((members, key)) = o.multi.take() {
                members.remove(key);
            }
            o.fail_all(libc::EIDRM);
        } else {
            o.fail_all(libc::ESHUTDOWN);
        }
    }
}

/// The callbacks of a close's requests have run: submissions are taken again.
pub fn closed(ctx: &mut Context) {
    if ctx.shut() == Shut::Closing && ctx.pending() == 0 {
        ctx.set_shut(Shut::Open);
    }
}

/// A handler's `modbus_free` closed the context under the interrupted call: what it
/// marked completes with EIDRM (a free), not ESHUTDOWN.
pub fn closed_by_free(ctx: &mut Context) {
    if ctx.shut() == Shut::Closing {
        ctx.set_shut(Shut::Open);
    }
}

/// `modbus_free`: what a close left completes with ESHUTDOWN, everything else with
/// EIDRM; from now on a submission (from those callbacks) fails with EIDRM.
pub fn free(ctx: &mut Context) {
    complete_close(ctx);
    ctx.set_shut(Shut::Freed);
    if let Ok(Some(o)) = ctx.async_state() {
        o.fail_all(libc::EIDRM);
    }
}

/// The next completed request, for the C layer to deliver and call back.
pub fn take_done(ctx: &mut Context) -> Option<Done> {
    ctx.async_state().ok()??.done.pop_front()
}

/// What to wait for (see [`Interest`]).
pub fn interest(ctx: &Context) -> Interest {
    let fd = ctx.fd();
    let Some(o) = ctx.async_view() else { return Interest { fd, events: 0, until: None, now: Duration::ZERO } };
    if ctx.shut() == Shut::Closing {
        // A close left requests to complete: at once.
        let now = transport::now();
        return Interest { fd, events: 0, until: Some(now), now };
    }
    if o.pending() == 0 {
        return Interest { fd, events: 0, until: None, now: Duration::ZERO };
    }
    let now = transport::now();
    if ctx.line.connecting() {
        return Interest { fd, events: libc::POLLOUT, until: o.connect_until, now };
    }
    if ctx.line.handshaking() {
        return Interest { fd, events: o.handshake_wants, until: o.connect_until, now };
    }
    // Bytes already read (a TLS session's plaintext, the read-ahead of the last
    // answer) that an expected answer may be made of.
    let expecting = o.receiving.is_some() || o.pipeline.awaits_answer();
    let here = expecting && (ctx.line.pending() > 0 || (o.receiving.is_none() && !ctx.rx.available().is_empty()));
    if fd < 0 || !o.done.is_empty() || here {
        // To connect, to report, or bytes already here: at once.
        return Interest { fd, events: 0, until: Some(now), now };
    }
    let mut events = 0;
    if !o.pipeline.output().is_empty() {
        events |= libc::POLLOUT;
    }
    let mut until = o.pipeline.deadline();
    if o.receiving.is_some() || o.pipeline.awaits_answer() {
        events |= libc::POLLIN;
        if let Some(r) = &o.receiving {
            if let Step::Wait { until: Some(t) } = r.step {
                until = Some(until.map_or(t, |u| u.min(t)));
            }
        }
    }
    if let Some(quiet) = o.quiet_until {
        // After a serial timeout: the next request waits for the quiet time's end.
        until = Some(until.map_or(quiet, |u| u.min(quiet)));
    } else if o.pipeline.in_flight() < o.pipeline.max_in_flight() && o.pipeline.pending() > o.pipeline.in_flight() {
        // Room on the wire for a queued request: go now.
        until = Some(now);
    }
    Interest { fd, events, until, now }
}

/// `modbus_get_pollfd`: the context's wake descriptor (made by the first call),
/// brought up to date with what the context waits for ([`interest`]): the line's
/// events registered in it, its timerfd armed for the deadline, and a request given
/// from now on (from any thread) makes it readable. Returns the descriptor and when
/// [`process`] is due without an event (`None`: no deadline).
pub fn wake_interest(ctx: &mut Context) -> Result<(i32, Option<Duration>)> {
    let i = interest(ctx);
    let generation = ctx.line.generation();
    if ctx.async_view().is_none() {
        // (Lent to a modbus_process under way, from its RTS hook: EBUSY.)
        state(ctx)?;
    }
    let o = ctx.async_state()?.ok_or(Error::INVALID)?;
    let w = match &mut o.wake {
        Some(w) => w,
        None => o.wake.insert(Box::new(Wake { set: WakeSet::new()?, line: Registered::default() })),
    };
    w.line.update(w.set.epfd, i.fd, generation, i.events, epoll::KEY_LINE)?;
    if let Some(t) = i.until {
        w.set.arm_by(t, i.now);
    }
    w.set.watch();
    Ok((w.set.epfd, i.until))
}

/// After `modbus_process` (its callbacks included): a request given from now on
/// wakes a waiter on the context's descriptor, should the application wait without
/// asking [`wake_interest`] first.
pub fn watch(ctx: &mut Context) {
    if let Ok(Some(Outstanding { wake: Some(w), .. })) = ctx.async_state() {
        w.set.watch();
    }
}

/// What the context's wake descriptor has ready, without waiting: the line's poll(2)
/// events (the eventfd and the timerfd are drained). A line that reports while it
/// waits for nothing leaves the set.
fn learn(w: &mut Wake) -> i16 {
    let mut events = [libc::epoll_event { events: 0, u64: 0 }; 4];
    let Ok((n, _)) = w.set.take(0, &mut events) else { return 0 };
    let mut line = 0;
    for ev in &events[..n] {
        if { ev.u64 } == epoll::KEY_LINE {
            line |= { ev.events } as u16 as i16;
        }
    }
    if line != 0 && w.line.idle_report(w.set.epfd) {
        return 0;
    }
    line
}

/// A readable wake descriptor can only be the line's input: the eventfd was not
/// written, the timerfd has not expired, and the line (`(fd, generation)`, the
/// context's) is registered, and waited on, for POLLIN alone.
fn only_line_readable(w: &Wake, line: (i32, u32)) -> bool {
    let r = &w.line;
    r.events == libc::POLLIN
        && r.wants == libc::POLLIN
        && (r.fd, r.generation) == line
        && !w.set.may_have_woken(transport::now)
}

/// `modbus_process`: the I/O that is ready, and what the clock says is due.
/// `revents` is the line's poll(2) events when the caller knows them (the multi
/// handle). From the application (`app`), it is only a hint: a context with its
/// wake descriptor asks the descriptor what is ready when `revents` says something
/// is (0, a wait that timed out, saves the asking: what became ready since stays
/// readable for the next wait). Returns the number of requests completed (their
/// results wait in the context for the C layer: [`take_done`]).
pub fn process(g: &mut Guard<'_>, revents: i16, app: bool) -> Result<usize> {
    // (From the RTS hook of a modbus_process: EBUSY.)
    g.async_state()?;
    complete_close(g);
    let Some(mut o) = g.lend_async() else { return Ok(0) };
    let line = (g.fd(), g.line.generation());
    let revents = match o.wake.as_deref_mut() {
        Some(w) => {
            // This call looks at every request: none given from now on needs to
            // wake anyone until the next watch.
            w.set.unwatch();
            match (revents, app) {
                (0, _) => 0,
                // The set is readable, not for its eventfd or timerfd: for the line,
                // registered for POLLIN alone (the pipelined path: no system call).
                (_, true) if only_line_readable(w, line) => libc::POLLIN,
                (_, true) => learn(w),
                (r, false) => r | learn(w),
            }
        }
        None => revents,
    };
    let before = o.done.len();
    let mut readable = revents & (libc::POLLIN | libc::POLLERR | libc::POLLHUP) != 0;
    let writable = revents & (libc::POLLOUT | libc::POLLERR | libc::POLLHUP) != 0;
    run(g, &mut o, &mut readable, writable);
    let completed = o.done.len() - before;
    mark(&o);
    g.give_back_async(o);
    // A close from the RTS hook it ran (or a signal handler meanwhile).
    complete_close(g);
    Ok(completed)
}

fn run(g: &mut Guard<'_>, o: &mut Outstanding, readable: &mut bool, writable: bool) {
    for _ in 0..4 * MAX_PENDING {
        if g.shut() != Shut::Open || g.stopping() {
            // Closed from the RTS hook (or a signal handler) meanwhile, or being
            // closed (or freed) by another thread: nothing more goes out; what is
            // pending completes with ESHUTDOWN (EIDRM) when that close is done.
            return;
        }
        let now = transport::now();
        let mut progress = false;
        for (e, end) in o.pipeline.due(now, g.client.late()) {
            progress = true;
            let result = match end {
                End::Sent => Ok(0),
                _ => Err(libc::ETIMEDOUT),
            };
            if matches!(end, End::Sent) {
                // A broadcast: rc as a write's.
                complete_broadcast(o, e);
            } else {
                session::error_print(g, Error::TIMED_OUT, Some("select"));
                let timeout = e.timeout;
                push(o, e, result, Vec::new());
                // A serial line has no transaction id: the recovery after a wait
                // that timed out (LINK: sleep and flush) keeps the line quiet for a
                // response timeout (the request's), then flushes it.
                let serial = g.framing() != Framing::Tcp;
                if serial
                    && crate::proto::session::after_wait(g.session.recovery, Error::TIMED_OUT) == Recovery::SleepFlush
                {
                    o.quiet_until = Some(now + timeout);
                }
            }
        }
        if o.pipeline.in_flight() == 0 {
            o.receiving = None;
        }
        if o.pipeline.is_empty() {
            return;
        }
        if g.fd() < 0 {
            // The first request of a context not connected yet, or the next after
            // the line was lost: the connect starts, and goes on while the
            // application waits for the socket to be writable.
            o.receiving = None;
            match session::connect_started(g) {
                Ok(true) => progress = true,
                Ok(false) => {
                    o.connect_until = Some(now + g.session.timeouts.response.duration());
                    return;
                }
                Err(e) => {
                    session::error_print(g, e, Some("connect"));
                    o.fail_all(e.errno());
                    return;
                }
            }
        }
        if g.line.connecting() {
            let timed_out = o.connect_until.is_some_and(|u| now >= u);
            if !writable && !timed_out {
                return;
            }
            o.connect_until = None;
            if let Err(e) = session::connect_done(g, timed_out) {
                session::error_print(g, e, Some("connect"));
                o.fail_all(e.errno());
                return;
            }
            progress = true;
        }
        if g.line.handshaking() {
            // Modbus/TCP Security: the handshake, as far as it goes without waiting.
            let until = *o.connect_until.get_or_insert(now + g.session.timeouts.response.duration());
            match session::handshake_step(g, now >= until) {
                Ok(Some(events)) => {
                    o.handshake_wants = events;
                    return;
                }
                Ok(None) => {
                    o.connect_until = None;
                    progress = true;
                }
                Err(e) => {
                    o.fail_all(e.errno());
                    return;
                }
            }
        }
        if write(g, o, now) {
            progress = true;
        }
        if g.fd() < 0 {
            continue;
        }
        if o.receiving.is_some() || o.pipeline.awaits_answer() {
            if let Some(f) = receive(g, o, readable) {
                progress = true;
                let r = o.receiving.take().expect("the receive that ended");
                finish(g, o, f, &r.msg[..]);
            }
        }
        if !progress {
            return;
        }
    }
}

/// Moves requests to the wire and writes what is waiting; true when bytes went out.
fn write(g: &mut Guard<'_>, o: &mut Outstanding, now: Duration) -> bool {
    if let Some(quiet) = o.quiet_until {
        if now < quiet {
            return false;
        }
        o.quiet_until = None;
        g.rx.clear();
        g.line.purge();
    }
    let moved = o.pipeline.fill(now, g.client.late());
    let out = o.pipeline.output();
    if out.is_empty() {
        return false;
    }
    if g.debug {
        session::trace_sent(out);
    }
    let timeout = g.session.timeouts.response;
    let written = match g.line.write_at_once(out, timeout) {
        Some(r) => r,
        // A serial line with RTS direction control (modbus_rtu_set_rts, or the
        // application's hook): the same sequence as a blocking call's, the frame's
        // time on the line included.
        None if g.line.rts_around_writes() => {
            let written = engine::write_with_rts(g, out);
            // The answer's timeout starts when the frame has left (as a blocking
            // call's): the sequence took the frame's time on the line.
            o.pipeline.restart_clocks(moved, transport::now());
            written
        }
        None => {
            let timeout = g.session.timeouts.response;
            g.line.write(out, timeout)
        }
    };
    match written {
        Ok(n) => {
            o.pipeline.wrote(n);
            n > 0
        }
        Err(e) if e.0 == libc::EAGAIN || e.0 == libc::EINTR => false,
        Err(e) => {
            session::error_print(g, e, None);
            lost(g, o, e);
            true
        }
    }
}

/// The line failed: everything pending completes with its error, and the line is
/// closed (the next request opens it again).
fn lost(g: &mut Guard<'_>, o: &mut Outstanding, e: Error) {
    if g.stopping() {
        // The failure is a close's (a signal handler's, another thread's): that
        // close ends what is pending (ESHUTDOWN, or EIDRM for a free), not this error.
        return;
    }
    o.fail_all(e.errno());
    session::close_line(g);
}

/// Drives the receive under way (or a new one) until it ends (`Some`) or must wait.
fn receive(g: &mut Guard<'_>, o: &mut Outstanding, readable: &mut bool) -> Option<Finished> {
    if o.receiving.is_none() {
        if !*readable && g.line.pending() == 0 && g.rx.available().is_empty() {
            // Nothing of the answer yet: the receive starts when it comes (its
            // deadline is the pipeline's meanwhile).
            return None;
        }
        let now = transport::now();
        let deadline = o.pipeline.answer_deadline().unwrap_or(now);
        let first = o.pipeline.first_awaiting().map(|e| e.adu());
        // A diagnostics answer on a serial framing is as long as its request.
        let framing = g.framing();
        let expecting = first.and_then(|adu| answer_length(framing, &adu[..adu.len() - framing.checksum_length()]));
        let mut s = session::settings(g, MsgKind::Confirmation, Driver::Ready, expecting);
        // A serial answer must come from the unit asked: a raw request names its own.
        if s.framing != Framing::Tcp {
            if let Some(unit) = first.and_then(|adu| adu.first()) {
                s.slave = i32::from(*unit);
            }
        }
        let left = deadline.saturating_sub(now).max(Duration::from_micros(1));
        s.timeouts.response = Timeout::new(left.as_secs() as u32, left.subsec_micros().max(1));
        let machine = Receiver::new(&s, || now);
        let mut r = Box::new(Receiving { machine, settings: s, step: Step::Wait { until: None }, msg: AduBuf::new() });
        let started = &mut *r;
        started.step = started.machine.start(&s, &mut started.msg[..], &mut g.rx, || now);
        o.receiving = Some(r);
    }
    let r = o.receiving.as_mut().expect("made above");
    session::drive_ready(g, r, readable)
}

/// Completes `e` with `result` and the answer's data.
fn push(o: &mut Outstanding, e: Entry<Completion>, result: std::result::Result<i32, i32>, data: Vec<u8>) {
    o.complete(Done { id: e.id, timeout: e.timeout, completion: e.payload, result, data });
}

/// A broadcast is out: it completes as its write would (the count it wrote).
fn complete_broadcast(o: &mut Outstanding, e: Entry<Completion>) {
    let rc = broadcast_count(e.adu());
    push(o, e, Ok(rc), Vec::new());
}

/// What a write returns for a request that gets no answer: the count it writes (1
/// for a single coil or register, the quantity of a multiple write; 0 for
/// Diagnostics, as `modbus_diagnostics` returns for Force Listen Only Mode).
fn broadcast_count(adu: &[u8]) -> i32 {
    use crate::proto::fc;
    let pdu = &adu[1..];
    match pdu[0] {
        fc::DIAGNOSTICS => 0,
        fc::WRITE_MULTIPLE_COILS | fc::WRITE_MULTIPLE_REGISTERS if pdu.len() >= 5 => {
            i32::from(u16::from_be_bytes([pdu[3], pdu[4]]))
        }
        _ => 1,
    }
}

/// The values an answer brings for `deliver`, and what the call returns.
fn values(framing: Framing, deliver: Deliver, rsp: &[u8], count: i32) -> (i32, Vec<u8>) {
    let h = framing.header_length();
    match deliver {
        Deliver::Bits { nb, .. } => (nb, counted_data(&rsp[h..], count as usize).to_vec()),
        Deliver::Registers { .. } if count > 0 => (count, counted_data(&rsp[h..], 2 * count as usize).to_vec()),
        Deliver::Registers { .. } | Deliver::Count => (count, Vec::new()),
        Deliver::Bytes { max, .. } => {
            let n = (count.max(0) as usize).min(max.max(0) as usize);
            (count, counted_data(&rsp[h..], n).to_vec())
        }
        // The whole answer, as it came.
        Deliver::Raw { .. } => (rsp.len() as i32, rsp.to_vec()),
        // Its PDU (without the checksum).
        Deliver::Pdu => {
            let pdu = &rsp[h..rsp.len() - framing.checksum_length()];
            (pdu.len() as i32, pdu.to_vec())
        }
        // The decoder reads the PDU (without the checksum).
        Deliver::Decode { .. } | Deliver::Stream { .. } => {
            (count, rsp[h..rsp.len() - framing.checksum_length()].to_vec())
        }
    }
}

/// The recovery a failed receive or a mismatched answer asks for, without sleeping
/// (see `session::recover`): a reconnect completes everything with `e`.
fn recover(g: &mut Guard<'_>, o: &mut Outstanding, recovery: Recovery, e: Error) {
    if session::recover(g, recovery, Driver::Ready) == Recovered::Lost {
        lost(g, o, e);
    }
}

/// Checks a frame against the request it answers and completes that request.
fn answered(g: &mut Guard<'_>, o: &mut Outstanding, rsp: &[u8]) {
    let framing = g.framing();
    let tid = (framing == Framing::Tcp && rsp.len() >= 2).then(|| u16::from_be_bytes([rsp[0], rsp[1]]));
    let e = match o.pipeline.answer(tid, g.client.late()) {
        Answer::Of(e) => e,
        Answer::Stale | Answer::Unexpected => {
            if g.debug {
                let what = match tid {
                    Some(t) => format!("Answer with transaction ID 0x{t:X} dropped (no request waits for it)\n"),
                    None => "Answer dropped (no request waits for it)\n".to_string(),
                };
                g.diag().err(format_args!("{what}"));
            }
            return;
        }
    };
    if let Deliver::Raw { .. } | Deliver::Pdu = e.payload.deliver {
        return answered_raw(g, o, e, rsp);
    }
    let mut diag = g.diag();
    match confirm::check(framing, e.adu(), rsp, &mut diag) {
        Ok(count) => {
            let (rc, data) = values(framing, e.payload.deliver, rsp, count);
            push(o, e, Ok(rc), data);
        }
        Err(Rejection::Exception(err)) => {
            session::error_print(g, err, None);
            push(o, e, Err(err.errno()), Vec::new());
        }
        Err(Rejection::Mismatch(err)) | Err(Rejection::Foreign(err)) => {
            push(o, e, Err(err.errno()), Vec::new());
            let recovery = crate::proto::session::after_mismatch(g.session.recovery);
            recover(g, o, recovery, err);
        }
    }
}

/// The answer to a raw request: handed over as it came, exception answers included,
/// when it is from the unit asked (a serial line) and of the function asked.
fn answered_raw(g: &mut Guard<'_>, o: &mut Outstanding, e: Entry<Completion>, rsp: &[u8]) {
    let framing = g.framing();
    let h = framing.header_length();
    let req = e.adu();
    let same_unit = framing == Framing::Tcp || req[0] == 0 || rsp[0] == req[0];
    let same_function = rsp.get(h).is_some_and(|f| f & 0x7F == req[h]);
    if same_unit && same_function {
        let (rc, data) = values(framing, e.payload.deliver, rsp, 0);
        push(o, e, Ok(rc), data);
        return;
    }
    let err = if same_unit { Error::BAD_DATA } else { Error::BAD_SLAVE };
    session::error_print(g, err, None);
    push(o, e, Err(err.errno()), Vec::new());
    let recovery = crate::proto::session::after_mismatch(g.session.recovery);
    recover(g, o, recovery, err);
}

/// A receive that ended: read by the one reader (`session::conclude`), then acted
/// on.
fn finish(g: &mut Guard<'_>, o: &mut Outstanding, f: Finished, msg: &[u8]) {
    if let Outcome::Failed { error: Error::TIMED_OUT, .. } = f.outcome {
        if f.traced == 0 {
            // Nothing of an answer by the first request's deadline: `due` completes it.
            return;
        }
    }
    match session::conclude(g, msg, &f, Driver::Ready) {
        Ok(Received::Frame(len)) => answered(g, o, &msg[..len]),
        // A serial frame for another slave: not ours; keep listening.
        Ok(Received::Ignored(_)) => {}
        Err(error) if error.line_lost() => lost(g, o, error),
        Err(error) => {
            // The oldest request in flight is the one this answer was for.
            let oldest = o.pipeline.ids().next();
            if let Some(id) = oldest {
                if let Some(e) = o.pipeline.cancel(id, g.client.late()) {
                    push(o, e, Err(error.errno()), Vec::new());
                }
            }
            recover(g, o, f.recovery, error);
        }
    }
}
