//! Data helpers: bits packed in bytes, and floats split over two registers
//! (libmodbus 3.1.11+ semantics; see the tests for where Debian's 3.1.6 differs).

/// `dest[idx + i] = bit i of value`, for i in 0..8.
pub fn set_bits_from_byte(dest: &mut [u8], value: u8) {
    for (i, d) in dest.iter_mut().take(8).enumerate() {
        *d = (value >> i) & 1;
    }
}

/// Unpacks `dest.len()` bits, LSB first, from `packed`.
pub fn set_bits_from_bytes(dest: &mut [u8], packed: &[u8]) {
    // 64 bits at a time (sizes the compiler knows, so the inner loop unrolls), then
    // 8 at a time: a byte's bits spread to one 0/1 byte each.
    let blocks = (dest.len() / 64).min(packed.len() / 8);
    let (dest_blocks, dest) = dest.split_at_mut(blocks * 64);
    let (packed_blocks, packed) = packed.split_at(blocks * 8);
    for (block, bytes) in dest_blocks.chunks_exact_mut(64).zip(packed_blocks.chunks_exact(8)) {
        for (eight, &byte) in block.chunks_exact_mut(8).zip(bytes) {
            eight.copy_from_slice(&SPREAD_BITS[byte as usize].to_le_bytes());
        }
    }
    let mut chunks = dest.chunks_exact_mut(8);
    let mut bytes = packed.iter();
    for (chunk, &byte) in (&mut chunks).zip(&mut bytes) {
        chunk.copy_from_slice(&SPREAD_BITS[byte as usize].to_le_bytes());
    }
    let rest = chunks.into_remainder();
    if let Some(&byte) = bytes.next() {
        set_bits_from_byte(rest, byte);
    }
}

/// `SPREAD_BITS[b]` holds bit i of `b` in its byte i (little-endian).
static SPREAD_BITS: [u64; 256] = spread_bits();

const fn spread_bits() -> [u64; 256] {
    let mut table = [0u64; 256];
    let mut b = 0;
    while b < 256 {
        let mut i = 0;
        while i < 8 {
            table[b] |= (((b >> i) & 1) as u64) << (8 * i);
            i += 1;
        }
        b += 1;
    }
    table
}

/// ORs `src[i] << i` together (at most 8 values; they are assumed to be 0 or 1).
pub fn byte_from_bits(src: &[u8]) -> u8 {
    src.iter().take(8).enumerate().fold(0u8, |acc, (i, &b)| acc | (b << i))
}

/// Registers to the wire: `values[i]` big-endian at `out[2 * i..]`, for as many as both
/// hold. A plain zip: the compiler turns it into vector shifts.
#[inline]
pub fn registers_to_be(values: &[u16], out: &mut [u8]) {
    for (pair, v) in out.chunks_exact_mut(2).zip(values) {
        pair.copy_from_slice(&v.to_be_bytes());
    }
}

/// Registers from the wire: `regs[i]` from the big-endian pair at `bytes[2 * i..]`, for
/// as many as both hold.
pub fn registers_from_be(bytes: &[u8], regs: &mut [u16]) {
    for (r, pair) in regs.iter_mut().zip(bytes.chunks_exact(2)) {
        *r = u16::from_be_bytes([pair[0], pair[1]]);
    }
}

/// Byte orders of a float in two registers, named after the order of its IEEE-754
/// bytes A (most significant) to D in register 0 high, register 0 low, register 1
/// high, register 1 low.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FloatOrder {
    Abcd,
    Dcba,
    Badc,
    Cdab,
}

impl FloatOrder {
    /// Positions of A, B, C, D in the four wire bytes.
    const fn layout(self) -> [usize; 4] {
        match self {
            FloatOrder::Abcd => [0, 1, 2, 3],
            FloatOrder::Dcba => [3, 2, 1, 0],
            FloatOrder::Badc => [1, 0, 3, 2],
            FloatOrder::Cdab => [2, 3, 0, 1],
        }
    }
}

pub fn get_float(regs: [u16; 2], order: FloatOrder) -> f32 {
    let wire = [(regs[0] >> 8) as u8, regs[0] as u8, (regs[1] >> 8) as u8, regs[1] as u8];
    let mut be = [0u8; 4];
    for (abcd, &pos) in order.layout().iter().enumerate() {
        be[abcd] = wire[pos];
    }
    f32::from_be_bytes(be)
}

