//! Checkpoints through the real binary: a run killed with SIGKILL at a seeded step (the
//! seed printed, fixed unless `MPM_KILL_SEED` says otherwise) and
//! continued with `mpm resume` ends bit for bit as the run that was never interrupted (its
//! final particle state byte for byte, its summary equal in everything but what a clock or
//! the process measures), serially, with DD on 2 threads and over 2 MPI ranks; a truncated
//! or corrupted newest checkpoint is found and the older one offered and used; and every
//! refusal (no checkpoint folder, another binary, another spec, a used folder, another rank
//! count) says what to do, exits non-zero and changes nothing. SIGTERM or SIGUSR1 at a seeded
//! step (serially, on 2 threads, to the launcher of 2 ranks) writes a last checkpoint, exits
//! 75, and `mpm resume` ends bit for bit too.

use serde_json::Value;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output};
use std::time::{Duration, Instant};

const MPM: &str = env!("CARGO_BIN_EXE_mpm");

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn ok(out: Output, what: &str) -> Output {
    assert!(out.status.success(), "{what} failed\nstdout:\n{}\nstderr:\n{}", text(&out.stdout), text(&out.stderr));
    out
}

fn mpm(args: &[&str]) -> Output {
    Command::new(MPM).args(args).output().expect("cannot start the mpm binary")
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// Keys of a summary measured by a clock or of the process (its memory, its command line,
/// the checkpoints it wrote), not of the run's state.
const PROCESS_KEYS: [&str; 27] = [
    "wall_s",
    "noise",
    "output_s",
    "grid_stage_s",
    "particle_stage_s",
    "substages",
    "steady_wall_s",
    "steady_grid_stage_s",
    "steady_particle_stage_s",
    "steady_substages",
    "roofline",
    "steady_s_per_step",
    "ns_per_particle_step",
    "particle_steps_per_s",
    "worker_busy_s",
    "load_imbalance",
    "peak_rss_bytes",
    "peak_rss_sum_bytes",
    "rank_busy_imbalance",
    "comm_s_per_step",
    "comm_frac",
    "wait_s_per_step",
    "wait_frac",
    "model_memory_bytes",
    "started_unix_s",
    "command_line",
    "checkpoint",
];

/// A summary without [`PROCESS_KEYS`], the spec's outputs and, per rank, its clocks and
/// memory.
fn comparable(path: &Path) -> Value {
    let mut v: Value = serde_json::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    let m = v.as_object_mut().unwrap();
    for k in PROCESS_KEYS {
        m.remove(k);
    }
    m["spec"].as_object_mut().unwrap().remove("outputs");
    if let Some(ranks) = m.get_mut("ranks").and_then(Value::as_array_mut) {
        for r in ranks {
            let r = r.as_object_mut().unwrap();
            r.remove("busy_s");
            r.remove("peak_rss_bytes");
            let ex = r["exchange"].as_object_mut().unwrap();
            ex.remove("seconds");
            ex.remove("wait_seconds");
        }
    }
    v
}

/// Every file under `dir` with its bytes: what "nothing changed" compares (the folder's
/// lock file, which names its last holder, aside).
fn contents(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let mut out = BTreeMap::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap() {
            let p = e.unwrap().path();
            if p.ends_with(".lock") {
                continue;
            }
            if p.is_dir() {
                stack.push(p.clone());
                out.insert(p, Vec::new());
            } else {
                out.insert(p.clone(), std::fs::read(&p).unwrap());
            }
        }
    }
    out
}

/// Steps of the complete checkpoints in `ck`, oldest first.
fn checkpoint_steps(ck: &Path) -> Vec<u64> {
    let mut steps: Vec<u64> = std::fs::read_dir(ck)
        .map(|rd| {
            rd.flatten()
                .filter_map(|e| e.file_name().to_string_lossy().strip_prefix("step-").and_then(|s| s.parse().ok()))
                .collect()
        })
        .unwrap_or_default();
    steps.sort_unstable();
    steps
}

