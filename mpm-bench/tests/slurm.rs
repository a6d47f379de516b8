//! `mpm-bench run --scheduler slurm` against a real Slurm: a one-node cluster (munged,
//! slurmctld, slurmd) that this test starts with `scripts/slurm-local.sh` in a state folder,
//! slurm.conf and ports of its own, and stops at its end, leaving no daemon behind.
//!
//! It needs root and the packages slurm-wlm and munge (`scripts/bootstrap.sh` installs them,
//! and `scripts/test.sh` runs it first): without them it fails, it does not skip.
//!
//! One test, its cases in order on one cluster (each case's seconds printed): the smoke
//! preset through Slurm (one job array) writes the configurations a local smoke campaign
//! writes; the hybrid preset's runs of 1 and 2 ranks run in allocations of that many tasks
//! and give the rows a local hybrid campaign gives; jobs still pending are collected by a
//! second invocation, never submitted twice, and a job someone else cancelled becomes a
//! failed row with Slurm's state; an array submitted by a harness killed before it recorded
//! it is adopted, never submitted twice; a requeued job gives one row; a checkpointed run
//! signalled before its time limit continues from its last checkpoint on the next
//! invocation; Ctrl-C cancels the arrays of the invocation that got it, and no other.

use mpm_bench::campaign::store::record::{Row, Status};

use mpm_bench::campaign::schedule::slurm::{JobRecord, JobsFile};
use mpm_bench::campaign::store::csv::read_rows;
use mpm_bench::machine::fingerprint;
use mpm_bench::machine::topology::Machine;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

fn script() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../scripts/slurm-local.sh")
}

fn text(o: &Output) -> String {
    format!("{}{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
}

/// Two consecutive free TCP ports (slurmctld's and slurmd's).
fn free_port_pair() -> u16 {
    let free = |p: u16| std::net::TcpListener::bind(("0.0.0.0", p)).is_ok();
    let start = 20_000 + (std::process::id() % 20_000) as u16;
    (start..60_000).step_by(2).find(|&p| free(p) && free(p + 1)).expect("two free ports")
}

/// Whether process `pid` lives (not a zombie).
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .is_ok_and(|s| s.rsplit_once(')').is_some_and(|(_, rest)| !rest.trim_start().starts_with('Z')))
}

/// Processes whose command name is `comm`.
fn processes(comm: &str) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| e.file_name().to_str()?.parse::<u32>().ok())
        .filter(|pid| std::fs::read_to_string(format!("/proc/{pid}/comm")).is_ok_and(|c| c.trim() == comm))
        .collect()
}

/// A one-node Slurm of this test's own, stopped when dropped (also when the test fails).
struct LocalSlurm {
    dir: PathBuf,
    conf: PathBuf,
    port: u16,
    stopped: bool,
}

impl LocalSlurm {
    fn start() -> Self {
        let base = std::env::temp_dir().join(format!("mpm-slurm-test-{}", std::process::id()));
        let s = Self { conf: base.with_extension("conf"), dir: base, port: free_port_pair(), stopped: false };
        let out = s.script("start");
        assert!(
            out.status.success(),
            "scripts/slurm-local.sh start failed (it needs root and the packages slurm-wlm and munge, which \
             scripts/bootstrap.sh installs): {}",
            text(&out)
        );
        s
    }

    fn script(&self, what: &str) -> Output {
        Command::new("bash")
            .arg(script())
            .arg(what)
            .env("MPM_SLURM_DIR", &self.dir)
            .env("SLURM_CONF", &self.conf)
            .env("MPM_SLURM_PORT", self.port.to_string())
            .output()
            .unwrap()
    }

    /// The daemons `status` names: `(name, pid)`.
    fn daemons(&self) -> Vec<(String, u32)> {
        let out = self.script("status");
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| {
                let (name, pid) = l.split_once(' ')?;
                Some((name.to_string(), pid.trim().parse().ok()?))
            })
            .collect()
    }

    /// A Slurm command (or `mpm-bench`) talking to this cluster.
    fn command(&self, program: &str) -> Command {
        let mut c = Command::new(program);
        c.env("SLURM_CONF", &self.conf);
        c
    }

    fn bench(&self) -> Command {
        self.command(env!("CARGO_BIN_EXE_mpm-bench"))
    }

    /// `sbatch --parsable` of a job that is not the harness's (someone else's).
    fn foreign_job(&self, args: &[&str]) -> String {
        let out = self.command("sbatch").args(["--parsable", "-o", "/dev/null"]).args(args).output().unwrap();
        assert!(out.status.success(), "{}", text(&out));
        String::from_utf8_lossy(&out.stdout).trim().to_string()
    }

    /// Every job's state, by id.
    fn states(&self) -> BTreeMap<String, String> {
        let out = self.command("squeue").args(["-h", "-r", "--states=all", "-o", "%i|%T"]).output().unwrap();
        assert!(out.status.success(), "{}", text(&out));
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .filter_map(|l| l.split_once('|').map(|(i, s)| (i.trim().to_string(), s.trim().to_string())))
            .collect()
    }

    fn state(&self, id: &str) -> String {
        self.states().get(id).cloned().unwrap_or_default()
    }

    fn scancel(&self, id: &str) {
        assert!(self.command("scancel").arg(id).status().unwrap().success());
    }

    fn stop(&mut self) -> Output {
        self.stopped = true;
        self.script("stop")
    }
}

