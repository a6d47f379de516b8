//! Campaign matrices: a preset and the command-line overrides resolved into a validated
//! campaign, its expansion into runs, and the seeded, interleaved run order.
//!
//! Expansion: every combination of the preset's models x ranks x threads x strategies x
//! optimisation levels x repetitions x pinning policies becomes a [`PlannedRun`]: the
//! solver's [`RunSpec`] (scenario, strategy, threads, ranks, grid, physics, the step budget
//! of its (model, optimisation level) cell) with the harness's optimisation level, pinning
//! policy, launcher and repetition. Every planned spec is checked as the solver checks it
//! (a warm-up not shorter than the steps is an error here too); the `serial` strategy only
//! pairs with one thread (per rank). `threads` is per rank; a run occupies ranks x threads workers. Order: repetition by repetition, each repetition's configurations shuffled by
//! a seeded Fisher-Yates (SplitMix64, stable across versions), so machine drift spreads over
//! every cell instead of biasing one.

use super::memory::impact_variant;
use super::preset::{parse_size, BudgetOverride, BudgetSpec, OptLevel, Preset};
use crate::campaign::exec::launcher::Launcher;
use crate::machine::placement::{PinPolicy, Places};
use crate::util::SplitMix64;
use anyhow::{anyhow, bail, Context, Result};
use mpm_core::{GridMode, Strategy};
use mpm_spec::scenario::{ImpactSpec, PlateSpec, TaylorSpec};
use mpm_spec::spec::{hex_sha256, Budget, CheckpointEvery, Outputs};
use mpm_spec::{RunSpec, Scenario, ScenarioKind};
use serde::{Deserialize, Serialize};
use std::time::Duration;

/// The most repetitions a cell may plan ([`Campaign`]'s check): beyond, a plan of hundreds of
/// thousands of runs takes minutes to build and days to run.
pub const MAX_REPS: u32 = 1000;

/// Models of the Taylor bar benchmark.
pub const KNOWN_MODELS: [u32; 4] = [1, 2, 3, 4];

/// Command-line overrides of a preset (every field optional).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overrides {
    /// `--models`.
    pub models: Option<Vec<u32>>,
    /// `--threads` (per rank).
    pub threads: Option<Vec<usize>>,
    /// `--ranks`.
    pub ranks: Option<Vec<usize>>,
    /// `--launcher` (not part of the campaign id: it says how ranks start, not what runs).
    pub launcher: Option<String>,
    /// `--strategies`.
    pub strategies: Option<Vec<Strategy>>,
    /// `--opt`.
    pub opt: Option<Vec<OptLevel>>,
    /// `--reps`.
    pub reps: Option<u32>,
    /// `--bind` / `--pin` (repeatable), with `--places` applied.
    pub pin: Option<Vec<PinPolicy>>,
    /// `--places`: applies to the preset's bindings when `--bind` is not given.
    pub places: Option<Places>,
    /// `--steps` (replaces every budget of the preset).
    pub steps: Option<u64>,
    /// `--end-time` (replaces every budget of the preset).
    pub end_time: Option<f64>,
    /// `--warmup`.
    pub warmup: Option<u64>,
    /// `--grid`.
    pub grid: Option<GridMode>,
    /// `--mem-limit` in bytes.
    pub mem_limit: Option<u64>,
    /// `--seed` (order only: not part of the campaign id).
    pub seed: Option<u64>,
    /// `--checkpoint-every` (how runs survive, not what runs: not part of the campaign id).
    pub checkpoint_every: Option<CheckpointEvery>,
    /// `--paired-blocks`: the cells of two or more threads in the paired design with this
    /// many blocks (replaces the preset's `paired`; 0 turns it off).
    pub paired_blocks: Option<u64>,
    /// `--inject-slowdown`: the test knob of every run (never a result).
    pub inject_slowdown: Option<f64>,
    /// `--skip-above-cores`: leave out the cells of more workers than the machine's usable
    /// cores (also when the preset does not say so).
    pub skip_above_cores: bool,
    /// `--inject-step-slowdown`: the other test knob (every worker alike: the time per step).
    pub inject_step_slowdown: Option<f64>,
}

impl Overrides {
    /// The preset's budget section after these overrides: a budget on the command line
    /// replaces every budget of the preset, a warm-up every warm-up.
    fn budget_of(&self, preset: &BudgetSpec) -> BudgetSpec {
        let mut budget = preset.clone();
        if self.steps.is_some() || self.end_time.is_some() {
            budget.steps = self.steps;
            budget.end_time = self.end_time;
            for o in &mut budget.overrides {
                o.steps = None;
                o.end_time = None;
            }
        }
        if let Some(w) = self.warmup {
            budget.warmup = w;
            for o in &mut budget.overrides {
                o.warmup = None;
            }
        }
        budget
    }

    /// Slug of the overrides that change what runs (seed excluded), e.g. `m1-2_t1-2_n5`.
    pub fn slug(&self) -> String {
        let join = |v: Vec<String>| v.join("-");
        let mut parts: Vec<String> = Vec::new();
        if let Some(m) = &self.models {
            parts.push(format!("m{}", join(m.iter().map(|x| x.to_string()).collect())));
        }
        if let Some(t) = &self.threads {
            parts.push(format!("t{}", join(t.iter().map(|x| x.to_string()).collect())));
        }
        if let Some(r) = &self.ranks {
            parts.push(format!("ranks{}", join(r.iter().map(|x| x.to_string()).collect())));
        }
        if let Some(s) = &self.strategies {
            parts.push(join(s.iter().map(|x| x.to_string()).collect()));
        }
        if let Some(o) = &self.opt {
            parts.push(join(o.iter().map(|x| x.to_string()).collect()));
        }
        if let Some(r) = self.reps {
            parts.push(format!("r{r}"));
        }
        if let Some(p) = &self.pin {
            parts.push(format!("pin-{}", join(p.iter().map(|x| x.label().replace(',', ".")).collect())));
        }
        if let (None, Some(k)) = (&self.pin, self.places) {
            parts.push(format!("places-{k}"));
        }
        if let Some(n) = self.steps {
            parts.push(format!("n{n}"));
        }
        if let Some(t) = self.end_time {
            parts.push(format!("end{t:e}"));
        }
        if let Some(w) = self.warmup {
            parts.push(format!("w{w}"));
        }
        if let Some(g) = self.grid {
            parts.push(g.name().to_string());
        }
        if let Some(m) = self.mem_limit {
            parts.push(format!("mem{}M", m >> 20));
        }
        if let Some(b) = self.paired_blocks {
            parts.push(format!("paired{b}"));
        }
        if let Some(f) = self.inject_slowdown {
            parts.push(format!("inject{f}"));
        }
        if let Some(f) = self.inject_step_slowdown {
            parts.push(format!("injectstep{f}"));
        }
        parts.join("_")
    }
}

