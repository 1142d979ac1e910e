//! The gateway's configuration: mbusd's command line and configuration file, the
//! extended keys, validated into a [`Config`]. Pure: no I/O but the file's text the
//! caller reads ([`read_file`] does that for it).
//!
//! Order: the defaults, then the file, then the command line again (the command line
//! wins, on a reload too). Errors are one line each:
//! `rsmodbus-gateway: FILE:LINE: KEY: what is wrong` (the file), or
//! `rsmodbus-gateway: -X: what is wrong` (the command line).

use std::fmt;
use std::net::IpAddr;
use std::path::{Path, PathBuf};

/// Most lines (the default one included), routes and `tls_role.*` entries.
pub const LINES_MAX: usize = 64;
pub const ROUTES_MAX: usize = 256;
pub const ROLES_MAX: usize = 64;
/// A path's most bytes (PATH_MAX less the NUL).
pub const PATH_MAX: usize = 4095;

/// The running configuration.
#[derive(Clone, Debug, PartialEq)]
pub struct Config {
    pub loglevel: u8,
    /// `-` is standard output; a bare name goes under /var/log.
    pub logfile: String,
    /// `[0]` is "default" (`device`/`speed`/`mode`, or `backend`), then the `line.*`.
    pub lines: Vec<LineDef>,
    /// The serial keys as given (`device`, `speed`, `mode`): the default line's when
    /// `backend = serial`.
    pub device: PathBuf,
    pub speed: u32,
    pub mode: SerialMode,
    pub rs485: bool,
    pub trx: Trx,
    pub address: String,
    /// 0: the plain Modbus/TCP front off.
    pub port: u16,
    pub maxconn: u32,
    pub timeout_s: u32,
    pub retries: u8,
    pub pause_ms: u32,
    pub wait_ms: u32,
    pub replyonbroadcast: bool,
    pub foreground: bool,
    /// The Modbus/TCP Security front: on when `tls_cert` is set.
    pub tls: Option<TlsFront>,
    pub roles: Vec<Role>,
    /// 0: off.
    pub rtutcp_port: u16,
    /// 0: off.
    pub udp_port: u16,
    pub udp_allow: Vec<Net>,
    pub routes: Vec<Route>,
    pub status_file: Option<PathBuf>,
    pub user: Option<String>,
    /// The units the unsecured fronts (Modbus/TCP, RTU over TCP, UDP) reach.
    pub plain_units: UnitSet,
    pub allow_plain: bool,
    pub config_path: Option<PathBuf>,
}

/// A line: its name and what it is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct LineDef {
    pub name: String,
    pub kind: LineKind,
}

#[derive(Clone, Debug, PartialEq, Eq)]
pub enum LineKind {
    Serial {
        device: PathBuf,
        speed: u32,
        mode: SerialMode,
    },
    /// A Modbus/TCP device; `port` is numeric (1-65535).
    Tcp {
        host: String,
        port: String,
    },
    /// RTU frames over TCP (a serial-to-Ethernet converter).
    RtuTcp {
        host: String,
        port: String,
    },
}

/// A serial mode: `8N1`, `7E1a` (a trailing `a`: Modbus ASCII).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SerialMode {
    pub data: u8,
    /// `N`, `E` or `O`.
    pub parity: char,
    pub stop: u8,
    pub ascii: bool,
}

/// The RS-485 direction control of the default line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Trx {
    /// Automatic (the adapter): nothing to do.
    Addc,
    /// RTS active on transmit (`-t`, `rts`, `rts_1`).
    RtsUp,
    /// RTS active on receive (`-r`, `rts_0`).
    RtsDown,
    /// `1` written to the file while transmitting (`-y`, `sysfs_1`).
    SysfsUp(PathBuf),
    /// `0` written to the file while transmitting (`-Y`, `sysfs_0`).
    SysfsDown(PathBuf),
}

/// `route = FIRST-LAST LINE [OFFSET]`: units first..=last go to `lines[line]` as
/// unit + offset (validated: 1-255, and unit 0 only to 0).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Route {
    pub first: u8,
    pub last: u8,
    pub line: usize,
    pub offset: i16,
}

/// `tls_role.NAME = r|rw FIRST-LAST`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Role {
    pub name: String,
    pub write: bool,
    pub first: u8,
    pub last: u8,
}

/// The Modbus/TCP Security front.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TlsFront {
    pub address: String,
    pub port: u16,
    pub cert: PathBuf,
    pub key: PathBuf,
    pub ca: PathBuf,
}

/// An address and prefix length (`10.0.0.0/8`, `::1/128`; no prefix: the host).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Net {
    pub addr: IpAddr,
    pub prefix: u8,
}

/// A set of units 0-255.
#[derive(Clone, Copy, PartialEq, Eq, Default)]
pub struct UnitSet([u64; 4]);

/// The command line, parsed (what it sets; `None`: not given).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Cli {
    /// `-h`: print [`usage`] and exit 0.
    pub help: bool,
    pub foreground: bool,
    pub logfile: Option<String>,
    pub loglevel: Option<u8>,
    pub config: Option<PathBuf>,
    pub device: Option<PathBuf>,
    pub speed: Option<u32>,
    pub mode: Option<SerialMode>,
    pub rs485: bool,
    pub trx: Option<Trx>,
    pub address: Option<String>,
    pub port: Option<u16>,
    pub maxconn: Option<u32>,
    pub retries: Option<u8>,
    pub pause_ms: Option<u32>,
    pub wait_ms: Option<u32>,
    pub timeout_s: Option<u32>,
    pub replyonbroadcast: bool,
}

/// Where an error is.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Place {
    /// A file's line.
    File { path: PathBuf, line: usize },
    /// A file as a whole (it cannot be read).
    Whole(PathBuf),
    /// A command-line option.
    Option(char),
    /// Neither (a default value).
    Nowhere,
}

/// A configuration error: `rsmodbus-gateway: FILE:LINE: KEY: what is wrong`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ConfigError {
    pub place: Place,
    /// The key (empty: none, e.g. a line without `=`).
    pub key: String,
    pub what: String,
}

impl fmt::Display for ConfigError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "rsmodbus-gateway: ")?;
        match &self.place {
            Place::File { path, line } => write!(f, "{}:{line}: ", shown(&path.to_string_lossy()))?,
            Place::Whole(path) => write!(f, "{}: ", shown(&path.to_string_lossy()))?,
            Place::Option(c) => write!(f, "-{c}: ")?,
            Place::Nowhere => {}
        }
        if !self.key.is_empty() && !matches!(self.place, Place::Option(_)) {
            write!(f, "{}: ", shown(&self.key))?;
        }
        write!(f, "{}", shown(&self.what))
    }
}

