//! Build script for rsmodbus.
//!
//! It makes the cdylib a drop-in for `libmodbus.so.5`:
//!
//! 1. sets the ELF soname to `libmodbus.so.5`;
//! 2. creates `libmodbus.so.5` and `libmodbus.so.5.1.0` symlinks next to the built
//!    `libmodbus.so` in `target/<profile>/`, so that programs linked with `-lmodbus`
//!    against the build tree load this library and not the system's libmodbus;
//! 3. writes `target/<profile>/libmodbus.pc` (from `libmodbus.pc.in`) and
//!    `target/<profile>/libmodbus-uninstalled.pc` (for building against the tree);
//! 4. generates the five public headers with cbindgen into `$OUT_DIR/include/` and,
//!    when `RSMODBUS_UPDATE_HEADERS=1`, into the committed `include/`. A committed
//!    header that differs from the generated one only produces a cargo warning here;
//!    `c-tests/suites/headers.sh` turns it into a failure. The `header` column of
//!    `abi/exports.txt` says which header declares each function; the `#define`s of
//!    the error numbers are those of `proto/src/error.rs` (`@ERRNO NAME@` lines of
//!    the configurations in `cbindgen/`).
//!
//! Environment: `RSMODBUS_PREFIX` (default `/usr/local`), `RSMODBUS_LIBDIR` (default
//! `${exec_prefix}/lib`), `RSMODBUS_INCLUDEDIR` (default `${prefix}/include`) and
//! `RSMODBUS_UPDATE_HEADERS`.

use std::collections::HashMap;
use std::env;
use std::fs;
use std::io;
use std::path::{Path, PathBuf};

/// The libmodbus API level implemented (headers, pkg-config version).
const LIBMODBUS_VERSION: (u32, u32, u32) = (3, 1, 12);
/// libtool `current - age`: the soname major of libmodbus 3.1.x.
const SONAME: &str = "libmodbus.so.5";
/// libtool 6:0:1 gives this real file name for libmodbus 3.1.6 through 3.1.12.
const REAL_NAME: &str = "libmodbus.so.5.1.0";
/// `rustc --print native-static-libs` for the staticlib on x86_64-linux-gnu.
const LIBS_PRIVATE_LINUX_GNU: &str = "-lgcc_s -lutil -lrt -lpthread -lm -ldl -lc";

/// Where the exported functions and objects are declared.
const FFI_ROOT: &str = "src/ffi/mod.rs";

/// Parameters cbindgen cannot spell as the C API does. Mostly declarations whose
/// top-level `const` qualifier on a by-value parameter cannot be spelt in Rust. The qualifier does not change the function's type, but libmodbus'
/// headers show it, so the generated prototypes get it back: (function, parameter
/// as generated, parameter as libmodbus declares it).
const CONST_VALUE_PARAMS: &[(&str, &str, &str)] = &[
    ("modbus_write_register", "uint16_t value", "const uint16_t value"),
    ("modbus_set_bits_from_byte", "uint8_t value", "const uint8_t value"),
    // A nullable function pointer is `Option<fn>` in Rust; cbindgen unwraps it only
    // when the function type is spelt out, not through its alias.
    ("modbus_set_tls_authorization", "Option<modbus_tls_authorize_t> authorize", "modbus_tls_authorize_t authorize"),
];

#[derive(Clone, Copy, PartialEq, Eq)]
enum Part {
    Main,
    Rtu,
    Tcp,
    Tls,
    Version,
    /// rsmodbus' own additions, spliced into modbus.h at [`EXTENSIONS_MARKER`].
    Extensions,
}

/// Where the rsmodbus extensions go in modbus.h (a line of cbindgen/modbus.toml).
const EXTENSIONS_MARKER: &str = "@RSMODBUS_EXTENSIONS@";
const EXTENSIONS_CONFIG: &str = "cbindgen/modbus-extensions.toml";

struct Header {
    file: &'static str,
    config: &'static str,
    part: Part,
}

const HEADERS: &[Header] = &[
    Header { file: "modbus.h", config: "cbindgen/modbus.toml", part: Part::Main },
    Header { file: "modbus-rtu.h", config: "cbindgen/modbus-rtu.toml", part: Part::Rtu },
    Header { file: "modbus-tcp.h", config: "cbindgen/modbus-tcp.toml", part: Part::Tcp },
    Header { file: "modbus-tls.h", config: "cbindgen/modbus-tls.toml", part: Part::Tls },
    Header { file: "modbus-version.h", config: "cbindgen/modbus-version.toml", part: Part::Version },
];

