//! Receiving one message, as a state machine without I/O.
//!
//! The driver asks [`Receiver::step`] what to do, does it (a peek, a wait, a read),
//! and reports the result with [`Receiver::done`] (or [`Receiver::stopped`] when the
//! context was closed under it). Time enters as an argument: the clock's reading when
//! the receive starts, and a clock the machine reads only when it needs a new
//! deadline. Every receive of every framing and line goes through this one machine:
//!
//! - **Timeouts.** The first wait ends at the response timeout (a confirmation) or
//!   the indication timeout (an indication; zero: never). Once bytes of the message
//!   are there, each wait ends a byte timeout after the last bytes came; with no byte
//!   timeout, the first deadline stands. A wait that ends in a timeout fails the
//!   receive with ETIMEDOUT, except while an RTU diagnostics request is searching for
//!   its CRC: then the frame ends where the line went quiet.
//! - **How much to read.** Never past the end of the message on a server or on a
//!   client that must leave a late confirmation on the line (`read_ahead` off), so the
//!   next message stays in the kernel; a client that owns its line reads all there
//!   is, and what lies past the message waits in the [`ReadAhead`] buffer for the next
//!   receive, which takes it before reading the line again.
//! - **When to wait.** Once bytes came, the rest usually came with them: a line that
//!   can be read without waiting is read so first, and waited on only when empty. A
//!   socket server first peeks: when the whole request is queued it takes exactly
//!   that in one read. A client socket with timed reads makes its first read a
//!   blocking one the kernel ends (one system call where a wait and a read were two).
//! - **Failures and their recovery** (see [`super::after_wait`] and friends): a
//!   failed wait ("select"), a failed read or end of stream ("read", ECONNRESET), too
//!   long a message ("too many data"), an ASCII frame that cannot be decoded or ends
//!   too soon, a bad CRC or LRC, a frame for another slave (ignored, not an error).

use core::time::Duration;

use super::{Recovery, Timeout, Timeouts, Wait, after_bad_checksum, after_read, after_wait};
use crate::ascii;
use crate::error::{Error, Result, errno};
use crate::frame::{Assembler, Framing, MAX_ADU_LENGTH, MsgKind, Progress, RtuIntegrity, rtu_integrity};

/// Bytes a client read past the end of the message it was assembling (or, on ASCII,
/// characters not decoded yet). They are handed out before the line is read again,
/// so reading ahead never changes what a later receive sees; a flush, close, connect
/// or a new descriptor drops them along with the kernel's queue.
#[derive(Clone, Debug)]
pub struct ReadAhead {
    pub buf: [u8; MAX_ADU_LENGTH],
    pub start: usize,
    pub end: usize,
}

impl ReadAhead {
    pub const fn new() -> Self {
        ReadAhead { buf: [0; MAX_ADU_LENGTH], start: 0, end: 0 }
    }

    #[inline]
    pub fn available(&self) -> &[u8] {
        &self.buf[self.start..self.end]
    }

    #[inline]
    pub fn consume(&mut self, n: usize) {
        self.start += n;
        if self.start == self.end {
            self.clear();
        }
    }

    #[inline]
    pub fn clear(&mut self) {
        self.start = 0;
        self.end = 0;
    }

    /// Keeps `rest` (read past a message while this buffer was empty).
    #[inline]
    fn keep(&mut self, rest: &[u8]) {
        if !rest.is_empty() {
            debug_assert!(self.available().is_empty());
            self.buf[..rest.len()].copy_from_slice(rest);
            self.start = 0;
            self.end = rest.len();
        }
    }
}

impl Default for ReadAhead {
    fn default() -> Self {
        Self::new()
    }
}

/// What the line under a receive can do.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct LineCaps {
    /// A stream socket: it can be peeked at.
    pub socket: bool,
    /// A read never blocks (a socket with `MSG_DONTWAIT`, a serial line opened
    /// non-blocking), so the line can be read to see whether bytes are there.
    pub reads_without_waiting: bool,
    /// A blocking read ends by itself within a kernel timeout set from the response
    /// timeout (a client socket the context connected, when that timeout is long
    /// enough for the kernel's timer to be exact enough).
    pub timed_reads: bool,
}

