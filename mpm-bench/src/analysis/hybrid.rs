//! Hybrid MPI x threads: speedup and efficiency against the total cores of a run (ranks x
//! threads per rank), for every (model, strategy, optimisation level) a campaign ran over
//! several ranks.
//!
//! A configuration is (model, strategy, opt level, ranks, threads per rank); its time is the
//! median steady-state time per step (rank 0's, which every step's reductions keep in step
//! with the others) over the `ok` repetitions. The base `T_1` is the same model, strategy and
//! opt level at one rank and one thread, so `S = T_1 / T_{R x T}` and `E = S / (R x T)`, with
//! 95 % bootstrap intervals as in [`super::stats`]. The communication's and the waiting's
//! shares of the wall time (each a run's maximum over ranks: the row's `comm_frac` and
//! `wait_frac`), the bytes sent per step and the memory summed over the ranks are medians
//! over the same rows. Rows that did not measure the waiting apart (before CSV schema 5)
//! give the exchange with the waiting in it, flagged [`HybridPoint::comm_includes_wait`],
//! and no waiting (not measured); when a configuration has rows of both kinds, only those
//! that split the waiting off count for the communication.
//!
//! One-process rows enter only as the `ranks = 1` configurations of a (model, strategy, opt)
//! that also has rows over several ranks; the paper's analyses never see the rows over
//! several ranks (they are split off when a campaign is read).

use super::stats::{bootstrap, choose_pin, Estimate, StatsOptions};
use crate::campaign::store::record::{Row, Status};
use crate::util::median;
use mpm_core::Strategy;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};

/// One hybrid configuration.
#[derive(Clone, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize)]
pub struct HybridKey {
    /// Model.
    pub model: u32,
    /// Strategy inside each rank.
    pub strategy: Strategy,
    /// Optimisation level.
    pub opt_level: String,
    /// MPI ranks.
    pub ranks: usize,
    /// Threads per rank.
    pub threads: usize,
}

impl HybridKey {
    /// Total cores the configuration occupies: ranks x threads per rank.
    pub fn cores(&self) -> usize {
        self.ranks * self.threads
    }

    /// `Model3 DD O3 2x1`.
    pub fn label(&self) -> String {
        format!(
            "Model{} {} {} {}x{}",
            self.model,
            super::stats::tag(self.strategy),
            self.opt_level.to_uppercase(),
            self.ranks,
            self.threads
        )
    }
}

/// One measured configuration with its speedup against one rank of one thread.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct HybridPoint {
    /// The configuration.
    pub key: HybridKey,
    /// Steady-state time per step (s).
    pub time: Estimate,
    /// `T_1`: one rank, one thread (s); `None` without such a run.
    pub t1: Option<Estimate>,
    /// `T_1 / T`.
    pub speedup: Option<Estimate>,
    /// Speedup over the total cores.
    pub efficiency: Option<Estimate>,
    /// Median communication seconds over the run's wall time (0 at one rank); with
    /// `comm_includes_wait`, the exchange seconds with the waiting for other ranks in them.
    pub comm_frac: Option<f64>,
    /// `comm_frac` includes waiting for the other ranks (rows before schema 5, which did not
    /// measure it apart).
    pub comm_includes_wait: bool,
    /// Median seconds waiting for other ranks over the run's wall time; `None` at one rank
    /// (nothing to wait for) and where it was not measured.
    pub wait_frac: Option<f64>,
    /// Median bytes sent per step, all ranks.
    pub comm_bytes_per_step: Option<f64>,
    /// Median peak memory summed over the ranks (bytes).
    pub memory_sum_bytes: Option<f64>,
    /// Any repetition had more workers than usable cores (or ranks sharing CPUs).
    pub oversubscribed: bool,
    /// Any repetition (or of its base) was measured on a busy host.
    pub noisy: bool,
    /// `ok` repetitions.
    pub reps: usize,
}

impl HybridPoint {
    /// Total cores.
    pub fn cores(&self) -> usize {
        self.key.cores()
    }
}

/// The hybrid analysis of a campaign.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct HybridAnalysis {
    /// Every measured configuration, sorted by key.
    pub points: Vec<HybridPoint>,
    /// The pinning policy analysed.
    pub pin_policy: String,
    /// Things the reader should know (several pinning policies, no base run, ...).
    pub notes: Vec<String>,
}

/// The `ok` rows of one configuration.
#[derive(Default)]
struct Samples {
    time: Vec<f64>,
    /// Communication alone (the waiting measured apart, or one rank).
    comm_frac: Vec<f64>,
    /// Exchange seconds with the waiting in them (rows that did not split it off).
    comm_with_wait: Vec<f64>,
    wait_frac: Vec<f64>,
    bytes: Vec<f64>,
    memory: Vec<f64>,
    oversubscribed: bool,
    noisy: bool,
}

