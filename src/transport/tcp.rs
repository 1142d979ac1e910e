//! TCP client connections (`modbus_new_tcp` over IPv4, `modbus_new_tcp_pi` over
//! whatever getaddrinfo returns), with libmodbus's socket options and a connect
//! bounded by the response timeout.

use std::ffi::CStr;
use std::mem::{size_of, zeroed};
use std::time::Duration;

use crate::error::{Error, Result};
use crate::proto::Diag;
use crate::transport::link::{TcpLink, TcpPiLink};
use crate::transport::{close, errno, last_error, set_option, wait};

unsafe extern "C" {
    /// POSIX `inet_pton` (not bound by the libc crate).
    pub fn inet_pton(af: libc::c_int, src: *const libc::c_char, dst: *mut libc::c_void) -> libc::c_int;
}

/// `IPTOS_LOWDELAY`.
const IPTOS_LOWDELAY: libc::c_int = 0x10;

/// TCP_NODELAY and low-delay TOS, as libmodbus sets them on IPv4 client sockets.
fn set_ipv4_options(fd: i32) -> Result<()> {
    set_option(fd, libc::IPPROTO_TCP, libc::TCP_NODELAY, 1)?;
    set_option(fd, libc::IPPROTO_IP, libc::IP_TOS, IPTOS_LOWDELAY)
}

/// A non-blocking stream socket of `family`, close-on-exec.
fn new_socket(family: i32, protocol: i32) -> Result<i32> {
    // SAFETY: plain system call with integer arguments.
    let fd = unsafe { libc::socket(family, libc::SOCK_STREAM | libc::SOCK_CLOEXEC | libc::SOCK_NONBLOCK, protocol) };
    if fd == -1 { Err(last_error()) } else { Ok(fd) }
}

/// How long a connect may wait for the handshake: `None`, not at all (the event-driven
/// client's: the connect goes on while the application's loop waits).
type ConnectWait = Option<Duration>;

/// Connects a non-blocking socket, waiting at most `timeout` for the handshake; with
/// no time to wait, `Ok(false)` when it is under way. A timeout gives ETIMEDOUT
/// (3.1.11+); any pending socket error gives ECONNREFUSED.
fn connect_within(fd: i32, addr: *const libc::sockaddr, len: libc::socklen_t, timeout: ConnectWait) -> Result<bool> {
    // SAFETY: `addr` points at a socket address of `len` bytes owned by the caller.
    let rc = unsafe { libc::connect(fd, addr, len) };
    if rc == 0 {
        return Ok(true);
    }
    if errno() != libc::EINPROGRESS {
        return Err(last_error());
    }
    let Some(timeout) = timeout else { return Ok(false) };
    if !wait(fd, libc::POLLOUT, Some(timeout))? {
        return Err(Error::TIMED_OUT);
    }
    connect_result(fd).map(|()| true)
}

/// The end of a connect under way (the socket was reported writable): its error,
/// if any, as ECONNREFUSED.
pub fn connect_result(fd: i32) -> Result<()> {
    let mut so_error: libc::c_int = 0;
    let mut optlen = size_of::<libc::c_int>() as libc::socklen_t;
    // SAFETY: `so_error` and `optlen` are live locals of the sizes getsockopt expects.
    let rc = unsafe {
        libc::getsockopt(fd, libc::SOL_SOCKET, libc::SO_ERROR, (&mut so_error as *mut libc::c_int).cast(), &mut optlen)
    };
    if rc == 0 && so_error != 0 {
        return Err(Error::CONN_REFUSED);
    }
    if rc == -1 { Err(last_error()) } else { Ok(()) }
}

/// Parses a dotted-quad IPv4 address.
fn parse_ipv4(ip: &CStr) -> Option<libc::in_addr> {
    // SAFETY: all-zero is a valid in_addr.
    let mut addr: libc::in_addr = unsafe { zeroed() };
    // SAFETY: `ip` is NUL-terminated and `addr` is a live in_addr for the result.
    let rc = unsafe { inet_pton(libc::AF_INET, ip.as_ptr(), (&mut addr as *mut libc::in_addr).cast()) };
    (rc == 1).then_some(addr)
}

/// Why a connect failed: before a connection was tried (the context keeps its
/// descriptor, as libmodbus), or in the trying (the context has none afterwards).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConnectError {
    Before(Error),
    During(Error),
}

/// A connected client socket: `blocking` when it could be switched to blocking (see
/// the context's `ClientSocket`); otherwise it stays non-blocking and is used as
/// libmodbus uses its socket.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Connected {
    pub fd: i32,
    pub blocking: bool,
    /// The connect goes on (no time to wait was given): [`connect_result`] when the
    /// socket is writable, then [`made_blocking`].
    pub in_progress: bool,
}

/// `modbus_connect` for a TCP (IPv4) context, the handshake bounded by `timeout`
/// (`None`: started only).
pub fn connect_ipv4(
    link: &TcpLink,
    timeout: ConnectWait,
    diag: &mut dyn Diag,
) -> core::result::Result<Connected, ConnectError> {
    let (ip, port) = (&link.ip, link.port);
    let fd = new_socket(libc::AF_INET, 0).map_err(ConnectError::Before)?;
    if let Err(e) = set_ipv4_options(fd) {
        close(fd);
        return Err(ConnectError::Before(e));
    }
    diag.out(format_args!("Connecting to {}:{}\n", ip.to_string_lossy(), port));
    let Some(in_addr) = parse_ipv4(ip) else {
        diag.err(format_args!("Invalid IP address: {}\n", ip.to_string_lossy()));
        close(fd);
        return Err(ConnectError::Before(Error::UNCHANGED));
    };
    // SAFETY: all-zero is a valid sockaddr_in.
    let mut sa: libc::sockaddr_in = unsafe { zeroed() };
    sa.sin_family = libc::AF_INET as libc::sa_family_t;
    sa.sin_port = (port as u16).to_be();
    sa.sin_addr = in_addr;
    let len = size_of::<libc::sockaddr_in>() as libc::socklen_t;
    match connect_within(fd, (&sa as *const libc::sockaddr_in).cast(), len, timeout) {
        Ok(true) => Ok(made_blocking(fd)),
        Ok(false) => Ok(Connected { fd, blocking: false, in_progress: true }),
        Err(e) => {
            close(fd);
            Err(ConnectError::During(e))
        }
    }
}

