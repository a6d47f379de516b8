//! The JSON summary of one `mpm run` (the interface between the solver program and the
//! harness, scripts and people; see the spec's "The solver's JSON summary"). `mpm` builds it
//! (`mpm_cli::summary::build`); the harness, scripts and tests read it with this type.
//!
//! One [`Summary`] per run, written only when the run succeeded. All figures are SI
//! (seconds, metres, joules, bytes). Key conventions:
//!
//! * `wall_s` is the wall-clock time of the whole stepping loop (all steps, warm-up
//!   included; output (VTU snapshots, pictures) and the scenario's sampling during the run
//!   (impact history, plate shock front) excluded and reported as `output_s`). `grid_stage_s`,
//!   `particle_stage_s` and `substages` cover the same steps, from the solver's own
//!   stage timers (paper split: grid-node stage Eqs. 1-6, particle stage Eqs. 7-15).
//! * The steady-state figures leave out the first `warmup_steps` steps:
//!   `steady_wall_s`, `steady_grid_stage_s`, `steady_particle_stage_s`, `steady_substages`,
//!   `steady_s_per_step`, `ns_per_particle_step = steady_wall_s / (particles x
//!   steady_steps)` and `particle_steps_per_s` (its inverse, per second). They are `null`
//!   when no step was left after the warm-up (for example `--steps 0`).
//! * `peak_rss_bytes` is the process's own high-water mark `VmHWM` from
//!   `/proc/self/status`, read last (after the final figures and any `--dump-state`); over
//!   several ranks it is rank 0's, and each rank's is in `ranks`, read at the same point.
//! * `particles` counts the whole problem's particles (over every rank), and so do
//!   `failed_particles` and the per-particle-step figures; `model_memory_bytes` is the
//!   writing process's (over several ranks rank 0's part).
//! * The scenario figures below are measured over every rank's particles (the program does
//!   it through `mpm_core`'s collectives) and equal the ones one process computes from the
//!   same state.
//! * Taylor bar lengths (`initial_length_m`, `final_length_m`, `face_diameter_m`) are
//!   measured by [`mpm_core::scenario::taylor::measure`]: the length is the z-extent of the
//!   particle centres plus one layer spacing (half a spacing beyond the end particles at each
//!   end, so exactly `L0 = 25.4 mm` at `t = 0`); the impact-face diameter is taken from
//!   particle centres. `length_convention` says so in the file itself.
//! * Impact figures (`cloud_front_m`, `cloud_front_robust_m`, `cloud_width_m`,
//!   `cloud_width_robust_m`, `hole_diameter_m`, `leading_debris_velocity_m_s`) are measured
//!   by [`mpm_core::scenario::impact::measure`] from particle centres; the robust variants
//!   ignore the outermost 0.1 % of the debris mass (see that module for the definitions).
//!   `cloud_history` samples them with the energies about every microsecond and at the end;
//!   `front_velocity_m_s` is [`mpm_core::scenario::impact::History::front_velocity`], the slope of the robust front over
//!   the last quarter of the run.
//! * Plate impact figures (`shock_speed_m_s`, `shock_pressure_pa`, `particle_velocity_m_s`,
//!   their Rankine-Hugoniot values `rh_*` and relative errors `*_rel_error`) come from
//!   [`mpm_core::scenario::plate::ShockTracker`]; `plate_configuration` says what was run.
//! * `bulk_viscosity` and `energy_rise_limit` are the run's settings; `energy` its energy
//!   bookkeeping ([`EnergyReport`]). Summaries written before these existed read back with
//!   them `null`.
//! * `worker_busy_s` holds, per worker, the steady-state seconds it spent in its own shares
//!   of the parallel phases (AE and DD; `null` for the serial strategy), and
//!   `load_imbalance` their largest over their mean (1 = balanced). Both strategies give
//!   every worker an equal share, so an imbalance well above 1 on a shared machine means a
//!   worker's CPU was slowed from outside the run: read such a run's timing with care.
//! * `provenance` ([`Provenance`]) names the source of the run: the host (CPU vendor,
//!   family, model, stepping, microcode, caches, SMT, hashed machine id, kernel), the rustc,
//!   git commit and dirty flag the binary was built with, and the binary's SHA-256.
//! * `dd_patch_particles` (DD and balanced DD only) holds the fewest, mean and most
//!   particles per patch over every step and the work imbalance (largest patch count over
//!   the mean per patch) averaged over the steps and at its worst ([`PatchCounts`]):
//!   a property of the cuts, not of the machine.
//! * `history` holds about 200 samples `{step, time, kinetic, internal}` evenly spaced in
//!   steps, including step 0 (the initial state) and the last step.
//! * `spec` is the [`RunSpec`] the run ran, resolved (every default filled in, the warm-up
//!   used): `mpm run --spec` of that spec repeats the run. `null` in summaries written
//!   before it existed.
//! * `work` ([`WorkReport`]) holds the deterministic work counters of every worker and
//!   sub-stage ([`mpm_core::work`]) and the efficiency bound they give: the same on any
//!   host. `noise` ([`NoiseReport`]) holds each worker's CPU time against the wall time,
//!   its involuntary context switches and its CPU's steal, and flags a worker that got less
//!   than a threshold share of the wall as CPU time. `paired` ([`PairedReport`]) holds a
//!   paired run's block times (the summary's own times are the `threads`-thread solver's).
//!   `inject_slowdown` and `injected_s` say that a test knob slowed the run on purpose: such
//!   a summary is never a result. All four `null` in older summaries.

