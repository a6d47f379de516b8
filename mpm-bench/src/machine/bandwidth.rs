//! `mpm-bench bandwidth`: the memory-bandwidth ceiling (STREAM triad) of this machine per
//! thread count and pinning policy, and its `bandwidth.json`.
//!
//! # The measurement
//!
//! The kernel is STREAM's triad, `a[i] = b[i] + s * c[i]`, over three `f64` arrays each much
//! larger than the last-level cache (by default 4 x the total last-level cache, at least
//! 64 MiB per array). For every thread count and pinning policy a fresh rayon pool is built
//! with [`mpm_host::pinning::build_pool`] (worker `j` pinned to the policy's `j`-th CPU from
//! [`Machine::place`], its placement read back), the arrays are allocated anew and first
//! touched by the workers that will use them (worker `j` owns the `j`-th
//! contiguous chunk, as in the solver, so pages land on the worker's NUMA node), one untimed
//! pass warms up, then `reps` passes are timed. The best pass gives the ceiling, as STREAM
//! reports it; the median and the worst are kept too. Bandwidth counts 3 arrays x 8 bytes
//! per element per pass (STREAM's convention: no write-allocate traffic), in GB/s
//! (10^9 bytes per second). Build the harness optimised (`--profile o3` or `--release`):
//! an unoptimised triad measures the compiler, not the memory.
//!
//! The analysis layer (`analysis::traffic`) estimates the bytes an MPM step moves, so a report can say
//! what fraction of this ceiling each stage reaches.

use super::fingerprint;
use super::placement::PinPolicy;
use super::topology::{human_bytes, Machine};
use crate::util::{median, now_rfc3339};
use anyhow::{bail, Context, Result};
use mpm_host::pinning;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::sync::Mutex;
use std::time::Instant;

/// Measure the memory-bandwidth ceiling (STREAM triad) per thread count and pinning policy.
///
/// Each thread count gets its own pinned rayon pool and freshly first-touched arrays; the
/// best of `--reps` timed passes is the ceiling. Store the JSON with the campaign it
/// belongs to (`--out results/<fingerprint>/<campaign>/bandwidth.json`) so `mpm-bench
/// report` can say what fraction of the ceiling each MPM stage reaches.
#[derive(Debug, Clone)]
pub struct BandwidthOptions {
    /// Thread counts to measure, comma-separated (more than the usable cores is allowed and
    /// flagged oversubscribed).
    pub threads: Vec<usize>,
    /// Pinning policy: close, spread, none, or an explicit CPU list such as 0,1 (repeat the
    /// flag to measure several policies).
    pub pin: Vec<String>,
    /// Size of EACH of the three arrays in MiB (0 = automatic: 4 x the total last-level
    /// cache, at least 64 MiB).
    pub size_mib: u64,
    /// Timed passes per configuration (the best one is the ceiling; STREAM uses 10).
    pub reps: usize,
    /// Write the result as JSON here (e.g. `results/FINGERPRINT/CAMPAIGN/bandwidth.json`).
    pub out: Option<PathBuf>,
}

/// The triad at one thread count and pinning policy.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BandwidthPoint {
    /// Worker threads.
    pub threads: usize,
    /// Pinning policy label (`close`, `spread`, `none` or a CPU list).
    pub pin: String,
    /// CPU requested for each worker (empty when not pinned).
    pub requested_cpus: Vec<usize>,
    /// CPU each worker was observed on (empty when not pinned).
    pub observed_cpus: Vec<usize>,
    /// More threads than usable cores.
    pub oversubscribed: bool,
    /// Every pinned worker was where it was asked to be (`None` when not pinned).
    pub verified: Option<bool>,
    /// Best pass (the ceiling), GB/s.
    pub best_gb_s: f64,
    /// Median pass, GB/s.
    pub median_gb_s: f64,
    /// Worst pass, GB/s.
    pub worst_gb_s: f64,
    /// Time of the best pass, s.
    pub best_s: f64,
}

/// `bandwidth.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct BandwidthReport {
    /// Always `stream-triad`.
    pub kernel: String,
    /// Machine fingerprint (see `manifest`).
    pub machine_id: String,
    /// CPU model.
    pub cpu_model: String,
    /// Packages (sockets).
    pub packages: usize,
    /// Physical cores.
    pub cores: usize,
    /// Total last-level cache, bytes.
    pub llc_bytes: u64,
    /// Bytes of each array.
    pub array_bytes: u64,
    /// Elements per array.
    pub elements: u64,
    /// Timed passes per configuration.
    pub reps: usize,
    /// Bytes counted per element and pass (24: read b, read c, write a).
    pub bytes_per_element: u64,
    /// The harness was built with debug assertions (numbers not meaningful).
    pub debug_build: bool,
    /// When measured (RFC 3339 UTC).
    pub timestamp: String,
    /// One entry per (thread count, policy).
    pub results: Vec<BandwidthPoint>,
}