impl Drop for LocalSlurm {
    fn drop(&mut self) {
        if !self.stopped {
            let _ = self.script("stop");
        }
    }
}

/// Wait up to `secs` for `cond`.
fn wait_for(secs: u64, what: &str, mut cond: impl FnMut() -> bool) {
    let t = Instant::now();
    while !cond() {
        assert!(t.elapsed() < Duration::from_secs(secs), "waited {secs} s for {what}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// Wait up to `secs` for `child` to exit: its status.
fn wait_exit(child: &mut std::process::Child, secs: u64, what: &str) -> std::process::ExitStatus {
    let t = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return s;
        }
        assert!(t.elapsed() < Duration::from_secs(secs), "waited {secs} s for {what}");
        std::thread::sleep(Duration::from_millis(200));
    }
}

/// The campaign folder an `mpm-bench run` printed.
fn folder(o: &Output) -> PathBuf {
    let out = String::from_utf8_lossy(&o.stdout);
    let line = out.lines().find_map(|l| l.strip_prefix("campaign folder: ")).unwrap_or_else(|| panic!("{}", text(o)));
    PathBuf::from(line.trim())
}

fn jobs(dir: &Path) -> Vec<JobRecord> {
    JobsFile::load(dir).unwrap().jobs
}

fn hostname() -> String {
    let o = Command::new("hostname").arg("-s").output().unwrap();
    String::from_utf8_lossy(&o.stdout).trim().to_string()
}

/// `scontrol show job`'s `key=` time of job `id` (`2026-11-26T16:12:14`: sorts as it reads).
fn job_time(slurm: &LocalSlurm, id: &str, key: &str) -> String {
    let o = slurm.command("scontrol").args(["show", "job", "-o", id]).output().unwrap();
    let line = String::from_utf8_lossy(&o.stdout).into_owned();
    let v = line.split_whitespace().find_map(|w| w.strip_prefix(key)?.strip_prefix('=').map(str::to_string));
    v.unwrap_or_else(|| panic!("no {key} in {line}"))
}

/// The smoke preset through Slurm, at most two jobs in the queue at once: its rows are a
/// local smoke campaign's configurations (the same planned runs, keys and requested CPUs),
/// each ok, verified on the CPUs placed, from a job of its own on this node, with the node's
/// machine in the manifest; no job was submitted while two others were still out.
fn smoke_through_slurm_is_the_local_smoke(slurm: &LocalSlurm, out: &Path) {
    let args = ["run", "--preset", "smoke", "--scheduler", "slurm", "--max-jobs", "2", "--poll-interval", "1", "--out"];
    let o = slurm.bench().args(args).arg(out).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let dir = folder(&o);
    assert!(dir.starts_with(out.join("slurm-mpmlocal")), "{}", dir.display());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("[8/8]") && err.contains("done: 8 rows written (8 ok"), "{err}");
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    let local = slurm
        .bench()
        .args(["run", "--preset", "smoke", "--mock", "--quiet", "--out"])
        .arg(out.join("local"))
        .output()
        .unwrap();
    assert!(local.status.success(), "{}", text(&local));
    let local_rows = read_rows(&folder(&local).join("runs.csv")).unwrap();
    // The key is the hash of the whole planned run (spec, opt level, pinning, repetition).
    let configuration = |rows: &[Row]| -> BTreeSet<(String, String, Vec<usize>)> {
        rows.iter()
            .inspect(|r| assert_eq!(r.run.key().0, r.id.run_key))
            .map(|r| (r.id.run_key.clone(), r.run.describe(), r.placement.requested_cpus.clone()))
            .collect()
    };
    assert_eq!(rows.len(), local_rows.len());
    assert_eq!(configuration(&rows), configuration(&local_rows));
    let fp = fingerprint::fingerprint(&Machine::detect().unwrap());
    let node = hostname();
    for r in &rows {
        assert_eq!(r.outcome.status, Status::Ok, "{}: {}", r.id.run_id, r.outcome.reason);
        assert!(!r.placement.observed_cpus.is_empty() && r.placement.observed_cpus == r.placement.requested_cpus);
        assert_eq!((r.id.machine_id.as_str(), r.id.node.as_str()), (fp.as_str(), node.as_str()));
        assert!(r.measured.as_ref().and_then(|f| f.timing.steady_s_per_step).is_some_and(|t| t > 0.0));
    }
    let ids: BTreeSet<&str> = rows.iter().map(|r| r.id.job_id.as_str()).collect();
    assert_eq!(ids.len(), rows.len(), "one array task per run");
    let arrays: BTreeSet<&str> = ids.iter().map(|id| id.split_once('_').expect("an array task").0).collect();
    assert_eq!(arrays.len(), 1, "one array: {ids:?}");
    let times: Vec<(String, String)> =
        ids.iter().map(|id| (job_time(slurm, id, "StartTime"), job_time(slurm, id, "EndTime"))).collect();
    for (i, (start, _)) in times.iter().enumerate() {
        let running = times.iter().enumerate().filter(|(j, (s, end))| *j != i && s <= start && end > start).count();
        assert!(running < 2, "task {i} started while {running} others ran (--max-jobs 2): {times:?}");
    }
    let man = mpm_bench::campaign::store::manifest::read(&dir.join("manifest.json")).unwrap();
    let n = &man.nodes[&fp];
    assert_eq!((n.node.as_str(), n.machine.fingerprint.as_str()), (node.as_str(), fp.as_str()));
    assert!(dir.join(&n.topology).is_file());
    assert!(man.sessions[0].scheduler.as_deref().is_some_and(|s| s.starts_with("slurm cluster mpmlocal")));
    assert!(jobs(&dir).is_empty(), "every job collected");
}

