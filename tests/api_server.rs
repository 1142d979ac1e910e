//! The Rust API's server (`api::Server` over the runner, `api::Handler`) on
//! loopback: the handler's answers and what it learns of a request, answers given
//! later, `Reply::Close`, `Handler::closed`, and `set_close_when_full`. Each server
//! runs on the test's thread; its clients are plain sockets on threads of their
//! own, which report what they read through a channel.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::sync::mpsc::{Receiver, channel};
use std::time::{Duration, Instant};

use modbus::api::{Error, Handler, Later, Modbus, Reply, RequestInfo, Server};

/// What a handler saw of a request, owned.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Seen {
    unit: u8,
    function: u8,
    transaction_id: u16,
    protocol_id: u16,
    request_id: i32,
    connection_id: u64,
    peer: Option<SocketAddr>,
    pdu: Vec<u8>,
}

/// A handler that records what it sees and answers as `reply` says.
struct Recorder {
    seen: Vec<Seen>,
    closed: Vec<u64>,
    reply: fn(&RequestInfo<'_>, &[u8]) -> Reply,
}

impl Recorder {
    fn new(reply: fn(&RequestInfo<'_>, &[u8]) -> Reply) -> Recorder {
        Recorder { seen: Vec::new(), closed: Vec::new(), reply }
    }
}

impl Handler for Recorder {
    fn request(&mut self, info: &RequestInfo<'_>, pdu: &[u8]) -> Reply {
        self.seen.push(Seen {
            unit: info.unit,
            function: info.function,
            transaction_id: info.transaction_id,
            protocol_id: info.protocol_id,
            request_id: info.request_id,
            connection_id: info.connection_id,
            peer: info.peer,
            pdu: pdu.to_vec(),
        });
        (self.reply)(info, pdu)
    }

    fn closed(&mut self, connection_id: u64) {
        self.closed.push(connection_id);
    }
}

fn server(max: usize) -> (Server, SocketAddr) {
    let ctx = Modbus::new_tcp(Some("127.0.0.1"), "0").unwrap();
    let server = Server::new(ctx, max).unwrap();
    let addr = server.local_addr().unwrap();
    (server, addr)
}

/// Runs `server` until `done` says so (5 s at most: then the test fails).
fn run_until<H: Handler>(server: &mut Server, h: &mut H, mut done: impl FnMut(&mut H) -> bool) {
    let end = Instant::now() + Duration::from_secs(5);
    while !done(h) {
        assert!(Instant::now() < end, "not done in time");
        server.run(Some(Duration::from_millis(10)), h).unwrap();
    }
}

/// A client on its own thread: `f` gets the connected socket, its result comes
/// through the channel.
fn client<T: Send + 'static>(addr: SocketAddr, f: impl FnOnce(TcpStream) -> T + Send + 'static) -> Receiver<T> {
    let (tx, rx) = channel();
    std::thread::spawn(move || {
        let s = TcpStream::connect(addr).unwrap();
        s.set_read_timeout(Some(Duration::from_secs(3))).unwrap();
        let _ = tx.send(f(s));
    });
    rx
}

/// What a socket reads until EOF, an error or the read timeout: (bytes, EOF seen).
fn read_to_end(mut s: TcpStream) -> (Vec<u8>, bool) {
    let mut out = Vec::new();
    let mut buf = [0u8; 260];
    loop {
        match s.read(&mut buf) {
            Ok(0) => return (out, true),
            Ok(n) => out.extend(&buf[..n]),
            Err(_) => return (out, false),
        }
    }
}

/// Reads one MBAP answer (its header says how long).
fn read_answer(s: &mut TcpStream) -> Vec<u8> {
    let mut head = [0u8; 6];
    s.read_exact(&mut head).unwrap();
    let len = u16::from_be_bytes([head[4], head[5]]) as usize;
    let mut rest = vec![0u8; len];
    s.read_exact(&mut rest).unwrap();
    [head.to_vec(), rest].concat()
}

/// An MBAP request.
fn mbap(tid: u16, protocol: u16, unit: u8, pdu: &[u8]) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend(tid.to_be_bytes());
    v.extend(protocol.to_be_bytes());
    v.extend((pdu.len() as u16 + 1).to_be_bytes());
    v.push(unit);
    v.extend(pdu);
    v
}

