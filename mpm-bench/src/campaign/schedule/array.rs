//! A campaign's runs as Slurm job arrays ([`submit_batch`]): the runs to submit, grouped by
//! the resources their jobs need ([`Shape`]: ranks as tasks, threads per rank as CPUs per
//! task), go in as one array per shape ([`batches`]), `sbatch --array=0-(n-1)%N` (`%N` from
//! `--max-jobs`).
//!
//! * Each task reads its run from the batch's list file (`json/<batch>.list`, one run id a
//!   line, written before `sbatch`), line `SLURM_ARRAY_TASK_ID + 1`, and runs
//!   `mpm-bench job json/<run id>.job.json`, its output in `json/<run id>.slurm.out`.
//! * The array is named [`job_name`]`(campaign, batch)`, the batch's key a hash of its run
//!   ids ([`batch_key`]), and its working folder is the campaign's `json/`: how a later
//!   invocation finds an array whose `sbatch` answer was lost.
//! * Slurm names a task `<array job id>_<task id>`; `squeue` shows tasks not split off yet
//!   as `<array>_[<ranges>%<throttle>]` ([`expand_task_ids`]).

use super::job::{self, JobFile};
use super::kind::{Shape, SlurmOptions};
use super::ledger::{job_name, JobRecord, JobsFile};
use super::state::{next_run_id, solver_for};
use crate::campaign::exec::run::RunContext;
use crate::campaign::exec::solver::Solver;
use crate::campaign::exec::watch::WatchSettings;
use crate::campaign::plan::matrix::{PlannedRun, RunKey};
use crate::campaign::plan::preset::OptLevel;
use crate::util::now_rfc3339;
use anyhow::{anyhow, Context, Result};
use sha2::Digest;
use std::collections::HashMap;
use std::path::Path;
use std::process::Command;

/// What every job of one invocation is submitted with.
pub struct Submission<'a> {
    /// The options of `--scheduler slurm`.
    pub options: &'a SlurmOptions,
    /// The host watch each job keeps around its run.
    pub watch: Option<WatchSettings>,
    /// The solver binary of each optimisation level.
    pub solvers: &'a HashMap<OptLevel, &'a Solver>,
}

/// The job id of `sbatch --parsable`'s answer (`123`, or `123;cluster`).
pub fn parse_sbatch(text: &str) -> Option<String> {
    let id = text.lines().find(|l| !l.trim().is_empty())?.trim().split(';').next()?.trim();
    (!id.is_empty() && id.chars().all(|c| c.is_ascii_digit())).then(|| id.to_string())
}

/// The most tasks of one array (Slurm's default `MaxArraySize` is 1001: tasks 0 to 1000).
pub const MAX_TASKS: usize = 1000;