/// Jobs still pending when the command runs again are collected, not submitted twice; a job
/// someone else cancelled is a failed row with Slurm's state; the next run redoes it.
fn pending_jobs_are_collected_not_submitted_twice(slurm: &LocalSlurm, out: &Path) {
    // Someone else's job holds the only node: the campaign's jobs wait behind it.
    let blocker = slurm.foreign_job(&["--exclusive", "--wrap", "sleep 600"]);
    wait_for(30, "the blocking job to run", || slurm.state(&blocker) == "RUNNING");
    let run = |extra: &[&str]| {
        let args =
            ["run", "--preset", "smoke", "--scheduler", "slurm", "--no-build", "--opt", "o3", "--poll-interval", "1"];
        let args2 = ["--threads", "1", "--strategies", "dd", "--reps", "3", "--out"];
        slurm.bench().args(args).args(args2).arg(out).args(extra).output().unwrap()
    };
    let first = run(&["--detach"]);
    assert!(first.status.success(), "{}", text(&first));
    let dir = folder(&first);
    let submitted = jobs(&dir);
    assert_eq!(submitted.len(), 3, "{}", text(&first));
    assert!(text(&first).contains("3 run(s) in the Slurm queue"), "{}", text(&first));
    for j in &submitted {
        assert_eq!(slurm.state(&j.job_id), "PENDING");
    }
    let jobs_before = slurm.states().len();
    let again = run(&["--detach"]);
    assert!(again.status.success(), "{}", text(&again));
    assert!(text(&again).contains("3 run(s) were submitted by an earlier invocation"), "{}", text(&again));
    assert_eq!(jobs(&dir), submitted, "nothing submitted twice");
    assert_eq!(slurm.states().len(), jobs_before, "no new job in Slurm");
    // Someone cancels one of the campaign's jobs; the node frees.
    let cancelled = submitted[1].job_id.clone();
    slurm.scancel(&cancelled);
    slurm.scancel(&blocker);
    let collect = run(&[]);
    assert_eq!(collect.status.code(), Some(1), "a failed run: {}", text(&collect));
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 3);
    let ids: BTreeSet<&str> = submitted.iter().map(|j| j.job_id.as_str()).collect();
    assert!(rows.iter().all(|r| ids.contains(r.id.job_id.as_str())), "only the jobs first submitted");
    let failed: Vec<&Row> = rows.iter().filter(|r| r.outcome.status == Status::Failed).collect();
    assert_eq!(failed.len(), 1);
    assert_eq!(failed[0].id.job_id, cancelled);
    assert!(
        failed[0].outcome.reason.starts_with(&format!("Slurm job {cancelled} CANCELLED")),
        "{}",
        failed[0].outcome.reason
    );
    assert_eq!(rows.iter().filter(|r| r.outcome.status == Status::Ok).count(), 2);
    assert!(jobs(&dir).is_empty());
    // A failure is not a result: the next invocation submits that run again.
    let redo = run(&[]);
    assert!(redo.status.success(), "{}", text(&redo));
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 4);
    let last = rows.last().unwrap();
    assert_eq!((last.outcome.status, last.id.run_key.as_str()), (Status::Ok, failed[0].id.run_key.as_str()));
    assert!(!ids.contains(last.id.job_id.as_str()));
}

