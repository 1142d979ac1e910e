//! The server session's state between two requests, whichever driver receives them
//! (a blocking `modbus_receive`, or the server runner), and its reading of how a
//! receive ended: whether the frame is a request to answer, what the diagnostics bus
//! counters count, and whether the next frame on a shared bus is another slave's
//! answer to skip.

use super::receive::Outcome;
use crate::error::Error;
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
    /// The answer of another slave, skipped.
    Skipped,
    /// A serial request for a unit not served (`theirs`; `ours`: the context's
    /// slave, or -1 when an application's filter said no).
    NotServed { theirs: u8, ours: i32 },
    /// Nothing to answer: a bad checksum or a failure (`Err`), reported as such.
    Failed(Error),
}

impl ServerSession {
    /// What the next receive reads: a request, or the other slave's answer to skip.
    #[inline]
    pub fn kind(&self) -> MsgKind {
        if self.skip_next { MsgKind::Confirmation } else { MsgKind::Indication }
    }

    /// A receive ended with `outcome` (`msg` its bytes). `accept`: whether a request
    /// for this unit, not a broadcast, is served (asked of serial framings only: the
    /// context's slave was checked by the receive, an application serving several
    /// units decides here); `shared_bus`: a serial line, where the answer of another
    /// slave follows its request.
    pub fn ended(&mut self, outcome: Outcome, msg: &[u8], shared_bus: bool, accept: impl FnOnce(u8) -> bool) -> Taken {
        if core::mem::take(&mut self.skip_next) {
            return Taken::Skipped;
        }
        match outcome {
            Outcome::Frame(len) => {
                let unit = msg[0];
                if unit == 0 || accept(unit) {
                    return Taken::Request(len);
                }
                self.skip_next = shared_bus;
                Taken::NotServed { theirs: unit, ours: -1 }
            }
            Outcome::Ignored { theirs, ours, .. } => {
                self.skip_next = shared_bus;
                Taken::NotServed { theirs, ours }
            }
            Outcome::BadChecksum { .. } => Taken::Failed(Error::BAD_CRC),
            Outcome::Failed { error, .. } => Taken::Failed(error),
        }
    }

    /// Forgets the other slave's answer awaited (the line was flushed or closed).
    pub fn reset(&mut self) {
        self.skip_next = false;
    }
}

/// What the diagnostics bus counters count of a receive that ended (`None`:
/// nothing; a timeout or a lost line is no message on the bus).
pub fn bus_event(framing: Framing, outcome: &Outcome) -> Option<BusEvent> {
    match outcome {
        Outcome::Frame(_) | Outcome::Ignored { .. } => Some(BusEvent::Frame),
        Outcome::BadChecksum { .. } => Some(BusEvent::CommunicationError),
        // ASCII: a frame that cannot be decoded; RTU and TCP: more bytes announced
        // than the ADU holds.
        Outcome::Failed { error, .. } if *error == Error::BAD_DATA && framing == Framing::Ascii => {
            Some(BusEvent::CommunicationError)
        }
        Outcome::Failed { error, .. } if *error == Error::BAD_DATA => Some(BusEvent::CharacterOverrun),
        Outcome::Failed { .. } => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_request_for_another_slave_on_a_shared_bus_skips_its_answer() {
        let mut s = ServerSession::default();
        let msg = [0x05, 0x03, 0, 0, 0, 1, 0, 0];
        let other = Outcome::Ignored { len: 8, theirs: 5, ours: 1 };
        assert_eq!(s.ended(other, &msg, true, |_| true), Taken::NotServed { theirs: 5, ours: 1 });
        assert_eq!(s.kind(), MsgKind::Confirmation);
        assert_eq!(s.ended(Outcome::Frame(7), &msg, true, |_| true), Taken::Skipped);
        assert_eq!(s.kind(), MsgKind::Indication);
        // Filtered by the application.
        assert_eq!(s.ended(Outcome::Frame(8), &msg, true, |u| u != 5), Taken::NotServed { theirs: 5, ours: -1 });
        assert_eq!(s.kind(), MsgKind::Confirmation);
        s.reset();
        assert_eq!(s.ended(Outcome::Frame(8), &msg, true, |_| true), Taken::Request(8));
        // Broadcasts are always taken; TCP has no shared bus.
        assert_eq!(s.ended(Outcome::Frame(8), &[0, 3], true, |_| false), Taken::Request(8));
        assert_eq!(s.ended(Outcome::Frame(8), &msg, false, |_| true), Taken::Request(8));
        assert_eq!(s.ended(Outcome::Frame(8), &msg, false, |_| false), Taken::NotServed { theirs: 5, ours: -1 });
        assert_eq!(s.kind(), MsgKind::Indication, "RTU over TCP: no other slave answers on the line");
    }

    #[test]
    fn bus_events() {
        let failed = |error| Outcome::Failed { error, site: None };
        assert_eq!(bus_event(Framing::Rtu, &Outcome::Frame(8)), Some(BusEvent::Frame));
        let bad = Outcome::BadChecksum { lrc: false, received: 1, computed: 2 };
        assert_eq!(bus_event(Framing::Rtu, &bad), Some(BusEvent::CommunicationError));
        assert_eq!(bus_event(Framing::Rtu, &failed(Error::BAD_DATA)), Some(BusEvent::CharacterOverrun));
        assert_eq!(bus_event(Framing::Ascii, &failed(Error::BAD_DATA)), Some(BusEvent::CommunicationError));
        assert_eq!(bus_event(Framing::Tcp, &failed(Error::TIMED_OUT)), None);
    }
}
