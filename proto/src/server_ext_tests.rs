//! Unit tests of [`crate::server_ext`]: every function code and diagnostics
//! sub-function, the seed documents' frame examples, and malformed requests of every
//! shape (short, long, wrong counts, out of range).

use super::*;
use crate::Recorded;
use crate::ascii::lrc;
use crate::crc::crc16;
use crate::reply::{MappingData, Table, Tables};

const T: Framing = Framing::Tcp;
const R: Framing = Framing::Rtu;
const A: Framing = Framing::Ascii;

/// A request ADU: TCP with TID 0x1234 and the MBAP length a client sends, RTU with
/// its CRC, ASCII (decoded) with its LRC.
fn adu(framing: Framing, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut v = match framing {
        Framing::Tcp => {
            let len = (pdu.len() + 1) as u16;
            vec![0x12, 0x34, 0, 0, (len >> 8) as u8, len as u8, unit]
        }
        _ => vec![unit],
    };
    v.extend_from_slice(pdu);
    match framing {
        Framing::Rtu => {
            let crc = crc16(&v);
            v.extend(crc.to_le_bytes());
        }
        Framing::Ascii => v.push(lrc(&v)),
        Framing::Tcp => {}
    }
    v
}

/// A small mapping: 16 coils and 16 holding registers from address 0.
struct Data {
    bits: Vec<u8>,
    registers: Vec<u16>,
}

impl Data {
    fn new() -> Data {
        Data { bits: vec![0; 16], registers: vec![0; 16] }
    }
    fn tables(&mut self) -> Tables<'_> {
        Tables {
            bits: Table { start: 0, data: &mut self.bits },
            input_bits: Table { start: 0, data: &mut [] },
            registers: Table { start: 0, data: &mut self.registers },
            input_registers: Table { start: 0, data: &mut [] },
        }
    }
}

struct Seen {
    answer: Answer,
    /// The sealed ADU written to the line; empty when nothing is sent.
    sent: Vec<u8>,
    diag: Recorded,
}

impl Seen {
    fn pdu(&self, framing: Framing) -> &[u8] {
        let h = framing.header_length();
        &self.sent[h..self.sent.len() - framing.checksum_length()]
    }
    fn exception(&self) -> Option<u8> {
        match self.answer.outcome {
            Outcome::Respond { exception, .. } => exception,
            Outcome::Fail(_) => None,
        }
    }
    fn silent(&self) -> bool {
        self.sent.is_empty()
    }
}

/// Runs one request through `modbus_reply`'s logic and reports the delivery as the
/// server flow would (sent unless suppressed or failed).
fn run_with(ext: &mut ServerExt, framing: Framing, quirks: u32, req: &[u8], data: &mut Data) -> Seen {
    let mut diag = Recorded::default();
    let mut out = [0u8; MAX_ADU_LENGTH];
    let server = Server { framing, quirks };
    let answer = ext.reply(server, req, req.len() as i32, &mut MappingData(&mut data.tables()), &mut diag, &mut out);
    let (sent, delivery) = match answer.outcome {
        Outcome::Respond { len, suppressed: false, .. } => {
            assert!(len + framing.checksum_length() <= framing.max_adu_length(), "response too long: {len}");
            let n = framing.seal(&mut out, len);
            (out[..n].to_vec(), Delivery::Sent)
        }
        _ => (Vec::new(), Delivery::NotSent),
    };
    ext.complete(&answer, delivery);
    Seen { answer, sent, diag }
}

fn run(ext: &mut ServerExt, framing: Framing, req: &[u8]) -> Seen {
    run_with(ext, framing, 0, req, &mut Data::new())
}

/// The request `pdu` to unit 0x11.
fn ask(ext: &mut ServerExt, framing: Framing, pdu: &[u8]) -> Seen {
    run(ext, framing, &adu(framing, 0x11, pdu))
}

fn assert_exception(s: &Seen, framing: Framing, function: u8, code: u8) {
    assert_eq!(s.exception(), Some(code), "{:02X?} {}", s.sent, s.diag.err);
    assert_eq!(s.pdu(framing), [function | 0x80, code]);
    assert!(matches!(s.answer.outcome, Outcome::Respond { flush_first: false, .. }));
}

fn with_diagnostics() -> ServerExt {
    let mut e = ServerExt::new();
    e.enable_diagnostics(true);
    e
}

fn diag_pdu(sub: u16, data: &[u16]) -> Vec<u8> {
    let mut p = vec![0x08];
    p.extend(sub.to_be_bytes());
    data.iter().for_each(|w| p.extend(w.to_be_bytes()));
    p
}

/// The value a counter sub-function answers, over the wire.
fn counter(ext: &mut ServerExt, sub: u16) -> u16 {
    let s = ask(ext, T, &diag_pdu(sub, &[0]));
    let pdu = s.pdu(T);
    assert_eq!(pdu[..3], [0x08, (sub >> 8) as u8, sub as u8]);
    u16::from_be_bytes([pdu[3], pdu[4]])
}

// ---------------------------------------------------------------- configuration

#[test]
fn fresh_extension_is_idle_and_frames_like_libmodbus() {
    let mut e = ServerExt::new();
    assert!(e.is_idle());
    assert!(!e.needs_extended_framing());
    e.set_exception_status(Some(0x6D));
    e.set_report_slave_id(Some((1, true, b"x"))).unwrap();
    assert!(!e.is_idle());
    assert!(!e.needs_extended_framing(), "07 and 11 frame like libmodbus");
    e.set_exception_status(None);
    e.set_report_slave_id(None).unwrap();
    assert!(e.is_idle());
    for configure in [
        |e: &mut ServerExt| e.enable_diagnostics(true),
        |e: &mut ServerExt| e.set_device_identification(0, Some(b"V")).unwrap(),
        |e: &mut ServerExt| e.set_file_record(1, 0, 1, None).unwrap(),
        |e: &mut ServerExt| e.set_fifo_queue(0, &[]).unwrap(),
    ] {
        let mut e = ServerExt::new();
        configure(&mut e);
        assert!(e.needs_extended_framing() && !e.is_idle());
    }
}

