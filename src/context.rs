//! The state behind a `modbus_t *`: configuration, the link it talks over, and the
//! file descriptor. Creation and configuration rules follow libmodbus 3.1.12.

use std::ffi::CStr;
use std::sync::Arc;

use crate::error::{Error, Result};
use crate::outstanding::Outstanding;
use crate::proto::frame::{Framing, MsgKind};
use crate::proto::limits::TCP_SLAVE;
use crate::proto::session::client::ClientSession;
use crate::proto::session::receive::{LineCaps, Settings};
use crate::proto::session::server::ServerSession;
use crate::stdio::{self, DebugSink};
use crate::stop::Stop;
use crate::transport::AduBuf;

/// `MODBUS_QUIRK_MAX_SLAVE`: accept slave ids 248..255.
pub const QUIRK_MAX_SLAVE: u32 = 1 << 1;
/// `MODBUS_QUIRK_REPLY_TO_BROADCAST`: an RTU server answers slave 0 too.
pub const QUIRK_REPLY_TO_BROADCAST: u32 = 1 << 2;

/// `MODBUS_ERROR_RECOVERY_LINK` and `_PROTOCOL`, and the timeouts: the session rules'.
pub use crate::proto::session::{RECOVERY_LINK, RECOVERY_PROTOCOL, Timeout, Timeouts};

/// The links a context talks over (transport settings), seen from the context.
pub use crate::transport::line::Line;
pub use crate::transport::link::{
    Link, RTU_RS232, RTU_RS485, RTU_RTS_DOWN, RTU_RTS_NONE, RTU_RTS_UP, RtsHook, RtuLink, TcpLink, TcpPiLink,
};

/// Bytes read past a message, for the next receive (see [`ReadAhead`]).
pub use crate::proto::session::receive::ReadAhead;

/// One Modbus context.
pub struct Context {
    /// The line: its settings, and the descriptor once open (see [`Line`]).
    pub line: Line,
    /// What a receive needs of the context, kept where a receive finds it whole
    /// (see `proto::session::receive::Settings`), and the only place these live: the
    /// framing, the slave (unit) id used for requests (-1 until set on RTU), the
    /// error recovery mode, the response, byte and indication timeouts, and whether
    /// the server answers the function codes beyond libmodbus (set by the server
    /// configuration calls: their requests are then framed whole; off, a server
    /// frames and answers them exactly as libmodbus does). The fields of one receive
    /// (its kind, what the line can do...) are set by the receive itself.
    pub session: Settings,
    pub debug: bool,
    pub quirks: u32,
    /// Read-ahead of the client side (see [`ReadAhead`]).
    pub rx: ReadAhead,
    /// The client session: transaction ids, the late ids, a diagnostics answer's
    /// length (see `proto::session::client`); every driver's.
    pub client: ClientSession,
    /// The server session: the other slave's answer to skip (see
    /// `proto::session::server`); the blocking server's and the runner's.
    pub server: ServerSession,
    /// Server-side configuration and diagnostics state beyond libmodbus (see
    /// [`crate::server_ext`]); `None` until a server configuration call, so an
    /// unconfigured context is exactly libmodbus and pays nothing for it.
    pub server_ext: Option<Box<crate::server_ext::ServerExt>>,
    /// Frame buffers lent to one transaction at a time (see [`SpareFrames`]).
    pub spare: SpareFrames,
    /// What a close from a signal handler or another thread needs without the lock
    /// (see [`crate::stop`]); shared with the handle and the line.
    pub stop: Arc<Stop>,
    /// The event-driven client's requests and state (see [`crate::outstanding`]),
    /// private to the context: made on the first asynchronous call, lent to
    /// `modbus_process` while it runs ([`Context::lend_async`]).
    asynchronous: Async,
    /// A close left requests of the event-driven client to complete, or a free is
    /// completing them (see [`Shut`]): new ones are refused meanwhile.
    shut: Shut,
    /// A server runner drives this context (`crate::runner`): nothing may wait in
    /// it (no sleep before a flush; writes are queued on the line).
    pub runner: bool,
    /// A server's connection: its id and peer (`crate::server::connection`).
    pub connection: Connection,
}

