//! Campaign presets: the TOML files `configs/<name>.toml` (also built in), their value
//! types (optimisation level, budgets) and the parsers of sizes, times and comma lists.
//!
//! A preset declares
//! models x threads x strategies x optimisation levels x repetitions x pinning policies and a
//! step budget (a step limit or a simulated end time, plus warm-up steps), with optional
//! per-model / per-optimisation-level budget overrides:
//!
//! ```toml
//! name = "quick"
//! description = "every model, few steps"
//! scenario = "taylor"
//! models = [1, 2, 3, 4]
//! threads = [1, 2, 4, 6, 8]     # per rank
//! # ranks = [1, 2]             # MPI ranks (default [1]: one process, no launcher)
//! # launcher = "mpirun --bind-to none -n {ranks}"   # for ranks > 1, see campaign::launcher
//! strategies = ["ae", "dd"]   # or "all": every parallel strategy of this solver build
//! opt = ["o3", "o0"]
//! reps = 1
//! pin = "close"            # OpenMP binding (alias key: bind); a list ["close", "spread"]; a CPU list "0,1"
//! places = "cores"         # OpenMP places: threads, cores, ll_caches, numa_domains, sockets
//! grid = "fixed"           # or "adaptive", "sparse"
//! seed = 2009              # run-order shuffle
//! # skip_above_cores = true  # cells of more workers than this machine's usable cores are
//! #                          # left out (and said), not run oversubscribed
//! # mem_limit = "8GiB"     # pretend the machine has this much memory (memory guard)
//! # timeout = "30m"        # per run
//! # checkpoint_every = "10m"   # each run saves its state this often (or a step count); a
//! #                            # killed, timed-out or interrupted run continues from it
//!
//! [physics]                # optional: every absent key is the solver's default
//! eos = "hugoniot"         # or "paper-printed"
//! q = { c1 = 1.5, c2 = 0.06 }
//! cfl = 0.5
//! energy_rise_limit = 0.05 # or "off"
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
//!
//! # paired = { blocks = 8 }  # cells of 2+ threads in the paired design (each run: a one-thread
//! #                          # solver beside the T-thread one, 8 alternating timed blocks of
//! #                          # (steps - warmup) / 8 steps; repetitions = processes per cell)
//!
//! # [[exclude]]             # cells of the matrix not run (every given key must match)
//! # model = 4
//! # opt = "o0"
//! # pin = "spread"          # a binding matches over whichever places the campaign uses
//! ```
//!
//! [`crate::campaign::plan::matrix`] resolves a preset and the command-line overrides into runs.

use crate::campaign::exec::launcher::Launcher;
use crate::machine::placement::{PinPolicy, Places};
use anyhow::{anyhow, bail, Context, Result};
use mpm_core::{BulkViscosity, GridMode, MgForm, Strategy};
use mpm_spec::spec::{Physics, RiseLimit};
use mpm_spec::ScenarioKind;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Presets shipped with the harness (embedded; `configs/<name>.toml` in the workspace wins
/// when present, so edits there apply without rebuilding).
pub const BUILTIN_PRESETS: [(&str, &str); 9] = [
    ("smoke", include_str!("../../../../configs/smoke.toml")),
    ("ci", include_str!("../../../../configs/ci.toml")),
    ("quick", include_str!("../../../../configs/quick.toml")),
    ("paper", include_str!("../../../../configs/paper.toml")),
    ("impact", include_str!("../../../../configs/impact.toml")),
    ("balanced", include_str!("../../../../configs/balanced.toml")),
    ("hybrid", include_str!("../../../../configs/hybrid.toml")),
    ("manycore", include_str!("../../../../configs/manycore.toml")),
    ("strategies", include_str!("../../../../configs/strategies.toml")),
];

/// Optimisation level = Cargo profile of the solver binary (`o3`, `o0`).
pub use mpm_spec::OptLevel;

/// Physics options of every run of a preset (each absent one: the solver's default).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PhysicsPreset {
    /// Form of the Mie-Grüneisen EOS (`hugoniot`, `paper-printed`).
    pub eos: Option<MgForm>,
    /// Artificial bulk viscosity `{ c1 = 1.5, c2 = 0.06 }`.
    pub q: Option<BulkViscosity>,
    /// CFL number.
    pub cfl: Option<f64>,
    /// Energy-rise limit: a fraction, or `"off"`.
    pub energy_rise_limit: Option<RiseLimit>,
}

