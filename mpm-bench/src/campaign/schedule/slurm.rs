//! Runs as Slurm job arrays (`mpm-bench run --scheduler slurm`): one array task per run, one
//! array per resource shape ([`super::array`]), submitted with `sbatch`, watched with `squeue`
//! (every `--poll-interval`, 30 s by default), collected as they end ([`run_jobs`]).
//!
//! * A task is `mpm-bench job json/<run id>.job.json` ([`super::job`]) on a node of its own
//!   (`--exclusive --nodes=1`, `--ntasks=<ranks>`, with several ranks `--cpus-per-task=<threads>`:
//!   the launcher starts the ranks inside that allocation), its array named
//!   `mpm-<campaign>-<batch>` and never requeued by Slurm (`--no-requeue`); the site's own
//!   options follow ours (`--sbatch-arg`). It runs the run there as a local campaign would
//!   (the pinning policy placed on that node's topology, the observed CPUs verified) and
//!   writes the finished row to `json/<run id>.row.json`, which this side appends to
//!   `runs.csv` as soon as it appears: rows arrive in the order tasks end, each at once.
//! * The campaign folder is `<out>/slurm-<cluster>/<campaign>`: a cluster's runs may land on
//!   several node types, and each row names its node and that node's fingerprint.
//! * Each run is recorded in `slurm-jobs.json` in the campaign folder ([`JobsFile`],
//!   [`super::ledger`]) from just before `sbatch` is asked (its job id filled in when
//!   `sbatch` answers) until the row is appended. Running the same command again collects
//!   the jobs an earlier invocation submitted (whatever their state: pending, running or
//!   ended meanwhile) instead of submitting their runs again; records without a job id (an
//!   invocation killed before it wrote `sbatch`'s answer down) are filled by finding their
//!   array by its name (`squeue --name`, else `sacct`) and adopted. `--detach` submits and
//!   exits, leaving the jobs to a later invocation.
//! * Exactly once: a job writes its run's files only while the ledger names it and its first
//!   start ([`super::ledger::Fence`]); only the row of that job and start is appended, and
//!   only when `runs.csv` does not hold the run's row already (read from the file).
//! * A job that ends without a row (failed, out of time, cancelled by someone, its node
//!   lost, or purged from Slurm's memory) is a failed row whose reason holds Slurm's state,
//!   reason and exit code (`scontrol show job`, else `sacct`) and the end of the job's output
//!   (`json/<run id>.slurm.out`).
//! * A checkpointed run's task asks for SIGUSR1 before its time limit; a task whose solver
//!   stopped at a complete checkpoint on it leaves `json/<run id>.stopped.json` and no row:
//!   the run is still to do, and the next invocation continues it from its checkpoint.
//! * Ctrl-C (or SIGTERM / SIGHUP) cancels the arrays this invocation submitted, and only
//!   those (`scancel`): jobs of earlier invocations, and everybody else's, keep running.
//!
//! Slurm is driven through its commands (`sbatch`, `squeue`, `scontrol`, `scancel`,
//! `sacct`), found on `PATH` and configured as the user's shell would (`SLURM_CONF`).

pub use super::array::parse_sbatch;
use super::array::{self, expand_task_ids, Submission};
use super::job;
pub use super::kind::{SlurmOptions, JOBS_FILE};
use super::ledger::{array_of, job_name};
pub use super::ledger::{JobRecord, JobsFile};
use super::scheduler::Scheduler;
use super::state::{solver_for, Books, CampaignState, Plan};
use crate::campaign::exec::run::{planned_row, RunContext};
use crate::campaign::exec::watch::WatchSettings;
use crate::campaign::plan::matrix::{PlannedRun, RunKey};
use crate::campaign::plan::memory::estimate_run_memory;
use crate::campaign::store::csv::read_rows;
use crate::campaign::store::record::{Row, Status};
use crate::util::now_rfc3339;
use anyhow::{anyhow, bail, Context, Result};
use std::collections::{BTreeMap, BTreeSet, HashMap, HashSet};
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::Ordering;
use std::sync::Mutex;
use std::time::{Duration, Instant};

/// How long a job Slurm calls `COMPLETED` may take to show its row (a shared filesystem's
/// attribute cache) before it counts as having ended without one.
const ROW_GRACE: Duration = Duration::from_secs(30);

/// The cluster's name, from `scontrol show config`: also the check that Slurm answers.
pub fn cluster_name() -> Result<String> {
    let text = slurm_command("scontrol", &["show", "config"])?;
    parse_cluster_name(&text).ok_or_else(|| anyhow!("`scontrol show config` names no ClusterName"))
}

/// `ClusterName = x` of `scontrol show config`.
pub fn parse_cluster_name(text: &str) -> Option<String> {
    text.lines().find_map(|l| {
        let (k, v) = l.split_once('=')?;
        (k.trim() == "ClusterName").then(|| v.trim().to_string()).filter(|v| !v.is_empty())
    })
}

