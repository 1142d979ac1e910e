//! The configuration's rules, each with the input that breaks it (the C gateway's
//! findings 1-4 and 15 among them).
use super::*;

fn args(s: &str) -> Vec<String> {
    s.split_whitespace().map(String::from).collect()
}

fn cli(s: &str) -> Cli {
    parse_args(&args(s)).unwrap()
}

/// The file `gw.conf` with `text`, and the command line `opts`.
fn load_with(opts: &str, text: &str) -> Result<Config, ConfigError> {
    load(&cli(opts), Some((Path::new("gw.conf"), text)))
}

fn ok(text: &str) -> Config {
    load_with("", text).unwrap_or_else(|e| panic!("{text:?}: {e}"))
}

/// The error's text, which must be one line naming the file.
fn err(text: &str) -> String {
    let e = load_with("", text).expect_err(text).to_string();
    assert!(e.starts_with("rsmodbus-gateway: gw.conf:"), "{e}");
    assert!(!e.contains('\n'), "{e}");
    e
}

const TLS: &str = "tls_cert = /c.pem\ntls_key = /k.pem\ntls_ca = /ca.pem\n";

// ---------------------------------------------------------------- the command line

#[test]
fn every_option_of_mbusd() {
    let c = cli(
        "-d -L - -v 7 -c /etc/g.conf -p /dev/ttyUSB0 -s 9600 -m 7E1a -S -t -A ::1 -P 1502 -C 100 -N 0 -R 0 -W 1000 -T 0 -b",
    );
    assert!(c.foreground && c.rs485 && c.replyonbroadcast && !c.help);
    assert_eq!(c.logfile.as_deref(), Some("-"));
    assert_eq!(c.loglevel, Some(7));
    assert_eq!(c.config, Some(PathBuf::from("/etc/g.conf")));
    assert_eq!(c.device, Some(PathBuf::from("/dev/ttyUSB0")));
    assert_eq!(c.speed, Some(9600));
    assert_eq!(c.mode, Some(SerialMode { data: 7, parity: 'E', stop: 1, ascii: true }));
    assert_eq!(c.trx, Some(Trx::RtsUp));
    assert_eq!(c.address.as_deref(), Some("::1"));
    assert_eq!((c.port, c.maxconn, c.retries), (Some(1502), Some(100), Some(0)));
    assert_eq!((c.pause_ms, c.wait_ms, c.timeout_s), (Some(0), Some(1000), Some(0)));
    assert_eq!(cli("-r").trx, Some(Trx::RtsDown));
    assert_eq!(cli("-y /sys/g").trx, Some(Trx::SysfsUp("/sys/g".into())));
    assert_eq!(cli("-Y /sys/g").trx, Some(Trx::SysfsDown("/sys/g".into())));
    assert_eq!(cli("-t -r").trx, Some(Trx::RtsDown), "the last one wins");
}

#[test]
fn options_grouped_and_glued_as_getopt() {
    let c = cli("-dSbv3 -P0 -L/tmp/x.log");
    assert!(c.foreground && c.rs485 && c.replyonbroadcast);
    assert_eq!((c.loglevel, c.port), (Some(3), Some(0)));
    assert_eq!(c.logfile.as_deref(), Some("/tmp/x.log"));
    assert!(cli("-h -Z").help, "-h stops there");
    assert_eq!(cli("-d --"), cli("-d"));
}

#[test]
fn option_errors_name_the_option() {
    let e = |s: &str| parse_args(&args(s)).unwrap_err();
    assert_eq!(e("-Z"), "rsmodbus-gateway: -Z: unknown option (-h lists them)");
    assert_eq!(e("-v"), "rsmodbus-gateway: -v: needs a value");
    assert_eq!(e("-v 10"), "rsmodbus-gateway: -v: must be 0 to 9, not '10'");
    assert_eq!(e("-s 9600abc"), "rsmodbus-gateway: -s: must be 1 to 4000000, not '9600abc'");
    assert_eq!(e("-s 0"), "rsmodbus-gateway: -s: must be 1 to 4000000, not '0'");
    assert_eq!(e("-P 65536"), "rsmodbus-gateway: -P: must be 0 to 65535, not '65536'");
    assert_eq!(e("-P -1"), "rsmodbus-gateway: -P: must be 0 to 65535, not '-1'");
    assert_eq!(e("-C 0"), "rsmodbus-gateway: -C: must be 1 to 10000, not '0'");
    assert_eq!(e("-N 16"), "rsmodbus-gateway: -N: must be 0 to 15, not '16'");
    assert_eq!(e("-R 10001"), "rsmodbus-gateway: -R: must be 0 to 10000, not '10001'");
    assert_eq!(e("-W 0"), "rsmodbus-gateway: -W: must be 1 to 10000, not '0'");
    assert_eq!(e("-T 1001"), "rsmodbus-gateway: -T: must be 0 to 1000, not '1001'");
    assert_eq!(e("-m 9N1"), "rsmodbus-gateway: -m: serial mode '9N1' is not like 8N1 (or 7E1a for ASCII)");
    assert_eq!(e("-d stray"), "rsmodbus-gateway: 'stray': not an option (-h lists them)");
    let long = format!("-p /{}", "d".repeat(4095));
    assert!(e(&long).starts_with("rsmodbus-gateway: -p: a path of 4096 bytes"), "{}", e(&long));
    assert!(parse_args(&["-p".into(), format!("/{}", "d".repeat(4094))]).is_ok());
}

