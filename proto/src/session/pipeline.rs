//! The requests of an event-driven client, without I/O: the queue, what goes on the
//! wire next, which request an answer belongs to, and when each one times out.
//!
//! A request is queued with its sealed ADU ([`Pipeline::submit`]). Up to
//! `max_in_flight` of them are on the wire at once (always one on a serial framing);
//! [`Pipeline::fill`] moves the next ones from the queue to the wire, their bytes
//! appended to one output buffer so that requests queued together go out in one
//! write. Each request in flight has its own deadline: its response timeout (the
//! context's when it was queued, or its own: [`Pipeline::set_timeout`]) from the
//! moment it went out. An answer is matched by its transaction id on TCP (in any
//! order), or is the answer of the one request in flight on a serial line
//! ([`Pipeline::answer`]); an answer whose request is gone (it timed out, or was
//! cancelled) is recognised by its transaction id and dropped, never handed to
//! another request. A broadcast (unit 0 on a serial framing) expects no answer: it
//! completes once it is out, after the line's turnaround delay.
//!
//! The payload `T` is what the driver does with a completed request (where its values
//! go, whom to tell): the pipeline only carries it.

use core::time::Duration;
use std::collections::VecDeque;

use super::late::LateIds;
use crate::frame::{Framing, MAX_ADU_LENGTH};

/// How many requests a context may hold (queued and in flight): a submit beyond
/// fails with EAGAIN.
pub const MAX_PENDING: usize = 1024;
/// The deepest pipelining: the transaction ids of the requests in flight and of
/// those that timed out stay distinct.
pub const MAX_IN_FLIGHT: usize = 256;
/// The silence after a broadcast on a serial line before the next request (the
/// serial line specification's turnaround delay is 100 to 200 ms).
pub const TURNAROUND: Duration = Duration::from_millis(100);

/// A request and its state.
pub struct Entry<T> {
    pub id: i32,
    /// The sealed ADU (binary, for the response checks), followed by what goes on
    /// the wire when it is not the ADU itself (ASCII: its characters); one
    /// allocation per request.
    bytes: Box<[u8]>,
    adu_len: u16,
    /// The transaction id (TCP).
    pub tid: u16,
    pub broadcast: bool,
    /// Its response timeout, taken when it was queued.
    pub timeout: Duration,
    /// When it went out (set by [`Pipeline::fill`]): its deadline counts from then.
    sent_at: Option<Duration>,
    pub payload: T,
}

impl<T> Entry<T> {
    /// `None` for an ADU longer than a frame.
    fn new(id: i32, adu: &[u8], wire: &[u8], tid: u16, broadcast: bool, timeout: Duration, payload: T) -> Option<Self> {
        if adu.len() > MAX_ADU_LENGTH {
            return None;
        }
        let mut bytes = Vec::with_capacity(adu.len() + wire.len());
        bytes.extend_from_slice(adu);
        bytes.extend_from_slice(wire);
        let adu_len = adu.len() as u16;
        Some(Entry { id, bytes: bytes.into_boxed_slice(), adu_len, tid, broadcast, timeout, sent_at: None, payload })
    }

    /// When it is due: its answer's deadline, or the end of a broadcast's
    /// turnaround; `None` while it has not gone out.
    fn deadline(&self) -> Option<Duration> {
        self.sent_at.map(|t| t + if self.broadcast { TURNAROUND } else { self.timeout })
    }

    /// The request's ADU (sealed, binary).
    pub fn adu(&self) -> &[u8] {
        &self.bytes[..usize::from(self.adu_len)]
    }

    /// The bytes that go on the wire.
    fn wire(&self) -> &[u8] {
        let n = usize::from(self.adu_len);
        if self.bytes.len() > n { &self.bytes[n..] } else { &self.bytes[..n] }
    }
}

/// How a request ended, as the pipeline sees it.
pub enum End {
    /// Its answer: the frame the driver received, to be checked against the request.
    Answered,
    /// Sent, and no answer expected (a broadcast).
    Sent,
    /// Its response timeout passed.
    TimedOut,
    /// Cancelled, or dropped by a close, or by a failure of the line (the errno).
    Failed(i32),
}

/// What an answer the driver received is.
pub enum Answer<T> {
    /// The answer of this request (taken out of the pipeline).
    Of(Entry<T>),
    /// An answer whose request is gone (it timed out or was cancelled): dropped.
    Stale,
    /// An answer no request of this pipeline asked for (an unknown transaction id,
    /// or a serial frame with nothing in flight).
    Unexpected,
}

/// The requests of one context.
pub struct Pipeline<T> {
    framing: Framing,
    /// The requests in flight (the first `sent`, in the order they went out), then
    /// the queue. One deque, grown one entry at a time at first: a context polled
    /// with one request at a time holds room for one.
    entries: VecDeque<Entry<T>>,
    sent: usize,
    max_in_flight: usize,
    /// The bytes of the requests that went in flight and are not written yet.
    out: Vec<u8>,
    next_id: i32,
}

