//! Bad input of `mpm`, tried as a new user would, through the real binary: negative
//! numbers read as values (not as flags), raw parse errors replaced by ones naming the
//! flag, absurd values and runs that cannot make progress refused at once (before any
//! allocation), outputs that would overwrite an input refused, and interrupts: the first
//! SIGTERM stops a run between steps, a second ends it at once.

use std::path::Path;
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant};

const MPM: &str = env!("CARGO_BIN_EXE_mpm");

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

fn path(p: &Path) -> &str {
    p.to_str().unwrap()
}

/// `mpm <args>` in `dir`: refused within a few seconds, exit status 1 or 2, with `says` in
/// its error and none of the messages the issue found unclear.
fn refused_in(dir: &Path, args: &[&str], says: &str) -> Output {
    let start = Instant::now();
    let out = Command::new(MPM).args(args).current_dir(dir).output().expect("cannot start the mpm binary");
    let err = text(&out.stderr);
    let took = start.elapsed();
    assert!(matches!(out.status.code(), Some(1 | 2)), "mpm {args:?} was not refused ({}):\n{err}", out.status);
    assert!(err.contains(says), "mpm {args:?}: the error should say {says:?}:\n{err}");
    for unclear in ["panicked", "unexpected argument", "invalid digit", "cannot parse integer", "memory allocation"] {
        assert!(!err.contains(unclear), "mpm {args:?}: {unclear:?} in\n{err}");
    }
    assert!(took < Duration::from_secs(10), "mpm {args:?} took {took:?} to be refused");
    out
}

/// [`refused_in`] a fresh folder.
fn refused(args: &[&str], says: &str) {
    let dir = tempfile::tempdir().unwrap();
    refused_in(dir.path(), args, says);
}

const TAYLOR: [&str; 6] = ["run", "taylor", "--model", "1", "--steps", "2"];

fn taylor(extra: &[&str]) -> Vec<String> {
    TAYLOR.iter().chain(extra).map(|s| s.to_string()).collect()
}

