//! The reports a summary holds: the energy bookkeeping, seconds and rates per sub-stage,
//! the work counters, the workers' CPU time, a paired run's blocks, the DD patch counts and
//! the checkpoints. Every report reads with the fields a file lacks defaulted (summaries of
//! older `mpm` versions, CSV rows of older schemas).

use mpm_core::{Simulation, StageTimes, Substage};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// The energy bookkeeping of a run: energies at the start and the end, and the extremes of
/// the balance [`mpm_core::energy::EnergyBalance`] over the steps.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct EnergyReport {
    /// Kinetic energy at `t = 0` (J).
    pub initial_kinetic_j: f64,
    /// Internal energy at `t = 0` (J).
    pub initial_internal_j: f64,
    /// Total energy at `t = 0` (J).
    pub initial_total_j: f64,
    /// Kinetic energy at the end (J).
    pub final_kinetic_j: f64,
    /// Internal energy at the end (J).
    pub final_internal_j: f64,
    /// Total energy at the end (J).
    pub final_total_j: f64,
    /// Work of the body forces (J).
    pub body_force_work_j: f64,
    /// Largest relative rise of the total energy less the body forces' work over its initial
    /// value, after any step (0 if it never rose).
    pub max_rise: f64,
    /// The step of the largest rise (0: none).
    pub max_rise_step: u64,
    /// Largest relative fall (0 if it never fell).
    pub max_fall: f64,
    /// The step of the largest fall (0: none).
    pub max_fall_step: u64,
    /// Particles with negative internal energy at the end.
    pub negative_internal_final: u64,
    /// Most particles with negative internal energy after any one step.
    pub negative_internal_max: u64,
    /// Steps after which some particle had negative internal energy.
    pub negative_internal_steps: u64,
    /// The first such step.
    pub first_negative_internal_step: Option<u64>,
    /// Times a failed particle's negative internal energy was set to zero
    /// (`mpm_core::material::failure`, "Internal energy").
    #[serde(default)]
    pub failed_energy_floors: u64,
    /// The energy that added (J), booked as a known source in the balance.
    #[serde(default)]
    pub failed_energy_floor_j: f64,
}

impl EnergyReport {
    /// The bookkeeping of `sim` now.
    pub fn of(sim: &Simulation) -> Self {
        let (init, last, b) = (sim.initial(), sim.diagnostics(), sim.energy_balance());
        Self {
            initial_kinetic_j: init.kinetic,
            initial_internal_j: init.internal,
            initial_total_j: init.total(),
            final_kinetic_j: last.kinetic,
            final_internal_j: last.internal,
            final_total_j: last.total(),
            body_force_work_j: b.external_work,
            max_rise: b.max_rise,
            max_rise_step: b.max_rise_step,
            max_fall: b.max_fall,
            max_fall_step: b.max_fall_step,
            negative_internal_final: last.negative_internal,
            negative_internal_max: b.negative_internal_max,
            negative_internal_steps: b.negative_internal_steps,
            first_negative_internal_step: b.first_negative_internal_step,
            failed_energy_floors: b.failed_floors,
            failed_energy_floor_j: b.failed_floor_energy,
        }
    }
}

/// Seconds per sub-stage, a JSON object keyed by the sub-stage's name, in execution order
/// (`grid_fit`, `binning`, `scatter`, `assembly`, `grid_update`, `gather`, `remap_scatter`,
/// `remap_assembly`, `stress_update`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct StageSeconds(pub BTreeMap<Substage, f64>);

impl StageSeconds {
    /// From the solver's timers (every [`Substage`]).
    pub fn from_times(t: &StageTimes) -> Self {
        Self(Substage::ALL.iter().map(|&s| (s, t.get(s))).collect())
    }

    /// Seconds of sub-stage `s`, if recorded.
    pub fn get(&self, s: Substage) -> Option<f64> {
        self.0.get(&s).copied()
    }

    /// The grid-node stage's seconds (its sub-stages summed), if any was recorded.
    pub fn grid_stage(&self) -> Option<f64> {
        self.sum(true)
    }

    /// The particle stage's seconds, if any was recorded.
    pub fn particle_stage(&self) -> Option<f64> {
        self.sum(false)
    }

    fn sum(&self, grid: bool) -> Option<f64> {
        let mut it = self.0.iter().filter(|(s, _)| s.is_grid_stage() == grid).map(|(_, v)| *v).peekable();
        it.peek()?;
        Some(it.sum())
    }
}

/// How close one sub-stage ran to the machine's limits in the steady state
/// ([`mpm_core::roofline`]): what it must move and compute per particle-step, counted from
/// the code, and the rates it achieved.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct StageRoofline {
    /// Bytes moved per particle-step (node terms weighted by the run's nodes per particle).
    pub bytes_per_particle_step: f64,
    /// Floating-point operations per particle-step.
    pub flops_per_particle_step: f64,
    /// Nanoseconds per particle-step.
    pub ns_per_particle_step: f64,
    /// Achieved bandwidth, 10^9 bytes per second (`null`: no time, or nothing moved).
    pub gb_per_s: Option<f64>,
    /// Achieved rate, 10^9 flops per second.
    pub gflop_per_s: Option<f64>,
}

