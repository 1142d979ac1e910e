//! The gateway's I/O around [`crate::core`]: the fronts (`api::Server`s, a
//! [`Handler`] each run), the lines (`api::Modbus` event-driven clients), one
//! `api::poll` over the fronts' descriptors, the lines' wake descriptors, a
//! signalfd (SIGHUP, SIGTERM, SIGINT) and the resolver's wake; start-up (the
//! configuration, the log, the lines, the fronts, the privileges, the daemon),
//! reload and stop.
//!
//! Exit status: 0 after SIGTERM or SIGINT; 1 on any start-up failure and any fatal
//! error while running (logged at level 0).

use std::io::{Read, Write};
use std::net::{IpAddr, ToSocketAddrs};
use std::os::fd::{AsRawFd, RawFd};
use std::os::unix::net::UnixStream;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use modbus::api::{self, Handler, Later, Modbus, Parity, PollFd, Reply, RequestInfo, Rts, Server};
use nix::errno::Errno;
use nix::sys::signal::{SigSet, Signal};
use nix::sys::signalfd::{SfdFlags, SignalFd};

use crate::config::{self, Cli, Config, LineKind, Trx};
use crate::core::{Answer, Core, Dest, Failure, Front, Incoming, LineSpec, Verdict};
use crate::log::FileLog;
use crate::logf;
use crate::{privs, status};

const POLLIN: i16 = 0x001;
/// How often the status file is written.
const STATUS_EVERY: Duration = Duration::from_secs(1);
/// A host name that did not resolve is tried again after this.
const RESOLVE_RETRY: Duration = Duration::from_secs(5);

/// Runs the gateway with the command line's arguments (after the program's name);
/// returns the exit status.
pub fn main(args: &[String]) -> i32 {
    // First: a SIGHUP, SIGTERM or SIGINT from now on waits for the signalfd (the
    // threads started later inherit the mask).
    let mut mask = SigSet::empty();
    for s in [Signal::SIGHUP, Signal::SIGTERM, Signal::SIGINT] {
        mask.add(s);
    }
    if let Err(e) = mask.thread_block() {
        eprintln!("rsmodbus-gateway: blocking the signals: {e}");
        return 1;
    }
    let cli = match config::parse_args(args) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            eprint!("{}", config::usage());
            return 1;
        }
    };
    if cli.help {
        print!("{}", config::usage());
        return 0;
    }
    let text = match &cli.config {
        Some(p) => match config::read_file(p) {
            Ok(t) => Some(t),
            Err(e) => {
                eprintln!("{e}");
                return 1;
            }
        },
        None => None,
    };
    let cfg = match config::load(&cli, cli.config.as_deref().zip(text.as_deref())) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("{e}");
            return 1;
        }
    };
    privs::raise_nofile();
    let user = match cfg.user.as_deref().map(privs::lookup).transpose() {
        Ok(u) => u,
        Err(e) => {
            eprintln!("rsmodbus-gateway: {e}");
            return 1;
        }
    };
    let log = match FileLog::open(&cfg.logfile, cfg.loglevel) {
        Ok(l) => l,
        Err(e) => {
            eprintln!("rsmodbus-gateway: cannot open the log file {}: {e}", FileLog::path_of(&cfg.logfile));
            return 1;
        }
    };
    let mut gw = match Gateway::start(cli, cfg, log) {
        Ok(g) => g,
        Err((mut log, e)) => {
            // Before the daemon: standard error still goes where it was.
            eprintln!("rsmodbus-gateway: {e}");
            if !log.is_stdout() {
                logf!(&mut log, 0, "{e}");
            }
            return 1;
        }
    };
    if let Some(u) = &user {
        if let Err(e) = privs::drop_to(u) {
            eprintln!("rsmodbus-gateway: {e}");
            gw.fatal(&e);
            return 1;
        }
    }
    if !gw.core.rules.foreground {
        if let Err(e) = nix::unistd::daemon(true, gw.core.log.is_stdout()) {
            eprintln!("rsmodbus-gateway: daemon: {e}");
            return 1;
        }
    }
    gw.run(&mask)
}

