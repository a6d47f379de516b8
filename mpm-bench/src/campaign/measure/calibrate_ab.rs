//! `mpm-bench calibrate --design ab`'s measurement: the side-by-side gate's cells (a preset,
//! by default `ci`) run by several sides of one build in one sitting, process by process
//! ([`crate::campaign::schedule::ab::run_sides`]): `--clean` sides with nothing injected,
//! `--injected` sides with an injected efficiency loss and as many with an injected step
//! slowdown. Every two clean sides make an A/A comparison and every clean side against an
//! injected one an injected comparison; [`crate::analysis::calibrate_ab`] judges them with
//! `mpm-bench ab`'s own verdict.

use super::calibrate::CalibrateOptions;
use crate::campaign::exec::process::Runner;
use crate::campaign::exec::solver::Solver;
use crate::campaign::plan::matrix::{Campaign, Overrides};
use crate::campaign::plan::preset;
use crate::campaign::schedule::ab::{run_sides, AbRecord, Side};
use crate::campaign::schedule::ExecOptions;
use crate::machine::topology::Machine;
use anyhow::{bail, Result};
use std::path::Path;
use std::sync::atomic::AtomicBool;

/// What a side of the calibration is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SideKind {
    /// Nothing injected.
    Clean,
    /// The injected efficiency loss (`--inject-slowdown`).
    Efficiency,
    /// The injected step slowdown (`--inject-step-slowdown`).
    Step,
}

impl SideKind {
    /// The name in the record and in `calibration.json`.
    pub fn name(self) -> &'static str {
        match self {
            SideKind::Clean => "clean",
            SideKind::Efficiency => "efficiency",
            SideKind::Step => "time_per_step",
        }
    }
}

/// The sides, in their order of labels: `clean`, then the injected efficiency loss, then the
/// injected step slowdown, the injected ones spread by the interleaving like the clean.
pub fn side_kinds(a: &CalibrateOptions) -> Vec<SideKind> {
    let mut v = vec![SideKind::Clean; a.clean];
    v.extend(std::iter::repeat_n(SideKind::Efficiency, a.injected));
    v.extend(std::iter::repeat_n(SideKind::Step, a.injected));
    v
}

/// The campaign of a side of `kind`: the preset (with `--reps`) and its knob.
pub fn side_campaign(a: &CalibrateOptions, kind: SideKind) -> Result<Campaign> {
    let ws = crate::campaign::exec::solver::workspace_root();
    let (p, src) = preset::load_preset(&a.preset, ws.as_deref())?;
    let ov = Overrides {
        reps: a.reps,
        inject_slowdown: (kind == SideKind::Efficiency).then_some(a.inject_slowdown),
        inject_step_slowdown: (kind == SideKind::Step).then_some(a.inject_step_slowdown),
        ..Overrides::default()
    };
    Campaign::resolve(p, src, &ov)
}

/// Run every side of the calibration side by side into `dir/<label>/`, with `solvers` (one
/// build on every side) through `runner`; the record of what ran, and each side's kind.
pub fn run(
    a: &CalibrateOptions,
    dir: &Path,
    machine: &Machine,
    solvers: &[Solver],
    runner: &mut dyn Runner,
    interrupted: &AtomicBool,
) -> Result<(AbRecord, Vec<SideKind>)> {
    let kinds = side_kinds(a);
    if a.clean < 2 {
        bail!("--clean {} gives no A/A comparison: use at least 2 (7 give 21 comparisons)", a.clean);
    }
    let campaigns: Vec<Campaign> = kinds.iter().map(|&k| side_campaign(a, k)).collect::<Result<_>>()?;
    let mut counter = std::collections::HashMap::new();
    let sides: Vec<Side<'_>> = kinds
        .iter()
        .zip(&campaigns)
        .map(|(k, c)| {
            let n = counter.entry(k.name()).or_insert(0usize);
            *n += 1;
            let label = format!("{}-{}", k.name(), n);
            Side { out_root: dir.join(&label), label, campaign: c, solvers }
        })
        .collect();
    let opts = ExecOptions {
        quiet: a.quiet,
        command: std::env::args().collect::<Vec<_>>().join(" "),
        ..ExecOptions::default()
    };
    let seed = a.seed.unwrap_or(campaigns[0].seed);
    let record = run_sides(&sides, machine, runner, &opts, seed, interrupted)?;
    Ok((record, kinds))
}
