//! One run as a child process: the request (the run's spec file), what came back, and the
//! runners: [`ProcessRunner`] writes the run's [`mpm_spec::RunSpec`] to a file and spawns
//! `mpm run --spec FILE` as a fresh process (clean memory figure, no state carried over; a
//! run with a checkpoint to continue from: `mpm resume DIR --spec FILE`), or
//! with several ranks `<launcher> mpm run --spec FILE` (see [`super::launcher`]) with the CPU
//! set of the run as the launcher's affinity mask, in a process group of its own so that a
//! timeout or Ctrl-C stops every rank; [`MockRunner`] fakes it in microseconds for tests.
//! The harness never composes solver flags: everything the solver needs is in the spec.
//!
//! A child dies with the harness (Linux parent-death signal, set between fork and exec), and
//! the temporary summary file of a child killed mid-run (timeout, Ctrl-C, SIGTERM) is removed
//! at once; leftovers of a harness killed outright are swept when the campaign is opened again
//! ([`remove_stale_temp_files`]).

use super::launcher::Launcher;
use crate::campaign::plan::matrix::PlannedRun;
use crate::campaign::plan::preset::OptLevel;
use mpm_core::{Strategy, Substage};
use mpm_spec::summary::{
    EndReason, Figures, Memory, NoiseReport, PairedReport, Physics, Pinning, Progress, RankReport, ScenarioFigures,
    Size, StageSeconds, Summary, TaylorFigures, Timing, WorkReport, WorkerUsage, MIN_CPU_SHARE,
};
use mpm_spec::RunSpec;
use std::io::Read;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

/// Everything one run needs.
#[derive(Clone, Debug)]
pub struct RunRequest {
    /// The run as planned.
    pub planned: PlannedRun,
    /// What the solver runs: the planned spec with this run's CPUs (`None` not pinned, and
    /// always `None` with several ranks: see `mask`) and outputs (the JSON summary at
    /// `json_path`, quiet).
    pub spec: RunSpec,
    /// Where the spec is written for the solver to read.
    pub spec_path: PathBuf,
    /// Solver binary.
    pub binary: PathBuf,
    /// Several ranks: the launcher's words (program first), `mpm run --spec FILE` follows.
    pub launcher: Option<Vec<String>>,
    /// Several ranks, pinned: the launcher's affinity mask (the CPU set of all ranks'
    /// workers, ascending), inherited by the ranks, which slice it by rank.
    pub mask: Option<Vec<usize>>,
    /// Where the solver writes its JSON summary.
    pub json_path: PathBuf,
    /// Per-run time limit.
    pub timeout: Option<Duration>,
    /// The run's checkpoint folder when it holds a checkpoint to continue from: the solver
    /// runs `mpm resume DIR --spec FILE` (the spec checked against the checkpoint's).
    pub resume: Option<PathBuf>,
}

impl RunRequest {
    /// The request of `planned` on `cpus`, its files at `json_path` (the summary) and
    /// `spec_path`.
    pub fn new(planned: &PlannedRun, cpus: Option<Vec<usize>>, json_path: PathBuf, spec_path: PathBuf) -> Self {
        let mut spec = planned.spec.clone();
        spec.cpus = cpus;
        spec.outputs.json = Some(json_path.clone());
        spec.outputs.quiet = true;
        Self {
            planned: planned.clone(),
            spec,
            spec_path,
            binary: PathBuf::new(),
            launcher: None,
            mask: None,
            json_path,
            timeout: None,
            resume: None,
        }
    }

    /// Arguments of `mpm`: the spec file, nothing else (`run --spec FILE`, or `resume DIR
    /// --spec FILE` to continue from the run's checkpoint).
    pub fn args(&self) -> Vec<String> {
        let spec = ["--spec".into(), self.spec_path.display().to_string()];
        match &self.resume {
            Some(dir) => [vec!["resume".into(), dir.display().to_string()], spec.to_vec()].concat(),
            None => [vec!["run".into()], spec.to_vec()].concat(),
        }
    }

    /// The program and its arguments: `mpm run --spec FILE`, or the launcher's words, then
    /// the solver binary and `run --spec FILE`.
    pub fn command_line(&self) -> (String, Vec<String>) {
        let binary = self.binary.display().to_string();
        match self.launcher.as_deref() {
            Some([program, rest @ ..]) => {
                let mut a: Vec<String> = rest.to_vec();
                a.push(binary);
                a.extend(self.args());
                (program.clone(), a)
            }
            _ => (binary, self.args()),
        }
    }

