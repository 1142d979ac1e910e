//! Modbus/TCP Security, the parts without I/O: the role a client certificate
//! carries, and what a request asks to touch, for the server's authorization.
//!
//! - The role is an X.509 v3 extension, OID 1.3.6.1.4.1.50316.802.1, whose value is
//!   one ASN.1 UTF8String (the specification's ); a certificate without it
//!   has no role. [`role`] finds it with a small DER walker over the
//!   certificate: the certificate's signature and chain are the TLS library's
//!   business, checked before this is asked.
//! - [`access`] says what a request asks for, as the authorization callback is
//!   given it: function code, and ranges of an address and a count (two for FC
//!   0x17, one per sub-request for file records).

use crate::fc;

/// The DER encoding of the role extension's OID, 1.3.6.1.4.1.50316.802.1.
pub const ROLE_OID: [u8; 11] = [0x2B, 0x06, 0x01, 0x04, 0x01, 0x83, 0x89, 0x0C, 0x86, 0x22, 0x01];

/// The longest role handed out (a role is a short name; a longer string is refused
/// as no role rather than copied around).
pub const MAX_ROLE_LENGTH: usize = 255;

const SEQUENCE: u8 = 0x30;
const OID: u8 = 0x06;
const BOOLEAN: u8 = 0x01;
const OCTET_STRING: u8 = 0x04;
const UTF8_STRING: u8 = 0x0C;
/// `[3] EXPLICIT` in a TBSCertificate: the extensions.
const EXTENSIONS: u8 = 0xA3;

/// One DER element: its tag and content, and what follows it.
fn element(der: &[u8]) -> Option<(u8, &[u8], &[u8])> {
    let (&tag, rest) = der.split_first()?;
    if tag & 0x1F == 0x1F {
        return None; // high tag numbers: none in the structures read here
    }
    let (&first, rest) = rest.split_first()?;
    let (len, rest) = if first < 0x80 {
        (first as usize, rest)
    } else {
        let n = (first & 0x7F) as usize;
        if n == 0 || n > 4 || rest.len() < n {
            return None;
        }
        let len = rest[..n].iter().fold(0usize, |acc, &b| acc << 8 | b as usize);
        (len, &rest[n..])
    };
    if rest.len() < len {
        return None;
    }
    Some((tag, &rest[..len], &rest[len..]))
}

/// The elements of a constructed value's content, in order.
fn elements(mut content: &[u8]) -> impl Iterator<Item = (u8, &[u8])> {
    core::iter::from_fn(move || {
        let (tag, value, rest) = element(content)?;
        content = rest;
        Some((tag, value))
    })
}

/// The role of a certificate (DER): the UTF8String of its role extension. `None`
/// when it has none, or the certificate cannot be read, or the value is not one
/// UTF8String of 1 to [`MAX_ROLE_LENGTH`] bytes without NUL.
pub fn role(cert: &[u8]) -> Option<&str> {
    let (SEQUENCE, certificate, _) = element(cert)? else { return None };
    let (SEQUENCE, tbs, _) = element(certificate)? else { return None };
    let (_, extensions) = elements(tbs).find(|&(tag, _)| tag == EXTENSIONS)?;
    let (SEQUENCE, list, _) = element(extensions)? else { return None };
    for (tag, extension) in elements(list) {
        if tag != SEQUENCE {
            return None;
        }
        let mut parts = elements(extension);
        let Some((OID, oid)) = parts.next() else { return None };
        if oid != ROLE_OID {
            continue;
        }
        let value = match parts.next()? {
            (BOOLEAN, _) => parts.next()?,
            other => other,
        };
        let (OCTET_STRING, value) = value else { return None };
        let (UTF8_STRING, text, rest) = element(value)? else { return None };
        if !rest.is_empty() || text.is_empty() || text.len() > MAX_ROLE_LENGTH || text.contains(&0) {
            return None;
        }
        return core::str::from_utf8(text).ok();
    }
    None
}

/// One range a request touches.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Range {
    pub address: u16,
    pub nb: u16,
}