#[test]
fn usage_lists_every_option_and_key() {
    let u = usage();
    for o in "-h -d -L -v -c -p -s -m -S -t -r -y -Y -A -P -C -N -R -W -T -b".split(' ') {
        assert!(u.lines().any(|l| l.starts_with(&format!("  {o} "))), "{o}");
    }
    let file_part: String = u
        .lines()
        .skip_while(|l| !l.starts_with("Configuration file"))
        .take_while(|l| !l.starts_with("SIGHUP"))
        .collect::<Vec<_>>()
        .join("\n");
    let words: Vec<&str> = file_part.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '.')).collect();
    for k in KEYS.iter().copied().chain(["tls_role.ROLE", "line.NAME", "route"]) {
        assert!(words.contains(&k), "{k} is not in -h's part on the file");
    }
}

// ---------------------------------------------------------------- the file

#[test]
fn defaults_are_mbusds() {
    let c = load(&Cli::default(), None).unwrap();
    assert_eq!(c, Config::default());
    assert_eq!((c.loglevel, c.port, c.maxconn, c.timeout_s), (2, 502, 32, 60));
    assert_eq!((c.retries, c.pause_ms, c.wait_ms), (3, 100, 500));
    assert_eq!(
        c.lines[0].kind,
        LineKind::Serial { device: "/dev/ttyS0".into(), speed: 19200, mode: SerialMode::parse("8N1").unwrap() }
    );
    assert!((0..=255).all(|u| c.plain_reaches(u)));
    assert_eq!(c.route(17), Some((0, 17)));
}

#[test]
fn mbusds_example_and_ours_load() {
    let mbusd = "# Logging\nloglevel = 2\nlogfile = /var/log/mbusd.log\ndevice = /dev/ttyS0\nspeed = 9600\nmode = 8n1\n\
                 # enable_rs485 = no\ntrx_control = addc\n# trx_sysfile =\naddress = 0.0.0.0\nport = 502\nmaxconn = 32\n\
                 timeout = 60\nretries = 3\npause = 100\nwait = 500\nreplyonbroadcast = no\n";
    let c = ok(mbusd);
    assert_eq!((c.speed, c.mode.parity, c.logfile.as_str()), (9600, 'N', "/var/log/mbusd.log"));
    let example = include_str!("../example.conf");
    let c = ok(example);
    assert_eq!(c.device, PathBuf::from("/dev/ttyUSB0"));
    assert_eq!(c.config_path, Some(PathBuf::from("gw.conf")));
    // Its TLS part uncommented: plain_units keeps the plain front off the roles' units.
    let tls: String = example
        .lines()
        .map(|l| l.strip_prefix('#').filter(|l| !l.starts_with([' ', '#'])).unwrap_or(l))
        .map(|l| format!("{l}\n"))
        .collect();
    let c = ok(&tls);
    assert_eq!((c.roles.len(), c.port, c.plain_units.to_string()), (2, 502, "248-255".to_string()));
    assert!(c.tls.is_some());
    assert!(err(&tls.replace("plain_units = 248-255", "")).contains("reaches units that tls_role.* protects"));
}

#[test]
fn every_key_sets_its_field() {
    let c = ok("loglevel = 9\nlogfile = -\ndevice = /dev/ttyUSB1\nspeed = 115200\nmode = 8E2\nenable_rs485 = yes\n\
                trx_control = sysfs_0\ntrx_sysfile = /sys/class/gpio/gpio4/value\naddress = ::\nport = 0\nmaxconn = 10000\n\
                timeout = 0\nretries = 15\npause = 0\nwait = 10000\nreplyonbroadcast = on\nstatus_file = /run/g.prom\n\
                rtutcp_port = 5020\nudp_port = 5021\nudp_allow = 10.0.0.0/8 ::1\nuser = modbus\nplain_units = 1-10 20\n\
                allow_plain = no\ntls_address = 127.0.0.1\ntls_port = 8802\n");
    assert_eq!((c.loglevel, c.logfile.as_str(), c.speed), (9, "-", 115200));
    assert_eq!(
        c.lines[0].kind,
        LineKind::Serial { device: "/dev/ttyUSB1".into(), speed: 115200, mode: SerialMode::parse("8E2").unwrap() }
    );
    assert!(c.rs485 && c.replyonbroadcast && !c.allow_plain);
    assert_eq!(c.trx, Trx::SysfsDown("/sys/class/gpio/gpio4/value".into()));
    assert_eq!((c.address.as_str(), c.port, c.maxconn, c.timeout_s), ("::", 0, 10000, 0));
    assert_eq!((c.retries, c.pause_ms, c.wait_ms), (15, 0, 10000));
    assert_eq!(c.status_file, Some(PathBuf::from("/run/g.prom")));
    assert_eq!((c.rtutcp_port, c.udp_port, c.udp_allow.len()), (5020, 5021, 2));
    assert_eq!(c.user.as_deref(), Some("modbus"));
    assert_eq!(c.plain_units.to_string(), "1-10 20");
    assert_eq!(c.tls, None, "no tls_cert: no TLS front");
}