/// Run a Slurm command; its standard output, or an error that says what to do.
fn slurm_command(program: &str, args: &[&str]) -> Result<String> {
    let out = Command::new(program).args(args).output().with_context(|| {
        format!(
            "cannot run `{program}`: Slurm's commands must be on PATH here (run from a login node of the cluster, \
             or start a one-node Slurm with scripts/slurm-local.sh start)"
        )
    })?;
    if !out.status.success() {
        bail!(
            "`{program} {}` failed: {} (is slurmctld reachable from here? scripts/slurm-local.sh start starts one on \
             this machine)",
            args.join(" "),
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    Ok(String::from_utf8_lossy(&out.stdout).into_owned())
}

/// The jobs this process submitted and has not collected, with their campaign folder: what a
/// second Ctrl-C cancels on its way out ([`cancel_submitted`]).
static SUBMITTED: Mutex<Option<(PathBuf, Vec<String>)>> = Mutex::new(None);

fn submitted() -> std::sync::MutexGuard<'static, Option<(PathBuf, Vec<String>)>> {
    SUBMITTED.lock().unwrap_or_else(|e| e.into_inner())
}

/// Cancel the jobs this process submitted and has not collected, and forget them: the
/// harness is about to exit at once (a second Ctrl-C).
pub fn cancel_submitted() {
    let Some((dir, ids)) = submitted().take() else { return };
    if ids.is_empty() {
        return;
    }
    if let Err(e) = scancel(&arrays(&ids)) {
        eprintln!("warning: {e:#}");
    }
    if let Ok(mut f) = JobsFile::load(&dir) {
        let _ = f.forget(&dir, &ids);
    }
}

// ------------------------------------------------------------------------------------------
// Slurm's answers
// ------------------------------------------------------------------------------------------

/// Where a job is in its life.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Phase {
    /// Waiting in the queue (or held, or requeued).
    Pending,
    /// Allocated: starting, running, completing.
    Running,
    /// Ended, one way or another.
    Ended,
}

/// The phase of a Slurm job state (`squeue %T`).
pub fn phase(state: &str) -> Phase {
    match state {
        "PENDING" | "REQUEUED" | "REQUEUE_FED" | "REQUEUE_HOLD" | "RESV_DEL_HOLD" | "SUSPENDED" => Phase::Pending,
        "COMPLETED" | "FAILED" | "CANCELLED" | "TIMEOUT" | "NODE_FAIL" | "OUT_OF_MEMORY" | "PREEMPTED"
        | "BOOT_FAIL" | "DEADLINE" | "REVOKED" | "SPECIAL_EXIT" => Phase::Ended,
        _ => Phase::Running,
    }
}

/// One job as `squeue` lists it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct QueueEntry {
    /// `PENDING`, `RUNNING`, `COMPLETED`, `TIMEOUT`, ...
    pub state: String,
    /// Its node (empty while pending).
    pub node: String,
    /// Slurm's reason (`Priority`, `Resources`, `TimeLimit`, `None`, ...).
    pub reason: String,
}

/// The lines `id|state|nodes|reason` of `squeue -h -o %i|%T|%N|%r`, by job id (an array's
/// tasks not split off yet, `123_[0-5%2]`, each by its own id).
pub fn parse_squeue(text: &str) -> BTreeMap<String, QueueEntry> {
    text.lines()
        .filter_map(|l| {
            let mut f = l.trim().splitn(4, '|');
            let id = f.next()?.trim();
            let state = f.next()?.trim();
            (!id.is_empty() && !state.is_empty()).then(|| {
                let node = f.next().unwrap_or("").trim().to_string();
                let reason = f.next().unwrap_or("").trim().to_string();
                let entry = QueueEntry { state: state.to_string(), node, reason };
                expand_task_ids(id).into_iter().map(move |id| (id, entry.clone()))
            })
        })
        .flatten()
        .collect()
}

/// The arrays (or plain jobs) of job ids `ids`, each once.
fn arrays(ids: &[String]) -> Vec<String> {
    ids.iter().map(|id| array_of(id).to_string()).collect::<BTreeSet<_>>().into_iter().collect()
}

/// The jobs `ids` (array tasks `123_4`, or plain jobs) Slurm still knows (`squeue -r
/// --states=all` of their arrays); a job it has forgotten is absent. An error when `squeue`
/// did not answer.
fn squeue(ids: &[String]) -> Result<BTreeMap<String, QueueEntry>> {
    if ids.is_empty() {
        return Ok(BTreeMap::new());
    }
    let out = Command::new("squeue")
        .args(["-h", "-r", "--states=all", "-o", "%i|%T|%N|%r", "-j", &arrays(ids).join(",")])
        .output()
        .context("cannot run squeue")?;
    let err = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() {
        // Every id unknown (purged after MinJobAge): squeue says so and fails.
        if err.contains("Invalid job id") {
            return Ok(BTreeMap::new());
        }
        bail!("squeue failed: {}", err.trim());
    }
    Ok(parse_squeue(&String::from_utf8_lossy(&out.stdout)))
}

