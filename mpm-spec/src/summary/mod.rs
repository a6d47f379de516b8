//! The JSON summary of one `mpm run` (the interface between the solver program and the
//! harness, scripts and people; see the spec's "The solver's JSON summary"). `mpm` builds it
//! (`mpm_cli::summary::build`); the harness, scripts and tests read it with this type.
//!
//! The Rust type is grouped, the JSON flat: [`Summary`] holds what the run was (its spec,
//! build, material, pinning: top-level fields) and [`Figures`], every figure it measured in
//! groups ([`figures`]: size, progress, timing, balance, memory, physics, communication,
//! work, noise, paired blocks, checkpoints; [`scenario`]: the scenario's own figures, one
//! variant per scenario). serde's `flatten` writes every group's fields as top-level keys,
//! so the key names below are those of the files `mpm` has always written, and every older
//! summary reads (a key it lacks reads as its default). The harness's CSV row is the same
//! figures flattened the same way.
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
//!   `inject_slowdown` and `injected_s` (the parallel efficiency's knob), and
//!   `inject_step_slowdown` and `injected_step_s` (the time per step's), say that a test
//!   knob slowed the run on purpose: such a summary is never a result. All `null` in older
//!   summaries.

pub mod figures;
pub mod reports;
pub mod scenario;

pub use figures::{Balance, Communication, Figures, Memory, Physics, Progress, Size, Timing};
pub use reports::{
    load_imbalance, CheckpointReport, EnergyReport, NoiseReport, PairedReport, PatchCounts, StageRoofline,
    StageSeconds, WorkReport, WorkerUsage, MIN_CPU_SHARE,
};
pub use scenario::{ImpactFigures, PlateFigures, ScenarioFigures, TaylorFigures};

use crate::build::OptLevel;
use crate::identity::Provenance;
use crate::scenario::ScenarioKind;
use crate::spec::RunSpec;
use mpm_core::{BulkViscosity, GridMode, Strategy};
use serde::{Deserialize, Serialize};

/// How the Taylor bar lengths are measured (written into every Taylor summary).
pub const LENGTH_CONVENTION: &str = "length: z-extent of particle centres plus one layer spacing (exactly L0 at t = 0); face diameter: from particle centres";

/// What the plate scenario runs (written into every plate summary).
pub const PLATE_CONFIGURATION: &str = "one lead slab (Table 3, no failure) moving onto a rigid wall at z = 0, in a 2 x 2-cell column with roller side walls (uniaxial strain): the shock runs from the wall into the slab and the particle velocity jump is the impact speed";

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
    /// Eq. 18 as printed (a misprint, safe only at small compression). Summaries written
    /// before the Hugoniot form existed call it `mie-gruneisen (paper form)`.
    #[serde(rename = "mie-gruneisen (paper-printed form)", alias = "mie-gruneisen (paper form)")]
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
    /// End time (s); `null` for a run limited only by `--steps`.
    pub end_time: Option<f64>,
    /// Step limit; `null` if none.
    pub step_limit: Option<u64>,
    /// Where the workers were asked to run and where they ran.
    #[serde(flatten)]
    pub pinning: Pinning,
    /// Artificial bulk viscosity coefficients `{c1, c2}` (`0, 0`: off).
    #[serde(default)]
    pub bulk_viscosity: Option<BulkViscosity>,
    /// Fraction of the initial total energy by which a rise stops the run; `null` when the
    /// check was off.
    #[serde(default)]
    pub energy_rise_limit: Option<f64>,
    /// Taylor bar: how its lengths are measured ([`LENGTH_CONVENTION`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub length_convention: Option<String>,
    /// Plate: what was run ([`PLATE_CONFIGURATION`]).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plate_configuration: Option<String>,
    /// The program's arguments.
    pub command_line: Vec<String>,
    /// Wall-clock start of the run, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// Where the run came from: host identity and kernel, rustc, git commit and dirty flag,
    /// the binary's SHA-256 (the command line is `command_line`). `null` in summaries
    /// written before it existed.
    #[serde(default)]
    pub provenance: Option<Provenance>,
    /// The injected slowdown this run was asked for (a test knob: never a result).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_slowdown: Option<f64>,
    /// The injected step slowdown this run was asked for (a test knob: never a result).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_step_slowdown: Option<f64>,
    /// Everything the run measured ([`Figures`]), its groups' fields top-level keys.
    #[serde(flatten)]
    pub figures: Figures,
}

