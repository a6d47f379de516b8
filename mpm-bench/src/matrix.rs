//! Campaign matrices: TOML presets, command-line overrides, expansion into runs, and the
//! seeded, interleaved run order.
//!
//! A preset (`configs/<name>.toml`) declares
//! models x threads x strategies x optimisation levels x repetitions x pinning policies and a
//! step budget (a step limit or a simulated end time, plus warm-up steps), with optional
//! per-model / per-optimisation-level budget overrides:
//!
//! ```toml
//! name = "quick"
//! description = "every model, few steps"
//! scenario = "taylor"
//! models = [1, 2, 3, 4]
//! threads = [1, 2, 4, 6, 8]
//! strategies = ["ae", "dd"]
//! opt = ["o3", "o0"]
//! reps = 1
//! pin = "close"            # or a list: ["close", "spread"]; or a CPU list "0,1"
//! grid = "fixed"           # or "adaptive"
//! seed = 2009              # run-order shuffle
//! # mem_limit = "8GiB"     # pretend the machine has this much memory (memory guard)
//! # timeout = "30m"        # per run
//!
//! [budget]
//! steps = 20               # or: end_time = 4e-5 (seconds)
//! warmup = 2
//!
//! [[budget.override]]      # the most specific matching override wins
//! model = 4
//! opt = "o0"
//! steps = 1
//! warmup = 0
//! ```
//!
//! Expansion: every combination becomes a [`RunSpec`]; the `serial` strategy only pairs with
//! one thread. Order: repetition by repetition, each repetition's configurations shuffled by
//! a seeded Fisher-Yates (SplitMix64, stable across versions), so machine drift spreads over
//! every cell instead of biasing one.

use crate::topology::PinPolicy;
use anyhow::{anyhow, bail, Context, Result};
use serde::{Deserialize, Serialize};
use std::fmt;
use std::path::{Path, PathBuf};
use std::str::FromStr;
use std::time::Duration;

/// Presets shipped with the harness (embedded; `configs/<name>.toml` in the workspace wins
/// when present, so edits there apply without rebuilding).
pub const BUILTIN_PRESETS: [(&str, &str); 4] = [
    ("smoke", include_str!("../../configs/smoke.toml")),
    ("quick", include_str!("../../configs/quick.toml")),
    ("paper", include_str!("../../configs/paper.toml")),
    ("impact", include_str!("../../configs/impact.toml")),
];

/// Models of the Taylor bar benchmark.
pub const KNOWN_MODELS: [u32; 4] = [1, 2, 3, 4];

/// Parallelisation strategy of a run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Strategy {
    /// One thread, no parallel machinery.
    Serial,
    /// Array expansion: per-thread copies of the nodal arrays.
    Ae,
    /// Domain decomposition: per-thread patches of the grid.
    Dd,
}

impl Strategy {
    /// Name as passed to `mpm --strategy` and written to CSV.
    pub fn as_str(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::Ae => "ae",
            Strategy::Dd => "dd",
        }
    }
}

impl From<Strategy> for mpm_core::Strategy {
    /// The solver's strategy for a campaign's strategy.
    fn from(s: Strategy) -> Self {
        match s {
            Strategy::Serial => mpm_core::Strategy::Serial,
            Strategy::Ae => mpm_core::Strategy::ArrayExpansion,
            Strategy::Dd => mpm_core::Strategy::DomainDecomposition,
        }
    }
}

impl fmt::Display for Strategy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for Strategy {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "serial" => Ok(Strategy::Serial),
            "ae" | "array-expansion" => Ok(Strategy::Ae),
            "dd" | "domain-decomposition" => Ok(Strategy::Dd),
            _ => bail!("unknown strategy '{s}' (known: serial, ae, dd)"),
        }
    }
}

/// Optimisation level = Cargo profile of the solver binary.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum OptLevel {
    /// `opt-level = 3` (profile `o3`).
    O3,
    /// `opt-level = 0`, debug assertions and overflow checks off (profile `o0`).
    O0,
}

impl OptLevel {
    /// Profile name (`o3` / `o0`).
    pub fn as_str(self) -> &'static str {
        match self {
            OptLevel::O3 => "o3",
            OptLevel::O0 => "o0",
        }
    }
}

impl fmt::Display for OptLevel {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl FromStr for OptLevel {
    type Err = anyhow::Error;
    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "o3" | "3" => Ok(OptLevel::O3),
            "o0" | "0" | "none" | "noopt" => Ok(OptLevel::O0),
            _ => bail!("unknown optimisation level '{s}' (known: o3, o0)"),
        }
    }
}

