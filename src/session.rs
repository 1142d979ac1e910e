//! The sessions on a context, for every driver: the one place that builds a
//! receive's settings ([`settings`]), reads how a receive ended ([`conclude`]: its
//! trace, its messages, its result) and carries out a recovery ([`recover`]), and
//! the line's own actions those need (connect, close, flush, the recovery sleep).
//! The rules are the protocol crate's (`proto::session`: the receive machine, the
//! recoveries, the client and server sessions); the drivers (the blocking calls in
//! `engine`, the event-driven client in `event`, the server runner in `runner`)
//! carry out the steps and differ only in how they wait ([`Driver`]).

use std::time::Duration;

use crate::context::{Context, RECOVERY_PROTOCOL};
use crate::error::{Error, Result};
use crate::outstanding::Receiving;
use crate::proto::Diag;
use crate::proto::frame::{Framing, MsgKind};
use crate::proto::session::Recovery;
use crate::proto::session::receive::{Dest, Finished, Outcome, ReadAhead, ReadHow, Settings, Step};
use crate::proto::session::server::{Taken, bus_event};
use crate::transport::Room;
use crate::transport::line::Line;
use crate::transport::{self, Ready};

/// How a driver waits, as far as a receive and a recovery go.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Driver {
    /// The blocking calls: waits in `ppoll` (a receive's), sleeps (a recovery's).
    Blocking,
    /// The event-driven client: never waits; the application's poll says when the
    /// line is ready, and a recovery's sleep becomes a time before which nothing is
    /// sent (see `event`).
    Ready,
    /// The server runner: never waits; a client's requests are read several at a
    /// time, and nothing sleeps on behalf of one client (or peer) while others wait.
    Runner,
}

/// The settings of a receive of `kind` on `ctx` under `driver`: the context's
/// (framing, slave, timeouts, recovery, whether the server answers the codes beyond
/// libmodbus, the ASCII delimiter its diagnostics may have changed), what the line
/// can do now, and what the driver allows. `expecting`: the length of header + PDU
/// the message must have when nothing in it tells (a serial diagnostics answer).
/// The one builder of a receive's settings.
#[inline]
pub fn settings(ctx: &Context, kind: MsgKind, driver: Driver, expecting: Option<usize>) -> Settings {
    let mut s = ctx.session;
    let ext = ctx.server_ext.as_deref();
    complete(&mut s, &ctx.line, ext, ctx.server.kind(), kind, driver, expecting);
    s
}

/// [`settings`] for the blocking driver, completed in place in the context's own
/// (`Context::session`), which its receive reads.
#[inline]
pub fn prepare(ctx: &mut Context, kind: MsgKind, expecting: Option<usize>) {
    let ext = ctx.server_ext.as_deref();
    complete(&mut ctx.session, &ctx.line, ext, ctx.server.kind(), kind, Driver::Blocking, expecting);
}

/// What [`settings`] adds to the context's settings `s`.
#[inline(always)]
fn complete(
    s: &mut Settings,
    line: &Line,
    ext: Option<&crate::server_ext::ServerExt>,
    server_kind: MsgKind,
    kind: MsgKind,
    driver: Driver,
    expecting: Option<usize>,
) {
    s.kind = kind;
    s.line = line.caps(kind, s.timeouts.response);
    s.expecting = expecting;
    if s.framing == Framing::Ascii {
        s.ascii_delimiter = ext.and_then(|e| e.diagnostics()).map_or(b'\n', |d| d.ascii_delimiter());
    }
    match driver {
        Driver::Blocking => {
            // A client that owns its line reads ahead; a server reading the other
            // slave's answer to skip never reads past it.
            s.read_ahead = kind == MsgKind::Confirmation && server_kind == MsgKind::Indication;
        }
        Driver::Ready => {
            // Readiness decides: never a read under a kernel timeout.
            s.line.timed_reads = false;
            s.read_ahead = true;
        }
        Driver::Runner => {
            // Never a peek, never a read under a kernel timeout: read what is there,
            // and on a stream keep what lies past a request for the next (several
            // requests in one read); a datagram is read whole; a serial line is never
            // read past its frame, as libmodbus reads it.
            s.line.socket = false;
            s.line.timed_reads = false;
            s.read_ahead = !line.shared_bus();
            // Unknown function codes are framed whole (MBAP length, ASCII frame,
            // CRC), for the answerer's `other`.
            s.extended = true;
            // The first wait has no end: the idle timeout governs a quiet client.
            s.timeouts.indication = crate::proto::session::Timeout::new(0, 0);
        }
    }
}

