//! `mpm`: run one explicit MPM simulation and write its JSON summary (and, optionally, VTU
//! snapshots). See `mpm run taylor --help`.

use anyhow::{bail, Context, Result};
use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
use clap::{Args, Parser, Subcommand, ValueEnum};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mpm_cli::atomic;
use mpm_cli::picture::{write_radiograph, RadiographNotes};
use mpm_cli::pinning::{self, PinnedPool};
use mpm_cli::summary::{EndReason, HistoryPoint, HistoryRecorder, RunContext, Summary, Timing, OPT_LEVEL};
use mpm_cli::vtk::{Encoding, SnapshotWriter};
use mpm_core::scenario::impact;
use mpm_core::scenario::taylor::{self, TaylorBar};
use mpm_core::{GridMode, MgForm, SimConfig, Simulation, Strategy, WallKind, DEFAULT_CFL};
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

const EXAMPLES: &str = "\
Examples:
  # Taylor bar Model 1 at 40 m/s to the paper's end time of 40 µs, serial, summary to a file
  mpm run taylor --model 1 --end-time 40e-6 --json model1.json

  # Domain decomposition on 2 worker threads pinned to CPUs 0 and 1, 50 steps
  mpm run taylor --model 2 --strategy dd --threads 2 --cpus 0,1 --steps 50 --json dd.json

  # Check the Table 2 counts of Model 3 without stepping
  mpm run taylor --model 3 --steps 0 --json counts.json

  # VTU snapshots every 20 steps for ParaView (open out/taylor.pvd)
  mpm run taylor --model 1 --vtk out --every 20

The JSON summary (SI units) holds the configuration, counts, wall time split into the
grid-node and particle stages with sub-stages, steady-state ns per particle-step, peak
memory (VmHWM), requested and observed CPUs, energies and the scenario's figures. It is
written only when the run succeeds; on a solver error (blow-up, particle leaving the grid)
the program prints the error with its step number and exits with status 1.";

const IMPACT_EXAMPLES: &str = "\
Examples:
  # The paper's small model (848,104 particles, 2.12 mm cells) to 30.6 µs after impact,
  # domain decomposition on 2 pinned threads, with a radiograph-style picture
  mpm run impact --strategy dd --threads 2 --cpus 0,1 --json impact.json --radiograph pictures

  # The same with 1.06 mm cells (the paper's finest grid at 0.53 mm spacing)
  mpm run impact --cell 1.06e-3 --strategy dd --threads 2 --json impact-1.06.json

  # The large model (13.5 M particles, 1 mm cells): a few steps and its memory
  mpm run impact --spacing 0.21e-3 --cell 1.0e-3 --strategy dd --threads 2 --steps 3 --json large.json

The summary adds cloud_front_m and cloud_width_m (absolute extremes of the debris beyond the
plate's rear face), their robust variants (ignoring the outermost 0.1 % of the debris mass),
hole_diameter_m and front_velocity_m_s.";

/// Run one explicit MPM simulation and write its JSON summary.
///
/// `mpm` runs one simulation of the explicit material point method (MUSL) with the serial,
/// array-expansion (AE) or domain-decomposition (DD) solver of Huang et al. (2008), on a
/// rayon pool of exactly --threads workers, optionally pinned to given CPUs. It prints a
/// human summary and writes a machine-readable JSON summary (timings per stage, memory,
/// pinning, physics checks) and optional VTU snapshots for ParaView.
#[derive(Debug, Parser)]
#[command(name = "mpm", version, after_help = EXAMPLES, propagate_version = true)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Run one simulation of a scenario (e.g. `mpm run taylor --model 1`).
    #[command(after_help = EXAMPLES)]
    Run(RunCmd),
}

#[derive(Debug, Args)]
struct RunCmd {
    #[command(subcommand)]
    scenario: Scenario,
}

#[derive(Debug, Subcommand)]
enum Scenario {
    /// Taylor bar: an OFHC copper cylinder (25.4 mm long, 7.6 mm across) hitting a rigid
    /// wall at z = 0, discretised as the paper's Models 1-4 (Table 2).
    #[command(after_help = EXAMPLES)]
    Taylor(TaylorArgs),
    /// Hypervelocity impact: a lead sphere (radius 7.5 mm, 20 g) at 6.58 km/s on a lead plate
    /// 6.35 mm thick and 140 mm square, with failure (paper Section 6); measures the debris
    /// cloud's leading edge, width, the hole and draws a radiograph-style side view.
    #[command(after_help = IMPACT_EXAMPLES)]
    Impact(ImpactArgs),
}

