//! Integration tests of the analysis commands (stats, figures, claims, regress, report,
//! bandwidth) on crafted campaigns written with the real CSV writer.

use mpm_bench::analysis::claims::{self, Verdict};
use mpm_bench::analysis::regress::{self, Outcome, RegressOptions};
use mpm_bench::analysis::results::load_campaign;
use mpm_bench::analysis::select::RowFilter;
use mpm_bench::analysis::stats::{Analysis, CellKey, Stage, StatsOptions};
use mpm_bench::campaign::store::csv::{read_rows, CsvLog};
use mpm_bench::campaign::store::record::{Row, Status};
use mpm_bench::machine::bandwidth;
use mpm_bench::report::figures::{self, FiguresOptions};
use std::path::{Path, PathBuf};

mod common;
use common::*;

fn analysis(dir: &Path) -> Analysis {
    load_campaign(dir, &RowFilter::analysis(false)).unwrap().analyse(None)
}

#[test]
fn stats_medians_speedups_and_intervals() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_campaign(&tmp.path().join("c"), &Craft::default());
    let an = analysis(&dir);
    // Model1 DD O3 at 2 threads: T1 = 0.01 s; T2 from the stage efficiencies.
    let p = an.point(1, DD, "o3", 2, Stage::Total).unwrap();
    let t1 = 0.004 + 0.006;
    let t2 = 0.004 / (2.0 * 0.9) + 0.006 / (2.0 * 0.95);
    assert!((p.time.value - t2).abs() < 1e-12, "{:?}", p.time);
    assert!((p.base.as_ref().unwrap().t1.value - t1).abs() < 1e-12);
    let s = p.speedup.unwrap();
    assert!((s.value - t1 / t2).abs() < 1e-9, "{s:?}");
    assert!(s.lo <= s.value && s.value <= s.hi && s.lo < s.hi, "{s:?}");
    assert_eq!(s.reps, 3);
    let e = p.efficiency.unwrap();
    assert!((e.value - s.value / 2.0).abs() < 1e-12);
    // Stage times are normalised per step.
    let g = an.point(1, DD, "o3", 2, Stage::Grid).unwrap();
    assert!((g.time.value - 0.004 / 1.8).abs() < 1e-12);
    // The one-thread point has speedup exactly 1 without a fake interval.
    let one = an.point(1, DD, "o3", 1, Stage::Total).unwrap();
    assert_eq!(one.speedup.unwrap().value, 1.0);
    assert!(one.speedup.unwrap().lo == 1.0 && one.speedup.unwrap().hi == 1.0);
    // Skipped cells are absent, not zero; their cell says why.
    assert!(an.point(4, AE, "o3", 4, Stage::Total).is_none());
    let cell = &an.cells[&CellKey::new(4, AE, "o3", 4)];
    assert!(!cell.measured() && cell.not_ok[0].0 == Status::Skipped);
    // Deterministic: the same rows give the same intervals.
    let again = analysis(&dir);
    assert_eq!(an.points, again.points);
    // Oversubscription is carried per point.
    let tmp2 = tempfile::tempdir().unwrap();
    let dir2 = write_campaign(&tmp2.path().join("c"), &Craft { cores: 2, ..Craft::default() });
    let an2 = analysis(&dir2);
    assert!(an2.point(1, DD, "o3", 4, Stage::Total).unwrap().oversubscribed);
    assert!(!an2.point(1, DD, "o3", 2, Stage::Total).unwrap().oversubscribed);
}

#[test]
fn single_repetition_gives_degenerate_intervals() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_campaign(&tmp.path().join("c"), &Craft { reps: 1, ..Craft::default() });
    let an = analysis(&dir);
    let s = an.point(2, AE, "o3", 2, Stage::Total).unwrap().speedup.unwrap();
    assert!(s.degenerate() && s.lo == s.value && s.hi == s.value);
    assert!(s.show(2).contains("n=1"), "{}", s.show(2));
    let mem = an.memory(&CellKey::new(2, AE, "o3", 2), &StatsOptions::default()).unwrap();
    assert!(mem.degenerate());
}