/// How a Wait step of the receive machine is carried out.
pub enum Waiting<'a> {
    /// In `ppoll`, until the line is readable or the deadline passes (the blocking
    /// calls).
    Block,
    /// Not at all (the event-driven client): the line is readable when the
    /// application's poll said so (`true`, taken once) or bytes are already read
    /// (a TLS session's plaintext); at the deadline the wait has timed out; else the
    /// step waits for the application's loop. Reads never wait either.
    Ready(&'a mut bool),
}

/// Executes one step of the receive machine (`Peek`, `Read` or `Wait`) on `line`:
/// the one executor of the machine's steps, for every driver (`engine::receive_msg`,
/// and [`drive_ready`] for the others). `msg` is the message's buffer, `rx` the read-ahead. Returns the
/// step's result for the machine, or `None` when, under [`Waiting::Ready`], the step
/// must wait for the application's loop.
#[inline(always)]
pub fn execute(
    line: &mut Line,
    rx: &mut ReadAhead,
    msg: &mut Room<'_>,
    step: Step,
    debug: bool,
    waiting: &mut Waiting<'_>,
) -> Option<Result<usize>> {
    let blocking = matches!(waiting, Waiting::Block);
    Some(match step {
        Step::Peek { block } => line.peek(&mut rx.buf, block && blocking),
        Step::Read { dest, how } => {
            let how = if blocking { how } else { ReadHow::Queued };
            match dest {
                Dest::Message { from, to } => line.read_message(msg, from..to, how, debug),
                Dest::ReadAhead => line.read(&mut rx.buf[..], how, debug),
            }
        }
        Step::Wait { until } => match waiting {
            Waiting::Block => line.wait(until, debug).map(|()| 0),
            Waiting::Ready(readable) => {
                if **readable || line.pending() > 0 {
                    **readable = false;
                    Ok(0)
                } else if until.is_some_and(|u| transport::now() >= u) {
                    Err(Error::TIMED_OUT)
                } else {
                    return None;
                }
            }
        },
        Step::Frame(_) | Step::Done(_) => unreachable!("the end of a receive is no step to execute"),
    })
}

/// Drives the receive `r` on `ctx`'s line by readiness (the event-driven client's,
/// the runner's): its steps are carried out until it ends (`Some`) or must wait for
/// the application's loop (`None`: `r.step` says for what).
#[inline(always)]
pub fn drive_ready(ctx: &mut Context, r: &mut Receiving, readable: &mut bool) -> Option<Finished> {
    let mut waiting = Waiting::Ready(readable);
    loop {
        match r.step {
            Step::Frame(len) => return Some(Finished::frame(len)),
            Step::Done(f) => return Some(f),
            step => {
                let result = execute(&mut ctx.line, &mut ctx.rx, &mut r.msg.room(), step, ctx.debug, &mut waiting)?;
                r.step = r.machine.next(&r.settings, result, &mut r.msg[..], &mut ctx.rx, transport::now);
            }
        }
    }
}

pub use crate::proto::session::receive::Received;

/// The end of a receive, read once for every driver: the debug trace of the
/// message (libmodbus prints its bytes as they arrive; printed at the end, the text
/// is the same with fewer writes), the messages of a bad or foreign frame or a
/// failure, and its result. The recovery `f` names is the caller's to carry out
/// ([`recover`]).
#[inline]
pub fn conclude(ctx: &Context, msg: &[u8], f: &Finished, driver: Driver) -> Result<Received> {
    match f.outcome {
        Outcome::Frame(len) if !ctx.debug => Ok(Received::Frame(len)),
        _ => conclude_reporting(ctx, msg, f, driver),
    }
}

#[inline(never)]
fn conclude_reporting(ctx: &Context, msg: &[u8], f: &Finished, driver: Driver) -> Result<Received> {
    if ctx.debug {
        trace_received(&msg[..f.traced], f.ended);
    }
    let mut diag = ctx.diag();
    match f.outcome {
        Outcome::Frame(len) => Ok(Received::Frame(len)),
        Outcome::Ignored { len, theirs, ours } => {
            diag.out(format_args!("Request for slave {theirs} ignored (not {ours})\n"));
            Ok(Received::Ignored(len))
        }
        Outcome::BadChecksum { lrc, received, computed } => {
            let what = if lrc { "LRC" } else { "CRC" };
            diag.err(format_args!("ERROR {what} received 0x{received:0X} != {what} calculated 0x{computed:0X}\n"));
            Err(Error::BAD_CRC)
        }
        Outcome::Failed { error, site } => {
            // (A runner's client that leaves is no error worth a line.)
            let left = driver == Driver::Runner && ctx.line.is_stream() && error == Error::CONN_RESET;
            if site.is_some() && !left {
                error_print(ctx, error, site);
            }
            Err(error)
        }
    }
}

