//! The server exports over socket pairs and loopback TCP: receive and reply with
//! every extension, listen and accept (descriptors above FD_SETSIZE included), and
//! accept stopped by another thread. (Integration tests: they use sockets, threads
//! and time, so they live outside `src/`.)

use std::{ptr, slice};

use modbus::context::Context;
use modbus::ffi::Modbus;
use modbus::ffi::context::{modbus_free, modbus_set_response_timeout, modbus_set_slave, modbus_set_socket};
use modbus::ffi::into_handle;
use modbus::ffi::server::*;
use modbus::proto::crc::crc16;
use modbus::transport::{close, errno};

fn socket_pair() -> (i32, i32) {
    let mut fds = [0i32; 2];
    // SAFETY: `fds` has room for the two descriptors socketpair returns.
    let rc = unsafe { libc::socketpair(libc::AF_UNIX, libc::SOCK_STREAM, 0, fds.as_mut_ptr()) };
    assert_eq!(rc, 0);
    (fds[0], fds[1])
}

fn write_all(fd: i32, bytes: &[u8]) {
    // SAFETY: reads `bytes.len()` bytes from a live slice.
    let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
    assert_eq!(n, bytes.len() as isize);
}

/// Whatever is readable on `fd` within 200 ms.
fn read_some(fd: i32) -> Vec<u8> {
    let mut buf = [0u8; 512];
    if !modbus::transport::wait(fd, libc::POLLIN, Some(std::time::Duration::from_millis(200))).unwrap() {
        return Vec::new();
    }
    // SAFETY: the kernel writes at most `buf.len()` bytes into the live buffer.
    let n = unsafe { libc::recv(fd, buf.as_mut_ptr().cast(), buf.len(), libc::MSG_DONTWAIT) };
    buf[..n.max(0) as usize].to_vec()
}

fn with_crc(mut v: Vec<u8>) -> Vec<u8> {
    let crc = crc16(&v);
    v.extend(crc.to_le_bytes());
    v
}

struct Ctx(*mut Modbus);

impl Drop for Ctx {
    fn drop(&mut self) {
        // SAFETY: the handle came from into_handle and is freed once.
        unsafe { modbus_free(self.0) };
    }
}

fn tcp(fd: i32) -> Ctx {
    let ctx = Ctx(into_handle(Context::new_tcp(Some(c"127.0.0.1"), 0)));
    // SAFETY: live handle.
    unsafe {
        modbus_set_socket(ctx.0, fd);
        modbus_set_response_timeout(ctx.0, 0, 1000);
    }
    ctx
}

fn rtu(fd: i32, slave: i32) -> Ctx {
    let ctx = Ctx(into_handle(Context::new_rtu(Some(c"/dev/null"), 115200, b'N', 8, 1)));
    // SAFETY: live handle.
    unsafe {
        modbus_set_socket(ctx.0, fd);
        modbus_set_slave(ctx.0, slave);
        modbus_set_response_timeout(ctx.0, 0, 1000);
    }
    ctx
}

#[test]
fn report_slave_id_names_the_exported_version() {
    assert_eq!(modbus::proto::reply::VERSION_STRING, modbus::ffi::version::LIBMODBUS_VERSION_STRING);
}

