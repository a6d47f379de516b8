//! The command line of `mpm`: commands, scenarios and options (with units, defaults and
//! examples in `--help`), and the parsers that check each value.

use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand, ValueEnum};
use mpm_core::scenario::taylor;
use mpm_core::scenario::{impact, plate};
use mpm_core::{BulkViscosity, GridMode, MgForm, Strategy, DEFAULT_ENERGY_RISE_LIMIT};
use mpm_spec::scenario::{Contact, ImpactSpec, PlateSpec, TaylorSpec};
use mpm_spec::spec::{
    Budget, CheckpointEvery, CheckpointOutput, Outputs, Paired, Physics, RadiographOutput, RiseLimit, VtkEncoding,
    VtkOutput,
};
use mpm_spec::{RunSpec, SpecError};
use std::path::PathBuf;
use std::sync::OnceLock;

pub const EXAMPLES: &str = "\
Examples:
  # Taylor bar Model 1 at 40 m/s to the paper's end time of 40 µs, serial, summary to a file
  mpm run taylor --model 1 --end-time 40e-6 --json model1.json

  # Domain decomposition on 2 worker threads pinned to CPUs 0 and 1, 50 steps
  mpm run taylor --model 2 --strategy dd --threads 2 --cpus 0,1 --steps 50 --json dd.json

  # Check the Table 2 counts of Model 3 without stepping
  mpm run taylor --model 3 --steps 0 --json counts.json

  # VTU snapshots every 20 steps for ParaView (open out/taylor.pvd)
  mpm run taylor --model 1 --vtk out --every 20

  # Two MPI ranks, each owning half of the grid with one DD worker; rank 0 writes the
  # summary, whose ranks section lists each rank's CPUs, particles and communication
  mpirun -n 2 mpm run taylor --model 3 --strategy dd --threads 1 --steps 20 --json x.json

  # A long run that survives a kill: its state saved every 10 minutes (the last two kept),
  # then continued from the newest checkpoint, bit for bit, to the same summary
  mpm run taylor --model 4 --end-time 40e-6 --checkpoint-dir ck --checkpoint-every 10m --json m4.json
  mpm resume ck

The JSON summary (SI units) holds the configuration, counts, wall time split into the
grid-node and particle stages with sub-stages, steady-state ns per particle-step, peak
memory (VmHWM), requested and observed CPUs, energies and the scenario's figures. It is
written only when the run succeeds; on a solver error (blow-up, particle leaving the grid)
the program prints the error with its step number and exits with status 1. Ctrl-C or
SIGTERM stops a run between steps (status 130; a second one at once); with --checkpoint-dir,
SIGTERM or SIGUSR1 first writes a last checkpoint (status 75: `mpm resume DIR` continues).";

pub const IMPACT_EXAMPLES: &str = "\
Examples:
  # The paper's small model (847,888 particles, 2.12 mm cells) to 30.6 µs after impact,
  # domain decomposition on 2 pinned threads, with a radiograph-style picture
  mpm run impact --strategy dd --threads 2 --cpus 0,1 --json impact.json --radiograph pictures

  # The same with 1.06 mm cells (the paper's finest grid at 0.53 mm spacing)
  mpm run impact --cell 1.06e-3 --strategy dd --threads 2 --json impact-1.06.json

  # The large model (13.5 M particles, 1 mm cells): a few steps and its memory
  mpm run impact --spacing 0.21e-3 --cell 1.0e-3 --strategy dd --threads 2 --steps 3 --json large.json

