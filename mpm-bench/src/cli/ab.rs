//! `mpm-bench ab` (two builds measured side by side, the CI gate of a pull request) and
//! `mpm-bench work-snapshot` (the work counters against a committed snapshot): their
//! options, and the steps from the builds to the verdict.

use crate::bad_input;
use anyhow::{Context, Result};
use clap::Args;
use mpm_bench::analysis::ab::{self, AbSettings};
use mpm_bench::analysis::work_snapshot;
use mpm_bench::campaign::exec::builds::{self, BuildRecord};
use mpm_bench::campaign::exec::process::{MockRunner, ProcessRunner, Runner};
use mpm_bench::campaign::exec::solver::{self, Solver};
use mpm_bench::campaign::plan::matrix::{Campaign, Overrides};
use mpm_bench::campaign::plan::preset;
use mpm_bench::campaign::schedule::ab::{run_sides, AbRecord, Side};
use mpm_bench::campaign::schedule::{self, ExecOptions};
use mpm_bench::machine::topology::Machine;
use std::path::{Path, PathBuf};

/// Two builds of the solver measured side by side in one sitting: the CI gate of a pull
/// request against its base.
#[derive(Args, Debug, Clone)]
pub struct AbArgs {
    /// The baseline: a git revision (branch, tag, commit) of this repository, checked out
    /// into a worktree and built into a target folder of its own (--baseline-target).
    #[arg(long, value_name = "REV", conflicts_with = "baseline_bin", required_unless_present = "baseline_bin")]
    pub baseline_rev: Option<String>,
    /// The baseline: solver binaries already built, DIR/o3/mpm (and DIR/o0/mpm): a Cargo
    /// target folder, or a bundle's bin/.
    #[arg(long, value_name = "DIR")]
    pub baseline_bin: Option<PathBuf>,
    /// The Cargo target folder --baseline-rev builds in (default: <target>/ab-baseline, a
    /// folder of its own). The built binaries are copied aside (DIR/ab-bin-<commit>/), so
    /// this checkout's target folder may be given to share its dependencies' builds; keep it
    /// in the CI cache to build only what changed.
    #[arg(long, value_name = "DIR")]
    pub baseline_target: Option<PathBuf>,
    /// An argument for the cargo builds this command makes (repeatable), e.g.
    /// --cargo-arg=--no-default-features (the solver without MPI, which ab never uses).
    #[arg(long = "cargo-arg", value_name = "ARG", allow_hyphen_values = true)]
    pub cargo_args: Vec<String>,
    /// The candidate: solver binaries already built (default: this checkout's, built as
    /// `mpm-bench run` builds them unless --no-build).
    #[arg(long, value_name = "DIR")]
    pub candidate_bin: Option<PathBuf>,
    /// Do not build this checkout's solver; use the existing target/o3/mpm (and o0).
    #[arg(long)]
    pub no_build: bool,
    /// The cells to measure: a preset name (ci, smoke, ...) or a TOML file.
    #[arg(long, default_value = "ci")]
    pub preset: String,
    /// Processes per cell and build (default: the preset's); each is one pair.
    #[arg(long)]
    pub reps: Option<u32>,
    /// Seed of the run order and of which build starts (recorded in ab.json).
    #[arg(long)]
    pub seed: Option<u64>,
    /// The output folder: baseline/ and candidate/ hold the two campaigns (every row of both
    /// sides), ab.json the order that ran, verdict.json the verdict. The same command resumes
    /// an interrupted comparison.
    #[arg(long, value_name = "DIR", default_value = "results/local/ab")]
    pub out: PathBuf,
    /// Relative change tolerated before a check can fail (0.05 = 5 %).
    #[arg(long, default_value_t = 0.05, allow_negative_numbers = true)]
    pub tolerance: f64,
    /// What to gate, comma-separated: efficiency (parallel efficiency), time (time per
    /// step: gated here, the builds ran moments apart on one host), work (the counters,
    /// exactly).
    #[arg(long, value_delimiter = ',', default_value = "efficiency,time,work")]
    pub metrics: Vec<String>,
    /// Do not fail when the candidate did not measure a cell the baseline did.
    #[arg(long)]
    pub allow_missing: bool,
    /// Also check the candidate's work counters against this committed snapshot.
    #[arg(long, value_name = "FILE")]
    pub work_snapshot: Option<PathBuf>,
    /// Write the machine-readable verdict here (JSON; `-` for standard output).
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,
    /// Append a Markdown summary of the verdict to FILE (e.g. "$GITHUB_STEP_SUMMARY").
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
    /// Test knob: the candidate's T-thread workers but the first work longer, so that its
    /// parallel efficiency drops by F (recorded; such rows are never a result).
    #[arg(long, value_name = "F")]
    pub candidate_inject_slowdown: Option<f64>,
    /// Test knob: every step of the candidate takes 1 / (1 - F) times as long on every worker
    /// alike (its time per step rises, its efficiency stays; recorded).
    #[arg(long, value_name = "F")]
    pub candidate_inject_step_slowdown: Option<f64>,
    /// No progress bar.
    #[arg(long, short = 'q')]
    pub quiet: bool,
    /// Use a fake solver on both sides (testing the harness itself).
    #[arg(long, hide = true)]
    pub mock: bool,
}

