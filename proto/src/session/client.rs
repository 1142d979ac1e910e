//! The client session's state that outlives one request, whichever driver carries
//! the requests out (a blocking call, or the event-driven client's pipeline): the
//! transaction ids, the late ids (one store: [`LateIds`]), and the length of the
//! answer a diagnostics request on a serial framing awaits.

use super::late::LateIds;
use crate::fc;
use crate::frame::Framing;
use crate::request::next_tid;

/// See the module.
#[derive(Debug, Default)]
pub struct ClientSession {
    /// The last transaction id used (TCP).
    tid: u16,
    late: LateIds,
    /// Header + PDU of the last diagnostics request sent on a serial framing, for
    /// its answer (see [`answer_length`]).
    expecting: Option<usize>,
}

impl ClientSession {
    /// The transaction id of the next request (TCP; the same id on other framings).
    #[inline]
    pub fn next_tid(&mut self, framing: Framing) -> u16 {
        if framing == Framing::Tcp {
            self.tid = next_tid(self.tid);
        }
        self.tid
    }

    /// The last transaction id used.
    pub fn tid(&self) -> u16 {
        self.tid
    }

    /// Sets the last transaction id (`modbus_send_raw_request_tid` leaves the
    /// sequence alone: only tests set it).
    pub fn set_tid(&mut self, tid: u16) {
        self.tid = tid;
    }

    /// A request goes out on its own (a blocking call): `adu`, its header and PDU,
    /// is what the answer's length may depend on.
    #[inline]
    pub fn sending(&mut self, framing: Framing, adu: &[u8]) {
        self.expecting = answer_length(framing, adu);
    }

    /// What [`ClientSession::sending`] noted, for the answer's receive (once).
    #[inline]
    pub fn take_expecting(&mut self) -> Option<usize> {
        self.expecting.take()
    }

    /// The context's late transaction ids.
    #[inline]
    pub fn late(&mut self) -> &mut LateIds {
        &mut self.late
    }
}

/// The length (header + PDU) of the answer to the request whose header and PDU are
/// `adu`, when nothing in that answer tells it: a diagnostics request on a serial
/// framing is answered with as many bytes as it has. `None` otherwise (the answer's
/// own layout, or TCP's MBAP length, tells).
#[inline]
pub fn answer_length(framing: Framing, adu: &[u8]) -> Option<usize> {
    let diagnostics = adu.get(framing.header_length()) == Some(&fc::DIAGNOSTICS);
    (framing != Framing::Tcp && diagnostics).then_some(adu.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_serial_diagnostics_answer_is_as_long_as_its_request() {
        let req = [0x11, 0x08, 0x00, 0x00, 0xA5, 0x37];
        assert_eq!(answer_length(Framing::Rtu, &req), Some(6));
        assert_eq!(answer_length(Framing::Ascii, &req), Some(6));
        assert_eq!(answer_length(Framing::Rtu, &[0x11, 0x03, 0, 0, 0, 1]), None);
        let tcp = [0, 1, 0, 0, 0, 6, 0xFF, 0x08, 0, 0, 0xA5, 0x37];
        assert_eq!(answer_length(Framing::Tcp, &tcp), None);
        let mut s = ClientSession::default();
        s.sending(Framing::Rtu, &req);
        assert_eq!(s.take_expecting(), Some(6));
        assert_eq!(s.take_expecting(), None, "once");
        assert_eq!(s.next_tid(Framing::Tcp), 1);
        assert_eq!(s.next_tid(Framing::Rtu), 1);
    }
}
