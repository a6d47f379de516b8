//! The host's load around each run and the `host_noisy` rule: what else used the machine
//! (1-minute load average, other runnable tasks, busy fraction of the run's CPUs, hypervisor
//! steal, all from `/proc`) and a short calibration (a fixed single-core spin and a memory
//! copy) compared with the one taken when the session started.
//!
//! The rule ([`HostReading::noise`]) flags a run when, in a quiet window just before or just
//! after it (the harness idle, no run of ours), or during it:
//!
//! * the run's CPUs were more than [`BUSY_MAX`] (10 %) busy with other work, or
//! * more other tasks were runnable than the CPUs the run leaves free (median of samples
//!   over the window, `procs_running` of `/proc/stat` less the sampling thread), or
//! * the hypervisor stole more than [`STEAL_MAX`] (5 %) of the CPU time during the run, or
//! * the spin or the copy calibration took more than [`CALIBRATION_MAX`] (1.25) times as long
//!   as at the session's start.
//!
//! The load average is recorded but not part of the rule: it lags by a minute and counts this
//! campaign's own previous runs.

use serde::{Deserialize, Serialize};
use std::hint::black_box;
use std::time::{Duration, Instant};

/// Largest busy fraction of the run's CPUs (other work) of a quiet host.
pub const BUSY_MAX: f64 = 0.10;
/// Largest steal fraction of a quiet host.
pub const STEAL_MAX: f64 = 0.05;
/// Largest calibration time over the session start's of a quiet host.
pub const CALIBRATION_MAX: f64 = 1.25;

/// `/proc/stat` and its reader live with the solver program's own measurement of noise
/// (`mpm_host::usage`), which reads the steal of each worker's CPU.
pub use mpm_host::usage::{parse_proc_stat, CpuTimes, StatSnapshot};

/// The 1-minute load average (`/proc/loadavg`).
pub fn load1() -> Option<f64> {
    std::fs::read_to_string("/proc/loadavg").ok()?.split_whitespace().next()?.parse().ok()
}

/// The host in a quiet window (no run of ours): load average, other runnable tasks, and the
/// busy fraction of some CPUs.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Probe {
    /// 1-minute load average.
    pub load1: Option<f64>,
    /// Other runnable tasks (median over the window's samples).
    pub others_running: Option<u32>,
    /// Mean busy fraction of the CPUs over the window (`None` for a zero window).
    pub cpus_busy: Option<f64>,
}

/// Watch the host for `window` (five samples of runnable tasks; the CPU times of `cpus`, all
/// CPUs when empty, at both ends).
pub fn probe(cpus: &[usize], window: Duration) -> Probe {
    let start = StatSnapshot::read();
    let mut running: Vec<u32> = Vec::new();
    const SAMPLES: u32 = 5;
    for i in 0..SAMPLES {
        if let Some(s) = if i == 0 { start.clone() } else { StatSnapshot::read() } {
            running.push(s.procs_running.saturating_sub(1));
        }
        if !window.is_zero() {
            std::thread::sleep(window / SAMPLES);
        }
    }
    running.sort_unstable();
    let end = StatSnapshot::read();
    let cpus_busy = match (&start, &end) {
        (Some(a), Some(b)) if !window.is_zero() => a.busy_since(b, cpus),
        _ => None,
    };
    Probe { load1: load1(), others_running: running.get(running.len() / 2).copied(), cpus_busy }
}

/// Seconds of a fixed single-core spin and of a fixed memory copy (medians of three).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Calibration {
    /// Integer spin (about 10 ms on a current core), s.
    pub spin_s: f64,
    /// Copy of 16 MiB, four times, s.
    pub copy_s: f64,
}

impl Calibration {
    /// Time both now.
    pub fn measure() -> Self {
        let mut src = vec![0u8; 16 << 20];
        for (i, b) in src.iter_mut().enumerate() {
            *b = i as u8;
        }
        let mut dst = vec![0u8; src.len()];
        let spin = median3(|| {
            let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
            for _ in 0..10_000_000u32 {
                x ^= x << 13;
                x ^= x >> 7;
                x ^= x << 17;
            }
            black_box(x);
        });
        let copy = median3(|| {
            for _ in 0..4 {
                dst.copy_from_slice(black_box(&src));
                black_box(&mut dst);
            }
        });
        Self { spin_s: spin, copy_s: copy }
    }

    /// This calibration's times over `start`'s (spin, copy); above 1 = slower now.
    pub fn ratio_to(&self, start: &Self) -> (Option<f64>, Option<f64>) {
        let r = |a: f64, b: f64| (b > 0.0 && a.is_finite()).then(|| a / b);
        (r(self.spin_s, start.spin_s), r(self.copy_s, start.copy_s))
    }
}