#[test]
fn mapping_layout_allocation_and_free() {
    let m = modbus_mapping_new_start_address(10, 3, 20, 0, 30, 2, 40, 1);
    assert!(!m.is_null());
    // SAFETY: a fresh mapping with the sizes asked for.
    unsafe {
        let r = &*m;
        assert_eq!((r.nb_bits, r.start_bits, r.nb_input_bits, r.start_input_bits), (3, 10, 0, 20));
        assert_eq!((r.nb_registers, r.start_registers, r.nb_input_registers, r.start_input_registers), (2, 30, 1, 40));
        assert!(r.tab_input_bits.is_null());
        assert_eq!(slice::from_raw_parts(r.tab_bits, 3), [0, 0, 0]);
        assert_eq!(slice::from_raw_parts(r.tab_registers, 2), [0, 0]);
        assert_eq!(slice::from_raw_parts(r.tab_input_registers, 1), [0]);
        // A C program may replace a table with its own allocation.
        libc::free(r.tab_registers.cast());
        (*m).tab_registers = libc::malloc(8).cast();
        modbus_mapping_free(m);
        modbus_mapping_free(ptr::null_mut());
    }
    let m = modbus_mapping_new(0, 0, 0, 0);
    // SAFETY: a fresh mapping.
    unsafe {
        assert!((*m).tab_bits.is_null() && (*m).tab_registers.is_null());
        modbus_mapping_free(m);
    }
    // Unsigned starts are stored as the int fields.
    let m = modbus_mapping_new_start_address(u32::MAX, 1, 0, 0, 0x8000_0000, 1, 0, 0);
    // SAFETY: a fresh mapping.
    unsafe {
        assert_eq!(((*m).start_bits, (*m).start_registers), (-1, i32::MIN));
        modbus_mapping_free(m);
    }
}

#[test]
fn reply_over_a_socket_tcp() {
    let (ours, peer) = socket_pair();
    let ctx = tcp(ours);
    let m = modbus_mapping_new_start_address(0, 0, 0, 0, 0x100, 4, 0, 0);
    let req = [0, 7, 0, 0, 0, 6, 0xFF, 6, 0x01, 0x02, 0xAB, 0xCD];
    // SAFETY: live handle, a request buffer of 12 bytes, a live mapping.
    unsafe {
        assert_eq!(modbus_reply(ctx.0, req.as_ptr(), 12, m), 12);
        assert_eq!(read_some(peer), req);
        assert_eq!(*(*m).tab_registers.add(2), 0xABCD);
        // CVE-2024-10918: a req_length past the request is refused, nothing is read.
        assert_eq!(modbus_reply(ctx.0, req.as_ptr(), 1 << 20, m), 9);
        assert_eq!(read_some(peer), [0, 7, 0, 0, 0, 3, 0xFF, 0x86, 3]);
        // A NULL mapping is a mapping without tables.
        let rd = [0, 8, 0, 0, 0, 6, 0xFF, 3, 0x01, 0x00, 0x00, 0x01];
        assert_eq!(modbus_reply(ctx.0, rd.as_ptr(), 12, ptr::null_mut()), 9);
        assert_eq!(read_some(peer), [0, 8, 0, 0, 0, 3, 0xFF, 0x83, 2]);
        // A 1-byte PDU in an 8-byte buffer (#837).
        let rsid = [0, 9, 0, 0, 0, 2, 0xFF, 0x11];
        assert_eq!(modbus_reply(ctx.0, rsid.as_ptr(), 8, m), 8 + 12);
        assert_eq!(read_some(peer)[7..10], [0x11, 0x0B, 0xB4]);
        // FC 07: nothing sent, ENOPROTOOPT.
        let fc7 = [0, 9, 0, 0, 0, 2, 0xFF, 0x07];
        assert_eq!(modbus_reply(ctx.0, fc7.as_ptr(), 8, m), -1);
        assert_eq!(errno(), libc::ENOPROTOOPT);
        assert!(read_some(peer).is_empty());
        // Unknown function: the pending bytes are flushed, then the exception goes.
        write_all(peer, &[1, 2, 3]);
        std::thread::sleep(std::time::Duration::from_millis(20));
        let unk = [0, 10, 0, 0, 0, 2, 0xFF, 0x08];
        assert_eq!(modbus_reply(ctx.0, unk.as_ptr(), 8, m), 9);
        assert_eq!(read_some(peer), [0, 10, 0, 0, 0, 3, 0xFF, 0x88, 1]);
        assert!(read_some(ours).is_empty());
        // modbus_reply_exception: any code below 12, else EINVAL.
        assert_eq!(modbus_reply_exception(ctx.0, rd.as_ptr(), 0), 9);
        assert_eq!(read_some(peer), [0, 8, 0, 0, 0, 3, 0xFF, 0x83, 0]);
        assert_eq!(modbus_reply_exception(ctx.0, rd.as_ptr(), 12), -1);
        assert_eq!(errno(), libc::EINVAL);
        assert_eq!(modbus_reply_exception(ctx.0, rd.as_ptr(), u32::MAX), -1);
        // NULL arguments.
        assert_eq!(modbus_reply(ptr::null_mut(), rd.as_ptr(), 12, m), -1);
        assert_eq!(errno(), libc::EINVAL);
        assert_eq!(modbus_reply(ctx.0, ptr::null(), 12, m), -1);
        assert_eq!(modbus_receive(ctx.0, ptr::null_mut()), -1);
        assert_eq!(modbus_reply_exception(ptr::null_mut(), rd.as_ptr(), 1), -1);
        modbus_mapping_free(m);
    }
    close(peer);
    close(ours);
}