    /// Write the spec file (TOML) for the solver.
    pub fn write_spec(&self) -> std::io::Result<()> {
        mpm_host::atomic::write_atomic(&self.spec_path, self.spec.to_toml().as_bytes())
            .map_err(|e| std::io::Error::other(format!("{:#}", anyhow::Error::new(e))))
    }
}

/// How a child process ended.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RunOutput {
    /// Exit code (`None` when killed by a signal or never started).
    pub exit_code: Option<i32>,
    /// Why it did not run or was stopped (spawn error, timeout, signal).
    pub error: Option<String>,
    /// Last lines of its standard error.
    pub stderr_tail: String,
    /// Wall time of the process (s).
    pub process_wall_s: f64,
    /// Stopped because the campaign was interrupted.
    pub interrupted: bool,
}

/// Runs one configuration.
pub trait Runner {
    /// Run `req`; the summary, if any, is at `req.json_path` afterwards.
    fn run(&mut self, req: &RunRequest) -> RunOutput;

    /// Why runs through `launcher` would all fail before they start, if they would (checked
    /// once, before a campaign's first run over several ranks). Only a runner that starts
    /// the launcher has anything to check.
    fn launcher_refusal(&self, _launcher: &Launcher) -> Option<String> {
        None
    }
}

/// Spawns the real solver, one fresh process per run.
pub struct ProcessRunner {
    interrupted: Arc<AtomicBool>,
}

impl ProcessRunner {
    /// A runner that stops its child when `interrupted` becomes true.
    pub fn new(interrupted: Arc<AtomicBool>) -> Self {
        Self { interrupted }
    }
}

/// The child in progress, its summary's temporary file and whether it leads a process group
/// of its own (a launcher and its ranks), for [`kill_live_child`].
static LIVE_CHILD: Mutex<Option<(u32, PathBuf, bool)>> = Mutex::new(None);

/// SIGKILL to `pid`, or to its whole process group when `group` (a launcher, whose ranks
/// must not outlive it).
fn kill_pid(pid: u32, group: bool) {
    if let Ok(pid) = libc::pid_t::try_from(pid) {
        let target = if group { -pid } else { pid };
        // SAFETY: kill(2) has no memory-safety preconditions. `pid` is our own child: for a
        // single process not yet reaped (LIVE_CHILD is cleared before the child is waited
        // for); with `group` the id of the process group it was started in
        // (`process_group(0)`), which the kernel does not hand out again while any member
        // lives (once none does, the call fails with ESRCH).
        unsafe { libc::kill(target, libc::SIGKILL) };
    }
}

/// Kill the solver child in progress (if any) and remove its temporary summary file: the
/// harness is about to exit without cleaning up (a second Ctrl-C).
pub fn kill_live_child() {
    let live = LIVE_CHILD.lock().unwrap_or_else(|e| e.into_inner()).take();
    if let Some((pid, tmp, group)) = live {
        kill_pid(pid, group);
        let _ = std::fs::remove_file(tmp);
    }
}

/// Remove temporary files (`.<name>.tmp.<pid>`) in `dir` left by processes that no longer
/// run (a solver or harness killed mid-write). Returns how many were removed.
pub fn remove_stale_temp_files(dir: &Path) -> usize {
    let Ok(rd) = std::fs::read_dir(dir) else { return 0 };
    let mut removed = 0;
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        let Some(pid) = mpm_host::atomic::temp_file_pid(&name) else { continue };
        if pid != std::process::id() && !process_runs(pid) && std::fs::remove_file(e.path()).is_ok() {
            removed += 1;
        }
    }
    removed
}

/// Whether process `pid` exists and is not a zombie (`/proc/<pid>/stat`, state after the
/// command name).
fn process_runs(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .ok()
        .and_then(|s| s.rsplit_once(')').map(|(_, rest)| !rest.trim_start().starts_with('Z')))
        .unwrap_or(false)
}

