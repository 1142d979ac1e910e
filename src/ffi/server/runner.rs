//! modbus.h extensions: a server that runs itself (`modbus_server_t`): one thread,
//! one epoll descriptor, every client of a listening context, or a serial line
//! (`crate::runner`). Its requests are answered on the one reply path, from a
//! mapping or the application's callbacks, as `modbus_reply` and
//! `modbus_reply_dispatch` answer them.

use std::cell::UnsafeCell;
use std::ffi::{c_int, c_void};
use std::ptr;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use super::callbacks::{Callbacks, modbus_server_callbacks_t};
use super::mapping::{CMapping, modbus_mapping_t};
use crate::context::Context;
use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::ffi::{Modbus, fail};
use crate::proto::reply::MappingData;
use crate::runner::{Answer, Answers, Later, Stopper};

/// What the requests are answered from.
enum Source {
    Nothing,
    Mapping(*mut modbus_mapping_t),
    Callbacks(Box<Callbacks>),
}

impl Answer for Source {
    fn any_unit(&self) -> bool {
        matches!(self, Source::Callbacks(cb) if cb.chooses_units())
    }

    fn arrived(&mut self, g: &mut Guard<'_>) {
        if let Source::Callbacks(cb) = self {
            cb.from(g, &[]);
        }
    }

    fn accept_unit(&mut self, unit: u8, req: &[u8]) -> bool {
        use crate::proto::reply::Data;
        match self {
            Source::Callbacks(cb) => cb.accept_unit(unit, req),
            _ => true,
        }
    }

    fn answer(&mut self, g: &mut Guard<'_>, req: &[u8], id: i32) -> Result<Option<usize>> {
        let len = req.len() as i32;
        match self {
            Source::Callbacks(cb) => {
                cb.from(g, req);
                cb.request_id = id;
                cb.deferred = false;
                let sent = crate::server::reply(g, req, len, &mut **cb)?;
                Ok((!cb.deferred).then_some(sent))
            }
            Source::Mapping(m) => {
                let mut mapping = CMapping(*m);
                crate::server::reply(g, req, len, &mut MappingData(&mut mapping)).map(Some)
            }
            Source::Nothing => Err(Error::INVALID),
        }
    }
}

/// A server runner as C holds it (`modbus_server_t`).
pub struct ServerRunner {
    /// Reachable while a run is under way (`modbus_server_stop` from another thread
    /// or a signal handler).
    stopper: Arc<Stopper>,
    /// Answers given later, from any thread (`modbus_server_answer`).
    answers: Arc<Answers>,
    /// A run is under way: the calls that change the runner wait for its end
    /// (EBUSY), a free from a callback is done when it ends.
    running: AtomicBool,
    doomed: AtomicBool,
    inner: UnsafeCell<Inner>,
}

struct Inner {
    server: crate::api::Server,
    source: Source,
}

/// The runner behind `s` for a call that changes it: EINVAL for NULL, EBUSY while
/// it runs.
///
/// # Safety
/// `s` must be NULL or a live runner.
unsafe fn inner<'a>(s: *mut ServerRunner) -> Result<&'a mut Inner> {
    // SAFETY: the caller's pointer, NULL or live.
    let Some(server) = (unsafe { s.as_ref() }) else { return Err(Error::INVALID) };
    if server.running.load(Ordering::SeqCst) {
        return Err(Error(libc::EBUSY));
    }
    // SAFETY: no run is under way, and the application calls these from one thread
    // at a time (the documented contract), so this is the only reference.
    Ok(unsafe { &mut *server.inner.get() })
}

