//! Target `gateway_master`: masters' bytes (Modbus/TCP framing) through the
//! gateway's core (`rsmodbus_gateway::core`) to two simulated lines that answer as
//! the input says: the request echoed, an exception, silence, garbage, a line that
//! cannot be reached, a request that could not be sent.
//!
//! Input: 3 bytes of settings, then operations:
//! - byte 0: retries (bits 0-1), `-b` (bit 2), UDP senders per line 1-4 (bits 3-4),
//!   line `b` serial or a network line (bit 5);
//! - byte 1: `plain_units`: the units whose `unit % 9` is below `byte % 10`;
//! - byte 2: routes: none (every unit to the default line), or units 1-8 to it and
//!   9-16 to line `b` as 1-8 (bit 0); roles `Operator = rw 1-3`, `Reader = r 1-247`;
//!   `udp_allow = 127.0.0.0/8`;
//! - then each operation is a byte (`op % 8`) and its arguments:
//!   - 0, 1: bytes for a master (`m = next & 7`, `n = next % 32 + 1` bytes follow):
//!     MBAP frames (a length out of 2-254 closes the connection, as the front does);
//!     masters 0-3 are Modbus/TCP, 4 RTU over TCP (protocol id 0), 5 and 6
//!     Modbus/TCP Security (roles Operator, Reader; none when the first byte of the
//!     frame is odd), 7 Modbus/UDP (the sender is `next >> 3` of 32, odd ones
//!     outside udp_allow);
//!   - 2: a line (`next & 1`) completes its request as `next` says;
//!   - 3: a master's connection closes (`next & 7`; it comes back with a new id);
//!   - 4: time goes by (`next` * 4 ms); the due log lines;
//!   - 5: line `b` becomes unavailable or available (`next & 1`);
//!   - 6, 7: the lines are given their next requests.
//!
//! Properties: no panic; a request is queued only if the policy lets it through
//! (protocol id 0, the UDP sender allowed, the TLS role's units and access, the
//! plain fronts' units, a route); what goes on a line is the request's PDU with the
//! unit its route gives, on that line, one at a time; every queued request is
//! answered exactly once, to its front and id, unless its master left (then never);
//! an answer is what the line said (or the gateway's exception); queues stay within
//! 16 per master; at the end, with the lines answering, nothing is left.

use std::collections::HashMap;
use std::net::IpAddr;
use std::time::{Duration, Instant};

use rsmodbus_gateway::config::{Config, LineDef, LineKind, Net, Role, Route, UnitSet};
use rsmodbus_gateway::core::{
    Answer, Core, Dest, Failure, Front, Incoming, LineSpec, QUEUE_MAX, Rules, Verdict, exception,
};
use rsmodbus_gateway::log::Null;

struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn next(&mut self) -> Option<u8> {
        let (&b, rest) = self.0.split_first()?;
        self.0 = rest;
        Some(b)
    }
    fn take(&mut self, n: usize) -> &[u8] {
        let n = n.min(self.0.len());
        let (a, b) = self.0.split_at(n);
        self.0 = b;
        a
    }
}

/// A request the core queued: what must reach the line, and who gets the answer.
struct Queued {
    master: usize,
    conn: u64,
    line: usize,
    raw: Vec<u8>,
}

struct Sim {
    core: Core<Config, Null>,
    now: Instant,
    /// Each master's bytes not framed yet, and its connection id.
    streams: [Vec<u8>; 8],
    conns: [u64; 8],
    next_conn: u64,
    next_id: i32,
    queued: HashMap<Dest, Queued>,
    serial_b: bool,
}

fn front_of(master: usize) -> Front {
    match master {
        0..=3 => Front::Tcp,
        4 => Front::RtuTcp,
        5 | 6 => Front::Tls,
        _ => Front::Udp,
    }
}

fn config(b0: u8, b1: u8, b2: u8) -> Config {
    let mut c = Config {
        retries: b0 & 3,
        replyonbroadcast: b0 & 4 != 0,
        maxconn: u32::from((b0 >> 3) & 3) + 1,
        pause_ms: 1,
        ..Config::default()
    };
    let kind = if b0 & 0x20 != 0 {
        LineKind::Serial { device: "/dev/b".into(), speed: 9600, mode: c.mode }
    } else {
        LineKind::Tcp { host: "127.0.0.1".into(), port: "502".into() }
    };
    c.lines.push(LineDef { name: "b".into(), kind });
    let mut plain = UnitSet::none();
    for u in 0..=255u8 {
        if u % 9 < b1 % 10 {
            plain.insert(u);
        }
    }
    c.plain_units = plain;
    if b2 & 1 != 0 {
        c.routes =
            vec![Route { first: 1, last: 8, line: 0, offset: 0 }, Route { first: 9, last: 16, line: 1, offset: -8 }];
    }
    c.roles = vec![
        Role { name: "Operator".into(), write: true, first: 1, last: 3 },
        Role { name: "Reader".into(), write: false, first: 1, last: 247 },
    ];
    c.udp_allow = vec![Net { addr: IpAddr::from([127, 0, 0, 0]), prefix: 8 }];
    c
}

