//! [`RunSpec`]: one run of `mpm`, resolved and typed.
//!
//! Every way of asking for a run reaches this one value: `mpm run <scenario> --flags` builds
//! it from the command line (defaults filled in [`RunSpec::new`], the flags applied on top),
//! `mpm run --spec FILE` reads it from a TOML or JSON file, and the harness writes one file
//! per run. [`RunSpec::check`] is the one place its values are validated, and every summary
//! echoes the spec it ran under the key `spec`, so a summary's `spec` re-runs the run.
//!
//! Names are part of the interface (spec files, summaries, the harness's CSV columns):
//! scenario parameters carry their SI unit (`velocity_m_s`, `cell_m`), enums serialise by
//! their short names (`dd`, `sparse`, `hugoniot`).

use crate::scenario::Scenario;
use crate::SpecError;
use mpm_core::{BulkViscosity, GridMode, MgForm, Strategy, DEFAULT_ENERGY_RISE_LIMIT};
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use sha2::{Digest, Sha256};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Layout version of [`RunSpec`]; a spec file of another version is refused by name.
pub const SPEC_VERSION: u32 = 1;

/// The largest injected slowdown ([`RunSpec::inject_slowdown`]): every step takes
/// `1 / (1 - F)` times its own time, ten times at 0.9; beyond, a run slows without bound
/// (a million times at 0.999999) while the regression gate it calibrates looks for losses
/// of a few percent.
pub const MAX_INJECT_SLOWDOWN: f64 = 0.9;

/// One run of `mpm`: what to simulate, how to split the work, how long, and what to write.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RunSpec {
    /// [`SPEC_VERSION`] of the writer.
    pub spec_version: u32,
    /// The problem and its parameters.
    pub scenario: Scenario,
    /// How the nodal scatter is made race-free.
    pub strategy: Strategy,
    /// Worker threads of each process (rank).
    pub threads: usize,
    /// MPI ranks the run is split over (1: one process).
    #[serde(default = "one")]
    pub ranks: usize,
    /// With several ranks: boxes per axis (their product the rank count); absent: the DD
    /// patch layout for that count.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rank_layout: Option<[usize; 3]>,
    /// The CPU of each worker (one per thread); absent: not pinned (with several ranks:
    /// each rank pins inside the mask its launcher gave it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cpus: Option<Vec<usize>>,
    /// The background grid.
    pub grid: GridMode,
    /// Material model and numerics.
    pub physics: Physics,
    /// When to stop and which steps are warm-up.
    pub budget: Budget,
    /// With several ranks: wait at a barrier before each exchange operation and report that
    /// time apart from the communication.
    #[serde(default)]
    pub split_wait: bool,
    /// Measure the parallel efficiency in the paired design ([`Paired`]): a one-thread
    /// solver of the same strategy beside the `threads`-thread one, in the same process,
    /// advancing in alternating timed blocks. Absent: one solver, as usual.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub paired: Option<Paired>,
    /// A test knob, absent (off) by default: every worker but the first does extra work in
    /// the grid-node stage, so that the parallel efficiency drops by about this fraction
    /// (in (0, [`MAX_INJECT_SLOWDOWN`]]). Such a run is never a result: the summary and the harness's rows record
    /// it, and the analyses refuse it unless asked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_slowdown: Option<f64>,
    /// A test knob, absent (off) by default: after every step, every worker (of the
    /// `threads`-thread solver and of a paired run's one-thread reference alike) waits,
    /// busy, so that each step takes `1 / (1 - F)` times as long: the time per step grows,
    /// the parallel efficiency does not move (in (0, 1)). Never a result: recorded in the
    /// summary and the rows, refused by the analyses unless asked.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_step_slowdown: Option<f64>,
    /// What to write besides the run itself. Not part of [`RunSpec::key`].
    #[serde(default)]
    pub outputs: Outputs,
}

fn one() -> usize {
    1
}

/// The paired design of a run: the `threads`-thread solver and a one-thread solver of the
/// same strategy, built from the same set-up in one process (the one-thread worker pinned to
/// the first CPU of the placement), take their warm-up steps and then `blocks` timed blocks
/// each, alternating (the first of each pair alternates too), every block the same number of
/// steps: `(steps - warmup) / blocks`. Block `b` of both covers the same simulated steps, so
/// the ratio of their times compares the same work under nearly the same host conditions.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Paired {
    /// Timed blocks of each solver (at least 2).
    pub blocks: u64,
}

/// The material model and the numerics of a run.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Physics {
    /// Form of the Mie-Grüneisen equation of state.
    pub eos: MgForm,
    /// Artificial bulk viscosity coefficients (`0, 0`: off).
    pub q: BulkViscosity,
    /// CFL number in (0, 1].
    pub cfl: f64,
    /// A rise of the total energy above this fraction of its initial value stops the run.
    pub energy_rise_limit: RiseLimit,
}