impl std::error::Error for ConfigError {}

/// Text for a one-line message: control characters escaped.
fn shown(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        if c.is_control() {
            out.extend(c.escape_default());
        } else {
            out.push(c);
        }
    }
    out
}

/// The number of requests a master may have waiting (exception 0x06 beyond).
pub const QUEUE_MAX: usize = 16;

/// The usage text (`-h`): every option as a `  -X ...` line, then every key of the
/// configuration file.
pub fn usage() -> String {
    format!(
        "rsmodbus-gateway {version}: Modbus/TCP to Modbus RTU/ASCII gateway (rsmodbus; mbusd's options)

Usage: rsmodbus-gateway [-h] [-d] [-L logfile] [-v level] [-c cfgfile]
                        [-p device] [-s speed] [-m mode] [-S]
                        [-t] [-r] [-y sysfsfile] [-Y sysfsfile]
                        [-A address] [-P port] [-C maxconn] [-N retries]
                        [-R pause] [-W wait] [-T timeout] [-b]

Options:
  -h         : this help
  -d         : don't fork (stay in the foreground)
  -L logfile : log file (default /var/log/rsmodbus-gateway.log; '-': standard output)
  -v level   : log level (0-9, default 2; 0: errors only)
  -c cfgfile : read the configuration from cfgfile (key = value lines); the options
               given override it, at start and on SIGHUP
  -p device  : serial device (default /dev/ttyS0)
  -s speed   : serial speed (1-4000000, default 19200)
  -m mode    : serial mode (default 8N1; a trailing 'a', e.g. 7E1a: Modbus ASCII)
  -S         : Linux RS-485 mode on the serial device
  -t         : RS-485 direction by RTS, active on transmit
  -r         : RS-485 direction by RTS, active on receive
  -y file    : RS-485 direction by writing 1 (transmit) / 0 to a sysfs file
  -Y file    : RS-485 direction by writing 0 (transmit) / 1 to a sysfs file
  -A address : TCP address to bind (default 0.0.0.0; IPv6 accepted)
  -P port    : TCP port (0-65535, default 502; 0: no plain Modbus/TCP front)
  -C maxconn : most simultaneous connections (1-10000, default 32; mbusd: up to 128)
  -N retries : retries of a request (0-15, default 3; 0: none)
  -R pause   : pause between requests in milliseconds (0-10000, default 100;
               0: 3.5 characters at the line's speed only; mbusd's minimum is 1)
  -W wait    : answer wait in milliseconds (1-10000, default 500)
  -T timeout : idle connection timeout in seconds (0-1000, default 60; 0: none)
  -b         : reply to broadcasts (the request echoed)

Configuration file (-c): mbusd's keys (loglevel logfile device speed mode enable_rs485
trx_control trx_sysfile address port maxconn timeout retries pause wait
replyonbroadcast), and past mbusd (rsmodbus-gateway(8)):
  tls_cert, tls_key, tls_ca         : Modbus/TCP Security front (mutual TLS)
  tls_address, tls_port             : where it listens (default port 802)
  tls_role.ROLE = r|rw FIRST-LAST   : what a certificate's role may do (else exception 01;
                                      r: function codes 01-04 only)
  rtutcp_port, udp_port             : RTU over TCP and Modbus/UDP fronts (0: none)
  udp_allow = NET ...               : the senders the UDP front answers (needed with udp_port)
  plain_units = LIST                : units the unsecured fronts reach (e.g. 1-10 20; default all)
  allow_plain = yes                 : start although an unsecured front reaches a role's units
  user = NAME                       : the user to run as once the fronts and lines are open
  backend = serial | tcp|rtutcp HOST PORT : the default line's kind
  line.NAME = serial DEV SPEED [MODE] | tcp|rtutcp HOST PORT : another line
  route = FIRST-LAST LINE [OFFSET]  : units to a line, remapped (no route: 0x0A)
  status_file = PATH                : counters per line and master (Prometheus text)
port = 0 turns the plain Modbus/TCP front off. '#' starts a comment at the start of a
line or after a blank. An error names the file, the line and the key.
SIGHUP reloads the configuration file; connections stay.

Exceptions: 0x0B when the device does not answer, 0x04 when its answers keep failing
the CRC, 0x06 when a master has {QUEUE_MAX} requests waiting.
",
        version = env!("CARGO_PKG_VERSION"),
    )
}

// ------------------------------------------------------------------ values

/// A strictly parsed integer within lo..=hi (decimal digits, a sign only where lo < 0).
fn number(v: &str, lo: i64, hi: i64) -> Result<i64, String> {
    let bad = || format!("must be {lo} to {hi}, not '{v}'");
    let digits = match v.strip_prefix('-') {
        Some(d) if lo < 0 => d,
        _ => v.strip_prefix('+').filter(|_| lo < 0).unwrap_or(v),
    };
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return Err(bad());
    }
    // Leading zeros, then at most 19 digits: i64 holds them.
    let significant = digits.trim_start_matches('0');
    if significant.len() > 18 {
        return Err(bad());
    }
    let n: i64 = significant.parse().unwrap_or(0);
    let n = if v.starts_with('-') { -n } else { n };
    if n < lo || n > hi { Err(bad()) } else { Ok(n) }
}

fn number_u32(v: &str, lo: u32, hi: u32) -> Result<u32, String> {
    number(v, lo.into(), hi.into()).map(|n| u32::try_from(n).unwrap_or(hi))
}

fn number_u16(v: &str, lo: u16, hi: u16) -> Result<u16, String> {
    number(v, lo.into(), hi.into()).map(|n| u16::try_from(n).unwrap_or(hi))
}

fn number_u8(v: &str, lo: u8, hi: u8) -> Result<u8, String> {
    number(v, lo.into(), hi.into()).map(|n| u8::try_from(n).unwrap_or(hi))
}

/// yes/no, true/false, on/off, 1/0 (any case).
fn boolean(v: &str) -> Result<bool, String> {
    match v.to_ascii_lowercase().as_str() {
        "yes" | "true" | "on" | "1" => Ok(true),
        "no" | "false" | "off" | "0" => Ok(false),
        _ => Err(format!("must be yes or no, not '{v}'")),
    }
}

/// A path: 1-4095 bytes, no NUL.
fn path(v: &str) -> Result<PathBuf, String> {
    if v.is_empty() {
        Err("no path".into())
    } else if v.len() > PATH_MAX {
        Err(format!("a path of {} bytes: at most {PATH_MAX}", v.len()))
    } else if v.contains('\0') {
        Err("a path with a NUL byte".into())
    } else {
        Ok(PathBuf::from(v))
    }
}

