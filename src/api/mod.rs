//! The safe Rust API of the library (`rsmodbus::api`): what the C API (`ffi/`) is
//! for C programs, for Rust programs, without `unsafe` on their side. One context
//! ([`Modbus`]: a client, the event-driven client, or what a [`Server`] serves),
//! a server that runs itself ([`Server`], answering through a [`Handler`]), and a
//! `ppoll` over descriptors ([`poll`]) for a program's own loop.
//!
//! A [`Modbus`] owns the same handle a `modbus_t *` is (`handle::Handle<Context>`):
//! every call locks it as the C calls do, so a close from another thread (or a
//! signal handler) acts on it the same way.

mod server;

pub use server::{Handler, Reply, RequestInfo, Server};

use std::ffi::{CStr, CString};
use std::os::fd::RawFd;
use std::path::Path;
use std::ptr::NonNull;
use std::sync::{Arc, Mutex};
use std::time::Duration;

use crate::context::{Context, RECOVERY_LINK};
use crate::engine::{self, Guard};
use crate::event;
use crate::handle::{self, Handle};
use crate::outstanding::{Completion as Payload, Deliver};
use crate::proto::request::Request;
use crate::transport::link::{RTU_RS485, RTU_RTS_DOWN, RTU_RTS_NONE, RTU_RTS_UP};
use crate::transport::tls;

pub use crate::error::Error;
pub use crate::runner::Later;

/// The API's results: an [`Error`] is the errno value the C call would set.
pub type Result<T> = std::result::Result<T, Error>;

/// A serial line's parity.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Parity {
    None,
    Even,
    Odd,
}

impl Parity {
    fn letter(self) -> u8 {
        match self {
            Parity::None => b'N',
            Parity::Even => b'E',
            Parity::Odd => b'O',
        }
    }
}

/// How the RTS line is driven around a send (`MODBUS_RTU_RTS_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Rts {
    None,
    /// RTS up while sending.
    Up,
    /// RTS down while sending.
    Down,
}

/// A completed request of the event-driven client ([`Modbus::send_raw`]).
#[derive(Debug, PartialEq, Eq)]
pub struct Completion {
    /// The id [`Modbus::send_raw`] returned.
    pub id: i32,
    /// The answer's PDU, function code first (an exception answer too); empty for a
    /// broadcast on a serial line, which completes once it is sent. Or the error
    /// (a timeout, a lost line, an answer from another unit or of another function).
    pub result: Result<Vec<u8>>,
}

/// What the authorization callback of a Modbus/TCP Security server is asked
/// ([`Modbus::set_tls_authorization`]): the client's role (`None`: its
/// certificate has none), the unit, the function code and one range the request
/// touches.
#[derive(Clone, Copy, Debug)]
pub struct Authorize<'a> {
    pub role: Option<&'a str>,
    pub unit: u8,
    pub function: u8,
    pub address: u16,
    pub count: u16,
}

/// One context (a `modbus_t`): `Send`, not `Sync`. Dropping it closes and frees it;
/// the event-driven requests pending are dropped with it.
pub struct Modbus {
    handle: NonNull<Handle<Context>>,
}

// SAFETY: the handle is a context behind its own lock (`handle::call` serialises
// every use); the C API hands the same handles between threads.
unsafe impl Send for Modbus {}

/// A string argument as C would pass it: EINVAL when it holds a NUL.
fn c_string(s: &str) -> Result<CString> {
    CString::new(s).map_err(|_| Error::INVALID)
}

/// A count the C constructors take as an `int`.
fn c_int(n: u32) -> Result<i32> {
    i32::try_from(n).map_err(|_| Error::INVALID)
}

impl Modbus {
    /// A context made by a constructor of `Context`, behind a handle of its own.
    pub(crate) fn from_context(ctx: Result<Context>) -> Result<Modbus> {
        let ptr = Handle::new(ctx?);
        Ok(Modbus { handle: NonNull::new(ptr).expect("a Box is never NULL") })
    }