/// One value or a list of them (TOML convenience).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum OneOrMany<T> {
    /// A single value.
    One(T),
    /// A list.
    Many(Vec<T>),
}

impl<T: Clone> OneOrMany<T> {
    /// As a list.
    pub fn to_vec(&self) -> Vec<T> {
        match self {
            OneOrMany::One(t) => vec![t.clone()],
            OneOrMany::Many(v) => v.clone(),
        }
    }
}

/// Per-model / per-optimisation-level budget override.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BudgetOverride {
    /// Model it applies to (all when absent).
    pub model: Option<u32>,
    /// Optimisation level it applies to (all when absent).
    pub opt: Option<OptLevel>,
    /// Step limit (replaces the end time).
    pub steps: Option<u64>,
    /// Simulated end time, s (replaces the step limit).
    pub end_time: Option<f64>,
    /// Warm-up steps.
    pub warmup: Option<u64>,
}

/// Step budget section of a preset.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BudgetSpec {
    /// Step limit.
    pub steps: Option<u64>,
    /// Simulated end time, s.
    pub end_time: Option<f64>,
    /// Warm-up steps (timed, excluded from the steady-state figure).
    #[serde(default)]
    pub warmup: u64,
    /// Overrides, most specific match wins.
    #[serde(default, rename = "override")]
    pub overrides: Vec<BudgetOverride>,
}

/// A preset as written in TOML.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Preset {
    /// Name (used in the campaign id).
    pub name: String,
    /// What the preset is for.
    #[serde(default)]
    pub description: String,
    /// Scenario passed to `mpm run` (`taylor`).
    #[serde(default = "default_scenario")]
    pub scenario: String,
    /// Models.
    pub models: Vec<u32>,
    /// Thread counts.
    pub threads: Vec<usize>,
    /// Strategies.
    pub strategies: Vec<Strategy>,
    /// Optimisation levels.
    pub opt: Vec<OptLevel>,
    /// Repetitions per configuration.
    #[serde(default = "one")]
    pub reps: u32,
    /// Pinning policies.
    #[serde(default = "default_pin")]
    pub pin: OneOrMany<PinPolicy>,
    /// `fixed` or `adaptive`.
    #[serde(default = "default_grid")]
    pub grid: String,
    /// Seed of the run-order shuffle.
    #[serde(default)]
    pub seed: u64,
    /// Pretend the machine has this much memory (`8GiB`), for the memory guard.
    pub mem_limit: Option<String>,
    /// Per-run time limit (`30m`), humantime syntax.
    pub timeout: Option<String>,
    /// Step budget.
    pub budget: BudgetSpec,
}

fn default_scenario() -> String {
    "taylor".into()
}
fn one() -> u32 {
    1
}
fn default_pin() -> OneOrMany<PinPolicy> {
    OneOrMany::One(PinPolicy::Close)
}
fn default_grid() -> String {
    "fixed".into()
}

/// Command-line overrides of a preset (every field optional).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Overrides {
    /// `--models`.
    pub models: Option<Vec<u32>>,
    /// `--threads`.
    pub threads: Option<Vec<usize>>,
    /// `--strategies`.
    pub strategies: Option<Vec<Strategy>>,
    /// `--opt`.
    pub opt: Option<Vec<OptLevel>>,
    /// `--reps`.
    pub reps: Option<u32>,
    /// `--pin` (repeatable).
    pub pin: Option<Vec<PinPolicy>>,
    /// `--steps` (replaces every budget of the preset).
    pub steps: Option<u64>,
    /// `--end-time` (replaces every budget of the preset).
    pub end_time: Option<f64>,
    /// `--warmup`.
    pub warmup: Option<u64>,
    /// `--grid`.
    pub grid: Option<String>,
    /// `--mem-limit` in bytes.
    pub mem_limit: Option<u64>,
    /// `--seed` (order only: not part of the campaign id).
    pub seed: Option<u64>,
}

impl Overrides {
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
        if let Some(n) = self.steps {
            parts.push(format!("n{n}"));
        }
        if let Some(t) = self.end_time {
            parts.push(format!("end{t:e}"));
        }
        if let Some(w) = self.warmup {
            parts.push(format!("w{w}"));
        }
        if let Some(g) = &self.grid {
            parts.push(g.clone());
        }
        if let Some(m) = self.mem_limit {
            parts.push(format!("mem{}M", m >> 20));
        }
        parts.join("_")
    }
}

/// The step budget of one run: exactly one of the two limits is set.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct RunBudget {
    /// Stop after this many steps.
    pub step_limit: Option<u64>,
    /// Stop at this simulated time (s).
    pub end_time: Option<f64>,
    /// Warm-up steps.
    pub warmup: u64,
}