#[test]
fn receive_tcp_keeps_the_rest_of_the_buffer() {
    let (ours, peer) = socket_pair();
    let ctx = tcp(ours);
    let mut buf = [0xEEu8; 260];
    // Two requests in one write: each receive takes exactly one.
    let a = [0, 1, 0, 0, 0, 6, 0xFF, 3, 0, 0, 0, 1];
    let b = [0, 2, 0, 0, 0, 2, 0xFF, 0x11];
    write_all(peer, &[&a[..], &b[..]].concat());
    // SAFETY: live handle, a 260-byte buffer.
    unsafe {
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 12);
        assert_eq!(buf[..12], a);
        assert!(buf[12..].iter().all(|&x| x == 0xEE));
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
        assert_eq!(buf[..8], b);
        close(peer);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), -1);
        assert_eq!(errno(), libc::ECONNRESET);
    }
    close(ours);
}

#[test]
fn receive_rtu_skips_the_answer_to_another_slave() {
    let (ours, peer) = socket_pair();
    let ctx = rtu(ours, 17);
    let mut buf = [0u8; 256];
    let other_req = with_crc(vec![5, 3, 0, 0, 0, 1]);
    let other_rsp = with_crc(vec![5, 3, 2, 0x12, 0x34]);
    let ours_req = with_crc(vec![17, 3, 0, 0, 0, 1]);
    // SAFETY: live handle, a 256-byte buffer.
    unsafe {
        write_all(peer, &other_req);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 0);
        // The other slave's answer is read as a confirmation and dropped.
        write_all(peer, &other_rsp);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 0);
        assert_eq!(buf[..7], other_rsp);
        write_all(peer, &ours_req);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
        assert_eq!(buf[..8], ours_req);
        // Broadcast is ours too, but the reply is suppressed.
        let bc = with_crc(vec![0, 6, 0, 1, 0, 9]);
        write_all(peer, &bc);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
        let m = modbus_mapping_new(0, 0, 4, 0);
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 8, m), 0);
        assert_eq!(*(*m).tab_registers.add(1), 9);
        assert!(read_some(peer).is_empty());
        // A bad CRC: EMBBADCRC, and the frame is in the buffer for a reply with -1.
        let mut bad = with_crc(vec![17, 6, 0, 2, 0, 7]);
        bad[7] ^= 0xFF;
        write_all(peer, &bad);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), -1);
        assert_eq!(errno(), modbus::error::EMBBADCRC);
        assert_eq!(buf[..8], bad);
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), -1, m), 5);
        assert_eq!(read_some(peer), with_crc(vec![17, 0x86, 3]));
        modbus_mapping_free(m);
    }
    close(peer);
    close(ours);
}