#[test]
fn figures_are_written_as_png_and_svg() {
    let tmp = tempfile::tempdir().unwrap();
    let results = tmp.path().join("results");
    write_campaign(&results.join("fp").join("camp"), &Craft { cores: 2, ..Craft::default() });
    let out = tmp.path().join("figs");
    figures::run(FiguresOptions {
        results: results.clone(),
        out: out.clone(),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap();
    for stem in ["fig07", "fig08", "fig09", "fig10", "fig11", "fig12", "fig13", "fig14", "fig_memory"] {
        let png = std::fs::read(out.join(format!("{stem}.png"))).unwrap();
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n", "{stem}.png");
        let svg = std::fs::read_to_string(out.join(format!("{stem}.svg"))).unwrap();
        assert!(svg.contains("<svg") && svg.trim_end().ends_with("</svg>"), "{stem}.svg");
    }
    let svg = std::fs::read_to_string(out.join("fig07.svg")).unwrap();
    assert!(svg.contains("Model1") && svg.contains("Model4") && svg.contains("Grid-node stage"));
    assert!(svg.contains("more threads than cores"), "the hollow-marker note is in the figure");
    let readme = std::fs::read_to_string(out.join("README.md")).unwrap();
    assert!(readme.contains("mpm-bench figures --results"), "{readme}");
    assert!(readme.contains("camp"));
}

#[test]
fn figures_report_clear_errors() {
    let tmp = tempfile::tempdir().unwrap();
    let err = figures::run(FiguresOptions {
        results: tmp.path().join("nope"),
        out: tmp.path().join("o"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap_err();
    assert!(format!("{err:#}").contains("does not exist"), "{err:#}");
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let err = figures::run(FiguresOptions {
        results: empty,
        out: tmp.path().join("o"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap_err();
    assert!(format!("{err:#}").contains("no runs.csv"), "{err:#}");
    let bad = tmp.path().join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("runs.csv"), "model,threads\n1,1\n").unwrap();
    let err = figures::run(FiguresOptions {
        results: bad,
        out: tmp.path().join("o"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap_err();
    assert!(format!("{err:#}").contains("missing column"), "{err:#}");
}

fn verdicts(dir: &Path) -> Vec<(String, Verdict)> {
    let c = load_campaign(dir, &RowFilter::analysis(false)).unwrap();
    let an = c.analyse(None);
    claims::evaluate(&c, &an).into_iter().map(|r| (r.id.to_string(), r.verdict)).collect()
}

/// A campaign run under `close` (the default craft) and under `spread` as crafted by
/// `spread` (its `per_socket` is where its socket penalty starts).
fn close_and_spread(dir: &Path, spread: Craft) -> PathBuf {
    write_campaign(dir, &Craft::default());
    write_campaign(dir, &Craft { pin: "spread", ..spread })
}

#[test]
fn claims_on_a_crafted_two_socket_machine() {
    let tmp = tempfile::tempdir().unwrap();
    // Spread pays the socket penalty from 2 threads on: C5 holds at 2 and 4 threads.
    let dir = close_and_spread(&tmp.path().join("c"), Craft { per_socket: 1, ..Craft::default() });
    let v = verdicts(&dir);
    for (id, verdict) in &v {
        assert_eq!(*verdict, Verdict::Holds, "{id}: {v:?}");
    }
    let c = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    let res = claims::evaluate(&c, &c.analyse(None));
    let md = claims::markdown(&res, "##");
    assert!(md.contains("| C5 |") && md.contains("**holds**"));
    assert!(!res[0].evidence.is_empty());
    assert!(res.iter().all(|r| !r.indicative && r.min_reps.is_none_or(|n| n >= 3)), "{res:?}");
    let c5 = &res[4];
    assert!(c5.evidence.iter().any(|e| e.contains("2 threads") && e.contains("spread (2 sockets)")), "{c5:?}");
    assert!(c5.evidence.iter().all(|e| !e.contains("6 threads") && !e.contains("8 threads")), "{c5:?}");
}

#[test]
fn c5_compares_one_socket_with_two_at_the_same_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    // Only close rows: 4 against 6 threads is not evidence any more.
    let v = verdicts(&write_campaign(&tmp.path().join("a"), &Craft::default()));
    assert_eq!(v[4].1, Verdict::CannotTell, "{v:?}");
    // Spread exactly as fast as close: everything within the noise.
    let v = verdicts(&close_and_spread(&tmp.path().join("b"), Craft::default()));
    assert_eq!(v[4].1, Verdict::CannotTell, "{v:?}");
    // Spread faster than close (more cache and memory bandwidth): does not hold.
    let v = verdicts(&close_and_spread(&tmp.path().join("c"), Craft { slow_parallel: 0.8, ..Craft::default() }));
    assert_eq!(v[4].1, Verdict::DoesNotHold, "{v:?}");
    // Spread slower: holds.
    let v = verdicts(&close_and_spread(&tmp.path().join("d"), Craft { slow_parallel: 1.25, ..Craft::default() }));
    assert_eq!(v[4].1, Verdict::Holds, "{v:?}");
}

/// One socket of two NUMA nodes: C5 compares one node with two at the same thread count
/// (close keeps 2 and 4 threads on node 0, spread crosses); one socket of one node: cannot
/// tell, saying why.
#[test]
fn c5_crosses_numa_nodes_on_one_socket() {
    let tmp = tempfile::tempdir().unwrap();
    // Close and spread rows of one machine; spread 25 % slower.
    let c5_on = |dir: &Path, topo: &'static str| {
        let close = Craft { topo: Some(topo), ..Craft::default() };
        write_campaign(dir, &close);
        write_campaign(dir, &Craft { pin: "spread", slow_parallel: 1.25, ..close });
        let c = load_campaign(dir, &RowFilter::analysis(false)).unwrap();
        claims::evaluate(&c, &c.analyse(None)).swap_remove(4)
    };
    let c5 = c5_on(&tmp.path().join("a"), "pack:1 numa:2 core:4 pu:1");
    assert_eq!(c5.verdict, Verdict::Holds, "{c5:?}");
    assert!(c5.evidence.iter().any(|e| e.contains("4 threads") && e.contains("spread (2 NUMA nodes)")), "{c5:?}");
    assert!(c5.evidence.iter().any(|e| e.contains("close (1 NUMA node)")), "{c5:?}");
    let c5 = c5_on(&tmp.path().join("b"), "pack:1 core:8 pu:1");
    assert_eq!(c5.verdict, Verdict::CannotTell, "{c5:?}");
    assert!(c5.reason.contains("1 socket and 1 NUMA node"), "{c5:?}");
}

/// Every claim on crafted rows where it holds, does not hold, and cannot be told.
#[test]
fn each_claim_holds_fails_and_cannot_tell() {
    use Verdict::{CannotTell as Cannot, DoesNotHold as Not, Holds};
    let tmp = tempfile::tempdir().unwrap();
    let one_core = Craft { topo: Some("pack:1 core:1 pu:1"), cores: 1, per_socket: 1, ..Craft::default() };
    let cases: Vec<(usize, Craft, Verdict)> = vec![
        (0, Craft::default(), Holds),
        (0, Craft { dd_grid_eff: 0.3, ..Craft::default() }, Not),
        (0, one_core.clone(), Cannot),
        (1, Craft::default(), Holds),
        (1, Craft { ae_copy_bytes: 0.0, ..Craft::default() }, Not),
        (1, Craft { threads: vec![1], ..Craft::default() }, Cannot),
        (2, Craft::default(), Holds),
        (2, Craft { ae_particle_eff: 0.3, ..Craft::default() }, Not),
        (2, one_core.clone(), Cannot),
        (3, Craft::default(), Holds),
        (3, Craft { o0_loss: 2.0, ..Craft::default() }, Not),
        (3, one_core, Cannot),
        (5, Craft::default(), Holds),
        (5, Craft { skip_m4_ae: false, ..Craft::default() }, Not),
        (5, Craft { models: vec![1, 2], ..Craft::default() }, Cannot),
    ];
    for (k, (claim, craft, want)) in cases.into_iter().enumerate() {
        let dir = write_campaign(&tmp.path().join(format!("c{k}")), &craft);
        let c = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
        let r = &claims::evaluate(&c, &c.analyse(None))[claim];
        assert_eq!(r.verdict, want, "case {k}: {} {}: {:?}", r.id, r.reason, r.evidence);
    }
}

#[test]
fn holds_needs_a_majority_and_intervals() {
    let tmp = tempfile::tempdir().unwrap();
    // O0 only a little better: AE's comparisons support C4, DD's are within the noise.
    let dir = write_campaign(&tmp.path().join("a"), &Craft { o0_loss: 0.5, ..Craft::default() });
    let c = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    let c4 = &claims::evaluate(&c, &c.analyse(None))[3];
    assert_eq!(c4.verdict, Verdict::CannotTell, "{c4:?}");
    assert!(c4.reason.contains("no majority"), "{}", c4.reason);
    assert!(c4.evidence.iter().any(|e| e.ends_with("supports")), "{c4:?}");
    // O0 clearly better: holds; clearly worse: does not hold.
    assert_eq!(verdicts(&write_campaign(&tmp.path().join("b"), &Craft::default()))[3].1, Verdict::Holds);
    let worse = write_campaign(&tmp.path().join("c"), &Craft { o0_loss: 2.0, ..Craft::default() });
    assert_eq!(verdicts(&worse)[3].1, Verdict::DoesNotHold);
    // One repetition: the verdicts are indicative and say so.
    let once = Craft { reps: 1, noise: vec![1.0], ..Craft::default() };
    let dir = write_campaign(&tmp.path().join("d"), &once);
    write_campaign(&dir, &Craft { pin: "spread", per_socket: 1, ..once });
    let c = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    let res = claims::evaluate(&c, &c.analyse(None));
    for r in &res[..5] {
        assert!(r.indicative && r.verdict_label().ends_with("(indicative)"), "{r:?}");
        assert!(r.reason.contains("indicative only"), "{}", r.reason);
    }
    assert!(claims::table(&res).contains("(indicative)"));
}

#[test]
fn claims_say_cannot_tell_on_one_socket_and_ignore_oversubscribed_points() {
    let tmp = tempfile::tempdir().unwrap();
    // A 2-core, 1-socket machine: 4-8 threads are oversubscribed.
    let dir = write_campaign(
        &tmp.path().join("c"),
        &Craft { topo: Some("pack:1 core:2 pu:1"), cores: 2, per_socket: 2, ..Craft::default() },
    );
    let v = verdicts(&dir);
    assert_eq!(v[4], ("C5".into(), Verdict::CannotTell));
    assert_eq!(v[0].1, Verdict::Holds, "2-thread points are real evidence: {v:?}");
    // Only one real thread count and it is oversubscribed: no scaling evidence at all.
    let dir = write_campaign(
        &tmp.path().join("d"),
        &Craft { topo: Some("pack:1 core:1 pu:1"), cores: 1, per_socket: 1, ..Craft::default() },
    );
    let v = verdicts(&dir);
    for i in [0, 2, 3] {
        assert_eq!(v[i].1, Verdict::CannotTell, "{v:?}");
    }
    assert_eq!(v[1].1, Verdict::Holds, "memory does not depend on time sharing: {v:?}");
    // No manifest: sockets unknown.
    let dir = write_campaign(&tmp.path().join("e"), &Craft { topo: None, ..Craft::default() });
    assert_eq!(verdicts(&dir)[4].1, Verdict::CannotTell);
}

#[test]
fn claims_that_the_data_contradict() {
    let tmp = tempfile::tempdir().unwrap();
    // AE never skipped and little memory: C6 does not hold (everything fits in 8 GB).
    let dir = write_campaign(&tmp.path().join("c"), &Craft { skip_m4_ae: false, ..Craft::default() });
    let v = verdicts(&dir);
    assert_eq!(v[5].1, Verdict::DoesNotHold, "{v:?}");
}

fn regress_args(base: &Path, cur: &Path) -> RegressOptions {
    RegressOptions::new(base, cur)
}

#[test]
fn regress_passes_against_itself_and_fails_on_a_20_percent_efficiency_drop() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    let json = tmp.path().join("verdict.json");
    let mut args = regress_args(&base, &base);
    args.json = Some(json.clone());
    assert_eq!(regress::run(args).unwrap(), 0);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "pass");
    // It passes, but says that it compared one campaign with itself.
    assert_eq!(v["same_rows"], true);
    let r = regress::evaluate(&regress_args(&base, &base)).unwrap();
    assert!(regress::lines(&r).contains("the same rows (one campaign given twice)"), "{}", regress::lines(&r));
    assert!(regress::markdown(&r).contains("the same rows"));

    // Parallel runs 25 % slower: efficiency x 0.8.
    let cur = write_campaign(&tmp.path().join("drop"), &Craft { slow_parallel: 1.25, ..Craft::default() });
    let mut args = regress_args(&base, &cur);
    args.json = Some(json.clone());
    assert_eq!(regress::run(args).unwrap(), 1);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "fail");
    let regs = v["regressions"].as_array().unwrap();
    assert!(regs.iter().any(|r| r["metric"] == "efficiency"));
    assert_eq!(v["same_rows"], false);
    let r = regress::evaluate(&regress_args(&base, &cur)).unwrap();
    assert!(!regress::lines(&r).contains("the same rows"));
    let eff = r.regressions.iter().find(|c| c.metric == "efficiency").unwrap();
    assert!((eff.ratio.value - 0.8).abs() < 1e-9, "{:?}", eff.ratio);
}

/// Rows measured on a busy host (`host_noisy`) are left out of regress, claims and figures
/// unless `--include-noisy` (then their points are grey in the figures), and the campaign
/// says what it left out.
#[test]
fn noisy_rows_are_excluded_unless_asked_and_grey_in_figures() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    let cur = write_campaign(&tmp.path().join("cur"), &Craft::default());
    // Three more repetitions of every parallel run, three times slower, on a busy host.
    let csv = cur.join("runs.csv");
    let extra: Vec<Row> = read_rows(&csv)
        .unwrap()
        .into_iter()
        .filter(|r| r.threads() > 1 && r.outcome.status == Status::Ok)
        .flat_map(|r| {
            (10..13).map(move |rep| {
                let mut b = r.clone();
                b.run.rep = 100 * (r.run.rep + 1) + rep;
                // A new repetition: its own run key (a key written twice counts once).
                b.id.run_key = b.run.key().0;
                b.id.run_id = format!("{}-busy{rep}", r.id.run_id);
                let m = &mut b.measured_mut().timing;
                for t in [&mut m.steady_s_per_step, &mut m.steady_grid_stage_s, &mut m.steady_particle_stage_s] {
                    *t = t.map(|t| 3.0 * t);
                }
                b.host.host_noisy = true;
                b.host.host_noise = "its CPUs 60 % busy with other work before the run".into();
                b
            })
        })
        .collect();
    let mut log = CsvLog::open(&csv).unwrap();
    for r in &extra {
        log.append(r).unwrap();
    }
    let r = regress::evaluate(&regress_args(&base, &cur)).unwrap();
    assert_eq!(r.exit_code(), 0, "noisy rows must not count: {}", r.reason);
    assert!(r.checks.iter().all(|c| c.current_reps == c.baseline_reps), "noisy repetitions left out");
    // With them, every repetition of a parallel cell has 3 more, three times slower: the
    // medians move (with so few repetitions over 100+ Holm-corrected checks the bootstrap
    // cannot call that beyond the noise, so the gate's verdict is not the test here).
    let r = regress::evaluate(&RegressOptions { include_noisy: true, ..regress_args(&base, &cur) }).unwrap();
    let slow: Vec<_> = r.checks.iter().filter(|c| c.current_reps > c.baseline_reps).collect();
    assert!(!slow.is_empty(), "with --include-noisy the slow rows count: {}", r.reason);
    assert!(slow.iter().any(|c| c.worse_by > 0.5), "the slow rows move the medians: {}", r.reason);
    let quiet = load_campaign(&cur, &RowFilter::analysis(false)).unwrap();
    assert_eq!(quiet.rows.len(), load_campaign(&base, &RowFilter::analysis(false)).unwrap().rows.len());
    assert_eq!(quiet.left_out.iter().map(|l| l.rows).sum::<usize>(), extra.len(), "{:?}", quiet.left_out);
    assert!(quiet.left_out.iter().all(|l| l.reason.contains("busy host")), "{:?}", quiet.left_out);
    let all = load_campaign(&cur, &RowFilter::analysis(true)).unwrap();
    assert_eq!(all.rows.len(), quiet.rows.len() + extra.len());
    // Figures by the same rule: without the noisy rows no point is grey; with them the
    // noisy cells' points are grey, the others not.
    let spec = figures::PAPER_FIGURES.iter().find(|f| f.number == 8).unwrap();
    let points = |c: &mpm_bench::analysis::results::Campaign| -> Vec<_> {
        figures::paper_panels(&c.analyse(None), spec).into_iter().flat_map(|p| p.lines).flat_map(|l| l.points).collect()
    };
    assert!(points(&quiet).iter().all(|p| !p.grey));
    let pts = points(&all);
    assert!(pts.iter().any(|p| p.grey) && pts.iter().any(|p| !p.grey));
    assert!(pts.iter().all(|p| p.grey == (p.x > 1.0)), "grey exactly where noisy rows are");
    // The figures' footnote says how many rows were left out and why.
    let notes = figures::footnotes(&quiet, &quiet.analyse(None)).join(" ");
    assert!(notes.contains(&format!("left out: {} measured on a busy host", extra.len())), "{notes}");
    assert!(notes.contains("every repetition left out"), "{notes}");
}

#[test]
fn regress_time_per_step_regression_fails_and_improvement_passes() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    // Everything 20 % slower: efficiency unchanged, time per step regressed.
    let slow = write_campaign(&tmp.path().join("slow"), &Craft { slow_all: 1.2, ..Craft::default() });
    let r = regress::evaluate(&regress_args(&base, &slow)).unwrap();
    assert_eq!(r.exit_code(), 1, "{}", r.reason);
    assert!(r.regressions.iter().all(|c| c.metric == "time_per_step"));
    // Faster parallel runs: improved, passes.
    let fast = write_campaign(&tmp.path().join("fast"), &Craft { slow_parallel: 0.8, ..Craft::default() });
    let r = regress::evaluate(&regress_args(&base, &fast)).unwrap();
    assert_eq!(r.exit_code(), 0, "{}", r.reason);
    assert!(!r.improvements.is_empty());
    assert!(r.checks.iter().all(|c| c.outcome != Outcome::Regressed));
}

#[test]
fn regress_noisy_but_unchanged_passes() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    // Median 8 % worse, but so noisy that the interval includes no change: passes.
    let noisy = write_campaign(
        &tmp.path().join("noisy"),
        &Craft { reps: 5, noise: vec![1.30, 0.85, 1.08, 0.9, 1.25], ..Craft::default() },
    );
    let r = regress::evaluate(&regress_args(&base, &noisy)).unwrap();
    assert_eq!(r.exit_code(), 0, "{}: {:?}", r.reason, r.regressions);
    let c =
        r.checks.iter().find(|c| c.metric == "time_per_step" && c.cell.key().is_some_and(|k| k.threads == 1)).unwrap();
    assert!(c.worse_by > 0.05 && c.ratio.lo < 1.0, "{c:?}");
}

#[test]
fn regress_refuses_other_machines_unless_forced() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    let other =
        write_campaign(&tmp.path().join("other"), &Craft { topo: Some("pack:1 core:8 pu:1"), ..Craft::default() });
    let json = tmp.path().join("v.json");
    let mut args = regress_args(&base, &other);
    args.json = Some(json.clone());
    assert_eq!(regress::run(args.clone()).unwrap(), 2);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "incomparable");
    assert!(v["reason"].as_str().unwrap().contains("different machines"), "{v}");
    args.force = true;
    assert_eq!(regress::run(args).unwrap(), 0);
}