/// A server's reading of a receive that ended with `r` (after [`conclude`]): the
/// diagnostics bus counters count it, and the server session says what it is (a
/// request, the other slave's answer skipped, a unit not served). `accept`: whether
/// a serial request for a unit is served (see `ServerSession::ended`).
pub fn taken(ctx: &mut Context, msg: &[u8], r: &Result<Received>, accept: impl FnOnce(u8) -> bool) -> Taken {
    let framing = ctx.framing();
    if let Some(ext) = ctx.server_ext.as_deref_mut() {
        if let Some(event) = bus_event(framing, r) {
            ext.bus_event(event);
        }
    }
    let shared_bus = ctx.line.shared_bus();
    let serial = framing != Framing::Tcp;
    let taken = ctx.server.ended(r, msg, shared_bus, |unit| !serial || accept(unit));
    let mut diag = ctx.diag();
    match taken {
        Taken::Skipped => diag.out(format_args!("Confirmation to ignore\n")),
        Taken::NotServed(unit) => diag.out(format_args!("Request for slave {unit} ignored (not served)\n")),
        _ => {}
    }
    taken
}

/// What a recovery left to the driver.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Recovered {
    /// Done (or nothing to do).
    Done,
    /// The context is being closed under the call: the sleep ended early.
    Stopped,
    /// The line must be closed and opened again, which a driver that never waits
    /// does its own way (the event-driven client completes what was in flight; the
    /// runner closes the client).
    Lost,
}

/// Carries out `recovery` (see `proto::session`) on `ctx` under `driver`, unless the
/// context is being closed under the call: the one recovery of every driver. A
/// blocking driver sleeps the response timeout where the rules say so; the others
/// never sleep (they flush at once, and leave a reconnect to their driver).
pub fn recover(ctx: &mut Context, recovery: Recovery, driver: Driver) -> Recovered {
    if recovery == Recovery::None {
        return Recovered::Done;
    }
    if ctx.stopping() {
        return Recovered::Stopped;
    }
    match (recovery, driver) {
        (Recovery::None, _) => Recovered::Done,
        // A bad checksum: the line's own flush, without `modbus_flush`'s trace.
        (Recovery::Flush, _) | (Recovery::SleepFlush, Driver::Ready | Driver::Runner) => {
            drop_pending(ctx);
            Recovered::Done
        }
        // The sleep ends early when the context is being closed: then no flush.
        (Recovery::SleepFlush, Driver::Blocking) => match sleep_response_timeout(ctx) {
            Ok(()) => {
                let _ = flush(ctx);
                Recovered::Done
            }
            Err(_) => Recovered::Stopped,
        },
        (Recovery::Reconnect | Recovery::ReconnectAfterSleep, Driver::Blocking) => {
            close_line(ctx);
            if recovery == Recovery::ReconnectAfterSleep && sleep_response_timeout(ctx).is_err() {
                return Recovered::Stopped;
            }
            let _ = connect(ctx);
            Recovered::Done
        }
        (Recovery::Reconnect | Recovery::ReconnectAfterSleep, _) => Recovered::Lost,
    }
}

/// Drops what the line holds now, without waiting: the read-ahead, a serial line's
/// queues, the rest of the datagram being read (never another sender's datagram).
pub fn drop_pending(ctx: &mut Context) {
    ctx.rx.clear();
    ctx.line.purge();
    ctx.line.discard();
}

/// libmodbus's `_error_print`: "ERROR <strerror>[: <context>]" on stderr, debug only.
pub fn error_print(ctx: &Context, error: Error, context: Option<&str>) {
    if !ctx.debug {
        return;
    }
    let text = transport::describe(error.0);
    let mut diag = ctx.diag();
    match context {
        Some(c) => diag.err(format_args!("ERROR {text}: {c}\n")),
        None => diag.err(format_args!("ERROR {text}\n")),
    }
}

/// `modbus_connect`: the line opens (and, on a Modbus/TCP Security context, runs
/// its handshake), bounded by the response timeout.
pub fn connect(ctx: &mut Context) -> Result<()> {
    ctx.rx.clear();
    let mut diag = ctx.diag();
    let timeout = ctx.session.timeouts.response.duration();
    ctx.line.open(timeout, ctx.debug, &mut diag)
}

/// The event-driven client's connect: as [`connect`], but a TCP connect is only
/// started (`Ok(false)`: under way, see `Line::connect_done`).
pub fn connect_started(ctx: &mut Context) -> Result<bool> {
    ctx.rx.clear();
    let mut diag = ctx.diag();
    let timeout = ctx.session.timeouts.response.duration();
    ctx.line.open_started(timeout, ctx.debug, &mut diag)
}

