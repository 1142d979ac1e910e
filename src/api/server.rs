//! A server that runs itself ([`Server`], over `crate::runner::Runner`), answering
//! every request as it came through the application's [`Handler`], as the C
//! runner's `raw` callback does: after the unit and the TLS authorization, nothing
//! of the reply's own runs.

use std::ffi::CString;
use std::net::SocketAddr;
use std::os::fd::RawFd;
use std::ptr::NonNull;
use std::sync::Arc;
use std::time::Duration;

use super::{Error, Later, Modbus, Result};
use crate::context::Context;
use crate::engine::Guard;
use crate::handle::{self, Handle};
use crate::proto::error::exception;
use crate::proto::frame::Framing;
use crate::proto::reply::{Data, Refusal, Request};
use crate::runner::{Answer, Answers, CLOSE_CONNECTION, Runner, Stopper};

/// What a [`Handler`] learns of a request.
#[derive(Clone, Copy, Debug)]
pub struct RequestInfo<'a> {
    pub unit: u8,
    pub function: u8,
    /// The MBAP transaction id (0 on serial lines and RTU over TCP).
    pub transaction_id: u16,
    /// The MBAP protocol id as received (0 on serial lines and RTU over TCP).
    pub protocol_id: u16,
    /// The id for an answer given later ([`Server::answer`]).
    pub request_id: i32,
    /// The client's connection, unique for the process's life (a TCP connection, a
    /// UDP sender); 0 on a serial line.
    pub connection_id: u64,
    /// The client's address (a TCP peer, a UDP sender); `None` on a serial line.
    pub peer: Option<SocketAddr>,
    /// The client's role (Modbus/TCP Security); `None` elsewhere, or when its
    /// certificate has none (or one that is not UTF-8).
    pub role: Option<&'a str>,
}

/// A [`Handler`]'s answer to a request.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Reply {
    /// This PDU, function code first (1 to 253 bytes; else exception 04).
    Pdu(Vec<u8>),
    /// An exception answer with this code (1 to 11; else exception 04).
    Exception(u8),
    /// The answer comes later: [`Server::answer`] with `info.request_id`.
    Later,
    /// No answer.
    Nothing,
    /// No answer, and the client's connection is closed (on a serial line or the
    /// UDP socket: no answer).
    Close,
}

/// The application's side of a [`Server`]: every request as it came.
pub trait Handler {
    /// Whether `unit` is served: a unit refused gets no answer on a serial line and
    /// exception 0B on TCP. Every unit by default.
    fn accept_unit(&mut self, _info: &RequestInfo<'_>, _unit: u8) -> bool {
        true
    }
    /// Every request as it came (the `raw` callback): `pdu` is its PDU, function
    /// code first.
    fn request(&mut self, info: &RequestInfo<'_>, pdu: &[u8]) -> Reply;
    /// A client's connection ended (closed by it, by the idle timeout, by
    /// [`Reply::Close`], by an error).
    fn closed(&mut self, _connection_id: u64) {}
}

/// A server that runs itself (`modbus_server_new`) over the context it takes.
pub struct Server {
    // (Dropped before the context it serves.)
    runner: Runner,
    stopper: Arc<Stopper>,
    answers: Arc<Answers>,
    ctx: Served,
}

/// The context a server serves: its own (the Rust API's), or the C application's,
/// which outlives the server (`modbus_server_new`'s contract).
enum Served {
    Owned(Modbus),
    Lent(NonNull<Handle<Context>>),
}

// SAFETY: a context behind its own lock (`handle::call` serialises every use); a
// lent one is the C application's, which may hand its server to another thread.
unsafe impl Send for Served {}

impl Served {
    fn call<R>(&self, f: impl FnOnce(&mut Guard<'_>) -> Result<R>) -> Result<R> {
        match self {
            Served::Owned(m) => m.call(f),
            // SAFETY: the C application's context outlives its server (the
            // contract of `Server::over_handle`).
            Served::Lent(ptr) => unsafe { handle::call(ptr.as_ptr(), f) },
        }
    }
}

impl Server {
    /// A server over `ctx` for up to `max_clients` clients at once (a listening
    /// context: TCP, RTU over TCP, Modbus/TCP Security), or over its own line (a
    /// serial or UDP context), as `modbus_server_new`. EINVAL: `max_clients` 0.
    pub fn new(ctx: Modbus, max_clients: usize) -> Result<Server> {
        if max_clients < 1 {
            return Err(Error::INVALID);
        }
        Server::over(Served::Owned(ctx), max_clients)
    }

