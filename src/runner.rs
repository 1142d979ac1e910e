//! The server runner (`modbus_server_*`): one thread, one epoll descriptor, every
//! client of a listening context (TCP, TCP-PI, RTU over TCP, Modbus/TCP Security),
//! or the own line of a serial or Modbus/UDP one. It drives the receive machine of the
//! blocking calls (`proto::session::receive`), on the same lines, by readiness, as
//! the event-driven client does (`crate::event`), and answers each request on the
//! one reply path (`crate::server::reply`, reached through the C layer's [`Answer`]).
//!
//! Each client is a context of its own, made from the listening one when it is
//! accepted (`Context::serving`): its socket is non-blocking, its TLS handshake
//! advances with readiness, its answers are queued on its line and leave together
//! once the requests of a read are answered (one `send` for a pipelined burst); a
//! client whose socket is full is read no more until it drains, so that it holds
//! no one else. A receive holds its buffer only while a request is arriving in
//! pieces; a client between requests holds its context and nothing else.
//!
//! Time: the runner's deadlines (a request's byte timeout, a client's idle
//! timeout, a serial line's silence) are kept in a heap and arm a timerfd in the
//! epoll set, so that the epoll descriptor alone says when there is work, for an
//! application that puts it in its own loop. A client is idle when no whole
//! request came from it for the idle timeout (bytes trickling in, or a handshake
//! that does not end, do not count): it is closed.
//!
//! Stopping (`modbus_server_stop`): a flag and an eventfd in the epoll set, both
//! safe to touch from a signal handler or another thread.

use std::cmp::Reverse;
use std::collections::BinaryHeap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use crate::context::Context;
use crate::engine::{self, Guard};
use crate::error::{Error, Result};
use crate::handle::lock::OwnerMutex;
use crate::outstanding::Receiving;
use crate::proto::Diag;
use crate::proto::frame::{MAX_ADU_LENGTH, MsgKind};
use crate::proto::session::receive::{Finished, Receiver, Step};
use crate::proto::session::server::Taken;
use crate::proto::session::{Recovery, Timeout};
use crate::session::{self, Driver};
use crate::transport::{self, AduBuf, epoll, listen};

