//! The driver's receive and exchange flows over real sockets and pty-like pairs, with
//! wall-clock timeouts and signals: split frames, late bytes, the response, byte and
//! indication timeouts, the TCP client's read under `SO_RCVTIMEO`, RTU and ASCII.
//! (Integration tests: they use sockets and time, so they live outside `src/`.)

use modbus::context::{Context, Timeout};
use modbus::engine::*;
use modbus::error::Error;
use modbus::lock::OwnerMutex as Mutex;
use modbus::proto::ascii;
use modbus::proto::frame::{MAX_ADU_LENGTH, MsgKind};
use modbus::proto::request::Request;
use modbus::session::*;
use modbus::transport;
use std::time::{Duration, Instant};

/// A connected pair of stream sockets: (ours, peer).
fn socket_pair() -> (i32, i32) {
    let mut fds = [0i32; 2];
    // SAFETY: `fds` has room for the two descriptors socketpair returns.
    let rc = unsafe { libc::socketpair(libc::AF_UNIX, libc::SOCK_STREAM, 0, fds.as_mut_ptr()) };
    assert_eq!(rc, 0);
    (fds[0], fds[1])
}

fn tcp_context(fd: i32) -> Mutex<Context> {
    let mut ctx = Context::new_tcp(Some(c"127.0.0.1"), 502).unwrap();
    ctx.set_descriptor(fd);
    Mutex::new(ctx)
}

fn read_registers_rsp(tid: u16) -> Vec<u8> {
    let mut v = tid.to_be_bytes().to_vec();
    v.extend([0, 0, 0, 7, 0xFF, 3, 4, 0x12, 0x34, 0xAB, 0xCD]);
    v
}

/// A context whose socket is one it connected itself (blocking, see
/// `Line::adopt_own`): its confirmations wait in the read.
fn client_socket_context(fd: i32) -> Mutex<Context> {
    let m = tcp_context(fd);
    m.lock().line.adopt_own(fd);
    m
}

/// The socket's SO_RCVTIMEO.
fn receive_timeout(fd: i32) -> Duration {
    let mut tv = libc::timeval { tv_sec: 0, tv_usec: 0 };
    let mut len = size_of::<libc::timeval>() as libc::socklen_t;
    // SAFETY: `tv` and `len` are live locals of the sizes getsockopt expects.
    let rc = unsafe {
        libc::getsockopt(fd, libc::SOL_SOCKET, libc::SO_RCVTIMEO, (&mut tv as *mut libc::timeval).cast(), &mut len)
    };
    assert_eq!(rc, 0);
    Duration::new(tv.tv_sec as u64, tv.tv_usec as u32 * 1000)
}

/// Waits for a confirmation that must time out; returns how long that took.
fn wait_for_timeout(g: &mut Guard<'_>) -> Duration {
    let mut buf = AduBuf::new();
    let started = Instant::now();
    assert_eq!(receive_msg(g, &mut buf.room(), MsgKind::Confirmation), Err(Error::TIMED_OUT));
    started.elapsed()
}

/// `took` lies in `[lo_ms, hi_ms)`.
fn assert_took(took: Duration, lo_ms: u64, hi_ms: u64) {
    assert!(took >= Duration::from_millis(lo_ms) && took < Duration::from_millis(hi_ms), "{took:?}");
}

#[test]
fn confirmation_split_into_single_bytes_is_assembled() {
    for client_socket in [false, true] {
        confirmation_split_into_single_bytes(client_socket);
    }
}

fn confirmation_split_into_single_bytes(client_socket: bool) {
    let (ours, peer) = socket_pair();
    let m = if client_socket { client_socket_context(ours) } else { tcp_context(ours) };
    let writer = std::thread::spawn(move || {
        let mut req = [0u8; 12];
        let mut got = 0;
        while got < 12 {
            got += transport::read(peer, &mut req[got..]).unwrap();
        }
        for b in read_registers_rsp(u16::from_be_bytes([req[0], req[1]])) {
            transport::write(peer, &[b]).unwrap();
            std::thread::sleep(Duration::from_millis(2));
        }
        peer
    });
    let mut g = m.lock();
    let mut rsp = AduBuf::new();
    let req = Request::ReadRegisters { function: 3, addr: 0, nb: 2 };
    let done = exchange(&mut g, &req, &mut rsp).unwrap();
    assert_eq!((done.len, done.count), (13, 2));
    assert_eq!(rsp[9..13], [0x12, 0x34, 0xAB, 0xCD]);
    transport::close(writer.join().unwrap());
    transport::close(ours);
}

