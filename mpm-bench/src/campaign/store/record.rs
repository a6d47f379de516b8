//! One CSV row per run: [`Row`], made of typed parts, is the single source of the columns.
//!
//! A row is the run as planned ([`PlannedRun`]: the solver's [`mpm_spec::RunSpec`] flattened,
//! with the harness's optimisation level, pinning policy, launcher and repetition), where
//! its workers went ([`Placement`]), what the solver measured (the [`Figures`] of its
//! summary, as it wrote them: every measured figure is declared once, in
//! [`mpm_spec::summary`]), the host around it ([`HostColumns`]) and how it ended
//! ([`Outcome`]). The columns are derived from these types ([`super::columns`], the parts
//! filled from their types by [`super::filled`]): a new solver option or figure is a new
//! column without any code here. The resume key (`run_key`) is the planned run's hash
//! ([`PlannedRun::key`]), written by the harness from its plan, never re-derived from what
//! the solver wrote back. Reading and appending rows is [`super::csv`]'s.
//!
//! Units are SI (seconds, bytes, joules, metres). Lists are written space-separated
//! (`"0 1"`), lists of lists `|`-separated. Empty cells mean "not measured" (for example
//! every measurement of a skipped row).

use super::columns::Layout;
use super::filled::{filled, FillError};
use crate::campaign::plan::matrix::{PlannedRun, RunKey};
use crate::machine::load::{HostReading, Probe};
use anyhow::Result;
use mpm_core::scenario::size::IMPACT_MODELS;
use mpm_core::{GridMode, Strategy};
use mpm_spec::summary::{Figures, PairedReport, ScenarioFigures};
use mpm_spec::{OptLevel, ScenarioKind};
use serde::{Deserialize, Deserializer, Serialize};
use std::sync::OnceLock;

/// Version of the row layout; bump it whenever the columns change in a way old readers
/// would misread. Schemas 1-5 were flat rows (see [`super::legacy`]); schema 6 is the
/// planned run's spec flattened (`scenario.kind`, `physics.cfl`, `budget.steps`, ...), the
/// resume key `run_key`, lists as lists, sub-stages by the solver's names
/// (`substages.scatter`), and the steady-state stage times (`steady_*`). Schema 7 adds the
/// node the run ran on (`node`) and its Slurm job (`job_id`), the checkpoints and restarts
/// (`checkpoints_written`, `checkpoint_write_s`, `restarts`, `restart_setup_s`,
/// `lost_compute_s`), the paired design (`paired.blocks` planned, `paired_*` measured: the
/// blocks' times), the workers' CPU time against the wall (`cpu_share_*`,
/// `involuntary_switches`), the work counters (`work_bytes.<stage>`, `work_*`) and the
/// injected slowdown (`inject_slowdown`, `injected_s`); schema-6 files read with these empty.
/// Schema 8 is the summary's figures flattened, each column named by its key in the JSON
/// summary (`sim_time`, `kinetic_energy`, `work.bytes.<stage>`, `noise.workers.cpu_share`,
/// `checkpoint.restarts`, `measured.paired.blocks`, the scenario's figures beside the tag
/// `scenario`); schema 6-7 files read with their columns renamed
/// ([`super::legacy::v7_as_current`]). Schema 9 adds the injected step slowdown
/// (`inject_step_slowdown`, `injected_step_s`); schema-8 files read with these empty
/// ([`super::legacy::ADDED_IN_V9`]). Schema 10 adds the cgroup's CPU quota of the run
/// (`cpu_quota`, CPUs of time per period) and the physical cores its workers could use
/// (`physical_cores`); schema 8-9 files read with these empty ([`super::legacy::ADDED_IN_V10`]).
pub const SCHEMA_VERSION: u32 = 10;

/// Outcome of one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Ran to its step limit or end time; all checks passed.
    #[default]
    Ok,
    /// Not attempted (e.g. the memory guard); `reason` says why.
    Skipped,
    /// The solver exited non-zero, timed out, or wrote no usable summary.
    Failed,
    /// Ran, but a check failed (e.g. observed CPUs differ from the requested ones).
    Invalid,
}

impl Status {
    /// Lower-case name as written in the CSV.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Skipped => "skipped",
            Status::Failed => "failed",
            Status::Invalid => "invalid",
        }
    }
}

