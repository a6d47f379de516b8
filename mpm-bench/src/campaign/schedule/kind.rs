//! Which scheduler a session asked for (`--scheduler`), with its options.
//!
//! * [`SchedulerKind::Local`] (`--scheduler local`, the default): on this machine, one fresh
//!   child process after another ([`super::local`]).
//! * [`SchedulerKind::Slurm`] (`--scheduler slurm`): one Slurm batch job per run, submitted
//!   and collected by [`super::slurm`]; each job runs `mpm-bench job FILE` on a node of its
//!   own, which runs the run there exactly as the local loop would ([`super::job`]).
//!
//! Either way a finished run is one row appended to the campaign's `runs.csv`, and resume,
//! the memory guard, placement and its verification mean the same.

use crate::campaign::plan::matrix::sanitize_id;
use std::time::Duration;

/// Where the runs of a campaign run (the scheduler chosen, [`super::Scheduler`]).
#[derive(Clone, Debug, Default, PartialEq)]
pub enum SchedulerKind {
    /// Here, one child process at a time.
    #[default]
    Local,
    /// As Slurm batch jobs, one per run.
    Slurm(SlurmOptions),
}

impl SchedulerKind {
    /// Whether the runs run on this machine.
    pub fn runs_here(&self) -> bool {
        matches!(self, SchedulerKind::Local)
    }

    /// For the manifest's session: `None` here, else the cluster and the options.
    pub fn describe(&self) -> Option<String> {
        match self {
            SchedulerKind::Local => None,
            SchedulerKind::Slurm(s) => Some(s.describe()),
        }
    }
}

/// The file of submitted jobs in a campaign folder.
pub const JOBS_FILE: &str = "slurm-jobs.json";

/// `--scheduler slurm` and its options.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SlurmOptions {
    /// The cluster's name (`scontrol show config`): the campaign folder is
    /// `<out>/slurm-<cluster>/<campaign>`.
    pub cluster: String,
    /// `--partition` of every job (default: the cluster's default partition).
    pub partition: Option<String>,
    /// `--account` of every job.
    pub account: Option<String>,
    /// `--time` of every job, as `sbatch` takes it (`30`, `1:30:00`, `1-00:00:00`); default:
    /// the preset's per-run timeout plus two minutes, else the partition's default.
    pub time_limit: Option<String>,
    /// At most this many of the campaign's jobs in the queue at once.
    pub max_jobs: Option<usize>,
    /// Submit, then exit without waiting: a later invocation collects the jobs.
    pub detach: bool,
}

impl SlurmOptions {
    /// The folder under the results root: `slurm-<cluster>`.
    pub fn folder(&self) -> String {
        format!("slurm-{}", sanitize_id(&self.cluster))
    }

    /// `slurm cluster C, partition P, account A, time T` (what was given).
    pub fn describe(&self) -> String {
        let mut s = format!("slurm cluster {}", self.cluster);
        for (name, v) in [("partition", &self.partition), ("account", &self.account), ("time limit", &self.time_limit)]
        {
            if let Some(v) = v {
                s.push_str(&format!(", {name} {v}"));
            }
        }
        s
    }

    /// The `sbatch` options every job of the campaign shares: a node of its own, never
    /// requeued by Slurm (a job that ends, however, is collected as it ended; the harness
    /// submits its run again), and the partition, account and time limit (`timeout`: the
    /// campaign's per-run limit).
    pub fn sbatch_args(&self, timeout: Option<Duration>) -> Vec<String> {
        let mut a: Vec<String> =
            ["--parsable", "--nodes=1", "--ntasks=1", "--exclusive", "--no-requeue"].map(String::from).to_vec();
        if let Some(p) = &self.partition {
            a.push(format!("--partition={p}"));
        }
        if let Some(acc) = &self.account {
            a.push(format!("--account={acc}"));
        }
        let time = self.time_limit.clone().or_else(|| timeout.map(|t| (t.as_secs() + 120).div_ceil(60).to_string()));
        if let Some(t) = time {
            a.push(format!("--time={t}"));
        }
        a
    }
}