/// What identifies a configuration for resuming: two rows with the same key ran the same
/// thing. `<hash>-r<repetition>`, the hash the 64 hex digits of a SHA-256
/// ([`PlannedRun::key`]); rows of older campaigns carry the first 16 digits only (the short
/// form, [`RunKey::names`]).
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RunKey(pub String);

impl RunKey {
    /// Hex digits of the hash in the short form older campaigns wrote.
    pub const SHORT_DIGITS: usize = 16;

    /// The hash and the repetition (`None` when the key is not of the form `<hex>-r<n>`).
    fn parts(&self) -> Option<(&str, &str)> {
        let (hash, rep) = self.0.rsplit_once("-r")?;
        let hex = !hash.is_empty() && hash.bytes().all(|b| b.is_ascii_hexdigit());
        (hex && !rep.is_empty() && rep.bytes().all(|b| b.is_ascii_digit())).then_some((hash, rep))
    }

    /// Whether this key is of the short form of older campaigns (16 hex digits of the hash).
    pub fn is_short(&self) -> bool {
        self.parts().is_some_and(|(hash, _)| hash.len() == Self::SHORT_DIGITS)
    }

    /// The short form of this key (itself when it is short, or not a key of the harness).
    pub fn short(&self) -> RunKey {
        match self.parts() {
            Some((hash, rep)) if hash.len() > Self::SHORT_DIGITS => {
                RunKey(format!("{}-r{rep}", &hash[..Self::SHORT_DIGITS]))
            }
            _ => self.clone(),
        }
    }

    /// Whether a row carrying this key is a row of `other`'s run: the same key, or the short
    /// form of the other (either way round). A short key names every full key it is the
    /// prefix of: whoever matches rows to planned runs must see that it names one only.
    pub fn names(&self, other: &RunKey) -> bool {
        self == other
            || (self.is_short() && !other.is_short() && other.short() == *self)
            || (other.is_short() && !self.is_short() && self.short() == *other)
    }
}

/// One run of the matrix: the solver's spec and what the harness adds to it. Its
/// serialisation is the run's configuration columns in the CSV (the spec flattened).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct PlannedRun {
    /// What the solver runs (no CPUs and no outputs: those are the run's own, added when it
    /// starts).
    #[serde(flatten)]
    pub spec: RunSpec,
    /// The matrix's model number: Taylor Model 1-4, or the impact's variant 1-4 (see
    /// [`impact_variant`]).
    pub model: u32,
    /// Optimisation level of the solver binary.
    pub opt: OptLevel,
    /// Pinning policy.
    pub pin: PinPolicy,
    /// With several ranks: the launcher command (expanded); absent at one rank.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub launcher: Option<String>,
    /// Repetition index.
    pub rep: u32,
}

impl PlannedRun {
    /// Taylor bar Model `model` with `strategy` on `threads` threads (one process), built by
    /// `opt`, `steps` steps without warm-up, pinned `close`, repetition 0; every other setting
    /// the solver's default. For tools and tests that need a run without a preset.
    pub fn taylor(model: u32, strategy: Strategy, opt: OptLevel, threads: usize, steps: u64) -> Self {
        let mut spec = RunSpec::new(Scenario::Taylor(TaylorSpec::model(u8::try_from(model).unwrap_or(0))))
            .expect("the Taylor bar's defaults are valid");
        spec.strategy = strategy;
        spec.threads = threads;
        spec.budget = Budget { steps: Some(steps), end_time_s: None, warmup: Some(0) };
        Self { spec, model, opt, pin: PinPolicy::CLOSE, launcher: None, rep: 0 }
    }

    /// One planned run per scenario with every optional part of the plan present (ranks'
    /// layout, budget, paired design, injected slowdown, launcher): the planned run's columns.
    pub fn shapes() -> Vec<Self> {
        [
            Scenario::Taylor(TaylorSpec::model(1)),
            Scenario::Impact(ImpactSpec::default()),
            Scenario::Plate(PlateSpec::default()),
        ]
        .into_iter()
        .map(|scenario| {
            let mut spec = RunSpec::new(scenario).expect("the default scenarios build");
            spec.rank_layout = Some([1, 1, 1]);
            spec.budget.steps = Some(1);
            spec.budget.warmup = Some(0);
            spec.paired = Some(mpm_spec::spec::Paired { blocks: 0 });
            spec.inject_slowdown = Some(0.0);
            spec.inject_step_slowdown = Some(0.0);
            Self { spec, model: 1, opt: OptLevel::O3, pin: PinPolicy::CLOSE, launcher: Some("mpirun".into()), rep: 0 }
        })
        .collect()
    }

