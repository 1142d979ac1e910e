//! The line a context talks over: how to open it (its [`Link`] settings and, for
//! Modbus/TCP Security, its [`Tls`] settings) and, once open, the descriptor with
//! what it is: a serial line, a stream socket, or a TLS session on one.
//!
//! Every system call a context makes on its descriptor goes through a [`Line`]: it
//! opens, accepts, adopts and closes descriptors, and executes the receive machine's
//! steps (peek, wait, read), writes, flushes and drives the RTS line. The driver
//! (`engine`) drives steps on a line and never asks which kind it is; a new kind of
//! line (UDP next) is a new [`Kind`] here, not new branches there. The line is also
//! the only writer of the stop state's copy of the descriptor ([`Stop::set_fd`]), so
//! that a close from a signal handler or another thread always acts on the
//! descriptor the line has.
//!
//! TLS sessions belong to their socket: the current socket's session lives in the
//! line; a server that serves many clients on one context (switching with
//! `modbus_set_socket`) parks the others' sessions, keyed by descriptor number and
//! socket cookie, so that a reused number never meets an old session. A session
//! whose peer has gone is dropped when its socket stops being current.

use std::ffi::CStr;
use std::ops::Range;
use std::sync::Arc;
use std::time::Duration;

use super::link::{Link, RTU_RTS_NONE, RTU_RTS_UP, RtsHook, RtuLink};
use super::room::Room;
use super::tcp::{self, ConnectError};
use super::tls::{self, Session, Tls};
use super::udp::{self, Datagram};
use super::{Ready, rtu};
use crate::error::{EMBTLS, Error, Result};
use crate::proto::Diag;
use crate::proto::frame::{MAX_ADU_LENGTH, MsgKind};
use crate::proto::session::Timeout;
use crate::proto::session::receive::{LineCaps, ReadHow};
use crate::stop::Stop;

/// Below this response timeout (in microseconds, below a second) a confirmation
/// never reads under `SO_RCVTIMEO`, which could fire too late (see [`Line::read`]).
const RCVTIMEO_MIN_RESPONSE_USEC: u32 = 200_000;

/// A TCP client socket the context connected itself. Unlike libmodbus's, it is
/// blocking after the connect, so that the first wait of a confirmation can be the
/// read itself, bounded by `SO_RCVTIMEO` (one system call instead of a poll and a
/// read); its sends pass `MSG_DONTWAIT`, so that they never block, as on libmodbus's
/// non-blocking socket. A descriptor the application hands over is never changed.
#[derive(Clone, Copy, Debug, Default)]
struct ClientSocket {
    /// The response timeout the socket's `SO_RCVTIMEO` was last derived from.
    rcvtimeo_for: Option<Timeout>,
}

/// What the line's descriptors are (fixed by the settings; one byte, so that every
/// operation's dispatch is one comparison).
#[derive(Clone, Copy, PartialEq, Eq)]
enum Kind {
    /// A serial line.
    Serial,
    /// A stream socket.
    Socket,
    /// A socket of a Modbus/TCP Security context, with its session in
    /// [`Held::session`] (none: a socket handed over that this context did not
    /// connect or accept, which cannot carry Modbus/TCP Security: EMBTLS).
    Tls,
    /// A UDP socket (Modbus/UDP): one message per datagram, read whole into
    /// [`Held::datagram`].
    Datagram,
}

/// What the line knows of its current descriptor beyond its kind.
#[derive(Default)]
struct Held {
    /// A serial line the context opened (with `O_NONBLOCK`): a read never blocks.
    nonblocking: bool,
    /// A socket the context connected itself.
    client: Option<ClientSocket>,
    /// The TLS session on the socket.
    session: Option<Box<Session>>,
    /// A connect under way (the event-driven client's): [`Line::connect_done`] ends it.
    connecting: bool,
    /// A TLS handshake under way without waiting ([`Line::handshake_step`]): a
    /// client's, or a runner's accepted client's.
    handshake: Option<Box<Handshake>>,
    /// Writes are queued here, to go out together in [`Line::send_queued`] (a
    /// server runner's client: the answers to every request of one read leave in
    /// one system call, and a client that does not read blocks nobody).
    queue: Option<Vec<u8>>,
    /// A UDP socket's datagram being read, and its sender.
    datagram: Option<Box<Datagram>>,
    /// A UDP socket connected to its one peer (a client's).
    connected: bool,
}

/// A TLS handshake: the connection, and a server's record cut.
struct Handshake {
    conn: tls::Conn,
    cut: Option<tls::RecordCut>,
}

/// The end of a TLS handshake a line takes.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Side {
    Client,
    Server,
}

/// The RTS sequence around a write on a serial line (`modbus_rtu_set_rts`): the
/// driver runs it, since the application's callback runs with the context unlocked.
#[derive(Clone)]
pub struct RtsSequence {
    /// The level that means "sending".
    pub up: bool,
    /// Microseconds before and after the frame.
    pub delay_us: i64,
    /// Microseconds one character takes on the line.
    pub onebyte_us: i64,
    /// The application's callback, or `None` for the built-in ioctl ([`Line::set_rts`]).
    pub hook: Option<RtsHook>,
}

/// A context's line (see the module documentation).
pub struct Line {
    settings: Link,
    security: Option<Box<Tls>>,
    kind: Kind,
    fd: i32,
    held: Held,
    stop: Arc<Stop>,
    /// Counts the descriptors the line had: a poller that registered the line's
    /// descriptor knows whether it is still the one it registered (a closed number
    /// may come back for another socket).
    generation: u32,
    /// The socket the application's `modbus_tcp_listen` made for this line, with its
    /// cookie ([`Line::listened`]).
    listener: Option<(i32, u64)>,
}

