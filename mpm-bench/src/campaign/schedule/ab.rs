//! Several builds' campaigns of one preset run side by side (`mpm-bench ab`, and its
//! calibration): each planned run once per side, the sides' processes back to back, so that
//! the host's drift reaches every side alike and a pair compares two builds moments apart.
//!
//! The sides share the campaign's seeded run order (cell by cell, repetition by repetition).
//! Within a pair the sides take turns in a seeded counterbalanced order ([`interleave`]):
//! with two sides `A B B A A B B A ...` (ABBA), the first side drawn from the seed; with more,
//! one seeded permutation and its reverse alternating, so that every side's mean position
//! over two pairs is the same and a linear drift cancels. The order that ran is recorded
//! ([`AbRecord`], `ab.json` in the output folder). Each side appends to its own campaign
//! folder as `mpm-bench run` does (its rows, manifest, summaries); an interrupted run resumes
//! with the same command (the pairs whose runs both sides hold are not run again).

use super::execute::Session;
use super::state::{next_run_id, solver_for, CampaignState, ExecOptions};
use crate::campaign::exec::process::Runner;
use crate::campaign::exec::solver::Solver;
use crate::campaign::plan::matrix::{Campaign, PlannedRun};
use crate::campaign::schedule::state::Plan;
use crate::campaign::store::manifest::{self, BinaryInfo};
use crate::machine::topology::Machine;
use crate::util::SplitMix64;
use anyhow::{bail, Context, Result};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use serde::{Deserialize, Serialize};
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// One side: a build (its solvers) and its campaign (the preset with this side's test knobs),
/// appending under `out_root` as `mpm-bench run --out OUT_ROOT` would.
pub struct Side<'a> {
    /// The side's name in the record and the verdict (`baseline`, `candidate`, `clean-3`).
    pub label: String,
    /// The campaign of this side.
    pub campaign: &'a Campaign,
    /// Its solver binaries.
    pub solvers: &'a [Solver],
    /// The results root of this side.
    pub out_root: PathBuf,
}

/// The seeded, counterbalanced order of `sides` sides in each of `pairs` pairs: pair `i` runs
/// the sides in the order `out[i]` (a permutation of `0..sides`). A seeded permutation on
/// even pairs, its reverse on odd ones: with two sides `AB BA AB BA ...` or `BA AB ...`.
pub fn interleave(sides: usize, pairs: usize, seed: u64) -> Vec<Vec<usize>> {
    let mut perm: Vec<usize> = (0..sides).collect();
    let mut rng = SplitMix64(seed ^ 0xAB_AB_AB_AB);
    for i in (1..sides).rev() {
        let j = usize::try_from(rng.below(i as u64 + 1)).unwrap_or(0);
        perm.swap(i, j);
    }
    let rev: Vec<usize> = perm.iter().rev().copied().collect();
    (0..pairs).map(|i| if i % 2 == 0 { perm.clone() } else { rev.clone() }).collect()
}

/// The order as letters (`AB`, `BA`; `A`-`Z` for the first 26 sides), for the record.
pub fn letters(order: &[usize]) -> String {
    order.iter().map(|&s| char::from(b'A' + u8::try_from(s.min(25)).unwrap_or(25))).collect()
}

/// What one side was, in the record.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct SideRecord {
    /// Its name.
    pub label: String,
    /// Its letter in [`AbRecord::order`].
    pub letter: String,
    /// Its campaign folder.
    pub dir: PathBuf,
    /// Its solver binaries (path, SHA-256).
    pub solvers: Vec<BinaryInfo>,
    /// Its injected efficiency loss (`--inject-slowdown`), if any: a test knob.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_slowdown: Option<f64>,
    /// Its injected step slowdown (`--inject-step-slowdown`), if any: a test knob.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inject_step_slowdown: Option<f64>,
    /// Its session's counts (rows written, ok, failed, ...).
    pub counts: manifest::SessionCounts,
    /// How its build was had (set by the command that knows: a revision built, binaries
    /// given), with the build's seconds.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub build: Option<serde_json::Value>,
}