/// Ctrl-C (SIGINT to the harness) cancels the arrays that invocation submitted, and only
/// those: the array of an earlier invocation (killed right after `sbatch` answered, its array
/// adopted) and someone else's job are left alone. Runs of 1 and 2 ranks: two arrays.
fn ctrl_c_cancels_only_this_invocations_arrays(slurm: &LocalSlurm, out: &Path) {
    let held = slurm.foreign_job(&["--hold", "--wrap", "true"]);
    std::fs::create_dir_all(out).unwrap();
    let bin = logging_sbatch(out, &out.join("sbatch.log"));
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let args = ["run", "--preset", "smoke", "--scheduler", "slurm", "--no-build", "--opt", "o3", "--threads", "1"];
    let args2 = ["--ranks", "1,2", "--strategies", "dd", "--reps", "1", "--steps", "100000", "--poll-interval", "1"];
    let run = || {
        let mut c = slurm.bench();
        c.args(args).args(args2).args(["--launcher", LAUNCHER, "--out"]).arg(out).env("PATH", &path);
        c
    };
    // An earlier invocation submitted the first array (a long run) and was killed.
    let earlier = run().env("KILL_ONCE", out.join("killed")).output().unwrap();
    assert_eq!(std::os::unix::process::ExitStatusExt::signal(&earlier.status), Some(9), "{}", text(&earlier));
    let dir = only_folder(out);
    let first = jobs(&dir);
    assert_eq!(first.len(), 1, "one run a shape");
    let name = format!("mpm-{}-{}", dir.file_name().unwrap().to_str().unwrap(), first[0].batch);
    let o = slurm.command("squeue").args(["-h", "--states=all", "--name", &name, "-o", "%F"]).output().unwrap();
    let j1 = format!("{}_0", String::from_utf8_lossy(&o.stdout).trim());
    wait_for(30, "the earlier array's task to run", || slurm.state(&j1) == "RUNNING");
    let log = std::fs::File::create(out.join("ctrl-c.log")).unwrap();
    let mut child = run().stdout(Stdio::null()).stderr(log).spawn().unwrap();
    wait_for(30, "the second array to be submitted", || {
        let j = jobs(&dir);
        j.len() == 2 && j.iter().all(|j| !j.job_id.is_empty())
    });
    let j2 = jobs(&dir).iter().find(|j| j.batch != first[0].batch).unwrap().job_id.clone();
    let array2 = j2.split_once('_').unwrap().0.to_string();
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    let status = child.wait().unwrap();
    let said = std::fs::read_to_string(out.join("ctrl-c.log")).unwrap();
    assert_eq!(status.code(), Some(130), "{said}");
    assert!(said.contains(&format!("adopting Slurm job {}", j1.split_once('_').unwrap().0)), "{said}");
    assert!(said.contains(&format!("cancelling this invocation's jobs {array2}\n")), "{said}");
    wait_for(15, "the cancelled array to end", || slurm.state(&j2) == "CANCELLED");
    assert_eq!(slurm.state(&j1), "RUNNING", "the earlier invocation's array runs on");
    assert_eq!(slurm.state(&held), "PENDING", "someone else's job is left alone");
    assert_eq!(jobs(&dir).iter().map(|j| j.job_id.clone()).collect::<Vec<_>>(), [j1], "still to collect");
    assert!(read_rows(&dir.join("runs.csv")).unwrap_or_default().is_empty(), "an interrupted run is not recorded");
}

/// Whether a run of campaign folder `dir` has written a checkpoint.
fn checkpoint_written(dir: &Path) -> bool {
    let Ok(runs) = std::fs::read_dir(dir.join("checkpoints")) else { return false };
    runs.flatten().any(|r| matches!(mpm_host::checkpoint::newest_header(&r.path()), Ok(Some(_))))
}

