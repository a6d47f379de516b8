//! Rows of older CSV schemas, converted into today's [`Row`]:
//!
//! * schemas 1-5 (before the run spec): read with the flat row type they were written with
//!   ([`LegacyRow`]) and converted ([`LegacyRow::into_row`]): their configuration becomes a
//!   planned run with the solver spec those harnesses asked for (the physics then was the
//!   spec's defaults; the impact's models are the [`impact_variant`]s), their measurements
//!   the summary's figures they recorded. Old rows carry no steady-state stage times
//!   (`steady_*` read empty);
//! * schemas 6-7 (the run spec's columns, the measurements under the harness's own names):
//!   their header renamed to the summary's keys ([`v7_header_as_current`]) and each record
//!   completed ([`v7_as_current`]), then read as this schema's.

use super::record::{HostColumns, Outcome, Placement, Row, RowId, Status};
use crate::campaign::plan::matrix::PlannedRun;
use crate::campaign::plan::memory::impact_variant;
use crate::machine::placement::PinPolicy;
use anyhow::{anyhow, Context, Result};
use mpm_core::{GridMode, Strategy, Substage};
use mpm_spec::scenario::{ImpactSpec, TaylorSpec};
use mpm_spec::spec::Budget;
use mpm_spec::summary::{
    Balance, Communication, EndReason, Figures, ImpactFigures, Memory, PatchCounts, Physics, Progress, ScenarioFigures,
    Size, StageSeconds, TaylorFigures, Timing,
};
use mpm_spec::{OptLevel, RunSpec, Scenario};
use serde::{Deserialize, Serialize};

/// Columns added since schema 1; older files lack them and still read (as empty / false;
/// `ranks` as 1 and `threads_per_rank` as `threads`).
pub const ADDED_SINCE_V1: [&str; 28] = [
    // schema 2
    "worker_busy_s",
    "load_imbalance",
    // schema 3
    "host_load1_before",
    "host_load1_after",
    "host_others_running_before",
    "host_others_running_after",
    "host_cpus_busy_before",
    "host_cpus_busy_after",
    "host_steal_frac",
    "calib_spin_ratio",
    "calib_copy_ratio",
    "host_noisy",
    "host_noise",
    "dd_work_imbalance",
    // schema 4
    "ranks",
    "threads_per_rank",
    "launcher",
    "rank_cpus",
    "rank_particles",
    "rank_busy_imbalance",
    "migrated_particles",
    "comm_s_per_step",
    "comm_frac",
    "comm_bytes_per_step",
    "comm_messages_per_step",
    "peak_rss_sum_bytes",
    // schema 5
    "wait_s_per_step",
    "wait_frac",
];

/// Columns added in schema 9: a schema-8 file lacks them and reads them as empty.
pub const ADDED_IN_V9: [&str; 2] = ["inject_step_slowdown", "injected_step_s"];

/// Columns added in schema 10: a schema-8 or 9 file lacks them and reads them as empty.
pub const ADDED_IN_V10: [&str; 2] = ["cpu_quota", "physical_cores"];

