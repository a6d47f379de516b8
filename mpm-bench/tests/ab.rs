//! `mpm-bench ab` end to end on the fake solver: two sides run side by side in ABBA order
//! into their own campaign folders, and the verdict passes A/A and fails each injected
//! change (efficiency, time per step) on the check that measures it.

use std::path::Path;
use std::process::Command;

/// `mpm-bench ab --mock` into `out` with `extra` arguments: the exit code and the verdict.
fn ab(out: &Path, extra: &[&str]) -> (i32, serde_json::Value) {
    let json = out.join("v.json");
    let o = Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
        .args(["ab", "--mock", "--baseline-bin", "unused", "--preset", "ci", "--reps", "6", "-q"])
        .arg("--out")
        .arg(out)
        .arg("--json")
        .arg(&json)
        .args(extra)
        .output()
        .unwrap();
    let text = std::fs::read_to_string(&json).unwrap_or_else(|_| {
        panic!("no verdict: {}\n{}", String::from_utf8_lossy(&o.stdout), String::from_utf8_lossy(&o.stderr))
    });
    (o.status.code().unwrap(), serde_json::from_str(&text).unwrap())
}

/// The metrics of the checks that failed.
fn failed(v: &serde_json::Value) -> Vec<String> {
    v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["outcome"] == "regressed")
        .map(|c| c["metric"].as_str().unwrap().to_string())
        .collect()
}

#[test]
fn ab_passes_the_same_build_and_fails_each_injected_change() {
    let tmp = tempfile::tempdir().unwrap();
    let (code, v) = ab(&tmp.path().join("aa"), &[]);
    assert_eq!(code, 0, "A/A: {v:#}");
    assert_eq!(v["design"], "interleaved");
    assert_eq!(v["pairs"], 24, "4 cells x 6 processes");
    assert!(failed(&v).is_empty());
    // Both sides' rows are kept, and the order that ran is recorded: ABBA from the seed.
    let rec: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tmp.path().join("aa/ab.json")).unwrap()).unwrap();
    let order: String = rec["order"].as_array().unwrap().iter().map(|p| p[1].as_str().unwrap()).collect();
    assert!(order.starts_with("ABBAABBA") || order.starts_with("BAABBAAB"), "{order}");
    for side in rec["sides"].as_array().unwrap() {
        let csv = Path::new(side["dir"].as_str().unwrap()).join("runs.csv");
        assert_eq!(std::fs::read_to_string(csv).unwrap().lines().count(), 25, "{side}");
    }
    assert!(tmp.path().join("aa/verdict.json").is_file());

    let (code, v) = ab(&tmp.path().join("step"), &["--candidate-inject-step-slowdown", "0.1"]);
    assert_eq!(code, 1, "a 10 % slower step: {v:#}");
    let f = failed(&v);
    assert!(!f.is_empty() && f.iter().all(|m| m == "time_per_step"), "only the time per step fails: {f:?}");

    let (code, v) = ab(&tmp.path().join("eff"), &["--candidate-inject-slowdown", "0.1"]);
    assert_eq!(code, 1, "a 10 % efficiency loss: {v:#}");
    assert!(failed(&v).iter().any(|m| m == "efficiency"), "{:?}", failed(&v));
}

/// Bad input exits 2 before anything runs: no baseline, a tolerance that is no fraction.
#[test]
fn ab_refuses_bad_input() {
    let tmp = tempfile::tempdir().unwrap();
    // As on a clean clone, whatever this checkout has built: no candidate solver either, so
    // the baseline's folder must be the error reported.
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
            .arg("ab")
            .args(args)
            .arg("--out")
            .arg(tmp.path())
            .env("MPM_BENCH_SOLVER_O3", tmp.path().join("no-such-mpm"))
            .env("MPM_BENCH_SOLVER_O0", tmp.path().join("no-such-mpm"))
            .output()
            .unwrap()
    };
    let o = run(&["--mock"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("--baseline-rev"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["--mock", "--baseline-bin", "x", "--tolerance", "-0.05"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("not a fraction"), "{}", String::from_utf8_lossy(&o.stderr));
    let o = run(&["--baseline-bin", "/nonexistent", "--no-build", "--preset", "smoke"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no `mpm` binary"), "{}", String::from_utf8_lossy(&o.stderr));
}

/// `work-snapshot`: written, checked equal (exit 0); one worker's bytes of one sub-stage
/// changed in the file: exit 1, naming the cell and the sub-stage.
#[test]
fn work_snapshot_names_the_changed_sub_stage() {
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("work.json");
    let run = |args: &[&str]| {
        Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
            .args(["work-snapshot", "--mock", "--preset", "ci"])
            .args(args)
            .arg(&file)
            .output()
            .unwrap()
    };
    assert!(run(&["--write"]).status.success());
    let o = run(&["--check"]);
    assert_eq!(o.status.code(), Some(0), "{}", String::from_utf8_lossy(&o.stdout));
    let mut snap: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    let cell = snap["cells"][1]["cell"].as_str().unwrap().to_string();
    let scatter = &mut snap["cells"][1]["bytes"]["scatter"][0];
    *scatter = serde_json::json!(scatter.as_u64().unwrap() + 1);
    std::fs::write(&file, serde_json::to_string(&snap).unwrap()).unwrap();
    let o = run(&["--check"]);
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(o.status.code(), Some(1), "{out}");
    assert!(out.contains(&format!("{cell}: scatter")), "names the cell and the sub-stage: {out}");
}