#[test]
fn errors_name_file_line_and_key() {
    assert_eq!(err("\n# c\nbogus = 1\n"), "rsmodbus-gateway: gw.conf:3: bogus: unknown key 'bogus'");
    assert_eq!(err("port = 70000"), "rsmodbus-gateway: gw.conf:1: port: must be 0 to 65535, not '70000'");
    assert_eq!(err("port 502"), "rsmodbus-gateway: gw.conf:1: 'port 502' is not 'key = value'");
    assert_eq!(err(" = 5"), "rsmodbus-gateway: gw.conf:1: no key before '='");
    assert_eq!(err("maxconn ="), "rsmodbus-gateway: gw.conf:1: maxconn: no value");
    // A control character in the file is escaped: the message stays one line.
    assert_eq!(err("bo\rgus = 1"), "rsmodbus-gateway: gw.conf:1: bo\\rgus: unknown key 'bo\\rgus'");
    let e = load(&Cli::default(), Some((Path::new("a\nb"), "x = 1"))).unwrap_err().to_string();
    assert_eq!(e, "rsmodbus-gateway: a\\nb:1: x: unknown key 'x'");
}

#[test]
fn numbers_are_strict() {
    assert_eq!(err("speed = 9600abc"), "rsmodbus-gateway: gw.conf:1: speed: must be 1 to 4000000, not '9600abc'");
    for bad in [
        "speed = 0",
        "speed = 4000001",
        "speed = +9600",
        "speed = 0x2580",
        "speed = 96 00",
        "speed = 99999999999999999999999",
    ] {
        assert!(err(bad).contains("speed: must be 1 to 4000000"), "{bad}");
    }
    assert_eq!(ok("speed = 009600").speed, 9600);
    assert!(err("loglevel = 10").contains("loglevel: must be 0 to 9"));
    assert!(err("enable_rs485 = banana").contains("enable_rs485: must be yes or no, not 'banana'"));
    assert!(ok("enable_rs485 = TRUE").rs485);
    assert!(!ok("replyonbroadcast = off").replyonbroadcast);
}

#[test]
fn finding_15_a_long_line_is_one_line() {
    // 600 bytes: the C gateway split it at 511 and parsed the tail as a directive.
    let device = format!("/dev/{}", "x".repeat(560));
    let text = format!("device = {device}port = 1\n");
    let c = ok(&text);
    assert_eq!(c.device, PathBuf::from(format!("{device}port = 1")));
    assert_eq!(c.port, 502);
    // Any length, up to the path limit, then an error (no truncation).
    let p = format!("/{}", "p".repeat(4094));
    assert_eq!(ok(&format!("status_file = {p}")).status_file, Some(PathBuf::from(&p)));
    assert_eq!(
        err(&format!("status_file = {p}q")),
        "rsmodbus-gateway: gw.conf:1: status_file: a path of 4096 bytes: at most 4095"
    );
    assert!(err(&format!("tls_cert = /{}", "c".repeat(5000))).contains("tls_cert: a path of 5001 bytes"));
}

#[test]
fn finding_15_hash_starts_a_comment_only_after_a_blank() {
    let c =
        ok("device = /dev/serial/by-id/usb-FTDI#1\nport = 1502 # the plain front\n  # indented comment\n#port = 9\n");
    assert_eq!(c.device, PathBuf::from("/dev/serial/by-id/usb-FTDI#1"));
    assert_eq!(c.port, 1502);
    assert_eq!(ok("logfile = /var/log/a#b\tc\t# tab then comment").logfile, "/var/log/a#b\tc");
    assert_eq!(ok("port = 1502\r\n").port, 1502, "CRLF");
}

#[test]
fn finding_15_names_are_checked_not_truncated() {
    let role = "R".repeat(100);
    assert_eq!(
        err(&format!("tls_role.{role} = r 1-10")),
        format!(
            "rsmodbus-gateway: gw.conf:1: tls_role.{role}: a role's name '{role}' must be 1 to 64 characters of A-Z a-z 0-9 _ . -"
        )
    );
    let r64 = "R".repeat(64);
    assert_eq!(ok(&format!("tls_role.{r64} = r 1-10")).roles[0].name, r64);
    assert!(err("tls_role. = r 1-10").contains("a role's name ''"));
    assert!(err("tls_role.a b = r 1-10").contains("a role's name 'a b'"));
    assert!(err(&format!("line.{} = tcp h 502", "L".repeat(65))).contains("a line's name"));
    assert!(err("line.a/b = tcp h 502").contains("a line's name 'a/b'"));
    assert_eq!(ok("line.A-z_0.9 = tcp h 502").lines[1].name, "A-z_0.9");
    assert!(err("line.default = tcp h 502").contains("'default' is the first line's name"));
}

#[test]
fn finding_15_duplicate_line_names_the_first() {
    assert_eq!(
        err("line.a = tcp h 502\n\nline.a = rtutcp h 503"),
        "rsmodbus-gateway: gw.conf:3: line.a: line 'a' is defined already at line 1"
    );
}

#[test]
fn finding_1_many_lines_then_a_limit() {
    let mut text: String = (0..LINES_MAX - 1).map(|i| format!("line.l{i} = serial /dev/ttyUSB{i} 9600\n")).collect();
    let c = ok(&text);
    assert_eq!(c.lines.len(), LINES_MAX);
    assert_eq!(c.lines[8].name, "l7");
    assert_eq!(
        c.lines[63].kind,
        LineKind::Serial { device: "/dev/ttyUSB62".into(), speed: 9600, mode: SerialMode::parse("8N1").unwrap() }
    );
    text.push_str("line.more = tcp h 502\n");
    assert_eq!(err(&text), "rsmodbus-gateway: gw.conf:64: line.more: more than 64 lines (the default one included)");
}