/// `ab.json`: what ran side by side, in which order.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct AbRecord {
    /// The seed of the order.
    pub seed: u64,
    /// The sides.
    pub sides: Vec<SideRecord>,
    /// Per pair run in this session: its run (the campaign's label and repetition) and the
    /// sides' order as letters (`AB`, `BA`).
    pub order: Vec<(String, String)>,
    /// Wall seconds of the session.
    pub wall_s: f64,
    /// The session was interrupted (Ctrl-C): the same command continues.
    pub interrupted: bool,
}

impl AbRecord {
    /// Write it to `path` (atomically).
    pub fn write(&self, path: &Path) -> Result<()> {
        let text = serde_json::to_string_pretty(self)?;
        mpm_host::atomic::write_atomic(path, text.as_bytes())
            .with_context(|| format!("cannot write {}", path.display()))
    }
}

/// The run a pair is made of, as the sides see it: the configuration and the repetition
/// (test knobs aside).
fn pair_label(run: &PlannedRun) -> String {
    format!("{}-r{}", run.label(), run.rep)
}

/// Run `sides` side by side on `machine` with `runner`, each into its campaign folder under
/// its `out_root` (the other settings from `opts`), in the order [`interleave`] gives for
/// `seed`. Every side must plan the same runs (one preset; only test knobs may differ).
pub fn run_sides(
    sides: &[Side<'_>],
    machine: &Machine,
    runner: &mut dyn Runner,
    opts: &ExecOptions,
    seed: u64,
    interrupted: &AtomicBool,
) -> Result<AbRecord> {
    let t0 = Instant::now();
    if sides.len() < 2 {
        bail!("side-by-side runs need at least two sides, got {}", sides.len());
    }
    let side_opts =
        |s: &Side<'_>| ExecOptions { out_root: s.out_root.clone(), quiet: true, eta: false, ..opts.clone() };
    let mut sessions = Vec::new();
    for s in sides {
        let o = side_opts(s);
        let plan = Plan::of(s.campaign, machine, s.solvers, &o).with_context(|| format!("the {} side", s.label))?;
        let counts = manifest::SessionCounts {
            planned: plan.planned,
            already_done: plan.planned - plan.todo.len(),
            ..Default::default()
        };
        sessions.push(Session::open(plan, (s.campaign, machine, s.solvers), &o, counts, None, None)?);
    }
    let order = sides[0].campaign.ordered(sides[0].campaign.seed);
    for (s, side) in sides.iter().enumerate().skip(1) {
        let other = side.campaign.ordered(side.campaign.seed);
        if other.len() != order.len() || other.iter().zip(&order).any(|(a, b)| pair_label(a) != pair_label(b)) {
            bail!(
                "the {} side plans other runs than the {} side: side-by-side runs need one preset and one seed (only \
                 the test knobs may differ); side {s}",
                side.label,
                sides[0].label
            );
        }
    }
    let todo: Vec<HashSet<String>> =
        sessions.iter().map(|s| s.plan.todo.iter().map(|(_, r)| pair_label(r)).collect()).collect();
    let pairs: Vec<&PlannedRun> = order.iter().filter(|r| todo.iter().any(|t| t.contains(&pair_label(r)))).collect();
    let turns = interleave(sides.len(), pairs.len(), seed);
    let bar = progress(pairs.len() * sides.len(), !opts.quiet);
    let mut record_order = Vec::new();
    {
        let mut states: Vec<CampaignState<'_>> = sessions
            .iter_mut()
            .zip(sides)
            .map(|(sess, side)| sess.state(side.campaign, machine, side.solvers, interrupted))
            .collect();
        'pairs: for (p, run) in pairs.iter().enumerate() {
            let label = pair_label(run);
            record_order.push((label.clone(), letters(&turns[p])));
            for &s in &turns[p] {
                if interrupted.load(Ordering::SeqCst) {
                    break 'pairs;
                }
                bar.set_message(format!("{} {}", sides[s].label, run.describe()));
                if todo[s].contains(&label) {
                    run_in(&mut states[s], runner, &label, &bar)?;
                }
                bar.inc(1);
            }
        }
    }
    bar.finish_and_clear();
    let was_interrupted = interrupted.load(Ordering::SeqCst);
    let mut records = Vec::new();
    for ((sess, side), s) in sessions.into_iter().zip(sides).zip(0..) {
        let dir = sess.plan.dir.clone();
        let counts = sess.close(interrupted)?;
        records.push(SideRecord {
            label: side.label.clone(),
            letter: letters(&[s]),
            dir,
            solvers: side.solvers.iter().map(Solver::info).collect(),
            inject_slowdown: side.campaign.inject_slowdown,
            inject_step_slowdown: side.campaign.inject_step_slowdown,
            counts,
            build: None,
        });
    }
    Ok(AbRecord {
        seed,
        sides: records,
        order: record_order,
        wall_s: t0.elapsed().as_secs_f64(),
        interrupted: was_interrupted,
    })
}