/// A line's or a role's name: 1-64 characters of [A-Za-z0-9_.-].
fn name(v: &str, what: &str) -> Result<String, String> {
    let ok = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-');
    if v.is_empty() || v.len() > 64 || !v.chars().all(ok) {
        Err(format!("{what} name '{v}' must be 1 to 64 characters of A-Z a-z 0-9 _ . -"))
    } else {
        Ok(v.to_string())
    }
}

/// An address to bind or a host to reach: 1-255 bytes, no blank or control.
fn host(v: &str, what: &str) -> Result<String, String> {
    if v.is_empty() || v.len() > 255 || v.chars().any(|c| c.is_whitespace() || c.is_control()) {
        Err(format!("{what} '{v}' must be 1 to 255 characters, no blank"))
    } else {
        Ok(v.to_string())
    }
}

/// A user name: 1-32 characters of [A-Za-z0-9_.-], not starting with '-'.
fn user(v: &str) -> Result<String, String> {
    let ok = |c: char| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-');
    if v.is_empty() || v.len() > 32 || v.starts_with('-') || !v.chars().all(ok) {
        Err(format!("user '{v}' must be 1 to 32 characters of A-Z a-z 0-9 _ . - (not first)"))
    } else {
        Ok(v.to_string())
    }
}

impl SerialMode {
    /// `8N1`, `7E1a`: data bits 5-8, parity N/E/O (any case), stop bits 1-2, and a
    /// trailing `a` (or `A`) for Modbus ASCII.
    pub fn parse(v: &str) -> Result<SerialMode, String> {
        let bad = || format!("serial mode '{v}' is not like 8N1 (or 7E1a for ASCII)");
        let b = v.as_bytes();
        let ascii = b.len() == 4 && matches!(b[3], b'a' | b'A');
        if b.len() != 3 && !ascii {
            return Err(bad());
        }
        let parity = (b[1] as char).to_ascii_uppercase();
        if !(b'5'..=b'8').contains(&b[0]) || !matches!(parity, 'N' | 'E' | 'O') || !matches!(b[2], b'1' | b'2') {
            return Err(bad());
        }
        Ok(SerialMode { data: b[0] - b'0', parity, stop: b[2] - b'0', ascii })
    }
}

impl fmt::Display for SerialMode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}{}{}{}", self.data, self.parity, self.stop, if self.ascii { "a" } else { "" })
    }
}

/// `FIRST-LAST`, each 0-255, first <= last.
fn unit_range(v: &str) -> Result<(u8, u8), String> {
    let (a, b) = v.split_once('-').ok_or_else(|| format!("'{v}' is not FIRST-LAST"))?;
    let first = number_u8(a, 0, 255).map_err(|e| format!("first unit {e}"))?;
    let last = number_u8(b, 0, 255).map_err(|e| format!("last unit {e}"))?;
    if first > last {
        return Err(format!("'{v}': the first unit is above the last"));
    }
    Ok((first, last))
}

impl UnitSet {
    /// `1-10 20 30-40` (blanks or commas between), or `all`.
    pub fn parse(v: &str) -> Result<UnitSet, String> {
        let mut set = UnitSet::none();
        let mut any = false;
        for part in v.split([',', ' ', '\t']).filter(|p| !p.is_empty()) {
            any = true;
            if part.eq_ignore_ascii_case("all") {
                set = UnitSet::all();
            } else if part.contains('-') {
                let (first, last) = unit_range(part)?;
                set.insert_range(first, last);
            } else {
                set.insert(number_u8(part, 0, 255).map_err(|e| format!("a unit {e}"))?);
            }
        }
        if any { Ok(set) } else { Err("no unit".into()) }
    }

    /// Whether a unit is in both sets.
    pub fn overlaps(&self, other: &UnitSet) -> bool {
        self.0.iter().zip(other.0.iter()).any(|(a, b)| a & b != 0)
    }
}

impl fmt::Display for UnitSet {
    /// `1-10 20 30-40`; `none` when empty.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let mut sep = "";
        let mut u = 0u16;
        if self.is_empty() {
            return write!(f, "none");
        }
        while u <= 255 {
            if !self.contains(u as u8) {
                u += 1;
                continue;
            }
            let first = u;
            while u < 255 && self.contains((u + 1) as u8) {
                u += 1;
            }
            if first == u {
                write!(f, "{sep}{first}")?;
            } else {
                write!(f, "{sep}{first}-{u}")?;
            }
            sep = " ";
            u += 1;
        }
        Ok(())
    }
}

impl Net {
    /// `10.0.0.0/8`, `192.168.1.7`, `::1/128` (an IPv4-mapped IPv6 net is taken as
    /// the IPv4 one).
    pub fn parse(v: &str) -> Result<Net, String> {
        let (a, p) = match v.split_once('/') {
            Some((a, p)) => (a, Some(p)),
            None => (v, None),
        };
        let addr: IpAddr = a.parse().map_err(|_| format!("'{v}' is not an address or ADDRESS/PREFIX"))?;
        let max = if addr.is_ipv4() { 32 } else { 128 };
        let prefix = match p {
            Some(p) => number_u8(p, 0, max).map_err(|e| format!("'{v}': the prefix {e}"))?,
            None => max,
        };
        Ok(match addr {
            IpAddr::V6(a6) => match a6.to_ipv4_mapped() {
                Some(a4) if prefix >= 96 => Net { addr: IpAddr::V4(a4), prefix: prefix - 96 },
                _ => Net { addr, prefix },
            },
            IpAddr::V4(_) => Net { addr, prefix },
        })
    }

    /// Whether `ip` is in this net (an IPv4-mapped IPv6 address as the IPv4 one).
    pub fn contains(&self, ip: IpAddr) -> bool {
        match (self.addr, ip.to_canonical()) {
            (IpAddr::V4(n), IpAddr::V4(a)) => {
                let mask = u32::MAX.checked_shl(32 - u32::from(self.prefix.min(32))).unwrap_or(0);
                u32::from(n) & mask == u32::from(a) & mask
            }
            (IpAddr::V6(n), IpAddr::V6(a)) => {
                let mask = u128::MAX.checked_shl(128 - u32::from(self.prefix.min(128))).unwrap_or(0);
                u128::from(n) & mask == u128::from(a) & mask
            }
            _ => false,
        }
    }
}

impl fmt::Display for Net {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}/{}", self.addr, self.prefix)
    }
}