use crate::build::OptLevel;
use crate::identity::Provenance;
use crate::scenario::ScenarioKind;
use crate::spec::RunSpec;
use mpm_core::grid::Occupancy;
use mpm_core::scenario::impact::HistorySample;
use mpm_core::{BulkViscosity, GridMode, Simulation, StageTimes, Strategy, Substage};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

/// How the Taylor bar lengths are measured (written into every Taylor summary).
pub const LENGTH_CONVENTION: &str = "length: z-extent of particle centres plus one layer spacing (exactly L0 at t = 0); face diameter: from particle centres";

/// What the plate scenario runs (written into every plate summary).
pub const PLATE_CONFIGURATION: &str = "one lead slab (Table 3, no failure) moving onto a rigid wall at z = 0, in a 2 x 2-cell column with roller side walls (uniaxial strain): the shock runs from the wall into the slab and the particle velocity jump is the impact speed";

/// The energy bookkeeping of a run: energies at the start and the end, and the extremes of
/// the balance [`mpm_core::energy::EnergyBalance`] over the steps.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
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

/// Why the stepping loop stopped.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum EndReason {
    /// The simulated time reached the end time.
    EndTime,
    /// The step limit was reached first (also the value of a summary under construction).
    #[default]
    StepLimit,
}

impl EndReason {
    /// Its JSON (and CSV) name: `end_time`, `step_limit`.
    pub fn name(self) -> &'static str {
        match self {
            EndReason::EndTime => "end_time",
            EndReason::StepLimit => "step_limit",
        }
    }
}

/// One sample of the energy history.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct HistoryPoint {
    /// Step number (0 = initial state).
    pub step: u64,
    /// Simulated time (s).
    pub time: f64,
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Internal energy (J).
    pub internal: f64,
}

/// The equation of state of a run, by the names summaries have always carried.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub enum EosKind {
    /// The Hugoniot-referenced Mie-Grüneisen form (the default).
    #[default]
    #[serde(rename = "mie-gruneisen (hugoniot form)")]
    MieGruneisenHugoniot,
    /// Eq. 18 as printed (a misprint, safe only at small compression).
    #[serde(rename = "mie-gruneisen (paper-printed form)")]
    MieGruneisenPaperPrinted,
    /// Linear (validation only).
    #[serde(rename = "linear")]
    Linear,
}

impl EosKind {
    /// The kind of `eos`.
    pub fn of(eos: &mpm_core::material::Eos) -> Self {
        use mpm_core::material::Eos;
        match eos {
            Eos::MieGruneisen(m) => match m.form {
                mpm_core::MgForm::Hugoniot => EosKind::MieGruneisenHugoniot,
                mpm_core::MgForm::PaperPrinted => EosKind::MieGruneisenPaperPrinted,
            },
            Eos::Linear(_) => EosKind::Linear,
        }
    }

    /// Its name (as in the JSON).
    pub fn name(self) -> &'static str {
        match self {
            EosKind::MieGruneisenHugoniot => "mie-gruneisen (hugoniot form)",
            EosKind::MieGruneisenPaperPrinted => "mie-gruneisen (paper-printed form)",
            EosKind::Linear => "linear",
        }
    }
}

