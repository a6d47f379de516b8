//! Which scheduler a session asked for (`--scheduler`), with its options.
//!
//! * [`SchedulerKind::Local`] (`--scheduler local`, the default): on this machine, one fresh
//!   child process after another ([`super::local`]).
//! * [`SchedulerKind::Slurm`] (`--scheduler slurm`): the runs as Slurm job arrays (one array
//!   task per run, one array per resource shape), submitted and collected by
//!   [`super::slurm`]; each task runs `mpm-bench job FILE` on a node of its own, which runs
//!   the run there exactly as the local loop would ([`super::job`]).
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
    /// As Slurm job arrays, one task per run.
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
    /// At most this many tasks of each of the campaign's arrays running at once (`%N`).
    pub max_jobs: Option<usize>,
    /// Submit, then exit without waiting: a later invocation collects the jobs.
    pub detach: bool,
    /// How often `squeue` is asked (default [`DEFAULT_POLL`]).
    pub poll_interval: Option<Duration>,
    /// `--sbatch-arg`: options passed to `sbatch` after the harness's own (checked by
    /// [`check_sbatch_arg`]).
    pub sbatch_extra: Vec<String>,
}

/// How often `squeue` is asked unless `--poll-interval` says otherwise: sites expect no
/// faster (many rate-limit slurmctld).
pub const DEFAULT_POLL: Duration = Duration::from_secs(30);

/// How many seconds before its time limit a checkpointed run's job is sent SIGUSR1
/// (`--signal=B:USR1@...`): time for the solver's last checkpoint.
pub const SIGNAL_LEAD_S: u64 = 120;

/// The resources of one run's job: its ranks (`--ntasks`) and threads per rank
/// (`--cpus-per-task` when several ranks).
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub struct Shape {
    /// MPI ranks: the job's tasks.
    pub ranks: usize,
    /// Threads per rank: each task's CPUs (asked only with several ranks).
    pub threads: usize,
}

impl Shape {
    /// The shape a run of `ranks` ranks of `threads` threads needs: one task (its threads
    /// use the node) for one rank, else `ranks` tasks of `threads` CPUs.
    pub fn of(ranks: usize, threads: usize) -> Self {
        if ranks > 1 {
            Self { ranks, threads }
        } else {
            Self { ranks: 1, threads: 0 }
        }
    }

    /// Its `sbatch` options: `--nodes=1 --ntasks=R [--cpus-per-task=T]`.
    fn args(self) -> Vec<String> {
        let mut a = vec!["--nodes=1".to_string(), format!("--ntasks={}", self.ranks)];
        if self.ranks > 1 {
            a.push(format!("--cpus-per-task={}", self.threads));
        }
        a
    }
}

/// The `sbatch` options the protocol relies on, with why a `--sbatch-arg` may not give them:
/// (long name, short letter).
const PROTOCOL_OPTIONS: [(&str, Option<char>, &str); 10] = [
    ("--array", Some('a'), "the harness submits the runs as job arrays of its own"),
    ("--parsable", None, "the harness asks for sbatch's parsable answer itself"),
    ("--requeue", None, "a requeued job would run its run twice: every job is submitted --no-requeue"),
    ("--job-name", Some('J'), "the job name is how a later invocation finds an array that a killed one submitted"),
    ("--output", Some('o'), "each task writes json/<run id>.slurm.out, where the harness reads it"),
    ("--error", Some('e'), "each task writes json/<run id>.slurm.out, where the harness reads it"),
    ("--chdir", Some('D'), "the working folder is how a later invocation finds its arrays"),
    ("--wrap", None, "the batch script is the harness's"),
    ("--ntasks", Some('n'), "the tasks are each run's ranks"),
    ("--cpus-per-task", Some('c'), "each task's CPUs are the run's threads per rank"),
];

/// Whether `arg` may pass through to `sbatch` (`--sbatch-arg`): an option, and none the
/// protocol relies on ([`PROTOCOL_OPTIONS`]); `Err` says why not.
pub fn check_sbatch_arg(arg: &str) -> Result<(), String> {
    let arg = arg.trim();
    if !arg.starts_with('-') || arg == "-" || arg == "--" {
        return Err(format!(
            "--sbatch-arg '{arg}' is not an sbatch option: give one option a time, e.g. --sbatch-arg=--qos=normal"
        ));
    }
    let name = arg.split('=').next().unwrap_or(arg);
    let refused = PROTOCOL_OPTIONS.iter().find(|(long, short, _)| {
        if let Some(given) = name.strip_prefix("--") {
            // sbatch takes any unambiguous abbreviation of a long option.
            *long == name || (given.len() >= 3 && long[2..].starts_with(given) && !given.contains('-'))
        } else {
            short.is_some_and(|c| name[1..].starts_with(c))
        }
    });
    match refused {
        Some((long, _, why)) => {
            Err(format!("--sbatch-arg '{arg}' is refused: {long} is set by the harness ({why}); leave it out"))
        }
        None => Ok(()),
    }
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
        if !self.sbatch_extra.is_empty() {
            s.push_str(&format!(", sbatch {}", self.sbatch_extra.join(" ")));
        }
        s
    }

    /// The `sbatch` options of an array of runs of `shape`: a node of its own for each task
    /// with the tasks and CPUs the shape needs, never requeued by Slurm (a job that ends,
    /// however, is collected as it ended; the harness submits its run again), the
    /// partition, account and time limit (`timeout`: the campaign's per-run limit), with
    /// `checkpointed` SIGUSR1 to the batch step [`SIGNAL_LEAD_S`] before the limit (the
    /// solver's last checkpoint), then the `--sbatch-arg`s (after ours: the site overrides).
    pub fn sbatch_args(&self, timeout: Option<Duration>, shape: Shape, checkpointed: bool) -> Vec<String> {
        let mut a: Vec<String> = vec!["--parsable".into()];
        a.extend(shape.args());
        a.extend(["--exclusive", "--no-requeue"].map(String::from));
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
        if checkpointed {
            a.push(format!("--signal=B:USR1@{SIGNAL_LEAD_S}"));
        }
        a.extend(self.sbatch_extra.iter().cloned());
        a
    }

    /// How often `squeue` is asked.
    pub fn poll(&self) -> Duration {
        self.poll_interval.unwrap_or(DEFAULT_POLL)
    }
}
