//! One CSV row per run: [`Row`], made of typed parts, is the single source of the columns.
//!
//! A row is the run as planned ([`PlannedRun`]: the solver's [`mpm_spec::RunSpec`] flattened,
//! with the harness's optimisation level, pinning policy, launcher and repetition), where
//! its workers went ([`Placement`]), what the solver measured ([`Measured`], built from its
//! summary in one place, [`Measured::of`]), the host around it ([`HostColumns`]) and how it
//! ended ([`Outcome`]). The columns are derived from these types ([`super::columns`]): a new
//! solver option or measurement is a new column without any code here. The resume key
//! (`run_key`) is the planned run's hash ([`PlannedRun::key`]), written by the harness from
//! its plan, never re-derived from what the solver wrote back.
//!
//! Rows are appended and flushed (and synced) right after each run, so an interrupted
//! campaign keeps every finished run. Reading back ([`read_rows`]) checks the header first:
//! files of CSV schemas 1-5 are read with their own row type and converted
//! ([`super::legacy`]).
//!
//! A torn last line (power loss, disk full, a kill in the middle of a write: no trailing
//! newline, or fewer fields than the header) is found before the file is parsed
//! ([`complete_len`]). Readers ([`read_rows`], used by every analysis command) warn and read
//! the complete rows; the campaign runner ([`repair_torn_tail`], also in [`CsvLog::open`])
//! moves the torn bytes to `runs.csv.torn-<time>`, says so, and redoes that run.
//!
//! Units are SI (seconds, bytes, joules, metres). Lists are written space-separated
//! (`"0 1"`), lists of lists `|`-separated. Empty cells mean "not measured" (for example
//! every measurement of a skipped row).

use super::columns::Layout;
use super::matrix::PlannedRun;
use crate::machine::load::{HostReading, Probe};
use anyhow::{bail, Context, Result};
use mpm_core::scenario::size::IMPACT_MODELS;
use mpm_core::{GridMode, Strategy, Substage};
use mpm_spec::scenario::{ImpactSpec, PlateSpec, TaylorSpec};
use mpm_spec::summary::{load_imbalance, EndReason, StageSeconds, Summary};
use mpm_spec::{OptLevel, RunSpec, Scenario, ScenarioKind};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
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
pub const SCHEMA_VERSION: u32 = 7;

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
    /// More workers than usable cores (time sharing: not a scaling point), as planned or as
    /// the solver found.
    pub oversubscribed: bool,
}

/// The rates one sub-stage achieved in the steady state (the summary's `roofline`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Rates {
    /// 10^9 bytes per second.
    pub gb_per_s: Option<f64>,
    /// 10^9 flops per second.
    pub gflop_per_s: Option<f64>,
}

