//! Typed decoders of responses: what a client call hands back, read from a response
//! that [`crate::confirm::check`] accepted (so its counts agree with its own length
//! and with the request). Each takes the response's PDU (from its function code on)
//! and the count the check returned; the C layer only copies the values out.

/// A big-endian word at `at`.
fn be16(pdu: &[u8], at: usize) -> u16 {
    u16::from_be_bytes([pdu[at], pdu[at + 1]])
}

/// `n` big-endian words from `at` on.
fn words(pdu: &[u8], at: usize, n: usize) -> impl Iterator<Item = u16> + '_ {
    pdu[at..at + 2 * n].chunks_exact(2).map(|w| u16::from_be_bytes([w[0], w[1]]))
}

/// The `n` data bytes of an answer with a byte count (FC 01-04, 11, 17): what follows
/// the count.
pub fn counted_data(pdu: &[u8], n: usize) -> &[u8] {
    &pdu[2..2 + n]
}

/// FC 07: the eight exception status outputs.
pub fn exception_status(pdu: &[u8]) -> u8 {
    pdu[1]
}

/// FC 08: the `n` data words after the sub-function.
pub fn diagnostics_data(pdu: &[u8], n: usize) -> impl Iterator<Item = u16> + '_ {
    words(pdu, 3, n)
}

/// FC 0B: the status word and the event counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommEventCounter {
    pub status: u16,
    pub event_count: u16,
}

impl CommEventCounter {
    pub fn decode(pdu: &[u8]) -> Self {
        CommEventCounter { status: be16(pdu, 1), event_count: be16(pdu, 3) }
    }
}

/// FC 0C: the status word, the counters and the `n` event bytes (newest first).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct CommEventLog<'a> {
    pub status: u16,
    pub event_count: u16,
    pub message_count: u16,
    pub events: &'a [u8],
}

impl<'a> CommEventLog<'a> {
    pub fn decode(pdu: &'a [u8], n: usize) -> Self {
        CommEventLog {
            status: be16(pdu, 2),
            event_count: be16(pdu, 4),
            message_count: be16(pdu, 6),
            events: &pdu[8..8 + n],
        }
    }
}

/// FC 14, one sub-request: its `n` registers.
pub fn file_record_data(pdu: &[u8], n: usize) -> impl Iterator<Item = u16> + '_ {
    words(pdu, 4, n)
}

/// FC 18: the `n` queued values.
pub fn fifo_data(pdu: &[u8], n: usize) -> impl Iterator<Item = u16> + '_ {
    words(pdu, 5, n)
}

/// FC 2B / MEI 0E: one answer of a device-identification stream.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeviceIdAnswer<'a> {
    pub conformity: u8,
    pub more_follows: bool,
    pub next_id: u8,
    count: usize,
    objects: &'a [u8],
}

impl<'a> DeviceIdAnswer<'a> {
    /// `count` is the number of objects the check found whole.
    pub fn decode(pdu: &'a [u8], count: usize) -> Self {
        DeviceIdAnswer { conformity: pdu[3], more_follows: pdu[4] == 0xFF, next_id: pdu[5], count, objects: &pdu[7..] }
    }

    /// The objects in the order received: (id, value).
    pub fn objects(&self) -> impl Iterator<Item = (u8, &'a [u8])> {
        let mut rest = self.objects;
        (0..self.count).map(move |_| {
            let (id, len) = (rest[0], rest[1] as usize);
            let value = &rest[2..2 + len];
            rest = &rest[2 + len..];
            (id, value)
        })
    }

    /// The object id to ask for next in a stream access (`read_code` 1 to 3) that
    /// asked from `object_id`, or `None` when the stream has ended: a specific access
    /// (`read_code` 4), no "more follows", or a device that names no later object and
    /// sent none (it would make the reader loop).
    pub fn next_request(&self, read_code: u8, object_id: u8) -> Option<u8> {
        let stuck = self.next_id <= object_id && self.count == 0;
        (read_code != 4 && self.more_follows && !stuck).then_some(self.next_id)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fixed_layouts() {
        assert_eq!(counted_data(&[3, 4, 0x12, 0x34, 0xAB, 0xCD], 4), [0x12, 0x34, 0xAB, 0xCD]);
        assert_eq!(exception_status(&[7, 0x6D]), 0x6D);
        assert_eq!(diagnostics_data(&[8, 0, 0, 0xA5, 0x37, 1, 2], 2).collect::<Vec<_>>(), [0xA537, 0x0102]);
        assert_eq!(
            CommEventCounter::decode(&[0x0B, 0xFF, 0xFF, 0x01, 0x08]),
            CommEventCounter { status: 0xFFFF, event_count: 0x0108 }
        );
        let log = CommEventLog::decode(&[0x0C, 8, 0, 0, 1, 8, 1, 0x21, 0x20, 0], 2);
        assert_eq!((log.status, log.event_count, log.message_count, log.events), (0, 0x0108, 0x0121, &[0x20, 0][..]));
        let file = [0x14, 6, 5, 6, 0x0D, 0xFE, 0, 0x20];
        assert_eq!(file_record_data(&file, 2).collect::<Vec<_>>(), [0x0DFE, 0x0020]);
        let fifo = [0x18, 0, 6, 0, 2, 0x01, 0xB8, 0x12, 0x84];
        assert_eq!(fifo_data(&fifo, 2).collect::<Vec<_>>(), [0x01B8, 0x1284]);
    }

    #[test]
    fn device_identification_objects_and_stream() {
        // MEI 0E, read code 1, conformity 0x81, more follows, next 2, 2 objects.
        let pdu = [0x2B, 0x0E, 1, 0x81, 0xFF, 2, 2, 0, 4, b'A', b'C', b'M', b'E', 1, 1, b'X'];
        let a = DeviceIdAnswer::decode(&pdu, 2);
        assert_eq!(a.conformity, 0x81);
        assert_eq!(a.objects().collect::<Vec<_>>(), [(0, &b"ACME"[..]), (1, &b"X"[..])]);
        assert_eq!(a.next_request(1, 0), Some(2));
        assert_eq!(a.next_request(4, 0), None);
        // No more: the stream ends; a device that names no later object and sends
        // none must not make the reader loop.
        let done = DeviceIdAnswer::decode(&[0x2B, 0x0E, 1, 0x81, 0, 0, 0], 0);
        assert_eq!(done.next_request(1, 0), None);
        let stuck = DeviceIdAnswer::decode(&[0x2B, 0x0E, 1, 0x81, 0xFF, 3, 0], 0);
        assert_eq!(stuck.next_request(1, 3), None);
        assert_eq!(stuck.next_request(1, 2), Some(3));
    }
}