#[test]
fn configuration_arguments_are_checked() {
    let mut e = ServerExt::new();
    for id in [-1, 0x07, 0x40, 0x7F, 0x100, i32::MAX] {
        assert_eq!(e.set_device_identification(id, Some(b"x")), Err(Error::INVALID), "{id}");
    }
    for id in [0, 2, 3, 6, 0x80, 0xFF] {
        assert_eq!(e.set_device_identification(id, Some(b"x")), Ok(()), "{id}");
    }
    assert_eq!(e.set_device_identification(0x80, Some(&[0; 245])), Err(Error::INVALID));
    assert_eq!(e.set_device_identification(0x80, Some(&[0; 244])), Ok(()));
    for level in [-1, 4, 0x80, 0x84, 0x101] {
        assert_eq!(e.set_conformity_level(level), Err(Error::INVALID), "{level}");
    }
    for level in [0, 1, 2, 3, 0x81, 0x82, 0x83] {
        assert_eq!(e.set_conformity_level(level), Ok(()));
    }
    // Files: 1..=65535, records 0..=9999, at most up to record 9999.
    for (file, record, nb) in
        [(0, 0, 1), (0x10000, 0, 1), (1, -1, 1), (1, 10000, 1), (1, 0, 0), (1, 9999, 2), (1, 0, 10001)]
    {
        assert_eq!(e.set_file_record(file, record, nb, None), Err(Error::INVALID), "{file} {record} {nb}");
    }
    assert_eq!(e.set_file_record(1, 0, 2, Some(&[1])), Err(Error::INVALID));
    assert_eq!(e.set_file_record(0xFFFF, 9999, 1, Some(&[7])), Ok(()));
    assert_eq!(e.set_file_record(2, 0, 10000, None), Ok(()));
    let mut one = [0u16; 1];
    assert_eq!(e.get_file_record(0xFFFF, 9999, &mut one), Ok(()));
    assert_eq!(one, [7]);
    assert_eq!(e.get_file_record(0xFFFF, 9998, &mut one), Ok(()), "grown with zeros");
    assert_eq!(e.get_file_record(3, 0, &mut one), Err(Error::INVALID));
    assert_eq!(e.get_file_record(0xFFFF, 9999, &mut [0u16; 2]), Err(Error::INVALID));
    assert_eq!(e.get_file_record(0xFFFF, 0, &mut []), Err(Error::INVALID));
    // FIFO queues.
    for addr in [-1, 0x10000] {
        assert_eq!(e.set_fifo_queue(addr, &[]), Err(Error::INVALID));
    }
    assert_eq!(e.set_fifo_queue(0, &vec![0; 0x10000]), Err(Error::INVALID));
    assert_eq!(e.set_fifo_queue(0xFFFF, &vec![0; 0xFFFF]), Ok(()));
    // Report slave id data.
    assert_eq!(e.set_report_slave_id(Some((1, true, &[0; 250]))), Err(Error::INVALID));
    assert_eq!(e.set_report_slave_id(Some((1, true, &[0; 249]))), Ok(()));
}

#[test]
fn unconfigured_functions_keep_libmodbus_answers() {
    // Something else is configured: the extended codes still get libmodbus's answer.
    let mut e = ServerExt::new();
    e.set_exception_status(Some(1));
    for framing in [T, R] {
        for pdu in [
            &[0x08, 0, 0, 0, 0][..],
            &[0x0B],
            &[0x0C],
            &[0x14, 7, 6, 0, 1, 0, 0, 0, 1],
            &[0x15, 9, 6, 0, 1, 0, 0, 0, 1, 0, 0],
            &[0x18, 0, 0],
            &[0x2B, 0x0E, 1, 0],
            &[0x42],
        ] {
            let s = ask(&mut e, framing, pdu);
            assert_eq!(s.exception(), Some(1));
            assert!(matches!(s.answer.outcome, Outcome::Respond { flush_first: true, .. }));
            assert_eq!(s.diag.err, format!("Unknown Modbus function code: 0x{:X}\n", pdu[0]));
        }
        // FC 11: libmodbus's LMB answer; FC 03 from the mapping.
        let s = ask(&mut e, framing, &[0x11]);
        assert_eq!(s.pdu(framing)[..5], [0x11, 0x0B, 0xB4, 0xFF, b'L']);
        let s = ask(&mut e, framing, &[0x03, 0, 0, 0, 1]);
        assert_eq!(s.pdu(framing), [0x03, 2, 0, 0]);
    }
    // FC 07 unconfigured stays silent with ENOPROTOOPT, diagnostics or not.
    let mut e = with_diagnostics();
    let s = ask(&mut e, R, &[0x07]);
    assert_eq!(s.answer.outcome, Outcome::Fail(Error(crate::error::errno::ENOPROTOOPT)));
    assert!(s.silent());
    // ... and it counts as no response, not as a completed message.
    assert_eq!(counter(&mut e, 0x0F), 1);
    let s = ask(&mut e, T, &[0x0B]);
    assert_eq!(s.pdu(T), [0x0B, 0, 0, 0, 1], "only the 08/0F request completed");
}

// ---------------------------------------------------------------- the seeds' frames

#[test]
fn seed_frame_examples() {
    // 07: slave 0x13, status 0x6D.
    let mut e = ServerExt::new();
    e.set_exception_status(Some(0x6D));
    let s = run(&mut e, R, &[0x13, 0x07, 0x4D, 0x42]);
    assert_eq!(s.sent, [0x13, 0x07, 0x6D, 0x43, 0xD8]);
    // 08/00: return query data from slave 0x17.
    let mut e = with_diagnostics();
    let req = [0x17, 0x08, 0x00, 0x00, 0xAA, 0x55, 0x5C, 0x62];
    assert_eq!(run(&mut e, R, &req).sent, req);
    // 0B: slave 0x23, 264 events.
    let mut e = with_diagnostics();
    e.diagnostics_mut().unwrap().preset(0x0108, 0, &[]);
    let s = run(&mut e, R, &[0x23, 0x0B, 0x59, 0x47]);
    assert_eq!(s.sent, [0x23, 0x0B, 0x00, 0x00, 0x01, 0x08, 0xA2, 0xDF]);
    // 0C: slave 0x13, 264 events, 289 messages, log 04 00. (The receive event of the
    // request itself is logged first here, so the log is preset after it.)
    let mut e = with_diagnostics();
    let mut diag = Recorded::default();
    let mut out = [0u8; MAX_ADU_LENGTH];
    let mut data = Data::new();
    let req = [0x13, 0x0C, 0x0C, 0x85];
    e.diagnostics_mut().unwrap().preset(0x0108, 0x0121, &[]);
    let server = Server { framing: R, quirks: 0 };
    // Log the receive event, then put the seed's state in place and build the answer.
    let mut probe = e.clone();
    let _ = probe.reply(server, &req, 4, &mut MappingData(&mut data.tables()), &mut diag, &mut out);
    let d = e.diagnostics_mut().unwrap();
    d.preset(0x0108, 0x0121, &[0x04, 0x00]);
    let body = &mut out[1..1 + MAX_PDU_LENGTH];
    let Ok(Handled::Pdu(n, _)) = e.comm_event_log(&req[1..2], body, &mut diag) else { panic!() };
    out[0] = 0x13;
    let len = R.seal(&mut out, 1 + n);
    assert_eq!(out[..len], [0x13, 0x0C, 0x08, 0x00, 0x00, 0x01, 0x08, 0x01, 0x21, 0x04, 0x00, 0x49, 0xB9]);
    // 14: two sub-requests to slave 8 (file 4 record 1, file 3 record 9, 2 each).
    let mut e = ServerExt::new();
    e.set_file_record(4, 1, 2, Some(&[0x0DFE, 0x0020])).unwrap();
    e.set_file_record(3, 9, 2, Some(&[0x33CD, 0x0040])).unwrap();
    let req = [
        0x08, 0x14, 0x0E, 0x06, 0x00, 0x04, 0x00, 0x01, 0x00, 0x02, 0x06, 0x00, 0x03, 0x00, 0x09, 0x00, 0x02, 0x22,
        0xAF,
    ];
    let s = run(&mut e, R, &req);
    assert_eq!(
        s.sent,
        [0x08, 0x14, 0x0C, 0x05, 0x06, 0x0D, 0xFE, 0x00, 0x20, 0x05, 0x06, 0x33, 0xCD, 0x00, 0x40, 0xB0, 0xA7]
    );
    // 15: three registers into file 4 from record 7; the answer is the echo.
    e.set_file_record(4, 0, 10, None).unwrap();
    let req =
        [0x08, 0x15, 0x0D, 0x06, 0x00, 0x04, 0x00, 0x07, 0x00, 0x03, 0x06, 0xAF, 0x04, 0xBE, 0x10, 0x0D, 0x10, 0x5D];
    let s = run(&mut e, R, &req);
    assert_eq!(s.sent, req);
    let mut got = [0u16; 3];
    e.get_file_record(4, 7, &mut got).unwrap();
    assert_eq!(got, [0x06AF, 0x04BE, 0x100D]);
    // 18: the queue at 0x04DE of slave 5.
    let mut e = ServerExt::new();
    e.set_fifo_queue(0x04DE, &[0x01B8, 0x1204]).unwrap();
    let s = run(&mut e, R, &[0x05, 0x18, 0x04, 0xDE, 0x02, 0x77]);
    assert_eq!(s.sent, [0x05, 0x18, 0x00, 0x06, 0x00, 0x02, 0x01, 0xB8, 0x12, 0x04, 0x59, 0x6D]);
}