/// `serial DEV SPEED [MODE]`, `tcp HOST PORT`, `rtutcp HOST PORT`.
fn line_kind(v: &str) -> Result<LineKind, String> {
    let t: Vec<&str> = v.split([' ', '\t']).filter(|p| !p.is_empty()).collect();
    match t.as_slice() {
        ["serial", dev, speed, rest @ ..] if rest.len() <= 1 => Ok(LineKind::Serial {
            device: path(dev)?,
            speed: number_u32(speed, 1, 4_000_000).map_err(|e| format!("speed {e}"))?,
            mode: match rest.first() {
                Some(m) => SerialMode::parse(m)?,
                None => SerialMode { data: 8, parity: 'N', stop: 1, ascii: false },
            },
        }),
        [kind @ ("tcp" | "rtutcp"), h, p] => {
            let host = host(h, "host")?;
            let port = number_u16(p, 1, 65535).map_err(|e| format!("port {e}"))?.to_string();
            Ok(if *kind == "tcp" { LineKind::Tcp { host, port } } else { LineKind::RtuTcp { host, port } })
        }
        _ => Err("must be 'serial DEVICE SPEED [MODE]', 'tcp HOST PORT' or 'rtutcp HOST PORT'".into()),
    }
}

// ------------------------------------------------------------------ the command line

/// Parses the command line as mbusd's getopt string `hdL:v:c:p:s:m:Stry:Y:A:P:C:N:R:W:T:b`
/// (options may be grouped, `-v3` or `-v 3`, `--` ends them). `args` are the
/// arguments after the program's name. `-h` stops there (`help`). Errors:
/// `rsmodbus-gateway: -X: what is wrong`.
pub fn parse_args(args: &[String]) -> Result<Cli, String> {
    let mut cli = Cli::default();
    let mut i = 0;
    while i < args.len() {
        let arg = &args[i];
        i += 1;
        if arg == "--" {
            if let Some(extra) = args.get(i) {
                return Err(format!("rsmodbus-gateway: '{}': not an option (-h lists them)", shown(extra)));
            }
            break;
        }
        let Some(group) = arg.strip_prefix('-').filter(|g| !g.is_empty()) else {
            return Err(format!("rsmodbus-gateway: '{}': not an option (-h lists them)", shown(arg)));
        };
        let mut chars = group.char_indices();
        while let Some((at, c)) = chars.next() {
            let fail = |what: String| format!("rsmodbus-gateway: -{}: {}", shown(&c.to_string()), shown(&what));
            let takes =
                matches!(c, 'L' | 'v' | 'c' | 'p' | 's' | 'm' | 'y' | 'Y' | 'A' | 'P' | 'C' | 'N' | 'R' | 'W' | 'T');
            let value = if takes {
                let rest = &group[at + c.len_utf8()..];
                let v = if !rest.is_empty() {
                    rest.to_string()
                } else if let Some(next) = args.get(i) {
                    i += 1;
                    next.clone()
                } else {
                    return Err(fail("needs a value".into()));
                };
                // The rest of the group was the value.
                while chars.next().is_some() {}
                v
            } else {
                String::new()
            };
            let v = value.as_str();
            match c {
                'h' => {
                    cli.help = true;
                    return Ok(cli);
                }
                'd' => cli.foreground = true,
                'L' => cli.logfile = Some(path(v).map_err(fail)?.to_string_lossy().into_owned()),
                'v' => cli.loglevel = Some(number_u8(v, 0, 9).map_err(fail)?),
                'c' => cli.config = Some(path(v).map_err(fail)?),
                'p' => cli.device = Some(path(v).map_err(fail)?),
                's' => cli.speed = Some(number_u32(v, 1, 4_000_000).map_err(fail)?),
                'm' => cli.mode = Some(SerialMode::parse(v).map_err(fail)?),
                'S' => cli.rs485 = true,
                't' => cli.trx = Some(Trx::RtsUp),
                'r' => cli.trx = Some(Trx::RtsDown),
                'y' => cli.trx = Some(Trx::SysfsUp(path(v).map_err(fail)?)),
                'Y' => cli.trx = Some(Trx::SysfsDown(path(v).map_err(fail)?)),
                'A' => cli.address = Some(host(v, "address").map_err(fail)?),
                'P' => cli.port = Some(number_u16(v, 0, 65535).map_err(fail)?),
                'C' => cli.maxconn = Some(number_u32(v, 1, 10000).map_err(fail)?),
                'N' => cli.retries = Some(number_u8(v, 0, 15).map_err(fail)?),
                'R' => cli.pause_ms = Some(number_u32(v, 0, 10000).map_err(fail)?),
                'W' => cli.wait_ms = Some(number_u32(v, 1, 10000).map_err(fail)?),
                'T' => cli.timeout_s = Some(number_u32(v, 0, 1000).map_err(fail)?),
                'b' => cli.replyonbroadcast = true,
                _ => return Err(fail("unknown option (-h lists them)".into())),
            }
        }
    }
    Ok(cli)
}

/// Reads a configuration file's text. An error names the file (and, for text that
/// is not UTF-8, the line).
pub fn read_file(path: &Path) -> Result<String, ConfigError> {
    let bytes = std::fs::read(path).map_err(|e| ConfigError {
        place: Place::Whole(path.to_path_buf()),
        key: String::new(),
        what: format!("cannot read it: {e}"),
    })?;
    String::from_utf8(bytes).map_err(|e| {
        let at = e.utf8_error().valid_up_to();
        let line = 1 + e.as_bytes()[..at].iter().filter(|b| **b == b'\n').count();
        ConfigError {
            place: Place::File { path: path.to_path_buf(), line },
            key: String::new(),
            what: "not UTF-8 text".into(),
        }
    })
}

// ------------------------------------------------------------------ the file

/// The configuration being built, with where each key was set (for the errors of
/// the checks made once everything is read).
struct Builder<'a> {
    c: Config,
    file: Option<&'a Path>,
    origin: std::collections::HashMap<&'static str, Place>,
    backend: LineKind,
    trx_control: TrxKind,
    trx_sysfile: Option<PathBuf>,
    tls_address: String,
    tls_port: u16,
    tls_cert: Option<PathBuf>,
    tls_key: Option<PathBuf>,
    tls_ca: Option<PathBuf>,
    /// The `line.*` entries and where each is.
    lines: Vec<(LineDef, usize)>,
    /// `route` entries: first, last, line name, offset, file line.
    routes: Vec<(u8, u8, String, i16, usize)>,
    role_lines: Vec<usize>,
    plain_units_given: bool,
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum TrxKind {
    Addc,
    RtsUp,
    RtsDown,
    SysfsUp,
    SysfsDown,
}