fn local_port(fd: i32) -> u16 {
    // SAFETY: all-zero is a valid sockaddr_in; getsockname fills at most `len` bytes.
    unsafe {
        let mut sa: libc::sockaddr_in = std::mem::zeroed();
        let mut len = size_of::<libc::sockaddr_in>() as libc::socklen_t;
        assert_eq!(libc::getsockname(fd, (&mut sa as *mut libc::sockaddr_in).cast(), &mut len), 0);
        u16::from_be(sa.sin_port)
    }
}

fn connect_to(port: u16) -> i32 {
    // SAFETY: plain socket calls on a fresh descriptor and a local sockaddr_in.
    unsafe {
        let fd = libc::socket(libc::AF_INET, libc::SOCK_STREAM, 0);
        let mut sa: libc::sockaddr_in = std::mem::zeroed();
        sa.sin_family = libc::AF_INET as libc::sa_family_t;
        sa.sin_port = port.to_be();
        sa.sin_addr.s_addr = u32::from_be_bytes([127, 0, 0, 1]).to_be();
        let rc = libc::connect(fd, (&sa as *const libc::sockaddr_in).cast(), size_of::<libc::sockaddr_in>() as u32);
        assert_eq!(rc, 0);
        fd
    }
}

/// `modbus_close` and `modbus_free` from another thread end a `modbus_tcp_accept`
/// that waits (it holds no lock while it waits) with EBADF, promptly; after the
/// free, the handle goes with the accept's return (valgrind in the C suites).
#[test]
fn accept_is_stopped_by_close_and_free_from_another_thread() {
    for free in [false, true] {
        let ctx = into_handle(Context::new_tcp(Some(c"127.0.0.1"), 0));
        // SAFETY: a live handle, passed to the other thread as a number.
        let mut lfd = unsafe { modbus_tcp_listen(ctx, 1) };
        assert!(lfd >= 0);
        let addr = ctx as usize;
        let stopper = std::thread::spawn(move || {
            std::thread::sleep(std::time::Duration::from_millis(200));
            let started = std::time::Instant::now();
            // SAFETY: the handle is live until this call.
            unsafe {
                if free {
                    modbus_free(addr as *mut Modbus);
                } else {
                    modbus::ffi::context::modbus_close(addr as *mut Modbus);
                }
            }
            started.elapsed()
        });
        let started = std::time::Instant::now();
        // SAFETY: live handle (freed by the other thread only once this returns),
        // a live local.
        let rc = unsafe { modbus_tcp_accept(ctx, &mut lfd) };
        let e = errno();
        let waited = started.elapsed();
        let took = stopper.join().unwrap();
        assert_eq!((rc, e), (-1, libc::EBADF), "free: {free}");
        assert!(waited < std::time::Duration::from_secs(2), "{waited:?}");
        assert!(took < std::time::Duration::from_millis(100), "{took:?}");
        if !free {
            // SAFETY: the handle is live (only closed).
            unsafe { modbus_free(ctx) };
        }
        close(lfd);
    }
}

