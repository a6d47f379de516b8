//! `slurm-jobs.json`, the ledger of a campaign's Slurm jobs ([`JobsFile`]), and the fence every
//! job passes before it writes ([`Fence`]).
//!
//! The runs go to Slurm as job arrays, one task per run: the record of a run names its array
//! task as Slurm does, `<array job id>_<task id>`, and the batch (the array) it went in with.
//! The harness records the runs of a batch in the ledger *before* `sbatch` is asked (with
//! empty job ids), fills the job ids in as soon as `sbatch` answers, and forgets a run's
//! record once its row is in `runs.csv`. So a task always has a record while it may run, and
//! a harness killed between `sbatch`'s answer and the ledger's update leaves records without
//! job ids, which the next invocation fills by finding the array by its name ([`job_name`] of
//! the batch).
//!
//! A task runs its run, and writes its files, only while the ledger's record of its run names
//! it: this array task (`SLURM_ARRAY_JOB_ID`_`SLURM_ARRAY_TASK_ID`; or no job id yet: the
//! harness is between `sbatch`'s answer and the ledger) and this start of it
//! (`SLURM_RESTART_COUNT`, 0 for the first start; jobs are submitted with
//! `--no-requeue`, so only someone overriding that restarts one). A job whose record is gone
//! (its run was collected, or given up as failed and submitted again) or names another job,
//! and a job started a second time, writes nothing and exits with [`FENCED`]; the row file a
//! job writes names the job and the start ([`RowFile`]), and the harness appends only a row of
//! the job and start its record names.

use super::kind::JOBS_FILE;
use crate::campaign::store::record::Row;
use anyhow::{Context, Result};
use mpm_host::atomic::write_atomic;
use serde::{Deserialize, Serialize};
use std::path::Path;

/// The exit code of a job the fence stopped (its run belongs to another job or start).
pub const FENCED: i32 = 3;

/// A submitted run (an array task) whose row is not in `runs.csv` yet.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobRecord {
    /// Slurm's id of the run's job: `<array job id>_<task id>` (a plain job id in a ledger
    /// of an older harness, which submitted a job per run); empty from just before `sbatch`
    /// is asked until it answers.
    pub job_id: String,
    /// The key of the batch the run was submitted in (its array is named
    /// [`job_name`]`(campaign, batch)`); empty for a job of its own (an older harness).
    #[serde(default)]
    pub batch: String,
    /// The run's task in its batch's array.
    #[serde(default)]
    pub task: usize,
    /// The run's resume key.
    pub run_key: String,
    /// The run's id (its files are `json/<run id>.*`).
    pub run_id: String,
    /// Its position in the seeded order of the session that submitted it.
    pub order_index: usize,
    /// When it was submitted (RFC 3339 UTC).
    pub submitted: String,
    /// Who submitted it: `mpm-bench pid N on HOST`.
    pub by: String,
    /// The start of the job whose writes count (`SLURM_RESTART_COUNT`): 0, the first.
    #[serde(default)]
    pub restart_count: u32,
}

impl JobRecord {
    /// Whether this record admits the job start `fence`: the same job (or no job id yet) and
    /// the same start. `Err` says why not.
    pub fn admits(&self, fence: &Fence) -> Result<(), String> {
        if !self.job_id.is_empty() && self.job_id != fence.job_id {
            return Err(format!(
                "run {} belongs to Slurm job {}, not to job {}",
                self.run_id, self.job_id, fence.job_id
            ));
        }
        if self.restart_count != fence.restart_count {
            return Err(format!(
                "job {} was started again by Slurm (start {}, the run's is start {}): a restarted job never writes \
                 its run's files a second time; the harness records the run failed and submits it again",
                fence.job_id, fence.restart_count, self.restart_count
            ));
        }
        Ok(())
    }
}

/// `slurm-jobs.json`: the jobs submitted and not yet collected.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct JobsFile {
    /// In submission order.
    pub jobs: Vec<JobRecord>,
}