impl Line {
    /// A line of these settings, not open.
    pub fn new(settings: Link, stop: Arc<Stop>) -> Line {
        let kind = if matches!(settings, Link::Rtu(_)) { Kind::Serial } else { Kind::Socket };
        Line { settings, security: None, kind, fd: -1, held: Held::default(), stop, generation: 0, listener: None }
    }

    /// Makes the line one of Modbus/TCP Security (a new context's).
    pub fn secure(&mut self) {
        self.security = Some(Box::default());
        self.kind = Kind::Tls;
    }

    /// Makes the line one of Modbus/UDP (a new context's).
    pub fn datagrams(&mut self) {
        self.kind = Kind::Datagram;
    }

    /// A line of Modbus/UDP.
    pub fn is_datagram(&self) -> bool {
        self.kind == Kind::Datagram
    }

    /// Drops what is left of the datagram being read (a message ends with its
    /// datagram); nothing on other lines.
    pub fn discard(&mut self) {
        if let Some(d) = self.held.datagram.as_deref_mut() {
            d.discard();
        }
    }

    /// On a server's UDP socket: the sender of the last datagram read.
    pub fn peer(&self) -> Option<udp::Peer> {
        self.held.datagram.as_deref().and_then(Datagram::peer)
    }

    /// On a server's UDP socket: the next answer goes to `peer`.
    pub fn set_peer(&mut self, peer: udp::Peer) {
        if let Some(d) = self.held.datagram.as_deref_mut() {
            d.set_peer(peer);
        }
    }

    /// On a server's UDP socket: the next write is the reply to the request `req`
    /// (as received, header first) and goes to that request's sender, whatever came
    /// since (see `udp::Senders`); EDESTADDRREQ when `req` is none of the last
    /// `udp::SENDERS` datagrams received. Nothing on other lines.
    #[inline]
    pub fn answering(&mut self, req: &[u8]) -> Result<()> {
        if self.kind != Kind::Datagram {
            return Ok(());
        }
        match self.held.datagram.as_deref_mut() {
            Some(d) if !self.held.connected => d.answering(req),
            _ => Ok(()),
        }
    }

    /// A stream socket (plain or TLS): a connection of its own per client.
    pub fn is_stream(&self) -> bool {
        matches!(self.kind, Kind::Socket | Kind::Tls)
    }

    /// `modbus_tcp_listen` (`pi`: `modbus_tcp_pi_listen`): a socket listening on the
    /// line's address for up to `nb_connection` pending clients, or, on a Modbus/UDP
    /// line, a socket bound to it. The caller owns it.
    pub fn listen(&self, pi: bool, nb_connection: i32, debug: bool, diag: &mut dyn Diag) -> Result<i32> {
        if self.kind == Kind::Datagram {
            if pi != matches!(self.settings, Link::TcpPi(_)) {
                return Err(Error::INVALID);
            }
            return udp::open(&self.settings, true, diag);
        }
        if pi {
            super::listen::listen_pi(&self.settings, nb_connection, debug, diag)
        } else {
            super::listen::listen_ipv4(&self.settings, nb_connection, diag)
        }
    }

    /// A server's UDP socket, bound to the line's address, becomes the line's: it
    /// answers each request to its sender.
    pub fn bind(&mut self, diag: &mut dyn Diag) -> Result<i32> {
        let fd = udp::open(&self.settings, true, diag)?;
        self.install(fd, Held { datagram: Some(Box::new(Datagram::serving())), ..Held::default() });
        Ok(fd)
    }

    /// Remembers `fd` as the socket `modbus_tcp_listen` (or `modbus_tcp_pi_listen`)
    /// made for this line, which the caller owns: a server runner made from the
    /// context serves on it rather than binding the address again.
    pub fn listened(&mut self, fd: i32) {
        self.listener = Some((fd, super::socket_cookie(fd)));
    }

    /// The socket [`Line::listened`] remembers, while it is still that socket (open,
    /// its number not reused for another: the socket's cookie tells) and, on a
    /// stream line, listening.
    pub fn listener(&self) -> Option<i32> {
        let (fd, cookie) = self.listener?;
        let same = cookie != 0 && super::socket_cookie(fd) == cookie;
        (same && (self.kind == Kind::Datagram || super::listen::is_listening(fd))).then_some(fd)
    }

    /// The descriptor, -1 when none.
    #[inline]
    pub fn fd(&self) -> i32 {
        self.fd
    }

    /// The settings the line opens from (the listening calls read them too).
    pub fn settings(&self) -> &Link {
        &self.settings
    }

    /// A serial line's settings; `None` for a TCP context.
    pub fn serial(&self) -> Option<&RtuLink> {
        match &self.settings {
            Link::Rtu(r) => Some(r),
            _ => None,
        }
    }

    pub fn serial_mut(&mut self) -> Option<&mut RtuLink> {
        match &mut self.settings {
            Link::Rtu(r) => Some(r),
            _ => None,
        }
    }

    /// The line is a bus others share (a serial line): a server there sees requests
    /// for other slaves, and their answers.
    pub fn shared_bus(&self) -> bool {
        matches!(self.settings, Link::Rtu(_))
    }

    /// The line is a stream socket, on which a server may listen and accept.
    pub fn accepts_clients(&self) -> bool {
        matches!(self.settings, Link::Tcp(_) | Link::TcpPi(_))
    }

    /// Modbus/TCP Security's settings; `None` for any other context.
    pub fn security(&self) -> Option<&Tls> {
        self.security.as_deref()
    }

    pub fn security_mut(&mut self) -> Option<&mut Tls> {
        self.security.as_deref_mut()
    }

