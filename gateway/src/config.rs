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

/// The usage text (`-h`).
pub fn usage() -> String {
    String::new()
}

/// Parses the command line: `args` are the arguments after the program's name.
/// Errors: `rsmodbus-gateway: -X: what is wrong`.
pub fn parse_args(args: &[String]) -> Result<Cli, String> {
    let _ = args;
    Ok(Cli::default())
}

/// Reads a configuration file's text (UTF-8; an error names the file).
pub fn read_file(path: &Path) -> Result<String, ConfigError> {
    std::fs::read_to_string(path).map_err(|e| ConfigError {
        place: Place::Whole(path.to_path_buf()),
        key: String::new(),
        what: format!("cannot read: {e}"),
    })
}

/// The configuration: the defaults, then the file (its path and text), then the
/// command line again; validated.
pub fn load(cli: &Cli, file: Option<(&Path, &str)>) -> Result<Config, ConfigError> {
    let _ = (cli, file);
    Ok(Config::default())
}

/// Whether a function code is a read (`r` roles may use it): 01-04 only.
pub fn is_read(function: u8) -> bool {
    (1..=4).contains(&function)
}

impl Default for Config {
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

impl Config {
    /// The line of `unit` and the unit it has there; `None`: no route (0x0A).
    pub fn route(&self, unit: u8) -> Option<(usize, u8)> {
        let _ = unit;
        None
    }

    /// The TLS policy, on the unit the master addressed: a `tls_role` entry of the
    /// master's role covers the unit, and gives `rw` unless the function is a read.
    pub fn authorized(&self, role: Option<&str>, unit: u8, function: u8) -> bool {
        let _ = (role, unit, function);
        false
    }

    /// Whether the unsecured fronts reach `unit` (`plain_units`).
    pub fn plain_reaches(&self, unit: u8) -> bool {
        self.plain_units.contains(unit)
    }

    /// Whether the UDP front answers `ip` (`udp_allow`).
    pub fn allowed_udp(&self, ip: IpAddr) -> bool {
        let _ = ip;
        false
    }

    /// The keys that differ in `new` and take a restart.
    pub fn restart_keys(&self, new: &Config) -> Vec<&'static str> {
        let _ = new;
        Vec::new()
    }

    /// `new` with the keys that take a restart kept from `self` (the running
    /// values), validated again as it will run.
    pub fn reloaded(&self, new: Config) -> Result<Config, ConfigError> {
        Ok(new)
    }
}

impl UnitSet {
    pub fn all() -> UnitSet {
        UnitSet([u64::MAX; 4])
    }
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
        f.debug_set().entries((0..=255u8).filter(|u| self.contains(*u))).finish()
    }
}

impl Net {
    /// Whether `ip` is in this net.
    pub fn contains(&self, ip: IpAddr) -> bool {
        let _ = ip;
        false
    }
}