/// The campaign of one side: the preset with `--reps`, `--seed` and the side's knobs.
fn side_campaign(a: &AbArgs, inject: (Option<f64>, Option<f64>)) -> Result<Campaign> {
    let ws = solver::workspace_root();
    let (preset, source) = preset::load_preset(&a.preset, ws.as_deref())?;
    let ov = Overrides {
        reps: a.reps,
        seed: a.seed,
        inject_slowdown: inject.0,
        inject_step_slowdown: inject.1,
        ..Overrides::default()
    };
    Campaign::resolve(preset, source, &ov)
}

/// The two builds' solvers, and how each was had.
fn builds(a: &AbArgs, campaign: &Campaign) -> Result<[(Vec<Solver>, BuildRecord); 2]> {
    if a.mock {
        let mock = |s: &str| {
            let v = campaign.opts.iter().map(|&opt| Solver { opt, path: "mock".into(), sha256: s.into() }).collect();
            (v, BuildRecord { source: "mock".into(), commit: None, build_s: 0.0 })
        };
        return Ok([mock("mock-a"), mock("mock-b")]);
    }
    let ws = solver::workspace_root();
    let given = |dir: &PathBuf| -> Result<(Vec<Solver>, BuildRecord)> {
        let s = builds::solvers_in(dir, &campaign.opts)?;
        Ok((s, BuildRecord { source: format!("binaries in {}", dir.display()), commit: None, build_s: 0.0 }))
    };
    // Binaries given as folders are checked before anything is built: a mistyped
    // --baseline-bin is reported at once, not after the candidate's build.
    let baseline_given = a.baseline_bin.as_ref().map(given).transpose()?;
    // The candidate next, kept aside: a baseline built in the same target folder would
    // replace target/<profile>/mpm.
    let candidate = match &a.candidate_bin {
        Some(dir) => given(dir)?,
        None => {
            let t0 = std::time::Instant::now();
            if !a.no_build {
                let ws =
                    ws.as_deref().context("cannot find the workspace to build the candidate: run from a checkout")?;
                for &opt in &campaign.opts {
                    solver::build_solver_in(ws, &solver::target_dir(ws), opt, &a.cargo_args, a.quiet)?;
                }
            }
            let built = solver::prepare_solvers(&campaign.opts, false, a.quiet)?;
            let s = builds::keep_aside(&built, &a.out.join("bin").join("candidate"))?;
            (s, BuildRecord { source: "this checkout".into(), commit: None, build_s: t0.elapsed().as_secs_f64() })
        }
    };
    let baseline = match (baseline_given, &a.baseline_rev) {
        (Some(b), _) => b,
        (None, Some(rev)) => {
            let ws = ws.as_deref().context("--baseline-rev needs the repository: run from a checkout")?;
            let target = a.baseline_target.clone().unwrap_or_else(|| builds::default_baseline_root(ws));
            builds::build_rev(ws, rev, &campaign.opts, &target, &a.cargo_args, a.quiet)?
        }
        (None, None) => anyhow::bail!("give the baseline: --baseline-rev REV or --baseline-bin DIR"),
    };
    Ok([baseline, candidate])
}