/// A checkpointed run's job sent SIGUSR1 mid-run (what `--signal=B:USR1@120` sends before
/// the time limit) stops at a complete checkpoint: no row, the run still to do; the same
/// command again continues it from that checkpoint: one row, ok, one restart.
fn a_signalled_job_continues_from_its_last_checkpoint(slurm: &LocalSlurm, out: &Path) {
    let args = ["run", "--preset", "smoke", "--scheduler", "slurm", "--no-build", "--opt", "o3", "--threads", "1"];
    let args2 = ["--strategies", "dd", "--reps", "1", "--steps", "600", "--checkpoint-every", "100"];
    let run = || {
        let mut c = slurm.bench();
        c.args(args).args(args2).args(["--poll-interval", "1", "--out"]).arg(out);
        c
    };
    let log = std::fs::File::create(out.with_extension("log")).unwrap();
    let mut child = run().stdout(Stdio::null()).stderr(log).spawn().unwrap();
    let recorded = |dir: &Path| jobs(dir).iter().any(|j| !j.job_id.is_empty());
    wait_for(60, "the job to be recorded", || {
        std::fs::read_dir(out.join("slurm-mpmlocal")).is_ok_and(|d| d.flatten().any(|e| recorded(&e.path())))
    });
    let dir = only_folder(out);
    let record = jobs(&dir)[0].clone();
    let script = std::fs::read_to_string(dir.join("json").join(format!("{}.slurm.sh", record.batch))).unwrap();
    assert!(script.contains("--signal=B:USR1@120"), "{script}");
    wait_for(120, "the run's first checkpoint", || checkpoint_written(&dir));
    let signal = slurm.command("scancel").args(["--signal=USR1", "--batch", &record.job_id]).output().unwrap();
    assert!(signal.status.success(), "{}", text(&signal));
    let status = wait_exit(&mut child, 120, "the harness to end after the signal");
    let said = std::fs::read_to_string(out.with_extension("log")).unwrap();
    assert_eq!(status.code(), Some(0), "{said}");
    assert!(said.contains("stopped at a complete checkpoint"), "{said}");
    assert!(read_rows(&dir.join("runs.csv")).unwrap_or_default().is_empty(), "no row: the run is still to do");
    assert!(jobs(&dir).is_empty(), "{said}");
    let again = run().output().unwrap();
    assert!(again.status.success(), "{}", text(&again));
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 1, "{}", text(&again));
    assert_eq!(rows[0].outcome.status, Status::Ok, "{}", rows[0].outcome.reason);
    let restarts = rows[0].measured.as_ref().and_then(|m| m.checkpoint.as_ref()).map(|c| c.restarts);
    assert_eq!(restarts, Some(1), "continued from its checkpoint");
    assert!(rows[0].outcome.lost_compute_s.is_some());
}

/// The launcher of the runs over two ranks: Open MPI as root, using the Slurm allocation's
/// tasks as its slots (no --oversubscribe).
const LAUNCHER: &str = "mpirun --allow-run-as-root --bind-to none -n {ranks}";

/// The hybrid preset narrowed to Model 1, 1 thread, 1 repetition (ranks 1 and 2) through
/// Slurm gives the rows a local hybrid campaign gives: the same run keys, each ok, its ranks
/// recorded and each rank seen on its CPUs; the 2-rank run's job was allocated 2 tasks of 1
/// CPU; the site's sbatch option passed through; an option the protocol relies on refused.
fn hybrid_ranks_through_slurm(slurm: &LocalSlurm, out: &Path) {
    let narrow = ["--models", "1", "--threads", "1", "--reps", "1", "--launcher", LAUNCHER, "--out"];
    let slurm_args = ["run", "--preset", "hybrid", "--scheduler", "slurm", "--no-build", "--poll-interval", "1"];
    let refused =
        slurm.bench().args(slurm_args).arg("--sbatch-arg=--array=0-1").args(narrow).arg(out).output().unwrap();
    assert_eq!(refused.status.code(), Some(2), "{}", text(&refused));
    assert!(text(&refused).contains("--array is set by the harness"), "{}", text(&refused));
    let o = slurm.bench().args(slurm_args).arg("--sbatch-arg=--nice=5").args(narrow).arg(out).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let rows = read_rows(&folder(&o).join("runs.csv")).unwrap();
    let local_args = ["run", "--preset", "hybrid", "--mock", "--quiet"];
    let local = slurm.bench().args(local_args).args(narrow).arg(out.join("local")).output().unwrap();
    assert!(local.status.success(), "{}", text(&local));
    let local_rows = read_rows(&folder(&local).join("runs.csv")).unwrap();
    let keys = |rows: &[Row]| -> BTreeSet<(String, usize)> {
        rows.iter().map(|r| (r.id.run_key.clone(), r.ranks())).collect()
    };
    assert_eq!(keys(&rows), keys(&local_rows));
    assert_eq!(rows.iter().map(Row::ranks).collect::<BTreeSet<_>>(), BTreeSet::from([1, 2]));
    for r in &rows {
        assert_eq!(r.outcome.status, Status::Ok, "{}: {}", r.id.run_id, r.outcome.reason);
        if r.ranks() == 2 {
            assert_eq!(r.placement.rank_cpus.len(), 2, "each rank's CPUs recorded");
            assert_eq!(job_field(slurm, &r.id.job_id, "NumTasks"), "2");
            assert_eq!(job_field(slurm, &r.id.job_id, "CPUs/Task"), "1");
        }
        assert_eq!(job_field(slurm, &r.id.job_id, "Nice"), "5", "--sbatch-arg passed through");
    }
}

