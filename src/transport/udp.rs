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

/// A second descriptor of the socket `fd`, close-on-exec: a server serves on it
/// while the application keeps (and closes) its own.
pub fn duplicate(fd: i32) -> Result<i32> {
    // SAFETY: plain fcntl with integer arguments.
    let dup = unsafe { libc::fcntl(fd, libc::F_DUPFD_CLOEXEC, 0) };
    if dup == -1 { Err(last_error()) } else { Ok(dup) }
}

/// The sender of a datagram (a server answers it there).
#[derive(Clone, Copy)]
pub struct Peer {
    addr: libc::sockaddr_storage,
    len: libc::socklen_t,
}

/// How many recent requests a server's socket remembers the sender of (see
/// [`Senders`]): a reply to a request older than the last `SENDERS` datagrams
/// received fails (EDESTADDRREQ).
pub const SENDERS: usize = 64;

/// A datagram a server received: its sender and its bytes.
struct Sent {
    peer: Peer,
    len: u16,
    bytes: [u8; MAX_ADU_LENGTH],
    /// A reply went to it.
    answered: bool,
}

/// The senders of the last [`SENDERS`] datagrams a server's socket received, with
/// the datagrams (oldest first), so that a reply goes to the sender of the request
/// it answers, however many datagrams came since (a hand-written loop may receive
/// from several peers before it replies). A request is known by its bytes as
/// `modbus_receive` handed them over: the MBAP transaction id, the unit and the PDU
/// (a datagram that starts with them).
#[derive(Default)]
struct Senders {
    recent: std::collections::VecDeque<Sent>,
}

impl Senders {
    fn record(&mut self, peer: Peer, datagram: &[u8]) {
        let mut sent = if self.recent.len() == SENDERS {
            self.recent.pop_front().expect("full")
        } else {
            Sent { peer, len: 0, bytes: [0; MAX_ADU_LENGTH], answered: false }
        };
        sent.peer = peer;
        sent.len = datagram.len() as u16;
        sent.bytes[..datagram.len()].copy_from_slice(datagram);
        sent.answered = false;
        self.recent.push_back(sent);
    }

    /// The sender of the request `req`: of the datagrams that start with it, the
    /// oldest not answered yet (requests alike to the byte from several peers get
    /// one answer each, in the order they came; a reply that sees only the header
    /// and function code, `modbus_reply_exception`'s, tells apart requests that
    /// differ there), else the newest (a request answered again).
    fn answering(&mut self, req: &[u8]) -> Option<Peer> {
        if req.is_empty() {
            return None;
        }
        let is = |s: &Sent| s.bytes[..s.len as usize].starts_with(req);
        if let Some(s) = self.recent.iter_mut().find(|s| !s.answered && is(s)) {
            s.answered = true;
            return Some(s.peer);
        }
        self.recent.iter().rev().find(|s| is(s)).map(|s| s.peer)
    }
}

impl Peer {
    /// The peer of a connected socket (`getpeername`), `None` when it has none.
    pub fn of_socket(fd: i32) -> Option<Peer> {
        // SAFETY: all-zero is a valid sockaddr_storage; the kernel writes at most `len`.
        let mut addr: libc::sockaddr_storage = unsafe { zeroed() };
        let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
        // SAFETY: `addr`/`len` describe a live buffer.
        let rc = unsafe { libc::getpeername(fd, (&mut addr as *mut libc::sockaddr_storage).cast(), &mut len) };
        (rc == 0 && len > 0).then_some(Peer { addr, len })
    }

    /// The address as C sees it: a `struct sockaddr` of `len` bytes.
    pub fn raw(&self) -> (*const libc::sockaddr, u32) {
        ((&self.addr as *const libc::sockaddr_storage).cast(), self.len)
    }

    /// The local address of a socket (`getsockname`), `None` when it has none.
    pub fn of_local(fd: i32) -> Option<Peer> {
        // SAFETY: all-zero is a valid sockaddr_storage; the kernel writes at most `len`.
        let mut addr: libc::sockaddr_storage = unsafe { zeroed() };
        let mut len = size_of::<libc::sockaddr_storage>() as libc::socklen_t;
        // SAFETY: `addr`/`len` describe a live buffer.
        let rc = unsafe { libc::getsockname(fd, (&mut addr as *mut libc::sockaddr_storage).cast(), &mut len) };
        (rc == 0 && len > 0).then_some(Peer { addr, len })
    }