/// The campaign in `dir` as if measured on another host of the same hardware: its manifest's
/// identity gets the machine id `machine_id` (and another microcode and kernel), and its
/// rows and manifest the fingerprint that follows. Returns the new fingerprint.
fn move_to_host(dir: &Path, machine_id: &str) -> String {
    use mpm_bench::campaign::store::manifest;
    use mpm_bench::machine::fingerprint as fp;
    let path = dir.join("manifest.json");
    let mut m = manifest::read(&path).unwrap();
    let machine = mpm_bench::machine::topology::Machine::synthetic("pack:2 core:4 pu:1").unwrap();
    let mut id = mpm_host::identity::parse_cpuinfo("vendor_id : GenuineIntel\ncpu family : 6\nmodel : 15\n");
    id.machine_id_sha256 = Some(mpm_host::identity::sha256_hex(machine_id.as_bytes()));
    id.microcode = format!("0x{}", machine_id.len());
    id.kernel = format!("6.{}", machine_id.len());
    let new = fp::fingerprint_with(&machine, Some(&id));
    m.machine.fingerprint = new.clone();
    m.machine.hardware_class = Some(fp::hardware_class_with(&machine, Some(&id), vec!["avx2".into()]));
    m.machine.identity = Some(id);
    manifest::write(&path, &m).unwrap();
    let rows = read_rows(&dir.join("runs.csv")).unwrap();
    std::fs::remove_file(dir.join("runs.csv")).unwrap();
    let mut log = CsvLog::open(&dir.join("runs.csv")).unwrap();
    for mut r in rows {
        r.id.machine_id = new.clone();
        log.append(&r).unwrap();
    }
    new
}