impl JobsFile {
    /// The file of campaign folder `dir` (empty when there is none).
    pub fn load(dir: &Path) -> Result<Self> {
        let p = dir.join(JOBS_FILE);
        if !p.is_file() {
            return Ok(Self::default());
        }
        read_json(&p)
    }

    /// Write it (atomically); an empty list removes the file.
    pub fn save(&self, dir: &Path) -> Result<()> {
        let p = dir.join(JOBS_FILE);
        if self.jobs.is_empty() {
            return match std::fs::remove_file(&p) {
                Err(e) if e.kind() != std::io::ErrorKind::NotFound => {
                    Err(e).with_context(|| format!("cannot remove {}", p.display()))
                }
                _ => Ok(()),
            };
        }
        write_json(&p, self)
    }

    /// Drop the records of job ids `ids` (and save).
    pub fn forget(&mut self, dir: &Path, ids: &[String]) -> Result<()> {
        self.jobs.retain(|j| !ids.contains(&j.job_id));
        self.save(dir)
    }

    /// Drop the records of the runs of batch `batch` (and save).
    pub fn forget_batch(&mut self, dir: &Path, batch: &str) -> Result<()> {
        self.jobs.retain(|j| j.batch != batch);
        self.save(dir)
    }

    /// Drop the record of run `run_id` (and save).
    pub fn forget_run(&mut self, dir: &Path, run_id: &str) -> Result<()> {
        self.jobs.retain(|j| j.run_id != run_id);
        self.save(dir)
    }

    /// The record of run `run_id`.
    pub fn of_run(&self, run_id: &str) -> Option<&JobRecord> {
        self.jobs.iter().find(|j| j.run_id == run_id)
    }
}

/// The name of the array of batch `batch` (or, from an older harness, of the job of run
/// `batch`) of campaign `campaign_id`: how an invocation finds an array that an earlier one
/// submitted and did not record (`squeue --name`).
pub fn job_name(campaign_id: &str, batch: &str) -> String {
    format!("mpm-{campaign_id}-{batch}")
}

/// The array job id of job id `job_id` (`123` of `123_4`; a plain job id is its own).
pub fn array_of(job_id: &str) -> &str {
    job_id.split('_').next().unwrap_or(job_id)
}

/// Which start of which Slurm job this process is.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Fence {
    /// `SLURM_ARRAY_JOB_ID`_`SLURM_ARRAY_TASK_ID` in an array task, else `SLURM_JOB_ID`.
    pub job_id: String,
    /// `SLURM_RESTART_COUNT` (0 when unset: the first start).
    pub restart_count: u32,
}

impl Fence {
    /// This process's, inside a Slurm job (`None` outside one).
    pub fn here() -> Option<Self> {
        Self::of(|name| std::env::var(name).ok())
    }

    /// The fence the Slurm variables `var` gives (`None` outside a job).
    pub fn of(var: impl Fn(&str) -> Option<String>) -> Option<Self> {
        let get = |name: &str| var(name).map(|v| v.trim().to_string()).filter(|v| !v.is_empty());
        let job_id = match (get("SLURM_ARRAY_JOB_ID"), get("SLURM_ARRAY_TASK_ID")) {
            (Some(array), Some(task)) => format!("{array}_{task}"),
            _ => get("SLURM_JOB_ID")?,
        };
        let restart_count = get("SLURM_RESTART_COUNT").and_then(|c| c.parse().ok()).unwrap_or(0);
        Some(Self { job_id, restart_count })
    }

    /// Whether the ledger of campaign folder `dir` lets this start write the files of run
    /// `run_id`; `Err` says why not.
    pub fn check(&self, dir: &Path, run_id: &str) -> Result<(), String> {
        let ledger = JobsFile::load(dir).map_err(|e| format!("{e:#}"))?;
        match ledger.of_run(run_id) {
            Some(record) => record.admits(self),
            None => Err(format!(
                "{} has no record of run {run_id}: its row was collected already, or the run was given up and \
                 submitted again as another job",
                dir.join(JOBS_FILE).display()
            )),
        }
    }
}