impl PhysicsPreset {
    /// `physics` with these options applied.
    pub fn apply(&self, physics: &mut Physics) {
        if let Some(e) = self.eos {
            physics.eos = e;
        }
        if let Some(q) = self.q {
            physics.q = q;
        }
        if let Some(c) = self.cfl {
            physics.cfl = c;
        }
        if let Some(l) = self.energy_rise_limit {
            physics.energy_rise_limit = l;
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

/// The paired design of a preset's cells of two or more threads ([`mpm_spec::spec::Paired`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PairedPreset {
    /// Timed blocks of each solver per run.
    pub blocks: u64,
}

/// Cells of the matrix a preset leaves out: those matching every key given.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Exclude {
    /// Model.
    pub model: Option<u32>,
    /// Optimisation level.
    pub opt: Option<OptLevel>,
    /// Strategy.
    pub strategy: Option<Strategy>,
    /// Threads (per rank).
    pub threads: Option<usize>,
    /// Pinning policy: a binding (`close`, `spread`, `primary`) matches that binding over
    /// whichever places the campaign uses; `none` and CPU lists match themselves.
    pub pin: Option<PinPolicy>,
}

impl Exclude {
    /// Whether the cell (model, opt, strategy, threads) pinned by `pin` is left out by this
    /// entry.
    pub fn matches(&self, model: u32, opt: OptLevel, strategy: Strategy, threads: usize, pin: &PinPolicy) -> bool {
        let same_pin = |want: &PinPolicy| match (want, pin) {
            (PinPolicy::Bind(a, _), PinPolicy::Bind(b, _)) => a == b,
            _ => want == pin,
        };
        self.model.is_none_or(|m| m == model)
            && self.opt.is_none_or(|o| o == opt)
            && self.strategy.is_none_or(|s| s == strategy)
            && self.threads.is_none_or(|t| t == threads)
            && self.pin.as_ref().is_none_or(same_pin)
    }
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
    /// Scenario of every run (`taylor`, or `impact` with the impact variants as models).
    #[serde(default)]
    pub scenario: ScenarioKind,
    /// Models.
    pub models: Vec<u32>,
    /// Thread counts (per rank).
    pub threads: Vec<usize>,
    /// MPI rank counts (default `[1]`: one process, run directly). Runs with more than one
    /// rank start `mpm` through [`Preset::launcher`].
    #[serde(default = "one_rank")]
    pub ranks: Vec<usize>,
    /// Launcher template of runs with several ranks (`{ranks}`, `{threads}` placeholders;
    /// default [`crate::campaign::exec::launcher::DEFAULT_LAUNCHER`]; `--launcher` and `MPM_BENCH_LAUNCHER`
    /// win over it).
    #[serde(default)]
    pub launcher: Option<Launcher>,
    /// Strategies: a list, one name, or `"all"`: every parallel strategy of this solver
    /// build ([`every_parallel_strategy`]; the serial oracle is named on its own).
    #[serde(deserialize_with = "strategies_or_all")]
    pub strategies: Vec<Strategy>,
    /// Optimisation levels.
    pub opt: Vec<OptLevel>,
    /// Repetitions per configuration.
    #[serde(default = "one")]
    pub reps: u32,
    /// Pinning policies (`bind` is accepted for the key): OpenMP bindings `close`,
    /// `spread`, `primary` (optionally `@places`), `none`, or CPU lists.
    #[serde(default = "default_pin", alias = "bind")]
    pub pin: OneOrMany<PinPolicy>,
    /// OpenMP places of every binding of `pin` (when absent: `cores`, or each binding's
    /// own `@places`).
    #[serde(default)]
    pub places: Option<Places>,
    /// `fixed`, `adaptive` or `sparse`.
    #[serde(default)]
    pub grid: GridMode,
    /// Physics options of every run (default: the solver's).
    #[serde(default)]
    pub physics: PhysicsPreset,
    /// Seed of the run-order shuffle.
    #[serde(default)]
    pub seed: u64,
    /// Leave out the cells whose runs need more workers (ranks x threads) than this
    /// machine's usable cores, saying which, instead of running them oversubscribed.
    #[serde(default)]
    pub skip_above_cores: bool,
    /// Pretend the machine has this much memory (`8GiB`), for the memory guard.
    pub mem_limit: Option<String>,
    /// Per-run time limit (`30m`), humantime syntax.
    pub timeout: Option<String>,
    /// Checkpoints of every run: steps (`500`) or wall-clock time (`"10m"`).
    #[serde(default)]
    pub checkpoint_every: Option<mpm_spec::spec::CheckpointEvery>,
    /// Step budget.
    pub budget: BudgetSpec,
    /// Measure the cells of two or more threads in the paired design.
    #[serde(default)]
    pub paired: Option<PairedPreset>,
    /// Cells of the matrix not run.
    #[serde(default)]
    pub exclude: Vec<Exclude>,
}

fn one() -> u32 {
    1
}
fn one_rank() -> Vec<usize> {
    vec![1]
}
fn default_pin() -> OneOrMany<PinPolicy> {
    OneOrMany::One(PinPolicy::CLOSE)
}

/// Every parallel strategy of this solver build, in [`Strategy::ALL`]'s order: what
/// `strategies = "all"` (and `--strategies all`) means.
pub fn every_parallel_strategy() -> Vec<Strategy> {
    Strategy::ALL.into_iter().filter(|s| s.is_parallel()).collect()
}

/// A preset's `strategies`: `"all"`, one name, or a list of names, each read as the
/// command line reads it (the message of a bad name lists the known ones).
fn strategies_or_all<'de, D: serde::Deserializer<'de>>(de: D) -> Result<Vec<Strategy>, D::Error> {
    let names = match OneOrMany::<String>::deserialize(de)? {
        OneOrMany::One(word) if word == "all" => return Ok(every_parallel_strategy()),
        names => names.to_vec(),
    };
    names.iter().map(|n| n.parse::<Strategy>().map_err(serde::de::Error::custom)).collect()
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

/// Parse preset TOML. A list left open is reported by the TOML parser at the line after
/// it; the message then also names the line that opened it.
pub fn parse_preset(text: &str) -> Result<Preset> {
    toml::from_str(text).map_err(|e| {
        let msg = e.to_string();
        match (msg.contains("expected `]`"), e.span()) {
            (true, Some(span)) => {
                let before = &text[..span.start.min(text.len())];
                let open =
                    before.lines().enumerate().filter(|(_, l)| l.matches('[').count() > l.matches(']').count()).last();
                match open {
                    Some((i, l)) => anyhow!("{msg}(the list opened on line {}, `{}`, is not closed)", i + 1, l.trim()),
                    None => anyhow!("{msg}"),
                }
            }
            _ => anyhow!("{msg}"),
        }
    })
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
    fn sizes_and_times() {
        assert_eq!(parse_size("8GiB").unwrap(), 8 << 30);
        assert_eq!(parse_size("512M").unwrap(), 512 << 20);
        assert!(parse_size("8X").is_err());
        assert_eq!(parse_seconds("4e-5").unwrap(), 4e-5);
        assert!((parse_seconds("40us").unwrap() - 4e-5).abs() < 1e-15);
        assert!(parse_seconds("-1").is_err());
    }

    /// A list left open: the parser stops on the next line; the message names the line
    /// that opened it.
    #[test]
    fn an_open_list_is_named_by_its_line() {
        let text = "name = \"x\"\nmodels = [1]\nthreads = [1, 2\nstrategies = [\"dd\"]\n";
        let err = parse_preset(text).unwrap_err().to_string();
        assert!(err.contains("line 3, `threads = [1, 2`, is not closed"), "{err}");
    }
}