/// Two campaigns of one hardware class measured on two hosts that differ only in their
/// machine id (two VMs of one runner type; microcode and kernel differ too) compare: exit 0,
/// both fingerprints kept in the verdict. Another CPU model is another class: exit 2
/// unless --force.
#[test]
fn regress_compares_two_machine_ids_of_one_hardware_class() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    let cur = write_campaign(&tmp.path().join("cur"), &Craft::default());
    let (fa, fb) = (move_to_host(&base, "machine-a"), move_to_host(&cur, "machine-b-other"));
    assert_ne!(fa, fb);
    let r = regress::evaluate(&regress_args(&base, &cur)).unwrap();
    assert_eq!(r.exit_code(), 0, "{}", r.reason);
    assert_eq!((r.baseline.fingerprint.as_str(), r.current.fingerprint.as_str()), (fa.as_str(), fb.as_str()));
    assert!(r.baseline.hardware_class.is_some() && r.baseline.hardware_class == r.current.hardware_class);
    assert!(regress::lines(&r).contains("two hosts of one hardware class"), "{}", regress::lines(&r));
    // Another CPU model: another class.
    let path = cur.join("manifest.json");
    let mut m = mpm_bench::campaign::store::manifest::read(&path).unwrap();
    m.machine.hardware_class.as_mut().unwrap().cpu_model = "85".into();
    mpm_bench::campaign::store::manifest::write(&path, &m).unwrap();
    let r = regress::evaluate(&regress_args(&base, &cur)).unwrap();
    assert_eq!(r.exit_code(), 2, "{}", r.reason);
    assert!(r.reason.contains("model 15 vs 85") && r.reason.contains("--force"), "{}", r.reason);
    let forced = regress::evaluate(&RegressOptions { force: true, ..regress_args(&base, &cur) }).unwrap();
    assert_eq!((forced.exit_code(), forced.forced), (0, true), "{}", forced.reason);
}