/// The connection ids of a server (`modbus_request_info_t::connection_id`): one
/// counter for the process, so that an id is never given twice, whichever server
/// gives it.
static CONNECTIONS: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);

/// A new connection id (never 0).
pub fn new_connection_id() -> u64 {
    CONNECTIONS.fetch_add(1, std::sync::atomic::Ordering::Relaxed) + 1
}

/// Who a server context's request comes from: its connection's id and its peer's
/// address. A client of a runner has them from its accept ([`Connection::accepted`]);
/// a context that serves whatever socket it holds (`modbus_tcp_accept`,
/// `modbus_set_socket`) tells its connections apart by their socket's cookie, so a
/// descriptor number used again is a new connection; a UDP socket gives each
/// sender an id of its own.
#[derive(Default)]
pub struct Connection {
    /// The connection is the context's for its life (a runner's client).
    pub(crate) fixed: bool,
    /// The socket cookie `id` is for.
    pub(crate) cookie: u64,
    /// The line's generation (`Line::generation`) when the cookie was read.
    pub(crate) generation: u32,
    pub(crate) id: u64,
    pub(crate) peer: Option<crate::transport::udp::Peer>,
    /// UDP: each sender's id and when it was last seen (a count of datagrams).
    pub(crate) senders: std::collections::HashMap<Vec<u8>, (u64, u64)>,
    pub(crate) seen: u64,
}

impl Connection {
    /// A runner's client, accepted on `fd`.
    pub fn accepted(fd: i32) -> Connection {
        Connection {
            fixed: true,
            id: new_connection_id(),
            peer: crate::transport::udp::Peer::of_socket(fd),
            ..Connection::default()
        }
    }
}

/// Where a context's event-driven state is (see [`Context::lend_async`]).
enum Async {
    /// No asynchronous call yet: a blocking context pays nothing for it.
    None,
    Here(Box<Outstanding>),
    /// Lent to the `modbus_process` under way, with the requests pending when it
    /// began (what calls from its RTS hook see).
    Lent {
        pending: usize,
    },
}

/// Whether the event-driven client takes requests (`modbus_close` and `modbus_free`
/// with requests pending; see `crate::event::close`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Shut {
    /// It does.
    Open,
    /// A close left requests pending: they complete with ESHUTDOWN on the loop's
    /// thread (the next `modbus_process`, or `modbus_free`); until their callbacks
    /// have run, a submission fails with ESHUTDOWN.
    Closing,
    /// `modbus_free` completes what is pending (EIDRM): a submission from those
    /// callbacks fails with EIDRM.
    Freed,
}

/// Frame buffers a context lends to each transaction and takes back: a transaction
/// then neither allocates nor zeroes 260 bytes per frame (it only ever reads what it
/// wrote). Allocated on first use, freed with the context.
#[derive(Debug, Default)]
pub struct SpareFrames([Option<Box<AduBuf>>; 2]);

impl SpareFrames {
    #[inline]
    pub fn take(&mut self) -> Box<AduBuf> {
        match self.0[0].take() {
            Some(frame) => frame,
            None => self.0[1].take().unwrap_or_else(|| Box::new(AduBuf::new())),
        }
    }

    #[inline]
    pub fn give(&mut self, frame: Box<AduBuf>) {
        let slot = if self.0[0].is_none() { &mut self.0[0] } else { &mut self.0[1] };
        *slot = Some(frame);
    }
}

impl Context {
    fn common(framing: Framing, link: Link, slave: i32) -> Context {
        let stop = Arc::new(Stop::default());
        Context::on_line(framing, Line::new(link, Arc::clone(&stop)), stop, slave)
    }

