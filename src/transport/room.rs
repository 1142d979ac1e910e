//! Where a message is read: its room, and the bytes around it that a read may use.
//! A TLS session reads the record that carries a message so that the record's header
//! lies just before the message's room and its tag just after it, and opens it in
//! place there: the plaintext lands where the message goes, with no copy
//! (`tls::Session::read_into`).

use core::ops::{Deref, DerefMut, Range};

use super::record;
use crate::proto::frame::MAX_ADU_LENGTH;

/// The bytes a read may use before a message's room: a TLS record's header.
pub const BEFORE: usize = record::HEADER;
/// The bytes a read may use after a message's room: the most a TLS record carries
/// after its plaintext (TLS 1.2's explicit nonce, moved out by the opening, and a tag).
pub const AFTER: usize = record::EXPLICIT_NONCE + record::TAG;

/// The buffer of one ADU, with [`BEFORE`] and [`AFTER`] around it. It dereferences
/// to the ADU's 260 bytes.
#[derive(Clone)]
pub struct AduBuf {
    bytes: [u8; BEFORE + MAX_ADU_LENGTH + AFTER],
}

impl AduBuf {
    pub const fn new() -> AduBuf {
        AduBuf { bytes: [0; BEFORE + MAX_ADU_LENGTH + AFTER] }
    }

    /// The ADU's 260 bytes, as an array.
    #[inline]
    pub fn adu_mut(&mut self) -> &mut [u8; MAX_ADU_LENGTH] {
        let Some((adu, _)) = self.bytes[BEFORE..].split_first_chunk_mut() else { unreachable!() };
        adu
    }

    /// The ADU's room, with the bytes around it.
    #[inline]
    pub fn room(&mut self) -> Room<'_> {
        Room { whole: &mut self.bytes, at: BEFORE, len: MAX_ADU_LENGTH }
    }
}

impl Default for AduBuf {
    fn default() -> Self {
        AduBuf::new()
    }
}

impl Deref for AduBuf {
    type Target = [u8];
    #[inline]
    fn deref(&self) -> &[u8] {
        &self.bytes[BEFORE..BEFORE + MAX_ADU_LENGTH]
    }
}

impl DerefMut for AduBuf {
    #[inline]
    fn deref_mut(&mut self) -> &mut [u8] {
        &mut self.bytes[BEFORE..BEFORE + MAX_ADU_LENGTH]
    }
}

impl core::fmt::Debug for AduBuf {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("AduBuf").finish_non_exhaustive()
    }
}

/// A message's room, `whole[at..at + len]`, and the bytes around it in `whole`
/// (none for a buffer the application gave).
pub struct Room<'a> {
    whole: &'a mut [u8],
    at: usize,
    len: usize,
}

impl<'a> Room<'a> {
    /// `msg` alone, with nothing around it.
    #[inline]
    pub fn bare(msg: &'a mut [u8]) -> Room<'a> {
        let len = msg.len();
        Room { whole: msg, at: 0, len }
    }

    /// The message's room.
    #[inline]
    pub fn msg(&mut self) -> &mut [u8] {
        &mut self.whole[self.at..self.at + self.len]
    }

    /// The message's room, to read.
    #[inline]
    pub fn msg_ref(&self) -> &[u8] {
        &self.whole[self.at..self.at + self.len]
    }

    /// The room's size: the message's length at most.
    #[inline]
    pub fn size(&self) -> usize {
        self.len
    }

    /// The bytes a read into `msg()[range]` may use, and where `msg()[range]` lies in
    /// them: from the start of the buffer when the read is the message's first (the
    /// bytes before the room are free), else from `range.start` (the message's bytes
    /// before it are kept); up to the end of the buffer.
    #[inline]
    pub fn around(&mut self, range: Range<usize>) -> (&mut [u8], Range<usize>) {
        debug_assert!(range.start <= range.end && range.end <= self.len);
        let from = if range.start == 0 { 0 } else { self.at + range.start };
        (&mut self.whole[from..], self.at + range.start - from..self.at + range.end - from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A message's first read may use the bytes before the room; a later read of the
    /// same message sees none of the bytes already read.
    #[test]
    fn around_keeps_what_was_read() {
        let mut adu = AduBuf::new();
        let mut room = adu.room();
        let (whole, at) = room.around(0..MAX_ADU_LENGTH);
        assert_eq!((whole.len(), at.clone()), (BEFORE + MAX_ADU_LENGTH + AFTER, BEFORE..BEFORE + MAX_ADU_LENGTH));
        whole[at.start..at.start + 3].copy_from_slice(b"abc");
        let (whole, at) = room.around(3..MAX_ADU_LENGTH);
        assert_eq!((whole.len(), at.clone()), (MAX_ADU_LENGTH - 3 + AFTER, 0..MAX_ADU_LENGTH - 3));
        whole[at].fill(b'z');
        assert_eq!(&room.msg_ref()[..4], b"abcz");
        let mut bare = [0u8; 8];
        let mut room = Room::bare(&mut bare);
        assert_eq!(room.around(0..8).1, 0..8);
        assert_eq!(room.around(2..6).1, 0..4);
    }
}
