//! The Rust API's closures stored in a context: the RTS switch of a serial line
//! (`set_custom_rts`, over a pseudo-terminal, with the event-driven client's raw
//! requests) and the authorization of a Modbus/TCP Security server
//! (`set_tls_authorization`, with certificates made by c-tests/tls/make-certs.sh).

mod common;
use common::wait_completion;

use std::ffi::CStr;
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};
use std::time::Duration;

use modbus::api::{Completion, Handler, Modbus, Parity, Reply, RequestInfo, Rts, Server};
use modbus::proto::crc::crc16;

/// A pseudo-terminal: its master descriptor and the path of its slave.
fn pty() -> (i32, String) {
    // SAFETY: plain system calls; ptsname's string is copied at once.
    unsafe {
        let master = libc::posix_openpt(libc::O_RDWR | libc::O_NOCTTY | libc::O_NONBLOCK);
        assert!(master >= 0);
        assert_eq!(libc::grantpt(master), 0);
        assert_eq!(libc::unlockpt(master), 0);
        let name = CStr::from_ptr(libc::ptsname(master)).to_str().unwrap().to_owned();
        (master, name)
    }
}

fn read_fd(fd: i32) -> Vec<u8> {
    let mut buf = [0u8; 256];
    // SAFETY: the kernel writes at most `buf.len()` bytes into the live buffer.
    let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
    buf[..n.max(0) as usize].to_vec()
}

fn with_crc(mut v: Vec<u8>) -> Vec<u8> {
    let crc = crc16(&v);
    v.extend(crc.to_le_bytes());
    v
}

#[test]
fn a_custom_rts_closure_switches_around_each_send() {
    let (master, slave) = pty();
    let mut m = Modbus::new_rtu(&slave, 115200, Parity::None, 8, 1).unwrap();
    assert_eq!((m.header_length(), m.checksum_length()), (1, 2));
    let switched = Arc::new(Mutex::new(Vec::new()));
    let s = Arc::clone(&switched);
    m.set_custom_rts(Box::new(move |on| s.lock().unwrap().push(on))).unwrap();
    m.connect().unwrap();
    m.set_rts(Rts::Up).unwrap();
    assert_eq!(*switched.lock().unwrap(), [false], "the idle state at once");
    m.set_response_timeout(Duration::from_secs(2)).unwrap();

    // A request answered: its PDU, without the checksum.
    let id = m.send_raw(&[5, 0x03, 0x00, 0x01, 0x00, 0x01]).unwrap();
    let mut asked = Vec::new();
    let c = wait_completion(&mut m, || {
        asked.extend(read_fd(master));
        if asked.len() == 8 {
            let answer = with_crc(vec![5, 0x03, 2, 0xAB, 0xCD]);
            // SAFETY: writes the live answer's bytes.
            unsafe { libc::write(master, answer.as_ptr().cast(), answer.len()) };
            asked.push(0);
        }
    });
    assert_eq!(asked[..8], with_crc(vec![5, 0x03, 0x00, 0x01, 0x00, 0x01]));
    assert_eq!(c, Completion { id, result: Ok(vec![0x03, 2, 0xAB, 0xCD]) });
    assert_eq!(*switched.lock().unwrap(), [false, true, false], "up to send, down after");

    // A broadcast completes once it is out, with no PDU.
    let id = m.send_raw(&[0, 0x06, 0x00, 0x01, 0x00, 0x02]).unwrap();
    let c = wait_completion(&mut m, || {});
    assert_eq!(c, Completion { id, result: Ok(vec![]) });
    assert_eq!(*switched.lock().unwrap(), [false, true, false, true, false]);
    assert_eq!(read_fd(master), with_crc(vec![0, 0x06, 0x00, 0x01, 0x00, 0x02]));
    // SAFETY: the master descriptor, closed once.
    unsafe { libc::close(master) };
}

/// The test certificates, made once into a directory of the target's.
fn certs() -> PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let dir = Path::new(env!("CARGO_TARGET_TMPDIR")).join("api-certs");
    if !dir.join("reader.pem").exists() {
        let ok = std::process::Command::new(root.join("c-tests/tls/make-certs.sh"))
            .arg(&dir)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::null())
            .status()
            .unwrap()
            .success();
        assert!(ok, "make-certs.sh (openssl) failed");
    }
    dir
}

/// Records the role of each request it answers; answers a read of a register with
/// 42, echoes the rest (a write's answer).
struct Roles(Arc<Mutex<Vec<Seen>>>);

/// A request's role and function code.
type Seen = (Option<String>, u8);

