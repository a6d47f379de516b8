//! The set-up of a run, written once for a fresh run (`mpm run`) and one continued from a
//! checkpoint (`mpm resume`): check the spec against the machine, reserve the outputs,
//! build the pinned pool, the scenario and the simulation, and what the program carries
//! ([`start`]); then step it ([`go`]). Only the simulation and the carry differ by
//! [`Origin`]: built from the set-up, or taken back from the checkpoint's files.

use crate::checkpointing::{RunLog, Saved};
use crate::machine::{check_progress, place_rank, start_pool, Plan};
use crate::output::Outputs;
use crate::ranks::Ranks;
use crate::solver::{resumed, simulation};
use crate::stepping::{go, record, Carry, Checkpoints, Ready};
use crate::tracking::{bar_figures, Tracking};
use anyhow::Result;
use mpm_cli::summary::{HistoryRecorder, Timing};
use mpm_core::{Exchange, Simulation};
use mpm_host::checkpoint::{Folder, Loaded};
use mpm_host::lock::FolderLock;
use mpm_host::pinning::PinnedPool;
use mpm_spec::scenario::Prepared;
use mpm_spec::summary::CheckpointReport;
use mpm_spec::RunSpec;
use std::time::{Duration, Instant};

/// Where a run starts from.
pub enum Origin {
    /// Its spec, afresh (`mpm run`).
    Fresh(Invocation),
    /// A checkpoint (`mpm resume`).
    Checkpoint(Box<Restart>),
}

/// The command that starts a fresh run, as its summary records it.
pub struct Invocation {
    /// When the command started, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// The command line.
    pub command_line: Vec<String>,
    /// `--force`: run even if the run is expected to take more steps than one that ends
    /// ([`check_progress`]).
    pub force: bool,
}

/// A checkpoint to continue from, read and checked.
pub struct Restart {
    /// This rank's file: its particles and their ids.
    pub loaded: Loaded,
    /// The state it saved besides the particles: the spec, the solver's, the program's.
    pub saved: Saved,
    /// SHA-256 of this binary (the one that wrote the checkpoint).
    pub binary_sha256: String,
    /// When this process started: its set-up until the loop is booked as the restart's.
    pub t0: Instant,
}

impl Origin {
    /// The VTU snapshots already written (a continued run's collection lists them).
    fn snapshots(&self) -> Vec<(u64, f64, String)> {
        match self {
            Origin::Fresh(_) => Vec::new(),
            Origin::Checkpoint(r) => {
                r.saved.program.snapshots.iter().map(|s| (s.step, s.time, s.file.clone())).collect()
            }
        }
    }
}

/// What differs between a fresh run and a continued one: the simulation and the carry,
/// the checkpoints (created when they are), a paired run's reference set-up, a restart's
/// start.
struct Begun {
    sim: Simulation,
    carry: Carry,
    checkpoints: Option<Checkpoints>,
    reference_setup: Option<mpm_core::Setup>,
    restart: Option<Instant>,
}

/// Set up the run of `spec` from `origin` on this process's rank, then step it to its
/// summary ([`go`]). `force`: run even if the memory estimate exceeds what is available.
pub fn start(mut spec: RunSpec, force: bool, origin: Origin, ranks: &mut Ranks) -> Result<()> {
    let lead = ranks.rank() == 0;
    let mut plan = Plan::check(&spec, force)?;
    let _lock = match &origin {
        Origin::Fresh(_) => claim_folder(&spec, lead)?,
        // `mpm resume` holds the folder from before it chose the checkpoint.
        Origin::Checkpoint(_) => None,
    };
    let (cpus, rank_oversubscribed) = place_rank(&spec, &mut plan, ranks)?;
    let mut outputs = Outputs::open(&spec, origin.snapshots(), ranks.rank())?;
    let pool = start_pool(spec.threads, cpus.as_deref())?;
    let bare = matches!(origin, Origin::Checkpoint(_));
    let (prepared, exchange) =
        ranks.build(&spec.scenario, spec.physics.eos, spec.rank_layout, spec.split_wait, bare)?;
    let taylor = matches!(spec.scenario, mpm_spec::Scenario::Taylor(_));
    let model_name = prepared.setup.model.clone();
    let (impact, plate) = (prepared.impact, prepared.plate);
    let begun = match origin {
        Origin::Fresh(invocation) => fresh(&mut spec, prepared, &pool, exchange, invocation, &mut outputs, ranks)?,
        Origin::Checkpoint(restart) => restored(&spec, prepared, &pool, exchange, *restart, ranks)?,
    };
    let Begun { sim, carry, checkpoints, reference_setup, restart } = begun;
    let run = Ready {
        spec,
        plan,
        rank_oversubscribed,
        pool,
        sim,
        outputs,
        carry,
        impact,
        plate,
        taylor,
        model_name,
        checkpoints,
        restart,
        reference_setup,
    };
    go(run, ranks)
}