/// A row of CSV schemas 1-5 (field order is their column order).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct LegacyRow {
    // ---- identity ----
    /// [`SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// Campaign id (folder name).
    pub campaign_id: String,
    /// Unique id of the run within the campaign: configuration key plus attempt number.
    pub run_id: String,
    /// Time the run ended (RFC 3339, UTC).
    pub timestamp: String,
    /// Git commit of the harness' workspace (`unknown` outside a repository).
    pub git_commit: String,
    /// Whether the work tree had uncommitted changes.
    pub git_dirty: bool,
    /// Machine fingerprint id (see `manifest`).
    pub machine_id: String,
    /// SHA-256 (first 16 hex digits) of the solver binary that ran.
    pub binary_sha256: String,
    /// Seed of the shuffled run order of the session that ran this row.
    pub seed: u64,
    /// Position of the run in that session's order (0-based).
    pub order_index: usize,

    // ---- configuration ----
    /// Scenario (`taylor`).
    pub scenario: String,
    /// Model number (1-4).
    pub model: u32,
    /// Particles.
    pub particles: Option<u64>,
    /// Grid cells (initial grid).
    pub cells: Option<u64>,
    /// Grid nodes (initial grid).
    pub nodes: Option<u64>,
    /// Mean number of grid nodes over the steps (differs from `nodes` on the adaptive grid).
    pub mean_nodes: Option<f64>,
    /// `fixed` or `adaptive`.
    pub grid_mode: String,
    /// `serial`, `ae` (array expansion) or `dd` (domain decomposition).
    pub strategy: Strategy,
    /// `o3` or `o0` (the Cargo profile of the solver binary).
    pub opt_level: String,
    /// Worker threads of the whole run: ranks x threads per rank (at one rank, the process's
    /// threads). Oversubscription and the host-noise rule count these against the cores.
    pub threads: usize,
    /// MPI ranks (1: one process started directly). Since schema 4.
    #[serde(default = "one")]
    pub ranks: usize,
    /// Worker threads of each rank (the solver's `--threads`). Since schema 4 (read as
    /// `threads` from older files).
    #[serde(default)]
    pub threads_per_rank: usize,
    /// The launcher command of a run with several ranks (empty at one rank). Since schema 4.
    #[serde(default)]
    pub launcher: String,
    /// Pinning policy label (`close`, `spread`, `none`, or a CPU list).
    pub pin_policy: String,
    /// CPU requested for each worker (space-separated; empty when not pinned). With several
    /// ranks: the CPU set handed to the launcher as its affinity mask, ascending; rank r's
    /// workers are asked to take its r-th slice of `threads_per_rank` CPUs.
    pub requested_cpus: String,
    /// CPU each worker observed itself on (space-separated); with several ranks every
    /// rank's workers, rank by rank.
    pub observed_cpus: String,
    /// With several ranks: each rank's observed CPUs, ranks separated by `|` (`"0|1"`).
    /// Since schema 4.
    #[serde(default)]
    pub rank_cpus: String,
    /// More threads than usable cores (time sharing: not a scaling point).
    pub oversubscribed: bool,
    /// Repetition index (0-based).
    pub rep: u32,
    /// Warm-up steps excluded from the steady-state figure.
    pub warmup_steps: u64,
    /// Step limit of the run, if it had one.
    pub step_limit: Option<u64>,
    /// Simulated end time of the run, if it had one (s).
    pub end_time_s: Option<f64>,
    /// Steps taken.
    pub steps: Option<u64>,
    /// Simulated time reached (s).
    pub sim_time_s: Option<f64>,
    /// Why the run stopped: `end_time` or `step_limit`.
    pub end_reason: String,
    /// First time step (s).
    pub dt_first_s: Option<f64>,

    // ---- measurements ----
    /// Solver's wall time of the time loop (s).
    pub wall_s: Option<f64>,
    /// Wall time of the child process as the harness saw it, set-up included (s).
    pub process_wall_s: Option<f64>,
    /// Grid-node stage (paper Eqs. 1-6), s.
    pub grid_stage_s: Option<f64>,
    /// Particle stage (paper Eqs. 7-15), s.
    pub particle_stage_s: Option<f64>,
    /// Sub-stage: adaptive grid re-fit / DD re-cut (s).
    pub sub_grid_fit_s: Option<f64>,
    /// Sub-stage: DD particle binning (s).
    pub sub_binning_s: Option<f64>,
    /// Sub-stage: P2G scatter of mass, momentum, force (s).
    pub sub_scatter_s: Option<f64>,
    /// Sub-stage: assembly of per-thread copies / sub-grids (s).
    pub sub_assembly_s: Option<f64>,
    /// Sub-stage: nodal update and boundary conditions (s).
    pub sub_grid_update_s: Option<f64>,
    /// Sub-stage: G2P gather of nodal accelerations (s).
    pub sub_gather_s: Option<f64>,
    /// Sub-stage: MUSL re-map scatter (s).
    pub sub_remap_scatter_s: Option<f64>,
    /// Sub-stage: MUSL re-map assembly (s).
    pub sub_remap_assembly_s: Option<f64>,
    /// Sub-stage: positions, strains, stress update (s).
    pub sub_stress_update_s: Option<f64>,
    /// Steady-state wall time per step, warm-up excluded (s).
    pub steady_s_per_step: Option<f64>,
    /// Wall time per particle per step (ns).
    pub ns_per_particle_step: Option<f64>,
    /// Particle-steps per second.
    pub particle_steps_per_s: Option<f64>,
    /// Steady-state busy seconds of each worker in its shares of the parallel phases
    /// (space-separated, worker order; empty for the serial strategy). Since schema 2.
    #[serde(default)]
    pub worker_busy_s: String,
    /// Largest worker busy time over the mean (1 = balanced; well above 1 on a
    /// non-oversubscribed run: a worker's CPU was slowed from outside the run). Since schema 2.
    #[serde(default)]
    pub load_imbalance: Option<f64>,
    /// DD and balanced DD: the most particles in a patch over the mean per patch, averaged
    /// over the run's steps (the summary's `dd_patch_particles.imbalance_mean`; a property
    /// of the cuts, not of the machine). Since schema 3.
    #[serde(default)]
    pub dd_work_imbalance: Option<f64>,
    /// Peak resident memory of the solver process (VmHWM read by the solver at its exit),
    /// bytes; with several ranks rank 0's (rows of solvers before the figures were measured
    /// across the ranks include rank 0's gathering every particle).
    pub peak_rss_bytes: Option<u64>,
    /// Peak resident memory summed over the ranks (each rank's VmHWM at its exit; in rows of
    /// older solvers at the end of its time steps); equal to `peak_rss_bytes` at one rank.
    /// Since schema 4.
    #[serde(default)]
    pub peak_rss_sum_bytes: Option<u64>,
    /// With several ranks: each rank's particles at the end (space-separated, rank order).
    /// Since schema 4.
    #[serde(default)]
    pub rank_particles: String,
    /// With several ranks: the largest rank busy time over the mean (1 = balanced). Since
    /// schema 4.
    #[serde(default)]
    pub rank_busy_imbalance: Option<f64>,
    /// With several ranks: particles that moved to another rank over the run, all ranks.
    /// Since schema 4.
    #[serde(default)]
    pub migrated_particles: Option<u64>,
    /// With several ranks: seconds in the exchange per step (packing, messages, reductions),
    /// of the rank that spent the most (the maximum over ranks), over all steps taken
    /// (warm-up included). 0 at one rank. Since schema 5 the communication alone (the runs
    /// use `--split-wait`, and the waiting is in `wait_s_per_step`); in schema-4 rows, whose
    /// `wait_s_per_step` is empty, it includes waiting for the other ranks. Since schema 4.
    #[serde(default)]
    pub comm_s_per_step: Option<f64>,
    /// That rank's exchange seconds over the run's wall time (with or without the waiting,
    /// as `comm_s_per_step`). Since schema 4.
    #[serde(default)]
    pub comm_frac: Option<f64>,
    /// With several ranks: seconds per step spent waiting for other ranks at the barrier in
    /// front of each exchange operation (`mpm run --split-wait`, the ranks'
    /// `exchange.wait_seconds`), of the rank that waited the most (the maximum over ranks,
    /// like `comm_s_per_step`, taken on its own: the two may come from different ranks), over
    /// all steps taken. Load imbalance or a CPU taken by another process, not the cost of
    /// the exchange. Empty at one rank (no other rank to wait for), when a rank did not
    /// report it, and in rows before schema 5 (not measured). Since schema 5.
    #[serde(default)]
    pub wait_s_per_step: Option<f64>,
    /// That rank's waiting over the run's wall time. Since schema 5.
    #[serde(default)]
    pub wait_frac: Option<f64>,
    /// Bytes sent per step, summed over the ranks: halo sums, migration and reductions.
    /// Since schema 4.
    #[serde(default)]
    pub comm_bytes_per_step: Option<f64>,
    /// Messages (point-to-point and collective calls) per step, summed over the ranks.
    /// Since schema 4.
    #[serde(default)]
    pub comm_messages_per_step: Option<f64>,
    /// The memory guard's estimate for this run, bytes.
    pub mem_estimate_bytes: u64,
    /// Exit code of the solver process (empty when it did not run or died by a signal).
    pub exit_code: Option<i32>,

    // ---- physics checksums ----
    /// Initial kinetic energy (J).
    pub kinetic_energy_initial_j: Option<f64>,
    /// Final kinetic energy (J).
    pub kinetic_energy_j: Option<f64>,
    /// Final internal energy (J).
    pub internal_energy_j: Option<f64>,
    /// Taylor bar: initial length (m).
    pub initial_length_m: Option<f64>,
    /// Taylor bar: final length (m).
    pub final_length_m: Option<f64>,
    /// Taylor bar: impact-face diameter (m).
    pub face_diameter_m: Option<f64>,
    /// Impact: debris-cloud leading edge beyond the plate's rear face (m).
    pub cloud_front_m: Option<f64>,
    /// Impact: debris-cloud width normal to the flight direction (m).
    pub cloud_width_m: Option<f64>,
    /// Failed particles at the end.
    pub failed_particles: Option<u64>,

    // ---- host load (since schema 3; see `machine::load` for the rule) ----
    /// 1-minute load average just before the run.
    #[serde(default)]
    pub host_load1_before: Option<f64>,
    /// 1-minute load average just after the run.
    #[serde(default)]
    pub host_load1_after: Option<f64>,
    /// Other runnable tasks in a quiet window just before the run (median of samples).
    #[serde(default)]
    pub host_others_running_before: Option<u32>,
    /// Other runnable tasks in a quiet window just after the run.
    #[serde(default)]
    pub host_others_running_after: Option<u32>,
    /// Busy fraction of the run's CPUs (all CPUs when not pinned) with other work in the
    /// window before the run.
    #[serde(default)]
    pub host_cpus_busy_before: Option<f64>,
    /// The same in the window after the run.
    #[serde(default)]
    pub host_cpus_busy_after: Option<f64>,
    /// Fraction of the CPU time stolen by the hypervisor during the run.
    #[serde(default)]
    pub host_steal_frac: Option<f64>,
    /// The spin calibration last taken before the run over the session start's.
    #[serde(default)]
    pub calib_spin_ratio: Option<f64>,
    /// The memory-copy calibration over the session start's.
    #[serde(default)]
    pub calib_copy_ratio: Option<f64>,
    /// The host was busy around the run: left out of claims and regress unless
    /// `--include-noisy`, grey in figures.
    #[serde(default)]
    pub host_noisy: bool,
    /// Why the row is `host_noisy` (empty when it is not).
    #[serde(default)]
    pub host_noise: String,

    // ---- status ----
    /// `ok`, `skipped`, `failed` or `invalid`.
    pub status: Status,
    /// Why a row is not `ok` (empty when it is).
    pub reason: String,
}