/// `mpm-bench ab`: build (or find) both sides, run them side by side, judge; the exit code.
pub fn cmd_ab(a: AbArgs) -> Result<i32> {
    let base = side_campaign(&a, (None, None)).unwrap_or_else(|e| bad_input(e));
    let cand = side_campaign(&a, (a.candidate_inject_slowdown, a.candidate_inject_step_slowdown))
        .unwrap_or_else(|e| bad_input(e));
    let settings = AbSettings {
        tolerance: a.tolerance,
        metrics: a.metrics.clone(),
        allow_missing: a.allow_missing,
        work_snapshot: a.work_snapshot.clone(),
    };
    ab::check_settings(&settings).unwrap_or_else(|e| bad_input(e));
    super::run::check_writable(&a.out)?;
    let machine = Machine::detect()?;
    let [(base_solvers, base_build), (cand_solvers, cand_build)] = builds(&a, &base)?;
    let sides = [
        Side { label: "baseline".into(), campaign: &base, solvers: &base_solvers, out_root: a.out.join("baseline") },
        Side { label: "candidate".into(), campaign: &cand, solvers: &cand_solvers, out_root: a.out.join("candidate") },
    ];
    let interrupted = schedule::install_interrupt_handler();
    let opts =
        ExecOptions { quiet: a.quiet, command: std::env::args().collect::<Vec<_>>().join(" "), ..Default::default() };
    let mut runner: Box<dyn Runner> =
        if a.mock { Box::new(MockRunner::default()) } else { Box::new(ProcessRunner::new(interrupted.clone())) };
    let seed = a.seed.unwrap_or(base.seed);
    let mut record = run_sides(&sides, &machine, runner.as_mut(), &opts, seed, &interrupted)?;
    for (side, build) in record.sides.iter_mut().zip([base_build, cand_build]) {
        side.build = Some(serde_json::to_value(build)?);
    }
    record.write(&a.out.join("ab.json"))?;
    if record.interrupted {
        eprintln!("interrupted: the rows so far are kept; the same command continues");
        return Ok(130);
    }
    verdict(&a, &settings, &record)
}

/// Judge the two sides the record names; write verdict.json beside it.
fn verdict(a: &AbArgs, settings: &AbSettings, record: &AbRecord) -> Result<i32> {
    let (base, cand) = (&record.sides[0].dir, &record.sides[1].dir);
    let r = ab::judge(settings, base, cand, ("baseline", "candidate"))?;
    mpm_bench::analysis::regress::write_json(&a.out.join("verdict.json"), &r)?;
    ab::emit(&r, a.json.as_deref(), a.markdown.as_deref())
}

/// The work counters of the gate's cells against a committed snapshot: check (exactly,
/// naming the cell and sub-stage that changed) or write.
#[derive(Args, Debug, Clone)]
pub struct WorkSnapshotArgs {
    /// Check this build's counters against the snapshot FILE: exit 0 equal, 1 changed.
    #[arg(long, value_name = "FILE", conflicts_with = "write", required_unless_present = "write")]
    pub check: Option<PathBuf>,
    /// Write this build's counters to FILE (commit it when the change is intended).
    #[arg(long, value_name = "FILE")]
    pub write: Option<PathBuf>,
    /// Take the counters from this campaign folder's rows instead of running the cells.
    #[arg(long, value_name = "DIR")]
    pub campaign: Option<PathBuf>,
    /// The cells: a preset name or a TOML file (one unpaired run per cell, 1 repetition).
    #[arg(long, default_value = "ci")]
    pub preset: String,
    /// Do not build the solver; use the existing target/o3/mpm.
    #[arg(long)]
    pub no_build: bool,
    /// Use a fake solver (testing the harness itself).
    #[arg(long, hide = true)]
    pub mock: bool,
}