/// What chooses the kill point: unset, a fixed seed; a number, that seed (to replay a
/// failure); `random`, a seed drawn from the OS.
const SEED_VAR: &str = "MPM_KILL_SEED";

/// The kill point's seed, by [`SEED_VAR`] (fixed by default), printed so that a failing
/// kill can be replayed.
fn seed() -> u64 {
    use std::hash::BuildHasher;
    let s = match std::env::var(SEED_VAR).as_deref() {
        Err(_) | Ok("") => 0x5eed_0041,
        Ok("random") => std::hash::RandomState::new().hash_one(std::process::id()),
        Ok(n) => n.parse().unwrap_or_else(|_| panic!("{SEED_VAR}={n}: give a number, or `random`")),
    };
    println!("kill seed {s} (replay: {SEED_VAR}={s}; {SEED_VAR}=random draws one)");
    s
}

/// The `i`-th number drawn from `seed` (SplitMix64: every bit of the seed moves them all).
fn draw(seed: u64, i: u64) -> u64 {
    let mut z = seed.wrapping_add(0x9e37_79b9_7f4a_7c15_u64.wrapping_mul(i + 1));
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Wait until `ck` holds a checkpoint of step `target` or later, wait `extra` more (the kill
/// then lands in a step or in the next checkpoint's writing), and kill `child` with
/// SIGKILL (with `group`, a launcher: its ranks too). Returns the newest checkpoint step then.
fn kill_after(child: &mut Child, ck: &Path, target: u64, extra: Duration, group: bool) -> u64 {
    wait_for_checkpoint(child, ck, target, extra);
    if group {
        // The launcher's ranks run in process groups of their own: each is killed by its id,
        // like the launcher (a node going down), none left to finish the run.
        let mut pids = children(child.id());
        pids.push(child.id());
        let pids: Vec<String> = pids.iter().map(u32::to_string).collect();
        let mut args = vec!["-KILL", "--"];
        args.extend(pids.iter().map(String::as_str));
        ok(Command::new("kill").args(&args).output().unwrap(), "kill the launcher and its ranks");
    } else {
        child.kill().unwrap();
    }
    let status = child.wait().unwrap();
    use std::os::unix::process::ExitStatusExt;
    assert_eq!(status.signal(), Some(9), "the run was to die of SIGKILL, it ended {status}: make it longer");
    *checkpoint_steps(ck).last().unwrap()
}

/// Wait until `ck` holds a checkpoint of step `target` or later (`child` still running),
/// then `extra` more.
fn wait_for_checkpoint(child: &mut Child, ck: &Path, target: u64, extra: Duration) {
    let start = Instant::now();
    while checkpoint_steps(ck).last().is_none_or(|&s| s < target) {
        if let Some(status) = child.try_wait().unwrap() {
            panic!("the run ended ({status}) before its checkpoint of step {target}: make it longer");
        }
        assert!(start.elapsed() < Duration::from_secs(120), "no checkpoint of step {target} after 2 minutes");
        std::thread::sleep(Duration::from_millis(2));
    }
    std::thread::sleep(extra);
}

/// The processes whose parent is `pid` (from `/proc/<pid>/stat`).
fn children(pid: u32) -> Vec<u32> {
    std::fs::read_dir("/proc")
        .unwrap()
        .flatten()
        .filter_map(|e| e.file_name().to_str().and_then(|n| n.parse::<u32>().ok()))
        .filter(|p| {
            let stat = std::fs::read_to_string(format!("/proc/{p}/stat")).unwrap_or_default();
            let after = stat.rsplit_once(')').map_or("", |(_, rest)| rest);
            after.split_whitespace().nth(1).and_then(|pp| pp.parse::<u32>().ok()) == Some(pid)
        })
        .collect()
}

/// `launcher` (empty: none) + `mpm run <args> --dump-state --json` into `dir/<name>.*`.
fn uninterrupted(dir: &Path, name: &str, launcher: &[&str], args: &[&str]) -> (PathBuf, PathBuf) {
    let (state, json) = (dir.join(format!("{name}.bin")), dir.join(format!("{name}.json")));
    let mut all: Vec<&str> = launcher.to_vec();
    all.extend([MPM, "run"]);
    all.extend(args);
    all.extend(["--quiet", "--dump-state", path(&state), "--json", path(&json)]);
    ok(Command::new(all[0]).args(&all[1..]).output().unwrap(), &format!("{all:?}"));
    (state, json)
}

/// A run cut short, started: its folder, the uninterrupted run's state and summary, the
/// checkpoint step after which to cut it and the wait after that (drawn from [`seed`]: a step
/// in 1..=8 intervals, up to 40 ms), the process, and its state, summary and checkpoint
/// folder.
struct Cut {
    _dir: tempfile::TempDir,
    want: (PathBuf, PathBuf),
    target: u64,
    extra: Duration,
    child: Child,
    paths: [PathBuf; 3],
}

/// `launcher` + `mpm run <args>` uninterrupted, then again checkpointing every `every` steps
/// (its standard error piped), to be cut.
fn cut_run(launcher: &[&str], args: &[&str], every: u64) -> Cut {
    let dir = tempfile::tempdir().unwrap();
    let want = uninterrupted(dir.path(), "whole", launcher, args);
    let s = seed();
    let target = every * (1 + draw(s, 0) % 8);
    let extra = Duration::from_millis(draw(s, 1) % 40);
    let (state, json, ck) = (dir.path().join("cut.bin"), dir.path().join("cut.json"), dir.path().join("ck"));
    let mut all: Vec<&str> = launcher.to_vec();
    all.extend([MPM, "run"]);
    all.extend(args);
    let every_s = every.to_string();
    all.extend(["--quiet", "--dump-state", path(&state), "--json", path(&json)]);
    all.extend(["--checkpoint-dir", path(&ck), "--checkpoint-every", &every_s]);
    let mut cmd = Command::new(all[0]);
    cmd.args(&all[1..]).stdout(std::process::Stdio::null()).stderr(std::process::Stdio::piped());
    let child = cmd.spawn().unwrap();
    Cut { _dir: dir, want, target, extra, child, paths: [state, json, ck] }
}

/// `launcher` + `mpm resume ck --json json`: its final state and summary must be the
/// uninterrupted run's (`want`: its state and summary). Returns the summary.
fn resumed_is_bitwise(launcher: &[&str], [state, json, ck]: &[PathBuf; 3], want: &(PathBuf, PathBuf)) -> Value {
    assert!(!json.exists() && !state.exists(), "a run cut short writes no summary and no state");
    let mut resume: Vec<&str> = launcher.to_vec();
    resume.extend([MPM, "resume", path(ck), "--json", path(json)]);
    ok(Command::new(resume[0]).args(&resume[1..]).output().unwrap(), "mpm resume");
    assert!(std::fs::read(state).unwrap() == std::fs::read(&want.0).unwrap(), "final particle states differ");
    assert_eq!(comparable(json), comparable(&want.1), "summaries differ");
    serde_json::from_str(&std::fs::read_to_string(json).unwrap()).unwrap()
}

/// The run of `args` killed after a checkpoint the seed chooses ([`seed`]: every `every`
/// steps, the kill between the checkpoint of a step in 1..=8 intervals and up to 40 ms
/// later), then continued with `mpm resume`: its final state and summary must be those of
/// the run never interrupted.
fn killed_and_resumed_is_bitwise(launcher: &[&str], args: &[&str], every: u64) {
    let Cut { _dir: _keep, want, target, extra, mut child, paths } = cut_run(launcher, args, every);
    let group = !launcher.is_empty();
    let newest = kill_after(&mut child, &paths[2], target, extra, group);
    println!("killed after the checkpoint of step {newest} (target {target}, {extra:?} later)");
    let v = resumed_is_bitwise(launcher, &paths, &want);
    let report = &v["checkpoint"];
    assert_eq!(report["restarts"], 1, "{report}");
    assert!(report["restart_steps"][0].as_u64().unwrap() >= target, "{report}");
    assert!(report["written"].as_u64().unwrap() >= 1 && report["last_bytes"].as_u64().unwrap() > 0, "{report}");
    assert!(report["restart_setup_s"].as_f64().unwrap() > 0.0, "{report}");
}

/// The run of `args` sent `signal` (`TERM`, `USR1`) after a checkpoint the seed chooses (as
/// [`killed_and_resumed_is_bitwise`]): it writes a last checkpoint of the step it is in and
/// exits 75 saying so; `mpm resume` then ends as the run never interrupted.
fn signalled_and_resumed_is_bitwise(launcher: &[&str], args: &[&str], every: u64, signal: &str) {
    let Cut { _dir: _keep, want, target, extra, mut child, paths } = cut_run(launcher, args, every);
    wait_for_checkpoint(&mut child, &paths[2], target, extra);
    let sent = Command::new("kill").args([&format!("-{signal}"), &child.id().to_string()]).status().unwrap();
    assert!(sent.success(), "kill -{signal} failed");
    let out = child.wait_with_output().unwrap();
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(75), "SIG{signal}: the run should stop after a last checkpoint:\n{err}");
    let newest = *checkpoint_steps(&paths[2]).last().unwrap();
    println!("SIG{signal} after the checkpoint of step {target} ({extra:?} later): last checkpoint of step {newest}");
    let said = format!("stopped at step {newest} on SIGTERM or SIGUSR1 after writing its last checkpoint");
    assert!(err.contains(&said) && err.contains("mpm resume"), "{err}");
    let v = resumed_is_bitwise(launcher, &paths, &want);
    assert_eq!(v["checkpoint"]["restart_steps"][0].as_u64(), Some(newest), "{}", v["checkpoint"]);
}

/// Taylor Model 1, 160 steps: about 1.5 s at o3.
const SERIAL: [&str; 5] = ["taylor", "--model", "1", "--steps", "160"];

#[test]
fn a_serial_run_killed_at_a_seeded_step_resumes_bit_for_bit() {
    killed_and_resumed_is_bitwise(&[], &SERIAL, 5);
}

#[test]
fn a_dd_run_on_two_threads_killed_at_a_seeded_step_resumes_bit_for_bit() {
    let mut args = SERIAL.to_vec();
    args.extend(["--strategy", "dd", "--threads", "2"]);
    killed_and_resumed_is_bitwise(&[], &args, 5);
}

/// SIGTERM (a batch system's time limit) mid-run: a last checkpoint, then `mpm resume`
/// bit for bit.
#[test]
fn sigterm_mid_run_writes_a_last_checkpoint_and_resumes_bit_for_bit() {
    signalled_and_resumed_is_bitwise(&[], &SERIAL, 5, "TERM");
}

/// SIGUSR1 (`sbatch --signal=USR1@120`) to DD on 2 threads: the same.
#[test]
fn sigusr1_mid_run_writes_a_last_checkpoint_and_resumes_bit_for_bit() {
    let mut args = SERIAL.to_vec();
    args.extend(["--strategy", "dd", "--threads", "2"]);
    signalled_and_resumed_is_bitwise(&[], &args, 5, "USR1");
}

/// Block colouring on three threads: its block lists are rebuilt every step, so nothing of
/// the strategy needs saving.
#[test]
fn a_colour_run_on_three_threads_killed_at_a_random_step_resumes_bit_for_bit() {
    let mut args = SERIAL.to_vec();
    args.extend(["--strategy", "colour", "--threads", "3"]);
    killed_and_resumed_is_bitwise(&[], &args, 5);
}

/// The coarse impact on the sparse grid with balanced cuts: the cloud history, the layout
/// chooser and the sparse blocks cross the restart.
#[test]
fn an_impact_killed_at_a_seeded_step_resumes_bit_for_bit() {
    let args = [
        "impact",
        "--spacing",
        "2.12e-3",
        "--cell",
        "4.24e-3",
        "--steps",
        "120",
        "--strategy",
        "dd-balanced",
        "--threads",
        "2",
    ];
    killed_and_resumed_is_bitwise(&[], &args, 4);
}

/// The MPI launcher of the tests (as root, more ranks than cores allowed).
#[cfg(feature = "mpi")]
const MPIRUN: [&str; 5] = ["mpirun", "--oversubscribe", "--allow-run-as-root", "-n", "2"];

/// Over two ranks (the coarse impact: particles move between ranks), each rank writing its
/// part; and a checkpoint of two ranks is refused to one process.
#[cfg(feature = "mpi")]
#[test]
fn a_run_over_two_ranks_killed_at_a_seeded_step_resumes_bit_for_bit() {
    let args = ["impact", "--spacing", "2.12e-3", "--cell", "4.24e-3", "--steps", "90", "--strategy", "dd"];
    killed_and_resumed_is_bitwise(&MPIRUN, &args, 4);
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("ck");
    let mut all: Vec<&str> = MPIRUN.to_vec();
    all.extend([MPM, "run", "taylor", "--model", "1", "--steps", "12", "--quiet", "--checkpoint-dir", path(&ck)]);
    all.extend(["--checkpoint-every", "5"]);
    ok(Command::new(all[0]).args(&all[1..]).output().unwrap(), "a run over 2 ranks");
    let names: Vec<String> = std::fs::read_dir(ck.join("step-0000000010"))
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names.len(), 2, "one file per rank: {names:?}");
    let before = contents(&ck);
    let json = dir.path().join("x.json");
    refused(&["resume", path(&ck), "--json", path(&json)], "mpirun -n 2 mpm resume", &ck, &before, &json);
}

