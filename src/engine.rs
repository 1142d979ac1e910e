//! The libmodbus flows that drive the sans-I/O core over a transport: sending with
//! the debug trace and LINK recovery, the receive loop with its three timeouts, and
//! the client's request/confirmation exchange.

use std::time::Duration;

use crate::context::{Context, RtsHook};
use crate::error::{Error, Result};
use crate::lock::OwnerGuard;
use crate::proto::confirm::{self, Rejection};
use crate::proto::frame::{Framing, MsgKind};
use crate::proto::request::Request;
use crate::proto::session::receive::{self, Finished, Receiver, Step};
use crate::proto::session::{self, Recovery};
use crate::proto::{Diag, ascii};
use crate::session::{Driver, Received, Recovered, conclude, error_print, flush_reporting};
use crate::session::{Waiting, execute, pause, recover, sleep_response_timeout, trace_sent};
use crate::transport::{self, Room};

/// A locked context. Functions that may call back into the application (the custom
/// RTS callback) take the guard so they can release the lock around the call.
pub type Guard<'a> = OwnerGuard<'a, Context>;

/// One ADU buffer, large enough for any framing, with room around it for a read.
pub use crate::transport::AduBuf;

/// Drives the RTS line of a serial context through the application's callback
/// (with the context unlocked, so the callback may call `modbus_get_socket` and
/// friends) or the built-in ioctl.
pub fn set_rts(g: &mut Guard<'_>, on: bool) {
    let hook = g.line.rts_hook();
    drive_rts(g, hook.as_ref(), on);
}