    /// A context over `line`, whose stop state is `stop`.
    fn on_line(framing: Framing, line: Line, stop: Arc<Stop>, slave: i32) -> Context {
        Context {
            line,
            session: Settings {
                framing,
                kind: MsgKind::Indication,
                extended: false,
                expecting: None,
                timeouts: Timeouts {
                    response: Timeout::new(0, 500_000),
                    byte: Timeout::new(0, 500_000),
                    indication: Timeout::new(0, 0),
                },
                recovery: 0,
                slave,
                any_unit: false,
                read_ahead: false,
                ascii_delimiter: b'\n',
                line: LineCaps { socket: false, reads_without_waiting: false, timed_reads: false },
            },
            debug: false,
            quirks: 0,
            rx: ReadAhead::new(),
            client: ClientSession::default(),
            server: ServerSession::default(),
            server_ext: None,
            spare: SpareFrames::default(),
            stop,
            asynchronous: Async::None,
            shut: Shut::Open,
            runner: false,
            connection: Default::default(),
        }
    }

    /// The context of one client of this listening context, for a server runner
    /// (see [`Line::serving`]): its framing, timeouts, recovery, slave, debug flag
    /// and quirks, and a line of the same settings, not open yet.
    pub fn serving(&mut self) -> Result<Context> {
        let stop = Arc::new(Stop::default());
        let line = self.line.serving(Arc::clone(&stop))?;
        let mut c = Context::on_line(self.framing(), line, stop, -1);
        c.session = self.session;
        c.debug = self.debug;
        c.quirks = self.quirks;
        c.runner = true;
        Ok(c)
    }

    /// `modbus_new_rtu`. The two messages are printed whatever the debug flag, as
    /// libmodbus does.
    pub fn new_rtu(device: Option<&CStr>, baud: i32, parity: u8, data_bit: i32, stop_bit: i32) -> Result<Context> {
        let device = match device {
            Some(d) if !d.is_empty() => d,
            _ => {
                stdio::err(format_args!("The device string is empty\n"));
                return Err(Error::INVALID);
            }
        };
        if baud == 0 {
            stdio::err(format_args!("The baud rate value must not be zero\n"));
            return Err(Error::INVALID);
        }
        if !matches!(parity, b'N' | b'E' | b'O') {
            return Err(Error::INVALID);
        }
        let bits = 1 + data_bit + (parity != b'N') as i32 + stop_bit;
        let onebyte_time = (1_000_000i64 * bits as i64 / baud as i64) as i32;
        let link = RtuLink {
            device: device.to_owned(),
            baud,
            parity,
            data_bit,
            stop_bit,
            saved_termios: None,
            serial_mode: RTU_RS232,
            rts: RTU_RTS_NONE,
            rts_delay: onebyte_time,
            onebyte_time,
            custom_rts: None,
        };
        Ok(Context::common(Framing::Rtu, link.into(), -1))
    }

    /// `modbus_new_ascii`: Modbus ASCII on a serial line. Same checks as RTU; the byte
    /// timeout starts at 1 s, the longest gap ASCII allows inside a frame.
    pub fn new_ascii(device: Option<&CStr>, baud: i32, parity: u8, data_bit: i32, stop_bit: i32) -> Result<Context> {
        let mut ctx = Context::new_rtu(device, baud, parity, data_bit, stop_bit)?;
        ctx.session.framing = Framing::Ascii;
        ctx.session.timeouts.byte = Timeout::new(1, 0);
        Ok(ctx)
    }

    /// `modbus_new_tcp`: NULL means any address ("0"); the address must fit the 15
    /// characters of a dotted quad.
    pub fn new_tcp(ip: Option<&CStr>, port: i32) -> Result<Context> {
        let ip = match ip {
            None => c"0".to_owned(),
            Some(ip) if ip.is_empty() => {
                stdio::err(format_args!("The IP string is empty\n"));
                return Err(Error::INVALID);
            }
            Some(ip) if ip.to_bytes().len() >= 16 => {
                stdio::err(format_args!("The IP string has been truncated\n"));
                return Err(Error::INVALID);
            }
            Some(ip) => ip.to_owned(),
        };
        Ok(Context::common(Framing::Tcp, TcpLink { ip, port }.into(), TCP_SLAVE))
    }

