//! The server side of the function codes libmodbus does not serve: 07 (read
//! exception status), 08 (diagnostics), 0B/0C (comm event counter and log), 14/15
//! (file records), 18 (FIFO queue), 2B/0E (read device identification), and a
//! configurable answer to 11 (report slave id).
//!
//! One [`ServerExt`] hangs off a context (`Context::server_ext`), created by the
//! first configuration call (`modbus_set_exception_status`,
//! `modbus_enable_diagnostics`, `modbus_set_device_identification`, ...). Everything
//! it serves is copied in: no pointer into the application's memory is kept. A
//! context without one (the default) is exactly libmodbus: `modbus_reply` never
//! reaches this module. With one, a request for something that was not configured
//! still gets libmodbus's answer (ILLEGAL FUNCTION after the flush, FC 07 silent
//! with ENOPROTOOPT).
//!
//! Framing: `Context::serves_extended` (one flag for the whole context) is set while
//! diagnostics, device identification, files or FIFO queues are configured, so that
//! requests of 08, 14, 15, 18 and 2B are read whole. On such a context a request
//! for one of those codes that is *not* configured is read whole too, then answered
//! with libmodbus' ILLEGAL FUNCTION (after the same flush); libmodbus itself would
//! have read it only up to the function code. Contexts without any configuration
//! are not affected.
//!
//! Pure logic, like `core::reply`: the request is a byte slice, the answer is
//! written into an ADU buffer, and the caller (the library's `server` module) does the I/O,
//! then reports how it went with [`ServerExt::complete`] so that the diagnostics
//! counters and the event log follow what really happened on the line.
//!
//! Every request is parsed against its exact length: a field past the end, a
//! count that disagrees with the bytes present, or a PDU longer than its layout is
//! ILLEGAL DATA VALUE; nothing is read outside the request or written outside the
//! 253-byte PDU.

use std::collections::BTreeMap;

use crate::diagnostics::{Delivery, Diagnostics, sub};
use crate::error::{Error, Result, exception};
use crate::frame::{Framing, MAX_ADU_LENGTH, MEI_READ_DEVICE_ID};
use crate::limits::{BROADCAST_ADDRESS, MAX_PDU_LENGTH};
use crate::reply::{Data, Outcome, QUIRK_REPLY_TO_BROADCAST, SILENT, Server, exception_response, pdu as pdu_of};
use crate::{Diag, fc};

/// Records per file: numbers 0..=9999.
pub const MAX_FILE_RECORDS: usize = 10_000;
/// The only reference type of file record sub-requests.
pub const FILE_REFERENCE_TYPE: u8 = 6;
/// Most values a FIFO queue read returns; a longer queue gets ILLEGAL DATA VALUE.
pub const MAX_FIFO_COUNT: usize = 31;
/// Longest value a FIFO queue may be configured with.
pub const MAX_FIFO_CONFIGURED: usize = 0xFFFF;
/// Longest device identification object: it must fit one response on its own
/// (253-byte PDU - 7 header bytes - object id - object length).
pub const MAX_OBJECT_LENGTH: usize = MAX_PDU_LENGTH - 9;
/// Longest additional data of a report slave id answer (PDU - fc, count, id, run).
pub const MAX_SLAVE_ID_DATA: usize = MAX_PDU_LENGTH - 4;

/// Conformity levels a server may declare (0 = derived from the objects).
pub const CONFORMITY_LEVELS: [u8; 6] = [0x01, 0x02, 0x03, 0x81, 0x82, 0x83];

/// What happens after the response went out (or would have).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum After {
    Nothing,
    /// Restart Communications Option: leave listen-only mode, clear the counters
    /// (and the event log when asked).
    Restart {
        clear_log: bool,
    },
    /// Force Listen Only Mode.
    EnterListenOnly,
    /// Clear Counters and Diagnostic Register.
    ClearCounters,
    /// Clear Overrun Counter and Flag.
    ClearOverrun,
}