/// A front: its server and kind.
struct FrontIo {
    kind: Front,
    server: Server,
}

/// A line's I/O: its context (none while its host name is not resolved yet), the
/// request on it.
struct LineIo {
    ctx: Option<Modbus>,
    in_flight: Option<i32>,
    /// Whether the context was connected when the request went (a network line: a
    /// timeout of a connect is "unreachable", of an answer "no answer").
    connected_at_send: bool,
    /// When the context said it has something due (a timeout, a pause).
    due: Option<Instant>,
    net: Option<NetLine>,
}

/// A network line: where it goes, by name or address.
struct NetLine {
    host: String,
    port: String,
    rtu: bool,
    /// The host is a name (resolved on the resolver's thread).
    named: bool,
    resolving: bool,
    addr: Option<IpAddr>,
    /// A new address, for when the request on the line is done.
    pending: Option<IpAddr>,
}

/// The resolver: one thread per named host (a lookup may take long; it never runs
/// on the loop), asked through a channel, answering through another and waking the
/// loop through a socket pair.
struct Resolver {
    wake: UnixStream,
    results: mpsc::Receiver<(usize, Result<IpAddr, String>)>,
    jobs: Vec<Option<mpsc::Sender<()>>>,
}

/// The running gateway.
struct Gateway {
    core: Core<Config, FileLog>,
    cli: Cli,
    fronts: Vec<FrontIo>,
    lines: Vec<LineIo>,
    resolver: Option<Resolver>,
    /// RS-485 direction file errors (from the library's RTS hook).
    trx_errors: Option<mpsc::Receiver<String>>,
    status_failed: bool,
}

/// The handler of one front's run: each request to the core.
struct FrontHandler<'a> {
    core: &'a mut Core<Config, FileLog>,
    front: usize,
    kind: Front,
}

impl Handler for FrontHandler<'_> {
    fn request(&mut self, info: &RequestInfo<'_>, pdu: &[u8]) -> Reply {
        let inc = Incoming {
            front: self.front,
            kind: self.kind,
            request_id: info.request_id,
            connection: info.connection_id,
            unit: info.unit,
            protocol_id: info.protocol_id,
            role: info.role,
            peer: info.peer.map(|a| a.ip().to_canonical()),
            pdu,
        };
        match self.core.request(&inc, Instant::now()) {
            Verdict::Queued => Reply::Later,
            Verdict::Exception(c) => Reply::Exception(c),
            Verdict::Close => Reply::Close,
            Verdict::Ignore => Reply::Nothing,
        }
    }

    fn closed(&mut self, connection_id: u64) {
        self.core.closed(connection_id);
    }
}

/// The serial parity of a mode's letter.
fn parity(c: char) -> Parity {
    match c {
        'E' | 'e' => Parity::Even,
        'O' | 'o' => Parity::Odd,
        _ => Parity::None,
    }
}

/// The settings every line gets (and again on reload).
fn configure(ctx: &mut Modbus, cfg: &Config) {
    let _ = ctx.set_response_timeout(Duration::from_millis(u64::from(cfg.wait_ms)));
    // Levels 8 and 9 trace the line's frames (the library's debug output).
    ctx.set_debug(cfg.loglevel >= 8);
}

/// A network line's context to `ip`.
fn net_context(n: &NetLine, ip: IpAddr, cfg: &Config) -> api::Result<Modbus> {
    let node = ip.to_string();
    let mut ctx =
        if n.rtu { Modbus::new_rtu_tcp(Some(&node), &n.port)? } else { Modbus::new_tcp(Some(&node), &n.port)? };
    configure(&mut ctx, cfg);
    ctx.set_link_recovery(true)?;
    Ok(ctx)
}

/// A front's context: `address` "0.0.0.0" is every address.
fn node(address: &str) -> Option<&str> {
    (address != "0.0.0.0").then_some(address)
}