/// Everything a receive needs to know of its context.
#[derive(Clone, Copy, Debug)]
pub struct Settings {
    pub framing: Framing,
    pub kind: MsgKind,
    /// The server answers the function codes beyond libmodbus: their requests are
    /// framed whole (see [`crate::frame::layout`]).
    pub extended: bool,
    /// The length (header + PDU) of the diagnostics request this confirmation
    /// answers, on a serial framing.
    pub expecting: Option<usize>,
    pub timeouts: Timeouts,
    /// `MODBUS_ERROR_RECOVERY_*` bits.
    pub recovery: i32,
    /// The context's slave (-1: unset); serial frames for others are ignored.
    pub slave: i32,
    /// A server that answers several units: serial frames for every unit are taken
    /// (the caller filters them), `slave` notwithstanding.
    pub any_unit: bool,
    /// Read all the line has, keeping what lies past the message (a client that owns
    /// its line); off, never read past the message.
    pub read_ahead: bool,
    /// The character after CR that ends an ASCII frame.
    pub ascii_delimiter: u8,
    pub line: LineCaps,
}

/// Where a read puts its bytes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Dest {
    /// `msg[from..to]`.
    Message { from: usize, to: usize },
    /// The whole of the (empty) read-ahead buffer: ASCII characters.
    ReadAhead,
}

/// How a read runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReadHow {
    /// The line is known to be readable (a wait said so, or a peek saw the bytes).
    Ready,
    /// Take what is queued, never wait: nothing there (or any failure) sends the
    /// receive to a wait, which reports.
    Queued,
    /// A blocking read that the kernel ends before this timeout does (the driver
    /// sets the socket's receive timeout from it); when it ends empty, a wait takes
    /// the rest of the time.
    Within(Timeout),
}

/// What the driver does next.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Step {
    /// Look at what the socket holds, into the read-ahead buffer (empty), without
    /// taking it; `block`: wait for the first byte without end.
    Peek { block: bool },
    /// Wait until the line is readable or the clock reaches `until` (`None`: no end).
    /// Report `Ok(_)` when readable, `Err(TIMED_OUT)` at the deadline.
    Wait { until: Option<Duration> },
    /// Read into `dest`.
    Read { dest: Dest, how: ReadHow },
    /// The receive is over.
    Done(Finished),
    /// The receive is over with a whole, valid message `msg[..len]`, and nothing to
    /// report or recover from (the usual end: the same as `Done` with
    /// [`Finished::frame`]).
    Frame(usize),
}

/// What a receive got, once its end was read (the drivers' one reader turns an
/// [`Outcome`] into this, or into the error).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// A complete, valid message of this length.
    Frame(usize),
    /// A valid serial frame addressed to another slave (libmodbus returns 0).
    Ignored(usize),
}

/// How a receive ended.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Outcome {
    /// A whole, valid message: `msg[..len]`.
    Frame(usize),
    /// A whole, valid serial frame for another slave (libmodbus returns 0).
    Ignored { len: usize, theirs: u8, ours: i32 },
    /// The CRC (RTU) or LRC (ASCII) does not match: EMBBADCRC.
    BadChecksum { lrc: bool, received: u16, computed: u16 },
    /// No message: `error`, printed with `site` in the debug trace (none for a stop).
    Failed { error: Error, site: Option<&'static str> },
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Finished {
    pub outcome: Outcome,
    /// What the driver does before it reports the outcome.
    pub recovery: Recovery,
    /// `msg[..traced]` is what the debug trace shows of the message.
    pub traced: usize,
    /// The message's framing ended (the trace ends its line).
    pub ended: bool,
}

impl Finished {
    /// A whole, valid message of `len` bytes.
    pub const fn frame(len: usize) -> Self {
        Finished { outcome: Outcome::Frame(len), recovery: Recovery::None, traced: len, ended: true }
    }

    /// The step that reports this end.
    fn into_step(self) -> Step {
        match self.outcome {
            Outcome::Frame(len) => Step::Frame(len),
            _ => Step::Done(self),
        }
    }

    fn failed(error: Error, site: &'static str, recovery: Recovery, traced: usize) -> Self {
        Finished { outcome: Outcome::Failed { error, site: Some(site) }, recovery, traced, ended: false }
    }
}

/// What the machine knows of the line.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum LineState {
    /// Nothing yet.
    Unknown,
    /// A peek saw this many bytes.
    Peeked(usize),
    /// A peek saw a whole message of this length: take exactly it.
    Whole(usize),
    /// Bytes are queued (a peek saw them): read without waiting.
    Queued,
    /// Bytes just came: more may have come with them.
    Arrived,
    /// A read that does not wait found nothing: wait.
    Empty,
    /// A wait said the line is readable.
    Readable,
    /// A wait ended at its deadline while an RTU diagnostics request searched for
    /// its CRC: the frame ends here.
    Quiet,
}

