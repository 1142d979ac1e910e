//! Debug output through the C library's own `stdout`/`stderr` streams.
//!
//! libmodbus prints its trace with `printf`/`fprintf`, so its lines interleave with the
//! application's own `printf` output in one stdio buffer. Writing through Rust's
//! `std::io::stdout` would keep a second buffer and reorder lines in a redirected
//! log; writing through the C `FILE *` keeps the order exactly as with libmodbus.

use core::fmt;
use std::io::Write;

use crate::proto::Diag;

unsafe extern "C" {
    static mut stdout: *mut libc::FILE;
    static mut stderr: *mut libc::FILE;
}

#[derive(Clone, Copy)]
enum Stream {
    Out,
    Err,
}

fn write_stream(stream: Stream, args: fmt::Arguments<'_>) {
    // Most lines are short: format on the stack, fall back to the heap for long ones.
    let mut small = [0u8; 256];
    let mut cursor = std::io::Cursor::new(&mut small[..]);
    let heap;
    let bytes: &[u8] = if cursor.write_fmt(args).is_ok() {
        let n = cursor.position() as usize;
        &small[..n]
    } else {
        heap = std::fmt::format(args);
        heap.as_bytes()
    };
    if bytes.is_empty() {
        return;
    }
    // SAFETY: `stdout`/`stderr` are the C library's stream globals, valid for the whole
    // process; reading the pointer value does not race with anything we do. `fwrite`
    // reads exactly `bytes.len()` bytes from a live slice.
    unsafe {
        let file = match stream {
            Stream::Out => stdout,
            Stream::Err => stderr,
        };
        libc::fwrite(bytes.as_ptr().cast(), 1, bytes.len(), file);
    }
}

/// Prints to C's stdout.
pub fn out(args: fmt::Arguments<'_>) {
    write_stream(Stream::Out, args);
}

/// Prints to C's stderr.
pub fn err(args: fmt::Arguments<'_>) {
    write_stream(Stream::Err, args);
}

/// The debug sink of a context: prints only when debug is on.
pub struct DebugSink {
    pub enabled: bool,
}

impl Diag for DebugSink {
    fn out(&mut self, args: fmt::Arguments<'_>) {
        if self.enabled {
            out(args);
        }
    }
    fn err(&mut self, args: fmt::Arguments<'_>) {
        if self.enabled {
            err(args);
        }
    }
}