fn one() -> usize {
    1
}

/// A space-separated CPU cell as a list.
fn cpus(s: &str) -> Vec<usize> {
    s.split_whitespace().filter_map(|t| t.parse().ok()).collect()
}

impl LegacyRow {
    /// Threads of each rank: `threads_per_rank`, or `threads` for rows written before
    /// schema 4 (one process).
    pub fn per_rank_threads(&self) -> usize {
        if self.threads_per_rank == 0 {
            self.threads / self.ranks.max(1)
        } else {
            self.threads_per_rank
        }
    }

    /// The run this row planned, as today's harness would plan it.
    fn planned(&self) -> Result<PlannedRun> {
        let scenario = match self.scenario.as_str() {
            "impact" => {
                let (spacing_m, cell_m) =
                    impact_variant(self.model).ok_or_else(|| anyhow!("unknown impact model {}", self.model))?;
                Scenario::Impact(ImpactSpec { spacing_m, cell_m, ..ImpactSpec::default() })
            }
            _ => Scenario::Taylor(TaylorSpec::model(u8::try_from(self.model).unwrap_or(0))),
        };
        let mut spec = RunSpec::new(scenario).map_err(|e| anyhow!("{e}"))?;
        spec.strategy = self.strategy;
        spec.threads = self.per_rank_threads().max(1);
        spec.ranks = self.ranks.max(1);
        spec.grid = if self.grid_mode.is_empty() {
            GridMode::Fixed
        } else {
            self.grid_mode.parse().map_err(|e: String| anyhow!(e))?
        };
        spec.budget = Budget { steps: self.step_limit, end_time_s: self.end_time_s, warmup: Some(self.warmup_steps) };
        spec.split_wait = spec.ranks > 1 && self.schema_version >= 5;
        let pin: PinPolicy = self.pin_policy.parse().with_context(|| format!("pin policy '{}'", self.pin_policy))?;
        let opt: OptLevel = self.opt_level.parse().map_err(|e: String| anyhow!(e))?;
        Ok(PlannedRun {
            spec,
            model: self.model,
            opt,
            pin,
            launcher: (self.ranks > 1 && !self.launcher.is_empty()).then(|| self.launcher.clone()),
            rep: self.rep,
        })
    }

