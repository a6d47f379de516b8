//! `mpm-bench imbalance`: the work imbalance of DD's uniform and balanced cuts over a run,
//! predicted from particle counts (nothing is timed, so it means the same on any machine).
//!
//! One serial simulation of the scenario runs; before every step the particles' cells on
//! the grid that step uses (the adaptive grid re-fitted to their bounding box, or the fixed
//! grid) are cut, for each thread count's layout ([`mpm_core::strategy::patch_layout`]),
//! uniformly as the paper's DD does and at the particle-count quantiles as `dd-balanced`
//! does ([`mpm_core::strategy::Cuts`], the code the solver runs). The work imbalance of a
//! step is the most particles in a patch over the mean per patch: a DD step's scatter and
//! binning take as long as the fullest patch, so it bounds the efficiency from above by
//! `1 / imbalance` for those stages. Block colouring's imbalance is predicted beside them,
//! from the same cells on the blocks the solver would cut for the thread count
//! ([`mpm_core::strategy::colour::imbalance`]).

use anyhow::{bail, Context, Result};
use mpm_core::grid::GridGeom;
use mpm_core::scenario::impact::Impact;
use mpm_core::scenario::taylor::{self, TaylorBar};
use mpm_core::strategy::{imbalance, patch_layout, BlockPlan, Cuts, LayoutChooser};
use mpm_core::{GridMode, Setup, SimConfig, Simulation};
use serde::Serialize;
use std::path::PathBuf;
use std::sync::Arc;

/// Predict the work imbalance of uniform and balanced DD cuts over a run (no timing).
#[derive(Debug, Clone)]
pub struct ImbalanceOptions {
    /// Scenario: taylor (the Taylor bar) or impact (sphere on plate).
    pub scenario: String,
    /// Model: Taylor bar 1-4; impact 1-3 = the small model with 2.12, 1.59, 1.06 mm cells,
    /// 4 = the large model.
    pub model: u32,
    /// Thread counts (one patch per thread; the layouts of `dd`), comma-separated.
    pub threads: Vec<usize>,
    /// Steps to run (default: to the scenario's end time, 40 us for the bar, 30.6 us for
    /// the impact).
    pub steps: Option<u64>,
    /// Folder for `imbalance-<scenario>-m<model>.{csv,png,svg}`.
    pub out: PathBuf,
}

/// One thread count's imbalance over the run.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct ImbalanceRow {
    /// Threads (= patches).
    pub threads: usize,
    /// Patch layout `px x py x pz` of uniform cuts (the paper's) on the first step's grid.
    pub layout: String,
    /// Layouts balanced cuts chose, most used first, with their step counts when more than
    /// one (e.g. `2x4x1` or `2x3x1 (148 steps), 1x6x1 (86 steps)`).
    pub balanced_layout: String,
    /// Uniform cuts: mean over the steps of max / mean particles per patch.
    pub uniform_mean: f64,
    /// Uniform cuts: the worst step.
    pub uniform_max: f64,
    /// Balanced cuts: mean over the steps.
    pub balanced_mean: f64,
    /// Balanced cuts: the worst step.
    pub balanced_max: f64,
    /// Block colouring: mean over the steps of its phases' fullest shares over their mean
    /// shares ([`mpm_core::strategy::colour::imbalance`]).
    pub colour_mean: f64,
    /// Block colouring: the worst step.
    pub colour_max: f64,
}

/// One step and thread count (a CSV row).
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct StepImbalance {
    /// Step about to be taken (1-based).
    pub step: u64,
    /// Simulated time at its start (s).
    pub time_s: f64,
    /// Threads (= patches).
    pub threads: usize,
    /// Layout `px x py x pz` of uniform cuts, as text.
    pub layout: String,
    /// Layout balanced cuts chose for the step.
    pub balanced_layout: String,
    /// Uniform cuts: max / mean particles per patch.
    pub uniform: f64,
    /// Balanced cuts: the same.
    pub balanced: f64,
    /// Block colouring: its phases' fullest shares over their mean shares.
    pub colour: f64,
}

