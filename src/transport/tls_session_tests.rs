//! Sessions after the handshake, over loopback: our own key update at the session's
//! limit (`Session::key_update_at`, lowered here from `KEY_UPDATE_AT` so that a few
//! records reach it): TLS 1.3 between our two sides and against `openssl s_server`,
//! and TLS 1.2's end of the session there; and the room an idle session keeps. The
//! certificates are c-tests/tls/make-certs.sh's, made with openssl.

use super::*;
use std::io::{BufRead, BufReader};
use std::net::{TcpListener, TcpStream};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::OnceLock;

use crate::proto::frame::MAX_ADU_LENGTH as MAX_ADU;

/// How long any step may take before the test fails instead of hanging.
const WAIT: Duration = Duration::from_secs(20);
/// The limit the tests lower a session's to: a key protects 3 records.
const LIMIT: u64 = 3;

/// The test certificates, made once beside the test binary.
fn certs() -> &'static Path {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let exe = std::env::current_exe().unwrap();
        let dir = exe.parent().unwrap().join("tls-session-certs");
        // The last file make-certs.sh writes.
        if !dir.join("operator-legacy.key").exists() {
            let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("c-tests/tls/make-certs.sh");
            let ok =
                Command::new(script).arg(&dir).stdout(Stdio::null()).stderr(Stdio::null()).status().unwrap().success();
            assert!(ok, "make-certs.sh (openssl) failed");
        }
        dir
    })
}

/// The settings of `who` (a certificate of make-certs.sh), with the test CA.
fn settings(who: &str, min_version: u16) -> TlsSettings {
    let c = certs();
    let pem = |name: String| read_file(&c.join(name)).unwrap();
    let mut s = TlsSettings::default();
    s.set_certificate_pem(&pem(format!("{who}.pem")), &pem(format!("{who}.key")), None).unwrap();
    s.set_ca_pem(&pem("ca.pem".to_owned())).unwrap();
    s.set_min_version(min_version).unwrap();
    s
}

/// The client's configuration made to offer TLS 1.2 only (the settings cannot ask
/// for that: a client offers 1.2 and 1.3, and every peer here picks 1.3).
fn tls12_only(s: &mut TlsSettings) {
    let key = s.key.as_ref().unwrap().clone_key();
    let mut config = ClientConfig::builder_with_provider(provider())
        .with_protocol_versions(&[&rustls::version::TLS12])
        .unwrap()
        .with_root_certificates(s.root_store().unwrap())
        .with_client_auth_cert(s.chain.clone(), key)
        .unwrap();
    config.enable_secret_extraction = true;
    s.client = Some(Arc::new(config));
}

fn deadline() -> Option<Duration> {
    Some(now() + WAIT)
}

/// A connection's handshake on `stream`, and the session after it.
fn established(stream: &TcpStream, conn: Conn) -> Session {
    handshaken(stream, conn).0
}

/// A connection's handshake on `stream`, the session after it, and the room its
/// buffers had at the end of the handshake (records received, records sent).
fn handshaken(stream: &TcpStream, conn: Conn) -> (Session, (usize, usize)) {
    let mut conn = conn;
    stream.set_read_timeout(Some(WAIT)).unwrap();
    let fd = stream.as_raw_fd();
    handshake(fd, &mut conn, None, deadline(), &|| false).unwrap();
    let room = (conn.b.input.capacity(), conn.b.output.buf.capacity());
    (Session::new(conn, fd).unwrap(), room)
}

/// One side of a connection: its session, its socket, and its buffers' room at the
/// end of the handshake.
struct Side {
    session: Session,
    stream: TcpStream,
    handshake_room: (usize, usize),
}

/// A session of each side over a loopback TCP connection: the client's, the server's.
fn sides(client: TlsSettings, server: TlsSettings) -> (Side, Side) {
    let (mut client, mut server) = (client, server);
    let listener = TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap();
    let serving = std::thread::spawn(move || {
        let (stream, _) = listener.accept().unwrap();
        let (session, handshake_room) = handshaken(&stream, server.accept().unwrap());
        Side { session, stream, handshake_room }
    });
    let stream = TcpStream::connect(addr).unwrap();
    let (session, handshake_room) = handshaken(&stream, client.connect("127.0.0.1").unwrap());
    (Side { session, stream, handshake_room }, serving.join().unwrap())
}

fn pair(client: TlsSettings, server: TlsSettings) -> ((Session, TcpStream), (Session, TcpStream)) {
    let (c, s) = sides(client, server);
    ((c.session, c.stream), (s.session, s.stream))
}