/// The step the driver is doing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Pending {
    Nothing,
    Peek,
    Wait,
    /// A read into the message; `queued`: one that does not wait.
    Read {
        queued: bool,
    },
    /// A read into the read-ahead buffer (ASCII characters).
    ReadStaged,
}

impl Pending {
    #[inline]
    fn of(step: &Step) -> Pending {
        match step {
            Step::Peek { .. } => Pending::Peek,
            Step::Wait { .. } => Pending::Wait,
            Step::Read { dest: Dest::ReadAhead, .. } => Pending::ReadStaged,
            Step::Read { how, .. } => Pending::Read { queued: *how == ReadHow::Queued },
            Step::Done(_) | Step::Frame(_) => Pending::Nothing,
        }
    }
}

#[derive(Clone, Debug)]
enum Body {
    Binary(Assembler),
    Ascii(ascii::Decoder),
}

/// The usual first steps of a receive, from its settings alone (nothing left over in
/// `rx`, a binary framing): a socket server peeks (blocking when the indication
/// timeout is infinite); a client socket with timed reads reads within the response
/// timeout. `None`: the first step needs the receive's state ([`Receiver::start`]).
/// Together with [`whole_after_peek`] and [`end`], the usual receive of a socket
/// server ends without that state being built.
#[inline]
pub fn first_step(s: &Settings, rx: &ReadAhead, room: usize) -> Option<Step> {
    if s.framing == Framing::Ascii || !rx.available().is_empty() {
        return None;
    }
    if s.line.socket && s.kind == MsgKind::Indication {
        return Some(Step::Peek { block: s.timeouts.first_wait(s.kind) == Wait::Forever });
    }
    if s.line.timed_reads && s.kind == MsgKind::Confirmation {
        let to = if s.read_ahead { room } else { s.framing.header_length() + 1 };
        return Some(Step::Read { dest: Dest::Message { from: 0, to }, how: ReadHow::Within(s.timeouts.response) });
    }
    None
}

/// After the peek of [`first_step`]: the length of the whole message `peeked`
/// shows, when it shows one that fits `room`. The driver may then take exactly
/// that message and end with [`end`] (or, if the read took less, hand the result
/// to [`Receiver::took`]).
#[inline]
pub fn whole_after_peek(s: &Settings, peeked: &[u8], room: usize) -> Option<usize> {
    assembler(s).whole(peeked).filter(|&len| len <= room)
}

/// The assembler of a binary receive with these settings.
#[inline]
fn assembler(s: &Settings) -> Assembler {
    Assembler::new(s.framing, s.kind).extended_requests(s.extended).expecting(s.expecting)
}

/// The step that ends a receive with the whole binary frame `msg[..len]`.
#[inline]
pub fn end(s: &Settings, msg: &[u8], len: usize) -> Step {
    if s.framing == Framing::Tcp {
        return Step::Frame(len);
    }
    check(s, msg, len).into_step()
}

/// The end of a binary frame `msg[..len]`: an RTU frame must have a good CRC and be
/// for us.
fn check(s: &Settings, msg: &[u8], len: usize) -> Finished {
    let outcome = match s.framing {
        Framing::Rtu => match rtu_integrity(&msg[..len], s.slave) {
            RtuIntegrity::Ok => Outcome::Frame(len),
            RtuIntegrity::BadCrc(received, computed) => Outcome::BadChecksum { lrc: false, received, computed },
            RtuIntegrity::OtherSlave(..) if s.any_unit => Outcome::Frame(len),
            RtuIntegrity::OtherSlave(theirs, ours) => Outcome::Ignored { len, theirs, ours },
        },
        _ => Outcome::Frame(len),
    };
    ended(s, outcome, len)
}