/// The energy-rise check: off, or the fraction that stops a run (serialised as `"off"` or
/// the number, since JSON has no infinity).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum RiseLimit {
    /// No check.
    Off,
    /// Stop when the total energy rises more than this fraction (> 0).
    Fraction(f64),
}

impl RiseLimit {
    /// As the solver's `f64` (infinite when off).
    pub fn as_f64(self) -> f64 {
        match self {
            RiseLimit::Off => f64::INFINITY,
            RiseLimit::Fraction(f) => f,
        }
    }

    /// From the solver's `f64` (infinite: off).
    pub fn from_f64(f: f64) -> Self {
        if f == f64::INFINITY {
            RiseLimit::Off
        } else {
            RiseLimit::Fraction(f)
        }
    }
}

impl Serialize for RiseLimit {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            RiseLimit::Off => s.serialize_str("off"),
            RiseLimit::Fraction(f) => s.serialize_f64(*f),
        }
    }
}

impl<'de> Deserialize<'de> for RiseLimit {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Number(f64),
            Word(String),
            Other(serde::de::IgnoredAny),
        }
        match Raw::deserialize(d)? {
            Raw::Number(f) => Ok(RiseLimit::Fraction(f)),
            Raw::Word(w) if w == "off" || w == "inf" => Ok(RiseLimit::Off),
            Raw::Word(w) => Err(serde::de::Error::custom(format!(
                "energy_rise_limit must be a fraction > 0 or \"off\", got \"{w}\""
            ))),
            Raw::Other(_) => Err(serde::de::Error::custom("energy_rise_limit must be a fraction > 0 or \"off\"")),
        }
    }
}

impl Default for Physics {
    /// The default EOS and viscosity, CFL 0.5, the default energy-rise limit.
    fn default() -> Self {
        Self {
            eos: MgForm::default(),
            q: BulkViscosity::default(),
            cfl: mpm_core::DEFAULT_CFL,
            energy_rise_limit: RiseLimit::Fraction(DEFAULT_ENERGY_RISE_LIMIT),
        }
    }
}

/// When a run stops, and which of its first steps are left out of the steady state.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Budget {
    /// Stop after this many steps (0: build, summarise, do not step).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub steps: Option<u64>,
    /// Stop at this simulated time (s); the last step is shortened to land on it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub end_time_s: Option<f64>,
    /// Leading steps timed but left out of the steady-state figures; absent: a tenth of the
    /// expected steps, at most 5 (the summary's spec holds the number used).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub warmup: Option<u64>,
}

/// Array encoding of VTU snapshots.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum VtkEncoding {
    /// Raw binary appended after the XML, zlib-compressed in blocks (VTK's
    /// `vtkZLibDataCompressor`: ParaView and VisIt read it as it is); exact.
    #[default]
    Compressed,
    /// Inline base64 binary (exact; a third larger than raw, not compressed).
    Binary,
    /// Inline ASCII (readable; values printed in shortest round-trip form).
    Ascii,
}

/// VTU snapshots of the particles (over several ranks one piece per rank and a `.pvtu`
/// naming them).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VtkOutput {
    /// Folder of the snapshots and their `.pvd` collection (created if needed).
    pub dir: PathBuf,
    /// A snapshot every this many steps (plus the initial and the final state).
    pub every: u64,
    /// Array encoding.
    #[serde(default)]
    pub encoding: VtkEncoding,
}

/// Radiograph-style pictures of the impact's debris cloud.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RadiographOutput {
    /// Folder of the pictures (created if needed).
    pub dir: PathBuf,
    /// Also a picture every this many steps (absent: only at the end).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub every: Option<u64>,
}

/// How often a run saves its state ([`CheckpointOutput::every`]): every so many steps, or
/// after so much wall-clock time since the last checkpoint (or the run's start). Written as
/// a whole number of steps (`every = 500`) or as a duration in words (`every = "10m"`,
/// `"1h 30m"`, `"90s"`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CheckpointEvery {
    /// Every this many steps (the step count a multiple of it).
    Steps(u64),
    /// When this much wall-clock time has passed since the last checkpoint.
    Duration(Duration),
}

impl CheckpointEvery {
    /// `500` (steps) or a duration such as `10m`, `90s`, `1h 30m`.
    pub fn parse(s: &str) -> Result<Self, String> {
        let s = s.trim();
        if let Ok(n) = s.parse::<u64>() {
            return Ok(CheckpointEvery::Steps(n));
        }
        if s.starts_with('-') {
            return Err(format!(
                "'{s}' is negative: the interval must be positive, a step count such as 500 or a duration such as 10m"
            ));
        }
        humantime::parse_duration(s).map(CheckpointEvery::Duration).map_err(|e| {
            format!("'{s}' is neither a step count nor a duration ({e}): give e.g. 500 (steps) or 10m, 90s, 1h 30m")
        })
    }
}

