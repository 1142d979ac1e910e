//! modbus-tcp.h: TCP client contexts (listen/accept are with the server exports).

use std::ffi::{c_char, c_int};

use crate::context::Context;
use crate::ffi::{Modbus, into_handle, opt_cstr};

/// Creates a TCP/IPv4 context for `ip_address` (dotted quad; NULL means any address,
/// for a server) and `port`.
///
/// # Safety
/// `ip_address` must be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_tcp(ip_address: *const c_char, port: c_int) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let ip = unsafe { opt_cstr(ip_address) };
    into_handle(Context::new_tcp(ip, port))
}

/// Creates a protocol-independent TCP context (IPv4 or IPv6, names resolved with
/// getaddrinfo). NULL `node` means any address; NULL or empty `service` is "502".
///
/// # Safety
/// `node` and `service` must each be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_tcp_pi(node: *const c_char, service: *const c_char) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let (node, service) = unsafe { (opt_cstr(node), opt_cstr(service)) };
    into_handle(Context::new_tcp_pi(node, service))
}

/// rsmodbus extension: a context that speaks RTU frames (slave id, PDU, CRC) over a
/// TCP/IPv4 connection, as most serial-to-Ethernet gateways do. Set the slave with
/// `modbus_set_slave`; the rest works as on an RTU context (CRC checks, slave
/// filter, broadcast), with `modbus_connect`/`modbus_tcp_listen`/`modbus_tcp_accept`
/// doing the TCP side.
///
/// # Safety
/// `ip_address` must be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_rtu_tcp(ip_address: *const c_char, port: c_int) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let ip = unsafe { opt_cstr(ip_address) };
    into_handle(Context::new_rtu_tcp(ip, port))
}

/// rsmodbus extension: RTU frames over TCP, any address family (IPv4 or IPv6, names
/// resolved with getaddrinfo), like `modbus_new_tcp_pi`.
///
/// # Safety
/// `node` and `service` must each be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_rtu_tcp_pi(node: *const c_char, service: *const c_char) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let (node, service) = unsafe { (opt_cstr(node), opt_cstr(service)) };
    into_handle(Context::new_rtu_tcp_pi(node, service))
}

/// rsmodbus extension: Modbus/UDP, as pymodbus and j2mod speak it: each request and
/// each answer is one datagram holding the MBAP header and the PDU. A client's
/// `modbus_connect` makes a socket that talks to this address only; a lost datagram
/// is a timeout, an answer that is not the one awaited (a duplicate) is dropped. A
/// server runs with modbus_server_new(3), or binds with `modbus_udp_bind`, then
/// answers each request (`modbus_reply`) to its sender.
///
/// # Safety
/// `ip_address` must be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_udp(ip_address: *const c_char, port: c_int) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let ip = unsafe { opt_cstr(ip_address) };
    into_handle(Context::new_udp(ip, port))
}

/// rsmodbus extension: Modbus/UDP over any address family (names resolved with
/// getaddrinfo), like `modbus_new_tcp_pi`; `modbus_udp_bind` binds.
///
/// # Safety
/// `node` and `service` must each be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_udp_pi(node: *const c_char, service: *const c_char) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let (node, service) = unsafe { (opt_cstr(node), opt_cstr(service)) };
    into_handle(Context::new_udp_pi(node, service))
}