/// What identifies a row: campaign, run, provenance.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct RowId {
    /// [`SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// Campaign id (folder name).
    pub campaign_id: String,
    /// Unique id of the run within the campaign: a readable label, the resume key and the
    /// attempt number.
    pub run_id: String,
    /// The resume key: the hash of the planned run and its repetition ([`PlannedRun::key`]).
    pub run_key: String,
    /// Time the run ended (RFC 3339, UTC).
    pub timestamp: String,
    /// Git commit of the harness' workspace (`unknown` outside a repository).
    pub git_commit: String,
    /// Whether the work tree had uncommitted changes.
    pub git_dirty: bool,
    /// Machine fingerprint id (see `manifest`): of the machine the run ran on (under Slurm,
    /// its node's; the manifest's `nodes` holds that machine's facts).
    pub machine_id: String,
    /// The node the run ran on: its Slurm node name in a Slurm job, else its host name.
    /// Since schema 7.
    pub node: String,
    /// The Slurm job that ran it (empty for a run of a local campaign). Since schema 7.
    pub job_id: String,
    /// SHA-256 (first 16 hex digits) of the solver binary that ran.
    pub binary_sha256: String,
    /// Seed of the shuffled run order of the session that ran this row.
    pub seed: u64,
    /// Position of the run in that session's order (0-based).
    pub order_index: usize,
}

/// Where the run's workers were asked to go and where they were seen.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Placement {
    /// CPU requested for each worker (empty when not pinned). With several ranks: the CPU
    /// set handed to the launcher as its affinity mask, ascending; rank r's workers are
    /// asked to take its r-th slice of `threads` CPUs.
    #[serde(default)]
    pub requested_cpus: Vec<usize>,
    /// CPU each worker observed itself on; with several ranks every rank's workers, rank by
    /// rank.
    #[serde(default)]
    pub observed_cpus: Vec<usize>,
    /// With several ranks: each rank's observed CPUs.
    #[serde(default)]
    pub rank_cpus: Vec<Vec<usize>>,
    /// More workers than usable cores, or a cgroup CPU quota (`cpu_quota`) below the
    /// workers (time sharing: not a scaling point), as planned or as the solver found.
    pub oversubscribed: bool,
    /// The physical cores the workers could use, SMT siblings counted once (since schema
    /// 10; empty before): what a speedup is compared with.
    #[serde(default)]
    pub physical_cores: Option<usize>,
}

/// The host around the run (since schema 3; see `machine::load` for the rule).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct HostColumns {
    /// 1-minute load average just before the run.
    pub host_load1_before: Option<f64>,
    /// 1-minute load average just after the run.
    pub host_load1_after: Option<f64>,
    /// Other runnable tasks in a quiet window just before the run (median of samples).
    pub host_others_running_before: Option<u32>,
    /// Other runnable tasks in a quiet window just after the run.
    pub host_others_running_after: Option<u32>,
    /// Busy fraction of the run's CPUs (all CPUs when not pinned) with other work in the
    /// window before the run.
    pub host_cpus_busy_before: Option<f64>,
    /// The same in the window after the run.
    pub host_cpus_busy_after: Option<f64>,
    /// Fraction of the CPU time stolen by the hypervisor during the run.
    pub host_steal_frac: Option<f64>,
    /// The spin calibration last taken before the run over the session start's.
    pub calib_spin_ratio: Option<f64>,
    /// The memory-copy calibration over the session start's.
    pub calib_copy_ratio: Option<f64>,
    /// The host was busy around the run: left out of claims and regress unless
    /// `--include-noisy`, grey in figures.
    #[serde(default)]
    pub host_noisy: bool,
    /// Why the row is `host_noisy` (empty when it is not).
    #[serde(default)]
    pub host_noise: String,
}

impl HostColumns {
    /// The host reading these columns record.
    pub fn reading(&self) -> HostReading {
        let probe = |load1, others_running, cpus_busy| Probe { load1, others_running, cpus_busy };
        HostReading {
            before: probe(self.host_load1_before, self.host_others_running_before, self.host_cpus_busy_before),
            after: probe(self.host_load1_after, self.host_others_running_after, self.host_cpus_busy_after),
            steal: self.host_steal_frac,
            spin_ratio: self.calib_spin_ratio,
            copy_ratio: self.calib_copy_ratio,
        }
    }

