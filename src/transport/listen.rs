//! TCP servers: `modbus_tcp_listen` / `modbus_tcp_pi_listen` open a listening socket
//! and hand it to the caller (the context does not make it its socket; it remembers
//! it for a server runner, `Line::listener`); `modbus_tcp_accept` /
//! `modbus_tcp_pi_accept` accept one client and make it the context's socket.
//!
//! Unlike libmodbus 3.1.12, descriptors at or above `FD_SETSIZE` are accepted: all
//! waiting is done with `poll`, so they work like any other.

use std::ffi::CStr;
use std::mem::{size_of, zeroed};

use crate::error::{Error, Result};
use crate::proto::Diag;
use crate::transport::link::Link;
use crate::transport::tcp::{AddrInfo, gai_error, inet_pton};
use crate::transport::{Ready, close, last_error, wait_or_wake};

unsafe extern "C" {
    /// POSIX `inet_ntop` (not bound by the libc crate).
    fn inet_ntop(
        af: libc::c_int,
        src: *const libc::c_void,
        dst: *mut libc::c_char,
        size: libc::socklen_t,
    ) -> *const libc::c_char;
}

fn set_reuseaddr(fd: i32) -> Result<()> {
    super::set_option(fd, libc::SOL_SOCKET, libc::SO_REUSEADDR, 1 as libc::c_int)
}

/// Runs `f`; on failure closes `fd` and passes the error (errno of the failed call) on.
fn or_close<T>(fd: i32, r: Result<T>) -> Result<T> {
    r.inspect_err(|_| close(fd))
}

fn bind_and_listen(fd: i32, addr: *const libc::sockaddr, len: libc::socklen_t, backlog: i32) -> Result<()> {
    // SAFETY: `addr` points at a socket address of `len` bytes owned by the caller.
    if unsafe { libc::bind(fd, addr, len) } == -1 {
        return Err(last_error());
    }
    // SAFETY: plain system call with integer arguments.
    if unsafe { libc::listen(fd, backlog) } == -1 {
        return Err(last_error());
    }
    Ok(())
}

/// `modbus_tcp_listen`: an IPv4 socket bound to the context's address and port.
/// An address starting with '0' (NULL ip, "0.0.0.0", ...) means any address.
pub fn listen_ipv4(link: &Link, nb_connection: i32, diag: &mut dyn Diag) -> Result<i32> {
    let Link::Tcp(link) = link else { return Err(Error::INVALID) };
    // SAFETY: plain system call with integer arguments.
    let fd = unsafe { libc::socket(libc::PF_INET, libc::SOCK_STREAM | libc::SOCK_CLOEXEC, libc::IPPROTO_TCP) };
    if fd == -1 {
        return Err(last_error());
    }
    or_close(fd, set_reuseaddr(fd))?;
    // SAFETY: all-zero is a valid sockaddr_in.
    let mut sa: libc::sockaddr_in = unsafe { zeroed() };
    sa.sin_family = libc::AF_INET as libc::sa_family_t;
    sa.sin_port = (link.port as u16).to_be();
    if link.ip.to_bytes().first() == Some(&b'0') {
        sa.sin_addr.s_addr = libc::INADDR_ANY.to_be();
    } else {
        // SAFETY: `ip` is NUL-terminated and `sin_addr` is a live in_addr.
        let rc = unsafe { inet_pton(libc::AF_INET, link.ip.as_ptr(), (&mut sa.sin_addr as *mut libc::in_addr).cast()) };
        if rc <= 0 {
            diag.err(format_args!("Invalid IP address: {}\n", link.ip.to_string_lossy()));
            close(fd);
            return Err(Error::UNCHANGED);
        }
    }
    let len = size_of::<libc::sockaddr_in>() as libc::socklen_t;
    or_close(fd, bind_and_listen(fd, (&sa as *const libc::sockaddr_in).cast(), len, nb_connection))?;
    Ok(fd)
}

