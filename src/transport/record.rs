//! The TLS record protection of a connection whose handshake rustls completed: the
//! traffic keys rustls hands over (`dangerous_into_kernel_connection`, the interface
//! rustls keeps for kTLS), used with ring's AEADs, the very primitives rustls' own
//! record layer calls. A record is sealed in place in the buffer it is sent from and
//! opened in place in the buffer it was read into: no allocation, no copy beyond the
//! plaintext into its record. TLS 1.3 (RFC 8446 section 5.2: the nonce is the IV
//! XOR the sequence number, the additional data the record header, the content
//! type inside) and TLS 1.2 (RFC 5246 section 6.2.3.3: AES-GCM with an explicit
//! nonce, RFC 5288; ChaCha20-Poly1305 as in TLS 1.3, RFC 7905; the additional data
//! is the sequence number, the type, the version and the plaintext's length).

use ring::aead::{AES_128_GCM, AES_256_GCM, Aad, Algorithm, CHACHA20_POLY1305, LessSafeKey, Nonce, UnboundKey};
use rustls::ConnectionTrafficSecrets;

/// Record content types.
pub const ALERT: u8 = 21;
pub const HANDSHAKE: u8 = 22;
pub const APPLICATION_DATA: u8 = 23;

/// The most plaintext one record carries (2^14).
pub const MAX_FRAGMENT: usize = 16384;
pub const HEADER: usize = 5;
pub const TAG: usize = 16;
pub const EXPLICIT_NONCE: usize = 8;

/// One direction's key, IV and sequence number.
pub struct Direction {
    key: LessSafeKey,
    iv: [u8; 12],
    seq: u64,
    /// TLS 1.2 AES-GCM: an explicit nonce in every record.
    explicit: bool,
    tls13: bool,
}

/// A record that does not open: its tag (or its length) is wrong.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BadRecord;

impl Direction {
    /// The direction of `secrets`, at sequence number `seq`.
    pub fn new(secrets: ConnectionTrafficSecrets, seq: u64, tls13: bool) -> Option<Direction> {
        let (algorithm, key, iv) = match &secrets {
            ConnectionTrafficSecrets::Aes128Gcm { key, iv } => (&AES_128_GCM, key, iv),
            ConnectionTrafficSecrets::Aes256Gcm { key, iv } => (&AES_256_GCM, key, iv),
            ConnectionTrafficSecrets::Chacha20Poly1305 { key, iv } => (&CHACHA20_POLY1305, key, iv),
            _ => return None,
        };
        Direction::with_key(algorithm, key.as_ref(), iv.as_ref().try_into().ok()?, seq, tls13)
    }

    fn with_key(algorithm: &'static Algorithm, key: &[u8], iv: [u8; 12], seq: u64, tls13: bool) -> Option<Direction> {
        let explicit = !tls13 && algorithm != &CHACHA20_POLY1305;
        let key = LessSafeKey::new(UnboundKey::new(algorithm, key).ok()?);
        Some(Direction { key, iv, seq, explicit, tls13 })
    }

    /// Records protected so far (the next one's sequence number).
    pub fn seq(&self) -> u64 {
        self.seq
    }

    fn nonce(&self) -> [u8; 12] {
        let mut nonce = self.iv;
        let (_, low) = nonce.split_at_mut(4);
        let xored = u64::from_be_bytes(low.try_into().unwrap_or_default()) ^ self.seq;
        low.copy_from_slice(&xored.to_be_bytes());
        nonce
    }

    /// The bytes a record adds to `len` bytes of plaintext.
    pub fn overhead(&self) -> usize {
        HEADER
            + TAG
            + if self.tls13 {
                1
            } else if self.explicit {
                EXPLICIT_NONCE
            } else {
                0
            }
    }

