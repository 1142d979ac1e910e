//! The server session's state between two requests, whichever driver receives them
//! (a blocking `modbus_receive`, or the server runner), and its reading of how a
//! receive ended: whether the frame is a request to answer, what the diagnostics bus
//! counters count, and whether the next frame on a shared bus is another slave's
//! answer to skip.

use super::receive::Received;
use crate::error::{Error, Result};
use crate::frame::{Framing, MsgKind};
use crate::server_ext::BusEvent;

/// See the module.
#[derive(Clone, Copy, Debug, Default)]
pub struct ServerSession {
    /// A request for another slave was seen on a shared bus: its answer comes next
    /// and is read (as a confirmation) and dropped.
    skip_next: bool,
}

/// What a server does with a receive that ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Taken {
    /// A request to answer: `msg[..len]`.
    Request(usize),
    /// The answer of another slave (or whatever came instead), skipped.
    Skipped,
    /// A serial request for a unit the application does not serve.
    NotServed(u8),
    /// A serial frame for another slave than the context's.
    OtherSlave,
    /// Nothing to answer: the receive failed (a bad checksum among the reasons).
    Failed(Error),
}

impl ServerSession {
    /// What the next receive reads: a request, or the other slave's answer to skip.
    #[inline]
    pub fn kind(&self) -> MsgKind {
        if self.skip_next { MsgKind::Confirmation } else { MsgKind::Indication }
    }

    /// A receive ended with `r` (`msg` its bytes). `accept`: whether a request for
    /// this unit, not a broadcast, is served (asked of serial framings only: the
    /// context's slave was checked by the receive, an application serving several
    /// units decides here); `shared_bus`: a serial line, where the answer of another
    /// slave follows its request.
    pub fn ended(
        &mut self,
        r: &Result<Received>,
        msg: &[u8],
        shared_bus: bool,
        accept: impl FnOnce(u8) -> bool,
    ) -> Taken {
        if core::mem::take(&mut self.skip_next) {
            return Taken::Skipped;
        }
        match *r {
            Ok(Received::Frame(len)) => {
                let unit = msg[0];
                if unit == 0 || accept(unit) {
                    return Taken::Request(len);
                }
                self.skip_next = shared_bus;
                Taken::NotServed(unit)
            }
            Ok(Received::Ignored(_)) => {
                self.skip_next = shared_bus;
                Taken::OtherSlave
            }
            Err(e) => Taken::Failed(e),
        }
    }

    /// Forgets the other slave's answer awaited.
    pub fn reset(&mut self) {
        self.skip_next = false;
    }
}

/// What the diagnostics bus counters count of a receive that ended (`None`:
/// nothing; a timeout or a lost line is no message on the bus).
pub fn bus_event(framing: Framing, r: &Result<Received>) -> Option<BusEvent> {
    match r {
        Ok(_) => Some(BusEvent::Frame),
        Err(e) if *e == Error::BAD_CRC => Some(BusEvent::CommunicationError),
        // ASCII: a frame that cannot be decoded; RTU and TCP: more bytes announced
        // than the ADU holds.
        Err(e) if *e == Error::BAD_DATA && framing == Framing::Ascii => Some(BusEvent::CommunicationError),
        Err(e) if *e == Error::BAD_DATA => Some(BusEvent::CharacterOverrun),
        Err(_) => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_for_another_slave_on_a_shared_bus_skips_its_answer() {
        let mut s = ServerSession::default();
        let msg = [0x05, 0x03, 0, 0, 0, 1, 0, 0];
        assert_eq!(s.ended(&Ok(Received::Ignored(8)), &msg, true, |_| true), Taken::OtherSlave);
        assert_eq!(s.kind(), MsgKind::Confirmation);
        assert_eq!(s.ended(&Err(Error::BAD_CRC), &msg, true, |_| true), Taken::Skipped, "whatever came");
        assert_eq!(s.kind(), MsgKind::Indication);
        // Filtered by the application.
        assert_eq!(s.ended(&Ok(Received::Frame(8)), &msg, true, |u| u != 5), Taken::NotServed(5));
        assert_eq!(s.kind(), MsgKind::Confirmation);
        s.reset();
        assert_eq!(s.ended(&Ok(Received::Frame(8)), &msg, true, |_| true), Taken::Request(8));
        // Broadcasts are always taken; RTU over TCP has no other slave on its line.
        assert_eq!(s.ended(&Ok(Received::Frame(8)), &[0, 3], true, |_| false), Taken::Request(8));
        assert_eq!(s.ended(&Ok(Received::Frame(8)), &msg, false, |_| false), Taken::NotServed(5));
        assert_eq!(s.kind(), MsgKind::Indication);
        assert_eq!(s.ended(&Err(Error::TIMED_OUT), &msg, false, |_| true), Taken::Failed(Error::TIMED_OUT));
    }

    #[test]
    fn bus_events() {
        assert_eq!(bus_event(Framing::Rtu, &Ok(Received::Frame(8))), Some(BusEvent::Frame));
        assert_eq!(bus_event(Framing::Rtu, &Ok(Received::Ignored(8))), Some(BusEvent::Frame));
        assert_eq!(bus_event(Framing::Rtu, &Err(Error::BAD_CRC)), Some(BusEvent::CommunicationError));
        assert_eq!(bus_event(Framing::Rtu, &Err(Error::BAD_DATA)), Some(BusEvent::CharacterOverrun));
        assert_eq!(bus_event(Framing::Ascii, &Err(Error::BAD_DATA)), Some(BusEvent::CommunicationError));
        assert_eq!(bus_event(Framing::Tcp, &Err(Error::TIMED_OUT)), None);
    }
}
