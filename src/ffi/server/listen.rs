//! modbus-tcp.h: the listening socket and the accept of a client, IPv4 and any
//! address family.

use std::ffi::c_int;

use crate::engine::Guard;
use crate::error::{Error, Result};
use crate::ffi::{Modbus, with_ctx};
use crate::transport::listen;

/// Opens an IPv4 listening socket on the context's address and port, for up to
/// `nb_connection` pending clients (on a Modbus/UDP context: a socket bound there,
/// as `modbus_udp_bind` makes). Returns the socket; the caller owns it. The context
/// does not make it its socket, but remembers it: `modbus_server_new` serves on it.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_listen(ctx: *mut Modbus, nb_connection: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| listen(g, false, nb_connection)) }
}

/// `modbus_tcp_listen` (`pi`: `modbus_tcp_pi_listen`): the socket, remembered by the
/// context for `modbus_server_new`.
fn listen(g: &mut Guard<'_>, pi: bool, nb_connection: c_int) -> Result<c_int> {
    let mut diag = g.diag();
    let fd = g.line.listen(pi, nb_connection, g.debug, &mut diag)?;
    g.line.listened(fd);
    Ok(fd)
}

/// rsmodbus extension: binds a Modbus/UDP context (`modbus_new_udp`,
/// `modbus_new_udp_pi`) to its address and port, and makes the socket the
/// context's (a socket it had is closed first): `modbus_receive` then reads each
/// request, and `modbus_reply` answers it to its sender. Returns the socket, which
/// `modbus_close` closes. EINVAL on a context of another kind.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_udp_bind(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            if !g.line.is_datagram() {
                return Err(Error::INVALID);
            }
            crate::session::close_line(g);
            let mut diag = g.diag();
            g.line.bind(&mut diag)
        })
    }
}

/// Accepts one client on `*s` and makes it the context's socket (TCP contexts, and RTU
/// framing over TCP). The context is not locked while waiting; a close of the context
/// (from a signal handler or another thread) ends the wait with EBADF.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
unsafe fn accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    let check = |g: &mut Guard<'_>| if s.is_null() || !g.line.accepts_clients() { Err(Error::INVALID) } else { Ok(()) };
    // SAFETY: `s` is non-NULL and valid per the caller once `check` passed, which
    // comes first.
    let wait = |w: &crate::handle::Waiting<'_>| listen::accept(unsafe { *s }, w.wake_fd(), &|| w.closed());
    let then = |g: &mut Guard<'_>, accepted: Result<(c_int, Option<String>)>, closed: bool| match accepted {
        Ok((fd, _)) if closed => {
            // Closed while the client was being accepted.
            crate::transport::close(fd);
            Err(Error::STOPPED)
        }
        Ok((fd, peer)) => {
            // Modbus/TCP Security: the client is served only once it has
            // authenticated (a failure closes its socket).
            crate::session::accepted(g, fd, peer.as_deref())?;
            Ok(fd)
        }
        Err(e) => {
            // As libmodbus: the context's socket is accept's -1, unless the context
            // was closed while waiting (nothing left to change).
            if !closed {
                g.set_descriptor(-1);
            }
            Err(e)
        }
    };
    // errno after the wait's end: freeing the handle (when a `modbus_free` came
    // meanwhile) must not change it.
    // SAFETY: forwarded caller contract.
    crate::ffi::status(unsafe { crate::handle::wait_unlocked(ctx, check, wait, then) })
}

/// Accepts one client on the listening socket `*s`; the new socket becomes the
/// context's and is returned.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { accept(ctx, s) }
}

/// Opens a listening socket on the first address getaddrinfo gives for the context's
/// node and service (IPv4 or IPv6; on a `modbus_new_udp_pi` context, a socket bound
/// there). Returns the socket; the caller owns it. The context remembers it, as
/// `modbus_tcp_listen` does.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_pi_listen(ctx: *mut Modbus, nb_connection: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| listen(g, true, nb_connection)) }
}

/// Accepts one client (IPv4 or IPv6) on the listening socket `*s`; the new socket
/// becomes the context's and is returned.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_pi_accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { accept(ctx, s) }
}
