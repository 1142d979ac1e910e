//! The libmodbus flows that drive the sans-I/O core over a transport: sending with
//! the debug trace and LINK recovery, the receive loop with its three timeouts, and
//! the client's request/confirmation exchange.

use std::time::Duration;

use crate::context::{ClientSocket, Context, Link, RECOVERY_PROTOCOL, RTU_RTS_NONE, RTU_RTS_UP, RtuLink};
use crate::error::{Error, Result};
use crate::lock::OwnerGuard;
use crate::proto::confirm::{self, Rejection};
use crate::proto::frame::{Framing, MAX_ADU_LENGTH, MsgKind};
use crate::proto::request::{Request, next_tid};
use crate::proto::session::receive::{self, Dest, Finished, LineCaps, Outcome, ReadHow, Receiver, Step};
use crate::proto::session::{self, Recovery, Timeout};
use crate::proto::{Diag, ascii};
use crate::stop::Stop;
use crate::transport::tcp::ConnectError;
use crate::transport::{self, Ready, rtu, tcp, tls};

/// A locked context. Functions that may call back into the application (the custom
/// RTS callback) take the guard so they can release the lock around the call.
pub type Guard<'a> = OwnerGuard<'a, Context>;

/// One ADU buffer, large enough for any framing.
pub type AduBuf = [u8; MAX_ADU_LENGTH];

/// libmodbus's `_error_print`: "ERROR <strerror>[: <context>]" on stderr, debug only.
pub fn error_print(ctx: &Context, error: Error, context: Option<&str>) {
    if !ctx.debug {
        return;
    }
    let text = describe(error.0);
    let mut diag = ctx.diag();
    match context {
        Some(c) => diag.err(format_args!("ERROR {text}: {c}\n")),
        None => diag.err(format_args!("ERROR {text}\n")),
    }
}

use crate::transport::describe;

/// `modbus_connect`: the transport opens the line, the context takes its descriptor.
pub fn connect(ctx: &mut Context) -> Result<()> {
    ctx.rx.clear();
    let mut diag = ctx.diag();
    let timeout = ctx.session.timeouts.response.duration();
    let connected = match &mut ctx.link {
        Link::Rtu(link) => {
            let fd = rtu::open(link, &mut diag)?;
            let configured = rtu::configure(fd, link, &mut diag);
            if let Some(saved) = link.saved_termios {
                ctx.stop.save_line(&saved);
            }
            if let Err(e) = configured {
                transport::close(fd);
                ctx.set_descriptor(-1);
                return Err(e);
            }
            ctx.set_descriptor(fd);
            ctx.line_nonblocking = true;
            return Ok(());
        }
        Link::Tcp(link) => tcp::connect_ipv4(link, timeout, &mut diag),
        Link::TcpPi(link) => tcp::connect_pi(link, timeout, &mut diag),
    };
    match connected {
        Ok(c) => {
            ctx.set_descriptor(c.fd);
            ctx.client_socket = c.blocking.then(ClientSocket::default);
            if ctx.tls.is_some() {
                return tls_handshake(ctx, Side::Client);
            }
            Ok(())
        }
        Err(ConnectError::Before(e)) => Err(e),
        Err(ConnectError::During(e)) => {
            ctx.set_descriptor(-1);
            Err(e)
        }
    }
}

/// `modbus_close`: the context gives up its descriptor (see `Context::release_descriptor`),
/// the transport closes it (a serial line gets its saved settings back first).
pub fn close(ctx: &mut Context) {
    ctx.rx.clear();
    if ctx.s < 0 {
        return;
    }
    match ctx.link {
        Link::Rtu(_) => {
            ctx.stop.forget_line();
            let fd = ctx.release_descriptor();
            rtu::close_line(fd, ctx.rtu().and_then(|l| l.saved_termios));
        }
        Link::Tcp(_) | Link::TcpPi(_) => {
            if let Some(mut session) = ctx.tls.as_deref_mut().and_then(|t| t.remove(ctx.s)) {
                session.close(ctx.s);
            }
            tcp::close_socket(ctx.release_descriptor())
        }
    }
}

/// Which end of a TLS handshake a context takes.
#[derive(Clone, Copy, PartialEq, Eq)]
pub enum Side {
    Client,
    Server,
}

