//! modbus.h / modbus-tcp.h: the server side. The data mapping (`modbus_mapping_t`
//! and its allocation), `modbus_receive`, `modbus_reply`, `modbus_reply_exception`,
//! and the TCP listen/accept calls.
//!
//! Where libmodbus would dereference a NULL pointer (request buffer, mapping, the
//! accept socket pointer) these give EINVAL, or an empty table for a NULL mapping.

use std::ffi::{c_int, c_uint};
use std::mem::{offset_of, size_of};
use std::ptr;
use std::slice;

use crate::core::frame::MAX_ADU_LENGTH;
use crate::core::reply::{Mapping, Table, request_extent};
use crate::engine::AduBuf;
use crate::error::Error;
use crate::ffi::{Modbus, fail, status, with_ctx};
use crate::transport::listen;

/// The data a server exposes (`modbus_mapping_t`): four tables, each with its size
/// and first address. The field order is libmodbus's ABI (input registers before
/// holding registers); the tables are allocated with the C allocator, so a C
/// program may free or replace them itself.
#[allow(non_camel_case_types)]
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct modbus_mapping_t {
    pub nb_bits: c_int,
    pub start_bits: c_int,
    pub nb_input_bits: c_int,
    pub start_input_bits: c_int,
    pub nb_input_registers: c_int,
    pub start_input_registers: c_int,
    pub nb_registers: c_int,
    pub start_registers: c_int,
    pub tab_bits: *mut u8,
    pub tab_input_bits: *mut u8,
    pub tab_input_registers: *mut u16,
    pub tab_registers: *mut u16,
}

#[cfg(target_pointer_width = "64")]
const _: () = {
    assert!(size_of::<modbus_mapping_t>() == 64);
    assert!(offset_of!(modbus_mapping_t, nb_bits) == 0);
    assert!(offset_of!(modbus_mapping_t, start_bits) == 4);
    assert!(offset_of!(modbus_mapping_t, nb_input_bits) == 8);
    assert!(offset_of!(modbus_mapping_t, start_input_bits) == 12);
    assert!(offset_of!(modbus_mapping_t, nb_input_registers) == 16);
    assert!(offset_of!(modbus_mapping_t, start_input_registers) == 20);
    assert!(offset_of!(modbus_mapping_t, nb_registers) == 24);
    assert!(offset_of!(modbus_mapping_t, start_registers) == 28);
    assert!(offset_of!(modbus_mapping_t, tab_bits) == 32);
    assert!(offset_of!(modbus_mapping_t, tab_input_bits) == 40);
    assert!(offset_of!(modbus_mapping_t, tab_input_registers) == 48);
    assert!(offset_of!(modbus_mapping_t, tab_registers) == 56);
};

/// A zero-filled C table of `nb` items, NULL for 0. `None` when the allocation failed.
fn alloc_table<T>(nb: c_uint) -> Option<*mut T> {
    if nb == 0 {
        return Some(ptr::null_mut());
    }
    // SAFETY: calloc checks `nb * size` for overflow and returns NULL or zeroed memory.
    let p = unsafe { libc::calloc(nb as usize, size_of::<T>()) }.cast::<T>();
    (!p.is_null()).then_some(p)
}