/// `mpm` dies with the harness: the parent-death signal is SIGKILL, so a harness killed by
/// any signal (SIGKILL included) leaves no solver running on the pinned CPUs. With `mask`,
/// the child (a launcher) starts with that CPU set as its affinity mask, which its ranks
/// inherit.
fn die_with_parent(cmd: &mut Command, mask: Option<&[usize]>) {
    use std::os::unix::process::CommandExt;
    let parent = libc::pid_t::try_from(std::process::id()).unwrap_or(libc::pid_t::MAX);
    let set = mask.map(cpu_set);
    // SAFETY: the closure runs in the forked child before exec, where only async-signal-safe
    // calls are allowed: it calls prctl(2), getppid(2) and sched_setaffinity(2) and builds
    // io::Errors from raw OS codes (no allocation, no locks), and touches only `parent`, an
    // integer, and `set`, a plain cpu_set_t built before the fork, both moved in.
    // Linux sends the signal when the thread that forked the child exits; the campaign loop
    // spawns every child from the one thread that runs it, for the campaign's whole life.
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL as libc::c_ulong, 0, 0, 0) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The parent may have died between fork and prctl: then nobody would signal us.
            if libc::getppid() != parent {
                return Err(std::io::Error::from_raw_os_error(libc::ESRCH));
            }
            if let Some(set) = &set {
                if libc::sched_setaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), set) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
            }
            Ok(())
        });
    }
}

/// A CPU set of the CPUs in `cpus` (those beyond `CPU_SETSIZE` left out).
fn cpu_set(cpus: &[usize]) -> libc::cpu_set_t {
    // SAFETY: cpu_set_t is a plain bit array; all zeroes is the empty set.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    let max = usize::try_from(libc::CPU_SETSIZE).unwrap_or(1024);
    for &c in cpus.iter().filter(|&&c| c < max) {
        // SAFETY: `c` is below CPU_SETSIZE, so the bit lies inside `set`.
        unsafe { libc::CPU_SET(c, &mut set) };
    }
    set
}

impl Runner for ProcessRunner {
    fn launcher_refusal(&self, launcher: &Launcher) -> Option<String> {
        launcher.root_refusal()
    }

    fn run(&mut self, req: &RunRequest) -> RunOutput {
        let start = Instant::now();
        let _ = std::fs::remove_file(&req.json_path);
        if let Err(e) = req.write_spec() {
            return RunOutput {
                error: Some(format!("cannot write the run's spec {}: {e}", req.spec_path.display())),
                ..RunOutput::default()
            };
        }
        let (program, args) = req.command_line();
        let mut cmd = Command::new(&program);
        cmd.args(args).stdin(Stdio::null()).stdout(Stdio::null()).stderr(Stdio::piped());
        // Rayon and OpenMP variables must not change the thread count behind our back.
        cmd.env_remove("RAYON_NUM_THREADS");
        let group = req.launcher.is_some();
        if group {
            use std::os::unix::process::CommandExt;
            // The launcher and its ranks in a group of their own: stopped together.
            cmd.process_group(0);
        }
        die_with_parent(&mut cmd, req.mask.as_deref());
        let mut child = match cmd.spawn() {
            Ok(c) => c,
            Err(e) => {
                let what = if group { "the launcher" } else { "the solver" };
                return RunOutput {
                    error: Some(format!("cannot start {what} {program}: {e}")),
                    ..RunOutput::default()
                };
            }
        };
        let tmp = mpm_host::atomic::temp_path_for_pid(&req.json_path, child.id());
        *LIVE_CHILD.lock().unwrap_or_else(|e| e.into_inner()) = Some((child.id(), tmp.clone(), group));
        let mut stderr = child.stderr.take();
        let reader = std::thread::spawn(move || {
            let mut s = String::new();
            if let Some(e) = stderr.as_mut() {
                let _ = e.read_to_string(&mut s);
            }
            s
        });
        let mut out = self.wait(&mut child, req, start);
        // A child killed mid-run leaves its reserved summary file behind.
        let _ = std::fs::remove_file(&tmp);
        if group {
            // Ranks of a launcher that ended or was killed: none may stay on the CPUs. Their
            // temporary files are named after rank 0's pid, which is not the launcher's.
            kill_pid(child.id(), true);
            remove_temp_files_for(&req.json_path);
        }
        out.process_wall_s = start.elapsed().as_secs_f64();
        let text = reader.join().unwrap_or_default();
        out.stderr_tail = tail(&text, 3);
        out
    }
}

