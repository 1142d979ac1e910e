//! The gateway without I/O: what happens to each master's request, from the front
//! that took it to the line that serves it and back.
//!
//! - Masters are keyed by their connection id (the library's: unique in the
//!   process, one per TCP connection, one per UDP sender). On each line every master
//!   has a queue of its own of at most [`QUEUE_MAX`] requests, and the line serves
//!   the masters that have one waiting in turn (a ring of them: round robin, O(1)).
//!   A full queue: exception 0x06, counted, logged at most once a second per line.
//! - A master whose connection closed ([`Core::closed`]) loses its queued requests;
//!   the one on the line finishes and its answer goes nowhere (no retry).
//! - Policy, before anything is queued: a non-zero MBAP protocol id closes the
//!   connection (mbusd); a UDP sender outside `udp_allow` is not answered; the TLS
//!   front's roles are checked on the unit the master addressed (exception 0x01);
//!   the other fronts reach `plain_units` only (exception 0x0A); a unit with no
//!   route, or routed to a line not available yet, 0x0A.
//! - The line: one request at a time, a pause after each (`pause`, or the line's
//!   3.5 characters at `pause = 0`); a request that got no answer or a bad one goes
//!   again first (`retries`), then is answered 0x0B (no answer) or 0x04 (bad CRC or
//!   data); a network line that cannot be reached answers 0x0A at once. A
//!   broadcast on a serial line gets no answer, or its request echoed (`-b`).
//!
//! The I/O (`run.rs`) feeds it requests ([`Core::request`]), asks it what to send
//! ([`Core::next_send`]) and when ([`Core::send_at`]), and gives it what the line
//! did ([`Core::completed`]); each call returns what to answer, and to whom.

use std::collections::{HashMap, VecDeque};
use std::fmt;
use std::net::IpAddr;
use std::time::{Duration, Instant};

use crate::log::Log;
use crate::logf;

/// Requests one master may have waiting on one line.
pub const QUEUE_MAX: usize = 16;
/// The largest PDU (function code and data).
pub const PDU_MAX: usize = 253;
const RAW_MAX: usize = PDU_MAX + 1;

/// The exception codes (the gateway answers 0x01, 0x04, 0x06, 0x0A and 0x0B).
pub use modbus::error::exception;

/// The kind of front a request came through.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Front {
    /// Modbus/TCP.
    Tcp,
    /// RTU frames over TCP.
    RtuTcp,
    /// Modbus/UDP.
    Udp,
    /// Modbus/TCP Security (mutual TLS, roles).
    Tls,
}

impl Front {
    /// Its name in the log.
    pub fn name(self) -> &'static str {
        match self {
            Front::Tcp => "Modbus/TCP",
            Front::RtuTcp => "RTU over TCP",
            Front::Udp => "Modbus/UDP",
            Front::Tls => "Modbus/TCP Security",
        }
    }
}

/// What the configuration decides (implemented by `config::Config`; by small
/// tables in tests and the fuzz target).
pub trait Rules {
    /// The line of `unit` and its unit there; `None`: no route.
    fn route(&self, unit: u8) -> Option<(usize, u8)>;
    /// Whether a TLS master of `role` may send `function` to `unit`.
    fn authorized(&self, role: Option<&str>, unit: u8, function: u8) -> bool;
    /// Whether the unsecured fronts reach `unit` (`plain_units`).
    fn plain_reaches(&self, unit: u8) -> bool;
    /// Whether the UDP front answers `ip` (`udp_allow`).
    fn allowed_udp(&self, ip: IpAddr) -> bool;
    /// Retries of a request that got no valid answer.
    fn retries(&self) -> u8;
    /// The pause after a transaction (zero: the line's silence only).
    fn pause(&self) -> Duration;
    /// `-b`: a broadcast is answered with its request.
    fn reply_on_broadcast(&self) -> bool;
    /// UDP senders one line keeps a queue for (`maxconn`).
    fn udp_masters_max(&self) -> usize;
}

/// A request as a front took it.
#[derive(Clone, Copy, Debug)]
pub struct Incoming<'a> {
    /// The front's index (where the answer goes) and kind.
    pub front: usize,
    pub kind: Front,
    /// The front's id of the request (its answer is given under it).
    pub request_id: i32,
    /// The master's connection id.
    pub connection: u64,
    /// The unit the master addressed.
    pub unit: u8,
    /// The MBAP protocol id as received (0 on RTU framing).
    pub protocol_id: u16,
    /// The role in a TLS master's certificate.
    pub role: Option<&'a str>,
    /// The sender (UDP: who is answered).
    pub peer: Option<IpAddr>,
    /// The PDU, function code first.
    pub pdu: &'a [u8],
}

/// What the front does with a request, now.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Verdict {
    /// Queued: the answer comes later (as a [`Reply`]).
    Queued,
    /// Answered at once with this exception.
    Exception(u8),
    /// The master's connection is closed, no answer.
    Close,
    /// Not answered.
    Ignore,
}

