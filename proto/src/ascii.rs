//! Modbus ASCII: the binary ADU `[slave][pdu][lrc]` written as ':' + two upper-case
//! hex digits per byte + CR LF. Frames are delimited by those characters, so the
//! decoder needs no length rules and gaps of any length within a frame are fine
//! (the transport bounds them with the byte timeout, 1 s by default).

use crate::error::{Error, Result};

/// Largest decoded frame: slave + 253-byte PDU + LRC.
pub const MAX_DECODED: usize = 255;
/// Largest encoded frame: ':' + 2 * 255 hex digits + CR LF.
pub const MAX_ENCODED: usize = 1 + 2 * MAX_DECODED + 2;

/// Longitudinal redundancy check: the two's complement of the byte sum.
pub fn lrc(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |sum, &b| sum.wrapping_add(b)).wrapping_neg()
}

const HEX: &[u8; 16] = b"0123456789ABCDEF";

/// Writes the ASCII form of `adu` (which already ends with its LRC) into `out`,
/// returning its length.
pub fn encode(adu: &[u8], out: &mut [u8]) -> usize {
    out[0] = b':';
    let mut n = 1;
    for &b in adu {
        out[n] = HEX[(b >> 4) as usize];
        out[n + 1] = HEX[(b & 0x0F) as usize];
        n += 2;
    }
    out[n] = b'\r';
    out[n + 1] = b'\n';
    n + 2
}

fn hex_value(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'A'..=b'F' => Some(c - b'A' + 10),
        b'a'..=b'f' => Some(c - b'a' + 10),
        _ => None,
    }
}

/// What the decoder knows after a character.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Keep feeding characters.
    NeedMore,
    /// A frame of this many decoded bytes (LRC included) ended with CR LF.
    Complete(usize),
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum State {
    /// Before ':'; anything else is line noise and skipped.
    Idle,
    /// Inside a frame, expecting a high nibble, a low nibble, or CR.
    High,
    Low(u8),
    /// After CR, expecting LF.
    Cr,
}

/// Decodes one ASCII frame character by character into a binary buffer.
#[derive(Clone, Debug)]
pub struct Decoder {
    state: State,
    len: usize,
    /// The character after CR that ends a frame: LF unless a server was told
    /// otherwise (diagnostics sub-function 03, Change ASCII Input Delimiter).
    delimiter: u8,
}

impl Default for Decoder {
    fn default() -> Self {
        Self::new()
    }
}

impl Decoder {
    pub const fn new() -> Self {
        Decoder { state: State::Idle, len: 0, delimiter: b'\n' }
    }

    /// A decoder whose frames end with CR and `delimiter`.
    pub const fn with_delimiter(delimiter: u8) -> Self {
        Decoder { state: State::Idle, len: 0, delimiter }
    }

    /// True once the start character was seen.
    pub fn in_frame(&self) -> bool {
        self.state != State::Idle
    }

    /// Decoded bytes so far.
    pub fn len(&self) -> usize {
        self.len
    }

    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Feeds one character; decoded bytes go to `out[self.len()]`. A ':' inside a
    /// frame starts over (the sender restarted). Non-hex characters, an odd number
    /// of digits, or more than [`MAX_DECODED`] bytes give `EMBBADDATA`.
    pub fn feed(&mut self, c: u8, out: &mut [u8]) -> Result<Step> {
        if c == b':' {
            self.state = State::High;
            self.len = 0;
            return Ok(Step::NeedMore);
        }
        match self.state {
            State::Idle => Ok(Step::NeedMore),
            State::High if c == b'\r' => {
                self.state = State::Cr;
                Ok(Step::NeedMore)
            }
            State::High => {
                let v = hex_value(c).ok_or(Error::BAD_DATA)?;
                if self.len >= MAX_DECODED.min(out.len()) {
                    return Err(Error::BAD_DATA);
                }
                self.state = State::Low(v);
                Ok(Step::NeedMore)
            }
            State::Low(high) => {
                let v = hex_value(c).ok_or(Error::BAD_DATA)?;
                out[self.len] = high << 4 | v;
                self.len += 1;
                self.state = State::High;
                Ok(Step::NeedMore)
            }
            State::Cr if c == self.delimiter => {
                self.state = State::Idle;
                Ok(Step::Complete(self.len))
            }
            State::Cr => Err(Error::BAD_DATA),
        }
    }
}

