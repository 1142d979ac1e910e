//! File-descriptor I/O: the only place that talks to the kernel for data transfer.
//!
//! Waiting uses `ppoll` (microsecond timeouts like libmodbus's `select`, but without
//! the 1024-descriptor limit of `fd_set`).

pub mod epoll;
pub mod line;
pub mod link;
pub mod listen;
mod record;
pub mod room;
pub mod rtu;
pub mod tcp;
pub mod tls;
pub mod udp;

pub use room::{AduBuf, Room};

use std::time::Duration;

use crate::error::{Error, Result};

/// `modbus_strerror` as an owned string.
pub fn describe(errnum: i32) -> String {
    match crate::error::strerror_modbus(errnum) {
        Some(s) => s.to_owned(),
        None => {
            // SAFETY: strerror returns a valid NUL-terminated string; we copy it at once.
            unsafe { std::ffi::CStr::from_ptr(libc::strerror(errnum)) }.to_string_lossy().into_owned()
        }
    }
}

/// The calling thread's errno.
pub fn errno() -> i32 {
    std::io::Error::last_os_error().raw_os_error().unwrap_or(0)
}

/// Sets the calling thread's errno.
pub fn set_errno(value: i32) {
    // SAFETY: `__errno_location` returns the valid, thread-local errno slot.
    unsafe { *libc::__errno_location() = value };
}

/// `Err(errno)` of the last failed call.
pub fn last_error() -> Error {
    Error(errno())
}

/// A context timeout as the `timespec` the waits take.
pub fn timespec_of(t: crate::proto::session::Timeout) -> libc::timespec {
    libc::timespec { tv_sec: t.sec as libc::time_t, tv_nsec: t.usec as libc::c_long * 1000 }
}

pub fn to_timespec(d: Duration) -> libc::timespec {
    libc::timespec { tv_sec: d.as_secs() as libc::time_t, tv_nsec: d.subsec_nanos() as libc::c_long }
}

/// The monotonic clock (`CLOCK_MONOTONIC`, the clock `ppoll` counts on), as the time
/// since an unspecified start: the time the receive machine's deadlines are in.
pub fn now() -> Duration {
    let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    // SAFETY: `ts` is a live, writable timespec; CLOCK_MONOTONIC always exists on
    // Linux, so the call cannot fail.
    unsafe { libc::clock_gettime(libc::CLOCK_MONOTONIC, &mut ts) };
    Duration::new(ts.tv_sec as u64, ts.tv_nsec as u32)
}

/// Waits until `fd` has `events`, or `timeout` passes (`None`: forever).
/// Returns `Ok(false)` on timeout; `Err` carries the errno (EINTR included, so the
/// caller decides whether to retry).
pub fn wait(fd: i32, events: libc::c_short, timeout: Option<Duration>) -> Result<bool> {
    let mut ts = timeout.map(to_timespec);
    Ok(wait_or_wake(fd, events, -1, ts.as_mut())? == Ready::Line)
}

/// What [`wait_or_wake`] saw.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Ready {
    /// `fd` has the events asked for (or an error or hang-up to report).
    Line,
    /// `wake` became readable first.
    Woken,
    TimedOut,
}

/// One `ppoll` on `fd` (skipped when negative, so that the call is a sleep) and, when
/// `wake` is not negative, on `wake` for input. The kernel writes the time left back
/// into `timeout`, as Linux's `select` does with its `timeval` (libmodbus relies on
/// that: with no byte timeout, every wait of one message shares the response
/// timeout), so reusing the same value across waits needs no clock reads.
/// `Err` carries the errno (EINTR included, for the caller to decide).
pub fn wait_or_wake(fd: i32, events: libc::c_short, wake: i32, timeout: Option<&mut libc::timespec>) -> Result<Ready> {
    let mut pfds =
        [libc::pollfd { fd, events, revents: 0 }, libc::pollfd { fd: wake, events: libc::POLLIN, revents: 0 }];
    let nfds = 1 + (wake >= 0) as usize;
    let ts_ptr = timeout.map_or(std::ptr::null_mut(), |t| t as *mut libc::timespec);
    // SAFETY: the raw ppoll system call (glibc's wrapper declares the timeout const,
    // though the kernel updates it): `pfds` holds `nfds` valid pollfds (a negative
    // descriptor is ignored by the kernel); `ts_ptr` is NULL or points at a live,
    // writable timespec; no signal mask.
    let rc = unsafe {
        libc::syscall(
            libc::SYS_ppoll,
            pfds.as_mut_ptr(),
            nfds as libc::nfds_t,
            ts_ptr,
            std::ptr::null::<libc::sigset_t>(),
            8usize,
        )
    };
    match rc {
        -1 => Err(last_error()),
        0 => Ok(Ready::TimedOut),
        _ if pfds[0].revents & libc::POLLNVAL != 0 => Err(Error(libc::EBADF)),
        _ if pfds[0].revents != 0 => Ok(Ready::Line),
        _ => Ok(Ready::Woken),
    }
}