/// A CI job's first run has no baseline: an error by default (exit 2), a pass with
/// `--missing-baseline pass` ("no baseline yet; this run becomes it"), with the JSON and
/// Markdown verdicts written; a broken current campaign is still an error.
#[test]
fn regress_first_baseline_mode() {
    let tmp = tempfile::tempdir().unwrap();
    let cur = write_campaign(&tmp.path().join("cur"), &Craft::default());
    let nowhere = tmp.path().join("baseline");
    let (code, text) = regress_cli(&nowhere, &cur, &[]);
    assert_eq!(code, 2, "{text}");
    std::fs::create_dir_all(&nowhere).unwrap();
    let (json, md) = (tmp.path().join("v.json"), tmp.path().join("gate.md"));
    let (code, text) = regress_cli(
        &nowhere,
        &cur,
        &["--missing-baseline", "pass", "--json", json.to_str().unwrap(), "--markdown", md.to_str().unwrap()],
    );
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("no baseline yet (") && text.contains("holds no campaign); this run becomes it"), "{text}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!((v["verdict"].as_str(), v["no_baseline"].as_bool()), (Some("pass"), Some(true)), "{v}");
    assert!(std::fs::read_to_string(&md).unwrap().contains("PASS"));
    let (code, text) = regress_cli(&nowhere, &tmp.path().join("no-current"), &["--missing-baseline", "pass"]);
    assert_eq!(code, 2, "{text}");
    // With a baseline, the mode changes nothing.
    let other = write_campaign(&tmp.path().join("other"), &Craft::default());
    let (code, text) = regress_cli(&other, &cur, &["--missing-baseline", "pass"]);
    assert!(code == 0 && !text.contains("no baseline yet"), "{text}");
}

/// `mpm-bench regress` as CI runs it: the exit code and the console.
fn regress_cli(base: &Path, cur: &Path, extra: &[&str]) -> (i32, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
        .args(["regress", "--baseline", base.to_str().unwrap(), "--current", cur.to_str().unwrap()])
        .args(extra)
        .output()
        .unwrap();
    let text = format!("{}{}", String::from_utf8_lossy(&out.stdout), String::from_utf8_lossy(&out.stderr));
    assert!(!text.contains("panicked"), "{text}");
    (out.status.code().unwrap(), text)
}

#[test]
fn regress_exit_codes_of_the_binary() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    // 0: the same measurements in another folder.
    let same = write_campaign(&tmp.path().join("same"), &Craft::default());
    let (code, text) = regress_cli(&base, &same, &[]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("verdict: pass") && text.contains("Holm"), "{text}");
    // 1: parallel runs 25 % slower; every check line carries its units.
    let slow = write_campaign(&tmp.path().join("slow"), &Craft { slow_parallel: 1.25, ..Craft::default() });
    let json = tmp.path().join("v.json");
    let (code, text) = regress_cli(&base, &slow, &["--json", json.to_str().unwrap()]);
    assert_eq!(code, 1, "{text}");
    for line in text.lines().filter(|l| l.contains("REGRESSED")) {
        let has_unit = line.contains(" ms ") || line.contains(" µs ") || line.contains("efficiency");
        assert!(has_unit && line.contains(" x ") && line.contains('%'), "{line}");
    }
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    let c = &v["regressions"][0];
    assert!(c["ratio"]["lo"].is_number() && c["ratio"]["hi"].is_number() && c["p_worse_holm"].is_number(), "{c}");
    assert!(c["baseline"].is_number() && c["unit"].is_string(), "{c}");
    // 2: unreadable input, another machine, nothing in common, bad flags.
    let (code, text) = regress_cli(&base, &tmp.path().join("nowhere"), &[]);
    assert_eq!(code, 2, "{text}");
    let other =
        write_campaign(&tmp.path().join("other"), &Craft { topo: Some("pack:1 core:8 pu:1"), ..Craft::default() });
    let (code, text) = regress_cli(&base, &other, &[]);
    assert_eq!(code, 2, "{text}");
    assert!(text.contains("different machines"), "{text}");
    let disjoint = write_campaign(&tmp.path().join("disjoint"), &Craft { models: vec![5], ..Craft::default() });
    let (code, text) = regress_cli(&base, &disjoint, &[]);
    assert_eq!(code, 2, "{text}");
    assert!(text.contains("nothing to compare"), "{text}");
    let (code, text) = regress_cli(&base, &same, &["--tolerance", "3"]);
    assert_eq!(code, 2, "{text}");
}

#[test]
fn regress_fails_on_missing_or_failed_cells_unless_allowed() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    // The 8-thread cells were not run.
    let partial = write_campaign(&tmp.path().join("partial"), &Craft { threads: vec![1, 2, 4, 6], ..Craft::default() });
    let (code, text) = regress_cli(&base, &partial, &[]);
    assert_eq!(code, 1, "{text}");
    assert!(text.contains("MISSING") && text.contains("Model1 DD O3 8t") && text.contains("FAILS the gate"), "{text}");
    let (code, text) = regress_cli(&base, &partial, &["--allow-missing"]);
    assert_eq!(code, 0, "{text}");
    assert!(text.contains("allowed by --allow-missing"), "{text}");
    // The 6-thread runs crashed: failed cells are named with the reason.
    let crashed = write_campaign(&tmp.path().join("crashed"), &Craft { fail_threads: Some(6), ..Craft::default() });
    let r = regress::evaluate(&regress_args(&base, &crashed)).unwrap();
    assert_eq!(r.exit_code(), 1, "{}", r.reason);
    let m = r.missing_in_current.iter().find(|m| m.cell == "Model2 AE O0 6t").unwrap();
    assert_eq!(m.status, "failed");
    assert!(m.reason.contains("3 of 3") && m.reason.contains("status 101"), "{m:?}");
    assert!(r.regressions.is_empty(), "{:?}", r.regressions);
}

#[test]
fn regress_holm_correction_is_applied_over_the_cells() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    let r = regress::evaluate(&regress_args(&base, &base)).unwrap();
    let gated: Vec<_> = r.checks.iter().filter(|c| c.gated).collect();
    assert!(gated.len() > 10);
    // Holm never lowers a p-value, and raises the smallest by the number of checks.
    for c in &gated {
        assert!(c.p_worse_holm.unwrap() >= c.p_worse.unwrap());
    }
    let smallest = gated.iter().min_by(|a, b| a.p_worse.unwrap().total_cmp(&b.p_worse.unwrap())).unwrap();
    let expect = (smallest.p_worse.unwrap() * gated.len() as f64).min(1.0);
    assert!((smallest.p_worse_holm.unwrap() - expect).abs() < 1e-12, "{smallest:?}");
}