/// The TLS handshake on the context's socket (just connected or accepted), bounded
/// by the response timeout; the session is kept for the socket. A failure closes the
/// socket and leaves the context without one.
pub fn tls_handshake(ctx: &mut Context, side: Side) -> Result<()> {
    let fd = ctx.s;
    let deadline = Some(transport::now() + ctx.session.timeouts.response.duration());
    let stop = std::sync::Arc::clone(&ctx.stop);
    let host = match &ctx.link {
        Link::Tcp(l) => l.ip.to_string_lossy().into_owned(),
        Link::TcpPi(l) => l.node.to_string_lossy().into_owned(),
        Link::Rtu(_) => return Err(Error::INVALID),
    };
    let Some(tls) = ctx.tls.as_deref_mut() else { return Err(Error::INVALID) };
    let started = match side {
        Side::Client => tls.settings.connect(&host),
        Side::Server => tls.settings.accept(),
    };
    // A server reads record by record (see `tls::RecordCut`); the handshake's
    // flights go out at once.
    let _ = transport::set_option(fd, libc::IPPROTO_TCP, libc::TCP_NODELAY, 1 as libc::c_int);
    let mut cut = (side == Side::Server).then(tls::RecordCut::default);
    let done = started.and_then(|mut conn| {
        tls::handshake(fd, &mut conn, cut.as_mut(), deadline, &|| stop.stopping())?;
        Ok(conn)
    });
    let mut diag = ctx.diag();
    match done {
        Ok(conn) => {
            if ctx.debug {
                let described = tls::describe_session(&conn);
                let session = tls::Session::new(conn, cut);
                let role = session.role().map_or_else(|| "none".to_owned(), |r| format!("{r:?}"));
                diag.out(format_args!("TLS handshake done: {described}, peer role {role}\n"));
                if let Some(tls) = ctx.tls.as_deref_mut() {
                    tls.insert(fd, session);
                }
            } else if let Some(tls) = ctx.tls.as_deref_mut() {
                tls.insert(fd, tls::Session::new(conn, cut));
            }
            Ok(())
        }
        Err(e) => {
            if ctx.debug {
                diag.err(format_args!("ERROR TLS handshake: {}\n", describe(e.0)));
            }
            if !ctx.stopping() {
                tcp::close_socket(ctx.release_descriptor());
            }
            Err(e)
        }
    }
}

/// `modbus_flush`: discard what is pending on the line. Returns the bytes dropped
/// (TCP) or 0 (RTU).
pub fn flush(ctx: &mut Context) -> Result<usize> {
    flush_reporting(ctx).0
}

/// [`flush`], and the error of its last failed system call, if any: the errno
/// libmodbus's `modbus_flush` leaves behind.
fn flush_reporting(ctx: &mut Context) -> (Result<usize>, Option<Error>) {
    let mut buffered = ctx.rx.available().len();
    ctx.rx.clear();
    let fd = ctx.s;
    if let Some(session) = ctx.tls.as_deref_mut().and_then(|t| t.session(fd)) {
        // Records queued on the socket are decrypted and dropped with the rest.
        while session.fill(fd, libc::MSG_DONTWAIT).is_ok() && !session.readable_end() {
            buffered += session.discard();
        }
        buffered += session.discard();
    }
    let (rc, left) = if ctx.is_socket() {
        let (rc, left) = flush_socket(ctx);
        (rc.map(|n| n + buffered), left)
    } else {
        let rc = rtu::flush(ctx.s);
        (rc, rc.err())
    };
    if let Ok(n) = rc {
        ctx.diag().out(format_args!("Bytes flushed ({n})\n"));
    }
    (rc, left)
}