impl BandwidthReport {
    /// The measurement at `threads` under `pin` (falls back to any policy at that count).
    pub fn ceiling(&self, threads: usize, pin: &str) -> Option<&BandwidthPoint> {
        self.results
            .iter()
            .find(|p| p.threads == threads && p.pin == pin)
            .or_else(|| self.results.iter().find(|p| p.threads == threads))
    }
}

/// Read a `bandwidth.json`.
pub fn read(path: &Path) -> Result<BandwidthReport> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text)
        .with_context(|| format!("{} is not a bandwidth.json written by `mpm-bench bandwidth`", path.display()))
}

/// Total last-level cache of a machine (bytes): the largest `size x count` of any level.
pub fn llc_bytes(m: &Machine) -> u64 {
    m.caches.iter().map(|c| c.size_bytes * c.count as u64).max().unwrap_or(32 << 20)
}

/// Split `s` into `t` contiguous chunks of near-equal length (the solver's partition).
fn split_mut(mut s: &mut [f64], t: usize) -> Vec<&mut [f64]> {
    let n = s.len();
    let mut out = Vec::with_capacity(t);
    for j in 0..t {
        let len = (j + 1) * n / t - j * n / t;
        let (head, tail) = std::mem::take(&mut s).split_at_mut(len);
        out.push(head);
        s = tail;
    }
    out
}

/// Worker `j`'s share of the three arrays `(a, b, c)`.
type Chunk<'a> = (&'a mut [f64], &'a mut [f64], &'a mut [f64]);

/// The triad's scalar.
const SCALAR: f64 = 3.0;

/// One (threads, policy) measurement with `elements` per array.
fn measure(
    machine: &Machine,
    policy: &PinPolicy,
    threads: usize,
    elements: usize,
    reps: usize,
) -> Result<BandwidthPoint> {
    let placement = machine.place(policy, threads)?;
    let cpus = (!placement.cpus.is_empty()).then_some(placement.cpus.as_slice());
    let pool = pinning::build_pool(threads, cpus)?;
    // vec![0.0; n] maps untouched zero pages: the first write below is the first touch.
    let (mut a, mut b, mut c) = (vec![0.0f64; elements], vec![0.0f64; elements], vec![0.0f64; elements]);
    let chunks: Vec<Mutex<Chunk<'_>>> = split_mut(&mut a, threads)
        .into_iter()
        .zip(split_mut(&mut b, threads))
        .zip(split_mut(&mut c, threads))
        .map(|((a, b), c)| Mutex::new((a, b, c)))
        .collect();
    pool.pool.broadcast(|ctx| {
        let mut g = chunks[ctx.index()].lock().unwrap_or_else(|e| e.into_inner());
        let (a, b, c) = &mut *g;
        a.fill(1.0);
        b.fill(2.0);
        c.fill(0.5);
    });
    let triad = || {
        pool.pool.broadcast(|ctx| {
            let mut g = chunks[ctx.index()].lock().unwrap_or_else(|e| e.into_inner());
            let (a, b, c) = &mut *g;
            for ((x, y), z) in a.iter_mut().zip(b.iter()).zip(c.iter()) {
                *x = y + SCALAR * z;
            }
        });
    };
    triad(); // warm-up
    let mut secs = Vec::with_capacity(reps);
    for _ in 0..reps.max(1) {
        let t0 = Instant::now();
        triad();
        secs.push(t0.elapsed().as_secs_f64().max(1e-9));
    }
    drop(chunks);
    let want = 2.0 + SCALAR * 0.5;
    if [0, elements / 2, elements - 1].iter().any(|&i| a[i] != want) {
        bail!("the triad produced wrong values (a[i] != {want}): the measurement is void");
    }
    secs.sort_by(f64::total_cmp);
    let bytes = 24.0 * elements as f64;
    let gb = |s: f64| bytes / s / 1e9;
    Ok(BandwidthPoint {
        threads,
        pin: policy.label(),
        requested_cpus: pool.requested.clone(),
        observed_cpus: pool.observed_cpus(),
        oversubscribed: placement.oversubscribed,
        verified: pool.verified(),
        best_gb_s: gb(secs[0]),
        median_gb_s: gb(median(&secs)),
        worst_gb_s: gb(secs[secs.len() - 1]),
        best_s: secs[0],
    })
}

