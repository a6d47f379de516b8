//! Campaign matrices: a preset and the command-line overrides resolved into a validated
//! campaign, its expansion into runs, and the seeded, interleaved run order.
//!
//! Expansion: every combination of the preset's models x ranks x threads x strategies x
//! optimisation levels x repetitions x pinning policies becomes a [`RunSpec`] with the step
//! budget of its (model, optimisation level) cell; the `serial` strategy only pairs with
//! one thread (per rank). `threads` is per rank; a run occupies ranks x threads workers. Order: repetition by repetition, each repetition's configurations shuffled by
//! a seeded Fisher-Yates (SplitMix64, stable across versions), so machine drift spreads over
//! every cell instead of biasing one.

use super::launcher::Launcher;
use super::preset::{parse_size, BudgetOverride, BudgetSpec, OptLevel, Preset};
use crate::machine::placement::{PinPolicy, Places};
use crate::util::SplitMix64;
use anyhow::{anyhow, bail, Context, Result};
use mpm_core::Strategy;
use serde::Serialize;
use std::time::Duration;

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
    pub grid: Option<String>,
    /// `--mem-limit` in bytes.
    pub mem_limit: Option<u64>,
    /// `--seed` (order only: not part of the campaign id).
    pub seed: Option<u64>,
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
    /// variants, see [`super::memory::impact_variant`]).
    pub scenario: String,
    /// Model.
    pub model: u32,
    /// Strategy.
    pub strategy: Strategy,
    /// Optimisation level.
    pub opt: OptLevel,
    /// Threads per rank (the solver's `--threads`).
    pub threads: usize,
    /// MPI ranks (1: one process, started directly).
    pub ranks: usize,
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
    /// Short human description: `Model4 ae o0 8 thr pin close rep 0`, with several ranks
    /// `Model3 dd o3 2 ranks x 2 thr pin close rep 0`.
    pub fn describe(&self) -> String {
        let kind = if self.scenario == "impact" { "Impact" } else { "Model" };
        let ranks = if self.ranks > 1 { format!("{} ranks x ", self.ranks) } else { String::new() };
        format!(
            "{kind}{} {} {} {ranks}{} thr pin {} rep {}",
            self.model, self.strategy, self.opt, self.threads, self.pin, self.rep
        )
    }

    /// Workers of the whole run: ranks x threads per rank (what oversubscription counts).
    pub fn total_threads(&self) -> usize {
        self.ranks * self.threads
    }

    /// Resume key (see [`super::record::run_key`]).
    pub fn key(&self) -> super::record::RunKey {
        super::record::run_key(
            self.model,
            self.strategy,
            self.opt.as_str(),
            self.ranks,
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
            scenario: preset.scenario.clone(),
            models: overrides.models.clone().unwrap_or_else(|| preset.models.clone()),
            threads: overrides.threads.clone().unwrap_or_else(|| preset.threads.clone()),
            ranks: overrides.ranks.clone().unwrap_or_else(|| preset.ranks.clone()),
            launcher: Launcher::choose(overrides.launcher.as_deref(), preset.launcher.as_ref())?,
            strategies: overrides.strategies.clone().unwrap_or_else(|| preset.strategies.clone()),
            opts: overrides.opt.clone().unwrap_or_else(|| preset.opt.clone()),
            reps: overrides.reps.unwrap_or(preset.reps),
            pins: overrides.pin.clone().unwrap_or_else(|| preset_pins(&preset, overrides.places)),
            grid: overrides.grid.clone().unwrap_or_else(|| preset.grid.clone()),
            seed: overrides.seed.unwrap_or(preset.seed),
            mem_limit: None,
            timeout: None,
            budget: overrides.budget_of(&preset.budget),
            preset,
        };
        c.check_matrix()?;
        c.mem_limit = match (overrides.mem_limit, &c.preset.mem_limit) {
            (Some(m), _) => Some(m),
            (None, Some(s)) => Some(parse_size(s).context("preset mem_limit")?),
            (None, None) => None,
        };
        c.timeout = match &c.preset.timeout {
            Some(t) => Some(humantime::parse_duration(t).map_err(|e| anyhow!("preset timeout '{t}': {e}"))?),
            None => None,
        };
        check_budget(&c.budget)?;
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
        let grid: mpm_core::GridMode =
            self.grid.parse().map_err(|e: String| anyhow::anyhow!("{e} (the preset's `grid` or --grid)"))?;
        if grid == mpm_core::GridMode::Sparse && self.ranks.iter().any(|&r| r > 1) {
            bail!(
                "the sparse grid runs in one process only: use grid = \"adaptive\" for a campaign over several ranks"
            );
        }
        if self.scenario != "taylor" && self.scenario != "impact" {
            bail!("unknown scenario '{}' (the campaign harness runs: taylor, impact)", self.scenario);
        }
        Ok(())
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
                        for &ranks in &self.ranks {
                            for &threads in &self.threads {
                                if strategy.check_threads(threads).is_err() {
                                    continue;
                                }
                                for pin in &self.pins {
                                    out.push(RunSpec {
                                        scenario: self.scenario.clone(),
                                        model,
                                        strategy,
                                        opt,
                                        threads,
                                        ranks,
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::preset::{load_preset, BUILTIN_PRESETS};

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
        assert!(c.expand().iter().all(|r| r.ranks == 1 && r.total_threads() == r.threads));
        let (p, _) = load_preset("hybrid", None).unwrap();
        let c = Campaign::resolve(p, "builtin".into(), &Overrides::default()).unwrap();
        assert_eq!(c.ranks, vec![1, 2]);
        let runs = c.expand();
        for (ranks, threads) in [(1, 1), (1, 2), (2, 1), (2, 2)] {
            assert!(runs.iter().any(|r| r.ranks == ranks && r.threads == threads), "{ranks}x{threads}");
        }
        let keys: std::collections::HashSet<_> = runs.iter().map(RunSpec::key).collect();
        assert_eq!(keys.len(), runs.len());
        assert_eq!(
            runs.iter().find(|r| r.ranks == 2 && r.threads == 2).unwrap().describe(),
            "Model1 dd o3 2 ranks x 2 thr pin close rep 0"
        );
        // --ranks replaces the preset's and names the campaign; zero ranks is refused.
        let (p, _) = load_preset("smoke", None).unwrap();
        let ov = Overrides { ranks: Some(vec![2]), ..Overrides::default() };
        let c = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap();
        assert!(c.expand().iter().all(|r| r.ranks == 2));
        assert!(c.id.contains("ranks2"), "{}", c.id);
        let ov = Overrides { ranks: Some(vec![0, 1]), ..Overrides::default() };
        let err = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("rank counts must be at least 1"), "{err}");
        // The sparse grid is one process's; an unknown grid names the known ones.
        let ov = Overrides { grid: Some("sparse".into()), ..Overrides::default() };
        assert_eq!(Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap().grid, "sparse");
        let ov = Overrides { grid: Some("sparse".into()), ranks: Some(vec![1, 2]), ..Overrides::default() };
        let err = Campaign::resolve(p.clone(), "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("one process only"), "{err}");
        let ov = Overrides { grid: Some("dense".into()), ..Overrides::default() };
        let err = Campaign::resolve(p, "builtin".into(), &ov).unwrap_err().to_string();
        assert!(err.contains("'fixed', 'adaptive' or 'sparse'"), "{err}");
    }

    /// The preset's `ranks` and `launcher` keys; `--launcher` wins over the preset and is
    /// checked; a bad template in a preset is an error naming it.
    #[test]
    fn preset_ranks_and_launcher_parse() {
        let text = include_str!("../../../configs/smoke.toml").to_string() + "\n";
        let with = text.replace(
            "threads = [1, 2]",
            "threads = [1, 2]\nranks = [1, 2, 4]\nlauncher = \"srun -n {ranks} -c {threads}\"",
        );
        let p = crate::campaign::preset::parse_preset(&with).unwrap();
        assert_eq!(p.ranks, vec![1, 2, 4]);
        let c = Campaign::resolve(p.clone(), "file".into(), &Overrides::default()).unwrap();
        if std::env::var(crate::campaign::launcher::LAUNCHER_ENV).is_err() {
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
        let err = format!("{:#}", crate::campaign::preset::parse_preset(&bad).unwrap_err());
        assert!(err.contains("unknown placeholder '{nodes}'"), "{err}");
        let bad = text.replace("threads = [1, 2]", "threads = [1, 2]\nranks = 2");
        assert!(crate::campaign::preset::parse_preset(&bad).is_err(), "ranks is a list");
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
