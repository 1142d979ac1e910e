//! The status file (`status_file`): the counters per line and per master in the
//! Prometheus text exposition format, rewritten every second.
//!
//! Written as `PATH.tmp`, then renamed over `PATH`, so that a reader never sees half
//! of it. The temporary file is made anew each time (a stale one is unlinked
//! first) with O_CREAT|O_EXCL|O_NOFOLLOW|O_NONBLOCK and mode 0644: a symlink or a
//! FIFO put at either name is never followed nor waited on (`rename` replaces the
//! name itself).

use std::fmt::Write as _;
use std::fs::OpenOptions;
use std::io::{self, Write};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};

use nix::fcntl::OFlag;

use crate::core::Line;

/// The version the file's first line names.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");

/// The file's text for these lines.
pub fn text(lines: &[Line]) -> String {
    let mut s = String::with_capacity(512);
    let _ = writeln!(s, "# rsmodbus-gateway {VERSION}");
    let _ = writeln!(s, "# TYPE rsmodbus_gateway_requests_total counter");
    for l in lines {
        let (n, k) = (l.name(), l.counters());
        let _ = writeln!(s, "rsmodbus_gateway_requests_total{{line=\"{n}\"}} {}", k.requests);
        let _ = writeln!(s, "rsmodbus_gateway_answers_total{{line=\"{n}\"}} {}", k.served);
        let _ = writeln!(s, "rsmodbus_gateway_timeouts_total{{line=\"{n}\"}} {}", k.timeouts);
        let _ = writeln!(s, "rsmodbus_gateway_bad_answers_total{{line=\"{n}\"}} {}", k.bad_answers);
        let _ = writeln!(s, "rsmodbus_gateway_exceptions_total{{line=\"{n}\"}} {}", k.exceptions);
        let _ = writeln!(s, "rsmodbus_gateway_queue_depth{{line=\"{n}\"}} {}", l.depth());
        for m in l.masters() {
            let c = m.connection;
            let _ = writeln!(s, "rsmodbus_gateway_master_requests_total{{line=\"{n}\",master=\"{c}\"}} {}", m.requests);
            let _ = writeln!(s, "rsmodbus_gateway_master_busy_total{{line=\"{n}\",master=\"{c}\"}} {}", m.busy);
            let _ = writeln!(s, "rsmodbus_gateway_master_queue_depth{{line=\"{n}\",master=\"{c}\"}} {}", m.depth);
        }
    }
    s
}

/// `PATH.tmp` of `path`.
fn temporary(path: &Path) -> PathBuf {
    let mut t = path.as_os_str().to_owned();
    t.push(".tmp");
    PathBuf::from(t)
}

/// Writes `text` to `path` through `PATH.tmp` (see the module's note).
pub fn write(path: &Path, text: &str) -> io::Result<()> {
    let tmp = temporary(path);
    match std::fs::remove_file(&tmp) {
        Err(e) if e.kind() != io::ErrorKind::NotFound => return Err(e),
        _ => {}
    }
    let mut f = OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o644)
        .custom_flags((OFlag::O_NOFOLLOW | OFlag::O_NONBLOCK | OFlag::O_CLOEXEC).bits())
        .open(&tmp)?;
    let written = f.write_all(text.as_bytes());
    drop(f);
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp);
        return Err(e);
    }
    std::fs::rename(&tmp, path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::os::unix::fs::{FileTypeExt, MetadataExt};

    fn dir(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("gw-status-{name}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn written_through_a_temporary_file() {
        let d = dir("plain");
        let p = d.join("s");
        write(&p, "a 1\n").unwrap();
        write(&p, "a 2\n").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "a 2\n");
        assert_eq!(std::fs::metadata(&p).unwrap().mode() & 0o777, 0o644);
        assert!(!temporary(&p).exists());
        std::fs::remove_dir_all(d).unwrap();
    }

    #[test]
    fn symlinks_and_fifos_are_not_followed() {
        let d = dir("links");
        let p = d.join("s");
        let victim = d.join("victim");
        std::fs::write(&victim, "precious").unwrap();
        // A symlink at the temporary name and at the name itself.
        std::os::unix::fs::symlink(&victim, temporary(&p)).unwrap();
        write(&p, "a 1\n").unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
        std::fs::remove_file(&p).unwrap();
        std::os::unix::fs::symlink(&victim, &p).unwrap();
        write(&p, "a 2\n").unwrap();
        assert_eq!(std::fs::read_to_string(&victim).unwrap(), "precious");
        assert!(!std::fs::symlink_metadata(&p).unwrap().file_type().is_symlink());
        // A FIFO at either name: not waited on.
        std::fs::remove_file(&p).unwrap();
        for at in [temporary(&p), p.clone()] {
            nix::unistd::mkfifo(&at, nix::sys::stat::Mode::from_bits_truncate(0o600)).unwrap();
            write(&p, "a 3\n").unwrap();
            assert!(!std::fs::metadata(&p).unwrap().file_type().is_fifo());
            assert_eq!(std::fs::read_to_string(&p).unwrap(), "a 3\n");
            std::fs::remove_file(&p).unwrap();
        }
        std::fs::remove_dir_all(d).unwrap();
    }
}