/// The key names as `&'static str` (for `origin` and `restart_keys`).
const KEYS: &[&str] = &[
    "loglevel",
    "logfile",
    "device",
    "speed",
    "mode",
    "enable_rs485",
    "trx_control",
    "trx_sysfile",
    "address",
    "port",
    "maxconn",
    "timeout",
    "retries",
    "pause",
    "wait",
    "replyonbroadcast",
    "status_file",
    "rtutcp_port",
    "udp_port",
    "udp_allow",
    "backend",
    "tls_address",
    "tls_port",
    "tls_cert",
    "tls_key",
    "tls_ca",
    "user",
    "plain_units",
    "allow_plain",
];

/// Splits a file's line into key and value: `#` starts a comment at the start of the
/// line or after a blank; blanks around both are dropped. `None`: nothing on it.
fn key_value(line: &str) -> Option<Result<(&str, &str), String>> {
    let line = line.strip_suffix('\r').unwrap_or(line);
    let mut end = line.len();
    let mut prev_blank = true;
    for (i, c) in line.char_indices() {
        if c == '#' && prev_blank {
            end = i;
            break;
        }
        prev_blank = c == ' ' || c == '\t';
    }
    let blank = [' ', '\t'];
    let line = line[..end].trim_matches(blank);
    if line.is_empty() {
        return None;
    }
    Some(match line.split_once('=') {
        None => Err(format!("'{line}' is not 'key = value'")),
        Some((k, _)) if k.trim_matches(blank).is_empty() => Err("no key before '='".into()),
        Some((k, v)) => Ok((k.trim_matches(blank), v.trim_matches(blank))),
    })
}