/// An answer given later.
#[derive(Clone, PartialEq, Eq, Debug)]
pub enum Answer {
    /// The line's answer (function code first; an exception answer too).
    Pdu(Vec<u8>),
    /// An exception of the gateway's.
    Exception(u8),
    /// None (a broadcast): the front forgets the request.
    Nothing,
}

/// Where an answer goes: the front and its request id.
#[derive(Clone, Copy, PartialEq, Eq, Hash, Debug)]
pub struct Dest {
    pub front: usize,
    pub request_id: i32,
}

/// Why a request on the line failed.
#[derive(Clone, Copy, PartialEq, Eq, Debug)]
pub enum Failure {
    /// The device did not answer in time (retried, then 0x0B).
    NoAnswer,
    /// Its answer failed the CRC or made no sense (retried, then 0x04).
    BadAnswer,
    /// A network line could not be reached (0x0A at once).
    Unreachable,
    /// The request could not be given to the line (0x0B at once).
    NotSent,
}

/// A line as the core sees it.
#[derive(Clone, Debug)]
pub struct LineSpec {
    pub name: String,
    /// The 3.5 characters of silence between frames (zero on a network line).
    pub gap: Duration,
    /// A serial line: unit 0 is a broadcast, which gets no answer.
    pub serial: bool,
}

/// A line's counters (the status file's).
#[derive(Clone, Copy, Default, Debug, PartialEq, Eq)]
pub struct Counters {
    /// Requests queued.
    pub requests: u64,
    /// Answers from the line.
    pub served: u64,
    /// Transactions that got no answer (or could not reach the device).
    pub timeouts: u64,
    /// Transactions whose answer failed the CRC or made no sense.
    pub bad_answers: u64,
    /// Exceptions the gateway answered for requests routed to the line.
    pub exceptions: u64,
}

/// One request: where its answer goes, and the bytes for the line.
#[derive(Clone, Copy)]
struct Request {
    front: u32,
    id: i32,
    conn: u64,
    /// The next of its master's queue (in the line's pool).
    next: u32,
    /// Sends so far.
    tries: u8,
    len: u8,
    /// The unit on the line, then the PDU.
    raw: [u8; RAW_MAX],
}

impl Request {
    fn raw(&self) -> &[u8] {
        &self.raw[..usize::from(self.len)]
    }
    fn dest(&self) -> Dest {
        Dest { front: self.front as usize, request_id: self.id }
    }
}

/// A master's queue: its requests in the line's pool, chained in order through
/// their `next` (a master costs 12 bytes of it, and no allocation of its own).
#[derive(Default)]
struct Chain {
    head: u32,
    tail: u32,
    len: u8,
}

impl Chain {
    fn len(&self) -> usize {
        usize::from(self.len)
    }
    fn is_empty(&self) -> bool {
        self.len == 0
    }
    fn push_back(&mut self, pool: &mut Pool, r: Request) {
        let slot = pool.put(r);
        if self.len == 0 {
            self.head = slot;
        } else {
            pool.slots[self.tail as usize].next = slot;
        }
        self.tail = slot;
        self.len += 1;
    }
    fn pop_front(&mut self, pool: &mut Pool) -> Option<Request> {
        if self.len == 0 {
            return None;
        }
        let r = pool.take(self.head);
        self.head = r.next;
        self.len -= 1;
        Some(r)
    }
}

/// The requests waiting on a line, in slots reused (no allocation per request once
/// the line has had as many waiting at once).
#[derive(Default)]
struct Pool {
    slots: Vec<Request>,
    free: Vec<u32>,
}

impl Pool {
    fn put(&mut self, r: Request) -> u32 {
        match self.free.pop() {
            Some(i) => {
                self.slots[i as usize] = r;
                i
            }
            None => {
                self.slots.push(r);
                (self.slots.len() - 1) as u32
            }
        }
    }
    fn take(&mut self, slot: u32) -> Request {
        self.free.push(slot);
        self.slots[slot as usize]
    }
}

struct Master {
    queue: Chain,
    /// Requests taken, refused as busy.
    requests: u64,
    busy: u64,
    udp: bool,
    /// The line's request count at its last request (the oldest idle UDP sender goes).
    last: u64,
}

struct Current {
    req: Request,
    /// Sent and not completed; else waiting to be sent again.
    on_wire: bool,
}

/// A line: its masters, their turn, the request on it.
pub struct Line {
    spec: LineSpec,
    available: bool,
    masters: HashMap<u64, Master>,
    pool: Pool,
    /// The masters with a request waiting, in turn.
    ready: VecDeque<u64>,
    current: Option<Current>,
    quiet_until: Option<Instant>,
    udp_masters: usize,
    counters: Counters,
    /// Refusals as busy not logged yet, and when the last log line was written.
    busy_unlogged: u64,
    busy_logged: Option<Instant>,
}