/// Sends `data`, and tells whether our key was updated for it: the sequence number
/// started again (the data's record is the first of a new key, or near it).
fn send(s: &mut Session, fd: i32, data: &[u8]) -> Result<bool> {
    let before = s.tx.seq();
    s.send(fd, data, Timeout::new(WAIT.as_secs() as u32, 0), &|| false)?;
    Ok(s.tx.seq() <= before)
}

/// Receives `len` bytes of plaintext (ECONNRESET: the peer's end came first).
fn receive(s: &mut Session, fd: i32, len: usize) -> Result<Vec<u8>> {
    let until = now() + WAIT;
    let mut got = vec![0; len];
    let mut at = 0;
    while at < len {
        match s.take(&mut got[at..]) {
            Ok(0) => return Err(Error::CONN_RESET),
            Ok(n) => at += n,
            Err(e) if e.0 == libc::EAGAIN && now() < until => {
                // Blocking, up to the socket's receive timeout.
                let _ = s.fill(fd, 0);
            }
            Err(e) => return Err(e),
        }
    }
    Ok(got)
}

/// The `i`-th message of a test: its number, and a length that varies.
fn message(i: usize) -> Vec<u8> {
    let mut m = format!("message {i} ").into_bytes();
    m.extend((0..(i * 37) % 300).map(|k| b'a' + (k % 26) as u8));
    m
}

/// TLS 1.3, our client and our server, each with a key good for 3 records: 20
/// messages each way. Each side updates its sending key every few records (its
/// sequence number starts again), and the other follows: every message opens intact
/// under the new keys, and each side's receiving sequence number ends equal to the
/// other's sending one, below the limit, which only a key update of the receiving
/// side (its sequence number restarted too) gives after some 20 records.
#[test]
fn tls13_key_update_at_the_limit_is_followed_by_our_peer() {
    const ROUNDS: usize = 20;
    let ((mut client, cs), (mut server, ss)) = pair(settings("operator", TLS_1_3), settings("server", TLS_1_3));
    assert!(client.tls13 && server.tls13);
    client.key_update_at = LIMIT;
    server.key_update_at = LIMIT;
    let echo = std::thread::spawn(move || {
        let fd = ss.as_raw_fd();
        let mut updates = 0;
        for i in 0..ROUNDS {
            let mut got = receive(&mut server, fd, message(i).len()).unwrap();
            assert_eq!(got, message(i), "server: message {i}");
            got.reverse();
            updates += usize::from(send(&mut server, fd, &got).unwrap());
            assert!(server.tx.seq() <= LIMIT);
        }
        (server, ss, updates)
    });
    let fd = cs.as_raw_fd();
    let mut updates = 0;
    for i in 0..ROUNDS {
        updates += usize::from(send(&mut client, fd, &message(i)).unwrap());
        assert!(client.tx.seq() <= LIMIT);
        let mut want = message(i);
        want.reverse();
        assert_eq!(receive(&mut client, fd, want.len()).unwrap(), want, "client: answer {i}");
    }
    let (server, _ss, server_updates) = echo.join().unwrap();
    // 20 records, a key for 3 each (the server's first key also protected its ticket).
    assert!(updates >= 6, "client: {updates} key updates");
    assert!(server_updates >= 6, "server: {server_updates} key updates");
    assert_eq!(server.rx.seq(), client.tx.seq(), "the server followed the client's keys");
    assert_eq!(client.rx.seq(), server.tx.seq(), "the client followed the server's keys");
    assert!(server.rx.seq() <= LIMIT && client.rx.seq() <= LIMIT);
}

/// `openssl s_server`, stopped (by its id) when dropped, also when the test fails.
struct Server(Child);