/// A value `setsockopt(2)` takes: plain C data, read by the kernel as bytes.
pub trait SocketOption: Copy {}
impl SocketOption for libc::c_int {}
impl SocketOption for libc::timeval {}

/// `setsockopt(2)` of `value` at `level`/`name`.
pub fn set_option<T: SocketOption>(fd: i32, level: i32, name: i32, value: T) -> Result<()> {
    // SAFETY: `value` is a live, plain-data local and its size is passed alongside it.
    let rc =
        unsafe { libc::setsockopt(fd, level, name, (&value as *const T).cast(), size_of::<T>() as libc::socklen_t) };
    if rc == -1 { Err(last_error()) } else { Ok(()) }
}

/// One `read(2)` into `buf`.
pub fn read(fd: i32, buf: &mut [u8]) -> Result<usize> {
    // SAFETY: the kernel writes at most `buf.len()` bytes into the live slice.
    let n = unsafe { libc::read(fd, buf.as_mut_ptr().cast(), buf.len()) };
    if n < 0 { Err(last_error()) } else { Ok(n as usize) }
}

/// One `recv(2)` into `buf`.
pub fn recv(fd: i32, buf: &mut [u8], flags: i32) -> Result<usize> {
    // SAFETY: the kernel writes at most `buf.len()` bytes into the live slice.
    let n = unsafe { libc::recv(fd, buf.as_mut_ptr().cast(), buf.len(), flags) };
    if n < 0 { Err(last_error()) } else { Ok(n as usize) }
}

/// One `send(2)` without SIGPIPE, with `flags` added.
pub fn send(fd: i32, buf: &[u8], flags: i32) -> Result<usize> {
    // SAFETY: the kernel reads at most `buf.len()` bytes from the live slice.
    let n = unsafe { libc::send(fd, buf.as_ptr().cast(), buf.len(), libc::MSG_NOSIGNAL | flags) };
    if n < 0 { Err(last_error()) } else { Ok(n as usize) }
}

/// One `write(2)`.
pub fn write(fd: i32, buf: &[u8]) -> Result<usize> {
    // SAFETY: the kernel reads at most `buf.len()` bytes from the live slice.
    let n = unsafe { libc::write(fd, buf.as_ptr().cast(), buf.len()) };
    if n < 0 { Err(last_error()) } else { Ok(n as usize) }
}

/// `close(2)`, ignoring the result as libmodbus does.
pub fn close(fd: i32) {
    // SAFETY: closing a descriptor number has no memory-safety preconditions.
    unsafe { libc::close(fd) };
}

/// The socket's cookie (`SO_COOKIE`): the kernel's number for the socket itself,
/// never reused while the system runs; 0 when the kernel gives none.
pub fn socket_cookie(fd: i32) -> u64 {
    /// `SO_COOKIE` of asm-generic/socket.h (x86, ARM, RISC-V...).
    const SO_COOKIE: libc::c_int = 57;
    let mut cookie: u64 = 0;
    let mut len = size_of::<u64>() as libc::socklen_t;
    // SAFETY: the kernel writes at most `len` bytes into the live u64 and updates
    // `len`, a live socklen_t.
    let rc = unsafe { libc::getsockopt(fd, libc::SOL_SOCKET, SO_COOKIE, (&mut cookie as *mut u64).cast(), &mut len) };
    if rc == 0 { cookie } else { 0 }
}

#[cfg(test)]
mod tests {
    use crate::error::errno;

    #[test]
    fn the_protocol_crates_errno_numbers_are_libcs() {
        let pairs = [
            (errno::EINTR, libc::EINTR),
            (errno::EBADF, libc::EBADF),
            (errno::EAGAIN, libc::EAGAIN),
            (errno::EPIPE, libc::EPIPE),
            (errno::ENOMEM, libc::ENOMEM),
            (errno::EINVAL, libc::EINVAL),
            (errno::EDEADLK, libc::EDEADLK),
            (errno::ENOPROTOOPT, libc::ENOPROTOOPT),
            (errno::ENOTSUP, libc::ENOTSUP),
            (errno::ECONNRESET, libc::ECONNRESET),
            (errno::ETIMEDOUT, libc::ETIMEDOUT),
            (errno::ECONNREFUSED, libc::ECONNREFUSED),
            (errno::ENETDOWN, libc::ENETDOWN),
            (errno::ECONNABORTED, libc::ECONNABORTED),
            (errno::ENOTCONN, libc::ENOTCONN),
        ];
        for (ours, libc) in pairs {
            assert_eq!(ours, libc);
        }
    }
}