    /// A Modbus/TCP Security context with an authorization callback.
    #[inline]
    pub fn authorizes(&self) -> bool {
        self.security.as_deref().is_some_and(|t| t.authorize.is_some())
    }

    /// The application's authorization callback, on a Modbus/TCP Security context
    /// that has one.
    pub fn authorizer(&self) -> Option<tls::Authorize> {
        self.security.as_deref().and_then(|t| t.authorize.clone())
    }

    /// The role in the certificate of the current socket's peer.
    pub fn peer_role(&self) -> Option<&CStr> {
        self.held.session.as_deref().and_then(Session::role)
    }

    /// Plaintext received on the current socket and not taken yet (0 without a
    /// session).
    pub fn pending(&self) -> usize {
        if let Some(d) = self.held.datagram.as_deref() {
            return d.pending();
        }
        self.held.session.as_deref().map_or(0, Session::pending)
    }

    /// What the line can do for a receive of `kind` (a confirmation reads under a
    /// kernel timeout derived from `response` when the socket allows it).
    #[inline]
    pub fn caps(&self, kind: MsgKind, response: Timeout) -> LineCaps {
        let socket = self.kind != Kind::Serial;
        LineCaps {
            socket,
            // A datagram holds a whole message: a read past its end would take the
            // next datagram's bytes as this message's rest.
            reads_without_waiting: (socket && self.kind != Kind::Datagram) || self.held.nonblocking,
            timed_reads: kind == MsgKind::Confirmation
                && self.held.client.is_some()
                && (response.sec > 0 || response.usec >= RCVTIMEO_MIN_RESPONSE_USEC),
        }
    }

    /// Makes `fd` the line's descriptor, with what the line knows of it; what the old
    /// one had is parked (a live TLS session of another socket) or dropped. The stop
    /// state follows.
    fn install(&mut self, fd: i32, held: Held) {
        let old = std::mem::replace(&mut self.held, held);
        if let (Some(session), Some(security)) = (old.session, self.security.as_deref_mut()) {
            if self.fd >= 0 && self.fd != fd && !session.readable_end() {
                security.park(self.fd, session);
            }
        }
        self.fd = fd;
        self.generation = self.generation.wrapping_add(1);
        self.stop.set_fd(fd);
    }

    /// How many descriptors the line had, this one included (see the field).
    pub fn generation(&self) -> u32 {
        self.generation
    }

    /// `modbus_set_socket`: `fd` (-1: none) as a descriptor the context did not open.
    /// On a Modbus/TCP Security context, the session of a socket this context
    /// accepted or connected earlier comes back with its socket.
    pub fn adopt(&mut self, fd: i32) {
        let mut held = Held::default();
        if let Some(security) = self.security.as_deref_mut() {
            if fd >= 0 {
                // The current session when it is this very socket's, else one parked.
                let current = if self.fd == fd {
                    self.held.session.take().filter(|s| s.cookie() == super::socket_cookie(fd))
                } else {
                    None
                };
                held.session = current.or_else(|| security.unpark(fd));
            }
        }
        if self.kind == Kind::Datagram && fd >= 0 {
            // Connected to a peer (a client's socket handed over with `modbus_set_socket`),
            // rather than bound and answering each sender.
            held.connected = udp::Peer::of_socket(fd).is_some();
            held.datagram = Some(Box::new(if held.connected { Datagram::default() } else { Datagram::serving() }));
        }
        self.install(fd, held);
    }

    /// `fd` as a descriptor the context opened itself: a serial line opened
    /// non-blocking, or a client socket made blocking (see [`ClientSocket`]). For the
    /// driver's tests; [`Line::open`] does this for real lines.
    pub fn adopt_own(&mut self, fd: i32) {
        let serial = self.kind == Kind::Serial;
        let client = (!serial).then(ClientSocket::default);
        self.install(fd, Held { nonblocking: serial, client, ..Held::default() });
    }

    /// Gives up the descriptor without closing it (for the caller to close): -1 from
    /// now on, with nothing of the old descriptor kept.
    pub fn abandon(&mut self) -> i32 {
        let fd = self.fd;
        self.held = Held::default();
        self.fd = -1;
        self.generation = self.generation.wrapping_add(1);
        self.stop.set_fd(-1);
        fd
    }

    /// `modbus_connect`: opens the line from its settings (serial: open and
    /// configure; TCP: connect within `timeout`, then the TLS handshake, bounded by
    /// it too, on a Modbus/TCP Security context).
    pub fn open(&mut self, timeout: Duration, debug: bool, diag: &mut dyn Diag) -> Result<()> {
        if self.kind == Kind::Datagram {
            let fd = udp::open(&self.settings, false, diag)?;
            let held = Held {
                client: Some(ClientSocket::default()),
                datagram: Some(Box::default()),
                connected: true,
                ..Held::default()
            };
            self.install(fd, held);
            return Ok(());
        }
        let connected = match &mut self.settings {
            Link::Rtu(link) => {
                let fd = rtu::open(link, diag)?;
                let configured = rtu::configure(fd, link, diag);
                if let Some(saved) = link.saved_termios.as_deref() {
                    self.stop.save_line(saved);
                }
                if let Err(e) = configured {
                    super::close(fd);
                    self.install(-1, Held::default());
                    return Err(e);
                }
                self.install(fd, Held { nonblocking: true, ..Held::default() });
                return Ok(());
            }
            Link::Tcp(link) => tcp::connect_ipv4(link, Some(timeout), diag),
            Link::TcpPi(link) => tcp::connect_pi(link, Some(timeout), diag),
        };
        match connected {
            Ok(c) => {
                let client = c.blocking.then(ClientSocket::default);
                self.install(c.fd, Held { client, ..Held::default() });
                if self.kind == Kind::Tls { self.handshake(Side::Client, timeout, debug, diag) } else { Ok(()) }
            }
            Err(ConnectError::Before(e)) => Err(e),
            Err(ConnectError::During(e)) => {
                self.install(-1, Held::default());
                Err(e)
            }
        }
    }