// ---------------------------------------------------------------- FC 07 and 11

#[test]
fn exception_status_and_report_slave_id() {
    let mut e = ServerExt::new();
    e.set_exception_status(Some(0xA5));
    for framing in [T, R, A] {
        let s = ask(&mut e, framing, &[0x07]);
        assert_eq!(s.pdu(framing), [0x07, 0xA5]);
        // A PDU with extra bytes (only possible through modbus_reply's req_length).
        assert_exception(&ask(&mut e, framing, &[0x07, 0]), framing, 0x07, 3);
    }
    e.set_report_slave_id(Some((0x55, true, b"IFTOOLS"))).unwrap();
    let s = ask(&mut e, R, &[0x11]);
    assert_eq!(s.pdu(R), [0x11, 9, 0x55, 0xFF, b'I', b'F', b'T', b'O', b'O', b'L', b'S']);
    e.set_report_slave_id(Some((7, false, &[0xEE; 249]))).unwrap();
    let s = ask(&mut e, T, &[0x11]);
    assert_eq!(s.pdu(T).len(), 253);
    assert_eq!(s.pdu(T)[..5], [0x11, 251, 7, 0x00, 0xEE]);
    let s = ask(&mut e, R, &[0x11]);
    assert_eq!(s.sent.len(), 256);
}

// ---------------------------------------------------------------- FC 08

#[test]
fn diagnostics_return_query_data_and_malformed_shapes() {
    let mut e = with_diagnostics();
    for words in [0usize, 1, 2, 125] {
        let data: Vec<u16> = (0..words as u16).map(|i| 0xA500 + i).collect();
        let pdu = diag_pdu(0, &data);
        let s = ask(&mut e, T, &pdu);
        assert_eq!(s.pdu(T), pdu, "{words} words");
    }
    // Odd data, too short a PDU, and a PDU longer than 253 bytes.
    assert_exception(&ask(&mut e, T, &[0x08, 0, 0, 1]), T, 0x08, 3);
    assert_exception(&ask(&mut e, T, &[0x08, 0]), T, 0x08, 3);
    assert_exception(&ask(&mut e, T, &[0x08]), T, 0x08, 3);
    let mut long = diag_pdu(0, &[0; 125]);
    long.push(0);
    long.push(0);
    let s = run(&mut e, T, &adu(T, 1, &long));
    assert_exception(&s, T, 0x08, 3);
}

#[test]
fn diagnostics_sub_functions_check_their_data() {
    let mut e = with_diagnostics();
    for sub in [0x02u16, 0x04, 0x0A, 0x0B, 0x0C, 0x0D, 0x0E, 0x0F, 0x10, 0x11, 0x12, 0x14] {
        for data in [&[][..], &[1], &[0xFF00], &[0, 0]] {
            let s = ask(&mut e, R, &diag_pdu(sub, data));
            assert_exception(&s, R, 0x08, 3);
            assert_eq!(s.diag.err, format!("Illegal data in diagnostics sub-function 0x{sub:X}\n"));
        }
    }
    // Restart: only 0000 and FF00.
    for data in [&[][..], &[1], &[0x00FF], &[0, 0]] {
        assert_exception(&ask(&mut e, R, &diag_pdu(1, data)), R, 0x08, 3);
    }
    // Reserved sub-functions.
    for sub in [0x05u16, 0x06, 0x07, 0x08, 0x09, 0x13, 0x15, 0x16, 0x100, 0xFFFF] {
        let s = ask(&mut e, R, &diag_pdu(sub, &[0]));
        assert_exception(&s, R, 0x08, 1);
        assert_eq!(s.diag.err, format!("Unknown diagnostics sub-function 0x{sub:X}\n"));
    }
    assert!(!e.diagnostics().unwrap().listen_only());
}

