//! The local scheduler: the runs here, one fresh child process after another, in the
//! campaign's seeded order, each recorded as soon as it ends. A run that failed because the
//! disk is full stops the campaign ([`DiskFull`]) instead of being recorded.

use super::scheduler::Scheduler;
use super::state::{next_run_id, solver_for, CampaignState};
use crate::campaign::exec::process::Runner;
use crate::campaign::exec::watch::HostWatch;
use crate::campaign::store::disk::{full_in_words, DiskFull};
use crate::campaign::store::record::{Row, Status};
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
            if let Some(why) = disk_full(&row) {
                // Every run after it would fail the same way: stop, the run unrecorded.
                let what = format!("run {} could not write its files ({})", row.id.run_id, row.outcome.reason);
                return Err(DiskFull { folder: s.ctx.json_dir.clone(), why, what }.into());
            }
            s.books.record(n, spec, &row)?;
        }
        Ok(())
    }
}

/// What the system said, when `row` is a run that failed because a disk is full (its spec or
/// its summary could not be written).
fn disk_full(row: &Row) -> Option<&'static str> {
    (row.outcome.status == Status::Failed).then(|| full_in_words(&row.outcome.reason)).flatten()
}

#[cfg(test)]
mod tests {
    use super::super::{execute, ExecOptions};
    use crate::campaign::exec::process::{MockRunner, RunOutput, RunRequest, Runner};
    use crate::campaign::exec::solver::Solver;
    use crate::campaign::plan::matrix::{Campaign, Overrides};
    use crate::campaign::plan::preset;
    use crate::campaign::store::csv::read_rows;
    use crate::campaign::store::record::Status;
    use crate::machine::topology::Machine;
    use std::sync::atomic::AtomicBool;

    /// The mock, but its `full_at`-th run (1-based) fails as `mpm` does when its summary
    /// cannot be written on a full disk.
    struct FullDisk {
        mock: MockRunner,
        full_at: usize,
    }

    impl Runner for FullDisk {
        fn run(&mut self, req: &RunRequest) -> RunOutput {
            if self.mock.calls.len() + 1 == self.full_at {
                self.mock.calls.push(req.clone());
                let why = std::io::Error::from_raw_os_error(libc::ENOSPC);
                return RunOutput {
                    exit_code: Some(1),
                    stderr_tail: format!("error: cannot write the JSON summary | caused by: {why}"),
                    process_wall_s: 0.01,
                    ..RunOutput::default()
                };
            }
            self.mock.run(req)
        }
    }

    /// A run that fails on a full disk stops the campaign with an error naming the full
    /// disk, that run unrecorded and the rows before it kept; the same campaign resumed
    /// with space back ends with one ok row per run and no failed one.
    #[test]
    fn a_full_disk_stops_the_campaign_and_it_resumes() {
        let (p, src) = preset::load_preset("smoke", None).unwrap();
        let c = Campaign::resolve(p, src, &Overrides::default()).unwrap();
        let m = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let solvers: Vec<Solver> =
            c.opts.iter().map(|&opt| Solver { opt, path: "mock".into(), sha256: "0123456789abcdef".into() }).collect();
        let out = tempfile::tempdir().unwrap();
        let opts = ExecOptions { out_root: out.path().into(), quiet: true, command: "t".into(), ..Default::default() };
        let flag = AtomicBool::new(false);
        let mut full = FullDisk { mock: MockRunner::default(), full_at: 3 };
        let err = format!("{:#}", execute(&c, &m, &solvers, &mut full, &opts, &flag).unwrap_err());
        assert!(err.contains("is full (No space left on device)") && err.contains("run the same command"), "{err}");
        assert_eq!(full.mock.calls.len(), 3, "no run after the full disk");
        let csv = std::fs::read_dir(out.path()).unwrap().flatten().next().unwrap().path().join(&c.id).join("runs.csv");
        let rows = read_rows(&csv).unwrap();
        assert_eq!(rows.len(), 2);
        let done = execute(&c, &m, &solvers, &mut MockRunner::default(), &opts, &flag).unwrap();
        assert_eq!(done.counts.ok, c.expand().len() - 2);
        let rows = read_rows(&csv).unwrap();
        assert!(rows.iter().all(|r| r.outcome.status == Status::Ok), "no failed row");
        let keys: std::collections::HashSet<_> = rows.iter().map(|r| r.key()).collect();
        assert_eq!((keys.len(), rows.len()), (c.expand().len(), c.expand().len()));
    }
}