    /// Short human description: `Model4 ae o0 8 thr pin close rep 0`, with several ranks
    /// `Model3 dd o3 2 ranks x 2 thr pin close rep 0`.
    pub fn describe(&self) -> String {
        let kind = if self.spec.scenario.kind() == ScenarioKind::Impact { "Impact" } else { "Model" };
        let ranks = if self.spec.ranks > 1 { format!("{} ranks x ", self.spec.ranks) } else { String::new() };
        format!(
            "{kind}{} {} {} {ranks}{} thr pin {} rep {}",
            self.model, self.spec.strategy, self.opt, self.spec.threads, self.pin, self.rep
        )
    }

    /// Workers of the whole run: ranks x threads per rank (what oversubscription counts).
    pub fn total_threads(&self) -> usize {
        self.spec.total_workers()
    }

    /// Resume key: the SHA-256 (64 hex digits) of the canonical JSON of everything that
    /// makes the run (the solver's spec without CPUs and outputs, the
    /// optimisation level, pinning policy, launcher and model), and the repetition. Any
    /// change of scenario, physics, budget, launcher, or a solver option added later, makes
    /// another run.
    pub fn key(&self) -> RunKey {
        let mut canonical = self.clone();
        canonical.rep = 0;
        canonical.spec.cpus = None;
        canonical.spec.outputs = Outputs::default();
        let text = serde_json::to_string(&canonical).expect("a planned run serialises");
        RunKey(format!("{}-r{}", hex_sha256(text.as_bytes()), self.rep))
    }

    /// A readable label of the configuration for run ids: `m1-dd-o3-t2-close`, with ranks
    /// `m1-dd-o3-t2-ranks2-close`.
    pub fn label(&self) -> String {
        let ranks = if self.spec.ranks > 1 { format!("-ranks{}", self.spec.ranks) } else { String::new() };
        let pin: String =
            self.pin.label().chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' { c } else { '.' }).collect();
        format!("m{}-{}-{}-t{}{ranks}-{pin}", self.model, self.spec.strategy, self.opt, self.spec.threads)
    }

    /// The step budget's words for people: `20 steps (w2)`, `to 4e-5 s (w2)`.
    pub fn budget_label(&self) -> String {
        let b = &self.spec.budget;
        let w = b.warmup.unwrap_or(0);
        match (b.steps, b.end_time_s) {
            (Some(n), _) => format!("{n} steps (w{w})"),
            (None, Some(t)) => format!("to {t:e} s (w{w})"),
            _ => "unbounded".into(),
        }
    }
}

/// A resolved campaign: preset plus overrides, validated. Its serialised form is the
/// manifest's `campaign`, and travels in a Slurm job's file ([`crate::campaign::schedule::job`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Campaign {
    /// Campaign id: the preset name, plus a slug of the overrides when there are any.
    pub id: String,
    /// Preset name.
    pub preset_name: String,
    /// Where the preset came from (file path or `builtin`).
    pub preset_source: String,
    /// The preset as loaded.
    pub preset: Preset,
    /// Overrides slug (empty when none).
    pub overrides: String,
    /// Scenario.
    pub scenario: ScenarioKind,
    /// Models.
    pub models: Vec<u32>,
    /// Threads per rank.
    pub threads: Vec<usize>,
    /// MPI rank counts.
    pub ranks: Vec<usize>,
    /// Launcher of runs with several ranks.
    pub launcher: Launcher,
    /// Strategies.
    pub strategies: Vec<Strategy>,
    /// Optimisation levels.
    pub opts: Vec<OptLevel>,
    /// Repetitions.
    pub reps: u32,
    /// Pinning policies.
    pub pins: Vec<PinPolicy>,
    /// Grid mode.
    pub grid: GridMode,
    /// Seed of the run order.
    pub seed: u64,
    /// Memory limit for the guard (bytes), if set.
    pub mem_limit: Option<u64>,
    /// Per-run time limit.
    #[serde(skip)]
    pub timeout: Option<Duration>,
    /// Every run's checkpoints (`None`: none), in `<campaign>/checkpoints/<run>/`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub checkpoint_every: Option<CheckpointEvery>,
    /// Budget section after CLI overrides.
    pub budget: BudgetSpec,
    /// The paired design of the cells of two or more threads (`None`: separate runs).
    pub paired: Option<mpm_spec::spec::Paired>,
    /// The injected slowdown of every run (a test knob; `None`: off).
    pub inject_slowdown: Option<f64>,
    /// Leave out the cells of more workers than the machine's usable cores (the preset's
    /// `skip_above_cores` or `--skip-above-cores`): [`Campaign::cap_workers`] applies it.
    #[serde(default)]
    pub skip_above_cores: bool,
    /// The most workers (ranks x threads) a run of this campaign may occupy, set by
    /// [`Campaign::cap_workers`]; cells above it are not run. `None`: no limit.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_workers: Option<usize>,
    /// The injected step slowdown of every run (a test knob; `None`: off).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_step_slowdown: Option<f64>,
}

/// The preset's pinning policies with the places asked (`--places`, else the preset's
/// `places`) applied to every binding; lists and `none` are unchanged.
fn preset_pins(preset: &Preset, places: Option<Places>) -> Vec<PinPolicy> {
    let pins = preset.pin.to_vec();
    match places.or(preset.places) {
        Some(k) => pins.iter().map(|p| p.with_places(k)).collect(),
        None => pins,
    }
}

