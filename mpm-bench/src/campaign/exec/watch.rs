//! The host watch of a campaign session: the calibration at the session's start (and again
//! every few runs), a quiet-window probe of the host before and after each run, the steal
//! during it, and the warning when a session starts on a busy host. What it measures goes
//! into each row's `host_*` / `calib_*` columns and the `host_noisy` flag
//! ([`crate::machine::load`] has the rule).

use crate::machine::load::{probe, Calibration, HostReading, Probe, StatSnapshot};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// How closely to watch the host.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct WatchSettings {
    /// Length of the quiet window before and after each run.
    pub window: Duration,
    /// Calibrate again before every this many runs.
    pub calibrate_every: usize,
    /// Length of the probe at the session's start.
    pub start_window: Duration,
}

impl Default for WatchSettings {
    /// 200 ms windows (0.4 s per run), calibration every 10 runs, 1 s at the start.
    fn default() -> Self {
        Self { window: Duration::from_millis(200), calibrate_every: 10, start_window: Duration::from_secs(1) }
    }
}

/// A session's watch over its host.
#[derive(Debug)]
pub struct HostWatch {
    settings: WatchSettings,
    start: Calibration,
    ratios: (Option<f64>, Option<f64>),
    runs: usize,
}

/// A probe before a run and the CPU times when it started.
pub struct BeforeRun {
    probe: Probe,
    stat: Option<StatSnapshot>,
}

impl HostWatch {
    /// Calibrate and probe the whole host; warn on stderr when it is busy already.
    pub fn start(settings: WatchSettings, pus: usize) -> Self {
        let p = probe(&[], settings.start_window);
        let start = Calibration::measure();
        let first = HostReading { before: p, ..HostReading::default() };
        if let Some(why) = first.noise(pus, pus) {
            eprintln!(
                "warning: the host is busy at the start of the campaign ({why}): timings will be noisy; rows \
                 measured on a busy host are flagged host_noisy and left out of claims and regress \
                 (--include-noisy keeps them)"
            );
        }
        Self { settings, start, ratios: (Some(1.0), Some(1.0)), runs: 0 }
    }

    /// The calibration of the session's start.
    pub fn calibration(&self) -> Calibration {
        self.start
    }

    /// Before a run on `cpus` (empty: not pinned): calibrate again when due, then probe.
    pub fn before_run(&mut self, cpus: &[usize]) -> BeforeRun {
        if self.runs > 0 && self.runs.is_multiple_of(self.settings.calibrate_every.max(1)) {
            self.ratios = Calibration::measure().ratio_to(&self.start);
        }
        self.runs += 1;
        let probe = probe(cpus, self.settings.window);
        BeforeRun { probe, stat: StatSnapshot::read() }
    }

    /// After the run that `before` preceded: the steal during it, a probe, the calibration.
    pub fn after_run(&self, cpus: &[usize], before: BeforeRun) -> HostReading {
        let end = StatSnapshot::read();
        let steal = match (&before.stat, &end) {
            (Some(a), Some(b)) => a.steal_since(b),
            _ => None,
        };
        HostReading {
            before: before.probe,
            after: probe(cpus, self.settings.window),
            steal,
            spin_ratio: self.ratios.0,
            copy_ratio: self.ratios.1,
        }
    }
}