#[test]
fn listen_accept_and_descriptors_above_fd_setsize() {
    let ctx = Ctx(into_handle(Context::new_tcp(Some(c"127.0.0.1"), 0)));
    // SAFETY: live handle and local descriptors throughout.
    unsafe {
        let lfd = modbus_tcp_listen(ctx.0, 2);
        assert!(lfd >= 0);
        // The listening socket is close-on-exec and is not the context's socket.
        assert_ne!(libc::fcntl(lfd, libc::F_GETFD) & libc::FD_CLOEXEC, 0);
        assert_eq!(modbus::ffi::context::modbus_get_socket(ctx.0), -1);
        // Move it above FD_SETSIZE when the limit allows.
        let mut lim: libc::rlimit = std::mem::zeroed();
        libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim);
        if lim.rlim_cur < 2048 && lim.rlim_max >= 2048 {
            lim.rlim_cur = 2048;
            libc::setrlimit(libc::RLIMIT_NOFILE, &lim);
        }
        let high = lim.rlim_cur >= 2048;
        let mut s = lfd;
        if high {
            s = libc::dup2(lfd, 1500 + (lfd % 100));
            assert!(s >= 1500);
            close(lfd);
        }
        let port = local_port(s);
        let client = connect_to(port);
        let fd = modbus_tcp_accept(ctx.0, &mut s);
        assert!(fd >= 0);
        assert_eq!(modbus::ffi::context::modbus_get_socket(ctx.0), fd);
        assert_ne!(libc::fcntl(fd, libc::F_GETFD) & libc::FD_CLOEXEC, 0);
        let fd = if high {
            let hi = libc::dup3(fd, 1600 + (fd % 100), libc::O_CLOEXEC);
            close(fd);
            modbus_set_socket(ctx.0, hi);
            hi
        } else {
            fd
        };
        let m = modbus_mapping_new(0, 0, 2, 0);
        let mut buf = [0u8; 260];
        write_all(client, &[0, 1, 0, 0, 0, 6, 1, 6, 0, 1, 0x55, 0xAA]);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 12);
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 12, m), 12);
        assert_eq!(read_some(client), buf[..12]);
        modbus_mapping_free(m);
        close(client);
        close(fd);
        close(s);
        // NULL and wrong arguments.
        assert_eq!(modbus_tcp_accept(ctx.0, ptr::null_mut()), -1);
        assert_eq!(errno(), libc::EINVAL);
        assert_eq!(modbus_tcp_listen(ptr::null_mut(), 1), -1);
        let mut bad = -1;
        assert_eq!(modbus_tcp_accept(ctx.0, &mut bad), -1);
        assert_eq!(errno(), libc::EBADF);
        assert_eq!(modbus::ffi::context::modbus_get_socket(ctx.0), -1);
    }
    let r = rtu(-1, 1);
    // SAFETY: live handle.
    unsafe {
        assert_eq!(modbus_tcp_listen(r.0, 1), -1);
        assert_eq!(errno(), libc::EINVAL);
        assert_eq!(modbus_tcp_pi_listen(r.0, 1), -1);
        let mut s = 0;
        assert_eq!(modbus_tcp_pi_accept(r.0, &mut s), -1);
        assert_eq!(errno(), libc::EINVAL);
    }
}

#[test]
fn pi_listen_on_ipv6_loopback() {
    let ctx = Ctx(into_handle(Context::new_tcp_pi(Some(c"::1"), Some(c"0"))));
    // SAFETY: live handle.
    unsafe {
        let s = modbus_tcp_pi_listen(ctx.0, 1);
        if s == -1 {
            // No IPv6 loopback here (AI_ADDRCONFIG): getaddrinfo fails.
            assert_eq!(errno(), libc::ECONNREFUSED);
            return;
        }
        assert_ne!(libc::fcntl(s, libc::F_GETFD) & libc::FD_CLOEXEC, 0);
        close(s);
    }
}

#[test]
fn listen_address_rules() {
    // An address starting with '0' is any address; an invalid one fails without errno.
    for (ip, ok) in [(c"0", true), (c"0.0.0.0", true), (c"127.0.0.1", true), (c"1.2.3", false)] {
        let ctx = Ctx(into_handle(Context::new_tcp(Some(ip), 0)));
        modbus::transport::set_errno(12345);
        // SAFETY: live handle.
        let s = unsafe { modbus_tcp_listen(ctx.0, 1) };
        assert_eq!(s >= 0, ok, "{ip:?}");
        if ok {
            close(s);
        } else {
            assert_eq!(errno(), 12345);
        }
    }
}

// ------------------------------------------------------------ beyond libmodbus