#[test]
fn diagnostic_register_and_ascii_delimiter() {
    let mut e = with_diagnostics();
    e.diagnostics_mut().unwrap().set_register(0x8420);
    assert_eq!(counter(&mut e, 0x02), 0x8420);
    e.bus_event(BusEvent::CharacterOverrun);
    assert_eq!(counter(&mut e, 0x02), 0x8421);
    assert_eq!(counter(&mut e, 0x12), 1);
    // 14: clear overrun counter and flag (echo).
    let pdu = diag_pdu(0x14, &[0]);
    assert_eq!(ask(&mut e, T, &pdu).pdu(T), pdu);
    assert_eq!(counter(&mut e, 0x02), 0x8420);
    assert_eq!(counter(&mut e, 0x12), 0);
    // 03: change the ASCII input delimiter.
    let s = ask(&mut e, A, &diag_pdu(3, &[0x2100]));
    assert_eq!(s.pdu(A), diag_pdu(3, &[0x2100]));
    assert_eq!(e.diagnostics().unwrap().ascii_delimiter(), b'!');
    for bad in [0x3A00u16, 0x0D00, 0x3000, 0x3900, 0x4100, 0x4600, 0x6100, 0x6600, 0x2101] {
        assert_exception(&ask(&mut e, A, &diag_pdu(3, &[bad])), A, 0x08, 3);
    }
    assert_exception(&ask(&mut e, A, &diag_pdu(3, &[])), A, 0x08, 3);
    assert_eq!(e.diagnostics().unwrap().ascii_delimiter(), b'!');
    assert_eq!(ask(&mut e, A, &diag_pdu(3, &[0x0A00])).exception(), None);
    assert_eq!(e.diagnostics().unwrap().get(3), Some(0x0A));
}

#[test]
fn counters_after_known_traffic() {
    let mut e = with_diagnostics();
    let mut data = Data::new();
    let mut req = |e: &mut ServerExt, framing: Framing, unit: u8, pdu: &[u8]| {
        e.bus_event(BusEvent::Frame);
        run_with(e, framing, 0, &adu(framing, unit, pdu), &mut data)
    };
    // RTU: 3 good reads, 1 exception, 1 broadcast write, 1 frame for another slave
    // (filtered by the receive: only counted on the bus), 2 CRC errors, 1 overrun.
    for _ in 0..3 {
        assert_eq!(req(&mut e, R, 0x11, &[0x03, 0, 0, 0, 2]).exception(), None);
    }
    assert_eq!(req(&mut e, R, 0x11, &[0x03, 0, 0x20, 0, 1]).exception(), Some(2));
    assert!(req(&mut e, R, 0, &[0x06, 0, 1, 0x12, 0x34]).silent());
    e.bus_event(BusEvent::Frame);
    e.bus_event(BusEvent::CommunicationError);
    e.bus_event(BusEvent::CommunicationError);
    e.bus_event(BusEvent::CharacterOverrun);
    // Exceptions sent by the application: busy (06) and NAK (07).
    for code in [6u8, 7] {
        e.bus_event(BusEvent::Frame);
        assert!(e.exception_request(R, &adu(R, 0x11, &[0x03])));
        e.exception_done(code, Delivery::Sent);
    }
    // 11 frames on the bus, 3 of them with errors; 7 requests; the counter requests
    // count themselves as bus and server messages when they are asked.
    let want: [(u16, u16); 8] =
        [(0x0B, 12), (0x0C, 2), (0x0D, 3), (0x0E, 11), (0x0F, 1), (0x10, 1), (0x11, 1), (0x12, 1)];
    for (sub, value) in want {
        e.bus_event(BusEvent::Frame);
        let s = run_with(&mut e, R, 0, &adu(R, 0x11, &diag_pdu(sub, &[0])), &mut data);
        assert_eq!(s.pdu(R)[3..], value.to_be_bytes(), "sub-function 0x{sub:X}");
    }
    assert_eq!(data.registers[1], 0x1234, "the broadcast write was done");
    // Completed: 3 reads + broadcast write + 8 counter requests.
    let s = run(&mut e, R, &adu(R, 0x11, &[0x0B]));
    assert_eq!(s.pdu(R), [0x0B, 0, 0, 0, 12]);
    // The log, newest first: this 0B's receive, then the 08 requests, ...
    let log = e.diagnostics().unwrap().events().to_vec();
    assert_eq!(log[..3], [0x40, 0x80, 0x40]);
    assert_eq!(
        log[16..],
        [
            0x40, 0x80, // 08/0B
            0x48, 0x80, 0x44, 0x80, // NAK, busy
            0x90, 0x82, 0x82, // overrun, 2 CRC errors
            0x40, 0xC0, // broadcast
            0x41, 0x80, // exception 02
            0x40, 0x80, 0x40, 0x80, 0x40, 0x80
        ]
    );
    // Clear Counters: echoed, then everything is 0 (the log stays).
    let pdu = diag_pdu(0x0A, &[0]);
    assert_eq!(ask(&mut e, R, &pdu).pdu(R), pdu);
    let d = e.diagnostics().unwrap();
    assert_eq!(((0x0B..=0x12).map(|s| d.get(s).unwrap()).sum::<u16>(), d.event_counter()), (0, 0));
    assert_eq!(d.events().len(), log.len() + 2);
}

#[test]
fn event_log_answer_and_counter_answer() {
    let mut e = with_diagnostics();
    ask(&mut e, T, &[0x03, 0, 0, 0, 1]);
    ask(&mut e, T, &[0x03, 0, 0x40, 0, 1]);
    let s = ask(&mut e, T, &[0x0C]);
    // 4 events logged before this answer + its own receive event.
    assert_eq!(s.pdu(T), [0x0C, 6 + 5, 0, 0, 0, 1, 0, 0, 0x80, 0x41, 0x80, 0x40, 0x80]);
    // A full log: 64 events, 72-byte PDU.
    for _ in 0..40 {
        ask(&mut e, T, &[0x03, 0, 0, 0, 1]);
    }
    let s = ask(&mut e, T, &[0x0C]);
    assert_eq!(s.pdu(T).len(), 8 + 64);
    assert_eq!(s.pdu(T)[1], 70);
    assert_eq!(s.pdu(T)[4..6], [0, 41]);
    // Malformed: extra bytes.
    assert_exception(&ask(&mut e, T, &[0x0C, 0]), T, 0x0C, 3);
    assert_exception(&ask(&mut e, T, &[0x0B, 0, 0]), T, 0x0B, 3);
    // Neither counts as a completed message.
    assert_eq!(ask(&mut e, T, &[0x0B]).pdu(T), [0x0B, 0, 0, 0, 41]);
}

