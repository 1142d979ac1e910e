//! The Rust API's event-driven client (`api::Modbus::send_raw`, `poll_fd`,
//! `process`, `next_completion`) against an `api::Server` on loopback.

mod common;
use common::wait_completion;

use std::time::Duration;

use modbus::api::{Completion, Error, Handler, Modbus, Reply, RequestInfo, Server};

/// Answers a read of holding registers (03) with its addresses as values; an
/// exception 02 for anything else.
struct Registers;

impl Handler for Registers {
    fn request(&mut self, _info: &RequestInfo<'_>, pdu: &[u8]) -> Reply {
        if pdu.len() == 5 && pdu[0] == 0x03 {
            let addr = u16::from_be_bytes([pdu[1], pdu[2]]);
            let nb = u16::from_be_bytes([pdu[3], pdu[4]]);
            let mut v = vec![0x03, (2 * nb) as u8];
            for a in addr..addr + nb {
                v.extend(a.to_be_bytes());
            }
            return Reply::Pdu(v);
        }
        Reply::Exception(0x02)
    }
}

/// A server on 127.0.0.1, an ephemeral port, running in a thread until the test
/// process ends; returns its port.
fn serve(h: impl Handler + Send + 'static) -> u16 {
    let ctx = Modbus::new_tcp(Some("127.0.0.1"), "0").unwrap();
    let mut server = Server::new(ctx, 8).unwrap();
    let port = server.local_addr().unwrap().port();
    std::thread::spawn(move || {
        let mut h = h;
        server.run(None, &mut h).unwrap();
    });
    port
}

#[test]
fn raw_requests_complete_with_their_answers_pdu() {
    let port = serve(Registers);
    let mut m = Modbus::new_tcp(Some("127.0.0.1"), &port.to_string()).unwrap();
    m.set_response_timeout(Duration::from_secs(2)).unwrap();
    assert_eq!(m.header_length(), 7);
    assert_eq!(m.checksum_length(), 0);
    let id = m.send_raw(&[1, 0x03, 0x00, 0x10, 0x00, 0x02]).unwrap();
    assert_eq!(m.pending(), 1);
    let c = wait_completion(&mut m, || {});
    assert_eq!(c, Completion { id, result: Ok(vec![0x03, 4, 0x00, 0x10, 0x00, 0x11]) });
    assert_eq!(m.pending(), 0);
    // An exception answer is an answer: its PDU.
    let id = m.send_raw(&[1, 0x2B, 0x0E, 0x01, 0x00]).unwrap();
    assert_eq!(wait_completion(&mut m, || {}), Completion { id, result: Ok(vec![0xAB, 0x02]) });
    assert!(m.is_connected());
    assert_eq!(m.send_raw(&[1]), Err(Error::INVALID));
}

#[test]
fn a_request_nobody_answers_times_out() {
    // A listener that never accepts: the connect succeeds, the answer never comes.
    let l = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = l.local_addr().unwrap().port();
    let mut m = Modbus::new_tcp(Some("127.0.0.1"), &port.to_string()).unwrap();
    m.set_response_timeout(Duration::from_millis(200)).unwrap();
    let id = m.send_raw(&[1, 0x03, 0x00, 0x00, 0x00, 0x01]).unwrap();
    let c = wait_completion(&mut m, || {});
    assert_eq!(c, Completion { id, result: Err(Error::TIMED_OUT) });
    assert_eq!(Error::TIMED_OUT.to_string(), "Connection timed out");
    assert_eq!(Error::BAD_CRC.to_string(), "Invalid CRC");
}

#[test]
fn contexts_and_servers_move_between_threads() {
    fn send<T: Send>() {}
    send::<Modbus>();
    send::<Server>();
}

#[test]
fn pipelined_raw_requests_complete_each_with_its_answer() {
    let port = serve(Registers);
    let mut m = Modbus::new_tcp(Some("127.0.0.1"), &port.to_string()).unwrap();
    m.set_max_in_flight(4).unwrap();
    let ids: Vec<i32> = (0..4u8).map(|i| m.send_raw(&[1, 0x03, 0x00, i, 0x00, 0x01]).unwrap()).collect();
    assert_eq!(m.pending(), 4);
    for (i, id) in ids.into_iter().enumerate() {
        let c = wait_completion(&mut m, || {});
        assert_eq!(c, Completion { id, result: Ok(vec![0x03, 2, 0x00, i as u8]) });
    }
    assert_eq!(m.set_max_in_flight(0), Err(Error::INVALID));
}