/// What the solver measured, from its JSON summary ([`Measured::of`]). Empty for a run
/// that did not finish.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Measured {
    /// Particles.
    pub particles: Option<u64>,
    /// Grid cells (initial grid).
    pub cells: Option<u64>,
    /// Grid nodes (initial grid).
    pub nodes: Option<u64>,
    /// Mean number of stored grid nodes over the steps.
    pub mean_nodes: Option<f64>,
    /// Steps taken.
    pub steps: Option<u64>,
    /// Simulated time reached (s).
    pub sim_time_s: Option<f64>,
    /// Why the run stopped: `end_time` or `step_limit`.
    pub end_reason: Option<EndReason>,
    /// First time step (s).
    pub dt_first_s: Option<f64>,
    /// Solver's wall time of the time loop, warm-up included (s).
    pub wall_s: Option<f64>,
    /// Grid-node stage (paper Eqs. 1-6), all steps (s).
    pub grid_stage_s: Option<f64>,
    /// Particle stage (paper Eqs. 7-15), all steps (s).
    pub particle_stage_s: Option<f64>,
    /// Seconds per sub-stage, all steps.
    #[serde(default)]
    pub substages: StageSeconds,
    /// Steps after the warm-up (the steady state).
    pub steady_steps: Option<u64>,
    /// Wall time of the steps after the warm-up (s).
    pub steady_wall_s: Option<f64>,
    /// Grid-node stage after the warm-up (s); empty in rows before schema 6.
    pub steady_grid_stage_s: Option<f64>,
    /// Particle stage after the warm-up (s); empty in rows before schema 6.
    pub steady_particle_stage_s: Option<f64>,
    /// Seconds per sub-stage after the warm-up; empty in rows before schema 6.
    #[serde(default)]
    pub steady_substages: StageSeconds,
    /// The instruction-set level of the particle kernels (`baseline`, `avx2`). Since schema 6.
    pub simd_level: Option<mpm_core::simd::SimdLevel>,
    /// Per sub-stage, the rates achieved in the steady state (`roofline.<stage>.gb_per_s`,
    /// `.gflop_per_s`; see `mpm_core::roofline` for the bytes and flops counted). Since
    /// schema 6.
    pub roofline: BTreeMap<Substage, Rates>,
    /// Steady-state wall time per step, warm-up excluded (s).
    pub steady_s_per_step: Option<f64>,
    /// Wall time per particle per step (ns).
    pub ns_per_particle_step: Option<f64>,
    /// Particle-steps per second.
    pub particle_steps_per_s: Option<f64>,
    /// Steady-state busy seconds of each worker in its shares of the parallel phases
    /// (worker order; empty for the serial strategy).
    #[serde(default)]
    pub worker_busy_s: Vec<f64>,
    /// Largest worker busy time over the mean (1 = balanced; well above 1 on a
    /// non-oversubscribed run: a worker's CPU was slowed from outside the run).
    pub load_imbalance: Option<f64>,
    /// DD and balanced DD: the most particles in a patch over the mean per patch, averaged
    /// over the run's steps (a property of the cuts, not of the machine).
    pub dd_work_imbalance: Option<f64>,
    /// Peak resident memory of the solver process (VmHWM read by the solver at its exit),
    /// bytes; with several ranks rank 0's.
    pub peak_rss_bytes: Option<u64>,
    /// Peak resident memory summed over the ranks; equal to `peak_rss_bytes` at one rank.
    pub peak_rss_sum_bytes: Option<u64>,
    /// With several ranks: each rank's particles at the end (rank order).
    #[serde(default)]
    pub rank_particles: Vec<u64>,
    /// With several ranks: the largest rank busy time over the mean (1 = balanced).
    pub rank_busy_imbalance: Option<f64>,
    /// With several ranks: particles that moved to another rank over the run, all ranks.
    pub migrated_particles: Option<u64>,
    /// With several ranks: seconds in the exchange per step of the rank that spent the most,
    /// over all steps taken; the communication alone (the waiting is `wait_s_per_step`;
    /// in schema-4 rows it includes the waiting). 0 at one rank.
    pub comm_s_per_step: Option<f64>,
    /// That rank's exchange seconds over the run's wall time.
    pub comm_frac: Option<f64>,
    /// With several ranks: seconds per step waiting for other ranks at the barrier in front
    /// of each exchange operation (`--split-wait`), of the rank that waited the most. Empty
    /// at one rank, when a rank did not report it, and in rows before schema 5.
    pub wait_s_per_step: Option<f64>,
    /// That rank's waiting over the run's wall time.
    pub wait_frac: Option<f64>,
    /// Bytes sent per step, summed over the ranks: halo sums, migration and reductions.
    pub comm_bytes_per_step: Option<f64>,
    /// Messages (point-to-point and collective calls) per step, summed over the ranks.
    pub comm_messages_per_step: Option<f64>,
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
    /// Checkpoints the run wrote, over every process that ran a part of it; empty for a run
    /// without checkpoints. Since schema 7.
    pub checkpoints_written: Option<u64>,
    /// Seconds spent writing them (in none of the timings above).
    pub checkpoint_write_s: Option<f64>,
    /// Times the run was continued from a checkpoint (0: it ran in one go).
    pub restarts: Option<u32>,
    /// Seconds the restarts spent before their first step (in none of the timings above).
    pub restart_setup_s: Option<f64>,
    /// A paired run's timed blocks completed by both solvers (schema 7).
    pub paired_blocks: Option<u64>,
    /// Its steps per block.
    pub paired_block_steps: Option<u64>,
    /// Seconds per step of the one-thread reference solver, per block.
    #[serde(default)]
    pub paired_t1_s: Vec<f64>,
    /// Seconds per step of the `threads`-thread solver, per block.
    #[serde(default)]
    pub paired_tt_s: Vec<f64>,
    /// The process's paired efficiency: the geometric mean of its blocks' `t1 / (T tT)`.
    pub paired_efficiency: Option<f64>,
    /// The reference solver's grid-node stage over its blocks (s).
    pub paired_t1_grid_stage_s: Option<f64>,
    /// The reference solver's particle stage over its blocks (s).
    pub paired_t1_particle_stage_s: Option<f64>,
    /// Each worker's CPU time over the wall time of the steps (1: it ran all the time;
    /// a paired run: over its blocks).
    #[serde(default)]
    pub cpu_share: Vec<f64>,
    /// The smallest `cpu_share`, the paired reference's included.
    pub cpu_share_min: Option<f64>,
    /// Each worker's involuntary context switches over the same span.
    #[serde(default)]
    pub involuntary_switches: Vec<u64>,
    /// Per sub-stage, the bytes each worker's counted work stands for (worker order; see
    /// `mpm_core::work`): deterministic, the same on any host.
    pub work_bytes: BTreeMap<Substage, Vec<u64>>,
    /// `W_1`: the bytes the serial solver moves for the same steps.
    pub work_serial_bytes: Option<u64>,
    /// The parallel efficiency the counted traffic allows, `W_1 / (T max W_w)`.
    pub work_bound: Option<f64>,
    /// `mean W_w / max W_w`.
    pub work_balance: Option<f64>,
    /// `1 - W_1 / sum W_w`: the share of the traffic the strategy adds.
    pub work_overhead: Option<f64>,
    /// Seconds of injected extra work (a test knob: such a row is never a result).
    pub injected_s: Option<f64>,
}