/// The contact condition at the run's rigid wall, `none` without one.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum WallContact {
    /// Only the normal velocity is stopped.
    #[default]
    Frictionless,
    /// Every velocity component is stopped.
    Sticking,
    /// No wall (the impact).
    None,
}

impl WallContact {
    /// The wall of `scenario`.
    pub fn of(scenario: &crate::Scenario) -> Self {
        match scenario {
            crate::Scenario::Taylor(t) => match t.wall {
                crate::scenario::Contact::Frictionless => WallContact::Frictionless,
                crate::scenario::Contact::Sticking => WallContact::Sticking,
            },
            crate::Scenario::Plate(_) => WallContact::Frictionless,
            crate::Scenario::Impact(_) => WallContact::None,
        }
    }

    /// Its name (as in the JSON).
    pub fn name(self) -> &'static str {
        match self {
            WallContact::Frictionless => "frictionless",
            WallContact::Sticking => "sticking",
            WallContact::None => "none",
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
}

impl PairedReport {
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

/// The JSON summary of one run. Field names are an interface (see the module docs): `mpm`
/// writes it, the harness reads it back with this type.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Summary {
    /// With several MPI ranks: one entry per rank, in rank order (rank 0 writes the summary).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ranks: Option<Vec<RankReport>>,
    /// The run as asked for, resolved (see the module docs); `null` in older summaries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spec: Option<RunSpec>,
    /// Scenario: `taylor`, `impact` or `plate`.
    pub scenario: ScenarioKind,
    /// Model number (Taylor bar 1-4; 0 for the impact).
    pub model: u8,
    /// Model label (`Model1` ... `Model4`, `impact-h0.53mm-dx2.12mm`).
    #[serde(default)]
    pub model_name: String,
    /// Scatter strategy, written by its short name: `serial`, `ae`, `dd`, `dd-balanced`,
    /// `colour` or `atomic`.
    pub strategy: Strategy,
    /// Worker threads of the pool.
    pub threads: usize,
    /// Optimisation level of the solver build (`o3`, `o0`).
    pub opt_level: OptLevel,
    /// Cargo profile of the solver build.
    pub profile: String,
    /// Version of the `mpm` program.
    pub mpm_version: String,
    /// Whether debug assertions were compiled in.
    pub debug_assertions: bool,
    /// Target triple of the build.
    pub target: String,
    /// Grid mode: `fixed`, `adaptive` or `sparse`.
    pub grid_mode: GridMode,
    /// Equation of state, `mie-gruneisen (hugoniot form)` or `mie-gruneisen (paper-printed form)`.
    pub eos: EosKind,
    /// Material name.
    pub material: String,
    /// CFL number.
    pub cfl: f64,
    /// Wall condition: `frictionless`, `sticking`, or `none` (the impact has no wall).
    pub wall: WallContact,
    /// Impact speed (m/s).
    pub velocity_m_s: f64,
    /// Particles.
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
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_stored_nodes: Option<usize>,
    /// How many of the last grid's cells, and of its blocks of 8^3 cells, hold a particle
    /// (what a sparse grid would store instead of the box); `null` in older summaries and
    /// when the particles are spread over MPI ranks.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_occupancy: Option<Occupancy>,
    /// Cell size (m).
    pub dx_m: f64,
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
    /// End time (s); `null` for a run limited only by `--steps`.
    pub end_time: Option<f64>,
    /// Step limit; `null` if none.
    pub step_limit: Option<u64>,
    /// Why the run stopped: `end_time` or `step_limit`.
    pub end_reason: EndReason,
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
    /// Grid-node stage after the warm-up (s).
    pub steady_grid_stage_s: f64,
    /// Particle stage after the warm-up (s).
    pub steady_particle_stage_s: f64,
    /// Sub-stages after the warm-up (s).
    pub steady_substages: StageSeconds,
    /// The instruction-set level the particle kernels ran at (`baseline`, `avx2`); `null` in
    /// older summaries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simd_level: Option<mpm_core::simd::SimdLevel>,
    /// Per sub-stage, the steady state's bytes and flops per particle-step and the GB/s and
    /// GFLOP/s it achieved ([`StageRoofline`]); `null` without steady steps and in older
    /// summaries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub roofline: Option<BTreeMap<Substage, StageRoofline>>,
    /// Steady-state wall time per step (s); `null` without steady steps.
    pub steady_s_per_step: Option<f64>,
    /// Steady-state wall time per particle and step (ns); `null` without steady steps.
    pub ns_per_particle_step: Option<f64>,
    /// Steady-state particle-steps per second; `null` without steady steps.
    pub particle_steps_per_s: Option<f64>,
    /// Steady-state seconds each worker spent in its shares of the parallel phases (worker
    /// order); `null` for the serial strategy.
    pub worker_busy_s: Option<Vec<f64>>,
    /// Largest of `worker_busy_s` over their mean (1 = balanced); `null` when serial or
    /// without steady steps.
    pub load_imbalance: Option<f64>,
    /// Peak resident memory of the process, `VmHWM` (bytes); `null` if unreadable.
    pub peak_rss_bytes: Option<u64>,
    /// Bytes held by the model: particles, nodal arrays, scatter buffers, strategy tables.
    pub model_memory_bytes: usize,
    /// CPUs the workers were asked to run on, in worker order (empty when not pinned).
    pub requested_cpus: Vec<usize>,
    /// CPUs the workers were observed on, in worker order (empty when not pinned).
    pub observed_cpus: Vec<usize>,
    /// Each worker's affinity mask as read back by the worker.
    pub worker_affinity: Vec<Vec<usize>>,
    /// Whether the workers were pinned.
    pub pinned: bool,
    /// Pinned runs: whether every worker's mask is exactly its requested CPU and it runs
    /// there (a `false` marks the run invalid); `null` when not pinned.
    pub pinning_verified: Option<bool>,
    /// More workers than available cores (or than distinct pinned CPUs).
    pub oversubscribed: bool,
    /// Cores available to the process.
    pub available_cores: usize,
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
    /// Energy history (about 200 samples, first and last step included).
    pub history: Vec<HistoryPoint>,
    /// Taylor bar length at `t = 0` (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_length_m: Option<f64>,
    /// Taylor bar length at the end (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub final_length_m: Option<f64>,
    /// Taylor bar impact-face diameter at `t = 0` (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_face_diameter_m: Option<f64>,
    /// Taylor bar impact-face diameter at the end (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub face_diameter_m: Option<f64>,
    /// How the lengths above are measured.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_convention: Option<String>,
    /// Impact: distance of the debris cloud's leading edge from the plate's rear face (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cloud_front_m: Option<f64>,
    /// Impact: leading edge ignoring the foremost 0.1 % of the debris mass (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cloud_front_robust_m: Option<f64>,
    /// Impact: largest debris diameter normal to the flight direction (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cloud_width_m: Option<f64>,
    /// Impact: diameter containing 99.9 % of the debris mass (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cloud_width_robust_m: Option<f64>,
    /// Impact: diameter of the hole in the plate (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub hole_diameter_m: Option<f64>,
    /// Impact: the speed at which the robust front moved, the least-squares slope of
    /// `cloud_history`'s robust front over the last quarter of the run (m/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub front_velocity_m_s: Option<f64>,
    /// Impact: debris mass beyond the rear face (kg).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub debris_mass_kg: Option<f64>,
    /// Impact: particle lattice spacing (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub spacing_m: Option<f64>,
    /// DD patch layout `[px, py, pz]` of the last step (DD only; balanced cuts choose it
    /// every step, see `mpm-bench imbalance` for the layouts over a run).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dd_layout: Option<[usize; 3]>,
    /// DD (uniform or balanced cuts) only: particles per patch and the work imbalance over
    /// every step of the run.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dd_patch_particles: Option<PatchCounts>,
    /// Artificial bulk viscosity coefficients `{c1, c2}` (`0, 0`: off).
    #[serde(default)]
    pub bulk_viscosity: Option<BulkViscosity>,
    /// Fraction of the initial total energy by which a rise stops the run; `null` when the
    /// check was off.
    #[serde(default)]
    pub energy_rise_limit: Option<f64>,
    /// Energy bookkeeping.
    #[serde(default)]
    pub energy: Option<EnergyReport>,
    /// Impact: mass-weighted z-velocity of the debris beyond the robust front at the end
    /// (m/s): how fast the leading 0.1 % of the debris moves now.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub leading_debris_velocity_m_s: Option<f64>,
    /// Impact: the cloud's figures and the energies about every microsecond and at the end.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cloud_history: Option<Vec<HistorySample>>,
    /// Plate: what was run ([`PLATE_CONFIGURATION`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plate_configuration: Option<String>,
    /// Plate: slab length (m).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub slab_length_m: Option<f64>,
    /// Plate: measured shock speed relative to the undisturbed slab (m/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_speed_m_s: Option<f64>,
    /// Plate: shocked normal stress `-sigma_zz`, volume average behind the front (Pa).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_pressure_pa: Option<f64>,
    /// Plate: shocked mean pressure `-tr(sigma)/3`, volume average (Pa).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_mean_pressure_pa: Option<f64>,
    /// Plate: particle velocity jump across the shock (m/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub particle_velocity_m_s: Option<f64>,
    /// Plate: Rankine-Hugoniot shock speed `c0 + s u_p` (m/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rh_shock_speed_m_s: Option<f64>,
    /// Plate: Rankine-Hugoniot pressure `rho0 U_s u_p` (Pa).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rh_pressure_pa: Option<f64>,
    /// Plate: Rankine-Hugoniot particle velocity (the impact speed, m/s).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rh_particle_velocity_m_s: Option<f64>,
    /// Plate: `shock_speed_m_s / rh_shock_speed_m_s - 1`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_speed_rel_error: Option<f64>,
    /// Plate: `shock_pressure_pa / rh_pressure_pa - 1`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_pressure_rel_error: Option<f64>,
    /// Plate: `particle_velocity_m_s / rh_particle_velocity_m_s - 1`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub particle_velocity_rel_error: Option<f64>,
    /// Plate: front samples in the shock tracker's path.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_front_samples: Option<usize>,
    /// The program's arguments.
    pub command_line: Vec<String>,
    /// Wall-clock start of the run, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// Where the run came from: host identity and kernel, rustc, git commit and dirty flag,
    /// the binary's SHA-256 (the command line is `command_line`). `null` in summaries
    /// written before it existed.
    #[serde(default)]
    pub provenance: Option<Provenance>,
    /// The deterministic work counters and their efficiency bound ([`WorkReport`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub work: Option<WorkReport>,
    /// Each worker's CPU time against the wall time of the steps ([`NoiseReport`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub noise: Option<NoiseReport>,
    /// A paired run's blocks ([`PairedReport`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paired: Option<PairedReport>,
    /// The injected slowdown this run was asked for (a test knob: never a result).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_slowdown: Option<f64>,
    /// Seconds of injected extra work over the run (the `threads`-thread solver's).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub injected_s: Option<f64>,
    /// Checkpoints written and restarts from them (absent when the run wrote none and was
    /// never continued from one). Their time is in none of the timings above.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checkpoint: Option<CheckpointReport>,
}

/// The checkpoints of a run and its restarts (`mpm resume`), over every process that ran a
/// part of it. Writing checkpoints and setting a restart up take time that `wall_s`, the
/// stage times and the steady-state figures leave out; it is reported here instead.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
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

impl Summary {
    /// The nodes the last step stored when the run used the sparse grid (`None` on a dense
    /// grid, where they are `final_nodes`, and in older summaries).
    pub fn sparse_stored_nodes(&self) -> Option<usize> {
        self.final_stored_nodes.filter(|_| self.grid_mode == GridMode::Sparse)
    }
}

/// One MPI rank of a run split over ranks (`mpirun -n R mpm run ...`).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RankReport {
    /// The rank.
    pub rank: usize,
    /// CPUs its workers were seen on at the end of the run.
    pub cpus: Vec<usize>,
    /// Whether its CPUs are shared with other ranks or threads (more than the launcher gave).
    pub oversubscribed: bool,
    /// Its particles at the end of the run.
    pub particles: usize,
    /// Particles that left it for another rank over the run.
    pub migrated: u64,
    /// Seconds its workers spent in their shares of the parallel phases (0 for serial).
    pub busy_s: f64,
    /// Steps taken.
    pub steps: u64,
    /// Its exchange traffic and time over the run.
    pub exchange: mpm_core::exchange::ExchangeStats,
    /// Its peak resident memory (`VmHWM`, bytes) at the end of the run, after the final
    /// figures and any `--dump-state` (which releases the grid's arrays before rank 0 takes
    /// in every particle); `null` if unreadable.
    #[serde(default)]
    pub peak_rss_bytes: Option<u64>,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_reason_names_are_its_json_names() {
        for r in [EndReason::EndTime, EndReason::StepLimit] {
            assert_eq!(serde_json::to_value(r).unwrap(), r.name());
        }
    }

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
