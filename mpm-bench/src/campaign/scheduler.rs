//! Where a campaign's runs run.
//!
//! * [`Scheduler::Local`] (`--scheduler local`, the default): on this machine, one fresh
//!   child process after another, by the runner's loop ([`super::runner`]).
//! * [`Scheduler::Slurm`] (`--scheduler slurm`): one Slurm batch job per run, submitted and
//!   collected by [`super::slurm`]; each job runs `mpm-bench job FILE` on a node of its own,
//!   which runs the run there exactly as the local loop would ([`super::job`]).
//!
//! Either way a finished run is one row appended to the campaign's `runs.csv`, and resume,
//! the memory guard, placement and its verification mean the same.

pub use super::slurm::SlurmOptions;

/// Where the runs of a campaign run.
#[derive(Clone, Debug, Default, PartialEq)]
pub enum Scheduler {
    /// Here, one child process at a time.
    #[default]
    Local,
    /// As Slurm batch jobs, one per run.
    Slurm(SlurmOptions),
}

impl Scheduler {
    /// Whether the runs run on this machine.
    pub fn runs_here(&self) -> bool {
        matches!(self, Scheduler::Local)
    }

    /// For the manifest's session: `None` here, else the cluster and the options.
    pub fn describe(&self) -> Option<String> {
        match self {
            Scheduler::Local => None,
            Scheduler::Slurm(s) => Some(s.describe()),
        }
    }
}