/// SIGUSR1 to the launcher, which passes it to both ranks: they agree on the step of their
/// last checkpoint, and `mpirun -n 2 mpm resume` ends bit for bit.
#[cfg(feature = "mpi")]
#[test]
fn sigusr1_to_the_launcher_of_two_ranks_writes_a_last_checkpoint_and_resumes_bit_for_bit() {
    let args = ["impact", "--spacing", "2.12e-3", "--cell", "4.24e-3", "--steps", "90", "--strategy", "dd"];
    signalled_and_resumed_is_bitwise(&MPIRUN, &args, 4, "USR1");
}

/// `mpm <args>` exits 1 with `message` in its error, and nothing under `dir` changed, and
/// `json` was not written.
fn refused(args: &[&str], message: &str, dir: &Path, before: &BTreeMap<PathBuf, Vec<u8>>, json: &Path) {
    let out = mpm(args);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "mpm {args:?} should be refused: {err}");
    assert!(err.contains(message), "mpm {args:?}: the error should say {message:?}:\n{err}");
    if dir.exists() {
        assert!(contents(dir) == *before, "mpm {args:?} changed {}", dir.display());
    }
    assert!(!json.exists(), "mpm {args:?} wrote {}", json.display());
}

/// A completed run of Model 1 whose checkpoints (steps 20 and 30 of 40) are left in `ck`,
/// and the uninterrupted run's summary and state.
fn completed_with_checkpoints(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let (state, json) = uninterrupted(dir, "whole", &[], &["taylor", "--model", "1", "--steps", "40"]);
    let ck = dir.join("ck");
    let args = ["run", "taylor", "--model", "1", "--steps", "40", "--quiet", "--checkpoint-dir", path(&ck)];
    let mut all = args.to_vec();
    let cut = dir.join("cut.bin");
    all.extend(["--checkpoint-every", "10", "--dump-state", path(&cut)]);
    ok(mpm(&all), "the run with checkpoints");
    assert_eq!(checkpoint_steps(&ck), [20, 30], "the last two kept, none of the final state");
    std::fs::remove_file(&cut).unwrap();
    (ck, state, json)
}