    /// `modbus_new_tcp_pi` (3.1.8+ rules): NULL node is any address, NULL or empty
    /// service is "502".
    pub fn new_tcp_pi(node: Option<&CStr>, service: Option<&CStr>) -> Result<Context> {
        let node = node.map(CStr::to_owned).unwrap_or_default();
        let service = match service {
            Some(s) if !s.is_empty() => s.to_owned(),
            _ => c"502".to_owned(),
        };
        Ok(Context::common(Framing::Tcp, TcpPiLink { node, service }.into(), TCP_SLAVE))
    }

    /// `modbus_new_udp`: Modbus/UDP over IPv4 (one ADU per datagram).
    pub fn new_udp(ip: Option<&CStr>, port: i32) -> Result<Context> {
        let mut ctx = Context::new_tcp(ip, port)?;
        ctx.line.datagrams();
        Ok(ctx)
    }

    /// `modbus_new_udp_pi`: Modbus/UDP over any address family.
    pub fn new_udp_pi(node: Option<&CStr>, service: Option<&CStr>) -> Result<Context> {
        let mut ctx = Context::new_tcp_pi(node, service)?;
        ctx.line.datagrams();
        Ok(ctx)
    }

    /// `modbus_new_tcp_tls`: Modbus/TCP Security, TLS over TCP/IPv4.
    pub fn new_tcp_tls(ip: Option<&CStr>, port: i32) -> Result<Context> {
        let mut ctx = Context::new_tcp(ip, port)?;
        ctx.line.secure();
        Ok(ctx)
    }

    /// `modbus_new_tcp_tls_pi`: Modbus/TCP Security over any address family.
    pub fn new_tcp_tls_pi(node: Option<&CStr>, service: Option<&CStr>) -> Result<Context> {
        let service = match service {
            Some(s) if !s.is_empty() => Some(s),
            _ => Some(c"802"),
        };
        let mut ctx = Context::new_tcp_pi(node, service)?;
        ctx.line.secure();
        Ok(ctx)
    }

    /// `modbus_new_rtu_tcp`: RTU frames (slave, PDU, CRC) over a TCP/IPv4 stream,
    /// as serial-to-Ethernet gateways speak them. Slave rules are RTU's.
    pub fn new_rtu_tcp(ip: Option<&CStr>, port: i32) -> Result<Context> {
        let mut ctx = Context::new_tcp(ip, port)?;
        ctx.session.framing = Framing::Rtu;
        ctx.session.slave = -1;
        Ok(ctx)
    }

    /// `modbus_new_rtu_tcp_pi`: RTU frames over TCP, any address family.
    pub fn new_rtu_tcp_pi(node: Option<&CStr>, service: Option<&CStr>) -> Result<Context> {
        let mut ctx = Context::new_tcp_pi(node, service)?;
        ctx.session.framing = Framing::Rtu;
        ctx.session.slave = -1;
        Ok(ctx)
    }

    pub fn rtu(&self) -> Option<&RtuLink> {
        self.line.serial()
    }

    pub fn rtu_mut(&mut self) -> Option<&mut RtuLink> {
        self.line.serial_mut()
    }

    /// The framing (held by the session settings).
    #[inline]
    pub fn framing(&self) -> Framing {
        self.session.framing
    }

    /// The descriptor (socket or serial line), -1 when closed.
    #[inline]
    pub fn fd(&self) -> i32 {
        self.line.fd()
    }

    /// The three timeouts, for the session rules.
    #[inline]
    pub fn timeouts(&self) -> Timeouts {
        self.session.timeouts
    }

    /// TCP (MBAP) framing.
    pub fn is_tcp(&self) -> bool {
        self.session.framing == Framing::Tcp
    }

    /// The debug sink (prints through C stdio when debug is on).
    pub fn diag(&self) -> DebugSink {
        DebugSink { enabled: self.debug }
    }

    /// Makes `fd` the context's descriptor (-1: none), as one the context did not
    /// open (see [`Line::adopt`]).
    pub fn set_descriptor(&mut self, fd: i32) {
        self.line.adopt(fd);
    }

    /// Gives up the descriptor (for the caller to close): -1 from now on, and no
    /// stopper acts on its number any more (see [`Stop::set_fd`]).
    pub fn release_descriptor(&mut self) -> i32 {
        self.line.abandon()
    }