/// The answer to one request: what to send (as `core::reply` would say it), and
/// what to do once it is sent.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Answer {
    pub outcome: Outcome,
    pub after: After,
    /// Counts as a completed message for the comm event counter if it ends without
    /// an exception (false for FC 0B, 0C and in listen-only mode).
    pub completed: bool,
}

/// What `modbus_receive` saw, for the bus counters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BusEvent {
    /// A whole frame (for us, a broadcast, or for another slave).
    Frame,
    /// A frame with a bad CRC/LRC, or an ASCII frame that cannot be decoded.
    CommunicationError,
    /// A frame longer than the receive buffer.
    CharacterOverrun,
}

#[derive(Clone, Debug, PartialEq, Eq)]
struct SlaveId {
    id: u8,
    run: bool,
    data: Vec<u8>,
}

/// Server-side configuration and state beyond libmodbus, per context.
#[derive(Clone, Debug, Default)]
pub struct ServerExt {
    exception_status: Option<u8>,
    slave_id: Option<SlaveId>,
    /// Device identification objects by id; basic objects 0..=2 read as empty when
    /// unset. Device identification is served while this is not empty.
    objects: BTreeMap<u8, Vec<u8>>,
    /// Declared conformity level, 0 for "derived from the objects".
    conformity: u8,
    files: BTreeMap<u16, Vec<u16>>,
    fifos: BTreeMap<u16, Vec<u16>>,
    diag: Option<Diagnostics>,
}

fn be16(b: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([b[at], b[at + 1]])
}

fn put16(out: &mut [u8], at: usize, v: u16) {
    out[at..at + 2].copy_from_slice(&v.to_be_bytes());
}

/// `Some(clear_log)` for a well-formed Restart Communications Option request.
fn restart_request(pdu: &[u8]) -> Option<bool> {
    if pdu.len() != 5 || pdu[0] != fc::DIAGNOSTICS || be16(pdu, 1) != sub::RESTART_COMMUNICATIONS {
        return None;
    }
    match be16(pdu, 3) {
        0x0000 => Some(false),
        0xFF00 => Some(true),
        _ => None,
    }
}

/// The category of a device identification object: 1 basic, 2 regular, 3 extended.
fn category(id: u8) -> u8 {
    match id {
        0x00..=0x02 => 1,
        0x03..=0x7F => 2,
        _ => 3,
    }
}

/// A response PDU written at the start of the body, or silence.
enum Handled {
    Pdu(usize, After),
    Silent(After),
}

type Handler = std::result::Result<Handled, u8>;

/// Prints the reason of an exception (stderr side of the debug sink) and returns it.
fn refuse(diag: &mut dyn Diag, code: u8, args: std::fmt::Arguments<'_>) -> Handler {
    diag.err(args);
    Err(code)
}

impl ServerExt {
    pub fn new() -> Self {
        Self::default()
    }

    // ------------------------------------------------------------ configuration

    /// True when nothing is configured (the context can drop it).
    pub fn is_idle(&self) -> bool {
        self.exception_status.is_none()
            && self.slave_id.is_none()
            && self.objects.is_empty()
            && self.conformity == 0
            && self.files.is_empty()
            && self.fifos.is_empty()
            && self.diag.is_none()
    }

    /// Requests of function codes 08, 14, 15, 18 or 2B must be framed whole
    /// (`Context::serves_extended`).
    pub fn needs_extended_framing(&self) -> bool {
        self.diag.is_some() || !self.objects.is_empty() || !self.files.is_empty() || !self.fifos.is_empty()
    }

    /// FC 07: `Some(status)` answers it, `None` restores libmodbus's silence.
    pub fn set_exception_status(&mut self, status: Option<u8>) {
        self.exception_status = status;
    }

    /// FC 11: `Some((id, run, data))` answers `[id][0xFF or 0x00][data]`, `None`
    /// restores libmodbus's "LMB<version>" answer.
    pub fn set_report_slave_id(&mut self, answer: Option<(u8, bool, &[u8])>) -> Result<()> {
        self.slave_id = match answer {
            Some((_, _, data)) if data.len() > MAX_SLAVE_ID_DATA => return Err(Error::INVALID),
            Some((id, run, data)) => Some(SlaveId { id, run, data: data.to_vec() }),
            None => None,
        };
        Ok(())
    }