/// How a job ended, as `scontrol show job` or `sacct` tell it.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct JobEnd {
    /// `COMPLETED`, `FAILED`, `TIMEOUT`, `CANCELLED`, `NODE_FAIL`, ...
    pub state: String,
    /// Slurm's `exit:signal` (`0:15` for a job killed by SIGTERM).
    pub exit_code: String,
    /// Slurm's reason (`TimeLimit`, `NonZeroExitCode`, ...), empty when none.
    pub reason: String,
    /// The node it ran on, empty when it never ran.
    pub node: String,
}

impl JobEnd {
    /// The process's exit code (`None` when it was killed by a signal or is not known).
    pub fn exit_status(&self) -> Option<i32> {
        let (code, signal) = self.exit_code.split_once(':')?;
        (signal.trim() == "0").then(|| code.trim().parse().ok()).flatten()
    }
}

/// One job of `scontrol show job -o ID` (a line of `Key=Value` words).
pub fn parse_scontrol_job(text: &str) -> Option<JobEnd> {
    let line = text.lines().find(|l| l.contains("JobState="))?;
    let get = |key: &str| {
        line.split_whitespace().find_map(|w| w.strip_prefix(key)?.strip_prefix('=')).unwrap_or("").to_string()
    };
    let none = |v: String| if v == "(null)" || v == "None" { String::new() } else { v };
    Some(JobEnd {
        state: get("JobState"),
        exit_code: get("ExitCode"),
        reason: none(get("Reason")),
        node: none(get("NodeList")),
    })
}

/// The job's line of `sacct -n -P -X -o State,ExitCode,NodeList` (`CANCELLED by 0` reads
/// as `CANCELLED`).
pub fn parse_sacct(text: &str) -> Option<JobEnd> {
    let line = text.lines().find(|l| !l.trim().is_empty())?;
    let f: Vec<&str> = line.trim().split('|').collect();
    let state = f.first()?.split_whitespace().next()?.to_string();
    let node = f.get(2).map_or("", |n| n.trim()).to_string();
    Some(JobEnd {
        state,
        exit_code: f.get(1).map_or("", |c| c.trim()).to_string(),
        reason: String::new(),
        node: if node == "None assigned" { String::new() } else { node },
    })
}

/// How job `id` ended: `scontrol` while slurmctld remembers it, else `sacct` when the
/// cluster keeps accounting.
fn job_end(id: &str) -> Option<JobEnd> {
    let run = |program: &str, args: &[&str]| {
        Command::new(program)
            .args(args)
            .output()
            .ok()
            .filter(|o| o.status.success())
            .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
    };
    run("scontrol", &["show", "job", "-o", id])
        .and_then(|t| parse_scontrol_job(&t))
        .or_else(|| {
            run("sacct", &["-n", "-P", "-X", "-j", id, "-o", "State,ExitCode,NodeList"]).and_then(|t| parse_sacct(&t))
        })
        .or_else(|| {
            let (array, _) = id.split_once('_')?;
            let text = run("scontrol", &["show", "job", "-o", array])?;
            removed_from_array(&text, id).then(|| JobEnd {
                state: "CANCELLED".into(),
                reason: format!("removed from array {array} while pending"),
                ..JobEnd::default()
            })
        })
}

/// Whether array task `id` (`123_4`) is missing from `scontrol show job -o 123`, which lists
/// the array's other tasks (`ArrayTaskId=0,2-3%2`): a pending task cancelled (`scancel
/// 123_4`) leaves no record of its own, it is only taken out of the array's.
pub fn removed_from_array(text: &str, id: &str) -> bool {
    let Some((array, _)) = id.split_once('_') else { return false };
    let tasks: Vec<String> = text
        .split_whitespace()
        .filter_map(|w| w.strip_prefix("ArrayTaskId="))
        .flat_map(|t| expand_task_ids(&format!("{array}_[{t}]")))
        .collect();
    !tasks.is_empty() && !tasks.iter().any(|t| t == id)
}

/// `scancel` of `ids`.
fn scancel(ids: &[String]) -> Result<()> {
    let out = Command::new("scancel").args(ids).output().context("cannot run scancel")?;
    if !out.status.success() {
        bail!("scancel {} failed: {}", ids.join(" "), String::from_utf8_lossy(&out.stderr).trim());
    }
    Ok(())
}

// ------------------------------------------------------------------------------------------
// Submitting and collecting
// ------------------------------------------------------------------------------------------

/// The Slurm scheduler: one array task per run, at most `--max-jobs` tasks of an array
/// running at once ([`run_jobs`]).
pub struct Slurm<'o> {
    /// The options of `--scheduler slurm`.
    pub options: &'o SlurmOptions,
    /// The host watch each job keeps around its run.
    pub watch: Option<WatchSettings>,
}

impl Scheduler for Slurm<'_> {
    fn run_all(&mut self, s: &mut CampaignState<'_>) -> Result<()> {
        let sub = Submission { options: self.options, watch: self.watch, solvers: &s.solvers };
        run_jobs(&s.ctx, &sub, s.plan, &mut s.attempts, &mut s.books)
    }
}