/// The runs of `queue` (with their places in the seeded order) as batches: one per shape,
/// in the order the shapes first appear, each in queue order and at most [`MAX_TASKS`] runs.
pub fn batches<'p>(queue: &[(usize, &'p PlannedRun)]) -> Vec<(Shape, Vec<(usize, &'p PlannedRun)>)> {
    let mut by_shape: Vec<(Shape, Vec<(usize, &'p PlannedRun)>)> = Vec::new();
    for &(i, run) in queue {
        let shape = Shape::of(run.spec.ranks, run.spec.threads);
        match by_shape.iter_mut().find(|(s, b)| *s == shape && b.len() < MAX_TASKS) {
            Some((_, b)) => b.push((i, run)),
            None => by_shape.push((shape, vec![(i, run)])),
        }
    }
    by_shape
}

/// The key of a batch of runs `run_ids`: `a` and 12 hex digits of their hash (run ids are
/// never used twice in a campaign, so neither is a key).
pub fn batch_key(run_ids: &[String]) -> String {
    let h = sha2::Sha256::digest(run_ids.join(",").as_bytes());
    format!("a{}", h.iter().take(6).map(|b| format!("{b:02x}")).collect::<String>())
}

/// The job ids `squeue -r` (or without `-r`) writes for `id`: itself, or for tasks not split
/// off yet (`123_[0-5%2]`, `123_[1,3-4]`) each task (`123_0`, ...).
pub fn expand_task_ids(id: &str) -> Vec<String> {
    let Some((array, rest)) = id.split_once("_[") else { return vec![id.to_string()] };
    let ranges = rest.trim_end_matches(']');
    let ranges = ranges.split('%').next().unwrap_or(ranges);
    let mut out = Vec::new();
    for part in ranges.split(',').filter(|p| !p.is_empty()) {
        let (from, to) = part.split_once('-').unwrap_or((part, part));
        let (Ok(from), Ok(to)) = (from.trim().parse::<usize>(), to.trim().parse::<usize>()) else {
            return vec![id.to_string()];
        };
        out.extend((from..=to).map(|t| format!("{array}_{t}")));
    }
    out
}

/// `text` as one shell word.
pub fn shell_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', r"'\''"))
}

/// The batch script of an array whose tasks run the runs listed in `list`, each with the
/// `mpm-bench` at `exe`; `about` and `sbatch` (the command it was submitted with) for the
/// reader.
fn script_text(about: &str, sbatch: &str, exe: &Path, json_dir: &Path, list: &Path) -> String {
    let dir = shell_quote(&json_dir.display().to_string());
    format!(
        "#!/bin/sh\n# {about}, submitted by mpm-bench as\n#   {sbatch}\n\
         # Task N runs the run on line N+1 of the list.\n\
         run=$(sed -n \"$((SLURM_ARRAY_TASK_ID + 1))p\" {list})\n\
         [ -n \"$run\" ] || {{ echo \"no run for task $SLURM_ARRAY_TASK_ID in {list}\" >&2; exit 2; }}\n\
         exec {exe} job {dir}/\"$run\".job.json >> {dir}/\"$run\".slurm.out 2>&1\n",
        list = shell_quote(&list.display().to_string()),
        exe = shell_quote(&exe.display().to_string()),
    )
}

/// Submit `batch` (runs of one `shape`, with their places in the seeded order) as one array,
/// each run under a run id no earlier job used: recorded in the ledger `file` before
/// `sbatch` is asked, their job ids (`<array>_<task>`) filled in when it answers (a refused
/// array is forgotten again). The records, in task order.
pub fn submit_batch(
    ctx: &RunContext,
    sub: &Submission,
    exe: &Path,
    (shape, batch): (Shape, &[(usize, &PlannedRun)]),
    attempts: &mut HashMap<RunKey, usize>,
    file: &mut JobsFile,
) -> Result<Vec<JobRecord>> {
    let dir = ctx.json_dir.parent().unwrap_or(Path::new("."));
    let mut ids = Vec::new();
    for (_, run) in batch {
        let mut run_id = next_run_id(attempts, run);
        // A job file there: an earlier job had this id (its run forgotten, cancelled, purged).
        while job::job_path(&ctx.json_dir, &run_id).exists() {
            run_id = next_run_id(attempts, run);
        }
        ids.push(run_id);
    }
    let key = batch_key(&ids);
    let by = format!("mpm-bench pid {} on {}", std::process::id(), crate::util::hostname());
    let mut records: Vec<JobRecord> = batch
        .iter()
        .zip(&ids)
        .enumerate()
        .map(|(task, ((order_index, run), run_id))| JobRecord {
            job_id: String::new(),
            batch: key.clone(),
            task,
            run_key: run.key().0,
            run_id: run_id.clone(),
            order_index: *order_index,
            submitted: now_rfc3339(),
            by: by.clone(),
            restart_count: 0,
        })
        .collect();
    file.jobs.extend(records.iter().cloned());
    file.save(dir)?;
    let array = match sbatch(ctx, sub, exe, shape, &records, batch) {
        Ok(id) => id,
        Err(e) => {
            file.forget_batch(dir, &key)?;
            return Err(e);
        }
    };
    for r in records.iter_mut() {
        r.job_id = format!("{array}_{}", r.task);
    }
    for j in file.jobs.iter_mut().filter(|j| j.batch == key) {
        j.job_id = format!("{array}_{}", j.task);
    }
    file.save(dir)?;
    Ok(records)
}

/// Write the job files, list and script of the batch `records` (its runs `batch`) and submit
/// it: the array's job id.
fn sbatch(
    ctx: &RunContext,
    sub: &Submission,
    exe: &Path,
    shape: Shape,
    records: &[JobRecord],
    batch: &[(usize, &PlannedRun)],
) -> Result<String> {
    let dir = &ctx.json_dir;
    for (record, (_, run)) in records.iter().zip(batch) {
        let job = JobFile {
            campaign: ctx.campaign.clone(),
            timeout: ctx.campaign.timeout,
            git: ctx.git.clone(),
            solver: solver_for(sub.solvers, run)?.clone(),
            run: (*run).clone(),
            order_index: record.order_index,
            run_id: record.run_id.clone(),
            watch: sub.watch,
        };
        job::write_json(&job::job_path(dir, &record.run_id), &job)?;
    }
    let key = &records[0].batch;
    let list = dir.join(format!("{key}.list"));
    let lines: String = records.iter().map(|r| format!("{}\n", r.run_id)).collect();
    mpm_host::atomic::write_atomic(&list, lines.as_bytes())?;
    let checkpointed = ctx.campaign.checkpoint_every.is_some();
    let mut args = sub.options.sbatch_args(ctx.campaign.timeout, shape, checkpointed);
    let throttle = sub.options.max_jobs.map(|n| format!("%{n}")).unwrap_or_default();
    args.push(format!("--array=0-{}{throttle}", records.len() - 1));
    args.push(format!("--job-name={}", job_name(&ctx.campaign.id, key)));
    args.push(format!("--output={}", dir.join(format!("{key}_%a.slurm.out")).display()));
    args.push(format!("--chdir={}", dir.display()));
    let script = dir.join(format!("{key}.slurm.sh"));
    let about = format!("{} run(s) of campaign {}, {} rank(s) each", records.len(), ctx.campaign.id, shape.ranks);
    let command = format!("sbatch {} {}", args.join(" "), script.display());
    mpm_host::atomic::write_atomic(&script, script_text(&about, &command, exe, dir, &list).as_bytes())?;
    let out = Command::new("sbatch")
        .args(&args)
        .arg(&script)
        .output()
        .context("cannot run sbatch (Slurm's commands must be on PATH here)")?;
    let answer = String::from_utf8_lossy(&out.stdout);
    parse_sbatch(&answer).filter(|_| out.status.success()).ok_or_else(|| {
        anyhow!(
            "sbatch refused the array of {} run(s) ({}): {}{}",
            records.len(),
            batch.first().map(|(_, r)| r.describe()).unwrap_or_default(),
            String::from_utf8_lossy(&out.stderr).trim(),
            answer.trim()
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::plan::preset::OptLevel;
    use mpm_core::Strategy;

    /// Pending tasks not split off yet are each a task; a task and a plain job are
    /// themselves.
    #[test]
    fn squeue_task_ranges_expand() {
        assert_eq!(expand_task_ids("12_[0-2%2]"), ["12_0", "12_1", "12_2"]);
        assert_eq!(expand_task_ids("12_[1,3-4]"), ["12_1", "12_3", "12_4"]);
        assert_eq!(expand_task_ids("12_5"), ["12_5"]);
        assert_eq!(expand_task_ids("12"), ["12"]);
        assert_eq!(expand_task_ids("12_[x]"), ["12_[x]"]);
        assert_eq!(shell_quote("/a b/it's"), r"'/a b/it'\''s'");
    }

    /// One batch per shape (ranks, and threads when several ranks), in queue order; a batch
    /// key names its runs.
    #[test]
    fn runs_are_batched_by_shape() {
        let run = |ranks: usize, threads: usize| {
            let mut r = PlannedRun::taylor(1, Strategy::DomainDecomposition, OptLevel::O3, threads, 10);
            r.spec.ranks = ranks;
            r
        };
        let runs = [run(1, 1), run(2, 1), run(1, 2), run(2, 1), run(2, 2)];
        let queue: Vec<(usize, &PlannedRun)> = runs.iter().enumerate().collect();
        let b = batches(&queue);
        let shapes: Vec<(Shape, Vec<usize>)> =
            b.iter().map(|(s, v)| (*s, v.iter().map(|(i, _)| *i).collect())).collect();
        assert_eq!(
            shapes,
            [
                (Shape { ranks: 1, threads: 0 }, vec![0, 2]),
                (Shape { ranks: 2, threads: 1 }, vec![1, 3]),
                (Shape { ranks: 2, threads: 2 }, vec![4]),
            ]
        );
        let k = batch_key(&["m1-a0".into(), "m1-b0".into()]);
        assert_eq!(k.len(), 13);
        assert_ne!(k, batch_key(&["m1-a0".into()]));
    }
}