/// Makes a server that runs itself over `ctx` for up to `max_clients` clients at
/// once: a TCP, TCP-PI, RTU-over-TCP or Modbus/TCP Security context (its listening
/// socket when `modbus_set_socket` gave it one, else the one `modbus_tcp_listen`
/// made for it, else one the server opens on the context's address and closes
/// with it), a Modbus/UDP context (its socket, else the one `modbus_tcp_listen`
/// bound for it, else one bound to its address), or a serial context (its line,
/// opened if it is not; `max_clients` is then not used for these two). Each client is answered as
/// `modbus_reply` answers on `ctx`, with `ctx`'s settings (debug, timeouts, TLS
/// configuration and authorization) as they are when the client connects.
/// `ctx` must outlive the server. Returns NULL with errno EINVAL (NULL context,
/// `max_clients` < 1), EMBTLSCONFIG (TLS settings missing), or the error of the
/// listen or open.
///
/// Linux only (epoll).
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_new(ctx: *mut Modbus, max_clients: c_int) -> *mut ServerRunner {
    let max_clients = usize::try_from(max_clients).unwrap_or(0);
    // SAFETY: forwarded caller contract (the context outlives the server).
    let made = unsafe { crate::api::Server::over_handle(ctx, max_clients) };
    match made {
        Ok(server) => Box::into_raw(Box::new(ServerRunner {
            stopper: server.stopper(),
            answers: server.answers(),
            running: AtomicBool::new(false),
            doomed: AtomicBool::new(false),
            inner: UnsafeCell::new(Inner { server, source: Source::Nothing }),
        })),
        Err(e) => {
            fail(e);
            ptr::null_mut()
        }
    }
}

/// Answers the requests through the callbacks `cb` (copied; see
/// `modbus_reply_dispatch`), with `user_data`, in place of a mapping. With
/// `accept_unit` set, a serial server answers the units it accepts (broadcasts
/// too), whatever the context's slave. EINVAL: `s` or `cb` NULL, `cb->struct_size`
/// refused (as `modbus_reply_dispatch` refuses it); EBUSY during a run.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner; `cb` NULL or valid for `cb->struct_size` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_set_callbacks(
    s: *mut ServerRunner,
    cb: *const modbus_server_callbacks_t,
    user_data: *mut c_void,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let inner = match unsafe { inner(s) } {
        Ok(i) => i,
        Err(e) => return fail(e),
    };
    // SAFETY: forwarded caller contract.
    let callbacks = match unsafe { Callbacks::new(cb, user_data) } {
        Ok(c) => c,
        Err(e) => return fail(e),
    };
    inner.source = Source::Callbacks(Box::new(callbacks));
    0
}

/// Answers the requests from `map` (which must outlive the server's runs), as
/// `modbus_reply` does, in place of callbacks.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner; `map` NULL or a mapping whose tables hold
/// their `nb_*` items.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_set_mapping(s: *mut ServerRunner, map: *mut modbus_mapping_t) -> c_int {
    // SAFETY: forwarded caller contract.
    let inner = match unsafe { inner(s) } {
        Ok(i) => i,
        Err(e) => return fail(e),
    };
    if map.is_null() {
        return fail(Error::INVALID);
    }
    inner.source = Source::Mapping(map);
    0
}

/// A client from which no whole request came for this long is closed (a client
/// that sends a byte now and then, or never ends its TLS handshake, too). 0, 0:
/// never. The default is 60 s. EINVAL: `usec` above 999999.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_set_idle_timeout(s: *mut ServerRunner, sec: u32, usec: u32) -> c_int {
    // SAFETY: forwarded caller contract.
    let inner = match unsafe { inner(s) } {
        Ok(i) => i,
        Err(e) => return fail(e),
    };
    match Context::checked_timeout(sec, usec) {
        Ok(t) => {
            inner.server.set_idle(t);
            0
        }
        Err(e) => fail(e),
    }
}

/// The server's epoll descriptor, for the application's own loop: readable when
/// `modbus_server_run(s, 0)` has work (a client, a request, a deadline).
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_get_fd(s: *mut ServerRunner) -> c_int {
    // SAFETY: forwarded caller contract.
    match unsafe { s.as_ref() } {
        // SAFETY: the descriptor never changes: read through the cell without a
        // reference to the rest.
        Some(server) => unsafe { (*server.inner.get()).server.fd() },
        None => fail(Error::INVALID),
    }
}