    /// Record `h` and flag the row by the `host_noisy` rule for a run of `workers` workers
    /// on a host of `pus` usable PUs.
    pub fn of(h: &HostReading, workers: usize, pus: usize) -> Self {
        let why = h.noise(workers, pus);
        Self {
            host_load1_before: h.before.load1,
            host_load1_after: h.after.load1,
            host_others_running_before: h.before.others_running,
            host_others_running_after: h.after.others_running,
            host_cpus_busy_before: h.before.cpus_busy,
            host_cpus_busy_after: h.after.cpus_busy,
            host_steal_frac: h.steal,
            calib_spin_ratio: h.spin_ratio,
            calib_copy_ratio: h.copy_ratio,
            host_noisy: why.is_some(),
            host_noise: why.unwrap_or_default(),
        }
    }
}

/// How the run ended, as the harness saw it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Outcome {
    /// `ok`, `skipped`, `failed` or `invalid`.
    pub status: Status,
    /// Why a row is not `ok` (empty when it is).
    #[serde(default)]
    pub reason: String,
    /// Exit code of the solver process (empty when it did not run or died by a signal).
    pub exit_code: Option<i32>,
    /// Wall time of the child process as the harness saw it, set-up included (s).
    pub process_wall_s: Option<f64>,
    /// The memory guard's estimate for this run, bytes.
    #[serde(default)]
    pub mem_estimate_bytes: u64,
    /// Compute time the run has lost to attempts that did not finish (killed, timed out,
    /// interrupted), this one's included: each attempt's time after its last checkpoint,
    /// all of it when it wrote none (s). Empty for a campaign without checkpoints. Since
    /// schema 7.
    pub lost_compute_s: Option<f64>,
}

/// One run of the campaign (one CSV row). Each part is a group of columns.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Row {
    /// Campaign, run and provenance.
    pub id: RowId,
    /// The run as planned: the solver's spec flattened, with the harness's settings.
    pub run: PlannedRun,
    /// Requested and observed CPUs.
    pub placement: Placement,
    /// What the solver measured: its summary's figures, as it wrote them (none for a run
    /// that did not finish).
    #[serde(default, deserialize_with = "figures_or_none")]
    pub measured: Option<Figures>,
    /// The host around the run.
    pub host: HostColumns,
    /// Status and the process.
    pub outcome: Outcome,
}

impl Row {
    /// A row of `run` with nothing recorded yet.
    pub fn planned(run: PlannedRun) -> Self {
        Self {
            id: RowId { schema_version: SCHEMA_VERSION, run_key: run.key().0, ..RowId::default() },
            run,
            placement: Placement::default(),
            measured: None,
            host: HostColumns::default(),
            outcome: Outcome::default(),
        }
    }