The summary adds cloud_front_m and cloud_width_m (absolute extremes of the debris beyond the
plate's rear face), their robust variants (ignoring the outermost 0.1 % of the debris mass),
hole_diameter_m, front_velocity_m_s (the slope of the robust front over the last quarter of
the run), leading_debris_velocity_m_s (the speed of the leading 0.1 % of the debris at the
end) and cloud_history (the figures and energies about every microsecond; with --radiograph
also drawn as DIR/history.png).";

pub const PLATE_EXAMPLES: &str = "\
Examples:
  # A lead slab at 500 m/s on a rigid wall, until the shock has crossed 80 % of the slab
  mpm run plate --json plate.json

  # A strong shock (219 GPa by Rankine-Hugoniot), a shorter slab
  mpm run plate --velocity 3000 --length 50e-3 --json plate-3k.json

  # Without artificial viscosity (the shock rings)
  mpm run plate --velocity 3000 --q 0,0

The summary adds shock_speed_m_s (least-squares slope of the later half of the front's path),
shock_pressure_pa (-sigma_zz, volume average behind the front), particle_velocity_m_s, the
Rankine-Hugoniot values rh_shock_speed_m_s, rh_pressure_pa, rh_particle_velocity_m_s and the
relative errors *_rel_error (measured / Rankine-Hugoniot - 1).";

/// Run one explicit MPM simulation and write its JSON summary.
///
/// `mpm` runs one simulation of the explicit material point method (MUSL) with the serial,
/// array-expansion (AE) or domain-decomposition (DD) solver of Huang et al. (2008), on a
/// rayon pool of exactly --threads workers, optionally pinned to given CPUs. It prints a
/// human summary and writes a machine-readable JSON summary (timings per stage, memory,
/// pinning, physics checks) and optional VTU snapshots for ParaView.
#[derive(Debug, Parser)]
#[command(name = "mpm", version = version_line(), after_help = EXAMPLES, propagate_version = true)]
pub struct Cli {
    #[command(subcommand)]
    pub command: Command,
}

/// The `--version` line: version, commit (with `-dirty`), build profile and opt-level,
/// compiler.
fn version_line() -> &'static str {
    use mpm_cli::summary::{CARGO_OPT_LEVEL, PROFILE};
    use mpm_host::identity::{GIT_COMMIT_SHORT, RUSTC, VERSION};
    static LINE: OnceLock<String> = OnceLock::new();
    LINE.get_or_init(|| {
        format!("{VERSION} (commit {GIT_COMMIT_SHORT}, profile {PROFILE}, opt-level {CARGO_OPT_LEVEL}, {RUSTC})")
    })
}

#[derive(Debug, Subcommand)]
pub enum Command {
    /// Run one simulation: a scenario and its flags (e.g. `mpm run taylor --model 1`), or a
    /// run spec (`mpm run --spec FILE`).
    Run(Box<RunCmd>),
    /// Continue a run from its newest checkpoint (`mpm run ... --checkpoint-dir DIR`): with
    /// the same strategy and thread count (and, over MPI, the same rank count) it ends bit
    /// for bit where the run would have ended had it never stopped, and writes the same
    /// summary (its `checkpoint` section counts the restarts and their cost).
    #[command(after_help = RESUME_HELP)]
    Resume(ResumeCmd),
}

pub const RESUME_HELP: &str = "\
Everything the run needs is in the checkpoint: its spec, outputs included (JSON summary,
snapshots, further checkpoints into the same folder). Over MPI start it with the rank count
that wrote it (`mpirun -n R mpm resume DIR`).

Refused, with nothing overwritten: a folder without checkpoints, a checkpoint written by
another mpm binary (its results would not be bit for bit those of the run), a checkpoint of
another spec than --spec FILE, and a damaged newest checkpoint (truncated or corrupted; then
the older one, checked, is offered: --older continues from it and keeps the damaged one as
DIR/damaged-step-N).

Examples:
  mpm resume ck                                   # continue, same outputs
  mpm resume ck --json again.json --quiet         # the summary elsewhere
  mpm resume ck --older                           # the newest checkpoint is damaged
  mpm resume ck --strategy dd --threads 2         # same physics to round-off, other speed
  mpirun -n 2 mpm resume ck                       # a checkpoint of 2 ranks";

/// `mpm resume DIR`.
#[derive(Debug, Args)]
pub struct ResumeCmd {
    /// The checkpoint folder of the run (its `--checkpoint-dir`).
    #[arg(value_name = "DIR")]
    pub dir: PathBuf,

    /// Write the JSON summary to FILE instead of the run's `outputs.json`.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,

    /// No progress bar and no human summary.
    #[arg(long, short)]
    pub quiet: bool,

    /// Continue only if the checkpoint is of the run in FILE (a spec or a summary; every
    /// key but `outputs` and `cpus` must match), and then with FILE's outputs and CPUs.
    #[arg(long, value_name = "FILE")]
    pub spec: Option<PathBuf>,

    /// Continue from the older of the two checkpoints when the newest is damaged (it is
    /// kept, renamed DIR/damaged-step-N).
    #[arg(long)]
    pub older: bool,

    /// Continue with another strategy (the same physics to round-off, not bit for bit).
    #[arg(long, value_parser = strategy_parser(), conflicts_with = "spec")]
    pub strategy: Option<Strategy>,

    /// Continue on another number of worker threads (the same physics to round-off, not bit
    /// for bit).
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_threads, conflicts_with = "spec")]
    pub threads: Option<usize>,

    /// Pin worker j to the j-th CPU of LIST (`--cpus` of `mpm run`); `none` unpins.
    #[arg(long, value_name = "LIST", allow_hyphen_values = true, conflicts_with = "spec")]
    pub cpus: Option<String>,

    /// Run even when the memory estimate exceeds the memory the run may use here (the
    /// least of its cgroup's, its Slurm job's and the host's available memory).
    #[arg(long)]
    pub force: bool,
}