    /// The address as the standard library holds it (`None`: neither IPv4 nor IPv6).
    pub fn socket_addr(&self) -> Option<std::net::SocketAddr> {
        use std::net::{Ipv4Addr, Ipv6Addr, SocketAddr, SocketAddrV4, SocketAddrV6};
        match i32::from(self.addr.ss_family) {
            libc::AF_INET if self.len as usize >= size_of::<libc::sockaddr_in>() => {
                // SAFETY: the family says the storage holds a sockaddr_in, which it
                // is large and aligned enough for; read by value.
                let a: libc::sockaddr_in =
                    unsafe { std::ptr::read((&self.addr as *const libc::sockaddr_storage).cast()) };
                let ip = Ipv4Addr::from(u32::from_be(a.sin_addr.s_addr));
                Some(SocketAddr::V4(SocketAddrV4::new(ip, u16::from_be(a.sin_port))))
            }
            libc::AF_INET6 if self.len as usize >= size_of::<libc::sockaddr_in6>() => {
                // SAFETY: as above, a sockaddr_in6.
                let a: libc::sockaddr_in6 =
                    unsafe { std::ptr::read((&self.addr as *const libc::sockaddr_storage).cast()) };
                let ip = Ipv6Addr::from(a.sin6_addr.s6_addr);
                Some(SocketAddr::V6(SocketAddrV6::new(ip, u16::from_be(a.sin6_port), a.sin6_flowinfo, a.sin6_scope_id)))
            }
            _ => None,
        }
    }

    /// The address's bytes (a key: the same sender gives the same bytes).
    pub fn bytes(&self) -> &[u8] {
        let len = (self.len as usize).min(size_of::<libc::sockaddr_storage>());
        // SAFETY: `addr` is a live sockaddr_storage of at least `len` bytes.
        unsafe { std::slice::from_raw_parts((&self.addr as *const libc::sockaddr_storage).cast::<u8>(), len) }
    }
}

/// The datagram being read, and where the answer goes.
pub struct Datagram {
    buf: Box<[u8; MAX_ADU_LENGTH]>,
    start: usize,
    end: usize,
    /// The sender of the last datagram read.
    from: Option<Peer>,
    /// Where the next answer goes when not to `from`: the sender of the request it
    /// answers ([`Datagram::answering`], [`Datagram::set_peer`]).
    to: Option<Peer>,
    /// A server's socket: the senders of the recent requests.
    senders: Option<Box<Senders>>,
}

impl Default for Datagram {
    fn default() -> Self {
        Datagram { buf: Box::new([0; MAX_ADU_LENGTH]), start: 0, end: 0, from: None, to: None, senders: None }
    }
}

impl Datagram {
    /// The datagrams of a server's socket, which answers each request to its sender.
    pub fn serving() -> Self {
        Datagram { senders: Some(Box::default()), ..Datagram::default() }
    }

    /// The sender of the last datagram read (`None` before any).
    pub fn peer(&self) -> Option<Peer> {
        self.from
    }

    /// The next answer goes to `peer` (a request answered later).
    pub fn set_peer(&mut self, peer: Peer) {
        self.to = Some(peer);
    }