/// What a request asks for, for the authorization callback: its function code and
/// the ranges it touches, in the order they are asked about ([`Access::ranges`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Access<'a> {
    pub function: u8,
    pdu: &'a [u8],
}

/// What the request PDU `pdu` (function code first) asks for. Its ranges:
/// - reads and multiple writes (01-04, 0F, 10): the start address and the count;
/// - single writes and mask write (05, 06, 16): the address, count 1;
/// - 17: the written registers, then the read ones;
/// - diagnostics (08): the sub-function as the address, count 0;
/// - file records (14, 15): each sub-request's file number and record length, in
///   the request's order (a server serves every sub-request, so every one is asked
///   about: asking about the first alone would let a second one through);
/// - FIFO (18): the FIFO pointer address, count 0;
/// - device identification (2B): the object id, count 0;
/// - any other code (07, 0B, 0C, 11, unknown): address 0 and count 0.
///
/// Every request has at least one range. Bytes missing from a short request read as
/// 0 (the server refuses the request afterwards, if allowed).
pub fn access(pdu: &[u8]) -> Access<'_> {
    Access { function: pdu.first().copied().unwrap_or(0), pdu }
}

impl<'a> Access<'a> {
    /// The ranges, in the order they are asked about (see [`access`]).
    pub fn ranges(&self) -> impl Iterator<Item = Range> + 'a {
        let pdu = self.pdu;
        let word = move |at: usize| match pdu.get(at..at + 2) {
            Some(&[hi, lo]) => u16::from_be_bytes([hi, lo]),
            _ => 0,
        };
        let byte = |at: usize| pdu.get(at).copied().unwrap_or(0) as u16;
        let range = |address, nb| Some(Range { address, nb });
        let fixed = match self.function {
            fc::READ_COILS
            | fc::READ_DISCRETE_INPUTS
            | fc::READ_HOLDING_REGISTERS
            | fc::READ_INPUT_REGISTERS
            | fc::WRITE_MULTIPLE_COILS
            | fc::WRITE_MULTIPLE_REGISTERS => [range(word(1), word(3)), None],
            fc::WRITE_SINGLE_COIL | fc::WRITE_SINGLE_REGISTER | fc::MASK_WRITE_REGISTER => [range(word(1), 1), None],
            fc::WRITE_AND_READ_REGISTERS => [range(word(5), word(7)), range(word(1), word(3))],
            fc::DIAGNOSTICS => [range(word(1), 0), None],
            fc::READ_FILE_RECORD | fc::WRITE_FILE_RECORD => [None, None],
            fc::READ_FIFO_QUEUE => [range(word(1), 0), None],
            // MEI type, read device id code, object id.
            fc::ENCAPSULATED_INTERFACE => [range(byte(3), 0), None],
            _ => [range(0, 0), None],
        };
        // File records: after the byte count, sub-requests of reference type, file
        // number, record number and record length; a write's carries its records too.
        let data_per_record = match self.function {
            fc::READ_FILE_RECORD => Some(0),
            fc::WRITE_FILE_RECORD => Some(2),
            _ => None,
        };
        let mut at = 2;
        let subs = core::iter::from_fn(move || {
            let per = data_per_record?;
            // The first is asked about even when cut short; others only when whole.
            if at != 2 && at + 7 > pdu.len() {
                return None;
            }
            let (file, nb) = (word(at + 1), word(at + 5));
            at += 7 + per * nb as usize;
            range(file, nb)
        });
        fixed.into_iter().flatten().chain(subs)
    }
}

/// Where the TLS record being read ends, so that a server never takes bytes of the
/// next record off its socket: a client's next request (and its first one, sent with
/// the end of its handshake) stays in the kernel until it is wanted, and an
/// application's `poll()` loop sees it. A record is a 5-byte header (content type,
/// version, length) and a body of that length; [`RecordCut::limit`] says how many
/// bytes the next read may take, [`RecordCut::advance`] accounts for what it took.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordCut {
    header: [u8; 5],
    have: usize,
    body_left: usize,
}