impl std::fmt::Display for CheckpointEvery {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CheckpointEvery::Steps(n) => write!(f, "{n} steps"),
            CheckpointEvery::Duration(d) => write!(f, "{}", humantime::format_duration(*d)),
        }
    }
}

impl Serialize for CheckpointEvery {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        match self {
            CheckpointEvery::Steps(n) => s.serialize_u64(*n),
            CheckpointEvery::Duration(d) => s.serialize_str(&humantime::format_duration(*d).to_string()),
        }
    }
}

impl<'de> Deserialize<'de> for CheckpointEvery {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        #[derive(Deserialize)]
        #[serde(untagged)]
        enum Raw {
            Steps(u64),
            Words(String),
            Other(serde::de::IgnoredAny),
        }
        match Raw::deserialize(d)? {
            Raw::Steps(n) => Ok(CheckpointEvery::Steps(n)),
            Raw::Words(w) => CheckpointEvery::parse(&w).map_err(serde::de::Error::custom),
            Raw::Other(_) => Err(serde::de::Error::custom(
                "a checkpoint interval is a whole number of steps >= 1 (every = 500) or a duration (every = \"10m\")",
            )),
        }
    }
}

/// Checkpoints of a run: its whole state, saved into a folder (the last two kept) so that
/// `mpm resume DIR` continues it bit for bit.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CheckpointOutput {
    /// The folder of the checkpoints (created if needed; one folder per run).
    pub dir: PathBuf,
    /// How often.
    pub every: CheckpointEvery,
}

/// What a run writes besides its state: the JSON summary, snapshots, pictures, the final
/// particle state, checkpoints. Outputs do not change what is computed, so they are not part of
/// [`RunSpec::key`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Outputs {
    /// The JSON summary (written atomically, only when the run succeeds).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub json: Option<PathBuf>,
    /// No progress bar and no human summary.
    #[serde(default)]
    pub quiet: bool,
    /// VTU snapshots.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub vtk: Option<VtkOutput>,
    /// Radiograph-style pictures (impact only).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub radiograph: Option<RadiographOutput>,
    /// The final particle state, sorted by particle id (binary; see `mpm run --help`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dump_state: Option<PathBuf>,
    /// Checkpoints of the run's state.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checkpoint: Option<CheckpointOutput>,
}

/// The file format of a spec.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SpecFormat {
    /// TOML.
    Toml,
    /// JSON.
    Json,
}

impl SpecFormat {
    /// By the file's extension: `.json` is JSON, anything else TOML.
    pub fn of_path(path: &Path) -> Self {
        match path.extension().and_then(|e| e.to_str()) {
            Some(e) if e.eq_ignore_ascii_case("json") => SpecFormat::Json,
            _ => SpecFormat::Toml,
        }
    }
}

impl RunSpec {
    /// The run of `scenario` with every default: serial on 1 thread in one process, not
    /// pinned, the scenario's grid and CFL number, the default EOS, viscosity and energy
    /// check, the scenario's end time, no outputs.
    pub fn new(scenario: Scenario) -> Result<Self, SpecError> {
        let end_time = scenario.default_end_time()?;
        Ok(Self {
            spec_version: SPEC_VERSION,
            grid: scenario.default_grid(1),
            physics: Physics { cfl: scenario.default_cfl(), ..Physics::default() },
            scenario,
            strategy: Strategy::Serial,
            threads: 1,
            ranks: 1,
            rank_layout: None,
            cpus: None,
            budget: Budget { steps: None, end_time_s: Some(end_time), warmup: None },
            split_wait: false,
            paired: None,
            inject_slowdown: None,
            inject_step_slowdown: None,
            outputs: Outputs::default(),
        })
    }

    /// Read a spec from `text` in `format`, refusing unknown keys and other spec versions,
    /// and check it.
    pub fn parse(text: &str, format: SpecFormat) -> Result<Self, SpecError> {
        let version = match format {
            SpecFormat::Toml => toml::from_str::<toml::Table>(text)
                .map_err(|e| SpecError::Parse(e.to_string()))?
                .get("spec_version")
                .and_then(toml::Value::as_integer),
            SpecFormat::Json => serde_json::from_str::<serde_json::Value>(text)
                .map_err(|e| json_error(text, &e))?
                .get("spec_version")
                .and_then(serde_json::Value::as_i64),
        };
        match version {
            Some(v) if v == i64::from(SPEC_VERSION) => {}
            Some(v) => return Err(SpecError::Version(v)),
            None => {
                return Err(SpecError::Parse(format!(
                    "the key `spec_version` is missing or not a whole number: give spec_version = {SPEC_VERSION}"
                )))
            }
        }
        let spec: RunSpec = match format {
            SpecFormat::Toml => serde_path_to_error::deserialize(toml::Deserializer::new(text))
                .map_err(|e| at_key(e.path(), e.inner().to_string()))?,
            SpecFormat::Json => serde_path_to_error::deserialize(&mut serde_json::Deserializer::from_str(text))
                .map_err(|e| at_key(e.path(), json_error(text, e.inner()).to_string()))?,
        };
        spec.check()?;
        Ok(spec)
    }