impl Gateway {
    /// Opens the lines and the fronts. An error comes back with the log.
    fn start(cli: Cli, cfg: Config, log: FileLog) -> Result<Gateway, (FileLog, String)> {
        let mut specs = Vec::new();
        let mut lines = Vec::new();
        for def in &cfg.lines {
            match Self::open_line(&def.name, &def.kind, &cfg) {
                Ok((spec, io)) => {
                    specs.push(spec);
                    lines.push(io);
                }
                Err(e) => return Err((log, e)),
            }
        }
        let mut gw = Gateway {
            core: Core::new(cfg, log, specs),
            cli,
            fronts: Vec::new(),
            lines,
            resolver: None,
            trx_errors: None,
            status_failed: false,
        };
        if let Err(e) = gw.default_line_rs485().and_then(|()| gw.open_fronts()) {
            let Gateway { core, .. } = gw;
            return Err((core.log, e));
        }
        for (i, l) in gw.lines.iter().enumerate() {
            if l.ctx.is_none() {
                gw.core.set_available(i, false);
            }
        }
        Ok(gw)
    }

    fn open_line(name: &str, kind: &LineKind, cfg: &Config) -> Result<(LineSpec, LineIo), String> {
        match kind {
            LineKind::Serial { device, speed, mode } => {
                let dev = device.to_str().ok_or_else(|| format!("line {name}: the device's name is not UTF-8"))?;
                let p = parity(mode.parity);
                let made = if mode.ascii {
                    Modbus::new_ascii(dev, *speed, p, mode.data, mode.stop)
                } else {
                    Modbus::new_rtu(dev, *speed, p, mode.data, mode.stop)
                };
                let mut ctx = made.map_err(|e| format!("line {name} ({dev}): {e}"))?;
                configure(&mut ctx, cfg);
                ctx.connect().map_err(|e| format!("line {name} ({dev}): {e}"))?;
                // A character: a start bit, the data bits, the parity bit, the stop bits.
                let bits = 1 + u32::from(mode.data) + u32::from(p != Parity::None) + u32::from(mode.stop);
                let gap = Duration::from_secs_f64(3.5 * f64::from(bits) / f64::from((*speed).max(1)));
                let spec = LineSpec { name: name.to_owned(), gap, serial: true };
                Ok((spec, LineIo { ctx: Some(ctx), in_flight: None, connected_at_send: true, due: None, net: None }))
            }
            LineKind::Tcp { host, port } | LineKind::RtuTcp { host, port } => {
                let rtu = matches!(kind, LineKind::RtuTcp { .. });
                let literal = host.trim_start_matches('[').trim_end_matches(']').parse::<IpAddr>().ok();
                let mut net = NetLine {
                    host: host.clone(),
                    port: port.clone(),
                    rtu,
                    named: literal.is_none(),
                    resolving: false,
                    addr: literal,
                    pending: None,
                };
                let ctx = match literal {
                    // A device on the network is connected by the first request,
                    // without waiting.
                    Some(ip) => {
                        Some(net_context(&net, ip, cfg).map_err(|e| format!("line {name} ({host} {port}): {e}"))?)
                    }
                    None => None,
                };
                net.resolving = false;
                // RTU over TCP: RTU framing, the serial broadcast rules.
                let spec = LineSpec { name: name.to_owned(), gap: Duration::ZERO, serial: rtu };
                Ok((spec, LineIo { ctx, in_flight: None, connected_at_send: false, due: None, net: Some(net) }))
            }
        }
    }