/// The table of the exports, one `name | header | since | page` row each; build.rs
/// reads the header of each (the format is described at the top of the file).
const EXPORTS: &str = "abi/exports.txt";

/// The header of each export, from [`EXPORTS`].
fn export_parts(manifest_dir: &Path) -> Result<HashMap<String, Part>, String> {
    let text = fs::read_to_string(manifest_dir.join(EXPORTS)).map_err(|e| format!("{EXPORTS}: {e}"))?;
    let mut parts = HashMap::new();
    for (i, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let at = format!("{EXPORTS}:{}", i + 1);
        let fields: Vec<&str> = line.split('|').map(str::trim).collect();
        let [name, header, since, page] = fields[..] else {
            return Err(format!("{at}: expected `name | header | since | page`"));
        };
        if [name, since, page].contains(&"") {
            return Err(format!("{at}: empty field"));
        }
        let part = match header {
            "modbus.h" => Part::Main,
            "modbus.h extensions" => Part::Extensions,
            "modbus-rtu.h" => Part::Rtu,
            "modbus-tcp.h" => Part::Tcp,
            "modbus-tls.h" => Part::Tls,
            other => return Err(format!("{at}: unknown header `{other}`")),
        };
        if parts.insert(name.to_owned(), part).is_some() {
            return Err(format!("{at}: second row for {name}"));
        }
    }
    Ok(parts)
}

/// Where the error numbers are defined, as `pub const NAME: i32 = EXPR;` lines.
const ERROR_RS: &str = "proto/src/error.rs";

/// The `#define`s of the error numbers, by group: each run of top-level
/// `pub const NAME: i32 = EXPR;` lines of [`ERROR_RS`] (comments may come between
/// them; a blank or any other line ends the run), under the name of its first
/// constant. A line `@ERRNO NAME@` of a cbindgen configuration stands for the group
/// `NAME`, with each expression spelt in C.
fn errno_groups(manifest_dir: &Path) -> Result<HashMap<String, String>, String> {
    let text = fs::read_to_string(manifest_dir.join(ERROR_RS)).map_err(|e| format!("{ERROR_RS}: {e}"))?;
    let mut groups = HashMap::new();
    let mut current: Option<(String, String)> = None;
    for line in text.lines() {
        if let Some(rest) = line.strip_prefix("pub const ") {
            if let Some((name, expr)) = rest.strip_suffix(';').and_then(|d| d.split_once(": i32 = ")) {
                let define =
                    format!("#define {name} {}\n", c_expression(expr).map_err(|e| format!("{ERROR_RS}: {name}: {e}"))?);
                current.get_or_insert_with(|| (name.to_owned(), String::new())).1.push_str(&define);
                continue;
            }
        }
        if current.is_some() && !line.trim_start().starts_with("//") {
            let (first, defines) = current.take().unwrap_or_default();
            groups.insert(first, defines);
        }
    }
    if let Some((first, defines)) = current {
        groups.insert(first, defines);
    }
    Ok(groups)
}

/// A constant expression of [`ERROR_RS`] in C: integer literals, constant names and
/// `exception::NAME as i32` (the enum's `MODBUS_EXCEPTION_NAME`) joined by `+`.
fn c_expression(expr: &str) -> Result<String, String> {
    let terms = expr
        .split(" + ")
        .map(|term| {
            if let Some(code) = term.strip_prefix("exception::").and_then(|t| t.strip_suffix(" as i32")) {
                Ok(format!("MODBUS_EXCEPTION_{code}"))
            } else if term.starts_with(|c: char| c.is_ascii_digit())
                && term.bytes().all(|b| b.is_ascii_digit() || b == b'_')
            {
                Ok(term.replace('_', ""))
            } else if term.starts_with(|c: char| c.is_ascii_uppercase())
                && term.bytes().all(|b| b.is_ascii_uppercase() || b.is_ascii_digit() || b == b'_')
            {
                Ok(term.to_owned())
            } else {
                Err(format!("cannot spell `{term}` in C"))
            }
        })
        .collect::<Result<Vec<_>, _>>()?;
    Ok(if terms.len() == 1 { terms.concat() } else { format!("({})", terms.join(" + ")) })
}