/// One master of a line, for the status file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MasterStatus {
    pub connection: u64,
    pub requests: u64,
    pub busy: u64,
    pub depth: usize,
}

impl Line {
    fn new(spec: LineSpec) -> Line {
        Line {
            spec,
            available: true,
            masters: HashMap::new(),
            pool: Pool::default(),
            ready: VecDeque::new(),
            current: None,
            quiet_until: None,
            udp_masters: 0,
            counters: Counters::default(),
            busy_unlogged: 0,
            busy_logged: None,
        }
    }

    pub fn name(&self) -> &str {
        &self.spec.name
    }

    pub fn counters(&self) -> Counters {
        self.counters
    }

    /// Requests waiting, the one on the line (or waiting to go again) included.
    pub fn depth(&self) -> usize {
        self.masters.values().map(|m| m.queue.len()).sum::<usize>() + usize::from(self.current.is_some())
    }

    /// The masters that sent something or have something queued, by connection id.
    pub fn masters(&self) -> Vec<MasterStatus> {
        let mut v: Vec<MasterStatus> = self
            .masters
            .iter()
            .filter(|(_, m)| m.requests > 0 || !m.queue.is_empty())
            .map(|(&c, m)| MasterStatus { connection: c, requests: m.requests, busy: m.busy, depth: m.queue.len() })
            .collect();
        v.sort_unstable_by_key(|m| m.connection);
        v
    }

    /// The request on the line (or waiting to go again), and whether it is sent.
    pub fn on_line(&self) -> Option<(Dest, bool)> {
        self.current.as_ref().map(|c| (c.req.dest(), c.on_wire))
    }

    fn log_busy<L: Log>(&mut self, log: &mut L, now: Instant) {
        logf!(log, 2, "line {}: {} request(s) refused, queues full (busy)", self.spec.name, self.busy_unlogged);
        self.busy_unlogged = 0;
        self.busy_logged = Some(now);
    }
}

/// The gateway's state: its rules, its log, its lines.
pub struct Core<R, L> {
    pub rules: R,
    pub log: L,
    lines: Vec<Line>,
}

impl<R: Rules, L: Log> Core<R, L> {
    pub fn new(rules: R, log: L, lines: Vec<LineSpec>) -> Self {
        Core { rules, log, lines: lines.into_iter().map(Line::new).collect() }
    }

    pub fn lines(&self) -> &[Line] {
        &self.lines
    }

    /// A network line becomes available (its address resolved) or not; requests
    /// routed to an unavailable line are answered 0x0A at once, and those waiting
    /// when it becomes so are answered 0x0A (returned).
    pub fn set_available(&mut self, line: usize, available: bool) -> Vec<(Dest, Answer)> {
        let mut out = Vec::new();
        let Some(l) = self.lines.get_mut(line) else { return out };
        l.available = available;
        if !available {
            l.ready.clear();
            for m in l.masters.values_mut() {
                while let Some(r) = m.queue.pop_front(&mut l.pool) {
                    l.counters.exceptions += 1;
                    out.push((r.dest(), Answer::Exception(exception::GATEWAY_PATH)));
                }
            }
            if let Some(c) = l.current.take_if(|c| !c.on_wire) {
                l.counters.exceptions += 1;
                out.push((c.req.dest(), Answer::Exception(exception::GATEWAY_PATH)));
            }
        }
        out
    }

