//! Target `gateway_config`: the gateway's configuration parser
//! (`rsmodbus_gateway::config`). The input is a configuration file's text (bytes
//! that are not UTF-8 become U+FFFD, as the parser only sees text). A first line
//! `#! ARGS` (a comment to the file) is also a command line, parsed and applied.
//!
//! Properties: no panic; every error is one line, `rsmodbus-gateway: fuzz.conf:...`
//! for the file and `rsmodbus-gateway: ...` for the command line; an accepted
//! configuration keeps the limits and rules load promises (lines, routes, roles
//! within their limits; route targets 1-255, unit 0 only to 0, routes apart, on
//! existing lines; names 1-64 characters; the TLS policy and udp_allow hold), and
//! reloading it onto itself changes nothing and names no key.

use std::path::Path;

use rsmodbus_gateway::config::{self, Cli, Config, LINES_MAX, ROLES_MAX, ROUTES_MAX, UnitSet};

const FILE: &str = "fuzz.conf";

pub fn gateway_config(data: &[u8]) {
    let text = String::from_utf8_lossy(data);
    let first = text.lines().next().and_then(|l| l.strip_prefix("#!")).unwrap_or("");
    let args: Vec<String> = first.split_whitespace().map(String::from).collect();
    let cli = match config::parse_args(&args) {
        Ok(cli) => cli,
        Err(e) => {
            assert!(e.starts_with("rsmodbus-gateway: ") && !e.contains('\n'), "{e:?}");
            Cli::default()
        }
    };
    // The file alone, then under the command line of its first line.
    for cli in [Cli::default(), cli] {
        match config::load(&cli, Some((Path::new(FILE), &text))) {
            Ok(c) => accepted(&c),
            Err(e) => {
                let e = e.to_string();
                assert!(!e.contains('\n'), "{e:?}");
                assert!(
                    e.starts_with(&format!("rsmodbus-gateway: {FILE}")) || e.starts_with("rsmodbus-gateway: -"),
                    "{e:?}"
                );
            }
        }
    }
}

fn valid_name(n: &str) -> bool {
    (1..=64).contains(&n.len()) && n.chars().all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '.' | '-'))
}

fn accepted(c: &Config) {
    assert!(!c.lines.is_empty() && c.lines.len() <= LINES_MAX);
    assert_eq!(c.lines[0].name, "default");
    for (i, l) in c.lines.iter().enumerate() {
        assert!(valid_name(&l.name), "{:?}", l.name);
        assert!(c.lines[..i].iter().all(|o| o.name != l.name), "duplicate line {:?}", l.name);
    }
    assert!(c.routes.len() <= ROUTES_MAX);
    assert!(c.roles.len() <= ROLES_MAX);
    for r in &c.roles {
        assert!(valid_name(&r.name) && r.first <= r.last);
    }
    for (i, r) in c.routes.iter().enumerate() {
        assert!(r.first <= r.last && r.line < c.lines.len());
        assert!(c.routes[..i].iter().all(|o| o.last < r.first || r.last < o.first), "overlapping routes");
    }
    for unit in 0..=255u8 {
        let by_route = c.routes.iter().find(|r| r.first <= unit && unit <= r.last);
        match (c.route(unit), by_route) {
            (Some((line, there)), _) => {
                assert!(line < c.lines.len());
                assert!(there != 0 || unit == 0, "unit {unit} remapped to 0");
                assert!(unit != 0 || there == 0, "a broadcast remapped to {there}");
            }
            (None, r) => assert!(!c.routes.is_empty() && r.is_none(), "unit {unit}: a route and no target"),
        }
    }
    if c.udp_port != 0 {
        assert!(!c.udp_allow.is_empty());
    }
    if c.tls.is_some() && !c.allow_plain && (c.port != 0 || c.rtutcp_port != 0 || c.udp_port != 0) {
        for r in &c.roles {
            let mut units = UnitSet::none();
            units.insert_range(r.first, r.last);
            assert!(!units.overlaps(&c.plain_units), "an unsecured front reaches role {:?}", r.name);
        }
    }
    for p in [c.status_file.as_deref(), c.tls.as_ref().map(|t| t.cert.as_path())].into_iter().flatten() {
        assert!(p.as_os_str().len() < 4096);
    }
    assert!(c.restart_keys(c).is_empty());
    assert_eq!(c.reloaded(c.clone()).as_ref(), Ok(c));
}