#[test]
fn silence_is_a_timeout_and_close_is_a_reset() {
    let (ours, peer) = socket_pair();
    let m = tcp_context(ours);
    let mut g = m.lock();
    g.session.timeouts.response = Timeout::new(0, 50_000);
    assert!(wait_for_timeout(&mut g) >= Duration::from_millis(45));
    let mut buf = AduBuf::new();
    // Half a frame, then the peer goes away.
    transport::write(peer, &[0, 1, 0, 0, 0, 7]).unwrap();
    transport::close(peer);
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Confirmation), Err(Error::CONN_RESET));
    transport::close(ours);
}

#[test]
fn byte_timeout_applies_between_bytes() {
    let (ours, peer) = socket_pair();
    let m = tcp_context(ours);
    let mut g = m.lock();
    g.session.timeouts.response = Timeout::new(2, 0);
    g.session.timeouts.byte = Timeout::new(0, 20_000);
    transport::write(peer, &[0, 1, 0, 0]).unwrap();
    // Ends on the byte timeout, long before the 2 s response timeout.
    assert!(wait_for_timeout(&mut g) < Duration::from_millis(1500));
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn client_socket_response_timeout_ends_on_time() {
    // The read waits with SO_RCVTIMEO at 3/4 of the response timeout, then ppoll
    // takes the rest: the timeout is neither early nor doubled.
    let (ours, peer) = socket_pair();
    let m = client_socket_context(ours);
    let mut g = m.lock();
    g.session.timeouts.response = Timeout::new(0, 300_000);
    for _ in 0..2 {
        // Not 225 ms (SO_RCVTIMEO alone), nor 525 (a full ppoll after it).
        assert_took(wait_for_timeout(&mut g), 300, 480);
        // 3/4 of it, as the kernel keeps it (rounded up to its tick, 10 ms at most).
        let set = receive_timeout(ours);
        assert!(set >= Duration::from_millis(225) && set <= Duration::from_millis(235), "{set:?}");
    }
    // A response timeout too short for the kernel's timer: ppoll only, on time.
    g.session.timeouts.response = Timeout::new(0, 100_000);
    assert_took(wait_for_timeout(&mut g), 100, 350);
    drop(g);
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn client_socket_without_byte_timeout_shares_the_response_timeout() {
    let (ours, peer) = socket_pair();
    let m = client_socket_context(ours);
    let mut g = m.lock();
    g.session.timeouts.response = Timeout::new(0, 400_000);
    g.session.timeouts.byte = Timeout::new(0, 0);
    let writer = std::thread::spawn(move || {
        std::thread::sleep(Duration::from_millis(150));
        transport::write(peer, &[0, 1, 0, 0]).unwrap();
        peer
    });
    // One 400 ms budget for the whole message, not a fresh one after the bytes.
    assert_took(wait_for_timeout(&mut g), 400, 520);
    transport::close(writer.join().unwrap());
    transport::close(ours);
}

#[test]
fn client_socket_wait_survives_a_signal() {
    extern "C" fn on_signal(_: libc::c_int) {}
    // SAFETY: installs a handler that does nothing, without SA_RESTART, for a
    // signal only this test sends; `action` is a live, fully initialised struct.
    unsafe {
        let mut action: libc::sigaction = std::mem::zeroed();
        action.sa_sigaction = on_signal as extern "C" fn(libc::c_int) as libc::sighandler_t;
        libc::sigemptyset(&mut action.sa_mask);
        assert_eq!(libc::sigaction(libc::SIGUSR2, &action, std::ptr::null_mut()), 0);
    }
    let (ours, peer) = socket_pair();
    let m = client_socket_context(ours);
    let mut g = m.lock();
    g.session.timeouts.response = Timeout::new(0, 300_000);
    // SAFETY: pthread_self has no preconditions.
    let waiter = unsafe { libc::pthread_self() };
    let signaller = std::thread::spawn(move || {
        // Within the SO_RCVTIMEO part of the wait (225 ms).
        std::thread::sleep(Duration::from_millis(180));
        // SAFETY: the waiting thread outlives this one (it joins it).
        unsafe { libc::pthread_kill(waiter, libc::SIGUSR2) };
    });
    // The rest of the 300 ms after the signal, not a fresh 300 ms (480).
    assert_took(wait_for_timeout(&mut g), 300, 460);
    signaller.join().unwrap();
    drop(g);
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn client_socket_send_never_blocks() {
    // The socket is blocking; a peer that reads nothing must still give EAGAIN
    // once the buffers are full, as libmodbus's non-blocking socket does.
    let (ours, peer) = socket_pair();
    let m = client_socket_context(ours);
    let mut g = m.lock();
    let mut out = [0u8; MAX_ADU_LENGTH];
    let mut result = Ok(0);
    for _ in 0..100_000 {
        result = send_msg(&mut g, &mut out, 200);
        if result.is_err() {
            break;
        }
    }
    assert_eq!(result, Err(Error(libc::EAGAIN)));
    drop(g);
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn oversized_announcement_is_refused() {
    let (ours, peer) = socket_pair();
    let m = tcp_context(ours);
    let mut g = m.lock();
    // Read response announcing 255 data bytes: 9 + 255 > 260.
    transport::write(peer, &[0, 1, 0, 0, 1, 2, 0xFF, 3, 0xFF]).unwrap();
    let mut buf = AduBuf::new();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Confirmation), Err(Error::BAD_DATA));
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn wrong_transaction_id_is_bad_data() {
    let (ours, peer) = socket_pair();
    let m = tcp_context(ours);
    let writer = std::thread::spawn(move || {
        let mut req = [0u8; 12];
        let mut got = 0;
        while got < 12 {
            got += transport::read(peer, &mut req[got..]).unwrap();
        }
        transport::write(peer, &read_registers_rsp(0x4242)).unwrap();
        peer
    });
    let mut g = m.lock();
    let mut rsp = AduBuf::new();
    let req = Request::ReadRegisters { function: 3, addr: 0, nb: 2 };
    assert_eq!(exchange(&mut g, &req, &mut rsp).err(), Some(Error::BAD_DATA));
    transport::close(writer.join().unwrap());
    transport::close(ours);
}

#[test]
fn not_connected_leaves_errno_alone() {
    let m = tcp_context(-1);
    let mut g = m.lock();
    let mut buf = AduBuf::new();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Err(Error::UNCHANGED));
}

#[test]
fn rtu_frame_for_another_slave_is_ignored_and_bad_crc_refused() {
    let (ours, peer) = socket_pair();
    let mut ctx = Context::new_rtu(Some(c"/dev/null"), 9600, b'N', 8, 1).unwrap();
    ctx.set_descriptor(ours);
    ctx.session.slave = 0x11;
    let m = Mutex::new(ctx);
    let mut g = m.lock();
    let frame = |slave: u8| {
        let mut f = vec![slave, 0x06, 0x00, 0x01, 0x00, 0x03];
        f.extend(modbus::proto::crc::crc16(&f).to_le_bytes());
        f
    };
    let mut buf = AduBuf::new();
    transport::write(peer, &frame(0x12)).unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Ok(Received::Ignored(8)));
    transport::write(peer, &frame(0x11)).unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Ok(Received::Frame(8)));
    let mut bad = frame(0x12);
    bad[7] ^= 0xFF;
    transport::write(peer, &bad).unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Err(Error::BAD_CRC));
    transport::close(peer);
    transport::close(ours);
}

