//! The receive machine against a simulated line: bytes arrive at given times, the
//! clock moves only when a step waits, and every step the machine asks for is logged
//! (they are the driver's system calls). Table by table: every framing, split
//! frames, late bytes, a timeout at each boundary, garbage before and after a
//! frame, end of stream, stops, and the recovery each failure asks for.

use std::collections::VecDeque;
use std::format;
use std::string::String;
use std::vec::Vec;

use super::*;
use crate::session::{RECOVERY_LINK, RECOVERY_PROTOCOL};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

/// A line: bytes that arrive at given times, and maybe an end of stream.
struct Line {
    now: Duration,
    arrivals: VecDeque<(Duration, Vec<u8>)>,
    queued: VecDeque<u8>,
    eof: Option<Duration>,
    log: Vec<String>,
    /// Stop the receive (a close from elsewhere) during step number `n`.
    stop_at: Option<usize>,
}

impl Line {
    fn new(arrivals: &[(u64, &[u8])]) -> Self {
        Line {
            now: Duration::ZERO,
            arrivals: arrivals.iter().map(|(t, b)| (ms(*t), b.to_vec())).collect(),
            queued: VecDeque::new(),
            eof: None,
            log: Vec::new(),
            stop_at: None,
        }
    }

    fn eof_at(mut self, t: u64) -> Self {
        self.eof = Some(ms(t));
        self
    }

    fn settle(&mut self) {
        while self.arrivals.front().is_some_and(|(t, _)| *t <= self.now) {
            let (_, bytes) = self.arrivals.pop_front().unwrap();
            self.queued.extend(bytes);
        }
    }

    fn at_eof(&self) -> bool {
        self.queued.is_empty() && self.eof.is_some_and(|t| t <= self.now)
    }

    fn readable(&self) -> bool {
        !self.queued.is_empty() || self.at_eof()
    }

    /// The next time something happens on the line.
    fn next_event(&self) -> Option<Duration> {
        let arrival = self.arrivals.front().map(|(t, _)| *t);
        let eof = self.eof.filter(|&t| t > self.now);
        match (arrival, eof) {
            (Some(a), Some(e)) => Some(a.min(e)),
            (a, e) => a.or(e),
        }
    }

    fn advance(&mut self, t: Duration) {
        self.now = self.now.max(t);
        self.settle();
    }

    /// Blocks until the line is readable or `until`; true when readable.
    fn block(&mut self, until: Option<Duration>) -> bool {
        self.settle();
        if self.readable() {
            return true;
        }
        match (self.next_event(), until) {
            (Some(t), Some(u)) if t > u => {
                self.advance(u);
                false
            }
            (Some(t), _) => {
                self.advance(t);
                true
            }
            (None, Some(u)) => {
                self.advance(u);
                false
            }
            (None, None) => panic!("blocks forever at {:?}: {:?}", self.now, self.log),
        }
    }

    fn take(&mut self, room: &mut [u8]) -> usize {
        let n = room.len().min(self.queued.len());
        for b in room.iter_mut().take(n) {
            *b = self.queued.pop_front().unwrap();
        }
        n
    }

    fn peek(&self, room: &mut [u8]) -> usize {
        let n = room.len().min(self.queued.len());
        for (b, q) in room.iter_mut().zip(self.queued.iter()) {
            *b = *q;
        }
        n
    }

    fn read_result(&mut self, room: &mut [u8]) -> Result<usize> {
        if self.at_eof() { Ok(0) } else { Ok(self.take(room)) }
    }