/// The campaign folder under `out` of the only campaign there (a harness killed before it
/// printed it).
fn only_folder(out: &Path) -> PathBuf {
    let all: Vec<PathBuf> =
        std::fs::read_dir(out.join("slurm-mpmlocal")).unwrap().flatten().map(|e| e.path()).collect();
    assert_eq!(all.len(), 1, "{all:?}");
    all[0].clone()
}

/// A folder with an `sbatch` that logs every submission to `log` and forwards it to Slurm's;
/// when `KILL_ONCE` names a file that does not exist, it creates it and kills its caller (the
/// harness) with SIGKILL once Slurm has answered, before the caller could read the answer.
fn logging_sbatch(dir: &Path, log: &Path) -> PathBuf {
    let real = Command::new("sh").args(["-c", "command -v sbatch"]).output().unwrap();
    let real = String::from_utf8_lossy(&real.stdout).trim().to_string();
    assert!(!real.is_empty(), "no sbatch on PATH");
    let bin = dir.join("bin");
    std::fs::create_dir_all(&bin).unwrap();
    let script = format!(
        "#!/bin/sh\necho \"$*\" >> '{}'\nanswer=$('{real}' \"$@\"); rc=$?\n\
         if [ -n \"$KILL_ONCE\" ] && [ ! -e \"$KILL_ONCE\" ]; then : > \"$KILL_ONCE\"; kill -KILL $PPID; exit 1; fi\n\
         printf '%s\\n' \"$answer\"\nexit $rc\n",
        log.display()
    );
    let path = bin.join("sbatch");
    std::fs::write(&path, script).unwrap();
    std::fs::set_permissions(&path, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    bin
}

/// The harness killed with SIGKILL right after `sbatch` answered for an array, before it
/// wrote the job ids down: the same command again adopts that array (found by its name),
/// never submits its runs a second time, and ends with one row per run key; once all are
/// done, the command again adds nothing.
fn an_array_submitted_by_a_killed_harness_is_adopted(slurm: &LocalSlurm, out: &Path) {
    let log = out.join("sbatch.log");
    let kill_once = out.join("killed");
    std::fs::create_dir_all(out).unwrap();
    let bin = logging_sbatch(out, &log);
    let path = format!("{}:{}", bin.display(), std::env::var("PATH").unwrap_or_default());
    let run = |kill: bool| {
        let args = ["run", "--preset", "smoke", "--scheduler", "slurm", "--no-build", "--opt", "o3", "--poll-interval"];
        let args2 = ["1", "--threads", "1", "--strategies", "dd", "--reps", "2", "--out"];
        let mut c = slurm.bench();
        c.args(args).args(args2).arg(out).env("PATH", &path);
        if kill {
            c.env("KILL_ONCE", &kill_once);
        }
        c.output().unwrap()
    };
    let killed = run(true);
    assert_eq!(std::os::unix::process::ExitStatusExt::signal(&killed.status), Some(9), "{}", text(&killed));
    let dir = only_folder(out);
    let left = jobs(&dir);
    assert_eq!(left.len(), 2, "the runs recorded before sbatch was asked");
    assert!(left.iter().all(|j| j.job_id.is_empty()), "sbatch's answer was never read");
    assert_eq!(left[0].batch, left[1].batch, "one array");
    let name = format!("mpm-{}-{}", dir.file_name().unwrap().to_str().unwrap(), left[0].batch);
    let o = slurm.command("squeue").args(["-h", "--states=all", "--name", &name, "-o", "%F"]).output().unwrap();
    let array = String::from_utf8_lossy(&o.stdout).trim().to_string();
    assert!(!array.is_empty() && !array.contains('\n'), "one array of that name in Slurm: {array:?}");
    let again = run(false);
    assert!(again.status.success(), "{}", text(&again));
    assert!(text(&again).contains(&format!("adopting Slurm job {array} ({name})")), "{}", text(&again));
    let submissions = || std::fs::read_to_string(&log).unwrap().lines().count();
    assert_eq!(submissions(), 1, "one array, one submission: its runs were not submitted again");
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 2);
    let keys: BTreeSet<&str> = rows.iter().map(|r| r.id.run_key.as_str()).collect();
    assert_eq!(keys.len(), 2, "one row per run key");
    assert!(rows.iter().all(|r| r.outcome.status == Status::Ok), "{rows:?}");
    for j in &left {
        let task = format!("{array}_{}", j.task);
        assert!(rows.iter().any(|r| r.id.job_id == task && r.id.run_id == j.run_id), "the adopted task {task}'s row");
    }
    assert!(jobs(&dir).is_empty());
    let done = run(false);
    assert!(done.status.success(), "{}", text(&done));
    assert_eq!(read_rows(&dir.join("runs.csv")).unwrap().len(), 2, "nothing added: {}", text(&done));
    assert_eq!(submissions(), 1, "nothing submitted");
}