impl<T> Pipeline<T> {
    pub fn new(framing: Framing) -> Self {
        Pipeline { framing, entries: VecDeque::new(), sent: 0, max_in_flight: 1, out: Vec::new(), next_id: 0 }
    }

    /// The framing the pipeline was made for.
    pub fn framing(&self) -> Framing {
        self.framing
    }

    /// The depth of pipelining: 1..=[`MAX_IN_FLIGHT`]; a serial framing keeps 1.
    pub fn set_max_in_flight(&mut self, n: usize) -> bool {
        if n == 0 || n > MAX_IN_FLIGHT {
            return false;
        }
        self.max_in_flight = n;
        true
    }

    pub fn max_in_flight(&self) -> usize {
        if self.framing == Framing::Tcp { self.max_in_flight } else { 1 }
    }

    /// Queued plus in flight.
    pub fn pending(&self) -> usize {
        self.entries.len()
    }

    pub fn in_flight(&self) -> usize {
        self.sent
    }

    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }

    /// The requests in flight, in the order they went out.
    fn on_wire(&self) -> impl Iterator<Item = &Entry<T>> + '_ {
        self.entries.range(..self.sent)
    }

    /// Takes the request at `i` out (in flight when `i < sent`).
    fn take(&mut self, i: usize) -> Entry<T> {
        if i < self.sent {
            self.sent -= 1;
        }
        self.entries.remove(i).expect("index checked")
    }

    /// Queues a request: `adu` sealed (binary), `wire` what goes on the line (the
    /// same bytes, or its ASCII characters: empty means `adu`), `timeout` its
    /// response timeout. Returns its id (>= 0), or `None` when the queue is full.
    pub fn submit(
        &mut self,
        adu: &[u8],
        wire: &[u8],
        tid: u16,
        broadcast: bool,
        timeout: Duration,
        payload: T,
    ) -> Option<i32> {
        let e = Entry::new(self.next_id, adu, wire, tid, broadcast, timeout, payload)?;
        let id = self.insert(self.entries.len(), e)?;
        self.next_id = if id == i32::MAX { 0 } else { id + 1 };
        Some(id)
    }

    /// Queues the next request of a call that takes several (a stream of device
    /// identification objects) under the id of the one that just completed, first in
    /// the queue. `None` when the queue is full.
    pub fn resubmit(
        &mut self,
        id: i32,
        adu: &[u8],
        wire: &[u8],
        tid: u16,
        timeout: Duration,
        payload: T,
    ) -> Option<i32> {
        let e = Entry::new(id, adu, wire, tid, false, timeout, payload)?;
        self.insert(self.sent, e)
    }

    /// Puts `e` at position `at`; `None` when the queue is full.
    fn insert(&mut self, at: usize, e: Entry<T>) -> Option<i32> {
        if self.pending() >= MAX_PENDING {
            return None;
        }
        if self.entries.len() == self.entries.capacity() && self.entries.capacity() < 2 {
            // Room for one more only, while there are few (a deque's first growth
            // makes room for four).
            self.entries.reserve_exact(1);
        }
        let id = e.id;
        self.entries.insert(at, e);
        Some(id)
    }

    /// Moves the next requests from the queue to the wire, as many as the depth
    /// allows (a broadcast holds the line for its turnaround: nothing goes with it
    /// or after it until then); their bytes are appended to [`Pipeline::output`].
    /// Each one's response timeout counts from `now`. `late`: the context's late
    /// transaction ids. Returns how many went.
    pub fn fill(&mut self, now: Duration, late: &mut LateIds) -> usize {
        let mut moved = 0;
        while self.sent < self.entries.len() && self.sent < self.max_in_flight() && !self.on_wire().any(|e| e.broadcast)
        {
            let e = &mut self.entries[self.sent];
            self.out.extend_from_slice(e.wire());
            e.sent_at = Some(now);
            let tid = e.tid;
            // A transaction id used again: its old request's late answer can no
            // longer be told apart; this request's answer wins.
            if self.framing == Framing::Tcp {
                late.reused(tid);
            }
            self.sent += 1;
            moved += 1;
        }
        moved
    }

    /// The last `n` requests [`Pipeline::fill`] moved to the wire count their time
    /// from `now` instead: their write took the frame's time on the line (an RTS
    /// sequence), and the answer's timeout, as a blocking call's, starts when it ends.
    pub fn restart_clocks(&mut self, n: usize, now: Duration) {
        let from = self.sent.saturating_sub(n);
        for e in self.entries.range_mut(from..self.sent) {
            e.sent_at = Some(now);
        }
    }

    /// Request `id`'s response timeout becomes `timeout` (counted from its send,
    /// past or to come); false when no such request is pending.
    pub fn set_timeout(&mut self, id: i32, timeout: Duration) -> bool {
        match self.entries.iter_mut().find(|e| e.id == id) {
            Some(e) => {
                e.timeout = timeout;
                true
            }
            None => false,
        }
    }

    /// Bytes to write.
    pub fn output(&self) -> &[u8] {
        &self.out
    }

    /// `n` bytes of [`Pipeline::output`] were written.
    pub fn wrote(&mut self, n: usize) {
        self.out.drain(..n.min(self.out.len()));
    }

    /// The earliest time something is due: an answer's deadline or the end of a
    /// broadcast's turnaround.
    pub fn deadline(&self) -> Option<Duration> {
        self.on_wire().filter_map(Entry::deadline).min()
    }

    /// The earliest deadline of a request that waits for an answer (a receive's
    /// time limit).
    pub fn answer_deadline(&self) -> Option<Duration> {
        self.on_wire().filter(|e| !e.broadcast).filter_map(Entry::deadline).min()
    }

    /// The oldest request in flight that expects an answer.
    pub fn first_awaiting(&self) -> Option<&Entry<T>> {
        self.on_wire().find(|e| !e.broadcast)
    }

    /// Expects an answer: a request in flight that is not a broadcast.
    pub fn awaits_answer(&self) -> bool {
        self.on_wire().any(|e| !e.broadcast)
    }

    /// The requests whose time is up at `now`: broadcasts whose turnaround ended
    /// ([`End::Sent`]) and requests whose response timeout passed
    /// ([`End::TimedOut`]), in the order they went out. The ids of those that timed
    /// out join `late`.
    pub fn due(&mut self, now: Duration, late: &mut LateIds) -> Vec<(Entry<T>, End)> {
        let mut ended = Vec::new();
        let mut i = 0;
        while i < self.sent {
            if self.entries[i].deadline().is_some_and(|d| now >= d) {
                let e = self.take(i);
                if e.broadcast {
                    ended.push((e, End::Sent));
                } else {
                    self.forget(e.tid, late);
                    ended.push((e, End::TimedOut));
                }
            } else {
                i += 1;
            }
        }
        ended
    }

    /// Remembers the transaction id of a request that left the wire before its
    /// answer came.
    fn forget(&self, tid: u16, late: &mut LateIds) {
        if self.framing == Framing::Tcp {
            late.push(tid);
        }
    }

    /// The request an answer belongs to. `tid`: the answer's transaction id (TCP);
    /// one of `late` is a late answer's.
    pub fn answer(&mut self, tid: Option<u16>, late: &mut LateIds) -> Answer<T> {
        let index = match (self.framing, tid) {
            (Framing::Tcp, Some(tid)) => self.on_wire().position(|e| e.tid == tid && !e.broadcast),
            (Framing::Tcp, None) => None,
            _ => self.on_wire().position(|e| !e.broadcast),
        };
        match index {
            Some(i) => Answer::Of(self.take(i)),
            None => match tid {
                Some(tid) if self.framing == Framing::Tcp && late.take(tid) => Answer::Stale,
                _ => Answer::Unexpected,
            },
        }
    }

    /// Takes request `id` out, wherever it is. A request on the wire is remembered
    /// as gone (its answer will be dropped); one partly written cannot be taken back
    /// from the line, so its bytes go out all the same. `late`: as for [`Pipeline::due`].
    pub fn cancel(&mut self, id: i32, late: &mut LateIds) -> Option<Entry<T>> {
        let i = self.entries.iter().position(|e| e.id == id)?;
        let on_wire = i < self.sent;
        let e = self.take(i);
        if on_wire && !e.broadcast {
            self.forget(e.tid, late);
        }
        Some(e)
    }

    /// Takes every request out (a close, a lost line): those in flight first, in the
    /// order they went out, then the queue. The output is dropped.
    pub fn drain(&mut self) -> Vec<Entry<T>> {
        self.out.clear();
        self.sent = 0;
        self.entries.drain(..).collect()
    }

    /// Takes the requests in flight out (the line failed under them), keeping the
    /// queue; the output is dropped.
    pub fn drain_in_flight(&mut self) -> Vec<Entry<T>> {
        self.out.clear();
        let n = std::mem::take(&mut self.sent);
        self.entries.drain(..n).collect()
    }

    /// The ids of the requests, in flight then queued (tests, `modbus_pending`).
    pub fn ids(&self) -> impl Iterator<Item = i32> + '_ {
        self.entries.iter().map(|e| e.id)
    }
}

#[cfg(test)]
#[path = "pipeline_tests.rs"]
mod tests;