/// Where the workers were asked to run and where they ran.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct Pinning {
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
}

impl Summary {
    /// The scenario (the key `scenario`, the tag of the scenario's figures).
    pub fn scenario(&self) -> ScenarioKind {
        self.figures.scenario.kind()
    }

    /// Complete the summary with what is known only when the run is over: every rank's
    /// report (`None` at one rank) and the exchange figures and memory sum they give, the
    /// workers' CPU time, a paired run's blocks (their reference's stage sums added), and
    /// the writing process's peak memory `peak_rss_bytes`, read last.
    pub fn finish(
        &mut self,
        ranks: Option<Vec<RankReport>>,
        noise: Option<NoiseReport>,
        paired: Option<PairedReport>,
        peak_rss_bytes: Option<u64>,
    ) {
        let f = &mut self.figures;
        f.noise = noise;
        f.paired = paired.map(|mut p| {
            p.sum_reference_stages();
            p
        });
        f.memory.peak_rss_bytes = peak_rss_bytes;
        let reports = ranks.as_deref().unwrap_or_default();
        f.communication = Communication::of(reports, f.progress.steps, f.timing.wall_s);
        f.memory.peak_rss_sum_bytes =
            if reports.is_empty() { peak_rss_bytes } else { reports.iter().map(|r| r.peak_rss_bytes).sum() };
        self.ranks = ranks;
    }