    /// The columns of a row: its parts flattened, the planned run's `outputs` and `cpus`
    /// left out (the solver's outputs are the harness's business; the CPUs are
    /// `requested_cpus`), and the summary's records of the run's course (`history`,
    /// `cloud_history`), which stay in its JSON.
    pub fn layout() -> &'static Layout {
        static LAYOUT: OnceLock<Layout> = OnceLock::new();
        LAYOUT.get_or_init(|| {
            let shapes = Row::shapes().expect("every part of a row can be filled");
            Layout::of(&shapes, &[&["outputs"], &["cpus"], &["history"], &["cloud_history"]])
                .expect("the row's shape has every column")
        })
    }

    /// The CSV header, in column order.
    pub fn header() -> Vec<String> {
        Self::layout().header()
    }

    /// Rows with every optional part present, one per scenario: the columns' names and
    /// types. The parts are filled from their types ([`filled`]); the planned runs are the
    /// scenarios' own ([`PlannedRun::shapes`]).
    fn shapes() -> Result<Vec<Row>, FillError> {
        let scenarios =
            [ScenarioFigures::Taylor(filled()?), ScenarioFigures::Impact(filled()?), ScenarioFigures::Plate(filled()?)];
        PlannedRun::shapes()
            .into_iter()
            .zip(scenarios)
            .map(|(run, scenario)| {
                let measured = Figures {
                    size: filled()?,
                    progress: filled()?,
                    timing: filled()?,
                    balance: filled()?,
                    memory: filled()?,
                    physics: filled()?,
                    communication: filled()?,
                    work: filled()?,
                    noise: filled()?,
                    cpu_quota: filled()?,
                    paired: filled()?,
                    checkpoint: filled()?,
                    injected_s: filled()?,
                    injected_step_s: filled()?,
                    scenario,
                };
                Ok(Row {
                    id: filled()?,
                    run,
                    placement: filled()?,
                    measured: Some(measured),
                    host: filled()?,
                    outcome: filled()?,
                })
            })
            .collect()
    }

    /// Resume key of this row's configuration (the planned run's, written by the harness).
    pub fn key(&self) -> RunKey {
        RunKey(self.id.run_key.clone())
    }

    /// The matrix's model number (Taylor Model 1-4, impact variant 1-4).
    pub fn model(&self) -> u32 {
        self.run.model
    }

    /// The scenario.
    pub fn scenario(&self) -> ScenarioKind {
        self.run.spec.scenario.kind()
    }

    /// The strategy.
    pub fn strategy(&self) -> Strategy {
        self.run.spec.strategy
    }

    /// The optimisation level of the solver binary.
    pub fn opt(&self) -> OptLevel {
        self.run.opt
    }

    /// Worker threads of the whole run: ranks x threads per rank (at one rank, the
    /// process's threads). Oversubscription and the host-noise rule count these.
    pub fn threads(&self) -> usize {
        self.run.spec.total_workers()
    }

    /// Worker threads of each rank (the solver's `threads`).
    pub fn threads_per_rank(&self) -> usize {
        self.run.spec.threads
    }

    /// MPI ranks (1: one process).
    pub fn ranks(&self) -> usize {
        self.run.spec.ranks
    }

    /// The grid.
    pub fn grid(&self) -> GridMode {
        self.run.spec.grid
    }

    /// The pinning policy's label (`close`, `spread`, `none`, a CPU list).
    pub fn pin_label(&self) -> String {
        self.run.pin.label()
    }

    /// Whether the run was split over several MPI ranks (kept out of the one-process
    /// analyses: figures 7-14, claims, regress).
    pub fn is_hybrid(&self) -> bool {
        self.ranks() > 1
    }

    /// Whether this row's exchange seconds (`comm_*`) include waiting for the other ranks:
    /// a run over several ranks without the waiting measured apart (rows before schema 5,
    /// or a rank that did not report it).
    pub fn comm_includes_wait(&self) -> bool {
        self.is_hybrid() && self.measured.as_ref().and_then(|f| f.communication.wait_s_per_step).is_none()
    }

    /// Record the host reading `h` and flag the row by the `host_noisy` rule for a host of
    /// `pus` usable PUs (every worker of the run counted).
    pub fn set_host(&mut self, h: &HostReading, pus: usize) {
        self.host = HostColumns::of(h, self.threads(), pus);
    }

    /// Flag the row `host_noisy` when a worker got less than
    /// [`mpm_spec::summary::MIN_CPU_SHARE`] of the wall time as CPU time (the solver's own
    /// measurement of each worker thread), saying which share in `host_noise`. Oversubscribed
    /// runs share their CPUs by design and are not flagged for it.
    pub fn flag_low_cpu_share(&mut self) {
        let threshold = mpm_spec::summary::MIN_CPU_SHARE;
        let Some(min) = self.measured.as_ref().and_then(Figures::cpu_share_min).filter(|&m| m < threshold) else {
            return;
        };
        if self.placement.oversubscribed {
            return;
        }
        let why = format!(
            "a worker got {:.0} % of the wall time as CPU time (below {:.0} %: something else ran on its CPU)",
            100.0 * min,
            100.0 * threshold
        );
        self.host.host_noisy = true;
        self.host.host_noise =
            if self.host.host_noise.is_empty() { why } else { format!("{}; {why}", self.host.host_noise) };
    }

    /// The injected slowdown the row ran with (a test knob: `inject_slowdown` or
    /// `inject_step_slowdown`, the larger), if any.
    pub fn injected(&self) -> Option<f64> {
        let s = &self.run.spec;
        s.inject_slowdown.into_iter().chain(s.inject_step_slowdown).filter(|&f| f > 0.0).reduce(f64::max)
    }

    /// Whether the row measured a paired cell (its blocks are in `paired.t1_s_per_step`,
    /// `paired.tt_s_per_step`).
    pub fn is_paired(&self) -> bool {
        self.paired().is_some_and(|p| !p.t1_s_per_step.is_empty() && p.t1_s_per_step.len() == p.tt_s_per_step.len())
    }

    /// The row's figures to fill in (empty figures of its scenario when it has none yet).
    pub fn measured_mut(&mut self) -> &mut Figures {
        let kind = self.scenario();
        self.measured.get_or_insert_with(|| Figures { scenario: ScenarioFigures::empty(kind), ..Figures::default() })
    }

    /// The paired blocks the row measured, if any.
    pub fn paired(&self) -> Option<&PairedReport> {
        self.measured.as_ref()?.paired.as_ref()
    }

    /// The row's cells, in column order.
    pub fn record(&self) -> Result<Vec<String>> {
        Self::layout().record(self)
    }
}

