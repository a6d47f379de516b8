//! `mpm-bench roofline-table`: the roofline table of runs from their summaries.

use mpm_bench::report::roofline_table::table;
use mpm_core::Substage;
use mpm_spec::summary::{StageRoofline, Summary};
use std::collections::BTreeMap;
use std::process::Command;

fn stage(ns: f64, bytes: f64, flops: f64) -> StageRoofline {
    StageRoofline {
        bytes_per_particle_step: bytes,
        flops_per_particle_step: flops,
        ns_per_particle_step: ns,
        gb_per_s: (bytes > 0.0).then(|| bytes / ns),
        gflop_per_s: (flops > 0.0).then(|| flops / ns),
    }
}

/// A 2-thread run with two timed sub-stages, one that took no time and one that did not run
/// but has a counted cost (the binning of a serial run: a few picoseconds of timer).
fn mock() -> Summary {
    let mut r = BTreeMap::new();
    r.insert(Substage::Scatter, stage(40.0, 200.0, 100.0));
    r.insert(Substage::StressUpdate, stage(60.0, 100.0, 300.0));
    r.insert(Substage::Gather, stage(0.0, 0.0, 0.0));
    r.insert(Substage::Binning, stage(0.003, 36.0, 6.0));
    let mut s = Summary { threads: 2, ..Summary::default() };
    s.figures.size.particles = 56_056;
    s.figures.timing.roofline = Some(r);
    s
}

/// Each timed sub-stage's row, the step as the sum of them (400 flops and 300 bytes in 100 ns:
/// 4 GFLOP/s, 3 GB/s), the share of the STREAM ceiling at the run's 2 workers, and no row (nor
/// a share of the step's bytes) for a sub-stage that did not run.
#[test]
fn rows_per_stage_and_the_step_against_the_ceiling() {
    let ceiling = |threads: usize| (threads == 2).then_some(10.0);
    let t = table(&[("m1".into(), mock())], &ceiling);
    let lines: Vec<&str> = t.lines().collect();
    assert_eq!(lines.len(), 2 + 3, "{t}");
    assert_eq!(lines[2], "| m1 | scatter | 40.0 | 200 | 100 | 5.00 | 50 % | 2.50 |");
    assert_eq!(lines[3], "| m1 | stress_update | 60.0 | 100 | 300 | 1.67 | 17 % | 5.00 |");
    assert!(lines[4].starts_with("| m1 | **step** ("), "{t}");
    assert!(lines[4].ends_with("x2, 56,056 particles) | 100.0 | 300 | 400 | 3.00 | 30 % | 4.00 |"), "{t}");
    assert!(!t.contains("gather") && !t.contains("binning"), "{t}");
    // Without a ceiling at the run's worker count: no share.
    let none = |_: usize| None;
    assert!(table(&[("m1".into(), mock())], &none).contains("| 5.00 | - | 2.50 |"));
}

/// A summary without a roofline (no steady steps) is refused with what to do; one with it
/// prints the table.
#[test]
fn the_command_reads_summaries_and_refuses_one_without_roofline() {
    let dir = tempfile::tempdir().unwrap();
    let good = dir.path().join("good.json");
    let bad = dir.path().join("bad.json");
    std::fs::write(&good, serde_json::to_string(&mock()).unwrap()).unwrap();
    std::fs::write(&bad, serde_json::to_string(&Summary::default()).unwrap()).unwrap();
    let run = |file: &std::path::Path| {
        Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
            .args(["roofline-table", "--summary", &format!("Model 1={}", file.display())])
            .output()
            .unwrap()
    };
    let out = run(&good);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    assert!(String::from_utf8_lossy(&out.stdout).contains("| Model 1 | scatter | 40.0 |"));
    let out = run(&bad);
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("has no roofline") && err.contains("rerun it with more steps"), "{err}");
}