/// What libmodbus's `perror(what)` prints in debug mode, for the error `e`: the
/// same line on stderr, without touching errno.
fn perror(debug: bool, what: &CStr, e: Error) {
    if debug {
        crate::stdio::err(format_args!("{}: {}\n", what.to_string_lossy(), super::describe(e.0)));
    }
}

/// `modbus_tcp_pi_listen`: the first address of getaddrinfo(node, service) (passive,
/// any family) that can be bound and listened on.
pub fn listen_pi(link: &Link, nb_connection: i32, debug: bool, diag: &mut dyn Diag) -> Result<i32> {
    let Link::TcpPi(link) = link else { return Err(Error::INVALID) };
    let node = (!link.node.is_empty()).then_some(link.node.as_c_str());
    let service: &CStr = if link.service.is_empty() { c"502" } else { &link.service };
    let list = match AddrInfo::lookup(node, service, libc::AI_PASSIVE | libc::AI_ADDRCONFIG) {
        Ok(list) => list,
        Err(code) => {
            diag.err(format_args!("Error returned by getaddrinfo: {}\n", gai_error(code)));
            return Err(Error::CONN_REFUSED);
        }
    };
    let mut last = Error::UNCHANGED;
    for ai in list.iter() {
        // SAFETY: plain system call with integer arguments.
        let fd = unsafe { libc::socket(ai.ai_family, ai.ai_socktype | libc::SOCK_CLOEXEC, ai.ai_protocol) };
        if fd < 0 {
            last = last_error();
            perror(debug, c"socket", last);
            continue;
        }
        if let Err(e) = set_reuseaddr(fd) {
            close(fd);
            last = e;
            perror(debug, c"setsockopt", e);
            continue;
        }
        // SAFETY: `ai_addr` points at `ai_addrlen` bytes of the list we own.
        if unsafe { libc::bind(fd, ai.ai_addr, ai.ai_addrlen) } == -1 {
            last = last_error();
            close(fd);
            perror(debug, c"bind", last);
            continue;
        }
        // SAFETY: plain system call with integer arguments.
        if unsafe { libc::listen(fd, nb_connection) } == -1 {
            last = last_error();
            close(fd);
            perror(debug, c"listen", last);
            continue;
        }
        return Ok(fd);
    }
    Err(last)
}

/// The textual address of an accepted peer (`inet_ntop`), or `None`.
fn peer_text(addr: &libc::sockaddr_storage) -> Option<String> {
    let mut buf = [0 as libc::c_char; 64];
    let src: *const libc::c_void = match addr.ss_family as i32 {
        libc::AF_INET => {
            let sin = (addr as *const libc::sockaddr_storage).cast::<libc::sockaddr_in>();
            // SAFETY: the family says the storage holds a sockaddr_in.
            unsafe { (&raw const (*sin).sin_addr).cast() }
        }
        libc::AF_INET6 => {
            let sin6 = (addr as *const libc::sockaddr_storage).cast::<libc::sockaddr_in6>();
            // SAFETY: the family says the storage holds a sockaddr_in6.
            unsafe { (&raw const (*sin6).sin6_addr).cast() }
        }
        _ => return None,
    };
    // SAFETY: `src` points at an address of the given family inside `addr`; `buf` has
    // room for the longest IPv6 text (46 bytes) and its size is passed.
    let p = unsafe { inet_ntop(addr.ss_family as i32, src, buf.as_mut_ptr(), buf.len() as libc::socklen_t) };
    if p.is_null() {
        return None;
    }
    // SAFETY: inet_ntop wrote a NUL-terminated string into `buf`.
    Some(unsafe { CStr::from_ptr(buf.as_ptr()) }.to_string_lossy().into_owned())
}

