//! Replays fuzz inputs through the targets without libFuzzer, and drives them with
//! random mutations of the corpus (a libFuzzer-free fallback).
//!
//! ```text
//! replay DIR_OR_FILE...            # target = name of the input's parent directory
//! replay --random TARGET SECONDS CORPUS_DIR
//! ```
//!
//! Each input runs in a forked child with a 10 s alarm, so a panic, an abort or a hang
//! is counted (and named) instead of stopping the run. Ends with `N passed, M failed`.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

fn usage() -> ! {
    eprintln!("usage: replay PATH... | replay --random TARGET SECONDS CORPUS_DIR");
    std::process::exit(2);
}

/// Runs `f(input)` in a child process. Returns None on success, or a description.
fn run_isolated(f: fn(&[u8]), input: &[u8]) -> Option<String> {
    // SAFETY: fork in a single-threaded program; the child only runs the target and
    // exits.
    let pid = unsafe { libc::fork() };
    if pid < 0 {
        return Some("fork failed".into());
    }
    if pid == 0 {
        // SAFETY: plain libc calls in the child.
        unsafe { libc::alarm(10) };
        f(input);
        // SAFETY: leave the child without running the parent's destructors.
        unsafe { libc::_exit(0) };
    }
    let mut status = 0;
    // SAFETY: waiting for our own child.
    unsafe { libc::waitpid(pid, &mut status, 0) };
    if libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0 {
        None
    } else if libc::WIFSIGNALED(status) {
        let sig = libc::WTERMSIG(status);
        Some(if sig == libc::SIGALRM { "hang (10 s)".into() } else { format!("killed by signal {sig}") })
    } else {
        Some(format!("exit status {}", libc::WEXITSTATUS(status)))
    }
}

fn inputs(path: &Path, out: &mut Vec<PathBuf>) {
    if path.is_dir() {
        let mut entries: Vec<_> = std::fs::read_dir(path).unwrap().flatten().map(|e| e.path()).collect();
        entries.sort();
        for e in entries {
            inputs(&e, out);
        }
    } else if path.is_file()
        && !path.file_name().is_some_and(|n| n.to_string_lossy().starts_with('.') || n == "README.md")
    {
        out.push(path.to_path_buf());
    }
}

/// The target an input belongs to: the nearest ancestor directory named like one.
fn target_of(path: &Path) -> Option<(&'static str, rsmodbus_fuzz::Target)> {
    for dir in path.ancestors().skip(1) {
        let name = dir.file_name()?.to_string_lossy();
        if let Some((n, f)) = rsmodbus_fuzz::TARGETS.iter().find(|(n, _)| *n == name) {
            return Some((n, *f));
        }
    }
    None
}

fn replay(paths: &[String]) -> i32 {
    let mut files = Vec::new();
    for p in paths {
        inputs(Path::new(p), &mut files);
    }
    let (mut passed, mut failed) = (0, 0);
    for file in &files {
        let Some((name, f)) = target_of(file) else {
            eprintln!("skip {} (not under a target directory)", file.display());
            continue;
        };
        let data = std::fs::read(file).unwrap();
        match run_isolated(f, &data) {
            None => passed += 1,
            Some(why) => {
                failed += 1;
                println!("FAIL {name} {}: {why}", file.display());
            }
        }
    }
    println!("replay: {passed} passed, {failed} failed");
    (failed > 0) as i32
}

/// xorshift64*.
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn random(target: &str, seconds: u64, corpus: &str) -> i32 {
    let Some(f) = rsmodbus_fuzz::target(target) else { usage() };
    let mut files = Vec::new();
    inputs(Path::new(corpus), &mut files);
    let mut seeds: Vec<Vec<u8>> = files.iter().map(|p| std::fs::read(p).unwrap()).collect();
    if seeds.is_empty() {
        seeds.push(vec![0; 16]);
    }
    let seed = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).unwrap().as_nanos() as u64 | 1;
    let mut rng = Rng(seed);
    let end = Instant::now() + Duration::from_secs(seconds);
    let (mut runs, mut failed) = (0u64, 0u64);
    let crash_dir = format!("fuzz/artifacts/{target}");
    // Batches of inputs run in one child each, so a crash costs one fork.
    while Instant::now() < end {
        let mut batch = Vec::with_capacity(256);
        for _ in 0..256 {
            let mut x = seeds[rng.below(seeds.len())].clone();
            for _ in 0..1 + rng.below(6) {
                let len = x.len();
                match rng.below(6) {
                    0 if len > 0 => x[rng.below(len)] = rng.next() as u8,
                    1 if len > 0 => x[rng.below(len)] ^= 1 << rng.below(8),
                    2 if len < 600 => x.insert(rng.below(len + 1), rng.next() as u8),
                    3 if len > 0 => {
                        x.remove(rng.below(len));
                    }
                    4 => x.truncate(rng.below(len + 1)),
                    5 if len > 1 => {
                        let other = &seeds[rng.below(seeds.len())];
                        let at = rng.below(len);
                        x.truncate(at);
                        x.extend_from_slice(&other[rng.below(other.len() + 1).min(other.len())..]);
                    }
                    _ => {}
                }
            }
            batch.push(x);
        }
        runs += batch.len() as u64;
        // Run the batch in a child; on failure, find the failing input one by one.
        let joined = batch.clone();
        if run_batch(f, joined).is_some() {
            for x in &batch {
                if let Some(why) = run_isolated(f, x) {
                    failed += 1;
                    std::fs::create_dir_all(&crash_dir).unwrap();
                    let path = format!("{crash_dir}/crash-{:016x}", rng.next());
                    std::fs::write(&path, x).unwrap();
                    println!("FAIL {target}: {why}; input saved to {path}");
                    break;
                }
            }
        }
    }
    println!("random {target}: {runs} inputs in {seconds} s");
    println!("random: {} passed, {failed} failed", (failed == 0) as u32);
    (failed > 0) as i32
}

fn run_batch(f: fn(&[u8]), batch: Vec<Vec<u8>>) -> Option<String> {
    // SAFETY: as in run_isolated.
    let pid = unsafe { libc::fork() };
    if pid == 0 {
        // SAFETY: plain libc calls in the child.
        unsafe { libc::alarm(30) };
        for x in &batch {
            f(x);
        }
        // SAFETY: leave the child at once.
        unsafe { libc::_exit(0) };
    }
    let mut status = 0;
    // SAFETY: waiting for our own child.
    unsafe { libc::waitpid(pid, &mut status, 0) };
    (!(libc::WIFEXITED(status) && libc::WEXITSTATUS(status) == 0)).then(|| "failed".to_string())
}

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let code = match args.first().map(String::as_str) {
        None => usage(),
        Some("--random") if args.len() == 4 => random(&args[1], args[2].parse().unwrap_or_else(|_| usage()), &args[3]),
        Some("--random") => usage(),
        Some(_) => replay(&args),
    };
    std::process::exit(code);
}