impl Sim {
    fn new(c: Config) -> Sim {
        let serial_b = matches!(c.lines[1].kind, LineKind::Serial { .. });
        let specs = vec![
            LineSpec { name: "default".into(), gap: Duration::from_millis(4), serial: true },
            LineSpec { name: "b".into(), gap: Duration::ZERO, serial: serial_b },
        ];
        Sim {
            core: Core::new(c, Null, specs),
            now: Instant::now(),
            streams: Default::default(),
            conns: [1, 2, 3, 4, 5, 6, 7, 8],
            next_conn: 9,
            next_id: 0,
            queued: HashMap::new(),
            serial_b,
        }
    }

    /// The policy the core must enforce, for a request that reached it.
    fn allowed(&self, kind: Front, role: Option<&str>, unit: u8, function: u8) -> Option<(usize, u8)> {
        let r = &self.core.rules;
        let policy = if kind == Front::Tls { r.authorized(role, unit, function) } else { r.plain_reaches(unit) };
        if !policy {
            return None;
        }
        r.route(unit)
    }

    fn close(&mut self, m: usize) {
        let conn = self.conns[m];
        self.core.closed(conn);
        self.queued.retain(|_, q| q.conn != conn);
        self.streams[m].clear();
        self.conns[m] = self.next_conn;
        self.next_conn += 1;
    }

    fn bytes(&mut self, m: usize, data: &[u8], sender: u8) {
        self.streams[m].extend_from_slice(data);
        loop {
            let s = &self.streams[m];
            if s.len() < 7 {
                return;
            }
            let len = usize::from(u16::from_be_bytes([s[4], s[5]]));
            if !(2..=254).contains(&len) {
                // The front closes such a connection.
                if front_of(m) == Front::Udp {
                    self.streams[m].clear();
                } else {
                    self.close(m);
                }
                return;
            }
            if s.len() < 6 + len {
                return;
            }
            let frame: Vec<u8> = self.streams[m].drain(..6 + len).collect();
            self.request(m, &frame, sender);
        }
    }

    fn request(&mut self, m: usize, frame: &[u8], sender: u8) {
        let kind = front_of(m);
        let protocol_id = if kind == Front::RtuTcp { 0 } else { u16::from_be_bytes([frame[2], frame[3]]) };
        let (unit, pdu) = (frame[6], &frame[7..]);
        let role = match m {
            _ if frame[0] & 1 == 1 => None,
            5 => Some("Operator"),
            6 => Some("Reader"),
            _ => None,
        };
        let (conn, peer) = if kind == Front::Udp {
            // UDP: each sender a master of its own.
            let ip = if sender & 1 == 0 { [127, 0, 0, sender] } else { [10, 0, 0, sender] };
            (1_000_000 + u64::from(sender), IpAddr::from(ip))
        } else {
            (self.conns[m], IpAddr::from([127, 0, 0, 1]))
        };
        self.next_id += 1;
        let id = self.next_id;
        let inc = Incoming {
            front: m,
            kind,
            request_id: id,
            connection: conn,
            unit,
            protocol_id,
            role: if kind == Front::Tls { role } else { None },
            peer: Some(peer),
            pdu,
        };
        let verdict = self.core.request(&inc, self.now);
        let rules = &self.core.rules;
        let udp_ok = kind != Front::Udp || rules.allowed_udp(peer);
        match verdict {
            Verdict::Close => {
                assert!(protocol_id != 0 && kind != Front::Udp);
                self.close(m);
            }
            Verdict::Ignore => assert!(protocol_id != 0 || !udp_ok, "ignored for no reason"),
            Verdict::Exception(e) => {
                assert!(protocol_id == 0 && udp_ok);
                let allowed = self.allowed(kind, inc.role, unit, pdu[0]);
                match e {
                    exception::ILLEGAL_FUNCTION => {
                        assert!(kind == Front::Tls && !rules.authorized(inc.role, unit, pdu[0]));
                    }
                    exception::GATEWAY_PATH => assert!(allowed.is_none() || allowed.is_some_and(|(l, _)| l == 1)),
                    exception::SLAVE_OR_SERVER_BUSY => assert!(allowed.is_some()),
                    _ => panic!("exception {e:#x} at once"),
                }
            }
            Verdict::Queued => {
                assert!(protocol_id == 0 && udp_ok, "queued past the front's rules");
                let (line, there) = self.allowed(kind, inc.role, unit, pdu[0]).expect("queued outside the policy");
                let mut raw = vec![there];
                raw.extend_from_slice(pdu);
                let dest = Dest { front: m, request_id: id };
                assert!(self.queued.insert(dest, Queued { master: m, conn, line, raw }).is_none());
            }
        }
    }