/// Allocates a mapping whose tables start at the given addresses. Every table is
/// zero-filled; a table of size 0 is NULL. Returns NULL with ENOMEM on failure.
#[allow(clippy::too_many_arguments)]
#[unsafe(no_mangle)]
pub extern "C" fn modbus_mapping_new_start_address(
    start_bits: c_uint,
    nb_bits: c_uint,
    start_input_bits: c_uint,
    nb_input_bits: c_uint,
    start_registers: c_uint,
    nb_registers: c_uint,
    start_input_registers: c_uint,
    nb_input_registers: c_uint,
) -> *mut modbus_mapping_t {
    let bits = alloc_table::<u8>(nb_bits);
    let input_bits = alloc_table::<u8>(nb_input_bits);
    let input_registers = alloc_table::<u16>(nb_input_registers);
    let registers = alloc_table::<u16>(nb_registers);
    // SAFETY: malloc has no preconditions; the result is checked for NULL.
    let m = unsafe { libc::malloc(size_of::<modbus_mapping_t>()) }.cast::<modbus_mapping_t>();
    let (Some(tab_bits), Some(tab_input_bits), Some(tab_input_registers), Some(tab_registers), false) =
        (bits, input_bits, input_registers, registers, m.is_null())
    else {
        let allocated = [
            bits.map(|p| p.cast::<libc::c_void>()),
            input_bits.map(|p| p.cast()),
            input_registers.map(|p| p.cast()),
            registers.map(|p| p.cast()),
            Some(m.cast()),
        ];
        for p in allocated.into_iter().flatten() {
            // SAFETY: each pointer is NULL or came from calloc/malloc above; freed once.
            unsafe { libc::free(p) };
        }
        crate::transport::set_errno(libc::ENOMEM);
        return ptr::null_mut();
    };
    let mapping = modbus_mapping_t {
        nb_bits: nb_bits as c_int,
        start_bits: start_bits as c_int,
        nb_input_bits: nb_input_bits as c_int,
        start_input_bits: start_input_bits as c_int,
        nb_input_registers: nb_input_registers as c_int,
        start_input_registers: start_input_registers as c_int,
        nb_registers: nb_registers as c_int,
        start_registers: start_registers as c_int,
        tab_bits,
        tab_input_bits,
        tab_input_registers,
        tab_registers,
    };
    // SAFETY: `m` is a fresh, suitably aligned allocation of the struct's size.
    unsafe { m.write(mapping) };
    m
}

/// Allocates a mapping whose tables all start at address 0 (note the argument order:
/// bits, input bits, holding registers, input registers).
#[unsafe(no_mangle)]
pub extern "C" fn modbus_mapping_new(
    nb_bits: c_int,
    nb_input_bits: c_int,
    nb_registers: c_int,
    nb_input_registers: c_int,
) -> *mut modbus_mapping_t {
    modbus_mapping_new_start_address(
        0,
        nb_bits as c_uint,
        0,
        nb_input_bits as c_uint,
        0,
        nb_registers as c_uint,
        0,
        nb_input_registers as c_uint,
    )
}

/// Frees a mapping and its four tables. NULL is a no-op.
///
/// # Safety
/// `mb_mapping` must be NULL or a mapping from `modbus_mapping_new*` not yet freed;
/// its table pointers must be NULL or allocated with the C allocator.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_mapping_free(mb_mapping: *mut modbus_mapping_t) {
    if mb_mapping.is_null() {
        return;
    }
    // SAFETY: guaranteed by the caller: a live mapping with C-allocated tables.
    unsafe {
        let m = &*mb_mapping;
        libc::free(m.tab_bits.cast());
        libc::free(m.tab_input_bits.cast());
        libc::free(m.tab_input_registers.cast());
        libc::free(m.tab_registers.cast());
        libc::free(mb_mapping.cast());
    }
}

/// The tables of a C mapping, lent one at a time to the reply logic. A NULL mapping,
/// a NULL or misaligned table, or a size below 1 is an empty table.
struct CMapping(*mut modbus_mapping_t);

/// # Safety
/// `p` must be NULL or valid for `nb` items, not otherwise borrowed for `'a`.
unsafe fn c_table<'a, T>(start: c_int, nb: c_int, p: *mut T) -> Table<'a, T> {
    let data: &mut [T] = if p.is_null() || nb <= 0 || !p.is_aligned() {
        &mut []
    } else {
        // SAFETY: guaranteed by the caller.
        unsafe { slice::from_raw_parts_mut(p, nb as usize) }
    };
    Table { start, data }
}

