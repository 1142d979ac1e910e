//! Serial-line diagnostics of a server: the eight bus counters of function code 08,
//! the communication event counter (FC 0B), the 64-entry communication event log
//! (FC 0C), the diagnostic register, and listen-only mode. Pure state: the server
//! flows report what happened ([`Diagnostics::frame_received`],
//! [`Diagnostics::request_received`], [`Diagnostics::request_done`], ...) and the
//! reply logic reads the values back.
//!
//! What each counter counts (all 16 bits, wrapping):
//!
//! | Sub-function | Counter | Incremented by |
//! |---|---|---|
//! | 0x0B | bus message | every frame `modbus_receive` reads whole: for this server, broadcast, for another slave, or with a bad checksum |
//! | 0x0C | bus communication error | a frame with a bad CRC (RTU) or LRC (ASCII), or an ASCII frame that cannot be decoded |
//! | 0x0D | bus exception error | every exception response sent (by `modbus_reply` or `modbus_reply_exception`) |
//! | 0x0E | server message | every request handed to `modbus_reply`/`modbus_reply_exception`, listen-only mode included |
//! | 0x0F | server no response | such a request that got no response: broadcast, listen-only mode, force listen only, a function `modbus_reply` does not answer |
//! | 0x10 | server NAK | exception 07 (NEGATIVE ACKNOWLEDGE) sent |
//! | 0x11 | server busy | exception 06 (SERVER DEVICE BUSY) sent |
//! | 0x12 | bus character overrun | a frame longer than the ADU buffer (RTU, TCP) |
//!
//! The communication event counter counts the requests completed without an
//! exception, except Get Comm Event Counter (0B) and Get Comm Event Log (0C)
//! themselves, and nothing in listen-only mode. The message count of FC 0C is the bus
//! message count.
//!
//! Event bytes, newest first, at most [`EVENT_LOG_SIZE`]:
//! - receive event `1xxx xxx0`, stored when a request arrives: bit 1 communication
//!   error, bit 4 character overrun, bit 5 in listen-only mode, bit 6 broadcast;
//! - send event `01xx xxxx`, stored when a request is done (answered or not): bit 0
//!   exception 1-3 sent, bit 1 exception 4, bit 2 exception 5-6, bit 3 exception 7,
//!   bit 4 the response could not be written, bit 5 in listen-only mode;
//! - `0x04` entered listen-only mode (stored instead of the send event of the Force
//!   Listen Only Mode request);
//! - `0x00` communication restart (stored instead of the send event of the Restart
//!   Communications Option request, after the optional log clear).

/// Entries of the communication event log.
pub const EVENT_LOG_SIZE: usize = 64;

/// Diagnostics sub-function codes (FC 08).
pub mod sub {
    pub const RETURN_QUERY_DATA: u16 = 0x00;
    pub const RESTART_COMMUNICATIONS: u16 = 0x01;
    pub const RETURN_DIAGNOSTIC_REGISTER: u16 = 0x02;
    pub const CHANGE_ASCII_DELIMITER: u16 = 0x03;
    pub const FORCE_LISTEN_ONLY: u16 = 0x04;
    pub const CLEAR_COUNTERS: u16 = 0x0A;
    pub const BUS_MESSAGE_COUNT: u16 = 0x0B;
    pub const BUS_COMM_ERROR_COUNT: u16 = 0x0C;
    pub const BUS_EXCEPTION_COUNT: u16 = 0x0D;
    pub const SERVER_MESSAGE_COUNT: u16 = 0x0E;
    pub const SERVER_NO_RESPONSE_COUNT: u16 = 0x0F;
    pub const SERVER_NAK_COUNT: u16 = 0x10;
    pub const SERVER_BUSY_COUNT: u16 = 0x11;
    pub const BUS_CHAR_OVERRUN_COUNT: u16 = 0x12;
    pub const CLEAR_OVERRUN: u16 = 0x14;
}