/// `json/<run id>.row.json`: the finished row and the job start that wrote it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RowFile {
    /// The job start that wrote it (empty outside Slurm).
    pub fence: Fence,
    /// The row.
    pub row: Row,
}

/// Write `value` as pretty JSON to `path`, atomically.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    write_atomic(path, serde_json::to_string_pretty(value)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))
}

/// Read the JSON file `path` as a `T`.
pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    serde_json::from_str(&text).with_context(|| format!("{} is not what mpm-bench wrote", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn record(job_id: &str) -> JobRecord {
        JobRecord {
            job_id: job_id.into(),
            batch: String::new(),
            task: 0,
            run_key: "k-r0".into(),
            run_id: "m1-a0".into(),
            order_index: 0,
            submitted: String::new(),
            by: String::new(),
            restart_count: 0,
        }
    }

    /// A record admits its own job's first start, and a job while its id is not recorded
    /// yet; never another job, nor a restarted start.
    #[test]
    fn the_fence_admits_only_the_recorded_start() {
        let first = Fence { job_id: "7".into(), restart_count: 0 };
        assert_eq!(record("7").admits(&first), Ok(()));
        assert_eq!(record("").admits(&first), Ok(()), "sbatch answered, the ledger not written yet");
        assert!(record("8").admits(&first).unwrap_err().contains("belongs to Slurm job 8"));
        let again = Fence { job_id: "7".into(), restart_count: 1 };
        assert!(record("7").admits(&again).unwrap_err().contains("started again"));
        let dir = tempfile::tempdir().unwrap();
        assert!(first.check(dir.path(), "m1-a0").unwrap_err().contains("has no record of run m1-a0"));
        JobsFile { jobs: vec![record("7")] }.save(dir.path()).unwrap();
        assert_eq!(first.check(dir.path(), "m1-a0"), Ok(()));
        // A ledger written before the restart count was recorded reads as first starts.
        let old =
            r#"{"jobs":[{"job_id":"7","run_key":"k-r0","run_id":"m1-a0","order_index":0,"submitted":"","by":""}]}"#;
        std::fs::write(dir.path().join(JOBS_FILE), old).unwrap();
        assert_eq!(first.check(dir.path(), "m1-a0"), Ok(()));
        assert_eq!(job_name("smoke", "m1-a0"), "mpm-smoke-m1-a0");
    }

    /// An array task's fence is `<array>_<task>` (its own `SLURM_JOB_ID` is another number);
    /// a plain job's is its job id; outside Slurm there is none.
    #[test]
    fn an_array_task_is_fenced_as_its_task() {
        fn env<'a>(vars: &'a [(&'static str, &'static str)]) -> impl Fn(&str) -> Option<String> + 'a {
            move |name: &str| vars.iter().find(|(k, _)| *k == name).map(|(_, v)| v.to_string())
        }
        let task = [
            ("SLURM_JOB_ID", "45"),
            ("SLURM_ARRAY_JOB_ID", "42"),
            ("SLURM_ARRAY_TASK_ID", "3"),
            ("SLURM_RESTART_COUNT", "1"),
        ];
        assert_eq!(Fence::of(env(&task)), Some(Fence { job_id: "42_3".into(), restart_count: 1 }));
        assert_eq!(Fence::of(env(&[("SLURM_JOB_ID", "7")])), Some(Fence { job_id: "7".into(), restart_count: 0 }));
        assert_eq!(Fence::of(env(&[])), None);
        assert!(record("42_3").admits(&Fence { job_id: "42_2".into(), restart_count: 0 }).is_err());
        assert_eq!((array_of("42_3"), array_of("7")), ("42", "7"));
    }
}