#[test]
fn bandwidth_smoke() {
    let args =
        bandwidth::BandwidthOptions { threads: vec![1, 2], pin: vec!["close".into()], size_mib: 2, reps: 2, out: None };
    let r = bandwidth::measure_all(&args).unwrap();
    assert_eq!(r.results.len(), 2);
    assert!(r.results.iter().all(|p| p.best_gb_s > 0.0 && p.best_gb_s >= p.worst_gb_s));
    assert_eq!(r.bytes_per_element, 24);
}

/// Every campaign committed under results/ (whatever its CSV schema) loads in every
/// analysis command: `figures`, `claims`, `regress` against itself (which passes) and
/// `report`, through the real binary.
#[test]
fn every_committed_campaign_loads_in_every_analysis_command() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results");
    let mut dirs = Vec::new();
    let mut stack = vec![root];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            if e.path().is_dir() {
                stack.push(e.path());
            } else if e.file_name() == "runs.csv" {
                dirs.push(d.clone());
            }
        }
    }
    assert!(dirs.len() >= 5, "{dirs:?}");
    let tmp = tempfile::tempdir().unwrap();
    for (i, d) in dirs.iter().enumerate() {
        let out = tmp.path().join(i.to_string());
        let dir = d.to_str().unwrap();
        let run = |args: &[&str]| {
            let o = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench")).args(args).output().unwrap();
            (o.status.code(), String::from_utf8_lossy(&o.stderr).into_owned())
        };
        let figs = out.join("figures");
        let (code, err) = run(&["figures", "--results", dir, "--out", figs.to_str().unwrap()]);
        assert_eq!(code, Some(0), "figures of {dir}: {err}");
        let (code, err) = run(&["claims", "--results", dir]);
        assert_eq!(code, Some(0), "claims of {dir}: {err}");
        let (code, err) = run(&["regress", "--baseline", dir, "--current", dir]);
        assert_eq!(code, Some(0), "regress of {dir} against itself: {err}");
        let rep = out.join("report");
        let (code, err) = run(&["report", "--results", dir, "--out", rep.to_str().unwrap()]);
        assert_eq!(code, Some(0), "report of {dir}: {err}");
        assert!(rep.join("index.html").is_file());
    }
}

/// The tables made from committed JSON summaries load them: `impact-table` on
/// results/impact and `roofline-table` on the roofline runs with their bandwidth ceiling.
#[test]
fn every_committed_table_source_loads() {
    let results = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results");
    let run = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench")).args(args).output().unwrap();
        (
            o.status.code(),
            String::from_utf8_lossy(&o.stdout).into_owned(),
            String::from_utf8_lossy(&o.stderr).into_owned(),
        )
    };
    let impact = results.join("impact");
    let (code, out, err) = run(&["impact-table", "--results", impact.to_str().unwrap()]);
    assert_eq!(code, Some(0), "impact-table: {err}");
    assert!(out.lines().filter(|l| l.starts_with("| ")).count() >= 5, "{out}");
    let roof = results.join("roofline");
    let mut args = vec!["roofline-table".to_string()];
    for e in std::fs::read_dir(&roof).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with("model") && name.ends_with(".json") {
            args.extend(["--summary".to_string(), e.path().display().to_string()]);
        }
    }
    assert!(args.len() >= 7, "{args:?}");
    args.extend(["--bandwidth".to_string(), roof.join("bandwidth.json").display().to_string()]);
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let (code, out, err) = run(&args);
    assert_eq!(code, Some(0), "roofline-table: {err}");
    assert!(out.contains("**step**"), "{out}");
}

