//! rsmodbus: a memory-safe, binary drop-in replacement for libmodbus (`libmodbus.so.5`).
//!
//! Layers, from the wire up (ARCHITECTURE.md has the whole picture):
//! - [`proto`]: the protocol crate `rsmodbus-proto` (framing, lengths, requests,
//!   response checks and decoders, server replies). No `unsafe`, no clock, no I/O.
//! - [`transport`]: file-descriptor I/O for serial lines and TCP (`poll`, never `select`).
//! - [`context`] and [`engine`]: a `modbus_t` context and the libmodbus flows that drive
//!   the protocol over a transport (send, receive, confirm, error recovery, debug
//!   trace); `server` (private) the server's receive and reply.
//! - [`handle`]: a handle's lifetime (make, call, wait unlocked, callbacks unlocked,
//!   close, free), with its lock ([`lock`], whose word names its owner) and what
//!   stopping a waiting call needs without it (`stop`, crate-private).
//! - [`api`]: the safe Rust API (a context, the event-driven client's raw requests,
//!   a server that runs itself with a handler), which [`ffi`] wraps.
//! - [`ffi`]: the exported C ABI, thin shims that check arguments and map errors to
//!   `-1`/`NULL` plus `errno` in one place.
//!
//! Modules are public where a user of the crate needs them: the fuzz crate and the
//! integration tests in tests/.
//!
//! # Panic policy
//! The library is built with `panic = "abort"` (enforced below at compile time for
//! release builds, what ships; `cargo test` builds it with unwinding): a
//! panic is a bug in this library, and the process stops with the panic message on
//! stderr instead of unwinding into C frames or returning a wrong answer.

// Release builds (what ships) only: `cargo test` builds the library with unwinding for
// the integration tests in tests/, which run in debug builds.
#[cfg(all(not(panic = "abort"), not(test), not(debug_assertions)))]
compile_error!("rsmodbus must be built with panic = \"abort\" (see the panic policy in src/lib.rs)");

/// The protocol crate, under the name the library's modules use.
pub use rsmodbus_proto as proto;
pub use rsmodbus_proto::error;
use rsmodbus_proto::server_ext;

pub mod api;
pub mod context;
pub mod engine;
pub mod event;
pub mod ffi;
pub mod handle;
pub mod outstanding;
pub mod runner;
mod server;
pub mod session;
mod stdio;
pub mod transport;

/// The context lock, by its own name (the engine's guard, the tests).
pub use handle::lock;
use handle::stop;