impl Handler for Roles {
    fn request(&mut self, info: &RequestInfo<'_>, pdu: &[u8]) -> Reply {
        self.0.lock().unwrap().push((info.role.map(str::to_owned), info.function));
        match pdu[0] {
            0x03 => Reply::Pdu(vec![0x03, 2, 0x00, 42]),
            _ => Reply::Pdu(pdu.to_vec()),
        }
    }
}

fn tls_client(c: &Path, who: &str, port: u16) -> Modbus {
    let mut m = Modbus::new_tls(Some("127.0.0.1"), &port.to_string()).unwrap();
    m.set_tls_certificate(&c.join(format!("{who}.pem")), &c.join(format!("{who}.key"))).unwrap();
    m.set_tls_ca(&c.join("ca.pem")).unwrap();
    m.set_response_timeout(Duration::from_secs(3)).unwrap();
    m
}

#[test]
fn a_tls_authorization_closure_decides_by_role() {
    let c = certs();
    let mut ctx = Modbus::new_tls(Some("127.0.0.1"), "0").unwrap();
    ctx.set_tls_certificate(&c.join("server.pem"), &c.join("server.key")).unwrap();
    ctx.set_tls_ca(&c.join("ca.pem")).unwrap();
    let asked = Arc::new(Mutex::new(Vec::new()));
    let a = Arc::clone(&asked);
    // Operators do anything, the others read holding registers.
    ctx.set_tls_authorization(Box::new(move |q| {
        a.lock().unwrap().push((q.role.map(str::to_owned), q.unit, q.function, q.address, q.count));
        q.role == Some("Operator") || q.function == 0x03
    }))
    .unwrap();
    let mut server = Server::new(ctx, 4).unwrap();
    let port = server.local_addr().unwrap().port();
    let seen = Arc::new(Mutex::new(Vec::new()));
    let mut h = Roles(Arc::clone(&seen));
    std::thread::spawn(move || server.run(None, &mut h));

    let write = [9, 0x06, 0x00, 0x05, 0x12, 0x34];
    let read = [9, 0x03, 0x00, 0x05, 0x00, 0x01];
    let mut operator = tls_client(&c, "operator", port);
    let id = operator.send_raw(&write).unwrap();
    assert_eq!(wait_completion(&mut operator, || {}), Completion { id, result: Ok(write[1..].to_vec()) });
    let mut reader = tls_client(&c, "reader", port);
    let id = reader.send_raw(&write).unwrap();
    assert_eq!(wait_completion(&mut reader, || {}), Completion { id, result: Ok(vec![0x86, 0x01]) }, "refused");
    let id = reader.send_raw(&read).unwrap();
    assert_eq!(wait_completion(&mut reader, || {}), Completion { id, result: Ok(vec![0x03, 2, 0, 42]) });

    let op = Some("Operator".to_owned());
    let rd = Some("Reader".to_owned());
    assert_eq!(
        *asked.lock().unwrap(),
        [(op.clone(), 9, 0x06, 5, 1), (rd.clone(), 9, 0x06, 5, 1), (rd.clone(), 9, 0x03, 5, 1)]
    );
    assert_eq!(*seen.lock().unwrap(), [(op, 0x06), (rd, 0x03)], "the refused write never reached the handler");
}

/// `process()` called when nothing came (it says "readable" without a wait): a
/// serial line read empty is nothing yet, not a line that ended; the answer that
/// comes next is its request's.
#[test]
fn process_without_a_wait_on_a_quiet_serial_line_loses_nothing() {
    let (master, slave) = pty();
    let mut m = Modbus::new_rtu(&slave, 115200, Parity::None, 8, 1).unwrap();
    m.connect().unwrap();
    m.set_response_timeout(Duration::from_secs(2)).unwrap();
    for value in [0x11u8, 0x22] {
        let id = m.send_raw(&[5, 0x03, 0x00, 0x01, 0x00, 0x01]).unwrap();
        for _ in 0..5 {
            m.process().unwrap();
            assert_eq!(m.next_completion(), None, "nothing came: no completion");
        }
        let mut asked = Vec::new();
        let c = wait_completion(&mut m, || {
            asked.extend(read_fd(master));
            if asked.len() == 8 {
                let answer = with_crc(vec![5, 0x03, 2, value, value]);
                // SAFETY: writes the live answer's bytes.
                unsafe { libc::write(master, answer.as_ptr().cast(), answer.len()) };
                asked.push(0);
            }
        });
        assert_eq!(c, Completion { id, result: Ok(vec![0x03, 2, value, value]) });
    }
    // SAFETY: the master descriptor, closed once.
    unsafe { libc::close(master) };
}