impl Campaign {
    /// Apply `overrides` to `preset` and validate the result.
    pub fn resolve(preset: Preset, source: String, overrides: &Overrides) -> Result<Self> {
        let slug = overrides.slug();
        let id = if slug.is_empty() { preset.name.clone() } else { format!("{}_{slug}", preset.name) };
        let mut c = Campaign {
            id: sanitize_id(&id),
            preset_name: preset.name.clone(),
            preset_source: source,
            overrides: slug,
            scenario: preset.scenario,
            models: overrides.models.clone().unwrap_or_else(|| preset.models.clone()),
            threads: overrides.threads.clone().unwrap_or_else(|| preset.threads.clone()),
            ranks: overrides.ranks.clone().unwrap_or_else(|| preset.ranks.clone()),
            launcher: Launcher::choose(overrides.launcher.as_deref(), preset.launcher.as_ref())?,
            strategies: overrides.strategies.clone().unwrap_or_else(|| preset.strategies.clone()),
            opts: overrides.opt.clone().unwrap_or_else(|| preset.opt.clone()),
            reps: overrides.reps.unwrap_or(preset.reps),
            pins: overrides.pin.clone().unwrap_or_else(|| preset_pins(&preset, overrides.places)),
            grid: overrides.grid.unwrap_or(preset.grid),
            seed: overrides.seed.unwrap_or(preset.seed),
            mem_limit: None,
            timeout: None,
            checkpoint_every: overrides.checkpoint_every.or(preset.checkpoint_every),
            budget: overrides.budget_of(&preset.budget),
            paired: match overrides.paired_blocks {
                Some(0) => None,
                Some(blocks) => Some(mpm_spec::spec::Paired { blocks }),
                None => preset.paired.map(|p| mpm_spec::spec::Paired { blocks: p.blocks }),
            },
            inject_slowdown: overrides.inject_slowdown,
            skip_above_cores: overrides.skip_above_cores || preset.skip_above_cores,
            max_workers: None,
            inject_step_slowdown: overrides.inject_step_slowdown,
            preset,
        };
        c.check_matrix()?;
        c.mem_limit = match (overrides.mem_limit, &c.preset.mem_limit) {
            (Some(m), _) => Some(m),
            (None, Some(s)) => Some(parse_size(s).context("preset mem_limit")?),
            (None, None) => None,
        };
        if let Some(m) = c.mem_limit.filter(|&m| m < 1 << 20) {
            bail!(
                "a memory limit of {m} bytes (--mem-limit or the preset's mem_limit) would skip every run: give \
                 the memory the machine should be taken to have, e.g. 8GiB"
            );
        }
        c.timeout = match &c.preset.timeout {
            Some(t) => {
                let d = humantime::parse_duration(t).map_err(|e| anyhow!("preset timeout '{t}': {e}"))?;
                if d.is_zero() {
                    bail!("preset timeout '{t}' would stop every run at once: give a positive duration (e.g. \"30m\")");
                }
                Some(d)
            }
            None => None,
        };
        check_budget(&c.budget)?;
        for opt in &c.opts {
            if !opt.has_profile() {
                bail!("optimisation level {opt} has no Cargo profile of its own: use o3 or o0");
            }
        }
        for run in c.try_expand()? {
            run.spec.check().with_context(|| format!("the preset's run {}", run.describe()))?;
        }
        Ok(c)
    }

    /// Known models and scenario, positive thread counts and repetitions, no empty list, a
    /// known grid mode.
    fn check_matrix(&self) -> Result<()> {
        for m in &self.models {
            if !KNOWN_MODELS.contains(m) {
                bail!("unknown model {m} (known: 1, 2, 3, 4)");
            }
        }
        if self.threads.contains(&0) {
            bail!("thread counts must be at least 1 (got 0)");
        }
        if self.ranks.contains(&0) {
            bail!("rank counts must be at least 1 (got 0; 1 runs one process without a launcher)");
        }
        for (what, empty) in [
            ("models", self.models.is_empty()),
            ("threads", self.threads.is_empty()),
            ("rank counts", self.ranks.is_empty()),
            ("strategies", self.strategies.is_empty()),
            ("optimisation levels", self.opts.is_empty()),
            ("pinning policies", self.pins.is_empty()),
        ] {
            if empty {
                bail!("the campaign has no {what}");
            }
        }
        if self.reps == 0 {
            bail!("repetitions must be at least 1");
        }
        if self.reps > MAX_REPS {
            bail!(
                "{} repetitions a cell is more than the {MAX_REPS} a campaign plans (each is a process of its \
                 own): the intervals narrow with the square root of the repetitions; use at most {MAX_REPS}, or \
                 `mpm-bench paired --blocks` for many samples in one process",
                self.reps
            );
        }
        self.check_no_repeats()?;
        if self.grid == GridMode::Sparse && self.ranks.iter().any(|&r| r > 1) {
            bail!(
                "the sparse grid runs in one process only: use grid = \"adaptive\" for a campaign over several ranks"
            );
        }
        if self.scenario == ScenarioKind::Plate {
            bail!("the campaign harness runs the taylor and impact scenarios; run the plate with `mpm run plate`");
        }
        Ok(())
    }

    /// No list of the matrix names one value twice (`--threads 1,1`): its runs would be
    /// planned twice under one run key, and counted as two repetitions of one.
    fn check_no_repeats(&self) -> Result<()> {
        fn repeated<T: PartialEq>(items: &[T]) -> Option<&T> {
            items.iter().enumerate().find(|(i, x)| items[..*i].contains(x)).map(|(_, x)| x)
        }
        let lists = [
            ("models", repeated(&self.models).map(u32::to_string)),
            ("thread counts", repeated(&self.threads).map(usize::to_string)),
            ("rank counts", repeated(&self.ranks).map(usize::to_string)),
            ("strategies", repeated(&self.strategies).map(Strategy::to_string)),
            ("optimisation levels", repeated(&self.opts).map(OptLevel::to_string)),
            ("pinning policies", repeated(&self.pins).map(PinPolicy::label)),
        ];
        if let Some((what, item)) = lists.into_iter().find_map(|(what, item)| Some((what, item?))) {
            bail!(
                "the campaign's {what} name {item} twice: list each once (its runs would be planned twice under \
                 one run key; repetitions are `--reps` or the preset's `reps`)"
            );
        }
        Ok(())
    }