    /// Requests of the event-driven client given and not completed (a blocking call
    /// meanwhile fails with EBUSY).
    pub fn pending(&self) -> usize {
        match &self.asynchronous {
            Async::None => 0,
            Async::Here(o) => o.pending(),
            Async::Lent { pending } => *pending,
        }
    }

    /// The event-driven client's state, if made; `EBUSY` while `modbus_process` has
    /// it (a call from the RTS hook it runs).
    pub fn async_state(&mut self) -> Result<Option<&mut Outstanding>> {
        match &mut self.asynchronous {
            Async::None => Ok(None),
            Async::Here(o) => Ok(Some(o)),
            Async::Lent { .. } => Err(Error(libc::EBUSY)),
        }
    }

    /// [`Context::async_state`], with the client session (its late ids) beside it.
    pub fn async_with_client(&mut self) -> Result<Option<(&mut Outstanding, &mut ClientSession)>> {
        match &mut self.asynchronous {
            Async::None => Ok(None),
            Async::Here(o) => Ok(Some((o, &mut self.client))),
            Async::Lent { .. } => Err(Error(libc::EBUSY)),
        }
    }

    /// [`Context::async_state`], made on first use.
    pub fn async_state_made(&mut self) -> Result<&mut Outstanding> {
        if let Async::None = self.asynchronous {
            self.asynchronous = Async::Here(Box::new(Outstanding::new(self.framing())));
        }
        Ok(self.async_state()?.expect("made above"))
    }

    /// The event-driven client's state to look at (`None`: not made, or lent).
    pub fn async_view(&self) -> Option<&Outstanding> {
        match &self.asynchronous {
            Async::Here(o) => Some(o),
            _ => None,
        }
    }

    /// Lends the event-driven client's state to `modbus_process` (`None`: not made,
    /// or lent already). Until it comes back ([`Context::give_back_async`]), its
    /// requests count as pending and calls that would change them fail with EBUSY.
    pub fn lend_async(&mut self) -> Option<Box<Outstanding>> {
        let Async::Here(o) = &self.asynchronous else { return None };
        let pending = o.pending();
        match std::mem::replace(&mut self.asynchronous, Async::Lent { pending }) {
            Async::Here(o) => Some(o),
            _ => unreachable!("checked above"),
        }
    }

    /// The state [`Context::lend_async`] lent comes back.
    pub fn give_back_async(&mut self, o: Box<Outstanding>) {
        self.asynchronous = Async::Here(o);
    }

    /// Whether the event-driven client takes requests (see [`Shut`]).
    pub fn shut(&self) -> Shut {
        self.shut
    }

    pub fn set_shut(&mut self, shut: Shut) {
        self.shut = shut;
    }

    /// A blocking call may run: nothing of the event-driven client is pending
    /// (else EBUSY).
    pub fn idle(&self) -> Result<()> {
        if self.pending() > 0 { Err(Error(libc::EBUSY)) } else { Ok(()) }
    }

    /// A call must end now with EBADF: the context is being closed under it (see
    /// [`crate::stop`]).
    #[inline]
    pub fn stopping(&self) -> bool {
        self.stop.stopping()
    }

    /// `modbus_set_slave`.
    pub fn set_slave(&mut self, slave: i32) -> Result<()> {
        let max = if self.quirks & QUIRK_MAX_SLAVE != 0 { 255 } else { 247 };
        let ok = (0..=max).contains(&slave) || (self.is_tcp() && slave == TCP_SLAVE);
        if !ok {
            return Err(Error::INVALID);
        }
        self.session.slave = slave;
        Ok(())
    }

    /// `modbus_set_response_timeout`: (0, 0) is refused; usec must be below 1 s.
    pub fn set_response_timeout(&mut self, sec: u32, usec: u32) -> Result<()> {
        if (sec == 0 && usec == 0) || usec > 999_999 {
            return Err(Error::INVALID);
        }
        self.session.timeouts.response = Timeout::new(sec, usec);
        Ok(())
    }

