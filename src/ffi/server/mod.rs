//! modbus.h / modbus-tcp.h: the server side, one file per area: the data mapping
//! (`modbus_mapping_t` and its allocation), `modbus_receive`, `modbus_reply` and
//! `modbus_reply_exception`, the TCP listen/accept calls, and the rsmodbus
//! extensions a server can be configured with, or answer through (callbacks).
//!
//! Where libmodbus would dereference a NULL pointer (request buffer, mapping, the
//! accept socket pointer) these give EINVAL, or an empty table for a NULL mapping.
//!
//! cbindgen reads the files in the order of the `mod` lines (which rustfmt sorts),
//! and that is the order of the prototypes within a header: the mapping's before
//! the receive and reply functions in modbus.h.

mod callbacks;
mod extensions;
mod listen;
mod mapping;
mod reply;
mod runner;

pub use callbacks::*;
pub use extensions::*;
pub use listen::*;
pub use mapping::*;
pub use reply::*;
pub use runner::*;
