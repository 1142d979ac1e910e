//! The libmodbus flows that drive the sans-I/O core over a transport: sending with
//! the debug trace and LINK recovery, the receive loop with its three timeouts, and
//! the client's request/confirmation exchange.

use std::time::{Duration, Instant};

use crate::context::{ClientSocket, Context, Link, RECOVERY_PROTOCOL, RTU_RTS_NONE, RTU_RTS_UP, RtuLink};
use crate::core::confirm::{self, Rejection};
use crate::core::frame::{Assembler, Framing, MAX_ADU_LENGTH, MsgKind, Progress, RtuIntegrity, rtu_integrity};
use crate::core::request::{Request, next_tid};
use crate::core::session::{self, Recovery, Wait};
use crate::core::{Diag, ascii};
use crate::error::{Error, Result};
use crate::lock::OwnerGuard;
use crate::transport::tcp::ConnectError;
use crate::transport::{self, Ready, rtu, tcp};

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
    let timeout = ctx.response_timeout.duration();
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
        Link::Tcp(_) | Link::TcpPi(_) => tcp::close_socket(ctx.release_descriptor()),
    }
}

/// `modbus_flush`: discard what is pending on the line. Returns the bytes dropped
/// (TCP) or 0 (RTU).
pub fn flush(ctx: &mut Context) -> Result<usize> {
    let buffered = ctx.rx.available().len();
    ctx.rx.clear();
    let rc = if ctx.is_socket() { flush_socket(ctx).map(|n| n + buffered) } else { rtu::flush(ctx.s) };
    if let Ok(n) = rc {
        ctx.diag().out(format_args!("Bytes flushed ({n})\n"));
    }
    rc
}

/// Drains a socket without waiting. The count is kept in 16 bits as libmodbus 3.1.11+
/// does; an overflow switches to PROTOCOL recovery and fails with EOVERFLOW.
fn flush_socket(ctx: &mut Context) -> Result<usize> {
    let mut sink = [0u8; MAX_ADU_LENGTH];
    let mut total: u16 = 0;
    loop {
        let n = transport::recv(ctx.s, &mut sink, libc::MSG_DONTWAIT).unwrap_or(0);
        total = match total.checked_add(n as u16) {
            Some(t) => t,
            None => {
                ctx.error_recovery = RECOVERY_PROTOCOL;
                return Err(Error(libc::EOVERFLOW));
            }
        };
        if n != MAX_ADU_LENGTH {
            return Ok(total as usize);
        }
    }
}