/// Event byte bits.
pub mod event {
    pub const RECEIVE: u8 = 0x80;
    pub const RECEIVE_COMM_ERROR: u8 = 0x02;
    pub const RECEIVE_OVERRUN: u8 = 0x10;
    pub const RECEIVE_LISTEN_ONLY: u8 = 0x20;
    pub const RECEIVE_BROADCAST: u8 = 0x40;
    pub const SEND: u8 = 0x40;
    pub const SEND_READ_EXCEPTION: u8 = 0x01;
    pub const SEND_ABORT_EXCEPTION: u8 = 0x02;
    pub const SEND_BUSY_EXCEPTION: u8 = 0x04;
    pub const SEND_NAK_EXCEPTION: u8 = 0x08;
    pub const SEND_WRITE_TIMEOUT: u8 = 0x10;
    pub const SEND_LISTEN_ONLY: u8 = 0x20;
    pub const ENTERED_LISTEN_ONLY: u8 = 0x04;
    pub const COMMUNICATION_RESTART: u8 = 0x00;
}

/// Bit of the diagnostic register that reports the character overrun flag.
pub const REGISTER_OVERRUN_FLAG: u16 = 0x0001;

/// The ASCII input delimiter at power-up (LF).
pub const DEFAULT_ASCII_DELIMITER: u8 = b'\n';

/// How a request ended, as far as the line is concerned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Delivery {
    /// A response was written.
    Sent,
    /// A response was built but writing it failed.
    SendFailed,
    /// No response (broadcast, listen-only mode, a function answered with silence).
    NotSent,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Counter {
    BusMessage = 0,
    BusCommError,
    BusException,
    ServerMessage,
    NoResponse,
    Nak,
    Busy,
    CharOverrun,
}

/// The diagnostics state of one server context.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Diagnostics {
    /// Indexed by [`Counter`], i.e. by sub-function - 0x0B.
    counters: [u16; 8],
    event_counter: u16,
    /// `log[..log_len]`, newest first.
    log: [u8; EVENT_LOG_SIZE],
    log_len: usize,
    listen_only: bool,
    /// The application's bits of the diagnostic register.
    register: u16,
    overrun_flag: bool,
    ascii_delimiter: u8,
}

impl Default for Diagnostics {
    fn default() -> Self {
        Self::new()
    }
}

impl Diagnostics {
    /// The power-up state: every counter 0, an empty log, not in listen-only mode.
    pub const fn new() -> Self {
        Diagnostics {
            counters: [0; 8],
            event_counter: 0,
            log: [0; EVENT_LOG_SIZE],
            log_len: 0,
            listen_only: false,
            register: 0,
            overrun_flag: false,
            ascii_delimiter: DEFAULT_ASCII_DELIMITER,
        }
    }

    fn bump(&mut self, c: Counter) {
        let v = &mut self.counters[c as usize];
        *v = v.wrapping_add(1);
    }

    /// The value that diagnostics sub-function `sub_function` reports or concerns:
    /// 0x02 the diagnostic register, 0x03 the ASCII input delimiter, 0x04 1 in
    /// listen-only mode (else 0), 0x0B..=0x12 the counters. `None` for any other.
    pub fn get(&self, sub_function: u16) -> Option<u16> {
        match sub_function {
            sub::RETURN_DIAGNOSTIC_REGISTER => Some(self.register()),
            sub::CHANGE_ASCII_DELIMITER => Some(self.ascii_delimiter as u16),
            sub::FORCE_LISTEN_ONLY => Some(self.listen_only as u16),
            sub::BUS_MESSAGE_COUNT..=sub::BUS_CHAR_OVERRUN_COUNT => {
                Some(self.counters[(sub_function - sub::BUS_MESSAGE_COUNT) as usize])
            }
            _ => None,
        }
    }

    /// The communication event counter (FC 0B).
    pub fn event_counter(&self) -> u16 {
        self.event_counter
    }