impl ProcessRunner {
    /// Wait for `child`: its exit, or a kill on interrupt or timeout.
    fn wait(&self, child: &mut Child, req: &RunRequest, start: Instant) -> RunOutput {
        let mut out = RunOutput::default();
        let group = req.launcher.is_some();
        let stop = |child: &mut Child| {
            LIVE_CHILD.lock().unwrap_or_else(|e| e.into_inner()).take();
            if group {
                kill_pid(child.id(), true);
            }
            let _ = child.kill();
            let _ = child.wait();
        };
        loop {
            match child.try_wait() {
                Ok(Some(status)) => {
                    LIVE_CHILD.lock().unwrap_or_else(|e| e.into_inner()).take();
                    out.exit_code = status.code();
                    if status.code().is_none() {
                        use std::os::unix::process::ExitStatusExt;
                        out.error = Some(format!("killed by signal {}", status.signal().unwrap_or(0)));
                    }
                    return out;
                }
                Ok(None) => {}
                Err(e) => {
                    out.error = Some(format!("cannot wait for the solver: {e}"));
                    stop(child);
                    return out;
                }
            }
            if self.interrupted.load(Ordering::SeqCst) {
                stop(child);
                out.interrupted = true;
                out.error = Some("interrupted".into());
                return out;
            }
            if req.timeout.is_some_and(|t| start.elapsed() > t) {
                stop(child);
                out.error = Some(format!(
                    "timed out after {}",
                    humantime::format_duration(Duration::from_secs(start.elapsed().as_secs()))
                ));
                return out;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// Remove the temporary files of `json_path` (`.<name>.tmp.<pid>`) whatever their pid: with
/// a launcher the writer is rank 0, a grandchild whose pid the harness does not know.
fn remove_temp_files_for(json_path: &Path) {
    let (Some(dir), Some(name)) = (json_path.parent(), json_path.file_name()) else { return };
    let prefix = format!(".{}.tmp.", name.to_string_lossy());
    let Ok(rd) = std::fs::read_dir(dir) else { return };
    for e in rd.flatten() {
        if e.file_name().to_string_lossy().starts_with(&prefix) {
            let _ = std::fs::remove_file(e.path());
        }
    }
}

/// The last `lines` lines of `s` that are not blank, joined by ` | `.
pub fn tail(s: &str, lines: usize) -> String {
    let v: Vec<&str> = s.lines().filter(|l| !l.trim().is_empty()).collect();
    v[v.len().saturating_sub(lines)..].join(" | ")
}

/// A fake solver for tests: writes a plausible JSON summary instantly.
#[derive(Clone, Debug, Default)]
pub struct MockRunner {
    /// Every request received, in order.
    pub calls: Vec<RunRequest>,
    /// Fail runs whose description contains this text.
    pub fail_when: Option<String>,
    /// Report CPUs other than the requested ones for runs whose description contains this.
    pub wrong_cpus_when: Option<String>,
    /// Raise the interrupt flag after this many calls (simulated Ctrl-C).
    pub interrupt_after: Option<(usize, Arc<AtomicBool>)>,
    /// Sleep this long per run.
    pub delay: Duration,
    /// Report a worker with half the wall time as CPU time for runs whose description
    /// contains this.
    pub low_cpu_when: Option<String>,
    /// Standard deviation of the mock's process effect on a paired run's efficiency (in
    /// logs; `None`: 0.03): the spread between processes that the blocks do not show.
    pub process_spread: Option<f64>,
}

impl Runner for MockRunner {
    fn run(&mut self, req: &RunRequest) -> RunOutput {
        self.calls.push(req.clone());
        std::thread::sleep(self.delay);
        if let Some((n, flag)) = &self.interrupt_after {
            if self.calls.len() > *n {
                flag.store(true, Ordering::SeqCst);
                return RunOutput { interrupted: true, error: Some("interrupted".into()), ..RunOutput::default() };
            }
        }
        let desc = req.planned.describe();
        if self.fail_when.as_ref().is_some_and(|f| desc.contains(f.as_str())) {
            return RunOutput {
                exit_code: Some(1),
                stderr_tail: "mock failure".into(),
                process_wall_s: 0.01,
                ..RunOutput::default()
            };
        }
        // As mpm: the spec is checked (`split_wait` needs several ranks, ...), and with
        // `split_wait` every rank reports its waiting.
        if let Err(e) = req.spec.check() {
            return RunOutput {
                exit_code: Some(1),
                stderr_tail: format!("error: {e}"),
                process_wall_s: 0.01,
                ..RunOutput::default()
            };
        }
        let split_wait = req.spec.split_wait;
        let requested = req.spec.cpus.clone().unwrap_or_default();
        let wrong = self.wrong_cpus_when.as_ref().is_some_and(|f| desc.contains(f.as_str()));
        let observed: Vec<usize> = if wrong { requested.iter().map(|c| c + 1).collect() } else { requested.clone() };
        let mut summary = mock_summary(req, requested, observed);
        let low_cpu = self.low_cpu_when.as_ref().is_some_and(|f| desc.contains(f.as_str()));
        let (noise, paired) = mock_noise_work_paired(req, &mut summary, low_cpu, self.process_spread.unwrap_or(0.03));
        let ranks = (req.spec.ranks > 1).then(|| mock_ranks(req, &summary, wrong, split_wait));
        let peak = summary.figures.memory.peak_rss_bytes;
        summary.finish(ranks, noise, paired, peak);
        let wall = summary.figures.timing.wall_s;
        let text = match serde_json::to_string(&summary) {
            Ok(t) => t,
            Err(e) => return RunOutput { error: Some(format!("mock cannot write JSON: {e}")), ..RunOutput::default() },
        };
        if let Err(e) = std::fs::write(&req.json_path, text) {
            return RunOutput { error: Some(format!("mock cannot write JSON: {e}")), ..RunOutput::default() };
        }
        RunOutput { exit_code: Some(0), process_wall_s: wall + 0.05, ..RunOutput::default() }
    }
}

/// Plausible rank reports of a run over several ranks: each rank's workers on its slice of
/// the mask as `mpm` places them (shared and flagged when the mask is too small), the
/// particles split evenly, a halo of 1 % of the particles' 80 bytes each way per step; with
/// `split_wait` each rank's waiting (the later ranks wait less).
fn mock_ranks(req: &RunRequest, s: &Summary, wrong: bool, split_wait: bool) -> Vec<RankReport> {
    let (ranks, threads) = (req.spec.ranks, req.spec.threads);
    let (particles, steps, wall_s) = (s.figures.size.particles, s.figures.progress.steps, s.figures.timing.wall_s);
    let mask = req.mask.clone().unwrap_or_default();
    let fits = mask.len() >= ranks * threads;
    (0..ranks)
        .map(|r| {
            let cpus: Vec<usize> = if mask.is_empty() {
                Vec::new()
            } else {
                (0..threads).map(|j| mask[(r * threads + j) % mask.len()] + usize::from(wrong)).collect()
            };
            let halo = (particles as u64 / 100) * 80 * steps;
            RankReport {
                rank: r,
                cpus,
                oversubscribed: !fits,
                particles: particles / ranks,
                migrated: 3,
                busy_s: wall_s * 0.9 * threads as f64,
                steps,
                exchange: mpm_core::exchange::ExchangeStats {
                    halo_bytes: halo,
                    halo_messages: 2 * steps,
                    migration_bytes: 1000,
                    migration_messages: 2 * steps,
                    reduction_bytes: 48 * steps,
                    reductions: 3 * steps,
                    seconds: wall_s * 0.02 * (r + 1) as f64,
                    wait_seconds: split_wait.then(|| wall_s * 0.04 * (ranks - r) as f64),
                },
                peak_rss_bytes: s.figures.memory.peak_rss_bytes.map(|b| b / ranks as u64 + (20 << 20)),
            }
        })
        .collect()
}

/// A generator seeded by the run's summary path (unique per run and campaign) less its parts
/// that change from one test run or machine to the next ([`mock_key`]), so that the mock's
/// noise differs between runs and campaigns but repeats for the same run: a test's verdict on
/// the mock is the same every time and on every machine, never a coin that fails one run in
/// forty.
fn mock_rng(req: &RunRequest) -> crate::util::SplitMix64 {
    let key = mock_key(&req.json_path);
    crate::util::SplitMix64(
        key.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)),
    )
}

/// `path` from just below its last temporary folder (`.tmp...`, as `tempfile` names them),
/// without the machine's fingerprint (a folder of 12 hex digits): `aa/baseline/ci_r6/json/x.json`
/// for `/tmp/.tmpAbC123/aa/baseline/0123456789ab/ci_r6/json/x.json`.
fn mock_key(path: &Path) -> String {
    let parts: Vec<String> = path.components().map(|c| c.as_os_str().to_string_lossy().into_owned()).collect();
    let start = parts.iter().rposition(|p| p.starts_with(".tmp")).map_or(0, |i| i + 1);
    let fingerprint = |p: &str| p.len() == 12 && p.bytes().all(|b| b.is_ascii_hexdigit());
    parts[start..].iter().filter(|p| !fingerprint(p)).collect::<PathBuf>().display().to_string()
}

/// A standard normal variate (Box-Muller).
fn mock_normal(rng: &mut crate::util::SplitMix64) -> f64 {
    let u = |r: &mut crate::util::SplitMix64| ((r.next_u64() >> 11) as f64 + 0.5) / (1u64 << 53) as f64;
    let (a, b) = (u(rng), u(rng));
    (-2.0 * a.ln()).sqrt() * (2.0 * std::f64::consts::PI * b).cos()
}

/// The mock's workers' CPU time (all of the wall, or half for one worker when `low_cpu`),
/// its work counters (the serial traffic of the model, AE's copies, DD's faces, colour's
/// binning and atomic's additions on top, split evenly; independent of the host and of an injected slowdown), and for a paired
/// spec its blocks: the one-thread time, and the `T`-thread time at an efficiency of 0.9
/// times a process effect (`spread`, in logs) times block noise (1 %), slowed by an injected
/// slowdown `F` to `1 / (1 - F)`.
fn mock_noise_work_paired(
    req: &RunRequest,
    s: &mut Summary,
    low_cpu: bool,
    spread: f64,
) -> (Option<NoiseReport>, Option<PairedReport>) {
    let spec = &req.spec;
    let t = spec.threads;
    let share = |w: usize| if low_cpu && w + 1 == t { 0.5 } else { 0.99 };
    let wall_s = s.figures.timing.wall_s;
    let workers = (0..t)
        .map(|w| WorkerUsage { cpu_s: share(w) * wall_s, cpu_share: share(w), ..WorkerUsage::default() })
        .collect();
    let noise = Some(NoiseReport::new(wall_s, workers, MIN_CPU_SHARE));
    let serial = (s.figures.size.particles as u64) * s.figures.progress.steps * 1000;
    let extra = match spec.strategy {
        Strategy::Serial => 0,
        Strategy::ArrayExpansion => serial / 10 * t as u64,
        Strategy::DomainDecomposition | Strategy::DdBalanced => serial / 20,
        Strategy::Colour => serial / 50,
        Strategy::Atomic => serial / 2,
    };
    let per = (serial + extra) / t as u64;
    let bytes: std::collections::BTreeMap<Substage, Vec<u64>> =
        [(Substage::Scatter, 0.4), (Substage::Assembly, 0.1), (Substage::StressUpdate, 0.5)]
            .into_iter()
            .map(|(k, f)| (k, vec![(per as f64 * f) as u64; t]))
            .collect();
    let worker_bytes: Vec<u64> = (0..t).map(|w| bytes.values().map(|v| v[w]).sum()).collect();
    let max = worker_bytes.iter().copied().max().unwrap_or(1).max(1);
    s.figures.work = Some(WorkReport {
        workers: Vec::new(),
        bytes,
        serial_bytes: serial,
        balance: 1.0,
        overhead: 1.0 - serial as f64 / worker_bytes.iter().sum::<u64>() as f64,
        efficiency_bound: serial as f64 / (t as f64 * max as f64),
        worker_bytes,
    });
    let inject = spec.inject_slowdown.unwrap_or(0.0);
    s.inject_slowdown = spec.inject_slowdown;
    if inject > 0.0 && t > 1 {
        s.figures.injected_s = Some(inject * wall_s);
    }
    // The step slowdown slows both solvers of a paired run alike (already in the mock's
    // T-thread step).
    let step = spec.inject_step_slowdown.unwrap_or(0.0);
    s.inject_step_slowdown = spec.inject_step_slowdown;
    if step > 0.0 {
        s.figures.injected_step_s = Some(step * wall_s);
    }
    let Some(p) = spec.paired else { return (noise, None) };
    let warmup = spec.budget.warmup.unwrap_or(0);
    let Ok(block_steps) = spec.paired_block_steps(warmup) else { return (noise, None) };
    let mut rng = mock_rng(req);
    // The one-thread time: the mock's T-thread step (slowed by the injection) at 0.9; the
    // step slowdown stays in both.
    let t1 = s.figures.timing.steady_s_per_step.unwrap_or(1e-3) * (1.0 - inject) * t as f64 * 0.9;
    let effect = (spread * mock_normal(&mut rng)).exp();
    let (mut t1s, mut tts) = (Vec::new(), Vec::new());
    for _ in 0..p.blocks {
        t1s.push(t1 * (0.01 * mock_normal(&mut rng)).exp());
        let e = 0.9 * effect * (0.01 * mock_normal(&mut rng)).exp();
        tts.push(t1 / (t as f64 * e) / (1.0 - inject));
    }
    let eff: Vec<f64> = t1s.iter().zip(&tts).map(|(a, b)| a / (t as f64 * b)).collect();
    s.figures.timing.steady_s_per_step = Some(crate::util::median(&tts));
    let paired = Some(PairedReport {
        reference_threads: 1,
        blocks: p.blocks,
        block_steps,
        reference_cpus: s.pinning.requested_cpus.first().copied().into_iter().collect(),
        efficiency: PairedReport::geometric_mean(&eff),
        block_efficiency: eff,
        reference_first: (0..p.blocks).map(|b| b % 2 == 0).collect(),
        t1_s_per_step: t1s,
        tt_s_per_step: tts,
        reference_steady_substages: s.figures.timing.steady_substages.clone(),
        ..PairedReport::default()
    });
    (noise, paired)
}

/// A plausible summary of `req`: times from the model size, strategy, threads and
/// optimisation level; the CPUs as given.
fn mock_summary(req: &RunRequest, requested: Vec<usize>, observed: Vec<usize>) -> Summary {
    let s = &req.spec;
    let size = s.scenario.size();
    let steps = s.budget.steps.unwrap_or(100);
    let warmup = s.budget.warmup.unwrap_or(0).min(steps);
    let speed = match s.strategy {
        Strategy::Colour => 0.95,
        Strategy::DomainDecomposition | Strategy::DdBalanced => 0.9,
        Strategy::Serial | Strategy::ArrayExpansion => 0.8,
        Strategy::Atomic => 0.6,
    } * (s.total_workers().min(2) as f64);
    // An injected slowdown F slows every run of more than one worker to 1 / (1 - F); the
    // step slowdown every run.
    let inject = if s.total_workers() > 1 { s.inject_slowdown.unwrap_or(0.0) } else { 0.0 };
    let per_step = size.particles as f64 * 50e-9 * if req.planned.opt == OptLevel::O0 { 8.0 } else { 1.0 }
        / speed
        / (1.0 - inject)
        / (1.0 - s.inject_step_slowdown.unwrap_or(0.0));
    let wall = per_step * steps as f64;
    let steady = per_step * (steps - warmup) as f64;
    Summary {
        spec: Some(s.clone()),
        model: s.scenario.model(),
        strategy: s.strategy,
        threads: s.threads,
        opt_level: req.planned.opt,
        grid_mode: s.grid,
        pinning: Pinning { requested_cpus: requested, observed_cpus: observed, ..Pinning::default() },
        figures: Figures {
            size: Size {
                particles: size.particles as usize,
                cells: (size.nodes / 2) as usize,
                nodes: size.nodes as usize,
                mean_nodes: size.nodes as f64,
                ..Size::default()
            },
            progress: Progress {
                steps,
                warmup_steps: warmup,
                steady_steps: steps - warmup,
                dt_first: 1e-8,
                sim_time: steps as f64 * 1e-8,
                end_reason: EndReason::StepLimit,
                ..Progress::default()
            },
            timing: Timing {
                wall_s: wall,
                grid_stage_s: wall * 0.45,
                particle_stage_s: wall * 0.55,
                substages: mock_split(wall),
                steady_wall_s: steady,
                steady_grid_stage_s: Some(steady * 0.45),
                steady_particle_stage_s: Some(steady * 0.55),
                steady_substages: mock_split(steady),
                ns_per_particle_step: Some(per_step * 1e9 / size.particles as f64),
                particle_steps_per_s: Some(size.particles as f64 / per_step),
                steady_s_per_step: Some(per_step),
                ..Timing::default()
            },
            memory: Memory { peak_rss_bytes: Some(size.memory_bytes(s.strategy, s.threads)), ..Memory::default() },
            physics: Physics {
                kinetic_energy_initial: 1000.0,
                kinetic_energy: 900.0,
                internal_energy: 99.0,
                ..Physics::default()
            },
            scenario: mock_scenario(s),
            ..Figures::default()
        },
        ..Summary::default()
    }
}

/// `total` seconds split over the sub-stages as the mock's steps spend them.
fn mock_split(total: f64) -> StageSeconds {
    StageSeconds(
        [
            (Substage::Scatter, 0.3),
            (Substage::Assembly, 0.1),
            (Substage::GridUpdate, 0.05),
            (Substage::Gather, 0.2),
            (Substage::StressUpdate, 0.35),
        ]
        .into_iter()
        .map(|(k, f)| (k, total * f))
        .collect(),
    )
}

/// The mock's scenario figures: a Taylor bar that shortened a little; the others empty.
fn mock_scenario(s: &RunSpec) -> ScenarioFigures {
    match ScenarioFigures::empty(s.scenario.kind()) {
        ScenarioFigures::Taylor(_) => ScenarioFigures::Taylor(TaylorFigures {
            initial_length_m: Some(0.0254),
            final_length_m: Some(0.0253),
            face_diameter_m: Some(0.0077),
            ..TaylorFigures::default()
        }),
        other => other,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::placement::PinPolicy;
    use mpm_spec::scenario::TaylorSpec;
    use mpm_spec::Scenario;

    /// The mock's noise is keyed by the run's place in its campaign, not by where a test's
    /// temporary folder is or which machine ran it; different campaigns and runs differ.
    #[test]
    fn the_mocks_noise_repeats_for_the_same_run_anywhere() {
        let k = |p: &str| mock_key(Path::new(p));
        assert_eq!(k("/tmp/.tmpAbC123/aa/baseline/0123456789ab/ci_r6/json/x.json"), "aa/baseline/ci_r6/json/x.json");
        assert_eq!(
            k("/var/tmp/.tmpZz9/aa/baseline/fedcba987654/ci_r6/json/x.json"),
            k("/tmp/.tmpAbC123/aa/baseline/0123456789ab/ci_r6/json/x.json")
        );
        assert_ne!(k("/t/.tmp1/aa/baseline/ci_r6/json/x.json"), k("/t/.tmp1/aa/candidate/ci_r6/json/x.json"));
        assert_ne!(k("/t/.tmp1/c/json/x-r0.json"), k("/t/.tmp1/c/json/x-r1.json"));
        assert_eq!(k("/results/m/ci/json/x.json"), "/results/m/ci/json/x.json");
    }

    /// The solver gets one argument, the spec file; the spec holds the run's CPUs and its
    /// summary's path. Several ranks: the launcher's words, then the binary and the same.
    #[test]
    fn the_request_is_a_spec_file() {
        let mut spec = RunSpec::new(Scenario::Taylor(TaylorSpec::model(2))).unwrap();
        spec.strategy = Strategy::DomainDecomposition;
        spec.threads = 2;
        spec.budget.steps = Some(5);
        let planned = PlannedRun { spec, model: 2, opt: OptLevel::O3, pin: PinPolicy::CLOSE, launcher: None, rep: 0 };
        let mut req = RunRequest::new(&planned, Some(vec![0, 1]), "x.json".into(), "x.toml".into());
        req.binary = "mpm".into();
        assert_eq!(req.args().join(" "), "run --spec x.toml");
        assert_eq!(req.command_line(), ("mpm".to_string(), req.args()));
        assert_eq!(req.spec.cpus, Some(vec![0, 1]));
        assert_eq!(req.spec.outputs.json, Some(PathBuf::from("x.json")));
        assert!(req.spec.outputs.quiet);
        assert_eq!(RunSpec { cpus: None, ..req.spec.clone() }.key(), planned.spec.key(), "the planned computation");
        let launcher = crate::campaign::exec::launcher::Launcher::parse("mpirun --bind-to none -n {ranks}").unwrap();
        let hybrid = RunRequest { launcher: Some(launcher.expand(2, 2)), mask: Some(vec![0, 1, 2, 3]), ..req };
        let (program, args) = hybrid.command_line();
        assert_eq!(program, "mpirun");
        assert_eq!(args.join(" "), "--bind-to none -n 2 mpm run --spec x.toml");
    }
}
