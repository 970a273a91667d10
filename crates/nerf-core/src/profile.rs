//! Opt-in wall-clock profiling of named phases (`NERF_PROFILE=1`), for finding where a training
//! step or a render spends its time. Costs one relaxed atomic load per span when off.

use std::collections::BTreeMap;
use std::sync::Mutex;
use std::sync::atomic::{AtomicU8, Ordering};
use std::time::Instant;

static ENABLED: AtomicU8 = AtomicU8::new(2); // 2 = not read from the environment yet
static TOTALS: Mutex<BTreeMap<&'static str, (f64, u64)>> = Mutex::new(BTreeMap::new());

pub fn enabled() -> bool {
    match ENABLED.load(Ordering::Relaxed) {
        2 => {
            let on = std::env::var_os("NERF_PROFILE").is_some_and(|v| v != "0");
            ENABLED.store(u8::from(on), Ordering::Relaxed);
            on
        }
        v => v == 1,
    }
}

/// Times `f` under `name` when profiling is on.
pub fn span<T>(name: &'static str, f: impl FnOnce() -> T) -> T {
    if !enabled() {
        return f();
    }
    let t = Instant::now();
    let out = f();
    let dt = t.elapsed().as_secs_f64();
    let mut totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
    let e = totals.entry(name).or_insert((0.0, 0));
    e.0 += dt;
    e.1 += 1;
    out
}

/// The accumulated table, one line per phase (empty when profiling is off).
pub fn report() -> String {
    let totals = TOTALS.lock().unwrap_or_else(|e| e.into_inner());
    totals
        .iter()
        .map(|(name, (secs, n))| {
            format!(
                "{name:<24} {secs:9.3} s  {n:7} calls  {:9.3} ms/call\n",
                1e3 * secs / *n as f64
            )
        })
        .collect()
}

/// Prints the accumulated table to stderr when profiling is on (end of a train, eval or render).
pub fn eprint_report() {
    if enabled() {
        eprint!("{}", report());
    }
}

/// The accumulated table, then starts a new one: for phases of one run that cost differently
/// (NSFF's static warm-up and its space-time steps).
pub fn take_report() -> String {
    let out = report();
    TOTALS.lock().unwrap_or_else(|e| e.into_inner()).clear();
    out
}

/// Peak resident memory of this process so far, in bytes (`VmHWM` in `/proc/self/status`;
/// `None` where that file does not exist).
pub fn peak_memory_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}