    /// Today's row of this old one.
    pub fn into_row(self) -> Result<Row> {
        let run = self.planned()?;
        let measured = self.figures(&run);
        Ok(Row {
            id: RowId {
                schema_version: self.schema_version,
                campaign_id: self.campaign_id,
                run_id: self.run_id,
                run_key: run.key().0,
                timestamp: self.timestamp,
                git_commit: self.git_commit,
                git_dirty: self.git_dirty,
                machine_id: self.machine_id,
                node: String::new(),
                job_id: String::new(),
                binary_sha256: self.binary_sha256,
                seed: self.seed,
                order_index: self.order_index,
            },
            run,
            placement: Placement {
                requested_cpus: cpus(&self.requested_cpus),
                observed_cpus: cpus(&self.observed_cpus),
                rank_cpus: if self.rank_cpus.is_empty() {
                    Vec::new()
                } else {
                    self.rank_cpus.split('|').map(cpus).collect()
                },
                oversubscribed: self.oversubscribed,
                physical_cores: None,
            },
            measured,
            host: HostColumns {
                host_load1_before: self.host_load1_before,
                host_load1_after: self.host_load1_after,
                host_others_running_before: self.host_others_running_before,
                host_others_running_after: self.host_others_running_after,
                host_cpus_busy_before: self.host_cpus_busy_before,
                host_cpus_busy_after: self.host_cpus_busy_after,
                host_steal_frac: self.host_steal_frac,
                calib_spin_ratio: self.calib_spin_ratio,
                calib_copy_ratio: self.calib_copy_ratio,
                host_noisy: self.host_noisy,
                host_noise: self.host_noise,
            },
            outcome: Outcome {
                status: self.status,
                reason: self.reason,
                exit_code: self.exit_code,
                process_wall_s: self.process_wall_s,
                mem_estimate_bytes: self.mem_estimate_bytes,
                lost_compute_s: None,
            },
        })
    }