#[test]
fn listen_only_mode_until_restart() {
    let mut e = with_diagnostics();
    let mut data = Data::new();
    // Force Listen Only Mode: no answer, 0x04 logged.
    let s = run_with(&mut e, R, 0, &adu(R, 0x11, &diag_pdu(4, &[0])), &mut data);
    assert!(s.silent());
    assert!(matches!(s.answer.outcome, Outcome::Respond { suppressed: true, len: 0, .. }));
    assert!(e.diagnostics().unwrap().listen_only());
    assert_eq!(e.diagnostics().unwrap().events(), [0x04, 0x80]);
    // Nothing is processed or answered: a write, a read, an unknown code, the
    // counters, a malformed restart, a broadcast.
    for pdu in [
        &[0x06, 0, 1, 0xAB, 0xCD][..],
        &[0x03, 0, 0, 0, 1],
        &[0x42],
        &diag_pdu(0x0B, &[0]),
        &diag_pdu(1, &[0x1234]),
        &diag_pdu(0, &[0x5555]),
    ] {
        let s = run_with(&mut e, R, 0, &adu(R, 0x11, pdu), &mut data);
        assert!(s.silent(), "{pdu:02X?}");
        assert!(s.diag.err.is_empty());
    }
    let s = run_with(&mut e, R, 0, &adu(R, 0, &[0x06, 0, 2, 0xAB, 0xCD]), &mut data);
    assert!(s.silent());
    assert_eq!(data.registers[..3], [0, 0, 0]);
    // modbus_reply_exception is silenced too.
    assert!(!e.exception_request(R, &adu(R, 0x11, &[0x03])));
    e.exception_done(4, Delivery::NotSent);
    let d = e.diagnostics().unwrap();
    assert_eq!(d.events()[..4], [0x60, 0xA0, 0x60, 0xE0]);
    assert_eq!(d.get(0x0F), Some(1 + 7 + 1));
    assert_eq!(d.get(0x0E), Some(9));
    assert_eq!(d.get(0x0D), Some(0));
    assert_eq!(d.event_counter(), 0);
    // Restart Communications Option (keep the log): not answered, leaves the mode.
    let s = run_with(&mut e, R, 0, &adu(R, 0x11, &diag_pdu(1, &[0])), &mut data);
    assert!(s.silent());
    let d = e.diagnostics().unwrap();
    assert!(!d.listen_only());
    assert_eq!(d.events()[..3], [0x00, 0xA0, 0x60]);
    assert_eq!(((0x0B..=0x12).map(|s| d.get(s).unwrap()).sum::<u16>(), d.event_counter()), (0, 0));
    // Answered again.
    let s = run_with(&mut e, R, 0, &adu(R, 0x11, &[0x06, 0, 1, 0xAB, 0xCD]), &mut data);
    assert_eq!(s.pdu(R), [0x06, 0, 1, 0xAB, 0xCD]);
    assert_eq!(data.registers[1], 0xABCD);
    // Listen-only again, then a restart that clears the log.
    run(&mut e, R, &adu(R, 0x11, &diag_pdu(4, &[0])));
    let s = run(&mut e, R, &adu(R, 0x11, &diag_pdu(1, &[0xFF00])));
    assert!(s.silent());
    assert_eq!(e.diagnostics().unwrap().events(), [0x00]);
}

#[test]
fn restart_in_normal_mode_answers_first() {
    let mut e = with_diagnostics();
    for _ in 0..3 {
        ask(&mut e, T, &[0x03, 0, 0, 0, 1]);
    }
    let pdu = diag_pdu(1, &[0xFF00]);
    let s = ask(&mut e, T, &pdu);
    assert_eq!(s.pdu(T), pdu);
    assert_eq!(e.diagnostics().unwrap().events(), [0x00]);
    assert_eq!(e.diagnostics().unwrap().event_counter(), 0);
    let pdu = diag_pdu(1, &[0]);
    assert_eq!(ask(&mut e, T, &pdu).pdu(T), pdu);
    assert_eq!(e.diagnostics().unwrap().events(), [0x00, 0x80, 0x00]);
    // A broadcast restart is done, not answered.
    let s = run(&mut e, R, &adu(R, 0, &diag_pdu(1, &[0xFF00])));
    assert!(s.silent());
    assert_eq!(e.diagnostics().unwrap().events(), [0x00]);
}

#[test]
fn diagnostics_off_forgets_everything() {
    let mut e = with_diagnostics();
    run(&mut e, R, &adu(R, 0x11, &diag_pdu(4, &[0])));
    e.enable_diagnostics(true);
    assert!(e.diagnostics().unwrap().listen_only(), "enabling twice keeps the state");
    e.enable_diagnostics(false);
    assert!(e.is_idle());
    let s = ask(&mut e, R, &[0x03, 0, 0, 0, 1]);
    assert_eq!(s.exception(), None);
    assert_eq!(ask(&mut e, R, &diag_pdu(0, &[1])).exception(), Some(1));
}

// ---------------------------------------------------------------- FC 14 / 15

fn read_sub(file: u16, record: u16, nb: u16) -> Vec<u8> {
    let mut v = vec![6];
    for w in [file, record, nb] {
        v.extend(w.to_be_bytes());
    }
    v
}

fn read_file_pdu(subs: &[Vec<u8>]) -> Vec<u8> {
    let body: Vec<u8> = subs.concat();
    let mut p = vec![0x14, body.len() as u8];
    p.extend(body);
    p
}

fn write_sub(file: u16, record: u16, values: &[u16]) -> Vec<u8> {
    let mut v = read_sub(file, record, values.len() as u16);
    values.iter().for_each(|x| v.extend(x.to_be_bytes()));
    v
}

fn write_file_pdu(subs: &[Vec<u8>]) -> Vec<u8> {
    let mut p = read_file_pdu(subs);
    p[0] = 0x15;
    p
}

fn files() -> ServerExt {
    let mut e = ServerExt::new();
    let values: Vec<u16> = (0..100).collect();
    e.set_file_record(1, 0, 100, Some(&values)).unwrap();
    e.set_file_record(2, 9990, 10, None).unwrap();
    e
}

#[test]
fn read_file_records() {
    let mut e = files();
    for framing in [T, R, A] {
        let s = ask(&mut e, framing, &read_file_pdu(&[read_sub(1, 98, 2), read_sub(2, 9999, 1)]));
        assert_eq!(s.pdu(framing), [0x14, 10, 5, 6, 0, 98, 0, 99, 3, 6, 0, 0]);
    }
    // The largest answer: one sub-request of 124 registers (252-byte PDU).
    e.set_file_record(3, 0, 124, None).unwrap();
    let s = ask(&mut e, T, &read_file_pdu(&[read_sub(3, 0, 124)]));
    assert_eq!(s.pdu(T).len(), 252);
    assert_eq!(s.pdu(T)[..4], [0x14, 250, 249, 6]);
    // 125 registers do not fit: ILLEGAL DATA VALUE (even if the file holds them).
    e.set_file_record(3, 0, 200, None).unwrap();
    assert_exception(&ask(&mut e, T, &read_file_pdu(&[read_sub(3, 0, 125)])), T, 0x14, 3);
    // Two sub-requests whose answers together do not fit.
    let s = ask(&mut e, T, &read_file_pdu(&[read_sub(3, 0, 100), read_sub(3, 0, 25)]));
    assert_exception(&s, T, 0x14, 3);
    // 35 sub-requests (245 bytes, the most) of one register each fit.
    let subs: Vec<Vec<u8>> = (0..35).map(|i| read_sub(1, i, 1)).collect();
    let s = ask(&mut e, R, &read_file_pdu(&subs));
    assert_eq!(s.pdu(R).len(), 2 + 35 * 4);
}