    /// The message count of FC 0C (the bus message count).
    pub fn message_count(&self) -> u16 {
        self.counters[Counter::BusMessage as usize]
    }

    /// The event log, newest first.
    pub fn events(&self) -> &[u8] {
        &self.log[..self.log_len]
    }

    pub fn listen_only(&self) -> bool {
        self.listen_only
    }

    /// The diagnostic register: the application's bits, with bit 0 set while the
    /// character overrun flag is.
    pub fn register(&self) -> u16 {
        self.register | if self.overrun_flag { REGISTER_OVERRUN_FLAG } else { 0 }
    }

    /// Sets the application's bits of the diagnostic register.
    pub fn set_register(&mut self, value: u16) {
        self.register = value;
    }

    /// The ASCII input delimiter (sub-function 0x03; LF at power-up).
    pub fn ascii_delimiter(&self) -> u8 {
        self.ascii_delimiter
    }

    pub fn set_ascii_delimiter(&mut self, c: u8) {
        self.ascii_delimiter = c;
    }

    /// Stores an event byte as the newest one; the oldest falls off a full log.
    pub fn push_event(&mut self, e: u8) {
        self.log.copy_within(0..EVENT_LOG_SIZE - 1, 1);
        self.log[0] = e;
        self.log_len = (self.log_len + 1).min(EVENT_LOG_SIZE);
    }

    fn listen_only_bits(&self, bit: u8) -> u8 {
        if self.listen_only { bit } else { 0 }
    }

    // ------------------------------------------------------------ the bus (modbus_receive)

    /// A whole frame was read (good, for another slave, or a broadcast).
    pub fn frame_received(&mut self) {
        self.bump(Counter::BusMessage);
    }

    /// A frame with a bad checksum, or one that cannot be decoded.
    pub fn communication_error(&mut self) {
        self.bump(Counter::BusMessage);
        self.bump(Counter::BusCommError);
        let e = event::RECEIVE | event::RECEIVE_COMM_ERROR | self.listen_only_bits(event::RECEIVE_LISTEN_ONLY);
        self.push_event(e);
    }

    /// A frame that did not fit the receive buffer: counted, and the overrun flag set.
    pub fn character_overrun(&mut self) {
        self.bump(Counter::BusMessage);
        self.bump(Counter::CharOverrun);
        self.overrun_flag = true;
        let e = event::RECEIVE | event::RECEIVE_OVERRUN | self.listen_only_bits(event::RECEIVE_LISTEN_ONLY);
        self.push_event(e);
    }

    // ------------------------------------------------------------ requests (modbus_reply)

    /// A request reached the server (before it is processed).
    pub fn request_received(&mut self, broadcast: bool) {
        self.bump(Counter::ServerMessage);
        let mut e = event::RECEIVE | self.listen_only_bits(event::RECEIVE_LISTEN_ONLY);
        if broadcast {
            e |= event::RECEIVE_BROADCAST;
        }
        self.push_event(e);
    }

    /// A request is done. `exception` is the code sent (if any); `completed` says
    /// whether it counts as a completed message for the event counter (the caller
    /// passes false for FC 0B, 0C and for requests that failed without an answer).
    pub fn request_done(&mut self, exception: Option<u8>, delivery: Delivery, completed: bool) {
        let mut e = event::SEND | self.listen_only_bits(event::SEND_LISTEN_ONLY);
        match delivery {
            Delivery::NotSent => self.bump(Counter::NoResponse),
            Delivery::Sent | Delivery::SendFailed => {
                if delivery == Delivery::SendFailed {
                    e |= event::SEND_WRITE_TIMEOUT;
                }
                if let Some(code) = exception {
                    self.bump(Counter::BusException);
                    e |= match code {
                        1..=3 => event::SEND_READ_EXCEPTION,
                        4 => event::SEND_ABORT_EXCEPTION,
                        5 | 6 => event::SEND_BUSY_EXCEPTION,
                        7 => event::SEND_NAK_EXCEPTION,
                        _ => 0,
                    };
                    match code {
                        6 => self.bump(Counter::Busy),
                        7 => self.bump(Counter::Nak),
                        _ => {}
                    }
                }
            }
        }
        if exception.is_none() && completed && !self.listen_only {
            self.event_counter = self.event_counter.wrapping_add(1);
        }
        self.push_event(e);
    }