    /// A request from a front: refused at once, or queued for its line.
    pub fn request(&mut self, inc: &Incoming<'_>, now: Instant) -> Verdict {
        let log = &mut self.log;
        if inc.protocol_id != 0 {
            logf!(
                log,
                3,
                "master {}: MBAP protocol id {} is not Modbus: {}",
                inc.connection,
                inc.protocol_id,
                if inc.kind == Front::Udp { "ignored" } else { "connection closed" }
            );
            return if inc.kind == Front::Udp { Verdict::Ignore } else { Verdict::Close };
        }
        if inc.kind == Front::Udp && !inc.peer.is_some_and(|ip| self.rules.allowed_udp(ip)) {
            logf!(log, 4, "UDP sender {:?} not in udp_allow: not answered", inc.peer);
            return Verdict::Ignore;
        }
        let (Some(&function), true) = (inc.pdu.first(), inc.pdu.len() <= PDU_MAX) else {
            return Verdict::Ignore;
        };
        let unit = inc.unit;
        if inc.kind == Front::Tls {
            if !self.rules.authorized(inc.role, unit, function) {
                logf!(
                    log,
                    3,
                    "TLS master with role {} refused: unit {unit}, function 0x{function:02X}",
                    inc.role.unwrap_or("(none)")
                );
                return Verdict::Exception(exception::ILLEGAL_FUNCTION);
            }
        } else if !self.rules.plain_reaches(unit) {
            logf!(log, 3, "unit {unit}: not in plain_units, refused on the {} front (exception 0x0A)", inc.kind.name());
            return Verdict::Exception(exception::GATEWAY_PATH);
        }
        let Some((index, there)) = self.rules.route(unit) else {
            logf!(log, 3, "unit {unit}: no route (exception 0x0A)");
            return Verdict::Exception(exception::GATEWAY_PATH);
        };
        let Some(line) = self.lines.get_mut(index) else {
            logf!(log, 3, "unit {unit}: no route (exception 0x0A)");
            return Verdict::Exception(exception::GATEWAY_PATH);
        };
        if !line.available {
            line.counters.exceptions += 1;
            logf!(log, 3, "line {}: not available, unit {unit} (exception 0x0A)", line.spec.name);
            return Verdict::Exception(exception::GATEWAY_PATH);
        }
        let udp = inc.kind == Front::Udp;
        let seq = line.counters.requests;
        if !line.masters.contains_key(&inc.connection) {
            if udp && line.udp_masters >= self.rules.udp_masters_max() {
                // The sender that asked least recently and has nothing waiting goes.
                let on_line = line.current.as_ref().map(|c| c.req.conn);
                let oldest = line
                    .masters
                    .iter()
                    .filter(|&(&c, m)| m.udp && m.queue.is_empty() && Some(c) != on_line)
                    .min_by_key(|(_, m)| m.last)
                    .map(|(&c, _)| c);
                match oldest {
                    Some(c) => {
                        line.masters.remove(&c);
                        line.udp_masters -= 1;
                    }
                    None => return refuse(line, log, now, None),
                }
            }
            line.udp_masters += usize::from(udp);
            line.masters
                .insert(inc.connection, Master { queue: Chain::default(), requests: 0, busy: 0, udp, last: seq });
        }
        let m = line.masters.get_mut(&inc.connection).expect("the master, made above");
        if m.queue.len() >= QUEUE_MAX {
            return refuse(line, log, now, Some(inc.connection));
        }
        let mut raw = [0u8; RAW_MAX];
        raw[0] = there;
        raw[1..=inc.pdu.len()].copy_from_slice(inc.pdu);
        if m.queue.is_empty() {
            line.ready.push_back(inc.connection);
        }
        m.queue.push_back(
            &mut line.pool,
            Request {
                front: inc.front as u32,
                id: inc.request_id,
                conn: inc.connection,
                next: 0,
                tries: 0,
                len: (inc.pdu.len() + 1) as u8,
                raw,
            },
        );
        m.requests += 1;
        m.last = seq;
        line.counters.requests += 1;
        logf!(
            log,
            5,
            "master {}: request 0x{function:02X} for unit {unit} queued on line {} ({} waiting)",
            inc.connection,
            line.spec.name,
            m.queue.len()
        );
        Verdict::Queued
    }

    /// When line `line` may be given its next request: `None`, nothing to send (or
    /// a request on it); else the time (`now` or before: at once).
    pub fn send_at(&self, line: usize, now: Instant) -> Option<Instant> {
        let l = self.lines.get(line)?;
        let work = match &l.current {
            Some(c) => !c.on_wire,
            None => !l.ready.is_empty(),
        };
        work.then(|| l.quiet_until.unwrap_or(now))
    }

    /// The next request for line `line` (unit, then PDU), if one may go now: it is
    /// then on the line until [`Core::completed`].
    pub fn next_send(&mut self, line: usize, now: Instant) -> Option<&[u8]> {
        let l = self.lines.get_mut(line)?;
        if l.quiet_until.is_some_and(|q| now < q) || l.current.as_ref().is_some_and(|c| c.on_wire) {
            return None;
        }
        if l.current.is_none() {
            let req = loop {
                let conn = l.ready.pop_front()?;
                let Some(m) = l.masters.get_mut(&conn) else { continue };
                let Some(req) = m.queue.pop_front(&mut l.pool) else { continue };
                if !m.queue.is_empty() {
                    l.ready.push_back(conn);
                }
                break req;
            };
            l.current = Some(Current { req, on_wire: false });
        }
        let c = l.current.as_mut().expect("a request for the line");
        c.on_wire = true;
        c.req.tries = c.req.tries.saturating_add(1);
        Some(c.req.raw())
    }