#[test]
fn lines_of_every_kind() {
    let c = ok("line.s = serial /dev/ttyS1 38400 7O2a\nline.t = tcp plc.example 502\nline.u = rtutcp 10.0.0.9 4001\n");
    assert_eq!(
        c.lines[1].kind,
        LineKind::Serial {
            device: "/dev/ttyS1".into(),
            speed: 38400,
            mode: SerialMode { data: 7, parity: 'O', stop: 2, ascii: true }
        }
    );
    assert_eq!(c.lines[2].kind, LineKind::Tcp { host: "plc.example".into(), port: "502".into() });
    assert_eq!(c.lines[3].kind, LineKind::RtuTcp { host: "10.0.0.9".into(), port: "4001".into() });
    assert!(err("line.s = serial /dev/ttyS1 9600abc").contains("line.s: speed must be 1 to 4000000, not '9600abc'"));
    assert!(err("line.s = serial /dev/ttyS1 9600 8X1").contains("serial mode '8X1'"));
    assert!(err("line.t = tcp h 0").contains("line.t: port must be 1 to 65535"));
    assert!(err("line.t = tcp h").contains("must be 'serial DEVICE SPEED [MODE]'"));
    assert!(err("line.t = tcp h 502 extra").contains("must be 'serial DEVICE SPEED [MODE]'"));
    assert!(err("line.t = modem h 502").contains("must be 'serial DEVICE SPEED [MODE]'"));
}

#[test]
fn backend_makes_the_default_line() {
    let c = ok("backend = tcp 192.0.2.1 502\ndevice = /dev/ttyS3");
    assert_eq!(c.lines[0].kind, LineKind::Tcp { host: "192.0.2.1".into(), port: "502".into() });
    assert_eq!(
        ok("backend = rtutcp gw 4001").lines[0].kind,
        LineKind::RtuTcp { host: "gw".into(), port: "4001".into() }
    );
    let c = ok("backend = tcp h 502\nbackend = serial\ndevice = /dev/ttyS3\nmode = 8E1");
    assert_eq!(
        c.lines[0].kind,
        LineKind::Serial { device: "/dev/ttyS3".into(), speed: 19200, mode: SerialMode::parse("8E1").unwrap() }
    );
    for bad in ["backend = tcp h", "backend = serial /dev/x 9600", "backend = ftp h 21"] {
        assert!(err(bad).contains("backend: must be 'serial', 'tcp HOST PORT' or 'rtutcp HOST PORT'"), "{bad}");
    }
}

#[test]
fn serial_modes() {
    assert_eq!(SerialMode::parse("8n1").unwrap().to_string(), "8N1");
    assert_eq!(SerialMode::parse("7E1A").unwrap().to_string(), "7E1a");
    assert_eq!(SerialMode::parse("5O2").unwrap(), SerialMode { data: 5, parity: 'O', stop: 2, ascii: false });
    for bad in ["", "8N", "4N1", "9N1", "8X1", "8N3", "8N1b", "8N1aa", "8N1 ascii", "８N1"] {
        assert!(SerialMode::parse(bad).is_err(), "{bad}");
    }
    assert!(ok("mode = 7E1a").mode.ascii);
    assert!(err("mode = 8N1x").contains("mode: serial mode '8N1x'"));
}

#[test]
fn trx_control() {
    assert_eq!(ok("trx_control = rts").trx, Trx::RtsUp);
    assert_eq!(ok("trx_control = rts_1").trx, Trx::RtsUp);
    assert_eq!(ok("trx_control = rts_0").trx, Trx::RtsDown);
    assert_eq!(ok("trx_sysfile = /s\ntrx_control = sysfs_1").trx, Trx::SysfsUp("/s".into()));
    assert_eq!(
        err("\ntrx_control = sysfs_1"),
        "rsmodbus-gateway: gw.conf:2: trx_control: sysfs_1 and sysfs_0 need trx_sysfile"
    );
    assert!(err("trx_control = rts2").contains("trx_control: must be addc"));
    // -y over the file's rts; -t over the file's sysfs.
    assert_eq!(load_with("-y /g", "trx_control = rts").unwrap().trx, Trx::SysfsUp("/g".into()));
    assert_eq!(load_with("-t", "trx_sysfile = /s\ntrx_control = sysfs_0").unwrap().trx, Trx::RtsUp);
}

// ---------------------------------------------------------------- routes

#[test]
fn finding_2_many_routes_then_a_limit() {
    let mut text: String = (0..=255).map(|u| format!("route = {u}-{u} default\n")).collect();
    let c = ok(&text);
    assert_eq!(c.routes.len(), ROUTES_MAX);
    assert_eq!(c.route(200), Some((0, 200)));
    text.push_str("route = 0-0 default\n");
    assert_eq!(err(&text), "rsmodbus-gateway: gw.conf:257: route: more than 256 routes");
}

