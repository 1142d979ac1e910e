//! CRC-16/MODBUS: reflected polynomial 0xA001, initial value 0xFFFF, sent low byte first.

/// Lookup table for one byte at a time, computed at compile time from the polynomial.
const TABLE: [u16; 256] = {
    let mut table = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u16;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 != 0 { (crc >> 1) ^ 0xA001 } else { crc >> 1 };
            bit += 1;
        }
        table[i] = crc;
        i += 1;
    }
    table
};

/// The CRC of `bytes` as a number; on the wire it goes `crc as u8` first, then `crc >> 8`.
pub fn crc16(bytes: &[u8]) -> u16 {
    bytes.iter().fold(0xFFFF, |crc, &b| (crc >> 8) ^ TABLE[((crc ^ b as u16) & 0xFF) as usize])
}

/// Reads the CRC stored (low byte first) in the last two bytes of an RTU frame.
pub fn stored_crc(frame: &[u8]) -> Option<u16> {
    match frame {
        [.., lo, hi] => Some(u16::from_le_bytes([*lo, *hi])),
        _ => None,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Bitwise reference straight from the definition, to check the table.
    fn crc16_bitwise(bytes: &[u8]) -> u16 {
        let mut crc = 0xFFFFu16;
        for &b in bytes {
            crc ^= b as u16;
            for _ in 0..8 {
                crc = if crc & 1 != 0 { (crc >> 1) ^ 0xA001 } else { crc >> 1 };
            }
        }
        crc
    }

    #[test]
    fn check_value() {
        // The catalogued check value of CRC-16/MODBUS over "123456789".
        assert_eq!(crc16(b"123456789"), 0x4B37);
    }

    #[test]
    fn table_matches_definition() {
        let data: Vec<u8> = (0..=255u8).collect();
        for n in 0..data.len() {
            assert_eq!(crc16(&data[..n]), crc16_bitwise(&data[..n]));
        }
    }

    #[test]
    fn libmodbus_debug_trace_vector() {
        // Write single coil 0x130 ON to slave 0x11, as libmodbus traces it: [8F][59].
        let frame = [0x11, 0x05, 0x01, 0x30, 0xFF, 0x00];
        assert_eq!(crc16(&frame).to_le_bytes(), [0x8F, 0x59]);
    }

    #[test]
    fn seed_frames() {
        // Frames of the protocol seed documents (shared/seeds), CRC low byte first.
        let frames: &[&[u8]] = &[
            // 11 03 006B 0003 -> 7687 (seed 004: read holding registers 40108..40110)
            &[0x11, 0x03, 0x00, 0x6B, 0x00, 0x03, 0x76, 0x87],
        ];
        for f in frames {
            let (body, _) = f.split_at(f.len() - 2);
            assert_eq!(Some(crc16(body)), stored_crc(f), "frame {f:02X?}");
        }
    }
}