    /// The figures this row recorded (none for a run skipped or failed before it was timed);
    /// the figures these schemas did not record read as their defaults (the steady-state
    /// stage times as not measured).
    fn figures(&self, run: &PlannedRun) -> Option<Figures> {
        if self.wall_s.is_none() && matches!(self.status, Status::Skipped | Status::Failed) {
            return None;
        }
        let wall_s = self.wall_s.unwrap_or(0.0);
        let worker_busy_s: Vec<f64> = self.worker_busy_s.split_whitespace().filter_map(|t| t.parse().ok()).collect();
        Some(Figures {
            size: Size {
                particles: self.particles.unwrap_or(0) as usize,
                cells: self.cells.unwrap_or(0) as usize,
                nodes: self.nodes.unwrap_or(0) as usize,
                mean_nodes: self.mean_nodes.or(self.nodes.map(|n| n as f64)).unwrap_or(0.0),
                ..Size::default()
            },
            progress: Progress {
                steps: self.steps.unwrap_or(0),
                sim_time: self.sim_time_s.unwrap_or(0.0),
                dt_first: self.dt_first_s.unwrap_or(0.0),
                end_reason: if self.end_reason == "end_time" { EndReason::EndTime } else { EndReason::StepLimit },
                ..Progress::default()
            },
            timing: Timing {
                wall_s,
                grid_stage_s: self.grid_stage_s.unwrap_or(0.0),
                particle_stage_s: self.particle_stage_s.unwrap_or(0.0),
                substages: self.substages(),
                steady_s_per_step: self.steady_s_per_step,
                ns_per_particle_step: self.ns_per_particle_step,
                particle_steps_per_s: self.particle_steps_per_s,
                ..Timing::default()
            },
            balance: Balance {
                worker_busy_s: (!worker_busy_s.is_empty()).then_some(worker_busy_s),
                load_imbalance: self.load_imbalance,
                dd_patch_particles: self
                    .dd_work_imbalance
                    .map(|imbalance_mean| PatchCounts { imbalance_mean, ..PatchCounts::default() }),
                ..Balance::default()
            },
            memory: Memory {
                peak_rss_bytes: self.peak_rss_bytes,
                peak_rss_sum_bytes: self.peak_rss_sum_bytes,
                ..Memory::default()
            },
            physics: Physics {
                kinetic_energy_initial: self.kinetic_energy_initial_j.unwrap_or(0.0),
                kinetic_energy: self.kinetic_energy_j.unwrap_or(0.0),
                internal_energy: self.internal_energy_j.unwrap_or(0.0),
                failed_particles: self.failed_particles.unwrap_or(0) as usize,
                ..Physics::default()
            },
            communication: Communication {
                rank_particles: self.rank_particles.split_whitespace().filter_map(|t| t.parse().ok()).collect(),
                rank_busy_imbalance: self.rank_busy_imbalance,
                migrated_particles: self.migrated_particles,
                comm_s_per_step: self.comm_s_per_step,
                comm_frac: self.comm_frac,
                wait_s_per_step: self.wait_s_per_step,
                wait_frac: self.wait_frac,
                comm_bytes_per_step: self.comm_bytes_per_step,
                comm_messages_per_step: self.comm_messages_per_step,
            },
            scenario: self.scenario_figures(run),
            ..Figures::default()
        })
    }