    /// RS-485 on the default line: the kernel's mode, the direction by RTS or
    /// through a file.
    fn default_line_rs485(&mut self) -> Result<(), String> {
        let cfg = &self.core.rules;
        let serial = matches!(cfg.lines[0].kind, LineKind::Serial { .. });
        let Some(ctx) = self.lines[0].ctx.as_mut() else { return Ok(()) };
        if cfg.rs485 {
            if !serial {
                return Err("enable_rs485 (-S): the default line is not a serial line".into());
            }
            ctx.set_rs485().map_err(|e| format!("line default: RS-485 mode: {e}"))?;
        }
        match &cfg.trx {
            Trx::Addc => {}
            Trx::RtsUp | Trx::RtsDown => {
                let mode = if cfg.trx == Trx::RtsUp { Rts::Up } else { Rts::Down };
                ctx.set_rts(mode).map_err(|e| {
                    format!("line default: RS-485 direction by RTS (-t, -r): {e} (a serial RTU line only)")
                })?;
            }
            Trx::SysfsUp(path) | Trx::SysfsDown(path) => {
                // Written before and after each transmission by the library's RTS
                // hook: `on` is the level it wants (-y: 1 while sending, -Y: 0).
                std::fs::OpenOptions::new()
                    .write(true)
                    .open(path)
                    .map_err(|e| format!("RS-485 direction file {}: {e}", path.display()))?;
                let (tx, rx) = mpsc::channel();
                let file = path.clone();
                let hook = move |on: bool| {
                    let r = std::fs::OpenOptions::new()
                        .write(true)
                        .open(&file)
                        .and_then(|mut f| f.write_all(if on { b"1" } else { b"0" }));
                    if let Err(e) = r {
                        let _ = tx.send(format!("RS-485 direction file {}: {e}", file.display()));
                    }
                };
                let mode = if matches!(cfg.trx, Trx::SysfsUp(_)) { Rts::Up } else { Rts::Down };
                ctx.set_custom_rts(Box::new(hook)).and_then(|()| ctx.set_rts(mode)).map_err(|e| {
                    format!(
                        "line default: RS-485 direction through {} (-y, -Y): {e} (a serial RTU line only)",
                        path.display()
                    )
                })?;
                self.trx_errors = Some(rx);
            }
        }
        Ok(())
    }

    /// The fronts: Modbus/TCP, RTU over TCP, Modbus/UDP, Modbus/TCP Security.
    fn open_fronts(&mut self) -> Result<(), String> {
        let cfg = &self.core.rules;
        let any = node(&cfg.address);
        let mut made: Vec<(Front, api::Result<Modbus>)> = Vec::new();
        if cfg.port > 0 {
            made.push((Front::Tcp, Modbus::new_tcp(any, &cfg.port.to_string())));
        }
        if cfg.rtutcp_port > 0 {
            made.push((Front::RtuTcp, Modbus::new_rtu_tcp(any, &cfg.rtutcp_port.to_string())));
        }
        if cfg.udp_port > 0 {
            made.push((Front::Udp, Modbus::new_udp(any, &cfg.udp_port.to_string())));
        }
        if let Some(tls) = &cfg.tls {
            // Each file named, readable now (before the privileges go).
            for (key, path) in [("tls_cert", &tls.cert), ("tls_key", &tls.key), ("tls_ca", &tls.ca)] {
                std::fs::File::open(path).map_err(|e| format!("{key} {}: {e}", path.display()))?;
            }
            let ctx = Modbus::new_tls(node(&tls.address), &tls.port.to_string()).and_then(|mut t| {
                t.set_tls_certificate(&tls.cert, &tls.key)?;
                t.set_tls_ca(&tls.ca)?;
                Ok(t)
            });
            let ctx = ctx.map_err(|e| {
                format!(
                    "Modbus/TCP Security front: {e} (tls_cert {}, tls_key {}, tls_ca {})",
                    tls.cert.display(),
                    tls.key.display(),
                    tls.ca.display()
                )
            })?;
            made.push((Front::Tls, Ok(ctx)));
        }
        let maxconn = cfg.maxconn.max(1) as usize;
        let idle = (cfg.timeout_s > 0).then(|| Duration::from_secs(u64::from(cfg.timeout_s)));
        for (kind, ctx) in made {
            let mut server =
                ctx.and_then(|c| Server::new(c, maxconn)).map_err(|e| format!("{} front: {e}", kind.name()))?;
            server.set_idle_timeout(idle);
            // At maxconn a new connection is accepted and closed (mbusd).
            server.set_close_when_full(true);
            logf!(&mut self.core.log, 2, "{} front ready", kind.name());
            self.fronts.push(FrontIo { kind, server });
        }
        Ok(())
    }

    /// A fatal error: logged at level 0.
    fn fatal(&mut self, e: &str) {
        logf!(&mut self.core.log, 0, "{e}");
    }

