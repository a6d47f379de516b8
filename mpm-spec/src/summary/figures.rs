//! What a run measured, grouped: [`Figures`] is the one declaration of every measured
//! figure. In the JSON summary each group's fields are top-level keys (serde `flatten`); the
//! harness's CSV row is these figures flattened the same way (a column per key, nested
//! objects joined with `.`). A new figure is a field of its group here and its computation
//! where `mpm` builds the summary; it becomes a key of the summary and a column of the row
//! with no other change.
//!
//! Every group reads with the fields a file lacks defaulted (summaries of older `mpm`
//! versions, CSV rows of older schemas converted), so a figure added later reads as its
//! default (0, empty, or `null` for an `Option`) from files written before it existed.

use super::reports::load_imbalance;
use super::reports::{CheckpointReport, EnergyReport, NoiseReport, PairedReport, PatchCounts, StageRoofline};
use super::reports::{StageSeconds, WorkReport};
use super::scenario::ScenarioFigures;
use super::{EndReason, HistoryPoint, RankReport};
use mpm_core::grid::Occupancy;
use mpm_core::Substage;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// Every figure of a run, by group. Flattened into the summary (its groups' fields are the
/// summary's keys) and into the harness's CSV row.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Figures {
    /// The problem's size: particles, cells, nodes.
    #[serde(flatten)]
    pub size: Size,
    /// Steps taken, time steps, simulated time and why the loop stopped.
    #[serde(flatten)]
    pub progress: Progress,
    /// Wall-clock and stage times, whole run and steady state, and the rates achieved.
    #[serde(flatten)]
    pub timing: Timing,
    /// How evenly the workers (and DD's patches) shared the work.
    #[serde(flatten)]
    pub balance: Balance,
    /// Peak memory of the process(es) and the model's own bytes.
    #[serde(flatten)]
    pub memory: Memory,
    /// Energies, momentum, failures and their bookkeeping.
    #[serde(flatten)]
    pub physics: Physics,
    /// The exchange between MPI ranks (zero at one rank).
    #[serde(flatten)]
    pub communication: Communication,
    /// The deterministic work counters and their efficiency bound.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub work: Option<WorkReport>,
    /// Each worker's CPU time against the wall time of the steps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseReport>,
    /// The CPU quota of the run's cgroup (cgroup v2 `cpu.max`, v1 `cpu.cfs_quota_us` over
    /// `cpu.cfs_period_us`; the tightest of its cgroup and their ancestors) as CPUs of time
    /// per period, where one is set; absent where none is. A quota below the thread count
    /// shares that time between the workers: the run's timings do not show parallel
    /// scaling (`mpm` warns, the harness flags the run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpu_quota: Option<f64>,
    /// A paired run's blocks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paired: Option<PairedReport>,
    /// Checkpoints written and restarts from them (absent when the run wrote none and was
    /// never continued from one). Their time is in none of the timings.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checkpoint: Option<CheckpointReport>,
    /// Seconds of injected extra work over the run (the `threads`-thread solver's; a test
    /// knob: such a run is never a result).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub injected_s: Option<f64>,
    /// Seconds the injected step slowdown added over the run (this process's, the
    /// `threads`-thread solver's; a test knob: such a run is never a result).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub injected_step_s: Option<f64>,
    /// The scenario's own figures, tagged by the key `scenario` (`taylor`, `impact`,
    /// `plate`).
    #[serde(flatten)]
    pub scenario: ScenarioFigures,
}

/// The problem's size.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Size {
    /// Particles (over every rank).
    pub particles: usize,
    /// Cells of the initial grid.
    pub cells: usize,
    /// Nodes of the initial grid.
    pub nodes: usize,
    /// Mean count of stored nodes over the steps (the initial count if no step was taken):
    /// every node of the grid's box, or on the sparse grid the nodes of its stored blocks.
    pub mean_nodes: f64,
    /// Nodes of the last step's grid (its box).
    pub final_nodes: usize,
    /// Nodes the last step stored: `final_nodes` on a dense grid, the stored blocks' nodes
    /// on the sparse grid (this rank's with several ranks); `null` in older summaries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub final_stored_nodes: Option<usize>,
    /// How many of the last grid's cells, and of its blocks of 8^3 cells, hold a particle
    /// (what a sparse grid would store instead of the box); `null` in older summaries and
    /// when the particles are spread over MPI ranks.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub final_occupancy: Option<Occupancy>,
    /// Cell size (m).
    pub dx_m: f64,
}