impl CMapping {
    /// Reads the mapping's header (a copy: the tables are borrowed separately).
    fn fields(&self) -> Option<modbus_mapping_t> {
        // SAFETY: `self.0` is NULL or a live mapping (contract of modbus_reply); the
        // struct is plain data, copied out field by field.
        unsafe { self.0.as_ref() }.copied()
    }
}

// SAFETY (for every method): modbus_reply's contract makes each non-NULL table valid
// for its `nb` items; the trait lends one table at a time, so no two slices coexist.
impl Mapping for CMapping {
    fn bits(&mut self) -> Table<'_, u8> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_bits, m.nb_bits, m.tab_bits) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    fn input_bits(&mut self) -> Table<'_, u8> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_input_bits, m.nb_input_bits, m.tab_input_bits) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    fn registers(&mut self) -> Table<'_, u16> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_registers, m.nb_registers, m.tab_registers) },
            None => Table { start: 0, data: &mut [] },
        }
    }
    fn input_registers(&mut self) -> Table<'_, u16> {
        match self.fields() {
            // SAFETY: see the impl comment.
            Some(m) => unsafe { c_table(m.start_input_registers, m.nb_input_registers, m.tab_input_registers) },
            None => Table { start: 0, data: &mut [] },
        }
    }
}

/// Waits for one request and stores it in `req`. Returns its length, or 0 for a
/// frame filtered out (RTU: another slave's request, or the answer to it).
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or valid for
/// `MODBUS_TCP_MAX_ADU_LENGTH` (TCP) or `MODBUS_RTU_MAX_ADU_LENGTH` (RTU) bytes.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_receive(ctx: *mut Modbus, req: *mut u8) -> c_int {
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let cap = g.framing.max_adu_length();
            // SAFETY: the caller's buffer holds the framing's maximum ADU.
            let caller = slice::from_raw_parts_mut(req, cap);
            // Bytes the receive does not reach keep their values, as in libmodbus
            // (which reads into the caller's buffer directly, even on errors).
            let mut buf: AduBuf = [0; MAX_ADU_LENGTH];
            buf[..cap].copy_from_slice(caller);
            let rc = crate::server::receive(g, &mut buf);
            caller.copy_from_slice(&buf[..cap]);
            rc.map(|n| n as c_int)
        })
    }
}

/// Answers the request `req` (as stored by `modbus_receive`) from `mb_mapping`.
/// Returns the bytes sent, 0 for an RTU broadcast (not answered), -1 on error
/// (ENOPROTOOPT for FC 0x07, which libmodbus 3.1.12 does not answer).
///
/// Only the bytes the request describes are read (its function code and byte counts,
/// at most one ADU), and never past `req_length` when it is not negative. For the
/// single-write functions `req_length` must be the request's exact length.
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or holding a request as described;
/// `mb_mapping` NULL or a mapping whose tables hold their `nb_*` items.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_reply(
    ctx: *mut Modbus,
    req: *const u8,
    req_length: c_int,
    mb_mapping: *mut modbus_mapping_t,
) -> c_int {
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            let bound = if req_length < 0 { usize::MAX } else { req_length as usize };
            // SAFETY: request_extent only asks for bytes inside the request as its own
            // header describes it (and below a non-negative req_length).
            let extent = request_extent(g.framing, bound, |i| *req.add(i));
            // SAFETY: the same bytes, now as one slice.
            let req = slice::from_raw_parts(req, extent);
            let mut mapping = CMapping(mb_mapping);
            crate::server::reply(g, req, req_length, &mut mapping).map(|n| n as c_int)
        })
    }
}

/// Sends exception `exception_code` (0..=11, else EINVAL) in answer to `req`.
/// Returns the bytes sent.
///
/// # Safety
/// `ctx` must be NULL or a live context; `req` NULL or holding at least the header
/// and function code of a request.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_reply_exception(ctx: *mut Modbus, req: *const u8, exception_code: c_uint) -> c_int {
    if req.is_null() {
        return fail(Error::INVALID);
    }
    // SAFETY: forwarded caller contract.
    unsafe {
        with_ctx(ctx, |g| {
            // SAFETY: the caller's request holds its header and function code.
            let req = slice::from_raw_parts(req, g.framing.header_length() + 1);
            crate::server::reply_exception(g, req, exception_code).map(|n| n as c_int)
        })
    }
}