/// Waits for a client's result while the server runs.
fn result<T, H: Handler>(server: &mut Server, h: &mut H, rx: &Receiver<T>) -> T {
    let mut got = None;
    run_until(server, h, |_| {
        got = got.take().or_else(|| rx.try_recv().ok());
        got.is_some()
    });
    got.unwrap()
}

#[test]
fn a_handler_answers_every_function_code_and_learns_who_asks() {
    let (mut server, addr) = server(4);
    let mut h = Recorder::new(|info, pdu| Reply::Pdu(vec![pdu[0], info.unit, 0x99]));
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(0x1234, 0, 7, &[0x41, 1, 2])).unwrap();
        let answer = read_answer(&mut s);
        (answer, s.local_addr().unwrap())
    });
    let (answer, local) = result(&mut server, &mut h, &rx);
    assert_eq!(answer, mbap(0x1234, 0, 7, &[0x41, 7, 0x99]), "a user-defined function code, answered whole");
    assert_eq!(h.seen.len(), 1);
    let seen = &h.seen[0];
    assert_eq!((seen.unit, seen.function, seen.transaction_id, seen.protocol_id), (7, 0x41, 0x1234, 0));
    assert_eq!(seen.pdu, [0x41, 1, 2]);
    assert_ne!(seen.connection_id, 0);
    assert!(seen.request_id > 0);
    assert_eq!(seen.peer, Some(local), "the client's address");
}

#[test]
fn exceptions_and_no_answer() {
    let (mut server, addr) = server(4);
    let mut h = Recorder::new(|_, pdu| match pdu[0] {
        0x03 => Reply::Exception(0x02),
        0x04 => Reply::Exception(0x40),
        _ => Reply::Nothing,
    });
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(1, 0, 1, &[0x03, 0, 0, 0, 1])).unwrap();
        let a = read_answer(&mut s);
        // An exception code out of range: the server device failed (04).
        s.write_all(&mbap(2, 0, 1, &[0x04, 0, 0, 0, 1])).unwrap();
        let b = read_answer(&mut s);
        // Nothing: no answer; the next request still is.
        s.write_all(&mbap(3, 0, 1, &[0x06, 0, 0, 0, 1])).unwrap();
        s.write_all(&mbap(4, 0, 1, &[0x03, 0, 0, 0, 1])).unwrap();
        let c = read_answer(&mut s);
        (a, b, c)
    });
    let (a, b, c) = result(&mut server, &mut h, &rx);
    assert_eq!(a, mbap(1, 0, 1, &[0x83, 0x02]));
    assert_eq!(b, mbap(2, 0, 1, &[0x84, 0x04]));
    assert_eq!(c, mbap(4, 0, 1, &[0x83, 0x02]), "no answer to 3, then 4's");
}

#[test]
fn an_answer_given_later() {
    let (mut server, addr) = server(4);
    let mut h = Recorder::new(|_, _| Reply::Later);
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(9, 0, 3, &[0x03, 0, 0, 0, 2])).unwrap();
        read_answer(&mut s)
    });
    run_until(&mut server, &mut h, |h| !h.seen.is_empty());
    let id = h.seen[0].request_id;
    // A register read answered with a count that is not the request's: refused, it
    // still waits.
    assert_eq!(server.answer(id, Later::Registers(vec![1])), Err(Error::INVALID));
    assert_eq!(server.answer(id + 1000, Later::Pdu(vec![0x03, 0])), Err(Error::INVALID), "no such request");
    server.answer(id, Later::Registers(vec![0x0102, 0x0304])).unwrap();
    let answer = result(&mut server, &mut h, &rx);
    assert_eq!(answer, mbap(9, 0, 3, &[0x03, 4, 1, 2, 3, 4]));
    assert_eq!(server.answer(id, Later::Nothing), Err(Error::INVALID), "answered already");
}

