//! A listener whose accept failed for want of descriptors comes back by itself
//! (the runner's retry timer), not only when one of its own clients leaves:
//! descriptors exhausted elsewhere in the process never deafen a server that has
//! no client (the security review's finding 5: a gateway's second front). Alone in
//! its test binary: it lowers the process's RLIMIT_NOFILE and fills the table.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use modbus::api::{Handler, Modbus, Reply, RequestInfo, Server};

struct Echo;

impl Handler for Echo {
    fn request(&mut self, _info: &RequestInfo<'_>, pdu: &[u8]) -> Reply {
        Reply::Pdu(pdu.to_vec())
    }
}

#[test]
fn a_listener_out_of_descriptors_comes_back_when_they_are_freed_elsewhere() {
    let ctx = Modbus::new_tcp(Some("127.0.0.1"), "0").unwrap();
    let mut server = Server::new(ctx, 100).unwrap();
    let addr = server.local_addr().unwrap();
    let mut h = Echo;

    let limit = libc::rlimit { rlim_cur: 256.min(current_max()), rlim_max: current_max() };
    // SAFETY: a plain system call on a live struct.
    assert_eq!(unsafe { libc::setrlimit(libc::RLIMIT_NOFILE, &limit) }, 0);
    // The table filled, then one descriptor freed: the client's socket takes it,
    // so that the server's accept finds none.
    let mut filler = Vec::new();
    while let Ok(f) = std::fs::File::open("/dev/null") {
        filler.push(f);
    }
    assert!(filler.len() > 100, "the table was filled ({} more)", filler.len());
    filler.pop();
    let mut s = TcpStream::connect(addr).unwrap();
    for _ in 0..5 {
        server.run(Some(Duration::from_millis(10)), &mut h).unwrap();
    }
    assert_eq!(server.clients(), 0, "the accept failed (EMFILE)");

    // Descriptors come free elsewhere (not by a client of this server's leaving).
    drop(filler);
    s.write_all(&[0, 1, 0, 0, 0, 3, 1, 0x41, 7]).unwrap();
    s.set_nonblocking(true).unwrap();
    let end = Instant::now() + Duration::from_secs(3);
    let mut answer: Vec<u8> = Vec::new();
    while answer.len() < 9 {
        assert!(Instant::now() < end, "the listener never came back");
        server.run(Some(Duration::from_millis(10)), &mut h).unwrap();
        let mut buf = [0u8; 64];
        if let Ok(n) = s.read(&mut buf) {
            answer.extend(&buf[..n]);
        }
    }
    assert_eq!(answer, [0, 1, 0, 0, 0, 3, 1, 0x41, 7]);
    assert_eq!(server.clients(), 1);
}

fn current_max() -> libc::rlim_t {
    let mut l = libc::rlimit { rlim_cur: 0, rlim_max: 0 };
    // SAFETY: a plain system call on a live struct.
    unsafe { libc::getrlimit(libc::RLIMIT_NOFILE, &mut l) };
    l.rlim_max
}