/// The whole prediction.
#[derive(Clone, Debug, Serialize)]
pub struct ImbalanceReport {
    /// `taylor` or `impact`.
    pub scenario: String,
    /// Model number.
    pub model: u32,
    /// Model label.
    pub model_name: String,
    /// Particles.
    pub particles: usize,
    /// Steps evaluated.
    pub steps: u64,
    /// Per thread count, over the steps.
    pub rows: Vec<ImbalanceRow>,
    /// Per step and thread count.
    pub samples: Vec<StepImbalance>,
}

/// The scenario's set-up, grid mode and default end time.
fn scenario(a: &ImbalanceOptions) -> Result<(Setup, GridMode, f64)> {
    match a.scenario.as_str() {
        "taylor" => {
            let model = u8::try_from(a.model).ok().filter(|m| (1..=4).contains(m));
            let Some(model) = model else { bail!("unknown Taylor bar model {}: use 1-4", a.model) };
            let setup = TaylorBar { model, ..TaylorBar::default() }.setup()?;
            Ok((setup, GridMode::Fixed, taylor::DEFAULT_END_TIME))
        }
        _ => {
            let Some((spacing, cell)) = crate::campaign::plan::memory::impact_variant(a.model) else {
                bail!("unknown impact model {}: use 1-3 (small model, 2.12/1.59/1.06 mm cells) or 4 (large)", a.model)
            };
            let (setup, _) = Impact { spacing, cell, ..Impact::default() }.setup()?;
            Ok((setup, GridMode::Sparse, mpm_core::scenario::impact::DEFAULT_END_TIME))
        }
    }
}

/// Per-step work: the cells of the particles, their histograms per cell plane along each
/// axis, and per thread count the cuts, counts and layout choice.
struct Evaluator {
    cell_of: Vec<[u32; 3]>,
    marginals: [Vec<u32>; 3],
    uniform: Cuts,
    counts: Vec<u32>,
    /// One per thread count, carried from step to step as in the solver.
    choosers: Vec<LayoutChooser>,
}

/// `px x py x pz`.
fn layout_text(l: [usize; 3]) -> String {
    format!("{}x{}x{}", l[0], l[1], l[2])
}

impl Evaluator {
    /// Store the particles' cells on `geom` and their histograms per cell plane.
    fn load(&mut self, geom: &GridGeom, x: &[mpm_core::math::Vec3]) {
        self.cell_of.clear();
        self.cell_of.extend(x.iter().map(|&p| geom.shape_cell(p).map(|c| c as u32)));
        for (a, m) in self.marginals.iter_mut().enumerate() {
            m.clear();
            m.resize(geom.cells[a], 0);
            self.cell_of.iter().for_each(|c| m[c[a] as usize] += 1);
        }
    }

    /// Uniform cuts of the paper's layout and balanced cuts of the layout `dd-balanced`
    /// chooses (thread count number `k`): the two layouts and imbalances; then block
    /// colouring's imbalance.
    fn evaluate(&mut self, geom: &GridGeom, k: usize, threads: usize) -> ([usize; 3], [usize; 3], f64, f64, f64) {
        let layout = patch_layout(threads, geom.cells);
        self.uniform.uniform(layout, geom.cells);
        self.counts.resize(threads, 0);
        self.uniform.count(&self.cell_of, &mut self.counts);
        let u = imbalance(&self.counts).unwrap_or(1.0);
        let [mx, my, mz] = &self.marginals;
        let chosen = self.choosers[k].choose(threads, layout, [mx, my, mz]);
        let balanced = Cuts::balanced(&self.cell_of, geom.cells, chosen);
        balanced.count(&self.cell_of, &mut self.counts);
        let b = imbalance(&self.counts).unwrap_or(1.0);
        let plan = BlockPlan::new(geom, threads);
        let cells = self.cell_of.iter().map(|c| c.map(|i| i as usize));
        let c = mpm_core::strategy::colour::imbalance(&plan, cells, threads);
        (layout, chosen, u, b, c)
    }
}