    /// The loop, until SIGTERM or SIGINT (0) or a fatal error (1).
    fn run(&mut self, mask: &SigSet) -> i32 {
        let signals = match SignalFd::with_flags(mask, SfdFlags::SFD_NONBLOCK | SfdFlags::SFD_CLOEXEC) {
            Ok(s) => s,
            Err(e) => {
                self.fatal(&format!("signalfd: {e}"));
                return 1;
            }
        };
        if let Err(e) = self.start_resolver() {
            self.fatal(&format!("the resolver: {e}"));
            return 1;
        }
        {
            let cfg = &self.core.rules;
            let first = match &cfg.lines[0].kind {
                LineKind::Serial { device, speed, mode } => format!(
                    "{} {speed} {}{}{}{}",
                    device.display(),
                    mode.data,
                    mode.parity,
                    mode.stop,
                    if mode.ascii { " (ASCII)" } else { "" }
                ),
                LineKind::Tcp { host, port } => format!("tcp {host} {port}"),
                LineKind::RtuTcp { host, port } => format!("rtutcp {host} {port}"),
            };
            let (address, port) = (cfg.address.clone(), cfg.port);
            logf!(&mut self.core.log, 2, "rsmodbus-gateway {} started: {address}:{port} -> {first}", status::VERSION);
        }
        let mut fds: Vec<PollFd> = Vec::with_capacity(2 + self.fronts.len() + self.lines.len());
        let mut next_status = Instant::now();
        let code = loop {
            let now = Instant::now();
            if self.core.rules.status_file.is_some() && now >= next_status {
                self.write_status();
                next_status = now + STATUS_EVERY;
            }
            let mut due: Option<Instant> = self.core.rules.status_file.as_ref().map(|_| next_status);
            let mut soonest = |t: Instant| due = Some(due.map_or(t, |d| d.min(t)));
            fds.clear();
            fds.push(PollFd { fd: signals.as_raw_fd(), events: POLLIN, revents: 0 });
            fds.push(PollFd {
                fd: self.resolver.as_ref().map_or(-1, |r| r.wake.as_raw_fd()),
                events: POLLIN,
                revents: 0,
            });
            for f in &self.fronts {
                fds.push(PollFd { fd: f.server.fd(), events: POLLIN, revents: 0 });
            }
            for (i, l) in self.lines.iter_mut().enumerate() {
                let mut fd: RawFd = -1;
                l.due = None;
                if let Some(ctx) = l.ctx.as_mut() {
                    if let Ok((wake, until)) = ctx.poll_fd() {
                        fd = wake;
                        if let Some(t) = until {
                            l.due = Some(now + t);
                            soonest(now + t);
                        }
                    }
                    if l.in_flight.is_none() {
                        if let Some(t) = self.core.send_at(i, now) {
                            soonest(t);
                        }
                    }
                }
                fds.push(PollFd { fd, events: POLLIN, revents: 0 });
            }
            if let Some(t) = self.core.tick_at() {
                soonest(t);
            }
            let timeout = due.map(|d| d.saturating_duration_since(now));
            match api::poll(&mut fds, timeout) {
                Ok(_) => {}
                Err(e) if e.errno() == Errno::EINTR as i32 => continue,
                Err(e) => {
                    self.fatal(&format!("poll: {e}"));
                    break 1;
                }
            }
            if fds[0].revents != 0 && self.signals(&signals) {
                break 0;
            }
            if fds[1].revents != 0 {
                self.resolved();
            }
            let base = 2;
            for k in 0..self.fronts.len() {
                if fds[base + k].revents == 0 {
                    continue;
                }
                let f = &mut self.fronts[k];
                let mut h = FrontHandler { core: &mut self.core, front: k, kind: f.kind };
                if let Err(e) = f.server.run(Some(Duration::ZERO), &mut h) {
                    let what = format!("{} front: {e}", f.kind.name());
                    self.fatal(&what);
                    return 1;
                }
            }
            let base = base + self.fronts.len();
            for i in 0..self.lines.len() {
                self.service_line(i, fds[base + i].revents);
            }
            self.core.tick(Instant::now());
            if let Some(rx) = &self.trx_errors {
                while let Ok(e) = rx.try_recv() {
                    logf!(&mut self.core.log, 1, "{e}");
                }
            }
        };
        self.stop();
        code
    }

