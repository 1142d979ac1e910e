//! modbus-tls.h: Modbus/TCP Security contexts (TLS, mutual authentication, roles).
//! rsmodbus extensions: libmodbus has none of this.

use std::ffi::{CStr, c_char, c_int, c_void};
use std::path::Path;
use std::sync::Arc;

use crate::context::Context;
use crate::error::{Error, Result};
use crate::ffi::{Modbus, into_handle, opt_cstr, with_ctx};
use crate::transport::tls::{self, Authorize, Tls};

/// Creates a Modbus/TCP Security client or server context: TLS over TCP/IPv4 to or on
/// `ip_address` (NULL: any address, for a server) and `port` (802 is the standard
/// port, `MODBUS_TCP_SECURITY_DEFAULT_PORT`).
///
/// # Safety
/// `ip_address` must be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_tcp_tls(ip_address: *const c_char, port: c_int) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let ip = unsafe { opt_cstr(ip_address) };
    into_handle(Context::new_tcp_tls(ip, port))
}

/// Creates a Modbus/TCP Security context on any address family (names resolved with
/// getaddrinfo); NULL or empty `service` is "802".
///
/// # Safety
/// `node` and `service` must each be NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_new_tcp_tls_pi(node: *const c_char, service: *const c_char) -> *mut Modbus {
    // SAFETY: forwarded caller contract.
    let (node, service) = unsafe { (opt_cstr(node), opt_cstr(service)) };
    into_handle(Context::new_tcp_tls_pi(node, service))
}

/// Runs `f` on the TLS state of a TLS context; EINVAL for any other context.
///
/// # Safety
/// `ctx` must be NULL or a live context.
unsafe fn with_tls(ctx: *mut Modbus, f: impl FnOnce(&mut Tls) -> Result<c_int>) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| match g.line.security_mut() {
            Some(t) => f(t),
            None => Err(Error::INVALID),
        })
    }
}

/// A required C string argument, as bytes; NULL gives EINVAL.
///
/// # Safety
/// `p` must be NULL or a NUL-terminated string.
unsafe fn required<'a>(p: *const c_char) -> Result<&'a CStr> {
    // SAFETY: forwarded caller contract.
    unsafe { opt_cstr(p) }.ok_or(Error::INVALID)
}

fn path(p: &CStr) -> &Path {
    use std::os::unix::ffi::OsStrExt;
    Path::new(std::ffi::OsStr::from_bytes(p.to_bytes()))
}

/// The context's certificate chain (PEM file, leaf first) and its private key (PEM
/// file: PKCS#8, PKCS#1 RSA or SEC1 EC, unencrypted). A server needs them; a client
/// needs them to be accepted by a server (mutual authentication).
///
/// # Safety
/// `ctx` must be NULL or a live context; the paths NULL or NUL-terminated strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_certificate(
    ctx: *mut Modbus,
    cert_chain_pem_file: *const c_char,
    private_key_pem_file: *const c_char,
) -> c_int {
    // SAFETY: forwarded caller contract (no password).
    unsafe {
        modbus_set_tls_certificate_with_password(ctx, cert_chain_pem_file, private_key_pem_file, std::ptr::null())
    }
}

/// [`modbus_set_tls_certificate`] with a private key encrypted with `password`
/// (PKCS#8 "ENCRYPTED PRIVATE KEY"; NULL: none). EMBTLSPASSWORD when the key is
/// encrypted and the password is NULL or does not decrypt it.
///
/// # Safety
/// `ctx` must be NULL or a live context; the paths and `password` NULL or
/// NUL-terminated strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_certificate_with_password(
    ctx: *mut Modbus,
    cert_chain_pem_file: *const c_char,
    private_key_pem_file: *const c_char,
    password: *const c_char,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let files = unsafe { required(cert_chain_pem_file).and_then(|c| Ok((c, required(private_key_pem_file)?))) };
    // SAFETY: `password` is NULL or NUL-terminated per the caller.
    let password = unsafe { opt_cstr(password) };
    // SAFETY: forwarded caller contract.
    unsafe {
        with_tls(ctx, |t| {
            let (chain, key) = files?;
            let chain = tls::read_file(path(chain))?;
            let key = tls::read_file(path(key))?;
            t.settings.set_certificate_pem(&chain, &key, password.map(CStr::to_bytes)).map(|()| 0)
        })
    }
}

/// [`modbus_set_tls_certificate`] from PEM text in memory.
///
/// # Safety
/// `ctx` must be NULL or a live context; the texts NULL or NUL-terminated strings.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_certificate_pem(
    ctx: *mut Modbus,
    cert_chain_pem: *const c_char,
    private_key_pem: *const c_char,
) -> c_int {
    // SAFETY: forwarded caller contract.
    let texts = unsafe { required(cert_chain_pem).and_then(|c| Ok((c, required(private_key_pem)?))) };
    // SAFETY: forwarded caller contract.
    unsafe {
        with_tls(ctx, |t| {
            let (chain, key) = texts?;
            t.settings.set_certificate_pem(chain.to_bytes(), key.to_bytes(), None).map(|()| 0)
        })
    }
}

/// The CA certificate(s) (PEM file) the peer's chain must lead to: a server accepts
/// only clients whose certificate it issued; a client accepts only such servers.
///
/// # Safety
/// `ctx` must be NULL or a live context; `ca_pem_file` NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_ca(ctx: *mut Modbus, ca_pem_file: *const c_char) -> c_int {
    // SAFETY: forwarded caller contract.
    let file = unsafe { required(ca_pem_file) };
    // SAFETY: forwarded caller contract.
    unsafe {
        with_tls(ctx, |t| {
            let pem = tls::read_file(path(file?))?;
            t.settings.set_ca_pem(&pem).map(|()| 0)
        })
    }
}