/// A fresh run's checkpoint folder: rank 0 holds it for the run (refused at once when
/// another process holds it); every rank checks it holds no checkpoint yet.
fn claim_folder(spec: &RunSpec, lead: bool) -> Result<Option<FolderLock>> {
    let Some(c) = &spec.outputs.checkpoint else { return Ok(None) };
    let lock = if lead { Some(Folder::new(&c.dir).lock(Duration::ZERO)?) } else { None };
    mpm_host::checkpoint::refuse_used_folder(&c.dir, &mpm_host::checkpoint::run_key(spec))?;
    Ok(lock)
}

/// A fresh run: the simulation of the set-up, the warm-up resolved into `spec` once the
/// first time step is known, its checkpoints, and the initial state recorded (the energy
/// history's first point, the bar's initial figures, the trackers' first samples, the
/// initial snapshot).
fn fresh(
    spec: &mut RunSpec,
    Prepared { setup, impact, plate }: Prepared,
    pool: &PinnedPool,
    exchange: Option<Box<dyn Exchange>>,
    invocation: Invocation,
    outputs: &mut Outputs,
    ranks: &mut Ranks,
) -> Result<Begun> {
    let taylor = matches!(spec.scenario, mpm_spec::Scenario::Taylor(_));
    // A paired run builds its one-thread reference from the same set-up.
    let reference_setup = spec.paired.map(|_| setup.clone());
    let sim = simulation(spec, setup, pool, exchange)?;
    check_progress(spec, sim.dt_first(), invocation.force)?;
    let (cells, nodes) = (sim.global_geom().num_cells(), sim.global_geom().num_nodes());
    let warmup = spec.budget.warmup.unwrap_or_else(|| spec.default_warmup(sim.dt_first()));
    spec.budget.warmup = Some(warmup);
    let checkpoints = Checkpoints::of(spec, ranks.rank(), mpm_host::identity::this_binary_sha256)?;
    let mut history = HistoryRecorder::new();
    record(&mut history, &sim);
    let initial_taylor = bar_figures(taylor, &sim, ranks.collectives())?;
    let mut tracking = Tracking::new(impact, plate)?;
    tracking.observe(&sim, ranks.collectives())?;
    outputs.initial(&sim)?;
    let log = RunLog {
        cells,
        nodes,
        started_unix_s: invocation.started_unix_s,
        command_line: invocation.command_line,
        timing: Timing { warmup_steps: warmup, ..Timing::default() },
        report: CheckpointReport::default(),
        history,
        initial_taylor,
    };
    Ok(Begun { sim, carry: Carry { log, tracking }, checkpoints, reference_setup, restart: None })
}

/// A run continued from a checkpoint: the simulation and the carry taken back, the restart
/// booked, its checkpoints going on into the same folder. Another strategy or thread count
/// than the checkpoint's starts the steady state afresh.
fn restored(
    spec: &RunSpec,
    Prepared { setup, impact, plate }: Prepared,
    pool: &PinnedPool,
    exchange: Option<Box<dyn Exchange>>,
    restart: Restart,
    ranks: &mut Ranks,
) -> Result<Begun> {
    let Restart { loaded, saved, binary_sha256, t0 } = restart;
    let step = loaded.header.step;
    let same = (saved.sim.strategy, saved.sim.threads) == (spec.strategy, spec.threads);
    let sim = resumed(spec, setup, pool, exchange, loaded.particles, loaded.ids, saved.sim)?;
    let mut bytes = [loaded.bytes];
    ranks.collectives().sum_counts(&mut bytes)?;
    let mut carry = Carry::restored(saved.program, impact, plate)?;
    carry.log.report.restarts += 1;
    carry.log.report.restart_steps.push(step);
    carry.log.report.last_bytes = bytes[0];
    if !same {
        // Steps of another strategy or thread count time something else: the steady state
        // starts here.
        let t = &mut carry.log.timing;
        (t.warmup_steps, t.warmup_wall_s, t.warmup_times, t.warmup_busy) = (step, t.wall_s, *sim.times(), None);
        if ranks.rank() == 0 {
            eprintln!(
                "note: continued with strategy {} on {} thread(s): the same physics to round-off, not bit for bit; the \
                 steady-state figures cover the steps from {step} on",
                spec.strategy, spec.threads
            );
        }
    }
    let checkpoints = Checkpoints::of(spec, ranks.rank(), || binary_sha256)?;
    Ok(Begun { sim, carry, checkpoints, reference_setup: None, restart: Some(t0) })
}