fn ended(s: &Settings, outcome: Outcome, len: usize) -> Finished {
    let recovery = match outcome {
        Outcome::BadChecksum { .. } => after_bad_checksum(s.recovery),
        _ => Recovery::None,
    };
    Finished { outcome, recovery, traced: len, ended: true }
}

/// One receive (see the module's documentation).
#[derive(Clone, Debug)]
pub struct Receiver {
    body: Body,
    /// Bytes of `msg` written (by reads, or taken from the read-ahead buffer).
    filled: usize,
    /// When the current wait ends (`None`: never).
    deadline: Option<Duration>,
    /// Bytes of the message came since the last wait: the next wait gets a fresh
    /// byte timeout (the clock is read then, and only then).
    rearm: bool,
    line: LineState,
    pending: Pending,
    finished: Option<Finished>,
}

impl Receiver {
    /// A receive that starts now; `now` reads the driver's monotonic clock, and is
    /// called only when the first wait has an end.
    #[inline]
    pub fn new(s: &Settings, now: impl FnOnce() -> Duration) -> Self {
        let deadline = match s.timeouts.first_wait(s.kind) {
            Wait::For(t) => Some(now() + t.duration()),
            Wait::Forever | Wait::Left => None,
        };
        let body = match s.framing {
            Framing::Ascii => Body::Ascii(ascii::Decoder::with_delimiter(s.ascii_delimiter)),
            _ => Body::Binary(assembler(s)),
        };
        Receiver {
            body,
            filled: 0,
            deadline,
            rearm: false,
            line: LineState::Unknown,
            pending: Pending::Nothing,
            finished: None,
        }
    }

    /// The first step: [`Receiver::step`], with the usual beginnings decided at once
    /// (see [`first_step`]).
    #[inline]
    pub fn start(&mut self, s: &Settings, msg: &mut [u8], rx: &mut ReadAhead, now: impl FnOnce() -> Duration) -> Step {
        match first_step(s, rx, msg.len()) {
            Some(step) => {
                self.pending = Pending::of(&step);
                step
            }
            None => self.step(s, msg, rx, now),
        }
    }

    /// The receive after its first step was taken by [`first_step`] (the driver builds
    /// this state only when that step did not end the receive): as [`Receiver::new`]
    /// then [`Receiver::start`], the receive having started at `started`.
    #[inline]
    pub fn after_first(s: &Settings, first: &Step, started: Duration) -> Self {
        let mut r = Receiver::new(s, || started);
        r.pending = Pending::of(first);
        r
    }

    /// What to do next. `msg` receives the message (at least the framing's largest
    /// ADU); `rx` is the context's read-ahead buffer; `now` reads the clock, called
    /// only for the deadline of a wait that follows new bytes.
    pub fn step(&mut self, s: &Settings, msg: &mut [u8], rx: &mut ReadAhead, now: impl FnOnce() -> Duration) -> Step {
        debug_assert_eq!(self.pending, Pending::Nothing, "step() before done() of the last step");
        if let Some(f) = self.finished.take() {
            return Step::Done(f);
        }
        let fed = match &self.body {
            Body::Binary(asm) => asm.len(),
            Body::Ascii(_) => return self.step_ascii(s, msg, rx, now),
        };
        if self.filled > fed {
            if let Some(f) = self.assemble(s, msg, rx) {
                return f.into_step();
            }
        }
        loop {
            let avail = rx.available();
            if avail.is_empty() {
                break;
            }
            // Left over from an earlier read: take only what this message needs, so
            // whatever stays behind keeps its order. They count as arriving now.
            let n = self.wanted().min(avail.len());
            msg[self.filled..self.filled + n].copy_from_slice(&avail[..n]);
            rx.consume(n);
            self.filled += n;
            self.bytes_came();
            if let Some(f) = self.assemble(s, msg, rx) {
                return f.into_step();
            }
        }
        let Body::Binary(asm) = &self.body else { unreachable!() };
        let from = self.filled;
        let to = if s.read_ahead { msg.len() } else { from + asm.wanted() };
        let message = Dest::Message { from, to };
        let line = s.line;
        let read = |how| Step::Read { dest: message, how };
        let step = match self.line {
            LineState::Quiet => {
                let len = asm.len();
                return end(s, msg, len);
            }
            LineState::Unknown if from == 0 && line.socket && s.kind == MsgKind::Indication => {
                Step::Peek { block: self.deadline.is_none() }
            }
            LineState::Unknown if from == 0 && line.timed_reads && s.kind == MsgKind::Confirmation => {
                read(ReadHow::Within(s.timeouts.response))
            }
            LineState::Peeked(n) => {
                // Peeked into the read-ahead buffer, which is empty otherwise.
                match asm.whole(&rx.buf[..n]).filter(|&len| len <= msg.len()) {
                    Some(len) => {
                        self.line = LineState::Whole(len);
                        Step::Read { dest: Dest::Message { from: 0, to: len }, how: ReadHow::Ready }
                    }
                    None => {
                        self.line = LineState::Queued;
                        read(ReadHow::Queued)
                    }
                }
            }
            LineState::Queued => read(ReadHow::Queued),
            LineState::Unknown | LineState::Arrived if from > 0 && line.reads_without_waiting => read(ReadHow::Queued),
            LineState::Readable | LineState::Whole(_) => read(ReadHow::Ready),
            _ => Step::Wait { until: self.wait_deadline(s, now) },
        };
        self.pending = Pending::of(&step);
        step
    }

