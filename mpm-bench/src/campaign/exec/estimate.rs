//! The campaign's duration, estimated from one short calibration run per optimisation
//! level ([`estimate_duration`]).
use crate::campaign::exec::process::{RunRequest, Runner};
use crate::campaign::exec::run::read_summary;
use crate::campaign::exec::solver::Solver;
use crate::campaign::plan::matrix::PlannedRun;
use crate::campaign::plan::preset::OptLevel;
use anyhow::{anyhow, Result};
use std::path::Path;
use std::time::Duration;

/// The campaign's duration, estimated from one short calibration run per optimisation level
/// (Taylor Model 1, serial, 20 steps, 2 of them warm-up: a few seconds): each run costs its
/// set-up (the calibration's, in proportion to the particles) and its steps x particles x the
/// calibration's time per particle-step, over the cores it uses (at 80 % efficiency; an
/// oversubscribed run gets no more than the cores). End-time budgets take their step count
/// from the calibration's time step scaled with the Taylor model's cell size; the impact's
/// steps are not estimated.
pub fn estimate_duration(
    runner: &mut dyn Runner,
    solvers: &[Solver],
    todo: &[(usize, PlannedRun)],
    json_dir: &Path,
    cores: usize,
) -> Result<String> {
    use std::collections::BTreeMap;
    let mut calib: BTreeMap<OptLevel, (f64, f64, f64)> = BTreeMap::new(); // ns per ps, setup s per particle, dt
    for opt in todo.iter().map(|(_, r)| r.opt).collect::<std::collections::BTreeSet<_>>() {
        let solver = solvers.iter().find(|s| s.opt == opt).ok_or_else(|| anyhow!("no {opt} solver"))?;
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
        calib.insert(opt, (ns, setup, s.figures.progress.dt_first));
    }
    let mut total = 0.0;
    let mut unknown = 0;
    for (_, r) in todo {
        let (ns, setup, dt1) = calib[&r.opt];
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
    let rates: Vec<String> =
        calib.iter().map(|(o, (ns, _, _))| format!("{ns:.0} ns per particle-step at {o}")).collect();
    Ok(format!(
        "estimated duration: about {} for {} run(s){} (from a calibration run of Taylor Model 1, 20 serial steps: {}; \
         a run costs its steps x particles at that rate over its cores, plus its set-up)",
        humantime::format_duration(Duration::from_secs(total.round() as u64)),
        todo.len() - unknown,
        if unknown > 0 { format!(", {unknown} more not estimated (impact end times)") } else { String::new() },
        rates.join(", ")
    ))
}
