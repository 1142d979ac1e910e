//! Error codes shared by the core and the C layer.
//!
//! libmodbus reports every failure as `-1` (or NULL) plus an `errno` value: either a
//! system code (`EINVAL`, `ETIMEDOUT`, ...) or one of its own codes above
//! `MODBUS_ENOBASE`. [`Error`] is exactly that number, so the core can speak the C
//! convention without knowing about the C layer, and the C layer sets it in one
//! place. The system codes are Linux's numbers ([`errno`]): this crate has no libc,
//! and the library crate checks them against its libc in a unit test.

use core::fmt;

/// The Linux `errno` numbers this crate names (asm-generic/errno*.h; the library's
/// tests compare each with libc's).
pub mod errno {
    pub const EINTR: i32 = 4;
    pub const EBADF: i32 = 9;
    pub const EAGAIN: i32 = 11;
    pub const ENOMEM: i32 = 12;
    pub const EINVAL: i32 = 22;
    pub const EPIPE: i32 = 32;
    pub const EDEADLK: i32 = 35;
    pub const ENOPROTOOPT: i32 = 92;
    pub const ENOTSUP: i32 = 95;
    pub const ENETDOWN: i32 = 100;
    pub const ECONNABORTED: i32 = 103;
    pub const ECONNRESET: i32 = 104;
    pub const ENOTCONN: i32 = 107;
    pub const ETIMEDOUT: i32 = 110;
    pub const ECONNREFUSED: i32 = 111;
}

// The C headers' `#define`s of MODBUS_ENOBASE and of the EMB* numbers are made from
// these lines by the library's build.rs: a line `@ERRNO NAME@` of a cbindgen
// configuration stands for the run of top-level `pub const ...: i32` lines that
// begins with NAME (up to a blank line), each expression spelt in C. Keep them to
// sums of literals, earlier constants and `exception::NAME as i32`.

/// libmodbus's base for its own error numbers ("random number to avoid errno conflicts").
pub const MODBUS_ENOBASE: i32 = 112_345_678;

/// Modbus exception codes (the `MODBUS_EXCEPTION_*` enum of modbus.h).
pub mod exception {
    pub const ILLEGAL_FUNCTION: u8 = 0x01;
    pub const ILLEGAL_DATA_ADDRESS: u8 = 0x02;
    pub const ILLEGAL_DATA_VALUE: u8 = 0x03;
    pub const SLAVE_OR_SERVER_FAILURE: u8 = 0x04;
    pub const ACKNOWLEDGE: u8 = 0x05;
    pub const SLAVE_OR_SERVER_BUSY: u8 = 0x06;
    pub const NEGATIVE_ACKNOWLEDGE: u8 = 0x07;
    pub const MEMORY_PARITY: u8 = 0x08;
    pub const NOT_DEFINED: u8 = 0x09;
    pub const GATEWAY_PATH: u8 = 0x0A;
    pub const GATEWAY_TARGET: u8 = 0x0B;
    /// One past the last defined code.
    pub const MAX: u8 = 0x0C;
}

pub const EMBXILFUN: i32 = MODBUS_ENOBASE + exception::ILLEGAL_FUNCTION as i32;
pub const EMBXILADD: i32 = MODBUS_ENOBASE + exception::ILLEGAL_DATA_ADDRESS as i32;
pub const EMBXILVAL: i32 = MODBUS_ENOBASE + exception::ILLEGAL_DATA_VALUE as i32;
pub const EMBXSFAIL: i32 = MODBUS_ENOBASE + exception::SLAVE_OR_SERVER_FAILURE as i32;
pub const EMBXACK: i32 = MODBUS_ENOBASE + exception::ACKNOWLEDGE as i32;
pub const EMBXSBUSY: i32 = MODBUS_ENOBASE + exception::SLAVE_OR_SERVER_BUSY as i32;
pub const EMBXNACK: i32 = MODBUS_ENOBASE + exception::NEGATIVE_ACKNOWLEDGE as i32;
pub const EMBXMEMPAR: i32 = MODBUS_ENOBASE + exception::MEMORY_PARITY as i32;
pub const EMBXGPATH: i32 = MODBUS_ENOBASE + exception::GATEWAY_PATH as i32;
pub const EMBXGTAR: i32 = MODBUS_ENOBASE + exception::GATEWAY_TARGET as i32;

pub const EMBBADCRC: i32 = EMBXGTAR + 1;
pub const EMBBADDATA: i32 = EMBXGTAR + 2;
pub const EMBBADEXC: i32 = EMBXGTAR + 3;
pub const EMBUNKEXC: i32 = EMBXGTAR + 4;
pub const EMBMDATA: i32 = EMBXGTAR + 5;
pub const EMBBADSLAVE: i32 = EMBXGTAR + 6;

/// Modbus/TCP Security failures (rsmodbus, beyond libmodbus's range): a handshake
/// or record that failed, and the reasons a C program may want to tell apart.
pub const EMBTLS: i32 = MODBUS_ENOBASE + 64;
pub const EMBTLSNOCERT: i32 = EMBTLS + 1;
pub const EMBTLSUNKNOWNCA: i32 = EMBTLS + 2;
pub const EMBTLSEXPIRED: i32 = EMBTLS + 3;
pub const EMBTLSNAME: i32 = EMBTLS + 4;
pub const EMBTLSVERSION: i32 = EMBTLS + 5;
pub const EMBTLSCONFIG: i32 = EMBTLS + 6;
pub const EMBTLSPASSWORD: i32 = EMBTLS + 7;
pub const EMBTLSCACERT: i32 = EMBTLS + 8;