    /// The nodes the last step stored when the run used the sparse grid (`None` on a dense
    /// grid, where they are `final_nodes`, and in older summaries).
    pub fn sparse_stored_nodes(&self) -> Option<usize> {
        self.figures.size.final_stored_nodes.filter(|_| self.grid_mode == GridMode::Sparse)
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

    /// The grouped type writes the flat JSON the spec names: every key of "The solver's
    /// JSON summary" is a top-level key (the scenario's figures under their scenario), and
    /// it reads back.
    #[test]
    fn the_json_is_flat_with_the_spec_keys() {
        let spec_keys = "scenario model strategy threads opt_level grid_mode eos particles cells nodes mean_nodes \
             steps dt_first sim_time end_reason wall_s grid_stage_s particle_stage_s substages \
             ns_per_particle_step particle_steps_per_s peak_rss_bytes requested_cpus observed_cpus \
             kinetic_energy_initial kinetic_energy internal_energy";
        let mut s = Summary::default();
        s.figures.timing.ns_per_particle_step = Some(1.0);
        s.figures.timing.particle_steps_per_s = Some(1.0);
        s.figures.memory.peak_rss_bytes = Some(1);
        s.figures.scenario = ScenarioFigures::Taylor(TaylorFigures {
            initial_length_m: Some(1.0),
            final_length_m: Some(1.0),
            face_diameter_m: Some(1.0),
            ..TaylorFigures::default()
        });
        let v = serde_json::to_value(&s).unwrap();
        let keys = v.as_object().unwrap();
        for k in spec_keys.split_whitespace().chain(["initial_length_m", "final_length_m", "face_diameter_m"]) {
            assert!(keys.contains_key(k), "{k}");
        }
        assert_eq!(keys["scenario"], "taylor");
        assert_eq!(serde_json::from_value::<Summary>(v).unwrap(), s);
        let mut i = Summary::default();
        i.figures.scenario = ScenarioFigures::Impact(ImpactFigures {
            cloud_front_m: Some(1.0),
            cloud_front_robust_m: Some(1.0),
            cloud_width_m: Some(1.0),
            cloud_width_robust_m: Some(1.0),
            hole_diameter_m: Some(1.0),
            front_velocity_m_s: Some(1.0),
            ..ImpactFigures::default()
        });
        let v = serde_json::to_value(&i).unwrap();
        for k in ["cloud_front_m", "cloud_front_robust_m", "cloud_width_m", "cloud_width_robust_m", "hole_diameter_m"] {
            assert!(v.get(k).is_some(), "{k}");
        }
        assert_eq!(v["scenario"], "impact");
        assert_eq!(serde_json::from_value::<Summary>(v).unwrap(), i);
    }

    /// The ranks' reports give the exchange figures: particles per rank, memory summed, the
    /// slowest rank's exchange per step, bytes and messages of all ranks per step, and the
    /// waiting of the rank that waited most when every rank measured it (--split-wait).
    /// At one rank the exchange is 0 and the memory sum the process's own.
    #[test]
    fn rank_reports_give_the_exchange_figures() {
        let mut reports: Vec<RankReport> = (0..2).map(|rank| RankReport { rank, ..RankReport::default() }).collect();
        for (i, r) in reports.iter_mut().enumerate() {
            r.particles = 100 + i;
            r.migrated = 2;
            r.busy_s = 1.0 + i as f64;
            r.peak_rss_bytes = Some(1000);
            r.exchange.halo_bytes = 800;
            r.exchange.reduction_bytes = 200;
            r.exchange.halo_messages = 20;
            r.exchange.seconds = 0.1 * (i + 1) as f64;
        }
        let mut s = Summary::default();
        s.figures.progress.steps = 10;
        s.figures.timing.wall_s = 2.0;
        s.finish(Some(reports.clone()), None, None, Some(500));
        let m = &s.figures.communication;
        assert_eq!(m.rank_particles, [100, 101]);
        assert_eq!(m.migrated_particles, Some(4));
        assert_eq!(s.figures.memory.peak_rss_sum_bytes, Some(2000));
        assert_eq!(m.comm_bytes_per_step, Some(200.0));
        assert_eq!(m.comm_messages_per_step, Some(4.0));
        assert!((m.comm_s_per_step.unwrap() - 0.02).abs() < 1e-15);
        assert!((m.comm_frac.unwrap() - 0.1).abs() < 1e-15);
        assert!((m.rank_busy_imbalance.unwrap() - 2.0 / 1.5).abs() < 1e-12);
        assert_eq!((m.wait_s_per_step, m.wait_frac), (None, None), "run without --split-wait");
        // With --split-wait: the waiting of the rank that waited most (rank 0 here, while
        // rank 1 communicated most), apart from the communication.
        for (i, r) in reports.iter_mut().enumerate() {
            r.exchange.wait_seconds = Some(0.3 - 0.1 * i as f64);
        }
        let m = Communication::of(&reports, 10, 2.0);
        assert!((m.wait_s_per_step.unwrap() - 0.03).abs() < 1e-15);
        assert!((m.wait_frac.unwrap() - 0.15).abs() < 1e-15);
        assert!((m.comm_frac.unwrap() - 0.1).abs() < 1e-15, "the communication is unchanged");
        // A rank without it: not measured.
        reports[1].exchange.wait_seconds = None;
        let m = Communication::of(&reports, 10, 2.0);
        assert_eq!((m.wait_s_per_step, m.wait_frac), (None, None));
        // One process: no exchange, the memory its own.
        let mut one = Summary::default();
        one.finish(None, None, None, Some(500));
        let c = &one.figures.communication;
        assert_eq!((c.comm_s_per_step, c.comm_frac, c.comm_bytes_per_step), (Some(0.0), Some(0.0), Some(0.0)));
        assert!(c.rank_particles.is_empty() && c.migrated_particles.is_none() && c.wait_s_per_step.is_none());
        assert_eq!((one.figures.memory.peak_rss_bytes, one.figures.memory.peak_rss_sum_bytes), (Some(500), Some(500)));
    }
}