    /// The event-driven client's open: a serial line opens as [`Line::open`] does; a
    /// TCP connect is started and goes on without waiting (`Ok(false)`: writable
    /// when it has ended, then [`Line::connect_done`]).
    pub fn open_started(&mut self, timeout: Duration, debug: bool, diag: &mut dyn Diag) -> Result<bool> {
        if self.kind == Kind::Datagram {
            return self.open(timeout, debug, diag).map(|()| true);
        }
        let started = match &mut self.settings {
            Link::Rtu(_) => return self.open(timeout, debug, diag).map(|()| true),
            Link::Tcp(link) => tcp::connect_ipv4(link, None, diag),
            Link::TcpPi(link) => tcp::connect_pi(link, None, diag),
        };
        match started {
            Ok(c) if c.in_progress => {
                self.install(c.fd, Held { connecting: true, ..Held::default() });
                Ok(false)
            }
            Ok(c) => {
                let client = c.blocking.then(ClientSocket::default);
                self.install(c.fd, Held { client, ..Held::default() });
                self.begin_client_handshake().map(|()| true)
            }
            Err(ConnectError::Before(e)) => Err(e),
            Err(ConnectError::During(e)) => {
                self.install(-1, Held::default());
                Err(e)
            }
        }
    }

    /// A connect of [`Line::open_started`] is under way.
    pub fn connecting(&self) -> bool {
        self.held.connecting
    }

    /// The end of a connect under way, once its socket is writable (or its time is up:
    /// `timed_out`). A failure closes the socket; on a Modbus/TCP Security context the
    /// handshake starts ([`Line::handshake_step`]).
    pub fn connect_done(&mut self, timed_out: bool) -> Result<()> {
        let fd = self.fd;
        let ended = if timed_out { Err(Error::TIMED_OUT) } else { tcp::connect_result(fd) };
        if let Err(e) = ended {
            let fd = self.abandon();
            super::close(fd);
            return Err(e);
        }
        let c = tcp::made_blocking(fd);
        let client = c.blocking.then(ClientSocket::default);
        self.held = Held { client, ..Held::default() };
        self.begin_client_handshake()
    }

    /// `modbus_tcp_accept`: `fd`, just accepted, becomes the line's socket; on a
    /// Modbus/TCP Security context the client is served only once it has
    /// authenticated (the handshake, bounded by `timeout`; a failure closes its
    /// socket).
    pub fn accepted(&mut self, fd: i32, timeout: Duration, debug: bool, diag: &mut dyn Diag) -> Result<()> {
        self.install(fd, Held::default());
        match self.security.as_deref_mut() {
            Some(security) => {
                // A session parked under this number was another socket's.
                security.forget(fd);
                self.handshake(Side::Server, timeout, debug, diag)
            }
            None => Ok(()),
        }
    }

    /// The TLS handshake on the line's socket (just connected or accepted), bounded
    /// by `timeout`; the session is kept with the socket. A failure closes the socket
    /// and leaves the line without one (unless the context is being closed under the
    /// call: the closer does that).
    fn handshake(&mut self, side: Side, timeout: Duration, debug: bool, diag: &mut dyn Diag) -> Result<()> {
        let fd = self.fd;
        let deadline = Some(super::now() + timeout);
        let stop = Arc::clone(&self.stop);
        let done = self.begin_handshake(side).and_then(|mut h| {
            tls::handshake(fd, &mut h.conn, h.cut.as_mut(), deadline, &|| stop.stopping())?;
            Ok(h)
        });
        self.end_handshake(done, debug, diag)
    }

    /// A connection of the context's TLS settings on the line's socket, about to
    /// shake hands.
    fn begin_handshake(&mut self, side: Side) -> Result<Handshake> {
        let host = match &self.settings {
            Link::Tcp(l) => l.ip.to_string_lossy().into_owned(),
            Link::TcpPi(l) => l.node.to_string_lossy().into_owned(),
            Link::Rtu(_) => return Err(Error::INVALID),
        };
        let Some(security) = self.security.as_deref_mut() else { return Err(Error::INVALID) };
        let conn = match side {
            Side::Client => security.settings.connect(&host),
            Side::Server => security.settings.accept(),
        }?;
        // A server reads record by record (see `tls::RecordCut`); the handshake's
        // flights go out at once.
        let _ = super::set_option(self.fd, libc::IPPROTO_TCP, libc::TCP_NODELAY, 1 as libc::c_int);
        let cut = (side == Side::Server).then(tls::RecordCut::default);
        Ok(Handshake { conn, cut })
    }

    /// The end of a handshake: its session kept with the socket, or the socket
    /// closed.
    fn end_handshake(&mut self, done: Result<Handshake>, debug: bool, diag: &mut dyn Diag) -> Result<()> {
        let fd = self.fd;
        let done = done.and_then(|Handshake { conn, .. }| {
            let described = debug.then(|| tls::describe_session(&conn));
            Ok((Box::new(Session::new(conn, fd)?), described))
        });
        match done {
            Ok((session, described)) => {
                if let Some(described) = described {
                    let role = session.role().map_or_else(|| "none".to_owned(), |r| format!("{r:?}"));
                    diag.out(format_args!("TLS handshake done: {described}, peer role {role}\n"));
                }
                self.held.session = Some(session);
                Ok(())
            }
            Err(e) => {
                if debug {
                    diag.err(format_args!("ERROR TLS handshake: {}\n", super::describe(e.0)));
                }
                if !self.stop.stopping() {
                    let fd = self.abandon();
                    tcp::close_socket(fd);
                }
                Err(e)
            }
        }
    }