    /// Read and check the spec file at `path` (TOML, or JSON by its extension). A JSON
    /// summary is accepted too: its `spec` is taken.
    pub fn read(path: &Path) -> Result<Self, SpecError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| SpecError::Io(format!("cannot read the spec file {}: {e}", path.display())))?;
        let format = SpecFormat::of_path(path);
        if format == SpecFormat::Json {
            if let Ok(serde_json::Value::Object(m)) = serde_json::from_str::<serde_json::Value>(&text) {
                if let Some(inner) = m.get("spec").filter(|_| !m.contains_key("spec_version")) {
                    return Self::parse(&inner.to_string(), SpecFormat::Json);
                }
            }
        }
        Self::parse(&text, format)
    }

    /// As TOML text (what `mpm run ... --print-spec` prints).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).expect("a run spec serialises to TOML")
    }

    /// As pretty JSON text.
    pub fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).expect("a run spec serialises to JSON")
    }

    /// The spec without its outputs, as canonical JSON (keys in declaration order, numbers
    /// in shortest round-trip form): equal for two specs exactly when they compute the same.
    pub fn canonical(&self) -> String {
        let compute = RunSpec { outputs: Outputs::default(), ..self.clone() };
        serde_json::to_string(&compute).expect("a run spec serialises to JSON")
    }

    /// SHA-256 of [`RunSpec::canonical`], hex: what identifies the computation.
    pub fn key(&self) -> String {
        hex_sha256(self.canonical().as_bytes())
    }

    /// Workers of the whole run: ranks x threads per rank.
    pub fn total_workers(&self) -> usize {
        self.ranks * self.threads
    }

    /// Steps the run is expected to take with first step `dt_first` (s): its step budget,
    /// or its end time over the first step, whichever is less (`u64::MAX` for an end time
    /// no number of such steps reaches).
    pub fn expected_steps(&self, dt_first: f64) -> u64 {
        // `as` saturates: an infinite or huge count is u64::MAX, a NaN 0.
        let by_time = |t: f64| if dt_first > 0.0 { (t / dt_first).ceil() as u64 } else { u64::MAX };
        match (self.budget.steps, self.budget.end_time_s) {
            (Some(n), None) => n,
            (Some(n), Some(t)) => n.min(by_time(t)),
            (None, Some(t)) => by_time(t),
            (None, None) => 0,
        }
    }

    /// Warm-up steps when the spec gives none: a tenth of the steps expected with first
    /// step `dt_first`, at most 5.
    pub fn default_warmup(&self, dt_first: f64) -> u64 {
        (self.expected_steps(dt_first) / 10).min(5)
    }

    /// Every check of the spec that needs no machine: ranges, the strategy against the
    /// threads, the CPU list, the budget, the grid and outputs against the ranks. The error
    /// names the spec key and the `mpm run` flag.
    pub fn check(&self) -> Result<(), SpecError> {
        let bad = |key: &'static str, flag: &'static str, why: String| Err(SpecError::Invalid { key, flag, why });
        if self.spec_version != SPEC_VERSION {
            return Err(SpecError::Version(i64::from(self.spec_version)));
        }
        self.scenario.check()?;
        if self.threads == 0 {
            return bad("threads", "--threads", "the thread count must be at least 1, got 0".into());
        }
        if let Err(e) = self.strategy.check_threads(self.threads) {
            return bad("strategy", "--strategy", e);
        }
        if self.ranks == 0 {
            return bad("ranks", "--ranks", "the rank count must be at least 1, got 0".into());
        }
        if let Some(l) = self.rank_layout {
            if self.ranks == 1 && l.iter().product::<usize>() > 1 {
                return bad(
                    "rank_layout",
                    "--rank-layout",
                    "a layout of several boxes needs several ranks: start the run with `mpirun -n R mpm run ...`"
                        .into(),
                );
            }
            if l.contains(&0) || l.iter().product::<usize>() != self.ranks {
                return bad(
                    "rank_layout",
                    "--rank-layout",
                    format!(
                        "the layout {}x{}x{} does not make {} rank(s): give positive counts whose product is the rank count",
                        l[0], l[1], l[2], self.ranks
                    ),
                );
            }
        }
        if let Some(cpus) = &self.cpus {
            if cpus.len() != self.threads {
                return bad(
                    "cpus",
                    "--cpus",
                    format!(
                        "{} CPU(s) given for {} thread(s): give exactly one CPU per worker thread",
                        cpus.len(),
                        self.threads
                    ),
                );
            }
        }
        if self.grid == GridMode::Sparse && self.ranks > 1 {
            return bad(
                "grid",
                "--grid",
                "the sparse grid runs in one process only: use the adaptive grid over several ranks".into(),
            );
        }
        if self.split_wait && self.ranks == 1 {
            return bad(
                "split_wait",
                "--split-wait",
                "there is no other rank to wait for in one process: use it with several ranks".into(),
            );
        }
        self.check_physics()?;
        self.check_budget()?;
        self.check_paired()?;
        for (f, key, flag) in [
            (self.inject_slowdown, "inject_slowdown", "--inject-slowdown"),
            (self.inject_step_slowdown, "inject_step_slowdown", "--inject-step-slowdown"),
        ] {
            if let Some(f) = f.filter(|f| !(*f > 0.0 && *f <= MAX_INJECT_SLOWDOWN)) {
                return bad(
                    key,
                    flag,
                    format!(
                        "the injected slowdown is a fraction in (0, {MAX_INJECT_SLOWDOWN}] such as 0.1, got {f}: it \
                         makes every step 1 / (1 - F) times as long, {MAX_INJECT_SLOWDOWN} already ten times, and \
                         0.999999 a million times (a run that never ends)"
                    ),
                );
            }
        }
        self.check_outputs()
    }

    /// Steps per block of a paired run with `warmup` warm-up steps: `(steps - warmup) /
    /// blocks`, which must be a whole number of at least one step.
    pub fn paired_block_steps(&self, warmup: u64) -> Result<u64, SpecError> {
        let Some(p) = self.paired else {
            return Err(SpecError::Invalid { key: "paired", flag: "--paired-blocks", why: "not a paired run".into() });
        };
        let steps = self.budget.steps.unwrap_or(0);
        let timed = steps.saturating_sub(warmup);
        if p.blocks == 0 || timed < p.blocks || !timed.is_multiple_of(p.blocks) {
            return Err(SpecError::Invalid {
                key: "budget.steps",
                flag: "--steps",
                why: format!(
                    "a paired run of {} blocks takes warm-up + blocks x steps per block steps: {steps} steps with {warmup} warm-up leave {timed}, not a multiple of {} (e.g. --steps {})",
                    p.blocks,
                    p.blocks,
                    warmup.saturating_add(p.blocks.saturating_mul((timed / p.blocks.max(1)).max(1)))
                ),
            });
        }
        Ok(timed / p.blocks)
    }

    fn check_paired(&self) -> Result<(), SpecError> {
        let Some(p) = self.paired else { return Ok(()) };
        let bad = |key: &'static str, flag: &'static str, why: String| Err(SpecError::Invalid { key, flag, why });
        if !self.strategy.is_parallel() || self.threads < 2 {
            return bad(
                "paired",
                "--paired-blocks",
                format!(
                    "the paired design compares a parallel strategy's 1-thread and T-thread solvers: use {} with 2 or more threads (got {} with {})",
                    Strategy::parallel_names(),
                    self.strategy,
                    self.threads
                ),
            );
        }
        if self.ranks > 1 {
            return bad("paired", "--paired-blocks", "the paired design runs in one process, not over ranks".into());
        }
        if self.outputs.checkpoint.is_some() {
            return bad(
                "paired",
                "--paired-blocks",
                "a paired run is one measurement of alternating blocks and cannot be continued from a checkpoint: \
                 leave out --checkpoint-dir"
                    .into(),
            );
        }
        if p.blocks < 2 {
            return bad(
                "paired.blocks",
                "--paired-blocks",
                format!("{} block(s) give no spread: use at least 2", p.blocks),
            );
        }
        if self.budget.steps.is_none() {
            return bad(
                "budget.steps",
                "--steps",
                "a paired run needs a step budget (warm-up + blocks x steps per block)".into(),
            );
        }
        if let Some(w) = self.budget.warmup {
            self.paired_block_steps(w)?;
        }
        Ok(())
    }

    fn check_physics(&self) -> Result<(), SpecError> {
        let p = &self.physics;
        if !(p.cfl > 0.0 && p.cfl <= 1.0) {
            return Err(SpecError::Invalid {
                key: "physics.cfl",
                flag: "--cfl",
                why: format!("the CFL number must be in (0, 1], got {}", p.cfl),
            });
        }
        if let Err(e) = p.q.validate() {
            return Err(SpecError::Invalid { key: "physics.q", flag: "--q", why: e.to_string() });
        }
        if let RiseLimit::Fraction(f) = p.energy_rise_limit {
            if !(f > 0.0 && f.is_finite()) {
                return Err(SpecError::Invalid {
                    key: "physics.energy_rise_limit",
                    flag: "--energy-rise-limit",
                    why: format!("the energy rise limit must be a fraction > 0 (or off), got {f}"),
                });
            }
        }
        Ok(())
    }

    fn check_budget(&self) -> Result<(), SpecError> {
        let b = &self.budget;
        if b.steps.is_none() && b.end_time_s.is_none() {
            return Err(SpecError::Invalid {
                key: "budget",
                flag: "--steps / --end-time",
                why: "the run has no end: give a step limit, an end time or both".into(),
            });
        }
        if let Some(t) = b.end_time_s {
            if !(t.is_finite() && t > 0.0) {
                return Err(SpecError::Invalid {
                    key: "budget.end_time_s",
                    flag: "--end-time",
                    why: format!("the end time must be a positive number of seconds (e.g. 40e-6), got {t}"),
                });
            }
        }
        if let (Some(w), Some(n)) = (b.warmup, b.steps) {
            if n > 0 && w >= n {
                return Err(SpecError::Invalid {
                    key: "budget.warmup",
                    flag: "--warmup",
                    why: format!("{w} warm-up step(s) leave no steady-state steps of {n}: use fewer (e.g. {})", n / 10),
                });
            }
        }
        Ok(())
    }

    fn check_outputs(&self) -> Result<(), SpecError> {
        let o = &self.outputs;
        match o.checkpoint.as_ref().map(|c| c.every) {
            Some(CheckpointEvery::Steps(0)) => {
                return Err(SpecError::Invalid {
                    key: "outputs.checkpoint.every",
                    flag: "--checkpoint-every",
                    why: "a checkpoint every 0 steps: give at least 1 (or a duration such as 10m)".into(),
                })
            }
            Some(CheckpointEvery::Duration(d)) if d.is_zero() => {
                return Err(SpecError::Invalid {
                    key: "outputs.checkpoint.every",
                    flag: "--checkpoint-every",
                    why: "a checkpoint every 0 s: give a positive duration such as 10m (or a step count)".into(),
                })
            }
            _ => {}
        }
        if o.vtk.as_ref().is_some_and(|v| v.every == 0) {
            return Err(SpecError::Invalid {
                key: "outputs.vtk.every",
                flag: "--every",
                why: "a snapshot every 0 steps: give at least 1".into(),
            });
        }
        if let Some(r) = &o.radiograph {
            if !matches!(self.scenario, Scenario::Impact(_)) {
                return Err(SpecError::Invalid {
                    key: "outputs.radiograph",
                    flag: "--radiograph",
                    why: "radiographs are drawn of the impact's debris cloud only".into(),
                });
            }
            if r.every == Some(0) {
                return Err(SpecError::Invalid {
                    key: "outputs.radiograph.every",
                    flag: "--radiograph-every",
                    why: "a picture every 0 steps: give at least 1".into(),
                });
            }
        }
        if self.ranks > 1 && o.radiograph.is_some() {
            return Err(SpecError::Invalid {
                key: "outputs.radiograph",
                flag: "--radiograph",
                why: "radiographs are not drawn over several ranks (each holds part of the cloud): run them in one \
                      process, or write --vtk snapshots, one piece per rank"
                    .into(),
            });
        }
        Ok(())
    }
}