/// The work counters of a run ([`mpm_core::work`]) and the efficiency bound they give.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct WorkReport {
    /// What each worker did in each sub-stage, over every step (worker order).
    pub workers: Vec<BTreeMap<Substage, mpm_core::Work>>,
    /// Per sub-stage, the bytes each worker's work stands for (worker order).
    pub bytes: BTreeMap<Substage, Vec<u64>>,
    /// `W_w`: each worker's bytes over every sub-stage.
    pub worker_bytes: Vec<u64>,
    /// `W_1`: the bytes the serial solver moves for the same steps.
    pub serial_bytes: u64,
    /// `mean W_w / max W_w`.
    pub balance: f64,
    /// `1 - W_1 / sum W_w`: the share of the traffic the strategy adds.
    pub overhead: f64,
    /// `W_1 / (T max W_w)`: the parallel efficiency the traffic allows on any host.
    pub efficiency_bound: f64,
}

impl WorkReport {
    /// The report of `counts` (`None` when nothing was counted, e.g. no step).
    pub fn of(counts: &mpm_core::WorkCounts) -> Option<Self> {
        let b = counts.bound()?;
        Some(Self {
            workers: counts.workers.clone(),
            bytes: counts.bytes_by_stage(),
            worker_bytes: b.worker_bytes,
            serial_bytes: b.serial_bytes,
            balance: b.balance,
            overhead: b.overhead,
            efficiency_bound: b.efficiency_bound,
        })
    }
}

/// What one worker thread got of the wall time.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct WorkerUsage {
    /// CPU time of the thread (user and system) over the measured span (s).
    pub cpu_s: f64,
    /// `cpu_s` over the span's wall time: 1 for a worker that ran all the time.
    pub cpu_share: f64,
    /// Times the thread was switched out against its will (preempted).
    pub involuntary_switches: u64,
    /// Times it gave up its CPU (waiting, yielding).
    pub voluntary_switches: u64,
    /// Fraction of its CPU's time the hypervisor stole over the span (pinned workers only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steal_frac: Option<f64>,
}

/// Noise that can be seen: what each worker got of the wall time of the steps measured.
/// Every worker is busy or spinning during a step, so a worker with much less CPU time than
/// wall time was kept off its CPU by something else (another process, the hypervisor).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct NoiseReport {
    /// Wall time of the span measured (s): the stepping loop, or a paired run's blocks of
    /// this solver.
    pub wall_s: f64,
    /// One entry per worker, in worker order.
    pub workers: Vec<WorkerUsage>,
    /// The smallest `cpu_share`.
    pub min_cpu_share: f64,
    /// The share below which a run is flagged.
    pub threshold: f64,
    /// Some worker got less than `threshold` of the wall as CPU time.
    pub low_cpu_share: bool,
}

impl NoiseReport {
    /// The report of `workers` over `wall_s` with the flag at `threshold`.
    pub fn new(wall_s: f64, workers: Vec<WorkerUsage>, threshold: f64) -> Self {
        let min = workers.iter().map(|w| w.cpu_share).fold(f64::INFINITY, f64::min);
        let min_cpu_share = if min.is_finite() { min } else { 1.0 };
        Self { wall_s, workers, min_cpu_share, threshold, low_cpu_share: min_cpu_share < threshold }
    }

    /// Why the run is flagged, in words (`None` when it is not).
    pub fn why(&self) -> Option<String> {
        self.low_cpu_share.then(|| {
            let (w, u) = self
                .workers
                .iter()
                .enumerate()
                .min_by(|a, b| a.1.cpu_share.total_cmp(&b.1.cpu_share))
                .expect("a flagged report has workers");
            format!(
                "worker {w} got {:.0} % of the wall time as CPU time (below {:.0} %; {} involuntary context switches)",
                100.0 * u.cpu_share,
                100.0 * self.threshold,
                u.involuntary_switches
            )
        })
    }
}

/// The share of the wall time below which a worker's CPU time flags a run.
pub const MIN_CPU_SHARE: f64 = 0.9;