/// How far the run got.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Progress {
    /// Steps taken.
    pub steps: u64,
    /// Leading steps excluded from the steady-state figures.
    pub warmup_steps: u64,
    /// Steps in the steady-state figures (`steps - warmup_steps`).
    pub steady_steps: u64,
    /// First time step (s).
    pub dt_first: f64,
    /// The CFL time step after the last step (s).
    pub dt_next: f64,
    /// Simulated time reached (s).
    pub sim_time: f64,
    /// Why the run stopped: `end_time` or `step_limit`.
    pub end_reason: EndReason,
}

/// Wall-clock and stage times (see the summary's module docs for what each covers).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Timing {
    /// Wall time of the whole stepping loop, warm-up included, output excluded (s).
    pub wall_s: f64,
    /// Time spent writing snapshots and pictures and sampling histories (s).
    pub output_s: f64,
    /// Grid-node stage (Eqs. 1-6), all steps (s).
    pub grid_stage_s: f64,
    /// Particle stage (Eqs. 7-15), all steps (s).
    pub particle_stage_s: f64,
    /// Seconds per sub-stage, all steps.
    pub substages: StageSeconds,
    /// Wall time of the steps after the warm-up (s).
    pub steady_wall_s: f64,
    /// Grid-node stage after the warm-up (s); `null` only in CSV rows of schemas before 6,
    /// which did not record it.
    pub steady_grid_stage_s: Option<f64>,
    /// Particle stage after the warm-up (s); `null` as `steady_grid_stage_s`.
    pub steady_particle_stage_s: Option<f64>,
    /// Sub-stages after the warm-up (s).
    pub steady_substages: StageSeconds,
    /// The instruction-set level the particle kernels ran at (`baseline`, `avx2`); `null` in
    /// older summaries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub simd_level: Option<mpm_core::simd::SimdLevel>,
    /// Per sub-stage, the steady state's bytes and flops per particle-step and the GB/s and
    /// GFLOP/s it achieved ([`StageRoofline`]); `null` without steady steps and in older
    /// summaries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub roofline: Option<BTreeMap<Substage, StageRoofline>>,
    /// Steady-state wall time per step (s); `null` without steady steps.
    pub steady_s_per_step: Option<f64>,
    /// Steady-state wall time per particle and step (ns); `null` without steady steps.
    pub ns_per_particle_step: Option<f64>,
    /// Steady-state particle-steps per second; `null` without steady steps.
    pub particle_steps_per_s: Option<f64>,
}

/// How evenly the work was shared.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Balance {
    /// Steady-state seconds each worker spent in its shares of the parallel phases (worker
    /// order); `null` for the serial strategy.
    pub worker_busy_s: Option<Vec<f64>>,
    /// Largest of `worker_busy_s` over their mean (1 = balanced); `null` when serial or
    /// without steady steps.
    pub load_imbalance: Option<f64>,
    /// DD patch layout `[px, py, pz]` of the last step (DD only; balanced cuts choose it
    /// every step, see `mpm-bench imbalance` for the layouts over a run).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dd_layout: Option<[usize; 3]>,
    /// DD (uniform or balanced cuts) only: particles per patch and the work imbalance over
    /// every step of the run.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub dd_patch_particles: Option<PatchCounts>,
}

/// Memory.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Memory {
    /// Peak resident memory of the process, `VmHWM` (bytes); with several ranks rank 0's;
    /// `null` if unreadable.
    pub peak_rss_bytes: Option<u64>,
    /// Peak resident memory summed over the ranks (each rank's `VmHWM`); equal to
    /// `peak_rss_bytes` at one rank; `null` in older summaries or when a rank's is
    /// unreadable.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub peak_rss_sum_bytes: Option<u64>,
    /// Bytes held by the model: particles, nodal arrays, scatter buffers, strategy tables;
    /// of both solvers in a paired run (the `threads`-thread one and its one-thread
    /// reference, both held by the process).
    pub model_memory_bytes: usize,
}

/// Energies, momentum and failures.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Physics {
    /// Kinetic energy at `t = 0` (J).
    pub kinetic_energy_initial: f64,
    /// Internal energy at `t = 0` (J).
    pub internal_energy_initial: f64,
    /// Kinetic energy at the end (J).
    pub kinetic_energy: f64,
    /// Internal energy at the end (J).
    pub internal_energy: f64,
    /// Momentum at `t = 0` (kg m/s).
    pub momentum_initial: [f64; 3],
    /// Momentum at the end (kg m/s).
    pub momentum: [f64; 3],
    /// Failed particles at the end.
    pub failed_particles: usize,
    /// Energy bookkeeping; `null` in older summaries.
    pub energy: Option<EnergyReport>,
    /// Energy history (about 200 samples, first and last step included): a record of the
    /// run's course, not a CSV column.
    pub history: Vec<HistoryPoint>,
}