/// `mpm run`: a scenario and its flags, or a spec file.
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true, subcommand_negates_reqs = true, after_help = format!("{SPEC_HELP}\n\n{EXAMPLES}"))]
pub struct RunCmd {
    #[command(subcommand)]
    pub scenario: Option<Scenario>,

    /// Run exactly the run spec in FILE: TOML, or JSON by the `.json` extension (a JSON
    /// summary is accepted too: its `spec`, the resolved run, is taken). Write one with
    /// `mpm run <scenario> ... --print-spec`.
    #[arg(long, value_name = "FILE", required = true)]
    pub spec: Option<PathBuf>,

    /// Write the JSON summary to FILE instead of the spec's `outputs.json`.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,

    /// No progress bar and no human summary (overrides the spec's `outputs.quiet`).
    #[arg(long, short)]
    pub quiet: bool,

    #[command(flatten)]
    pub control: Control,
}

/// Options of a run that are not part of its spec.
#[derive(Debug, Args, Clone, Copy)]
pub struct Control {
    /// Print the resolved run spec as TOML and exit without running (save it and run it
    /// with `mpm run --spec FILE`).
    #[arg(long)]
    pub print_spec: bool,

    /// Run even when the memory estimate exceeds the memory the run may use here (the least
    /// of its cgroup's, its Slurm job's and the host's available memory: the run may then be
    /// killed by the system, or swap), or when it would take more steps than a run that ends.
    #[arg(long)]
    pub force: bool,
}

pub const SPEC_HELP: &str = "\
A run spec holds everything a run computes and writes: the scenario and its parameters,
strategy, threads, ranks, CPUs, grid, physics (EOS, q, CFL, energy limit), budget (steps,
end time, warm-up) and outputs. Every JSON summary echoes the spec it ran under `spec`:

  mpm run taylor --model 2 --strategy dd --threads 2 --steps 50 --print-spec > run.toml
  mpm run --spec run.toml --json again.json     # the same run
  mpm run --spec model2.json                    # a summary's spec, run again";

#[derive(Debug, Subcommand)]
pub enum Scenario {
    /// Taylor bar: an OFHC copper cylinder (25.4 mm long, 7.6 mm across) hitting a rigid
    /// wall at z = 0, discretised as the paper's Models 1-4 (Table 2).
    #[command(after_help = EXAMPLES)]
    Taylor(TaylorArgs),
    /// Hypervelocity impact: a lead sphere (radius 7.5 mm, 20 g) at 6.58 km/s on a lead plate
    /// 6.35 mm thick and 140 mm square, with failure (paper Section 6); measures the debris
    /// cloud's leading edge, width, the hole and draws a radiograph-style side view.
    #[command(after_help = IMPACT_EXAMPLES)]
    Impact(ImpactArgs),
    /// Plate impact: a lead slab (Table 3, no failure) hitting a rigid wall at z = 0 inside a
    /// 2 x 2-cell column with roller side walls (uniaxial strain); measures the shock speed
    /// and the shocked state against the Rankine-Hugoniot relations (the validation of shock
    /// capturing).
    #[command(after_help = PLATE_EXAMPLES)]
    Plate(PlateArgs),
}

/// Options of the plate impact scenario.
#[derive(Debug, Args)]
pub struct PlateArgs {
    /// Impact speed of the slab towards the wall, m/s (> 0). The particle velocity jump of the
    /// shock equals it.
    #[arg(long, value_name = "M/S", default_value_t = plate::DEFAULT_VELOCITY,
          allow_hyphen_values = true, value_parser = parse_f64)]
    pub velocity: f64,

    /// Slab length along z, m (at least 32 cells).
    #[arg(long, value_name = "M", default_value_t = plate::DEFAULT_LENGTH, allow_hyphen_values = true, value_parser = parse_f64)]
    pub length: f64,

    /// Grid cell size, m.
    #[arg(long, value_name = "M", default_value_t = plate::DEFAULT_CELL, allow_hyphen_values = true, value_parser = parse_f64)]
    pub cell: f64,

    /// Particles per cell along each axis.
    #[arg(long, value_name = "N", default_value_t = plate::DEFAULT_PARTICLES_PER_CELL as u8,
          allow_hyphen_values = true, value_parser = |s: &str| parse_between(s, 1, 8))]
    pub particles_per_cell: u8,

    #[command(flatten)]
    pub eos: EosOption,

    #[command(flatten)]
    pub run: RunOptions,
}

/// `--eos`: the form of the Mie-Grüneisen equation of state.
#[derive(Debug, Args)]
pub struct EosOption {
    /// Form of the Mie-Grüneisen equation of state: hugoniot (alias lsdyna), the
    /// Hugoniot-referenced form; paper-printed (alias paper), Eq. 18 as the paper prints it,
    /// with mu where eta = mu / (1 + mu) belongs: a misprint, safe only at small compression.
    #[arg(long, value_enum, default_value_t = EosArg::Hugoniot)]
    pub eos: EosArg,
}