/// Drains a socket without waiting. The count is kept in 16 bits as libmodbus 3.1.11+
/// does; an overflow switches to PROTOCOL recovery and fails with EOVERFLOW. The
/// second value is the error of the last read, when it failed.
fn flush_socket(ctx: &mut Context) -> (Result<usize>, Option<Error>) {
    let mut sink = [0u8; MAX_ADU_LENGTH];
    let mut total: u16 = 0;
    loop {
        let (n, left) = match transport::recv(ctx.s, &mut sink, libc::MSG_DONTWAIT) {
            Ok(n) => (n, None),
            Err(e) => (0, Some(e)),
        };
        total = match total.checked_add(n as u16) {
            Some(t) => t,
            None => {
                ctx.session.recovery = RECOVERY_PROTOCOL;
                return (Err(Error(libc::EOVERFLOW)), Some(Error(libc::EOVERFLOW)));
            }
        };
        if n != MAX_ADU_LENGTH {
            return (Ok(total as usize), left);
        }
    }
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

/// Drives the RTS line through the application's callback (with the context
/// unlocked, so the callback may call `modbus_get_socket` and friends) or the
/// built-in ioctl.
pub fn set_rts(g: &mut Guard<'_>, on: bool) {
    let Some(link) = g.rtu() else { return };
    match link.custom_rts.clone() {
        Some(hook) => call_unlocked(g, || hook(on)),
        None => rtu::set_rts_line(g.s, on),
    }
}

/// Calls an application's callback with the context unlocked, so that it may call
/// `modbus_get_socket` and friends on it (see `handle::call_unlocked`).
pub fn call_unlocked<R>(g: &mut Guard<'_>, f: impl FnOnce() -> R) -> R {
    crate::handle::call_unlocked(g, f)
}

/// The RTS sequence's sleeps (a stop cuts them short; the wait that follows the
/// send then reports it).
fn sleep_us(ctx: &Context, us: i64) {
    if us > 0 {
        let _ = pause(ctx, Duration::from_micros(us as u64));
    }
}

/// Writes one sealed ADU to the line.
#[inline]
fn write_adu(g: &mut Guard<'_>, adu: &[u8]) -> Result<usize> {
    if g.tls.is_some() {
        return write_tls(g, adu);
    }
    if g.is_socket() {
        // A client socket the context made blocking must still never block in a send.
        transport::send(g.s, adu, if g.client_socket.is_some() { libc::MSG_DONTWAIT } else { 0 })
    } else {
        write_serial(g, adu)
    }
}

/// [`write_adu`] on a TLS session: one record, waiting for room up to the response
/// timeout. A socket without a session (one given by `modbus_set_socket` that this
/// context did not connect or accept) cannot carry it: EMBTLS.
#[inline(never)]
fn write_tls(ctx: &mut Context, adu: &[u8]) -> Result<usize> {
    let fd = ctx.s;
    let deadline = Some(transport::now() + ctx.session.timeouts.response.duration());
    let stop = std::sync::Arc::clone(&ctx.stop);
    match ctx.tls.as_deref_mut().and_then(|t| t.session(fd)) {
        Some(session) => session.send(fd, adu, deadline, &|| stop.stopping()),
        None => Err(Error(crate::error::EMBTLS)),
    }
}

/// [`write_adu`] on a serial line (apart, so that a socket's send stays short).
#[inline(never)]
fn write_serial(g: &mut Guard<'_>, adu: &[u8]) -> Result<usize> {
    if g.rtu().is_none_or(|l| l.rts == RTU_RTS_NONE) { transport::write(g.s, adu) } else { write_with_rts(g, adu) }
}

/// [`write_adu`] on a serial line with the RTS sequence.
#[inline(never)]
fn write_with_rts(g: &mut Guard<'_>, adu: &[u8]) -> Result<usize> {
    let Some(&RtuLink { rts, rts_delay, onebyte_time, .. }) = g.rtu() else { return transport::write(g.s, adu) };
    g.diag().err(format_args!("Sending request using RTS signal\n"));
    set_rts(g, rts == RTU_RTS_UP);
    sleep_us(g, rts_delay as i64);
    let rc = transport::write(g.s, adu);
    sleep_us(g, onebyte_time as i64 * adu.len() as i64 + rts_delay as i64);
    set_rts(g, rts != RTU_RTS_UP);
    rc
}

/// libmodbus's `send_msg`: seal the ADU of `len` bytes in `buf`, print it, send it,
/// and under LINK recovery retry until it goes out. Returns the bytes sent.
pub fn send_msg(g: &mut Guard<'_>, buf: &mut [u8], len: usize) -> Result<usize> {
    let len = g.framing.seal(buf, len);
    let adu = &buf[..len];
    if g.debug || g.framing == Framing::Ascii {
        return send_traced_or_encoded(g, adu);
    }
    match write_adu(g, adu) {
        Ok(n) if n == len => Ok(len),
        first => send_after_failure(g, adu, len, first),
    }
}

/// [`send_msg`] with the debug trace or the ASCII encoding (apart, so that the usual
/// send stays a short function).
#[inline(never)]
fn send_traced_or_encoded(g: &mut Guard<'_>, adu: &[u8]) -> Result<usize> {
    if g.debug {
        use std::fmt::Write as _;
        let mut line = String::with_capacity(adu.len() * 4 + 1);
        for b in adu {
            let _ = write!(line, "[{b:02X}]");
        }
        line.push('\n');
        crate::stdio::out(format_args!("{line}"));
    }
    let mut chars = [0u8; ascii::MAX_ENCODED];
    let wire = if g.framing == Framing::Ascii {
        let n = ascii::encode(adu, &mut chars);
        &chars[..n]
    } else {
        adu
    };
    match write_adu(g, wire) {
        Ok(n) if n == wire.len() => Ok(adu.len()),
        first => send_after_failure(g, wire, adu.len(), first),
    }
}

/// A send whose first write did not take the whole frame: a short write is
/// EMBBADDATA; an error is printed and, under LINK recovery, the line is reopened
/// (or flushed) and the write tried again until it goes out. Returns `len`, the
/// ADU's length, once `wire` is out.
#[cold]
#[inline(never)]
fn send_after_failure(g: &mut Guard<'_>, wire: &[u8], len: usize, mut written: Result<usize>) -> Result<usize> {
    loop {
        if g.stopping() {
            return Err(Error::STOPPED);
        }
        match written {
            Ok(n) if n == wire.len() => return Ok(len),
            Ok(_) => return Err(Error::BAD_DATA),
            Err(e) => {
                error_print(g, e, None);
                match session::after_send(g.session.recovery, e) {
                    Recovery::ReconnectAfterSleep => {
                        close(g);
                        sleep_response_timeout(g)?;
                        let _ = connect(g);
                    }
                    Recovery::SleepFlush => {
                        sleep_response_timeout(g)?;
                        let _ = flush(g);
                    }
                    _ => return Err(e),
                }
            }
        }
        written = write_adu(g, wire);
    }
}

/// What a receive got.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// A complete, valid message of this length.
    Frame(usize),
    /// A valid serial frame addressed to another slave (libmodbus returns 0).
    Ignored(usize),
}

