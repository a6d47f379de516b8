//! `mpm-bench calibrate`'s measurement: the regression gate's own campaign (a preset, by
//! default `ci`) run several times with the same binary and several times with an injected
//! slowdown of known size, interleaved in one session ([`run_campaigns`]). What the gate
//! makes of them, and why, is [`crate::analysis::calibrate`]'s.

use crate::campaign::exec::process::Runner;
use crate::campaign::exec::solver::Solver;
use crate::campaign::exec::watch::WatchSettings;
use crate::campaign::plan::matrix::{Campaign, Overrides};
use crate::campaign::plan::preset;
use crate::campaign::schedule::{self, ExecOptions};
use crate::machine::topology::Machine;
use anyhow::{bail, Context, Result};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Measure the gate's false-alarm rate and detection power on this host.
#[derive(Debug, Clone)]
pub struct CalibrateOptions {
    /// The preset of every gate run: a name (ci, quick, ...) or a TOML file.
    pub preset: String,
    /// Clean campaigns (the same binary, nothing injected); every pair is an A/A comparison.
    pub clean: usize,
    /// Campaigns with the injected slowdown; each is compared with every clean one.
    pub injected: usize,
    /// The injected efficiency loss, a fraction (0.1: the T-thread efficiency drops by 10 %).
    pub inject_slowdown: f64,
    /// Stop starting campaigns when the next would likely end after this much time (e.g.
    /// 90m); the comparisons are made with the campaigns done.
    pub budget: Option<String>,
    /// The gate's tolerance, as `regress --tolerance`.
    pub tolerance: f64,
    /// The gate's metrics, as `regress --metrics` (the CI recipe gates efficiency and work).
    pub metrics: Vec<String>,
    /// Root of the results tree: the campaigns go to
    /// <out>/<fingerprint>/calibrate-<preset>-{clean,inject<F>}-<i>/.
    pub out: PathBuf,
    /// Where to write calibration.json (default: <out>/<fingerprint>/calibrate-<preset>/calibration.json).
    pub json: Option<PathBuf>,
    /// Do not build the solver; use the existing target/o3/mpm (and target/o0/mpm).
    pub no_build: bool,
    /// No progress lines.
    pub quiet: bool,
    /// Use a fake solver (testing the harness itself).
    pub mock: bool,
    /// Calibrate `mpm-bench ab` (sides of one build run side by side, process by process)
    /// instead of `regress` on whole campaigns.
    pub design_ab: bool,
    /// With `design_ab`: the injected step slowdown of the time-per-step sides (a fraction).
    pub inject_step_slowdown: f64,
    /// With `design_ab`: processes per cell and side (default: the preset's).
    pub reps: Option<u32>,
    /// With `design_ab`: the seed of the sides' order.
    pub seed: Option<u64>,
}

/// One campaign of the calibration.
#[derive(Clone, Debug, Serialize)]
pub struct CalibrationCampaign {
    /// `clean` or `injected`.
    pub kind: &'static str,
    /// Its folder.
    pub dir: PathBuf,
    /// Its wall time (s).
    pub wall_s: f64,
}

/// The order of `clean` clean and `injected` injected campaigns: the injected ones spread
/// evenly among the clean ones (`false`: clean, `true`: injected).
pub fn schedule(clean: usize, injected: usize) -> Vec<bool> {
    let n = clean + injected;
    let mut out = vec![false; n];
    for j in 0..injected {
        // The middle of the j-th of `injected` equal stretches.
        out[((2 * j + 1) * n) / (2 * injected)] = true;
    }
    out
}

/// Parse a duration such as `90m`.
fn parse_budget(s: &str) -> Result<Duration> {
    let d = humantime::parse_duration(s.trim()).map_err(|e| anyhow::anyhow!("bad --budget '{s}': {e} (e.g. 90m)"))?;
    if d.is_zero() {
        bail!("--budget {s} leaves no time for a campaign: give e.g. 90m");
    }
    Ok(d)
}