    /// On a server's socket: the next answer is the reply to `req` (the request as
    /// received: header first) and goes to its sender. EDESTADDRREQ when `req` is
    /// none of the last [`SENDERS`] datagrams received.
    pub fn answering(&mut self, req: &[u8]) -> Result<()> {
        let Some(senders) = self.senders.as_deref_mut() else { return Ok(()) };
        let peer = senders.answering(req).ok_or(Error(libc::EDESTADDRREQ))?;
        self.to = Some(peer);
        Ok(())
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
        // SAFETY: all-zero is a valid sockaddr_storage.
        let mut from = Peer { addr: unsafe { zeroed() }, len: size_of::<libc::sockaddr_storage>() as libc::socklen_t };
        // SAFETY: the kernel writes at most the buffer's length and `len` bytes of
        // address into the live buffers.
        let n = unsafe {
            libc::recvfrom(
                fd,
                self.buf.as_mut_ptr().cast(),
                self.buf.len(),
                flags,
                (&mut from.addr as *mut libc::sockaddr_storage).cast(),
                &mut from.len,
            )
        };
        if n < 0 {
            return Err(last_error());
        }
        self.start = 0;
        self.end = n as usize;
        if n == 0 {
            return Err(Error(libc::EAGAIN));
        }
        self.from = Some(from);
        self.to = None;
        if let Some(senders) = self.senders.as_deref_mut() {
            senders.record(from, &self.buf[..self.end]);
        }
        Ok(())
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
    /// request it answers ([`Datagram::answering`], [`Datagram::set_peer`]), or of
    /// the last datagram read (EDESTADDRREQ before any).
    pub fn send(&self, fd: i32, frame: &[u8], connected: bool) -> Result<usize> {
        if connected {
            return super::send(fd, frame, 0);
        }
        let Some(to) = self.to.as_ref().or(self.from.as_ref()) else { return Err(Error(libc::EDESTADDRREQ)) };
        // SAFETY: the kernel reads `frame` and `len` bytes of the stored address.
        let n = unsafe {
            libc::sendto(
                fd,
                frame.as_ptr().cast(),
                frame.len(),
                libc::MSG_NOSIGNAL,
                (&to.addr as *const libc::sockaddr_storage).cast(),
                to.len,
            )
        };
        if n < 0 { Err(last_error()) } else { Ok(n as usize) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A sender told apart by its port.
    fn peer(port: u16) -> Peer {
        // SAFETY: all-zero is a valid sockaddr_storage.
        let mut addr: libc::sockaddr_storage = unsafe { zeroed() };
        addr.ss_family = libc::AF_INET as libc::sa_family_t;
        // SAFETY: the storage holds a sockaddr_in (its family says so).
        unsafe { (*(&mut addr as *mut libc::sockaddr_storage).cast::<libc::sockaddr_in>()).sin_port = port.to_be() };
        Peer { addr, len: size_of::<libc::sockaddr_in>() as libc::socklen_t }
    }

    fn port(p: Option<Peer>) -> Option<u16> {
        p.map(|p| {
            // SAFETY: made by `peer` above: a sockaddr_in.
            u16::from_be(unsafe { (*(&p.addr as *const libc::sockaddr_storage).cast::<libc::sockaddr_in>()).sin_port })
        })
    }

    /// A read of one register at `addr`, unit 1, transaction id `tid`.
    fn read(tid: u16, addr: u16) -> Vec<u8> {
        let [t0, t1] = tid.to_be_bytes();
        let [a0, a1] = addr.to_be_bytes();
        vec![t0, t1, 0, 0, 0, 6, 1, 3, a0, a1, 0, 1]
    }

    #[test]
    fn each_request_is_answered_to_its_sender() {
        let mut s = Senders::default();
        // Two peers, the same transaction id and unit, other addresses.
        s.record(peer(1), &read(7, 1));
        s.record(peer(2), &read(7, 2));
        assert_eq!(port(s.answering(&read(7, 2))), Some(2));
        assert_eq!(port(s.answering(&read(7, 1))), Some(1));
        // Answered again: the same sender.
        assert_eq!(port(s.answering(&read(7, 1))), Some(1));
        // Never received.
        assert_eq!(port(s.answering(&read(8, 1))), None);
        assert_eq!(port(s.answering(&[])), None);
    }

    #[test]
    fn requests_alike_get_one_answer_each_in_order() {
        let mut s = Senders::default();
        s.record(peer(1), &read(1, 5));
        s.record(peer(2), &read(1, 5));
        s.record(peer(3), &read(1, 5));
        assert_eq!(port(s.answering(&read(1, 5))), Some(1));
        assert_eq!(port(s.answering(&read(1, 5))), Some(2));
        assert_eq!(port(s.answering(&read(1, 5))), Some(3));
        // All answered: the newest again.
        assert_eq!(port(s.answering(&read(1, 5))), Some(3));
    }

    #[test]
    fn a_reply_that_sees_the_header_only_matches_a_prefix() {
        let mut s = Senders::default();
        s.record(peer(1), &read(3, 10));
        s.record(peer(2), &read(4, 10));
        // modbus_reply_exception: header and function code.
        assert_eq!(port(s.answering(&read(4, 10)[..8])), Some(2));
        // A datagram longer than its request (bytes after it) still matches.
        let mut long = read(5, 1);
        let req = long.clone();
        long.extend_from_slice(&[9, 9]);
        s.record(peer(3), &long);
        assert_eq!(port(s.answering(&req)), Some(3));
    }

    #[test]
    fn the_table_holds_the_last_senders() {
        let mut s = Senders::default();
        for i in 0..(SENDERS as u16 + 10) {
            s.record(peer(i), &read(i, 0));
        }
        assert_eq!(s.recent.len(), SENDERS);
        // The first ten are forgotten, the others known.
        assert_eq!(port(s.answering(&read(9, 0))), None);
        assert_eq!(port(s.answering(&read(10, 0))), Some(10));
        assert_eq!(port(s.answering(&read(SENDERS as u16 + 9, 0))), Some(SENDERS as u16 + 9));
    }
}