    fn over(ctx: Served, max_clients: usize) -> Result<Server> {
        let runner = ctx.call(|g| Runner::new(g, max_clients))?;
        Ok(Server { stopper: runner.stopper(), answers: runner.answers(), runner, ctx })
    }

    /// A server over the C application's context `ptr` (`modbus_server_new`);
    /// EINVAL: NULL, or `max_clients` 0.
    ///
    /// # Safety
    /// `ptr` is NULL or a live context that outlives the server.
    pub(crate) unsafe fn over_handle(ptr: *mut Handle<Context>, max_clients: usize) -> Result<Server> {
        let ptr = NonNull::new(ptr).ok_or(Error::INVALID)?;
        if max_clients < 1 {
            return Err(Error::INVALID);
        }
        Server::over(Served::Lent(ptr), max_clients)
    }

    /// The idle timeout as C gives it (zero: none).
    pub(crate) fn set_idle(&mut self, t: crate::proto::session::Timeout) {
        self.runner.set_idle_timeout(t);
    }

    /// The stop, reachable without the server (`modbus_server_stop`).
    pub(crate) fn stopper(&self) -> Arc<Stopper> {
        Arc::clone(&self.stopper)
    }

    /// The answers given later, reachable without the server
    /// (`modbus_server_answer`).
    pub(crate) fn answers(&self) -> Arc<Answers> {
        Arc::clone(&self.answers)
    }

    /// A client from which no whole request came for this long is closed (`None`:
    /// never; default 60 s).
    pub fn set_idle_timeout(&mut self, t: Option<Duration>) {
        let t = t.map_or(Ok(crate::proto::session::Timeout { sec: 0, usec: 0 }), |t| {
            let sec = u32::try_from(t.as_secs()).unwrap_or(u32::MAX);
            // (A timeout below a microsecond is one.)
            let usec = if sec == 0 && t.subsec_micros() == 0 { 1 } else { t.subsec_micros() };
            Context::checked_timeout(sec, usec)
        });
        if let Ok(t) = t {
            self.set_idle(t);
        }
    }

    /// At `max_clients`: accept a new connection and close it at once (mbusd),
    /// instead of leaving it in the backlog (the default, libmodbus-like).
    pub fn set_close_when_full(&mut self, on: bool) {
        self.runner.set_close_when_full(on);
    }

    /// The server's epoll descriptor: readable when [`Server::run`] has work.
    pub fn fd(&self) -> RawFd {
        self.runner.fd()
    }

    /// The address it listens on (its UDP socket's); `None` on a serial line.
    pub fn local_addr(&self) -> Option<SocketAddr> {
        let fd = self.runner.socket();
        if fd < 0 {
            return None;
        }
        crate::transport::udp::Peer::of_local(fd)?.socket_addr()
    }

    /// The clients connected now.
    pub fn clients(&self) -> usize {
        self.runner.clients()
    }

    /// Accepts, reads and answers through `h`, closes idle clients, for `timeout`
    /// (`None`: until [`Server::stop`]; zero: what is ready now). Returns the
    /// requests answered.
    pub fn run(&mut self, timeout: Option<Duration>, h: &mut dyn Handler) -> Result<usize> {
        self.run_answering(timeout, &mut Adapter { h, arrived: None })
    }

    /// [`Server::run`] with the runner's own answerer (the C layer's callbacks or
    /// mapping).
    pub(crate) fn run_answering(&mut self, timeout: Option<Duration>, answer: &mut dyn Answer) -> Result<usize> {
        let ctx = &self.ctx;
        let on_server = |f: &mut dyn FnMut(&mut Guard<'_>)| {
            ctx.call(|g| {
                f(g);
                Ok(())
            })
        };
        self.runner.run(timeout, &on_server, answer)
    }

    /// The answer to request `id` of a [`Reply::Later`] (`modbus_server_answer`):
    /// sent by the run under way (woken) or the next; dropped when its client has
    /// left. EINVAL: no request `id` waits for an answer, or `a` does not fit it.
    pub fn answer(&self, id: i32, a: Later) -> Result<()> {
        self.answers.give(&self.stopper, id, a)
    }

    /// Ends the run under way (or the next) once the request being answered is.
    pub fn stop(&self) {
        self.stopper.stop();
    }
}

/// Who a request comes from, read on its context before it is answered.
struct From {
    framing: Framing,
    connection_id: u64,
    peer: Option<SocketAddr>,
    role: Option<CString>,
}

impl From {
    fn of(g: &mut Guard<'_>) -> From {
        let (connection_id, peer) = crate::server::connection(g);
        From {
            framing: g.framing(),
            connection_id,
            peer: peer.and_then(|p| p.socket_addr()),
            role: g.line.peer_role().map(ToOwned::to_owned),
        }
    }