#[test]
fn read_file_record_errors() {
    let mut e = files();
    let good = read_sub(1, 0, 1);
    // ILLEGAL DATA ADDRESS: unknown file, file 0, record past the end, record
    // number above 9999, wrong reference type; also when another sub-request is fine.
    let mut ref5 = good.clone();
    ref5[0] = 5;
    for sub in
        [read_sub(9, 0, 1), read_sub(0, 0, 1), read_sub(1, 99, 2), read_sub(1, 100, 1), read_sub(2, 10000, 1), ref5]
    {
        for subs in [vec![sub.clone()], vec![good.clone(), sub.clone()]] {
            assert_exception(&ask(&mut e, R, &read_file_pdu(&subs)), R, 0x14, 2);
        }
    }
    // ILLEGAL DATA VALUE: byte counts and lengths.
    let p = read_file_pdu(std::slice::from_ref(&good));
    let shapes: Vec<Vec<u8>> = vec![
        vec![0x14],                // no byte count
        vec![0x14, 0],             // byte count 0
        p[..p.len() - 1].to_vec(), // one byte short
        [&p[..], &[0]].concat(),   // one byte long
        {
            let mut q = p.clone();
            q[1] = 6;
            q.pop();
            q
        }, // 6: not a sub-request
        {
            let mut q = [&p[..], &[6, 0]].concat();
            q[1] = 9;
            q
        }, // 9: not a multiple of 7
        read_file_pdu(&vec![good.clone(); 36]), // 252 > 0xF5
        read_file_pdu(&[read_sub(1, 0, 0)]), // zero records
    ];
    for pdu in shapes {
        assert_exception(&ask(&mut e, T, &pdu), T, 0x14, 3);
    }
    // Structure is checked before addresses.
    let s = ask(&mut e, T, &read_file_pdu(&[read_sub(9, 0, 1), read_sub(1, 0, 0)]));
    assert_eq!(s.exception(), Some(3));
}

#[test]
fn write_file_records() {
    let mut e = files();
    let pdu = write_file_pdu(&[write_sub(1, 0, &[0xAAAA, 0xBBBB]), write_sub(2, 9999, &[0xCCCC])]);
    for framing in [T, R, A] {
        assert_eq!(ask(&mut e, framing, &pdu).pdu(framing), pdu);
    }
    let mut got = [0u16; 3];
    e.get_file_record(1, 0, &mut got).unwrap();
    assert_eq!(got, [0xAAAA, 0xBBBB, 2]);
    e.get_file_record(2, 9999, &mut got[..1]).unwrap();
    assert_eq!(got[0], 0xCCCC);
    // The largest request: 122 registers (251 bytes of data).
    e.set_file_record(4, 0, 200, None).unwrap();
    let pdu = write_file_pdu(&[write_sub(4, 0, &[0x5A5A; 122])]);
    assert_eq!(pdu.len(), 253);
    assert_eq!(ask(&mut e, R, &pdu).pdu(R), pdu);
    // A bad second sub-request: nothing is written at all.
    let before = e.clone();
    for bad in [write_sub(9, 0, &[1]), write_sub(1, 99, &[1, 2]), write_sub(1, 10000, &[1])] {
        let pdu = write_file_pdu(&[write_sub(1, 0, &[0x1111]), bad]);
        assert_exception(&ask(&mut e, T, &pdu), T, 0x15, 2);
    }
    let mut got = [0u16; 1];
    e.get_file_record(1, 0, &mut got).unwrap();
    assert_eq!(got, [0xAAAA]);
    assert_eq!(e.files, before.files);
}

#[test]
fn write_file_record_errors() {
    let mut e = files();
    let p = write_file_pdu(&[write_sub(1, 0, &[1, 2])]);
    let shapes: Vec<Vec<u8>> = vec![
        vec![0x15],
        vec![0x15, 0],
        write_file_pdu(&[read_sub(1, 0, 0)]), // 7 bytes: below 9
        {
            let mut q = write_sub(1, 0, &[1]);
            q[6] = 0;
            write_file_pdu(&[q])
        }, // zero records, 2 data bytes
        p[..p.len() - 1].to_vec(),            // data short
        [&p[..], &[0]].concat(),              // one byte long
        {
            let mut q = p.clone();
            q[1] += 1;
            q.push(0);
            q
        }, // trailing byte inside the count
        {
            let mut q = p.clone();
            q[8] = 3;
            q
        }, // claims 3 records, has 2
        {
            let mut q = p.clone();
            q[8] = 1;
            q
        }, // claims 1 record, 2 bytes left over
        {
            let mut q = write_file_pdu(&[write_sub(1, 0, &[0; 123])]);
            q.truncate(253);
            q[1] = 251;
            q
        }, // 0xFB ok? no: 123 records claimed
        {
            let mut q = vec![0x15, 0xFC];
            q.extend(vec![0; 0xFC]);
            q
        }, // 252 > 0xFB
    ];
    for (i, pdu) in shapes.into_iter().enumerate() {
        let s = ask(&mut e, T, &pdu);
        assert_exception(&s, T, 0x15, 3);
        let why = &s.diag.err;
        assert!(why.contains("write_file_record") || why.starts_with("Request too long"), "shape {i}: {why}");
    }
    let mut got = [0u16; 2];
    e.get_file_record(1, 0, &mut got).unwrap();
    assert_eq!(got, [0, 1]);
}

// ---------------------------------------------------------------- FC 18

#[test]
fn fifo_queues() {
    let mut e = ServerExt::new();
    let full: Vec<u16> = (1..=31).collect();
    e.set_fifo_queue(0, &[]).unwrap();
    e.set_fifo_queue(0x1000, &full).unwrap();
    e.set_fifo_queue(0xFFFF, &[0; 32]).unwrap();
    assert_eq!(ask(&mut e, T, &[0x18, 0, 0]).pdu(T), [0x18, 0, 2, 0, 0]);
    let s = ask(&mut e, R, &[0x18, 0x10, 0x00]);
    assert_eq!(s.pdu(R)[..7], [0x18, 0, 64, 0, 31, 0, 1]);
    assert_eq!(s.pdu(R).len(), 5 + 62);
    // Reading does not remove anything.
    assert_eq!(ask(&mut e, R, &[0x18, 0x10, 0x00]).pdu(R), s.pdu(R));
    assert_exception(&ask(&mut e, T, &[0x18, 0xFF, 0xFF]), T, 0x18, 3);
    assert_exception(&ask(&mut e, T, &[0x18, 0x10, 0x01]), T, 0x18, 2);
    for bad in [&[0x18][..], &[0x18, 0x10], &[0x18, 0x10, 0x00, 0x00]] {
        assert_exception(&ask(&mut e, A, bad), A, 0x18, 3);
    }
    // Replacing a queue copies the new values.
    e.set_fifo_queue(0x1000, &[0xBEEF]).unwrap();
    assert_eq!(ask(&mut e, T, &[0x18, 0x10, 0x00]).pdu(T), [0x18, 0, 4, 0, 1, 0xBE, 0xEF]);
}