/// A row's figures: none when the row has no measured cell (a run that did not finish).
fn figures_or_none<'de, D: Deserializer<'de>>(d: D) -> Result<Option<Figures>, D::Error> {
    let v = serde_json::Value::deserialize(d)?;
    if v.is_null() || v.as_object().is_some_and(|m| m.is_empty()) {
        return Ok(None);
    }
    serde_json::from_value(v).map(Some).map_err(serde::de::Error::custom)
}

/// The impact variant number of `spacing` and `cell` (1-4), if it is one.
pub fn impact_model_of(spacing: f64, cell: f64) -> Option<u32> {
    IMPACT_MODELS.iter().position(|&(h, c)| h == spacing && c == cell).map(|i| i as u32 + 1)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::load::Probe;
    use mpm_spec::scenario::ImpactSpec;
    use mpm_spec::Scenario;

    /// A planned Taylor run of `model`, `threads` threads, DD, o3, 10 steps.
    fn row(model: u32, threads: usize) -> Row {
        Row::planned(PlannedRun::taylor(model, Strategy::DomainDecomposition, OptLevel::O3, threads, 10))
    }

    /// The resume key is the planned run's: the same plan gives the same key; any change
    /// of scenario, physics, budget, launcher or repetition another.
    #[test]
    fn keys_follow_the_whole_plan() {
        let a = row(1, 2);
        assert_eq!(a.key(), row(1, 2).key());
        let mut b = a.clone();
        b.run.spec.scenario = Scenario::Impact(ImpactSpec::default());
        let mut c = a.clone();
        c.run.spec.physics.q.c1 = 1.0;
        let mut d = a.clone();
        d.run.spec.budget.warmup = Some(1);
        let mut e = a.clone();
        e.run.launcher = Some("srun".into());
        let mut f = a.clone();
        f.run.rep = 1;
        let keys: std::collections::HashSet<_> =
            [&a, &b, &c, &d, &e, &f].into_iter().map(|r| Row::planned(r.run.clone()).key()).collect();
        assert_eq!(keys.len(), 6);
        // CPUs and outputs are the run's own, not the plan's.
        let mut g = a.clone();
        g.run.spec.cpus = Some(vec![0, 1]);
        g.run.spec.outputs.json = Some("x.json".into());
        assert_eq!(Row::planned(g.run).key(), a.key());
    }

    /// The host-noise rule counts every worker of the run (ranks x threads per rank) against
    /// the PUs: two ranks of one thread leave no CPU free on two PUs.
    #[test]
    fn host_noise_counts_ranks_times_threads() {
        let reading = HostReading {
            before: Probe { load1: None, others_running: Some(1), cpus_busy: Some(0.0) },
            after: Probe { load1: None, others_running: Some(0), cpus_busy: Some(0.0) },
            ..HostReading::default()
        };
        let mut one = row(1, 1);
        one.set_host(&reading, 2);
        assert!(!one.host.host_noisy, "{}", one.host.host_noise);
        let mut two = row(1, 1);
        two.run.spec.ranks = 2;
        two.set_host(&reading, 2);
        assert!(two.host.host_noisy && two.host.host_noise.contains("0 free CPU"), "{}", two.host.host_noise);
    }
}