fn strs(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// Negative numbers are values: each reaches its flag's own check, which says what to give.
#[test]
fn negative_numbers_are_values_with_their_flags_message() {
    let cases: [(&[&str], &str); 8] = [
        (&["--checkpoint-dir", "ck", "--checkpoint-every", "-5"], "'-5' is negative: the interval must be positive"),
        (&["--checkpoint-dir", "ck", "--checkpoint-every=-5"], "the interval must be positive"),
        (&["--cpus=-1,0"], "'-1' in CPU list '-1,0' is not a CPU number: CPUs are numbered from 0"),
        (&["--cpus", "-1"], "'-1' in CPU list '-1' is not a CPU number"),
        (&["--rank-layout", "-1x1x1"], "is not a rank layout: give three positive counts"),
        (&["--strategy", "dd", "--threads", "2", "--paired-blocks=-1"], "-1 is negative"),
        (&["--threads", "99999999999999999999"], "threads is too many"),
        (&["--ranks", "0"], "invalid ranks (--ranks): the rank count must be at least 1"),
    ];
    for (extra, says) in cases {
        refused(&strs(&taylor(extra)), says);
    }
}

/// Values that are not numbers of the flag's form: the flag named with the form it takes,
/// never the parser's own words ("invalid digit found in string").
#[test]
fn malformed_numbers_name_the_flag_and_the_form() {
    let cases: [(&[&str], &str); 6] = [
        (
            &["run", "taylor", "--model", "abc"],
            "for '--model <1-4>': 'abc' is not a whole number: give one from 1 to 4",
        ),
        (&["run", "taylor", "--model", "9"], "9 is not in 1..=4: give a whole number from 1 to 4"),
        (
            &["run", "plate", "--particles-per-cell", "x", "--steps", "2"],
            "'x' is not a whole number: give one from 1 to 8",
        ),
        (&["run", "taylor", "--model", "1", "--steps", "1.5"], "for '--steps <N>': '1.5' is not a whole number"),
        (&["run", "taylor", "--model", "1", "--cfl", "abc"], "for '--cfl <X>': 'abc' is not a number"),
        (&["run", "taylor", "--model", "1", "--strategy", "dd", "--threads", "x2"], "'x2' is not a thread count"),
    ];
    for (args, says) in cases {
        refused(args, says);
    }
}

/// Absurd values, and runs that could not make progress, refused at once by the checks,
/// the size estimate or the step estimate: never a hang, an abort or a figure of NaN.
#[test]
fn runs_that_cannot_make_progress_are_refused_at_once() {
    let cases: [(&[&str], &str); 12] = [
        (
            &["run", "taylor", "--model", "1", "--strategy", "dd", "--threads", "2", "--inject-slowdown", "0.999999"],
            "a fraction in (0, 0.9]",
        ),
        (&["run", "taylor", "--model", "1", "--velocity", "1e9"], "give at most 100000 m/s"),
        (&["run", "taylor", "--model", "1", "--end-time", "1e300"], "the run would take about"),
        (&["run", "taylor", "--model", "1", "--cfl", "1e-300"], "a larger --cfl"),
        (&["run", "impact", "--spacing", "1e-9", "--steps", "1"], "would need billions of particles"),
        (&["run", "impact", "--cell", "1", "--steps", "1"], "give a cell of 1 to 8 spacings"),
        (&["run", "impact", "--spacing", "2e-3", "--cell", "10", "--steps", "2"], "give a cell of 1 to 8 spacings"),
        (
            &["run", "impact", "--spacing", "2e-3", "--cell", "10e-3", "--steps", "2"],
            "thicker than the 0.00635 m plate",
        ),
        (&["run", "plate", "--cell", "1e-9", "--steps", "2"], "the run needs about"),
        (&["run", "plate", "--cell", "1e-10", "--steps", "2"], "more than the 4294967294 a run can hold"),
        (&["run", "plate", "--length", "1e-9", "--steps", "2"], "the shock measurements need at least 32 cells"),
        (&["run", "taylor", "--model", "1", "--steps", "18446744073709551615"], "its --steps"),
    ];
    for (args, says) in cases {
        refused(args, says);
    }
    // The refusal of a long run says how to run it anyway, and --force does.
    let dir = tempfile::tempdir().unwrap();
    let out = refused_in(dir.path(), &["run", "taylor", "--model", "1", "--end-time", "1e300"], "--force");
    assert_eq!(text(&out.stderr).matches("caused by").count(), 0, "{}", text(&out.stderr));
}

/// A coarse impact whose figures cannot all be measured (a 2-step run: no front to fit)
/// prints them as not available, never as NaN.
#[test]
fn a_figure_not_measured_is_printed_as_not_available() {
    let dir = tempfile::tempdir().unwrap();
    let args = ["run", "impact", "--spacing", "2e-3", "--cell", "4e-3", "--steps", "2"];
    let out = Command::new(MPM).args(args).current_dir(dir.path()).output().unwrap();
    let said = text(&out.stdout);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(said.contains("debris cloud:") && said.contains("front velocity n/a m/s"), "{said}");
    assert!(!said.contains("NaN"), "{said}");
}

/// No output over an input or another output: the spec file, the summary and the state
/// dump, the checkpoint folder (of a new run, and of one continued); nothing is written.
#[test]
fn outputs_never_overwrite_inputs() {
    let dir = tempfile::tempdir().unwrap();
    let d = dir.path();
    let printed = Command::new(MPM).args(["run", "taylor", "--model", "1", "--steps", "12", "--print-spec"]).output();
    let spec = d.join("s.toml");
    std::fs::write(&spec, printed.unwrap().stdout).unwrap();
    let before = std::fs::read(&spec).unwrap();
    let s = path(&spec);
    refused_in(d, &["run", "--spec", s, "--json", s], "is the same file as the spec file --spec");
    refused_in(d, &["run", "--spec", "./s.toml", "--json", s], "is the same file as");
    assert_eq!(std::fs::read(&spec).unwrap(), before, "the spec is unchanged");
    refused_in(d, &strs(&taylor(&["--json", "x.json", "--dump-state", "x.json"])), "--json x.json is the same file");
    refused_in(d, &strs(&taylor(&["--checkpoint-dir", "ck", "--vtk", "ck"])), "same folder as --checkpoint-dir");
    refused_in(d, &strs(&taylor(&["--checkpoint-dir", "ck", "--json", "ck/x.json"])), "lies in --checkpoint-dir");
    assert!(!d.join("x.json").exists() && !d.join("ck").exists(), "nothing written");
    // A run with checkpoints, then its continuation with a summary over a checkpoint.
    let run = ["run", "taylor", "--model", "1", "--steps", "12", "--quiet", "--checkpoint-dir", "ck"];
    let out = Command::new(MPM).args(run).args(["--checkpoint-every", "5"]).current_dir(d).output().unwrap();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let ckpt = d.join("ck/step-0000000010/rank-0000.ckpt");
    let kept = std::fs::read(&ckpt).unwrap();
    refused_in(d, &["resume", "ck", "--json", path(&ckpt)], "lies in the checkpoint folder");
    refused_in(d, &["resume", "ck", "--threads", "-1"], "the thread count must be at least 1");
    refused_in(d, &["resume", "ck", "--cpus=-1,0"], "'-1' in CPU list '-1,0' is not a CPU number");
    assert_eq!(std::fs::read(&ckpt).unwrap(), kept, "the checkpoint is unchanged");
}

/// A run of Taylor Model 3 with DD on 2 threads, each step made ten times as long by the
/// injected slowdown at its bound, started in `dir`: returned once it steps (its initial
/// snapshot written, and a moment more for the slowdown to take hold).
fn long_steps(dir: &Path) -> Child {
    let args = ["run", "taylor", "--model", "3", "--steps", "100000", "--strategy", "dd", "--threads", "2"];
    let mut child = Command::new(MPM)
        .args(args)
        .args(["--inject-slowdown", "0.9", "--quiet", "--json", "x.json", "--vtk", "v", "--every", "100000"])
        .current_dir(dir)
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let start = Instant::now();
    while !dir.join("v/taylor_000000.vtu").exists() {
        assert!(child.try_wait().unwrap().is_none(), "the run ended before it stepped");
        assert!(start.elapsed() < Duration::from_secs(60), "the run did not start stepping in a minute");
        std::thread::sleep(Duration::from_millis(20));
    }
    std::thread::sleep(Duration::from_millis(1500));
    child
}

/// Send SIGTERM to `child`.
fn term(child: &Child) {
    let ok = Command::new("kill").args(["-TERM", &child.id().to_string()]).status().unwrap().success();
    assert!(ok, "kill -TERM failed");
}

/// The exit status and standard error of `child`, which must end within `limit`.
fn ended_within(mut child: Child, limit: Duration) -> (Option<i32>, String) {
    let start = Instant::now();
    loop {
        if let Some(status) = child.try_wait().unwrap() {
            let mut err = String::new();
            std::io::Read::read_to_string(child.stderr.as_mut().unwrap(), &mut err).unwrap();
            return (status.code(), err);
        }
        if start.elapsed() > limit {
            child.kill().unwrap();
            child.wait().unwrap();
            panic!("the run did not end within {limit:?} of the signal");
        }
        std::thread::sleep(Duration::from_millis(10));
    }
}

/// The first SIGTERM stops the run between steps (exit 130, no summary), however slow
/// its steps.
#[test]
fn sigterm_stops_a_slowed_run_between_steps() {
    let dir = tempfile::tempdir().unwrap();
    let child = long_steps(dir.path());
    term(&child);
    let (code, err) = ended_within(child, Duration::from_secs(30));
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("interrupted at step") && err.contains("no summary written"), "{err}");
    assert!(!dir.path().join("x.json").exists(), "an interrupted run writes no summary");
}

/// A second SIGTERM ends the run at once, in the middle of a step.
#[test]
fn a_second_sigterm_ends_the_run_at_once() {
    let dir = tempfile::tempdir().unwrap();
    let child = long_steps(dir.path());
    term(&child);
    std::thread::sleep(Duration::from_millis(5));
    term(&child);
    let (code, err) = ended_within(child, Duration::from_secs(2));
    assert_eq!(code, Some(130), "{err}");
    assert!(err.contains("a second interrupt: mpm stops at once"), "{err}");
    // At once: not at the end of the step, where the first would have stopped it.
    assert!(!err.contains("interrupted at step"), "{err}");
    assert!(!dir.path().join("x.json").exists(), "an interrupted run writes no summary");
}
