//! Server flows: `modbus_receive`, `modbus_reply` and `modbus_reply_exception` over a
//! locked context. The decisions are made by the sans-I/O core
//! ([`crate::proto::reply`], and [`crate::server_ext`] for a context configured
//! beyond libmodbus); this module only does what the outcome says, in libmodbus's
//! order: sleep and flush, then send (or not, for an RTU broadcast).
//!
//! A context with diagnostics enabled (`modbus_enable_diagnostics`) also reports
//! here what happened on the line: frames and checksum errors from the receive,
//! responses sent or not from the replies (see [`crate::proto::diagnostics`]). A
//! context without the extension pays one pointer test per call.

use crate::context::{Context, new_connection_id};
use crate::engine::{self, AduBuf, Guard};
use crate::error::{Error, Result, exception};
use crate::proto::Diag;
use crate::proto::diagnostics::Delivery;
use crate::proto::frame::{Framing, MsgKind};
use crate::proto::reply::{Data, Outcome, Server, exception_response};
use crate::proto::security;
use crate::proto::session::Recovery;
use crate::proto::session::server::Taken;
use crate::session::{self, Driver, Received, Recovered};
use crate::transport::Room;
use crate::transport::udp::Peer;

/// A UDP server remembers this many senders; the least recent goes first (and gets
/// a new id if it comes back).
const UDP_PEERS_MAX: usize = 4096;

/// The connection of the request `ctx` is serving: its id (0 on a serial line) and
/// its peer (a stream socket's, a datagram's sender; `None` on a serial line).
pub fn connection(ctx: &mut Context) -> (u64, Option<Peer>) {
    if ctx.line.is_datagram() {
        let Some(peer) = ctx.line.peer() else { return (0, None) };
        let c = &mut ctx.connection;
        c.seen += 1;
        let seen = c.seen;
        if let Some(entry) = c.senders.get_mut(peer.bytes()) {
            entry.1 = seen;
            return (entry.0, Some(peer));
        }
        if c.senders.len() >= UDP_PEERS_MAX {
            if let Some(oldest) = c.senders.iter().min_by_key(|(_, v)| v.1).map(|(k, _)| k.clone()) {
                c.senders.remove(&oldest);
            }
        }
        let id = new_connection_id();
        c.senders.insert(peer.bytes().to_vec(), (id, seen));
        return (id, Some(peer));
    }
    if !ctx.line.is_stream() || ctx.fd() < 0 {
        return (0, None);
    }
    let fd = ctx.fd();
    let generation = ctx.line.generation();
    let c = &mut ctx.connection;
    // The socket is asked only when the line's descriptor changed (modbus_set_socket
    // again with the same socket keeps its id).
    if !c.fixed && (c.id == 0 || c.generation != generation) {
        let cookie = crate::transport::socket_cookie(fd);
        if c.id == 0 || cookie != c.cookie {
            c.cookie = cookie;
            c.id = new_connection_id();
            c.peer = Peer::of_socket(fd);
        }
        c.generation = generation;
    }
    (c.id, c.peer)
}

/// `modbus_receive`: waits for one request and returns its length, or 0 for a frame
/// libmodbus filters out (RTU: addressed to another slave, or the answer of that
/// slave which follows it on a shared bus). With `units`, a serial request is kept
/// when `units` accepts its unit (or it is a broadcast), whatever the context's
/// slave (`modbus_receive_dispatch`). The server session (`session::taken`) reads
/// what came, as the runner's does.
#[inline(always)]
pub fn receive(g: &mut Guard<'_>, buf: &mut [u8], units: Option<&mut dyn Data>) -> Result<usize> {
    if g.framing() == Framing::Tcp && g.server_ext.is_none() {
        // The usual server: a request, nothing to count (no other slave's answer
        // follows a request on TCP).
        return match engine::receive_msg(g, &mut Room::bare(buf), MsgKind::Indication)? {
            Received::Frame(len) => Ok(len),
            Received::Ignored(_) => Ok(0),
        };
    }
    let kind = g.server.kind();
    let any_unit = units.is_some() && kind == MsgKind::Indication && g.framing() != Framing::Tcp;
    g.session.any_unit = any_unit;
    let r = engine::receive_msg(g, &mut Room::bare(buf), kind);
    g.session.any_unit = false;
    if g.server_ext.is_none() && kind == MsgKind::Indication {
        // The usual request: nothing to count, nothing to skip.
        match r {
            Ok(Received::Frame(len)) if g.framing() == Framing::Tcp || !any_unit || buf[0] == 0 => return Ok(len),
            Err(e) => return Err(e),
            _ => {}
        }
    }
    let frame = match r {
        Ok(Received::Frame(len)) => len,
        _ => 0,
    };
    let taken = session::taken(g, buf, &r, |unit| units.is_none_or(|u| u.accept_unit(unit, &buf[..frame])));
    match taken {
        Taken::Request(len) => Ok(len),
        Taken::Skipped | Taken::NotServed(_) | Taken::OtherSlave => Ok(0),
        Taken::Failed(e) => Err(e),
    }
}

/// Carries out an outcome: flush first if asked, then send unless suppressed.
fn perform(g: &mut Guard<'_>, outcome: Outcome, out: &mut AduBuf) -> (Result<usize>, Delivery) {
    match outcome {
        Outcome::Fail(e) => (Err(e), Delivery::NotSent),
        Outcome::Respond { len, flush_first, suppressed, .. } => {
            if flush_first {
                // The rest of a request libmodbus could not frame may still be
                // arriving: a blocking server sleeps, then flushes; a runner waits for
                // no one (a serial line drops what it holds, a datagram its rest; a
                // socket's requests were framed whole by their MBAP length).
                let driver = if g.runner { Driver::Runner } else { Driver::Blocking };
                if session::recover(g, Recovery::SleepFlush, driver) == Recovered::Stopped {
                    return (Err(Error::STOPPED), Delivery::NotSent);
                }
            }
            if suppressed {
                return (Ok(0), Delivery::NotSent);
            }
            match engine::send_msg(g, out, len) {
                Ok(n) => (Ok(n), Delivery::Sent),
                Err(e) => (Err(e), Delivery::SendFailed),
            }
        }
    }
}