    /// The signals that came: true to stop.
    fn signals(&mut self, fd: &SignalFd) -> bool {
        let mut stop = false;
        while let Ok(Some(si)) = fd.read_signal() {
            match Signal::try_from(si.ssi_signo as i32) {
                Ok(Signal::SIGHUP) => self.reload(),
                Ok(Signal::SIGTERM | Signal::SIGINT) => stop = true,
                _ => {}
            }
        }
        stop
    }

    /// Line `i`: what its context did, the answers, the next request.
    fn service_line(&mut self, i: usize, revents: i16) {
        let l = &mut self.lines[i];
        let Some(ctx) = l.ctx.as_mut() else { return };
        // When its wake descriptor is readable, or what its context said was due is.
        if revents != 0 || l.due.is_some_and(|d| Instant::now() >= d) {
            if let Err(e) = ctx.process_events(revents) {
                let name = self.core.lines()[i].name().to_owned();
                logf!(&mut self.core.log, 1, "line {name}: {e}");
            }
        }
        while let Some(c) = ctx.next_completion() {
            if l.in_flight != Some(c.id) {
                continue;
            }
            l.in_flight = None;
            let now = Instant::now();
            let done = match c.result {
                Ok(pdu) => self.core.completed(i, Ok(pdu), now),
                Err(e) => {
                    let failure = classify(e.errno(), l.net.is_some(), l.connected_at_send || ctx.is_connected());
                    if failure == Failure::Unreachable {
                        if let Some(n) = l.net.as_mut().filter(|n| n.named && !n.resolving) {
                            // Resolved again: the name may point elsewhere now.
                            if let Some(Some(tx)) = self.resolver.as_ref().and_then(|r| r.jobs.get(i)) {
                                n.resolving = tx.send(()).is_ok();
                            }
                        }
                    }
                    self.core.completed(i, Err((failure, &e)), now)
                }
            };
            if let Some((dest, answer)) = done {
                answer_to(&self.fronts, dest, answer);
            }
        }
        if l.in_flight.is_none() {
            if let Some(ip) = l.net.as_mut().and_then(|n| n.pending.take()) {
                self.switch_address(i, ip);
            }
        }
        let l = &mut self.lines[i];
        let Some(ctx) = l.ctx.as_mut() else { return };
        if l.in_flight.is_some() {
            return;
        }
        let now = Instant::now();
        let Some(raw) = self.core.next_send(i, now) else { return };
        l.connected_at_send = l.net.is_none() || ctx.is_connected();
        match ctx.send_raw(raw) {
            // It goes out at the next process (the request woke the descriptor).
            Ok(id) => l.in_flight = Some(id),
            Err(e) => {
                if let Some((dest, answer)) = self.core.completed(i, Err((Failure::NotSent, &e)), now) {
                    answer_to(&self.fronts, dest, answer);
                }
            }
        }
    }

    /// Starts the resolver's threads for the lines given by host name.
    fn start_resolver(&mut self) -> std::io::Result<()> {
        if !self.lines.iter().any(|l| l.net.as_ref().is_some_and(|n| n.named)) {
            return Ok(());
        }
        let (wake, wake_tx) = UnixStream::pair()?;
        wake.set_nonblocking(true)?;
        wake_tx.set_nonblocking(true)?;
        let (results_tx, results) = mpsc::channel();
        let mut jobs = Vec::new();
        for (i, l) in self.lines.iter_mut().enumerate() {
            let Some(n) = l.net.as_mut().filter(|n| n.named) else {
                jobs.push(None);
                continue;
            };
            let (tx, rx) = mpsc::channel::<()>();
            let (host, port) = (n.host.clone(), n.port.clone());
            let (results_tx, mut wake_tx) = (results_tx.clone(), wake_tx.try_clone()?);
            std::thread::Builder::new().name(format!("resolve-{i}")).spawn(move || {
                while rx.recv().is_ok() {
                    loop {
                        let r = resolve(&host, &port);
                        let ok = r.is_ok();
                        if results_tx.send((i, r)).is_err() {
                            return;
                        }
                        let _ = wake_tx.write(&[1]);
                        if ok {
                            break;
                        }
                        std::thread::sleep(RESOLVE_RETRY);
                    }
                    // Requests that came meanwhile: one lookup serves them.
                    while rx.try_recv().is_ok() {}
                }
            })?;
            n.resolving = tx.send(()).is_ok();
            jobs.push(Some(tx));
        }
        self.resolver = Some(Resolver { wake, results, jobs });
        Ok(())
    }