    /// Runs one receive to its end, calling the machine as the driver does: the
    /// stateless `first_step` when it has one (the state is built after it, only if
    /// it did not end the receive), else `new` and `start`; then `next` with each
    /// result (`stopped` and `step` for a stop).
    fn run(&mut self, s: Settings, msg: &mut [u8], rx: &mut ReadAhead) -> Finished {
        let now = self.now;
        self.settle();
        let first = first_step(&s, rx, msg.len());
        let mut machine: Option<Receiver> = None;
        let mut step = match first {
            Some(step) => step,
            None => machine.insert(Receiver::new(&s, || now)).start(&s, msg, rx, || now),
        };
        let started = now;
        for n in 0..64 {
            let result = match step {
                Step::Done(f) => return f,
                Step::Frame(len) => return Finished::frame(len),
                Step::Peek { block } => {
                    self.log.push(if block { "peek (blocks)" } else { "peek" }.into());
                    if block {
                        self.block(None);
                    }
                    if self.at_eof() {
                        Ok(0)
                    } else {
                        match self.peek(&mut rx.buf) {
                            0 => Err(Error(errno::EAGAIN)),
                            // As the driver: a whole message queued is taken at once.
                            n => {
                                let whole = match &machine {
                                    None => whole_after_peek(&s, &rx.buf[..n], msg.len()),
                                    Some(m) => m.whole_after_peek(&s, &rx.buf[..n], msg.len()),
                                };
                                match whole {
                                    Some(len) => {
                                        self.log.push(format!("read 0..{len}"));
                                        let took = self.take(&mut msg[..len]);
                                        let now = self.now;
                                        step =
                                            match &mut machine {
                                                None if took == len => end(&s, msg, len),
                                                m => m
                                                    .get_or_insert_with(|| Receiver::after_first(&s, &step, now))
                                                    .took(&s, len, Ok(took), msg, rx, || now),
                                            };
                                        continue;
                                    }
                                    None => Ok(n),
                                }
                            }
                        }
                    }
                }
                Step::Wait { until } => {
                    self.log.push(match until {
                        Some(u) => format!("wait until {}", u.as_millis()),
                        None => "wait".into(),
                    });
                    if self.block(until) { Ok(0) } else { Err(Error::TIMED_OUT) }
                }
                Step::Read { dest, how } => {
                    let room = match dest {
                        Dest::Message { from, to } => &mut msg[from..to],
                        Dest::ReadAhead => &mut rx.buf[..],
                    };
                    let what = match dest {
                        Dest::Message { from, to } => format!("{from}..{to}"),
                        Dest::ReadAhead => "characters".into(),
                    };
                    match how {
                        ReadHow::Ready => {
                            self.log.push(format!("read {what}"));
                            if s.line.socket {
                                self.block(None);
                            }
                            if self.readable() { self.read_result(room) } else { Err(Error(errno::EAGAIN)) }
                        }
                        ReadHow::Queued => {
                            self.log.push(format!("read queued {what}"));
                            if self.readable() { self.read_result(room) } else { Err(Error(errno::EAGAIN)) }
                        }
                        ReadHow::Within(t) => {
                            self.log.push(format!("read within {what}"));
                            // The driver sets the kernel's timer to 3/4 of the timeout.
                            if self.block(Some(self.now + t.duration() * 3 / 4)) {
                                self.read_result(room)
                            } else {
                                Err(Error(errno::EAGAIN))
                            }
                        }
                    }
                }
            };
            self.settle();
            let now = self.now;
            let m = machine.get_or_insert_with(|| Receiver::after_first(&s, &step, started));
            step = if self.stop_at == Some(n) {
                m.stopped();
                m.step(&s, msg, rx, || now)
            } else {
                m.next(&s, result, msg, rx, || now)
            };
        }
        panic!("no end after 64 steps: {:?}", self.log);
    }
}

fn timeouts(response: u64, byte: u64, indication: u64) -> Timeouts {
    let t = |ms: u64| Timeout::new((ms / 1000) as u32, (ms % 1000 * 1000) as u32);
    Timeouts { response: t(response), byte: t(byte), indication: t(indication) }
}

/// A context's settings as the library makes them: TCP on a socket (a client's with
/// timed reads), RTU and ASCII on a non-blocking serial line.
fn settings(framing: Framing, kind: MsgKind) -> Settings {
    let socket = framing == Framing::Tcp;
    Settings {
        framing,
        kind,
        extended: false,
        expecting: None,
        timeouts: timeouts(500, 100, 0),
        recovery: 0,
        slave: 1,
        any_unit: false,
        read_ahead: kind == MsgKind::Confirmation,
        ascii_delimiter: b'\n',
        line: LineCaps { socket, reads_without_waiting: true, timed_reads: socket && kind == MsgKind::Confirmation },
    }
}

fn tcp_client() -> Settings {
    settings(Framing::Tcp, MsgKind::Confirmation)
}
fn tcp_server() -> Settings {
    settings(Framing::Tcp, MsgKind::Indication)
}
fn rtu_client() -> Settings {
    settings(Framing::Rtu, MsgKind::Confirmation)
}
fn rtu_server() -> Settings {
    settings(Framing::Rtu, MsgKind::Indication)
}
fn ascii_client() -> Settings {
    settings(Framing::Ascii, MsgKind::Confirmation)
}
fn ascii_server() -> Settings {
    settings(Framing::Ascii, MsgKind::Indication)
}

