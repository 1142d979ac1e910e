//! rsmodbus-gateway: Modbus/TCP masters in front of Modbus lines, on rsmodbus' safe
//! Rust API (`rsmodbus::api`). No `unsafe` here.
#![forbid(unsafe_code)]

pub mod config;
pub mod core;
pub mod log;
pub mod privs;
pub mod run;
pub mod status;
