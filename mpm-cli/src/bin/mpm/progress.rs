//! The progress bar of a run on a terminal: simulated time or steps, rate and ETA.

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use mpm_core::Simulation;
use std::io::IsTerminal;
use std::time::Instant;

/// The progress bar, if one is shown.
pub struct Progress {
    /// The bar.
    pub bar: ProgressBar,
    by_steps: bool,
    end_time: Option<f64>,
    step_limit: Option<u64>,
    start: Instant,
    /// The step the bar started at (a run continued from a checkpoint starts there).
    first_step: u64,
}

impl Progress {
    /// The bar of a run stopping at `end_time` or `step_limit`, starting at `sim`'s step.
    pub fn new(quiet: bool, end_time: Option<f64>, step_limit: Option<u64>, sim: &Simulation) -> Option<Self> {
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
        let progress = Self { bar, by_steps, end_time, step_limit, start: Instant::now(), first_step: sim.steps() };
        progress.update(sim);
        progress.bar.reset_eta();
        Some(progress)
    }

    pub fn update(&self, sim: &Simulation) {
        let steps = sim.steps();
        let rate = (steps - self.first_step) as f64 / self.start.elapsed().as_secs_f64().max(1e-9);
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