    /// The result of the last step: bytes peeked or read, `Ok(_)` for a wait that
    /// found the line readable, or the error (`TIMED_OUT` when a wait reached its
    /// deadline).
    #[inline]
    pub fn done(&mut self, s: &Settings, result: Result<usize>) {
        let pending = core::mem::replace(&mut self.pending, Pending::Nothing);
        let mode = s.recovery;
        match pending {
            Pending::Nothing => debug_assert!(false, "done() without a step"),
            Pending::Peek => {
                self.line = match result {
                    Ok(n) if n > 0 => LineState::Peeked(n),
                    _ => LineState::Empty,
                }
            }
            Pending::Wait => match result {
                Ok(_) => self.line = LineState::Readable,
                Err(Error::TIMED_OUT) if matches!(&self.body, Body::Binary(a) if a.searching_crc()) => {
                    self.line = LineState::Quiet;
                }
                Err(e) => self.finished = Some(Finished::failed(e, "select", after_wait(mode, e), self.traced())),
            },
            Pending::Read { .. } | Pending::ReadStaged => match result {
                Ok(n) if n > 0 => {
                    if pending == Pending::ReadStaged {
                        // ASCII keeps its decoded bytes in the decoder: `filled`
                        // holds the characters the read put in the read-ahead buffer.
                        self.filled = n;
                    } else {
                        self.filled += n;
                    }
                    self.bytes_came();
                }
                // A read that does not wait, or one the kernel ended empty: wait.
                _ if pending == (Pending::Read { queued: true }) => self.line = LineState::Empty,
                Err(Error(errno::EAGAIN | errno::EINTR)) => self.line = LineState::Empty,
                Ok(_) | Err(Error::CONN_RESET) => {
                    let e = Error::CONN_RESET;
                    self.finished = Some(Finished::failed(e, "read", after_read(mode, e), self.traced()));
                }
                Err(e) => self.finished = Some(Finished::failed(e, "read", after_read(mode, e), self.traced())),
            },
        }
    }

    /// [`Receiver::done`] then [`Receiver::step`], in one call: the result of the
    /// last step, and what to do next. The usual transitions are taken directly: a
    /// peek that shows a whole request (take exactly it), a read that brings a whole
    /// message (its end).
    #[inline]
    pub fn next(
        &mut self,
        s: &Settings,
        result: Result<usize>,
        msg: &mut [u8],
        rx: &mut ReadAhead,
        now: impl FnOnce() -> Duration,
    ) -> Step {
        // (A read or a peek is pending only on binary framings, and never once the
        // receive is finished.)
        if let Ok(n) = result
            && n > 0
            && let Body::Binary(asm) = &self.body
        {
            if self.pending == Pending::Peek {
                if let Some(len) = asm.whole(&rx.buf[..n]).filter(|&len| len <= msg.len()) {
                    self.line = LineState::Whole(len);
                    self.pending = Pending::Read { queued: false };
                    return Step::Read { dest: Dest::Message { from: 0, to: len }, how: ReadHow::Ready };
                }
            } else if self.filled == 0 && matches!(self.pending, Pending::Read { .. }) {
                return self.first_bytes(s, n, msg, rx, now);
            }
        }
        self.done(s, result);
        self.step(s, msg, rx, now)
    }