    /// Sets (`Some`) or removes (`None`) device identification object `id`.
    /// Objects 0x07..=0x7F are reserved by the protocol; values are at most
    /// [`MAX_OBJECT_LENGTH`] bytes.
    pub fn set_device_identification(&mut self, id: i32, value: Option<&[u8]>) -> Result<()> {
        let id = match u8::try_from(id) {
            Ok(id) if !(0x07..=0x7F).contains(&id) => id,
            _ => return Err(Error::INVALID),
        };
        match value {
            Some(v) if v.len() > MAX_OBJECT_LENGTH => return Err(Error::INVALID),
            Some(v) => {
                self.objects.insert(id, v.to_vec());
            }
            None => {
                self.objects.remove(&id);
            }
        }
        Ok(())
    }

    /// Declares the conformity level (one of [`CONFORMITY_LEVELS`]), or 0 to derive
    /// it from the objects.
    pub fn set_conformity_level(&mut self, level: i32) -> Result<()> {
        match u8::try_from(level) {
            Ok(l) if l == 0 || CONFORMITY_LEVELS.contains(&l) => {
                self.conformity = l;
                Ok(())
            }
            _ => Err(Error::INVALID),
        }
    }

    /// The conformity level answered: the declared one, else 0x81 (basic objects
    /// only), 0x82 (regular objects too) or 0x83 (extended objects too); individual
    /// access is always supported then.
    pub fn conformity_level(&self) -> u8 {
        if self.conformity != 0 {
            return self.conformity;
        }
        match self.objects.keys().next_back() {
            Some(&id) => 0x80 | category(id),
            None => 0x81,
        }
    }

    /// Writes `values` (or `nb` zeros when `None`) into file `file` from record
    /// `record`, creating the file or growing it to `record + nb` records.
    pub fn set_file_record(&mut self, file: i32, record: i32, nb: i32, values: Option<&[u16]>) -> Result<()> {
        let (file, first, nb) = Self::file_args(file, record, nb)?;
        if values.is_some_and(|v| v.len() != nb) {
            return Err(Error::INVALID);
        }
        let records = self.files.entry(file).or_default();
        if records.len() < first + nb {
            records.resize(first + nb, 0);
        }
        match values {
            Some(v) => records[first..first + nb].copy_from_slice(v),
            None => records[first..first + nb].fill(0),
        }
        Ok(())
    }

    /// Copies `dest.len()` records of file `file` from record `record`.
    pub fn get_file_record(&self, file: i32, record: i32, dest: &mut [u16]) -> Result<()> {
        let (file, first, nb) = Self::file_args(file, record, dest.len() as i32)?;
        let records = self.files.get(&file).ok_or(Error::INVALID)?;
        let part = records.get(first..first + nb).ok_or(Error::INVALID)?;
        dest.copy_from_slice(part);
        Ok(())
    }

    fn file_args(file: i32, record: i32, nb: i32) -> Result<(u16, usize, usize)> {
        let max = MAX_FILE_RECORDS as i64;
        if !(1..=0xFFFF).contains(&file) || !(0..max).contains(&(record as i64)) || nb < 1 {
            return Err(Error::INVALID);
        }
        if record as i64 + nb as i64 > max {
            return Err(Error::INVALID);
        }
        Ok((file as u16, record as usize, nb as usize))
    }

    /// Sets the FIFO queue read at pointer address `addr` (a copy of `values`).
    pub fn set_fifo_queue(&mut self, addr: i32, values: &[u16]) -> Result<()> {
        if !(0..=0xFFFF).contains(&addr) || values.len() > MAX_FIFO_CONFIGURED {
            return Err(Error::INVALID);
        }
        self.fifos.insert(addr as u16, values.to_vec());
        Ok(())
    }