/// The stage panels use the steady-state stage times: a 1-thread run whose one warm-up step
/// took most of its particle stage (as Model 4's set-up step did) gives that stage a speedup
/// within the 2 cores, where the whole-run times gave 5.5; a speedup above the cores (here
/// one forced by a slow base run's steady times) is flagged on the point, crossed out in the
/// figure and listed in points.csv; rows without steady stage times give no stage point,
/// and the analysis says so.
#[test]
fn stage_speedups_are_steady_state_and_impossible_ones_flagged() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("m4");
    std::fs::create_dir_all(&dir).unwrap();
    let fp = fingerprint(Some("pack:1 core:2 pu:1"));
    let mut log = mpm_bench::campaign::store::csv::CsvLog::open(&dir.join("runs.csv")).unwrap();
    // Model 4, DD, 3 steps with 1 warm-up; per steady step 2.0 s grid + 3.0 s particle at one
    // thread, half that at two (pinned to CPUs 0 and 1); the 1-thread warm-up step spent
    // 21 s in the particle stage. Model 3: a base run 6x slow in its steady state.
    for (model, threads, grid, particle, warm_particle) in
        [(4, 1, 2.0, 3.0, 21.0), (4, 2, 1.0, 1.5, 1.5), (3, 1, 6.0, 6.0, 6.0), (3, 2, 0.5, 0.5, 0.5)]
    {
        for rep in 0..3 {
            let mut r = planned_row(&dir, &fp, model, DD, "o3", threads, rep, "close", 3);
            r.run.spec.budget.warmup = Some(1);
            r.placement.requested_cpus = (0..threads).collect();
            r.outcome.status = Status::Ok;
            let f = r.measured_mut();
            (f.progress.steps, f.progress.steady_steps) = (3, 2);
            let m = &mut f.timing;
            m.grid_stage_s = 3.0 * grid;
            m.particle_stage_s = 2.0 * particle + warm_particle;
            m.steady_grid_stage_s = Some(2.0 * grid);
            m.steady_particle_stage_s = Some(2.0 * particle);
            m.steady_s_per_step = Some(grid + particle);
            m.wall_s = 3.0 * (grid + particle) + warm_particle;
            log.append(&r).unwrap();
        }
    }
    drop(log);
    let c = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    let an = c.analyse(None);
    let p4 = an.point(4, DD, "o3", 2, Stage::Particle).unwrap();
    let s4 = p4.speedup.unwrap().value;
    assert!((s4 - 2.0).abs() < 1e-9 && p4.flags.is_empty(), "Model 4 particle stage: {s4}, {:?}", p4.flags);
    let p3 = an.point(3, DD, "o3", 2, Stage::Total).unwrap();
    assert!(p3.speedup.unwrap().value > 11.0 && !p3.flags.is_empty(), "{p3:?}");
    assert!(p3.flags[0].contains("above the 2 physical core(s)"), "{:?}", p3.flags);
    assert!(!p3.is_real_parallel(), "a flagged point is no evidence of scaling");
    let out = tmp.path().join("figs");
    figures::run(FiguresOptions {
        results: dir.clone(),
        out: out.clone(),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap();
    let mut rdr = csv::Reader::from_path(out.join("points.csv")).unwrap();
    let rows: Vec<std::collections::HashMap<String, String>> = rdr.deserialize().map(Result::unwrap).collect();
    let get = |fig: &str, panel: &str, model: &str| {
        rows.iter()
            .find(|r| r["figure"] == fig && r["panel"] == panel && r["model"] == model && r["threads"] == "2")
            .unwrap_or_else(|| panic!("{fig} {panel} Model{model}"))
            .clone()
    };
    let pt = get("fig11", "particle", "4");
    assert_eq!((pt["value"].parse::<f64>().unwrap(), pt["flags"].as_str()), (2.0, ""));
    assert!(get("fig11", "total", "3")["flags"].contains("above the 2 physical core(s)"));
    assert!(std::fs::read_to_string(out.join("README.md")).unwrap().contains("flagged"));
    // The same rows without steady stage times (written before schema 6): no stage point.
    let rows: Vec<_> = mpm_bench::campaign::store::csv::read_rows(&dir.join("runs.csv"))
        .unwrap()
        .into_iter()
        .map(|mut r| {
            r.measured_mut().timing.steady_grid_stage_s = None;
            r.measured_mut().timing.steady_particle_stage_s = None;
            r
        })
        .collect();
    let an = mpm_bench::analysis::stats::Analysis::from_rows(&rows, None, &Default::default());
    assert!(an.point(4, DD, "o3", 2, Stage::Particle).is_none());
    assert!(an.point(4, DD, "o3", 2, Stage::Total).is_some());
    assert!(an.notes.iter().any(|n| n.contains("no steady-state stage times")), "{:?}", an.notes);
}

/// The flag counts physical cores: a 2-thread speedup of 1.8 on two SMT siblings of one
/// core (schema 10's `physical_cores`) is flagged and says so; the same on two cores, or
/// on a row that predates the column (its distinct CPUs count), is plain data.
#[test]
fn smt_siblings_count_as_one_core() {
    let point = |physical: Option<usize>| {
        let tmp = tempfile::tempdir().unwrap();
        let dir = tmp.path().join("smt");
        std::fs::create_dir_all(&dir).unwrap();
        let fp = fingerprint(Some("pack:1 core:1 pu:2"));
        let mut log = CsvLog::open(&dir.join("runs.csv")).unwrap();
        for (threads, step) in [(1, 1.8), (2, 1.0)] {
            for rep in 0..3 {
                let mut r = planned_row(&dir, &fp, 2, DD, "o3", threads, rep, "close", 3);
                r.placement.requested_cpus = (0..threads).collect();
                r.placement.physical_cores = physical.map(|p: usize| p.min(threads));
                r.outcome.status = Status::Ok;
                let f = r.measured_mut();
                (f.progress.steps, f.progress.steady_steps) = (3, 3);
                f.timing.steady_s_per_step = Some(step);
                f.timing.wall_s = 3.0 * step;
                log.append(&r).unwrap();
            }
        }
        drop(log);
        let an = analysis(&dir);
        an.point(2, DD, "o3", 2, Stage::Total).unwrap().flags.clone()
    };
    let flags = point(Some(1));
    assert_eq!(flags.len(), 1, "{flags:?}");
    assert!(flags[0].contains("above the 1 physical core(s)") && flags[0].contains("SMT siblings"), "{flags:?}");
    assert!(point(Some(2)).is_empty());
    assert!(point(None).is_empty(), "a row before schema 10: its 2 CPUs count");
}

/// The margin's measurement: no speedup in the committed campaigns' figures (their runs one
/// worker per core, none oversubscribed) exceeds [`SUPERLINEAR_MARGIN`] per thread, the
/// largest cache effect measured so far (DD's smaller blocks on Model 4) included.
#[test]
fn committed_speedups_stay_within_the_margin() {
    use mpm_bench::analysis::stats::SUPERLINEAR_MARGIN;
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut files = Vec::new();
    let mut stack = vec![root.join("results"), root.join("paper-figures")];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().map(Result::unwrap) {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.file_name().is_some_and(|n| n == "points.csv") {
                files.push(p);
            }
        }
    }
    assert!(files.len() >= 2, "{files:?}");
    let (mut worst, mut seen) = ((0.0f64, String::new()), 0);
    for f in &files {
        let mut rdr = csv::Reader::from_path(f).unwrap();
        for r in rdr.deserialize::<std::collections::HashMap<String, String>>().map(Result::unwrap) {
            let threads: f64 = r["threads"].parse().unwrap();
            if r["metric"] != "speedup" || r["oversubscribed"] == "true" || threads < 2.0 {
                continue;
            }
            seen += 1;
            let per = r["value"].parse::<f64>().unwrap() / threads;
            if per > worst.0 {
                worst = (
                    per,
                    format!("{}: {} {} Model{} {}", f.display(), r["figure"], r["panel"], r["model"], r["strategy"]),
                );
            }
        }
    }
    assert!(seen > 20, "{seen} speedups read");
    assert!(worst.0 > 1.0 && worst.0 < SUPERLINEAR_MARGIN, "largest speedup per core {:.3} ({})", worst.0, worst.1);
}

/// Cells of different step budgets (a quick campaign against a smoke one) are refused, exit
/// 2, naming the keys that differ, whatever the times say; the same budget compares.
#[test]
fn regress_refuses_campaigns_of_different_budgets() {
    let tmp = tempfile::tempdir().unwrap();
    let base = write_campaign(&tmp.path().join("base"), &Craft::default());
    let other = tmp.path().join("other");
    std::fs::create_dir_all(&other).unwrap();
    std::fs::copy(base.join("manifest.json"), other.join("manifest.json")).unwrap();
    let mut log = CsvLog::open(&other.join("runs.csv")).unwrap();
    for mut r in read_rows(&base.join("runs.csv")).unwrap() {
        r.run.spec.budget.steps = Some(100);
        r.run.spec.budget.warmup = Some(5);
        log.append(&r).unwrap();
    }
    drop(log);
    let r = regress::evaluate(&regress_args(&base, &other)).unwrap();
    assert_eq!(r.exit_code(), 2, "{}", r.reason);
    assert!(
        r.reason.contains("budget.steps 100 instead of 10") && r.reason.contains("budget.warmup 5 instead of 0"),
        "{}",
        r.reason
    );
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
        .args(["regress", "--baseline", base.to_str().unwrap(), "--current", other.to_str().unwrap()])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert_eq!(regress::evaluate(&regress_args(&base, &base)).unwrap().exit_code(), 0);
}