/// A job in the queue, by this invocation or an earlier one.
struct InFlight<'p> {
    record: JobRecord,
    run: &'p PlannedRun,
    /// Submitted by this invocation: Ctrl-C cancels it.
    own: bool,
    /// When `squeue` first said it had ended.
    ended: Option<Instant>,
}

/// The failed row of a job that ended without writing one: Slurm's state, reason and exit
/// code (`end`, else `queue`), the node, and the end of the job's output.
fn failed_row(
    ctx: &RunContext,
    sub: &Submission,
    f: &InFlight,
    queue: Option<&QueueEntry>,
    end: Option<JobEnd>,
) -> Result<Row> {
    let solver = solver_for(sub.solvers, f.run)?;
    let mut row = planned_row(ctx.campaign, &ctx.git, solver, f.run);
    let id = &f.record.job_id;
    row.id.run_id = f.record.run_id.clone();
    row.id.order_index = f.record.order_index;
    row.id.job_id = id.clone();
    row.id.timestamp = now_rfc3339();
    row.outcome.mem_estimate_bytes = estimate_run_memory(&f.run.spec);
    row.outcome.status = Status::Failed;
    let (state, reason, node) = match (&end, queue) {
        (Some(e), _) => (e.state.clone(), e.reason.clone(), e.node.clone()),
        (None, Some(q)) => (q.state.clone(), q.reason.clone(), q.node.clone()),
        (None, None) => (String::new(), String::new(), String::new()),
    };
    match job::read_started(&ctx.json_dir, &f.record.run_id) {
        Some(s) => {
            row.id.node = s.node;
            row.id.machine_id = s.fingerprint;
        }
        None => row.id.node = node,
    }
    row.outcome.exit_code = end.as_ref().and_then(JobEnd::exit_status);
    let mut why = if state.is_empty() {
        format!("Slurm no longer knows job {id} (purged from slurmctld's memory, no accounting) and it left no row")
    } else {
        let code = end.as_ref().map(|e| e.exit_code.clone()).filter(|c| !c.is_empty());
        let details: Vec<String> =
            [(!reason.is_empty()).then(|| format!("reason {reason}")), code.map(|c| format!("exit code {c}"))]
                .into_iter()
                .flatten()
                .collect();
        let details = if details.is_empty() { String::new() } else { format!(" ({})", details.join(", ")) };
        format!("Slurm job {id} {state}{details}")
    };
    if !row.id.node.is_empty() {
        why.push_str(&format!(" on node {}", row.id.node));
    }
    let out_path = ctx.json_dir.join(format!("{}.slurm.out", f.record.run_id));
    match std::fs::read_to_string(&out_path) {
        Ok(output) => {
            let tail = crate::campaign::exec::process::tail(&output, 3);
            if !tail.is_empty() {
                why.push_str(": ");
                why.push_str(&tail);
            }
        }
        // The job ran but its output is not here: the nodes do not share this folder.
        Err(_) if !row.id.node.is_empty() => why.push_str(&format!(
            "; its output {} is not here: is the results folder on a filesystem every node shares?",
            out_path.display()
        )),
        Err(_) => {}
    }
    row.outcome.reason = why;
    Ok(row)
}

/// What the solver of `record`'s job said when it stopped at a complete checkpoint (its
/// note, written by the job start the record names), if it did: no row, the run is still to
/// do.
fn stopped(json_dir: &Path, record: &JobRecord) -> Option<String> {
    let s = job::read_stopped(json_dir, &record.run_id).ok().flatten()?;
    (record.admits(&s.fence).is_ok() && !record.job_id.is_empty()).then_some(s.reason)
}

/// The row of `f` if its job has ended: the one it wrote, or a failed one when it ended
/// without (`queue`: what `squeue` said, when it answered; `None` inside means Slurm no
/// longer knows the job).
fn ended_row(
    ctx: &RunContext,
    sub: &Submission,
    f: &mut InFlight,
    queue: Option<Option<&QueueEntry>>,
) -> Result<Option<Row>> {
    match job::read_row(&ctx.json_dir, &f.record.run_id) {
        // Only the row of the job and start the ledger names counts (another start's is
        // not this run's result).
        Ok(Some(written)) if f.record.admits(&written.fence).is_ok() && !f.record.job_id.is_empty() => {
            let mut row = written.row;
            row.id.job_id = f.record.job_id.clone();
            return Ok(Some(row));
        }
        Ok(_) => {}
        Err(e) => {
            let mut row = failed_row(ctx, sub, f, None, None)?;
            row.outcome.reason = format!("Slurm job {}: {e:#}", f.record.job_id);
            return Ok(Some(row));
        }
    }
    let Some(q) = queue else { return Ok(None) };
    if let Some(q) = q {
        if phase(&q.state) != Phase::Ended {
            return Ok(None);
        }
        // A job that completed writes its row before it ends: give a shared filesystem time to
        // show it.
        let first = *f.ended.get_or_insert_with(Instant::now);
        if q.state == "COMPLETED" && first.elapsed() < ROW_GRACE {
            return Ok(None);
        }
    }
    let end = job_end(&f.record.job_id);
    // Not in squeue's answer, yet Slurm has it waiting or running: not ended.
    if q.is_none() && end.as_ref().is_some_and(|e| phase(&e.state) != Phase::Ended) {
        return Ok(None);
    }
    failed_row(ctx, sub, f, q, end).map(Some)
}