/// Checks the LRC at the end of a decoded frame.
pub fn check_lrc(frame: &[u8]) -> core::result::Result<(), (u8, u8)> {
    match frame.split_last() {
        Some((&received, body)) if lrc(body) == received => Ok(()),
        Some((&received, body)) => Err((received, lrc(body))),
        None => Err((0, 0)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn decode_all(text: &[u8]) -> Result<Vec<u8>> {
        let mut d = Decoder::new();
        let mut out = [0u8; MAX_DECODED];
        for &c in text {
            if let Step::Complete(n) = d.feed(c, &mut out)? {
                return Ok(out[..n].to_vec());
            }
        }
        panic!("no complete frame in {:?}", String::from_utf8_lossy(text));
    }

    #[test]
    fn read_holding_register_frame() {
        // Slave 1, FC 03, address 0, quantity 1: sum 5, LRC 0xFB.
        let adu = [0x01, 0x03, 0x00, 0x00, 0x00, 0x01, lrc(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x01])];
        assert_eq!(adu[6], 0xFB);
        let mut out = [0u8; MAX_ENCODED];
        let n = encode(&adu, &mut out);
        assert_eq!(&out[..n], b":010300000001FB\r\n");
        assert_eq!(decode_all(&out[..n]).unwrap(), adu);
        assert_eq!(check_lrc(&adu), Ok(()));
    }

    #[test]
    fn seed_read_holding_registers_example() {
        // Seed 004's request 11 03 006B 0003 in ASCII form.
        let body = [0x11, 0x03, 0x00, 0x6B, 0x00, 0x03];
        assert_eq!(lrc(&body), 0x7E);
        assert_eq!(decode_all(b":1103006B00037E\r\n").unwrap()[..6], body);
    }

    #[test]
    fn noise_before_start_is_skipped_and_restart_resets() {
        assert_eq!(decode_all(b"xx\r\n:01:010300000001FB\r\n").unwrap().len(), 7);
        assert_eq!(decode_all(b":010300000001fb\r\n").unwrap()[6], 0xFB);
    }

    #[test]
    fn changed_input_delimiter() {
        let mut d = Decoder::with_delimiter(b'!');
        let mut out = [0u8; MAX_DECODED];
        let text = b":010300000001FB\r!";
        let steps: Vec<Step> = text.iter().map(|&c| d.feed(c, &mut out).unwrap()).collect();
        assert_eq!(steps.last(), Some(&Step::Complete(7)));
        let mut d = Decoder::with_delimiter(b'!');
        let r: Result<Vec<Step>> = b":010300000001FB\r\n".iter().map(|&c| d.feed(c, &mut out)).collect();
        assert_eq!(r.err(), Some(Error::BAD_DATA));
    }

    #[test]
    fn malformed_frames() {
        let mut out = [0u8; MAX_DECODED];
        for bad in [&b":01G3\r\n"[..], b":013\r\n", b":0103\rX"] {
            let mut d = Decoder::new();
            let r: Result<Vec<Step>> = bad.iter().map(|&c| d.feed(c, &mut out)).collect();
            assert_eq!(r.err(), Some(Error::BAD_DATA), "{:?}", String::from_utf8_lossy(bad));
        }
        let mut frame = vec![b':'];
        frame.extend(std::iter::repeat_n(b'0', 2 * MAX_DECODED + 2));
        let mut d = Decoder::new();
        let r: Result<Vec<Step>> = frame.iter().map(|&c| d.feed(c, &mut out)).collect();
        assert_eq!(r.err(), Some(Error::BAD_DATA));
        assert_eq!(check_lrc(&[0x01, 0x03, 0x00]), Err((0x00, 0xFC)));
    }
}