/// Fails when a group of error numbers has no `@ERRNO NAME@` line in any
/// configuration: its numbers would be in no header.
fn errno_all_used(manifest_dir: &Path, groups: &HashMap<String, String>) -> Result<(), String> {
    let mut configs = String::new();
    for rel in HEADERS.iter().map(|h| h.config).chain([EXTENSIONS_CONFIG]) {
        configs += &fs::read_to_string(manifest_dir.join(rel)).map_err(|e| format!("{rel}: {e}"))?;
    }
    let mut unused: Vec<&str> =
        groups.keys().filter(|name| !configs.contains(&format!("\n@ERRNO {name}@"))).map(String::as_str).collect();
    unused.sort_unstable();
    if unused.is_empty() {
        Ok(())
    } else {
        Err(format!("{ERROR_RS}: no `@ERRNO NAME@` line in cbindgen/ for {}", unused.join(", ")))
    }
}

/// Replaces every `@ERRNO NAME@` line of `text` with the group `NAME`.
fn expand_errno(text: &str, groups: &HashMap<String, String>) -> Result<String, String> {
    let mut out = String::with_capacity(text.len());
    for line in text.split_inclusive('\n') {
        match line.trim_end().strip_prefix("@ERRNO ").and_then(|l| l.strip_suffix('@')) {
            Some(name) => {
                let defines = groups.get(name).ok_or_else(|| format!("@ERRNO {name}@: no such group in {ERROR_RS}"))?;
                // The last line of a configuration text has no newline of its own.
                out.push_str(if line.ends_with('\n') { defines } else { defines.trim_end_matches('\n') });
            }
            None => out.push_str(line),
        }
    }
    Ok(out)
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-changed=src/ffi");
    println!("cargo:rerun-if-changed=cbindgen");
    println!("cargo:rerun-if-changed=libmodbus.pc.in");
    println!("cargo:rerun-if-changed={EXPORTS}");
    println!("cargo:rerun-if-changed={ERROR_RS}");
    // So that the stale-header warning follows edits of the committed headers, and
    // RSMODBUS_UPDATE_HEADERS=1 repairs a hand-edited header even if it was set before.
    println!("cargo:rerun-if-changed=include");
    for var in ["RSMODBUS_PREFIX", "RSMODBUS_LIBDIR", "RSMODBUS_INCLUDEDIR", "RSMODBUS_UPDATE_HEADERS"] {
        println!("cargo:rerun-if-env-changed={var}");
    }

    let manifest_dir = PathBuf::from(env::var_os("CARGO_MANIFEST_DIR").expect("CARGO_MANIFEST_DIR"));
    let out_dir = PathBuf::from(env::var_os("OUT_DIR").expect("OUT_DIR"));
    let target_os = env::var("CARGO_CFG_TARGET_OS").unwrap_or_default();
    let target_env = env::var("CARGO_CFG_TARGET_ENV").unwrap_or_default();
    let elf = !matches!(target_os.as_str(), "macos" | "ios" | "tvos" | "watchos" | "windows");

    if elf {
        println!("cargo:rustc-cdylib-link-arg=-Wl,-soname,{SONAME}");
    }

    // OUT_DIR is target/[<triple>/]<profile>/build/<pkg>-<hash>/out.
    let profile_dir = out_dir.ancestors().nth(3).map(Path::to_path_buf);
    if let Some(profile_dir) = &profile_dir {
        if elf {
            for link in [SONAME, REAL_NAME] {
                if let Err(e) = ensure_symlink(&profile_dir.join(link), "libmodbus.so") {
                    println!("cargo:warning=cannot create {link} symlink: {e}");
                }
            }
        }
        let libs_private = if target_os == "linux" && target_env == "gnu" { LIBS_PRIVATE_LINUX_GNU } else { "" };
        if let Err(e) = write_pkg_config(&manifest_dir, profile_dir, libs_private) {
            println!("cargo:warning=cannot write libmodbus.pc: {e}");
        }
    } else {
        println!("cargo:warning=unexpected OUT_DIR layout, no symlinks or libmodbus.pc");
    }

    generate_headers(&manifest_dir, &out_dir);
}

/// Makes `link` a symlink to `target` (relative), replacing anything else there.
fn ensure_symlink(link: &Path, target: &str) -> io::Result<()> {
    if let Ok(meta) = fs::symlink_metadata(link) {
        if meta.file_type().is_symlink() && fs::read_link(link)? == Path::new(target) {
            return Ok(());
        }
        fs::remove_file(link)?;
    }
    make_symlink(target, link)
}

#[cfg(unix)]
fn make_symlink(target: &str, link: &Path) -> io::Result<()> {
    std::os::unix::fs::symlink(target, link)
}