impl Measured {
    /// Everything a row records of a summary, in one place: counts, times (whole run and
    /// steady state), balance, memory, the exchange of runs over several ranks (the rank
    /// that spent the most on each figure, bytes and messages of all ranks, per step), and
    /// the physics checksums.
    pub fn of(s: &Summary) -> Self {
        let mut m = Measured {
            particles: Some(s.particles as u64),
            cells: Some(s.cells as u64),
            nodes: Some(s.nodes as u64),
            mean_nodes: Some(s.mean_nodes),
            steps: Some(s.steps),
            sim_time_s: Some(s.sim_time),
            end_reason: Some(s.end_reason),
            dt_first_s: Some(s.dt_first),
            wall_s: Some(s.wall_s),
            grid_stage_s: Some(s.grid_stage_s),
            particle_stage_s: Some(s.particle_stage_s),
            substages: s.substages.clone(),
            steady_steps: Some(s.steady_steps),
            steady_wall_s: Some(s.steady_wall_s),
            steady_grid_stage_s: Some(s.steady_grid_stage_s),
            steady_particle_stage_s: Some(s.steady_particle_stage_s),
            steady_substages: s.steady_substages.clone(),
            simd_level: s.simd_level,
            roofline: s
                .roofline
                .iter()
                .flatten()
                .map(|(&k, r)| (k, Rates { gb_per_s: r.gb_per_s, gflop_per_s: r.gflop_per_s }))
                .collect(),
            steady_s_per_step: s.steady_s_per_step,
            ns_per_particle_step: s.ns_per_particle_step,
            particle_steps_per_s: s.particle_steps_per_s,
            worker_busy_s: s.worker_busy_s.clone().unwrap_or_default(),
            load_imbalance: s.load_imbalance,
            dd_work_imbalance: s.dd_patch_particles.map(|p| p.imbalance_mean),
            peak_rss_bytes: s.peak_rss_bytes,
            peak_rss_sum_bytes: s.peak_rss_bytes,
            comm_s_per_step: Some(0.0),
            comm_frac: Some(0.0),
            comm_bytes_per_step: Some(0.0),
            comm_messages_per_step: Some(0.0),
            kinetic_energy_initial_j: Some(s.kinetic_energy_initial),
            kinetic_energy_j: Some(s.kinetic_energy),
            internal_energy_j: Some(s.internal_energy),
            initial_length_m: s.initial_length_m,
            final_length_m: s.final_length_m,
            face_diameter_m: s.face_diameter_m,
            cloud_front_m: s.cloud_front_m,
            cloud_width_m: s.cloud_width_m,
            failed_particles: Some(s.failed_particles as u64),
            checkpoints_written: s.checkpoint.as_ref().map(|c| c.written),
            checkpoint_write_s: s.checkpoint.as_ref().map(|c| c.write_s),
            restarts: Some(s.checkpoint.as_ref().map_or(0, |c| c.restarts)),
            restart_setup_s: s.checkpoint.as_ref().map(|c| c.restart_setup_s),
            ..Measured::default()
        };
        m.add_paired_noise_work(s);
        if let Some(ranks) = s.ranks.as_deref().filter(|r| !r.is_empty()) {
            m.rank_particles = ranks.iter().map(|r| r.particles as u64).collect();
            m.rank_busy_imbalance = load_imbalance(&ranks.iter().map(|r| r.busy_s).collect::<Vec<_>>());
            m.migrated_particles = Some(ranks.iter().map(|r| r.migrated).sum());
            m.peak_rss_sum_bytes = ranks.iter().map(|r| r.peak_rss_bytes).sum();
            let steps = s.steps.max(1) as f64;
            let comm_max = ranks.iter().map(|r| r.exchange.seconds).fold(0.0, f64::max);
            m.comm_s_per_step = Some(comm_max / steps);
            m.comm_frac = (s.wall_s > 0.0).then(|| comm_max / s.wall_s);
            // The waiting (--split-wait) aggregates as the communication: its own maximum
            // over ranks; not measured unless every rank reports it.
            let wait_max =
                ranks.iter().map(|r| r.exchange.wait_seconds).try_fold(0.0, |m, w| w.map(|w| f64::max(m, w)));
            m.wait_s_per_step = wait_max.map(|w| w / steps);
            m.wait_frac = wait_max.filter(|_| s.wall_s > 0.0).map(|w| w / s.wall_s);
            let bytes: u64 = ranks
                .iter()
                .map(|r| r.exchange.halo_bytes + r.exchange.migration_bytes + r.exchange.reduction_bytes)
                .sum();
            let messages: u64 = ranks
                .iter()
                .map(|r| r.exchange.halo_messages + r.exchange.migration_messages + r.exchange.reductions)
                .sum();
            m.comm_bytes_per_step = Some(bytes as f64 / steps);
            m.comm_messages_per_step = Some(messages as f64 / steps);
        }
        m
    }
}

impl Measured {
    /// The summary's paired blocks, the workers' CPU time, the work counters and the
    /// injected work (schema 7).
    fn add_paired_noise_work(&mut self, s: &Summary) {
        if let Some(p) = &s.paired {
            self.paired_blocks = Some(p.blocks);
            self.paired_block_steps = Some(p.block_steps);
            self.paired_t1_s = p.t1_s_per_step.clone();
            self.paired_tt_s = p.tt_s_per_step.clone();
            self.paired_efficiency = p.efficiency.is_finite().then_some(p.efficiency);
            self.paired_t1_grid_stage_s = p.reference_steady_substages.grid_stage();
            self.paired_t1_particle_stage_s = p.reference_steady_substages.particle_stage();
        }
        if let Some(n) = &s.noise {
            self.cpu_share = n.workers.iter().map(|w| w.cpu_share).collect();
            self.involuntary_switches = n.workers.iter().map(|w| w.involuntary_switches).collect();
        }
        let reference = s.paired.as_ref().and_then(|p| p.reference_noise.as_ref());
        self.cpu_share_min = s.noise.iter().chain(reference).map(|n| n.min_cpu_share).reduce(f64::min);
        if let Some(w) = &s.work {
            self.work_bytes = w.bytes.clone();
            self.work_serial_bytes = Some(w.serial_bytes);
            self.work_bound = Some(w.efficiency_bound);
            self.work_balance = Some(w.balance);
            self.work_overhead = Some(w.overhead);
        }
        self.injected_s = s.injected_s;
    }
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
    /// What the solver measured.
    pub measured: Measured,
    /// The host around the run.
    pub host: HostColumns,
    /// Status and the process.
    pub outcome: Outcome,
}