/// The exchange between MPI ranks, from the ranks' reports: the figure of the rank that
/// spent the most for times, sums over the ranks for traffic. At one rank the exchange
/// figures are 0 and the rank figures empty; all are `null` in older summaries.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Communication {
    /// With several ranks: each rank's particles at the end (rank order).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub rank_particles: Vec<u64>,
    /// With several ranks: the largest rank busy time over the mean (1 = balanced).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rank_busy_imbalance: Option<f64>,
    /// With several ranks: particles that moved to another rank over the run, all ranks.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub migrated_particles: Option<u64>,
    /// Seconds in the exchange per step of the rank that spent the most, over all steps
    /// taken; the communication alone (the waiting is `wait_s_per_step`; in CSV rows of
    /// schema 4 it includes the waiting). 0 at one rank.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub comm_s_per_step: Option<f64>,
    /// That rank's exchange seconds over the run's wall time.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub comm_frac: Option<f64>,
    /// With several ranks: seconds per step waiting for other ranks at the barrier in front
    /// of each exchange operation (`--split-wait`), of the rank that waited the most.
    /// `null` at one rank and when a rank did not report it.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wait_s_per_step: Option<f64>,
    /// That rank's waiting over the run's wall time.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub wait_frac: Option<f64>,
    /// Bytes sent per step, summed over the ranks: halo sums, migration and reductions.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub comm_bytes_per_step: Option<f64>,
    /// Messages (point-to-point and collective calls) per step, summed over the ranks.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub comm_messages_per_step: Option<f64>,
}

impl Communication {
    /// The exchange figures of a run from its ranks' reports (none at one rank: exchange 0):
    /// for times the rank that spent the most, for traffic the sums over the ranks, per step
    /// of the `steps` taken, fractions of `wall_s`.
    pub fn of(ranks: &[RankReport], steps: u64, wall_s: f64) -> Self {
        if ranks.is_empty() {
            return Self {
                comm_s_per_step: Some(0.0),
                comm_frac: Some(0.0),
                comm_bytes_per_step: Some(0.0),
                comm_messages_per_step: Some(0.0),
                ..Self::default()
            };
        }
        let steps = steps.max(1) as f64;
        let comm_max = ranks.iter().map(|r| r.exchange.seconds).fold(0.0, f64::max);
        // The waiting (--split-wait) aggregates as the communication: its own maximum over
        // ranks; not measured unless every rank reports it.
        let wait_max = ranks.iter().map(|r| r.exchange.wait_seconds).try_fold(0.0, |m, w| w.map(|w| f64::max(m, w)));
        let e = |r: &RankReport| r.exchange;
        let bytes: u64 = ranks.iter().map(|r| e(r).halo_bytes + e(r).migration_bytes + e(r).reduction_bytes).sum();
        let messages: u64 = ranks.iter().map(|r| e(r).halo_messages + e(r).migration_messages + e(r).reductions).sum();
        Self {
            rank_particles: ranks.iter().map(|r| r.particles as u64).collect(),
            rank_busy_imbalance: load_imbalance(&ranks.iter().map(|r| r.busy_s).collect::<Vec<_>>()),
            migrated_particles: Some(ranks.iter().map(|r| r.migrated).sum()),
            comm_s_per_step: Some(comm_max / steps),
            comm_frac: (wall_s > 0.0).then(|| comm_max / wall_s),
            wait_s_per_step: wait_max.map(|w| w / steps),
            wait_frac: wait_max.filter(|_| wall_s > 0.0).map(|w| w / wall_s),
            comm_bytes_per_step: Some(bytes as f64 / steps),
            comm_messages_per_step: Some(messages as f64 / steps),
        }
    }
}

impl Figures {
    /// The smallest share of the wall time a worker got as CPU time, the paired reference
    /// worker's included (`None` when not measured).
    pub fn cpu_share_min(&self) -> Option<f64> {
        let reference = self.paired.as_ref().and_then(|p| p.reference_noise.as_ref());
        self.noise.iter().chain(reference).map(|n| n.min_cpu_share).reduce(f64::min)
    }
}
