// tokio-many: the tokio-modbus row of benches/many.sh. Polls N Modbus TCP devices
// (c-tests/event/sim-devices.c) the way benches/many-client.c does, with
// tokio-modbus 0.17 on one current-thread tokio runtime: one connection per device,
// then per cycle one read of 10 holding registers at address 0 on every device at
// once (the reads' futures joined with join_all, which polls only the ones woken:
// cheaper than a spawned task per read, which was tried), 2 s timeout each.
//
//   tokio-many PORT N CYCLES
//
// Output: "LIBINFO: tokio-modbus 0.17", then "RESULT mode=tokio n=... cycles=...
// median_ms=... max_ms=... rss_kb=... ok=... failed=... cpu_ms=..." like
// many-client: rss_kb is VmHWM (the peak resident set), cpu_ms the user and system
// CPU time of the process over the measured cycles only.
//
// SPDX-License-Identifier: MIT OR Apache-2.0

use std::net::{Ipv4Addr, SocketAddr};
use std::process::ExitCode;
use std::time::{Duration, Instant};

use futures_util::future::join_all;
use tokio::time::timeout;
use tokio_modbus::Slave;
use tokio_modbus::client::{Context, Reader, tcp};

const TIMEOUT: Duration = Duration::from_secs(2);

/// User plus system CPU time of the process so far, in milliseconds.
fn cpu_ms() -> f64 {
    // SAFETY: getrusage fills the zeroed struct it is given; RUSAGE_SELF is valid.
    let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut ru) } != 0 {
        return -1.0;
    }
    let ms = |tv: libc::timeval| tv.tv_sec as f64 * 1e3 + tv.tv_usec as f64 / 1e3;
    ms(ru.ru_utime) + ms(ru.ru_stime)
}

/// The peak resident set (VmHWM) in KiB, -1 if /proc does not say.
fn peak_rss_kb() -> i64 {
    std::fs::read_to_string("/proc/self/status")
        .ok()
        .and_then(|s| {
            s.lines()
                .find_map(|l| l.strip_prefix("VmHWM:"))
                .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        })
        .unwrap_or(-1)
}

fn main() -> ExitCode {
    let args: Vec<String> = std::env::args().collect();
    let parsed = (args.len() == 4)
        .then(|| Some((args[1].parse::<u16>().ok()?, args[2].parse::<usize>().ok()?, args[3].parse::<usize>().ok()?)))
        .flatten();
    let Some((port, n, cycles)) = parsed.filter(|&(_, n, c)| n > 0 && c > 0) else {
        eprintln!("usage: tokio-many PORT N CYCLES");
        return ExitCode::from(2);
    };
    println!("LIBINFO: tokio-modbus 0.17");
    let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("tokio-many: runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    rt.block_on(poll(port, n, cycles))
}

async fn poll(port: u16, n: usize, cycles: usize) -> ExitCode {
    let addr = SocketAddr::from((Ipv4Addr::LOCALHOST, port));
    let mut devices: Vec<Context> = Vec::with_capacity(n);
    for i in 0..n {
        match tcp::connect_slave(addr, Slave::tcp_device()).await {
            Ok(ctx) => devices.push(ctx),
            Err(e) => {
                eprintln!("device {i}: {e}");
                return ExitCode::FAILURE;
            }
        }
    }
    let (mut ok, mut failed) = (0usize, 0usize);
    let mut times = Vec::with_capacity(cycles);
    let cpu0 = cpu_ms();
    for _ in 0..cycles {
        let t0 = Instant::now();
        let reads = devices.iter_mut().map(|ctx| async move {
            let read = timeout(TIMEOUT, ctx.read_holding_registers(0, 10)).await;
            matches!(read, Ok(Ok(Ok(regs))) if regs.len() == 10)
        });
        for good in join_all(reads).await {
            if good {
                ok += 1;
            } else {
                failed += 1;
            }
        }
        times.push(t0.elapsed().as_secs_f64() * 1e3);
    }
    let cpu = cpu_ms() - cpu0;
    let max = times.iter().copied().fold(0.0, f64::max);
    times.sort_by(f64::total_cmp);
    println!(
        "RESULT mode=tokio n={n} cycles={cycles} median_ms={:.2} max_ms={max:.2} rss_kb={} ok={ok} failed={failed} cpu_ms={cpu:.0}",
        times[cycles / 2],
        peak_rss_kb()
    );
    if failed == 0 { ExitCode::SUCCESS } else { ExitCode::FAILURE }
}