#[cfg(not(unix))]
fn make_symlink(_target: &str, _link: &Path) -> io::Result<()> {
    Ok(())
}

fn env_or(var: &str, default: &str) -> String {
    env::var(var).ok().filter(|v| !v.is_empty()).unwrap_or_else(|| default.to_owned())
}

fn version_string() -> String {
    let (major, minor, micro) = LIBMODBUS_VERSION;
    format!("{major}.{minor}.{micro}")
}

/// Writes `libmodbus.pc` (installed layout) and `libmodbus-uninstalled.pc` (this
/// build tree: the library in `target/<profile>`, the committed `include/`).
fn write_pkg_config(manifest_dir: &Path, profile_dir: &Path, libs_private: &str) -> io::Result<()> {
    let template = fs::read_to_string(manifest_dir.join("libmodbus.pc.in"))?;
    let fill = |prefix: &str, libdir: &str, includedir: &str, cflags: &str| {
        template
            .replace("@PREFIX@", prefix)
            .replace("@LIBDIR@", libdir)
            .replace("@INCLUDEDIR@", includedir)
            .replace("@CFLAGS@", cflags)
            .replace("@VERSION@", &version_string())
            .replace("@LIBS_PRIVATE@", libs_private)
    };

    let installed = fill(
        &env_or("RSMODBUS_PREFIX", "/usr/local"),
        &env_or("RSMODBUS_LIBDIR", "${exec_prefix}/lib"),
        &env_or("RSMODBUS_INCLUDEDIR", "${prefix}/include"),
        "-I${includedir}/modbus",
    );
    write_if_changed(&profile_dir.join("libmodbus.pc"), installed.as_bytes())?;

    let tree = fill(
        &manifest_dir.display().to_string(),
        &profile_dir.display().to_string(),
        "${prefix}/include",
        "-I${includedir}",
    );
    write_if_changed(&profile_dir.join("libmodbus-uninstalled.pc"), tree.as_bytes())?;
    Ok(())
}

fn write_if_changed(path: &Path, contents: &[u8]) -> io::Result<bool> {
    if fs::read(path).is_ok_and(|old| old == contents) {
        return Ok(false);
    }
    if let Some(parent) = path.parent() {
        fs::create_dir_all(parent)?;
    }
    fs::write(path, contents)?;
    Ok(true)
}

/// What the headers are made of besides the sources and the cbindgen configurations.
struct Inputs<'a> {
    manifest_dir: &'a Path,
    ffi_root: &'a Path,
    /// The header of each exported symbol that has a row in [`EXPORTS`].
    parts: HashMap<String, Part>,
    /// Every exported symbol cbindgen finds.
    symbols: Vec<String>,
    /// The error numbers' `#define`s, by group ([`errno_groups`]).
    errno: HashMap<String, String>,
}

fn generate_headers(manifest_dir: &Path, out_dir: &Path) {
    let ffi_root = manifest_dir.join(FFI_ROOT);
    let gen_dir = out_dir.join("include");
    // Headers of an earlier run must not stand in for ones this run cannot make
    // (c-tests/suites/headers.sh compares the committed headers with these).
    let _ = fs::remove_dir_all(&gen_dir);
    if !ffi_root.exists() {
        println!("cargo:warning={FFI_ROOT} does not exist yet; headers not generated");
        return;
    }
    let update = env::var("RSMODBUS_UPDATE_HEADERS").is_ok_and(|v| v == "1");

    // First pass: every exported symbol, to decide which header declares it.
    let symbols: Vec<String> = match load_config(manifest_dir, "cbindgen/modbus.toml")
        .and_then(|config| run_cbindgen(config, Some(&ffi_root)))
    {
        Ok(bindings) => bindings.dynamic_symbols_names().map(str::to_owned).collect(),
        Err(e) => {
            println!("cargo:warning=cbindgen failed, headers not generated: {e}");
            return;
        }
    };
    let (parts, errno) = match (export_parts(manifest_dir), errno_groups(manifest_dir)) {
        (Ok(parts), Ok(errno)) => (parts, errno),
        (Err(e), _) | (_, Err(e)) => {
            println!("cargo:warning=headers not generated: {e}");
            return;
        }
    };
    if let Err(e) = errno_all_used(manifest_dir, &errno) {
        println!("cargo:warning=headers not generated: {e}");
        return;
    }
    for name in symbols.iter().filter(|name| !parts.contains_key(*name)) {
        println!("cargo:warning={name} has no row in {EXPORTS}: it is declared in no header");
    }
    let inputs = Inputs { manifest_dir, ffi_root: &ffi_root, parts, symbols, errno };

    let mut stale = Vec::new();
    for header in HEADERS {
        let text = match render_header(&inputs, header) {
            Ok(text) => text,
            Err(e) => {
                println!("cargo:warning=cannot generate {}: {e}", header.file);
                continue;
            }
        };
        if let Err(e) = write_if_changed(&gen_dir.join(header.file), text.as_bytes()) {
            println!("cargo:warning=cannot write {}: {e}", header.file);
        }
        let committed = manifest_dir.join("include").join(header.file);
        if update {
            if let Err(e) = write_if_changed(&committed, text.as_bytes()) {
                println!("cargo:warning=cannot update include/{}: {e}", header.file);
            }
        } else if fs::read(&committed).map_or(true, |old| old != text.as_bytes()) {
            stale.push(header.file);
        }
    }
    if !stale.is_empty() {
        println!(
            "cargo:warning=committed header(s) out of date: include/{}; run \
             `RSMODBUS_UPDATE_HEADERS=1 cargo build` (c-tests/suites/headers.sh fails until then)",
            stale.join(", include/")
        );
    }
}