/// One run of the matrix.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct RunSpec {
    /// Scenario: `taylor` (models 1-4 = Table 2) or `impact` (models 1-4 = the paper's
    /// variants, see [`crate::runner::impact_variant`]).
    pub scenario: String,
    /// Model.
    pub model: u32,
    /// Strategy.
    pub strategy: Strategy,
    /// Optimisation level.
    pub opt: OptLevel,
    /// Threads.
    pub threads: usize,
    /// Pinning policy.
    pub pin: PinPolicy,
    /// Repetition index.
    pub rep: u32,
    /// `fixed` / `adaptive`.
    pub grid: String,
    /// Budget.
    pub budget: RunBudget,
}

impl RunSpec {
    /// Short human description: `Model4 ae o0 8 threads pin close rep 0`.
    pub fn describe(&self) -> String {
        let kind = if self.scenario == "impact" { "Impact" } else { "Model" };
        format!(
            "{kind}{} {} {} {} thr pin {} rep {}",
            self.model, self.strategy, self.opt, self.threads, self.pin, self.rep
        )
    }

    /// Resume key (see [`crate::record::run_key`]).
    pub fn key(&self) -> crate::record::RunKey {
        crate::record::run_key(
            self.model,
            self.strategy.as_str(),
            self.opt.as_str(),
            self.threads,
            &self.pin.label(),
            self.rep,
            &self.grid,
            self.budget.warmup,
            self.budget.step_limit,
            self.budget.end_time,
        )
    }
}

/// A resolved campaign: preset plus overrides, validated.
#[derive(Clone, Debug, PartialEq, Serialize)]
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
    pub scenario: String,
    /// Models.
    pub models: Vec<u32>,
    /// Threads.
    pub threads: Vec<usize>,
    /// Strategies.
    pub strategies: Vec<Strategy>,
    /// Optimisation levels.
    pub opts: Vec<OptLevel>,
    /// Repetitions.
    pub reps: u32,
    /// Pinning policies.
    pub pins: Vec<PinPolicy>,
    /// Grid mode.
    pub grid: String,
    /// Seed of the run order.
    pub seed: u64,
    /// Memory limit for the guard (bytes), if set.
    pub mem_limit: Option<u64>,
    /// Per-run time limit.
    #[serde(skip)]
    pub timeout: Option<Duration>,
    /// Budget section after CLI overrides.
    pub budget: BudgetSpec,
}

/// Find and parse a preset: a path to a TOML file, or a built-in name.
/// `workspace` (when known) is searched for `configs/<name>.toml` first.
pub fn load_preset(name_or_path: &str, workspace: Option<&Path>) -> Result<(Preset, String)> {
    let as_path = PathBuf::from(name_or_path);
    let looks_like_path = name_or_path.ends_with(".toml") || name_or_path.contains('/');
    if looks_like_path || as_path.is_file() {
        let text = std::fs::read_to_string(&as_path)
            .with_context(|| format!("cannot read preset file {}", as_path.display()))?;
        let p = parse_preset(&text).with_context(|| format!("bad preset file {}", as_path.display()))?;
        return Ok((p, as_path.display().to_string()));
    }
    let Some((_, builtin)) = BUILTIN_PRESETS.iter().find(|(n, _)| *n == name_or_path) else {
        let known: Vec<&str> = BUILTIN_PRESETS.iter().map(|(n, _)| *n).collect();
        bail!("unknown preset '{name_or_path}' (known: {}; or give a path to a .toml file)", known.join(", "));
    };
    if let Some(ws) = workspace {
        let file = ws.join("configs").join(format!("{name_or_path}.toml"));
        if file.is_file() {
            let text = std::fs::read_to_string(&file).with_context(|| format!("cannot read {}", file.display()))?;
            let p = parse_preset(&text).with_context(|| format!("bad preset file {}", file.display()))?;
            return Ok((p, file.display().to_string()));
        }
    }
    Ok((parse_preset(builtin).context("bad built-in preset")?, "builtin".into()))
}

/// Parse preset TOML.
pub fn parse_preset(text: &str) -> Result<Preset> {
    toml::from_str(text).map_err(|e| anyhow!("{e}"))
}