/// `mpm-bench work-snapshot`: the exit code (0 equal or written, 1 changed).
pub fn cmd_work_snapshot(a: WorkSnapshotArgs) -> Result<i32> {
    let rows = match &a.campaign {
        Some(dir) => read_rows(dir)?,
        None => run_cells(&a)?,
    };
    if let Some(path) = &a.write {
        let from = a.campaign.as_ref().map_or(String::new(), |d| format!(" --campaign {}", d.display()));
        let command = format!("mpm-bench work-snapshot --preset {}{from} --write {}", a.preset, path.display());
        let snap = work_snapshot::snapshot_of(&rows, &a.preset, &command)?;
        work_snapshot::write(path, &snap)?;
        println!("wrote the work counters of {} cell(s) to {}", snap.cells.len(), path.display());
        return Ok(0);
    }
    let path = a.check.as_deref().context("give --check FILE or --write FILE")?;
    let c = work_snapshot::check_rows(path, &rows)?;
    println!("{}", c.summary());
    for ch in &c.changed {
        println!("  {}: {}", ch.cell, ch.changes.join("; "));
    }
    for n in &c.not_in_snapshot {
        println!("  not in the snapshot: {n}");
    }
    Ok(if c.passed() { 0 } else { 1 })
}

/// The rows of a campaign folder (any rows with counters: noisy, injected and oversubscribed
/// rows count the same work).
fn read_rows(dir: &Path) -> Result<Vec<mpm_bench::campaign::store::record::Row>> {
    let filter = mpm_bench::analysis::select::RowFilter::analysis(true).with_injected(true);
    Ok(mpm_bench::analysis::results::load_campaign(dir, &filter)?.rows)
}

/// Run every cell of the preset once (1 repetition) into a temporary folder; its rows.
fn run_cells(a: &WorkSnapshotArgs) -> Result<Vec<mpm_bench::campaign::store::record::Row>> {
    let ws = solver::workspace_root();
    let (preset, source) = preset::load_preset(&a.preset, ws.as_deref()).unwrap_or_else(|e| bad_input(e));
    let ov = Overrides { reps: Some(1), ..Overrides::default() };
    let campaign = Campaign::resolve(preset, source, &ov).unwrap_or_else(|e| bad_input(e));
    let machine = Machine::detect()?;
    let tmp = TempDir(std::env::temp_dir().join(format!("mpm-bench-work-snapshot-{}", std::process::id())));
    let opts = ExecOptions { out_root: tmp.0.clone(), quiet: true, fresh: true, ..Default::default() };
    let interrupted = schedule::install_interrupt_handler();
    let summary = if a.mock {
        let solvers: Vec<Solver> =
            campaign.opts.iter().map(|&opt| Solver { opt, path: "mock".into(), sha256: "mock".into() }).collect();
        schedule::execute(&campaign, &machine, &solvers, &mut MockRunner::default(), &opts, &interrupted)?
    } else {
        let solvers = solver::prepare_solvers(&campaign.opts, !a.no_build, false)?;
        let mut r = ProcessRunner::new(interrupted.clone());
        schedule::execute(&campaign, &machine, &solvers, &mut r, &opts, &interrupted)?
    };
    read_rows(&summary.dir)
}

/// A folder removed when dropped.
struct TempDir(PathBuf);

impl Drop for TempDir {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}