/// What identifies a configuration for resuming: two rows with the same key ran the same
/// thing.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RunKey(pub String);

impl Row {
    /// A row of `run` with nothing recorded yet.
    pub fn planned(run: PlannedRun) -> Self {
        Self {
            id: RowId { schema_version: SCHEMA_VERSION, run_key: run.key().0, ..RowId::default() },
            run,
            placement: Placement::default(),
            measured: Measured::default(),
            host: HostColumns::default(),
            outcome: Outcome::default(),
        }
    }

    /// The columns of a row: its parts flattened, the planned run's `outputs` and `cpus`
    /// left out (the solver's outputs are the harness's business; the CPUs are
    /// `requested_cpus`).
    pub fn layout() -> &'static Layout {
        static LAYOUT: OnceLock<Layout> = OnceLock::new();
        LAYOUT.get_or_init(|| {
            Layout::of(&Row::templates(), &[&["outputs"], &["cpus"]]).expect("the row's template has every column")
        })
    }

    /// The CSV header, in column order.
    pub fn header() -> Vec<String> {
        Self::layout().header()
    }

    /// Rows with every optional part present, one per scenario (whose parameters differ):
    /// the columns' names and types.
    fn templates() -> Vec<Row> {
        let scenarios = [
            Scenario::Taylor(TaylorSpec::model(1)),
            Scenario::Impact(ImpactSpec::default()),
            Scenario::Plate(PlateSpec::default()),
        ];
        scenarios
            .into_iter()
            .map(|scenario| {
                let mut spec = RunSpec::new(scenario).expect("the default scenarios build");
                spec.rank_layout = Some([1, 1, 1]);
                spec.budget.steps = Some(1);
                spec.budget.warmup = Some(0);
                spec.paired = Some(mpm_spec::spec::Paired { blocks: 0 });
                spec.inject_slowdown = Some(0.0);
                let run = PlannedRun {
                    spec,
                    model: 1,
                    opt: OptLevel::O3,
                    pin: crate::machine::placement::PinPolicy::CLOSE,
                    launcher: Some("mpirun".into()),
                    rep: 0,
                };
                let all = StageSeconds(Substage::ALL.iter().map(|&s| (s, 0.0)).collect());
                Row {
                    placement: Placement {
                        requested_cpus: vec![0],
                        observed_cpus: vec![0],
                        rank_cpus: vec![vec![0]],
                        oversubscribed: false,
                    },
                    measured: Measured {
                        particles: Some(0),
                        cells: Some(0),
                        nodes: Some(0),
                        mean_nodes: Some(0.0),
                        steps: Some(0),
                        sim_time_s: Some(0.0),
                        end_reason: Some(EndReason::StepLimit),
                        dt_first_s: Some(0.0),
                        wall_s: Some(0.0),
                        grid_stage_s: Some(0.0),
                        particle_stage_s: Some(0.0),
                        substages: all.clone(),
                        steady_steps: Some(0),
                        steady_wall_s: Some(0.0),
                        steady_grid_stage_s: Some(0.0),
                        steady_particle_stage_s: Some(0.0),
                        steady_substages: all,
                        simd_level: Some(mpm_core::simd::SimdLevel::Avx2),
                        roofline: Substage::ALL
                            .iter()
                            .map(|&s| (s, Rates { gb_per_s: Some(0.0), gflop_per_s: Some(0.0) }))
                            .collect(),
                        steady_s_per_step: Some(0.0),
                        ns_per_particle_step: Some(0.0),
                        particle_steps_per_s: Some(0.0),
                        worker_busy_s: vec![0.0],
                        load_imbalance: Some(0.0),
                        dd_work_imbalance: Some(0.0),
                        peak_rss_bytes: Some(0),
                        peak_rss_sum_bytes: Some(0),
                        rank_particles: vec![0],
                        rank_busy_imbalance: Some(0.0),
                        migrated_particles: Some(0),
                        comm_s_per_step: Some(0.0),
                        comm_frac: Some(0.0),
                        wait_s_per_step: Some(0.0),
                        wait_frac: Some(0.0),
                        comm_bytes_per_step: Some(0.0),
                        comm_messages_per_step: Some(0.0),
                        kinetic_energy_initial_j: Some(0.0),
                        kinetic_energy_j: Some(0.0),
                        internal_energy_j: Some(0.0),
                        initial_length_m: Some(0.0),
                        final_length_m: Some(0.0),
                        face_diameter_m: Some(0.0),
                        cloud_front_m: Some(0.0),
                        cloud_width_m: Some(0.0),
                        failed_particles: Some(0),
                        checkpoints_written: Some(0),
                        checkpoint_write_s: Some(0.0),
                        restarts: Some(0),
                        restart_setup_s: Some(0.0),
                        paired_blocks: Some(0),
                        paired_block_steps: Some(0),
                        paired_t1_s: vec![0.0],
                        paired_tt_s: vec![0.0],
                        paired_efficiency: Some(0.0),
                        paired_t1_grid_stage_s: Some(0.0),
                        paired_t1_particle_stage_s: Some(0.0),
                        cpu_share: vec![0.0],
                        cpu_share_min: Some(0.0),
                        involuntary_switches: vec![0],
                        work_bytes: Substage::ALL.iter().map(|&s| (s, vec![0])).collect(),
                        work_serial_bytes: Some(0),
                        work_bound: Some(0.0),
                        work_balance: Some(0.0),
                        work_overhead: Some(0.0),
                        injected_s: Some(0.0),
                    },
                    host: HostColumns {
                        host_load1_before: Some(0.0),
                        host_load1_after: Some(0.0),
                        host_others_running_before: Some(0),
                        host_others_running_after: Some(0),
                        host_cpus_busy_before: Some(0.0),
                        host_cpus_busy_after: Some(0.0),
                        host_steal_frac: Some(0.0),
                        calib_spin_ratio: Some(0.0),
                        calib_copy_ratio: Some(0.0),
                        host_noisy: false,
                        host_noise: String::new(),
                    },
                    outcome: Outcome {
                        status: Status::Ok,
                        reason: String::new(),
                        exit_code: Some(0),
                        process_wall_s: Some(0.0),
                        mem_estimate_bytes: 0,
                        lost_compute_s: Some(0.0),
                    },
                    ..Row::planned(run)
                }
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
        self.is_hybrid() && self.measured.wait_s_per_step.is_none()
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
        let Some(min) = self.measured.cpu_share_min.filter(|&m| m < threshold) else { return };
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

    /// The injected slowdown the row ran with (a test knob), if any.
    pub fn injected(&self) -> Option<f64> {
        self.run.spec.inject_slowdown.filter(|&f| f > 0.0)
    }

    /// Whether the row measured a paired cell (its blocks are in `paired_t1_s`, `paired_tt_s`).
    pub fn is_paired(&self) -> bool {
        !self.measured.paired_t1_s.is_empty() && self.measured.paired_t1_s.len() == self.measured.paired_tt_s.len()
    }

    /// The row's cells, in column order.
    pub fn record(&self) -> Result<Vec<String>> {
        Self::layout().record(self)
    }
}

/// The impact variant number of `spacing` and `cell` (1-4), if it is one.
pub fn impact_model_of(spacing: f64, cell: f64) -> Option<u32> {
    IMPACT_MODELS.iter().position(|&(h, c)| h == spacing && c == cell).map(|i| i as u32 + 1)
}

/// Length in bytes of the complete part of a results CSV: the header and every record that
/// ends in a newline and has as many fields as the header. What follows is a torn tail.
pub fn complete_len(bytes: &[u8]) -> usize {
    let mut len = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    loop {
        let mut r = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(&bytes[..len]);
        let width = match r.headers() {
            Ok(h) => h.len(),
            Err(_) => return len,
        };
        let mut last: Option<(usize, usize)> = None;
        let mut rec = csv::StringRecord::new();
        while let Ok(true) = r.read_record(&mut rec) {
            let start = rec.position().map_or(0, |p| p.byte() as usize);
            last = Some((start, rec.len()));
        }
        match last {
            Some((start, fields)) if fields < width && start < len => len = start,
            _ => return len,
        }
    }
}

/// A line of a results CSV that is not a row (a stray write, a hand edit, a line of another
/// program): set aside like a torn line, its run redone on resume.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Garbage {
    /// Line number in the file (1 = the header).
    pub line: u64,
    /// Why it is not a row.
    pub why: String,
    /// Its bytes, newline included.
    pub bytes: Vec<u8>,
}

/// The rows of a CSV's complete part and its garbage lines.
struct Parsed {
    rows: Vec<Row>,
    garbage: Vec<Garbage>,
    /// Byte ranges of the header and of every good record, in order.
    good: Vec<std::ops::Range<usize>>,
}

/// Read every row of a results CSV, checking the header first (files of schemas 1-5 are
/// converted). A torn last line and garbage lines are left out with a warning (the file is
/// not changed; resuming the campaign moves them aside and redoes their runs).
pub fn read_rows(path: &Path) -> Result<Vec<Row>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot open {}", path.display()))?;
    let good = complete_len(&bytes);
    if good < bytes.len() {
        eprintln!(
            "warning: {} ends in a torn line ({} bytes: an interrupted write); reading the complete rows only \
             (resuming the campaign moves it aside and redoes that run)",
            path.display(),
            bytes.len() - good
        );
    }
    let parsed = parse_rows(&bytes[..good], path)?;
    warn_garbage(path, &parsed.garbage, "resuming the campaign moves them aside and redoes their runs");
    Ok(parsed.rows)
}