/// Options of the hypervelocity impact scenario.
#[derive(Debug, Args)]
pub struct ImpactArgs {
    /// Particle lattice spacing, m. 0.53e-3 gives the paper's small model (847,888 particles),
    /// 0.21e-3 the large one (13,542,030).
    #[arg(long, value_name = "M", default_value_t = impact::DEFAULT_SPACING, allow_hyphen_values = true, value_parser = parse_f64)]
    pub spacing: f64,

    /// Grid cell size, m. The paper compares 1.06e-3, 1.59e-3 and 2.12e-3 (4 x 4 x 4
    /// particles per cell, its best match) at 0.53e-3 spacing, and uses 1.0e-3 at 0.21e-3.
    #[arg(long, value_name = "M", default_value_t = impact::DEFAULT_CELL, allow_hyphen_values = true, value_parser = parse_f64)]
    pub cell: f64,

    /// Impact speed of the sphere, m/s.
    #[arg(long, value_name = "M/S", default_value_t = impact::IMPACT_VELOCITY,
          allow_hyphen_values = true, value_parser = parse_f64)]
    pub velocity: f64,

    #[command(flatten)]
    pub eos: EosOption,

    /// Write radiograph-style side views (mass projected onto the plane of the flight axis)
    /// as PNG into DIR (created if needed): one at the end, and every K steps with
    /// --radiograph-every; and history.png, the cloud's front and width against time.
    #[arg(long, value_name = "DIR")]
    pub radiograph: Option<PathBuf>,

    /// With --radiograph: also a picture every K steps.
    #[arg(long, value_name = "K", requires = "radiograph", allow_hyphen_values = true, value_parser = parse_count)]
    pub radiograph_every: Option<u64>,

    #[command(flatten)]
    pub run: RunOptions,
}

/// Options of the Taylor bar scenario.
#[derive(Debug, Args)]
pub struct TaylorArgs {
    /// Model 1-4 of the paper's Table 2: 56,056 / 244,341 / 1,155,192 / 12,416,320
    /// particles on a fixed grid of 49,152 / 165,888 / 1,022,208 / 8,177,664 cells.
    #[arg(long, value_name = "1-4", allow_hyphen_values = true, value_parser = |s: &str| parse_between(s, 1, 4))]
    pub model: u8,

    /// Impact speed towards the wall, m/s.
    #[arg(long, value_name = "M/S", default_value_t = taylor::DEFAULT_VELOCITY,
          allow_hyphen_values = true, value_parser = parse_f64)]
    pub velocity: f64,

    #[command(flatten)]
    pub eos: EosOption,

    /// Contact condition at the rigid wall z = 0.
    #[arg(long, value_enum, default_value_t = WallArg::Frictionless)]
    pub wall: WallArg,

    #[command(flatten)]
    pub run: RunOptions,
}

/// Options every scenario shares.
#[derive(Debug, Args)]
pub struct RunOptions {
    /// Simulated end time, s. Default: the paper's (Taylor bar 40e-6, impact 30.6e-6; plate:
    /// when the shock has crossed 80 % of the slab) unless --steps is given; with
    /// both, the run stops at whichever comes first. The last step is shortened to land
    /// exactly on the end time.
    #[arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = parse_f64)]
    pub end_time: Option<f64>,

