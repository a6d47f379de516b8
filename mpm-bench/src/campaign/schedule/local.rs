//! The local scheduler: the runs here, one fresh child process after another, in the
//! campaign's seeded order, each recorded as soon as it ends.

use super::scheduler::Scheduler;
use super::state::{next_run_id, solver_for, CampaignState};
use crate::campaign::exec::process::Runner;
use crate::campaign::exec::watch::HostWatch;
use anyhow::Result;
use std::sync::atomic::Ordering;

/// Runs here, one after another, by `runner`, with the host watched around each (`watch`).
pub struct Local<'r> {
    /// What runs a run (the `mpm` child process, or the mock).
    pub runner: &'r mut dyn Runner,
    /// The host's load and calibration around each run.
    pub watch: Option<HostWatch>,
}

impl Scheduler for Local<'_> {
    fn run_all(&mut self, s: &mut CampaignState<'_>) -> Result<()> {
        for (n, (order_index, spec)) in s.plan.todo.iter().enumerate() {
            if s.ctx.interrupted.load(Ordering::SeqCst) {
                s.books.counts.interrupted = true;
                break;
            }
            s.books.progress.start(n, spec);
            let solver = solver_for(&s.solvers, spec)?;
            let run_id = next_run_id(&mut s.attempts, spec);
            let Some(row) = s.ctx.run_one(self.runner, self.watch.as_mut(), solver, spec, *order_index, run_id)? else {
                s.books.counts.interrupted = true;
                break;
            };
            s.books.record(n, spec, &row)?;
        }
        Ok(())
    }
}