    /// On a Modbus/TCP Security line just connected without waiting: the client
    /// handshake starts ([`Line::handshake_step`] carries it on).
    fn begin_client_handshake(&mut self) -> Result<()> {
        if self.kind != Kind::Tls {
            return Ok(());
        }
        self.start_handshake(Side::Client)
    }

    /// A handshake of `side` starts on the line's socket, to be carried on by
    /// [`Line::handshake_step`]; a failure to start it closes the socket.
    fn start_handshake(&mut self, side: Side) -> Result<()> {
        match self.begin_handshake(side) {
            Ok(h) => {
                self.held.handshake = Some(Box::new(h));
                Ok(())
            }
            Err(e) => {
                let fd = self.abandon();
                tcp::close_socket(fd);
                Err(e)
            }
        }
    }

    /// A line for one client of this listening line (a server runner's): the same
    /// link settings and, on a Modbus/TCP Security line, the server configuration
    /// (EMBTLSCONFIG without a certificate, key and CA) and the authorization
    /// callback. Not open: [`Line::accept_started`] gives it its socket.
    pub fn serving(&mut self, stop: Arc<Stop>) -> Result<Line> {
        let settings = match &self.settings {
            Link::Tcp(l) => Link::Tcp(super::link::TcpLink { ip: l.ip.clone(), port: l.port }),
            Link::TcpPi(l) => Link::TcpPi(super::link::TcpPiLink { node: l.node.clone(), service: l.service.clone() }),
            Link::Rtu(_) => return Err(Error::INVALID),
        };
        let mut line = Line::new(settings, stop);
        if let Some(security) = self.security.as_deref_mut() {
            let config = security.settings.server_config()?;
            let mut tls = Tls::default();
            tls.settings = tls::TlsSettings::serving(config);
            tls.authorize = security.authorize.clone();
            line.security = Some(Box::new(tls));
            line.kind = Kind::Tls;
        }
        Ok(line)
    }

    /// A socket just accepted (non-blocking) becomes the line's, with its writes
    /// queued ([`Line::send_queued`]); on a Modbus/TCP Security line the server
    /// handshake starts, carried on by [`Line::handshake_step`] without waiting. A
    /// failure to start it closes the socket.
    pub fn accept_started(&mut self, fd: i32) -> Result<()> {
        self.install(fd, Held { queue: Some(Vec::new()), ..Held::default() });
        if self.kind != Kind::Tls {
            return Ok(());
        }
        self.start_handshake(Side::Server)
    }

    /// Bytes queued and not sent yet (see [`Line::accept_started`]).
    pub fn queued(&self) -> usize {
        let plain = self.held.queue.as_ref().map_or(0, Vec::len);
        plain + self.held.session.as_deref().map_or(0, |s| usize::from(s.wants_write()))
    }

    /// Sends what is queued, as far as the socket takes it without waiting: true when
    /// all is out, false when the rest waits for the socket to be writable.
    pub fn send_queued(&mut self) -> Result<bool> {
        let fd = self.fd;
        let Some(queue) = self.held.queue.as_mut() else { return Ok(true) };
        if self.kind == Kind::Tls {
            let Some(session) = self.held.session.as_deref_mut() else { return Err(no_session(fd)) };
            return session.send_without_waiting(fd, queue);
        }
        while !queue.is_empty() {
            match super::send(fd, queue, libc::MSG_DONTWAIT) {
                Ok(n) => {
                    queue.drain(..n);
                }
                Err(e) if e.0 == libc::EAGAIN => return Ok(false),
                Err(e) if e.0 == libc::EINTR => {}
                Err(e) => return Err(e),
            }
        }
        if queue.capacity() > 4 * MAX_ADU_LENGTH {
            // A burst's room is given back: an idle client holds little.
            *queue = Vec::new();
        }
        Ok(true)
    }

    /// A handshake is under way without waiting (the event-driven client's, a
    /// runner's client's).
    pub fn handshaking(&self) -> bool {
        self.held.handshake.is_some()
    }

    /// The handshake under way, as far as it goes without waiting: `Ok(None)` when it
    /// is done (the session is the line's), `Ok(Some(events))` when it goes on once
    /// the socket is ready for `events`. A failure, or `timed_out`, closes the socket.
    pub fn handshake_step(&mut self, timed_out: bool, debug: bool, diag: &mut dyn Diag) -> Result<Option<i16>> {
        let Some(mut h) = self.held.handshake.take() else { return Ok(None) };
        let step =
            if timed_out { Err(Error::TIMED_OUT) } else { tls::handshake_step(self.fd, &mut h.conn, h.cut.as_mut()) };
        match step {
            Ok(tls::Progress::Wants(events)) => {
                self.held.handshake = Some(h);
                Ok(Some(events))
            }
            Ok(tls::Progress::Done) => self.end_handshake(Ok(*h), debug, diag).map(|()| None),
            Err(e) => self.end_handshake(Err(e), debug, diag).map(|()| None),
        }
    }

    /// `modbus_close`: a serial line gets the settings it had before back, a TLS
    /// session sends close_notify; the descriptor is closed.
    pub fn close(&mut self) {
        if self.fd < 0 {
            return;
        }
        if let Some(session) = self.held.session.as_deref_mut() {
            session.close(self.fd);
        }
        if let Link::Rtu(link) = &self.settings {
            self.stop.forget_line();
            let saved = link.saved_termios.as_deref().copied();
            let fd = self.abandon();
            rtu::close_line(fd, saved);
        } else {
            let fd = self.abandon();
            tcp::close_socket(fd);
        }
    }