#[test]
fn routes_may_come_before_their_line() {
    let c = ok("route = 1-10 b 100\nroute = 11-20 default\nline.b = tcp h 502\n");
    assert_eq!(c.route(1), Some((1, 101)));
    assert_eq!(c.route(10), Some((1, 110)));
    assert_eq!(c.route(15), Some((0, 15)));
    assert_eq!(c.route(21), None, "no route: 0x0A");
    assert_eq!(err("\nroute = 1-10 c"), "rsmodbus-gateway: gw.conf:2: route: no line 'c' (default, or a line.c entry)");
    assert!(err("route = 1-10").contains("route: must be 'FIRST-LAST LINE [OFFSET]'"));
    assert!(err("route = 10-1 default").contains("the first unit is above the last"));
    assert!(err("route = 1-256 default").contains("last unit must be 0 to 255"));
    assert!(err("route = 5 default").contains("'5' is not FIRST-LAST"));
}

#[test]
fn finding_3_offsets_cannot_overflow_or_leave_1_to_255() {
    assert_eq!(
        err("route = 1-10 default 2147483647"),
        "rsmodbus-gateway: gw.conf:1: route: the offset must be -255 to 255, not '2147483647'"
    );
    assert!(err("route = 1-10 default -9223372036854775809").contains("the offset must be -255 to 255"));
    assert!(err("route = 250-255 default 1").contains("reach units 251-256: a target must be 1 to 255"));
    assert_eq!(ok("route = 250-254 default 1").route(254), Some((0, 255)));
    assert_eq!(ok("route = 255-255 default -254").route(255), Some((0, 1)));
}

#[test]
fn finding_3_no_route_remaps_to_unit_0() {
    assert_eq!(
        err("route = 1-10 default -1"),
        "rsmodbus-gateway: gw.conf:1: route: units 1-10 with offset -1 reach units 0-9: a target must be 1 to 255"
    );
    assert!(err("route = 0-5 default 1").contains("unit 0 (a broadcast) must stay unit 0"));
    let c = ok("route = 0-5 default\nroute = 6-9 default 10");
    assert_eq!(c.route(0), Some((0, 0)), "a broadcast stays a broadcast");
    assert_eq!(c.route(6), Some((0, 16)));
    // Even a hand-made Config never sends a unicast to unit 0.
    let mut c = Config::default();
    c.routes.push(Route { first: 1, last: 1, line: 0, offset: -1 });
    assert_eq!(c.route(1), None);
}

#[test]
fn finding_15_overlapping_routes_name_both() {
    assert_eq!(
        err("route = 1-10 default\n\nroute = 5-20 default 100"),
        "rsmodbus-gateway: gw.conf:3: route: units 5-20 overlap units 1-10 of the route at line 1"
    );
    assert!(err("route = 10-20 default\nroute = 0-10 default").contains("units 0-10 overlap units 10-20"));
    ok("route = 1-10 default\nroute = 11-20 default");
}

// ---------------------------------------------------------------- TLS and the policy

#[test]
fn tls_front_and_roles() {
    let c = ok(&format!("{TLS}port = 0\ntls_role.Operator = rw 1-10\ntls_role.Reader = r 1-247\ntls_port = 8802"));
    let t = c.tls.clone().unwrap();
    assert_eq!((t.address.as_str(), t.port), ("0.0.0.0", 8802));
    assert_eq!((t.cert, t.key, t.ca), ("/c.pem".into(), "/k.pem".into(), "/ca.pem".into()));
    assert_eq!(c.roles.len(), 2);
    assert!(err("tls_role.X = w 1-10").contains("tls_role.X: must be 'r FIRST-LAST' or 'rw FIRST-LAST'"));
    assert!(err("tls_role.X = r 1-300").contains("last unit must be 0 to 255"));
    let roles: String = (0..ROLES_MAX).map(|i| format!("tls_role.R{i} = r 1-10\n")).collect();
    assert_eq!(ok(&roles).roles.len(), 64);
    assert!(
        err(&format!("{roles}tls_role.X = r 1-1")).contains("gw.conf:65: tls_role.X: more than 64 tls_role entries")
    );
}

#[test]
fn tls_needs_its_key_and_ca() {
    assert_eq!(
        err("port = 0\ntls_cert = /c.pem\ntls_ca = /ca.pem"),
        "rsmodbus-gateway: gw.conf:2: tls_cert: the Modbus/TCP Security front needs tls_key"
    );
    assert!(err("port = 0\ntls_cert = /c.pem\ntls_key = /k.pem").contains("needs tls_ca"));
    assert_eq!(ok("tls_key = /k.pem\ntls_ca = /ca.pem").tls, None);
    assert_eq!(ok(&format!("{TLS}tls_cert =")).tls, None, "an empty tls_cert: no front");
}

#[test]
fn authorization_on_the_addressed_unit() {
    let c = ok(&format!(
        "{TLS}port = 0\ntls_role.Op = rw 1-10\ntls_role.Ro = r 20-30\ntls_role.Ro = rw 40-40\nroute = 1-10 default 100"
    ));
    assert!(c.authorized(Some("Op"), 5, 0x06));
    assert!(c.authorized(Some("Op"), 5, 0x17));
    assert!(!c.authorized(Some("Op"), 105, 0x03), "the addressed unit, not the routed one");
    assert!(!c.authorized(Some("Op"), 11, 0x03));
    assert!(c.authorized(Some("Ro"), 20, 0x03));
    assert!(c.authorized(Some("Ro"), 30, 0x04));
    assert!(!c.authorized(Some("Ro"), 20, 0x06));
    assert!(c.authorized(Some("Ro"), 40, 0x10), "a second entry of the role");
    assert!(!c.authorized(None, 5, 0x03));
    assert!(!c.authorized(Some("op"), 5, 0x03), "role names are exact");
    assert!(!c.authorized(Some("O"), 5, 0x03));
}