/// `scontrol show job`'s `key=` value of job `id`.
fn job_field(slurm: &LocalSlurm, id: &str, key: &str) -> String {
    let o = slurm.command("scontrol").args(["show", "job", "-o", id]).output().unwrap();
    let line = String::from_utf8_lossy(&o.stdout).into_owned();
    line.split_whitespace().find_map(|w| w.strip_prefix(key)?.strip_prefix('=').map(str::to_string)).unwrap_or_default()
}

/// Make job `id` requeueable, as an administrator may (`scontrol update Requeue=1`): the
/// harness submits with `--no-requeue`, which refuses a plain `scontrol requeue`.
fn make_requeueable(slurm: &LocalSlurm, id: &str) {
    let refused = slurm.command("scontrol").args(["requeue", id]).output().unwrap();
    assert!(!refused.status.success(), "a job of the harness is not requeueable: {}", text(&refused));
    assert_eq!(job_field(slurm, id, "Requeue"), "0");
    let update = slurm.command("scontrol").args(["update", &format!("jobid={id}"), "Requeue=1"]).output().unwrap();
    assert!(update.status.success(), "{}", text(&update));
}

/// `scontrol requeue` of job `id`.
fn requeue(slurm: &LocalSlurm, id: &str) {
    let requeue = slurm.command("scontrol").args(["requeue", id]).output().unwrap();
    assert!(requeue.status.success(), "{}", text(&requeue));
}