    /// Stop after N steps (0: build the model, write the summary, do not step). Without
    /// --end-time the end time does not apply.
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_count)]
    pub steps: Option<u64>,

    /// Background grid: the scenario's fixed grid (exact Table 2 counts), a grid re-fitted
    /// to the particles every step (same cell size), or that grid storing only the blocks of
    /// 4^3 nodes the particles touch (same results bit for bit, memory that follows the
    /// particles rather than their box). Default: fixed for the Taylor bar and the plate,
    /// sparse for the impact (its debris cloud leaves any fixed box, and its box is 1-4 %
    /// occupied), adaptive for the impact over several ranks.
    #[arg(long, value_enum)]
    pub grid: Option<GridArg>,

    /// CFL number in (0, 1]: dt = CFL x dx / max(sound speed + particle speed). Default: 0.5
    /// for the Taylor bar and the impact; 0.2 for the plate, whose measurements are the point:
    /// its 3 km/s shock runs 3.15 % fast at CFL 0.5 and 2.66 % at 0.2 (500 m/s: within about
    /// 1 % at either).
    #[arg(long, value_name = "X", allow_hyphen_values = true, value_parser = parse_f64)]
    pub cfl: Option<f64>,

    /// Artificial bulk viscosity coefficients C1,C2 (quadratic, linear; cell size as length):
    /// q = rho dx^2 C1 (tr D)^2 - rho dx c C2 tr D in compression. `0,0` turns it off.
    #[arg(long = "q", value_name = "C1,C2", default_value = DEFAULT_Q, allow_hyphen_values = true, value_parser = parse_q)]
    pub q: BulkViscosity,

    /// Stop the run with an error when the total energy rises more than this fraction above
    /// its initial value (`inf` turns the check off).
    #[arg(long, value_name = "F", default_value_t = DEFAULT_ENERGY_RISE_LIMIT, allow_hyphen_values = true,
          value_parser = parse_energy_rise_limit)]
    pub energy_rise_limit: f64,

    /// How the nodal scatter is made race-free: serial (1 thread), ae (array expansion), dd
    /// (domain decomposition, uniform patches), dd-balanced (cut planes moved every step to
    /// the particle-count quantiles, and the layout the paper's unless another factorisation
    /// of the thread count predicts a clearly smaller imbalance, e.g. 2x4x1 for a thin plate),
    /// colour (blocks of cells in 8 colours, the blocks of one colour scattered at once
    /// straight into the global arrays) or atomic (every thread's particles added straight
    /// into the global arrays by atomic additions; reproduces to round-off only).
    #[arg(long, default_value_t = Strategy::Serial, value_parser = strategy_parser())]
    pub strategy: Strategy,

    /// Worker threads of the rayon pool (exactly this many). Default 1; more than 1 needs
    /// --strategy ae, dd, dd-balanced, colour or atomic. More threads than cores is allowed and
    /// flagged as oversubscribed.
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_threads)]
    pub threads: Option<usize>,

    /// Pin worker j to the j-th CPU of LIST (one CPU per thread), e.g. `0,1` or `0-3`.
    /// The workers' real affinity and CPU are read back and recorded. Default: not pinned.
    #[arg(long, value_name = "LIST", allow_hyphen_values = true, value_parser = parse_cpus)]
    pub cpus: Option<CpuList>,

    /// Leading steps that are timed but left out of the steady-state figures
    /// (ns per particle-step, particle-steps per second). Default: min(5, expected steps / 10).
    #[arg(long, value_name = "K", allow_hyphen_values = true, value_parser = parse_count)]
    pub warmup: Option<u64>,

    /// Write the JSON summary to FILE (atomically; only if the run succeeds). The directory
    /// must exist; this is checked before the run starts.
    #[arg(long, value_name = "FILE")]
    pub json: Option<PathBuf>,

    /// Write VTU snapshots of the particles (velocity, stress, pressure, von Mises, plastic
    /// strain, density, failure) and a .pvd collection into DIR (created if needed). Over
    /// several MPI ranks each rank writes its particles as one .vtu piece per snapshot and
    /// rank 0 a .pvtu naming the pieces; the .pvd lists the .pvtu files.
    #[arg(long, value_name = "DIR")]
    pub vtk: Option<PathBuf>,

    /// With --vtk: a snapshot every K steps (plus the initial and the final state).
    #[arg(long, value_name = "K", default_value_t = 100, requires = "vtk", allow_hyphen_values = true,
          value_parser = parse_count)]
    pub every: u64,

    /// With --vtk: array encoding of the snapshots.
    #[arg(long, value_enum, value_name = "ENCODING", default_value_t = EncodingArg::Compressed, requires = "vtk")]
    pub vtk_format: EncodingArg,

    /// No progress bar and no human summary (warnings and errors still go to stderr).
    #[arg(long, short)]
    pub quiet: bool,

    /// Ranks the run is split over: start it with `mpirun -n R mpm run ...` (each rank owns a
    /// box of the grid and runs --threads workers). Default: the launcher's rank count. A
    /// value that differs from what mpirun started is an error.
    #[arg(long, value_name = "R", allow_hyphen_values = true, value_parser = parse_count)]
    pub ranks: Option<u64>,

    /// With several ranks: boxes per axis as `RXxRYxRZ` (e.g. `2x1x1`), their product the
    /// rank count. Default: the domain-decomposition layout for that count (2: 2x1x1,
    /// 4: 2x2x1, 8: 2x2x2), cut uniformly over the particles' initial bounding box.
    #[arg(long, value_name = "RXxRYxRZ", allow_hyphen_values = true, value_parser = parse_layout)]
    pub rank_layout: Option<[usize; 3]>,

    /// With several ranks: wait at a barrier in front of every exchange operation and report
    /// that time apart (`exchange.wait_seconds` per rank in the JSON), so that
    /// `exchange.seconds` is the communication alone, not waiting for a slower rank (load
    /// imbalance, or a CPU another process took). Adds one global synchronisation per
    /// operation (6 per step): for measuring, not for production runs at many ranks.
    #[arg(long)]
    pub split_wait: bool,

    /// Save the run's whole state into DIR (created if needed) every --checkpoint-every, the
    /// last two kept, so that `mpm resume DIR` continues it bit for bit after a kill, a
    /// time-out or a reboot. DIR must hold no checkpoints yet (nothing is overwritten).
    /// SIGTERM or SIGUSR1 (a batch system's time limit: `sbatch --signal=USR1@120`) then
    /// writes a last checkpoint of the step the run is in and stops it with exit status 75;
    /// a second SIGTERM or Ctrl-C ends it at once (130).
    #[arg(long, value_name = "DIR")]
    pub checkpoint_dir: Option<PathBuf>,

    /// With --checkpoint-dir: how often, as steps (`500`) or as wall-clock time since the
    /// last checkpoint (`10m`, `90s`, `1h 30m`). Writing one takes about as long as the
    /// disk needs for 137 bytes per particle; it is left out of every timing and reported
    /// in the summary's `checkpoint` section.
    #[arg(long, value_name = "N|DURATION", default_value = "10m", requires = "checkpoint_dir",
          allow_hyphen_values = true, value_parser = CheckpointEvery::parse)]
    pub checkpoint_every: CheckpointEvery,

    /// Measure the parallel efficiency in the paired design: beside the --threads solver, a
    /// one-thread solver of the same strategy runs in this process (its worker on the first
    /// of --cpus), both take the warm-up steps and then N timed blocks of (steps - warmup) / N
    /// steps each, alternating. The summary's `paired` section holds both solvers' seconds
    /// per step per block and the block efficiencies t1 / (T tT). Needs --steps with a whole
    /// number of steps per block, --warmup, a parallel strategy (ae, dd, dd-balanced, colour,
    /// atomic) and 2 or more threads.
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_count)]
    pub paired_blocks: Option<u64>,

    /// TEST KNOB, never for results: every worker but the first does extra work in the
    /// grid-node stage of every step, so that the parallel efficiency drops by about the
    /// fraction F (0 < F < 1; a one-thread run is unchanged). The results are bitwise those
    /// without it. Recorded in the summary (`inject_slowdown`, `injected_s`); the harness's
    /// rows record it and its analyses refuse such runs unless asked. What `mpm-bench
    /// calibrate` uses to measure whether the regression gate sees a known slowdown.
    #[arg(long, value_name = "F", allow_hyphen_values = true, value_parser = parse_f64)]
    pub inject_slowdown: Option<f64>,

    /// TEST KNOB, never for results: after every step every worker (and a paired run's
    /// one-thread reference alike) waits, busy, so that each step takes 1 / (1 - F) times as
    /// long (0 < F < 1): the time per step grows by that factor, the parallel efficiency
    /// stays. The results are bitwise those without it. Recorded in the summary
    /// (`inject_step_slowdown`, `injected_step_s`); the harness's rows record it and its
    /// analyses refuse such runs unless asked. What `mpm-bench calibrate --design ab` uses
    /// to measure whether the gate sees a slower step.
    #[arg(long, value_name = "F", allow_hyphen_values = true, value_parser = parse_f64)]
    pub inject_step_slowdown: Option<f64>,

    /// Write the final particle state to FILE (binary, little-endian, sorted by particle id:
    /// per particle the id as u64, then position, velocity and stress as 12 f64). Used to
    /// compare runs over different rank and thread counts.
    #[arg(long, value_name = "FILE")]
    pub dump_state: Option<PathBuf>,

    #[command(flatten)]
    pub control: Control,
}