/// `modbus_reply` and `modbus_reply_dispatch`: answers `req` (at most the bytes the
/// request describes; see [`crate::proto::reply::request_extent`]) from `data`.
/// Returns the bytes sent, 0 for a suppressed RTU broadcast, a unit `data` does not
/// serve on a serial line, an answer `data` withholds (and, with diagnostics, in
/// listen-only mode). On TCP, a unit not served is answered with exception 0B
/// (gateway target device failed to respond), as gateways answer it. On a UDP
/// server's socket the answer goes to the sender of `req` (`Line::answering`).
#[inline]
pub fn reply<D: Data>(g: &mut Guard<'_>, req: &[u8], req_length: i32, data: &mut D) -> Result<usize> {
    g.line.answering(req)?;
    let framing = g.framing();
    let unit = req.get(framing.header_length() - 1).copied().unwrap_or(0);
    let broadcast = framing.is_serial() && unit == 0;
    if !broadcast && !data.accept_unit(unit, req) {
        if framing.is_serial() {
            g.diag().out(format_args!("Request for slave {unit} not served\n"));
            return Ok(0);
        }
        return exception_reply(g, req, exception::GATEWAY_TARGET as u32);
    }
    if g.line.authorizes() && !authorized(g, req)? {
        // Exception 01, nothing changed; as modbus_reply_exception sends it
        // (not in listen-only mode, counted by the diagnostics).
        return exception_reply(g, req, exception::ILLEGAL_FUNCTION as u32);
    }
    let server = Server { framing: g.framing(), quirks: g.quirks };
    let mut sink = g.diag();
    let mut out = g.spare.take();
    let result = match g.server_ext.as_deref_mut() {
        None => {
            let outcome = server.answer(req, req_length, data, &mut sink, out.adu_mut());
            perform(g, outcome, &mut out).0
        }
        Some(ext) => {
            let answer = ext.reply(server, req, req_length, data, &mut sink, out.adu_mut());
            let (result, delivery) = perform(g, answer.outcome, &mut out);
            if let Some(ext) = g.server_ext.as_deref_mut() {
                ext.complete(&answer, delivery);
            }
            result
        }
    };
    g.spare.give(out);
    result
}

/// Modbus/TCP Security: asks the application's authorization callback about each
/// range `req` touches, for the role of the client on the context's socket (R-24 to
/// R-28 of the specification). The callback runs with the context unlocked: if it
/// makes another socket current, the client that would get the answer is not the
/// one whose role was asked about, so nothing is served or sent (EINVAL); if the
/// context was closed meanwhile, the stop ends the reply (EBADF).
fn authorized(g: &mut Guard<'_>, req: &[u8]) -> Result<bool> {
    let fd = g.fd();
    let Some(hook) = g.line.authorizer() else { return Ok(true) };
    let role: Option<std::ffi::CString> = g.line.peer_role().map(ToOwned::to_owned);
    let h = g.framing().header_length();
    let unit = req.get(h - 1).copied().unwrap_or(0);
    let access = security::access(req.get(h..).unwrap_or(&[]));
    for range in access.ranges() {
        let allowed =
            engine::call_unlocked(g, || hook(role.as_deref(), unit, access.function, range.address, range.nb));
        if g.fd() != fd {
            // Closed meanwhile (another thread, a signal handler): the stop; or
            // another socket made current by the callback.
            return Err(if g.fd() < 0 || g.stopping() { Error::STOPPED } else { Error::INVALID });
        }
        if !allowed {
            let shown = role.as_deref().map_or_else(|| "none".to_owned(), |r| format!("{r:?}"));
            g.diag().out(format_args!(
                "Request 0x{:02X} at {} ({} item(s)) refused for role {shown}\n",
                access.function, range.address, range.nb
            ));
            return Ok(false);
        }
    }
    Ok(true)
}

/// `modbus_reply_exception`: sends exception `code` (below `MODBUS_EXCEPTION_MAX`,
/// else EINVAL) for `req`, without flushing and even for a broadcast. With
/// diagnostics in listen-only mode nothing is sent and 0 is returned. On a UDP
/// server's socket the answer goes to the sender of `req` (`Line::answering`).
pub fn reply_exception(g: &mut Guard<'_>, req: &[u8], code: u32) -> Result<usize> {
    if code >= exception::MAX as u32 {
        return Err(Error::INVALID);
    }
    g.line.answering(req)?;
    exception_reply(g, req, code)
}

/// [`reply_exception`] once the answer's destination is set.
fn exception_reply(g: &mut Guard<'_>, req: &[u8], code: u32) -> Result<usize> {
    if code >= exception::MAX as u32 {
        return Err(Error::INVALID);
    }
    let framing = g.framing();
    if let Some(ext) = g.server_ext.as_deref_mut() {
        if !ext.exception_request(framing, req) {
            ext.exception_done(code as u8, Delivery::NotSent);
            return Ok(0);
        }
    }
    let mut out = g.spare.take();
    let len = exception_response(framing, req, code as u8, out.adu_mut());
    let r = engine::send_msg(g, &mut out[..], len);
    g.spare.give(out);
    if let Some(ext) = g.server_ext.as_deref_mut() {
        ext.exception_done(code as u8, if r.is_ok() { Delivery::Sent } else { Delivery::SendFailed });
    }
    r
}