/// A sealed frame of `framing` from its unsealed bytes.
fn sealed(framing: Framing, unsealed: &[u8]) -> Vec<u8> {
    let mut buf = [0u8; 300];
    buf[..unsealed.len()].copy_from_slice(unsealed);
    let n = framing.seal(&mut buf, unsealed.len());
    buf[..n].to_vec()
}

/// TCP: a read-holding-registers response with two registers (tid 1, unit 1).
fn tcp_response() -> Vec<u8> {
    sealed(Framing::Tcp, &[0, 1, 0, 0, 0, 0, 1, 0x03, 4, 0, 10, 0, 20])
}
/// TCP: a read-holding-registers request (address 0, 2 registers).
fn tcp_request() -> Vec<u8> {
    sealed(Framing::Tcp, &[0, 1, 0, 0, 0, 0, 1, 0x03, 0, 0, 0, 2])
}
fn rtu_response() -> Vec<u8> {
    sealed(Framing::Rtu, &[1, 0x03, 4, 0, 10, 0, 20])
}
fn rtu_request() -> Vec<u8> {
    sealed(Framing::Rtu, &[1, 0x03, 0, 0, 0, 2])
}
/// The characters of an ASCII frame.
fn ascii_chars(unsealed: &[u8]) -> Vec<u8> {
    let adu = sealed(Framing::Ascii, unsealed);
    let mut out = [0u8; 600];
    let n = ascii::encode(&adu, &mut out);
    out[..n].to_vec()
}

struct Run {
    finished: Finished,
    log: Vec<String>,
    now: u64,
    msg: [u8; MAX_ADU_LENGTH],
    rx: ReadAhead,
    queued: usize,
}

fn run(s: Settings, line: Line) -> Run {
    let mut line = line;
    let mut msg = [0u8; MAX_ADU_LENGTH];
    let mut rx = ReadAhead::new();
    let finished = line.run(s, &mut msg, &mut rx);
    Run { finished, log: line.log, now: line.now.as_millis() as u64, msg, rx, queued: line.queued.len() }
}

fn frame(len: usize) -> Outcome {
    Outcome::Frame(len)
}
fn failed(error: Error, site: &'static str) -> Outcome {
    Outcome::Failed { error, site: Some(site) }
}

/// One row: settings, what arrives when, what the receive gives, the steps it took,
/// the clock when it ended.
struct Row {
    name: &'static str,
    s: Settings,
    line: Line,
    outcome: Outcome,
    steps: &'static [&'static str],
    ends_at: u64,
}

fn check_rows(rows: Vec<Row>) {
    for row in rows {
        let r = run(row.s, row.line);
        assert_eq!(r.finished.outcome, row.outcome, "{}: outcome (steps {:?})", row.name, r.log);
        assert_eq!(r.log, row.steps, "{}: steps", row.name);
        assert_eq!(r.now, row.ends_at, "{}: clock at the end", row.name);
    }
}