/// Carries out the recovery a failure asks for (see `proto::session`), unless the
/// context is being closed under the call.
fn recover(ctx: &mut Context, recovery: Recovery) {
    if recovery == Recovery::None || ctx.stopping() {
        return;
    }
    match recovery {
        Recovery::None => {}
        // The sleep ends early when the context is being closed: then no flush.
        Recovery::SleepFlush => {
            if sleep_response_timeout(ctx).is_ok() {
                let _ = flush(ctx);
            }
        }
        // A bad checksum: the line's own flush, without `modbus_flush`'s trace.
        Recovery::Flush => {
            ctx.rx.clear();
            let _ = rtu::flush(ctx.s);
        }
        Recovery::Reconnect | Recovery::ReconnectAfterSleep => {
            close(ctx);
            if recovery == Recovery::ReconnectAfterSleep && sleep_response_timeout(ctx).is_err() {
                return;
            }
            let _ = connect(ctx);
        }
    }
}

/// Below this response timeout a confirmation never reads under `SO_RCVTIMEO`, which
/// could fire too late (see [`read_within`]).
const RCVTIMEO_MIN_RESPONSE_TIMEOUT: Duration = Duration::from_millis(200);

/// Completes the context's session settings with those of this receive (its kind,
/// what the line can do now) for the receive machine.
#[inline]
fn prepare_session(ctx: &mut Context, kind: MsgKind) {
    let socket = ctx.is_socket();
    let confirmation = kind == MsgKind::Confirmation;
    let ignore = confirmation && ctx.rtu().is_some_and(|l| l.confirmation_to_ignore);
    let s = &mut ctx.session;
    debug_assert_eq!(s.framing, ctx.framing, "the session's framing is the context's");
    s.kind = kind;
    s.line = LineCaps { socket, reads_without_waiting: socket || ctx.line_nonblocking, timed_reads: false };
    s.expecting = None;
    s.read_ahead = false;
    if confirmation {
        s.expecting = ctx.diagnostics_sent.take();
        s.read_ahead = !ignore;
        s.line.timed_reads =
            ctx.client_socket.is_some() && s.timeouts.response.duration() >= RCVTIMEO_MIN_RESPONSE_TIMEOUT;
    }
    if ctx.framing == Framing::Ascii {
        s.ascii_delimiter =
            ctx.server_ext.as_ref().and_then(|e| e.diagnostics()).map_or(b'\n', |d| d.ascii_delimiter());
    }
}

