//! The library's modules import one another without a cycle (ARCHITECTURE.md: the
//! layers point one way), `transport`'s submodules included: a module that names
//! `crate::X` (outside comments and its tests) depends on `X`.
//!
//! SPDX-License-Identifier: MIT OR Apache-2.0

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::Path;

/// Modules below every layer (the protocol crate, errors, the lock, stdio).
const BELOW: [&str; 6] = ["proto", "error", "lock", "stop", "stdio", "server_ext"];

fn walk(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            walk(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module a file is, to `depth` path segments (`transport::line` at 2).
fn module(rel: &str, depth: usize) -> String {
    let mut parts: Vec<&str> = rel.trim_end_matches(".rs").split('/').collect();
    if matches!(parts.last(), Some(&"mod") | Some(&"lib")) {
        parts.pop();
    }
    parts.truncate(depth);
    parts.join("::")
}

/// The code of a file without its tests and comments.
fn code(text: &str) -> String {
    let text = text.split("#[cfg(test)]").next().unwrap_or("");
    text.lines().filter(|l| !l.trim_start().starts_with("//")).collect::<Vec<_>>().join("\n")
}

fn graph(depth: usize) -> BTreeMap<String, BTreeSet<String>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    walk(&root, &mut files);
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    for f in files {
        let rel = f.strip_prefix(&root).unwrap().to_str().unwrap().to_owned();
        let from = module(&rel, depth);
        let text = code(&fs::read_to_string(&f).unwrap());
        let parent: Vec<&str> = from.split("::").collect();
        let mut refs = Vec::new();
        for (prefix, base) in [("crate::", Vec::new()), ("super::", parent[..parent.len().saturating_sub(1)].to_vec())]
        {
            for (i, _) in text.match_indices(prefix) {
                if i > 0 && text.as_bytes()[i - 1].is_ascii_alphanumeric() {
                    continue;
                }
                let rest = &text[i + prefix.len()..];
                let path: Vec<&str> = rest
                    .split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'))
                    .next()
                    .unwrap_or("")
                    .split("::")
                    .filter(|s| !s.is_empty() && s.chars().next().is_some_and(|c| c.is_ascii_lowercase()))
                    .collect();
                let mut full = base.clone();
                full.extend(path);
                if !full.is_empty() {
                    full.truncate(depth);
                    refs.push(full.join("::"));
                }
            }
        }
        for to in refs {
            let top = to.split("::").next().unwrap_or("");
            if to != from
                && !to.starts_with(&format!("{from}::"))
                && !from.starts_with(&format!("{to}::"))
                && !BELOW.contains(&top)
                && !from.is_empty()
            {
                g.entry(from.clone()).or_default().insert(to);
            }
        }
    }
    g
}

/// A cycle through `start`, if any (depth-first search).
fn cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        g: &BTreeMap<String, BTreeSet<String>>,
        v: &str,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == v) {
            let mut c = path[i..].to_vec();
            c.push(v.to_owned());
            return Some(c);
        }
        if done.contains(v) {
            return None;
        }
        path.push(v.to_owned());
        for w in g.get(v).into_iter().flatten() {
            if let Some(c) = visit(g, w, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(v.to_owned());
        None
    }
    let mut done = BTreeSet::new();
    for v in g.keys() {
        if let Some(c) = visit(g, v, &mut Vec::new(), &mut done) {
            return Some(c);
        }
    }
    None
}

#[test]
fn no_import_cycle_between_the_librarys_modules() {
    for depth in [1, 2] {
        let g = graph(depth);
        assert!(g.len() > 5, "too few modules found: {g:?}");
        if let Some(c) = cycle(&g) {
            panic!("import cycle at depth {depth}: {}", c.join(" -> "));
        }
    }
}

#[test]
fn the_check_finds_a_cycle() {
    let mut g: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    g.entry("engine".into()).or_default().insert("event".into());
    g.entry("event".into()).or_default().insert("engine".into());
    assert!(cycle(&g).is_some());
    g.remove("event");
    assert!(cycle(&g).is_none());
}