fn warn_garbage(path: &Path, garbage: &[Garbage], then: &str) {
    if garbage.is_empty() {
        return;
    }
    let lines: Vec<String> = garbage.iter().map(|g| format!("line {}: {}", g.line, g.why)).collect();
    eprintln!(
        "warning: {} has {} line(s) that are not rows, left out ({then}): {}",
        path.display(),
        garbage.len(),
        lines.join("; ")
    );
}

/// Move garbage lines of `path` (lines that are not rows of its schema) to
/// `<name>.garbage-<UTC time>` beside it and rewrite the file with its rows only; say so on
/// stderr. Returns the new file, if any. Call after [`repair_torn_tail`].
pub fn repair_garbage(path: &Path) -> Result<Option<PathBuf>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let good = complete_len(&bytes);
    let parsed = parse_rows(&bytes[..good], path)?;
    if parsed.garbage.is_empty() {
        return Ok(None);
    }
    let stamp: String = crate::util::now_rfc3339().chars().filter(|c| c.is_ascii_alphanumeric()).collect();
    let name = path.file_name().map_or_else(|| "runs.csv".into(), |n| n.to_string_lossy().into_owned());
    let aside = path.with_file_name(format!("{name}.garbage-{stamp}"));
    let set_aside: Vec<u8> = parsed.garbage.iter().flat_map(|g| g.bytes.iter().copied()).collect();
    mpm_host::atomic::write_atomic(&aside, &set_aside)?;
    let mut kept: Vec<u8> = parsed.good.iter().flat_map(|r| bytes[r.clone()].iter().copied()).collect();
    kept.extend_from_slice(&bytes[good..]);
    mpm_host::atomic::write_atomic(path, &kept)?;
    warn_garbage(path, &parsed.garbage, &format!("moved to {}; their runs will be redone", aside.display()));
    Ok(Some(aside))
}