/// Submit the runs of `plan` still to do as Slurm job arrays (those an earlier invocation
/// submitted are collected, not submitted again), at most `--max-jobs` tasks of an array
/// running at once, and append each finished task's row through `books` as it ends. Returns
/// when every task has been collected, on Ctrl-C (after cancelling this invocation's
/// arrays), or with `--detach` once everything is submitted.
fn run_jobs(
    ctx: &RunContext,
    sub: &Submission,
    plan: &Plan,
    attempts: &mut HashMap<RunKey, usize>,
    books: &mut Books,
) -> Result<()> {
    let dir = &plan.dir;
    let exe = std::env::current_exe().context("cannot find this program, which every job runs")?;
    let mut file = JobsFile::load(dir)?;
    // A job whose row is in runs.csv already was collected (the harness stopped before it
    // forgot the job).
    let recorded: HashSet<&str> = plan.existing.iter().map(|r| r.id.run_id.as_str()).collect();
    let before = file.jobs.len();
    file.jobs.retain(|j| !recorded.contains(j.run_id.as_str()));
    if file.jobs.len() != before {
        file.save(dir)?;
    }
    adopt_unrecorded(&ctx.campaign.id, &ctx.json_dir, &mut file, books, dir)?;
    let mut flight: Vec<InFlight> = Vec::new();
    let mut queue: Vec<(usize, &PlannedRun)> = Vec::new();
    for (order_index, run) in &plan.todo {
        let key = run.key();
        match file.jobs.iter().find(|j| RunKey(j.run_key.clone()).names(&key)) {
            Some(j) => flight.push(InFlight { record: j.clone(), run, own: false, ended: None }),
            None => queue.push((*order_index, run)),
        }
    }
    if !flight.is_empty() {
        let ids: Vec<String> = flight.iter().map(|f| f.record.job_id.clone()).collect();
        books.progress.say(&format!(
            "{} run(s) were submitted by an earlier invocation (jobs {}): collecting them, not submitting them again",
            flight.len(),
            ids.join(" ")
        ));
    }
    *submitted() = Some((dir.clone(), Vec::new()));
    let result = submit_all(ctx, sub, &exe, &mut file, &mut flight, &queue, attempts, dir)
        .and_then(|()| drive(ctx, sub, &mut file, &mut flight, books, dir));
    *submitted() = None;
    result
}

