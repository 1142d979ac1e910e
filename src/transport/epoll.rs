//! epoll(7), for the multi handle of the event-driven client (`modbus_multi_*`):
//! one descriptor that is readable when any of its contexts has work.

use crate::error::Result;
use crate::transport::last_error;

/// `epoll_create1(EPOLL_CLOEXEC)`.
pub fn create() -> Result<i32> {
    // SAFETY: plain system call with an integer argument.
    let fd = unsafe { libc::epoll_create1(libc::EPOLL_CLOEXEC) };
    if fd == -1 { Err(last_error()) } else { Ok(fd) }
}

/// `epoll_ctl`: `op` on `fd` with `events` (poll(2) bits: `POLLIN` and `POLLOUT` are
/// `EPOLLIN` and `EPOLLOUT`) and `key` as the event's data.
pub fn control(epfd: i32, op: i32, fd: i32, events: i16, key: u64) -> Result<()> {
    let mut ev = libc::epoll_event { events: events as u16 as u32, u64: key };
    // SAFETY: `ev` is a live epoll_event for the call.
    let rc = unsafe { libc::epoll_ctl(epfd, op, fd, &mut ev) };
    if rc == -1 { Err(last_error()) } else { Ok(()) }
}

/// `epoll_wait` into `events` for at most `timeout_ms` (-1: no end); the events
/// that came. EINTR is no event.
pub fn wait(epfd: i32, events: &mut [libc::epoll_event], timeout_ms: i32) -> Result<usize> {
    // SAFETY: `events` is a live, writable array of its length.
    let n = unsafe { libc::epoll_wait(epfd, events.as_mut_ptr(), events.len() as i32, timeout_ms) };
    if n >= 0 {
        return Ok(n as usize);
    }
    let e = last_error();
    if e.0 == libc::EINTR { Ok(0) } else { Err(e) }
}