/// The serial server's fast path (a line the context opened, O_NONBLOCK): whole
/// requests, requests arriving in pieces, back-to-back requests (each receive
/// takes one), a request framed by its byte count, and the indication timeout.
#[test]
fn serial_requests_in_pieces_and_back_to_back() {
    let (ours, peer) = socket_pair();
    // SAFETY: fcntl on a descriptor this test owns.
    unsafe { libc::fcntl(ours, libc::F_SETFL, libc::fcntl(ours, libc::F_GETFL) | libc::O_NONBLOCK) };
    let mut ctx = Context::new_rtu(Some(c"/dev/null"), 9600, b'N', 8, 1).unwrap();
    ctx.line.adopt_own(ours);
    ctx.session.slave = 0x11;
    ctx.session.timeouts.byte = modbus::context::Timeout::new(0, 300_000);
    let m = Mutex::new(ctx);
    let mut g = m.lock();
    let rtu = |body: &[u8]| {
        let mut f = body.to_vec();
        f.extend(modbus::proto::crc::crc16(body).to_le_bytes());
        f
    };
    let read = rtu(&[0x11, 0x03, 0x00, 0x6B, 0x00, 0x03]);
    let write = rtu(&[0x11, 0x10, 0x00, 0x01, 0x00, 0x02, 0x04, 0x00, 0x0A, 0x01, 0x02]);
    let mut buf = AduBuf::new();

    // Back to back: each receive takes exactly one request.
    transport::write(peer, &[read.clone(), write.clone(), read.clone()].concat()).unwrap();
    for expected in [&read, &write, &read] {
        assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Ok(Received::Frame(expected.len())));
        assert_eq!(&buf[..expected.len()], &expected[..]);
    }

    // In pieces, with pauses below the byte timeout.
    for cuts in [[1usize, 2], [2, 5], [3, 7]] {
        let sender = std::thread::spawn({
            let frame = read.clone();
            move || {
                let mut at = 0;
                for cut in cuts.into_iter().chain([frame.len()]) {
                    transport::write(peer, &frame[at..cut]).unwrap();
                    at = cut;
                    std::thread::sleep(std::time::Duration::from_millis(30));
                }
            }
        });
        assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Ok(Received::Frame(read.len())));
        assert_eq!(&buf[..read.len()], &read[..]);
        sender.join().unwrap();
    }

    // Nothing arrives: the indication timeout.
    g.session.timeouts.indication = modbus::context::Timeout::new(0, 50_000);
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Err(Error::TIMED_OUT));
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn ascii_exchange_over_a_stream() {
    let (ours, peer) = socket_pair();
    let mut ctx = Context::new_ascii(Some(c"/dev/null"), 9600, b'E', 7, 1).unwrap();
    ctx.set_descriptor(ours);
    ctx.session.slave = 1;
    let m = Mutex::new(ctx);
    let server = std::thread::spawn(move || {
        let mut got = Vec::new();
        let mut chunk = [0u8; 64];
        while !got.ends_with(b"\r\n") {
            let n = transport::read(peer, &mut chunk).unwrap();
            got.extend_from_slice(&chunk[..n]);
        }
        // Noise, then the answer split with a pause inside the frame.
        transport::write(peer, b"\0\0:0103020").unwrap();
        std::thread::sleep(Duration::from_millis(30));
        transport::write(peer, b"1A257\r\n").unwrap();
        (peer, got)
    });
    let mut g = m.lock();
    let mut rsp = AduBuf::new();
    let done = exchange(&mut g, &Request::ReadRegisters { function: 3, addr: 0, nb: 1 }, &mut rsp).unwrap();
    assert_eq!(done.count, 1);
    assert_eq!(rsp[..done.len], [0x01, 0x03, 0x02, 0x01, 0xA2, 0x57]);
    let (peer, request) = server.join().unwrap();
    assert_eq!(request, b":010300000001FB\r\n");
    // A wrong LRC is a checksum error.
    transport::write(peer, b":010302000100F0\r\n").unwrap();
    let mut buf = AduBuf::new();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Confirmation), Err(Error::BAD_CRC));
    // Another slave's frame is ignored, a broadcast accepted.
    transport::write(peer, b":020300000001FA\r\n:000300000001FC\r\n").unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Ok(Received::Ignored(7)));
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Indication), Ok(Received::Frame(7)));
    transport::close(peer);
    transport::close(ours);
}