/// The campaign of the `i`-th calibration run: the preset, with the injected slowdown when
/// `injected`, its own id and seed.
pub fn campaign_of(a: &CalibrateOptions, injected: bool, i: usize) -> Result<Campaign> {
    let ws = crate::campaign::exec::solver::workspace_root();
    let (p, src) = preset::load_preset(&a.preset, ws.as_deref())?;
    let name = p.name.clone();
    let seed = p.seed;
    let ov = Overrides { inject_slowdown: injected.then_some(a.inject_slowdown), ..Overrides::default() };
    let mut c = Campaign::resolve(p, src, &ov)?;
    c.id = if injected {
        format!("calibrate-{name}-inject{}-{i}", a.inject_slowdown)
    } else {
        format!("calibrate-{name}-clean-{i}")
    };
    c.seed = seed.wrapping_add(i as u64 + if injected { 1000 } else { 0 });
    Ok(c)
}

/// Run the calibration's campaigns on `machine` with `solvers` through `runner`, clean and
/// injected interleaved ([`schedule`]), until done or the budget says stop (progress lines
/// unless quiet). The gate's comparisons of them are [`crate::analysis::calibrate::judge`]'s.
pub fn run_campaigns(
    a: &CalibrateOptions,
    machine: &Machine,
    solvers: &[Solver],
    runner: &mut dyn Runner,
    watch: Option<WatchSettings>,
    interrupted: &AtomicBool,
) -> Result<Vec<CalibrationCampaign>> {
    let budget = a.budget.as_deref().map(parse_budget).transpose()?;
    let start = Instant::now();
    let mut campaigns: Vec<CalibrationCampaign> = Vec::new();
    let order = schedule(a.clean, a.injected);
    let (mut nc, mut ni) = (0, 0);
    for (k, &injected) in order.iter().enumerate() {
        if interrupted.load(Ordering::SeqCst) {
            bail!("interrupted after {k} campaign(s); run the same command again to resume");
        }
        let longest = campaigns.iter().map(|c| c.wall_s).fold(0.0, f64::max);
        if let Some(b) = budget {
            if k > 0 && start.elapsed().as_secs_f64() + longest > b.as_secs_f64() {
                eprintln!(
                    "note: --budget {}: stopping after {k} of {} campaigns (the next would end after it)",
                    humantime::format_duration(b),
                    order.len()
                );
                break;
            }
        }
        let i = if injected { ni } else { nc };
        let c = campaign_of(a, injected, i)?;
        if !a.quiet {
            eprintln!("calibrate: campaign {} of {}: {}", k + 1, order.len(), c.id);
        }
        let opts = ExecOptions {
            out_root: a.out.clone(),
            quiet: true,
            watch,
            command: std::env::args().collect::<Vec<_>>().join(" "),
            ..ExecOptions::default()
        };
        let s = schedule::execute(&c, machine, solvers, runner, &opts, interrupted)
            .with_context(|| format!("calibration campaign {}", c.id))?;
        if s.counts.interrupted {
            bail!("interrupted in campaign {}; run the same command again to resume", c.id);
        }
        campaigns.push(CalibrationCampaign {
            kind: if injected { "injected" } else { "clean" },
            dir: s.dir.clone(),
            wall_s: s.wall.as_secs_f64(),
        });
        if injected {
            ni += 1;
        } else {
            nc += 1;
        }
    }
    Ok(campaigns)
}

/// The mock runner's stand-in solvers (`--mock`).
pub fn mock_solvers() -> Vec<Solver> {
    [crate::campaign::plan::preset::OptLevel::O3, crate::campaign::plan::preset::OptLevel::O0]
        .into_iter()
        .map(|opt| Solver { opt, path: "mock".into(), sha256: "mock".into() })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn injected_campaigns_spread_among_the_clean() {
        let s = schedule(7, 3);
        assert_eq!(s.iter().filter(|&&x| x).count(), 3);
        assert_eq!(s, [false, true, false, false, false, true, false, false, true, false]);
        assert_eq!(schedule(2, 0), [false, false]);
        assert_eq!(schedule(1, 1), [false, true]);
    }
}