#[test]
fn tcp_client_rows() {
    let rsp = tcp_response();
    let (a, b) = rsp.split_at(9);
    let n = rsp.len();
    check_rows(vec![
        Row {
            name: "whole response: one timed read",
            s: tcp_client(),
            line: Line::new(&[(3, &rsp)]),
            outcome: frame(n),
            steps: &["read within 0..260"],
            ends_at: 3,
        },
        Row {
            name: "split response, second part within the byte timeout",
            s: tcp_client(),
            line: Line::new(&[(3, a), (50, b)]),
            outcome: frame(n),
            steps: &["read within 0..260", "read queued 9..260", "wait until 103", "read 9..260"],
            ends_at: 50,
        },
        Row {
            name: "second part later than the byte timeout",
            s: tcp_client(),
            line: Line::new(&[(3, a), (150, b)]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["read within 0..260", "read queued 9..260", "wait until 103"],
            ends_at: 103,
        },
        Row {
            name: "no byte timeout: the rest shares the response timeout",
            s: Settings { timeouts: timeouts(500, 0, 0), ..tcp_client() },
            line: Line::new(&[(3, a), (450, b)]),
            outcome: frame(n),
            steps: &["read within 0..260", "read queued 9..260", "wait until 500", "read 9..260"],
            ends_at: 450,
        },
        Row {
            name: "no byte timeout, the rest too late",
            s: Settings { timeouts: timeouts(500, 0, 0), ..tcp_client() },
            line: Line::new(&[(3, a), (501, b)]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["read within 0..260", "read queued 9..260", "wait until 500"],
            ends_at: 500,
        },
        Row {
            name: "no answer: the kernel's timer at 3/4, then a wait for the rest",
            s: tcp_client(),
            line: Line::new(&[]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["read within 0..260", "wait until 500"],
            ends_at: 500,
        },
        Row {
            name: "answer after the kernel's timer, within the response timeout",
            s: tcp_client(),
            line: Line::new(&[(450, &rsp)]),
            outcome: frame(n),
            steps: &["read within 0..260", "wait until 500", "read 0..260"],
            ends_at: 450,
        },
        Row {
            name: "answer exactly at the response timeout is too late",
            s: tcp_client(),
            line: Line::new(&[(501, &rsp)]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["read within 0..260", "wait until 500"],
            ends_at: 500,
        },
        Row {
            name: "no timed reads: wait, then read",
            s: Settings { line: LineCaps { timed_reads: false, ..tcp_client().line }, ..tcp_client() },
            line: Line::new(&[(3, &rsp)]),
            outcome: frame(n),
            steps: &["wait until 500", "read 0..260"],
            ends_at: 3,
        },
        Row {
            name: "end of stream",
            s: tcp_client(),
            line: Line::new(&[]).eof_at(5),
            outcome: failed(Error::CONN_RESET, "read"),
            steps: &["read within 0..260"],
            ends_at: 5,
        },
        Row {
            name: "end of stream in the middle of a response",
            s: tcp_client(),
            line: Line::new(&[(3, a)]).eof_at(5),
            outcome: failed(Error::CONN_RESET, "read"),
            steps: &["read within 0..260", "read queued 9..260", "wait until 103", "read 9..260"],
            ends_at: 5,
        },
    ]);
}

#[test]
fn tcp_server_rows() {
    let req = tcp_request();
    let n = req.len();
    let (a, b) = req.split_at(4);
    let mut two = req.clone();
    two.extend_from_slice(&req);
    // FC 0x10 announcing 250 bytes of values: past the largest ADU.
    let too_long = [0, 1, 0, 0, 0, 255, 1, 0x10, 0, 0, 0, 125, 250];
    check_rows(vec![
        Row {
            name: "whole request queued: a peek and one read of exactly the request",
            s: tcp_server(),
            line: Line::new(&[(7, &req)]),
            outcome: frame(n),
            steps: &["peek (blocks)", "read 0..12"],
            ends_at: 7,
        },
        Row {
            name: "two pipelined requests: the second stays in the kernel",
            s: tcp_server(),
            line: Line::new(&[(0, &two)]),
            outcome: frame(n),
            steps: &["peek (blocks)", "read 0..12"],
            ends_at: 0,
        },
        Row {
            name: "part of a request at the peek: read without waiting, then wait for the rest",
            s: tcp_server(),
            line: Line::new(&[(1, a), (30, b)]),
            outcome: frame(n),
            steps: &[
                "peek (blocks)",
                "read queued 0..8",
                "read queued 4..8",
                "wait until 101",
                "read 4..8",
                "read queued 8..12",
            ],
            ends_at: 30,
        },
        Row {
            name: "indication timeout: a peek that does not wait, then a wait",
            s: Settings { timeouts: timeouts(500, 100, 300), ..tcp_server() },
            line: Line::new(&[(20, &req)]),
            outcome: frame(n),
            steps: &["peek", "wait until 300", "read 0..8", "read queued 8..12"],
            ends_at: 20,
        },
        Row {
            name: "indication timeout passes",
            s: Settings { timeouts: timeouts(500, 100, 300), ..tcp_server() },
            line: Line::new(&[(301, &req)]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["peek", "wait until 300"],
            ends_at: 300,
        },
        Row {
            name: "the rest of a request later than the byte timeout",
            s: tcp_server(),
            line: Line::new(&[(0, a), (200, b)]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["peek (blocks)", "read queued 0..8", "read queued 4..8", "wait until 100"],
            ends_at: 100,
        },
        Row {
            name: "a request longer than the largest ADU",
            s: tcp_server(),
            line: Line::new(&[(0, &too_long)]),
            outcome: failed(Error::BAD_DATA, "too many data"),
            steps: &["peek (blocks)", "read queued 0..8", "read queued 8..13"],
            ends_at: 0,
        },
        Row {
            name: "the client goes away",
            s: tcp_server(),
            line: Line::new(&[]).eof_at(40),
            outcome: failed(Error::CONN_RESET, "read"),
            steps: &["peek (blocks)", "wait", "read 0..8"],
            ends_at: 40,
        },
    ]);
}

#[test]
fn rtu_rows() {
    let req = rtu_request();
    let rsp = rtu_response();
    let mut bad = rsp.clone();
    bad[3] ^= 0xFF;
    let mut other = rtu_response();
    other[0] = 2;
    let other = sealed(Framing::Rtu, &other[..other.len() - 2]);
    let (a, b) = rsp.split_at(4);
    check_rows(vec![
        Row {
            name: "server: wait, the function code, the rest without waiting",
            s: rtu_server(),
            line: Line::new(&[(10, &req)]),
            outcome: frame(req.len()),
            steps: &["wait", "read 0..2", "read queued 2..8"],
            ends_at: 10,
        },
        Row {
            name: "server: the rest arrives a little later",
            s: rtu_server(),
            line: Line::new(&[(10, &req[..2]), (40, &req[2..])]),
            outcome: frame(req.len()),
            steps: &["wait", "read 0..2", "read queued 2..8", "wait until 110", "read 2..8"],
            ends_at: 40,
        },
        Row {
            name: "server: the rest later than the byte timeout",
            s: rtu_server(),
            line: Line::new(&[(10, &req[..3]), (111, &req[3..])]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["wait", "read 0..2", "read queued 2..8", "read queued 3..8", "wait until 110"],
            ends_at: 110,
        },
        Row {
            name: "server: indication timeout",
            s: Settings { timeouts: timeouts(500, 100, 250), ..rtu_server() },
            line: Line::new(&[]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["wait until 250"],
            ends_at: 250,
        },
        Row {
            name: "client: the response in one read",
            s: rtu_client(),
            line: Line::new(&[(20, &rsp)]),
            outcome: frame(rsp.len()),
            steps: &["wait until 500", "read 0..260"],
            ends_at: 20,
        },
        Row {
            name: "client: a response split across reads",
            s: rtu_client(),
            line: Line::new(&[(20, a), (60, b)]),
            outcome: frame(rsp.len()),
            steps: &["wait until 500", "read 0..260", "read queued 4..260", "wait until 120", "read 4..260"],
            ends_at: 60,
        },
        Row {
            name: "client: no response",
            s: rtu_client(),
            line: Line::new(&[]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["wait until 500"],
            ends_at: 500,
        },
        Row {
            name: "client: bad CRC",
            s: rtu_client(),
            line: Line::new(&[(20, &bad)]),
            outcome: Outcome::BadChecksum {
                lrc: false,
                received: u16::from_le_bytes([bad[7], bad[8]]),
                computed: crate::crc::crc16(&bad[..7]),
            },
            steps: &["wait until 500", "read 0..260"],
            ends_at: 20,
        },
        Row {
            name: "client: a frame of another slave is ignored",
            s: rtu_client(),
            line: Line::new(&[(20, &other)]),
            outcome: Outcome::Ignored { len: other.len(), theirs: 2, ours: 1 },
            steps: &["wait until 500", "read 0..260"],
            ends_at: 20,
        },
        Row {
            name: "client that leaves late confirmations on the line: reads stop at the frame",
            s: Settings { read_ahead: false, ..rtu_client() },
            line: Line::new(&[(20, &rsp)]),
            outcome: frame(rsp.len()),
            steps: &["wait until 500", "read 0..2", "read queued 2..3", "read queued 3..9"],
            ends_at: 20,
        },
    ]);
}

#[test]
fn ascii_rows() {
    let rsp = ascii_chars(&[1, 0x03, 4, 0, 10, 0, 20]);
    let req = ascii_chars(&[1, 0x03, 0, 0, 0, 2]);
    let (a, b) = rsp.split_at(7);
    let mut noisy = b"\x00zz".to_vec();
    noisy.extend_from_slice(&req);
    let mut bad_lrc = req.clone();
    let l = bad_lrc.len();
    bad_lrc[l - 3] = if bad_lrc[l - 3] == b'0' { b'1' } else { b'0' };
    let short = ascii_chars(&[1, 0x03, 4, 0, 10]); // announces 4 bytes, carries 2
    let bad_char = b":01G3\r\n".to_vec();
    let decoded_len = 7 + 1;
    check_rows(vec![
        Row {
            name: "client: a frame in one read",
            s: ascii_client(),
            line: Line::new(&[(20, &rsp)]),
            outcome: frame(decoded_len),
            steps: &["wait until 500", "read characters"],
            ends_at: 20,
        },
        Row {
            name: "client: a frame in two reads",
            s: ascii_client(),
            line: Line::new(&[(20, a), (90, b)]),
            outcome: frame(decoded_len),
            steps: &["wait until 500", "read characters", "wait until 120", "read characters"],
            ends_at: 90,
        },
        Row {
            name: "client: the rest of a frame later than the byte timeout",
            s: ascii_client(),
            line: Line::new(&[(20, a), (121, b)]),
            outcome: failed(Error::TIMED_OUT, "select"),
            steps: &["wait until 500", "read characters", "wait until 120"],
            ends_at: 120,
        },
        Row {
            name: "server: noise before ':' is skipped, and starts no byte timeout",
            s: Settings { timeouts: timeouts(500, 100, 1000), ..ascii_server() },
            line: Line::new(&[(20, b"xx"), (400, &noisy)]),
            outcome: frame(7),
            steps: &["wait until 1000", "read characters", "wait until 1000", "read characters"],
            ends_at: 400,
        },
        Row {
            name: "server: bad LRC",
            s: ascii_server(),
            line: Line::new(&[(5, &bad_lrc)]),
            outcome: {
                let mut dec = [0u8; 16];
                let mut d = ascii::Decoder::new();
                let mut len = 0;
                for &c in &bad_lrc {
                    if let Ok(ascii::Step::Complete(n)) = d.feed(c, &mut dec) {
                        len = n;
                    }
                }
                Outcome::BadChecksum {
                    lrc: true,
                    received: dec[len - 1] as u16,
                    computed: ascii::lrc(&dec[..len - 1]) as u16,
                }
            },
            steps: &["wait", "read characters"],
            ends_at: 5,
        },
        Row {
            name: "client: a frame shorter than its content says",
            s: ascii_client(),
            line: Line::new(&[(5, &short)]),
            outcome: failed(Error::BAD_DATA, "frame too short"),
            steps: &["wait until 500", "read characters"],
            ends_at: 5,
        },
        Row {
            name: "server: a character that is not hex",
            s: ascii_server(),
            line: Line::new(&[(5, &bad_char)]),
            outcome: failed(Error::BAD_DATA, "invalid ASCII frame"),
            steps: &["wait", "read characters"],
            ends_at: 5,
        },
    ]);
}

#[test]
fn read_ahead_keeps_what_follows_for_the_next_receive() {
    // TCP: two responses in one read; the second is taken from the buffer, no I/O.
    let rsp = tcp_response();
    let mut two = rsp.clone();
    two.extend_from_slice(&rsp);
    let mut line = Line::new(&[(3, &two)]);
    let mut msg = [0u8; MAX_ADU_LENGTH];
    let mut rx = ReadAhead::new();
    let f = line.run(tcp_client(), &mut msg, &mut rx);
    assert_eq!(f.outcome, frame(rsp.len()));
    assert_eq!(rx.available(), &rsp[..]);
    let f = line.run(tcp_client(), &mut msg, &mut rx);
    assert_eq!(f.outcome, frame(rsp.len()));
    assert_eq!(&msg[..rsp.len()], &rsp[..]);
    assert_eq!(line.log, ["read within 0..260"]);
    assert!(rx.available().is_empty());

    // Part of a second response: the next receive takes it, then reads the rest,
    // which must come within a byte timeout of the receive's start.
    let mut line = Line::new(&[(3, &two[..rsp.len() + 5]), (50, &two[rsp.len() + 5..])]);
    let f = line.run(tcp_client(), &mut msg, &mut rx);
    assert_eq!(f.outcome, frame(rsp.len()));
    assert_eq!(rx.available(), &rsp[..5]);
    let f = line.run(tcp_client(), &mut msg, &mut rx);
    assert_eq!(f.outcome, frame(rsp.len()));
    assert_eq!(&msg[..rsp.len()], &rsp[..]);
    assert_eq!(line.log, ["read within 0..260", "read queued 5..260", "wait until 103", "read 5..260"]);

    // RTU: garbage after a frame stays for the next receive, which frames it by its
    // (unknown) function code and fails on its CRC.
    let rtu = rtu_response();
    let mut with_garbage = rtu.clone();
    with_garbage.extend_from_slice(&[0xFF; 5]);
    let mut line = Line::new(&[(3, &with_garbage)]);
    let mut rx = ReadAhead::new();
    let f = line.run(rtu_client(), &mut msg, &mut rx);
    assert_eq!(f.outcome, frame(rtu.len()));
    assert_eq!(rx.available(), &[0xFF; 5]);
    let f = line.run(rtu_client(), &mut msg, &mut rx);
    assert!(matches!(f.outcome, Outcome::BadChecksum { lrc: false, .. }), "{:?}", f.outcome);

    // ASCII: a second frame in the same read is decoded by the next receive.
    let chars = ascii_chars(&[1, 0x03, 2, 0, 7]);
    let mut two = chars.clone();
    two.extend_from_slice(&chars);
    let mut line = Line::new(&[(3, &two)]);
    let mut rx = ReadAhead::new();
    assert_eq!(line.run(ascii_client(), &mut msg, &mut rx).outcome, frame(6));
    assert_eq!(rx.available(), &chars[..]);
    assert_eq!(line.run(ascii_client(), &mut msg, &mut rx).outcome, frame(6));
    assert_eq!(&msg[..5], &[1, 0x03, 2, 0, 7]);
    assert_eq!(line.log, ["wait until 500", "read characters"]);
}

#[test]
fn garbage_before_a_frame() {
    // RTU: garbage is read as a frame (libmodbus has no silence detection): its
    // unknown function code makes it 4 bytes long, with a bad CRC; what follows it
    // stays on the line.
    let req = rtu_request();
    let mut line_bytes = vec![0x01, 0x7F, 0x00, 0x00];
    line_bytes.extend_from_slice(&req);
    let r = run(Settings { recovery: RECOVERY_PROTOCOL, ..rtu_server() }, Line::new(&[(0, &line_bytes)]));
    assert!(matches!(r.finished.outcome, Outcome::BadChecksum { lrc: false, .. }));
    assert_eq!(r.finished.recovery, Recovery::Flush);
    assert_eq!(r.queued, req.len());
    // TCP: garbage with a bad length goes the same way: framed by its content.
    let r = run(tcp_server(), Line::new(&[(0, &[0, 0, 0, 0, 0, 2, 1, 0x7F, 9, 9])]));
    assert_eq!(r.finished.outcome, frame(8));
    assert_eq!(r.queued, 2);
}

#[test]
fn diagnostics_request_ends_where_its_crc_matches_or_the_line_goes_quiet() {
    let s = Settings { extended: true, ..rtu_server() };
    // Return query data with three words.
    let req = sealed(Framing::Rtu, &[1, 0x08, 0, 0, 0xA5, 0x37, 1, 2, 3, 4]);
    let r = run(s, Line::new(&[(0, &req)]));
    assert_eq!(r.finished.outcome, frame(req.len()));
    assert_eq!(&r.msg[..req.len()], &req[..]);
    // Cut short: when the line goes quiet, the frame ends there, with a bad CRC.
    let r = run(s, Line::new(&[(0, &req[..9])]));
    assert!(matches!(r.finished.outcome, Outcome::BadChecksum { .. }), "{:?}", r.finished.outcome);
    assert_eq!(r.finished.traced, 9);
    assert!(r.finished.ended);
    assert_eq!(r.now, 100);
}

#[test]
fn a_confirmation_to_a_diagnostics_request_is_as_long_as_the_request() {
    let rsp = sealed(Framing::Rtu, &[1, 0x08, 0, 0, 1, 2, 3, 4]);
    let s = Settings { expecting: Some(8), ..rtu_client() };
    let mut with_more = rsp.clone();
    with_more.extend_from_slice(&[9, 9]);
    let r = run(s, Line::new(&[(0, &with_more)]));
    assert_eq!(r.finished.outcome, frame(rsp.len()));
    assert_eq!(r.rx.available(), &[9, 9]);
}

#[test]
fn every_failure_asks_for_its_recovery() {
    let link = RECOVERY_LINK;
    let protocol = RECOVERY_PROTOCOL;
    let cases: Vec<(&str, Settings, Line, Recovery)> = vec![
        ("timeout, LINK", Settings { recovery: link, ..tcp_client() }, Line::new(&[]), Recovery::SleepFlush),
        ("timeout, PROTOCOL", Settings { recovery: protocol, ..tcp_client() }, Line::new(&[]), Recovery::None),
        (
            "end of stream, LINK",
            Settings { recovery: link, ..tcp_client() },
            Line::new(&[]).eof_at(1),
            Recovery::Reconnect,
        ),
        ("end of stream, none", tcp_client(), Line::new(&[]).eof_at(1), Recovery::None),
        (
            "bad CRC, PROTOCOL",
            Settings { recovery: protocol, ..rtu_client() },
            Line::new(&[(0, &[1, 0x03, 2, 0, 0, 0, 0])]),
            Recovery::Flush,
        ),
        (
            "bad CRC, LINK",
            Settings { recovery: link, ..rtu_client() },
            Line::new(&[(0, &[1, 0x03, 2, 0, 0, 0, 0])]),
            Recovery::None,
        ),
        (
            "too many data, both",
            Settings { recovery: link | protocol, ..tcp_server() },
            Line::new(&[(0, &[0, 1, 0, 0, 0, 255, 1, 0x10, 0, 0, 0, 125, 250])]),
            Recovery::None,
        ),
    ];
    for (name, s, line, recovery) in cases {
        let r = run(s, line);
        assert_eq!(r.finished.recovery, recovery, "{name}: {:?}", r.finished.outcome);
    }
}

#[test]
fn a_stop_ends_the_receive_at_any_step_without_recovery() {
    let rsp = tcp_response();
    for framing in [Framing::Tcp, Framing::Rtu, Framing::Ascii] {
        for kind in [MsgKind::Confirmation, MsgKind::Indication] {
            for at in 0..3 {
                let mut line = Line::new(&[(10, &rsp[..3]), (20, &rsp[3..6])]);
                line.stop_at = Some(at);
                let s = Settings { recovery: RECOVERY_LINK | RECOVERY_PROTOCOL, ..settings(framing, kind) };
                let mut msg = [0u8; MAX_ADU_LENGTH];
                let mut rx = ReadAhead::new();
                let f = line.run(s, &mut msg, &mut rx);
                let what = format!("{framing:?} {kind:?} stopped at step {at}: {:?}", line.log);
                assert_eq!(f.outcome, Outcome::Failed { error: Error::STOPPED, site: None }, "{what}");
                assert_eq!(f.recovery, Recovery::None, "{what}");
                assert_eq!(line.log.len(), at + 1, "{what}");
            }
        }
    }
}

#[test]
fn a_failed_read_after_a_wait_waits_again() {
    // EAGAIN after a wait that said readable (a spurious wake-up): wait again,
    // within the same deadline.
    let rsp = rtu_response();
    let rtu_settings = rtu_client();
    let link_settings = Settings { recovery: RECOVERY_LINK, ..rtu_client() };
    let mut m = Receiver::new(&rtu_settings, || ms(0));
    let mut msg = [0u8; MAX_ADU_LENGTH];
    let mut rx = ReadAhead::new();
    assert_eq!(m.step(&rtu_settings, &mut msg, &mut rx, || ms(30)), Step::Wait { until: Some(ms(500)) });
    m.done(&rtu_settings, Ok(0));
    assert!(matches!(m.step(&rtu_settings, &mut msg, &mut rx, || ms(30)), Step::Read { how: ReadHow::Ready, .. }));
    m.done(&rtu_settings, Err(Error(errno::EAGAIN)));
    assert_eq!(m.step(&rtu_settings, &mut msg, &mut rx, || ms(30)), Step::Wait { until: Some(ms(500)) });
    m.done(&rtu_settings, Ok(0));
    assert!(matches!(m.step(&rtu_settings, &mut msg, &mut rx, || ms(30)), Step::Read { how: ReadHow::Ready, .. }));
    msg[..rsp.len()].copy_from_slice(&rsp);
    m.done(&rtu_settings, Ok(rsp.len()));
    match m.step(&rtu_settings, &mut msg, &mut rx, || ms(30)) {
        Step::Frame(len) => assert_eq!(len, rsp.len()),
        other => panic!("{other:?}"),
    }
    // Another error of the read: reported, with its recovery.
    let mut m = Receiver::new(&link_settings, || ms(0));
    let _ = m.step(&link_settings, &mut msg, &mut rx, || ms(30));
    m.done(&link_settings, Ok(0));
    let _ = m.step(&link_settings, &mut msg, &mut rx, || ms(30));
    m.done(&link_settings, Err(Error(errno::EBADF)));
    match m.step(&link_settings, &mut msg, &mut rx, || ms(30)) {
        Step::Done(f) => {
            assert_eq!(f.outcome, failed(Error(errno::EBADF), "read"));
            assert_eq!(f.recovery, Recovery::Reconnect);
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn the_trace_shows_the_bytes_of_the_message_taken_so_far() {
    let rsp = tcp_response();
    let r = run(tcp_client(), Line::new(&[(0, &rsp[..9])]));
    assert_eq!(r.finished.outcome, failed(Error::TIMED_OUT, "select"));
    assert_eq!((r.finished.traced, r.finished.ended), (9, false));
    let r = run(tcp_client(), Line::new(&[(0, &rsp)]));
    assert_eq!((r.finished.traced, r.finished.ended), (rsp.len(), true));
    let chars = ascii_chars(&[1, 0x03, 2, 0, 7]);
    let r = run(ascii_client(), Line::new(&[(0, &chars[..7])]));
    assert_eq!((r.finished.traced, r.finished.ended), (3, false));
}