    /// Looks at what has arrived without taking it (a socket server's first step):
    /// into `room`, waiting for it when `block`.
    #[inline]
    pub fn peek(&mut self, room: &mut [u8], block: bool) -> Result<usize> {
        if self.kind == Kind::Tls {
            return tls_peek(self.fd, &mut self.held.session, room, block);
        }
        if self.kind == Kind::Datagram {
            return datagram_peek(self.fd, &mut self.held, room, block);
        }
        let flags = libc::MSG_PEEK | if block { 0 } else { libc::MSG_DONTWAIT };
        super::recv(self.fd, room, flags)
    }

    /// One read into `room`, as the machine says: when the line is ready (it may
    /// block), of what is queued (never blocks), or within the kernel timeout set from
    /// a response timeout on a client socket the context connected (one system call
    /// where a wait and a read were two: `SO_RCVTIMEO` runs on the kernel's timer
    /// wheel, which may fire up to an eighth of the time plus a tick or two late, so
    /// it is set to 3/4 of the response timeout; when it fires (EAGAIN), the machine
    /// waits for the rest, which therefore ends when libmodbus's `select` would).
    #[inline]
    pub fn read(&mut self, room: &mut [u8], how: ReadHow, debug: bool) -> Result<usize> {
        let fd = self.fd;
        match self.kind {
            Kind::Socket => match how {
                ReadHow::Ready => super::recv(fd, room, 0),
                ReadHow::Queued => super::recv(fd, room, libc::MSG_DONTWAIT),
                ReadHow::Within(timeout) => read_within(fd, &mut self.held.client, room, timeout, debug),
            },
            // A serial line read when a readiness driver only thought it readable
            // (a hint given without a wait): a terminal read empty is nothing there
            // yet (VMIN 0), not a line that ended, as a socket's EAGAIN.
            Kind::Serial => match super::read(fd, room) {
                Ok(0) if matches!(how, ReadHow::Queued) => Err(Error(libc::EAGAIN)),
                r => r,
            },
            Kind::Tls => {
                let all = 0..room.len();
                tls_read(fd, &mut self.held, room, all, how)
            }
            Kind::Datagram => datagram_read(fd, &mut self.held, room, how),
        }
    }

    /// [`Line::read`] into `msg()[range]` of a message's room (on a TLS session, with
    /// the bytes around it that [`Room::around`] gives).
    #[inline]
    pub fn read_message(
        &mut self,
        msg: &mut Room<'_>,
        range: Range<usize>,
        how: ReadHow,
        debug: bool,
    ) -> Result<usize> {
        if self.kind == Kind::Tls {
            let (whole, at) = msg.around(range);
            return tls_read(self.fd, &mut self.held, whole, at, how);
        }
        self.read(&mut msg.msg()[range], how, debug)
    }

    /// Takes the whole message a [`Line::peek`] showed, `room` long: one read of what
    /// is there (on a TLS session, of the plaintext the peek showed).
    #[inline]
    pub fn take(&mut self, room: &mut [u8]) -> Result<usize> {
        match self.kind {
            Kind::Socket => super::recv(self.fd, room, 0),
            Kind::Tls => match self.held.session.as_deref_mut() {
                Some(session) => session.take(room),
                None => Err(no_session(self.fd)),
            },
            Kind::Datagram => {
                let n = self.read(room, ReadHow::Ready, false);
                // The message is the datagram: what follows it in there is no message.
                self.held.datagram.as_deref_mut().map(Datagram::discard);
                n
            }
            _ => self.read(room, ReadHow::Ready, false),
        }
    }

    /// Waits until the line is readable or the monotonic clock reaches `until`
    /// (`None`: forever); a signal does not restart the timeout. A close of the
    /// context from a signal handler or another thread ends it with `Err(STOPPED)`: a
    /// socket is shut down by the closer, a serial line's wait also watches the
    /// context's wake-up descriptor. On a TLS session, the wait ends when plaintext is
    /// there (a readable socket may bring only part of a record, or none of the
    /// application's data).
    pub fn wait(&mut self, until: Option<Duration>, debug: bool) -> Result<()> {
        let fd = self.fd;
        match self.kind {
            Kind::Serial => wait_line(&self.stop, fd, self.stop.wake_fd(), until, debug),
            Kind::Socket => wait_line(&self.stop, fd, -1, until, debug),
            Kind::Datagram if self.pending() > 0 => Ok(()),
            Kind::Datagram => wait_line(&self.stop, fd, -1, until, debug),
            Kind::Tls => {
                let Some(session) = self.held.session.as_deref_mut() else { return Err(no_session(fd)) };
                while !session.readable() {
                    wait_line(&self.stop, fd, -1, until, debug)?;
                    match session.fill(fd, libc::MSG_DONTWAIT) {
                        Err(e) if e.0 != libc::EAGAIN && e.0 != libc::EINTR => return Err(e),
                        _ => {}
                    }
                }
                Ok(())
            }
        }
    }

