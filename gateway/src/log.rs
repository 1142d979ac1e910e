//! The gateway's log: lines `DD Mon YYYY HH:MM:SS [ERROR: ]text`, as the C gateway
//! and mbusd write them, to a file (appended) or standard output. A line below the
//! level is never formatted: callers ask [`Log::enabled`] first (the [`logf!`]
//! macro does).

use std::fmt;
use std::fs::File;
use std::io::{self, Write};
use std::time::{SystemTime, UNIX_EPOCH};

/// Where the gateway's messages go. `level` 0 is an error (written with `ERROR: `),
/// 9 the most detail.
pub trait Log {
    /// Whether a message at `level` is written.
    fn enabled(&self, level: u8) -> bool;
    /// Writes one message (the caller checked [`Log::enabled`]).
    fn write(&mut self, level: u8, args: fmt::Arguments<'_>);
}

/// Logs `format!`-like arguments at a level, formatting nothing below it.
#[macro_export]
macro_rules! logf {
    ($log:expr, $level:expr, $($arg:tt)*) => {{
        let level: u8 = $level;
        if $crate::log::Log::enabled(&*$log, level) {
            $crate::log::Log::write(&mut *$log, level, format_args!($($arg)*));
        }
    }};
}

/// A log that writes nothing (tests, fuzzing).
#[derive(Default)]
pub struct Null;

impl Log for Null {
    fn enabled(&self, _level: u8) -> bool {
        false
    }
    fn write(&mut self, _level: u8, _args: fmt::Arguments<'_>) {}
}

/// A log that keeps every message (tests).
#[derive(Default)]
pub struct Memory {
    pub level: u8,
    pub lines: Vec<(u8, String)>,
}

impl Log for Memory {
    fn enabled(&self, level: u8) -> bool {
        level <= self.level
    }
    fn write(&mut self, level: u8, args: fmt::Arguments<'_>) {
        self.lines.push((level, args.to_string()));
    }
}

enum Out {
    Stdout,
    File(File),
}

/// The log file (or standard output, `-`).
pub struct FileLog {
    pub level: u8,
    out: Out,
    /// The UTC offset of local time, seconds (read from the system's zone at most
    /// once an hour, at the time of `offset_at`).
    offset: i64,
    offset_at: i64,
    buf: Vec<u8>,
}

impl FileLog {
    /// Opens `path` for appending (`-`: standard output; a bare name goes under
    /// /var/log, as mbusd does).
    pub fn open(path: &str, level: u8) -> io::Result<FileLog> {
        let out = if path == "-" {
            Out::Stdout
        } else {
            let full = Self::path_of(path);
            Out::File(std::fs::OpenOptions::new().append(true).create(true).open(full)?)
        };
        Ok(FileLog { level, out, offset: local_offset(), offset_at: unix_now(), buf: Vec::with_capacity(256) })
    }

    /// The file a `logfile` value names.
    pub fn path_of(path: &str) -> String {
        if path.contains('/') { path.to_owned() } else { format!("/var/log/{path}") }
    }

    /// Whether the log is standard output.
    pub fn is_stdout(&self) -> bool {
        matches!(self.out, Out::Stdout)
    }
}

impl Log for FileLog {
    fn enabled(&self, level: u8) -> bool {
        level <= self.level
    }

