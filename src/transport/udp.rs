//! Modbus/UDP (`modbus_new_udp`, `modbus_new_udp_pi`), as pymodbus and j2mod speak
//! it: one ADU, MBAP header first, per datagram. A client's socket is connected to
//! its server (it sends with `send` and hears no one else); a server's socket is
//! bound, and answers each request to the address it came from.
//!
//! The receive machine reads a stream: a datagram is read whole into [`Datagram`]
//! (a read shorter than a datagram would lose its end) and handed out from there, as
//! a TLS session hands out its plaintext.

use std::ffi::CStr;
use std::mem::zeroed;

use super::link::{Link, TcpLink, TcpPiLink};
use super::tcp::{AddrInfo, gai_error};
use super::{close, last_error};
use crate::error::{Error, Result};
use crate::proto::Diag;
use crate::proto::frame::MAX_ADU_LENGTH;

unsafe extern "C" {
    fn inet_pton(af: libc::c_int, src: *const libc::c_char, dst: *mut libc::c_void) -> libc::c_int;
}

/// A datagram socket of `family`, close-on-exec.
fn new_socket(family: i32, protocol: i32) -> Result<i32> {
    // SAFETY: plain system call with integer arguments.
    let fd = unsafe { libc::socket(family, libc::SOCK_DGRAM | libc::SOCK_CLOEXEC, protocol) };
    if fd == -1 { Err(last_error()) } else { Ok(fd) }
}

/// The IPv4 address of a UDP context (`"0..."`: any).
fn ipv4(link: &TcpLink, diag: &mut dyn Diag) -> Result<libc::sockaddr_in> {
    // SAFETY: all-zero is a valid sockaddr_in.
    let mut sa: libc::sockaddr_in = unsafe { zeroed() };
    sa.sin_family = libc::AF_INET as libc::sa_family_t;
    sa.sin_port = (link.port as u16).to_be();
    if link.ip.to_bytes().first() == Some(&b'0') {
        sa.sin_addr.s_addr = libc::INADDR_ANY.to_be();
        return Ok(sa);
    }
    // SAFETY: `ip` is NUL-terminated and `sin_addr` is a live in_addr.
    let rc = unsafe { inet_pton(libc::AF_INET, link.ip.as_ptr(), (&mut sa.sin_addr as *mut libc::in_addr).cast()) };
    if rc <= 0 {
        diag.err(format_args!("Invalid IP address: {}\n", link.ip.to_string_lossy()));
        return Err(Error::UNCHANGED);
    }
    Ok(sa)
}

/// A socket made and then connected (`bind == false`) or bound to `addr`.
fn attach(family: i32, protocol: i32, addr: *const libc::sockaddr, len: libc::socklen_t, bind: bool) -> Result<i32> {
    let fd = new_socket(family, protocol)?;
    // SAFETY: `addr` points at a socket address of `len` bytes owned by the caller.
    let rc = unsafe {
        if bind {
            let one: libc::c_int = 1;
            libc::setsockopt(
                fd,
                libc::SOL_SOCKET,
                libc::SO_REUSEADDR,
                (&one as *const libc::c_int).cast(),
                size_of::<libc::c_int>() as libc::socklen_t,
            );
            libc::bind(fd, addr, len)
        } else {
            libc::connect(fd, addr, len)
        }
    };
    if rc == -1 {
        let e = last_error();
        close(fd);
        return Err(e);
    }
    Ok(fd)
}

/// The client's socket (`bind == false`), connected to the context's server, or the
/// server's, bound to the context's address (`bind == true`).
pub fn open(link: &Link, bind: bool, diag: &mut dyn Diag) -> Result<i32> {
    match link {
        Link::Tcp(l) => {
            let sa = ipv4(l, diag)?;
            if !bind {
                diag.out(format_args!("Connecting to {}:{} (UDP)\n", l.ip.to_string_lossy(), l.port));
            }
            let len = size_of::<libc::sockaddr_in>() as libc::socklen_t;
            attach(libc::AF_INET, 0, (&sa as *const libc::sockaddr_in).cast(), len, bind)
        }
        Link::TcpPi(l) => open_pi(l, bind, diag),
        Link::Rtu(_) => Err(Error::INVALID),
    }
}

fn open_pi(link: &TcpPiLink, bind: bool, diag: &mut dyn Diag) -> Result<i32> {
    let node = (!link.node.is_empty()).then_some(link.node.as_c_str());
    let service: &CStr = if link.service.is_empty() { c"502" } else { &link.service };
    let flags = libc::AI_ADDRCONFIG | if bind { libc::AI_PASSIVE } else { 0 };
    let list = match AddrInfo::lookup_of(node, service, flags, libc::SOCK_DGRAM) {
        Ok(list) => list,
        Err(code) => {
            diag.err(format_args!("Error returned by getaddrinfo: {}\n", gai_error(code)));
            return Err(Error::CONN_REFUSED);
        }
    };
    let mut last = Error::CONN_REFUSED;
    for ai in list.iter() {
        match attach(ai.ai_family, ai.ai_protocol, ai.ai_addr, ai.ai_addrlen, bind) {
            Ok(fd) => return Ok(fd),
            Err(e) => last = e,
        }
    }
    Err(last)
}

