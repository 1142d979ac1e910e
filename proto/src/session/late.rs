//! The transaction ids of a client's requests that left the wire before their
//! answer came (their response timeout passed, or they were cancelled): an answer
//! that comes later carries one of them and is dropped, never taken for another
//! request's. One store per context, for every driver: the blocking calls and the
//! event-driven client's pipeline ask the same one.

use std::collections::VecDeque;

/// How many ids are remembered: the deepest pipelining (256) twice over.
pub const REMEMBERED: usize = 512;

/// The ids (TCP transaction ids), oldest first.
#[derive(Debug, Default)]
pub struct LateIds {
    ids: VecDeque<u16>,
}

impl LateIds {
    /// `tid`'s answer, should it come, is late.
    pub fn push(&mut self, tid: u16) {
        if self.ids.len() == REMEMBERED {
            self.ids.pop_front();
        }
        self.ids.push_back(tid);
    }

    /// True when `tid` is a late answer's (it is forgotten then: dropped once).
    pub fn take(&mut self, tid: u16) -> bool {
        match self.ids.iter().rposition(|&t| t == tid) {
            Some(k) => {
                self.ids.remove(k);
                true
            }
            None => false,
        }
    }

    /// `tid` is used again by a new request: its answer is that request's.
    pub fn reused(&mut self, tid: u16) {
        if !self.ids.is_empty() {
            self.ids.retain(|&t| t != tid);
        }
    }

    pub fn len(&self) -> usize {
        self.ids.len()
    }

    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn late_ids_are_dropped_once_and_forgotten_when_used_again() {
        let mut late = LateIds::default();
        late.push(7);
        late.push(9);
        assert!(late.take(9));
        assert!(!late.take(9), "dropped once");
        late.reused(7);
        assert!(!late.take(7), "a new request's answer");
        for t in 0..(REMEMBERED as u16 + 10) {
            late.push(t);
        }
        assert_eq!(late.len(), REMEMBERED);
        assert!(!late.take(3), "the oldest are forgotten");
        assert!(late.take(REMEMBERED as u16 + 9));
    }
}