    /// Seals `data` (at most [`MAX_FRAGMENT`] bytes) of content type `typ` into one
    /// record at the start of `out` (at least `data.len() + overhead()` long); returns
    /// the record's length.
    pub fn seal(&mut self, typ: u8, data: &[u8], out: &mut [u8]) -> usize {
        let len = data.len();
        let nonce = self.nonce();
        let (body_at, sealed_len) = if self.explicit { (HEADER + EXPLICIT_NONCE, len) } else { (HEADER, len) };
        let inner = usize::from(self.tls13);
        let record = body_at + sealed_len + inner + TAG;
        let outer = if self.tls13 { APPLICATION_DATA } else { typ };
        let body_len = (record - HEADER) as u16;
        out[..HEADER].copy_from_slice(&[outer, 3, 3, (body_len >> 8) as u8, body_len as u8]);
        if self.explicit {
            out[HEADER..body_at].copy_from_slice(&nonce[4..]);
        }
        out[body_at..body_at + len].copy_from_slice(data);
        if self.tls13 {
            out[body_at + len] = typ;
        }
        let (head, body) = out.split_at_mut(body_at);
        let (plain, tag) = body[..sealed_len + inner + TAG].split_at_mut(sealed_len + inner);
        let aad12;
        let aad: &[u8] = if self.tls13 {
            &head[..HEADER]
        } else {
            aad12 = tls12_aad(self.seq, typ, len);
            &aad12
        };
        let sealed = self.key.seal_in_place_separate_tag(Nonce::assume_unique_for_key(nonce), Aad::from(aad), plain);
        // ring fails only for more than 2^36 bytes, and a record holds 2^14.
        let Ok(sealed) = sealed else { unreachable!("a record's plaintext is too long for the AEAD") };
        tag.copy_from_slice(sealed.as_ref());
        self.seq += 1;
        record
    }

    /// Opens the record `record` (header and body) in place: its content type and
    /// where its plaintext lies within `record`.
    pub fn open(&mut self, record: &mut [u8]) -> Result<(u8, core::ops::Range<usize>), BadRecord> {
        let (head, body) = record.split_at_mut(HEADER);
        let typ = head[0];
        let opened = if self.tls13 {
            // Every record after the handshake is application data outside.
            if typ != APPLICATION_DATA {
                return Err(BadRecord);
            }
            let nonce = Nonce::assume_unique_for_key(self.nonce());
            self.key.open_in_place(nonce, Aad::from(&*head), body).map_err(|_| BadRecord)?.len()
        } else if self.explicit {
            if body.len() < EXPLICIT_NONCE + TAG {
                return Err(BadRecord);
            }
            let mut nonce = [0u8; 12];
            nonce[..4].copy_from_slice(&self.iv[..4]);
            nonce[4..].copy_from_slice(&body[..EXPLICIT_NONCE]);
            let aad = tls12_aad(self.seq, typ, body.len() - EXPLICIT_NONCE - TAG);
            let nonce = Nonce::assume_unique_for_key(nonce);
            self.key.open_within(nonce, Aad::from(aad), body, EXPLICIT_NONCE..).map_err(|_| BadRecord)?.len()
        } else {
            let aad = tls12_aad(self.seq, typ, body.len().checked_sub(TAG).ok_or(BadRecord)?);
            let nonce = Nonce::assume_unique_for_key(self.nonce());
            self.key.open_in_place(nonce, Aad::from(aad), body).map_err(|_| BadRecord)?.len()
        };
        self.seq += 1;
        // open_within moves the plaintext to the start of the body.
        if !self.tls13 {
            if opened > MAX_FRAGMENT {
                return Err(BadRecord);
            }
            return Ok((typ, HEADER..HEADER + opened));
        }
        // TLS 1.3: the content type is the last byte that is not padding.
        let plain = &record[HEADER..HEADER + opened];
        match plain.iter().rposition(|&b| b != 0) {
            Some(at) if at <= MAX_FRAGMENT => Ok((plain[at], HEADER..HEADER + at)),
            _ => Err(BadRecord),
        }
    }
}

fn tls12_aad(seq: u64, typ: u8, len: usize) -> [u8; 13] {
    let mut aad = [0u8; 13];
    aad[..8].copy_from_slice(&seq.to_be_bytes());
    aad[8] = typ;
    aad[9] = 3;
    aad[10] = 3;
    aad[11..].copy_from_slice(&(len as u16).to_be_bytes());
    aad
}