/// An errno value, as libmodbus would set it.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct Error(pub i32);

impl Error {
    /// A failure of the line itself (not of one message): the connection was reset,
    /// closed, aborted or is gone, or the network under it is down.
    #[inline]
    pub const fn line_lost(self) -> bool {
        matches!(
            self.0,
            errno::ECONNRESET | errno::EPIPE | errno::ENOTCONN | errno::EBADF | errno::ECONNABORTED | errno::ENETDOWN
        )
    }

    /// Fail with -1 but leave errno as it is (libmodbus does this in a few places,
    /// e.g. receiving on a context that is not connected).
    pub const UNCHANGED: Error = Error(0);
    pub const INVALID: Error = Error(errno::EINVAL);
    pub const TIMED_OUT: Error = Error(errno::ETIMEDOUT);
    pub const CONN_RESET: Error = Error(errno::ECONNRESET);
    /// The context was closed under the call (from a signal handler or another
    /// thread; see the library's `stop` module).
    pub const STOPPED: Error = Error(errno::EBADF);
    /// A call other than `modbus_close`, `modbus_free` and `modbus_get_socket` made
    /// from a signal handler that interrupted a call of its thread on the same context.
    pub const REENTERED: Error = Error(errno::EDEADLK);
    pub const CONN_REFUSED: Error = Error(errno::ECONNREFUSED);
    pub const NO_MEMORY: Error = Error(errno::ENOMEM);
    pub const NOT_SUPPORTED: Error = Error(errno::ENOTSUP);
    pub const BAD_CRC: Error = Error(EMBBADCRC);
    pub const BAD_DATA: Error = Error(EMBBADDATA);
    pub const BAD_EXCEPTION: Error = Error(EMBBADEXC);
    pub const TOO_MANY_DATA: Error = Error(EMBMDATA);
    pub const BAD_SLAVE: Error = Error(EMBBADSLAVE);

    /// The errno a client sees when the server answered with exception `code`.
    pub const fn from_exception(code: u8) -> Error {
        Error(MODBUS_ENOBASE + code as i32)
    }

    pub const fn errno(self) -> i32 {
        self.0
    }
}

/// `modbus_strerror`'s text: the library's own message for its codes, the system's
/// for the others (without the "(os error N)" the standard library adds).
impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match strerror_modbus(self.0) {
            Some(s) => f.write_str(s),
            None => {
                let text = std::io::Error::from_raw_os_error(self.0).to_string();
                let suffix = format!(" (os error {})", self.0);
                f.write_str(text.strip_suffix(&suffix).unwrap_or(&text))
            }
        }
    }
}

impl std::error::Error for Error {}

impl fmt::Debug for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "Error({} = {:?})", self.0, strerror_modbus(self.0))
    }
}

/// The libmodbus-specific message for `errnum`, or `None` when libmodbus defers to
/// the C library's `strerror`.
pub fn strerror_modbus(errnum: i32) -> Option<&'static str> {
    strerror_modbus_c(errnum).map(|s| s.to_str().unwrap_or_default())
}

/// [`strerror_modbus`] as C strings, for `modbus_strerror`.
pub const fn strerror_modbus_c(errnum: i32) -> Option<&'static core::ffi::CStr> {
    Some(match errnum {
        EMBXILFUN => c"Illegal function",
        EMBXILADD => c"Illegal data address",
        EMBXILVAL => c"Illegal data value",
        EMBXSFAIL => c"Slave device or server failure",
        EMBXACK => c"Acknowledge",
        EMBXSBUSY => c"Slave device or server is busy",
        EMBXNACK => c"Negative acknowledge",
        EMBXMEMPAR => c"Memory parity error",
        EMBXGPATH => c"Gateway path unavailable",
        EMBXGTAR => c"Target device failed to respond",
        EMBBADCRC => c"Invalid CRC",
        EMBBADDATA => c"Invalid data",
        EMBBADEXC => c"Invalid exception code",
        EMBMDATA => c"Too many data",
        EMBBADSLAVE => c"Response not from requested slave",
        EMBTLS => c"TLS failure",
        EMBTLSNOCERT => c"TLS: the peer sent no certificate",
        EMBTLSUNKNOWNCA => c"TLS: certificate not issued by a trusted CA",
        EMBTLSEXPIRED => c"TLS: certificate expired or not yet valid",
        EMBTLSNAME => c"TLS: certificate not valid for the peer's name or address",
        EMBTLSVERSION => c"TLS: protocol version not accepted (TLS 1.2 or newer)",
        EMBTLSCONFIG => c"TLS: certificate, key or CA not set",
        EMBTLSPASSWORD => c"TLS: the private key is encrypted: password missing or wrong",
        EMBTLSCACERT => c"TLS: the peer presented a CA certificate as its own (not an end-entity certificate)",
        _ => return None,
    })
}

pub type Result<T> = core::result::Result<T, Error>;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_match_libmodbus() {
        assert_eq!(EMBXILFUN, 112_345_679);
        assert_eq!(EMBXGTAR, 112_345_689);
        assert_eq!(EMBBADCRC, 112_345_690);
        assert_eq!(EMBBADSLAVE, 112_345_695);
        assert_eq!(Error::from_exception(9).errno(), 112_345_687);
    }

    #[test]
    fn codes_without_own_text_fall_through() {
        assert_eq!(strerror_modbus(EMBUNKEXC), None);
        assert_eq!(strerror_modbus(MODBUS_ENOBASE), None);
        assert_eq!(strerror_modbus(MODBUS_ENOBASE + 9), None);
        assert_eq!(strerror_modbus(EMBMDATA), Some("Too many data"));
    }
}