    /// The sub-stage seconds this row recorded (`sub_<stage>_s`).
    fn substages(&self) -> StageSeconds {
        let sub = [
            (Substage::GridFit, self.sub_grid_fit_s),
            (Substage::Binning, self.sub_binning_s),
            (Substage::Scatter, self.sub_scatter_s),
            (Substage::Assembly, self.sub_assembly_s),
            (Substage::GridUpdate, self.sub_grid_update_s),
            (Substage::Gather, self.sub_gather_s),
            (Substage::RemapScatter, self.sub_remap_scatter_s),
            (Substage::RemapAssembly, self.sub_remap_assembly_s),
            (Substage::StressUpdate, self.sub_stress_update_s),
        ];
        StageSeconds(sub.into_iter().filter_map(|(k, v)| v.map(|v| (k, v))).collect())
    }

    /// The scenario's figures these schemas recorded: the bar's lengths, the cloud's front
    /// and width.
    fn scenario_figures(&self, run: &PlannedRun) -> ScenarioFigures {
        match ScenarioFigures::empty(run.spec.scenario.kind()) {
            ScenarioFigures::Taylor(_) => ScenarioFigures::Taylor(TaylorFigures {
                initial_length_m: self.initial_length_m,
                final_length_m: self.final_length_m,
                face_diameter_m: self.face_diameter_m,
                ..TaylorFigures::default()
            }),
            ScenarioFigures::Impact(_) => ScenarioFigures::Impact(ImpactFigures {
                cloud_front_m: self.cloud_front_m,
                cloud_width_m: self.cloud_width_m,
                ..ImpactFigures::default()
            }),
            other => other,
        }
    }
}

/// Check the header `have` of a schema 1-5 CSV (`path`, for the message): every column of
/// schema 5 but those added since schema 1.
pub fn check_legacy_header(have: &[String], path: &std::path::Path) -> Result<()> {
    let want = legacy_header();
    let missing: Vec<&str> = want
        .iter()
        .filter(|c| !have.contains(c) && !ADDED_SINCE_V1.contains(&c.as_str()))
        .map(String::as_str)
        .collect();
    if !missing.is_empty() {
        anyhow::bail!(
            "{} is missing column(s) {} of CSV schema 1-5 and is not a later schema either; it was written \
             by another program: move it aside or run with --fresh",
            path.display(),
            missing.join(", ")
        );
    }
    Ok(())
}

/// Today's row of one schema 1-5 record under `headers`.
pub fn parse_legacy_record(headers: &csv::StringRecord, rec: &csv::StringRecord) -> Result<Row> {
    let old: LegacyRow = rec.deserialize(Some(headers)).map_err(|e| anyhow!("{e}"))?;
    old.into_row()
}