/// A campaign whose runs ran on two machines (a cluster's node types under `--scheduler
/// slurm`) is analysed machine by machine: each part holds one machine's rows and finds the
/// speedups that machine alone gives, with that machine's facts from the manifest's nodes;
/// `figures` writes each machine's figures apart, `claims` judges each, `report` shows them
/// as two sets, and `regress` refuses the mix.
#[test]
fn runs_of_several_machines_are_split_by_fingerprint() {
    use mpm_bench::analysis::results::load_campaigns;
    use mpm_bench::campaign::store::manifest::{self, NodeInfo};
    use mpm_bench::machine::fingerprint;
    use mpm_bench::machine::topology::Machine;
    use mpm_bench::report::comparison::{self, ReportOptions};
    let tmp = tempfile::tempdir().unwrap();
    let (ta, tb) = ("pack:2 core:4 pu:1", "pack:1 core:8 pu:1");
    let a = write_campaign(
        &tmp.path().join("a").join("camp"),
        &Craft { topo: Some(ta), models: vec![1, 2], ..Craft::default() },
    );
    let b = write_campaign(
        &tmp.path().join("b").join("camp"),
        &Craft { topo: Some(tb), models: vec![1, 2], slow_parallel: 1.3, ..Craft::default() },
    );
    let (fa, fb) = (fingerprint(Some(ta)), fingerprint(Some(tb)));
    // One folder with both machines' rows, interleaved as jobs end, and a manifest written
    // by a third machine (the login node) that names both nodes' machines.
    let both = tmp.path().join("slurm-c").join("camp");
    std::fs::create_dir_all(&both).unwrap();
    let (ra, rb) = (read_rows(&a.join("runs.csv")).unwrap(), read_rows(&b.join("runs.csv")).unwrap());
    let mut log = CsvLog::open(&both.join("runs.csv")).unwrap();
    for (x, y) in ra.iter().zip(&rb) {
        log.append(x).unwrap();
        log.append(y).unwrap();
    }
    write_manifest(&both, "pack:1 core:2 pu:1");
    let mut man = manifest::read(&both.join("manifest.json")).unwrap();
    for (fp, t) in [(&fa, ta), (&fb, tb)] {
        let machine = fingerprint::machine_info(&Machine::synthetic(t).unwrap());
        man.nodes.insert(fp.clone(), NodeInfo { node: format!("node-{t}"), machine, topology: String::new() });
    }
    manifest::write(&both.join("manifest.json"), &man).unwrap();

    let parts = load_campaigns(&both, &RowFilter::analysis(false)).unwrap();
    assert_eq!(parts.len(), 2);
    let speedups = |an: &Analysis| -> Vec<(CellKey, Option<f64>)> {
        an.points
            .iter()
            .filter(|p| p.stage == Stage::Total)
            .map(|p| (p.key.clone(), p.speedup.map(|s| s.value)))
            .collect()
    };
    for (part, (fp, alone)) in
        parts.iter().zip([(&fa, &a), (&fb, &b)].into_iter().collect::<std::collections::BTreeMap<_, _>>())
    {
        assert_eq!(&part.fingerprint(), fp);
        assert!(part.all_rows().all(|r| &r.id.machine_id == fp));
        assert_eq!(
            part.manifest.as_ref().unwrap().machine.fingerprint,
            *fp,
            "the node's machine, not the login node's"
        );
        assert_eq!(part.label(), format!("camp@{fp}"));
        assert_eq!(speedups(&part.analyse(None)), speedups(&analysis(alone)), "machine {fp} as if alone");
        assert!(part.analyse(None).notes.iter().all(|n| !n.contains("machines")), "{:?}", part.analyse(None).notes);
    }
    let err = format!("{:#}", load_campaign(&both, &RowFilter::analysis(false)).unwrap_err());
    assert!(err.contains("2 machines") && err.contains(&fa) && err.contains(&fb), "{err}");

    let out = tmp.path().join("figs");
    figures::run(FiguresOptions {
        results: both.clone(),
        out: out.clone(),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap();
    for fp in [&fa, &fb] {
        assert!(out.join(fp).join("fig07.svg").is_file(), "figures of {fp}");
        assert!(std::fs::read_to_string(out.join(fp).join("README.md")).unwrap().contains(fp.as_str()));
    }
    assert!(!out.join("fig07.svg").exists(), "no figure mixes the machines");

    let md = tmp.path().join("claims.md");
    let args = claims::ClaimsOptions {
        results: both.clone(),
        markdown: Some(md.clone()),
        pin: None,
        include_noisy: false,
        include_injected: false,
    };
    claims::run(args).unwrap();
    let text = std::fs::read_to_string(&md).unwrap();
    assert!(text.contains(&format!("## Machine `{fa}`")) && text.contains(&format!("## Machine `{fb}`")), "{text}");

    let report = comparison::build(&ReportOptions {
        dirs: vec![both.clone()],
        out: tmp.path().join("report"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap();
    assert_eq!(report.comparisons.len(), 1, "two sets, one comparison");
    let md = report.page.to_markdown();
    assert!(md.contains(&fa) && md.contains(&fb));
}

/// `claims` on a campaign with no usable row (every run failed) is an error naming the
/// folder and its rows by status, never a table of "cannot tell" with exit status 0.
#[test]
fn claims_refuse_a_campaign_without_a_usable_row() {
    use mpm_core::Strategy;
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().join("failed");
    std::fs::create_dir_all(&dir).unwrap();
    let fp = fingerprint(None);
    let mut log = CsvLog::open(&dir.join("runs.csv")).unwrap();
    for threads in [1, 2] {
        log.append(&failed_row(&dir, &fp, 1, Strategy::DomainDecomposition, "o3", threads, 0)).unwrap();
    }
    let args = claims::ClaimsOptions {
        results: dir.clone(),
        markdown: None,
        pin: None,
        include_noisy: false,
        include_injected: false,
    };
    let err = format!("{:#}", claims::run(args).unwrap_err());
    assert!(err.contains("no usable row") && err.contains("2 failed"), "{err}");
    assert!(err.contains(&dir.display().to_string()) && err.contains("reason"), "{err}");
}

/// A run key written twice (`ok` rows of one planned run appended again) counts once in
/// the analyses: the campaign loads with the rows it had, each cell's repetitions unchanged.
#[test]
fn a_repeated_run_key_counts_once() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_campaign(&tmp.path().join("twice"), &Craft::default());
    let once = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    let csv = dir.join("runs.csv");
    let again: Vec<Row> = read_rows(&csv).unwrap().into_iter().filter(|r| r.outcome.status == Status::Ok).collect();
    assert!(!again.is_empty());
    let mut log = CsvLog::open(&csv).unwrap();
    for r in &again {
        log.append(r).unwrap();
    }
    let twice = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    assert_eq!(twice.rows, once.rows, "the repeated rows are left out");
}