impl RecordCut {
    /// Most bytes the next read may take: the rest of the header, or of the body.
    #[inline]
    pub fn limit(&self) -> usize {
        if self.have < 5 { 5 - self.have } else { self.body_left }
    }

    /// True between records.
    pub fn at_boundary(&self) -> bool {
        self.have == 0
    }

    /// Accounts for `bytes` read from the stream (any number, split anywhere).
    pub fn advance(&mut self, mut bytes: &[u8]) {
        while !bytes.is_empty() {
            if self.have < 5 {
                let n = bytes.len().min(5 - self.have);
                self.header[self.have..self.have + n].copy_from_slice(&bytes[..n]);
                self.have += n;
                bytes = &bytes[n..];
                if self.have == 5 {
                    self.body_left = u16::from_be_bytes([self.header[3], self.header[4]]) as usize;
                    if self.body_left == 0 {
                        self.have = 0;
                    }
                }
            } else {
                let n = bytes.len().min(self.body_left);
                self.body_left -= n;
                bytes = &bytes[n..];
                if self.body_left == 0 {
                    self.have = 0;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    /// A DER element with a short or long length.
    fn der(tag: u8, content: &[u8]) -> Vec<u8> {
        let mut out = std::vec![tag];
        match content.len() {
            n if n < 0x80 => out.push(n as u8),
            n if n < 0x100 => out.extend_from_slice(&[0x81, n as u8]),
            n => out.extend_from_slice(&[0x82, (n >> 8) as u8, n as u8]),
        }
        out.extend_from_slice(content);
        out
    }

    fn extension(oid: &[u8], critical: bool, value: &[u8]) -> Vec<u8> {
        let mut content = der(OID, oid);
        if critical {
            content.extend(der(BOOLEAN, &[0xFF]));
        }
        content.extend(der(OCTET_STRING, value));
        der(SEQUENCE, &content)
    }

    /// A certificate shaped as X.509 (the fields before the extensions are opaque
    /// elements: this reader skips them).
    fn certificate(extensions: &[Vec<u8>]) -> Vec<u8> {
        let mut tbs = der(0xA0, &der(0x02, &[2])); // version v3
        tbs.extend(der(0x02, &[0x01, 0x23])); // serial
        for _ in 0..5 {
            tbs.extend(der(SEQUENCE, &[0x05, 0x00])); // algorithm, issuer, validity, subject, key
        }
        if !extensions.is_empty() {
            tbs.extend(der(EXTENSIONS, &der(SEQUENCE, &extensions.concat())));
        }
        let mut cert = der(SEQUENCE, &tbs);
        cert.extend(der(SEQUENCE, &[0x05, 0x00]));
        cert.extend(der(0x03, &[0x00, 0xAA]));
        der(SEQUENCE, &cert)
    }

    const BASIC_CONSTRAINTS: [u8; 3] = [0x55, 0x1D, 0x13];

    #[test]
    fn the_role_extension_is_found_among_others() {
        let role_ext = extension(&ROLE_OID, false, &der(UTF8_STRING, b"Operator"));
        let other = extension(&BASIC_CONSTRAINTS, true, &der(SEQUENCE, &[]));
        assert_eq!(role(&certificate(&[other.clone(), role_ext.clone()])), Some("Operator"));
        assert_eq!(role(&certificate(&[role_ext])), Some("Operator"));
        let critical = extension(&ROLE_OID, true, &der(UTF8_STRING, "Opérateur".as_bytes()));
        assert_eq!(role(&certificate(&[critical])), Some("Opérateur"));
        // A long role: lengths in the long form all the way up.
        let long = "R".repeat(200);
        assert_eq!(
            role(&certificate(&[extension(&ROLE_OID, false, &der(UTF8_STRING, long.as_bytes()))])),
            Some(&long[..])
        );
    }

    #[test]
    fn no_role() {
        assert_eq!(role(&certificate(&[])), None);
        let other = extension(&BASIC_CONSTRAINTS, false, &der(SEQUENCE, &[]));
        assert_eq!(role(&certificate(&[other])), None);
        // Not a UTF8String, empty, NUL inside, too long, trailing bytes, not UTF-8.
        for value in [
            der(0x13, b"Operator"),
            der(UTF8_STRING, b""),
            der(UTF8_STRING, b"Op\0erator"),
            der(UTF8_STRING, "R".repeat(MAX_ROLE_LENGTH + 1).as_bytes()),
            [der(UTF8_STRING, b"A"), std::vec![0]].concat(),
            der(UTF8_STRING, &[0xC3, 0x28]),
        ] {
            assert_eq!(role(&certificate(&[extension(&ROLE_OID, false, &value)])), None, "{value:02X?}");
        }
        // A similar OID (one arc more, one less).
        let mut longer = ROLE_OID.to_vec();
        longer.push(1);
        assert_eq!(role(&certificate(&[extension(&longer, false, &der(UTF8_STRING, b"X"))])), None);
        assert_eq!(role(&certificate(&[extension(&ROLE_OID[..10], false, &der(UTF8_STRING, b"X"))])), None);
    }

    #[test]
    fn bad_der_is_no_role_and_no_panic() {
        let cert = certificate(&[extension(&ROLE_OID, false, &der(UTF8_STRING, b"Operator"))]);
        for cut in 0..cert.len() {
            let _ = role(&cert[..cut]);
        }
        for i in 0..cert.len() {
            let mut bad = cert.clone();
            bad[i] ^= 0xFF;
            let _ = role(&bad);
        }
        assert_eq!(role(&[]), None);
        assert_eq!(role(&[0x30, 0x84, 0xFF, 0xFF, 0xFF, 0xFF]), None);
        assert_eq!(role(&[0x3F, 0x01, 0x00]), None);
    }

    /// Reads `stream` as a server does, `chunk(i)` bytes at most per read, never past
    /// a record's end: the reads that end a record end exactly at record boundaries.
    fn cut_reads(stream: &[u8], chunk: impl Fn(usize) -> usize) -> Vec<usize> {
        let mut cut = RecordCut::default();
        let mut at = 0;
        let mut ends = Vec::new();
        let mut i = 0;
        while at < stream.len() {
            let n = cut.limit().min(chunk(i).max(1)).min(stream.len() - at);
            assert!(n > 0);
            cut.advance(&stream[at..at + n]);
            at += n;
            i += 1;
            if cut.at_boundary() {
                ends.push(at);
            }
        }
        ends
    }

    #[test]
    fn reads_stop_at_record_boundaries() {
        // Three records: 2-byte body, empty body, 300-byte body; then half a header.
        let mut stream = std::vec![23, 3, 3, 0, 2, 0xAA, 0xBB, 21, 3, 3, 0, 0, 23, 3, 3, 1, 44];
        stream.extend(std::iter::repeat_n(0x55, 300));
        let whole = stream.len();
        stream.extend_from_slice(&[23, 3]);
        for chunk in [1usize, 2, 3, 5, 7, 64, 1000] {
            assert_eq!(cut_reads(&stream, |_| chunk), [7, 12, whole], "chunks of {chunk}");
        }
        assert_eq!(cut_reads(&stream, |i| [1, 9, 2, 300][i % 4]), [7, 12, whole]);
        // The header's length field decides the body, whatever it holds.
        let mut cut = RecordCut::default();
        cut.advance(&[0xFF, 0, 0, 0xFF, 0xFF]);
        assert_eq!(cut.limit(), 0xFFFF);
    }

    #[test]
    fn what_requests_ask_for() {
        let r = |address, nb| Range { address, nb };
        let asked = |pdu: &[u8]| {
            let a = access(pdu);
            (a.function, a.ranges().collect::<Vec<_>>())
        };
        type Case<'a> = (&'a [u8], u8, &'a [Range]);
        let cases: [Case; 12] = [
            (&[0x03, 0x00, 0x10, 0x00, 0x7D], 0x03, &[r(16, 125)]),
            (&[0x01, 0x01, 0x00, 0x07, 0xD0], 0x01, &[r(256, 2000)]),
            (&[0x06, 0x00, 0x05, 0x12, 0x34], 0x06, &[r(5, 1)]),
            (&[0x05, 0x00, 0x05, 0xFF, 0x00], 0x05, &[r(5, 1)]),
            (&[0x10, 0x00, 0x02, 0x00, 0x02, 0x04, 0, 1, 0, 2], 0x10, &[r(2, 2)]),
            (&[0x16, 0x00, 0x04, 0xF2, 0x00, 0x00, 0x25], 0x16, &[r(4, 1)]),
            (&[0x17, 0x00, 0x01, 0x00, 0x02, 0x00, 0x09, 0x00, 0x01, 0x02, 0, 7], 0x17, &[r(9, 1), r(1, 2)]),
            (&[0x08, 0x00, 0x0A, 0x00, 0x00], 0x08, &[r(10, 0)]),
            (&[0x14, 0x07, 0x06, 0x00, 0x04, 0x00, 0x01, 0x00, 0x02], 0x14, &[r(4, 2)]),
            (&[0x18, 0x04, 0xDE], 0x18, &[r(0x04DE, 0)]),
            (&[0x2B, 0x0E, 0x04, 0x81], 0x2B, &[r(0x81, 0)]),
            (&[0x07], 0x07, &[r(0, 0)]),
        ];
        for (pdu, function, ranges) in cases {
            assert_eq!(asked(pdu), (function, ranges.to_vec()), "{pdu:02X?}");
        }
        // Short requests read missing bytes as 0, never past the end.
        assert_eq!(asked(&[0x03, 0x00]), (3, vec![r(0, 0)]));
        assert_eq!(asked(&[]), (0, vec![r(0, 0)]));
        assert_eq!(asked(&[0x17, 0, 1, 0, 2]), (0x17, vec![r(0, 0), r(1, 2)]));
        assert_eq!(asked(&[0x14]), (0x14, vec![r(0, 0)]));
        assert_eq!(asked(&[0x15, 9, 6, 0, 3]), (0x15, vec![r(3, 0)]));
    }

    #[test]
    fn every_file_record_sub_request_is_asked_about() {
        let r = |address, nb| Range { address, nb };
        // Read: file 4 records 1-2, file 9 record 0 (3 records), file 1 (1 record).
        let read = [
            0x14, 21, 6, 0, 4, 0, 1, 0, 2, 6, 0, 9, 0, 0, 0, 3, 6, 0, 1, 0, 0, 0, 1, //
        ];
        assert_eq!(access(&read).ranges().collect::<Vec<_>>(), [r(4, 2), r(9, 3), r(1, 1)]);
        // Write: file 1 record 0 (1 record), then file 2 record 5 (2 records): the
        // second sub-request, after the first one's data, is asked about too.
        let write = [
            0x15, 20, 6, 0, 1, 0, 0, 0, 1, 0xAA, 0xBB, 6, 0, 2, 0, 5, 0, 2, 1, 2, 3, 4, //
        ];
        assert_eq!(access(&write).ranges().collect::<Vec<_>>(), [r(1, 1), r(2, 2)]);
        // A sub-request cut short after a whole one is not (the server refuses the
        // request); a record length running past the end ends the walk.
        assert_eq!(access(&write[..write.len() - 6]).ranges().count(), 1);
        assert_eq!(access(&[0x15, 9, 6, 0, 1, 0, 0, 0xFF, 0xFF, 0, 0]).ranges().count(), 1);
        // The most a PDU holds: 35 read sub-requests, each asked about.
        let mut most = vec![0x14, 245];
        for k in 0..35u8 {
            most.extend_from_slice(&[6, 0, k, 0, 0, 0, 1]);
        }
        let asked: Vec<_> = access(&most).ranges().collect();
        assert_eq!(asked.len(), 35);
        assert!(asked.iter().enumerate().all(|(k, a)| *a == r(k as u16, 1)));
    }
}