/// Options of the hypervelocity impact scenario.
#[derive(Debug, Args)]
struct ImpactArgs {
    /// Particle lattice spacing, m. 0.53e-3 gives the paper's small model (848,104 particles;
    /// paper 847,888), 0.21e-3 the large one (13.5 M).
    #[arg(long, value_name = "M", default_value_t = impact::DEFAULT_SPACING, value_parser = parse_length)]
    spacing: f64,

    /// Grid cell size, m. The paper compares 1.06e-3, 1.59e-3 and 2.12e-3 (4 x 4 x 4
    /// particles per cell, its best match) at 0.53e-3 spacing, and uses 1.0e-3 at 0.21e-3.
    #[arg(long, value_name = "M", default_value_t = impact::DEFAULT_CELL, value_parser = parse_length)]
    cell: f64,

    /// Impact speed of the sphere, m/s.
    #[arg(long, value_name = "M/S", default_value_t = impact::IMPACT_VELOCITY,
          allow_hyphen_values = true, value_parser = parse_velocity)]
    velocity: f64,

    /// Form of the Mie-Grüneisen equation of state.
    #[arg(long, value_enum, default_value_t = EosArg::Paper)]
    eos: EosArg,

    /// Write radiograph-style side views (mass projected onto the plane of the flight axis)
    /// as PNG into DIR (created if needed): one at the end, and every K steps with
    /// --radiograph-every.
    #[arg(long, value_name = "DIR")]
    radiograph: Option<PathBuf>,

    /// With --radiograph: also a picture every K steps.
    #[arg(long, value_name = "K", requires = "radiograph", value_parser = clap::value_parser!(u64).range(1..))]
    radiograph_every: Option<u64>,

    #[command(flatten)]
    run: RunOptions,
}

/// Options of the Taylor bar scenario.
#[derive(Debug, Args)]
struct TaylorArgs {
    /// Model 1-4 of the paper's Table 2: 56,056 / 244,341 / 1,155,192 / 12,416,320
    /// particles on a fixed grid of 49,152 / 165,888 / 1,022,208 / 8,177,664 cells.
    #[arg(long, value_name = "1-4", value_parser = clap::value_parser!(u8).range(1..=4))]
    model: u8,

    /// Impact speed towards the wall, m/s.
    #[arg(long, value_name = "M/S", default_value_t = taylor::DEFAULT_VELOCITY,
          allow_hyphen_values = true, value_parser = parse_velocity)]
    velocity: f64,

    /// Form of the Mie-Grüneisen equation of state.
    #[arg(long, value_enum, default_value_t = EosArg::Paper)]
    eos: EosArg,

    /// Contact condition at the rigid wall z = 0.
    #[arg(long, value_enum, default_value_t = WallArg::Frictionless)]
    wall: WallArg,

    #[command(flatten)]
    run: RunOptions,
}

/// Options every scenario shares.
#[derive(Debug, Args)]
struct RunOptions {
    /// Simulated end time, s. Default: the paper's (Taylor bar 40e-6, impact 30.6e-6)
    /// unless --steps is given; with
    /// both, the run stops at whichever comes first. The last step is shortened to land
    /// exactly on the end time.
    #[arg(long, value_name = "SECONDS", allow_hyphen_values = true, value_parser = parse_end_time)]
    end_time: Option<f64>,

    /// Stop after N steps (0: build the model, write the summary, do not step). Without
    /// --end-time the end time does not apply.
    #[arg(long, value_name = "N")]
    steps: Option<u64>,

    /// Background grid: the scenario's fixed grid (exact Table 2 counts) or a grid re-fitted
    /// to the particles every step (same cell size). Default: fixed for the Taylor bar,
    /// adaptive for the impact (its debris cloud leaves any fixed box).
    #[arg(long, value_enum)]
    grid: Option<GridArg>,