    /// The resolver's answers.
    fn resolved(&mut self) {
        let Some(r) = self.resolver.as_mut() else { return };
        let mut sink = [0u8; 64];
        while matches!((&r.wake).read(&mut sink), Ok(n) if n > 0) {}
        let results: Vec<_> = r.results.try_iter().collect();
        for (i, result) in results {
            let name = self.core.lines()[i].name().to_owned();
            let Some(n) = self.lines[i].net.as_mut() else { continue };
            match result {
                Ok(ip) => {
                    n.resolving = false;
                    if n.addr == Some(ip) {
                        continue;
                    }
                    logf!(&mut self.core.log, 2, "line {name}: {} is {ip}", n.host);
                    if self.lines[i].in_flight.is_some() {
                        self.lines[i].net.as_mut().expect("a network line").pending = Some(ip);
                    } else {
                        self.switch_address(i, ip);
                    }
                }
                Err(e) => {
                    logf!(&mut self.core.log, 1, "line {name}: {} does not resolve: {e} (again in 5 s)", n.host);
                }
            }
        }
    }

    /// A network line goes to `ip` from now on (a new context).
    fn switch_address(&mut self, i: usize, ip: IpAddr) {
        let Some(n) = self.lines[i].net.as_mut() else { return };
        match net_context(n, ip, &self.core.rules) {
            Ok(ctx) => {
                n.addr = Some(ip);
                self.lines[i].ctx = Some(ctx);
                self.lines[i].in_flight = None;
                self.core.set_available(i, true);
            }
            Err(e) => {
                let name = self.core.lines()[i].name().to_owned();
                logf!(&mut self.core.log, 0, "line {name}: {ip}: {e}");
            }
        }
    }

    /// SIGHUP: the configuration file again; all of it or nothing.
    fn reload(&mut self) {
        let Some(path) = self.core.rules.config_path.clone() else {
            logf!(&mut self.core.log, 1, "reload: no configuration file (-c)");
            return;
        };
        let unprefixed = |e: &config::ConfigError| {
            let s = e.to_string();
            s.strip_prefix("rsmodbus-gateway: ").map(str::to_owned).unwrap_or(s)
        };
        let loaded =
            config::read_file(&path).and_then(|text| config::load(&self.cli, Some((path.as_path(), text.as_str()))));
        let new = match loaded {
            Ok(n) => n,
            Err(e) => {
                logf!(&mut self.core.log, 0, "reload: {}: the running configuration stays", unprefixed(&e));
                return;
            }
        };
        for key in self.core.rules.restart_keys(&new) {
            logf!(&mut self.core.log, 1, "reload: {key} changed: it takes a restart");
        }
        let new = match self.core.rules.reloaded(new) {
            Ok(n) => n,
            Err(e) => {
                logf!(&mut self.core.log, 0, "reload: {}: the running configuration stays", unprefixed(&e));
                return;
            }
        };
        self.core.log.level = new.loglevel;
        for l in &mut self.lines {
            if let Some(ctx) = l.ctx.as_mut() {
                configure(ctx, &new);
            }
        }
        let idle = (new.timeout_s > 0).then(|| Duration::from_secs(u64::from(new.timeout_s)));
        for f in &mut self.fronts {
            f.server.set_idle_timeout(idle);
        }
        let (routes, roles) = (new.routes.len(), new.roles.len());
        self.core.rules = new;
        logf!(
            &mut self.core.log,
            2,
            "configuration reloaded from {}: {routes} route(s), {roles} role(s)",
            path.display()
        );
    }