/// Opens an IPv4 listening socket on the context's address and port, for up to
/// `nb_connection` pending clients. Returns the socket; the caller owns it.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_listen(ctx: *mut Modbus, nb_connection: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| listen::listen_ipv4(g, nb_connection)) }
}

/// Accepts one client on `*s` and makes it the context's socket (TCP contexts, and RTU
/// framing over TCP). The context is not locked while waiting.
///
/// # Safety
/// `ctx` must be NULL or a live context; `s` NULL or a valid pointer.
unsafe fn accept(ctx: *mut Modbus, s: *mut c_int) -> c_int {
    // SAFETY: guaranteed by the caller.
    let Some(handle) = (unsafe { ctx.as_ref() }) else {
        return fail(Error::INVALID);
    };
    if s.is_null() || !handle.ctx.lock().is_socket() {
        return fail(Error::INVALID);
    }
    // SAFETY: `s` is non-NULL and valid per the caller.
    let listen_fd = unsafe { *s };
    let accepted = listen::accept(listen_fd);
    let mut g = handle.ctx.lock();
    status(match accepted {
        Ok((fd, peer)) => {
            g.s = fd;
            listen::report_accept(&mut g.diag(), peer.as_deref());
            Ok(fd)
        }
        Err(e) => {
            g.s = -1;
            Err(e)
        }
    })
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
/// node and service (IPv4 or IPv6). Returns the socket; the caller owns it.
///
/// # Safety
/// `ctx` must be NULL or a live context.
#[unsafe(no_mangle)]
pub unsafe extern "C" fn modbus_tcp_pi_listen(ctx: *mut Modbus, nb_connection: c_int) -> c_int {
    // SAFETY: forwarded caller contract.
    unsafe { with_ctx(ctx, |g| listen::listen_pi(g, nb_connection)) }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::context::Context;
    use crate::core::crc::crc16;
    use crate::ffi::context::{modbus_free, modbus_set_response_timeout, modbus_set_slave, modbus_set_socket};
    use crate::ffi::into_handle;
    use crate::transport::{close, errno};

    fn socket_pair() -> (i32, i32) {
        let mut fds = [0i32; 2];
        // SAFETY: `fds` has room for the two descriptors socketpair returns.
        let rc = unsafe { libc::socketpair(libc::AF_UNIX, libc::SOCK_STREAM, 0, fds.as_mut_ptr()) };
        assert_eq!(rc, 0);
        (fds[0], fds[1])
    }

    fn write_all(fd: i32, bytes: &[u8]) {
        // SAFETY: reads `bytes.len()` bytes from a live slice.
        let n = unsafe { libc::write(fd, bytes.as_ptr().cast(), bytes.len()) };
        assert_eq!(n, bytes.len() as isize);
    }

    /// Whatever is readable on `fd` within 200 ms.
    fn read_some(fd: i32) -> Vec<u8> {
        let mut buf = [0u8; 512];
        if !crate::transport::wait(fd, libc::POLLIN, Some(std::time::Duration::from_millis(200))).unwrap() {
            return Vec::new();
        }
        // SAFETY: the kernel writes at most `buf.len()` bytes into the live buffer.
        let n = unsafe { libc::recv(fd, buf.as_mut_ptr().cast(), buf.len(), libc::MSG_DONTWAIT) };
        buf[..n.max(0) as usize].to_vec()
    }

    fn with_crc(mut v: Vec<u8>) -> Vec<u8> {
        let crc = crc16(&v);
        v.extend(crc.to_le_bytes());
        v
    }

    struct Ctx(*mut Modbus);

    impl Drop for Ctx {
        fn drop(&mut self) {
            // SAFETY: the handle came from into_handle and is freed once.
            unsafe { modbus_free(self.0) };
        }
    }

    fn tcp(fd: i32) -> Ctx {
        let ctx = Ctx(into_handle(Context::new_tcp(Some(c"127.0.0.1"), 0)));
        // SAFETY: live handle.
        unsafe {
            modbus_set_socket(ctx.0, fd);
            modbus_set_response_timeout(ctx.0, 0, 1000);
        }
        ctx
    }

    fn rtu(fd: i32, slave: i32) -> Ctx {
        let ctx = Ctx(into_handle(Context::new_rtu(Some(c"/dev/null"), 115200, b'N', 8, 1)));
        // SAFETY: live handle.
        unsafe {
            modbus_set_socket(ctx.0, fd);
            modbus_set_slave(ctx.0, slave);
            modbus_set_response_timeout(ctx.0, 0, 1000);
        }
        ctx
    }

    #[test]
    fn report_slave_id_names_the_exported_version() {
        assert_eq!(crate::core::reply::VERSION_STRING, crate::ffi::version::LIBMODBUS_VERSION_STRING);
    }

    #[test]
    fn mapping_layout_allocation_and_free() {
        let m = modbus_mapping_new_start_address(10, 3, 20, 0, 30, 2, 40, 1);
        assert!(!m.is_null());
        // SAFETY: a fresh mapping with the sizes asked for.
        unsafe {
            let r = &*m;
            assert_eq!((r.nb_bits, r.start_bits, r.nb_input_bits, r.start_input_bits), (3, 10, 0, 20));
            assert_eq!(
                (r.nb_registers, r.start_registers, r.nb_input_registers, r.start_input_registers),
                (2, 30, 1, 40)
            );
            assert!(r.tab_input_bits.is_null());
            assert_eq!(slice::from_raw_parts(r.tab_bits, 3), [0, 0, 0]);
            assert_eq!(slice::from_raw_parts(r.tab_registers, 2), [0, 0]);
            assert_eq!(slice::from_raw_parts(r.tab_input_registers, 1), [0]);
            // A C program may replace a table with its own allocation.
            libc::free(r.tab_registers.cast());
            (*m).tab_registers = libc::malloc(8).cast();
            modbus_mapping_free(m);
            modbus_mapping_free(ptr::null_mut());
        }
        let m = modbus_mapping_new(0, 0, 0, 0);
        // SAFETY: a fresh mapping.
        unsafe {
            assert!((*m).tab_bits.is_null() && (*m).tab_registers.is_null());
            modbus_mapping_free(m);
        }
        // Unsigned starts are stored as the int fields.
        let m = modbus_mapping_new_start_address(u32::MAX, 1, 0, 0, 0x8000_0000, 1, 0, 0);
        // SAFETY: a fresh mapping.
        unsafe {
            assert_eq!(((*m).start_bits, (*m).start_registers), (-1, i32::MIN));
            modbus_mapping_free(m);
        }
    }

    #[test]
    fn reply_over_a_socket_tcp() {
        let (ours, peer) = socket_pair();
        let ctx = tcp(ours);
        let m = modbus_mapping_new_start_address(0, 0, 0, 0, 0x100, 4, 0, 0);
        let req = [0, 7, 0, 0, 0, 6, 0xFF, 6, 0x01, 0x02, 0xAB, 0xCD];
        // SAFETY: live handle, a request buffer of 12 bytes, a live mapping.
        unsafe {
            assert_eq!(modbus_reply(ctx.0, req.as_ptr(), 12, m), 12);
            assert_eq!(read_some(peer), req);
            assert_eq!(*(*m).tab_registers.add(2), 0xABCD);
            // CVE-2024-10918: a req_length past the request is refused, nothing is read.
            assert_eq!(modbus_reply(ctx.0, req.as_ptr(), 1 << 20, m), 9);
            assert_eq!(read_some(peer), [0, 7, 0, 0, 0, 3, 0xFF, 0x86, 3]);
            // A NULL mapping is a mapping without tables.
            let rd = [0, 8, 0, 0, 0, 6, 0xFF, 3, 0x01, 0x00, 0x00, 0x01];
            assert_eq!(modbus_reply(ctx.0, rd.as_ptr(), 12, ptr::null_mut()), 9);
            assert_eq!(read_some(peer), [0, 8, 0, 0, 0, 3, 0xFF, 0x83, 2]);
            // A 1-byte PDU in an 8-byte buffer (#837).
            let rsid = [0, 9, 0, 0, 0, 2, 0xFF, 0x11];
            assert_eq!(modbus_reply(ctx.0, rsid.as_ptr(), 8, m), 8 + 12);
            assert_eq!(read_some(peer)[7..10], [0x11, 0x0B, 0xB4]);
            // FC 07: nothing sent, ENOPROTOOPT.
            let fc7 = [0, 9, 0, 0, 0, 2, 0xFF, 0x07];
            assert_eq!(modbus_reply(ctx.0, fc7.as_ptr(), 8, m), -1);
            assert_eq!(errno(), libc::ENOPROTOOPT);
            assert!(read_some(peer).is_empty());
            // Unknown function: the pending bytes are flushed, then the exception goes.
            write_all(peer, &[1, 2, 3]);
            std::thread::sleep(std::time::Duration::from_millis(20));
            let unk = [0, 10, 0, 0, 0, 2, 0xFF, 0x08];
            assert_eq!(modbus_reply(ctx.0, unk.as_ptr(), 8, m), 9);
            assert_eq!(read_some(peer), [0, 10, 0, 0, 0, 3, 0xFF, 0x88, 1]);
            assert!(read_some(ours).is_empty());
            // modbus_reply_exception: any code below 12, else EINVAL.
            assert_eq!(modbus_reply_exception(ctx.0, rd.as_ptr(), 0), 9);
            assert_eq!(read_some(peer), [0, 8, 0, 0, 0, 3, 0xFF, 0x83, 0]);
            assert_eq!(modbus_reply_exception(ctx.0, rd.as_ptr(), 12), -1);
            assert_eq!(errno(), libc::EINVAL);
            assert_eq!(modbus_reply_exception(ctx.0, rd.as_ptr(), u32::MAX), -1);
            // NULL arguments.
            assert_eq!(modbus_reply(ptr::null_mut(), rd.as_ptr(), 12, m), -1);
            assert_eq!(errno(), libc::EINVAL);
            assert_eq!(modbus_reply(ctx.0, ptr::null(), 12, m), -1);
            assert_eq!(modbus_receive(ctx.0, ptr::null_mut()), -1);
            assert_eq!(modbus_reply_exception(ptr::null_mut(), rd.as_ptr(), 1), -1);
            modbus_mapping_free(m);
        }
        close(peer);
        close(ours);
    }

    #[test]
    fn receive_tcp_keeps_the_rest_of_the_buffer() {
        let (ours, peer) = socket_pair();
        let ctx = tcp(ours);
        let mut buf = [0xEEu8; 260];
        // Two requests in one write: each receive takes exactly one.
        let a = [0, 1, 0, 0, 0, 6, 0xFF, 3, 0, 0, 0, 1];
        let b = [0, 2, 0, 0, 0, 2, 0xFF, 0x11];
        write_all(peer, &[&a[..], &b[..]].concat());
        // SAFETY: live handle, a 260-byte buffer.
        unsafe {
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 12);
            assert_eq!(buf[..12], a);
            assert!(buf[12..].iter().all(|&x| x == 0xEE));
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
            assert_eq!(buf[..8], b);
            close(peer);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), -1);
            assert_eq!(errno(), libc::ECONNRESET);
        }
        close(ours);
    }

    #[test]
    fn receive_rtu_skips_the_answer_to_another_slave() {
        let (ours, peer) = socket_pair();
        let ctx = rtu(ours, 17);
        let mut buf = [0u8; 256];
        let other_req = with_crc(vec![5, 3, 0, 0, 0, 1]);
        let other_rsp = with_crc(vec![5, 3, 2, 0x12, 0x34]);
        let ours_req = with_crc(vec![17, 3, 0, 0, 0, 1]);
        // SAFETY: live handle, a 256-byte buffer.
        unsafe {
            write_all(peer, &other_req);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 0);
            // The other slave's answer is read as a confirmation and dropped.
            write_all(peer, &other_rsp);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 0);
            assert_eq!(buf[..7], other_rsp);
            write_all(peer, &ours_req);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
            assert_eq!(buf[..8], ours_req);
            // Broadcast is ours too, but the reply is suppressed.
            let bc = with_crc(vec![0, 6, 0, 1, 0, 9]);
            write_all(peer, &bc);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 8);
            let m = modbus_mapping_new(0, 0, 4, 0);
            assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 8, m), 0);
            assert_eq!(*(*m).tab_registers.add(1), 9);
            assert!(read_some(peer).is_empty());
            // A bad CRC: EMBBADCRC, and the frame is in the buffer for a reply with -1.
            let mut bad = with_crc(vec![17, 6, 0, 2, 0, 7]);
            bad[7] ^= 0xFF;
            write_all(peer, &bad);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), -1);
            assert_eq!(errno(), crate::error::EMBBADCRC);
            assert_eq!(buf[..8], bad);
            assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), -1, m), 5);
            assert_eq!(read_some(peer), with_crc(vec![17, 0x86, 3]));
            modbus_mapping_free(m);
        }
        close(peer);
        close(ours);
    }

    fn local_port(fd: i32) -> u16 {
        // SAFETY: all-zero is a valid sockaddr_in; getsockname fills at most `len` bytes.
        unsafe {
            let mut sa: libc::sockaddr_in = std::mem::zeroed();
            let mut len = size_of::<libc::sockaddr_in>() as libc::socklen_t;
            assert_eq!(libc::getsockname(fd, (&mut sa as *mut libc::sockaddr_in).cast(), &mut len), 0);
            u16::from_be(sa.sin_port)
        }
    }

    fn connect_to(port: u16) -> i32 {
        // SAFETY: plain socket calls on a fresh descriptor and a local sockaddr_in.
        unsafe {
            let fd = libc::socket(libc::AF_INET, libc::SOCK_STREAM, 0);
            let mut sa: libc::sockaddr_in = std::mem::zeroed();
            sa.sin_family = libc::AF_INET as libc::sa_family_t;
            sa.sin_port = port.to_be();
            sa.sin_addr.s_addr = u32::from_be_bytes([127, 0, 0, 1]).to_be();
            let rc = libc::connect(fd, (&sa as *const libc::sockaddr_in).cast(), size_of::<libc::sockaddr_in>() as u32);
            assert_eq!(rc, 0);
            fd
        }
    }

    #[test]
    fn listen_accept_and_descriptors_above_fd_setsize() {
        let ctx = Ctx(into_handle(Context::new_tcp(Some(c"127.0.0.1"), 0)));
        // SAFETY: live handle and local descriptors throughout.
        unsafe {
            let lfd = modbus_tcp_listen(ctx.0, 2);
            assert!(lfd >= 0);
            // The listening socket is close-on-exec and is not the context's socket.
            assert_ne!(libc::fcntl(lfd, libc::F_GETFD) & libc::FD_CLOEXEC, 0);
            assert_eq!(crate::ffi::context::modbus_get_socket(ctx.0), -1);
            // Move it above FD_SETSIZE when the limit allows.
            let mut lim: libc::rlimit = std::mem::zeroed();
            libc::getrlimit(libc::RLIMIT_NOFILE, &mut lim);
            if lim.rlim_cur < 2048 && lim.rlim_max >= 2048 {
                lim.rlim_cur = 2048;
                libc::setrlimit(libc::RLIMIT_NOFILE, &lim);
            }
            let high = lim.rlim_cur >= 2048;
            let mut s = lfd;
            if high {
                s = libc::dup2(lfd, 1500 + (lfd % 100));
                assert!(s >= 1500);
                close(lfd);
            }
            let port = local_port(s);
            let client = connect_to(port);
            let fd = modbus_tcp_accept(ctx.0, &mut s);
            assert!(fd >= 0);
            assert_eq!(crate::ffi::context::modbus_get_socket(ctx.0), fd);
            assert_ne!(libc::fcntl(fd, libc::F_GETFD) & libc::FD_CLOEXEC, 0);
            let fd = if high {
                let hi = libc::dup3(fd, 1600 + (fd % 100), libc::O_CLOEXEC);
                close(fd);
                modbus_set_socket(ctx.0, hi);
                hi
            } else {
                fd
            };
            let m = modbus_mapping_new(0, 0, 2, 0);
            let mut buf = [0u8; 260];
            write_all(client, &[0, 1, 0, 0, 0, 6, 1, 6, 0, 1, 0x55, 0xAA]);
            assert_eq!(modbus_receive(ctx.0, buf.as_mut_ptr()), 12);
            assert_eq!(modbus_reply(ctx.0, buf.as_ptr(), 12, m), 12);
            assert_eq!(read_some(client), buf[..12]);
            modbus_mapping_free(m);
            close(client);
            close(fd);
            close(s);
            // NULL and wrong arguments.
            assert_eq!(modbus_tcp_accept(ctx.0, ptr::null_mut()), -1);
            assert_eq!(errno(), libc::EINVAL);
            assert_eq!(modbus_tcp_listen(ptr::null_mut(), 1), -1);
            let mut bad = -1;
            assert_eq!(modbus_tcp_accept(ctx.0, &mut bad), -1);
            assert_eq!(errno(), libc::EBADF);
            assert_eq!(crate::ffi::context::modbus_get_socket(ctx.0), -1);
        }
        let r = rtu(-1, 1);
        // SAFETY: live handle.
        unsafe {
            assert_eq!(modbus_tcp_listen(r.0, 1), -1);
            assert_eq!(errno(), libc::EINVAL);
            assert_eq!(modbus_tcp_pi_listen(r.0, 1), -1);
            let mut s = 0;
            assert_eq!(modbus_tcp_pi_accept(r.0, &mut s), -1);
            assert_eq!(errno(), libc::EINVAL);
        }
    }

    #[test]
    fn pi_listen_on_ipv6_loopback() {
        let ctx = Ctx(into_handle(Context::new_tcp_pi(Some(c"::1"), Some(c"0"))));
        // SAFETY: live handle.
        unsafe {
            let s = modbus_tcp_pi_listen(ctx.0, 1);
            if s == -1 {
                // No IPv6 loopback here (AI_ADDRCONFIG): getaddrinfo fails.
                assert_eq!(errno(), libc::ECONNREFUSED);
                return;
            }
            assert_ne!(libc::fcntl(s, libc::F_GETFD) & libc::FD_CLOEXEC, 0);
            close(s);
        }
    }

    #[test]
    fn listen_address_rules() {
        // An address starting with '0' is any address; an invalid one fails without errno.
        for (ip, ok) in [(c"0", true), (c"0.0.0.0", true), (c"127.0.0.1", true), (c"1.2.3", false)] {
            let ctx = Ctx(into_handle(Context::new_tcp(Some(ip), 0)));
            crate::transport::set_errno(12345);
            // SAFETY: live handle.
            let s = unsafe { modbus_tcp_listen(ctx.0, 1) };
            assert_eq!(s >= 0, ok, "{ip:?}");
            if ok {
                close(s);
            } else {
                assert_eq!(errno(), 12345);
            }
        }
    }
}