/// libmodbus's `_modbus_receive_msg`, for every framing and line: the one receive
/// path. The session's machine (`proto::session::receive`) decides every step; this
/// loop carries each out with its system call and reports the result. What the
/// machine asks for makes the system-call counts: a TCP client's response is one
/// read under `SO_RCVTIMEO`; a TCP server peeks and takes a whole request in one
/// read, never a byte past it; a serial line is waited on, then read without waiting
/// until it is empty. A close of the context from a signal handler or another
/// thread ends the receive after the step it interrupts, with `Error::STOPPED`.
pub fn receive_msg(ctx: &mut Context, buf: &mut [u8], kind: MsgKind) -> Result<Received> {
    if ctx.debug || ctx.s < 0 {
        let mut diag = ctx.diag();
        match kind {
            MsgKind::Indication => diag.out(format_args!("Waiting for an indication...\n")),
            MsgKind::Confirmation => diag.out(format_args!("Waiting for a confirmation...\n")),
        }
        if ctx.s < 0 {
            diag.err(format_args!("ERROR The connection is not established.\n"));
            return Err(Error::UNCHANGED);
        }
    }
    debug_assert!(buf.len() >= ctx.framing.max_adu_length());
    prepare_session(ctx, kind);
    // The usual first steps need no state of the receive: it is built when a step
    // does not end the receive (see `receive::first_step`).
    let first = if ctx.tls.is_some() { None } else { receive::first_step(&ctx.session, &ctx.rx, buf.len()) };
    let mut machine: Option<Receiver> = None;
    let mut started = None;
    let mut step = match first {
        Some(step) => {
            if matches!(step, Step::Read { .. }) {
                // The deadline runs from before the read, which may wait.
                started = Some(transport::now());
            }
            step
        }
        None => {
            let m = machine.insert(Receiver::new(&ctx.session, transport::now));
            m.start(&ctx.session, buf, &mut ctx.rx, transport::now)
        }
    };
    let tls = ctx.tls.is_some();
    loop {
        let result = match step {
            Step::Frame(len) if !ctx.debug => return Ok(Received::Frame(len)),
            Step::Frame(len) => return finish(ctx, buf, Finished::frame(len)),
            Step::Done(finished) => return finish(ctx, buf, finished),
            step if tls => tls_step(ctx, buf, step),
            Step::Peek { block } => {
                let flags = libc::MSG_PEEK | if block { 0 } else { libc::MSG_DONTWAIT };
                let peeked = transport::recv(ctx.s, &mut ctx.rx.buf, flags);
                // A whole message queued: taken at once, exactly (never a byte past it).
                let whole = match (&machine, peeked) {
                    (None, Ok(n)) => receive::whole_after_peek(&ctx.session, &ctx.rx.buf[..n], buf.len()),
                    (Some(m), Ok(n)) => m.whole_after_peek(&ctx.session, &ctx.rx.buf[..n], buf.len()),
                    _ => None,
                };
                if let Some(len) = whole {
                    let read = transport::recv(ctx.s, &mut buf[..len], 0);
                    if !ctx.stopping() {
                        step = match &mut machine {
                            None if matches!(read, Ok(n) if n == len) => receive::end(&ctx.session, buf, len),
                            m => {
                                let m = match m {
                                    Some(m) => m,
                                    None => m.insert(Receiver::after_first(&ctx.session, &step, transport::now())),
                                };
                                m.took(&ctx.session, len, read, buf, &mut ctx.rx, transport::now)
                            }
                        };
                        continue;
                    }
                }
                peeked
            }
            Step::Read { dest: Dest::Message { from, to }, how: ReadHow::Ready } if ctx.session.line.socket => {
                transport::recv(ctx.s, &mut buf[from..to], 0)
            }
            Step::Read { dest: Dest::Message { from, to }, how: ReadHow::Within(timeout) } => {
                read_within(ctx.s, &mut ctx.client_socket, &mut buf[from..to], timeout, ctx.debug)
            }
            step => execute(ctx, buf, step),
        };
        let m = match &mut machine {
            Some(m) => m,
            None => {
                let started = started.unwrap_or_else(transport::now);
                machine.insert(Receiver::after_first(&ctx.session, &step, started))
            }
        };
        if ctx.stopping() {
            m.stopped();
            step = m.step(&ctx.session, buf, &mut ctx.rx, transport::now);
        } else {
            step = m.next(&ctx.session, result, buf, &mut ctx.rx, transport::now);
        }
    }
}