/// A job requeued while it runs, and one requeued after its row was collected: the second
/// start writes nothing (the ledger names the first start only, or no job at all), and the
/// campaign has one row of the run.
fn a_requeued_job_gives_one_row(slurm: &LocalSlurm, out: &Path) {
    let args = ["run", "--preset", "smoke", "--scheduler", "slurm", "--no-build", "--opt", "o3", "--threads", "1"];
    let args2 = ["--strategies", "dd", "--reps", "1", "--poll-interval", "1", "--out"];
    // While it runs (a long run): the restarted start is fenced out, the run is a failed row.
    let log = std::fs::File::create(out.with_extension("log")).unwrap();
    let mut bench = slurm.bench();
    bench.args(args).args(["--steps", "100000"]).args(args2).arg(out).stdout(Stdio::null()).stderr(log);
    let mut child = bench.spawn().unwrap();
    let recorded = |dir: &Path| jobs(dir).iter().any(|j| !j.job_id.is_empty());
    wait_for(60, "the job to be recorded", || {
        std::fs::read_dir(out.join("slurm-mpmlocal")).is_ok_and(|d| d.flatten().any(|e| recorded(&e.path())))
    });
    let dir = only_folder(out);
    let record = jobs(&dir)[0].clone();
    wait_for(60, "the job to run", || slurm.state(&record.job_id) == "RUNNING");
    make_requeueable(slurm, &record.job_id);
    requeue(slurm, &record.job_id);
    let status = wait_exit(&mut child, 180, "the harness to end after the requeue");
    let said = std::fs::read_to_string(out.with_extension("log")).unwrap();
    assert_eq!(status.code(), Some(1), "a failed run: {said}");
    assert_eq!(job_field(slurm, &record.job_id, "Restarts"), "1", "{said}");
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 1, "{said}");
    assert_eq!((rows[0].outcome.status, rows[0].id.job_id.as_str()), (Status::Failed, record.job_id.as_str()));
    assert!(rows[0].outcome.reason.contains("started again by Slurm"), "{}", rows[0].outcome.reason);
    assert!(!dir.join("json").join(format!("{}.row.json", record.run_id)).exists(), "no start wrote a row");
    // After it was collected: the restart finds no record of its run and writes nothing. (A
    // job that ended cannot be made requeueable: it is, while it waits behind another job.)
    let quick = out.join("quick");
    let blocker = slurm.foreign_job(&["--exclusive", "--wrap", "sleep 600"]);
    wait_for(30, "the blocking job to run", || slurm.state(&blocker) == "RUNNING");
    let o = slurm.bench().args(args).args(args2).arg(&quick).arg("--detach").output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let qdir = folder(&o);
    make_requeueable(slurm, &jobs(&qdir)[0].job_id);
    slurm.scancel(&blocker);
    let o = slurm.bench().args(args).args(args2).arg(&quick).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    let rows = read_rows(&qdir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 1);
    let (job, run_id) = (rows[0].id.job_id.clone(), rows[0].id.run_id.clone());
    let json = qdir.join("json");
    let files_before: BTreeMap<String, Vec<u8>> = std::fs::read_dir(&json)
        .unwrap()
        .flatten()
        .filter(|e| !e.file_name().to_string_lossy().ends_with(".slurm.out"))
        .map(|e| (e.file_name().to_string_lossy().into_owned(), std::fs::read(e.path()).unwrap()))
        .collect();
    requeue(slurm, &job);
    wait_for(120, "the requeued job to run again and end", || {
        job_field(slurm, &job, "Restarts") == "1"
            && ["COMPLETED", "FAILED"].contains(&job_field(slurm, &job, "JobState").as_str())
    });
    let output = std::fs::read_to_string(json.join(format!("{run_id}.slurm.out"))).unwrap();
    assert!(output.contains(&format!("has no record of run {run_id}")), "{output}");
    for (name, bytes) in &files_before {
        assert_eq!(&std::fs::read(json.join(name)).unwrap(), bytes, "{name} was written again");
    }
    let o = slurm.bench().args(args).args(args2).arg(&quick).output().unwrap();
    assert!(o.status.success(), "{}", text(&o));
    assert_eq!(read_rows(&qdir.join("runs.csv")).unwrap().len(), 1, "one row of the run");
}

/// One case of the test: on the cluster, into its own results folder.
type Case = fn(&LocalSlurm, &Path);

#[test]
fn campaigns_through_a_one_node_slurm() {
    let t0 = Instant::now();
    let mut slurm = LocalSlurm::start();
    let daemons = slurm.daemons();
    let names: BTreeSet<&str> = daemons.iter().map(|(n, _)| n.as_str()).collect();
    assert_eq!(names, BTreeSet::from(["munged", "slurmctld", "slurmd"]), "{daemons:?}");
    let tmp = tempfile::tempdir().unwrap();
    let cases: [(&str, Case); 7] = [
        ("smoke", smoke_through_slurm_is_the_local_smoke),
        ("hybrid", hybrid_ranks_through_slurm),
        ("pending", pending_jobs_are_collected_not_submitted_twice),
        ("killed", an_array_submitted_by_a_killed_harness_is_adopted),
        ("requeue", a_requeued_job_gives_one_row),
        ("checkpoint", a_signalled_job_continues_from_its_last_checkpoint),
        ("ctrl-c", ctrl_c_cancels_only_this_invocations_arrays),
    ];
    for (name, case) in cases {
        let t = Instant::now();
        case(&slurm, &tmp.path().join(name));
        eprintln!("Slurm case {name}: {:.0} s", t.elapsed().as_secs_f64());
    }
    // Jobs still run (the earlier invocation's, someone else's held one): stop takes them too.
    let steps: Vec<u32> = processes("slurmstepd");
    assert!(!steps.is_empty(), "a job step runs");
    let stopped = slurm.stop();
    assert!(stopped.status.success(), "{}", text(&stopped));
    for (name, pid) in &daemons {
        assert!(!alive(*pid), "{name} (pid {pid}) outlived stop");
    }
    for pid in steps {
        assert!(!alive(pid), "slurmstepd {pid} outlived stop");
    }
    assert!(processes("mpm").iter().all(|p| {
        !std::fs::read_to_string(format!("/proc/{p}/cmdline"))
            .unwrap_or_default()
            .contains(tmp.path().to_str().unwrap())
    }));
    assert!(!slurm.dir.exists() && !slurm.conf.exists(), "stop removes the state and the configuration");
    eprintln!("Slurm tests: {:.0} s", t0.elapsed().as_secs_f64());
}