/// Move a torn tail of `path` (see [`complete_len`]) to `<name>.torn-<UTC time>` beside it
/// and cut the file to its complete rows; say so on stderr. Returns the new file, if any.
pub fn repair_torn_tail(path: &Path) -> Result<Option<PathBuf>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let good = complete_len(&bytes);
    if good == bytes.len() {
        return Ok(None);
    }
    let stamp: String = crate::util::now_rfc3339().chars().filter(|c| c.is_ascii_alphanumeric()).collect();
    let name = path.file_name().map_or_else(|| "runs.csv".into(), |n| n.to_string_lossy().into_owned());
    let aside = path.with_file_name(format!("{name}.torn-{stamp}"));
    mpm_host::atomic::write_atomic(&aside, &bytes[good..])?;
    let f = OpenOptions::new().write(true).open(path).with_context(|| format!("cannot repair {}", path.display()))?;
    f.set_len(good as u64).with_context(|| format!("cannot repair {}", path.display()))?;
    f.sync_all().ok();
    eprintln!(
        "warning: {} ended in a torn line (an interrupted write); moved it to {}; its run will be redone",
        path.display(),
        aside.display()
    );
    Ok(Some(aside))
}

/// The header of a CSV's complete part.
fn file_header(bytes: &[u8], path: &Path) -> Result<Vec<String>> {
    let mut r = csv::ReaderBuilder::new().has_headers(true).from_reader(bytes);
    Ok(r.headers()
        .with_context(|| format!("cannot read the header of {}", path.display()))?
        .iter()
        .map(str::to_string)
        .collect())
}

/// Parse the rows of a CSV's complete part, checking the header first: this schema's
/// columns (in any order, a subset read as absent), or a schema 1-5 file. A record with
/// another number of fields than the header, or whose cells are not a row, is garbage.
fn parse_rows(bytes: &[u8], path: &Path) -> Result<Parsed> {
    let have = file_header(bytes, path)?;
    let legacy = !have.iter().any(|c| c == "run_key");
    if legacy {
        super::legacy::check_legacy_header(&have, path)?;
    } else {
        let want = Row::header();
        if let Some(extra) = have.iter().find(|c| !want.contains(c)) {
            bail!(
                "{} has the column `{extra}`, which this harness (CSV schema {SCHEMA_VERSION}) does not know: it \
                 was written by a newer version; read it with that one, or move it aside",
                path.display()
            );
        }
    }
    let mut r = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(bytes);
    let headers = r.headers().with_context(|| format!("cannot read the header of {}", path.display()))?.clone();
    let mut parsed = Parsed { rows: Vec::new(), garbage: Vec::new(), good: Vec::new() };
    let mut records: Vec<(usize, u64, Result<csv::StringRecord, String>)> = Vec::new();
    let mut rec = csv::StringRecord::new();
    loop {
        let start = r.position().byte() as usize;
        let line = r.position().line();
        match r.read_record(&mut rec) {
            Ok(true) => records.push((start, line, Ok(rec.clone()))),
            Ok(false) => break,
            Err(e) => {
                records.push((start, line, Err(e.to_string())));
                break;
            }
        }
    }
    let header_end = records.first().map_or(bytes.len(), |(s, _, _)| *s);
    parsed.good.push(0..header_end);
    for (i, (start, line, rec)) in records.iter().enumerate() {
        let end = records.get(i + 1).map_or(bytes.len(), |(s, _, _)| *s);
        let row = rec.as_ref().map_err(String::clone).and_then(|rec| {
            if rec.len() != headers.len() {
                return Err(format!("{} fields, the header has {}", rec.len(), headers.len()));
            }
            if legacy {
                super::legacy::parse_legacy_record(&headers, rec).map_err(|e| format!("{e:#}"))
            } else {
                Row::layout().parse::<Row>(&have, rec).map_err(|e| format!("{e:#}"))
            }
        });
        match row {
            Ok(row) => {
                parsed.rows.push(row);
                parsed.good.push(*start..end);
            }
            Err(why) => parsed.garbage.push(Garbage { line: *line, why, bytes: bytes[*start..end].to_vec() }),
        }
    }
    Ok(parsed)
}