    fn write(&mut self, level: u8, args: fmt::Arguments<'_>) {
        let now = unix_now();
        if now - self.offset_at >= 3600 || now < self.offset_at {
            self.offset = local_offset();
            self.offset_at = now;
        }
        self.buf.clear();
        stamp(&mut self.buf, now + self.offset);
        if level == 0 {
            self.buf.extend_from_slice(b" ERROR: ");
        } else {
            self.buf.push(b' ');
        }
        let _ = self.buf.write_fmt(args);
        self.buf.push(b'\n');
        // One write per line: lines of the log never interleave.
        let _ = match &mut self.out {
            Out::Stdout => {
                let mut o = io::stdout().lock();
                o.write_all(&self.buf).and_then(|()| o.flush())
            }
            Out::File(f) => f.write_all(&self.buf),
        };
    }
}

const MONTHS: [&str; 12] = ["Jan", "Feb", "Mar", "Apr", "May", "Jun", "Jul", "Aug", "Sep", "Oct", "Nov", "Dec"];

/// `DD Mon YYYY HH:MM:SS` of `secs` (seconds since the epoch, local time already added).
fn stamp(out: &mut Vec<u8>, secs: i64) {
    let days = secs.div_euclid(86_400);
    let rem = secs.rem_euclid(86_400);
    let (y, m, d) = civil(days);
    let _ = write!(
        out,
        "{d:02} {} {y:04} {:02}:{:02}:{:02}",
        MONTHS[(m - 1) as usize],
        rem / 3600,
        rem / 60 % 60,
        rem % 60
    );
}

/// The civil date (year, month 1-12, day 1-31) of a day number since 1970-01-01
/// (H. Hinnant's algorithm).
fn civil(days: i64) -> (i64, i64, i64) {
    let z = days + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = doy - (153 * mp + 2) / 5 + 1;
    let m = if mp < 10 { mp + 3 } else { mp - 9 };
    (yoe + era * 400 + i64::from(m <= 2), m, d)
}

/// The current UTC offset of local time from the zone file (TZ naming a file, else
/// /etc/localtime): the last transition's type in a TZif file before now; 0 if it
/// cannot be read (the stamps are then UTC).
fn local_offset() -> i64 {
    let path = match std::env::var("TZ") {
        Ok(tz) if tz.is_empty() || tz == "UTC" || tz == "UTC0" => return 0,
        Ok(tz) => {
            let name = tz.trim_start_matches(':');
            if name.starts_with('/') { name.to_owned() } else { format!("/usr/share/zoneinfo/{name}") }
        }
        Err(_) => "/etc/localtime".to_owned(),
    };
    let Ok(data) = std::fs::read(path) else { return 0 };
    tzif_offset(&data, unix_now()).unwrap_or(0)
}

fn unix_now() -> i64 {
    SystemTime::now().duration_since(UNIX_EPOCH).map_or(0, |d| d.as_secs() as i64)
}

/// The offset at `now` from a TZif file's data (version 2+ data block preferred).
fn tzif_offset(data: &[u8], now: i64) -> Option<i64> {
    fn be32(b: &[u8], at: usize) -> Option<i64> {
        Some(i64::from(i32::from_be_bytes(b.get(at..at + 4)?.try_into().ok()?)))
    }
    fn be64(b: &[u8], at: usize) -> Option<i64> {
        Some(i64::from_be_bytes(b.get(at..at + 8)?.try_into().ok()?))
    }
    fn counts(b: &[u8]) -> Option<[usize; 6]> {
        if b.get(..4)? != b"TZif" {
            return None;
        }
        let mut c = [0usize; 6];
        for (i, v) in c.iter_mut().enumerate() {
            *v = usize::try_from(be32(b, 20 + 4 * i)?).ok()?;
        }
        Some(c)
    }
    let [isutc, isstd, leap, timecnt, typecnt, charcnt] = counts(data)?;
    let mut block = data;
    let mut tsize = 4;
    if data.get(4).is_some_and(|&v| v >= b'2') {
        let v1 = 44 + timecnt * 5 + typecnt * 6 + charcnt + leap * 8 + isstd + isutc;
        block = data.get(v1..)?;
        tsize = 8;
    }
    let [_, _, _, timecnt, typecnt, _] = counts(block)?;
    if typecnt == 0 {
        return None;
    }
    let times = 44;
    let idx = times + timecnt * tsize;
    let types = idx + timecnt;
    let mut which = 0usize;
    for i in 0..timecnt {
        let t = if tsize == 8 { be64(block, times + 8 * i)? } else { be32(block, times + 4 * i)? };
        if t > now {
            break;
        }
        which = usize::from(*block.get(idx + i)?);
    }
    if timecnt == 0 {
        which = 0;
    }
    if which >= typecnt {
        return None;
    }
    be32(block, types + 6 * which)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stamps() {
        let mut v = Vec::new();
        stamp(&mut v, 0);
        assert_eq!(v, b"01 Jan 1970 00:00:00");
        v.clear();
        stamp(&mut v, 1_798_000_000); // 2026-12-23 ...
        assert_eq!(String::from_utf8(v).unwrap(), "23 Dec 2026 04:26:40");
        v = Vec::new();
        stamp(&mut v, 951_782_400); // 2000-02-29
        assert_eq!(v, b"29 Feb 2000 00:00:00");
    }

    #[test]
    fn levels() {
        let mut m = Memory { level: 2, lines: Vec::new() };
        let log = &mut m;
        logf!(log, 3, "not {}", 1);
        logf!(log, 2, "yes {}", 2);
        assert_eq!(m.lines, vec![(2, "yes 2".to_owned())]);
    }

    #[test]
    fn zone_files() {
        // Whatever the machine's zone, reading it never panics and gives a sane offset.
        let o = local_offset();
        assert!(o.abs() <= 14 * 3600);
        assert_eq!(tzif_offset(b"TZif2", 0), None);
        for name in ["Europe/Berlin", "America/New_York", "UTC"] {
            if let Ok(d) = std::fs::read(format!("/usr/share/zoneinfo/{name}")) {
                // 2026-07-01: summer time.
                let off = tzif_offset(&d, 1_782_864_000).unwrap();
                let want = match name {
                    "Europe/Berlin" => 7200,
                    "America/New_York" => -14400,
                    _ => 0,
                };
                assert_eq!(off, want, "{name}");
            }
        }
    }
}