    /// Force Listen Only Mode took effect: the request got no answer; 0x04 is logged.
    pub fn enter_listen_only(&mut self) {
        self.bump(Counter::NoResponse);
        self.listen_only = true;
        self.push_event(event::ENTERED_LISTEN_ONLY);
    }

    /// Restart Communications Option: leaves listen-only mode, clears the counters
    /// and the event counter (and the log when `clear_log`), then logs 0x00.
    pub fn restart(&mut self, clear_log: bool) {
        self.listen_only = false;
        self.counters = [0; 8];
        self.event_counter = 0;
        self.overrun_flag = false;
        if clear_log {
            self.log_len = 0;
        }
        self.push_event(event::COMMUNICATION_RESTART);
    }

    /// Clear Counters and Diagnostic Register (sub-function 0x0A): every counter, the
    /// event counter and the register (the application's bits and the overrun flag).
    /// The event log stays.
    pub fn clear_counters(&mut self) {
        self.counters = [0; 8];
        self.event_counter = 0;
        self.register = 0;
        self.overrun_flag = false;
    }

    /// Clear Overrun Counter and Flag (sub-function 0x14).
    pub fn clear_overrun(&mut self) {
        self.counters[Counter::CharOverrun as usize] = 0;
        self.overrun_flag = false;
    }