/// [`modbus_set_tls_ca`] from PEM text in memory.
///
/// # Safety
/// `ctx` must be NULL or a live context; `ca_pem` NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_ca_pem(ctx: *mut Modbus, ca_pem: *const c_char) -> c_int {
    // SAFETY: forwarded caller contract.
    let text = unsafe { required(ca_pem) };
    // SAFETY: forwarded caller contract.
    unsafe { with_tls(ctx, |t| t.settings.set_ca_pem(text?.to_bytes()).map(|()| 0)) }
}

/// The lowest TLS version accepted: `MODBUS_TLS_1_2` (the default) or
/// `MODBUS_TLS_1_3`; anything else gives EINVAL.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_min_version(ctx: *mut Modbus, version: c_int) -> c_int {
    let version = u16::try_from(version).unwrap_or(0);
    // SAFETY: forwarded caller contract.
    unsafe { with_tls(ctx, |t| t.settings.set_min_version(version).map(|()| 0)) }
}

/// The name or address a client checks the server's certificate against (NULL: the
/// address or node the context connects to).
///
/// # Safety
/// `ctx` must be NULL or a live context; `name` NULL or a NUL-terminated string.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_server_name(ctx: *mut Modbus, name: *const c_char) -> c_int {
    // SAFETY: forwarded caller contract.
    let name = unsafe { opt_cstr(name) }.map(|n| n.to_str().map(str::to_owned));
    // SAFETY: forwarded caller contract.
    unsafe {
        with_tls(ctx, |t| {
            let name = name.transpose().map_err(|_| Error::INVALID)?;
            t.settings.set_server_name(name).map(|()| 0)
        })
    }
}

/// The C type of the authorization callback.
pub type AuthorizeFn = unsafe extern "C" fn(
    ctx: *mut Modbus,
    role: *const c_char,
    unit_id: c_int,
    function: c_int,
    address: c_int,
    nb: c_int,
    user_data: *mut c_void,
) -> c_int;

/// The server's authorization callback: before `modbus_reply` serves a request, it
/// calls `authorize` with the client's role (NULL: its certificate has none), the
/// unit id, the function code and each range the request touches; 1 allows, 0 (or
/// anything but 1) refuses, and the client gets exception 01 ILLEGAL FUNCTION with
/// nothing changed. The context is not locked during the call. NULL: every
/// authenticated client is served.
///
/// # Safety
/// `ctx` must be NULL or a live context; `authorize` NULL or a function safe to call
/// with these arguments and `user_data` for as long as it is set.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_set_tls_authorization(
    ctx: *mut Modbus,
    authorize: Option<AuthorizeFn>,
    user_data: *mut c_void,
) -> c_int {
    // Plain numbers, so that the hook may cross threads.
    let (handle, data) = (ctx as usize, user_data as usize);
    let hook = authorize.map(|f| -> Authorize {
        Arc::new(move |role: Option<&CStr>, unit: u8, function: u8, address: u16, nb: u16| {
            let role = role.map_or(std::ptr::null(), CStr::as_ptr);
            // SAFETY: the application registered `f` with `user_data` for this
            // context; `role` is NULL or a string that outlives the call.
            let rc = unsafe {
                f(
                    handle as *mut Modbus,
                    role,
                    unit as c_int,
                    function as c_int,
                    address as c_int,
                    nb as c_int,
                    data as _,
                )
            };
            rc == 1
        })
    });
    // SAFETY: forwarded caller contract.
    unsafe {
        with_tls(ctx, |t| {
            t.authorize = hook;
            Ok(0)
        })
    }
}

/// Copies the role of the peer on the context's current socket into `buf` (at most
/// `size` bytes with the terminating NUL, truncated if longer) and returns its
/// length; -1 with ENOENT when the peer's certificate has no role (or no TLS session
/// is on the socket), EINVAL for a context that is not a TLS context or a NULL `buf`
/// with a non-zero `size`.
///
/// # Safety
/// `ctx` must be NULL or a live context; `buf` NULL or `size` writable bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_tls_peer_role(ctx: *mut Modbus, buf: *mut c_char, size: usize) -> c_int {
    if buf.is_null() && size > 0 {
        return crate::ffi::fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.line.security().ok_or(Error::INVALID)?;
            let role = g.line.peer_role().ok_or(Error(libc::ENOENT))?;
            let bytes = role.to_bytes();
            if size > 0 {
                let n = bytes.len().min(size - 1);
                // SAFETY: `buf` holds `size` writable bytes (caller contract); n + 1 <= size.
                let out = std::slice::from_raw_parts_mut(buf.cast::<u8>(), n + 1);
                out[..n].copy_from_slice(&bytes[..n]);
                out[n] = 0;
            }
            Ok(bytes.len() as c_int)
        })
    }
}

/// The number of bytes received on the context's current socket and not yet taken
/// by `modbus_receive` (0 without a session): requests that came in the same TLS
/// record as the one just read. They are already out of the socket, so `poll()`
/// does not report them: a server that polls calls `modbus_receive` again while
/// this is above 0. EINVAL when the context is not a TLS one.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_get_tls_pending(ctx: *mut Modbus) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            g.line.security().ok_or(Error::INVALID)?;
            Ok(g.line.pending().min(c_int::MAX as usize) as c_int)
        })
    }
}