pub fn set_float(f: f32, order: FloatOrder) -> [u16; 2] {
    let be = f.to_be_bytes();
    let mut wire = [0u8; 4];
    for (abcd, &pos) in order.layout().iter().enumerate() {
        wire[pos] = be[abcd];
    }
    [u16::from_be_bytes([wire[0], wire[1]]), u16::from_be_bytes([wire[2], wire[3]])]
}

#[cfg(test)]
mod tests {
    use super::*;

    const F: f32 = 123456.0; // bits 0x47F12000

    #[test]
    fn float_setters_follow_3_1_12() {
        // Upstream >= 3.1.11 values (reference 3.10); Debian 3.1.6 (= 3.1.8..3.1.10)
        // swaps the bytes inside each register for the setters: abcd gives
        // {0xF147, 0x0020} there. That difference is deliberate (3.1.12 is the API level).
        assert_eq!(set_float(F, FloatOrder::Abcd), [0x47F1, 0x2000]);
        assert_eq!(set_float(F, FloatOrder::Dcba), [0x0020, 0xF147]);
        assert_eq!(set_float(F, FloatOrder::Badc), [0xF147, 0x0020]);
        assert_eq!(set_float(F, FloatOrder::Cdab), [0x2000, 0x47F1]);
    }

    #[test]
    fn float_getters_match_every_release_since_3_1_8() {
        assert_eq!(get_float([0x47F1, 0x2000], FloatOrder::Abcd), F);
        assert_eq!(get_float([0x0020, 0xF147], FloatOrder::Dcba), F);
        assert_eq!(get_float([0xF147, 0x0020], FloatOrder::Badc), F);
        assert_eq!(get_float([0x2000, 0x47F1], FloatOrder::Cdab), F);
    }

    #[test]
    fn float_round_trips() {
        for order in [FloatOrder::Abcd, FloatOrder::Dcba, FloatOrder::Badc, FloatOrder::Cdab] {
            for f in [0.0f32, -1.5, 3.4e38, f32::MIN_POSITIVE] {
                assert_eq!(get_float(set_float(f, order), order).to_bits(), f.to_bits());
            }
        }
    }

    #[test]
    fn bits() {
        let mut d = [9u8; 10];
        set_bits_from_byte(&mut d[1..], 0b1010_0101);
        assert_eq!(d, [9, 1, 0, 1, 0, 0, 1, 0, 1, 9]);
        let mut d = [9u8; 12];
        set_bits_from_bytes(&mut d[..10], &[0xCD, 0x01]);
        assert_eq!(d, [1, 0, 1, 1, 0, 0, 1, 1, 1, 0, 9, 9]);
        assert_eq!(byte_from_bits(&[1, 0, 1, 1, 0, 0, 1, 1]), 0xCD);
        assert_eq!(byte_from_bits(&[1, 1, 1]), 0x07);
    }

    #[test]
    fn registers_cross_the_wire_big_endian_at_every_length() {
        // Every length up to a full 125-register read (the compiled loop goes 16
        // registers at a time, then 4, then one); the sentinels after the last pair
        // and register must survive.
        for n in 0usize..=125 {
            let values: Vec<u16> = (0..n as u16).map(|i| 0x0102u16.wrapping_mul(i + 1) ^ 0xA55A).collect();
            let mut wire = vec![0xEEu8; 2 * n + 3];
            registers_to_be(&values, &mut wire);
            for (i, v) in values.iter().enumerate() {
                assert_eq!([wire[2 * i], wire[2 * i + 1]], [(v >> 8) as u8, *v as u8], "n={n} i={i}");
            }
            assert_eq!(&wire[2 * n..], &[0xEE; 3], "n={n}: nothing written past the values");
            let mut back = vec![0xBEEFu16; n + 2];
            registers_from_be(&wire[..2 * n], &mut back);
            assert_eq!(&back[..n], &values[..], "n={n}");
            assert_eq!(&back[n..], &[0xBEEF; 2], "n={n}: nothing written past the pairs");
        }
    }

    #[test]
    fn registers_stop_at_the_shorter_side() {
        let mut wire = [0u8; 5]; // room for two pairs and a half
        registers_to_be(&[0x1234, 0x5678, 0x9ABC], &mut wire);
        assert_eq!(wire, [0x12, 0x34, 0x56, 0x78, 0]);
        let mut regs = [0u16; 3];
        registers_from_be(&[0xAB, 0xCD, 0xEF], &mut regs); // one pair and a stray byte
        assert_eq!(regs, [0xABCD, 0, 0]);
    }
}