    /// CFL number in (0, 1]: dt = CFL x dx / max(sound speed + particle speed).
    #[arg(long, value_name = "X", default_value_t = DEFAULT_CFL,
          allow_hyphen_values = true, value_parser = parse_cfl)]
    cfl: f64,

    /// How the nodal scatter is made race-free: serial (1 thread), ae (array expansion) or
    /// dd (domain decomposition).
    #[arg(long, default_value_t = Strategy::Serial, value_parser = strategy_parser())]
    strategy: Strategy,

    /// Worker threads of the rayon pool (exactly this many). Default 1; more than 1 needs
    /// --strategy ae or dd. More threads than cores is allowed and flagged as oversubscribed.
    #[arg(long, value_name = "N", allow_hyphen_values = true, value_parser = parse_threads)]
    threads: Option<usize>,

    /// Pin worker j to the j-th CPU of LIST (one CPU per thread), e.g. `0,1` or `0-3`.
    /// The workers' real affinity and CPU are read back and recorded. Default: not pinned.
    #[arg(long, value_name = "LIST")]
    cpus: Option<String>,

    /// Leading steps that are timed but left out of the steady-state figures
    /// (ns per particle-step, particle-steps per second). Default: min(5, expected steps / 10).
    #[arg(long, value_name = "K")]
    warmup: Option<u64>,

    /// Write the JSON summary to FILE (atomically; only if the run succeeds). The directory
    /// must exist; this is checked before the run starts.
    #[arg(long, value_name = "FILE")]
    json: Option<PathBuf>,

    /// Write VTU snapshots of the particles (velocity, stress, pressure, von Mises, plastic
    /// strain, density, failure) and a .pvd collection into DIR (created if needed).
    #[arg(long, value_name = "DIR")]
    vtk: Option<PathBuf>,

    /// With --vtk: a snapshot every K steps (plus the initial and the final state).
    #[arg(long, value_name = "K", default_value_t = 100, requires = "vtk",
          value_parser = clap::value_parser!(u64).range(1..))]
    every: u64,

    /// With --vtk: array encoding of the snapshots.
    #[arg(long, value_enum, value_name = "ENCODING", default_value_t = Encoding::Binary, requires = "vtk")]
    vtk_format: Encoding,

    /// No progress bar and no human summary (warnings and errors still go to stderr).
    #[arg(long, short)]
    quiet: bool,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum EosArg {
    /// Eq. 18 exactly as the paper prints it.
    Paper,
    /// The common LS-DYNA form.
    Lsdyna,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum WallArg {
    /// Only the normal velocity is stopped.
    Frictionless,
    /// Every velocity component is stopped.
    Sticking,
}

impl WallArg {
    fn name(self) -> &'static str {
        match self {
            WallArg::Frictionless => "frictionless",
            WallArg::Sticking => "sticking",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum GridArg {
    /// The scenario's grid, unchanged (a particle leaving it is an error).
    Fixed,
    /// Re-fitted to the particles' bounding box every step.
    Adaptive,
}

/// `--strategy`: one of the short names of [`Strategy::ALL`], described by its label where
/// that says more than the name.
fn strategy_parser() -> impl TypedValueParser<Value = Strategy> {
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

fn parse_f64(s: &str) -> Result<f64, String> {
    s.trim().parse::<f64>().map_err(|_| format!("'{s}' is not a number"))
}

fn parse_length(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("'{s}' is not a positive length in metres"))
    }
}

fn parse_end_time(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if v.is_finite() && v > 0.0 {
        Ok(v)
    } else {
        Err(format!("the end time must be a positive number of seconds (e.g. 40e-6), got {s}"))
    }
}

fn parse_velocity(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if v.is_finite() && v >= 0.0 {
        Ok(v)
    } else {
        Err(format!("the impact speed must be a finite number of m/s >= 0 (towards the wall), got {s}"))
    }
}

fn parse_cfl(s: &str) -> Result<f64, String> {
    let v = parse_f64(s)?;
    if v > 0.0 && v <= 1.0 {
        Ok(v)
    } else {
        Err(format!("the CFL number must be in (0, 1], got {s} (default {DEFAULT_CFL})"))
    }
}

fn parse_threads(s: &str) -> Result<usize, String> {
    match s.trim().parse::<i64>() {
        Ok(n) if n >= 1 => Ok(n as usize),
        Ok(_) => Err(format!("the thread count must be at least 1, got {s}")),
        Err(_) => Err(format!("'{s}' is not a thread count")),
    }
}

/// Raised when the user interrupts the run.
#[derive(Debug, thiserror::Error)]
#[error("interrupted at step {0} (Ctrl-C); no summary written")]
struct Interrupted(u64);

fn main() {
    let cli = Cli::parse();
    if let Err(e) = run(cli) {
        eprintln!("error: {e}");
        for cause in e.chain().skip(1) {
            eprintln!("  caused by: {cause}");
        }
        let code = if e.downcast_ref::<Interrupted>().is_some() { 130 } else { 1 };
        std::process::exit(code);
    }
}

fn run(cli: Cli) -> Result<()> {
    let command_line: Vec<String> = std::env::args().collect();
    match cli.command {
        Command::Run(RunCmd { scenario: Scenario::Taylor(args) }) => {
            let run = ScenarioRun::Taylor(args);
            run_scenario(&run, command_line)
        }
        Command::Run(RunCmd { scenario: Scenario::Impact(args) }) => {
            let run = ScenarioRun::Impact(args);
            run_scenario(&run, command_line)
        }
    }
}

/// A JSON output reserved before the run: a temporary file in the target directory that
/// becomes the summary by a rename when the run succeeds, and is removed otherwise.
struct PendingFile {
    tmp: PathBuf,
    dest: PathBuf,
    done: bool,
}

impl PendingFile {
    fn reserve(dest: &Path) -> Result<Self> {
        if dest.is_dir() {
            bail!("cannot write the JSON summary to {}: it is a directory; give a file name", dest.display());
        }
        let parent = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if !parent.is_dir() {
            bail!(
                "cannot write the JSON summary to {}: directory {} does not exist (create it first)",
                dest.display(),
                parent.display()
            );
        }
        let tmp = atomic::temp_path_for(dest);
        std::fs::File::create(&tmp).with_context(|| {
            format!(
                "cannot write the JSON summary to {}: directory {} is not writable",
                dest.display(),
                parent.display()
            )
        })?;
        Ok(Self { tmp, dest: dest.to_path_buf(), done: false })
    }

    fn commit(mut self, bytes: &[u8]) -> Result<()> {
        atomic::write_atomic(&self.dest, bytes).context("cannot write the JSON summary")?;
        self.done = true;
        Ok(())
    }
}

impl Drop for PendingFile {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// The progress bar, if one is shown.
struct Progress {
    bar: ProgressBar,
    by_steps: bool,
    end_time: Option<f64>,
    step_limit: Option<u64>,
    start: Instant,
}

impl Progress {
    fn new(quiet: bool, end_time: Option<f64>, step_limit: Option<u64>) -> Option<Self> {
        if quiet || !std::io::stderr().is_terminal() {
            return None;
        }
        let by_steps = end_time.is_none();
        let len = match (by_steps, end_time, step_limit) {
            (true, _, Some(n)) => n,
            (_, Some(t), _) => (t * 1e12).round() as u64,
            _ => 0,
        };
        let bar = ProgressBar::with_draw_target(Some(len), ProgressDrawTarget::stderr());
        let style = ProgressStyle::with_template("[{elapsed_precise}] {bar:24.cyan/blue} {msg}, ETA {eta}")
            .unwrap_or_else(|_| ProgressStyle::default_bar())
            .progress_chars("=> ");
        bar.set_style(style);
        Some(Self { bar, by_steps, end_time, step_limit, start: Instant::now() })
    }

    fn update(&self, sim: &Simulation) {
        let steps = sim.steps();
        let rate = steps as f64 / self.start.elapsed().as_secs_f64().max(1e-9);
        let t_us = sim.time() * 1e6;
        let msg = match (self.end_time, self.step_limit) {
            (Some(end), Some(n)) => format!("t {t_us:.3}/{:.3} µs, step {steps}/{n}, {rate:.1} steps/s", end * 1e6),
            (Some(end), None) => {
                format!("t {t_us:.3}/{:.3} µs, step {steps}, {rate:.1} steps/s", end * 1e6)
            }
            (None, Some(n)) => format!("step {steps}/{n}, t {t_us:.3} µs, {rate:.1} steps/s"),
            (None, None) => format!("step {steps}"),
        };
        if self.by_steps {
            self.bar.set_position(steps);
        } else {
            self.bar.set_position((sim.time() * 1e12).round() as u64);
        }
        self.bar.set_message(msg);
    }
}

/// The scenario a run was asked for.
enum ScenarioRun {
    Taylor(TaylorArgs),
    Impact(ImpactArgs),
}

/// A scenario built and ready to run.
struct Prepared {
    setup: mpm_core::Setup,
    model: u8,
    velocity: f64,
    wall: &'static str,
    taylor: Option<(taylor::TaylorFigures, [f64; 3])>,
    impact: Option<impact::ImpactGeometry>,
}

fn eos_of(e: EosArg) -> MgForm {
    match e {
        EosArg::Paper => MgForm::Paper,
        EosArg::Lsdyna => MgForm::LsDyna,
    }
}

impl ScenarioRun {
    fn options(&self) -> &RunOptions {
        match self {
            ScenarioRun::Taylor(a) => &a.run,
            ScenarioRun::Impact(a) => &a.run,
        }
    }

    fn name(&self) -> &'static str {
        match self {
            ScenarioRun::Taylor(_) => "taylor",
            ScenarioRun::Impact(_) => "impact",
        }
    }

    fn describe(&self) -> String {
        match self {
            ScenarioRun::Taylor(a) => format!("Taylor bar Model {}", a.model),
            ScenarioRun::Impact(a) => {
                format!("impact, spacing {} mm, cell {} mm", a.spacing * 1e3, a.cell * 1e3)
            }
        }
    }

    fn default_end_time(&self) -> f64 {
        match self {
            ScenarioRun::Taylor(_) => taylor::DEFAULT_END_TIME,
            ScenarioRun::Impact(_) => impact::DEFAULT_END_TIME,
        }
    }

    fn default_grid(&self) -> GridMode {
        match self {
            ScenarioRun::Taylor(_) => GridMode::Fixed,
            ScenarioRun::Impact(_) => GridMode::Adaptive,
        }
    }

    fn build(&self) -> Result<Prepared> {
        match self {
            ScenarioRun::Taylor(args) => {
                let bar = TaylorBar {
                    model: args.model,
                    velocity: args.velocity,
                    eos: eos_of(args.eos),
                    wall: match args.wall {
                        WallArg::Frictionless => WallKind::Slip,
                        WallArg::Sticking => WallKind::Stick,
                    },
                };
                let setup = bar.setup().with_context(|| format!("cannot set up Taylor bar Model {}", args.model))?;
                let figures = taylor::measure(&setup.particles, setup.spacing);
                let spacing = setup.spacing;
                Ok(Prepared {
                    setup,
                    model: args.model,
                    velocity: args.velocity,
                    wall: args.wall.name(),
                    taylor: Some((figures, spacing)),
                    impact: None,
                })
            }
            ScenarioRun::Impact(args) => {
                let imp = impact::Impact {
                    spacing: args.spacing,
                    cell: args.cell,
                    velocity: args.velocity,
                    eos: eos_of(args.eos),
                };
                let (setup, geometry) = imp.setup().context("cannot set up the impact")?;
                Ok(Prepared {
                    setup,
                    model: 0,
                    velocity: args.velocity,
                    wall: "none",
                    taylor: None,
                    impact: Some(geometry),
                })
            }
        }
    }

    /// Radiograph directory and interval (impact only).
    fn radiograph(&self) -> Option<(&Path, Option<u64>)> {
        match self {
            ScenarioRun::Impact(a) => a.radiograph.as_deref().map(|d| (d, a.radiograph_every)),
            ScenarioRun::Taylor(_) => None,
        }
    }
}

/// Write a radiograph of the current state into `dir`.
fn radiograph_png(dir: &Path, sim: &Simulation, geometry: &impact::ImpactGeometry, name: &str) -> Result<PathBuf> {
    let f = impact::measure(sim.particles(), geometry);
    let notes = RadiographNotes {
        time: sim.time(),
        plate_faces: (0.0, geometry.rear_face),
        lines: vec![
            format!(
                "leading edge {:.1} mm behind the plate (robust {:.1} mm)",
                f.cloud_front * 1e3,
                f.cloud_front_robust * 1e3
            ),
            format!(
                "width {:.1} mm (robust {:.1} mm), hole {:.1} mm",
                f.cloud_width * 1e3,
                f.cloud_width_robust * 1e3,
                f.hole_diameter * 1e3
            ),
        ],
    };
    let path = dir.join(name);
    write_radiograph(&path, sim.particles(), sim.spacing()[0], &notes, (900, 900))?;
    Ok(path)
}

fn run_scenario(scenario: &ScenarioRun, command_line: Vec<String>) -> Result<()> {
    let started_unix_s =
        std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0.0, |d| d.as_secs_f64());
    let o = scenario.options();
    // ---- everything that can be checked before building the model -------------------
    let strategy = o.strategy;
    let threads = o.threads.unwrap_or(1);
    strategy.check_threads(threads).map_err(anyhow::Error::msg)?;
    let cpus = match &o.cpus {
        Some(list) => {
            let c = pinning::parse_cpu_list(list).context("invalid --cpus")?;
            pinning::validate_cpus(&c, threads).context("invalid --cpus")?;
            Some(c)
        }
        None => None,
    };
    let step_limit = o.steps;
    let end_time = match (o.end_time, step_limit) {
        (Some(t), _) => Some(t),
        (None, None) => Some(scenario.default_end_time()),
        (None, Some(_)) => None,
    };
    if let (Some(w), Some(n)) = (o.warmup, step_limit) {
        if n > 0 && w >= n {
            bail!(
                "--warmup {w} leaves no steady-state steps of --steps {n}: use fewer warm-up steps (e.g. --warmup {})",
                n / 10
            );
        }
    }
    let available_cores = pinning::available_cores();
    let distinct_cpus = cpus.as_ref().map(|c| {
        let mut d = c.clone();
        d.sort_unstable();
        d.dedup();
        d.len()
    });
    let oversubscribed = threads > available_cores || distinct_cpus.is_some_and(|d| d < threads);
    if oversubscribed {
        match distinct_cpus {
            Some(d) if d < threads && threads <= available_cores => eprintln!(
                "warning: oversubscribed: {threads} threads on {d} pinned CPU(s); timings of this run do not show parallel scaling"
            ),
            _ => eprintln!(
                "warning: oversubscribed: {threads} threads on {available_cores} cores; timings of this run do not show parallel scaling"
            ),
        }
    }
    let pending_json = o.json.as_deref().map(PendingFile::reserve).transpose()?;
    let mut snapshots = o.vtk.as_deref().map(|d| SnapshotWriter::new(d, scenario.name(), o.vtk_format)).transpose()?;
    let radiographs = scenario.radiograph();
    if let Some((dir, _)) = radiographs {
        std::fs::create_dir_all(dir)
            .with_context(|| format!("cannot create the radiograph directory {}", dir.display()))?;
    }

    // ---- pool, model, simulation -------------------------------------------------------
    let pool: PinnedPool = pinning::build_pool(threads, cpus.as_deref())?;
    let mismatches = pool.mismatches();
    if !mismatches.is_empty() {
        eprintln!(
            "warning: pinning not as requested (the run is marked pinning_verified = false): {}",
            mismatches.join("; ")
        );
    }
    let prepared = scenario.build()?;
    let Prepared { setup, model, velocity, wall, taylor: taylor_figures, impact: impact_geometry } = prepared;
    let model_name = setup.model.clone();
    let config = SimConfig {
        strategy,
        threads,
        grid_mode: match o.grid {
            Some(GridArg::Fixed) => GridMode::Fixed,
            Some(GridArg::Adaptive) => GridMode::Adaptive,
            None => scenario.default_grid(),
        },
        cfl: o.cfl,
        ..SimConfig::default()
    };
    let mut sim = Simulation::new(setup, config).context("cannot set up the simulation")?;
    let (cells, nodes) = (sim.geom().num_cells(), sim.geom().num_nodes());
    let warmup = o.warmup.unwrap_or_else(|| {
        let expected = match (step_limit, end_time) {
            (Some(n), None) => n,
            (Some(n), Some(t)) => n.min((t / sim.dt_first()).ceil() as u64),
            (None, Some(t)) => (t / sim.dt_first()).ceil() as u64,
            (None, None) => 0,
        };
        (expected / 10).min(5)
    });

    // ---- Ctrl-C: stop between steps, write nothing ---------------------------------------
    let interrupted = Arc::new(AtomicBool::new(false));
    {
        let flag = Arc::clone(&interrupted);
        // A second Ctrl-C ends the process at once.
        let _ = ctrlc::set_handler(move || {
            if flag.swap(true, Ordering::SeqCst) {
                std::process::exit(130);
            }
        });
    }

    // ---- the stepping loop ----------------------------------------------------------
    let mut history = HistoryRecorder::new();
    let record = |h: &mut HistoryRecorder, sim: &Simulation| {
        let d = sim.diagnostics();
        h.record(HistoryPoint { step: sim.steps(), time: sim.time(), kinetic: d.kinetic, internal: d.internal });
    };
    record(&mut history, &sim);
    if let Some(w) = snapshots.as_mut() {
        w.write(0, 0.0, sim.particles())?;
    }
    let progress = Progress::new(o.quiet, end_time, step_limit);
    let mut timing = Timing { warmup_steps: warmup, ..Timing::default() };
    let mut output = Duration::ZERO;
    let mut warm_done = warmup == 0;
    // Stop once the remaining time is below a millionth of a step (round-off).
    let tol = 1e-6 * sim.dt_first();
    let loop_start = Instant::now();
    // The whole loop runs on the pool's first worker (one hand-over to the pool per run,
    // not per step); the solver's parallel phases broadcast from there.
    let end_reason = pool.pool.install(|| -> Result<EndReason> {
        loop {
            if let Some(end) = end_time {
                if end - sim.time() <= tol {
                    return Ok(EndReason::EndTime);
                }
            }
            if step_limit.is_some_and(|n| sim.steps() >= n) {
                return Ok(EndReason::StepLimit);
            }
            if interrupted.load(Ordering::Relaxed) {
                if let Some(p) = &progress {
                    p.bar.abandon();
                }
                return Err(Interrupted(sim.steps()).into());
            }
            let dt_max = end_time.map_or(f64::INFINITY, |end| end - sim.time());
            if let Err(e) = sim.step(&pool.pool, dt_max) {
                if let Some(p) = &progress {
                    p.bar.abandon();
                }
                return Err(anyhow::Error::new(e).context(format!(
                    "the simulation failed in the step starting at t = {:.6e} s ({}, strategy {}, {} thread(s)); no summary written",
                    sim.time(),
                    scenario.describe(),
                    strategy.name(),
                    threads
                )));
            }
            record(&mut history, &sim);
            if !warm_done && sim.steps() >= warmup {
                warm_done = true;
                timing.warmup_wall_s = loop_start.elapsed().saturating_sub(output).as_secs_f64();
                timing.warmup_times = *sim.times();
                timing.warmup_busy = sim.worker_busy();
            }
            if let Some(p) = &progress {
                p.update(&sim);
            }
            if let Some(w) = snapshots.as_mut() {
                if sim.steps() % o.every == 0 {
                    let t0 = Instant::now();
                    w.write(sim.steps(), sim.time(), sim.particles())?;
                    output += t0.elapsed();
                }
            }
            if let (Some((dir, Some(k))), Some(g)) = (radiographs, impact_geometry.as_ref()) {
                if sim.steps() % k == 0 {
                    let t0 = Instant::now();
                    radiograph_png(dir, &sim, g, &format!("radiograph_{:06}.png", sim.steps()))?;
                    output += t0.elapsed();
                }
            }
        }
    })?;
    timing.wall_s = loop_start.elapsed().saturating_sub(output).as_secs_f64();
    if !warm_done {
        // The run ended inside the warm-up: no steady-state steps.
        timing.warmup_wall_s = timing.wall_s;
        timing.warmup_times = *sim.times();
        timing.warmup_busy = sim.worker_busy();
    }
    if let Some(w) = snapshots.as_mut() {
        let t0 = Instant::now();
        w.write(sim.steps(), sim.time(), sim.particles())?;
        output += t0.elapsed();
    }
    if let (Some((dir, _)), Some(g)) = (radiographs, impact_geometry.as_ref()) {
        let t0 = Instant::now();
        let path = radiograph_png(dir, &sim, g, "radiograph_final.png")?;
        output += t0.elapsed();
        if !o.quiet {
            eprintln!("radiograph: {}", path.display());
        }
    }
    timing.output_s = output.as_secs_f64();
    if let Some(p) = &progress {
        p.bar.finish_and_clear();
    }

    // ---- summary ----------------------------------------------------------------------
    let summary = Summary::build(
        &sim,
        RunContext {
            scenario: scenario.name(),
            model,
            model_name,
            velocity,
            wall,
            cells,
            nodes,
            end_time,
            step_limit,
            end_reason,
            timing: &timing,
            pool: &pool,
            available_cores,
            oversubscribed,
            history: history.finish(200),
            taylor: taylor_figures,
            impact: impact_geometry,
            command_line,
            started_unix_s,
        },
    );
    if let Some(p) = pending_json {
        let mut text = serde_json::to_string_pretty(&summary)?;
        text.push('\n');
        p.commit(text.as_bytes())?;
    }
    if !o.quiet {
        print_human(&summary, o.json.as_deref(), snapshots.as_ref());
    }
    Ok(())
}

fn group(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i) % 3 == 0 {
            out.push(',');
        }
        out.push(c);
    }
    out
}

