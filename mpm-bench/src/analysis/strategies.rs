//! Beyond the paper: the scatter strategies used since 2008 (block colouring, atomic adds)
//! against the paper's two (domain decomposition, array expansion), and the measured choice
//! of strategy per model and thread count. Read by `mpm-bench claims` (a section after
//! C1-C7, which stay as they are) and `mpm-bench report`.
//!
//! The rules are the claims' ([`super::claims`]): time per step and efficiency of the total
//! step at O3, only at real parallel points (more than one thread, not oversubscribed);
//! memory (peak resident) at every thread count, time sharing does not change it. Two
//! estimates differ only when their intervals do not overlap ([`compare`]; 5 % with single
//! repetitions); otherwise the verdict is "cannot tell".

use super::estimate::{compare, Compare, Estimate};
use super::stats::{parallel_strategies, tag, Analysis, CellKey, Stage, StatsOptions};
use mpm_core::Strategy;
use std::fmt::Write as _;

/// The strategies used since the paper, each compared with [`PAPER`].
pub const NEW: [Strategy; 2] = [Strategy::Colour, Strategy::Atomic];
/// The paper's strategies the new ones are compared with.
pub const PAPER: [Strategy; 2] = [Strategy::DomainDecomposition, Strategy::ArrayExpansion];

/// What is compared.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Measure {
    /// Parallel efficiency of the total step (higher is better).
    Efficiency,
    /// Steady-state seconds per step (lower is better).
    TimePerStep,
    /// Peak resident memory in bytes (lower is better).
    Memory,
}

impl Measure {
    fn name(self) -> &'static str {
        match self {
            Measure::Efficiency => "efficiency",
            Measure::TimePerStep => "s/step",
            Measure::Memory => "peak memory (MiB)",
        }
    }
}

/// One new strategy against one of the paper's at one model and thread count.
#[derive(Clone, Debug)]
pub struct Versus {
    /// Taylor model.
    pub model: u32,
    /// Threads.
    pub threads: usize,
    /// What is compared.
    pub measure: Measure,
    /// The new strategy and its estimate.
    pub new: (Strategy, Estimate),
    /// The paper's strategy and its estimate.
    pub paper: (Strategy, Estimate),
}

impl Versus {
    /// `better`, `worse` (beyond the noise) or `cannot tell` (the intervals overlap), for the
    /// new strategy.
    pub fn verdict(&self) -> &'static str {
        let higher_is_better = self.measure == Measure::Efficiency;
        match (compare(&self.new.1, &self.paper.1), higher_is_better) {
            (Compare::Within, _) => "cannot tell",
            (Compare::Greater, true) | (Compare::Less, false) => "better",
            (Compare::Greater, false) | (Compare::Less, true) => "worse",
        }
    }

    /// One line: `Model2, 2 threads, efficiency: COLOUR 0.95 [0.93, 0.97] vs DD ... -> better`.
    pub fn line(&self) -> String {
        let k = if self.measure == Measure::Memory { 1.0 / (1u64 << 20) as f64 } else { 1.0 };
        let digits = match self.measure {
            Measure::Efficiency => 3,
            Measure::TimePerStep => 5,
            Measure::Memory => 1,
        };
        format!(
            "Model{}, {} thread(s), {}: {} {} vs {} {} -> {}",
            self.model,
            self.threads,
            self.measure.name(),
            tag(self.new.0),
            self.new.1.scale(k).show(digits),
            tag(self.paper.0),
            self.paper.1.scale(k).show(digits),
            self.verdict()
        )
    }
}

/// The total step's point of `s` at O3 on `threads`, if it is a real parallel point.
fn real_point(an: &Analysis, model: u32, s: Strategy, threads: usize) -> Option<&super::stats::Point> {
    an.point(model, s, "o3", threads, Stage::Total).filter(|p| p.is_real_parallel())
}

/// Every comparison of a new strategy with a paper one the campaign allows, model by model.
pub fn comparisons(an: &Analysis) -> Vec<Versus> {
    let o = StatsOptions::default();
    let mut out = Vec::new();
    for m in an.models() {
        for n in an.thread_counts() {
            for new in NEW {
                for paper in PAPER {
                    let mut push = |measure, a: Option<Estimate>, b: Option<Estimate>| {
                        if let (Some(a), Some(b)) = (a, b) {
                            out.push(Versus { model: m, threads: n, measure, new: (new, a), paper: (paper, b) });
                        }
                    };
                    if let (Some(p), Some(q)) = (real_point(an, m, new, n), real_point(an, m, paper, n)) {
                        push(Measure::Efficiency, p.efficiency, q.efficiency);
                        push(Measure::TimePerStep, Some(p.time), Some(q.time));
                    }
                    let memory = |s| an.memory(&CellKey::new(m, s, "o3", n), &o);
                    push(Measure::Memory, memory(new), memory(paper));
                }
            }
        }
    }
    out
}