/// Parse a size such as `8GiB`, `8G`, `512M`, `1000000` (bytes).
pub fn parse_size(s: &str) -> Result<u64> {
    let t = s.trim();
    let split = t.find(|c: char| !(c.is_ascii_digit() || c == '.')).unwrap_or(t.len());
    let (num, unit) = t.split_at(split);
    let v: f64 = num.parse().map_err(|_| anyhow!("bad size '{s}' (examples: 8GiB, 512M, 1000000)"))?;
    let mult: f64 = match unit.trim().to_ascii_lowercase().as_str() {
        "" | "b" => 1.0,
        "k" | "kb" | "kib" => 1024.0,
        "m" | "mb" | "mib" => 1024.0 * 1024.0,
        "g" | "gb" | "gib" => 1024.0 * 1024.0 * 1024.0,
        "t" | "tb" | "tib" => 1024.0f64.powi(4),
        _ => bail!("bad size unit in '{s}' (use K, M, G or T; binary multiples)"),
    };
    Ok((v * mult) as u64)
}

/// Parse a simulated time: plain seconds (`4e-5`) or with a unit (`40us`, `0.5ms`).
pub fn parse_seconds(s: &str) -> Result<f64> {
    let t = s.trim();
    if let Ok(v) = t.parse::<f64>() {
        if v > 0.0 && v.is_finite() {
            return Ok(v);
        }
        bail!("end time must be positive, got '{s}'");
    }
    let d = humantime::parse_duration(t).map_err(|_| anyhow!("bad time '{s}' (examples: 4e-5, 40us, 0.04ms)"))?;
    if d.is_zero() {
        bail!("end time must be positive, got '{s}'");
    }
    Ok(d.as_secs_f64())
}

impl Campaign {
    /// Apply `overrides` to `preset` and validate the result.
    pub fn resolve(preset: Preset, source: String, overrides: &Overrides) -> Result<Self> {
        let models = overrides.models.clone().unwrap_or_else(|| preset.models.clone());
        let threads = overrides.threads.clone().unwrap_or_else(|| preset.threads.clone());
        let strategies = overrides.strategies.clone().unwrap_or_else(|| preset.strategies.clone());
        let opts = overrides.opt.clone().unwrap_or_else(|| preset.opt.clone());
        let reps = overrides.reps.unwrap_or(preset.reps);
        let pins = overrides.pin.clone().unwrap_or_else(|| preset.pin.to_vec());
        let grid = overrides.grid.clone().unwrap_or_else(|| preset.grid.clone());
        let seed = overrides.seed.unwrap_or(preset.seed);
        for m in &models {
            if !KNOWN_MODELS.contains(m) {
                bail!("unknown model {m} (known: 1, 2, 3, 4)");
            }
        }
        if threads.contains(&0) {
            bail!("thread counts must be at least 1 (got 0)");
        }
        for (what, empty) in [
            ("models", models.is_empty()),
            ("threads", threads.is_empty()),
            ("strategies", strategies.is_empty()),
            ("optimisation levels", opts.is_empty()),
            ("pinning policies", pins.is_empty()),
        ] {
            if empty {
                bail!("the campaign has no {what}");
            }
        }
        if reps == 0 {
            bail!("repetitions must be at least 1");
        }
        if grid != "fixed" && grid != "adaptive" {
            bail!("unknown grid mode '{grid}' (known: fixed, adaptive)");
        }
        if preset.scenario != "taylor" && preset.scenario != "impact" {
            bail!("unknown scenario '{}' (the campaign harness runs: taylor, impact)", preset.scenario);
        }
        let mem_limit = match (overrides.mem_limit, &preset.mem_limit) {
            (Some(m), _) => Some(m),
            (None, Some(s)) => Some(parse_size(s).context("preset mem_limit")?),
            (None, None) => None,
        };
        let timeout = match &preset.timeout {
            Some(t) => Some(humantime::parse_duration(t).map_err(|e| anyhow!("preset timeout '{t}': {e}"))?),
            None => None,
        };
        let mut budget = preset.budget.clone();
        if overrides.steps.is_some() || overrides.end_time.is_some() {
            // A budget on the command line replaces every budget of the preset.
            budget.steps = overrides.steps;
            budget.end_time = overrides.end_time;
            for o in &mut budget.overrides {
                o.steps = None;
                o.end_time = None;
            }
        }
        if let Some(w) = overrides.warmup {
            budget.warmup = w;
            for o in &mut budget.overrides {
                o.warmup = None;
            }
        }
        if budget.steps.is_some() && budget.end_time.is_some() {
            bail!("give either a step limit or an end time, not both");
        }
        if budget.steps.is_none() && budget.end_time.is_none() {
            bail!("the campaign has no step budget: set steps or end_time");
        }
        if budget.steps == Some(0) {
            bail!("the step limit must be at least 1");
        }
        let slug = overrides.slug();
        let id = if slug.is_empty() { preset.name.clone() } else { format!("{}_{slug}", preset.name) };
        let id = sanitize_id(&id);
        Ok(Campaign {
            id,
            preset_name: preset.name.clone(),
            preset_source: source,
            overrides: slug,
            scenario: preset.scenario.clone(),
            models,
            threads,
            strategies,
            opts,
            reps,
            pins,
            grid,
            seed,
            mem_limit,
            timeout,
            budget,
            preset,
        })
    }