/// An append-only CSV log: header written once, every row flushed and synced.
pub struct CsvLog {
    path: PathBuf,
    file: File,
}

impl CsvLog {
    /// Open (creating if needed) `path` for appending. An existing file must carry this
    /// harness' header; a torn last line and garbage lines are moved aside first
    /// ([`repair_torn_tail`], [`repair_garbage`]).
    pub fn open(path: &Path) -> Result<Self> {
        if path.is_file() {
            repair_torn_tail(path)?;
            // Rewrites the file (by a rename): before the handle below is opened.
            repair_garbage(path)?;
        }
        let mut file = OpenOptions::new()
            .read(true)
            .append(true)
            .create(true)
            .open(path)
            .with_context(|| format!("cannot open {} for appending", path.display()))?;
        let mut text = Vec::new();
        file.read_to_end(&mut text).with_context(|| format!("cannot read {}", path.display()))?;
        if text.is_empty() {
            let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
            w.write_record(Row::header())?;
            let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
            file.write_all(&bytes).with_context(|| format!("cannot write {}", path.display()))?;
            file.sync_data().ok();
        } else {
            // Demand this schema's exact header: rows appended under another header would be
            // misread.
            if file_header(&text, path)? != Row::header() {
                bail!(
                    "{} was written by another version of the harness (its columns differ from schema version \
                     {SCHEMA_VERSION}); new rows cannot be appended to it: move it aside, write to another \
                     --out, or run with --fresh",
                    path.display()
                );
            }
        }
        Ok(Self { path: path.to_path_buf(), file })
    }

    /// Append one row and make it durable.
    pub fn append(&mut self, row: &Row) -> Result<()> {
        let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
        w.write_record(row.record()?)?;
        let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
        self.file.write_all(&bytes).with_context(|| format!("cannot append to {}", self.path.display()))?;
        self.file.flush()?;
        self.file.sync_data().ok();
        Ok(())
    }

    /// Path of the log.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::legacy::{legacy_header, LegacyRow, ADDED_SINCE_V1};

    /// A planned Taylor run of `model`, `threads` threads, DD, o3, 10 steps.
    fn row(model: u32, threads: usize) -> Row {
        Row::planned(PlannedRun::taylor(model, Strategy::DomainDecomposition, OptLevel::O3, threads, 10))
    }