#[test]
fn close_drops_the_connection_without_an_answer_and_closed_is_told() {
    let (mut server, addr) = server(4);
    // mbusd drops a connection whose MBAP protocol id is not 0.
    let mut h =
        Recorder::new(|info, pdu| if info.protocol_id != 0 { Reply::Close } else { Reply::Pdu(vec![pdu[0], 0]) });
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(1, 0, 1, &[0x41])).unwrap();
        let first = read_answer(&mut s);
        // (A known function code: an unknown one after a protocol id that is not 0
        // is framed as libmodbus frames it, one byte after the code.)
        s.write_all(&mbap(2, 5, 1, &[0x03, 0, 0, 0, 1])).unwrap();
        (first, read_to_end(s))
    });
    let (first, (rest, eof)) = result(&mut server, &mut h, &rx);
    assert_eq!(first, mbap(1, 0, 1, &[0x41, 0]));
    assert_eq!((rest, eof), (vec![], true), "EOF, no answer");
    assert_eq!(h.seen[1].protocol_id, 5);
    let id = h.seen[1].connection_id;
    run_until(&mut server, &mut h, |h| !h.closed.is_empty());
    assert_eq!(h.closed, [id], "closed() names the connection Reply::Close ended");
    assert_eq!(server.clients(), 0);
}

#[test]
fn closed_is_told_when_the_client_leaves_and_at_the_idle_timeout() {
    let (mut server, addr) = server(4);
    server.set_idle_timeout(Some(Duration::from_millis(200)));
    let mut h = Recorder::new(|_, pdu| Reply::Pdu(vec![pdu[0], 1]));
    // A client that asks once and leaves.
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(1, 0, 1, &[0x42])).unwrap();
        read_answer(&mut s)
    });
    result(&mut server, &mut h, &rx);
    let id = h.seen[0].connection_id;
    run_until(&mut server, &mut h, |h| !h.closed.is_empty());
    assert_eq!(h.closed, [id], "the client closed its connection");
    // A client that says nothing: closed at the idle timeout.
    let rx = client(addr, read_to_end);
    let started = Instant::now();
    let (bytes, eof) = result(&mut server, &mut h, &rx);
    assert!(eof && bytes.is_empty());
    assert!(started.elapsed() >= Duration::from_millis(150));
    run_until(&mut server, &mut h, |h| h.closed.len() == 2);
    assert_ne!(h.closed[1], id);
    assert_ne!(h.closed[1], 0);
}

/// Two clients connected and served (their requests answered).
fn two_clients<H: Handler>(server: &mut Server, h: &mut H, addr: SocketAddr) -> Vec<TcpStream> {
    let rxs: Vec<_> = (0..2)
        .map(|i| {
            client(addr, move |mut s| {
                s.write_all(&mbap(i, 0, 1, &[0x41])).unwrap();
                read_answer(&mut s);
                s
            })
        })
        .collect();
    rxs.iter().map(|rx| result(server, h, rx)).collect()
}

#[test]
fn close_when_full_accepts_and_closes_at_the_maximum() {
    let (mut server, addr) = server(2);
    server.set_close_when_full(true);
    let mut h = Recorder::new(|_, pdu| Reply::Pdu(vec![pdu[0], 1]));
    let held = two_clients(&mut server, &mut h, addr);
    assert_eq!(server.clients(), 2);
    let started = Instant::now();
    let rx = client(addr, read_to_end);
    let (bytes, eof) = result(&mut server, &mut h, &rx);
    assert!(eof && bytes.is_empty(), "the third connection is closed at once");
    assert!(started.elapsed() < Duration::from_secs(1));
    assert_eq!(server.clients(), 2);
    assert!(h.closed.is_empty(), "it never was a client");
    // One leaves: the next is served.
    drop(held);
    run_until(&mut server, &mut h, |h| h.closed.len() == 2);
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(7, 0, 1, &[0x41])).unwrap();
        read_answer(&mut s)
    });
    assert_eq!(result(&mut server, &mut h, &rx), mbap(7, 0, 1, &[0x41, 1]));
}

#[test]
fn by_default_a_connection_beyond_the_maximum_waits() {
    let (mut server, addr) = server(2);
    let mut h = Recorder::new(|_, pdu| Reply::Pdu(vec![pdu[0], 1]));
    let mut held = two_clients(&mut server, &mut h, addr);
    let rx = client(addr, |mut s| {
        s.write_all(&mbap(7, 0, 1, &[0x41])).unwrap();
        read_answer(&mut s)
    });
    for _ in 0..30 {
        server.run(Some(Duration::from_millis(10)), &mut h).unwrap();
    }
    assert!(rx.try_recv().is_err(), "left in the backlog");
    assert_eq!(server.clients(), 2);
    held.pop();
    assert_eq!(result(&mut server, &mut h, &rx), mbap(7, 0, 1, &[0x41, 1]), "served once a client left");
}