    /// Byte and indication timeouts: (0, 0) disables them.
    pub fn checked_timeout(sec: u32, usec: u32) -> Result<Timeout> {
        if usec > 999_999 {
            return Err(Error::INVALID);
        }
        Ok(Timeout::new(sec, usec))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults() {
        let c = Context::new_tcp(Some(c"127.0.0.1"), 502).unwrap();
        assert_eq!((c.session.slave, c.fd(), c.client.tid()), (0xFF, -1, 0));
        assert_eq!(c.session.timeouts.response, Timeout::new(0, 500_000));
        assert_eq!(c.session.timeouts.byte, Timeout::new(0, 500_000));
        assert!(c.session.timeouts.indication.is_zero());
        let r = Context::new_rtu(Some(c"/dev/null"), 9600, b'N', 8, 1).unwrap();
        assert_eq!(r.session.slave, -1);
        // 10 bits at 9600 baud.
        assert_eq!(r.rtu().unwrap().onebyte_time, 1041);
        assert_eq!(r.rtu().unwrap().rts_delay, 1041);
    }

    #[test]
    fn creation_errors() {
        assert_eq!(Context::new_rtu(None, 9600, b'N', 8, 1).err(), Some(Error::INVALID));
        assert_eq!(Context::new_rtu(Some(c"/dev/x"), 0, b'N', 8, 1).err(), Some(Error::INVALID));
        assert_eq!(Context::new_rtu(Some(c"/dev/x"), 9600, b'X', 8, 1).err(), Some(Error::INVALID));
        assert_eq!(Context::new_tcp(Some(c""), 502).err(), Some(Error::INVALID));
        assert_eq!(Context::new_tcp(Some(c"255.255.255.2555"), 502).err(), Some(Error::INVALID));
        assert!(Context::new_tcp(Some(c"255.255.255.255"), 502).is_ok());
        assert!(Context::new_tcp_pi(None, None).is_ok());
    }

    #[test]
    fn slave_ranges() {
        let mut r = Context::new_rtu(Some(c"/dev/x"), 9600, b'N', 8, 1).unwrap();
        assert!(r.set_slave(247).is_ok());
        assert_eq!(r.set_slave(248), Err(Error::INVALID));
        assert_eq!(r.set_slave(0xFF), Err(Error::INVALID));
        r.quirks |= QUIRK_MAX_SLAVE;
        assert!(r.set_slave(255).is_ok());
        assert_eq!(r.set_slave(256), Err(Error::INVALID));
        let mut t = Context::new_tcp(None, 502).unwrap();
        assert!(t.set_slave(0xFF).is_ok());
        assert_eq!(t.set_slave(-1), Err(Error::INVALID));
    }

    #[test]
    fn the_session_settings_follow_the_context() {
        let contexts = [
            Context::new_tcp(None, 502).unwrap(),
            Context::new_tcp_pi(None, None).unwrap(),
            Context::new_rtu_tcp(None, 502).unwrap(),
            Context::new_rtu_tcp_pi(None, None).unwrap(),
            Context::new_tcp_tls(None, 802).unwrap(),
            Context::new_rtu(Some(c"/dev/null"), 9600, b'N', 8, 1).unwrap(),
            Context::new_ascii(Some(c"/dev/null"), 9600, b'E', 7, 1).unwrap(),
        ];
        let framings =
            [Framing::Tcp, Framing::Tcp, Framing::Rtu, Framing::Rtu, Framing::Tcp, Framing::Rtu, Framing::Ascii];
        for (c, framing) in contexts.into_iter().zip(framings) {
            assert_eq!(c.framing(), framing);
            assert_eq!(c.session.slave, if framing == Framing::Tcp { 0xFF } else { -1 });
        }
    }

    #[test]
    fn timeouts() {
        let mut c = Context::new_tcp(None, 502).unwrap();
        assert_eq!(c.set_response_timeout(0, 0), Err(Error::INVALID));
        assert_eq!(c.set_response_timeout(0, 1_000_000), Err(Error::INVALID));
        assert!(c.set_response_timeout(0, 999_999).is_ok());
        assert_eq!(Context::checked_timeout(0, 1_000_000), Err(Error::INVALID));
        assert_eq!(Context::checked_timeout(0, 0), Ok(Timeout::new(0, 0)));
    }
}