/// The system call of a step (but the socket's peek and plain read, which the
/// receive loop makes itself).
#[inline(never)]
fn execute(ctx: &mut Context, buf: &mut [u8], step: Step) -> Result<usize> {
    match step {
        Step::Peek { block } => {
            let flags = libc::MSG_PEEK | if block { 0 } else { libc::MSG_DONTWAIT };
            transport::recv(ctx.s, &mut ctx.rx.buf, flags)
        }
        Step::Wait { until } => wait_readable(ctx, until).map(|()| 0),
        Step::Read { dest, how } => {
            let socket = ctx.is_socket();
            let room = match dest {
                Dest::Message { from, to } => &mut buf[from..to],
                Dest::ReadAhead => &mut ctx.rx.buf[..],
            };
            match how {
                ReadHow::Ready if socket => transport::recv(ctx.s, room, 0),
                ReadHow::Ready => transport::read(ctx.s, room),
                ReadHow::Queued if socket => transport::recv(ctx.s, room, libc::MSG_DONTWAIT),
                ReadHow::Queued => transport::read(ctx.s, room),
                ReadHow::Within(timeout) => read_within(ctx.s, &mut ctx.client_socket, room, timeout, ctx.debug),
            }
        }
        Step::Done(_) | Step::Frame(_) => unreachable!("handled by the receive loop"),
    }
}

/// The end of a receive: the debug trace of the message (libmodbus prints its bytes
/// as they arrive; printed at the end, the text is the same with fewer writes), the
/// messages of a bad or foreign frame, the recovery.
#[inline]
fn finish(ctx: &mut Context, buf: &[u8], f: Finished) -> Result<Received> {
    match f.outcome {
        Outcome::Frame(len) if !ctx.debug => Ok(Received::Frame(len)),
        _ => finish_reporting(ctx, buf, f),
    }
}

/// [`finish`] with something to print or to recover from.
#[inline(never)]
fn finish_reporting(ctx: &mut Context, buf: &[u8], f: Finished) -> Result<Received> {
    if ctx.debug && (f.traced > 0 || f.ended) {
        use std::fmt::Write as _;
        let mut trace = String::with_capacity(f.traced * 4 + 1);
        for b in &buf[..f.traced] {
            let _ = write!(trace, "<{b:02X}>");
        }
        if f.ended {
            trace.push('\n');
        }
        crate::stdio::out(format_args!("{trace}"));
    }
    let mut diag = ctx.diag();
    let result = match f.outcome {
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
            if site.is_some() {
                error_print(ctx, error, site);
            }
            Err(error)
        }
    };
    recover(ctx, f.recovery);
    result
}

/// Waits until the line is readable or the monotonic clock reaches `until` (`None`:
/// forever); a signal does not restart the timeout. A close of the context from a
/// signal handler or another thread ends it with `Err(STOPPED)`: a socket is shut
/// down by the closer, a serial line's wait also watches the context's wake-up
/// descriptor.
fn wait_readable(ctx: &Context, until: Option<Duration>) -> Result<()> {
    let wake = if ctx.is_socket() { -1 } else { ctx.stop.wake_fd() };
    wait_line(&ctx.stop, ctx.s, wake, until, ctx.debug)
}

/// [`wait_readable`] on the parts of a context it needs.
fn wait_line(stop: &Stop, fd: i32, wake: i32, until: Option<Duration>, debug: bool) -> Result<()> {
    loop {
        if stop.stopping() {
            return Err(Error::STOPPED);
        }
        let mut left = until.map(|u| transport::to_timespec(u.saturating_sub(transport::now())));
        match transport::wait_or_wake(fd, libc::POLLIN, wake, left.as_mut()) {
            Ok(Ready::Line) => return Ok(()),
            Ok(Ready::TimedOut) => return Err(Error::TIMED_OUT),
            Ok(Ready::Woken) => stop.drain_wake(),
            Err(e) if e.0 == libc::EINTR => {
                crate::stdio::DebugSink { enabled: debug }.err(format_args!("A non blocked signal was caught\n"))
            }
            Err(e) => return Err(e),
        }
    }
}