    /// The request `req` (its ADU), request `id`, as a [`Handler`] sees it.
    fn info(&self, req: &[u8], request_id: i32) -> RequestInfo<'_> {
        let h = self.framing.header_length();
        let mbap = self.framing == Framing::Tcp && req.len() >= 4;
        RequestInfo {
            unit: req.get(h.wrapping_sub(1)).copied().unwrap_or(0),
            function: req.get(h).copied().unwrap_or(0),
            transaction_id: if mbap { u16::from_be_bytes([req[0], req[1]]) } else { 0 },
            protocol_id: if mbap { u16::from_be_bytes([req[2], req[3]]) } else { 0 },
            request_id,
            connection_id: self.connection_id,
            peer: self.peer,
            role: self.role.as_deref().and_then(|r| r.to_str().ok()),
        }
    }
}

/// A [`Handler`] as the runner's answerer.
struct Adapter<'h> {
    h: &'h mut dyn Handler,
    /// The serial request about to be asked about (`Answer::arrived`).
    arrived: Option<From>,
}

impl Answer for Adapter<'_> {
    fn any_unit(&self) -> bool {
        true
    }

    fn arrived(&mut self, g: &mut Guard<'_>) {
        self.arrived = Some(From::of(g));
    }

    fn accept_unit(&mut self, unit: u8, req: &[u8]) -> bool {
        match &self.arrived {
            Some(from) => self.h.accept_unit(&from.info(req, 0), unit),
            None => true,
        }
    }

    fn answer(&mut self, g: &mut Guard<'_>, req: &[u8], id: i32) -> Result<Option<usize>> {
        let from = From::of(g);
        let mut call = Call { h: &mut *self.h, from: &from, req, id, then: Then::Answered };
        let sent = crate::server::reply(g, req, req.len() as i32, &mut call)?;
        match call.then {
            Then::Answered => Ok(Some(sent)),
            Then::Later => Ok(None),
            Then::Close => Err(CLOSE_CONNECTION),
        }
    }

    fn closed(&mut self, connection_id: u64) {
        self.h.closed(connection_id);
    }
}

/// What follows a [`Handler`]'s reply.
enum Then {
    Answered,
    Later,
    Close,
}

/// One request through a [`Handler`], as the reply's [`Data`]: every function
/// code goes to `other`, after the unit and the authorization.
struct Call<'a, 'h> {
    h: &'a mut (dyn Handler + 'h),
    from: &'a From,
    req: &'a [u8],
    id: i32,
    then: Then,
}

/// Never asked: every request goes to `other` ([`Data::takes_every_function`]).
const UNUSED: Refusal = Refusal::Exception(exception::ILLEGAL_FUNCTION);

impl Data for Call<'_, '_> {
    fn accept_unit(&mut self, unit: u8, req: &[u8]) -> bool {
        self.h.accept_unit(&self.from.info(req, self.id), unit)
    }

    fn read_bits(&mut self, _rq: &Request, _address: u16, _dest: &mut [u8]) -> std::result::Result<(), Refusal> {
        Err(UNUSED)
    }

    fn read_registers(&mut self, _rq: &Request, _address: u16, _dest: &mut [u16]) -> std::result::Result<(), Refusal> {
        Err(UNUSED)
    }

    fn write_bits(&mut self, _rq: &Request, _address: u16, _src: &[u8]) -> std::result::Result<(), Refusal> {
        Err(UNUSED)
    }

    fn write_registers(&mut self, _rq: &Request, _address: u16, _src: &[u16]) -> std::result::Result<(), Refusal> {
        Err(UNUSED)
    }

    fn takes_every_function(&self) -> bool {
        true
    }

    fn other(&mut self, _rq: &Request, pdu: &[u8], rsp: &mut [u8]) -> Option<std::result::Result<usize, Refusal>> {
        let info = self.from.info(self.req, self.id);
        let misuse = Refusal::Exception(exception::SLAVE_OR_SERVER_FAILURE);
        Some(match self.h.request(&info, pdu) {
            Reply::Pdu(v) if !v.is_empty() && v.len() <= rsp.len() => {
                rsp[..v.len()].copy_from_slice(&v);
                Ok(v.len())
            }
            Reply::Pdu(_) => Err(misuse),
            Reply::Exception(code) if (1..exception::MAX).contains(&code) => Err(Refusal::Exception(code)),
            Reply::Exception(_) => Err(misuse),
            Reply::Later => {
                self.then = Then::Later;
                Err(Refusal::Silent)
            }
            Reply::Nothing => Err(Refusal::Silent),
            Reply::Close => {
                self.then = Then::Close;
                Err(Refusal::Silent)
            }
        })
    }
}