/// A truncated or corrupted newest checkpoint is refused, naming the damage and offering
/// the older one; `--older` continues from it (bit for bit) and keeps the damaged one.
#[test]
fn a_damaged_newest_checkpoint_is_refused_and_the_older_one_used() {
    let dir = tempfile::tempdir().unwrap();
    let (ck, want_state, want_json) = completed_with_checkpoints(dir.path());
    let newest = ck.join("step-0000000030/rank-0000.ckpt");
    let good = std::fs::read(&newest).unwrap();
    let json = dir.path().join("c.json");
    // Corrupted: one bit of a particle's stress.
    let mut bad = good.clone();
    let at = good.len() - 32 - 56056 * 40;
    bad[at] ^= 0x04;
    std::fs::write(&newest, &bad).unwrap();
    let before = contents(&ck);
    let cmd = ["resume", path(&ck), "--json", path(&json)];
    refused(&cmd, "is corrupted: its SHA-256 checksum does not match", &ck, &before, &json);
    refused(&cmd, "the older checkpoint", &ck, &before, &json);
    refused(&cmd, "--older", &ck, &before, &json);
    // Truncated: the last half lost.
    std::fs::write(&newest, &good[..good.len() / 2]).unwrap();
    let before = contents(&ck);
    refused(&cmd, "is truncated", &ck, &before, &json);
    refused(&cmd, "step 20) is intact", &ck, &before, &json);
    // --older: continued from step 20, to the uninterrupted run's end.
    let out = ok(mpm(&["resume", path(&ck), "--older", "--json", path(&json)]), "mpm resume --older");
    assert!(text(&out.stderr).contains("damaged-step-0000000030"), "{}", text(&out.stderr));
    let state = dir.path().join("cut.bin");
    assert!(std::fs::read(&state).unwrap() == std::fs::read(&want_state).unwrap(), "final states differ");
    assert_eq!(comparable(&json), comparable(&want_json));
    let kept = std::fs::read(ck.join("damaged-step-0000000030/rank-0000.ckpt")).unwrap();
    assert!(kept == good[..good.len() / 2], "the damaged checkpoint is kept as it was");
    assert_eq!(checkpoint_steps(&ck), [20, 30], "the continued run wrote its checkpoint of step 30 again");
    // --older with an intact newest checkpoint: refused.
    let before = contents(&ck);
    std::fs::remove_file(&json).unwrap();
    refused(&["resume", path(&ck), "--older", "--json", path(&json)], "is intact", &ck, &before, &json);
}