// ---------------------------------------------------------------- FC 2B / 0E

fn devid(code: u8, id: u8) -> Vec<u8> {
    vec![0x2B, 0x0E, code, id]
}

/// The objects of a device identification answer: (id, value).
fn objects(pdu: &[u8]) -> Vec<(u8, Vec<u8>)> {
    let mut pos = 7;
    let mut v = Vec::new();
    for _ in 0..pdu[6] {
        let len = pdu[pos + 1] as usize;
        v.push((pdu[pos], pdu[pos + 2..pos + 2 + len].to_vec()));
        pos += 2 + len;
    }
    assert_eq!(pos, pdu.len());
    v
}

#[test]
fn device_identification_basic_regular_extended() {
    let mut e = ServerExt::new();
    e.set_device_identification(0, Some(b"IFTOOLS")).unwrap();
    e.set_device_identification(1, Some(b"SENSOR")).unwrap();
    e.set_device_identification(2, Some(b"V1.01")).unwrap();
    // Basic only: conformity 0x81.
    let s = ask(&mut e, R, &devid(1, 0));
    let mut want = vec![0x2B, 0x0E, 1, 0x81, 0, 0, 3, 0, 7];
    want.extend(b"IFTOOLS\x01\x06SENSOR\x02\x05V1.01");
    assert_eq!(s.pdu(R), want);
    // As the seed shows it, with conformity level 01 declared.
    e.set_conformity_level(1).unwrap();
    let s = ask(&mut e, R, &devid(1, 0));
    assert_eq!(s.pdu(R)[3], 0x01);
    // ... where individual access is not supported.
    assert_exception(&ask(&mut e, R, &devid(4, 0)), R, 0x2B, 3);
    e.set_conformity_level(0).unwrap();
    // Regular and extended objects.
    e.set_device_identification(3, Some(b"http://x")).unwrap();
    e.set_device_identification(6, Some(b"app")).unwrap();
    e.set_device_identification(0x80, Some(&[1, 2, 3])).unwrap();
    e.set_device_identification(0xFF, Some(b"")).unwrap();
    let ids = |s: &Seen| objects(s.pdu(T)).iter().map(|o| o.0).collect::<Vec<_>>();
    let s = ask(&mut e, T, &devid(1, 0));
    assert_eq!((s.pdu(T)[3], ids(&s)), (0x83, vec![0, 1, 2]));
    let s = ask(&mut e, T, &devid(2, 0));
    assert_eq!(ids(&s), [0, 1, 2, 3, 6]);
    let s = ask(&mut e, T, &devid(3, 0));
    assert_eq!(ids(&s), [0, 1, 2, 3, 6, 0x80, 0xFF]);
    assert_eq!(objects(s.pdu(T))[5].1, [1, 2, 3]);
    // A starting id: from there; an unknown one restarts at 0.
    assert_eq!(ids(&ask(&mut e, T, &devid(3, 6))), [6, 0x80, 0xFF]);
    assert_eq!(ids(&ask(&mut e, T, &devid(3, 0x81))), [0, 1, 2, 3, 6, 0x80, 0xFF]);
    assert_eq!(ids(&ask(&mut e, T, &devid(1, 3))), [0, 1, 2]);
    // Individual access.
    let s = ask(&mut e, T, &devid(4, 3));
    assert_eq!(s.pdu(T), [0x2B, 0x0E, 4, 0x83, 0, 0, 1, 3, 8, b'h', b't', b't', b'p', b':', b'/', b'/', b'x']);
    assert_eq!(objects(ask(&mut e, T, &devid(4, 0xFF)).pdu(T)), [(0xFF, vec![])]);
    for unknown in [4u8, 5, 7, 0x7F, 0x81, 0xFE] {
        assert_exception(&ask(&mut e, T, &devid(4, unknown)), T, 0x2B, 2);
    }
    // Unset basic objects are empty.
    e.set_device_identification(1, None).unwrap();
    assert_eq!(objects(ask(&mut e, T, &devid(4, 1)).pdu(T)), [(1, vec![])]);
    // A declared regular level: extended objects are out of reach.
    e.set_conformity_level(0x82).unwrap();
    let s = ask(&mut e, T, &devid(3, 0));
    assert_eq!((s.pdu(T)[2], s.pdu(T)[3], ids(&s)), (3, 0x82, vec![0, 1, 2, 3, 6]));
    assert_exception(&ask(&mut e, T, &devid(4, 0x80)), T, 0x2B, 2);
    // Removing every object turns device identification off.
    for id in [0, 2, 3, 6, 0x80, 0xFF] {
        e.set_device_identification(id, None).unwrap();
    }
    e.set_conformity_level(0).unwrap();
    assert!(e.is_idle());
    assert_eq!(ask(&mut e, T, &devid(1, 0)).exception(), Some(1));
}

#[test]
fn device_identification_stream_splits_with_more_follows() {
    let mut e = ServerExt::new();
    for (id, len) in [(0u8, 100usize), (1, 100), (2, 100), (0x80, 244), (0x81, 10), (0x82, 10)] {
        e.set_device_identification(id as i32, Some(&vec![b'a' + id % 26; len])).unwrap();
    }
    let mut next = 0u8;
    let mut seen = Vec::new();
    let mut rounds = 0;
    loop {
        let s = ask(&mut e, R, &devid(3, next));
        let pdu = s.pdu(R);
        assert!(pdu.len() <= MAX_PDU_LENGTH);
        seen.extend(objects(pdu).iter().map(|o| (o.0, o.1.len())));
        rounds += 1;
        if pdu[4] == 0 {
            assert_eq!(pdu[5], 0);
            break;
        }
        assert_eq!(pdu[4], 0xFF);
        next = pdu[5];
    }
    assert_eq!(rounds, 4, "0+1, 2, 0x80 alone (253 bytes), 0x81+0x82");
    assert_eq!(seen, [(0, 100), (1, 100), (2, 100), (0x80, 244), (0x81, 10), (0x82, 10)]);
    // The first answer: objects 0 and 1 (2 * 102 + 7 = 211; a third would be 313).
    let s = ask(&mut e, R, &devid(1, 0));
    assert_eq!(s.pdu(R)[4..7], [0xFF, 2, 2]);
    let s = ask(&mut e, R, &devid(1, 2));
    assert_eq!(s.pdu(R)[4..7], [0x00, 0, 1]);
    // An individual read of the largest object fits exactly.
    let s = ask(&mut e, T, &devid(4, 0x80));
    assert_eq!(s.pdu(T).len(), MAX_PDU_LENGTH);
}