    /// Test helper: a state as a long-running device would have it.
    #[cfg(test)]
    pub(crate) fn preset(&mut self, event_counter: u16, message_count: u16, events_newest_first: &[u8]) {
        self.event_counter = event_counter;
        self.counters[Counter::BusMessage as usize] = message_count;
        self.log_len = 0;
        for &e in events_newest_first.iter().rev() {
            self.push_event(e);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn counters(d: &Diagnostics) -> Vec<u16> {
        (0x0B..=0x12).map(|s| d.get(s).unwrap()).collect()
    }

    #[test]
    fn power_up_state() {
        let d = Diagnostics::new();
        assert_eq!(counters(&d), [0; 8]);
        assert_eq!((d.event_counter(), d.message_count(), d.events().len()), (0, 0, 0));
        assert_eq!(d.get(2), Some(0));
        assert_eq!(d.get(3), Some(b'\n' as u16));
        assert_eq!(d.get(4), Some(0));
        for s in [0, 1, 5, 9, 0x0A, 0x13, 0x14, 0xFFFF] {
            assert_eq!(d.get(s), None, "{s}");
        }
    }

    #[test]
    fn a_normal_exchange() {
        let mut d = Diagnostics::new();
        d.frame_received();
        d.request_received(false);
        d.request_done(None, Delivery::Sent, true);
        assert_eq!(counters(&d), [1, 0, 0, 1, 0, 0, 0, 0]);
        assert_eq!(d.event_counter(), 1);
        assert_eq!(d.events(), [0x40, 0x80]);
        // Not counted as a completion (FC 0B / 0C).
        d.frame_received();
        d.request_received(false);
        d.request_done(None, Delivery::Sent, false);
        assert_eq!(d.event_counter(), 1);
        assert_eq!(d.message_count(), 2);
    }

    #[test]
    fn exceptions_by_code() {
        let mut d = Diagnostics::new();
        let mut sent = Vec::new();
        for code in 1..=11u8 {
            d.request_received(false);
            d.request_done(Some(code), Delivery::Sent, true);
            sent.push(d.events()[0]);
        }
        assert_eq!(sent, [0x41, 0x41, 0x41, 0x42, 0x44, 0x44, 0x48, 0x40, 0x40, 0x40, 0x40]);
        assert_eq!(counters(&d), [0, 0, 11, 11, 0, 1, 1, 0]);
        assert_eq!(d.event_counter(), 0);
        // A failed write: the timeout bit; still an exception returned.
        d.request_received(false);
        d.request_done(Some(2), Delivery::SendFailed, true);
        assert_eq!(d.events()[0], 0x51);
        assert_eq!(d.get(0x0D), Some(12));
        // A successful request whose answer could not be written still completed.
        d.request_done(None, Delivery::SendFailed, true);
        assert_eq!(d.events()[0], 0x50);
        assert_eq!(d.event_counter(), 1);
    }

    #[test]
    fn no_response_and_broadcast() {
        let mut d = Diagnostics::new();
        d.request_received(true);
        d.request_done(None, Delivery::NotSent, true);
        assert_eq!(d.events(), [0x40, 0xC0]);
        assert_eq!(d.get(0x0F), Some(1));
        // A broadcast write completed: counted as an event.
        assert_eq!(d.event_counter(), 1);
        // An exception that was not sent is not an exception returned.
        d.request_received(true);
        d.request_done(Some(2), Delivery::NotSent, true);
        assert_eq!((d.get(0x0D), d.get(0x0F), d.event_counter()), (Some(0), Some(2), 1));
    }

    #[test]
    fn bus_errors() {
        let mut d = Diagnostics::new();
        d.communication_error();
        d.character_overrun();
        assert_eq!(counters(&d), [2, 1, 0, 0, 0, 0, 0, 1]);
        assert_eq!(d.events(), [0x90, 0x82]);
        assert_eq!(d.register(), 1);
        d.set_register(0x8000);
        assert_eq!(d.get(2), Some(0x8001));
        d.clear_overrun();
        assert_eq!((d.get(0x12), d.get(2), d.get(0x0C)), (Some(0), Some(0x8000), Some(1)));
        d.character_overrun();
        d.clear_counters();
        assert_eq!(counters(&d), [0; 8]);
        assert_eq!(d.get(2), Some(0));
        assert_eq!(d.events().len(), 3);
    }

    #[test]
    fn listen_only_and_restart() {
        let mut d = Diagnostics::new();
        d.request_received(false);
        d.request_done(None, Delivery::Sent, true);
        d.request_received(false);
        d.enter_listen_only();
        assert!(d.listen_only());
        assert_eq!(d.get(4), Some(1));
        assert_eq!(d.events(), [0x04, 0x80, 0x40, 0x80]);
        // Requests in listen-only mode: flagged, not answered, not completed.
        d.communication_error();
        d.request_received(true);
        d.request_done(None, Delivery::NotSent, true);
        assert_eq!(d.events()[..3], [0x60, 0xE0, 0xA2]);
        assert_eq!(d.event_counter(), 1);
        assert_eq!(d.get(0x0F), Some(2));
        // Restart without clearing the log.
        d.request_received(false);
        d.restart(false);
        assert!(!d.listen_only());
        assert_eq!(counters(&d), [0; 8]);
        assert_eq!(d.event_counter(), 0);
        assert_eq!(d.events()[..2], [0x00, 0xA0]);
        assert_eq!(d.events().len(), 9);
        // And with.
        d.restart(true);
        assert_eq!(d.events(), [0x00]);
    }

    #[test]
    fn log_keeps_the_newest_64_and_counters_wrap() {
        let mut d = Diagnostics::new();
        for i in 0..200u32 {
            d.push_event(i as u8);
        }
        assert_eq!(d.events().len(), 64);
        assert_eq!(d.events()[0], 199);
        assert_eq!(d.events()[63], 136);
        for _ in 0..65537 {
            d.frame_received();
        }
        assert_eq!(d.message_count(), 1);
    }
}