impl Drop for Server {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// TLS 1.3, our client with a key good for 3 records against `openssl s_server`
/// (which prints what it receives, and sends what it reads): 60 lines, some 20 key
/// updates of ours. OpenSSL prints every line intact, in order: it took each
/// KeyUpdate and opened what followed under the next key (a record it cannot open
/// ends the connection with an alert); and a line it sends after them arrives.
/// (`-rev`, which answers each line, waits a second after each KeyUpdate.)
#[test]
fn tls13_key_update_at_the_limit_is_followed_by_openssl() {
    const LINES: usize = 60;
    let c = certs();
    let mut child = Command::new("openssl")
        .arg("s_server")
        .args(["-accept", "127.0.0.1:0", "-naccept", "1", "-tls1_3"])
        .arg("-cert")
        .arg(c.join("server.pem"))
        .arg("-key")
        .arg(c.join("server.key"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("openssl s_server");
    let (mut stdin, stdout) = (child.stdin.take().unwrap(), child.stdout.take().unwrap());
    let _server = Server(child);
    // "ACCEPT 127.0.0.1:PORT" once it listens; then what it prints, line by line.
    let mut lines = BufReader::new(stdout).lines();
    let port = lines
        .by_ref()
        .map_while(core::result::Result::ok)
        .find_map(|l| l.strip_prefix("ACCEPT 127.0.0.1:").and_then(|p| p.trim().parse::<u16>().ok()))
        .expect("s_server's ACCEPT line");
    let (printed, printing) = std::sync::mpsc::channel();
    std::thread::spawn(move || lines.map_while(core::result::Result::ok).try_for_each(|l| printed.send(l)));

    let stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
    let mut tls = settings("operator", TLS_1_3);
    let mut client = established(&stream, tls.connect("127.0.0.1").unwrap());
    assert!(client.tls13);
    client.key_update_at = LIMIT;
    let fd = stream.as_raw_fd();
    let mut updates = 0;
    for i in 0..LINES {
        let mut line = message(i);
        line.push(b'\n');
        updates += usize::from(send(&mut client, fd, &line).unwrap());
        assert!(client.tx.seq() <= LIMIT);
    }
    assert!(updates >= 19, "{updates} key updates");
    let want: Vec<String> = (0..LINES).map(|i| String::from_utf8(message(i)).unwrap()).collect();
    let mut got = Vec::new();
    while got.len() < LINES {
        let line = printing.recv_timeout(WAIT).unwrap_or_else(|_| panic!("s_server printed {got:?}"));
        if line.starts_with("message ") {
            got.push(line);
        }
    }
    assert_eq!(got, want);
    // s_server sends the lines of its input (one letter alone would be a command).
    std::io::Write::write_all(&mut stdin, b"after the key updates\n").unwrap();
    assert_eq!(receive(&mut client, fd, 22).unwrap(), b"after the key updates\n");
    client.close(fd);
}

/// TLS 1.2 has no key update: at the limit, the next send fails with EMBTLS and
/// nothing more goes out (the peer reads the messages before it, then the end).
#[test]
fn tls12_session_ends_at_the_limit() {
    let mut ours = settings("operator", TLS_1_2);
    tls12_only(&mut ours);
    let ((mut client, cs), (mut server, ss)) = pair(ours, settings("server", TLS_1_2));
    assert!(!client.tls13 && !server.tls13);
    let fd = cs.as_raw_fd();
    client.key_update_at = client.tx.seq() + LIMIT;
    for i in 0..LIMIT as usize {
        assert!(!send(&mut client, fd, &message(i)).unwrap());
    }
    let seq = client.tx.seq();
    assert_eq!(send(&mut client, fd, &message(3)), Err(Error(EMBTLS)));
    assert_eq!(send(&mut client, fd, &message(4)), Err(Error(EMBTLS)), "and stays ended");
    assert_eq!(client.tx.seq(), seq, "nothing sealed");
    assert!(!client.wants_write());
    drop(cs);
    let sfd = ss.as_raw_fd();
    for i in 0..LIMIT as usize {
        assert_eq!(receive(&mut server, sfd, message(i).len()).unwrap(), message(i));
    }
    assert_eq!(receive(&mut server, sfd, 1), Err(Error::CONN_RESET), "nothing after");
}

/// `who`'s settings with the CA's certificate sent `copies` times after its own (a
/// longer chain: the handshake's records grow past what a transaction needs).
fn padded(who: &str, copies: usize) -> TlsSettings {
    let c = certs();
    let pem = |name: &str| read_file(&c.join(name)).unwrap();
    let mut chain = pem(&format!("{who}.pem"));
    for _ in 0..copies {
        chain.extend(pem("ca.pem"));
    }
    let mut s = settings(who, TLS_1_3);
    s.set_certificate_pem(&chain, &pem(&format!("{who}.key")), None).unwrap();
    s
}

/// After a handshake whose records are larger than a transaction's (longer chains of
/// certificates each way), each side's session keeps no more room than its
/// transactions use: records received, the first 2,048 bytes (`INITIAL_INPUT`);
/// records sent, 512 (`OUTPUT_KEPT`). Messages still go both ways after it, and one
/// larger than both (2 records) grows them again.
#[test]
fn an_idle_session_keeps_a_transactions_room_after_its_handshake() {
    let (mut client, mut server) = sides(padded("operator", 8), padded("server", 8));
    for (side, who) in [(&client, "client"), (&server, "server")] {
        let (input, output) = side.handshake_room;
        assert!(input > INITIAL_INPUT && output > OUTPUT_KEPT, "{who}: the handshake needed only {input} / {output}");
        let (input, output) = (side.session.input.capacity(), side.session.output.buf.capacity());
        assert!(input <= INITIAL_INPUT && output <= OUTPUT_KEPT, "{who} keeps {input} / {output} bytes of room");
    }
    let (cfd, sfd) = (client.stream.as_raw_fd(), server.stream.as_raw_fd());
    let big: Vec<u8> = (0..20_000).map(|i| (i % 251) as u8).collect();
    for data in [message(1), message(7), big.clone()] {
        send(&mut client.session, cfd, &data).unwrap();
        assert_eq!(receive(&mut server.session, sfd, data.len()).unwrap(), data);
        send(&mut server.session, sfd, &data).unwrap();
        assert_eq!(receive(&mut client.session, cfd, data.len()).unwrap(), data);
    }
    assert!(server.session.output.buf.capacity() > big.len(), "grown again for the larger message");
}

/// Waits until `fd` has at least `bytes` bytes to read.
fn queued(fd: i32, bytes: usize) {
    let until = now() + WAIT;
    loop {
        let mut n: libc::c_int = 0;
        // SAFETY: FIONREAD writes one int into the live local.
        assert_eq!(unsafe { libc::ioctl(fd, libc::FIONREAD, &mut n) }, 0);
        if n as usize >= bytes {
            return;
        }
        assert!(now() < until, "{n} bytes queued, waited for {bytes}");
        std::thread::sleep(Duration::from_millis(1));
    }
}

/// Seals each of `messages` into its own record and sends them all with one `send`.
fn send_together(s: &mut Session, fd: i32, messages: &[&[u8]]) -> usize {
    for m in messages {
        s.seal_data(m).unwrap();
    }
    let len = s.output.end;
    s.output.flush_within(fd, Timeout::new(WAIT.as_secs() as u32, 0), &mut None, &|| false).unwrap();
    len
}

/// `Session::read_into`, as a client reads an answer into an ADU buffer with room
/// around it (`room::AduBuf`), TLS 1.3 and 1.2:
/// - the session's first answer is read whole into the session's input (the server's
///   session tickets may come with it);
/// - after a read that left nothing held, one record alone is opened where it
///   landed: its plaintext is the message, and nothing entered the session's input (a
///   copy into it would leave records there); a read that is not for one answer
///   reads it into the input;
/// - two records that arrived together are read as a stream: within the buffer's
///   room, both at once (the message's room gets their plaintext in order); past it,
///   the first, then the second from the socket; the read after them takes all that
///   is there into the input;
/// - a part of a record is kept until the rest comes;
/// - a record that is not application data (a key update) leaves nothing to take,
///   and the next record opens under the new key;
/// - a changed byte fails the read, and so does every read after it.
#[test]
fn read_into_opens_a_lone_record_in_place_and_the_rest_in_the_input() {
    for tls13 in [true, false] {
        let mut ours = settings("operator", if tls13 { TLS_1_3 } else { TLS_1_2 });
        if !tls13 {
            tls12_only(&mut ours);
        }
        let ((mut client, cs), (mut server, ss)) = pair(ours, settings("server", TLS_1_2));
        assert_eq!(client.tls13, tls13);
        let (cfd, sfd) = (cs.as_raw_fd(), ss.as_raw_fd());
        let mut adu = room::AduBuf::new();
        let at = room::BEFORE..room::BEFORE + MAX_ADU;
        // The server's session tickets (TLS 1.3) come first: read them away.
        if tls13 {
            send(&mut server, sfd, b"x").unwrap();
            assert_eq!(receive(&mut client, cfd, 1).unwrap(), b"x");
        }
        let read_one = |client: &mut Session, adu: &mut room::AduBuf, one: bool| {
            let mut room = adu.room();
            let (whole, range) = room.around(0..MAX_ADU);
            assert_eq!(range, at);
            client.read_into(cfd, libc::MSG_DONTWAIT, whole, range, one)
        };
        let read = |client: &mut Session, adu: &mut room::AduBuf| read_one(client, adu, true);

        // The first answer, then one record alone.
        let answer: Vec<u8> = (0..259).map(|i| (i * 7) as u8).collect();
        let len = send_together(&mut server, sfd, &[&answer]);
        queued(cfd, len);
        let held = client.have;
        assert_eq!(read(&mut client, &mut adu), Ok(259), "tls13 {tls13}");
        assert_eq!(&adu[..259], &answer[..]);
        assert_ne!(client.have, held, "tls13 {tls13}: the first answer went around the input");
        let len = send_together(&mut server, sfd, &[&answer]);
        queued(cfd, len);
        let held = client.have;
        assert_eq!(read(&mut client, &mut adu), Ok(259), "tls13 {tls13}");
        assert_eq!(&adu[..259], &answer[..]);
        assert_eq!((client.have, client.pending()), (held, 0), "tls13 {tls13}: the record went through the input");
        let len = send_together(&mut server, sfd, &[&answer]);
        queued(cfd, len);
        assert_eq!(read_one(&mut client, &mut adu, false), Ok(259));
        assert_eq!(&adu[..259], &answer[..]);
        assert_eq!(client.have, len, "tls13 {tls13}: a read of what is queued takes it into the input");

        // Two records within the buffer's room, then two past it.
        let (a, b) = (vec![1u8; 100], vec![2u8; 100]);
        let len = send_together(&mut server, sfd, &[&a, &b]);
        queued(cfd, len);
        assert_eq!(read(&mut client, &mut adu), Ok(200), "tls13 {tls13}");
        assert_eq!(&adu[..200], &[a, b].concat()[..]);
        let len = send_together(&mut server, sfd, &[&answer]);
        queued(cfd, len);
        let held = client.have;
        assert_eq!(read(&mut client, &mut adu), Ok(259), "tls13 {tls13}");
        assert_ne!(client.have, held, "tls13 {tls13}: the read after two records went around the input");
        let (a, b) = (vec![3u8; 250], vec![4u8; 250]);
        let len = send_together(&mut server, sfd, &[&a, &b]);
        queued(cfd, len);
        for want in [a, b] {
            assert_eq!(read(&mut client, &mut adu), Ok(250), "tls13 {tls13}");
            assert_eq!(&adu[..250], &want[..]);
        }
        assert_eq!(client.pending(), 0);

        // The rest of a message after its first bytes: those stay as they are.
        adu[..100].fill(9);
        let len = send_together(&mut server, sfd, &[&answer[..150]]);
        queued(cfd, len);
        let mut room = adu.room();
        let (whole, range) = room.around(100..MAX_ADU);
        assert_eq!(client.read_into(cfd, libc::MSG_DONTWAIT, whole, range, true), Ok(150));
        assert_eq!(&adu[..100], &[9; 100][..], "tls13 {tls13}: the message's first bytes changed");
        assert_eq!(&adu[100..250], &answer[..150]);

        // A part of a record, then the rest.
        server.seal_data(&answer).unwrap();
        let record = server.output.buf[..server.output.end].to_vec();
        server.output.end = 0;
        super::super::send(sfd, &record[..100], 0).unwrap();
        queued(cfd, 100);
        assert_eq!(read(&mut client, &mut adu), Err(Error(libc::EAGAIN)));
        super::super::send(sfd, &record[100..], 0).unwrap();
        queued(cfd, record.len() - 100);
        assert_eq!(read(&mut client, &mut adu), Ok(259));
        assert_eq!(&adu[..259], &answer[..]);

        if tls13 {
            // A key update alone, then a message under the new key.
            let seq = client.rx.seq();
            server.update_keys().unwrap();
            let len = server.output.end;
            server.output.flush(sfd).unwrap();
            queued(cfd, len);
            assert_eq!(read(&mut client, &mut adu), Err(Error(libc::EAGAIN)));
            assert!(client.rx.seq() < seq, "the client's receiving key was updated");
            let len = send_together(&mut server, sfd, &[b"after"]);
            queued(cfd, len);
            assert_eq!(read(&mut client, &mut adu), Ok(5));
            assert_eq!(&adu[..5], b"after");
        }

        // A record with a changed byte.
        server.seal_data(&answer).unwrap();
        let end = server.output.end;
        server.output.buf[end - 1] ^= 1;
        server.output.flush(sfd).unwrap();
        queued(cfd, end);
        let failed = read(&mut client, &mut adu);
        assert!(matches!(failed, Err(e) if e.0 != libc::EAGAIN), "tls13 {tls13}: {failed:?}");
        assert_eq!(read(&mut client, &mut adu), failed, "and stays failed");
    }
}