impl<'a> Builder<'a> {
    fn new(file: Option<&'a Path>) -> Builder<'a> {
        let c = Config::default();
        Builder {
            backend: c.lines[0].kind.clone(),
            c,
            file,
            origin: std::collections::HashMap::new(),
            trx_control: TrxKind::Addc,
            trx_sysfile: None,
            tls_address: "0.0.0.0".into(),
            tls_port: 802,
            tls_cert: None,
            tls_key: None,
            tls_ca: None,
            lines: Vec::new(),
            routes: Vec::new(),
            role_lines: Vec::new(),
            plain_units_given: false,
        }
    }

    fn at(&self, line: usize) -> Place {
        match self.file {
            Some(p) => Place::File { path: p.to_path_buf(), line },
            None => Place::Nowhere,
        }
    }

    fn error(&self, line: usize, key: &str, what: String) -> ConfigError {
        ConfigError { place: self.at(line), key: key.to_string(), what }
    }

    /// Where a key was set (the file's line, an option), or `Nowhere`: its default.
    fn origin_of(&self, key: &str) -> Place {
        self.origin.get(key).cloned().unwrap_or(Place::Nowhere)
    }

    fn read(&mut self, text: &str) -> Result<(), ConfigError> {
        for (n, raw) in text.split('\n').enumerate() {
            let n = n + 1;
            match key_value(raw) {
                None => {}
                Some(Err(what)) => return Err(ConfigError { place: self.at(n), key: String::new(), what }),
                Some(Ok((k, v))) => self.set(n, k, v).map_err(|what| self.error(n, k, what))?,
            }
        }
        Ok(())
    }

    /// One `key = value` of the file, at line `n`.
    fn set(&mut self, n: usize, k: &str, v: &str) -> Result<(), String> {
        if let Some(line_name) = k.strip_prefix("line.") {
            return self.set_line(n, line_name, v);
        }
        if let Some(role) = k.strip_prefix("tls_role.") {
            return self.set_role(n, role, v);
        }
        if k == "route" {
            return self.set_route(n, v);
        }
        let Some(key) = KEYS.iter().copied().find(|key| *key == k) else {
            return Err(format!("unknown key '{k}'"));
        };
        // Keys whose empty value means "none".
        let optional = matches!(key, "trx_sysfile" | "status_file" | "tls_cert" | "tls_key" | "tls_ca" | "user");
        if v.is_empty() && !optional {
            return Err("no value".into());
        }
        let c = &mut self.c;
        match key {
            "loglevel" => c.loglevel = number_u8(v, 0, 9)?,
            "logfile" => c.logfile = path(v)?.to_string_lossy().into_owned(),
            "device" => c.device = path(v)?,
            "speed" => c.speed = number_u32(v, 1, 4_000_000)?,
            "mode" => c.mode = SerialMode::parse(v)?,
            "enable_rs485" => c.rs485 = boolean(v)?,
            "trx_control" => {
                self.trx_control = match v {
                    "addc" => TrxKind::Addc,
                    "rts" | "rts_1" => TrxKind::RtsUp,
                    "rts_0" => TrxKind::RtsDown,
                    "sysfs_1" => TrxKind::SysfsUp,
                    "sysfs_0" => TrxKind::SysfsDown,
                    _ => return Err(format!("must be addc, rts, rts_1, rts_0, sysfs_1 or sysfs_0, not '{v}'")),
                }
            }
            "trx_sysfile" => self.trx_sysfile = if v.is_empty() { None } else { Some(path(v)?) },
            "address" => c.address = host(v, "address")?,
            "port" => c.port = number_u16(v, 0, 65535)?,
            "maxconn" => c.maxconn = number_u32(v, 1, 10000)?,
            "timeout" => c.timeout_s = number_u32(v, 0, 1000)?,
            "retries" => c.retries = number_u8(v, 0, 15)?,
            "pause" => c.pause_ms = number_u32(v, 0, 10000)?,
            "wait" => c.wait_ms = number_u32(v, 1, 10000)?,
            "replyonbroadcast" => c.replyonbroadcast = boolean(v)?,
            "status_file" => c.status_file = if v.is_empty() { None } else { Some(path(v)?) },
            "rtutcp_port" => c.rtutcp_port = number_u16(v, 0, 65535)?,
            "udp_port" => c.udp_port = number_u16(v, 0, 65535)?,
            "udp_allow" => {
                for net in v.split([' ', '\t', ',']).filter(|p| !p.is_empty()) {
                    c.udp_allow.push(Net::parse(net)?);
                }
            }
            "backend" => {
                self.backend = if v == "serial" {
                    LineKind::Serial { device: PathBuf::new(), speed: 0, mode: c.mode }
                } else {
                    match line_kind(v) {
                        Ok(k @ (LineKind::Tcp { .. } | LineKind::RtuTcp { .. })) => k,
                        _ => return Err("must be 'serial', 'tcp HOST PORT' or 'rtutcp HOST PORT'".into()),
                    }
                }
            }
            "tls_address" => self.tls_address = host(v, "address")?,
            "tls_port" => self.tls_port = number_u16(v, 1, 65535)?,
            "tls_cert" => self.tls_cert = if v.is_empty() { None } else { Some(path(v)?) },
            "tls_key" => self.tls_key = if v.is_empty() { None } else { Some(path(v)?) },
            "tls_ca" => self.tls_ca = if v.is_empty() { None } else { Some(path(v)?) },
            "user" => c.user = if v.is_empty() { None } else { Some(user(v)?) },
            "plain_units" => {
                let set = UnitSet::parse(v)?;
                if self.plain_units_given {
                    for u in 0..=255u8 {
                        if set.contains(u) {
                            c.plain_units.insert(u);
                        }
                    }
                } else {
                    c.plain_units = set;
                    self.plain_units_given = true;
                }
            }
            "allow_plain" => c.allow_plain = boolean(v)?,
            _ => return Err(format!("unknown key '{k}'")),
        }
        let place = self.at(n);
        self.origin.insert(key, place);
        Ok(())
    }

    fn set_line(&mut self, n: usize, line_name: &str, v: &str) -> Result<(), String> {
        let line_name = name(line_name, "a line's")?;
        if line_name == "default" {
            return Err("'default' is the first line's name (device, or backend)".into());
        }
        if let Some((_, first)) = self.lines.iter().find(|(l, _)| l.name == line_name) {
            return Err(format!("line '{line_name}' is defined already at line {first}"));
        }
        if self.lines.len() + 1 >= LINES_MAX {
            return Err(format!("more than {LINES_MAX} lines (the default one included)"));
        }
        let kind = line_kind(v)?;
        self.lines.push((LineDef { name: line_name, kind }, n));
        Ok(())
    }

    fn set_role(&mut self, n: usize, role: &str, v: &str) -> Result<(), String> {
        let role = name(role, "a role's")?;
        if self.c.roles.len() >= ROLES_MAX {
            return Err(format!("more than {ROLES_MAX} tls_role entries"));
        }
        let t: Vec<&str> = v.split([' ', '\t']).filter(|p| !p.is_empty()).collect();
        let (write, range) = match t.as_slice() {
            ["r", range] => (false, range),
            ["rw", range] => (true, range),
            _ => return Err("must be 'r FIRST-LAST' or 'rw FIRST-LAST'".into()),
        };
        let (first, last) = unit_range(range)?;
        self.c.roles.push(Role { name: role, write, first, last });
        self.role_lines.push(n);
        Ok(())
    }

    fn set_route(&mut self, n: usize, v: &str) -> Result<(), String> {
        if self.routes.len() >= ROUTES_MAX {
            return Err(format!("more than {ROUTES_MAX} routes"));
        }
        let t: Vec<&str> = v.split([' ', '\t']).filter(|p| !p.is_empty()).collect();
        let (range, line, offset) = match t.as_slice() {
            [range, line] => (range, line, 0),
            [range, line, offset] => (range, line, number(offset, -255, 255).map_err(|e| format!("the offset {e}"))?),
            _ => return Err("must be 'FIRST-LAST LINE [OFFSET]'".into()),
        };
        let (first, last) = unit_range(range)?;
        let line = name(line, "a line's")?;
        // Targets 1-255; unit 0 (a broadcast) only to unit 0.
        if first == 0 && offset != 0 {
            return Err(format!("units {first}-{last} with offset {offset}: unit 0 (a broadcast) must stay unit 0"));
        }
        let low = i64::from(first.max(1)) + offset;
        let high = i64::from(last) + offset;
        if last > 0 && (low < 1 || high > 255) {
            return Err(format!(
                "units {first}-{last} with offset {offset} reach units {low}-{high}: a target must be 1 to 255"
            ));
        }
        if let Some((f, l, _, _, at)) = self.routes.iter().find(|(f, l, ..)| first <= *l && *f <= last) {
            return Err(format!("units {first}-{last} overlap units {f}-{l} of the route at line {at}"));
        }
        let offset = i16::try_from(offset).map_err(|_| "the offset is out of range".to_string())?;
        self.routes.push((first, last, line, offset, n));
        Ok(())
    }

    /// The command line, over the file.
    fn apply_cli(&mut self, cli: &Cli) {
        let c = &mut self.c;
        let mut given: Vec<(&'static str, char)> = Vec::new();
        macro_rules! opt {
            ($field:ident, $dst:expr, $key:literal, $ch:literal) => {
                if let Some(v) = &cli.$field {
                    $dst = v.clone();
                    given.push(($key, $ch));
                }
            };
        }
        opt!(logfile, c.logfile, "logfile", 'L');
        opt!(loglevel, c.loglevel, "loglevel", 'v');
        opt!(device, c.device, "device", 'p');
        opt!(speed, c.speed, "speed", 's');
        opt!(mode, c.mode, "mode", 'm');
        opt!(address, c.address, "address", 'A');
        opt!(port, c.port, "port", 'P');
        opt!(maxconn, c.maxconn, "maxconn", 'C');
        opt!(retries, c.retries, "retries", 'N');
        opt!(pause_ms, c.pause_ms, "pause", 'R');
        opt!(wait_ms, c.wait_ms, "wait", 'W');
        opt!(timeout_s, c.timeout_s, "timeout", 'T');
        if cli.foreground {
            c.foreground = true;
        }
        if cli.rs485 {
            c.rs485 = true;
            given.push(("enable_rs485", 'S'));
        }
        if cli.replyonbroadcast {
            c.replyonbroadcast = true;
            given.push(("replyonbroadcast", 'b'));
        }
        if let Some(trx) = &cli.trx {
            let (kind, file, ch) = match trx {
                Trx::Addc => (TrxKind::Addc, None, 't'),
                Trx::RtsUp => (TrxKind::RtsUp, None, 't'),
                Trx::RtsDown => (TrxKind::RtsDown, None, 'r'),
                Trx::SysfsUp(p) => (TrxKind::SysfsUp, Some(p.clone()), 'y'),
                Trx::SysfsDown(p) => (TrxKind::SysfsDown, Some(p.clone()), 'Y'),
            };
            self.trx_control = kind;
            if file.is_some() {
                self.trx_sysfile = file;
                given.push(("trx_sysfile", ch));
            }
            given.push(("trx_control", ch));
        }
        for (key, ch) in given {
            self.origin.insert(key, Place::Option(ch));
        }
    }

    /// Checks what takes the whole file and the command line; the Config.
    fn finish(mut self) -> Result<Config, ConfigError> {
        let fail = |place: Place, key: &str, what: String| ConfigError { place, key: key.to_string(), what };
        // The RS-485 direction.
        self.c.trx = match (self.trx_control, self.trx_sysfile.clone()) {
            (TrxKind::Addc, _) => Trx::Addc,
            (TrxKind::RtsUp, _) => Trx::RtsUp,
            (TrxKind::RtsDown, _) => Trx::RtsDown,
            (TrxKind::SysfsUp, Some(p)) => Trx::SysfsUp(p),
            (TrxKind::SysfsDown, Some(p)) => Trx::SysfsDown(p),
            (_, None) => {
                return Err(fail(
                    self.origin_of("trx_control"),
                    "trx_control",
                    "sysfs_1 and sysfs_0 need trx_sysfile".into(),
                ));
            }
        };
        // The lines: the default one, then line.*.
        let default = match &self.backend {
            LineKind::Serial { .. } => {
                LineKind::Serial { device: self.c.device.clone(), speed: self.c.speed, mode: self.c.mode }
            }
            other => other.clone(),
        };
        self.c.lines = vec![LineDef { name: "default".into(), kind: default }];
        self.c.lines.extend(self.lines.iter().map(|(l, _)| l.clone()));
        // The routes, by the lines' names (a line may come after its route).
        let mut routes = Vec::with_capacity(self.routes.len());
        for (first, last, line, offset, at) in &self.routes {
            let Some(index) = self.c.lines.iter().position(|l| &l.name == line) else {
                return Err(fail(self.at(*at), "route", format!("no line '{line}' (default, or a line.{line} entry)")));
            };
            routes.push(Route { first: *first, last: *last, line: index, offset: *offset });
        }
        self.c.routes = routes;
        // The Modbus/TCP Security front.
        self.c.tls = match &self.tls_cert {
            None => None,
            Some(cert) => {
                let need = |key: &str, v: &Option<PathBuf>| {
                    v.clone().ok_or_else(|| {
                        fail(
                            self.origin_of("tls_cert"),
                            "tls_cert",
                            format!("the Modbus/TCP Security front needs {key}"),
                        )
                    })
                };
                Some(TlsFront {
                    address: self.tls_address.clone(),
                    port: self.tls_port,
                    cert: cert.clone(),
                    key: need("tls_key", &self.tls_key)?,
                    ca: need("tls_ca", &self.tls_ca)?,
                })
            }
        };
        check(&self.c).map_err(|(key, role, what)| match (self.origin_of(key), role) {
            // A front on by default: the line of the role it overlaps.
            (Place::Nowhere, Some(r)) => {
                fail(self.at(self.role_lines[r]), &format!("tls_role.{}", self.c.roles[r].name), what)
            }
            (Place::Nowhere, None) => match self.file {
                Some(p) => fail(Place::Whole(p.to_path_buf()), key, what),
                None => fail(Place::Nowhere, key, what),
            },
            (place, _) => fail(place, key, what),
        })?;
        Ok(self.c)
    }
}

/// The checks of a whole configuration (at load, and again as it runs after a
/// reload): `(key, the overlapping role's index, what is wrong)`.
fn check(c: &Config) -> Result<(), (&'static str, Option<usize>, String)> {
    if c.udp_port != 0 && c.udp_allow.is_empty() {
        return Err((
            "udp_port",
            None,
            "the Modbus/UDP front needs udp_allow (the senders it answers: NET ..., e.g. 10.0.0.0/8)".into(),
        ));
    }
    if c.tls.is_some() && !c.allow_plain {
        let fronts = [
            ("port", "the Modbus/TCP front", c.port),
            ("rtutcp_port", "the RTU over TCP front", c.rtutcp_port),
            ("udp_port", "the Modbus/UDP front", c.udp_port),
        ];
        for (key, front, port) in fronts {
            if port == 0 {
                continue;
            }
            let overlap = c.roles.iter().position(|r| {
                let mut units = UnitSet::none();
                units.insert_range(r.first, r.last);
                units.overlaps(&c.plain_units)
            });
            if overlap.is_some() {
                return Err((
                    key,
                    overlap,
                    format!(
                        "{front} (port {port}) reaches units that tls_role.* protects: set {key} = 0, limit plain_units, or set allow_plain = yes"
                    ),
                ));
            }
        }
    }
    Ok(())
}

/// The configuration: the defaults, then the file (its path and text), then the
/// command line again; validated. The error names the file, the line and the key
/// (or the option).
pub fn load(cli: &Cli, file: Option<(&Path, &str)>) -> Result<Config, ConfigError> {
    let mut b = Builder::new(file.map(|(p, _)| p));
    if let Some((_, text)) = file {
        b.read(text)?;
    }
    b.apply_cli(cli);
    let mut c = b.finish()?;
    c.config_path = file.map(|(p, _)| p.to_path_buf());
    Ok(c)
}

/// Whether a function code is a read, which an `r` role may use: 01 to 04 (read
/// coils, discrete inputs, holding and input registers) only. Anything else needs
/// `rw`: 0x17 (read/write registers) writes, 0x2B (encapsulated interface) may
/// carry writes (its MEI type is not the policy's to see), the diagnostics and
/// the user-defined codes may change a device's state.
pub fn is_read(function: u8) -> bool {
    (1..=4).contains(&function)
}

impl Default for Config {
    /// mbusd's defaults; no TLS front, no routes, the plain fronts reach every unit.
    fn default() -> Config {
        let mode = SerialMode { data: 8, parity: 'N', stop: 1, ascii: false };
        Config {
            loglevel: 2,
            logfile: "/var/log/rsmodbus-gateway.log".into(),
            lines: vec![LineDef {
                name: "default".into(),
                kind: LineKind::Serial { device: "/dev/ttyS0".into(), speed: 19200, mode },
            }],
            device: "/dev/ttyS0".into(),
            speed: 19200,
            mode,
            rs485: false,
            trx: Trx::Addc,
            address: "0.0.0.0".into(),
            port: 502,
            maxconn: 32,
            timeout_s: 60,
            retries: 3,
            pause_ms: 100,
            wait_ms: 500,
            replyonbroadcast: false,
            foreground: false,
            tls: None,
            roles: Vec::new(),
            rtutcp_port: 0,
            udp_port: 0,
            udp_allow: Vec::new(),
            routes: Vec::new(),
            status_file: None,
            user: None,
            plain_units: UnitSet::all(),
            allow_plain: false,
            config_path: None,
        }
    }
}

/// A line's kind without the serial settings (those are `device`, `speed`, `mode`).
fn backend_of(kind: &LineKind) -> Option<&LineKind> {
    match kind {
        LineKind::Serial { .. } => None,
        other => Some(other),
    }
}

impl Config {
    /// The line of `unit` and the unit it has there; `None`: no route (0x0A). With
    /// no route at all, every unit goes to the default line as it is.
    pub fn route(&self, unit: u8) -> Option<(usize, u8)> {
        if self.routes.is_empty() {
            return Some((0, unit));
        }
        let r = self.routes.iter().find(|r| r.first <= unit && unit <= r.last)?;
        let there = u8::try_from(i16::from(unit) + r.offset).ok()?;
        // Never a broadcast made of a unicast (load refuses such a route).
        (there != 0 || unit == 0).then_some((r.line, there))
    }

    /// The TLS policy, on the unit the master addressed (before any route): a
    /// `tls_role` entry of the master's role covers the unit, and is `rw` unless
    /// the function is a read ([`is_read`]). No role: refused.
    pub fn authorized(&self, role: Option<&str>, unit: u8, function: u8) -> bool {
        let Some(role) = role else { return false };
        self.roles.iter().any(|r| r.name == role && r.first <= unit && unit <= r.last && (r.write || is_read(function)))
    }

    /// Whether the unsecured fronts reach `unit` (`plain_units`).
    pub fn plain_reaches(&self, unit: u8) -> bool {
        self.plain_units.contains(unit)
    }

    /// Whether the UDP front answers `ip` (`udp_allow`).
    pub fn allowed_udp(&self, ip: IpAddr) -> bool {
        self.udp_allow.iter().any(|n| n.contains(ip))
    }

    /// The keys that differ in `new` and take a restart (in the file's order of
    /// keys; `line.*` for the lines, `route` when a new route names a line that is
    /// not running).
    pub fn restart_keys(&self, new: &Config) -> Vec<&'static str> {
        let mut keys = Vec::new();
        let mut differ = |key: &'static str, d: bool| {
            if d {
                keys.push(key);
            }
        };
        differ("logfile", self.logfile != new.logfile);
        differ("device", self.device != new.device);
        differ("speed", self.speed != new.speed);
        differ("mode", self.mode != new.mode);
        differ("enable_rs485", self.rs485 != new.rs485);
        let sysfile = |t: &Trx| match t {
            Trx::SysfsUp(p) | Trx::SysfsDown(p) => Some(p.clone()),
            _ => None,
        };
        differ("trx_control", std::mem::discriminant(&self.trx) != std::mem::discriminant(&new.trx));
        differ("trx_sysfile", sysfile(&self.trx) != sysfile(&new.trx));
        differ("address", self.address != new.address);
        differ("port", self.port != new.port);
        differ("maxconn", self.maxconn != new.maxconn);
        differ("rtutcp_port", self.rtutcp_port != new.rtutcp_port);
        differ("udp_port", self.udp_port != new.udp_port);
        differ("backend", backend_of(&self.lines[0].kind) != backend_of(&new.lines[0].kind));
        differ("line.*", self.lines[1..] != new.lines[1..]);
        let tls = |f: fn(&TlsFront) -> String| (self.tls.as_ref().map(f), new.tls.as_ref().map(f));
        let (a, b) = tls(|t| t.address.clone());
        differ("tls_address", a != b);
        let (a, b) = tls(|t| t.port.to_string());
        differ("tls_port", a != b);
        let (a, b) = tls(|t| t.cert.to_string_lossy().into_owned());
        differ("tls_cert", a != b);
        let (a, b) = tls(|t| t.key.to_string_lossy().into_owned());
        differ("tls_key", a != b);
        let (a, b) = tls(|t| t.ca.to_string_lossy().into_owned());
        differ("tls_ca", a != b);
        differ("user", self.user != new.user);
        differ("route", self.routes_on_running(new).is_none());
        keys
    }