/// The length of the whole record that `held` starts with, once its header is there.
pub fn record_len(held: &[u8]) -> Option<usize> {
    (held.len() >= HEADER).then(|| HEADER + u16::from_be_bytes([held[3], held[4]]) as usize)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn direction(kind: usize, seq: u64, tls13: bool) -> Direction {
        let algorithm = [&AES_128_GCM, &AES_256_GCM, &CHACHA20_POLY1305][kind];
        let key = [kind as u8 + 7; 32];
        let iv = [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12];
        Direction::with_key(algorithm, &key[..algorithm.key_len()], iv, seq, tls13).unwrap()
    }

    /// Every suite and version: what one side seals, the other opens, in order; a
    /// changed byte or a record out of order does not open.
    #[test]
    fn sealed_records_open_in_order_and_not_otherwise() {
        for tls13 in [false, true] {
            for kind in 0..3 {
                let mut tx = direction(kind, 5, tls13);
                let mut rx = direction(kind, 5, tls13);
                let mut out = vec![0u8; 400];
                for (n, typ) in [(12, APPLICATION_DATA), (0, APPLICATION_DATA), (2, ALERT), (260, APPLICATION_DATA)] {
                    let data: Vec<u8> = (0..n).map(|i| i as u8 ^ 0x5a).collect();
                    let len = tx.seal(typ, &data, &mut out);
                    assert_eq!(len, n + tx.overhead());
                    assert_eq!(record_len(&out[..len]), Some(len));
                    let mut bad = out[..len].to_vec();
                    bad[len - 1] ^= 1;
                    let mut probe = direction(kind, rx.seq(), tls13);
                    assert_eq!(probe.open(&mut bad), Err(BadRecord));
                    let (got, at) = rx.open(&mut out[..len]).unwrap();
                    assert_eq!((got, &out[at]), (typ, &data[..]), "tls13 {tls13} kind {kind} n {n}");
                }
                let len = tx.seal(APPLICATION_DATA, b"x", &mut out);
                tx.seal(APPLICATION_DATA, b"y", &mut out[len..]);
                assert_eq!(rx.open(&mut out[len..len * 2]), Err(BadRecord), "out of order");
            }
        }
    }

    /// TLS 1.3 (RFC 8446 section 5.4): the content type is the last byte of the inner
    /// plaintext that is not zero; the zeros after it are padding. A plaintext of
    /// zeros has no type, and one over 2^14 bytes is too long; both do not open.
    #[test]
    fn tls13_padding_and_the_inner_type() {
        let mut out = vec![0u8; MAX_FRAGMENT + 64];
        // Sealed with the type 0: the inner plaintext is data, its type, zeros.
        let cases = [
            ([b"abc".as_slice(), &[APPLICATION_DATA], &[0; 7]].concat(), Ok((APPLICATION_DATA, 3))),
            ([&[ALERT][..], &[0; 1]].concat(), Ok((ALERT, 0))),
            ([&[0u8, 5, 0][..], &[HANDSHAKE], &[0; 30]].concat(), Ok((HANDSHAKE, 3))),
            (vec![0; 5], Err(BadRecord)),
            ([vec![1; MAX_FRAGMENT], vec![APPLICATION_DATA]].concat(), Ok((APPLICATION_DATA, MAX_FRAGMENT))),
            ([vec![1; MAX_FRAGMENT + 1], vec![APPLICATION_DATA]].concat(), Err(BadRecord)),
        ];
        for (inner, want) in cases {
            let (mut tx, mut rx) = (direction(0, 0, true), direction(0, 0, true));
            let len = tx.seal(0, &inner, &mut out);
            let got = rx.open(&mut out[..len]).map(|(typ, at)| (typ, at.len()));
            assert_eq!(got, want, "inner plaintext of {} bytes", inner.len() + 1);
        }
        // A TLS 1.3 record whose outer type is not application data does not open.
        let (mut tx, mut rx) = (direction(0, 0, true), direction(0, 0, true));
        let len = tx.seal(APPLICATION_DATA, b"x", &mut out);
        out[0] = HANDSHAKE;
        assert_eq!(rx.open(&mut out[..len]), Err(BadRecord));
    }
}