/// One step of the receive machine on a TLS session: the same steps, on the
/// plaintext the session decrypted. A wait ends when plaintext is there (a readable
/// socket may bring only part of a record, or none of the application's data); a
/// read takes records from the socket only when no plaintext is left.
#[inline(never)]
fn tls_step(ctx: &mut Context, buf: &mut [u8], step: Step) -> Result<usize> {
    let Context { tls, rx, stop, client_socket, debug, s: fd, .. } = ctx;
    let fd = *fd;
    let Some(session) = tls.as_deref_mut().and_then(|t| t.session(fd)) else { return Err(Error(crate::error::EMBTLS)) };
    match step {
        Step::Peek { block } => {
            let flags = if block { 0 } else { libc::MSG_DONTWAIT };
            while !session.readable() {
                session.fill(fd, flags)?;
            }
            match session.peek(&mut rx.buf) {
                0 => session.take(&mut []),
                n => Ok(n),
            }
        }
        Step::Wait { until } => {
            while !session.readable() {
                wait_line(stop, fd, -1, until, *debug)?;
                match session.fill(fd, libc::MSG_DONTWAIT) {
                    Err(e) if e.0 != libc::EAGAIN && e.0 != libc::EINTR => return Err(e),
                    _ => {}
                }
            }
            Ok(0)
        }
        Step::Read { dest, how } => {
            let room = match dest {
                Dest::Message { from, to } => &mut buf[from..to],
                Dest::ReadAhead => &mut rx.buf[..],
            };
            let flags = match how {
                ReadHow::Queued => libc::MSG_DONTWAIT,
                ReadHow::Ready => 0,
                ReadHow::Within(timeout) if receive_timeout_set(fd, client_socket, timeout) => 0,
                ReadHow::Within(_) => libc::MSG_DONTWAIT,
            };
            // One recv at most: a part of a record, or a record with no application
            // data, leaves nothing to take (EAGAIN), and the machine waits again.
            if !session.readable() {
                session.fill(fd, flags)?;
            }
            session.take(room)
        }
        Step::Done(_) | Step::Frame(_) => unreachable!("handled by the caller"),
    }
}

/// The first read of a confirmation on a client socket the context connected (see
/// [`ClientSocket`]): the read itself waits, one system call where a wait and a read
/// were two. `SO_RCVTIMEO` runs on the kernel's timer wheel, which may fire up to an
/// eighth of the time plus a tick or two late, so it is set to 3/4 of the response
/// timeout; when it fires (EAGAIN), the machine waits for the rest of the response
/// timeout, which therefore ends when libmodbus's `select` would.
fn read_within(
    fd: i32,
    socket: &mut Option<ClientSocket>,
    room: &mut [u8],
    timeout: Timeout,
    debug: bool,
) -> Result<usize> {
    // Without the timer the read must not block: then it only looks.
    let flags = if receive_timeout_set(fd, socket, timeout) { 0 } else { libc::MSG_DONTWAIT };
    let read = transport::recv(fd, room, flags);
    if debug && matches!(read, Err(Error(libc::EINTR))) {
        crate::stdio::DebugSink { enabled: true }.err(format_args!("A non blocked signal was caught\n"));
    }
    read
}

/// Sets the socket's `SO_RCVTIMEO` to 3/4 of `timeout` unless it already is; false
/// when it cannot be set (a blocking read could then block for ever).
fn receive_timeout_set(fd: i32, socket: &mut Option<ClientSocket>, timeout: Timeout) -> bool {
    let Some(socket) = socket.as_mut() else { return false };
    if socket.rcvtimeo_for != Some(timeout) {
        if tcp::set_receive_timeout(fd, timeout.duration() * 3 / 4).is_err() {
            return false;
        }
        socket.rcvtimeo_for = Some(timeout);
    }
    true
}