/// Owns a getaddrinfo result list.
pub struct AddrInfo(*mut libc::addrinfo);

impl AddrInfo {
    /// Resolves `node`/`service` for stream sockets with the given flags.
    pub fn lookup(node: Option<&CStr>, service: &CStr, flags: i32) -> core::result::Result<AddrInfo, i32> {
        AddrInfo::lookup_of(node, service, flags, libc::SOCK_STREAM)
    }

    /// Resolves `node`/`service` for sockets of `socktype` with the given flags.
    pub fn lookup_of(
        node: Option<&CStr>,
        service: &CStr,
        flags: i32,
        socktype: i32,
    ) -> core::result::Result<AddrInfo, i32> {
        // SAFETY: all-zero is a valid addrinfo hints value.
        let mut hints: libc::addrinfo = unsafe { zeroed() };
        hints.ai_flags = flags;
        hints.ai_family = libc::AF_UNSPEC;
        hints.ai_socktype = socktype;
        let mut list = std::ptr::null_mut();
        let node_ptr = node.map_or(std::ptr::null(), CStr::as_ptr);
        // SAFETY: the strings are NUL-terminated or NULL; `list` receives the result.
        let rc = unsafe { libc::getaddrinfo(node_ptr, service.as_ptr(), &hints, &mut list) };
        if rc != 0 { Err(rc) } else { Ok(AddrInfo(list)) }
    }

    /// The entries in order.
    pub fn iter(&self) -> impl Iterator<Item = &libc::addrinfo> {
        // SAFETY: each `ai_next` is NULL or points at the next entry of the list we own.
        std::iter::successors(unsafe { self.0.as_ref() }, |ai| unsafe { ai.ai_next.as_ref() })
    }
}

impl Drop for AddrInfo {
    fn drop(&mut self) {
        if !self.0.is_null() {
            // SAFETY: the list came from getaddrinfo and is freed exactly once.
            unsafe { libc::freeaddrinfo(self.0) };
        }
    }
}

/// The text of a getaddrinfo error code.
pub fn gai_error(code: i32) -> String {
    // SAFETY: gai_strerror returns a pointer to a static NUL-terminated string.
    unsafe { CStr::from_ptr(libc::gai_strerror(code)) }.to_string_lossy().into_owned()
}

/// `modbus_connect` for a protocol-independent TCP context: the first address that
/// connects wins (`None`: the first whose connect starts).
pub fn connect_pi(
    link: &TcpPiLink,
    timeout: ConnectWait,
    diag: &mut dyn Diag,
) -> core::result::Result<Connected, ConnectError> {
    let (node, service) = (&link.node, &link.service);
    let node_arg = (!node.is_empty()).then_some(node.as_c_str());
    let list = match AddrInfo::lookup(node_arg, service, libc::AI_ADDRCONFIG) {
        Ok(list) => list,
        Err(code) => {
            diag.err(format_args!("Error returned by getaddrinfo: {}\n", gai_error(code)));
            return Err(ConnectError::Before(Error::CONN_REFUSED));
        }
    };
    let mut last = Error::CONN_REFUSED;
    for ai in list.iter() {
        let fd = match new_socket(ai.ai_family, ai.ai_protocol) {
            Ok(fd) => fd,
            Err(e) => {
                last = e;
                continue;
            }
        };
        if ai.ai_family == libc::AF_INET
            && let Err(e) = set_ipv4_options(fd)
        {
            close(fd);
            last = e;
            continue;
        }
        diag.out(format_args!("Connecting to [{}]:{}\n", node.to_string_lossy(), service.to_string_lossy()));
        match connect_within(fd, ai.ai_addr, ai.ai_addrlen, timeout) {
            Ok(true) => return Ok(made_blocking(fd)),
            Ok(false) => return Ok(Connected { fd, blocking: false, in_progress: true }),
            Err(e) => {
                close(fd);
                last = e;
            }
        }
    }
    Err(ConnectError::During(last))
}

/// A freshly connected socket, switched to blocking when the kernel lets it.
pub fn made_blocking(fd: i32) -> Connected {
    let mut nonblocking: libc::c_int = 0;
    // SAFETY: FIONBIO reads one live c_int.
    let rc = unsafe { libc::ioctl(fd, libc::FIONBIO, &mut nonblocking as *mut libc::c_int) };
    Connected { fd, blocking: rc == 0, in_progress: false }
}

/// Sets `SO_RCVTIMEO` (0 = none).
pub fn set_receive_timeout(fd: i32, timeout: Duration) -> Result<()> {
    let tv = libc::timeval {
        tv_sec: timeout.as_secs() as libc::time_t,
        tv_usec: timeout.subsec_micros() as libc::suseconds_t,
    };
    set_option(fd, libc::SOL_SOCKET, libc::SO_RCVTIMEO, tv)
}

/// `modbus_close` for TCP: shut down both directions, then close.
pub fn close_socket(fd: i32) {
    // SAFETY: shutdown on a descriptor number has no memory preconditions.
    unsafe { libc::shutdown(fd, libc::SHUT_RDWR) };
    close(fd);
}
