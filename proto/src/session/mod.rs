//! The session rules of libmodbus, without I/O: which time a wait gets, and which
//! recovery follows a failure. The library's driver executes them (its waits, reads,
//! sleeps, flushes and reconnects); here they are data, tested rule by rule.
//!
//! [`receive`] is the receive of one message as a state machine: the driver
//! executes its steps (peeks, waits, reads) and reports their results.

use core::time::Duration;

pub mod client;
pub mod late;
pub mod pipeline;
pub mod receive;
pub mod server;

use crate::error::{Error, errno};
use crate::frame::MsgKind;

/// A timeout as the C API sets it: seconds and microseconds (0..=999999).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Timeout {
    pub sec: u32,
    pub usec: u32,
}

impl Timeout {
    pub const fn new(sec: u32, usec: u32) -> Self {
        Timeout { sec, usec }
    }

    #[inline]
    pub const fn is_zero(self) -> bool {
        self.sec == 0 && self.usec == 0
    }

    #[inline]
    pub const fn duration(self) -> Duration {
        Duration::new(self.sec as u64, self.usec * 1000)
    }
}

/// The three timeouts of a context.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Timeouts {
    /// The first wait of a confirmation (never zero: the C API refuses it).
    pub response: Timeout,
    /// Each wait after bytes of a message arrived; zero: what is left of the
    /// current wait goes on.
    pub byte: Timeout,
    /// The first wait of an indication; zero: forever.
    pub indication: Timeout,
}

/// What the next wait of a receive gets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Wait {
    /// A fresh time.
    For(Timeout),
    /// No end.
    Forever,
    /// What is left of the current wait (the kernel counts it down).
    Left,
}

impl Timeouts {
    /// The first wait of a receive: the response timeout for a confirmation, the
    /// indication timeout (zero: forever) for an indication.
    #[inline]
    pub const fn first_wait(&self, kind: MsgKind) -> Wait {
        match kind {
            MsgKind::Confirmation => Wait::For(self.response),
            MsgKind::Indication if self.indication.is_zero() => Wait::Forever,
            MsgKind::Indication => Wait::For(self.indication),
        }
    }

    /// The wait after bytes of the message arrived: a fresh byte timeout, or, when
    /// that is zero, what is left of the current one.
    #[inline]
    pub const fn after_bytes(&self) -> Wait {
        if self.byte.is_zero() { Wait::Left } else { Wait::For(self.byte) }
    }
}

/// `MODBUS_ERROR_RECOVERY_LINK` and `_PROTOCOL` bits of a context's recovery mode.
pub const RECOVERY_LINK: i32 = 1 << 1;
pub const RECOVERY_PROTOCOL: i32 = 1 << 2;

/// What follows a failure.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Recovery {
    /// Report the error.
    None,
    /// Sleep the response timeout, then discard what is pending on the line.
    SleepFlush,
    /// Discard what is pending on the line at once.
    Flush,
    /// Close the connection and open it again.
    Reconnect,
    /// Close, sleep the response timeout, open again, and send once more.
    ReconnectAfterSleep,
}

/// The recovery after a wait for a message failed.
pub const fn after_wait(mode: i32, e: Error) -> Recovery {
    if mode & RECOVERY_LINK == 0 {
        return Recovery::None;
    }
    match e.0 {
        errno::ETIMEDOUT => Recovery::SleepFlush,
        errno::EBADF => Recovery::Reconnect,
        _ => Recovery::None,
    }
}

/// The recovery after a read of a message failed (end of stream counts as
/// ECONNRESET).
pub const fn after_read(mode: i32, e: Error) -> Recovery {
    match e.0 {
        errno::ECONNRESET | errno::ECONNREFUSED | errno::EBADF if mode & RECOVERY_LINK != 0 => Recovery::Reconnect,
        _ => Recovery::None,
    }
}

/// The recovery after a send failed (the send is then tried again, until it goes
/// out).
pub const fn after_send(mode: i32, e: Error) -> Recovery {
    if mode & RECOVERY_LINK == 0 {
        return Recovery::None;
    }
    match e.0 {
        errno::EBADF | errno::ECONNRESET | errno::EPIPE => Recovery::ReconnectAfterSleep,
        _ => Recovery::SleepFlush,
    }
}

/// The recovery after a response that does not answer the request (wrong function,
/// count or echo), or comes from another sender (transaction id, protocol id,
/// slave).
pub const fn after_mismatch(mode: i32) -> Recovery {
    if mode & RECOVERY_PROTOCOL != 0 { Recovery::SleepFlush } else { Recovery::None }
}

/// The recovery after a frame with a bad CRC or LRC.
pub const fn after_bad_checksum(mode: i32) -> Recovery {
    if mode & RECOVERY_PROTOCOL != 0 { Recovery::Flush } else { Recovery::None }
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: Timeouts =
        Timeouts { response: Timeout::new(0, 500_000), byte: Timeout::new(0, 20_000), indication: Timeout::new(0, 0) };

    #[test]
    fn waits() {
        assert_eq!(T.first_wait(MsgKind::Confirmation), Wait::For(Timeout::new(0, 500_000)));
        assert_eq!(T.first_wait(MsgKind::Indication), Wait::Forever);
        let t = Timeouts { indication: Timeout::new(2, 0), ..T };
        assert_eq!(t.first_wait(MsgKind::Indication), Wait::For(Timeout::new(2, 0)));
        assert_eq!(T.after_bytes(), Wait::For(Timeout::new(0, 20_000)));
        let t = Timeouts { byte: Timeout::new(0, 0), ..T };
        assert_eq!(t.after_bytes(), Wait::Left);
        assert_eq!(Timeout::new(1, 250_000).duration(), Duration::from_millis(1250));
    }

    #[test]
    fn recoveries() {
        let (none, link, protocol, both) = (0, RECOVERY_LINK, RECOVERY_PROTOCOL, RECOVERY_LINK | RECOVERY_PROTOCOL);
        let e = |n| Error(n);
        // After a wait.
        assert_eq!(after_wait(none, Error::TIMED_OUT), Recovery::None);
        assert_eq!(after_wait(link, Error::TIMED_OUT), Recovery::SleepFlush);
        assert_eq!(after_wait(link, e(errno::EBADF)), Recovery::Reconnect);
        assert_eq!(after_wait(link, e(errno::EINVAL)), Recovery::None);
        assert_eq!(after_wait(protocol, Error::TIMED_OUT), Recovery::None);
        // After a read.
        for n in [errno::ECONNRESET, errno::ECONNREFUSED, errno::EBADF] {
            assert_eq!(after_read(link, e(n)), Recovery::Reconnect);
            assert_eq!(after_read(protocol, e(n)), Recovery::None);
        }
        assert_eq!(after_read(both, Error::TIMED_OUT), Recovery::None);
        // After a send.
        for n in [errno::EBADF, errno::ECONNRESET, errno::EPIPE] {
            assert_eq!(after_send(link, e(n)), Recovery::ReconnectAfterSleep);
            assert_eq!(after_send(none, e(n)), Recovery::None);
        }
        assert_eq!(after_send(link, e(errno::EAGAIN)), Recovery::SleepFlush);
        // Protocol errors.
        assert_eq!(after_mismatch(protocol), Recovery::SleepFlush);
        assert_eq!(after_mismatch(link), Recovery::None);
        assert_eq!(after_bad_checksum(protocol), Recovery::Flush);
        assert_eq!(after_bad_checksum(link), Recovery::None);
    }
}