    /// Turns diagnostics (counting, FC 08, 0B, 0C) on from the power-up state, or off.
    pub fn enable_diagnostics(&mut self, on: bool) {
        match (on, self.diag.is_some()) {
            (true, false) => self.diag = Some(Diagnostics::new()),
            (false, _) => self.diag = None,
            (true, true) => {}
        }
    }

    pub fn diagnostics(&self) -> Option<&Diagnostics> {
        self.diag.as_ref()
    }

    pub fn diagnostics_mut(&mut self) -> Option<&mut Diagnostics> {
        self.diag.as_mut()
    }

    // ------------------------------------------------------------ the line

    /// Counts what `modbus_receive` saw (diagnostics only).
    pub fn bus_event(&mut self, e: BusEvent) {
        if let Some(d) = self.diag.as_mut() {
            match e {
                BusEvent::Frame => d.frame_received(),
                BusEvent::CommunicationError => d.communication_error(),
                BusEvent::CharacterOverrun => d.character_overrun(),
            }
        }
    }

    /// `modbus_reply_exception` is about to answer a request: counts it. Returns
    /// false in listen-only mode, where nothing may be sent; the caller then reports
    /// [`Delivery::NotSent`] to [`ServerExt::exception_done`].
    pub fn exception_request(&mut self, framing: Framing, req: &[u8]) -> bool {
        let Some(d) = self.diag.as_mut() else { return true };
        let h = framing.header_length();
        let broadcast = framing.is_serial() && req.get(h - 1) == Some(&0);
        d.request_received(broadcast);
        !d.listen_only()
    }

    /// The end of a `modbus_reply_exception`.
    pub fn exception_done(&mut self, code: u8, delivery: Delivery) {
        if let Some(d) = self.diag.as_mut() {
            d.request_done(Some(code), delivery, false);
        }
    }

    /// The end of a `modbus_reply`: counts the result and performs the actions
    /// that follow the response (restart, listen-only mode, clears).
    pub fn complete(&mut self, answer: &Answer, delivery: Delivery) {
        let Some(d) = self.diag.as_mut() else { return };
        match answer.after {
            After::EnterListenOnly => d.enter_listen_only(),
            After::Restart { clear_log } => d.restart(clear_log),
            after => {
                let (exception, failed) = match answer.outcome {
                    Outcome::Respond { exception, .. } => (exception, false),
                    Outcome::Fail(_) => (None, true),
                };
                d.request_done(exception, delivery, answer.completed && !failed);
                match after {
                    After::ClearCounters => d.clear_counters(),
                    After::ClearOverrun => d.clear_overrun(),
                    _ => {}
                }
            }
        }
    }

    // ------------------------------------------------------------ modbus_reply