#[test]
fn ascii_frames_shorter_than_their_content_are_refused() {
    let (ours, peer) = socket_pair();
    let mut ctx = Context::new_ascii(Some(c"/dev/null"), 9600, b'N', 8, 1).unwrap();
    ctx.set_descriptor(ours);
    ctx.session.slave = 0xEF;
    let m = Mutex::new(ctx);
    let mut g = m.lock();
    let mut buf = AduBuf::new();
    // Fuzz finding F4: [EF][11] decodes with a good LRC but has no function code
    // (11 is the LRC): it must be refused, not reach the response checks.
    transport::write(peer, b":EF11\r\n").unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Confirmation), Err(Error::BAD_DATA));
    // F3: report slave id claiming 255 bytes with 11 in the frame.
    let mut body = vec![0xEF, 0x11, 0xFF, 0xB4, 0xFF, b'L', b'M', b'B', b'3', b'.', b'1', b'.', b'1', b'2'];
    body.push(ascii::lrc(&body));
    let mut text = [0u8; ascii::MAX_ENCODED];
    let n = ascii::encode(&body, &mut text);
    transport::write(peer, &text[..n]).unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Confirmation), Err(Error::BAD_DATA));
    // The same answer with its true byte count is fine.
    body[2] = 11;
    body.pop();
    body.push(ascii::lrc(&body));
    let n = ascii::encode(&body, &mut text);
    transport::write(peer, &text[..n]).unwrap();
    assert_eq!(receive_msg(&mut g, &mut buf.room(), MsgKind::Confirmation), Ok(Received::Frame(15)));
    transport::close(peer);
    transport::close(ours);
}