#[test]
fn reads_are_function_codes_1_to_4() {
    let read: Vec<u8> = (0..=255u8).filter(|f| is_read(*f)).collect();
    assert_eq!(read, [1, 2, 3, 4]);
    // Read/write registers writes; the encapsulated interface (read device id
    // among others) and the diagnostics need rw too.
    for f in [0x05, 0x06, 0x07, 0x08, 0x0F, 0x10, 0x14, 0x16, 0x17, 0x18, 0x2B, 0x41, 0x83] {
        assert!(!is_read(f), "{f:#04x}");
    }
}

#[test]
fn finding_4_an_unsecured_front_reaching_a_roles_units_is_refused() {
    // The plain front on by default: the error is at the role's line.
    assert_eq!(
        err(&format!("{TLS}tls_role.Op = rw 1-247")),
        "rsmodbus-gateway: gw.conf:4: tls_role.Op: the Modbus/TCP front (port 502) reaches units that tls_role.* protects: \
         set port = 0, limit plain_units, or set allow_plain = yes"
    );
    assert_eq!(
        err(&format!("port = 1502\n{TLS}tls_role.Op = rw 1-247")),
        "rsmodbus-gateway: gw.conf:1: port: the Modbus/TCP front (port 1502) reaches units that tls_role.* protects: \
         set port = 0, limit plain_units, or set allow_plain = yes"
    );
    assert!(err(&format!("port = 0\nrtutcp_port = 5020\n{TLS}tls_role.Op = rw 1-10")).contains(
        "gw.conf:2: rtutcp_port: the RTU over TCP front (port 5020) reaches units that tls_role.* protects: set rtutcp_port = 0"
    ));
    assert!(
        err(&format!("port = 0\nudp_port = 5021\nudp_allow = ::1\n{TLS}tls_role.Op = rw 1-10"))
            .contains("gw.conf:2: udp_port: the Modbus/UDP front (port 5021) reaches units")
    );
    // The ways out: the plain front off, plain_units apart from the roles, or said so.
    ok(&format!("port = 0\n{TLS}tls_role.Op = rw 1-247"));
    let c = ok(&format!("{TLS}tls_role.Op = rw 1-100\nplain_units = 101-247\nplain_units = 0"));
    assert!(c.plain_reaches(0) && c.plain_reaches(101) && !c.plain_reaches(100) && !c.plain_reaches(248));
    assert!(
        err(&format!("{TLS}tls_role.Op = rw 1-100\nplain_units = 100-247"))
            .contains("reaches units that tls_role.* protects")
    );
    assert!(ok(&format!("{TLS}tls_role.Op = rw 1-247\nallow_plain = yes")).allow_plain);
    // Roles without the TLS front protect nothing to refuse for.
    ok("tls_role.Op = rw 1-247");
    // The command line's -P is named when it turns the front on.
    assert!(
        load_with("-P 502", &format!("port = 0\n{TLS}tls_role.Op = rw 1-247"))
            .unwrap_err()
            .to_string()
            .starts_with("rsmodbus-gateway: -P: the Modbus/TCP front (port 502) reaches units")
    );
    assert!(load_with("-P 0", &format!("{TLS}tls_role.Op = rw 1-247")).is_ok());
}

#[test]
fn finding_10_udp_needs_udp_allow() {
    assert_eq!(
        err("\nudp_port = 5021"),
        "rsmodbus-gateway: gw.conf:2: udp_port: the Modbus/UDP front needs udp_allow (the senders it answers: NET ..., e.g. 10.0.0.0/8)"
    );
    let c = ok(
        "udp_port = 5021\nudp_allow = 10.0.0.0/8 192.168.1.7\nudp_allow = ::1/128, 2001:db8::/32 ::ffff:172.16.0.0/108",
    );
    let yes = ["10.1.2.3", "192.168.1.7", "::1", "2001:db8::5", "::ffff:10.9.9.9", "172.16.0.1", "172.31.255.255"];
    let no = ["11.0.0.1", "192.168.1.8", "::2", "2001:db9::5", "::ffff:11.0.0.1", "172.32.0.0", "0.0.0.0"];
    for ip in yes {
        assert!(c.allowed_udp(ip.parse().unwrap()), "{ip}");
    }
    for ip in no {
        assert!(!c.allowed_udp(ip.parse().unwrap()), "{ip}");
    }
    assert!(ok("udp_allow = 0.0.0.0/0").allowed_udp("203.0.113.9".parse().unwrap()));
    assert!(!Config::default().allowed_udp("127.0.0.1".parse().unwrap()));
    assert!(err("udp_allow = 10.0.0.0/33").contains("udp_allow: '10.0.0.0/33': the prefix must be 0 to 32"));
    assert!(err("udp_allow = host.example").contains("udp_allow: 'host.example' is not an address"));
}