#[test]
fn extended_requests_are_framed_whole_only_once_configured() {
    let (ours, peer) = socket_pair();
    let ctx = tcp(ours);
    let mut buf = [0u8; 260];
    let diag = [0, 1, 0, 0, 0, 6, 0xFF, 0x08, 0, 0, 0x12, 0x34];
    // SAFETY: live handle, a 260-byte buffer.
    unsafe {
        // Unconfigured: libmodbus's framing (up to the function code) and answer.
        write_all(peer, &diag);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 8, ptr::null_mut()), 9);
        assert_eq!(read_some(peer), [0, 1, 0, 0, 0, 3, 0xFF, 0x88, 1]);
        // Configured: the whole request, echoed.
        assert_eq!(modbus_enable_diagnostics(ctx.0, 1), 0);
        write_all(peer, &diag);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 12);
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 12, ptr::null_mut()), 12);
        assert_eq!(read_some(peer), diag);
        // -1 as req_length: the extent comes from the request (MBAP length here).
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), -1, ptr::null_mut()), 12);
        assert_eq!(read_some(peer), diag);
        // A req_length shorter than the request: an odd byte of data, ILLEGAL DATA VALUE.
        assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 11, ptr::null_mut()), 9);
        assert_eq!(read_some(peer), [0, 1, 0, 0, 0, 3, 0xFF, 0x88, 3]);
        // Off again: back to libmodbus.
        assert_eq!(modbus_enable_diagnostics(ctx.0, 0), 0);
        write_all(peer, &diag);
        assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
        let g = (*ctx.0).lock();
        assert!(g.server_ext.is_none() && !g.session.extended);
    }
    close(peer);
    close(ours);
}