/// Accepts clients, carries their TLS handshakes on, reads their requests and
/// answers them, closes the idle ones, for up to `timeout_ms` milliseconds (0:
/// what is ready now, without waiting; -1: until `modbus_server_stop`). Several
/// requests that come together are all answered, their answers sent together. The
/// callbacks run on this thread and must not block. Returns the requests answered,
/// or -1 with errno: EINVAL (no mapping or callbacks set, `timeout_ms` below -1),
/// EBUSY (a run is under way), or the error of the wait.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_run(s: *mut ServerRunner, timeout_ms: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    let inner = match unsafe { inner(s) } {
        Ok(i) => i,
        Err(e) => return fail(e),
    };
    if timeout_ms < -1 || matches!(inner.source, Source::Nothing) {
        return fail(Error::INVALID);
    }
    // SAFETY: `inner` succeeded: `s` is live.
    let server = unsafe { &*s };
    server.running.store(true, Ordering::SeqCst);
    let timeout = (timeout_ms >= 0).then(|| Duration::from_millis(timeout_ms as u64));
    let r = inner.server.run_answering(timeout, &mut inner.source);
    server.running.store(false, Ordering::SeqCst);
    if server.doomed.load(Ordering::SeqCst) {
        // Freed by a callback meanwhile.
        // SAFETY: the pointer of `modbus_server_new`, not used after this.
        drop(unsafe { Box::from_raw(s) });
    }
    match r {
        Ok(n) => n.min(c_int::MAX as usize) as c_int,
        Err(e) => fail(e),
    }
}

/// Ends the run under way (or the next) as soon as the request being answered is.
/// Safe from a callback, another thread, or a signal handler.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_stop(s: *mut ServerRunner) -> c_int {
    // SAFETY: forwarded caller contract; only the stop, which is shared, is read.
    match unsafe { s.as_ref() } {
        Some(server) => {
            server.stopper.stop();
            0
        }
        None => fail(Error::INVALID),
    }
}

/// Answers request `request_id` (`ri->request_id` of a callback that returned
/// `MODBUS_REPLY_LATER`) as that callback would have: `rc` > 0, the answer's PDU in
/// `rsp_pdu` (function code first, `rc` bytes); `MODBUS_REPLY_EXCEPTION(code)`, an
/// exception answer; 0, a write (05, 06, 0F, 10, 16) is done: the usual answer;
/// `MODBUS_REPLY_NONE`, no answer. A read is answered with
/// `modbus_server_answer_registers` or `modbus_server_answer_bits`. May be called
/// from any thread and from a callback; the answer goes out in the run under way
/// (woken) or the next. An answer for a client that has left is dropped. EINVAL:
/// `s` NULL, `request_id` not waiting for an answer (never deferred, or answered
/// already), `rc` none of those (a PDU longer than 253 bytes, an exception code out
/// of range, 0 for a request that is no write), `rsp_pdu` NULL with `rc` > 0.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner; `rsp_pdu` NULL or valid for `rc` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_answer(
    s: *mut ServerRunner,
    request_id: c_int,
    rsp_pdu: *const u8,
    rc: c_int,
) -> c_int {
    use super::callbacks::REPLY_NONE;
    use crate::proto::error::exception;
    let later = match rc {
        0 => Later::Done,
        REPLY_NONE => Later::Nothing,
        n if n > 0 && n as usize <= crate::proto::limits::MAX_PDU_LENGTH && !rsp_pdu.is_null() => {
            // SAFETY: the caller's buffer of `rc` bytes.
            Later::Pdu(unsafe { std::slice::from_raw_parts(rsp_pdu, n as usize) }.to_vec())
        }
        n if n < 0 && -n < exception::MAX as c_int => Later::Exception((-n) as u8),
        _ => return fail(Error::INVALID),
    };
    // SAFETY: forwarded caller contract.
    unsafe { give(s, request_id, later) }
}