    /// Writes one frame. A socket never blocks in it (a client socket the context
    /// made blocking passes `MSG_DONTWAIT`); a TLS session sends one record, waiting
    /// for room up to `timeout`.
    #[inline]
    pub fn write(&mut self, frame: &[u8], timeout: Timeout) -> Result<usize> {
        let fd = self.fd;
        if let Some(queue) = &mut self.held.queue {
            queue.extend_from_slice(frame);
            return Ok(frame.len());
        }
        match self.kind {
            Kind::Socket => super::send(fd, frame, if self.held.client.is_some() { libc::MSG_DONTWAIT } else { 0 }),
            Kind::Serial => super::write(fd, frame),
            Kind::Tls => tls_write(fd, &mut self.held.session, &self.stop, frame, timeout),
            Kind::Datagram => datagram_write(fd, &self.held, frame),
        }
    }

    /// [`Line::write`] when it needs nothing of the driver: a socket, a serial line
    /// without an RTS sequence, a TLS session (which waits for room up to `timeout`
    /// itself); `None` otherwise (the driver then runs the RTS sequence, or
    /// [`Line::write`] queues the frame for the event-driven client).
    #[inline]
    pub fn write_at_once(&mut self, frame: &[u8], timeout: Timeout) -> Option<Result<usize>> {
        match self.kind {
            Kind::Socket if self.held.queue.is_none() => {
                Some(super::send(self.fd, frame, if self.held.client.is_some() { libc::MSG_DONTWAIT } else { 0 }))
            }
            Kind::Tls if self.held.queue.is_none() => {
                Some(tls_write(self.fd, &mut self.held.session, &self.stop, frame, timeout))
            }
            Kind::Serial if !self.rts_around_writes() => Some(super::write(self.fd, frame)),
            Kind::Datagram => Some(datagram_write(self.fd, &self.held, frame)),
            _ => None,
        }
    }

    /// A write on this line needs an RTS sequence ([`Line::rts_sequence`]).
    #[inline]
    pub fn rts_around_writes(&self) -> bool {
        self.kind == Kind::Serial && matches!(&self.settings, Link::Rtu(l) if l.rts != RTU_RTS_NONE)
    }

    /// The RTS sequence a write on this line needs, if any.
    pub fn rts_sequence(&self) -> Option<RtsSequence> {
        match &self.settings {
            Link::Rtu(l) if l.rts != RTU_RTS_NONE => Some(RtsSequence {
                up: l.rts == RTU_RTS_UP,
                delay_us: l.rts_delay as i64,
                onebyte_us: l.onebyte_time as i64,
                hook: l.custom_rts.clone(),
            }),
            _ => None,
        }
    }

    /// The application's RTS callback (`modbus_rtu_set_custom_rts`), if any.
    pub fn rts_hook(&self) -> Option<RtsHook> {
        self.serial().and_then(|l| l.custom_rts.clone())
    }

    /// The built-in RTS driver: raises or lowers the RTS modem line.
    pub fn set_rts(&self, on: bool) {
        rtu::set_rts_line(self.fd, on);
    }

    /// `modbus_flush`: drops what has arrived. Returns the bytes dropped (sockets,
    /// `held` included: what the driver had read ahead from the line; a serial line
    /// says 0), and the error of the last failed system call, if any. A socket's
    /// count is kept in 16 bits as libmodbus 3.1.11+ does: an overflow fails with
    /// EOVERFLOW.
    pub fn flush(&mut self, held: usize) -> (Result<usize>, Option<Error>) {
        let fd = self.fd;
        if self.kind == Kind::Serial {
            let rc = rtu::flush(fd);
            return (rc, rc.err());
        }
        let mut buffered = held;
        if let Some(d) = self.held.datagram.as_deref_mut() {
            buffered += d.discard();
        }
        if let Some(session) = self.held.session.as_deref_mut() {
            // Records queued on the socket are decrypted and dropped with the rest.
            while session.fill(fd, libc::MSG_DONTWAIT).is_ok() && !session.readable_end() {
                buffered += session.discard();
            }
            buffered += session.discard();
        }
        let (rc, left) = drain_socket(fd);
        (rc.map(|n| n + buffered), left)
    }

    /// After a bad checksum: discards what the serial line holds (no trace, no
    /// count); nothing on a socket.
    pub fn purge(&mut self) {
        if self.kind == Kind::Serial {
            let _ = rtu::flush(self.fd);
        }
    }
}

/// Drains a socket without waiting (see [`Line::flush`]).
fn drain_socket(fd: i32) -> (Result<usize>, Option<Error>) {
    let mut sink = [0u8; MAX_ADU_LENGTH];
    let mut total: u16 = 0;
    loop {
        let (n, left) = match super::recv(fd, &mut sink, libc::MSG_DONTWAIT) {
            Ok(n) => (n, None),
            Err(e) => (0, Some(e)),
        };
        total = match total.checked_add(n as u16) {
            Some(t) => t,
            None => return (Err(Error(libc::EOVERFLOW)), Some(Error(libc::EOVERFLOW))),
        };
        if n != MAX_ADU_LENGTH {
            return (Ok(total as usize), left);
        }
    }
}

/// [`Line::wait`] on the parts of a line it needs.
fn wait_line(stop: &Stop, fd: i32, wake: i32, until: Option<Duration>, debug: bool) -> Result<()> {
    loop {
        if stop.stopping() {
            return Err(Error::STOPPED);
        }
        let mut left = until.map(|u| super::to_timespec(u.saturating_sub(super::now())));
        match super::wait_or_wake(fd, libc::POLLIN, wake, left.as_mut()) {
            Ok(Ready::Line) => return Ok(()),
            Ok(Ready::TimedOut) => return Err(Error::TIMED_OUT),
            Ok(Ready::Woken) => stop.drain_wake(),
            Err(e) if e.0 == libc::EINTR => signal_caught(debug),
            Err(e) => return Err(e),
        }
    }
}

/// libmodbus's trace of a wait a signal interrupted.
fn signal_caught(debug: bool) {
    crate::stdio::DebugSink { enabled: debug }.err(format_args!("A non blocked signal was caught\n"))
}