    #[test]
    fn header_is_complete_and_rows_round_trip_bit_for_bit() {
        let h = Row::header();
        for col in [
            "run_key",
            "scenario.kind",
            "physics.cfl",
            "budget.steps",
            "requested_cpus",
            "substages.scatter",
            "steady_grid_stage_s",
            "status",
        ] {
            assert!(h.iter().any(|c| c == col), "{col}");
        }
        assert!(!h.iter().any(|c| c.starts_with("outputs") || c == "cpus"), "outputs and cpus are not columns");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let mut log = CsvLog::open(&p).unwrap();
        let mut r = row(2, 4);
        r.run.spec.physics.cfl = 0.1 + 0.2;
        r.run.spec.rank_layout = Some([2, 1, 1]);
        r.placement.requested_cpus = vec![0, 1, 0, 1];
        r.placement.rank_cpus = vec![vec![0, 1], vec![2, 3]];
        r.measured.wall_s = Some(1.0 / 3.0);
        r.measured.substages = StageSeconds([(Substage::Scatter, 0.25)].into_iter().collect());
        r.measured.end_reason = Some(EndReason::EndTime);
        r.outcome.status = Status::Skipped;
        r.outcome.reason = "memory, guard".into();
        log.append(&r).unwrap();
        let mut impact = r.clone();
        impact.run.spec.scenario = Scenario::Impact(ImpactSpec::default());
        log.append(&impact).unwrap();
        drop(log);
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![r, impact]);
        // A torn last line is moved aside on reopen.
        std::fs::OpenOptions::new().append(true).open(&p).unwrap().write_all(b"1,abc,").unwrap();
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row(1, 1)).unwrap();
        assert_eq!(read_rows(&p).unwrap().len(), 3);
        let aside: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with("runs.csv.torn-"))
            .collect();
        assert_eq!(aside.len(), 1);
        assert_eq!(std::fs::read(aside[0].path()).unwrap(), b"1,abc,");
    }

    /// Both kinds of torn tail are found before parsing: no trailing newline, and a line
    /// with fewer fields than the header; readers skip them, the repair moves them aside.
    #[test]
    fn torn_tails_are_found_read_around_and_moved_aside() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row(1, 2)).unwrap();
        log.append(&row(2, 2)).unwrap();
        drop(log);
        let good = std::fs::read(&p).unwrap();
        assert_eq!(complete_len(&good), good.len());
        let line = String::from_utf8(good.clone()).unwrap().lines().last().unwrap().to_string();
        let half = &line[..line.len() / 2];
        for tail in [half.to_string(), format!("{half}\n"), line.clone()] {
            let torn = [good.as_slice(), tail.as_bytes()].concat();
            assert_eq!(complete_len(&torn), good.len(), "{tail:?}");
            std::fs::write(&p, &torn).unwrap();
            assert_eq!(read_rows(&p).unwrap().len(), 2, "the reader reads around {tail:?}");
            assert_eq!(std::fs::read(&p).unwrap(), torn, "reading changes nothing");
            let aside = repair_torn_tail(&p).unwrap().unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), good);
            assert_eq!(std::fs::read(&aside).unwrap(), tail.as_bytes());
            std::fs::remove_file(aside).unwrap();
        }
        assert_eq!(repair_torn_tail(&p).unwrap(), None);
    }

    #[test]
    fn missing_and_unknown_columns_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        std::fs::write(&p, "schema_version,campaign_id\n1,x\n").unwrap();
        let err = format!("{:#}", read_rows(&p).unwrap_err());
        assert!(err.contains("missing column"), "{err}");
        assert!(err.contains("observed_cpus"), "{err}");
        std::fs::write(&p, "schema_version,run_key,from_the_future\n6,k,1\n").unwrap();
        let err = format!("{:#}", read_rows(&p).unwrap_err());
        assert!(err.contains("from_the_future") && err.contains("newer version"), "{err}");
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

    /// `row` as a legacy CSV file (header and one line) without the columns `drop` (none of
    /// the row's cells may hold a comma).
    fn legacy_csv_without(row: &LegacyRow, drop: &[&str]) -> String {
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(row).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let header = legacy_header();
        let idx: Vec<usize> = drop.iter().map(|c| header.iter().position(|h| h == c).unwrap()).collect();
        let keep = |line: &str| {
            line.split(',').enumerate().filter(|(i, _)| !idx.contains(i)).map(|(_, c)| c).collect::<Vec<_>>().join(",")
        };
        text.lines().map(|l| keep(l) + "\n").collect()
    }

    /// A schema-1 file (without the columns added since) still reads: its row converted,
    /// one process, the rest intact. Appending to it is refused.
    #[test]
    fn schema_1_files_still_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let old = LegacyRow {
            schema_version: 1,
            campaign_id: "old".into(),
            model: 2,
            strategy: Strategy::ArrayExpansion,
            opt_level: "o0".into(),
            threads: 2,
            pin_policy: "close".into(),
            grid_mode: "fixed".into(),
            step_limit: Some(20),
            warmup_steps: 2,
            sub_scatter_s: Some(0.5),
            wall_s: Some(1.5),
            ..LegacyRow::default()
        };
        std::fs::write(&p, legacy_csv_without(&old, &ADDED_SINCE_V1)).unwrap();
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows.len(), 1);
        let r = &rows[0];
        assert_eq!(
            (r.id.schema_version, r.model(), r.strategy(), r.opt()),
            (1, 2, Strategy::ArrayExpansion, OptLevel::O0)
        );
        assert_eq!((r.threads(), r.ranks(), r.run.spec.budget.steps), (2, 1, Some(20)));
        assert_eq!(r.measured.wall_s, Some(1.5));
        assert_eq!(r.measured.substages.get(Substage::Scatter), Some(0.5));
        assert_eq!(r.measured.steady_grid_stage_s, None, "not recorded before schema 6");
        assert!(CsvLog::open(&p).is_err(), "appending schema-6 rows to a schema-1 file must be refused");
    }

    /// The same row over two ranks in a schema-4 file (no `wait_*` columns) reads with them
    /// empty and its exchange seconds flagged as including the waiting.
    #[test]
    fn schema_4_rows_have_no_waiting() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let old = LegacyRow {
            schema_version: 4,
            model: 3,
            strategy: Strategy::DomainDecomposition,
            opt_level: "o3".into(),
            pin_policy: "close".into(),
            threads: 2,
            ranks: 2,
            threads_per_rank: 1,
            launcher: "mpirun -n 2".into(),
            comm_frac: Some(0.031),
            ..LegacyRow::default()
        };
        std::fs::write(&p, legacy_csv_without(&old, &["wait_s_per_step", "wait_frac"])).unwrap();
        let rows = read_rows(&p).unwrap();
        let r = &rows[0];
        assert_eq!((r.ranks(), r.threads_per_rank(), r.threads()), (2, 1, 2));
        assert!(r.comm_includes_wait() && r.measured.comm_frac == Some(0.031));
        assert!(!r.run.spec.split_wait, "schema 4 ran without it");
    }

    /// Every campaign folder committed under results/ reads, whatever its schema: every
    /// row converts, the one-process rows and the rows over ranks as they were recorded.
    #[test]
    fn every_committed_campaign_reads() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results");
        let mut found = 0;
        let mut stack = vec![root];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.file_name().is_some_and(|n| n == "runs.csv") {
                    let rows = read_rows(&p).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
                    assert!(!rows.is_empty(), "{}", p.display());
                    assert!(rows.iter().all(|r| r.id.run_key.ends_with(&format!("-r{}", r.run.rep))));
                    found += 1;
                }
            }
        }
        assert!(found >= 5, "found {found} campaigns");
        // Schema 2 (before the host's noise columns existed: read as not noisy).
        let r5 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/d02fbfc20d44/quick_m1-2-3_t1-2_o3_r5/runs.csv");
        let rows = read_rows(&r5).unwrap();
        assert_eq!(rows.len(), 60);
        assert!(rows.iter().all(|r| r.id.schema_version == 2 && !r.host.host_noisy && r.ranks() == 1));
        // The current schema: the reference quick campaign, made at a clean commit.
        let quick = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/54276cbdfe10/quick/runs.csv");
        let rows = read_rows(&quick).unwrap();
        assert_eq!(rows.len(), 210);
        assert!(rows.iter().all(|r| r.id.schema_version == SCHEMA_VERSION && !r.id.git_dirty && r.ranks() == 1));
    }
}