/// A parsed `--cpus` list.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CpuList(pub Vec<usize>);

/// `--cpus`: a CPU list such as `0,1` or `0-3`.
fn parse_cpus(s: &str) -> Result<CpuList, String> {
    mpm_host::pinning::parse_cpu_list(s).map(CpuList).map_err(|e| e.to_string())
}

/// `2x1x1` as `[2, 1, 1]`.
fn parse_layout(s: &str) -> Result<[usize; 3], String> {
    let parts: Vec<usize> = s
        .split('x')
        .map(|p| p.trim().parse::<usize>())
        .collect::<Result<_, _>>()
        .map_err(|_| format!("'{s}' is not a rank layout: give three positive counts joined by 'x', e.g. 2x1x1"))?;
    match parts[..] {
        [a, b, c] if a > 0 && b > 0 && c > 0 => Ok([a, b, c]),
        _ => Err(format!("'{s}' is not a rank layout: give three positive counts joined by 'x', e.g. 2x1x1")),
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum EosArg {
    /// Hugoniot-referenced (LS-DYNA's Grüneisen EOS with a = 0, S2 = S3 = 0).
    #[value(alias = "lsdyna", alias = "ls-dyna")]
    Hugoniot,
    /// Eq. 18 as printed (a misprint; safe only at small compression).
    #[value(alias = "paper")]
    PaperPrinted,
}

/// Default of `--q`: the default coefficients of [`BulkViscosity`].
pub const DEFAULT_Q: &str = "1.5,0.06";

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum WallArg {
    /// Only the normal velocity is stopped.
    Frictionless,
    /// Every velocity component is stopped.
    Sticking,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum GridArg {
    /// The scenario's grid, unchanged (a particle leaving it is an error).
    Fixed,
    /// Re-fitted to the particles' bounding box every step.
    Adaptive,
    /// Adaptive, storing only the blocks of nodes the particles touch (one process only).
    Sparse,
}

/// `--strategy`: one of the short names of [`Strategy::ALL`], described by its label where
/// that says more than the name.
pub fn strategy_parser() -> impl TypedValueParser<Value = Strategy> {
    let value = |s: Strategy| {
        let v = PossibleValue::new(s.name());
        if s.label() == s.name() {
            v
        } else {
            v.help(s.label())
        }
    };
    PossibleValuesParser::new(Strategy::ALL.map(value)).try_map(|name| name.parse::<Strategy>())
}

pub fn parse_f64(s: &str) -> Result<f64, String> {
    s.trim().parse::<f64>().map_err(|_| format!("'{s}' is not a number"))
}

/// A whole number >= 0 (steps, warm-up steps, intervals, ranks); the spec's checks say
/// what range a value needs.
pub fn parse_count(s: &str) -> Result<u64, String> {
    match s.trim().parse::<i128>() {
        Ok(n) if n < 0 => Err(format!("{s} is negative: give a whole number >= 0")),
        Ok(n) => u64::try_from(n).map_err(|_| format!("{s} is too large")),
        Err(_) => Err(format!("'{s}' is not a whole number")),
    }
}

/// A whole number from `least` to `most` (`--model`, `--particles-per-cell`).
pub fn parse_between(s: &str, least: u8, most: u8) -> Result<u8, String> {
    match s.trim().parse::<i128>() {
        Ok(n) if (i128::from(least)..=i128::from(most)).contains(&n) => Ok(n as u8),
        Ok(n) => Err(format!("{n} is not in {least}..={most}: give a whole number from {least} to {most}")),
        Err(_) => Err(format!("'{s}' is not a whole number: give one from {least} to {most}")),
    }
}

/// `--q C1,C2`: two numbers (the spec's check wants them finite and >= 0).
pub fn parse_q(s: &str) -> Result<BulkViscosity, String> {
    let parts: Vec<&str> = s.split(',').collect();
    let [c1, c2] = parts.as_slice() else {
        return Err(format!("--q takes two numbers C1,C2 (e.g. {DEFAULT_Q}; 0,0 turns it off), got '{s}'"));
    };
    Ok(BulkViscosity { c1: parse_f64(c1)?, c2: parse_f64(c2)? })
}

/// `--energy-rise-limit`: a fraction, or `inf` / `off` (no check).
pub fn parse_energy_rise_limit(s: &str) -> Result<f64, String> {
    match s.trim() {
        "off" | "inf" => Ok(f64::INFINITY),
        _ => parse_f64(s),
    }
}

pub fn parse_threads(s: &str) -> Result<usize, String> {
    match s.trim().parse::<i128>() {
        Ok(n) if n >= 1 => usize::try_from(n).map_err(|_| format!("{s} threads is too many")),
        Ok(_) => Err(format!("the thread count must be at least 1, got {s}")),
        Err(_) => Err(format!("'{s}' is not a thread count")),
    }
}

/// `--vtk-format`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
pub enum EncodingArg {
    /// Raw binary appended after the XML, zlib-compressed (ParaView reads it as it is;
    /// exact; the smallest).
    Compressed,
    /// Inline base64 binary (exact; a third larger than raw).
    Binary,
    /// Inline ASCII (readable; values printed in shortest round-trip form).
    Ascii,
}

impl From<EosArg> for MgForm {
    fn from(e: EosArg) -> Self {
        match e {
            EosArg::Hugoniot => MgForm::Hugoniot,
            EosArg::PaperPrinted => MgForm::PaperPrinted,
        }
    }
}

impl From<GridArg> for GridMode {
    fn from(g: GridArg) -> Self {
        match g {
            GridArg::Fixed => GridMode::Fixed,
            GridArg::Adaptive => GridMode::Adaptive,
            GridArg::Sparse => GridMode::Sparse,
        }
    }
}

impl Scenario {
    /// The options every scenario shares.
    pub fn options(&self) -> &RunOptions {
        match self {
            Scenario::Taylor(a) => &a.run,
            Scenario::Impact(a) => &a.run,
            Scenario::Plate(a) => &a.run,
        }
    }

    /// The scenario of the spec, its Mie-Grüneisen form, and the radiograph output.
    fn parts(&self) -> (mpm_spec::Scenario, MgForm, Option<RadiographOutput>) {
        match self {
            Scenario::Taylor(a) => (
                mpm_spec::Scenario::Taylor(TaylorSpec {
                    model: a.model,
                    velocity_m_s: a.velocity,
                    wall: match a.wall {
                        WallArg::Frictionless => Contact::Frictionless,
                        WallArg::Sticking => Contact::Sticking,
                    },
                }),
                a.eos.eos.into(),
                None,
            ),
            Scenario::Impact(a) => (
                mpm_spec::Scenario::Impact(ImpactSpec {
                    spacing_m: a.spacing,
                    cell_m: a.cell,
                    velocity_m_s: a.velocity,
                }),
                a.eos.eos.into(),
                a.radiograph.clone().map(|dir| RadiographOutput { dir, every: a.radiograph_every }),
            ),
            Scenario::Plate(a) => (
                mpm_spec::Scenario::Plate(PlateSpec {
                    velocity_m_s: a.velocity,
                    length_m: a.length,
                    cell_m: a.cell,
                    particles_per_cell: a.particles_per_cell,
                }),
                a.eos.eos.into(),
                None,
            ),
        }
    }

    /// The run spec these flags ask for, on `ranks` ranks (the launcher's count when
    /// `--ranks` is not given): the scenario's defaults ([`RunSpec::new`]) with every flag
    /// applied, checked. The one place flags become a spec.
    pub fn spec(&self, ranks: usize) -> Result<RunSpec, SpecError> {
        let (scenario, eos, radiograph) = self.parts();
        let o = self.options();
        let mut spec = RunSpec::new(scenario)?;
        spec.strategy = o.strategy;
        spec.threads = o.threads.unwrap_or(1);
        spec.ranks = ranks;
        spec.rank_layout = o.rank_layout;
        spec.cpus = o.cpus.clone().map(|c| c.0);
        spec.grid = o.grid.map_or_else(|| scenario.default_grid(ranks), GridMode::from);
        spec.physics = Physics {
            eos,
            q: o.q,
            cfl: o.cfl.unwrap_or(spec.physics.cfl),
            energy_rise_limit: RiseLimit::from_f64(o.energy_rise_limit),
        };
        spec.budget = Budget {
            steps: o.steps,
            end_time_s: match (o.end_time, o.steps) {
                (Some(t), _) => Some(t),
                (None, None) => spec.budget.end_time_s,
                (None, Some(_)) => None,
            },
            warmup: o.warmup,
        };
        spec.split_wait = o.split_wait;
        spec.paired = o.paired_blocks.map(|blocks| Paired { blocks });
        spec.inject_slowdown = o.inject_slowdown;
        spec.inject_step_slowdown = o.inject_step_slowdown;
        spec.outputs = Outputs {
            json: o.json.clone(),
            quiet: o.quiet,
            vtk: o.vtk.clone().map(|dir| VtkOutput {
                dir,
                every: o.every,
                encoding: match o.vtk_format {
                    EncodingArg::Compressed => VtkEncoding::Compressed,
                    EncodingArg::Binary => VtkEncoding::Binary,
                    EncodingArg::Ascii => VtkEncoding::Ascii,
                },
            }),
            radiograph,
            dump_state: o.dump_state.clone(),
            checkpoint: o.checkpoint_dir.clone().map(|dir| CheckpointOutput { dir, every: o.checkpoint_every }),
        };
        spec.check()?;
        Ok(spec)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn q_and_counts_parse_and_leave_ranges_to_the_spec() {
        assert_eq!(parse_q(DEFAULT_Q), Ok(BulkViscosity::default()));
        assert_eq!(parse_q("0,0"), Ok(BulkViscosity::OFF));
        assert_eq!(parse_q(" 2 , 0.1"), Ok(BulkViscosity { c1: 2.0, c2: 0.1 }));
        for bad in ["1.5", "1,2,3", "a,b", ""] {
            assert!(parse_q(bad).is_err(), "{bad}");
        }
        assert_eq!(parse_energy_rise_limit("inf"), Ok(f64::INFINITY));
        assert_eq!(parse_energy_rise_limit("off"), Ok(f64::INFINITY));
        assert!(parse_energy_rise_limit("x").is_err());
        assert_eq!(parse_count("12"), Ok(12));
        assert!(parse_count("-1").unwrap_err().contains("negative"));
        assert!(parse_count("1.5").unwrap_err().contains("whole number"));
        assert!(parse_threads("-1").unwrap_err().contains("at least 1"));
    }
}
