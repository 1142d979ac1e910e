//! The settings of the lines a context talks over: a serial line (RTU and ASCII
//! framing), a TCP/IPv4 address, or a node and service for getaddrinfo (TCP and RTU
//! framing over TCP). Plain data: the transport opens, configures and closes lines
//! from them; the context holds one.

use std::ffi::CString;

pub const RTU_RS232: i32 = 0;
pub const RTU_RS485: i32 = 1;
pub const RTU_RTS_NONE: i32 = 0;
pub const RTU_RTS_UP: i32 = 1;
pub const RTU_RTS_DOWN: i32 = 2;

/// The application's RTS callback (`modbus_rtu_set_custom_rts`), as the C layer
/// wraps it: called with the line's new state, it calls the application's function
/// with the context pointer it was registered on.
pub type RtsHook = std::sync::Arc<dyn Fn(bool) + Send + Sync>;

/// Serial line settings and state.
pub struct RtuLink {
    pub device: CString,
    pub baud: i32,
    pub parity: u8,
    pub data_bit: i32,
    pub stop_bit: i32,
    /// Terminal settings found at connect, restored at close (boxed: a TCP context
    /// does not carry their room).
    pub saved_termios: Option<Box<libc::termios>>,
    pub serial_mode: i32,
    pub rts: i32,
    pub rts_delay: i32,
    /// Microseconds to send one character at this speed and format.
    pub onebyte_time: i32,
    /// `None` means the built-in ioctl that drives the RTS line.
    pub custom_rts: Option<RtsHook>,
}

pub struct TcpLink {
    /// The address as given (IPv4 dotted quad), or "0" for any address.
    pub ip: CString,
    pub port: i32,
}

pub struct TcpPiLink {
    pub node: CString,
    pub service: CString,
}

pub enum Link {
    Rtu(RtuLink),
    Tcp(TcpLink),
    TcpPi(TcpPiLink),
}

impl From<RtuLink> for Link {
    fn from(link: RtuLink) -> Link {
        Link::Rtu(link)
    }
}

impl From<TcpLink> for Link {
    fn from(link: TcpLink) -> Link {
        Link::Tcp(link)
    }
}

impl From<TcpPiLink> for Link {
    fn from(link: TcpPiLink) -> Link {
        Link::TcpPi(link)
    }
}