/// The unit id a request goes to.
fn unit(ctx: &Context) -> u8 {
    ctx.session.slave as u8
}

/// Encodes `req` with the next transaction id into `buf`; returns its unsealed length.
pub fn build_request(ctx: &mut Context, req: &Request<'_>, buf: &mut AduBuf) -> usize {
    if ctx.framing == Framing::Tcp {
        ctx.t_id = next_tid(ctx.t_id);
    }
    req.encode(ctx.framing, unit(ctx), ctx.t_id, buf)
}

/// A complete client exchange: send `req`, wait for the confirmation, check it.
/// On success `rsp[..len]` holds the response and `count` is libmodbus's value count.
pub struct Confirmed {
    pub len: usize,
    pub count: i32,
}

pub fn exchange(g: &mut Guard<'_>, req: &Request<'_>, rsp: &mut AduBuf) -> Result<Confirmed> {
    if g.session.slave < 0 {
        // libmodbus asserts (and aborts) here: an RTU request needs a slave id.
        g.diag().err(format_args!("ERROR The slave is not set (call modbus_set_slave)\n"));
        return Err(Error::INVALID);
    }
    let mut out = g.spare.take();
    let result = exchange_with(g, req, &mut out, rsp);
    g.spare.give(out);
    result
}

fn exchange_with(g: &mut Guard<'_>, req: &Request<'_>, out: &mut AduBuf, rsp: &mut AduBuf) -> Result<Confirmed> {
    let n = build_request(g, req, out);
    note_diagnostics(g, &out[..n]);
    let sent = send_msg(g, out, n)?;
    let received = receive_msg(g, rsp, MsgKind::Confirmation)?;
    let req_adu = &out[..sent];
    let (len, rsp_adu) = match received {
        Received::Frame(len) => (len, &rsp[..len]),
        Received::Ignored(len) => (0, &rsp[..len]),
    };
    let ctx: &mut Context = g;
    let mut diag = ctx.diag();
    let checked = if len == 0 && !rsp_adu.is_empty() {
        // libmodbus checks a frame its RTU filter dropped with length 0: the slave
        // pre-check refuses it.
        diag.err(format_args!("The responding slave {} isn't the requested slave {}\n", rsp_adu[0], req_adu[0]));
        Err(Rejection::Foreign(Error::BAD_SLAVE))
    } else {
        confirm::check(ctx.framing, req_adu, rsp_adu, &mut diag)
    };
    match checked {
        Ok(count) => Ok(Confirmed { len, count }),
        Err(Rejection::Exception(e)) => {
            error_print(ctx, e, None);
            Err(e)
        }
        Err(Rejection::Mismatch(e)) => {
            if session::after_mismatch(ctx.session.recovery) == Recovery::SleepFlush
                && sleep_response_timeout(ctx).is_ok()
            {
                let _ = flush(ctx);
            }
            Err(e)
        }
        Err(Rejection::Foreign(e)) => {
            if session::after_mismatch(ctx.session.recovery) == Recovery::None {
                return Err(e);
            }
            // libmodbus sets errno, then flushes: a failed read of the flush leaves
            // its own errno instead.
            sleep_response_timeout(ctx)?;
            let (_, left) = flush_reporting(ctx);
            Err(left.unwrap_or(e))
        }
    }
}

/// `modbus_send_raw_request[_tid]`: `raw[0]` is the unit, the rest is the PDU.
pub fn send_raw(g: &mut Guard<'_>, raw: &[u8], tid: u16) -> Result<usize> {
    let mut out: AduBuf = [0; MAX_ADU_LENGTH];
    let h = g.framing.write_header(&mut out, raw[0], tid);
    let pdu = &raw[1..];
    out[h..h + pdu.len()].copy_from_slice(pdu);
    note_diagnostics(g, &out[..h + pdu.len()]);
    send_msg(g, &mut out, h + pdu.len())
}

/// Remembers the length of a diagnostics request about to go out on a serial
/// framing, so that its answer can be framed (see `Context::diagnostics_sent`).
fn note_diagnostics(ctx: &mut Context, unsealed: &[u8]) {
    let h = ctx.framing.header_length();
    ctx.diagnostics_sent = (ctx.framing != Framing::Tcp && unsealed.get(h) == Some(&crate::proto::fc::DIAGNOSTICS))
        .then_some(unsealed.len());
}
