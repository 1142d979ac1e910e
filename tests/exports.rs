//! The table of the exports, `abi/exports.txt`, against the sources: every
//! `#[unsafe(no_mangle)]` function or static of `src/ffi/` has exactly one row, and
//! every row names one of them, with a header and a version the table's format
//! allows. (Reads files only; `c-tests/suites/symbols.sh` compares the table with the
//! symbols of the built library.)

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

const ROOT: &str = env!("CARGO_MANIFEST_DIR");
const HEADERS: [&str; 5] = ["modbus.h", "modbus.h extensions", "modbus-rtu.h", "modbus-tcp.h", "modbus-tls.h"];

/// One row: header, since, page.
type Row = (String, String, String);

/// The rows of the table by name, and the problems of its lines.
fn table() -> (BTreeMap<String, Row>, Vec<String>) {
    let text = fs::read_to_string(Path::new(ROOT).join("abi/exports.txt")).expect("abi/exports.txt");
    let mut rows = BTreeMap::new();
    let mut problems = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let fields: Vec<&str> = line.split('|').map(str::trim).collect();
        let [name, header, since, page] = fields[..] else {
            problems.push(format!("line {}: not `name | header | since | page`: {line}", i + 1));
            continue;
        };
        if !HEADERS.contains(&header) {
            problems.push(format!("{name}: unknown header `{header}`"));
        }
        let version = since.split('.').all(|n| !n.is_empty() && n.bytes().all(|b| b.is_ascii_digit()));
        if !(since == "rsmodbus" || (version && since.split('.').count() == 3)) {
            problems.push(format!("{name}: since `{since}` is neither a libmodbus version X.Y.Z nor rsmodbus"));
        }
        if page.is_empty() {
            problems.push(format!("{name}: no page"));
        }
        if rows.insert(name.to_owned(), (header.to_owned(), since.to_owned(), page.to_owned())).is_some() {
            problems.push(format!("{name}: more than one row"));
        }
    }
    (rows, problems)
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in fs::read_dir(dir).expect("read_dir") {
        let path = entry.expect("dir entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The names of the `#[unsafe(no_mangle)]` items of `source`: the first `fn` or
/// `static` after the attribute (other attributes and comments may come between).
fn no_mangle_items(source: &str) -> Vec<String> {
    let mut names = Vec::new();
    let mut lines = source.lines().map(str::trim);
    while let Some(line) = lines.next() {
        if line != "#[unsafe(no_mangle)]" {
            continue;
        }
        let item = lines.by_ref().find(|l| !l.starts_with("#[") && !l.starts_with("//")).unwrap_or_default();
        let words: Vec<&str> = item.split(|c: char| c.is_whitespace() || "(:<".contains(c)).collect();
        let name = words.iter().position(|w| *w == "fn" || *w == "static").and_then(|i| words.get(i + 1));
        names.push(name.map_or_else(|| format!("(unparsed item: {item})"), |n| (*n).to_owned()));
    }
    names
}

fn exported_items() -> BTreeMap<String, Vec<String>> {
    let mut files = Vec::new();
    rust_files(&Path::new(ROOT).join("src/ffi"), &mut files);
    let mut items: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for file in files {
        let source = fs::read_to_string(&file).expect("source file");
        let rel = file.strip_prefix(ROOT).unwrap_or(&file).display().to_string();
        for name in no_mangle_items(&source) {
            items.entry(name).or_default().push(rel.clone());
        }
    }
    items
}

#[test]
fn every_export_has_one_row_and_every_row_an_export() {
    let (rows, mut problems) = table();
    let items = exported_items();
    assert!(items.len() > 100, "found only {} exported items in src/ffi", items.len());
    for (name, files) in &items {
        if !rows.contains_key(name) {
            problems.push(format!("{name} ({}) has no row in abi/exports.txt", files.join(", ")));
        }
        if files.len() > 1 {
            problems.push(format!("{name} is exported more than once: {}", files.join(", ")));
        }
    }
    let exported: BTreeSet<&String> = items.keys().collect();
    for name in rows.keys().filter(|n| !exported.contains(n)) {
        problems.push(format!("abi/exports.txt has a row for {name}, which src/ffi does not export"));
    }
    assert!(problems.is_empty(), "abi/exports.txt and src/ffi disagree:\n  {}", problems.join("\n  "));
}

#[test]
fn the_item_finder_reads_functions_and_statics() {
    let source = "#[unsafe(no_mangle)]\npub static libmodbus_version_major: c_uint = 3;\n\
                  /// doc\n#[allow(clippy::too_many_arguments)]\n#[unsafe(no_mangle)]\n\
                  // a comment\npub unsafe extern \"C\" fn modbus_x(ctx: *mut Modbus) -> c_int {\n\
                  #[unsafe(no_mangle)]\npub extern \"C\" fn rsmodbus_version() -> *const c_char {\n";
    assert_eq!(no_mangle_items(source), ["libmodbus_version_major", "modbus_x", "rsmodbus_version"]);
}