fn print_human(s: &Summary, json: Option<&Path>, snaps: Option<&SnapshotWriter>) {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    // A closed stdout (e.g. `| head`) must not panic: write errors are ignored.
    macro_rules! out {
        ($($t:tt)*) => {{
            let _ = writeln!(stdout, $($t)*);
        }};
    }
    let what = if s.scenario == "taylor" { format!("Taylor bar Model {}", s.model) } else { s.model_name.clone() };
    out!(
        "{what} at {} m/s: {} particles, {} cells, {} nodes ({} grid, dx = {:.4} mm)",
        s.velocity_m_s,
        group(s.particles as u64),
        group(s.cells as u64),
        group(s.nodes as u64),
        s.grid_mode,
        s.dx_m * 1e3
    );
    let cpus = if s.pinned {
        format!(
            ", pinned to CPUs {} (observed {}{})",
            pinning::format_cpu_list(&s.requested_cpus),
            s.observed_cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(","),
            if s.pinning_verified == Some(true) { ", verified" } else { ", NOT as requested" }
        )
    } else {
        String::new()
    };
    out!(
        "solver: strategy {}, {} thread(s){}{}, {} build, {}, CFL {}, {} wall",
        s.strategy,
        s.threads,
        cpus,
        if s.oversubscribed { " (oversubscribed)" } else { "" },
        OPT_LEVEL,
        s.eos,
        s.cfl,
        s.wall
    );
    let reason = match s.end_reason {
        EndReason::EndTime => "end time reached",
        EndReason::StepLimit => "step limit reached",
    };
    out!("steps: {} to t = {:.3} µs ({reason}), dt first {:.3e} s", group(s.steps), s.sim_time * 1e6, s.dt_first);
    let total = s.grid_stage_s + s.particle_stage_s;
    let pct = |x: f64| if total > 0.0 { 100.0 * x / total } else { 0.0 };
    out!(
        "wall time: {:.3} s; grid-node stage {:.3} s ({:.0} %), particle stage {:.3} s ({:.0} %)",
        s.wall_s,
        s.grid_stage_s,
        pct(s.grid_stage_s),
        s.particle_stage_s,
        pct(s.particle_stage_s)
    );
    match (s.ns_per_particle_step, s.particle_steps_per_s) {
        (Some(ns), Some(rate)) => out!(
            "steady state ({} steps after {} warm-up): {:.1} ns per particle-step, {:.3e} particle-steps/s, {:.3} ms per step",
            s.steady_steps,
            s.warmup_steps,
            ns,
            rate,
            s.steady_s_per_step.unwrap_or(0.0) * 1e3
        ),
        _ => out!("steady state: no steps after the warm-up"),
    }
    if let (Some(busy), Some(imb)) = (&s.worker_busy_s, s.load_imbalance) {
        let list = busy.iter().map(|b| format!("{b:.3}")).collect::<Vec<_>>().join(" / ");
        let note = if imb > 1.1 && !s.oversubscribed {
            " (unequal: a worker's CPU was slowed from outside this run; repeat it)"
        } else {
            ""
        };
        out!("workers: busy {list} s in their shares, load imbalance {imb:.3}{note}");
    }
    if let (Some(l0), Some(l), Some(d)) = (s.initial_length_m, s.final_length_m, s.face_diameter_m) {
        out!("bar: length {:.3} mm (initial {:.3} mm), impact-face diameter {:.3} mm", l * 1e3, l0 * 1e3, d * 1e3);
    }
    if let (Some(front), Some(width)) = (s.cloud_front_m, s.cloud_width_m) {
        out!(
            "debris cloud: leading edge {:.2} mm behind the plate (robust {:.2} mm), width {:.2} mm (robust {:.2} mm), hole {:.2} mm, front velocity {:.0} m/s",
            front * 1e3,
            s.cloud_front_robust_m.unwrap_or(f64::NAN) * 1e3,
            width * 1e3,
            s.cloud_width_robust_m.unwrap_or(f64::NAN) * 1e3,
            s.hole_diameter_m.unwrap_or(f64::NAN) * 1e3,
            s.front_velocity_m_s.unwrap_or(f64::NAN)
        );
    }
    out!(
        "energy: kinetic {:.4} J (initial {:.4} J), internal {:.4} J; failed particles {}",
        s.kinetic_energy,
        s.kinetic_energy_initial,
        s.internal_energy,
        s.failed_particles
    );
    out!(
        "memory: peak RSS {}, model {:.1} MiB",
        s.peak_rss_bytes.map_or("unknown".into(), |b| format!("{:.1} MiB", b as f64 / 1048576.0)),
        s.model_memory_bytes as f64 / 1048576.0
    );
    if let Some(w) = snaps {
        out!("snapshots: {} VTU file(s), open {}", w.steps().len(), w.pvd_path().display());
    }
    if let Some(j) = json {
        out!("summary: {}", j.display());
    }
}