    /// Budget of one (model, opt) cell: the most specific matching override wins.
    pub fn budget_for(&self, model: u32, opt: OptLevel) -> Budget {
        let mut step_limit = self.budget.steps;
        let mut end_time = self.budget.end_time;
        let mut warmup = self.budget.warmup;
        let mut matches: Vec<(u8, &BudgetOverride)> = self
            .budget
            .overrides
            .iter()
            .filter(|o| o.model.is_none_or(|m| m == model) && o.opt.is_none_or(|x| x == opt))
            .map(|o| (u8::from(o.model.is_some()) * 2 + u8::from(o.opt.is_some()), o))
            .collect();
        matches.sort_by_key(|(s, _)| *s);
        for (_, o) in matches {
            if let Some(n) = o.steps {
                step_limit = Some(n);
                end_time = None;
            }
            if let Some(t) = o.end_time {
                end_time = Some(t);
                step_limit = None;
            }
            if let Some(w) = o.warmup {
                warmup = w;
            }
        }
        Budget { steps: step_limit, end_time_s: end_time, warmup: Some(warmup) }
    }

    /// The scenario of model `model` (Taylor Model 1-4, or the impact's variant 1-4).
    fn scenario_of(&self, model: u32) -> Result<Scenario> {
        Ok(match self.scenario {
            ScenarioKind::Taylor => Scenario::Taylor(TaylorSpec::model(u8::try_from(model)?)),
            ScenarioKind::Impact => {
                let (spacing_m, cell_m) =
                    impact_variant(model).ok_or_else(|| anyhow!("unknown impact model {model}"))?;
                Scenario::Impact(ImpactSpec { spacing_m, cell_m, ..ImpactSpec::default() })
            }
            ScenarioKind::Plate => bail!("the campaign harness does not run the plate"),
        })
    }

    /// The solver's spec of one cell of the matrix.
    fn spec_of(&self, model: u32, opt: OptLevel, strategy: Strategy, ranks: usize, threads: usize) -> Result<RunSpec> {
        let mut spec = RunSpec::new(self.scenario_of(model)?).map_err(|e| anyhow!("{e}"))?;
        spec.strategy = strategy;
        spec.threads = threads;
        spec.ranks = ranks;
        spec.grid = self.grid;
        self.preset.physics.apply(&mut spec.physics);
        spec.budget = self.budget_for(model, opt);
        // Each rank's waiting for the others apart from its communication (the row's wait_*
        // and comm_* columns); the solver refuses it at one rank.
        spec.split_wait = ranks > 1;
        // The paired design compares a cell's T-thread solver with a one-thread one: cells of
        // one thread (and the serial strategy) stay separate runs.
        spec.paired = self.paired.filter(|_| strategy.is_parallel() && threads > 1 && ranks == 1);
        spec.inject_slowdown = self.inject_slowdown;
        spec.inject_step_slowdown = self.inject_step_slowdown;
        Ok(spec)
    }

    /// Every run of the matrix, in declaration order.
    pub fn expand(&self) -> Vec<PlannedRun> {
        self.try_expand().expect("a resolved campaign expands")
    }

    fn try_expand(&self) -> Result<Vec<PlannedRun>> {
        let mut out = Vec::new();
        for rep in 0..self.reps {
            for &model in &self.models {
                for &opt in &self.opts {
                    for &strategy in &self.strategies {
                        for &ranks in &self.ranks {
                            for &threads in &self.threads {
                                let above = self.max_workers.is_some_and(|max| ranks * threads > max);
                                if strategy.check_threads(threads).is_err() || above {
                                    continue;
                                }
                                let excluded = |pin: &PinPolicy| {
                                    self.preset.exclude.iter().any(|e| e.matches(model, opt, strategy, threads, pin))
                                };
                                if self.pins.iter().all(excluded) {
                                    continue;
                                }
                                let spec = self.spec_of(model, opt, strategy, ranks, threads)?;
                                let launcher = (ranks > 1).then(|| self.launcher.expand(ranks, threads).join(" "));
                                for pin in self.pins.iter().filter(|p| !excluded(p)) {
                                    out.push(PlannedRun {
                                        spec: spec.clone(),
                                        model,
                                        opt,
                                        pin: pin.clone(),
                                        launcher: launcher.clone(),
                                        rep,
                                    });
                                }
                            }
                        }
                    }
                }
            }
        }
        Ok(out)
    }

    /// Leave out the cells whose runs occupy more than `cores` workers (ranks x threads),
    /// so that none runs oversubscribed: returns the (ranks, threads) pairs left out,
    /// ascending (empty when every cell fits). An error when nothing would be left to run.
    pub fn cap_workers(&mut self, cores: usize) -> Result<Vec<(usize, usize)>> {
        let mut above: Vec<(usize, usize)> = self
            .expand()
            .iter()
            .filter(|r| r.total_threads() > cores)
            .map(|r| (r.spec.ranks, r.spec.threads))
            .collect();
        above.sort_unstable();
        above.dedup();
        self.max_workers = Some(cores);
        if self.expand().is_empty() {
            bail!(
                "every run of campaign {} needs more than the {cores} usable core(s) here: nothing is left to run \
                 (choose thread counts with --threads)",
                self.id
            );
        }
        Ok(above)
    }

    /// The line that says which cells [`Campaign::cap_workers`] left out on `cores` cores.
    pub fn cap_note(cores: usize, above: &[(usize, usize)]) -> String {
        let label = |&(ranks, t): &(usize, usize)| if ranks > 1 { format!("{ranks}x{t}") } else { t.to_string() };
        format!(
            "note: {cores} usable core(s) here: the runs of {} threads are skipped, not run oversubscribed \
             (skip_above_cores)",
            above.iter().map(label).collect::<Vec<_>>().join("/")
        )
    }