#[test]
fn unit_sets() {
    assert_eq!(UnitSet::parse("1-10 20,30-40").unwrap().to_string(), "1-10 20 30-40");
    assert_eq!(UnitSet::parse("all").unwrap(), UnitSet::all());
    assert_eq!(UnitSet::all().to_string(), "0-255");
    assert_eq!(UnitSet::none().to_string(), "none");
    assert_eq!(UnitSet::parse("255 0").unwrap().to_string(), "0 255");
    for bad in ["", "256", "1-", "-1", "a", "5-1", "1-10-20"] {
        assert!(UnitSet::parse(bad).is_err(), "{bad}");
    }
    assert!(err("plain_units =").contains("plain_units: no value"));
}

#[test]
fn user_and_optional_values() {
    assert_eq!(ok("user = _modbus-gw.1").user.as_deref(), Some("_modbus-gw.1"));
    assert!(err("user = -x").contains("user: user '-x'"));
    assert!(err("user = a b").contains("user: user 'a b'"));
    assert!(err(&format!("user = {}", "u".repeat(33))).contains("user: user"));
    let c = ok("user =\nstatus_file =\ntrx_sysfile =");
    assert_eq!((c.user, c.status_file), (None, None));
    assert!(err("logfile =").contains("logfile: no value"));
    assert!(err("address = a b").contains("address: address 'a b'"));
}

// ---------------------------------------------------------------- the command line over the file

#[test]
fn the_command_line_wins_over_the_file() {
    let c = load_with("-P 1502 -v 5 -p /dev/ttyUSB9 -s 9600 -m 7E1 -N 1 -R 5 -W 50 -T 9 -C 7 -A 127.0.0.1 -L - -S -b -d",
        "port = 502\nloglevel = 1\ndevice = /dev/ttyS0\nspeed = 38400\nmode = 8N1\nretries = 3\npause = 100\nwait = 500\n\
         timeout = 60\nmaxconn = 32\naddress = 0.0.0.0\nlogfile = /tmp/l\nenable_rs485 = no\nreplyonbroadcast = no\n")
    .unwrap();
    assert_eq!((c.port, c.loglevel, c.speed, c.retries, c.pause_ms, c.wait_ms), (1502, 5, 9600, 1, 5, 50));
    assert_eq!((c.timeout_s, c.maxconn, c.address.as_str(), c.logfile.as_str()), (9, 7, "127.0.0.1", "-"));
    assert!(c.rs485 && c.replyonbroadcast && c.foreground);
    assert_eq!(
        c.lines[0].kind,
        LineKind::Serial { device: "/dev/ttyUSB9".into(), speed: 9600, mode: SerialMode::parse("7E1").unwrap() }
    );
}

// ---------------------------------------------------------------- reload

const RUNNING: &str = "device = /dev/ttyS0\nretries = 5\nwait = 900\nroute = 1-10 default\nline.b = tcp h 502\n\
                       route = 11-20 b\nstatus_file = /run/a\n";

#[test]
fn reload_a_removed_key_returns_to_its_default() {
    let old = ok(RUNNING);
    let new = ok("device = /dev/ttyS0\nline.b = tcp h 502\n");
    assert!(old.restart_keys(&new).is_empty());
    let c = old.reloaded(new).unwrap();
    assert_eq!((c.retries, c.wait_ms, c.routes.len(), c.status_file.clone()), (3, 500, 0, None));
    assert_eq!(c.route(77), Some((0, 77)));
}

#[test]
fn reload_the_command_line_still_wins() {
    let old = load_with("-N 1 -v 6", RUNNING).unwrap();
    let new = load_with("-N 1 -v 6", "retries = 9\nloglevel = 1\nwait = 100\nline.b = tcp h 502\n").unwrap();
    let c = old.reloaded(new).unwrap();
    assert_eq!((c.retries, c.loglevel, c.wait_ms), (1, 6, 100));
}

#[test]
fn reload_keeps_and_names_what_takes_a_restart() {
    let old = load_with("-d", &format!("{RUNNING}port = 0\n{TLS}user = a\n")).unwrap();
    let new = ok("device = /dev/ttyUSB0\nspeed = 9600\nmode = 7E1\nport = 0\nmaxconn = 9\naddress = ::\nlogfile = -\n\
                  enable_rs485 = yes\ntrx_control = rts\nrtutcp_port = 5020\nline.b = tcp other 502\nline.c = tcp h 503\n\
                  tls_cert = /c2.pem\ntls_key = /k.pem\ntls_ca = /ca.pem\ntls_port = 803\nuser = b\nroute = 1-5 c\nretries = 0\n");
    assert_eq!(
        old.restart_keys(&new),
        [
            "logfile",
            "device",
            "speed",
            "mode",
            "enable_rs485",
            "trx_control",
            "address",
            "maxconn",
            "rtutcp_port",
            "line.*",
            "tls_port",
            "tls_cert",
            "user",
            "route"
        ]
    );
    let c = old.reloaded(new).unwrap();
    assert_eq!(c.retries, 0, "the rest is the new file's");
    let mut kept = c.clone();
    kept.retries = old.retries;
    kept.routes = old.routes.clone();
    kept.status_file = old.status_file.clone();
    kept.wait_ms = old.wait_ms;
    assert_eq!(kept, old, "every key that takes a restart keeps its running value");
    assert_eq!(c.routes, old.routes, "a route to a line not running: the running routes stay");
    assert!(c.foreground);
}

