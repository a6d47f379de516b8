//! The campaign's duration, estimated from one short calibration run per optimisation
//! level ([`estimate_duration`]: a real run, `--dry-run --estimate`), or at a nominal rate
//! for a plain `--dry-run` ([`nominal_estimate`]).
use crate::campaign::exec::process::{RunRequest, Runner};
use crate::campaign::exec::run::read_summary;
use crate::campaign::exec::solver::Solver;
use crate::campaign::plan::matrix::PlannedRun;
use crate::campaign::plan::preset::OptLevel;
use anyhow::{anyhow, Result};
use std::collections::BTreeMap;
use std::path::Path;
use std::time::Duration;

/// What a calibration gives an estimate: the time per particle-step, the set-up time per
/// particle, and the first time step of Taylor Model 1 (s).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rate {
    /// Nanoseconds per particle-step of one thread.
    pub ns_per_particle_step: f64,
    /// Set-up seconds per particle.
    pub setup_s_per_particle: f64,
    /// First time step of Taylor Model 1 (s).
    pub dt_first: f64,
}

/// The rate `--dry-run` assumes, since it runs nothing: the development VM's serial speed at
/// O3 (about 190 ns per particle-step on Taylor Model 1, 1 us of set-up per particle), and
/// Taylor Model 1's first time step (5.6e-8 s). Unoptimised code is taken 10 times slower.
pub fn nominal_rate(opt: OptLevel) -> Rate {
    let slower = if opt == OptLevel::O3 { 1.0 } else { 10.0 };
    Rate { ns_per_particle_step: 190.0 * slower, setup_s_per_particle: 1e-6, dt_first: 5.6e-8 }
}

/// The campaign's duration, estimated from one short calibration run per optimisation level
/// (Taylor Model 1, serial, 20 steps, 2 of them warm-up: a few seconds), as [`sum`] says.
pub fn estimate_duration(
    runner: &mut dyn Runner,
    solvers: &[Solver],
    todo: &[(usize, PlannedRun)],
    json_dir: &Path,
    cores: usize,
) -> Result<String> {
    let mut calib: BTreeMap<OptLevel, Rate> = BTreeMap::new();
    for opt in todo.iter().map(|(_, r)| r.opt).collect::<std::collections::BTreeSet<_>>() {
        let solver = solvers.iter().find(|s| s.opt == opt).ok_or_else(|| anyhow!("no {opt} solver"))?;
        calib.insert(opt, calibrate(runner, solver, json_dir)?);
    }
    Ok(format!(
        "{} (from a calibration run of Taylor Model 1, 20 serial steps: {}; a run costs its steps x particles at \
         that rate over its cores, plus its set-up)",
        sum(todo, &calib, cores),
        rates(&calib)
    ))
}

/// The estimate `--dry-run` prints: [`sum`] at the [`nominal_rate`].
pub fn nominal_estimate(todo: &[(usize, PlannedRun)], cores: usize) -> String {
    let calib: BTreeMap<OptLevel, Rate> = todo.iter().map(|(_, r)| (r.opt, nominal_rate(r.opt))).collect();
    format!(
        "{} (at an assumed {}; a real run, or --dry-run --estimate, calibrates on this host instead)",
        sum(todo, &calib, cores),
        rates(&calib)
    )
}

fn rates(calib: &BTreeMap<OptLevel, Rate>) -> String {
    let r: Vec<String> =
        calib.iter().map(|(o, r)| format!("{:.0} ns per particle-step at {o}", r.ns_per_particle_step)).collect();
    r.join(", ")
}

/// One calibration run of `solver`.
fn calibrate(runner: &mut dyn Runner, solver: &Solver, json_dir: &Path) -> Result<Rate> {
    let opt = solver.opt;
    let mut run = PlannedRun::taylor(1, mpm_core::Strategy::Serial, opt, 1, 20);
    run.spec.budget.warmup = Some(2);
    let mut req = RunRequest::new(
        &run,
        None,
        json_dir.join(format!("calibration-{opt}.json")),
        json_dir.join(format!("calibration-{opt}.spec.toml")),
    );
    req.binary = solver.path.clone();
    req.timeout = Some(Duration::from_secs(300));
    let out = runner.run(&req);
    let summary = read_summary(&req.json_path);
    let _ = std::fs::remove_file(&req.json_path);
    let _ = std::fs::remove_file(&req.spec_path);
    let s = summary.map_err(|e| anyhow!("the {opt} calibration run: {e}"))?;
    let ns = s
        .figures
        .timing
        .ns_per_particle_step
        .ok_or_else(|| anyhow!("the {opt} calibration run has no steady steps"))?;
    let setup = (out.process_wall_s - s.figures.timing.wall_s).max(0.0) / s.figures.size.particles.max(1) as f64;
    Ok(Rate { ns_per_particle_step: ns, setup_s_per_particle: setup, dt_first: s.figures.progress.dt_first })
}

/// The duration of the runs `todo` at the rates `calib` (one per optimisation level of the
/// runs): each run costs its set-up (per particle) and its steps x particles x the time per
/// particle-step, over the cores it uses (at 80 % efficiency; an oversubscribed run gets no
/// more than the cores), plus, paired, as much again for its one-thread reference. End-time
/// budgets take their step count from the first time step scaled with the Taylor model's
/// cell size; the impact's steps are not estimated.
pub fn sum(todo: &[(usize, PlannedRun)], calib: &BTreeMap<OptLevel, Rate>, cores: usize) -> String {
    let mut total = 0.0;
    let mut unknown = 0;
    for (_, r) in todo {
        let rate = calib[&r.opt];
        let (ns, setup, dt1) = (rate.ns_per_particle_step, rate.setup_s_per_particle, rate.dt_first);
        let size = r.spec.scenario.size();
        let p = size.particles as f64;
        let steps = match (r.spec.budget.steps, r.spec.budget.end_time_s, r.spec.scenario) {
            (Some(n), _, _) => n as f64,
            (None, Some(t), mpm_spec::Scenario::Taylor(tb)) => {
                let nz = [48.0, 72.0, 132.0, 264.0][usize::from(tb.model.clamp(1, 4)) - 1];
                t / (dt1 * 48.0 / nz)
            }
            _ => {
                unknown += 1;
                continue;
            }
        };
        let workers = r.total_threads();
        let speed = if workers > 1 { 0.8 * workers.min(cores) as f64 } else { 1.0 };
        // A paired run steps a one-thread reference beside it.
        let reference = if r.spec.paired.is_some() { steps * p * ns * 1e-9 } else { 0.0 };
        total += p * setup + steps * p * ns * 1e-9 / speed + reference;
    }
    format!(
        "estimated duration: about {} for {} run(s) on {cores} core(s){}",
        humantime::format_duration(Duration::from_secs(total.round() as u64)),
        todo.len() - unknown,
        if unknown > 0 { format!(", {unknown} more not estimated (impact end times)") } else { String::new() },
    )
}