    /// Answers `req` (see `core::reply::request_extent`): the configured function
    /// codes here, everything else through `server.answer` (libmodbus's answers, from
    /// `data`). In listen-only mode nothing is processed or sent.
    pub fn reply(
        &mut self,
        server: Server,
        req: &[u8],
        req_length: i32,
        data: &mut dyn Data,
        diag: &mut dyn Diag,
        out: &mut [u8; MAX_ADU_LENGTH],
    ) -> Answer {
        let framing = server.framing;
        let h = framing.header_length();
        let slave = req.get(h - 1).copied().unwrap_or(0);
        let function = req.get(h).copied().unwrap_or(0);
        let pdu = pdu_of(framing, req);
        let broadcast = framing.is_serial() && slave as i32 == BROADCAST_ADDRESS;

        if let Some(d) = self.diag.as_mut() {
            d.request_received(broadcast);
            if d.listen_only() {
                // Only Restart Communications Option is heard, and not answered.
                let after = match restart_request(pdu) {
                    Some(clear_log) => After::Restart { clear_log },
                    None => After::Nothing,
                };
                return Answer { outcome: SILENT, after, completed: false };
            }
        }

        let diag_on = self.diag.is_some();
        let served = match function {
            fc::READ_EXCEPTION_STATUS => self.exception_status.is_some(),
            fc::DIAGNOSTICS | fc::GET_COMM_EVENT_COUNTER | fc::GET_COMM_EVENT_LOG => diag_on,
            fc::REPORT_SLAVE_ID => self.slave_id.is_some(),
            fc::READ_FILE_RECORD | fc::WRITE_FILE_RECORD => !self.files.is_empty(),
            fc::READ_FIFO_QUEUE => !self.fifos.is_empty(),
            fc::ENCAPSULATED_INTERFACE => !self.objects.is_empty(),
            _ => false,
        };
        if !served {
            let outcome = server.answer(req, req_length, data, diag, out);
            return Answer { outcome, after: After::Nothing, completed: true };
        }

        let completed = !matches!(function, fc::GET_COMM_EVENT_COUNTER | fc::GET_COMM_EVENT_LOG);
        let handled = if pdu.len() > MAX_PDU_LENGTH {
            refuse(diag, exception::ILLEGAL_DATA_VALUE, format_args!("Request too long ({} bytes)\n", pdu.len()))
        } else {
            let body = &mut out[h..h + MAX_PDU_LENGTH];
            match function {
                fc::READ_EXCEPTION_STATUS => self.read_exception_status(pdu, body, diag),
                fc::DIAGNOSTICS => self.diagnostics_reply(pdu, body, diag),
                fc::GET_COMM_EVENT_COUNTER => self.comm_event_counter(pdu, body, diag),
                fc::GET_COMM_EVENT_LOG => self.comm_event_log(pdu, body, diag),
                fc::REPORT_SLAVE_ID => self.report_slave_id(body),
                fc::READ_FILE_RECORD => self.read_file_record(pdu, body, diag),
                fc::WRITE_FILE_RECORD => self.write_file_record(pdu, body, diag),
                fc::READ_FIFO_QUEUE => self.read_fifo_queue(pdu, body, diag),
                _ => self.device_identification(pdu, body, diag),
            }
        };
        let suppressed = broadcast && server.quirks & QUIRK_REPLY_TO_BROADCAST == 0;
        let (outcome, after) = match handled {
            Ok(Handled::Pdu(len, after)) => {
                framing.write_header(out, slave, framing.response_tid(req));
                (Outcome::Respond { len: h + len, exception: None, flush_first: false, suppressed }, after)
            }
            Ok(Handled::Silent(after)) => (SILENT, after),
            Err(code) => {
                let len = exception_response(framing, req, code, out);
                (Outcome::Respond { len, exception: Some(code), flush_first: false, suppressed }, After::Nothing)
            }
        };
        Answer { outcome, after, completed }
    }