fn load_config(manifest_dir: &Path, rel: &str) -> Result<cbindgen::Config, String> {
    cbindgen::Config::from_file(manifest_dir.join(rel)).map_err(|e| format!("{rel}: {e}"))
}

fn run_cbindgen(config: cbindgen::Config, src: Option<&Path>) -> Result<cbindgen::Bindings, String> {
    let mut builder = cbindgen::Builder::new().with_config(config);
    if let Some(src) = src {
        builder = builder.with_src(src);
    }
    builder.generate().map_err(|e| e.to_string())
}

fn render_header(inputs: &Inputs<'_>, header: &Header) -> Result<String, String> {
    let mut text = render(inputs, header.config, header.part)?;
    if header.part == Part::Main {
        let extensions = render(inputs, EXTENSIONS_CONFIG, Part::Extensions)?;
        let line = format!("{EXTENSIONS_MARKER}\n");
        if !text.contains(&line) {
            return Err(format!("{EXTENSIONS_MARKER} line missing from {}", header.config));
        }
        text = text.replacen(&line, extensions.trim_start_matches('\n'), 1);
    }
    for (function, generated, wanted) in CONST_VALUE_PARAMS {
        text = add_const(&text, function, generated, wanted);
    }
    Ok(text)
}

/// Runs cbindgen with the configuration `config_rel`, keeping only the symbols of
/// `part` (none for the version header, which is all configuration text).
fn render(inputs: &Inputs<'_>, config_rel: &str, part: Part) -> Result<String, String> {
    let mut config = load_config(inputs.manifest_dir, config_rel)?;
    let (major, minor, micro) = LIBMODBUS_VERSION;
    for text in [&mut config.header, &mut config.after_includes, &mut config.trailer].into_iter().flatten() {
        *text = expand_errno(text, &inputs.errno)
            .map_err(|e| format!("{config_rel}: {e}"))?
            .replace("@LIBMODBUS_VERSION_MAJOR@", &major.to_string())
            .replace("@LIBMODBUS_VERSION_MINOR@", &minor.to_string())
            .replace("@LIBMODBUS_VERSION_MICRO@", &micro.to_string());
    }

    let src = match part {
        Part::Version => None,
        part => {
            // Leave out every symbol that belongs to another header, or to none.
            let elsewhere = |name: &&String| inputs.parts.get(*name) != Some(&part);
            config.export.exclude.extend(inputs.symbols.iter().filter(elsewhere).cloned());
            Some(inputs.ffi_root)
        }
    };
    let bindings = run_cbindgen(config, src)?;
    let mut out = Vec::new();
    bindings.write(&mut out);
    String::from_utf8(out).map_err(|e| e.to_string())
}

/// Rewrites `generated` into `wanted` inside the prototype of `function`, if present.
fn add_const(text: &str, function: &str, generated: &str, wanted: &str) -> String {
    let Some(start) = text.find(&format!(" {function}(")) else {
        return text.to_owned();
    };
    let end = start + text[start..].find(");").unwrap_or(text.len() - start);
    let proto = &text[start..end];
    if proto.contains(wanted) {
        return text.to_owned();
    }
    format!("{}{}{}", &text[..start], proto.replacen(generated, wanted, 1), &text[end..])
}