/// Answers request `request_id`, a register read (03, 04, or 17, whose read part
/// `ri->pdu` tells), with the `nb` values at `values` (host order; `nb` must be the
/// quantity the request reads). As `modbus_server_answer` otherwise; EINVAL also
/// when the request is no register read, or `nb` is not its quantity.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner; `values` NULL or valid for `nb` values.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_answer_registers(
    s: *mut ServerRunner,
    request_id: c_int,
    values: *const u16,
    nb: c_int,
) -> c_int {
    if values.is_null() || !(1..=crate::proto::limits::MAX_READ_REGISTERS as c_int).contains(&nb) {
        return fail(Error::INVALID);
    }
    // SAFETY: the caller's `nb` values.
    let v = unsafe { std::slice::from_raw_parts(values, nb as usize) }.to_vec();
    // SAFETY: forwarded caller contract.
    unsafe { give(s, request_id, Later::Registers(v)) }
}

/// Answers request `request_id`, a bit read (01 or 02), with the `nb` bits at
/// `bits` (one per byte, 0 or not; `nb` must be the quantity the request reads).
/// As `modbus_server_answer` otherwise; EINVAL also when the request is no bit
/// read, or `nb` is not its quantity.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner; `bits` NULL or valid for `nb` bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_answer_bits(
    s: *mut ServerRunner,
    request_id: c_int,
    bits: *const u8,
    nb: c_int,
) -> c_int {
    if bits.is_null() || !(1..=crate::proto::limits::MAX_READ_BITS as c_int).contains(&nb) {
        return fail(Error::INVALID);
    }
    // SAFETY: the caller's `nb` bytes.
    let v = unsafe { std::slice::from_raw_parts(bits, nb as usize) }.iter().map(|&b| (b != 0) as u8).collect();
    // SAFETY: forwarded caller contract.
    unsafe { give(s, request_id, Later::Bits(v)) }
}

/// Answers request `request_id` with exception `exception_code` (a positive
/// `MODBUS_EXCEPTION_*` code, 1 to 11). As `modbus_server_answer` otherwise;
/// EINVAL also for a code out of range.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_answer_exception(
    s: *mut ServerRunner,
    request_id: c_int,
    exception_code: c_int,
) -> c_int {
    use crate::proto::error::exception;
    if !(1..exception::MAX as c_int).contains(&exception_code) {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe { give(s, request_id, Later::Exception(exception_code as u8)) }
}

/// Gives `later` for request `id` of `s`.
///
/// # Safety
/// `s` must be NULL or a live runner.
unsafe fn give(s: *mut ServerRunner, id: c_int, later: Later) -> c_int {
    // SAFETY: forwarded caller contract; only the shared parts are read.
    let Some(server) = (unsafe { s.as_ref() }) else { return fail(Error::INVALID) };
    match server.answers.give(&server.stopper, id, later) {
        Ok(()) => 0,
        Err(e) => fail(e),
    }
}

/// Closes every client (and the listening socket the server opened) and frees the
/// server; the context stays as it was. From a callback, the server is freed when
/// the run returns.
///
/// Linux only (epoll).
///
/// # Safety
/// `s` must be NULL or a live runner, not used afterwards.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_server_free(s: *mut ServerRunner) {
    // SAFETY: forwarded caller contract.
    let Some(server) = (unsafe { s.as_ref() }) else { return };
    if server.running.load(Ordering::SeqCst) {
        server.doomed.store(true, Ordering::SeqCst);
        server.stopper.stop();
        return;
    }
    // SAFETY: the pointer of `modbus_server_new`, not used after this.
    drop(unsafe { Box::from_raw(s) });
}