impl Samples {
    /// Add row `r`: its placement always, its times and exchange when it is `ok` and timed.
    fn add(&mut self, r: &Row) {
        self.oversubscribed |= r.placement.oversubscribed;
        let Some(f) = r.measured.as_ref().filter(|_| r.outcome.status == Status::Ok) else { return };
        let Some(t) = f.timing.steady_s_per_step else { return };
        self.time.push(t);
        self.noisy |= r.host.host_noisy;
        let c = &f.communication;
        if r.comm_includes_wait() {
            self.comm_with_wait.extend(c.comm_frac);
        } else {
            self.comm_frac.extend(c.comm_frac);
        }
        self.wait_frac.extend(c.wait_frac);
        self.bytes.extend(c.comm_bytes_per_step);
        self.memory.extend(f.memory.peak_rss_sum_bytes.or(f.memory.peak_rss_bytes).map(|b| b as f64));
    }
}

impl HybridAnalysis {
    /// Analyse `hybrid` (rows over several ranks) with `one` (one-process rows) as the
    /// `ranks = 1` configurations and the base. Empty when `hybrid` is.
    pub fn from_rows(one: &[Row], hybrid: &[Row], pin: Option<&str>, opts: &StatsOptions) -> Self {
        let mut an = HybridAnalysis::default();
        if hybrid.is_empty() {
            return an;
        }
        let (chosen, note) = choose_pin(one.iter().chain(hybrid), pin);
        an.notes.extend(note);
        let cells: BTreeSet<(u32, Strategy, &str)> = hybrid
            .iter()
            .filter(|r| r.pin_label() == chosen)
            .map(|r| (r.model(), r.strategy(), r.opt().as_str()))
            .collect();
        let mut samples: BTreeMap<HybridKey, Samples> = BTreeMap::new();
        for r in one.iter().chain(hybrid) {
            if r.pin_label() != chosen || !cells.contains(&(r.model(), r.strategy(), r.opt().as_str())) {
                continue;
            }
            let key = HybridKey {
                model: r.model(),
                strategy: r.strategy(),
                opt_level: r.opt().to_string(),
                ranks: r.ranks().max(1),
                threads: r.threads_per_rank(),
            };
            samples.entry(key).or_default().add(r);
        }
        let mut missing = BTreeSet::new();
        for (key, s) in &samples {
            if s.time.is_empty() {
                continue;
            }
            let base_key = HybridKey { ranks: 1, threads: 1, ..key.clone() };
            let base = samples.get(&base_key).filter(|b| !b.time.is_empty());
            let label = key.label();
            let time = bootstrap(&[&s.time], &|m| m[0], opts, &label);
            let (t1, speedup) = match base {
                Some(_) if base_key == *key => (Some(time), Some(Estimate::point(1.0, s.time.len()))),
                Some(b) => (
                    Some(bootstrap(&[&b.time], &|m| m[0], opts, &base_key.label())),
                    Some(bootstrap(&[&b.time, &s.time], &|m| m[0] / m[1], opts, &format!("{label}/speedup"))),
                ),
                None => {
                    missing.insert(format!("Model{} {} {}", key.model, key.strategy, key.opt_level));
                    (None, None)
                }
            };
            let med = |v: &[f64]| (!v.is_empty()).then(|| median(v));
            let (comm_frac, comm_includes_wait) = match med(&s.comm_frac) {
                Some(c) => (Some(c), false),
                None => (med(&s.comm_with_wait), !s.comm_with_wait.is_empty()),
            };
            an.points.push(HybridPoint {
                key: key.clone(),
                time,
                t1,
                speedup,
                efficiency: speedup.map(|e| e.scale(1.0 / key.cores() as f64)),
                comm_frac,
                comm_includes_wait,
                wait_frac: med(&s.wait_frac),
                comm_bytes_per_step: med(&s.bytes),
                memory_sum_bytes: med(&s.memory),
                oversubscribed: s.oversubscribed,
                noisy: s.noisy || base.is_some_and(|b| b.noisy),
                reps: s.time.len(),
            });
        }
        if !missing.is_empty() {
            an.notes.push(format!(
                "no run of 1 rank x 1 thread (ok) for {}: no hybrid speedup there",
                missing.into_iter().collect::<Vec<_>>().join(", ")
            ));
        }
        an.pin_policy = chosen;
        an
    }

    /// The (model, strategy, opt level) combinations, sorted.
    pub fn combos(&self) -> Vec<(u32, Strategy, String)> {
        let set: BTreeSet<(u32, Strategy, String)> =
            self.points.iter().map(|p| (p.key.model, p.key.strategy, p.key.opt_level.clone())).collect();
        set.into_iter().collect()
    }

    /// The rank counts measured, ascending.
    pub fn rank_counts(&self) -> Vec<usize> {
        let set: BTreeSet<usize> = self.points.iter().map(|p| p.key.ranks).collect();
        set.into_iter().collect()
    }

    /// The points of one line: a combination at `ranks` ranks, by ascending total cores.
    pub fn line(&self, model: u32, strategy: Strategy, opt: &str, ranks: usize) -> Vec<&HybridPoint> {
        let mut v: Vec<&HybridPoint> = self
            .points
            .iter()
            .filter(|p| {
                p.key.model == model && p.key.strategy == strategy && p.key.opt_level == opt && p.key.ranks == ranks
            })
            .collect();
        v.sort_by_key(|p| p.cores());
        v
    }
}