/// Run the measurement on this machine (without printing or writing).
pub fn measure_all(args: &BandwidthOptions) -> Result<BandwidthReport> {
    if args.threads.is_empty() || args.threads.contains(&0) {
        bail!("--threads needs positive thread counts, e.g. --threads 1,2,4");
    }
    let policies: Vec<PinPolicy> = args.pin.iter().map(|p| p.parse()).collect::<Result<_>>()?;
    let machine = Machine::detect()?;
    for p in &policies {
        machine.check_policy(p)?;
    }
    let llc = llc_bytes(&machine);
    let array_bytes = if args.size_mib > 0 { args.size_mib << 20 } else { (4 * llc).max(64 << 20) };
    let elements = (array_bytes / 8) as usize;
    if elements < 1024 {
        bail!("--size-mib {} is too small for a bandwidth measurement", args.size_mib);
    }
    let need = 3 * array_bytes;
    if machine.total_memory_bytes > 0 && need > machine.total_memory_bytes / 2 {
        bail!(
            "3 arrays of {} need {}, more than half of this machine's memory ({}): choose a smaller --size-mib",
            human_bytes(array_bytes),
            human_bytes(need),
            human_bytes(machine.total_memory_bytes)
        );
    }
    let mut results = Vec::new();
    for policy in &policies {
        for &t in &args.threads {
            results.push(
                measure(&machine, policy, t, elements, args.reps)
                    .with_context(|| format!("triad with {t} thread(s), pinning {policy}"))?,
            );
        }
    }
    Ok(BandwidthReport {
        kernel: "stream-triad".into(),
        machine_id: fingerprint::fingerprint(&machine),
        cpu_model: machine.cpu_model.clone(),
        packages: machine.num_packages(),
        cores: machine.num_cores(),
        llc_bytes: llc,
        array_bytes: elements as u64 * 8,
        elements: elements as u64,
        reps: args.reps.max(1),
        bytes_per_element: 24,
        debug_build: cfg!(debug_assertions),
        timestamp: now_rfc3339(),
        results,
    })
}

/// A plain-text table of a report.
pub fn table(r: &BandwidthReport) -> String {
    let mut s = format!(
        "STREAM triad a = b + {SCALAR}*c, 3 arrays x {} ({} elements), best of {} passes; {} ({} socket(s), {} cores, LLC {})\n",
        human_bytes(r.array_bytes),
        r.elements,
        r.reps,
        r.cpu_model,
        r.packages,
        r.cores,
        human_bytes(r.llc_bytes)
    );
    s.push_str(&format!(
        "{:>7}  {:<8} {:>10} {:>10} {:>10}  {:<16} {}\n",
        "threads", "pin", "best GB/s", "median", "worst", "CPUs", "note"
    ));
    for p in &r.results {
        let cpus = if p.observed_cpus.is_empty() {
            "-".to_string()
        } else {
            p.observed_cpus.iter().map(usize::to_string).collect::<Vec<_>>().join(" ")
        };
        let mut note = Vec::new();
        if p.oversubscribed {
            note.push("oversubscribed");
        }
        if p.verified == Some(false) {
            note.push("PINNING NOT VERIFIED");
        }
        s.push_str(&format!(
            "{:>7}  {:<8} {:>10.2} {:>10.2} {:>10.2}  {:<16} {}\n",
            p.threads,
            p.pin,
            p.best_gb_s,
            p.median_gb_s,
            p.worst_gb_s,
            cpus,
            note.join(", ")
        ));
    }
    if r.debug_build {
        s.push_str("warning: this harness was built with debug assertions; build with --profile o3 for real numbers\n");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn split_covers_everything() {
        let mut v = vec![0.0; 10];
        let parts = split_mut(&mut v, 3);
        assert_eq!(parts.iter().map(|p| p.len()).collect::<Vec<_>>(), vec![3, 3, 4]);
    }

    #[test]
    fn small_triad_is_correct() {
        let machine = Machine::synthetic("pack:1 core:1 pu:1").unwrap();
        let p = measure(&machine, &PinPolicy::None, 2, 4096, 2).unwrap();
        assert!(p.best_gb_s > 0.0 && p.best_gb_s >= p.worst_gb_s);
    }
}