    /// What the line did with its request: the answer's PDU, or why not (with the
    /// library's message). Returns where the answer goes, if anywhere (`None`: sent
    /// again after the pause, or its master is gone).
    pub fn completed(
        &mut self,
        line: usize,
        result: Result<Vec<u8>, (Failure, &dyn fmt::Display)>,
        now: Instant,
    ) -> Option<(Dest, Answer)> {
        let pause = self.rules.pause();
        let l = self.lines.get_mut(line)?;
        let cur = l.current.take_if(|c| c.on_wire)?;
        l.quiet_until = Some(now + if pause.is_zero() { l.spec.gap } else { pause });
        let gone = !l.masters.contains_key(&cur.req.conn);
        let broadcast = l.spec.serial && cur.req.raw[0] == 0;
        let log = &mut self.log;
        let answer = match result {
            Ok(_) if broadcast => {
                if self.rules.reply_on_broadcast() {
                    Answer::Pdu(cur.req.raw()[1..].to_vec())
                } else {
                    Answer::Nothing
                }
            }
            Ok(pdu) => {
                l.counters.served += 1;
                Answer::Pdu(pdu)
            }
            Err((failure, why)) => {
                if failure == Failure::BadAnswer {
                    l.counters.bad_answers += 1;
                } else {
                    l.counters.timeouts += 1;
                }
                let retries = self.rules.retries();
                let again = matches!(failure, Failure::NoAnswer | Failure::BadAnswer);
                if again && !gone && !broadcast && cur.req.tries <= retries {
                    logf!(
                        log,
                        3,
                        "line {}: unit {}, request 0x{:02X}: {why}, try {} of {}",
                        l.spec.name,
                        cur.req.raw[0],
                        cur.req.raw[1],
                        u32::from(cur.req.tries) + 1,
                        u32::from(retries) + 1
                    );
                    // Again, first, after the pause.
                    l.current = Some(Current { req: cur.req, on_wire: false });
                    return None;
                }
                logf!(
                    log,
                    1,
                    "line {}: unit {}, request 0x{:02X}: {why} after {} tries",
                    l.spec.name,
                    cur.req.raw[0],
                    cur.req.raw[1],
                    cur.req.tries
                );
                l.counters.exceptions += 1;
                Answer::Exception(match failure {
                    Failure::BadAnswer => exception::SLAVE_OR_SERVER_FAILURE,
                    Failure::Unreachable => exception::GATEWAY_PATH,
                    Failure::NoAnswer | Failure::NotSent => exception::GATEWAY_TARGET,
                })
            }
        };
        if gone {
            return None;
        }
        Some((cur.req.dest(), answer))
    }

    /// A master's connection closed: its queued requests go (the fronts forget
    /// them with the connection); the one on a line finishes, unanswered.
    pub fn closed(&mut self, connection: u64) {
        let mut dropped = 0;
        for l in &mut self.lines {
            if let Some(mut m) = l.masters.remove(&connection) {
                l.udp_masters -= usize::from(m.udp);
                if !m.queue.is_empty() {
                    dropped += m.queue.len();
                    l.ready.retain(|&c| c != connection);
                }
                while m.queue.pop_front(&mut l.pool).is_some() {}
                // Its request waiting to go again does not.
                if l.current.take_if(|c| !c.on_wire && c.req.conn == connection).is_some() {
                    dropped += 1;
                }
            }
        }
        if dropped > 0 {
            logf!(&mut self.log, 4, "master {connection}: gone, {dropped} request(s) dropped");
        }
    }

    /// The log lines that are due (the refusals as busy of the last second).
    pub fn tick(&mut self, now: Instant) {
        for l in &mut self.lines {
            if l.busy_unlogged > 0 && l.busy_logged.is_none_or(|t| now >= t + Duration::from_secs(1)) {
                l.log_busy(&mut self.log, now);
            }
        }
    }

    /// When [`Core::tick`] has something to do.
    pub fn tick_at(&self) -> Option<Instant> {
        self.lines
            .iter()
            .filter(|l| l.busy_unlogged > 0)
            .filter_map(|l| l.busy_logged.map(|t| t + Duration::from_secs(1)))
            .min()
    }
}

/// A request refused as busy: counted, logged at most once a second per line.
fn refuse<L: Log>(line: &mut Line, log: &mut L, now: Instant, master: Option<u64>) -> Verdict {
    if let Some(m) = master.and_then(|c| line.masters.get_mut(&c)) {
        m.busy += 1;
    }
    line.counters.exceptions += 1;
    line.busy_unlogged += 1;
    if line.busy_logged.is_none_or(|t| now >= t + Duration::from_secs(1)) {
        line.log_busy(log, now);
    }
    Verdict::Exception(exception::SLAVE_OR_SERVER_BUSY)
}