#[test]
fn reload_routes_follow_the_running_lines_by_name() {
    let old = ok("line.a = tcp h 1\nline.b = tcp h 2\nroute = 1-10 b");
    // The same lines given in another order: the routes name them.
    let new = ok("line.b = tcp h 2\nline.a = tcp h 1\nroute = 1-10 a\nroute = 11-12 b");
    assert_eq!(old.restart_keys(&new), ["line.*"]);
    let c = old.reloaded(new).unwrap();
    assert_eq!(c.lines, old.lines);
    assert_eq!((c.route(5), c.route(11)), (Some((1, 5)), Some((2, 11))));
}

#[test]
fn reload_backend_and_trx_sysfile() {
    let old = ok("trx_sysfile = /a\ntrx_control = sysfs_1");
    assert_eq!(old.restart_keys(&ok("trx_sysfile = /b\ntrx_control = sysfs_1")), ["trx_sysfile"]);
    assert_eq!(old.restart_keys(&ok("backend = tcp h 502\ntrx_sysfile = /a\ntrx_control = sysfs_1")), ["backend"]);
    assert_eq!(
        old.restart_keys(&ok("port = 503\nudp_port = 9\nudp_allow = ::1")),
        ["trx_control", "trx_sysfile", "port", "udp_port"]
    );
}

#[test]
fn reload_is_checked_as_it_will_run() {
    // Running with the plain front and plain_units apart from the role; the new file
    // turns the front off (which takes a restart) and lets plain_units reach all.
    let old = ok(&format!("{TLS}tls_role.Op = rw 1-10\nplain_units = 11-255"));
    let new = ok(&format!("{TLS}tls_role.Op = rw 1-10\nport = 0\n"));
    let e = old.reloaded(new).unwrap_err().to_string();
    assert_eq!(
        e,
        "rsmodbus-gateway: gw.conf: port: the Modbus/TCP front (port 502) reaches units that tls_role.* protects: \
         set port = 0, limit plain_units, or set allow_plain = yes (as running: port takes a restart)"
    );
}

#[test]
fn read_file_names_the_file() {
    let e = read_file(Path::new("/nonexistent/gw.conf")).unwrap_err().to_string();
    assert!(e.starts_with("rsmodbus-gateway: /nonexistent/gw.conf: cannot read it: "), "{e}");
    let dir = std::env::temp_dir().join(format!("gwconfig-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let f = dir.join("latin1.conf");
    std::fs::write(&f, b"port = 1\ndevice = /dev/tty\xe9\n").unwrap();
    let e = read_file(&f).unwrap_err();
    assert_eq!(e.place, Place::File { path: f.clone(), line: 2 });
    assert!(e.to_string().ends_with(":2: not UTF-8 text"));
    std::fs::write(&f, "port = 1\n").unwrap();
    assert_eq!(read_file(&f).unwrap(), "port = 1\n");
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_fuzz_seeds_load_or_fail_as_meant() {
    let seed = |name: &str| {
        std::fs::read_to_string(format!("{}/../fuzz/corpus/gateway_config/{name}", env!("CARGO_MANIFEST_DIR"))).unwrap()
    };
    for name in ["example.conf", "mbusd-keys.conf", "lines-and-routes.conf"] {
        ok(&seed(name));
    }
    let every = seed("every-key.conf");
    let args: Vec<String> = every.lines().next().unwrap()[2..].split_whitespace().map(String::from).collect();
    let c = load(&parse_args(&args).unwrap(), Some((Path::new("gw.conf"), &every))).unwrap();
    assert_eq!((c.loglevel, c.retries, c.port, c.roles.len()), (5, 1, 0, 3));
    assert!(err(&seed("tls-refused.conf")).contains("tls_role.Op: the Modbus/TCP front (port 502)"));
    assert!(err(&seed("errors.conf")).contains("gw.conf:2: line.a: line 'a' is defined already at line 1"));
}

/// The man page: its CONFIGURATION FILE section names every key, and its EXAMPLE
/// (TLS with roles) loads: it is safe.
#[test]
fn the_man_page_documents_every_key_and_its_example_loads() {
    let page = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/../man/src/rsmodbus-gateway.md")).unwrap();
    let section = &page[page.find("## CONFIGURATION FILE").unwrap()..page.find("## SIGNALS").unwrap()];
    let section = section.replace('`', "");
    for k in KEYS.iter().copied().chain(["tls_role.", "line.", "route"]) {
        // As the test suite looks for it: not inside a longer word.
        let found = section.match_indices(k).any(|(i, _)| {
            let before =
                section[..i].chars().next_back().is_none_or(|c| !(c.is_ascii_lowercase() || c == '_' || c == '.'));
            let after = section[i + k.len()..].chars().next().is_none_or(|c| !(c.is_ascii_lowercase() || c == '_'));
            before && after
        });
        assert!(found, "{k} is not in the man page's CONFIGURATION FILE");
    }
    let example = &page[page.find("## EXAMPLE").unwrap()..];
    let example = &example[example.find("```\n").unwrap() + 4..];
    let example = &example[..example.find("```").unwrap()];
    let c = ok(example);
    assert!(c.tls.is_some() && !c.roles.is_empty() && !c.allow_plain);
}