/// Run the scenario serially and evaluate the cuts before every step (no printing).
pub fn measure(a: &ImbalanceOptions) -> Result<ImbalanceReport> {
    if a.threads.is_empty() || a.threads.contains(&0) {
        bail!("--threads needs thread counts of at least 1, e.g. 2,4,6,8");
    }
    let (setup, grid_mode, end_time) = scenario(a)?;
    let model_name = setup.model.clone();
    let spec = setup.grid.clone();
    let pool = mpm_host::pinning::build_pool(1, None)?.pool;
    let mut sim = Simulation::new(setup, SimConfig { grid_mode, ..SimConfig::default() }, Arc::clone(&pool))?;
    let mut ev = Evaluator {
        cell_of: Vec::new(),
        marginals: Default::default(),
        uniform: Cuts::default(),
        counts: Vec::new(),
        choosers: vec![LayoutChooser::default(); a.threads.len()],
    };
    let mut samples = Vec::new();
    let mut step = 0u64;
    while a.steps.map_or(sim.time() < end_time * (1.0 - 1e-12), |n| step < n) {
        let x = &sim.particles().x;
        let geom = if grid_mode.is_adaptive() {
            let (lo, hi) = sim.particles().bounding_box();
            GridGeom::fit(&spec, lo, hi)
        } else {
            *sim.geom()
        };
        ev.load(&geom, x);
        for (k, &t) in a.threads.iter().enumerate() {
            let (layout, chosen, uniform, balanced, colour) = ev.evaluate(&geom, k, t);
            samples.push(StepImbalance {
                step: step + 1,
                time_s: sim.time(),
                threads: t,
                layout: layout_text(layout),
                balanced_layout: layout_text(chosen),
                uniform,
                balanced,
                colour,
            });
        }
        let dt_max = if a.steps.is_some() { f64::INFINITY } else { end_time - sim.time() };
        pool.install(|| sim.step(dt_max)).with_context(|| format!("step {} failed", step + 1))?;
        step += 1;
    }
    let rows = a.threads.iter().map(|&t| row_of(t, &samples)).collect();
    Ok(ImbalanceReport {
        scenario: a.scenario.clone(),
        model: a.model,
        model_name,
        particles: sim.particles().len(),
        steps: step,
        rows,
        samples,
    })
}

/// The summary row of `threads` from the per-step samples.
fn row_of(threads: usize, samples: &[StepImbalance]) -> ImbalanceRow {
    let mine: Vec<&StepImbalance> = samples.iter().filter(|s| s.threads == threads).collect();
    let n = mine.len().max(1) as f64;
    let mean = |f: fn(&StepImbalance) -> f64| mine.iter().map(|s| f(s)).sum::<f64>() / n;
    let max = |f: fn(&StepImbalance) -> f64| mine.iter().map(|s| f(s)).fold(0.0, f64::max);
    // Layouts balanced cuts used, most steps first (ties: first used first).
    let mut used: Vec<(&str, usize)> = Vec::new();
    for s in &mine {
        match used.iter_mut().find(|(l, _)| *l == s.balanced_layout) {
            Some((_, c)) => *c += 1,
            None => used.push((&s.balanced_layout, 1)),
        }
    }
    used.sort_by_key(|u| std::cmp::Reverse(u.1));
    let balanced_layout = match used.as_slice() {
        [(l, _)] => l.to_string(),
        _ => used
            .iter()
            .map(|(l, c)| format!("{l} ({c} step{})", if *c == 1 { "" } else { "s" }))
            .collect::<Vec<_>>()
            .join(", "),
    };
    ImbalanceRow {
        threads,
        layout: mine.first().map_or_else(String::new, |s| s.layout.clone()),
        balanced_layout,
        uniform_mean: mean(|s| s.uniform),
        uniform_max: max(|s| s.uniform),
        balanced_mean: mean(|s| s.balanced),
        balanced_max: max(|s| s.balanced),
        colour_mean: mean(|s| s.colour),
        colour_max: max(|s| s.colour),
    }
}