/// Whether `fd` is connected to a peer (a client's socket handed over with
/// `modbus_set_socket`), rather than bound and answering each sender.
pub fn has_peer(fd: i32) -> bool {
    // SAFETY: all-zero is a valid sockaddr_storage; the kernel writes at most `len`.
    let mut addr: libc::sockaddr_storage = unsafe { zeroed() };
    let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
    // SAFETY: `addr`/`len` describe a live buffer.
    unsafe { libc::getpeername(fd, (&mut addr as *mut libc::sockaddr_storage).cast(), &mut len) == 0 }
}

/// The sender of a datagram (a server answers it there).
#[derive(Clone, Copy)]
pub struct Peer {
    addr: libc::sockaddr_storage,
    len: libc::socklen_t,
}

/// The datagram being read, and where the answer goes.
pub struct Datagram {
    buf: Box<[u8; MAX_ADU_LENGTH]>,
    start: usize,
    end: usize,
    /// The sender of the last datagram (a server answers it).
    peer: libc::sockaddr_storage,
    peer_len: libc::socklen_t,
}

impl Default for Datagram {
    fn default() -> Self {
        // SAFETY: all-zero is a valid sockaddr_storage.
        Datagram { buf: Box::new([0; MAX_ADU_LENGTH]), start: 0, end: 0, peer: unsafe { zeroed() }, peer_len: 0 }
    }
}

impl Datagram {
    /// The sender of the last datagram read (`None` before any).
    pub fn peer(&self) -> Option<Peer> {
        (self.peer_len > 0).then_some(Peer { addr: self.peer, len: self.peer_len })
    }

    /// The next answer goes to `peer` (a request answered later).
    pub fn set_peer(&mut self, peer: Peer) {
        self.peer = peer.addr;
        self.peer_len = peer.len;
    }
}

impl Datagram {
    /// Bytes of the datagram not taken yet.
    pub fn pending(&self) -> usize {
        self.end - self.start
    }

    /// Reads the next datagram (with `flags`: `MSG_DONTWAIT`), whole: what does not fit
    /// one ADU is cut off (it is no Modbus message). An empty datagram counts as
    /// nothing read (EAGAIN).
    pub fn fill(&mut self, fd: i32, flags: i32) -> Result<()> {
        let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
        // SAFETY: the kernel writes at most the buffer's length and `len` bytes of
        // address into the live buffers.
        let n = unsafe {
            libc::recvfrom(
                fd,
                self.buf.as_mut_ptr().cast(),
                self.buf.len(),
                flags,
                (&mut self.peer as *mut libc::sockaddr_storage).cast(),
                &mut len,
            )
        };
        if n < 0 {
            return Err(last_error());
        }
        self.peer_len = len;
        self.start = 0;
        self.end = n as usize;
        if n == 0 { Err(Error(libc::EAGAIN)) } else { Ok(()) }
    }

    /// Copies what is left of the datagram into `room` without taking it.
    pub fn peek(&self, room: &mut [u8]) -> usize {
        let n = self.pending().min(room.len());
        room[..n].copy_from_slice(&self.buf[self.start..self.start + n]);
        n
    }

    /// Takes what is left of the datagram into `room` (as much as fits).
    pub fn take(&mut self, room: &mut [u8]) -> usize {
        let n = self.peek(room);
        self.start += n;
        n
    }

    /// Drops what is left of the datagram (a message ends with its datagram).
    pub fn discard(&mut self) -> usize {
        let n = self.pending();
        self.start = self.end;
        n
    }

    /// Sends `frame`: on a connected socket to its peer, else to the sender of the
    /// last datagram read (EDESTADDRREQ before any).
    pub fn send(&self, fd: i32, frame: &[u8], connected: bool) -> Result<usize> {
        if connected {
            return super::send(fd, frame, 0);
        }
        if self.peer_len == 0 {
            return Err(Error(libc::EDESTADDRREQ));
        }
        // SAFETY: the kernel reads `frame` and `peer_len` bytes of the stored address.
        let n = unsafe {
            libc::sendto(
                fd,
                frame.as_ptr().cast(),
                frame.len(),
                libc::MSG_NOSIGNAL,
                (&self.peer as *const libc::sockaddr_storage).cast(),
                self.peer_len,
            )
        };
        if n < 0 { Err(last_error()) } else { Ok(n as usize) }
    }
}