fn median3(mut f: impl FnMut()) -> f64 {
    let mut t: Vec<f64> = (0..3)
        .map(|_| {
            let t0 = Instant::now();
            f();
            t0.elapsed().as_secs_f64()
        })
        .collect();
    t.sort_by(f64::total_cmp);
    t[1]
}

/// What a row records of its host (the CSV's `host_*` and `calib_*` columns).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HostReading {
    /// Probe just before the run.
    pub before: Probe,
    /// Probe just after the run.
    pub after: Probe,
    /// Steal fraction during the run.
    pub steal: Option<f64>,
    /// Spin calibration over the session start's.
    pub spin_ratio: Option<f64>,
    /// Copy calibration over the session start's.
    pub copy_ratio: Option<f64>,
}

impl HostReading {
    /// Why a run of `threads` threads on a host of `pus` usable PUs was measured on a busy
    /// host (see the module docs), `None` when it was not.
    pub fn noise(&self, threads: usize, pus: usize) -> Option<String> {
        let mut why: Vec<String> = Vec::new();
        let free = pus.saturating_sub(threads) as u32;
        for (when, p) in [("before", &self.before), ("after", &self.after)] {
            if let Some(b) = p.cpus_busy.filter(|b| *b > BUSY_MAX) {
                why.push(format!("its CPUs {:.0} % busy with other work {when} the run", b * 100.0));
            }
            if let Some(n) = p.others_running.filter(|n| *n > free) {
                why.push(format!("{n} other runnable task(s) {when} the run, {free} free CPU(s)"));
            }
        }
        if let Some(s) = self.steal.filter(|s| *s > STEAL_MAX) {
            why.push(format!("{:.0} % of the CPU time stolen by the hypervisor", s * 100.0));
        }
        for (name, r) in [("spin", self.spin_ratio), ("copy", self.copy_ratio)] {
            if let Some(r) = r.filter(|r| *r > CALIBRATION_MAX) {
                why.push(format!("{name} calibration {r:.2}x its session-start time"));
            }
        }
        (!why.is_empty()).then(|| why.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn quiet() -> HostReading {
        let p = Probe { load1: Some(0.2), others_running: Some(0), cpus_busy: Some(0.02) };
        HostReading { before: p, after: p, steal: Some(0.0), spin_ratio: Some(1.02), copy_ratio: Some(0.97) }
    }

    #[test]
    fn a_quiet_host_is_not_noisy() {
        assert_eq!(quiet().noise(2, 2), None);
        assert_eq!(HostReading::default().noise(2, 2), None, "nothing measured, nothing flagged");
        // A high load average alone (our own previous runs) does not flag a run.
        let mut h = quiet();
        h.before.load1 = Some(8.0);
        assert_eq!(h.noise(2, 2), None);
    }

    #[test]
    fn each_sign_of_a_busy_host_flags_the_run() {
        let mut h = quiet();
        h.after.cpus_busy = Some(0.35);
        assert!(h.noise(2, 2).unwrap().contains("35 % busy with other work after"));
        let mut h = quiet();
        h.before.others_running = Some(1);
        assert!(h.noise(2, 2).unwrap().contains("1 other runnable task(s) before the run, 0 free"));
        assert_eq!(h.noise(1, 2), None, "one other task fits on the CPU a 1-thread run leaves free");
        let mut h = quiet();
        h.steal = Some(0.08);
        assert!(h.noise(1, 2).unwrap().contains("8 % of the CPU time stolen"));
        let mut h = quiet();
        h.copy_ratio = Some(1.4);
        assert!(h.noise(1, 2).unwrap().contains("copy calibration 1.40x"));
        // At the thresholds: still quiet.
        let mut h = quiet();
        h.before.cpus_busy = Some(BUSY_MAX);
        h.steal = Some(STEAL_MAX);
        h.spin_ratio = Some(CALIBRATION_MAX);
        assert_eq!(h.noise(2, 2), None);
    }

    #[test]
    fn probe_and_calibration_read_this_host() {
        let p = probe(&[0], Duration::from_millis(60));
        assert!(p.others_running.is_some() && p.cpus_busy.is_some_and(|b| (0.0..=1.0).contains(&b)), "{p:?}");
        assert!(probe(&[], Duration::ZERO).cpus_busy.is_none());
        let c = Calibration::measure();
        assert!(c.spin_s > 0.0 && c.copy_s > 0.0);
        let (s, k) = c.ratio_to(&c);
        assert_eq!((s, k), (Some(1.0), Some(1.0)));
        assert_eq!(c.ratio_to(&Calibration::default()), (None, None));
    }
}