/// Accepts one client on `listen_fd` (close-on-exec, blocking, as libmodbus), with
/// TCP_NODELAY, which libmodbus leaves off there: with Nagle's algorithm, the answers
/// to requests a client pipelined wait, after the first, for its acknowledgement (a
/// round trip, or a delayed ACK's 40 ms); an answer is a whole frame, never worth
/// holding back. Returns the new descriptor and the peer's address text. Signals do not
/// end the wait (with `SA_RESTART` or without); `closed()` does, checked at the start
/// and whenever the eventfd `wake` (-1: none) is written: `Err(STOPPED)`.
pub fn accept(listen_fd: i32, wake: i32, closed: &dyn Fn() -> bool) -> Result<(i32, Option<String>)> {
    if listen_fd < 0 {
        // What accept4 says (ppoll would skip a negative descriptor and wait on).
        return Err(Error(libc::EBADF));
    }
    loop {
        if closed() {
            return Err(Error::STOPPED);
        }
        match wait_or_wake(listen_fd, libc::POLLIN, wake, None) {
            Ok(Ready::Line) => {}
            Ok(_) => {
                let mut count = [0u8; 8];
                let _ = super::read(wake, &mut count);
                continue;
            }
            Err(e) if e.0 == libc::EINTR => continue,
            Err(e) => return Err(e),
        }
        // SAFETY: all-zero is a valid sockaddr_storage.
        let mut addr: libc::sockaddr_storage = unsafe { zeroed() };
        let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
        // SAFETY: `addr`/`len` are live locals describing a buffer of `len` bytes.
        let fd = unsafe {
            libc::accept4(listen_fd, (&mut addr as *mut libc::sockaddr_storage).cast(), &mut len, libc::SOCK_CLOEXEC)
        };
        if fd >= 0 {
            // Best effort, as on a client socket: the accept stands without it.
            let _ = super::set_option(fd, libc::IPPROTO_TCP, libc::TCP_NODELAY, 1 as libc::c_int);
            return Ok((fd, peer_text(&addr)));
        }
        let e = last_error();
        // Taken by another process first (a non-blocking listener), or a signal.
        if e.0 != libc::EAGAIN && e.0 != libc::EINTR {
            return Err(e);
        }
    }
}

/// One client from the listening socket `listen_fd` without waiting (a server
/// runner's): its socket, non-blocking, with TCP_NODELAY, and the peer's address
/// text; `None` when no client is waiting.
pub fn accept_now(listen_fd: i32) -> Result<Option<(i32, Option<String>)>> {
    loop {
        // SAFETY: all-zero is a valid sockaddr_storage.
        let mut addr: libc::sockaddr_storage = unsafe { zeroed() };
        let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
        // SAFETY: `addr`/`len` are live locals describing a buffer of `len` bytes.
        let fd = unsafe {
            libc::accept4(
                listen_fd,
                (&mut addr as *mut libc::sockaddr_storage).cast(),
                &mut len,
                libc::SOCK_CLOEXEC | libc::SOCK_NONBLOCK,
            )
        };
        if fd >= 0 {
            let _ = super::set_option(fd, libc::IPPROTO_TCP, libc::TCP_NODELAY, 1 as libc::c_int);
            return Ok(Some((fd, peer_text(&addr))));
        }
        let e = last_error();
        match e.0 {
            libc::EINTR => continue,
            // Gone before it was taken: no client after all.
            libc::EAGAIN | libc::ECONNABORTED => return Ok(None),
            _ => return Err(e),
        }
    }
}

/// Whether `fd` is a listening socket (`SO_ACCEPTCONN`).
pub fn is_listening(fd: i32) -> bool {
    let mut value: libc::c_int = 0;
    let mut len = size_of::<libc::c_int>() as libc::socklen_t;
    // SAFETY: `value`/`len` are live locals describing a buffer of `len` bytes.
    let rc = unsafe {
        libc::getsockopt(fd, libc::SOL_SOCKET, libc::SO_ACCEPTCONN, (&mut value as *mut libc::c_int).cast(), &mut len)
    };
    rc == 0 && value != 0
}

/// Prints libmodbus 3.1.12's accept message.
pub fn report_accept(diag: &mut dyn Diag, peer: Option<&str>) {
    match peer {
        Some(p) => diag.out(format_args!("Client connection accepted from {p}.\n")),
        None => diag.err(format_args!("Client connection accepted from unparsable IP.\n")),
    }
}