    fn read_exception_status(&self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        if pdu.len() != 1 {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Invalid length in read_exception_status\n"),
            );
        }
        body[0] = fc::READ_EXCEPTION_STATUS;
        body[1] = self.exception_status.unwrap_or(0);
        Ok(Handled::Pdu(2, After::Nothing))
    }

    fn report_slave_id(&self, body: &mut [u8]) -> Handler {
        let Some(s) = &self.slave_id else { return Err(exception::ILLEGAL_FUNCTION) };
        body[0] = fc::REPORT_SLAVE_ID;
        body[1] = (2 + s.data.len()) as u8;
        body[2] = s.id;
        body[3] = if s.run { 0xFF } else { 0x00 };
        body[4..4 + s.data.len()].copy_from_slice(&s.data);
        Ok(Handled::Pdu(4 + s.data.len(), After::Nothing))
    }

    fn diagnostics_reply(&mut self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        let Some(d) = self.diag.as_mut() else { return Err(exception::ILLEGAL_FUNCTION) };
        if pdu.len() < 3 {
            return refuse(diag, exception::ILLEGAL_DATA_VALUE, format_args!("Invalid length in diagnostics\n"));
        }
        let sub_function = be16(pdu, 1);
        let data = &pdu[3..];
        let word = if data.len() == 2 { Some(be16(data, 0)) } else { None };
        let echo = |body: &mut [u8], after: After| {
            body[..pdu.len()].copy_from_slice(pdu);
            Ok(Handled::Pdu(pdu.len(), after))
        };
        let bad_data = |diag: &mut dyn Diag| {
            refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Illegal data in diagnostics sub-function 0x{sub_function:X}\n"),
            )
        };
        match sub_function {
            sub::RETURN_QUERY_DATA if data.len() % 2 == 0 => echo(body, After::Nothing),
            sub::RESTART_COMMUNICATIONS => match restart_request(pdu) {
                Some(clear_log) => echo(body, After::Restart { clear_log }),
                None => bad_data(diag),
            },
            sub::CHANGE_ASCII_DELIMITER => match data {
                [c, 0] if !matches!(c, b':' | b'\r' | b'0'..=b'9' | b'A'..=b'F' | b'a'..=b'f') => {
                    d.set_ascii_delimiter(*c);
                    echo(body, After::Nothing)
                }
                _ => bad_data(diag),
            },
            sub::FORCE_LISTEN_ONLY if word == Some(0) => Ok(Handled::Silent(After::EnterListenOnly)),
            sub::CLEAR_COUNTERS if word == Some(0) => echo(body, After::ClearCounters),
            sub::CLEAR_OVERRUN if word == Some(0) => echo(body, After::ClearOverrun),
            sub::RETURN_DIAGNOSTIC_REGISTER | sub::BUS_MESSAGE_COUNT..=sub::BUS_CHAR_OVERRUN_COUNT
                if word == Some(0) =>
            {
                let value = d.get(sub_function).unwrap_or(0);
                body[..3].copy_from_slice(&pdu[..3]);
                put16(body, 3, value);
                Ok(Handled::Pdu(5, After::Nothing))
            }
            sub::RETURN_QUERY_DATA
            | sub::RETURN_DIAGNOSTIC_REGISTER
            | sub::FORCE_LISTEN_ONLY
            | sub::CLEAR_COUNTERS
            | sub::BUS_MESSAGE_COUNT..=sub::BUS_CHAR_OVERRUN_COUNT
            | sub::CLEAR_OVERRUN => bad_data(diag),
            _ => refuse(
                diag,
                exception::ILLEGAL_FUNCTION,
                format_args!("Unknown diagnostics sub-function 0x{sub_function:X}\n"),
            ),
        }
    }

    fn comm_event_counter(&self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        let Some(d) = self.diag.as_ref() else { return Err(exception::ILLEGAL_FUNCTION) };
        if pdu.len() != 1 {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Invalid length in get_comm_event_counter\n"),
            );
        }
        body[0] = fc::GET_COMM_EVENT_COUNTER;
        put16(body, 1, 0x0000); // never busy: one request at a time
        put16(body, 3, d.event_counter());
        Ok(Handled::Pdu(5, After::Nothing))
    }

    fn comm_event_log(&self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        let Some(d) = self.diag.as_ref() else { return Err(exception::ILLEGAL_FUNCTION) };
        if pdu.len() != 1 {
            return refuse(diag, exception::ILLEGAL_DATA_VALUE, format_args!("Invalid length in get_comm_event_log\n"));
        }
        let events = d.events();
        body[0] = fc::GET_COMM_EVENT_LOG;
        body[1] = (6 + events.len()) as u8;
        put16(body, 2, 0x0000);
        put16(body, 4, d.event_counter());
        put16(body, 6, d.message_count());
        body[8..8 + events.len()].copy_from_slice(events);
        Ok(Handled::Pdu(8 + events.len(), After::Nothing))
    }

    /// One sub-request: (reference type, file, first record, number of records).
    fn file_sub_request(s: &[u8]) -> (u8, u16, u16, u16) {
        (s[0], be16(s, 1), be16(s, 3), be16(s, 5))
    }

    /// The records a sub-request names, or why not (ILLEGAL DATA ADDRESS).
    fn file_range(&self, s: &[u8], diag: &mut dyn Diag, name: &str) -> std::result::Result<(u16, usize, usize), u8> {
        let (reference, file, record, nb) = Self::file_sub_request(s);
        let size = self.files.get(&file).map_or(0, Vec::len);
        if reference != FILE_REFERENCE_TYPE
            || (record as usize) >= MAX_FILE_RECORDS
            || record as usize + nb as usize > size
        {
            diag.err(format_args!(
                "Illegal file record (reference {reference}, file {file}, record {record}, {nb} records) in {name}\n"
            ));
            return Err(exception::ILLEGAL_DATA_ADDRESS);
        }
        Ok((file, record as usize, nb as usize))
    }

    fn read_file_record(&self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        let byte_count = pdu.get(1).copied().unwrap_or(0) as usize;
        if !(7..=0xF5).contains(&byte_count) || byte_count % 7 != 0 || pdu.len() != 2 + byte_count {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Illegal byte count {byte_count} in read_file_record\n"),
            );
        }
        let subs = pdu[2..].chunks_exact(7);
        // Lengths first: each sub-request at least one record, the answer one PDU.
        let mut total = 2usize;
        for s in subs.clone() {
            let nb = be16(s, 5) as usize;
            total += 2 + 2 * nb;
            if nb == 0 || total > MAX_PDU_LENGTH {
                return refuse(
                    diag,
                    exception::ILLEGAL_DATA_VALUE,
                    format_args!("Illegal record length {nb} in read_file_record\n"),
                );
            }
        }
        for s in subs.clone() {
            self.file_range(s, diag, "read_file_record")?;
        }
        body[0] = fc::READ_FILE_RECORD;
        body[1] = (total - 2) as u8;
        let mut pos = 2;
        for s in subs {
            let (file, first, nb) = self.file_range(s, diag, "read_file_record")?;
            body[pos] = (1 + 2 * nb) as u8;
            body[pos + 1] = FILE_REFERENCE_TYPE;
            pos += 2;
            for &v in &self.files[&file][first..first + nb] {
                put16(body, pos, v);
                pos += 2;
            }
        }
        Ok(Handled::Pdu(pos, After::Nothing))
    }

    fn write_file_record(&mut self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        let data_length = pdu.get(1).copied().unwrap_or(0) as usize;
        let bad_length = |diag: &mut dyn Diag, what: std::fmt::Arguments<'_>| {
            refuse(diag, exception::ILLEGAL_DATA_VALUE, format_args!("Illegal {what} in write_file_record\n"))
        };
        if !(9..=0xFB).contains(&data_length) || pdu.len() != 2 + data_length {
            return bad_length(diag, format_args!("request data length {data_length}"));
        }
        // The sub-requests, each followed by its data, must fill the request exactly.
        let mut spans = Vec::new();
        let mut pos = 2;
        while pos < pdu.len() {
            if pos + 7 > pdu.len() {
                return bad_length(diag, format_args!("sub-request at byte {pos}"));
            }
            let nb = be16(pdu, pos + 5) as usize;
            let end = pos + 7 + 2 * nb;
            if nb == 0 || end > pdu.len() {
                return bad_length(diag, format_args!("record length {nb}"));
            }
            spans.push(pos..end);
            pos = end;
        }
        for span in &spans {
            self.file_range(&pdu[span.clone()], diag, "write_file_record")?;
        }
        for span in spans {
            let s = &pdu[span];
            let (file, first, nb) = self.file_range(s, diag, "write_file_record")?;
            let Some(records) = self.files.get_mut(&file) else { return Err(exception::ILLEGAL_DATA_ADDRESS) };
            for (k, r) in records[first..first + nb].iter_mut().enumerate() {
                *r = be16(s, 7 + 2 * k);
            }
        }
        body[..pdu.len()].copy_from_slice(pdu);
        Ok(Handled::Pdu(pdu.len(), After::Nothing))
    }

    fn read_fifo_queue(&self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        if pdu.len() != 3 {
            return refuse(diag, exception::ILLEGAL_DATA_VALUE, format_args!("Invalid length in read_fifo_queue\n"));
        }
        let addr = be16(pdu, 1);
        let Some(queue) = self.fifos.get(&addr) else {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_ADDRESS,
                format_args!("Illegal FIFO pointer address 0x{addr:X} in read_fifo_queue\n"),
            );
        };
        if queue.len() > MAX_FIFO_COUNT {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("FIFO queue 0x{addr:X} holds {} values (max {MAX_FIFO_COUNT})\n", queue.len()),
            );
        }
        body[0] = fc::READ_FIFO_QUEUE;
        put16(body, 1, (2 + 2 * queue.len()) as u16);
        put16(body, 3, queue.len() as u16);
        for (k, &v) in queue.iter().enumerate() {
            put16(body, 5 + 2 * k, v);
        }
        Ok(Handled::Pdu(5 + 2 * queue.len(), After::Nothing))
    }

    /// The value of object `id` as served: basic objects always exist.
    fn object(&self, id: u8) -> Option<&[u8]> {
        match self.objects.get(&id) {
            Some(v) => Some(v),
            None if category(id) == 1 => Some(&[]),
            None => None,
        }
    }

    fn device_identification(&self, pdu: &[u8], body: &mut [u8], diag: &mut dyn Diag) -> Handler {
        if pdu.len() < 2 {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Invalid length in encapsulated interface\n"),
            );
        }
        if pdu[1] != MEI_READ_DEVICE_ID {
            return refuse(diag, exception::ILLEGAL_FUNCTION, format_args!("Unsupported MEI type 0x{:X}\n", pdu[1]));
        }
        if pdu.len() != 4 {
            return refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Invalid length in read_device_identification\n"),
            );
        }
        let (code, id) = (pdu[2], pdu[3]);
        let level = self.conformity_level();
        let level_category = level & 0x7F;
        let header = |body: &mut [u8], more: bool, next: u8, count: u8| {
            body[..7].copy_from_slice(&[
                fc::ENCAPSULATED_INTERFACE,
                MEI_READ_DEVICE_ID,
                code,
                level,
                if more { 0xFF } else { 0x00 },
                next,
                count,
            ]);
        };
        match code {
            1..=3 => {
                // Objects of the categories up to the one asked for, as far as the
                // device conforms; an unknown starting id restarts at object 0.
                let limit = code.min(level_category);
                let ids: Vec<u8> =
                    (0..=2u8).chain(self.objects.keys().copied().filter(|&k| k > 2 && category(k) <= limit)).collect();
                let start = ids.iter().position(|&k| k == id).unwrap_or(0);
                let mut pos = 7;
                let mut count = 0u8;
                let mut next = None;
                for &k in &ids[start..] {
                    let value = self.object(k).unwrap_or(&[]);
                    if pos + 2 + value.len() > MAX_PDU_LENGTH {
                        next = Some(k);
                        break;
                    }
                    body[pos] = k;
                    body[pos + 1] = value.len() as u8;
                    body[pos + 2..pos + 2 + value.len()].copy_from_slice(value);
                    pos += 2 + value.len();
                    count += 1;
                }
                header(body, next.is_some(), next.unwrap_or(0), count);
                Ok(Handled::Pdu(pos, After::Nothing))
            }
            4 => {
                if level & 0x80 == 0 {
                    return refuse(
                        diag,
                        exception::ILLEGAL_DATA_VALUE,
                        format_args!("Individual access not supported (conformity level 0x{level:02X})\n"),
                    );
                }
                let value = match self.object(id) {
                    Some(v) if category(id) <= level_category => v,
                    _ => {
                        return refuse(
                            diag,
                            exception::ILLEGAL_DATA_ADDRESS,
                            format_args!("Unknown device identification object 0x{id:X}\n"),
                        );
                    }
                };
                header(body, false, 0, 1);
                body[7] = id;
                body[8] = value.len() as u8;
                body[9..9 + value.len()].copy_from_slice(value);
                Ok(Handled::Pdu(9 + value.len(), After::Nothing))
            }
            _ => refuse(
                diag,
                exception::ILLEGAL_DATA_VALUE,
                format_args!("Illegal read device id code {code} in read_device_identification\n"),
            ),
        }
    }
}

#[cfg(test)]
#[path = "server_ext_tests.rs"]
mod tests;