/// A paired run's measurement ([`crate::spec::Paired`]): per block, the seconds per step of
/// the one-thread solver and of the `threads`-thread solver, and their ratio.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PairedReport {
    /// Threads of the reference solver (1).
    pub reference_threads: usize,
    /// Timed blocks completed by both solvers.
    pub blocks: u64,
    /// Steps per block.
    pub block_steps: u64,
    /// CPU the reference solver's worker was observed on (empty when not pinned).
    pub reference_cpus: Vec<usize>,
    /// Seconds per step of the reference solver, per block.
    pub t1_s_per_step: Vec<f64>,
    /// Seconds per step of the `threads`-thread solver, per block.
    pub tt_s_per_step: Vec<f64>,
    /// Which ran first in each block: `true` for the reference.
    pub reference_first: Vec<bool>,
    /// `t1 / (T tT)` of each block.
    pub block_efficiency: Vec<f64>,
    /// The process's paired efficiency: the geometric mean of the blocks' (`exp` of their
    /// mean logarithm).
    pub efficiency: f64,
    /// The reference solver's sub-stage seconds over its blocks (its warm-up left out).
    pub reference_steady_substages: StageSeconds,
    /// The reference worker's CPU time against the wall time of its blocks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_noise: Option<NoiseReport>,
    /// Largest position difference between the two solvers at the end, over the bar's or
    /// grid's size (round-off only: they run the same steps).
    pub max_position_difference: f64,
    /// The reference solver's grid-node stage over its blocks (s): its
    /// `reference_steady_substages` of that stage summed; `null` in older summaries.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_grid_stage_s: Option<f64>,
    /// The reference solver's particle stage over its blocks (s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_particle_stage_s: Option<f64>,
}

impl PairedReport {
    /// Sum the reference solver's sub-stages into its two stage times.
    pub fn sum_reference_stages(&mut self) {
        self.reference_grid_stage_s = self.reference_steady_substages.grid_stage();
        self.reference_particle_stage_s = self.reference_steady_substages.particle_stage();
    }

    /// The geometric mean of block efficiencies (NaN when there are none).
    pub fn geometric_mean(e: &[f64]) -> f64 {
        (e.iter().map(|x| x.ln()).sum::<f64>() / e.len() as f64).exp()
    }
}

/// Largest over mean of per-worker busy times; `None` when empty or all zero.
pub fn load_imbalance(busy: &[f64]) -> Option<f64> {
    let mean = busy.iter().sum::<f64>() / busy.len() as f64;
    let max = busy.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    (mean > 0.0 && mean.is_finite()).then(|| max / mean)
}

/// Particles per DD patch over a run, and the work imbalance they give (the most particles
/// in a patch over the mean per patch, per step): what balanced cuts improve. Unlike
/// `load_imbalance`, which is measured from busy times, it depends on the particles only.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PatchCounts {
    /// Fewest particles in a patch, over every patch and step.
    pub min: u32,
    /// Mean particles per patch.
    pub mean: f64,
    /// Most particles in a patch, over every patch and step.
    pub max: u32,
    /// Mean over the steps of the step's largest patch count over its mean.
    pub imbalance_mean: f64,
    /// Largest over the steps of the same.
    pub imbalance_max: f64,
}

impl From<&mpm_core::strategy::PatchLoad> for PatchCounts {
    fn from(l: &mpm_core::strategy::PatchLoad) -> Self {
        Self {
            min: l.min,
            mean: l.mean(),
            max: l.max,
            imbalance_mean: l.imbalance_mean(),
            imbalance_max: l.imbalance_max,
        }
    }
}

/// The checkpoints of a run and its restarts (`mpm resume`), over every process that ran a
/// part of it. Writing checkpoints and setting a restart up take time that `wall_s`, the
/// stage times and the steady-state figures leave out; it is reported here instead.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct CheckpointReport {
    /// Checkpoints written over the run.
    pub written: u64,
    /// Seconds spent writing them (rank 0's, each rank writing its own part at the same
    /// time).
    pub write_s: f64,
    /// Bytes of the last checkpoint written, all ranks' files together (0 if none).
    pub last_bytes: u64,
    /// Times the run was continued from a checkpoint.
    pub restarts: u32,
    /// The step each restart continued from, in order.
    #[serde(default)]
    pub restart_steps: Vec<u64>,
    /// Seconds the restarts spent before their first step: starting, reading and checking
    /// the checkpoint, rebuilding the simulation.
    pub restart_setup_s: f64,
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Sub-stages are keyed by the core's enum, written by name in execution order, and the
    /// two stages are their sums.
    #[test]
    fn stage_seconds_round_trip_by_name_in_order() {
        let s = StageSeconds([(Substage::Gather, 2.0), (Substage::Scatter, 1.0)].into_iter().collect());
        let j = serde_json::to_string(&s).unwrap();
        assert_eq!(j, r#"{"scatter":1.0,"gather":2.0}"#);
        let back: StageSeconds = serde_json::from_str(&j).unwrap();
        assert_eq!(back, s);
        assert_eq!((back.grid_stage(), back.particle_stage()), (Some(1.0), Some(2.0)));
        assert!(serde_json::from_str::<StageSeconds>(r#"{"scater":1.0}"#).is_err(), "unknown sub-stage");
    }
}