/// Run the side's planned run labelled `label` (the one of its runs still to do) and record
/// its row.
fn run_in(state: &mut CampaignState<'_>, runner: &mut dyn Runner, label: &str, bar: &ProgressBar) -> Result<()> {
    let Some((n, (order_index, spec))) = state.plan.todo.iter().enumerate().find(|(_, (_, r))| pair_label(r) == label)
    else {
        return Ok(());
    };
    let solver = solver_for(&state.solvers, spec)?;
    let run_id = next_run_id(&mut state.attempts, spec);
    let Some(row) = state.ctx.run_one(runner, None, solver, spec, *order_index, run_id)? else {
        state.books.counts.interrupted = true;
        return Ok(());
    };
    state.books.record(n, spec, &row)?;
    if row.outcome.status != crate::campaign::store::record::Status::Ok {
        bar.println(format!("{label}: {} ({})", row.outcome.status.as_str(), row.outcome.reason));
    }
    Ok(())
}

/// The bar over every side's runs.
fn progress(total: usize, show: bool) -> ProgressBar {
    let bar = if show && total > 0 {
        ProgressBar::with_draw_target(Some(total as u64), ProgressDrawTarget::stderr())
    } else {
        ProgressBar::hidden()
    };
    bar.set_style(
        ProgressStyle::with_template("[{elapsed_precise}] {bar:24.cyan/blue} {pos}/{len} runs ETA {eta} | {wide_msg}")
            .expect("valid template")
            .progress_chars("=> "),
    );
    bar.enable_steady_tick(Duration::from_millis(500));
    bar
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Two sides alternate ABBA (or BAAB), the start from the seed; more sides take a seeded
    /// permutation and its reverse, so every side's mean position over two pairs is equal.
    #[test]
    fn sides_alternate_counterbalanced() {
        let starts: HashSet<String> = (0..16).map(|seed| letters(&interleave(2, 1, seed)[0])).collect();
        assert_eq!(starts.len(), 2, "the seed chooses which side starts: {starts:?}");
        for seed in 0..16 {
            let o = interleave(2, 6, seed);
            let text: String = o.iter().map(|p| letters(p)).collect();
            assert!(text == "ABBAABBAABBA" || text == "BAABBAABBAAB", "{text}");
            let five = interleave(5, 4, seed);
            for pair in five.chunks(2) {
                for side in 0..5 {
                    let pos: usize = pair.iter().map(|p| p.iter().position(|&s| s == side).unwrap()).sum();
                    assert_eq!(pos, 4, "side {side} in {pair:?}");
                }
            }
        }
        assert_eq!(interleave(3, 4, 7), interleave(3, 4, 7), "the order is a function of the seed");
    }
}