/// The header of the last legacy schema (5), in column order.
pub fn legacy_header() -> Vec<String> {
    let mut w = csv::WriterBuilder::new().has_headers(true).from_writer(Vec::new());
    w.serialize(LegacyRow::default()).expect("a default row serialises");
    let bytes = w.into_inner().expect("in-memory writer");
    let mut r = csv::ReaderBuilder::new().has_headers(true).from_reader(bytes.as_slice());
    r.headers().expect("header line").iter().map(str::to_string).collect()
}

/// Schema 6-7 columns whose name changed in schema 8 (the summary's own keys), old -> new.
const RENAMED_V7: [(&str, &str); 24] = [
    ("sim_time_s", "sim_time"),
    ("dt_first_s", "dt_first"),
    ("dd_work_imbalance", "dd_patch_particles.imbalance_mean"),
    ("kinetic_energy_initial_j", "kinetic_energy_initial"),
    ("kinetic_energy_j", "kinetic_energy"),
    ("internal_energy_j", "internal_energy"),
    ("checkpoints_written", "checkpoint.written"),
    ("checkpoint_write_s", "checkpoint.write_s"),
    ("restarts", "checkpoint.restarts"),
    ("restart_setup_s", "checkpoint.restart_setup_s"),
    ("paired_blocks", "measured.paired.blocks"),
    ("paired_block_steps", "paired.block_steps"),
    ("paired_t1_s", "paired.t1_s_per_step"),
    ("paired_tt_s", "paired.tt_s_per_step"),
    ("paired_efficiency", "paired.efficiency"),
    ("paired_t1_grid_stage_s", "paired.reference_grid_stage_s"),
    ("paired_t1_particle_stage_s", "paired.reference_particle_stage_s"),
    ("cpu_share", "noise.workers.cpu_share"),
    ("cpu_share_min", "noise.min_cpu_share"),
    ("involuntary_switches", "noise.workers.involuntary_switches"),
    ("work_serial_bytes", "work.serial_bytes"),
    ("work_bound", "work.efficiency_bound"),
    ("work_balance", "work.balance"),
    ("work_overhead", "work.overhead"),
];

/// Whether a header is of schema 6 or 7: the planned run's columns (`run_key`) without the
/// summary's scenario tag (`scenario`) that schema 8 writes.
pub fn is_v7_header(have: &[String]) -> bool {
    have.iter().any(|c| c == "run_key") && !have.iter().any(|c| c == "scenario")
}

/// A schema 6-7 header as today's: the columns renamed to the summary's keys
/// ([`RENAMED_V7`], `work_bytes.<stage>` to `work.bytes.<stage>`) and the scenario's tag
/// `scenario` added.
pub fn v7_header_as_current(have: &[String]) -> Vec<String> {
    let mut header: Vec<String> = have
        .iter()
        .map(|name| match RENAMED_V7.iter().find(|(old, _)| old == name) {
            Some((_, new)) => new.to_string(),
            None => match name.strip_prefix("work_bytes.") {
                Some(stage) => format!("work.bytes.{stage}"),
                None => name.clone(),
            },
        })
        .collect();
    header.push("scenario".into());
    header
}

/// A schema 6-7 record under `have` as today's, under [`v7_header_as_current`]: the
/// scenario's tag added to a row that measured anything (its wall time), and
/// `checkpoint.restarts` left empty where no checkpoint was written (those schemas wrote 0
/// there).
pub fn v7_as_current(have: &[String], rec: &csv::StringRecord) -> csv::StringRecord {
    let cell = |name: &str| have.iter().position(|c| c == name).and_then(|i| rec.get(i)).unwrap_or("");
    let no_checkpoint = cell("checkpoints_written").is_empty();
    let mut cells: Vec<&str> = have
        .iter()
        .zip(rec.iter())
        .map(|(name, text)| if name == "restarts" && no_checkpoint { "" } else { text })
        .collect();
    cells.push(if cell("wall_s").is_empty() { "" } else { cell("scenario.kind") });
    csv::StringRecord::from(cells)
}