fn drive_rts(g: &mut Guard<'_>, hook: Option<&RtsHook>, on: bool) {
    match hook {
        Some(hook) => call_unlocked(g, || hook(on)),
        None => g.line.set_rts(on),
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

/// Writes one sealed ADU to the line (a TLS session waits for room up to the
/// response timeout), with the RTS sequence around it when the line has one.
#[inline]
fn write_adu(g: &mut Guard<'_>, adu: &[u8]) -> Result<usize> {
    let timeout = g.session.timeouts.response;
    match g.line.write_at_once(adu, timeout) {
        Some(written) => written,
        None => write_with_rts(g, adu),
    }
}

/// [`write_adu`] with the RTS sequence (the event-driven client's too).
#[inline(never)]
pub fn write_with_rts(g: &mut Guard<'_>, adu: &[u8]) -> Result<usize> {
    let timeout = g.session.timeouts.response;
    let Some(rts) = g.line.rts_sequence() else { return g.line.write(adu, timeout) };
    g.diag().err(format_args!("Sending request using RTS signal\n"));
    drive_rts(g, rts.hook.as_ref(), rts.up);
    sleep_us(g, rts.delay_us);
    let rc = g.line.write(adu, timeout);
    sleep_us(g, rts.onebyte_us * adu.len() as i64 + rts.delay_us);
    drive_rts(g, rts.hook.as_ref(), !rts.up);
    rc
}

/// libmodbus's `send_msg`: seal the ADU of `len` bytes in `buf`, print it, send it,
/// and under LINK recovery retry until it goes out. Returns the bytes sent.
pub fn send_msg(g: &mut Guard<'_>, buf: &mut [u8], len: usize) -> Result<usize> {
    let len = g.framing().seal(buf, len);
    let adu = &buf[..len];
    if g.debug || g.framing() == Framing::Ascii {
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
        trace_sent(adu);
    }
    let mut chars = [0u8; ascii::MAX_ENCODED];
    let wire = if g.framing() == Framing::Ascii {
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
                let recovery = session::after_send(g.session.recovery, e);
                if recovery == Recovery::None {
                    return Err(e);
                }
                // Reopened after a sleep, or flushed after one; then sent again.
                if recover(g, recovery, Driver::Blocking) == Recovered::Stopped {
                    return Err(Error::STOPPED);
                }
            }
        }
        written = write_adu(g, wire);
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
pub fn receive_msg(ctx: &mut Context, room: &mut Room<'_>, kind: MsgKind) -> Result<Received> {
    if ctx.debug || ctx.fd() < 0 {
        let mut diag = ctx.diag();
        match kind {
            MsgKind::Indication => diag.out(format_args!("Waiting for an indication...\n")),
            MsgKind::Confirmation => diag.out(format_args!("Waiting for a confirmation...\n")),
        }
        if ctx.fd() < 0 {
            diag.err(format_args!("ERROR The connection is not established.\n"));
            return Err(Error::UNCHANGED);
        }
    }
    debug_assert!(room.size() >= ctx.framing().max_adu_length());
    let expecting = if kind == MsgKind::Confirmation { ctx.client.take_expecting() } else { None };
    crate::session::prepare(ctx, kind, expecting);
    // The usual first steps need no state of the receive: it is built when a step
    // does not end the receive (see `receive::first_step`).
    let first = receive::first_step(&ctx.session, &ctx.rx, room.size());
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
            m.start(&ctx.session, room.msg(), &mut ctx.rx, transport::now)
        }
    };
    loop {
        let result = match step {
            Step::Frame(len) if !ctx.debug => return Ok(Received::Frame(len)),
            Step::Frame(len) => return finish(ctx, room.msg_ref(), Finished::frame(len)),
            Step::Done(finished) => return finish(ctx, room.msg_ref(), finished),
            _ => {
                let Some(r) = execute(&mut ctx.line, &mut ctx.rx, room, step, ctx.debug, &mut Waiting::Block) else {
                    unreachable!("a blocking step always ends")
                };
                r
            }
        };
        if let (Step::Peek { .. }, Ok(n)) = (step, result) {
            // A whole message queued: taken at once, exactly (never a byte past it).
            let whole = match &machine {
                None => receive::whole_after_peek(&ctx.session, &ctx.rx.buf[..n], room.size()),
                Some(m) => m.whole_after_peek(&ctx.session, &ctx.rx.buf[..n], room.size()),
            };
            if let Some(len) = whole {
                let buf = room.msg();
                let read = ctx.line.take(&mut buf[..len]);
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
        }
        let m = match &mut machine {
            Some(m) => m,
            None => {
                let started = started.unwrap_or_else(transport::now);
                machine.insert(Receiver::after_first(&ctx.session, &step, started))
            }
        };
        if ctx.stopping() {
            m.stopped();
            step = m.step(&ctx.session, room.msg(), &mut ctx.rx, transport::now);
        } else {
            step = m.next(&ctx.session, result, room.msg(), &mut ctx.rx, transport::now);
        }
    }
}

/// The end of a blocking receive: read by the one reader ([`conclude`]), then the
/// recovery it names, carried out with its sleeps.
#[inline]
fn finish(ctx: &mut Context, buf: &[u8], f: Finished) -> Result<Received> {
    let result = conclude(ctx, buf, &f, Driver::Blocking);
    if f.recovery != Recovery::None {
        recover(ctx, f.recovery, Driver::Blocking);
    }
    result
}

/// The unit id a request goes to.
fn unit(ctx: &Context) -> u8 {
    ctx.session.slave as u8
}

/// Encodes `req` with the next transaction id into `buf`; returns its unsealed length.
pub fn build_request(ctx: &mut Context, req: &Request<'_>, buf: &mut AduBuf) -> usize {
    let tid = ctx.client.next_tid(ctx.framing());
    req.encode(ctx.framing(), unit(ctx), tid, buf)
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
    g.idle()?;
    let mut out = g.spare.take();
    let result = exchange_with(g, req, &mut out, rsp);
    g.spare.give(out);
    result
}

fn exchange_with(g: &mut Guard<'_>, req: &Request<'_>, out: &mut AduBuf, rsp: &mut AduBuf) -> Result<Confirmed> {
    let n = build_request(g, req, out);
    note_diagnostics(g, &out[..n]);
    let sent = send_msg(g, out, n)?;
    let received = receive_answer(g, rsp, &out[..sent])?;
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
        confirm::check(ctx.framing(), req_adu, rsp_adu, &mut diag)
    };
    match checked {
        Ok(count) => Ok(Confirmed { len, count }),
        Err(Rejection::Exception(e)) => {
            error_print(ctx, e, None);
            Err(e)
        }
        Err(Rejection::Mismatch(e)) => {
            recover(ctx, session::after_mismatch(ctx.session.recovery), Driver::Blocking);
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

/// Receives the confirmation of the TCP request `req` (or of a serial one). An answer
/// to an earlier request of this context that timed out (its transaction id says
/// so) is dropped and the receive starts again: libmodbus takes it as this request's
/// answer and fails it (EMBBADDATA), and the next request's too.
fn receive_answer(g: &mut Guard<'_>, rsp: &mut AduBuf, req: &[u8]) -> Result<Received> {
    let tcp = g.framing() == Framing::Tcp;
    loop {
        match receive_msg(g, &mut rsp.room(), MsgKind::Confirmation) {
            Ok(Received::Frame(len)) if tcp && len >= 2 && rsp[..2] != req[..2] => {
                let tid = u16::from_be_bytes([rsp[0], rsp[1]]);
                if g.line.is_datagram() {
                    // Modbus/UDP: a datagram repeated or late on the way is another
                    // request's answer, never this one's.
                    g.diag().err(format_args!("Answer with transaction ID 0x{tid:X} dropped (not awaited)\n"));
                    continue;
                }
                if !g.client.late().take(tid) {
                    return Ok(Received::Frame(len));
                }
                g.diag().err(format_args!("Late answer with transaction ID 0x{tid:X} dropped\n"));
            }
            Err(e) if tcp && e == Error::TIMED_OUT => {
                g.client.late().push(u16::from_be_bytes([req[0], req[1]]));
                return Err(e);
            }
            other => return other,
        }
    }
}

/// `modbus_send_raw_request[_tid]`: `raw[0]` is the unit, the rest is the PDU.
pub fn send_raw(g: &mut Guard<'_>, raw: &[u8], tid: u16) -> Result<usize> {
    g.idle()?;
    let mut out = AduBuf::new();
    let h = g.framing().write_header(&mut out, raw[0], tid);
    let pdu = &raw[1..];
    out[h..h + pdu.len()].copy_from_slice(pdu);
    note_diagnostics(g, &out[..h + pdu.len()]);
    send_msg(g, &mut out, h + pdu.len())
}

/// Notes a request about to go out on its own, for its answer's receive (see
/// `ClientSession::sending`).
fn note_diagnostics(ctx: &mut Context, unsealed: &[u8]) {
    let framing = ctx.framing();
    ctx.client.sending(framing, unsealed);
}