#[test]
fn device_identification_malformed() {
    let mut e = ServerExt::new();
    e.set_device_identification(0, Some(b"V")).unwrap();
    for code in [0u8, 5, 0x80, 0xFF] {
        let s = ask(&mut e, T, &devid(code, 0));
        assert_exception(&s, T, 0x2B, 3);
        assert_eq!(s.diag.err, format!("Illegal read device id code {code} in read_device_identification\n"));
    }
    assert_exception(&ask(&mut e, T, &[0x2B, 0x0D, 0, 0]), T, 0x2B, 1);
    assert_exception(&ask(&mut e, T, &[0x2B, 0x0D]), T, 0x2B, 1);
    for bad in [&[0x2B][..], &[0x2B, 0x0E], &[0x2B, 0x0E, 1], &[0x2B, 0x0E, 1, 0, 0]] {
        assert_exception(&ask(&mut e, R, bad), R, 0x2B, 3);
    }
}

// ---------------------------------------------------------------- framing details

#[test]
fn broadcasts_are_done_but_not_answered() {
    let mut e = files();
    e.enable_diagnostics(true);
    let pdu = write_file_pdu(&[write_sub(1, 5, &[0x7777])]);
    let s = run(&mut e, R, &adu(R, 0, &pdu));
    assert!(s.silent());
    let mut got = [0u16; 1];
    e.get_file_record(1, 5, &mut got).unwrap();
    assert_eq!(got, [0x7777]);
    assert_eq!(e.diagnostics().unwrap().events()[..2], [0x40, 0xC0]);
    // With MODBUS_QUIRK_REPLY_TO_BROADCAST the answer goes out; TCP unit 0 always.
    let s = run_with(&mut e, R, QUIRK_REPLY_TO_BROADCAST, &adu(R, 0, &pdu), &mut Data::new());
    assert_eq!(s.pdu(R), pdu);
    let s = run(&mut e, T, &adu(T, 0, &pdu));
    assert_eq!(s.pdu(T), pdu);
    assert_eq!(e.diagnostics().unwrap().events()[..2], [0x40, 0x80], "no broadcast bit on TCP");
}

#[test]
fn headers_echo_tid_unit_and_checksums() {
    let mut e = ServerExt::new();
    e.set_exception_status(Some(0x6D));
    let mut req = adu(T, 0x2A, &[0x07]);
    req[2] = 0;
    req[3] = 0;
    let s = run(&mut e, T, &req);
    assert_eq!(s.sent, [0x12, 0x34, 0, 0, 0, 3, 0x2A, 0x07, 0x6D]);
    let s = run(&mut e, A, &adu(A, 0x13, &[0x07]));
    assert_eq!(s.sent, [0x13, 0x07, 0x6D, lrc(&[0x13, 0x07, 0x6D])]);
    // Exceptions keep the header too.
    e.set_fifo_queue(1, &[]).unwrap();
    let s = run(&mut e, T, &adu(T, 9, &[0x18, 0, 2]));
    assert_eq!(s.sent, [0x12, 0x34, 0, 0, 0, 3, 9, 0x98, 2]);
}

#[test]
fn truncated_and_empty_requests() {
    let mut e = files();
    e.enable_diagnostics(true);
    e.set_exception_status(Some(1));
    e.set_fifo_queue(0, &[1]).unwrap();
    e.set_device_identification(0, Some(b"V")).unwrap();
    // Nothing at all, a bare header, a header and a CRC.
    for framing in [T, R, A] {
        for n in 0..=framing.header_length() + framing.checksum_length() {
            let req = adu(framing, 1, &[0x08, 0, 0, 0, 0]);
            let s = run(&mut e, framing, &req[..n]);
            assert!(s.exception().is_some() || s.silent(), "{framing:?} {n}");
        }
    }
    // Each extended request cut at every length is refused with an exception.
    let full = [
        diag_pdu(0x0B, &[0]),
        read_file_pdu(&[read_sub(1, 0, 2)]),
        write_file_pdu(&[write_sub(1, 0, &[1, 2])]),
        vec![0x18, 0, 0],
        devid(1, 0),
    ];
    for pdu in full {
        for cut in 1..pdu.len() {
            for framing in [T, R] {
                let s = ask(&mut e, framing, &pdu[..cut]);
                assert_eq!(s.exception(), Some(3), "{pdu:02X?} cut at {cut}: {}", s.diag.err);
            }
        }
    }
}

/// Deterministic pseudo-random requests against a fully configured server: no
/// panic, no answer longer than the framing allows, only exceptions 1-3.
#[test]
fn random_requests_never_misbehave() {
    let mut rng = crate::test_rng::XorShift::new(0x9E37_79B9_7F4A_7C15);
    let mut next = || rng.next_u64();
    let mut e = files();
    e.enable_diagnostics(true);
    e.set_exception_status(Some(3));
    e.set_report_slave_id(Some((1, true, &[0; 249]))).unwrap();
    e.set_fifo_queue(0, &[1; 31]).unwrap();
    e.set_fifo_queue(1, &[1; 40]).unwrap();
    for id in [0, 1, 2, 3, 0x80, 0x90] {
        e.set_device_identification(id, Some(&[b'x'; 244])).unwrap();
    }
    let functions = [3u8, 7, 8, 0x0B, 0x0C, 0x11, 0x14, 0x15, 0x18, 0x2B];
    let mut data = Data::new();
    for round in 0..30_000 {
        let framing = [T, R, A][round % 3];
        let len = (next() % 262) as usize;
        let mut req: Vec<u8> = (0..len).map(|_| next() as u8).collect();
        let h = framing.header_length();
        if req.len() > h {
            req[h] = functions[(next() % functions.len() as u64) as usize];
        }
        if req.len() > h + 4 && next() % 2 == 0 {
            // Small, plausible values so that the success paths run too.
            req[h + 1] = (next() % 3) as u8;
            req[h + 2] = [0x00, 0x0E, 0x01, 0x0B, 0x07][(next() % 5) as usize];
            req[h + 3] = (next() % 5) as u8;
            req[h + 4] = (next() % 3) as u8;
            if req[h] == 0x14 || req[h] == 0x15 {
                req[h + 2] = 6;
            }
        }
        let s = run_with(&mut e, framing, 0, &req, &mut data);
        if let Outcome::Respond { len, exception, .. } = s.answer.outcome {
            assert!(len + framing.checksum_length() <= framing.max_adu_length());
            assert!(matches!(exception, None | Some(1..=3)), "{exception:?}");
        }
        if e.diagnostics().unwrap().listen_only() {
            run(&mut e, framing, &adu(framing, 1, &diag_pdu(1, &[0])));
        }
    }
}