    fn write_status(&mut self) {
        let Some(path) = self.core.rules.status_file.as_deref() else { return };
        match status::write(path, &status::text(self.core.lines())) {
            Ok(()) => self.status_failed = false,
            Err(e) => {
                if !self.status_failed {
                    let shown = path.display().to_string();
                    logf!(&mut self.core.log, 1, "status file {shown}: {e}");
                }
                self.status_failed = true;
            }
        }
    }

    /// The end: the counters a last time, the lines closed before the fronts.
    fn stop(&mut self) {
        for l in self.core.lines().iter().map(|l| (l.name().to_owned(), l.counters())).collect::<Vec<_>>() {
            let (name, k) = l;
            logf!(
                &mut self.core.log,
                2,
                "line {name}: {} answers, {} timeouts, {} bad answers",
                k.served,
                k.timeouts,
                k.bad_answers
            );
        }
        self.write_status();
        logf!(&mut self.core.log, 2, "rsmodbus-gateway stopped");
        self.lines.clear();
        self.fronts.clear();
    }
}

/// Gives an answer to its front (a master that left: the front drops it).
fn answer_to(fronts: &[FrontIo], dest: Dest, answer: Answer) {
    let Some(f) = fronts.get(dest.front) else { return };
    let later = match answer {
        Answer::Pdu(p) => Later::Pdu(p),
        Answer::Exception(c) => Later::Exception(c),
        Answer::Nothing => Later::Nothing,
    };
    let _ = f.server.answer(dest.request_id, later);
}

/// Why a request failed on a line, from the library's error: a bad CRC or data is
/// a bad answer; on a network line, a connect refused or unroutable, or one that
/// timed out (the line not connected), is unreachable; the rest is no answer.
pub fn classify(errno: i32, network: bool, connected: bool) -> Failure {
    use modbus::error::{EMBBADCRC, EMBBADDATA};
    let unreachable = [Errno::ECONNREFUSED, Errno::EHOSTUNREACH, Errno::ENETUNREACH, Errno::EHOSTDOWN, Errno::ENETDOWN];
    match errno {
        EMBBADCRC | EMBBADDATA => Failure::BadAnswer,
        e if network && unreachable.iter().any(|u| *u as i32 == e) => Failure::Unreachable,
        e if network && !connected && e == Errno::ETIMEDOUT as i32 => Failure::Unreachable,
        _ => Failure::NoAnswer,
    }
}

/// `host`'s first address, IPv4 first (`port` must be a number).
fn resolve(host: &str, port: &str) -> Result<IpAddr, String> {
    let port: u16 = port.parse().map_err(|_| format!("port {port} is not a number"))?;
    let addrs: Vec<_> = (host, port).to_socket_addrs().map_err(|e| e.to_string())?.collect();
    addrs.iter().find(|a| a.is_ipv4()).or(addrs.first()).map(|a| a.ip()).ok_or_else(|| "no address".to_owned())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn failures() {
        use modbus::error::{EMBBADCRC, EMBBADDATA};
        assert_eq!(classify(EMBBADCRC, false, true), Failure::BadAnswer);
        assert_eq!(classify(EMBBADDATA, true, true), Failure::BadAnswer);
        assert_eq!(classify(Errno::ETIMEDOUT as i32, false, false), Failure::NoAnswer);
        assert_eq!(classify(Errno::ETIMEDOUT as i32, true, true), Failure::NoAnswer);
        assert_eq!(classify(Errno::ETIMEDOUT as i32, true, false), Failure::Unreachable);
        assert_eq!(classify(Errno::ECONNREFUSED as i32, true, true), Failure::Unreachable);
        assert_eq!(classify(Errno::ECONNREFUSED as i32, false, true), Failure::NoAnswer);
        assert_eq!(classify(Errno::EHOSTUNREACH as i32, true, false), Failure::Unreachable);
    }

    #[test]
    fn resolving() {
        assert_eq!(resolve("127.0.0.1", "502"), Ok(IpAddr::from([127, 0, 0, 1])));
        assert!(resolve("localhost", "x").is_err());
    }
}