/// A read within the kernel timeout (see [`Line::read`]).
fn read_within(
    fd: i32,
    socket: &mut Option<ClientSocket>,
    room: &mut [u8],
    timeout: Timeout,
    debug: bool,
) -> Result<usize> {
    // Without the timer the read must not block: then it only looks.
    let flags = if receive_timeout_set(fd, socket, timeout) { 0 } else { libc::MSG_DONTWAIT };
    let read = super::recv(fd, room, flags);
    if debug && matches!(read, Err(Error(libc::EINTR))) {
        signal_caught(true);
    }
    read
}

/// Sets the socket's `SO_RCVTIMEO` to 3/4 of `timeout` unless it already is; false
/// when it cannot be set (a blocking read could then block for ever).
fn receive_timeout_set(fd: i32, socket: &mut Option<ClientSocket>, timeout: Timeout) -> bool {
    let Some(socket) = socket.as_mut() else { return false };
    if socket.rcvtimeo_for != Some(timeout) {
        if tcp::set_receive_timeout(fd, timeout.duration() * 3 / 4).is_err() {
            return false;
        }
        socket.rcvtimeo_for = Some(timeout);
    }
    true
}

/// What a read, peek or wait on a socket of a Modbus/TCP Security context without a
/// session (one handed over that this context did not connect or accept, or whose
/// session was dropped when its peer went) ends with: EMBTLS, unless the stream has
/// ended, which a read of it would say (ECONNRESET, as on a TCP socket). A write
/// without a session is always EMBTLS (a peer that stopped sending may still read).
#[cold]
fn no_session(fd: i32) -> Error {
    let mut byte = [0u8; 1];
    match super::recv(fd, &mut byte, libc::MSG_PEEK | libc::MSG_DONTWAIT) {
        Ok(0) => Error::CONN_RESET,
        Err(e) if e == Error::CONN_RESET => e,
        _ => Error(EMBTLS),
    }
}

/// [`Line::peek`] on a UDP socket: the datagram being read (the next one when none is).
fn datagram_peek(fd: i32, held: &mut Held, room: &mut [u8], block: bool) -> Result<usize> {
    let Some(d) = held.datagram.as_deref_mut() else { return Err(Error(libc::EBADF)) };
    if d.pending() == 0 {
        d.fill(fd, if block { 0 } else { libc::MSG_DONTWAIT })?;
    }
    Ok(d.peek(room))
}

/// [`Line::read`] on a UDP socket: takes from the datagram being read; when none is
/// left, reads the next one whole (within the kernel timeout of a client's response
/// timeout, as a TCP client reads).
fn datagram_read(fd: i32, held: &mut Held, room: &mut [u8], how: ReadHow) -> Result<usize> {
    let Held { datagram, client, .. } = held;
    let Some(d) = datagram.as_deref_mut() else { return Err(Error(libc::EBADF)) };
    if d.pending() == 0 {
        let flags = match how {
            ReadHow::Queued => libc::MSG_DONTWAIT,
            ReadHow::Ready => 0,
            ReadHow::Within(timeout) if receive_timeout_set(fd, client, timeout) => 0,
            ReadHow::Within(_) => libc::MSG_DONTWAIT,
        };
        d.fill(fd, flags)?;
    }
    Ok(d.take(room))
}

/// [`Line::write`] on a UDP socket: to its peer, or to the sender of the request.
fn datagram_write(fd: i32, held: &Held, frame: &[u8]) -> Result<usize> {
    match held.datagram.as_deref() {
        Some(d) => d.send(fd, frame, held.connected),
        None => Err(Error(libc::EBADF)),
    }
}

/// [`Line::peek`] on a TLS session: the plaintext, decrypted from the socket's
/// records as needed.
#[inline(never)]
fn tls_peek(fd: i32, session: &mut Option<Box<Session>>, room: &mut [u8], block: bool) -> Result<usize> {
    let Some(session) = session.as_deref_mut() else { return Err(no_session(fd)) };
    let flags = if block { 0 } else { libc::MSG_DONTWAIT };
    while !session.readable() {
        session.fill(fd, flags)?;
    }
    match session.peek(room) {
        0 => session.take(&mut []),
        n => Ok(n),
    }
}

/// [`Line::read`] on a TLS session into `buf[at]`: takes plaintext; reads records
/// from the socket only when none is left, one `recv` at most (a part of a record, or
/// a record with no application data, leaves nothing to take: EAGAIN, and the machine
/// waits again).
#[inline(never)]
fn tls_read(fd: i32, held: &mut Held, buf: &mut [u8], at: Range<usize>, how: ReadHow) -> Result<usize> {
    let Held { session, client, .. } = held;
    let Some(session) = session.as_deref_mut() else { return Err(no_session(fd)) };
    let flags = match how {
        ReadHow::Queued => libc::MSG_DONTWAIT,
        ReadHow::Ready => 0,
        ReadHow::Within(timeout) if receive_timeout_set(fd, client, timeout) => 0,
        ReadHow::Within(_) => libc::MSG_DONTWAIT,
    };
    session.read_into(fd, flags, buf, at, !matches!(how, ReadHow::Queued))
}

/// [`Line::write`] on a TLS session.
#[inline(never)]
fn tls_write(
    fd: i32,
    session: &mut Option<Box<Session>>,
    stop: &Stop,
    frame: &[u8],
    timeout: Timeout,
) -> Result<usize> {
    let Some(session) = session.as_deref_mut() else { return Err(Error(EMBTLS)) };
    session.send(fd, frame, timeout, &|| stop.stopping())
}