#[test]
fn diagnostics_follow_receive_and_reply() {
    let (ours, peer) = socket_pair();
    let ctx = rtu(ours, 17);
    let mut buf = [0u8; 256];
    let m = modbus_mapping_new(0, 0, 4, 0);
    // SAFETY: live handle, a 256-byte buffer, a live mapping.
    unsafe {
        assert_eq!(modbus_enable_diagnostics(ctx.0, 1), 0);
        let mut exchange = |frame: &[u8]| {
            write_all(peer, frame);
            let rc = modbus_receive(ctx.0, buf.as_mut_ptr());
            let sent = if rc > 0 { modbus_reply(ctx.0, buf.as_ptr(), rc, m) } else { rc };
            (rc, sent, read_some(peer))
        };
        let read = with_crc(vec![17, 3, 0, 0, 0, 1]);
        assert_eq!(exchange(&read).1, 7);
        // Another slave's request and its answer: bus messages only.
        assert_eq!(exchange(&with_crc(vec![5, 3, 0, 0, 0, 1])).0, 0);
        assert_eq!(exchange(&with_crc(vec![5, 3, 2, 0, 0])).0, 0);
        // A CRC error.
        let mut bad = read.clone();
        bad[6] ^= 0xFF;
        assert_eq!(exchange(&bad).0, -1);
        // An exception (address 9) and a broadcast write.
        assert_eq!(exchange(&with_crc(vec![17, 3, 0, 9, 0, 1])).2, with_crc(vec![17, 0x83, 2]));
        assert_eq!(exchange(&with_crc(vec![0, 6, 0, 1, 0, 7])).1, 0);
        let mut v = 0u16;
        let want = [(0x0B, 6), (0x0C, 1), (0x0D, 1), (0x0E, 3), (0x0F, 1), (0x10, 0), (0x11, 0), (0x12, 0)];
        for (sub, value) in want {
            assert_eq!(modbus_get_diagnostics(ctx.0, sub, &mut v), 0);
            assert_eq!(v, value, "sub-function 0x{sub:X}");
        }
        let (mut events, mut messages) = (0u16, 0u16);
        let mut log = [0u8; 64];
        assert_eq!(modbus_get_event_log(ctx.0, &mut events, &mut messages, log.as_mut_ptr(), 64), 7);
        assert_eq!((events, messages), (2, 6));
        assert_eq!(log[..7], [0x40, 0xC0, 0x41, 0x80, 0x82, 0x40, 0x80]);
        assert_eq!(modbus_get_event_log(ctx.0, ptr::null_mut(), ptr::null_mut(), ptr::null_mut(), 0), 7);
        assert_eq!(modbus_get_event_log(ctx.0, ptr::null_mut(), ptr::null_mut(), log.as_mut_ptr(), 2), 7);
        // Listen-only mode from the wire, then modbus_reply_exception is silent too.
        assert_eq!(exchange(&with_crc(vec![17, 8, 0, 4, 0, 0])).1, 0);
        assert_eq!(modbus_get_diagnostics(ctx.0, 4, &mut v), 0);
        assert_eq!(v, 1);
        assert_eq!(exchange(&read).2, Vec::<u8>::new());
        assert_eq!(modbus_reply_exception(ctx.0, read.as_ptr(), 6), 0);
        assert!(read_some(peer).is_empty());
        // Restart: no answer, out of listen-only mode.
        let (_, sent, answer) = exchange(&with_crc(vec![17, 8, 0, 1, 0xFF, 0]));
        assert_eq!((sent, answer), (0, vec![]));
        assert_eq!(modbus_get_event_log(ctx.0, ptr::null_mut(), ptr::null_mut(), log.as_mut_ptr(), 64), 1);
        assert_eq!(log[0], 0);
        assert_eq!(exchange(&read).1, 7);
        // modbus_reply_exception counts busy and NAK.
        assert_eq!(modbus_reply_exception(ctx.0, read.as_ptr(), 6), 5);
        assert_eq!(modbus_reply_exception(ctx.0, read.as_ptr(), 7), 5);
        let _ = read_some(peer);
        for (sub, value) in [(0x0D, 2), (0x10, 1), (0x11, 1)] {
            modbus_get_diagnostics(ctx.0, sub, &mut v);
            assert_eq!(v, value);
        }
        assert_eq!(modbus_set_diagnostic_register(ctx.0, 0x1234), 0);
        modbus_get_diagnostics(ctx.0, 2, &mut v);
        assert_eq!(v, 0x1234);
        // Argument errors.
        for sub in [-1, 0, 1, 5, 0x13, 0x14, 0x10000] {
            assert_eq!(modbus_get_diagnostics(ctx.0, sub, &mut v), -1, "{sub}");
            assert_eq!(errno(), libc::EINVAL);
        }
        assert_eq!(modbus_get_diagnostics(ctx.0, 0x0B, ptr::null_mut()), -1);
        assert_eq!(modbus_get_event_log(ctx.0, ptr::null_mut(), ptr::null_mut(), ptr::null_mut(), 1), -1);
        assert_eq!(modbus_get_event_log(ctx.0, ptr::null_mut(), ptr::null_mut(), log.as_mut_ptr(), -1), -1);
        assert_eq!(modbus_enable_diagnostics(ctx.0, 0), 0);
        assert_eq!(modbus_get_diagnostics(ctx.0, 0x0B, &mut v), -1);
        assert_eq!(modbus_get_event_log(ctx.0, ptr::null_mut(), ptr::null_mut(), ptr::null_mut(), 0), -1);
        assert_eq!(modbus_set_diagnostic_register(ctx.0, 1), -1);
        assert_eq!(modbus_enable_diagnostics(ptr::null_mut(), 1), -1);
        modbus_mapping_free(m);
    }
    close(peer);
    close(ours);
}