    /// After a peek of `peeked`: the length of the whole message it shows, when it
    /// shows one that fits `room`. The driver may then take exactly that message and
    /// report it with [`Receiver::took`] instead of reporting the peek.
    #[inline]
    pub fn whole_after_peek(&self, s: &Settings, peeked: &[u8], room: usize) -> Option<usize> {
        match &self.body {
            Body::Binary(_) if self.pending == Pending::Peek => whole_after_peek(s, peeked, room),
            _ => None,
        }
    }

    /// The result of reading the whole message [`Receiver::whole_after_peek`] found,
    /// and what to do next.
    #[inline]
    pub fn took(
        &mut self,
        s: &Settings,
        len: usize,
        result: Result<usize>,
        msg: &mut [u8],
        rx: &mut ReadAhead,
        now: impl FnOnce() -> Duration,
    ) -> Step {
        if matches!(result, Ok(n) if n == len) {
            self.pending = Pending::Nothing;
            self.filled = len;
            return end(s, msg, len);
        }
        self.line = LineState::Whole(len);
        self.pending = Pending::Read { queued: false };
        self.next(s, result, msg, rx, now)
    }

    /// The first bytes of the message came (`n` of them, in `msg`): the end when they
    /// hold the whole message (what lies past it goes to `rx`), else the next step.
    #[inline]
    fn first_bytes(
        &mut self,
        s: &Settings,
        n: usize,
        msg: &mut [u8],
        rx: &mut ReadAhead,
        now: impl FnOnce() -> Duration,
    ) -> Step {
        self.pending = Pending::Nothing;
        let Body::Binary(asm) = &self.body else { unreachable!("binary framings only") };
        let len = match self.line {
            LineState::Whole(len) if len == n => Some(len),
            _ => asm.whole(&msg[..n]),
        };
        if let Some(len) = len {
            rx.keep(&msg[len..n]);
            self.filled = len;
            return end(s, msg, len);
        }
        self.filled = n;
        self.bytes_came();
        self.step(s, msg, rx, now)
    }

    /// The context was closed under the last step (from a signal handler or another
    /// thread): the receive ends with `Error::STOPPED`, no recovery, nothing printed.
    pub fn stopped(&mut self) {
        self.pending = Pending::Nothing;
        self.finished = Some(Finished {
            outcome: Outcome::Failed { error: Error::STOPPED, site: None },
            recovery: Recovery::None,
            traced: self.traced(),
            ended: false,
        });
    }

    /// Some of the message came: a receive that waits with nothing of its message
    /// may be dropped and started again when bytes come (an indication's first wait
    /// has no end).
    pub fn started(&self) -> bool {
        self.traced() > 0
    }

    /// Bytes of the message accepted so far (what the trace shows of it).
    fn traced(&self) -> usize {
        match &self.body {
            Body::Binary(_) => self.filled,
            Body::Ascii(d) => d.len(),
        }
    }

    fn wanted(&self) -> usize {
        match &self.body {
            Body::Binary(a) => a.wanted(),
            Body::Ascii(_) => 0,
        }
    }

    /// Bytes came: the next wait gets a fresh byte timeout, or, with none, the
    /// current deadline stands. On ASCII that holds only once the characters prove
    /// to be inside a frame (see `step_ascii`).
    #[inline]
    fn bytes_came(&mut self) {
        self.line = LineState::Arrived;
        self.rearm = !matches!(self.body, Body::Ascii(_));
    }

    /// The deadline of the wait about to start: a byte timeout from `now` when bytes
    /// came since the last wait, else the current one.
    fn wait_deadline(&mut self, s: &Settings, now: impl FnOnce() -> Duration) -> Option<Duration> {
        if core::mem::take(&mut self.rearm) {
            if let Wait::For(t) = s.timeouts.after_bytes() {
                self.deadline = Some(now() + t.duration());
            }
        }
        self.deadline
    }