/// What the runner asks of the C layer for each request.
pub trait Answer {
    /// Serial lines: the units are the answerer's to choose ([`Answer::accept_unit`]),
    /// not the context's slave alone.
    fn any_unit(&self) -> bool;
    /// The serial request `req` is about to be asked about ([`Answer::accept_unit`])
    /// on the context `g`.
    fn arrived(&mut self, g: &mut Guard<'_>);
    /// Whether a serial request `req` for `unit` is served.
    fn accept_unit(&mut self, unit: u8, req: &[u8]) -> bool;
    /// Answers `req`, the runner's request `id`, on the client's context `g`; the
    /// answer is queued on its line (a socket's) or sent (a serial line's). `None`:
    /// the answer comes later ([`Answers::give`] with `id`).
    /// [`CLOSE_CONNECTION`] closes the client's connection (a socket's; on the
    /// context's own line, nothing is answered).
    fn answer(&mut self, g: &mut Guard<'_>, req: &[u8], id: i32) -> Result<Option<usize>>;
    /// A client's connection ended (it closed it, the idle timeout, an error,
    /// [`CLOSE_CONNECTION`]): told from the run, after the event that closed it.
    fn closed(&mut self, _connection_id: u64) {}
}

/// What [`Answer::answer`] returns to have the client's connection closed, with no
/// answer (a connection lost).
pub const CLOSE_CONNECTION: Error = Error(libc::ECONNABORTED);

/// How long a listener rests after an accept failed (out of descriptors or memory)
/// before it is asked again, unless a client's close brings it back first.
pub const ACCEPT_RETRY: Duration = Duration::from_millis(100);

/// An answer given later (`modbus_server_answer` and its typed siblings).
pub enum Later {
    /// The answer's PDU, function code first.
    Pdu(Vec<u8>),
    /// The values of a register read (03, 04, 17).
    Registers(Vec<u16>),
    /// The bits of a bit read (01, 02), one per byte.
    Bits(Vec<u8>),
    /// A write is done: its usual answer.
    Done,
    /// An exception answer with this code.
    Exception(u8),
    /// No answer: the request is forgotten.
    Nothing,
}

/// What an answer given later must fit: the request's function code and the items
/// a read asks for.
#[derive(Clone, Copy)]
struct Expect {
    function: u8,
    nb: u16,
}

impl Expect {
    fn of(pdu: &[u8]) -> Expect {
        Expect { function: pdu.first().copied().unwrap_or(0), nb: crate::proto::reply::read_quantity(pdu) }
    }

    /// The request being answered, in one word (0: none).
    fn pack(self, id: i32) -> u64 {
        ((id as u64) << 32) | ((self.function as u64) << 16) | self.nb as u64
    }

    fn unpack(word: u64, id: i32) -> Option<Expect> {
        (word != 0 && (word >> 32) as i32 == id).then_some(Expect { function: (word >> 16) as u8, nb: word as u16 })
    }

    /// Whether `later` answers such a request.
    fn fits(self, later: &Later) -> bool {
        use crate::proto::reply::{Given, given_fits};
        match later {
            Later::Registers(v) => given_fits(self.function, self.nb, Given::Registers(v)),
            Later::Bits(v) => given_fits(self.function, self.nb, Given::Bits(v)),
            Later::Done => given_fits(self.function, self.nb, Given::Done),
            Later::Pdu(_) | Later::Exception(_) | Later::Nothing => true,
        }
    }
}

/// The answers given later, from any thread, for the run to send; and the requests
/// that wait for one, so that an answer that does not fit its request is refused
/// when it is given.
#[derive(Default)]
pub struct Answers {
    state: std::sync::Mutex<Given>,
    any: AtomicBool,
    /// The request being answered now ([`Expect::pack`]): a callback may hand its id
    /// to another thread, which may answer before the callback has returned.
    current: std::sync::atomic::AtomicU64,
}

#[derive(Default)]
struct Given {
    queue: Vec<(i32, Later)>,
    waiting: std::collections::HashMap<i32, Expect>,
}

/// A request whose answer comes later: whose it is, and what its answer needs
/// (its header and the start of its PDU).
struct Pending {
    slot: u32,
    generation: u32,
    /// The request's header and up to 7 bytes of its PDU.
    head: [u8; 16],
    head_len: u8,
    /// A UDP request's sender.
    peer: Option<crate::transport::udp::Peer>,
}

/// A pending request's (id, head, head length, UDP sender), as a drive reports it.
type Deferred = (i32, [u8; 16], u8, Option<crate::transport::udp::Peer>);

/// What a drive of one client needs besides the client, and what it reports.
struct Serving<'s, 'a> {
    /// The server's context (lent configuration); `None` when the client is it.
    server: Option<OnServer<'s>>,
    answer: &'a mut dyn Answer,
    /// Requests answered.
    answered: usize,
    /// The request ids, and the requests waiting for their answer.
    requests: &'a mut Requests,
    /// Requests whose answer comes later.
    later: Vec<Deferred>,
}

impl<'s, 'a> Serving<'s, 'a> {
    fn new(server: Option<OnServer<'s>>, answer: &'a mut dyn Answer, requests: &'a mut Requests) -> Self {
        Serving { server, answer, answered: 0, requests, later: Vec::new() }
    }
}

/// The runner's requests: the last id given, the requests whose answer comes later
/// (by id: an id is not given again while its request waits), the answers given.
#[derive(Default)]
struct Requests {
    next_id: i32,
    pending: std::collections::HashMap<i32, Pending>,
    answers: std::sync::Arc<Answers>,
}

/// Runs a function on the server's own context, locked (the C layer's handle).
pub type OnServer<'a> = &'a dyn Fn(&mut dyn FnMut(&mut Guard<'_>)) -> Result<()>;

/// The stop of a runner, reachable without the runner (see the module).
pub struct Stopper {
    stopping: AtomicBool,
    wake: i32,
}

impl Stopper {
    /// `modbus_server_stop`: the run under way (or the next) returns. Safe in a
    /// signal handler: an atomic store and a `write`.
    pub fn stop(&self) {
        self.stopping.store(true, Ordering::SeqCst);
        self.wake();
    }

    /// Wakes the run's wait (an answer given later is there to send).
    fn wake(&self) {
        epoll::signal(self.wake);
    }
}

impl Answers {
    fn lock(&self) -> std::sync::MutexGuard<'_, Given> {
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// `modbus_server_answer` and its typed siblings: the answer to request `id`,
    /// sent by the run under way (woken by `stopper`) or the next. EINVAL: no
    /// request `id` waits for an answer (never deferred, or answered already), or
    /// the answer does not fit it (registers for a bit read, a count that is not
    /// the request's, a write done for a read); the request still waits then.
    pub fn give(&self, stopper: &Stopper, id: i32, answer: Later) -> Result<()> {
        let mut state = self.lock();
        let expect = match state.waiting.get(&id) {
            Some(e) => *e,
            None => {
                let current = Expect::unpack(self.current.load(Ordering::SeqCst), id);
                match current {
                    Some(e) if !state.queue.iter().any(|(q, _)| *q == id) => e,
                    _ => return Err(Error::INVALID),
                }
            }
        };
        if !expect.fits(&answer) {
            return Err(Error::INVALID);
        }
        state.waiting.remove(&id);
        state.queue.push((id, answer));
        drop(state);
        self.any.store(true, Ordering::SeqCst);
        stopper.wake();
        Ok(())
    }

    /// Request `id` (`pdu`) is being answered now.
    fn answering(&self, id: i32, pdu: &[u8]) {
        self.current.store(Expect::of(pdu).pack(id), Ordering::SeqCst);
    }

    /// Request `id` (`pdu`) waits for an answer given later (unless one was given
    /// already, from the callback or another thread).
    fn wait_for(&self, id: i32, pdu: &[u8]) {
        let mut state = self.lock();
        if !state.queue.iter().any(|(q, _)| *q == id) {
            state.waiting.insert(id, Expect::of(pdu));
        }
    }

    fn take(&self) -> Vec<(i32, Later)> {
        if !self.any.swap(false, Ordering::SeqCst) {
            return Vec::new();
        }
        std::mem::take(&mut self.lock().queue)
    }
}

impl Drop for Stopper {
    fn drop(&mut self) {
        transport::close(self.wake);
    }
}

/// epoll keys below the clients'.
const KEY_WAKE: u64 = 0;
const KEY_TIMER: u64 = 1;
/// The listening socket, or the context's own line (serial, UDP).
const KEY_LINE: u64 = 2;
const FIRST_CLIENT: u64 = 3;

/// The epoll key of the client in `slot`: its generation tells a stale event (of a
/// client closed in the same batch, its slot taken again) from a current one.
fn client_key(slot: u32, generation: u32) -> u64 {
    (FIRST_CLIENT + slot as u64) | ((generation as u64) << 32)
}

/// Answers queued past this go out before more requests are read.
const QUEUE_HIGH: usize = 16 * MAX_ADU_LENGTH;

/// A client, or the context's own line: where its receive stands.
#[derive(Default)]
struct Conn {
    /// A request arriving in pieces (with its buffer), kept between readiness.
    receiving: Option<Box<Receiving>>,
    /// When it was accepted or its last whole request came.
    last: Duration,
    /// The deadline a timer is set for (a receive's wait).
    timer: Option<Duration>,
    /// An accepted client of a server context configured beyond libmodbus
    /// (`modbus_enable_diagnostics` and its siblings): that configuration, and its
    /// counters, are the server context's, lent to the client for each answer.
    shares_ext: bool,
}

/// One accepted client.
struct Client {
    ctx: OwnerMutex<Context>,
    conn: Conn,
    generation: u32,
    /// The events it is registered for.
    events: i16,
}

/// What a timer entry is for.
#[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Due {
    /// A receive's wait (byte timeout, a serial frame's silence).
    Wait,
    /// The idle timeout.
    Idle,
    /// The listener comes back after an accept failed ([`ACCEPT_RETRY`]).
    Retry,
}

/// (deadline, slot (u32::MAX: the context's own line), generation, what).
type Timer = Reverse<(Duration, u32, u32, Due)>;

const OWN_SLOT: u32 = u32::MAX;

/// The runner (see the module).
pub struct Runner {
    epfd: i32,
    timerfd: i32,
    /// The timerfd's deadline as armed.
    armed: Option<Duration>,
    /// The listening socket (-1 on a serial or UDP context), and whether the runner
    /// opened it (and closes it).
    listen_fd: i32,
    owns_listen: bool,
    /// The listening socket is in the epoll set (it leaves while the clients are
    /// at their maximum, or no descriptor is left for one more).
    listening: bool,
    /// A serial or UDP context's own line (its descriptor), served on the context
    /// itself.
    own_line: Option<(i32, Conn)>,
    clients: Vec<Option<Box<Client>>>,
    free: Vec<u32>,
    live: usize,
    max_clients: usize,
    /// At the maximum, a new connection is accepted and closed at once (mbusd's
    /// way), rather than left in the backlog.
    close_when_full: bool,
    /// The connection ids of the clients closed since the run last told the
    /// answerer ([`Answer::closed`]).
    closed: Vec<u64>,
    generation: u32,
    timers: BinaryHeap<Timer>,
    idle: Option<Duration>,
    /// A receive's state and buffer, kept for the next one.
    spare: Option<Box<Receiving>>,
    stopper: std::sync::Arc<Stopper>,
    /// Requests whose answer comes later, by id, and the answers given.
    requests: Requests,
}

impl Runner {
    /// A runner for the context `g`, for up to `max_clients` clients: a listening
    /// context's socket when it has one listening (`modbus_set_socket` with what
    /// `modbus_tcp_listen` returned), else the socket `modbus_tcp_listen` made for
    /// it (the libmodbus habit: listen first, then hand the context over; the
    /// application keeps it), else one it opens on the context's address; a serial
    /// context's line, opened if it is not; a Modbus/UDP context's socket, else the
    /// one `modbus_tcp_listen` bound for it (a duplicate of it becomes the
    /// context's), else one bound to its address. EMBTLSCONFIG: a Modbus/TCP
    /// Security context without its certificate, key and CA.
    pub fn new(g: &mut Guard<'_>, max_clients: usize) -> Result<Runner> {
        let wake = epoll::eventfd()?;
        let stopper = std::sync::Arc::new(Stopper { stopping: AtomicBool::new(false), wake });
        let epfd = epoll::create()?;
        let mut r = Runner {
            epfd,
            timerfd: -1,
            armed: None,
            listen_fd: -1,
            owns_listen: false,
            listening: false,
            own_line: None,
            clients: Vec::new(),
            free: Vec::new(),
            live: 0,
            max_clients,
            close_when_full: false,
            closed: Vec::new(),
            generation: 0,
            timers: BinaryHeap::new(),
            idle: Some(Duration::from_secs(60)),
            spare: None,
            stopper,
            requests: Requests::default(),
        };
        r.timerfd = epoll::timerfd()?;
        epoll::control(epfd, libc::EPOLL_CTL_ADD, wake, libc::POLLIN, KEY_WAKE)?;
        epoll::control(epfd, libc::EPOLL_CTL_ADD, r.timerfd, libc::POLLIN, KEY_TIMER)?;
        if !g.line.is_stream() {
            // A serial line, or a UDP socket: the context's own line, served on the
            // context itself.
            if g.fd() < 0 && g.line.is_datagram() {
                match g.line.listener() {
                    // The application keeps its socket (and closes it): the context
                    // serves on a descriptor of its own of that socket.
                    Some(bound) => g.line.adopt(crate::transport::udp::duplicate(bound)?),
                    None => {
                        let mut diag = g.diag();
                        g.line.bind(&mut diag)?;
                    }
                }
            } else if g.fd() < 0 {
                crate::session::connect(g)?;
            }
            let fd = g.fd();
            epoll::control(epfd, libc::EPOLL_CTL_ADD, fd, libc::POLLIN, KEY_LINE)?;
            r.own_line = Some((fd, Conn::default()));
            return Ok(r);
        }
        // A client's line is made now once, so that a context that cannot serve
        // (TLS settings missing) fails here rather than at each client.
        drop(g.serving()?);
        let fd = g.fd();
        if fd >= 0 && listen::is_listening(fd) {
            r.listen_fd = fd;
        } else if let Some(listening) = g.line.listener() {
            r.listen_fd = listening;
        } else {
            let backlog = max_clients.clamp(1, 4096) as i32;
            let mut diag = g.diag();
            let pi = matches!(g.line.settings(), crate::transport::link::Link::TcpPi(_));
            r.listen_fd = g.line.listen(pi, backlog, g.debug, &mut diag)?;
            r.owns_listen = true;
        }
        // SAFETY: plain fcntl on a descriptor: a listener that never blocks.
        unsafe {
            let flags = libc::fcntl(r.listen_fd, libc::F_GETFL);
            libc::fcntl(r.listen_fd, libc::F_SETFL, flags | libc::O_NONBLOCK);
        }
        epoll::control(epfd, libc::EPOLL_CTL_ADD, r.listen_fd, libc::POLLIN, KEY_LINE)?;
        r.listening = true;
        Ok(r)
    }

    /// The stop, for `modbus_server_stop`.
    pub fn stopper(&self) -> std::sync::Arc<Stopper> {
        std::sync::Arc::clone(&self.stopper)
    }

    /// Where answers given later go (`modbus_server_answer`).
    pub fn answers(&self) -> std::sync::Arc<Answers> {
        std::sync::Arc::clone(&self.requests.answers)
    }

    /// The epoll descriptor: readable when [`Runner::run`] has work.
    pub fn fd(&self) -> i32 {
        self.epfd
    }

    /// The socket it listens on (or the UDP socket it serves), -1 for a serial line.
    pub fn socket(&self) -> i32 {
        match &self.own_line {
            Some((fd, _)) if self.listen_fd < 0 => *fd,
            _ => self.listen_fd,
        }
    }

    /// Clients connected now.
    pub fn clients(&self) -> usize {
        self.live
    }

    /// At the maximum of clients, accept a new connection and close it at once
    /// (true), or leave it in the listening socket's backlog (false, the default).
    pub fn set_close_when_full(&mut self, on: bool) {
        self.close_when_full = on;
        self.resume_listening();
    }

    /// `modbus_server_set_idle_timeout` (zero: none).
    pub fn set_idle_timeout(&mut self, t: Timeout) {
        self.idle = (!t.is_zero()).then(|| t.duration());
        if let Some(idle) = self.idle {
            // Every client is looked at again under the new timeout.
            for (slot, c) in self.clients.iter().enumerate() {
                if let Some(c) = c {
                    self.timers.push(Reverse((c.conn.last + idle, slot as u32, c.generation, Due::Idle)));
                }
            }
        }
        self.rearm();
    }

    /// `modbus_server_run`: accepts, handshakes, reads and answers, closes idle
    /// clients, for `timeout` (`None`: until stopped; zero: what is ready now).
    /// Returns the requests answered.
    pub fn run(&mut self, timeout: Option<Duration>, server: OnServer<'_>, answer: &mut dyn Answer) -> Result<usize> {
        let end = timeout.map(|t| transport::now() + t);
        let mut events = [libc::epoll_event { events: 0, u64: 0 }; 256];
        let mut answered = 0;
        loop {
            self.tell_closed(answer);
            if self.stopper.stopping.swap(false, Ordering::SeqCst) {
                epoll::drain(self.stopper.wake);
                return Ok(answered);
            }
            let wait_ms = match end {
                None => -1,
                Some(end) => {
                    let left = end.saturating_sub(transport::now());
                    // Rounded up: the wait never ends before `end`.
                    left.as_nanos().div_ceil(1_000_000).min(i32::MAX as u128) as i32
                }
            };
            let n = epoll::wait(self.epfd, &mut events, wait_ms)?;
            for ev in &events[..n] {
                let key = ev.u64;
                let revents = { ev.events } as u16 as i16;
                match key {
                    // A stop (seen above) or an answer given later (sent below).
                    KEY_WAKE => epoll::drain(self.stopper.wake),
                    KEY_TIMER => epoll::drain(self.timerfd),
                    KEY_LINE if self.own_line.is_some() => answered += self.own_line_ready(server, answer, true),
                    KEY_LINE => self.accept(server),
                    _ => answered += self.client_ready(key, revents, server, answer),
                }
            }
            answered += self.fire_timers(server, answer);
            answered += self.send_later(server);
            if end.is_some_and(|e| transport::now() >= e) && !self.stopper.stopping.load(Ordering::SeqCst) {
                self.tell_closed(answer);
                return Ok(answered);
            }
        }
    }

    /// Tells the answerer of the clients closed since it was last told.
    fn tell_closed(&mut self, answer: &mut dyn Answer) {
        for id in self.closed.drain(..) {
            answer.closed(id);
        }
    }

    /// Accepts the clients waiting, up to the maximum (beyond it, with
    /// `close_when_full`, accepts and closes them).
    fn accept(&mut self, server: OnServer<'_>) {
        loop {
            let full = self.live >= self.max_clients;
            if full && !self.close_when_full {
                break;
            }
            let (fd, peer) = match listen::accept_now(self.listen_fd) {
                Ok(Some(accepted)) => accepted,
                Ok(None) => return,
                Err(e) => {
                    // Out of descriptors or memory: the listener rests (a
                    // level-triggered listener would report at once again) until a
                    // client leaves or the retry timer comes, whichever is first:
                    // descriptors freed elsewhere in the process (another runner's
                    // clients) bring it back too.
                    let _ = server(&mut |g| session::error_print(g, e, Some("accept")));
                    self.pause_listening();
                    self.timers.push(Reverse((transport::now() + ACCEPT_RETRY, OWN_SLOT, 0, Due::Retry)));
                    self.rearm();
                    return;
                }
            };
            if full {
                let live = self.live;
                let _ = server(&mut |g| {
                    if g.debug {
                        g.diag().out(format_args!("Connection refused: {live} clients already\n"));
                    }
                });
                transport::close(fd);
                continue;
            }
            let mut made = None;
            let _ = server(&mut |g| {
                if g.debug {
                    listen::report_accept(&mut g.diag(), peer.as_deref());
                }
                made = Some(g.serving().map(|c| (c, g.server_ext.is_some())));
            });
            let (mut ctx, shares_ext) = match made {
                Some(Ok(made)) => made,
                _ => {
                    transport::close(fd);
                    continue;
                }
            };
            if ctx.line.accept_started(fd).is_err() {
                continue;
            }
            ctx.connection = crate::context::Connection::accepted(fd);
            // (A server's handshake starts with the client's hello: POLLIN too.)
            let events = libc::POLLIN;
            let slot = match self.free.pop() {
                Some(s) => s,
                None => {
                    self.clients.push(None);
                    (self.clients.len() - 1) as u32
                }
            };
            self.generation = self.generation.wrapping_add(1);
            let generation = self.generation;
            let key = client_key(slot, generation);
            if epoll::control(self.epfd, libc::EPOLL_CTL_ADD, fd, events, key).is_err() {
                ctx.line.close();
                self.free.push(slot);
                continue;
            }
            let now = transport::now();
            let conn = Conn { last: now, shares_ext, ..Conn::default() };
            self.clients[slot as usize] =
                Some(Box::new(Client { ctx: OwnerMutex::new(ctx), conn, generation, events }));
            self.live += 1;
            if let Some(idle) = self.idle {
                self.timers.push(Reverse((now + idle, slot, generation, Due::Idle)));
                self.rearm();
            }
        }
        self.pause_listening();
    }

    fn pause_listening(&mut self) {
        if self.listening {
            let _ = epoll::control(self.epfd, libc::EPOLL_CTL_DEL, self.listen_fd, 0, KEY_LINE);
            self.listening = false;
        }
    }

    fn resume_listening(&mut self) {
        if !self.listening && self.listen_fd >= 0 && (self.live < self.max_clients || self.close_when_full) {
            self.listening =
                epoll::control(self.epfd, libc::EPOLL_CTL_ADD, self.listen_fd, libc::POLLIN, KEY_LINE).is_ok();
        }
    }

    /// A client's socket is ready.
    fn client_ready(&mut self, key: u64, revents: i16, server: OnServer<'_>, answer: &mut dyn Answer) -> usize {
        let slot = (key & 0xFFFF_FFFF) - FIRST_CLIENT;
        let generation = (key >> 32) as u32;
        let readable = revents & (libc::POLLIN | libc::POLLERR | libc::POLLHUP) != 0;
        self.drive_client(slot as u32, generation, readable, server, answer)
    }

    /// Drives the client in `slot` (if it is still the one of `generation`).
    fn drive_client(
        &mut self,
        slot: u32,
        generation: u32,
        readable: bool,
        server: OnServer<'_>,
        answer: &mut dyn Answer,
    ) -> usize {
        let Some(Some(c)) = self.clients.get_mut(slot as usize) else { return 0 };
        if c.generation != generation {
            return 0;
        }
        let mut sv = Serving::new(Some(server), answer, &mut self.requests);
        let result = {
            let mut g = c.ctx.lock();
            drive(&mut g, &mut c.conn, readable, &mut self.spare, &mut sv)
        };
        let answered = sv.answered;
        for (id, head, head_len, peer) in sv.later {
            self.requests.pending.insert(id, Pending { slot, generation, head, head_len, peer });
        }
        match result {
            Ok((events, until)) => {
                if events != c.events {
                    let fd = c.ctx.lock().fd();
                    let key = client_key(slot, generation);
                    if epoll::control(self.epfd, libc::EPOLL_CTL_MOD, fd, events, key).is_ok() {
                        c.events = events;
                    }
                }
                if let Some(t) = until {
                    if c.conn.timer != Some(t) {
                        c.conn.timer = Some(t);
                        self.timers.push(Reverse((t, slot, generation, Due::Wait)));
                        self.rearm();
                    }
                }
            }
            Err(_) => self.close_client(slot),
        }
        answered
    }

    /// The context's own line (serial, UDP) is ready (or a deadline of its receive
    /// came).
    fn own_line_ready(&mut self, server: OnServer<'_>, answer: &mut dyn Answer, readable: bool) -> usize {
        let Some((_, conn)) = self.own_line.as_mut() else { return 0 };
        let spare = &mut self.spare;
        // (The context is the server's: nothing to lend.)
        let mut sv = Serving::new(None, answer, &mut self.requests);
        let mut until = None;
        let _ = server(&mut |g| {
            // A runner drives the context: nothing may wait in it (no sleep before
            // a flush while other peers wait, a stop waits for no sleep).
            let was = std::mem::replace(&mut g.runner, true);
            if let Ok((_, u)) = drive(g, conn, readable, spare, &mut sv) {
                until = u;
            }
            g.runner = was;
        });
        let answered = sv.answered;
        for (id, head, head_len, peer) in sv.later {
            self.requests.pending.insert(id, Pending { slot: OWN_SLOT, generation: 0, head, head_len, peer });
        }
        if let Some(t) = until {
            if conn.timer != Some(t) {
                conn.timer = Some(t);
                self.timers.push(Reverse((t, OWN_SLOT, 0, Due::Wait)));
                self.rearm();
            }
        }
        answered
    }

    /// Sends the answers given later (`modbus_server_answer`) to the clients whose
    /// requests they answer; those of clients gone are dropped. Returns the answers
    /// sent.
    fn send_later(&mut self, server: OnServer<'_>) -> usize {
        let mut sent_count = 0;
        for (id, later) in self.requests.answers.take() {
            let counts = !matches!(later, Later::Nothing);
            let Some(p) = self.requests.pending.remove(&id) else { continue };
            if p.slot == OWN_SLOT {
                // The context's own line (serial, UDP): answered on the context.
                let mut later = Some(later);
                let _ = server(&mut |g| {
                    if let Some(later) = later.take() {
                        let _ = send_answer(g, &p, later);
                    }
                });
                sent_count += usize::from(counts);
                continue;
            }
            let Some(Some(c)) = self.clients.get_mut(p.slot as usize) else { continue };
            if c.generation != p.generation {
                continue;
            }
            let mut g = c.ctx.lock();
            let sent = send_answer(&mut g, &p, later);
            sent_count += usize::from(counts && sent.is_ok());
            let events = match sent {
                Ok(true) => libc::POLLIN,
                Ok(false) => libc::POLLOUT,
                Err(_) => {
                    drop(g);
                    self.close_client(p.slot);
                    continue;
                }
            };
            if events != c.events {
                let fd = g.fd();
                if epoll::control(self.epfd, libc::EPOLL_CTL_MOD, fd, events, client_key(p.slot, p.generation)).is_ok()
                {
                    c.events = events;
                }
            }
        }
        sent_count
    }

    /// Closes the client in `slot`.
    fn close_client(&mut self, slot: u32) {
        let Some(c) = self.clients.get_mut(slot as usize).and_then(Option::take) else { return };
        let mut c = c;
        let ctx = c.ctx.get_mut();
        let fd = ctx.fd();
        // A failed handshake has closed the socket already (fd -1).
        if fd >= 0 {
            let _ = epoll::control(self.epfd, libc::EPOLL_CTL_DEL, fd, 0, 0);
        }
        if ctx.debug {
            ctx.diag().out(format_args!("Connection closed on socket {fd}\n"));
        }
        // What is still queued goes if the socket takes it at once.
        let _ = ctx.line.send_queued();
        self.closed.push(ctx.connection.id);
        ctx.line.close();
        drop(c);
        self.free.push(slot);
        self.live -= 1;
        self.resume_listening();
    }

    /// Runs the deadlines that came; re-arms the timer for the next.
    fn fire_timers(&mut self, server: OnServer<'_>, answer: &mut dyn Answer) -> usize {
        let mut answered = 0;
        let now = transport::now();
        while let Some(&Reverse((at, slot, generation, due))) = self.timers.peek() {
            if at > now {
                break;
            }
            self.timers.pop();
            if due == Due::Retry {
                self.resume_listening();
                continue;
            }
            if slot == OWN_SLOT {
                if let Some((_, conn)) = self.own_line.as_mut() {
                    if conn.timer == Some(at) {
                        conn.timer = None;
                        answered += self.own_line_ready(server, answer, false);
                    }
                }
                continue;
            }
            let Some(Some(c)) = self.clients.get_mut(slot as usize) else { continue };
            if c.generation != generation {
                continue;
            }
            match due {
                Due::Wait => {
                    if c.conn.timer == Some(at) {
                        c.conn.timer = None;
                        answered += self.drive_client(slot, generation, false, server, answer);
                    }
                }
                Due::Idle => {
                    let Some(idle) = self.idle else { continue };
                    let next = c.conn.last + idle;
                    if next > now {
                        self.timers.push(Reverse((next, slot, generation, Due::Idle)));
                    } else {
                        if c.ctx.get_mut().debug {
                            c.ctx.get_mut().diag().out(format_args!("Idle client closed\n"));
                        }
                        self.close_client(slot);
                    }
                }
                // (Taken above.)
                Due::Retry => {}
            }
        }
        self.rearm();
        answered
    }

    /// Arms the timerfd for the earliest deadline.
    fn rearm(&mut self) {
        let next = self.timers.peek().map(|Reverse((at, ..))| *at);
        if next != self.armed {
            self.armed = next;
            epoll::arm(self.timerfd, next);
        }
    }
}

impl Drop for Runner {
    fn drop(&mut self) {
        for slot in 0..self.clients.len() as u32 {
            self.close_client(slot);
        }
        if self.owns_listen {
            transport::close(self.listen_fd);
        }
        transport::close(self.timerfd);
        transport::close(self.epfd);
    }
}

/// Drives one client (or the own line): the handshake, the queued answers, the
/// requests that came. Returns what to wait for next (the events, and a receive's
/// deadline), or an error that ends the client.
fn drive(
    g: &mut Guard<'_>,
    c: &mut Conn,
    mut readable: bool,
    spare: &mut Option<Box<Receiving>>,
    sv: &mut Serving<'_, '_>,
) -> Result<(i16, Option<Duration>)> {
    if g.line.handshaking() {
        let debug = g.debug;
        let mut diag = g.diag();
        if let Some(events) = g.line.handshake_step(false, debug, &mut diag)? {
            return Ok((events, None));
        }
    }
    if g.line.queued() > 0 && !g.line.send_queued()? {
        // The client does not read its answers: nothing more is read from it.
        return Ok((libc::POLLOUT, None));
    }
    let datagrams = g.line.is_datagram();
    let mut until = None;
    loop {
        let skipping = g.server.kind() == MsgKind::Confirmation;
        if c.receiving.is_none() {
            // (The wait for the answer of another unit's slave starts at once, as
            // libmodbus's next receive would start it.)
            if !readable && g.line.pending() == 0 && g.rx.available().is_empty() && !skipping {
                break;
            }
            c.receiving = Some(start(g, spare, sv.answer.any_unit()));
        }
        let r = c.receiving.as_mut().expect("made above");
        let finished = session::drive_ready(g, r, &mut readable);
        let Some(f) = finished else {
            // Waiting: a receive with nothing of its message is dropped (it starts
            // again when bytes come); one under way keeps its buffer and deadline.
            let r = c.receiving.take().expect("under way");
            if datagrams && r.machine.started() {
                // A datagram holds a whole request: one cut short is dropped (its
                // rest would be the next datagram's bytes).
                if g.debug {
                    g.diag().err(format_args!("ERROR Datagram shorter than its request: dropped\n"));
                }
                g.rx.clear();
                g.line.discard();
                *spare = Some(r);
            } else if r.machine.started() || skipping {
                if let Step::Wait { until: Some(t) } = r.step {
                    until = Some(t);
                }
                c.receiving = Some(r);
            } else {
                *spare = Some(r);
            }
            break;
        };
        let r = c.receiving.take().expect("ended");
        let end = finish(g, c, f, &r.msg[..], sv);
        *spare = Some(r);
        if datagrams {
            // What followed the request in its datagram is no request.
            g.rx.clear();
            g.line.discard();
        }
        end?;
        if g.line.queued() > QUEUE_HIGH && !g.line.send_queued()? {
            return Ok((libc::POLLOUT, None));
        }
    }
    if g.line.queued() > 0 && !g.line.send_queued()? {
        return Ok((libc::POLLOUT, until));
    }
    Ok((libc::POLLIN, until))
}

/// A receive that starts now on `g`'s line (see `session::settings`).
fn start(g: &mut Guard<'_>, spare: &mut Option<Box<Receiving>>, any_unit: bool) -> Box<Receiving> {
    let now = transport::now();
    let mut s = session::settings(g, g.server.kind(), Driver::Runner, None);
    s.any_unit = any_unit;
    let machine = Receiver::new(&s, || now);
    let mut r = match spare.take() {
        Some(mut r) => {
            r.machine = machine;
            r.settings = s;
            r
        }
        None => Box::new(Receiving { machine, settings: s, step: Step::Wait { until: None }, msg: AduBuf::new() }),
    };
    let started = &mut *r;
    started.step = started.machine.start(&s, &mut started.msg[..], &mut g.rx, || now);
    r
}

/// A receive ended: read by the one reader (`session::conclude`) and the server
/// session (`session::taken`, which counts it on the diagnostics bus counters): a
/// request is answered; a serial frame for another unit makes the next frame one to
/// skip; a failure ends a client (the context's own line drops what it holds).
fn finish(g: &mut Guard<'_>, c: &mut Conn, f: Finished, msg: &[u8], sv: &mut Serving<'_, '_>) -> Result<()> {
    // The context's own line (serial, UDP) recovers from what a client's
    // connection is closed for.
    let own = !g.line.is_stream();
    let r = session::conclude(g, msg, &f, Driver::Runner);
    // A client of a server context configured beyond libmodbus gets its
    // configuration and counters, lent for the count and the answer.
    let lend = sv.server.filter(|_| c.shares_ext);
    let lent = |g: &mut Guard<'_>| {
        if let Some(server) = lend {
            let _ = server(&mut |s| std::mem::swap(&mut s.server_ext, &mut g.server_ext));
        }
    };
    lent(g);
    // (Asked of serial framings only.)
    let answer = &mut *sv.answer;
    let any_unit = answer.any_unit();
    if any_unit {
        answer.arrived(g);
    }
    let frame = match r {
        Ok(crate::session::Received::Frame(len)) => len,
        _ => 0,
    };
    let taken = session::taken(g, msg, &r, |unit| !any_unit || answer.accept_unit(unit, &msg[..frame]));
    let result = match taken {
        Taken::Request(len) => {
            c.last = transport::now();
            let id = next_id(&mut sv.requests.next_id, &sv.requests.pending);
            let pdu = crate::proto::reply::pdu(g.framing(), &msg[..len]);
            let answers = &*sv.requests.answers;
            answers.answering(id, pdu);
            let answered = sv.answer.answer(g, &msg[..len], id);
            if let Ok(None) = answered {
                answers.wait_for(id, pdu);
            }
            answers.current.store(0, Ordering::SeqCst);
            match answered {
                Ok(Some(_)) => {
                    sv.answered += 1;
                    Ok(())
                }
                Ok(None) => {
                    let h = g.framing().header_length();
                    let n = (h + 7).min(len - g.framing().checksum_length().min(len));
                    let mut head = [0u8; 16];
                    head[..n].copy_from_slice(&msg[..n]);
                    sv.later.push((id, head, n as u8, g.line.peer()));
                    Ok(())
                }
                Err(e) if !own && e.line_lost() => Err(e),
                Err(_) => Ok(()),
            }
        }
        Taken::Skipped | Taken::NotServed(_) | Taken::OtherSlave => Ok(()),
        Taken::Failed(_) if own => {
            // A bad checksum, a frame cut short or too long: what the line holds
            // goes, and the next frame starts clean.
            session::recover(g, Recovery::Flush, Driver::Runner);
            Ok(())
        }
        Taken::Failed(e) if e == Error::BAD_CRC => {
            session::recover(g, Recovery::Flush, Driver::Runner);
            Ok(())
        }
        Taken::Failed(e) => Err(e),
    };
    lent(g);
    result
}

/// The next request id: 1 to `i32::MAX`, wrapping, never one still waiting for
/// its answer.
fn next_id(last: &mut i32, pending: &std::collections::HashMap<i32, Pending>) -> i32 {
    loop {
        *last = if *last == i32::MAX { 1 } else { (*last).max(0) + 1 };
        if !pending.contains_key(last) {
            return *last;
        }
    }
}

/// Sends the answer given later to the request `p` on `g`'s line: true when it is
/// out, false when part waits for the socket to be writable.
fn send_answer(g: &mut Guard<'_>, p: &Pending, later: Later) -> Result<bool> {
    use crate::proto::frame::MAX_ADU_LENGTH as MAX;
    use crate::proto::reply::{Given, given_pdu};
    let framing = g.framing();
    let head = &p.head[..p.head_len as usize];
    let h = framing.header_length();
    let mut out = [0u8; MAX];
    let tid = framing.response_tid(head);
    let pdu_room = h..h + crate::proto::limits::MAX_PDU_LENGTH;
    let given = match &later {
        Later::Nothing => return Ok(true),
        Later::Exception(_) | Later::Pdu(_) => None,
        Later::Registers(v) => Some(Given::Registers(v)),
        Later::Bits(v) => Some(Given::Bits(v)),
        Later::Done => Some(Given::Done),
    };
    let len = match (&later, given) {
        (Later::Exception(code), _) => Some(crate::proto::reply::exception_response(framing, head, *code, &mut out)),
        (Later::Pdu(pdu), _) => {
            framing.write_header(&mut out, head[h - 1], tid);
            out[h..h + pdu.len()].copy_from_slice(pdu);
            Some(h + pdu.len())
        }
        (_, Some(given)) => {
            framing.write_header(&mut out, head[h - 1], tid);
            given_pdu(&head[h..], given, &mut out[pdu_room]).map(|n| h + n)
        }
        _ => None,
    };
    // (Checked when given: an answer that does not fit its request never comes here.)
    let Some(len) = len else { return Ok(true) };
    if let Some(peer) = p.peer {
        g.line.set_peer(peer);
    }
    engine::send_msg(g, &mut out, len)?;
    g.line.send_queued()
}