#[test]
fn configuration_exports() {
    let ctx = tcp(-1);
    let mut regs = [0u16; 4];
    // SAFETY: live handle; pointers to live locals.
    unsafe {
        let g = |c: &Ctx| {
            let g = (*c.0).lock();
            (g.server_ext.is_some(), g.session.extended)
        };
        assert_eq!(modbus_set_exception_status(ctx.0, 0x6D), 0);
        assert_eq!(g(&ctx), (true, false));
        for bad in [-2, 256] {
            assert_eq!(modbus_set_exception_status(ctx.0, bad), -1);
            assert_eq!(errno(), libc::EINVAL);
        }
        assert_eq!(modbus_set_exception_status(ctx.0, -1), 0);
        assert_eq!(g(&ctx), (false, false));
        // Report slave id.
        assert_eq!(modbus_set_report_slave_id(ctx.0, 0x55, 1, b"abc".as_ptr(), 3), 0);
        assert_eq!(modbus_set_report_slave_id(ctx.0, 256, 1, ptr::null(), 0), -1);
        assert_eq!(modbus_set_report_slave_id(ctx.0, 1, 1, ptr::null(), 1), -1);
        assert_eq!(modbus_set_report_slave_id(ctx.0, 1, 1, [0u8; 250].as_ptr(), 250), -1);
        assert_eq!(modbus_set_report_slave_id(ctx.0, -1, 0, ptr::null(), 0), 0);
        assert_eq!(g(&ctx), (false, false));
        // Device identification: C strings and byte runs.
        assert_eq!(modbus_set_device_identification(ctx.0, 0, c"ACME".as_ptr(), -1), 0);
        assert_eq!(g(&ctx), (true, true));
        assert_eq!(modbus_set_device_identification(ctx.0, 0x80, b"\0\x01".as_ptr().cast(), 2), 0);
        assert_eq!(modbus_set_device_identification(ctx.0, 0x07, c"x".as_ptr(), -1), -1);
        assert_eq!(modbus_set_device_identification(ctx.0, 0, c"x".as_ptr(), -2), -1);
        assert_eq!(modbus_set_device_identification(ctx.0, 1, [b'x'; 245].as_ptr().cast(), 245), -1);
        assert_eq!(modbus_set_conformity_level(ctx.0, 0x84), -1);
        assert_eq!(modbus_set_conformity_level(ctx.0, 0x82), 0);
        assert_eq!(modbus_set_conformity_level(ctx.0, 0), 0);
        assert_eq!(modbus_set_device_identification(ctx.0, 0, ptr::null(), 0), 0);
        assert_eq!(modbus_set_device_identification(ctx.0, 0x80, ptr::null(), 0), 0);
        assert_eq!(g(&ctx), (false, false));
        // Files.
        assert_eq!(modbus_set_file_record(ctx.0, 1, 10, 2, [7u16, 8].as_ptr()), 2);
        assert_eq!(g(&ctx), (true, true));
        assert_eq!(modbus_get_file_record(ctx.0, 1, 9, 4, regs.as_mut_ptr()), -1);
        assert_eq!(modbus_get_file_record(ctx.0, 1, 9, 3, regs.as_mut_ptr()), 3);
        assert_eq!(regs[..3], [0, 7, 8]);
        assert_eq!(modbus_set_file_record(ctx.0, 1, 0, 0, ptr::null()), -1);
        assert_eq!(modbus_set_file_record(ctx.0, 0, 0, 1, ptr::null()), -1);
        assert_eq!(modbus_set_file_record(ctx.0, 1, 9999, 2, ptr::null()), -1);
        assert_eq!(modbus_get_file_record(ctx.0, 1, 0, 1, ptr::null_mut()), -1);
        assert_eq!(modbus_get_file_record(ctx.0, 2, 0, 1, regs.as_mut_ptr()), -1);
        // FIFO queues.
        assert_eq!(modbus_set_fifo_queue(ctx.0, 3, ptr::null(), 0), 0);
        assert_eq!(modbus_set_fifo_queue(ctx.0, 3, ptr::null(), 1), -1);
        assert_eq!(modbus_set_fifo_queue(ctx.0, 3, regs.as_ptr(), -1), -1);
        assert_eq!(modbus_set_fifo_queue(ctx.0, 0x10000, regs.as_ptr(), 1), -1);
        // NULL contexts.
        assert_eq!(modbus_set_fifo_queue(ptr::null_mut(), 0, ptr::null(), 0), -1);
        assert_eq!(modbus_set_exception_status(ptr::null_mut(), 0), -1);
        assert_eq!(modbus_get_file_record(ptr::null_mut(), 1, 0, 1, regs.as_mut_ptr()), -1);
        assert_eq!(errno(), libc::EINVAL);
    }
}