/// Every refusal of a checkpoint: exit 1, a message saying what to do, nothing changed.
#[test]
fn checkpoints_that_cannot_continue_the_run_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (ck, _, _) = completed_with_checkpoints(dir.path());
    let json = dir.path().join("c.json");
    let before = contents(&ck);
    let resume = |d: &Path| vec!["resume".to_string(), d.display().to_string(), "--json".into(), path(&json).into()];
    let refuse = |args: Vec<String>, message: &str, d: &Path| {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let before = if d.exists() { contents(d) } else { BTreeMap::new() };
        refused(&args, message, d, &before, &json);
    };
    // Not a checkpoint folder: missing, empty, other files, a file, an unfinished checkpoint.
    let other = dir.path().join("other");
    refuse(resume(&other), "does not exist", &other);
    std::fs::create_dir(&other).unwrap();
    refuse(resume(&other), "is not a checkpoint folder of mpm", &other);
    std::fs::write(other.join("notes.txt"), "hello").unwrap();
    std::fs::create_dir(other.join("step-12")).unwrap();
    refuse(resume(&other), "is not a checkpoint folder of mpm", &other);
    refuse(resume(&other.join("notes.txt")), "is a file", &other);
    std::fs::create_dir(other.join(".step-0000000005.partial")).unwrap();
    refuse(resume(&other), "only one whose writing was interrupted", &other);
    // A checkpoint file that is not one.
    let fake = dir.path().join("fake");
    std::fs::create_dir_all(fake.join("step-0000000010")).unwrap();
    std::fs::write(fake.join("step-0000000010/rank-0000.ckpt"), "{\"particles\": []}").unwrap();
    refuse(resume(&fake), "is not an mpm checkpoint file", &fake);
    // Another binary: this one with a byte appended (it runs the same, its hash differs).
    let copy = dir.path().join("mpm-other");
    let mut bin = std::fs::read(MPM).unwrap();
    bin.push(0);
    std::fs::write(&copy, bin).unwrap();
    use std::os::unix::fs::PermissionsExt;
    std::fs::set_permissions(&copy, std::fs::Permissions::from_mode(0o755)).unwrap();
    let out = Command::new(&copy).args(["resume", path(&ck), "--json", path(&json)]).output().unwrap();
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(
        err.contains("written by another mpm binary") && err.contains("Resume with the binary that wrote it"),
        "{err}"
    );
    assert!(contents(&ck) == before && !json.exists());
    // Another spec than --spec FILE.
    let spec = dir.path().join("other.toml");
    let printed = ok(mpm(&["run", "taylor", "--model", "1", "--steps", "41", "--print-spec"]), "--print-spec");
    std::fs::write(&spec, &printed.stdout).unwrap();
    let mut args = resume(&ck);
    args.extend(["--spec".into(), path(&spec).into()]);
    refuse(args, "is of another run than", &ck);
    let mut args = resume(&ck);
    args.extend(["--spec".into(), path(&spec).into()]);
    refuse(args, "they differ in budget.steps", &ck);
    // A new run into a folder with checkpoints: of this run, and of another.
    let run = |steps: &str| {
        ["run", "taylor", "--model", "1", "--steps", steps, "--checkpoint-dir", path(&ck), "--json", path(&json)]
            .map(String::from)
            .to_vec()
    };
    refuse(
        run("40"),
        "already holds checkpoints of this run (the newest at step 30): continue it with `mpm resume",
        &ck,
    );
    refuse(run("41"), "holds checkpoints of another run", &ck);
    // The same run's spec with other outputs continues.
    let same = dir.path().join("same.toml");
    let printed = ok(mpm(&["run", "taylor", "--model", "1", "--steps", "40", "--print-spec"]), "--print-spec");
    std::fs::write(&same, &printed.stdout).unwrap();
    ok(mpm(&["resume", path(&ck), "--spec", path(&same), "--json", path(&json)]), "resume --spec of the same run");
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!((v["steps"].as_u64(), v["checkpoint"]["restart_steps"][0].as_u64()), (Some(40), Some(30)));
}