/// The end of a connect [`connect_started`] left under way (on a Modbus/TCP Security
/// context, the handshake starts: [`handshake_step`]).
pub fn connect_done(ctx: &mut Context, timed_out: bool) -> Result<()> {
    ctx.line.connect_done(timed_out)
}

/// The TLS handshake of a connect without waiting, as far as it goes (see
/// `Line::handshake_step`).
pub fn handshake_step(ctx: &mut Context, timed_out: bool) -> Result<Option<i16>> {
    let mut diag = ctx.diag();
    ctx.line.handshake_step(timed_out, ctx.debug, &mut diag)
}

/// `modbus_tcp_accept`: the client just accepted on `fd` becomes the context's (on
/// a Modbus/TCP Security context once its handshake, bounded by the response
/// timeout, is done).
pub fn accepted(ctx: &mut Context, fd: i32, peer: Option<&str>) -> Result<()> {
    let mut diag = ctx.diag();
    crate::transport::listen::report_accept(&mut diag, peer);
    let timeout = ctx.session.timeouts.response.duration();
    ctx.line.accepted(fd, timeout, ctx.debug, &mut diag)
}

/// Closes the line (a serial line gets its saved settings back first), dropping
/// what was read ahead: a recovery's close, and the end of `modbus_close` (which
/// first marks the event-driven client's requests to complete with ESHUTDOWN:
/// `event::close`).
pub fn close_line(ctx: &mut Context) {
    ctx.rx.clear();
    ctx.line.close();
}

/// `modbus_flush`: discard what is pending on the line. Returns the bytes dropped
/// (TCP) or 0 (RTU).
pub fn flush(ctx: &mut Context) -> Result<usize> {
    flush_reporting(ctx).0
}

/// [`flush`], and the error of its last failed system call, if any: the errno
/// libmodbus's `modbus_flush` leaves behind. A socket's count overflowing 16 bits
/// switches to PROTOCOL recovery (libmodbus 3.1.11+).
pub fn flush_reporting(ctx: &mut Context) -> (Result<usize>, Option<Error>) {
    let (rc, left) = ctx.line.flush(ctx.rx.available().len());
    ctx.rx.clear();
    if rc == Err(Error(libc::EOVERFLOW)) {
        ctx.session.recovery = RECOVERY_PROTOCOL;
    }
    if let Ok(n) = rc {
        ctx.diag().out(format_args!("Bytes flushed ({n})\n"));
    }
    (rc, left)
}

/// Sleeps the response timeout (error recovery); `Err(STOPPED)` as soon as the
/// context is being closed under the call.
pub fn sleep_response_timeout(ctx: &Context) -> Result<()> {
    pause(ctx, ctx.session.timeouts.response.duration())
}

/// Sleeps `d`, resuming after signals, and ends early with `Err(STOPPED)` when the
/// context is being closed under the call (the wake-up descriptor of
/// [`crate::stop`] ends the wait).
pub fn pause(ctx: &Context, d: Duration) -> Result<()> {
    let wake = ctx.stop.wake_fd();
    let mut left = transport::to_timespec(d);
    loop {
        if ctx.stopping() {
            return Err(Error::STOPPED);
        }
        match transport::wait_or_wake(-1, 0, wake, Some(&mut left)) {
            Ok(Ready::TimedOut) => return Ok(()),
            Ok(_) => ctx.stop.drain_wake(),
            // EINTR: the kernel counted `left` down; anything else cannot happen
            // with no descriptor of ours but an eventfd.
            Err(e) if e.0 == libc::EINTR => {}
            Err(_) => return Ok(()),
        }
    }
}

/// The debug trace of a frame sent: each byte as `[XX]`, then a new line.
pub fn trace_sent(bytes: &[u8]) {
    use std::fmt::Write as _;
    let mut line = String::with_capacity(bytes.len() * 4 + 1);
    for b in bytes {
        let _ = write!(line, "[{b:02X}]");
    }
    line.push('\n');
    crate::stdio::out(format_args!("{line}"));
}

/// The debug trace of a message received: each byte as `<XX>`, and a new line when
/// its framing ended (nothing when there is neither).
pub fn trace_received(bytes: &[u8], ended: bool) {
    if bytes.is_empty() && !ended {
        return;
    }
    use std::fmt::Write as _;
    let mut trace = String::with_capacity(bytes.len() * 4 + 1);
    for b in bytes {
        let _ = write!(trace, "<{b:02X}>");
    }
    if ended {
        trace.push('\n');
    }
    crate::stdio::out(format_args!("{trace}"));
}