    /// The handle, for C (`modbus_new_*`); [`Modbus::from_raw`] takes it back.
    pub(crate) fn into_raw(self) -> *mut Handle<Context> {
        let ptr = self.handle.as_ptr();
        std::mem::forget(self);
        ptr
    }

    /// The handle a `modbus_new_*` handed out, owned again.
    ///
    /// # Safety
    /// `ptr` was returned by [`Modbus::into_raw`], is live, and is not used through
    /// the C API afterwards (it belongs to the value returned).
    pub(crate) unsafe fn from_raw(ptr: *mut Handle<Context>) -> Option<Modbus> {
        NonNull::new(ptr).map(|handle| Modbus { handle })
    }

    /// Frees the context without closing its line first (`modbus_free`, as
    /// libmodbus: unless a call is inside it, see `handle::free`).
    pub(crate) fn free(self) {
        let ptr = self.into_raw();
        // SAFETY: the handle was this value's, live, and is not used after the free.
        unsafe { handle::free(ptr) }
    }

    /// Runs `f` on the locked context, as a C call does (`handle::call`).
    pub(crate) fn call<R>(&self, f: impl FnOnce(&mut Guard<'_>) -> Result<R>) -> Result<R> {
        // SAFETY: the handle is live while `self` is (freed only by its drop). No
        // thread of a Rust program is ended by `pthread_cancel` (which `call` defers
        // over the call), so no frame with a destructor is skipped.
        unsafe { handle::call(self.handle.as_ptr(), f) }
    }

    /// An RTU context on the serial line `device` (`modbus_new_rtu`).
    pub fn new_rtu(device: &str, baud: u32, parity: Parity, data_bits: u8, stop_bits: u8) -> Result<Modbus> {
        let device = c_string(device)?;
        let baud = c_int(baud)?;
        Modbus::from_context(Context::new_rtu(Some(&device), baud, parity.letter(), data_bits.into(), stop_bits.into()))
    }

    /// A Modbus ASCII context on the serial line `device` (`modbus_new_ascii`).
    pub fn new_ascii(device: &str, baud: u32, parity: Parity, data_bits: u8, stop_bits: u8) -> Result<Modbus> {
        let device = c_string(device)?;
        let baud = c_int(baud)?;
        Modbus::from_context(Context::new_ascii(
            Some(&device),
            baud,
            parity.letter(),
            data_bits.into(),
            stop_bits.into(),
        ))
    }

    /// Node and service as `modbus_new_*_pi` take them.
    fn pi(
        node: Option<&str>,
        service: &str,
        make: fn(Option<&CStr>, Option<&CStr>) -> Result<Context>,
    ) -> Result<Modbus> {
        let node = node.map(c_string).transpose()?;
        let service = c_string(service)?;
        Modbus::from_context(make(node.as_deref(), Some(&service)))
    }

    /// A Modbus/TCP context, any address family (`modbus_new_tcp_pi`); `node`
    /// `None`: any address (a server).
    pub fn new_tcp(node: Option<&str>, service: &str) -> Result<Modbus> {
        Modbus::pi(node, service, Context::new_tcp_pi)
    }

    /// RTU frames over TCP (`modbus_new_rtu_tcp_pi`).
    pub fn new_rtu_tcp(node: Option<&str>, service: &str) -> Result<Modbus> {
        Modbus::pi(node, service, Context::new_rtu_tcp_pi)
    }

    /// Modbus/UDP (`modbus_new_udp_pi`).
    pub fn new_udp(node: Option<&str>, service: &str) -> Result<Modbus> {
        Modbus::pi(node, service, Context::new_udp_pi)
    }

    /// Modbus/TCP Security (`modbus_new_tcp_tls_pi`).
    pub fn new_tls(node: Option<&str>, service: &str) -> Result<Modbus> {
        Modbus::pi(node, service, Context::new_tcp_tls_pi)
    }

    /// Runs `f` on the TLS state; EINVAL for a context that is not a TLS one.
    fn with_tls<R>(&mut self, f: impl FnOnce(&mut tls::Tls) -> Result<R>) -> Result<R> {
        self.call(|g| match g.line.security_mut() {
            Some(t) => f(t),
            None => Err(Error::INVALID),
        })
    }

    /// The certificate chain and private key, PEM files (`modbus_set_tls_certificate`).
    pub fn set_tls_certificate(&mut self, cert: &Path, key: &Path) -> Result<()> {
        let chain = tls::read_file(cert)?;
        let key = tls::read_file(key)?;
        self.with_tls(|t| t.settings.set_certificate_pem(&chain, &key, None))
    }

    /// The CA certificate(s), a PEM file (`modbus_set_tls_ca`).
    pub fn set_tls_ca(&mut self, ca: &Path) -> Result<()> {
        let pem = tls::read_file(ca)?;
        self.with_tls(|t| t.settings.set_ca_pem(&pem))
    }

    /// The server's authorization callback (`modbus_set_tls_authorization`): asked
    /// for each range a request touches before it is served; false refuses it
    /// (exception 01). A role that is not UTF-8 is refused without asking. It runs
    /// with the context unlocked, on the thread that serves.
    pub fn set_tls_authorization(&mut self, f: Box<dyn FnMut(&Authorize<'_>) -> bool + Send>) -> Result<()> {
        let f = Mutex::new(f);
        let hook: tls::Authorize =
            Arc::new(move |role: Option<&CStr>, unit: u8, function: u8, address: u16, count: u16| {
                let role = match role.map(CStr::to_str) {
                    None => None,
                    Some(Ok(r)) => Some(r),
                    Some(Err(_)) => return false,
                };
                let mut f = f.lock().unwrap_or_else(|e| e.into_inner());
                f(&Authorize { role, unit, function, address, count })
            });
        self.with_tls(|t| {
            t.authorize = Some(hook);
            Ok(())
        })
    }

    /// Opens the line: connects, or opens and configures the serial line
    /// (`modbus_connect`).
    pub fn connect(&mut self) -> Result<()> {
        self.call(|g| crate::session::connect(g))
    }

    /// Closes the line (`modbus_close`); event-driven requests pending complete
    /// with ESHUTDOWN at the next [`Modbus::process`].
    pub fn close(&mut self) {
        // SAFETY: the handle is live while `self` is.
        unsafe { handle::close(self.handle.as_ptr()) }
    }

    /// The line is open.
    pub fn is_connected(&self) -> bool {
        // SAFETY: the handle is live while `self` is.
        unsafe { self.handle.as_ref() }.socket() >= 0
    }

    /// The response timeout (`modbus_set_response_timeout`); zero: EINVAL.
    pub fn set_response_timeout(&mut self, t: Duration) -> Result<()> {
        let sec = u32::try_from(t.as_secs()).map_err(|_| Error::INVALID)?;
        self.call(|g| g.set_response_timeout(sec, t.subsec_micros()))
    }

    /// The debug trace on stdout and stderr (`modbus_set_debug`).
    pub fn set_debug(&mut self, on: bool) {
        let _ = self.call(|g| {
            g.debug = on;
            Ok(())
        });
    }

    /// `MODBUS_ERROR_RECOVERY_LINK` on or off (`modbus_set_error_recovery`).
    pub fn set_link_recovery(&mut self, on: bool) -> Result<()> {
        self.call(|g| {
            if on {
                g.session.recovery |= RECOVERY_LINK;
            } else {
                g.session.recovery &= !RECOVERY_LINK;
            }
            Ok(())
        })
    }

    /// Runs `f` on a serial context; EINVAL for others.
    fn with_rtu<R>(&mut self, f: impl FnOnce(&mut Guard<'_>) -> Result<R>) -> Result<R> {
        self.call(|g| if g.rtu().is_none() { Err(Error::INVALID) } else { f(g) })
    }

    /// RS-485 mode (`modbus_rtu_set_serial_mode(ctx, MODBUS_RTU_RS485)`), after
    /// [`Modbus::connect`] (EBADF before).
    pub fn set_rs485(&mut self) -> Result<()> {
        self.with_rtu(|g| {
            let fd = g.fd();
            let Some(link) = g.rtu_mut() else { return Err(Error::INVALID) };
            crate::transport::rtu::set_serial_mode(fd, link, RTU_RS485)
        })
    }

    /// How RTS is driven around a send (`modbus_rtu_set_rts`).
    pub fn set_rts(&mut self, mode: Rts) -> Result<()> {
        let mode = match mode {
            Rts::None => RTU_RTS_NONE,
            Rts::Up => RTU_RTS_UP,
            Rts::Down => RTU_RTS_DOWN,
        };
        self.with_rtu(|g| {
            if let Some(l) = g.rtu_mut() {
                l.rts = mode;
            }
            engine::set_rts(g, mode != RTU_RTS_UP);
            Ok(())
        })
    }

    /// The application's RTS switch in place of the ioctl
    /// (`modbus_rtu_set_custom_rts`): called with true before a send and false
    /// after it, when an RTS mode is set, with the context unlocked.
    pub fn set_custom_rts(&mut self, f: Box<dyn FnMut(bool) + Send>) -> Result<()> {
        let f = Mutex::new(f);
        let hook: crate::context::RtsHook = Arc::new(move |on: bool| {
            let mut f = f.lock().unwrap_or_else(|e| e.into_inner());
            f(on)
        });
        self.with_rtu(|g| {
            if let Some(l) = g.rtu_mut() {
                l.custom_rts = Some(hook);
            }
            Ok(())
        })
    }

    /// The slave (unit) of the blocking calls (`modbus_set_slave`).
    pub fn set_slave(&mut self, unit: u8) -> Result<()> {
        self.call(|g| g.set_slave(unit.into()))
    }

    /// The bytes before the PDU in a message (`modbus_get_header_length`).
    pub fn header_length(&self) -> usize {
        self.call(|g| Ok(g.framing().header_length())).unwrap_or(0)
    }

    /// The bytes after the PDU in a message (`modbus_get_checksum_length`).
    pub fn checksum_length(&self) -> usize {
        self.call(|g| Ok(g.framing().checksum_length())).unwrap_or(0)
    }

    /// Sends `raw` (the unit, then the PDU) without waiting, as
    /// `modbus_send_raw_request_async` does; the answer comes as a [`Completion`]
    /// ([`Modbus::next_completion`]) with this id. EINVAL: `raw` not 2 to 254
    /// bytes; EAGAIN: the queue is full.
    pub fn send_raw(&mut self, raw: &[u8]) -> Result<i32> {
        let payload = Payload { callback: None, user_data: std::ptr::null_mut(), deliver: Deliver::Pdu };
        self.call(|g| submit_raw(g, raw, payload))
    }

    /// What to wait for (`modbus_get_pollfd`): the context's wake descriptor
    /// (readable: call [`Modbus::process`]) and how long until it is due anyway.
    pub fn poll_fd(&mut self) -> Result<(RawFd, Option<Duration>)> {
        self.call(|g| {
            let (fd, until) = event::wake_interest(g)?;
            Ok((fd, until.map(|t| t.saturating_sub(crate::transport::now()))))
        })
    }

    /// Does the I/O that is ready and what is due, without blocking
    /// (`modbus_process`); the completed requests wait for
    /// [`Modbus::next_completion`].
    pub fn process(&mut self) -> Result<()> {
        self.process_events(libc::POLLIN)
    }

    /// [`Modbus::process`] given what the wait reported of the wake descriptor
    /// (`revents`; 0, a wait that timed out, saves asking it what is ready).
    pub fn process_events(&mut self, revents: i16) -> Result<()> {
        self.call(|g| {
            event::process(g, revents, true)?;
            event::closed(g);
            event::watch(g);
            Ok(())
        })
    }

    /// How many requests may be on the wire at once on a TCP context (pipelining,
    /// `modbus_set_max_in_flight`): 1 to 256, default 1; a serial line has one.
    pub fn set_max_in_flight(&mut self, n: usize) -> Result<()> {
        let n = i32::try_from(n).map_err(|_| Error::INVALID)?;
        self.call(|g| event::set_max_in_flight(g, n))
    }

    /// The requests given and not completed (`modbus_pending`).
    pub fn pending(&self) -> usize {
        self.call(|g| Ok(event::pending(g))).unwrap_or(0)
    }

    /// The oldest completion not taken yet.
    pub fn next_completion(&mut self) -> Option<Completion> {
        let done = self.call(|g| Ok(event::take_done(g))).ok()??;
        let result = match done.result {
            Ok(_) => Ok(done.data),
            Err(errno) => Err(Error(errno)),
        };
        Some(Completion { id: done.id, result })
    }
}

/// Whether a raw request (the unit, then the PDU) of `len` bytes may be sent: 2 to
/// 254.
pub(crate) fn raw_length_ok(len: usize) -> bool {
    (2..=crate::proto::limits::MAX_PDU_LENGTH + 1).contains(&len)
}

/// Queues the raw request `raw` (the unit, then the PDU) on the event-driven
/// client of `g`, its answer to go as `payload` says (`send_raw`, and
/// `modbus_send_raw_request_async`): the request's id. EINVAL: not 2 to 254 bytes.
pub(crate) fn submit_raw(g: &mut Guard<'_>, raw: &[u8], payload: Payload) -> Result<i32> {
    if !raw_length_ok(raw.len()) {
        return Err(Error::INVALID);
    }
    event::submit(g, &Request::Raw { unit: raw[0], pdu: &raw[1..] }, payload)
}

impl Drop for Modbus {
    fn drop(&mut self) {
        let ptr = self.handle.as_ptr();
        // SAFETY: the handle is this value's, live, and not used after the free.
        unsafe {
            handle::close(ptr);
            handle::free(ptr);
        }
    }
}

/// A descriptor to wait on, as `struct pollfd` ([`poll`]).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PollFd {
    pub fd: RawFd,
    pub events: i16,
    pub revents: i16,
}

const _: () = {
    assert!(size_of::<PollFd>() == size_of::<libc::pollfd>());
    assert!(align_of::<PollFd>() == align_of::<libc::pollfd>());
    assert!(std::mem::offset_of!(PollFd, fd) == std::mem::offset_of!(libc::pollfd, fd));
    assert!(std::mem::offset_of!(PollFd, events) == std::mem::offset_of!(libc::pollfd, events));
    assert!(std::mem::offset_of!(PollFd, revents) == std::mem::offset_of!(libc::pollfd, revents));
};

/// `ppoll` over `fds` for up to `timeout` (`None`: until one is ready): the number
/// ready. A descriptor that is not open is reported (POLLNVAL), never touched; a
/// negative one is skipped. EINTR when a signal came.
pub fn poll(fds: &mut [PollFd], timeout: Option<Duration>) -> Result<usize> {
    let ts = timeout.map(crate::transport::to_timespec);
    let ts_ptr = ts.as_ref().map_or(std::ptr::null(), |t| t as *const libc::timespec);
    // SAFETY: `PollFd` has the layout of `struct pollfd` (checked above); the array
    // and the timespec are live for the call, which writes only `revents`.
    let n = unsafe { libc::ppoll(fds.as_mut_ptr().cast(), fds.len() as libc::nfds_t, ts_ptr, std::ptr::null()) };
    if n < 0 { Err(crate::transport::last_error()) } else { Ok(n as usize) }
}