/// Another thread count and strategy after the restart: the same physics to round-off.
#[test]
fn a_run_continued_on_another_strategy_agrees_to_round_off() {
    let dir = tempfile::tempdir().unwrap();
    let (ck, _, want_json) = completed_with_checkpoints(dir.path());
    let json = dir.path().join("c.json");
    let out = ok(
        mpm(&["resume", path(&ck), "--strategy", "ae", "--threads", "2", "--json", path(&json)]),
        "resume on another strategy",
    );
    assert!(text(&out.stderr).contains("not bit for bit"), "{}", text(&out.stderr));
    let (a, b) = (comparable(&want_json), comparable(&json));
    assert_eq!(b["strategy"], "ae");
    assert_eq!(b["steps"], a["steps"]);
    for k in ["kinetic_energy", "internal_energy", "final_length_m", "face_diameter_m", "sim_time"] {
        let (x, y) = (a[k].as_f64().unwrap(), b[k].as_f64().unwrap());
        let rel = ((x - y) / x).abs();
        println!("{k}: {rel:.1e}");
        assert!(rel < 1e-9, "{k}: {x} vs {y}");
    }
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(
        (v["warmup_steps"].as_u64(), v["steady_steps"].as_u64()),
        (Some(30), Some(10)),
        "steady state from the restart"
    );
}
