//! Server flows: `modbus_receive`, `modbus_reply` and `modbus_reply_exception` over a
//! locked context. The decisions are made by the sans-I/O core
//! ([`crate::core::reply`]); this module only does what the outcome says, in
//! libmodbus's order: sleep and flush, then send (or not, for an RTU broadcast).

use crate::context::Context;
use crate::core::Diag;
use crate::core::frame::{Framing, MAX_ADU_LENGTH, MsgKind};
use crate::core::reply::{Mapping, Outcome, Server, exception_response};
use crate::engine::{self, AduBuf, Guard, Received};
use crate::error::{Error, Result, exception};

/// `modbus_receive`: waits for one request and returns its length, or 0 for a frame
/// libmodbus filters out (RTU: addressed to another slave, or the answer of that
/// slave which follows it on a shared bus).
pub fn receive(g: &mut Guard<'_>, buf: &mut AduBuf) -> Result<usize> {
    if g.framing == Framing::Tcp {
        return Ok(match engine::receive_msg(g, buf, MsgKind::Indication)? {
            Received::Frame(len) => len,
            Received::Ignored(_) => 0,
        });
    }
    let ignore_next = g.rtu().is_some_and(|l| l.confirmation_to_ignore);
    if ignore_next {
        // The reply of the slave addressed by the previous request: read it as a
        // confirmation, whatever happens, and drop it.
        let _ = engine::receive_msg(g, buf, MsgKind::Confirmation);
        set_confirmation_to_ignore(g, false);
        g.diag().out(format_args!("Confirmation to ignore\n"));
        return Ok(0);
    }
    match engine::receive_msg(g, buf, MsgKind::Indication)? {
        Received::Frame(len) => Ok(len),
        Received::Ignored(_) => {
            set_confirmation_to_ignore(g, true);
            Ok(0)
        }
    }
}

fn set_confirmation_to_ignore(ctx: &mut Context, value: bool) {
    if let Some(link) = ctx.rtu_mut() {
        link.confirmation_to_ignore = value;
    }
}

/// `modbus_reply`: answers `req` (at most the bytes the request describes; see
/// [`crate::core::reply::request_extent`]) from `mapping`. Returns the bytes sent, 0
/// for a suppressed RTU broadcast.
pub fn reply(g: &mut Guard<'_>, req: &[u8], req_length: i32, mapping: &mut dyn Mapping) -> Result<usize> {
    let server = Server { framing: g.framing, quirks: g.quirks };
    let mut out: AduBuf = [0; MAX_ADU_LENGTH];
    let outcome = server.reply(req, req_length, mapping, &mut g.diag(), &mut out);
    match outcome {
        Outcome::Fail(e) => Err(e),
        Outcome::Respond { len, flush_first, suppressed, .. } => {
            if flush_first {
                // The rest of a request libmodbus could not frame may still be arriving.
                engine::sleep_response_timeout(g);
                let _ = engine::flush(g);
            }
            if suppressed {
                return Ok(0);
            }
            engine::send_msg(g, &mut out, len)
        }
    }
}

/// `modbus_reply_exception`: sends exception `code` (below `MODBUS_EXCEPTION_MAX`,
/// else EINVAL) for `req`, without flushing and even for a broadcast.
pub fn reply_exception(g: &mut Guard<'_>, req: &[u8], code: u32) -> Result<usize> {
    if code >= exception::MAX as u32 {
        return Err(Error::INVALID);
    }
    let mut out: AduBuf = [0; MAX_ADU_LENGTH];
    let len = exception_response(g.framing, req, code as u8, &mut out);
    engine::send_msg(g, &mut out, len)
}