    /// `new`'s routes on this configuration's lines (by name); `None`: one names a
    /// line that is not running.
    fn routes_on_running(&self, new: &Config) -> Option<Vec<Route>> {
        new.routes
            .iter()
            .map(|r| {
                let name = &new.lines.get(r.line)?.name;
                let line = self.lines.iter().position(|l| &l.name == name)?;
                Some(Route { line, ..r.clone() })
            })
            .collect()
    }

    /// After a reload (SIGHUP): `new` (the file read again, the command line applied
    /// again) with the keys that take a restart kept from `self`, the running
    /// configuration; checked again as it will run (an unsecured front kept running
    /// must not reach the roles' units). An error: nothing changes.
    pub fn reloaded(&self, new: Config) -> Result<Config, ConfigError> {
        let mut c = new;
        c.routes = match self.routes_on_running(&c) {
            Some(routes) => routes,
            None => self.routes.clone(),
        };
        c.logfile = self.logfile.clone();
        c.device = self.device.clone();
        c.speed = self.speed;
        c.mode = self.mode;
        c.lines = self.lines.clone();
        c.rs485 = self.rs485;
        c.trx = self.trx.clone();
        c.address = self.address.clone();
        c.port = self.port;
        c.maxconn = self.maxconn;
        c.rtutcp_port = self.rtutcp_port;
        c.udp_port = self.udp_port;
        c.tls = self.tls.clone();
        c.user = self.user.clone();
        c.foreground = self.foreground;
        c.config_path = self.config_path.clone().or(c.config_path);
        check(&c).map_err(|(key, _, what)| ConfigError {
            place: match &c.config_path {
                Some(p) => Place::Whole(p.clone()),
                None => Place::Nowhere,
            },
            key: key.to_string(),
            what: format!("{what} (as running: {key} takes a restart)"),
        })?;
        Ok(c)
    }
}

impl UnitSet {
    /// Every unit, 0-255.
    pub fn all() -> UnitSet {
        UnitSet([u64::MAX; 4])
    }
    /// No unit.
    pub fn none() -> UnitSet {
        UnitSet([0; 4])
    }
    pub fn contains(&self, unit: u8) -> bool {
        self.0[usize::from(unit >> 6)] & (1u64 << (unit & 63)) != 0
    }
    pub fn insert(&mut self, unit: u8) {
        self.0[usize::from(unit >> 6)] |= 1u64 << (unit & 63);
    }
    pub fn insert_range(&mut self, first: u8, last: u8) {
        for u in first..=last {
            self.insert(u);
        }
    }
    pub fn is_empty(&self) -> bool {
        self.0 == [0; 4]
    }
}

impl fmt::Debug for UnitSet {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "UnitSet({self})")
    }
}

#[cfg(test)]
#[path = "config_tests.rs"]
mod tests;