    /// Feeds the assembler the bytes of `msg` it has not seen; the finished receive
    /// when the message is complete (what lies past it goes to `rx`) or too long.
    fn assemble(&mut self, s: &Settings, msg: &[u8], rx: &mut ReadAhead) -> Option<Finished> {
        let Body::Binary(asm) = &mut self.body else { return None };
        let filled = self.filled;
        if asm.is_empty() && filled > 0 {
            // The usual case: one read brought the whole message.
            if let Some(len) = asm.whole(&msg[..filled]) {
                rx.keep(&msg[len..filled]);
                self.filled = len;
                return Some(check(s, msg, len));
            }
        }
        while asm.len() < filled {
            let start = asm.len();
            let n = asm.wanted().min(filled - start);
            match asm.received(&msg[..start + n], n) {
                Ok(Progress::NeedMore(_)) => {}
                Ok(Progress::Complete(len)) => {
                    rx.keep(&msg[len..filled]);
                    self.filled = len;
                    return Some(check(s, msg, len));
                }
                Err(e) => {
                    rx.keep(&msg[start + n..filled]);
                    return Some(Finished::failed(e, "too many data", Recovery::None, start + n));
                }
            }
        }
        None
    }

    /// The end of a binary frame `msg[..len]`: an RTU frame must have a good CRC and
    /// be for us.
    /// ASCII: characters are read into the read-ahead buffer and decoded from there
    /// (a frame ends at its delimiter, so nothing past it is taken as part of it);
    /// every read follows a wait.
    fn step_ascii(&mut self, s: &Settings, msg: &mut [u8], rx: &mut ReadAhead, now: impl FnOnce() -> Duration) -> Step {
        if self.filled > 0 {
            rx.start = 0;
            rx.end = core::mem::take(&mut self.filled);
        }
        let Body::Ascii(decoder) = &mut self.body else { unreachable!() };
        if !rx.available().is_empty() {
            let mut used = 0;
            let mut outcome = None;
            for &c in rx.available() {
                used += 1;
                match decoder.feed(c, msg) {
                    Ok(ascii::Step::NeedMore) => {}
                    Ok(ascii::Step::Complete(len)) => {
                        outcome = Some(Ok(len));
                        break;
                    }
                    Err(e) => {
                        outcome = Some(Err(e));
                        break;
                    }
                }
            }
            rx.consume(used);
            match outcome {
                Some(Ok(len)) => return self.check_ascii(s, msg, len).into_step(),
                Some(Err(e)) => {
                    let traced = decoder.len();
                    return Step::Done(Finished::failed(e, "invalid ASCII frame", Recovery::None, traced));
                }
                // Characters (read now, or left over from an earlier read) that are
                // inside a frame: the byte timeout runs.
                None if decoder.in_frame() => self.rearm = true,
                None => {}
            }
        }
        if self.line == LineState::Readable {
            self.pending = Pending::ReadStaged;
            Step::Read { dest: Dest::ReadAhead, how: ReadHow::Ready }
        } else {
            self.pending = Pending::Wait;
            Step::Wait { until: self.wait_deadline(s, now) }
        }
    }

    /// The end of an ASCII frame `msg[..len]` (decoded, LRC last): a good LRC, for
    /// us, and at least as long as its content says (the frame's own length stands
    /// in for the lengths a PDU does not carry).
    fn check_ascii(&self, s: &Settings, msg: &[u8], len: usize) -> Finished {
        let frame = &msg[..len];
        if let Err((received, computed)) = ascii::check_lrc(frame) {
            let outcome = Outcome::BadChecksum { lrc: true, received: received as u16, computed: computed as u16 };
            return ended(s, outcome, len);
        }
        if frame[0] as i32 != s.slave && frame[0] != 0 && !s.any_unit {
            return ended(s, Outcome::Ignored { len, theirs: frame[0], ours: s.slave }, len);
        }
        let whole = len >= 3
            && Assembler::new(Framing::Ascii, s.kind)
                .extended_requests(s.extended)
                .expecting(Some(len - Framing::Ascii.checksum_length()))
                .whole(frame)
                .is_some();
        if !whole {
            // The characters ended before the content did (a byte count or a layout
            // asks for more): refused like an RTU frame cut short.
            let outcome = Outcome::Failed { error: Error::BAD_DATA, site: Some("frame too short") };
            return Finished { outcome, recovery: Recovery::None, traced: len, ended: true };
        }
        ended(s, Outcome::Frame(len), len)
    }
}

#[cfg(test)]
#[path = "receive_tests.rs"]
mod tests;