/// Sleeps the response timeout (error recovery); `Err(STOPPED)` as soon as the
/// context is being closed under the call.
pub fn sleep_response_timeout(ctx: &Context) -> Result<()> {
    pause(ctx, ctx.response_timeout.duration())
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
        Some(hook) => {
            // The handle must outlive the callback, which may free it (or a signal
            // handler may, meanwhile): a reference held across it.
            let stop = std::sync::Arc::clone(&g.stop);
            stop.refs.fetch_add(1, std::sync::atomic::Ordering::SeqCst);
            OwnerGuard::unlocked(g, || hook(on));
            if stop.refs.fetch_sub(1, std::sync::atomic::Ordering::SeqCst) == 1 {
                // `modbus_free` came meanwhile: the handle is ours to free, when this
                // call releases the lock (see `OwnerGuard::release`).
                stop.refs.store(1, std::sync::atomic::Ordering::SeqCst);
                OwnerGuard::raise_flag(g);
            }
        }
        None => rtu::set_rts_line(g.s, on),
    }
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
    if g.is_socket() {
        // A client socket the context made blocking must still never block in a send.
        transport::send(g.s, adu, if g.client_socket.is_some() { libc::MSG_DONTWAIT } else { 0 })
    } else {
        write_serial(g, adu)
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
                match session::after_send(g.error_recovery, e) {
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

/// What the receive loop got.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// A complete, valid message of this length.
    Frame(usize),
    /// RTU: a valid frame addressed to another slave (libmodbus returns 0).
    Ignored(usize),
}

/// LINK recovery after a failed wait (see `session::after_wait`).
fn recover_after_wait(ctx: &mut Context, e: Error) {
    if ctx.stopping() {
        return;
    }
    match session::after_wait(ctx.error_recovery, e) {
        // The sleep ends early when the context is being closed: then no flush.
        Recovery::SleepFlush if sleep_response_timeout(ctx).is_ok() => {
            let _ = flush(ctx);
        }
        Recovery::Reconnect => {
            close(ctx);
            let _ = connect(ctx);
        }
        _ => {}
    }
}

/// LINK recovery after a failed read (see `session::after_read`).
fn recover_after_read(ctx: &mut Context, e: Error) {
    if !ctx.stopping() && session::after_read(ctx.error_recovery, e) == Recovery::Reconnect {
        close(ctx);
        let _ = connect(ctx);
    }
}

/// libmodbus's `_modbus_receive_msg`: read one message, step by step. The first wait
/// uses the response timeout (confirmation) or the indication timeout (0 = forever);
/// later waits use a fresh byte timeout, or, when that is 0, what is left of the
/// first one.
///
/// Fewer system calls than libmodbus, same observable behaviour:
/// - a client reads ahead as much as the line has, keeping what lies past its
///   response in the context's [`ReadAhead`](crate::context::ReadAhead) for the
///   next receive (a client owns its line);
/// - a TCP server peeks at what has arrived and, when it holds the whole request,
///   takes exactly that request in one read; it never takes bytes past the request,
///   so the application's own poll loop still sees pipelined requests.
pub fn receive_msg(g: &mut Guard<'_>, buf: &mut [u8], kind: MsgKind) -> Result<Received> {
    let ctx: &mut Context = g;
    let mut diag = ctx.diag();
    match kind {
        MsgKind::Indication => diag.out(format_args!("Waiting for an indication...\n")),
        MsgKind::Confirmation => diag.out(format_args!("Waiting for a confirmation...\n")),
    }
    if ctx.s < 0 {
        diag.err(format_args!("ERROR The connection is not established.\n"));
        return Err(Error::UNCHANGED);
    }
    if ctx.framing == Framing::Ascii {
        return receive_ascii(ctx, buf, kind);
    }
    debug_assert!(buf.len() >= ctx.framing.max_adu_length());
    if ctx.is_socket() && kind == MsgKind::Indication && ctx.rx.available().is_empty() {
        if let Some(len) = take_whole_indication(ctx, buf) {
            if ctx.debug {
                let mut trace = String::with_capacity(len * 4 + 1);
                push_trace(&mut trace, &buf[..len]);
                trace.push('\n');
                flush_trace(ctx, &mut trace);
            }
            return check_integrity(ctx, &buf[..len]);
        }
    }
    receive_otherwise(ctx, buf, kind)
}

/// Every receive but the socket server's fast path (kept apart so that the latter
/// stays a short function).
#[inline(never)]
fn receive_otherwise(ctx: &mut Context, buf: &mut [u8], kind: MsgKind) -> Result<Received> {
    if ctx.line_nonblocking && kind == MsgKind::Indication && !ctx.debug && ctx.rx.available().is_empty() {
        return receive_serial_request(ctx, buf);
    }
    receive_steps(ctx, buf, kind, 0, first_timeout(ctx, kind))
}

/// Serial server fast path: after the first wait, the slave and function code, then,
/// when the function code alone tells the rest of the request's length (every
/// request but FC 0F, 10, 17 and the extended ones), the rest in one read that does
/// not wait. Each read takes no more than the request, as in the general loop, which
/// carries on with the bytes read so far whenever a piece is not there yet (or the
/// wait failed: it waits again, with what is left of the timeout, and reports).
fn receive_serial_request(ctx: &mut Context, buf: &mut [u8]) -> Result<Received> {
    let mut budget = first_timeout(ctx, MsgKind::Indication);
    let h = ctx.framing.header_length();
    let mut filled = 0;
    if wait_readable(ctx, budget.as_mut()).is_ok() {
        filled = transport::read(ctx.s, &mut buf[..h + 1]).unwrap_or(0);
        let total = if filled == h + 1 {
            Assembler::new(ctx.framing, MsgKind::Indication)
                .extended_requests(ctx.serves_extended)
                .total_if_known(&buf[..h + 1])
        } else {
            None
        };
        if let Some(total) = total.filter(|&total| total <= buf.len()) {
            filled += read_if_queued(ctx, &mut buf[h + 1..total]).unwrap_or(0);
            if filled == total {
                return check_integrity(ctx, &buf[..filled]);
            }
        }
        if filled > 0 {
            rearm_after_bytes(ctx, &mut budget);
        }
    }
    receive_steps(ctx, buf, MsgKind::Indication, filled, budget)
}

/// The general receive loop of RTU and TCP (see [`receive_msg`]); `buf[..filled]`
/// holds bytes of the message already read, `budget` the time for the next wait.
fn receive_steps(
    ctx: &mut Context,
    buf: &mut [u8],
    kind: MsgKind,
    mut filled: usize,
    mut budget: Option<libc::timespec>,
) -> Result<Received> {
    let read_ahead = kind == MsgKind::Confirmation && !ctx.rtu().is_some_and(|l| l.confirmation_to_ignore);
    let expecting = if kind == MsgKind::Confirmation { ctx.diagnostics_sent.take() } else { None };
    let mut asm = Assembler::new(ctx.framing, kind).extended_requests(ctx.serves_extended).expecting(expecting);
    let mut trace = String::new();
    // Bytes in `buf`: those the assembler took, then (reading ahead) any after them.
    loop {
        if read_ahead && asm.is_empty() && filled > 0 {
            // The usual case: one read brought the whole message.
            if let Some(len) = asm.whole(&buf[..filled]) {
                keep_unread(ctx, &buf[len..filled]);
                if ctx.debug {
                    push_trace(&mut trace, &buf[..len]);
                    trace.push('\n');
                    flush_trace(ctx, &mut trace);
                }
                return check_integrity(ctx, &buf[..len]);
            }
        }
        while asm.len() < filled {
            let start = asm.len();
            let n = asm.wanted().min(filled - start);
            if ctx.debug {
                push_trace(&mut trace, &buf[start..start + n]);
            }
            match asm.received(&buf[..start + n], n) {
                Ok(Progress::NeedMore(_)) => {}
                Ok(Progress::Complete(len)) => {
                    keep_unread(ctx, &buf[len..filled]);
                    if ctx.debug {
                        trace.push('\n');
                        flush_trace(ctx, &mut trace);
                    }
                    return check_integrity(ctx, &buf[..len]);
                }
                Err(e) => {
                    keep_unread(ctx, &buf[start + n..filled]);
                    flush_trace(ctx, &mut trace);
                    error_print(ctx, e, Some("too many data"));
                    return Err(e);
                }
            }
        }
        let want = asm.wanted();
        if !ctx.rx.available().is_empty() {
            // Left over from an earlier read: take only what this message needs, so
            // whatever stays behind keeps its order.
            let n = want.min(ctx.rx.available().len());
            buf[filled..filled + n].copy_from_slice(&ctx.rx.available()[..n]);
            ctx.rx.consume(n);
            filled += n;
            continue;
        }
        if filled > 0 {
            // Within a message the rest has usually arrived with its start: read it
            // without waiting when the read cannot block, and wait only if it is
            // not there yet.
            let room = if read_ahead { &mut buf[filled..] } else { &mut buf[filled..filled + want] };
            if let Some(n) = read_if_queued(ctx, room) {
                filled += n;
                rearm_after_bytes(ctx, &mut budget);
                continue;
            }
        }
        let end = if read_ahead { buf.len() } else { filled + want };
        let mut read = None;
        if filled == 0 && kind == MsgKind::Confirmation {
            read = read_within_response_timeout(ctx, &mut buf[..end], &mut budget);
        }
        let read = match read {
            Some(read) => read,
            None => {
                if let Err(e) = wait_readable(ctx, budget.as_mut()) {
                    if e == Error::TIMED_OUT && asm.searching_crc() {
                        // The diagnostics request ended without a matching CRC: a bad frame.
                        if ctx.debug {
                            trace.push('\n');
                            flush_trace(ctx, &mut trace);
                        }
                        return check_integrity(ctx, &buf[..asm.len()]);
                    }
                    flush_trace(ctx, &mut trace);
                    error_print(ctx, e, Some("select"));
                    recover_after_wait(ctx, e);
                    return Err(e);
                }
                read_line(ctx.is_socket(), ctx.s, &mut buf[filled..end])
            }
        };
        if ctx.stopping() {
            flush_trace(ctx, &mut trace);
            return Err(Error::STOPPED);
        }
        match read {
            Ok(0) | Err(Error(libc::ECONNRESET)) => {
                flush_trace(ctx, &mut trace);
                error_print(ctx, Error::CONN_RESET, Some("read"));
                recover_after_read(ctx, Error::CONN_RESET);
                return Err(Error::CONN_RESET);
            }
            Ok(n) => filled += n,
            Err(e) if e.0 == libc::EAGAIN || e.0 == libc::EINTR => continue,
            Err(e) => {
                flush_trace(ctx, &mut trace);
                error_print(ctx, e, Some("read"));
                recover_after_read(ctx, e);
                return Err(e);
            }
        }
        rearm_after_bytes(ctx, &mut budget);
    }
}

/// Keeps bytes read past the end of a message for the next receive (the read-ahead
/// buffer is empty whenever a read runs, so order is kept).
fn keep_unread(ctx: &mut Context, rest: &[u8]) {
    if !rest.is_empty() {
        ctx.rx.buf[..rest.len()].copy_from_slice(rest);
        ctx.rx.start = 0;
        ctx.rx.end = rest.len();
    }
}

/// The receive loop of Modbus ASCII: characters are read ahead (a frame ends at its
/// CR LF, so nothing past it is consumed as part of it) and decoded into `buf`. The
/// first wait uses the response or indication timeout, the later ones the byte
/// timeout (1 s by default on ASCII contexts: the gap the protocol allows).
fn receive_ascii(ctx: &mut Context, buf: &mut [u8], kind: MsgKind) -> Result<Received> {
    let mut budget = first_timeout(ctx, kind);
    let delimiter = ctx.server_ext.as_ref().and_then(|e| e.diagnostics()).map_or(b'\n', |d| d.ascii_delimiter());
    let mut decoder = ascii::Decoder::with_delimiter(delimiter);
    let mut trace = String::new();
    loop {
        if ctx.rx.available().is_empty() {
            if let Err(e) = wait_readable(ctx, budget.as_mut()) {
                flush_trace(ctx, &mut trace);
                error_print(ctx, e, Some("select"));
                recover_after_wait(ctx, e);
                return Err(e);
            }
            let read = read_line(ctx.is_socket(), ctx.s, &mut ctx.rx.buf);
            if ctx.stopping() {
                flush_trace(ctx, &mut trace);
                return Err(Error::STOPPED);
            }
            match read {
                Ok(0) | Err(Error(libc::ECONNRESET)) => {
                    flush_trace(ctx, &mut trace);
                    error_print(ctx, Error::CONN_RESET, Some("read"));
                    recover_after_read(ctx, Error::CONN_RESET);
                    return Err(Error::CONN_RESET);
                }
                Ok(n) => ctx.rx.end = n,
                Err(e) if e.0 == libc::EAGAIN || e.0 == libc::EINTR => continue,
                Err(e) => {
                    flush_trace(ctx, &mut trace);
                    error_print(ctx, e, Some("read"));
                    recover_after_read(ctx, e);
                    return Err(e);
                }
            }
        }
        let mut used = 0;
        let mut outcome = None;
        for &c in ctx.rx.available() {
            used += 1;
            let before = decoder.len();
            match decoder.feed(c, buf) {
                Ok(ascii::Step::NeedMore) => {
                    if ctx.debug && decoder.len() > before {
                        push_trace(&mut trace, &buf[before..decoder.len()]);
                    }
                }
                Ok(ascii::Step::Complete(len)) => {
                    outcome = Some(Ok(len));
                    break;
                }
                Err(e) => {
                    outcome = Some(Err(e));
                    break;
                }
            }
        }
        ctx.rx.consume(used);
        match outcome {
            None => {
                if decoder.in_frame() {
                    rearm_after_bytes(ctx, &mut budget);
                }
            }
            Some(Ok(len)) => {
                if ctx.debug {
                    trace.push('\n');
                    flush_trace(ctx, &mut trace);
                }
                let received = check_integrity(ctx, &buf[..len])?;
                if received == Received::Frame(len) && !ascii_frame_is_whole(ctx, kind, &buf[..len]) {
                    // The characters ended before the content did (a byte count or a
                    // layout asks for more): refuse it like an RTU frame cut short.
                    error_print(ctx, Error::BAD_DATA, Some("frame too short"));
                    return Err(Error::BAD_DATA);
                }
                return Ok(received);
            }
            Some(Err(e)) => {
                flush_trace(ctx, &mut trace);
                error_print(ctx, e, Some("invalid ASCII frame"));
                return Err(e);
            }
        }
    }
}

/// The first wait of a receive: the response timeout for a confirmation, the
/// indication timeout (0 = forever) for a request.
fn first_timeout(ctx: &Context, kind: MsgKind) -> Option<libc::timespec> {
    match ctx.timeouts().first_wait(kind) {
        Wait::For(t) => Some(transport::timespec_of(t)),
        Wait::Forever | Wait::Left => None,
    }
}

/// An ASCII frame ends at its delimiter whatever its content says; the checks after
/// receiving rely on the content's own lengths, as RTU and TCP frames are read by
/// them. A frame is whole when it holds at least what the binary length rules ask
/// for (the frame's own length stands in for the lengths a PDU does not carry).
fn ascii_frame_is_whole(ctx: &Context, kind: MsgKind, frame: &[u8]) -> bool {
    frame.len() >= 3
        && Assembler::new(Framing::Ascii, kind)
            .extended_requests(ctx.serves_extended)
            .expecting(Some(frame.len() - Framing::Ascii.checksum_length()))
            .whole(frame)
            .is_some()
}

/// Waits until the line is readable or the time in `budget` runs out (`None`:
/// forever). The kernel counts `budget` down, so a later wait with the same value
/// gets what is left, and a signal does not restart the timeout. A close of the
/// context from a signal handler or another thread ends it with `Err(STOPPED)`: a
/// socket is shut down by the closer, a serial line's wait also watches the
/// context's wake-up descriptor.
fn wait_readable(ctx: &Context, mut budget: Option<&mut libc::timespec>) -> Result<()> {
    let wake = if ctx.is_socket() { -1 } else { ctx.stop.wake_fd() };
    loop {
        if ctx.stopping() {
            return Err(Error::STOPPED);
        }
        match transport::wait_or_wake(ctx.s, libc::POLLIN, wake, budget.as_deref_mut()) {
            Ok(Ready::Line) => return Ok(()),
            Ok(Ready::TimedOut) => return Err(Error::TIMED_OUT),
            Ok(Ready::Woken) => ctx.stop.drain_wake(),
            Err(e) if e.0 == libc::EINTR => ctx.diag().err(format_args!("A non blocked signal was caught\n")),
            Err(e) => return Err(e),
        }
    }
}

/// Below this response timeout a confirmation waits with `ppoll` only: `SO_RCVTIMEO`
/// could fire too late (see [`read_within_response_timeout`]).
const RCVTIMEO_MIN_RESPONSE_TIMEOUT: Duration = Duration::from_millis(200);

/// The first wait of a confirmation on a client socket the context connected (see
/// [`ClientSocket`](crate::context::ClientSocket)): the read itself, one system call
/// where a poll and a read were two. `SO_RCVTIMEO` runs on the kernel's timer wheel,
/// which may fire up to an eighth of the time plus a tick or two late, so it is set
/// to 3/4 of the response timeout; when it fires (or a signal comes), `budget` gets
/// the exact rest of the response timeout, measured on the monotonic clock, for the
/// usual `ppoll`. The timeout therefore ends when libmodbus's `select` would.
/// `None` when the caller is to wait as usual; otherwise the read's result.
fn read_within_response_timeout(
    ctx: &mut Context,
    room: &mut [u8],
    budget: &mut Option<libc::timespec>,
) -> Option<Result<usize>> {
    let timeout = ctx.response_timeout;
    let socket = ctx.client_socket.as_mut()?;
    if timeout.duration() < RCVTIMEO_MIN_RESPONSE_TIMEOUT {
        return None;
    }
    if socket.rcvtimeo_for != Some(timeout) {
        tcp::set_receive_timeout(ctx.s, timeout.duration() * 3 / 4).ok()?;
        socket.rcvtimeo_for = Some(timeout);
    }
    let started = Instant::now();
    let read = transport::recv(ctx.s, room, 0);
    let rest_of_timeout = || Some(transport::to_timespec(timeout.duration().saturating_sub(started.elapsed())));
    match read {
        Err(e) if e.0 == libc::EAGAIN || e.0 == libc::EINTR => {
            if e.0 == libc::EINTR {
                ctx.diag().err(format_args!("A non blocked signal was caught\n"));
            }
            *budget = rest_of_timeout();
            None
        }
        Ok(n) if n > 0 && ctx.byte_timeout.is_zero() => {
            // No byte timeout: the rest of the message shares the response timeout.
            *budget = rest_of_timeout();
            Some(read)
        }
        _ => Some(read),
    }
}

/// After bytes of a message arrived, the next wait gets a fresh byte timeout or, when
/// that is 0, what is left of the current one.
#[inline]
fn rearm_after_bytes(ctx: &Context, budget: &mut Option<libc::timespec>) {
    if let Wait::For(t) = ctx.timeouts().after_bytes() {
        *budget = Some(transport::timespec_of(t));
    }
}

/// A read that never blocks: bytes already queued on the line, or `None` (nothing
/// there, an error, or a descriptor a read could block on) for the waiting path to
/// handle as usual.
fn read_if_queued(ctx: &Context, room: &mut [u8]) -> Option<usize> {
    let got = if ctx.is_socket() {
        transport::recv(ctx.s, room, libc::MSG_DONTWAIT)
    } else if ctx.line_nonblocking {
        transport::read(ctx.s, room)
    } else {
        return None;
    };
    got.ok().filter(|&n| n > 0)
}

/// One read from the line: `recv` on a socket, `read` on a serial line.
fn read_line(socket: bool, fd: i32, buf: &mut [u8]) -> Result<usize> {
    if socket { transport::recv(fd, buf, 0) } else { transport::read(fd, buf) }
}

/// Socket server fast path: peek at the queued bytes (blocking when the indication
/// timeout is infinite) and, when they hold a whole request, take exactly that
/// request. `None` when the slow path must run (nothing queued yet, a partial
/// request, an oversized one, or an error it will report).
fn take_whole_indication(ctx: &mut Context, buf: &mut [u8]) -> Option<usize> {
    let flags = libc::MSG_PEEK | if ctx.indication_timeout.is_zero() { 0 } else { libc::MSG_DONTWAIT };
    // Peek into the (empty) read-ahead buffer: the caller's buffer only ever receives
    // the request.
    let peeked = &mut ctx.rx.buf;
    let queued = match transport::recv(ctx.s, peeked, flags) {
        Ok(n) if n > 0 => n,
        _ => return None,
    };
    let len = Assembler::new(ctx.framing, MsgKind::Indication)
        .extended_requests(ctx.serves_extended)
        .whole(&peeked[..queued])?;
    // The request is queued whole, so this read returns all of it and nothing more.
    match transport::recv(ctx.s, buf.get_mut(..len)?, 0) {
        Ok(n) if n == len => Some(len),
        _ => None,
    }
}

fn push_trace(trace: &mut String, bytes: &[u8]) {
    use std::fmt::Write as _;
    for b in bytes {
        let _ = write!(trace, "<{b:02X}>");
    }
}

/// Prints the `<XX>` bytes collected so far (libmodbus prints them as they arrive;
/// collecting them per message keeps the same text with fewer writes).
fn flush_trace(ctx: &Context, trace: &mut String) {
    if ctx.debug && !trace.is_empty() {
        crate::stdio::out(format_args!("{trace}"));
        trace.clear();
    }
}

/// End of the receive loop: RTU frames must have a good CRC and be ours.
#[inline]
fn check_integrity(ctx: &mut Context, frame: &[u8]) -> Result<Received> {
    if ctx.framing == Framing::Tcp {
        return Ok(Received::Frame(frame.len()));
    }
    check_serial_integrity(ctx, frame)
}

#[inline(never)]
fn check_serial_integrity(ctx: &mut Context, frame: &[u8]) -> Result<Received> {
    let mut diag = ctx.diag();
    if ctx.framing == Framing::Ascii {
        if let Err((received, computed)) = ascii::check_lrc(frame) {
            diag.err(format_args!("ERROR LRC received 0x{received:0X} != LRC calculated 0x{computed:0X}\n"));
            if session::after_bad_checksum(ctx.error_recovery) == Recovery::Flush {
                ctx.rx.clear();
                let _ = rtu::flush(ctx.s);
            }
            return Err(Error::BAD_CRC);
        }
        if frame[0] as i32 != ctx.slave && frame[0] != 0 {
            diag.out(format_args!("Request for slave {} ignored (not {})\n", frame[0], ctx.slave));
            return Ok(Received::Ignored(frame.len()));
        }
        return Ok(Received::Frame(frame.len()));
    }
    match rtu_integrity(frame, ctx.slave) {
        RtuIntegrity::Ok => Ok(Received::Frame(frame.len())),
        RtuIntegrity::BadCrc(received, computed) => {
            diag.err(format_args!("ERROR CRC received 0x{received:0X} != CRC calculated 0x{computed:0X}\n"));
            if session::after_bad_checksum(ctx.error_recovery) == Recovery::Flush {
                let _ = rtu::flush(ctx.s);
            }
            Err(Error::BAD_CRC)
        }
        RtuIntegrity::OtherSlave(theirs, ours) => {
            diag.out(format_args!("Request for slave {theirs} ignored (not {ours})\n"));
            Ok(Received::Ignored(frame.len()))
        }
    }
}

/// The unit id a request goes to.
fn unit(ctx: &Context) -> u8 {
    ctx.slave as u8
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
    if g.slave < 0 {
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
            if session::after_mismatch(ctx.error_recovery) == Recovery::SleepFlush
                && sleep_response_timeout(ctx).is_ok()
            {
                let _ = flush(ctx);
            }
            Err(e)
        }
        Err(Rejection::Foreign(e)) => {
            if session::after_mismatch(ctx.error_recovery) == Recovery::None {
                return Err(e);
            }
            // errno first, then the flush, whose failed non-blocking read may
            // overwrite it: the order libmodbus has.
            transport::set_errno(e.0);
            sleep_response_timeout(ctx)?;
            let _ = flush(ctx);
            Err(Error::UNCHANGED)
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
    ctx.diagnostics_sent = (ctx.framing != Framing::Tcp && unsealed.get(h) == Some(&crate::core::fc::DIAGNOSTICS))
        .then_some(unsealed.len());
}
