//! The example frames of the protocol seed documents (shared/seeds, the RTU examples
//! of document 004), checked in both directions and with both checksums: the CRC
//! the document prints, the framing of request and answer, the answer accepted for
//! its request, and the same frames in ASCII form with their LRC.

use crate::ascii;
use crate::confirm::{self, Rejection};
use crate::crc::crc16;
use crate::error::{EMBXILADD, Error};
use crate::frame::{Assembler, Framing, MsgKind, Progress};
use crate::{Recorded, Silent};

/// (request, answer) as printed, CRC included. Where the page lost a byte to its
/// layout (FC 0F: the byte count of the request and the first CRC byte of the
/// answer), the frame is completed and the surviving CRC byte checked below.
const EXAMPLES: &[(&[u8], &[u8])] = &[
    (&[0x11, 0x01, 0x00, 0x13, 0x00, 0x25, 0x0E, 0x84], &[0x11, 0x01, 0x05, 0xCD, 0x6B, 0xB2, 0x0E, 0x1B, 0x45, 0xE6]),
    (&[0x11, 0x02, 0x00, 0xC4, 0x00, 0x16, 0xBA, 0xA9], &[0x11, 0x02, 0x03, 0xAC, 0xDB, 0x35, 0x20, 0x18]),
    (
        &[0x11, 0x03, 0x00, 0x6B, 0x00, 0x03, 0x76, 0x87],
        &[0x11, 0x03, 0x06, 0xAE, 0x41, 0x56, 0x52, 0x43, 0x40, 0x49, 0xAD],
    ),
    (&[0x11, 0x04, 0x00, 0x08, 0x00, 0x01, 0xB2, 0x98], &[0x11, 0x04, 0x02, 0x00, 0x0A, 0xF8, 0xF4]),
    (&[0x11, 0x05, 0x00, 0xAC, 0xFF, 0x00, 0x4E, 0x8B], &[0x11, 0x05, 0x00, 0xAC, 0xFF, 0x00, 0x4E, 0x8B]),
    (&[0x11, 0x06, 0x00, 0x01, 0x00, 0x03, 0x9A, 0x9B], &[0x11, 0x06, 0x00, 0x01, 0x00, 0x03, 0x9A, 0x9B]),
    (
        &[0x11, 0x0F, 0x00, 0x13, 0x00, 0x0A, 0x02, 0xCD, 0x01, 0xBF, 0x0B],
        &[0x11, 0x0F, 0x00, 0x13, 0x00, 0x0A, 0x26, 0x99],
    ),
    (
        &[0x11, 0x10, 0x00, 0x01, 0x00, 0x02, 0x04, 0x00, 0x0A, 0x01, 0x02, 0xC6, 0xF0],
        &[0x11, 0x10, 0x00, 0x01, 0x00, 0x02, 0x12, 0x98],
    ),
];

/// The error example: read coils at 0x04A1 of slave 10, answered "illegal data address".
const ERROR_EXAMPLE: (&[u8], &[u8]) =
    (&[0x0A, 0x01, 0x04, 0xA1, 0x00, 0x01, 0xAC, 0x63], &[0x0A, 0x81, 0x02, 0xB0, 0x53]);

/// Frames `bytes` with an assembler fed one byte at a time; its length when whole.
fn framed_length(framing: Framing, kind: MsgKind, bytes: &[u8]) -> usize {
    let mut asm = Assembler::new(framing, kind);
    let mut have = 0;
    loop {
        let n = asm.wanted().min(1);
        assert!(have + n <= bytes.len(), "{kind:?} {bytes:02X?} wants more bytes than it has");
        have += n;
        if let Progress::Complete(len) = asm.received(&bytes[..have], n).unwrap() {
            return len;
        }
    }
}

/// The ASCII form of an RTU example: same slave and PDU, LRC instead of CRC, through
/// the encoder and back through the decoder.
fn as_ascii(rtu: &[u8]) -> Vec<u8> {
    let mut body = rtu[..rtu.len() - 2].to_vec();
    body.push(ascii::lrc(&body));
    let mut text = [0u8; ascii::MAX_ENCODED];
    let n = ascii::encode(&body, &mut text);
    assert_eq!(text[0], b':');
    assert_eq!(&text[n - 2..n], b"\r\n");
    let mut decoder = ascii::Decoder::new();
    let mut out = [0u8; ascii::MAX_DECODED];
    for &c in &text[..n] {
        if let ascii::Step::Complete(len) = decoder.feed(c, &mut out).unwrap() {
            assert_eq!(ascii::check_lrc(&out[..len]), Ok(()));
            return out[..len].to_vec();
        }
    }
    panic!("no frame decoded");
}

#[test]
fn printed_crcs_are_right() {
    for (req, rsp) in EXAMPLES.iter().chain([&ERROR_EXAMPLE]) {
        for frame in [req, rsp] {
            let (body, crc) = frame.split_at(frame.len() - 2);
            assert_eq!(crc16(body).to_le_bytes(), crc, "{frame:02X?}");
        }
    }
}

#[test]
fn frames_are_read_whole_in_both_directions() {
    for (req, rsp) in EXAMPLES.iter().chain([&ERROR_EXAMPLE]) {
        assert_eq!(framed_length(Framing::Rtu, MsgKind::Indication, req), req.len());
        assert_eq!(framed_length(Framing::Rtu, MsgKind::Confirmation, rsp), rsp.len());
        let (areq, arsp) = (as_ascii(req), as_ascii(rsp));
        assert_eq!(framed_length(Framing::Ascii, MsgKind::Indication, &areq), areq.len());
        assert_eq!(framed_length(Framing::Ascii, MsgKind::Confirmation, &arsp), arsp.len());
    }
}

#[test]
fn answers_are_accepted_for_their_requests() {
    let counts = [37, 22, 3, 1, 1, 1, 10, 2];
    for ((req, rsp), count) in EXAMPLES.iter().zip(counts) {
        // The value count libmodbus reports: bytes of bits for reads of bits.
        let want = match req[1] {
            1 | 2 => (count + 7) / 8,
            _ => count,
        };
        assert_eq!(confirm::check(Framing::Rtu, req, rsp, &mut Recorded::default()), Ok(want), "{req:02X?}");
        let (areq, arsp) = (as_ascii(req), as_ascii(rsp));
        assert_eq!(confirm::check(Framing::Ascii, &areq, &arsp, &mut Silent), Ok(want));
    }
    let (req, rsp) = ERROR_EXAMPLE;
    let refused = Err(Rejection::Exception(Error(EMBXILADD)));
    assert_eq!(confirm::check(Framing::Rtu, req, rsp, &mut Silent), refused);
    assert_eq!(confirm::check(Framing::Ascii, &as_ascii(req), &as_ascii(rsp), &mut Silent), refused);
}