/// The table for people.
pub fn table(r: &ImbalanceReport) -> String {
    let mut s = format!(
        "{} {} ({} particles), {} steps: work imbalance = most particles in a patch / mean per patch\n",
        r.scenario, r.model_name, r.particles, r.steps
    );
    s.push_str(&format!(
        "{:>7}  {:<7}  {:>12} {:>11}  {:>13} {:>12}  {:>11} {:>10}  {}\n",
        "threads",
        "layout",
        "uniform mean",
        "uniform max",
        "balanced mean",
        "balanced max",
        "colour mean",
        "colour max",
        "balanced layout"
    ));
    for row in &r.rows {
        s.push_str(&format!(
            "{:>7}  {:<7}  {:>12.3} {:>11.3}  {:>13.3} {:>12.3}  {:>11.3} {:>10.3}  {}\n",
            row.threads,
            row.layout,
            row.uniform_mean,
            row.uniform_max,
            row.balanced_mean,
            row.balanced_max,
            row.colour_mean,
            row.colour_max,
            row.balanced_layout
        ));
    }
    s.push_str(
        "layout: the paper's, used by uniform cuts; balanced layout: the one dd-balanced chose (steps per layout if it \
         changed); colour: the colour phases' fullest shares over their mean shares (blocks of the solver's rule)\n",
    );
    s
}

/// Stem of the output files.
pub fn stem(r: &ImbalanceReport) -> String {
    format!("imbalance-{}-m{}", r.scenario, r.model)
}

/// Write the per-step samples as CSV to `path`.
pub fn write_csv(r: &ImbalanceReport, path: &std::path::Path) -> Result<()> {
    let mut w = csv::Writer::from_path(path).with_context(|| format!("cannot write {}", path.display()))?;
    for s in &r.samples {
        w.serialize(s)?;
    }
    w.flush().with_context(|| format!("cannot write {}", path.display()))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn args(scenario: &str, model: u32, steps: u64) -> ImbalanceOptions {
        ImbalanceOptions {
            scenario: scenario.into(),
            model,
            threads: vec![1, 2, 4, 8],
            steps: Some(steps),
            out: PathBuf::from("unused"),
        }
    }

    /// Taylor Model 1: one sample per step and thread count; one patch is always balanced;
    /// balanced cuts are never worse than uniform on the symmetric bar, and the table and
    /// CSV carry every row.
    #[test]
    fn taylor_bar_balanced_never_worse_than_uniform() {
        let r = measure(&args("taylor", 1, 3)).unwrap();
        assert_eq!(r.steps, 3);
        assert_eq!(r.samples.len(), 3 * 4);
        assert_eq!(r.rows[0].uniform_max, 1.0);
        assert_eq!(r.rows[0].balanced_max, 1.0);
        assert_eq!(r.rows[3].layout, "2x2x2");
        // The symmetric bar keeps the paper's layout with balanced cuts too.
        assert_eq!(r.rows[3].balanced_layout, "2x2x2");
        for row in &r.rows {
            assert!(row.balanced_max <= row.uniform_max + 1e-12, "{row:?}");
            assert!(row.balanced_mean >= 1.0 && row.uniform_mean >= row.balanced_mean - 1e-12, "{row:?}");
            assert!(row.colour_mean >= 1.0 && row.colour_max >= row.colour_mean, "{row:?}");
        }
        let t = table(&r);
        assert!(t.contains("2x2x2") && t.contains("balanced mean"), "{t}");
        let dir = std::env::temp_dir().join(format!("mpm-bench-imbalance-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let csv = dir.join("x.csv");
        write_csv(&r, &csv).unwrap();
        let text = std::fs::read_to_string(&csv).unwrap();
        assert!(text.starts_with("step,time_s,threads,layout,balanced_layout,uniform,balanced,colour\n"), "{text}");
        assert_eq!(text.lines().count(), 1 + 12);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn bad_arguments_are_refused_with_advice() {
        let e = measure(&args("taylor", 7, 1)).unwrap_err().to_string();
        assert!(e.contains("use 1-4"), "{e}");
        let e = measure(&args("impact", 9, 1)).unwrap_err().to_string();
        assert!(e.contains("use 1-3"), "{e}");
        let e = measure(&ImbalanceOptions { threads: vec![0], ..args("taylor", 1, 1) }).unwrap_err().to_string();
        assert!(e.contains("at least 1"), "{e}");
    }
}