/// The section as plain-text lines: a summary per new strategy, then every comparison.
pub fn lines(an: &Analysis) -> Vec<String> {
    let all = comparisons(an);
    if all.is_empty() {
        return vec![format!(
            "no comparison: the campaign has no O3 rows of {} beside {} (run the strategies preset)",
            NEW.map(tag).join(" or "),
            PAPER.map(tag).join(" or ")
        )];
    }
    let mut out = Vec::new();
    for new in NEW {
        for paper in PAPER {
            let v: Vec<&Versus> = all.iter().filter(|v| v.new.0 == new && v.paper.0 == paper).collect();
            if v.is_empty() {
                continue;
            }
            let count = |w: &str| v.iter().filter(|x| x.verdict() == w).count();
            out.push(format!(
                "{} against {}: better in {}, worse in {}, cannot tell in {} of {} comparison(s)",
                tag(new),
                tag(paper),
                count("better"),
                count("worse"),
                count("cannot tell"),
                v.len()
            ));
        }
    }
    out.extend(all.iter().map(Versus::line));
    out
}

/// The fastest strategy at one model and thread count.
#[derive(Clone, Debug)]
pub struct Choice {
    /// Taylor model.
    pub model: u32,
    /// Threads.
    pub threads: usize,
    /// The fastest parallel strategy and its time per step.
    pub best: (Strategy, Estimate),
    /// The next fastest, if another strategy ran there.
    pub runner_up: Option<(Strategy, Estimate)>,
}

impl Choice {
    /// Whether the fastest is faster than the next beyond the noise.
    pub fn clear(&self) -> bool {
        self.runner_up.as_ref().is_none_or(|r| compare(&self.best.1, &r.1) == Compare::Less)
    }
}

/// The measured choice: per model and real parallel thread count, the parallel strategy with
/// the lowest time per step at O3 (the total step), and the next one.
pub fn choices(an: &Analysis) -> Vec<Choice> {
    let mut out = Vec::new();
    for m in an.models() {
        for n in an.thread_counts() {
            let mut ranked: Vec<(Strategy, Estimate)> =
                parallel_strategies().filter_map(|s| Some((s, real_point(an, m, s, n)?.time))).collect();
            ranked.sort_by(|a, b| a.1.value.total_cmp(&b.1.value));
            let mut it = ranked.into_iter();
            if let Some(best) = it.next() {
                out.push(Choice { model: m, threads: n, best, runner_up: it.next() });
            }
        }
    }
    out
}

/// The choices as table rows: model, threads, fastest, its s/step, next, its s/step, verdict.
pub fn choice_rows(an: &Analysis) -> Vec<Vec<String>> {
    choices(an)
        .iter()
        .map(|c| {
            let (next, next_time) = c.runner_up.map_or(("-".into(), "-".into()), |(s, e)| (tag(s), e.show(5)));
            let verdict = match (c.runner_up, c.clear()) {
                (None, _) => "the only one measured".to_string(),
                (Some(_), true) => "faster beyond the noise".to_string(),
                (Some((s, _)), false) => format!("cannot tell from {}", tag(s)),
            };
            vec![
                format!("Model{}", c.model),
                c.threads.to_string(),
                tag(c.best.0),
                c.best.1.show(5),
                next,
                next_time,
                verdict,
            ]
        })
        .collect()
}

/// Column heads of [`choice_rows`].
pub const CHOICE_HEAD: [&str; 7] = ["model", "threads", "fastest", "s/step", "next", "s/step", "verdict"];

/// The section of `mpm-bench claims` beyond the paper, as Markdown (`heading`: its level).
pub fn markdown(an: &Analysis, heading: &str) -> String {
    let mut s = format!("\n{heading} Beyond the paper: block colouring and atomic adds against DD and AE\n\n");
    for l in lines(an) {
        let _ = writeln!(s, "- {l}");
    }
    s
}

/// The same as plain text.
pub fn text(an: &Analysis) -> String {
    let mut s = String::from("\nBeyond the paper: block colouring and atomic adds against DD and AE\n");
    for l in lines(an) {
        let _ = writeln!(s, "    {l}");
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn e(value: f64, lo: f64, hi: f64) -> Estimate {
        Estimate { value, lo, hi, reps: 3 }
    }

    /// Higher efficiency and lower time or memory are better; overlapping intervals cannot
    /// tell.
    #[test]
    fn verdicts_follow_the_measure_and_the_intervals() {
        let v = |measure, a, b| Versus {
            model: 1,
            threads: 2,
            measure,
            new: (Strategy::Colour, a),
            paper: (Strategy::DomainDecomposition, b),
        };
        assert_eq!(v(Measure::Efficiency, e(0.95, 0.94, 0.96), e(0.8, 0.78, 0.82)).verdict(), "better");
        assert_eq!(v(Measure::TimePerStep, e(0.95, 0.94, 0.96), e(0.8, 0.78, 0.82)).verdict(), "worse");
        assert_eq!(v(Measure::Memory, e(0.8, 0.79, 0.81), e(0.95, 0.94, 0.96)).verdict(), "better");
        assert_eq!(v(Measure::Efficiency, e(0.9, 0.85, 0.95), e(0.92, 0.9, 0.94)).verdict(), "cannot tell");
        let line = v(Measure::Efficiency, e(0.95, 0.94, 0.96), e(0.8, 0.78, 0.82)).line();
        assert!(line.starts_with("Model1, 2 thread(s), efficiency: COLOUR 0.950 [0.940, 0.960] vs DD"), "{line}");
    }
}