/// A spec file's error at the key `path` (named unless it is the root).
fn at_key(path: &serde_path_to_error::Path, why: String) -> SpecError {
    let why = why.strip_prefix("cannot read the spec: ").unwrap_or(&why).to_string();
    match path.to_string().as_str() {
        "." | "" => SpecError::Parse(why),
        key => SpecError::Parse(format!("at key `{key}`: {why}")),
    }
}

/// A JSON spec's error with the text where it is (JSON's errors give only a line and a
/// column; TOML's show the line): up to 40 characters before the column and 20 after, so
/// that the key is named.
fn json_error(text: &str, e: &serde_json::Error) -> SpecError {
    let line = text.lines().nth(e.line().saturating_sub(1)).unwrap_or("");
    let chars: Vec<char> = line.chars().collect();
    let col = e.column().min(chars.len());
    let near: String = chars[col.saturating_sub(40)..(col + 20).min(chars.len())].iter().collect();
    match near.trim() {
        "" => SpecError::Parse(e.to_string()),
        near => SpecError::Parse(format!("{e}, at `{near}`")),
    }
}

/// Lower-case hex SHA-256 of `bytes`.
pub fn hex_sha256(bytes: &[u8]) -> String {
    Sha256::digest(bytes).iter().map(|b| format!("{b:02x}")).collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::{Contact, ImpactSpec, PlateSpec, TaylorSpec};

    fn taylor(model: u8) -> RunSpec {
        RunSpec::new(Scenario::Taylor(TaylorSpec::model(model))).unwrap()
    }

    /// A paired DD run on 2 threads of `blocks` blocks, `steps` steps (and no end time when
    /// `steps` is given), `warmup` warm-up steps.
    fn paired(blocks: u64, steps: u64, warmup: Option<u64>) -> RunSpec {
        let mut s = taylor(1);
        s.strategy = Strategy::DomainDecomposition;
        s.threads = 2;
        s.paired = Some(Paired { blocks });
        s.budget = Budget { steps: (warmup.is_some()).then_some(steps), end_time_s: Some(4e-5), warmup };
        s
    }

    /// A paired run's blocks: warm-up + blocks x steps per block; the new keys are absent
    /// from a spec without them (its key is unchanged) and round-trip when present.
    #[test]
    fn paired_blocks_divide_the_steps() {
        let s = paired(4, 14, Some(2));
        s.check().unwrap();
        assert_eq!(s.paired_block_steps(2).unwrap(), 3);
        let err = s.paired_block_steps(3).unwrap_err().to_string();
        assert!(err.contains("not a multiple of 4") && err.contains("--steps 11"), "{err}");
        let plain = taylor(1);
        assert!(!plain.to_json().contains("paired") && !plain.to_json().contains("inject"));
        let mut knob = s.clone();
        knob.inject_slowdown = Some(0.1);
        assert_eq!(RunSpec::parse(&knob.to_toml(), SpecFormat::Toml).unwrap(), knob);
        assert_ne!(knob.key(), s.key(), "an injected run is another computation's timing");
        let mut step = s.clone();
        step.inject_step_slowdown = Some(0.1);
        step.check().unwrap();
        assert_eq!(RunSpec::parse(&step.to_toml(), SpecFormat::Toml).unwrap(), step);
        assert_ne!(step.key(), s.key());
        assert_ne!(step.key(), knob.key());
    }

    #[test]
    fn defaults_are_the_scenarios() {
        let t = taylor(1);
        assert_eq!((t.grid, t.physics.cfl, t.budget.end_time_s), (GridMode::Fixed, 0.5, Some(40e-6)));
        let i = RunSpec::new(Scenario::Impact(ImpactSpec::default())).unwrap();
        assert_eq!((i.grid, i.budget.end_time_s), (GridMode::Sparse, Some(30.6e-6)));
        let p = RunSpec::new(Scenario::Plate(PlateSpec::default())).unwrap();
        assert_eq!(p.physics.cfl, 0.2);
        assert!(p.budget.end_time_s.unwrap() > 0.0);
        for s in [t, i, p] {
            s.check().unwrap();
        }
    }

    /// TOML and JSON round trips are exact (floats included), and the key ignores outputs
    /// but nothing else.
    #[test]
    fn round_trips_and_keys() {
        let mut s = taylor(2);
        s.strategy = Strategy::DomainDecomposition;
        s.threads = 2;
        s.cpus = Some(vec![0, 1]);
        s.physics.q = BulkViscosity { c1: 1.25, c2: 0.1 };
        s.physics.energy_rise_limit = RiseLimit::Off;
        s.budget = Budget { steps: Some(30), end_time_s: Some(1.0e-5 / 3.0), warmup: Some(3) };
        s.outputs.json = Some("x.json".into());
        for every in [CheckpointEvery::Steps(250), CheckpointEvery::Duration(Duration::from_secs(5430))] {
            s.outputs.checkpoint = Some(CheckpointOutput { dir: "ck".into(), every });
            assert_eq!(RunSpec::parse(&s.to_toml(), SpecFormat::Toml).unwrap(), s);
            assert_eq!(RunSpec::parse(&s.to_json(), SpecFormat::Json).unwrap(), s);
        }
        assert!(s.to_toml().contains(r#"every = "1h 30m 30s""#), "{}", s.to_toml());
        let no_out = RunSpec { outputs: Outputs::default(), ..s.clone() };
        assert_eq!(no_out.key(), s.key());
        let other = RunSpec {
            scenario: Scenario::Taylor(TaylorSpec { wall: Contact::Sticking, ..TaylorSpec::model(2) }),
            ..s.clone()
        };
        assert_ne!(other.key(), s.key());
        let other = RunSpec { physics: Physics { cfl: 0.4, ..s.physics }, ..s.clone() };
        assert_ne!(other.key(), s.key());
    }

    #[test]
    fn checkpoint_intervals_are_steps_or_durations() {
        assert_eq!(CheckpointEvery::parse("500"), Ok(CheckpointEvery::Steps(500)));
        assert_eq!(CheckpointEvery::parse(" 10m"), Ok(CheckpointEvery::Duration(Duration::from_secs(600))));
        assert_eq!(CheckpointEvery::parse("1h 30m"), Ok(CheckpointEvery::Duration(Duration::from_secs(5400))));
        let err = CheckpointEvery::parse("10 minutes please").unwrap_err();
        assert!(err.contains("neither a step count nor a duration"), "{err}");
        assert!(CheckpointEvery::parse("-3").is_err());
    }

    #[test]
    fn unknown_keys_and_versions_are_refused_by_name() {
        let text = taylor(1).to_toml();
        let err = RunSpec::parse(&text.replace("threads = 1", "threads = 1\nthreds = 2"), SpecFormat::Toml)
            .unwrap_err()
            .to_string();
        assert!(err.contains("threds"), "{err}");
        let err = RunSpec::parse(&text.replace("spec_version = 1", "spec_version = 7"), SpecFormat::Toml)
            .unwrap_err()
            .to_string();
        assert!(err.contains("version 7"), "{err}");
    }

    #[test]
    fn checks_name_the_key_and_the_flag() {
        let cases: Vec<(RunSpec, &str)> = vec![
            (RunSpec { threads: 2, ..taylor(1) }, "--strategy"),
            (RunSpec { threads: 0, ..taylor(1) }, "--threads"),
            (RunSpec { cpus: Some(vec![0, 1]), ..taylor(1) }, "--cpus"),
            (RunSpec { physics: Physics { cfl: 1.5, ..Physics::default() }, ..taylor(1) }, "--cfl"),
            (RunSpec { budget: Budget { steps: Some(5), end_time_s: None, warmup: Some(5) }, ..taylor(1) }, "--warmup"),
            (RunSpec { budget: Budget::default(), ..taylor(1) }, "--steps / --end-time"),
            (RunSpec { grid: GridMode::Sparse, ranks: 2, ..taylor(1) }, "--grid"),
            (RunSpec { rank_layout: Some([2, 2, 1]), ranks: 2, ..taylor(1) }, "--rank-layout"),
            (RunSpec { split_wait: true, ..taylor(1) }, "--split-wait"),
            (
                RunSpec {
                    outputs: Outputs {
                        checkpoint: Some(CheckpointOutput { dir: "c".into(), every: CheckpointEvery::Steps(0) }),
                        ..Outputs::default()
                    },
                    ..taylor(1)
                },
                "--checkpoint-every",
            ),
            (RunSpec { inject_slowdown: Some(1.0), ..taylor(1) }, "--inject-slowdown"),
            (RunSpec { inject_step_slowdown: Some(0.0), ..taylor(1) }, "--inject-step-slowdown"),
            (RunSpec { paired: Some(Paired { blocks: 4 }), ..taylor(1) }, "--paired-blocks"),
            (paired(4, 12, Some(2)), "--steps"),
            (paired(1, 12, Some(2)), "--paired-blocks"),
            (paired(4, 12, None), "--steps"),
            (
                RunSpec {
                    outputs: Outputs {
                        checkpoint: Some(CheckpointOutput { dir: "c".into(), every: CheckpointEvery::Steps(5) }),
                        ..Outputs::default()
                    },
                    ..paired(4, 14, Some(2))
                },
                "--paired-blocks",
            ),
        ];
        for (spec, flag) in cases {
            let err = spec.check().unwrap_err().to_string();
            assert!(err.contains(flag), "{flag}: {err}");
        }
    }

    /// Snapshots run over ranks (a piece per rank and a `.pvtu` each); radiographs stay in
    /// one process.
    #[test]
    fn snapshots_run_over_ranks_radiographs_do_not() {
        let vtk = VtkOutput { dir: "v".into(), every: 5, encoding: VtkEncoding::Compressed };
        let s = RunSpec { ranks: 2, outputs: Outputs { vtk: Some(vtk), ..Outputs::default() }, ..taylor(1) };
        s.check().unwrap();
        let mut i = RunSpec::new(Scenario::Impact(ImpactSpec::default())).unwrap();
        i.ranks = 2;
        i.grid = GridMode::Adaptive;
        i.check().unwrap();
        i.outputs.radiograph = Some(RadiographOutput { dir: "r".into(), every: None });
        let err = i.check().unwrap_err().to_string();
        assert!(err.contains("--radiograph") && err.contains("several ranks"), "{err}");
    }

    #[test]
    fn a_summary_file_is_read_through_its_spec() {
        let s = taylor(3);
        let dir = std::env::temp_dir().join(format!("mpm-spec-test-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("summary.json");
        std::fs::write(&path, format!("{{\"scenario\": \"taylor\", \"spec\": {}}}", s.to_json())).unwrap();
        assert_eq!(RunSpec::read(&path).unwrap(), s);
        std::fs::remove_dir_all(dir).unwrap();
    }
}