    /// An answer the core gave: to a request waiting, once.
    fn answered(&mut self, dest: Dest, answer: &Answer, line_said: Option<&[u8]>) {
        let q = self.queued.remove(&dest).expect("an answer to a request not waiting (or twice)");
        assert_eq!(front_of(q.master), front_of(dest.front));
        let broadcast = q.raw[0] == 0 && (q.line == 0 || self.serial_b);
        match answer {
            Answer::Pdu(p) if broadcast => assert_eq!(p[..], q.raw[1..]),
            Answer::Pdu(p) => assert_eq!(Some(&p[..]), line_said, "not what the line said"),
            Answer::Nothing => assert!(broadcast && !self.core.rules.replyonbroadcast),
            Answer::Exception(e) => assert!(
                [exception::SLAVE_OR_SERVER_FAILURE, exception::GATEWAY_PATH, exception::GATEWAY_TARGET].contains(e)
            ),
        }
    }

    fn dispatch(&mut self) {
        for line in 0..2 {
            let Some(raw) = self.core.next_send(line, self.now).map(<[u8]>::to_vec) else { continue };
            assert!(self.core.next_send(line, self.now).is_none(), "two requests on a line");
            let (dest, sent) = self.core.lines()[line].on_line().expect("the request sent");
            assert!(sent);
            if let Some(q) = self.queued.get(&dest) {
                assert_eq!(q.line, line, "on another line than its route's");
                assert_eq!(q.raw, raw, "not the request (or its unit not the route's)");
            }
        }
    }

    fn complete(&mut self, line: usize, how: u8, data: &[u8]) {
        let Some((_, true)) = self.core.lines()[line].on_line() else { return };
        let raw = self.core.lines()[line].on_line().and_then(|(d, _)| self.queued.get(&d)).map(|q| q.raw.clone());
        let echo = raw.map(|r| r[1..].to_vec()).unwrap_or_else(|| vec![3, 0]);
        let said: Option<Vec<u8>> = match how % 8 {
            0 => Some(echo),
            1 => Some(vec![echo[0] | 0x80, data.first().copied().unwrap_or(2)]),
            6 => Some(data.to_vec()),
            7 => Some(Vec::new()),
            _ => None,
        };
        let failure = match how % 8 {
            2 => Failure::NoAnswer,
            3 => Failure::BadAnswer,
            4 => Failure::Unreachable,
            _ => Failure::NotSent,
        };
        let out = match &said {
            Some(p) => self.core.completed(line, Ok(p.clone()), self.now),
            None => self.core.completed(line, Err((failure, &"simulated")), self.now),
        };
        if let Some((dest, answer)) = out {
            self.answered(dest, &answer, said.as_deref());
        }
    }

    fn check(&self) {
        for l in self.core.lines() {
            for m in l.masters() {
                assert!(m.depth <= QUEUE_MAX, "a queue past {QUEUE_MAX}");
            }
            if l.masters().iter().filter(|m| m.connection >= 1_000_000).count() > self.core.rules.udp_masters_max() {
                panic!("more UDP senders than maxconn on a line");
            }
        }
    }
}

pub fn gateway_master(data: &[u8]) {
    let mut input = Bytes(data);
    let (Some(b0), Some(b1), Some(b2)) = (input.next(), input.next(), input.next()) else { return };
    let mut sim = Sim::new(config(b0, b1, b2));
    while let Some(op) = input.next() {
        let arg = input.next().unwrap_or(0);
        match op % 8 {
            0 | 1 => {
                let n = usize::from(input.next().unwrap_or(0) % 32) + 1;
                let bytes = input.take(n).to_vec();
                sim.bytes(usize::from(arg & 7), &bytes, arg >> 3);
            }
            2 => {
                let extra = input.take(usize::from(arg >> 4)).to_vec();
                sim.complete(usize::from(arg & 1), arg >> 1, &extra);
            }
            3 => sim.close(usize::from(arg & 7)),
            4 => {
                sim.now += Duration::from_millis(u64::from(arg) * 4);
                sim.core.tick(sim.now);
            }
            5 => {
                for (dest, answer) in sim.core.set_available(1, arg & 1 == 1) {
                    sim.answered(dest, &answer, None);
                }
            }
            _ => sim.dispatch(),
        }
        sim.check();
    }
    // The end: the lines available and answering; every request still waiting is
    // answered.
    for (dest, answer) in sim.core.set_available(1, true) {
        sim.answered(dest, &answer, None);
    }
    for _ in 0..(QUEUE_MAX * 50 * 4) {
        if sim.queued.is_empty() && (0..2).all(|l| sim.core.lines()[l].on_line().is_none()) {
            break;
        }
        sim.now += Duration::from_millis(50);
        sim.dispatch();
        for line in 0..2 {
            sim.complete(line, 0, &[]);
        }
    }
    assert!(sim.queued.is_empty(), "{} request(s) never answered", sim.queued.len());
    for l in sim.core.lines() {
        assert_eq!(l.depth(), 0, "requests left on line {}", l.name());
    }
}