    /// Budget of one (model, opt) cell: the most specific matching override wins.
    pub fn budget_for(&self, model: u32, opt: OptLevel) -> RunBudget {
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
        // Warm-up must leave at least one steady step when the step count is known.
        if let Some(n) = step_limit {
            warmup = warmup.min(n.saturating_sub(1));
        }
        RunBudget { step_limit, end_time, warmup }
    }

    /// Every run of the matrix, in declaration order.
    pub fn expand(&self) -> Vec<RunSpec> {
        let mut out = Vec::new();
        for rep in 0..self.reps {
            for &model in &self.models {
                for &opt in &self.opts {
                    for &strategy in &self.strategies {
                        for &threads in &self.threads {
                            if strategy == Strategy::Serial && threads != 1 {
                                continue;
                            }
                            for pin in &self.pins {
                                out.push(RunSpec {
                                    scenario: self.scenario.clone(),
                                    model,
                                    strategy,
                                    opt,
                                    threads,
                                    pin: pin.clone(),
                                    rep,
                                    grid: self.grid.clone(),
                                    budget: self.budget_for(model, opt),
                                });
                            }
                        }
                    }
                }
            }
        }
        out
    }

    /// The run order: repetition by repetition, each shuffled with `seed`.
    pub fn ordered(&self, seed: u64) -> Vec<RunSpec> {
        let all = self.expand();
        let mut rng = SplitMix64(seed);
        let mut out = Vec::with_capacity(all.len());
        for rep in 0..self.reps {
            let mut block: Vec<RunSpec> = all.iter().filter(|r| r.rep == rep).cloned().collect();
            rng.shuffle(&mut block);
            out.extend(block);
        }
        out
    }
}

fn sanitize_id(s: &str) -> String {
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

/// SplitMix64: a tiny PRNG whose output is fixed forever (unlike `rand`'s `StdRng`), so a
/// recorded seed reproduces the same order with any later build.
#[derive(Clone, Debug)]
pub struct SplitMix64(pub u64);

impl SplitMix64 {
    /// Next 64 random bits.
    pub fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in `0..n` (n > 0), without modulo bias.
    pub fn below(&mut self, n: u64) -> u64 {
        let zone = u64::MAX - (u64::MAX % n);
        loop {
            let v = self.next_u64();
            if v < zone {
                return v % n;
            }
        }
    }

    /// Fisher-Yates shuffle.
    pub fn shuffle<T>(&mut self, v: &mut [T]) {
        for i in (1..v.len()).rev() {
            let j = self.below(i as u64 + 1) as usize;
            v.swap(i, j);
        }
    }
}

/// Parse a comma list with `parse_one` (used by the CLI), naming the bad item.
pub fn parse_list<T>(s: &str, what: &str, parse_one: impl Fn(&str) -> Result<T>) -> Result<Vec<T>> {
    let items: Vec<&str> = s.split(',').map(str::trim).collect();
    if items.iter().any(|i| i.is_empty()) {
        bail!("bad {what} list '{s}': empty entry");
    }
    items.into_iter().map(|i| parse_one(i).with_context(|| format!("bad {what} list '{s}'"))).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

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
        assert_eq!(c.budget_for(4, OptLevel::O0).end_time, Some(4e-5));
    }

    #[test]
    fn shuffle_is_seeded_and_stable() {
        let mut a: Vec<u32> = (0..20).collect();
        let mut b = a.clone();
        SplitMix64(7).shuffle(&mut a);
        SplitMix64(7).shuffle(&mut b);
        assert_eq!(a, b);
        assert_ne!(a, (0..20).collect::<Vec<_>>());
        // Fixed forever: a recorded seed must give the same order with any later build.
        assert_eq!(SplitMix64(0).next_u64(), 0xE220_A839_7B1D_CDAF);
    }

    #[test]
    fn sizes_and_times() {
        assert_eq!(parse_size("8GiB").unwrap(), 8 << 30);
        assert_eq!(parse_size("512M").unwrap(), 512 << 20);
        assert!(parse_size("8X").is_err());
        assert_eq!(parse_seconds("4e-5").unwrap(), 4e-5);
        assert!((parse_seconds("40us").unwrap() - 4e-5).abs() < 1e-15);
        assert!(parse_seconds("-1").is_err());
    }
}