    /// The run order: repetition by repetition, each shuffled with `seed`.
    pub fn ordered(&self, seed: u64) -> Vec<PlannedRun> {
        let all = self.expand();
        let mut rng = SplitMix64(seed);
        let mut out = Vec::with_capacity(all.len());
        for rep in 0..self.reps {
            let mut block: Vec<PlannedRun> = all.iter().filter(|r| r.rep == rep).cloned().collect();
            rng.shuffle(&mut block);
            out.extend(block);
        }
        out
    }
}

/// Exactly one of a step limit (at least 1) and an end time.
fn check_budget(budget: &BudgetSpec) -> Result<()> {
    if budget.steps.is_some() && budget.end_time.is_some() {
        bail!("give either a step limit or an end time, not both");
    }
    if budget.steps.is_none() && budget.end_time.is_none() {
        bail!("the campaign has no step budget: set steps or end_time");
    }
    if budget.steps == Some(0) {
        bail!("the step limit must be at least 1");
    }
    Ok(())
}

/// `s` as a folder name: ASCII letters (lower-cased), digits, `-`, `_` and `.` kept, every
/// other character `-`; a name over 80 characters shortened with a hash of the whole.
pub fn sanitize_id(s: &str) -> String {
    let mut id: String = s
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || matches!(c, '-' | '_' | '.') { c.to_ascii_lowercase() } else { '-' })
        .collect();
    if id.len() > 80 {
        // Too long to read: keep the start and a hash of the whole.
        use sha2::Digest;
        let h = sha2::Sha256::digest(s.as_bytes());
        id.truncate(60);
        id.push('_');
        id.push_str(&h.iter().take(4).map(|b| format!("{b:02x}")).collect::<String>());
    }
    id
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::plan::preset::{load_preset, BUILTIN_PRESETS};

    /// The key keeps the whole SHA-256; the short form of older campaigns names the run whose
    /// hash it begins, of the same repetition, and no other.
    #[test]
    fn the_key_is_the_whole_sha256_and_the_short_form_names_it() {
        let run = PlannedRun::taylor(1, Strategy::DomainDecomposition, OptLevel::O3, 2, 10);
        let key = run.key();
        let (hash, rep) = key.0.rsplit_once("-r").unwrap();
        assert_eq!((hash.len(), rep), (64, "0"));
        assert!(hash.bytes().all(|b| b.is_ascii_hexdigit()) && !key.is_short());
        let short = RunKey(format!("{}-r0", &hash[..16]));
        assert!(short.is_short());
        assert_eq!(key.short(), short);
        assert_eq!(short.short(), short);
        assert!(short.names(&key) && key.names(&short) && key.names(&key));
        let mut other_rep = run.clone();
        other_rep.rep = 1;
        assert!(!short.names(&other_rep.key()), "another repetition");
        let other = PlannedRun::taylor(1, Strategy::DomainDecomposition, OptLevel::O3, 4, 10).key();
        assert!(!short.names(&other) && !key.names(&other));
        // Two short keys, or two full ones, name each other only when equal.
        assert!(!short.names(&other.short()));
        assert!(!RunKey("free text".into()).names(&key) && !RunKey("free text".into()).is_short());
    }

    #[test]
    fn builtin_presets_parse_and_expand() {
        for (name, _) in BUILTIN_PRESETS {
            let (p, _) = load_preset(name, None).unwrap();
            let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
            assert_eq!(c.id, name);
            assert!(!c.expand().is_empty());
        }
        let (p, _) = load_preset("paper", None).unwrap();
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(c.models, vec![1, 2, 3, 4]);
        assert_eq!(c.threads, vec![1, 2, 4, 6, 8]);
        assert_eq!(c.budget_for(4, OptLevel::O0).end_time_s, Some(4e-5));
    }

    /// The strategies preset: every strategy on Models 1-4 at O3, threads 1 and 2 (4 and 8
    /// oversubscribed on 2 cores, left out on Model 4), serial on one thread only, the cells
    /// of 2+ threads paired, 3 processes a cell, and at most 25 minutes on 2 cores at the
    /// rate `--dry-run` assumes.
    #[test]
    fn strategies_preset_runs_every_strategy_within_25_minutes() {
        let (p, _) = load_preset("strategies", None).unwrap();
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(c.strategies, Strategy::ALL.to_vec());
        assert_eq!((c.models.clone(), c.opts.clone(), c.reps), (vec![1, 2, 3, 4], vec![OptLevel::O3], 3));
        let runs = c.expand();
        for m in 1..=4u32 {
            for s in Strategy::ALL {
                let threads: std::collections::BTreeSet<usize> =
                    runs.iter().filter(|r| r.model == m && r.spec.strategy == s).map(|r| r.spec.threads).collect();
                let want: Vec<usize> = match (s.is_parallel(), m) {
                    (false, _) => vec![1],
                    (true, 4) => vec![1, 2],
                    (true, _) => vec![1, 2, 4, 8],
                };
                assert_eq!(threads.into_iter().collect::<Vec<_>>(), want, "Model{m} {s}");
            }
        }
        assert!(runs.iter().all(|r| r.spec.paired.is_some() == (r.spec.threads > 1)));
        let todo: Vec<(usize, PlannedRun)> = runs.into_iter().enumerate().collect();
        let text = crate::campaign::exec::estimate::nominal_estimate(&todo, 2);
        let minutes: u64 = text
            .split_whitespace()
            .skip_while(|w| *w != "about")
            .nth(1)
            .and_then(|w| w.strip_suffix('m')?.parse().ok())
            .unwrap_or_else(|| panic!("no minutes in {text}"));
        assert!(minutes < 25, "{text}");
    }

    /// The paper preset pins as the paper did: OpenMP close over cores, so on two quad-core
    /// sockets the second socket is used only past 4 threads.
    #[test]
    fn paper_preset_uses_the_papers_placement() {
        let (p, _) = load_preset("paper", None).unwrap();
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(c.pins, vec![PinPolicy::CLOSE]);
        let m = crate::machine::topology::Machine::synthetic("pack:2 core:4 pu:1").unwrap();
        let socket = |cpu: usize| cpu / 4;
        for n in [1, 2, 4, 6, 8] {
            let cpus = m.place(&c.pins[0], n).unwrap().cpus;
            let second = cpus.iter().filter(|&&cpu| socket(cpu) == 1).count();
            assert_eq!(second, n.saturating_sub(4), "{n} threads: {cpus:?}");
        }
    }

    /// `ranks` defaults to one process; the hybrid preset crosses ranks with threads per rank,
    /// and every run has its own key.
    #[test]
    fn ranks_default_to_one_and_cross_threads() {
        let (p, _) = load_preset("smoke", None).unwrap();
        assert_eq!(p.ranks, vec![1]);
        assert_eq!(p.launcher, None);
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert!(c.expand().iter().all(|r| r.spec.ranks == 1 && r.total_threads() == r.spec.threads));
        let (p, _) = load_preset("hybrid", None).unwrap();
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(c.ranks, vec![1, 2]);
        let runs = c.expand();
        for (ranks, threads) in [(1, 1), (1, 2), (2, 1), (2, 2)] {
            assert!(runs.iter().any(|r| r.spec.ranks == ranks && r.spec.threads == threads), "{ranks}x{threads}");
        }
        let keys: std::collections::HashSet<_> = runs.iter().map(PlannedRun::key).collect();
        assert_eq!(keys.len(), runs.len());
        assert_eq!(
            runs.iter().find(|r| r.spec.ranks == 2 && r.spec.threads == 2).unwrap().describe(),
            "Model1 dd o3 2 ranks x 2 thr pin close rep 0"
        );
        // --ranks replaces the preset's and names the campaign; zero ranks is refused.
        let (p, _) = load_preset("smoke", None).unwrap();
        let ov = Overrides { ranks: Some(vec![2]), ..Overrides::default() };
        let c = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap();
        assert!(c.expand().iter().all(|r| r.spec.ranks == 2));
        assert!(c.id.contains("ranks2"), "{}", c.id);
        let ov = Overrides { ranks: Some(vec![0, 1]), ..Overrides::default() };
        let err = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("rank counts must be at least 1"), "{err}");
        // The sparse grid is one process's; an unknown grid names the known ones.
        let ov = Overrides { grid: Some(GridMode::Sparse), ..Overrides::default() };
        assert_eq!(Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap().grid, GridMode::Sparse);
        let ov = Overrides { grid: Some(GridMode::Sparse), ranks: Some(vec![1, 2]), ..Overrides::default() };
        let err = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("one process only"), "{err}");
        let text = include_str!("../../../../configs/smoke.toml").replace("grid = \"fixed\"", "grid = \"dense\"");
        let err = format!("{:#}", crate::campaign::plan::preset::parse_preset(&text).unwrap_err());
        assert!(err.contains("dense") && err.contains("`fixed`, `adaptive`, `sparse`"), "{err}");
        drop(p);
    }

    /// The preset's `ranks` and `launcher` keys; `--launcher` wins over the preset and is
    /// checked; a bad template in a preset is an error naming it.
    #[test]
    fn preset_ranks_and_launcher_parse() {
        let text = include_str!("../../../../configs/smoke.toml").to_string() + "\n";
        let with = text.replace(
            "threads = [1, 2]",
            "threads = [1, 2]\nranks = [1, 2, 4]\nlauncher = \"srun -n {ranks} -c {threads}\"",
        );
        let p = crate::campaign::plan::preset::parse_preset(&with).unwrap();
        assert_eq!(p.ranks, vec![1, 2, 4]);
        let c = Campaign::resolve(p.clone(), "file".into(), &Overrides::default()).unwrap();
        if std::env::var(crate::campaign::exec::launcher::LAUNCHER_ENV).is_err() {
            assert_eq!(c.launcher.expand(4, 2), ["srun", "-n", "4", "-c", "2"]);
        }
        let ov = Overrides { launcher: Some("mpiexec -np {ranks}".into()), ..Overrides::default() };
        let c = Campaign::resolve(p.clone(), "file".into(), &ov).unwrap();
        assert_eq!(c.launcher.expand(2, 1), ["mpiexec", "-np", "2"]);
        assert!(!c.id.contains("mpiexec"), "the launcher is not part of the campaign id: {}", c.id);
        let ov = Overrides { launcher: Some("mpiexec -np 2".into()), ..Overrides::default() };
        let err = Campaign::resolve(p, "file".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("{ranks}"), "{err}");
        let bad = with.replace("srun -n {ranks} -c {threads}", "srun -n {nodes}");
        let err = format!("{:#}", crate::campaign::plan::preset::parse_preset(&bad).unwrap_err());
        assert!(err.contains("unknown placeholder '{nodes}'"), "{err}");
        let bad = text.replace("threads = [1, 2]", "threads = [1, 2]\nranks = 2");
        assert!(crate::campaign::plan::preset::parse_preset(&bad).is_err(), "ranks is a list");
    }

    /// `strategies = "all"` is every parallel strategy of this build; one name and lists are
    /// read as the command line reads them.
    #[test]
    fn strategies_all_one_name_or_a_list() {
        use crate::campaign::plan::preset::{every_parallel_strategy, parse_preset};
        let smoke = include_str!("../../../../configs/smoke.toml");
        let with = |value: &str| smoke.replace("strategies = [\"ae\", \"dd\"]", &format!("strategies = {value}"));
        let all = parse_preset(&with("\"all\"")).unwrap().strategies;
        assert_eq!(all, every_parallel_strategy());
        assert!(all.contains(&Strategy::DdBalanced) && !all.contains(&Strategy::Serial), "{all:?}");
        assert_eq!(parse_preset(&with("\"dd\"")).unwrap().strategies, vec![Strategy::DomainDecomposition]);
        assert_eq!(parse_preset(&with("[\"ae\", \"array-expansion\"]")).unwrap().strategies.len(), 2);
        let err = format!("{:#}", parse_preset(&with("[\"ae\", \"zz\"]")).unwrap_err());
        assert!(err.contains("unknown strategy 'zz'") && err.contains("dd-balanced"), "{err}");
    }

    /// The manycore preset: Models 1-4, 1-16 threads, every parallel strategy, O0 for
    /// Model 1 only, Model 4 at 8 threads only, spread beside close for Model 2 at 2-8
    /// threads, paired, 3 processes a cell, thread counts above the cores skipped.
    #[test]
    fn manycore_preset_is_the_many_core_matrix() {
        let (p, _) = load_preset("manycore", None).unwrap();
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert!(c.skip_above_cores && c.paired.is_some() && c.reps >= 3, "{c:?}");
        assert_eq!((c.models.clone(), c.threads.clone()), (vec![1, 2, 3, 4], vec![1, 2, 4, 8, 16]));
        assert_eq!(c.strategies, crate::campaign::plan::preset::every_parallel_strategy());
        let runs = c.expand();
        let cells = |f: &dyn Fn(&PlannedRun) -> bool| {
            let mut v: Vec<(u32, OptLevel, usize, String)> =
                runs.iter().filter(|r| f(r)).map(|r| (r.model, r.opt, r.spec.threads, r.pin.label())).collect();
            v.sort();
            v.dedup();
            v
        };
        assert!(cells(&|r| r.opt == OptLevel::O0).iter().all(|c| c.0 == 1));
        assert_eq!(cells(&|r| r.model == 4), vec![(4, OptLevel::O3, 8, "close".to_string())]);
        let spread: Vec<(u32, usize)> = cells(&|r| r.pin.label() == "spread").iter().map(|c| (c.0, c.2)).collect();
        assert_eq!(spread, vec![(2, 2), (2, 4), (2, 8)]);
        for strategy in &c.strategies {
            for model in [1, 2, 3] {
                let threads = cells(&|r| r.model == model && r.spec.strategy == *strategy && r.opt == OptLevel::O3);
                let counts: Vec<usize> = threads.iter().filter(|c| c.3 == "close").map(|c| c.2).collect();
                assert_eq!(counts, vec![1, 2, 4, 8, 16], "Model{model} {strategy}");
            }
        }
    }

    /// skip_above_cores: the cells of more workers than the cores are left out and said;
    /// none left is an error.
    #[test]
    fn cells_above_the_cores_are_left_out() {
        let (p, _) = load_preset("manycore", None).unwrap();
        let mut c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        let all = c.expand().len();
        assert_eq!(c.clone().cap_workers(16).unwrap(), vec![]);
        let above = c.cap_workers(2).unwrap();
        assert_eq!(above, vec![(1, 4), (1, 8), (1, 16)]);
        let runs = c.expand();
        assert!(!runs.is_empty() && runs.len() < all && runs.iter().all(|r| r.total_threads() <= 2));
        assert_eq!(
            Campaign::cap_note(2, &above),
            "note: 2 usable core(s) here: the runs of 4/8/16 threads are skipped, not run oversubscribed \
             (skip_above_cores)"
        );
        // Ranks count: 2 ranks x 2 threads is 4 workers.
        let (p, _) = load_preset("hybrid", None).unwrap();
        let mut h = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(h.cap_workers(3).unwrap(), vec![(2, 2)]);
        assert!(h.expand().iter().all(|r| r.total_threads() <= 3));
        // Nothing left: an error that says what to do.
        let (p, _) = load_preset("smoke", None).unwrap();
        let ov = Overrides { threads: Some(vec![4]), skip_above_cores: true, ..Overrides::default() };
        let mut s = Campaign::resolve(p, "builtin".into(), &ov).unwrap();
        assert!(s.skip_above_cores);
        let err = s.cap_workers(2).unwrap_err().to_string();
        assert!(err.contains("nothing is left to run") && err.contains("--threads"), "{err}");
    }

    /// A list naming one value twice (`--threads 1,1`) is refused, naming the list and the
    /// value: its runs would share one run key.
    #[test]
    fn a_value_listed_twice_is_refused() {
        let (p, _) = load_preset("smoke", None).unwrap();
        let ov = Overrides { threads: Some(vec![1, 2, 1]), ..Overrides::default() };
        let err = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("thread counts name 1 twice") && err.contains("--reps"), "{err}");
        let ov = Overrides { opt: Some(vec![OptLevel::O3, OptLevel::O3]), ..Overrides::default() };
        let err = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("optimisation levels name o3 twice"), "{err}");
        let ov = Overrides { threads: Some(vec![1, 2]), ..Overrides::default() };
        let runs = Campaign::resolve(p, "builtin".into(), &ov).unwrap().expand();
        let keys: std::collections::HashSet<_> = runs.iter().map(PlannedRun::key).collect();
        assert_eq!(keys.len(), runs.len(), "one run key per planned run");
    }

    #[test]
    fn places_override_applies_to_the_preset_bindings() {
        let (p, _) = load_preset("smoke", None).unwrap();
        let ov = Overrides { places: Some(Places::Sockets), ..Overrides::default() };
        let c = Campaign::resolve(p, "builtin".into(), &ov).unwrap();
        assert!(c.pins.iter().all(|p| !matches!(p, PinPolicy::Bind(_, k) if *k != Places::Sockets)));
        assert!(c.id.contains("places-sockets"), "{}", c.id);
        // A preset's own `places` applies when --places is not given.
        let (mut p, _) = load_preset("smoke", None).unwrap();
        p.places = Some(Places::NumaDomains);
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(c.pins, vec![PinPolicy::Bind(crate::machine::placement::Bind::Close, Places::NumaDomains)]);
    }
}