/// The rules of the running configuration.
impl Rules for crate::config::Config {
    fn route(&self, unit: u8) -> Option<(usize, u8)> {
        crate::config::Config::route(self, unit)
    }
    fn authorized(&self, role: Option<&str>, unit: u8, function: u8) -> bool {
        crate::config::Config::authorized(self, role, unit, function)
    }
    fn plain_reaches(&self, unit: u8) -> bool {
        crate::config::Config::plain_reaches(self, unit)
    }
    fn allowed_udp(&self, ip: IpAddr) -> bool {
        crate::config::Config::allowed_udp(self, ip)
    }
    fn retries(&self) -> u8 {
        self.retries
    }
    fn pause(&self) -> Duration {
        Duration::from_millis(u64::from(self.pause_ms))
    }
    fn reply_on_broadcast(&self) -> bool {
        self.replyonbroadcast
    }
    fn udp_masters_max(&self) -> usize {
        self.maxconn as usize
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::log::Memory;

    /// Rules for tests: routes as (first, last, line, offset); roles (name, write,
    /// first, last).
    #[derive(Default)]
    struct T {
        routes: Vec<(u8, u8, usize, i16)>,
        roles: Vec<(&'static str, bool, u8, u8)>,
        plain: Option<(u8, u8)>,
        retries: u8,
        pause_ms: u64,
        echo: bool,
        udp_max: usize,
    }

    impl Rules for T {
        fn route(&self, unit: u8) -> Option<(usize, u8)> {
            if self.routes.is_empty() {
                return Some((0, unit));
            }
            let r = self.routes.iter().find(|r| (r.0..=r.1).contains(&unit))?;
            Some((r.2, u8::try_from(i16::from(unit) + r.3).ok()?))
        }
        fn authorized(&self, role: Option<&str>, unit: u8, function: u8) -> bool {
            let read = (1..=4).contains(&function);
            self.roles.iter().any(|r| Some(r.0) == role && (r.2..=r.3).contains(&unit) && (read || r.1))
        }
        fn plain_reaches(&self, unit: u8) -> bool {
            self.plain.is_none_or(|(a, b)| (a..=b).contains(&unit))
        }
        fn allowed_udp(&self, ip: IpAddr) -> bool {
            ip.is_loopback()
        }
        fn retries(&self) -> u8 {
            self.retries
        }
        fn pause(&self) -> Duration {
            Duration::from_millis(self.pause_ms)
        }
        fn reply_on_broadcast(&self) -> bool {
            self.echo
        }
        fn udp_masters_max(&self) -> usize {
            self.udp_max
        }
    }

    fn core(t: T, lines: &[&str]) -> Core<T, Memory> {
        let specs = lines
            .iter()
            .map(|n| LineSpec { name: (*n).to_owned(), gap: Duration::from_millis(2), serial: true })
            .collect();
        Core::new(t, Memory { level: 9, lines: Vec::new() }, specs)
    }

    fn inc(kind: Front, conn: u64, id: i32, unit: u8, pdu: &[u8]) -> Incoming<'_> {
        Incoming {
            front: 0,
            kind,
            request_id: id,
            connection: conn,
            unit,
            protocol_id: 0,
            role: None,
            peer: Some(IpAddr::from([127, 0, 0, 1])),
            pdu,
        }
    }

    const READ: &[u8] = &[3, 0, 0, 0, 1];

    #[test]
    fn turns_between_masters() {
        let mut c = core(T::default(), &["default"]);
        let t = Instant::now();
        for id in 0..3 {
            assert_eq!(c.request(&inc(Front::Tcp, 1, id, 1, READ), t), Verdict::Queued);
        }
        assert_eq!(c.request(&inc(Front::Tcp, 2, 10, 1, READ), t), Verdict::Queued);
        let mut order = Vec::new();
        let mut now = t;
        while let Some(at) = c.send_at(0, now) {
            now = now.max(at);
            assert_eq!(c.next_send(0, now).unwrap(), &[1, 3, 0, 0, 0, 1]);
            assert!(c.next_send(0, now).is_none(), "one at a time");
            let (d, a) = c.completed(0, Ok(vec![3, 2, 0, 7]), now).unwrap();
            assert_eq!(a, Answer::Pdu(vec![3, 2, 0, 7]));
            order.push(d.request_id);
            assert!(c.send_at(0, now).is_none_or(|at| at > now), "the pause");
        }
        assert_eq!(order, [0, 10, 1, 2]);
        assert_eq!(c.lines()[0].counters().served, 4);
        assert_eq!(c.lines()[0].depth(), 0);
    }

    #[test]
    fn queue_full_busy_logged_once_a_second() {
        let mut c = core(T::default(), &["default"]);
        let t = Instant::now();
        for id in 0..QUEUE_MAX as i32 {
            assert_eq!(c.request(&inc(Front::Tcp, 1, id, 1, READ), t), Verdict::Queued);
        }
        for id in 0..100 {
            assert_eq!(c.request(&inc(Front::Tcp, 1, 100 + id, 1, READ), t), Verdict::Exception(6));
        }
        let busy: Vec<_> = c.log.lines.iter().filter(|l| l.1.contains("busy")).cloned().collect();
        assert_eq!(busy, [(2, "line default: 1 request(s) refused, queues full (busy)".to_owned())]);
        assert_eq!(c.tick_at(), Some(t + Duration::from_secs(1)));
        c.tick(t + Duration::from_millis(999));
        c.tick(t + Duration::from_secs(1));
        assert!(c.log.lines.iter().any(|l| l.1 == "line default: 99 request(s) refused, queues full (busy)"));
        assert_eq!(c.tick_at(), None);
        assert_eq!(c.lines()[0].masters()[0].busy, 100);
    }

    #[test]
    fn closed_master_drops_its_queue() {
        let mut c = core(T::default(), &["default"]);
        let t = Instant::now();
        for id in 0..4 {
            c.request(&inc(Front::Tcp, 1, id, 1, READ), t);
        }
        c.request(&inc(Front::Tcp, 2, 9, 1, READ), t);
        assert!(c.next_send(0, t).is_some()); // master 1's first
        c.closed(1);
        // Its request on the line finishes, answered nowhere; then master 2's.
        assert_eq!(c.completed(0, Ok(vec![3, 2, 0, 0]), t), None);
        let now = c.send_at(0, t).unwrap();
        c.next_send(0, now).unwrap();
        assert_eq!(c.completed(0, Ok(vec![3, 2, 0, 0]), now).unwrap().0.request_id, 9);
        assert_eq!(c.send_at(0, now), None);
        // A new master with a new id starts afresh.
        assert_eq!(c.request(&inc(Front::Tcp, 3, 1, 1, READ), t), Verdict::Queued);
        assert_eq!(c.lines()[0].masters().len(), 2);
    }

    #[test]
    fn closed_master_during_the_retry_wait() {
        let mut c = core(T { retries: 3, ..T::default() }, &["default"]);
        let t = Instant::now();
        c.request(&inc(Front::Tcp, 1, 1, 1, READ), t);
        c.next_send(0, t).unwrap();
        assert_eq!(c.completed(0, Err((Failure::NoAnswer, &"timeout")), t), None);
        assert!(c.lines()[0].on_line().is_some_and(|(_, sent)| !sent));
        c.closed(1);
        // Not sent again, not answered (fuzz target gateway_master).
        assert_eq!(c.lines()[0].on_line(), None);
        assert_eq!(c.send_at(0, t), None);
        assert!(c.set_available(0, false).is_empty());
    }

    #[test]
    fn retries_then_exceptions() {
        let mut c = core(T { retries: 2, ..T::default() }, &["default"]);
        let t = Instant::now();
        let mut now = t;
        c.request(&inc(Front::Tcp, 1, 5, 1, READ), t);
        c.request(&inc(Front::Tcp, 2, 6, 1, READ), t);
        let mut sends = 0;
        let res = loop {
            now = now.max(c.send_at(0, now).unwrap());
            c.next_send(0, now).unwrap();
            sends += 1;
            if let Some(r) = c.completed(0, Err((Failure::NoAnswer, &"Connection timed out")), now) {
                break r;
            }
        };
        assert_eq!(sends, 3);
        assert_eq!(res, (Dest { front: 0, request_id: 5 }, Answer::Exception(0x0B)));
        now = now.max(c.send_at(0, now).unwrap());
        c.next_send(0, now).unwrap();
        assert_eq!(c.completed(0, Err((Failure::Unreachable, &"refused")), now).unwrap().1, Answer::Exception(0x0A));
        c.request(&inc(Front::Tcp, 1, 7, 1, READ), t);
        let res = loop {
            now = now.max(c.send_at(0, now).unwrap());
            c.next_send(0, now).unwrap();
            if let Some(r) = c.completed(0, Err((Failure::BadAnswer, &"Invalid CRC")), now) {
                break r;
            }
        };
        assert_eq!(res.1, Answer::Exception(0x04));
        let k = c.lines()[0].counters();
        assert_eq!((k.timeouts, k.bad_answers, k.exceptions), (4, 3, 3));
        assert!(
            c.log.lines.iter().any(|l| l.1 == "line default: unit 1, request 0x03: Connection timed out, try 2 of 3")
        );
    }

    #[test]
    fn broadcasts() {
        for echo in [false, true] {
            let mut c = core(T { echo, retries: 3, ..T::default() }, &["default"]);
            let t = Instant::now();
            c.request(&inc(Front::Tcp, 1, 5, 0, &[6, 0, 1, 0, 2]), t);
            assert_eq!(c.next_send(0, t).unwrap(), &[0, 6, 0, 1, 0, 2]);
            let a = c.completed(0, Ok(Vec::new()), t).unwrap().1;
            assert_eq!(a, if echo { Answer::Pdu(vec![6, 0, 1, 0, 2]) } else { Answer::Nothing });
        }
    }

    #[test]
    fn policy() {
        let t = T {
            routes: vec![(1, 1, 0, 0), (2, 2, 1, -1)],
            roles: vec![("Op", true, 1, 1), ("Reader", false, 1, 2)],
            plain: Some((2, 2)),
            ..T::default()
        };
        let mut c = core(t, &["default", "b"]);
        let now = Instant::now();
        let tls = |role, unit, pdu| Incoming { role, ..inc(Front::Tls, 1, 1, unit, pdu) };
        assert_eq!(c.request(&tls(Some("Op"), 1, &[6, 0, 0, 0, 1]), now), Verdict::Queued);
        assert_eq!(c.request(&tls(Some("Reader"), 1, &[6, 0, 0, 0, 1]), now), Verdict::Exception(1));
        assert_eq!(c.request(&tls(Some("Reader"), 2, READ), now), Verdict::Queued);
        assert_eq!(c.request(&tls(None, 1, READ), now), Verdict::Exception(1));
        assert_eq!(c.request(&tls(Some("Op"), 2, READ), now), Verdict::Exception(1));
        // The plain fronts: unit 2 only; unit 1 is the TLS front's.
        for kind in [Front::Tcp, Front::RtuTcp, Front::Udp] {
            assert_eq!(c.request(&inc(kind, 2, 1, 1, READ), now), Verdict::Exception(0x0A));
            assert_eq!(c.request(&inc(kind, 2, 1, 2, READ), now), Verdict::Queued);
        }
        // Routed: unit 2 is line b's unit 1.
        assert_eq!(c.next_send(1, now).unwrap()[0], 1);
        assert!(c.log.lines.iter().any(|l| l.0 == 5 && l.1.contains("line b")));
        // No route.
        assert_eq!(c.request(&tls(Some("Reader"), 3, READ), now), Verdict::Exception(1));
        // A non-zero MBAP protocol id.
        assert_eq!(c.request(&Incoming { protocol_id: 1, ..inc(Front::Tcp, 2, 1, 2, READ) }, now), Verdict::Close);
        // UDP: not in udp_allow, no answer.
        let far = Incoming { peer: Some(IpAddr::from([10, 0, 0, 1])), ..inc(Front::Udp, 9, 1, 2, READ) };
        assert_eq!(c.request(&far, now), Verdict::Ignore);
        let none = Incoming { peer: None, ..inc(Front::Udp, 9, 1, 2, READ) };
        assert_eq!(c.request(&none, now), Verdict::Ignore);
    }

    #[test]
    fn udp_senders_have_queues_of_their_own_bounded() {
        let mut c = core(T { udp_max: 2, ..T::default() }, &["default"]);
        let t = Instant::now();
        for id in 0..QUEUE_MAX as i32 {
            assert_eq!(c.request(&inc(Front::Udp, 1, id, 1, READ), t), Verdict::Queued);
        }
        // A second sender is not refused for the first one's full queue.
        assert_eq!(c.request(&inc(Front::Udp, 2, 0, 1, READ), t), Verdict::Queued);
        // A third: both others have requests waiting: busy.
        assert_eq!(c.request(&inc(Front::Udp, 3, 0, 1, READ), t), Verdict::Exception(6));
        // Sender 2 served: it is idle, and the oldest idle one goes for sender 3.
        let mut now = t;
        for _ in 0..2 {
            now = now.max(c.send_at(0, now).unwrap());
            c.next_send(0, now).unwrap();
            c.completed(0, Ok(vec![3, 2, 0, 0]), now).unwrap();
        }
        assert_eq!(c.request(&inc(Front::Udp, 3, 0, 1, READ), t), Verdict::Queued);
        let conns: Vec<u64> = c.lines()[0].masters().iter().map(|m| m.connection).collect();
        assert_eq!(conns, [1, 3]);
        // TCP masters do not count.
        assert_eq!(c.request(&inc(Front::Tcp, 4, 0, 1, READ), t), Verdict::Queued);
    }

    #[test]
    fn unavailable_line() {
        let mut c = core(T::default(), &["default"]);
        let t = Instant::now();
        c.request(&inc(Front::Tcp, 1, 1, 1, READ), t);
        let out = c.set_available(0, false);
        assert_eq!(out, [(Dest { front: 0, request_id: 1 }, Answer::Exception(0x0A))]);
        assert_eq!(c.request(&inc(Front::Tcp, 1, 2, 1, READ), t), Verdict::Exception(0x0A));
        assert_eq!(c.send_at(0, t), None);
        c.set_available(0, true);
        assert_eq!(c.request(&inc(Front::Tcp, 1, 3, 1, READ), t), Verdict::Queued);
    }

    #[test]
    fn pause_zero_is_the_lines_gap() {
        let mut c = core(T::default(), &["default"]);
        let t = Instant::now();
        c.request(&inc(Front::Tcp, 1, 1, 1, READ), t);
        c.request(&inc(Front::Tcp, 1, 2, 1, READ), t);
        c.next_send(0, t).unwrap();
        c.completed(0, Ok(vec![3, 2, 0, 0]), t);
        assert_eq!(c.send_at(0, t), Some(t + Duration::from_millis(2)));
    }
}