/// Submit the runs of `queue` as one array per batch ([`array::batches`]), into `flight`.
#[allow(clippy::too_many_arguments)]
fn submit_all<'p>(
    ctx: &RunContext,
    sub: &Submission,
    exe: &Path,
    file: &mut JobsFile,
    flight: &mut Vec<InFlight<'p>>,
    queue: &[(usize, &'p PlannedRun)],
    attempts: &mut HashMap<RunKey, usize>,
    dir: &Path,
) -> Result<()> {
    for (shape, batch) in array::batches(queue) {
        if ctx.interrupted.load(Ordering::SeqCst) {
            break;
        }
        let records = array::submit_batch(ctx, sub, exe, (shape, &batch), attempts, file).with_context(|| {
            format!(
                "{} job(s) already submitted are kept in {}: run the same command again to collect them",
                file.jobs.len(),
                dir.join(JOBS_FILE).display()
            )
        })?;
        if let Some((_, ids)) = submitted().as_mut() {
            ids.extend(records.iter().map(|r| r.job_id.clone()));
        }
        flight.extend(records.into_iter().zip(&batch).map(|(record, (_, run))| InFlight {
            record,
            run,
            own: true,
            ended: None,
        }));
    }
    Ok(())
}

/// Records without a job id: an invocation stopped between asking `sbatch` and writing its
/// answer down. Each batch's array (an older harness's job of one run) is looked for by its
/// name and working folder (`squeue`, then `sacct`) and adopted; the runs of a batch whose
/// array Slurm does not know were not submitted, and their records go (the runs are
/// submitted again). An error when Slurm cannot be asked: guessing could submit a run twice.
fn adopt_unrecorded(campaign_id: &str, json_dir: &Path, file: &mut JobsFile, books: &Books, dir: &Path) -> Result<()> {
    let mut lost = Vec::new();
    let mut found: HashMap<String, Option<String>> = HashMap::new();
    for record in file.jobs.iter_mut().filter(|j| j.job_id.is_empty()) {
        let own = if record.batch.is_empty() { &record.run_id } else { &record.batch };
        let name = job_name(campaign_id, own);
        let array = match found.get(&name) {
            Some(a) => a.clone(),
            None => {
                let a = find_job(&name, json_dir, &record.submitted)?;
                match &a {
                    Some(id) => books.progress.say(&format!(
                        "adopting Slurm job {id} ({name}): submitted by an invocation that stopped before recording it"
                    )),
                    None => {
                        books.progress.say(&format!("no Slurm job {name} was submitted: its runs are submitted now"))
                    }
                }
                found.insert(name.clone(), a.clone());
                a
            }
        };
        match array {
            Some(id) if record.batch.is_empty() => record.job_id = id,
            Some(id) => record.job_id = format!("{id}_{}", record.task),
            None => lost.push(record.run_id.clone()),
        }
    }
    file.jobs.retain(|j| !lost.contains(&j.run_id));
    file.save(dir)
}

/// The (array) job id of the job named `name` whose working folder is `workdir`: from
/// `squeue` while slurmctld remembers it, else from `sacct` (jobs since a day before
/// `submitted`) when the cluster keeps accounting.
fn find_job(name: &str, workdir: &Path, submitted: &str) -> Result<Option<String>> {
    let text = slurm_command("squeue", &["-h", "--states=all", "--name", name, "-o", "%F|%Z"])?;
    if let Some(id) = job_in(&text, workdir) {
        return Ok(Some(id));
    }
    let since = humantime::parse_rfc3339_weak(submitted).unwrap_or_else(|_| std::time::SystemTime::now())
        - Duration::from_secs(86_400);
    let since = humantime::format_rfc3339_seconds(since).to_string();
    let since = since.trim_end_matches('Z');
    let sacct = ["-n", "-P", "-X", "-S", since, "--name", name, "-o", "JobID,WorkDir"];
    // Without accounting sacct fails: then slurmctld's memory was all there is.
    Ok(slurm_command("sacct", &sacct).ok().and_then(|t| job_in(&t, workdir)))
}

/// The first (array) job id of lines `id|working folder` whose folder is `workdir` (`123`
/// of an array task's `123_4` or `123_[0-5]`).
pub fn job_in(text: &str, workdir: &Path) -> Option<String> {
    text.lines().find_map(|l| {
        let (id, wd) = l.trim().split_once('|')?;
        let id = array_of(id.trim());
        (Path::new(wd.trim()) == workdir && !id.is_empty()).then(|| id.to_string())
    })
}

/// The loop of [`run_jobs`]: ask Slurm how the jobs are, append the rows of those that
/// ended, until none is left (or Ctrl-C, or `--detach`).
fn drive(
    ctx: &RunContext,
    sub: &Submission,
    file: &mut JobsFile,
    flight: &mut Vec<InFlight>,
    books: &mut Books,
    dir: &Path,
) -> Result<()> {
    let mut done = 0;
    let mut last = String::from("waiting for the first job to end");
    let mut poll = Poll::default();
    loop {
        if ctx.interrupted.load(Ordering::SeqCst) {
            return cancel_own(flight, file, books, dir);
        }
        poll.ask(flight, sub.options.poll(), books);
        collect_ended(ctx, sub, flight, &poll, file, books, dir, (&mut done, &mut last))?;
        let phases: Vec<Phase> = flight.iter().map(|f| poll.phase(&f.record.job_id)).collect();
        let running = phases.iter().filter(|p| **p != Phase::Pending).count();
        books.progress.queue(phases.len() - running, running, done, &last);
        if flight.is_empty() {
            return Ok(());
        }
        if sub.options.detach {
            books.counts.queued = flight.len();
            return Ok(());
        }
        std::thread::sleep(Duration::from_millis(250));
    }
}

/// Ctrl-C: cancel this invocation's arrays (and forget their runs), keep the others for a
/// later invocation.
fn cancel_own(flight: &[InFlight], file: &mut JobsFile, books: &mut Books, dir: &Path) -> Result<()> {
    let own: Vec<String> = flight.iter().filter(|f| f.own).map(|f| f.record.job_id.clone()).collect();
    if !own.is_empty() {
        let arrays = arrays(&own);
        books.progress.say(&format!("interrupt: cancelling this invocation's jobs {}", arrays.join(" ")));
        scancel(&arrays)?;
        file.forget(dir, &own)?;
    }
    books.counts.interrupted = true;
    books.counts.queued = flight.len() - own.len();
    Ok(())
}

/// What `squeue` last said about the jobs in flight (`None` after an error), and when.
#[derive(Default)]
struct Poll {
    states: Option<BTreeMap<String, QueueEntry>>,
    at: Option<Instant>,
    error: Option<String>,
}

impl Poll {
    /// Ask when there is no answer yet or the last is older than `every`; an error is said
    /// once and asked again.
    fn ask(&mut self, flight: &[InFlight], every: Duration, books: &Books) {
        if self.at.is_some_and(|t| t.elapsed() < every) {
            return;
        }
        let ids: Vec<String> = flight.iter().map(|f| f.record.job_id.clone()).collect();
        match squeue(&ids) {
            Ok(s) => {
                self.states = Some(s);
                self.error = None;
            }
            Err(e) => {
                if self.error.is_none() {
                    books.progress.say(&format!("warning: {e:#}; asking again"));
                }
                self.error = Some(format!("{e:#}"));
                self.states = None;
            }
        }
        self.at = Some(Instant::now());
    }

    /// What the last answer said about job `id`: `None` without an answer, `Some(None)` when
    /// the answer did not name it.
    fn entry(&self, id: &str) -> Option<Option<&QueueEntry>> {
        self.states.as_ref().map(|s| s.get(id))
    }

    /// The phase of job `id` by the last answer (pending when unknown).
    fn phase(&self, id: &str) -> Phase {
        self.entry(id).flatten().map_or(Phase::Pending, |q| phase(&q.state))
    }
}

/// Append the rows of the jobs in `flight` that ended (and forget them), counting them in
/// `progress.0` and naming the last in `progress.1`; forget those whose solver stopped at a
/// complete checkpoint, saying so (their runs stay to do).
#[allow(clippy::too_many_arguments)]
fn collect_ended(
    ctx: &RunContext,
    sub: &Submission,
    flight: &mut Vec<InFlight>,
    poll: &Poll,
    file: &mut JobsFile,
    books: &mut Books,
    dir: &Path,
    progress: (&mut usize, &mut String),
) -> Result<()> {
    let (done, last) = progress;
    let mut i = 0;
    while i < flight.len() {
        if let Some(why) = stopped(&ctx.json_dir, &flight[i].record) {
            let f = flight.remove(i);
            books.progress.say(&format!(
                "job {} of {}: stopped at a complete checkpoint ({why}); the next invocation continues it from there",
                f.record.job_id,
                f.run.describe()
            ));
            forget_collected(file, dir, &f.record.job_id)?;
            continue;
        }
        let answer = poll.entry(&flight[i].record.job_id);
        match ended_row(ctx, sub, &mut flight[i], answer)? {
            Some(row) => {
                let f = flight.remove(i);
                if let Some(why) = in_csv(dir, &f.record)? {
                    books.progress.say(&format!(
                        "job {} of {}: not appended, {why}",
                        f.record.job_id,
                        f.run.describe()
                    ));
                } else {
                    books.record(*done, f.run, &row)?;
                    *done += 1;
                    *last = format!("{}: {}", f.run.describe(), row.outcome.status.as_str());
                }
                forget_collected(file, dir, &f.record.job_id)?;
            }
            None => i += 1,
        }
    }
    Ok(())
}

/// Forget job `id`, collected: in the ledger and among the jobs a second Ctrl-C cancels.
fn forget_collected(file: &mut JobsFile, dir: &Path, id: &str) -> Result<()> {
    file.forget(dir, &[id.to_string()])?;
    if let Some((_, ids)) = submitted().as_mut() {
        ids.retain(|i| i != id);
    }
    Ok(())
}

/// Why `runs.csv` of campaign folder `dir` holds `record`'s run already (`None`: it does
/// not): a row of its run id, or a done row (`ok`, or skipped by the memory guard) of its run
/// key. The file is read, not this session's memory: a row is appended once per run.
fn in_csv(dir: &Path, record: &JobRecord) -> Result<Option<String>> {
    let csv = dir.join("runs.csv");
    if !csv.is_file() {
        return Ok(None);
    }
    let key = RunKey(record.run_key.clone());
    Ok(read_rows(&csv)?.iter().find_map(|r| {
        let done = matches!(r.outcome.status, Status::Ok | Status::Skipped);
        if r.id.run_id == record.run_id {
            Some(format!("runs.csv has the row of run {} already", r.id.run_id))
        } else if done && r.key().names(&key) {
            Some(format!(
                "runs.csv has a {} row of its run key already (run {})",
                r.outcome.status.as_str(),
                r.id.run_id
            ))
        } else {
            None
        }
    }))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Slurm 22.05's answers, as this project's one-node Slurm gave them.
    #[test]
    fn slurm_answers_parse() {
        let q = parse_squeue("4|CANCELLED||Priority\n1|COMPLETED|vm|None\n3|PENDING||Resources\n2|RUNNING|vm|None\n");
        assert_eq!(q.len(), 4);
        assert_eq!(q["2"], QueueEntry { state: "RUNNING".into(), node: "vm".into(), reason: "None".into() });
        assert_eq!(q["3"].node, "");
        let phases: Vec<Phase> = ["1", "2", "3", "4"].iter().map(|id| phase(&q[*id].state)).collect();
        assert_eq!(phases, [Phase::Ended, Phase::Running, Phase::Pending, Phase::Ended]);
        assert_eq!(phase("COMPLETING"), Phase::Running);
        let line = "JobId=2 JobName=wrap UserId=root(0) JobState=TIMEOUT Reason=TimeLimit Dependency=(null) \
                    Requeue=1 Restarts=0 BatchFlag=1 Reboot=0 ExitCode=0:15 RunTime=00:01:21 TimeLimit=00:01:00 \
                    ReqNodeList=(null) ExcNodeList=(null) NodeList=vm BatchHost=vm NumNodes=1";
        let end = parse_scontrol_job(line).unwrap();
        assert_eq!(
            end,
            JobEnd { state: "TIMEOUT".into(), exit_code: "0:15".into(), reason: "TimeLimit".into(), node: "vm".into() }
        );
        assert_eq!(end.exit_status(), None, "killed by a signal");
        let failed =
            parse_scontrol_job("JobId=3 JobState=FAILED Reason=NonZeroExitCode ExitCode=3:0 NodeList=vm").unwrap();
        assert_eq!(failed.exit_status(), Some(3));
        let pending =
            parse_scontrol_job("JobId=4 JobState=CANCELLED Reason=None ExitCode=0:0 NodeList=(null)").unwrap();
        assert_eq!((pending.reason.as_str(), pending.node.as_str()), ("", ""));
        assert_eq!(parse_scontrol_job("slurm_load_jobs error: Invalid job id specified"), None);
        let s = parse_sacct("CANCELLED by 0|0:0|None assigned\n").unwrap();
        assert_eq!((s.state.as_str(), s.exit_status(), s.node.as_str()), ("CANCELLED", Some(0), ""));
        assert_eq!(parse_sbatch("17\n"), Some("17".into()));
        assert_eq!(parse_sbatch("17;mpmlocal\n"), Some("17".into()));
        assert_eq!(parse_sbatch("sbatch: error: Batch job submission failed"), None);
        assert_eq!(
            parse_cluster_name("Configuration data as of x\nClusterName             = mpmlocal\n"),
            Some("mpmlocal".into())
        );
    }

    /// Every job gets a node of its own, the tasks its ranks need (CPUs per task its threads
    /// when several ranks), and is never requeued by Slurm; the time limit is the given one,
    /// else the per-run timeout plus two minutes, in whole minutes; a checkpointed run asks
    /// for SIGUSR1 before it; the site's options come last.
    #[test]
    fn sbatch_options() {
        use super::super::kind::{check_sbatch_arg, Shape};
        let mut o = SlurmOptions { cluster: "c".into(), ..SlurmOptions::default() };
        let one = Shape::of(1, 4);
        let base = ["--parsable", "--nodes=1", "--ntasks=1", "--exclusive", "--no-requeue"];
        assert_eq!(o.sbatch_args(None, one, false), base);
        assert_eq!(
            o.sbatch_args(None, Shape::of(2, 3), false),
            ["--parsable", "--nodes=1", "--ntasks=2", "--cpus-per-task=3", "--exclusive", "--no-requeue"]
        );
        assert_eq!(o.sbatch_args(Some(Duration::from_secs(300)), one, false)[5], "--time=7");
        assert_eq!(o.sbatch_args(Some(Duration::from_secs(301)), one, false)[5], "--time=8");
        o.partition = Some("big".into());
        o.account = Some("proj".into());
        o.time_limit = Some("1:00:00".into());
        o.sbatch_extra = vec!["--constraint=skylake".into(), "--qos=long".into()];
        assert_eq!(
            o.sbatch_args(Some(Duration::from_secs(300)), one, true)[5..],
            [
                "--partition=big",
                "--account=proj",
                "--time=1:00:00",
                "--signal=B:USR1@120",
                "--constraint=skylake",
                "--qos=long"
            ]
        );
        assert_eq!(o.folder(), "slurm-c");
        assert_eq!(o.poll(), Duration::from_secs(30));
        for ok in ["--constraint=skylake", "--qos=normal", "--mem=8G", "-C", "--ntasks-per-node=1", "--no-requeue"] {
            assert_eq!(check_sbatch_arg(ok), Ok(()), "{ok}");
        }
        for (bad, named) in [
            ("--array=0-3", "--array"),
            ("-a0-3", "--array"),
            ("--arr=1", "--array"),
            ("--parsable", "--parsable"),
            ("--requeue", "--requeue"),
            ("-J", "--job-name"),
            ("--ntasks=4", "--ntasks"),
        ] {
            let e = check_sbatch_arg(bad).unwrap_err();
            assert!(e.contains(&format!("{named} is set by the harness")), "{bad}: {e}");
        }
        assert!(check_sbatch_arg("qos=x").unwrap_err().contains("not an sbatch option"));
    }

    /// `squeue -r` of an array: each task by its id, pending ones not split off yet too.
    #[test]
    fn array_tasks_in_squeue() {
        let q = parse_squeue("12_[2-3%2]|PENDING||JobArrayTaskLimit\n12_0|RUNNING|vm|None\n12_1|COMPLETED|vm|None\n");
        assert_eq!(q.keys().collect::<Vec<_>>(), ["12_0", "12_1", "12_2", "12_3"]);
        assert_eq!(q["12_3"].reason, "JobArrayTaskLimit");
        assert_eq!(arrays(&["12_0".into(), "12_3".into(), "9".into()]), ["12", "9"]);
        assert_eq!(job_in("12_[0-1]|/c/json\n", Path::new("/c/json")), Some("12".into()));
        let array = "JobId=12 ArrayJobId=12 ArrayTaskId=0,2-3%2 JobState=PENDING\nJobId=14 ArrayJobId=12 \
                     ArrayTaskId=4 JobState=COMPLETED\n";
        assert!(removed_from_array(array, "12_1"), "a pending task cancelled");
        assert!(!removed_from_array(array, "12_3") && !removed_from_array(array, "12_4"));
        assert!(!removed_from_array("", "12_1"), "the array unknown: nothing to say");
    }
}
