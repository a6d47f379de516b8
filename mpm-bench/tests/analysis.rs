//! Integration tests of the analysis commands (stats, figures, claims, regress, report,
//! bandwidth) on crafted campaigns written with the real CSV writer.

use mpm_bench::analysis::claims::{self, Verdict};
use mpm_bench::analysis::regress::{self, Outcome, RegressArgs};
use mpm_bench::analysis::results::load_campaign;
use mpm_bench::analysis::stats::{Analysis, CellKey, Stage, StatsOptions};
use mpm_bench::campaign::manifest::{self, GitInfo, Manifest, SoftwareInfo, MANIFEST_VERSION};
use mpm_bench::campaign::record::{CsvLog, Row, Status, SCHEMA_VERSION};
use mpm_bench::machine::bandwidth;
use mpm_bench::machine::fingerprint;
use mpm_bench::machine::topology::Machine;
use mpm_bench::report::comparison::{self as report, ReportArgs};
use mpm_bench::report::figures::{self, FiguresArgs};
use mpm_core::Strategy;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

const AE: Strategy = Strategy::ArrayExpansion;
const DD: Strategy = Strategy::DomainDecomposition;
const DDB: Strategy = Strategy::DdBalanced;

/// How a crafted campaign is made.
#[derive(Clone)]
struct Craft {
    /// hwloc synthetic topology of the manifest (None: no manifest).
    topo: Option<&'static str>,
    models: Vec<u32>,
    threads: Vec<usize>,
    /// Threads above this are oversubscribed.
    cores: usize,
    /// Cores per socket (efficiency drops past it).
    per_socket: usize,
    reps: u32,
    /// Multiplicative noise per repetition.
    noise: Vec<f64>,
    /// Factor on every time with more than one thread.
    slow_parallel: f64,
    /// Factor on every time.
    slow_all: f64,
    /// Skip Model4 AE at 4+ threads (memory guard).
    skip_m4_ae: bool,
    pin: &'static str,
}

impl Default for Craft {
    fn default() -> Self {
        Self {
            topo: Some("pack:2 core:4 pu:1"),
            models: vec![1, 2, 3, 4],
            threads: vec![1, 2, 4, 6, 8],
            cores: 8,
            per_socket: 4,
            reps: 3,
            noise: vec![1.0, 1.01, 0.99],
            slow_parallel: 1.0,
            slow_all: 1.0,
            skip_m4_ae: true,
            pin: "close",
        }
    }
}

/// Stage efficiencies of the crafted machine: DD beats AE, more so for larger models; AE's
/// grid stage is its bottleneck; O0 scales better than O3; crossing a socket costs 20 %.
fn eff(model: u32, strategy: Strategy, opt: &str, particle: bool, n: usize, per_socket: usize) -> f64 {
    if n == 1 {
        return 1.0;
    }
    let mut e = match (strategy, particle) {
        (AE, false) => 0.75 - 0.1 * model as f64,
        (AE, true) => 0.93,
        // Balanced cuts: less waiting for the fullest patch (claim C7).
        (DDB, false) => 0.95,
        (DDB, true) => 0.97,
        (_, false) => 0.9,
        (_, true) => 0.95,
    };
    if opt == "o0" {
        e = 1.0 - 0.5 * (1.0 - e);
    }
    if n > per_socket {
        e *= 0.8;
    }
    e
}

fn fingerprint(topo: Option<&str>) -> String {
    topo.map(|t| fingerprint::fingerprint(&Machine::synthetic(t).unwrap())).unwrap_or_else(|| "nomanifest".into())
}

fn write_campaign(dir: &Path, c: &Craft) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let fp = fingerprint(c.topo);
    let mut log = CsvLog::open(&dir.join("runs.csv")).unwrap();
    for &m in &c.models {
        let (g1, p1) = (0.004 * m as f64, 0.006 * m as f64);
        for strategy in [AE, DD, DDB] {
            for opt in ["o3", "o0"] {
                let slow = if opt == "o0" { 5.0 } else { 1.0 };
                for &n in &c.threads {
                    for rep in 0..c.reps {
                        let noise = c.noise[rep as usize % c.noise.len()];
                        let par = if n > 1 { c.slow_parallel } else { 1.0 };
                        let k = slow * noise * par * c.slow_all;
                        let g = g1 * k / (n as f64 * eff(m, strategy, opt, false, n, c.per_socket));
                        let p = p1 * k / (n as f64 * eff(m, strategy, opt, true, n, c.per_socket));
                        let mem = 1e8 * m as f64 + if strategy == AE { 3e7 * m as f64 * (n - 1) as f64 } else { 1e6 };
                        let skip = c.skip_m4_ae && m == 4 && strategy == AE && n >= 4;
                        let steps = 10u64;
                        let row = Row {
                            schema_version: SCHEMA_VERSION,
                            campaign_id: dir.file_name().unwrap().to_string_lossy().into_owned(),
                            run_id: format!("m{m}-{strategy}-{opt}-t{n}-r{rep}"),
                            machine_id: fp.clone(),
                            scenario: "taylor".into(),
                            model: m,
                            particles: Some(10_000 * m as u64),
                            nodes: Some(5_000 * m as u64),
                            mean_nodes: Some(5_000.0 * m as f64),
                            grid_mode: "fixed".into(),
                            strategy,
                            opt_level: opt.into(),
                            threads: n,
                            pin_policy: c.pin.into(),
                            oversubscribed: n > c.cores,
                            rep,
                            steps: if skip { None } else { Some(steps) },
                            wall_s: (!skip).then_some((g + p) * steps as f64),
                            grid_stage_s: (!skip).then_some(g * steps as f64),
                            particle_stage_s: (!skip).then_some(p * steps as f64),
                            steady_s_per_step: (!skip).then_some(g + p),
                            peak_rss_bytes: (!skip).then_some((mem * 1.0) as u64),
                            mem_estimate_bytes: if skip { 9_500_000_000 } else { mem as u64 },
                            dd_work_imbalance: match strategy {
                                DD => Some(1.0 + 0.05 * (n - 1) as f64),
                                DDB => Some(1.0 + 0.002 * (n - 1) as f64),
                                _ => None,
                            },
                            status: if skip { Status::Skipped } else { Status::Ok },
                            reason: if skip {
                                "memory guard: estimated 9.5 GB exceeds the limit".into()
                            } else {
                                String::new()
                            },
                            ..Row::default()
                        };
                        log.append(&row).unwrap();
                    }
                }
            }
        }
    }
    if let Some(t) = c.topo {
        write_manifest(dir, t);
    }
    dir.to_path_buf()
}

/// The manifest of a crafted campaign on the hwloc synthetic topology `t` (16 GiB).
fn write_manifest(dir: &Path, t: &str) {
    let machine = Machine::synthetic(t).unwrap();
    let mut info = fingerprint::machine_info(&machine);
    info.memory_bytes = 16 << 30;
    let m = Manifest {
        manifest_version: MANIFEST_VERSION,
        campaign_id: dir.file_name().unwrap().to_string_lossy().into_owned(),
        campaign: serde_json::Value::Null,
        machine: info,
        software: SoftwareInfo {
            rustc: "rustc test".into(),
            cargo_profiles: serde_json::Value::Null,
            rustflags: String::new(),
            binaries: vec![],
            env: BTreeMap::new(),
            hwloc_api: "2.9.0".into(),
            harness_version: "test".into(),
            git: GitInfo::default(),
        },
        sessions: vec![],
    };
    manifest::write(&dir.join("manifest.json"), &m).unwrap();
}

fn analysis(dir: &Path) -> Analysis {
    load_campaign(dir).unwrap().analyse(None)
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
    figures::run(FiguresArgs { results: results.clone(), out: out.clone(), pin: None }).unwrap();
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
    let err = figures::run(FiguresArgs { results: tmp.path().join("nope"), out: tmp.path().join("o"), pin: None })
        .unwrap_err();
    assert!(format!("{err:#}").contains("does not exist"), "{err:#}");
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    let err = figures::run(FiguresArgs { results: empty, out: tmp.path().join("o"), pin: None }).unwrap_err();
    assert!(format!("{err:#}").contains("no runs.csv"), "{err:#}");
    let bad = tmp.path().join("bad");
    std::fs::create_dir_all(&bad).unwrap();
    std::fs::write(bad.join("runs.csv"), "model,threads\n1,1\n").unwrap();
    let err = figures::run(FiguresArgs { results: bad, out: tmp.path().join("o"), pin: None }).unwrap_err();
    assert!(format!("{err:#}").contains("missing column"), "{err:#}");
}

fn verdicts(dir: &Path) -> Vec<(String, Verdict)> {
    let c = load_campaign(dir).unwrap();
    let an = c.analyse(None);
    claims::evaluate(&c, &an).into_iter().map(|r| (r.id.to_string(), r.verdict)).collect()
}

#[test]
fn claims_on_a_crafted_two_socket_machine() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_campaign(&tmp.path().join("c"), &Craft::default());
    let v = verdicts(&dir);
    for (id, verdict) in &v {
        assert_eq!(*verdict, Verdict::Holds, "{id}: {v:?}");
    }
    let c = load_campaign(&dir).unwrap();
    let res = claims::evaluate(&c, &c.analyse(None));
    let md = claims::markdown(&res, "##");
    assert!(md.contains("| C5 |") && md.contains("**holds**"));
    assert!(!res[0].evidence.is_empty());
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

fn regress_args(base: &Path, cur: &Path) -> RegressArgs {
    RegressArgs {
        baseline: base.to_path_buf(),
        current: cur.to_path_buf(),
        tolerance: 0.05,
        force: false,
        json: None,
        stages: vec!["total".into()],
        include_oversubscribed: false,
        pin: None,
    }
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

    // Parallel runs 25 % slower: efficiency x 0.8.
    let cur = write_campaign(&tmp.path().join("drop"), &Craft { slow_parallel: 1.25, ..Craft::default() });
    let mut args = regress_args(&base, &cur);
    args.json = Some(json.clone());
    assert_eq!(regress::run(args).unwrap(), 1);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "fail");
    let regs = v["regressions"].as_array().unwrap();
    assert!(regs.iter().any(|r| r["metric"] == "efficiency"));
    let r = regress::evaluate(&regress_args(&base, &cur)).unwrap();
    let eff = r.regressions.iter().find(|c| c.metric == "efficiency").unwrap();
    assert!((eff.ratio.value - 0.8).abs() < 1e-9, "{:?}", eff.ratio);
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
    let c = r.checks.iter().find(|c| c.metric == "time_per_step" && c.cell.threads == 1).unwrap();
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
    let err = regress::run(args.clone()).unwrap_err();
    assert!(format!("{err:#}").contains("different machines"), "{err:#}");
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "incomparable");
    args.force = true;
    assert_eq!(regress::run(args).unwrap(), 0);
}

#[test]
fn report_compares_two_machines() {
    let tmp = tempfile::tempdir().unwrap();
    let a = write_campaign(&tmp.path().join("a"), &Craft::default());
    let b = write_campaign(
        &tmp.path().join("b"),
        &Craft { topo: Some("pack:1 core:2 pu:1"), cores: 2, per_socket: 2, slow_parallel: 1.1, ..Craft::default() },
    );
    let out = tmp.path().join("rep").join("compare.md");
    report::run(ReportArgs { dirs: vec![a, b], out: out.clone(), pin: None }).unwrap();
    let md = std::fs::read_to_string(&out).unwrap();
    for needle in
        ["## Machines", "Base time T1", "### AE O3", "## The paper's claims per machine", "compare-eff-dd-o3.png"]
    {
        assert!(md.contains(needle), "missing {needle}");
    }
    let png = std::fs::read(out.parent().unwrap().join("compare-eff-dd-o3.png")).unwrap();
    assert_eq!(&png[..4], b"\x89PNG");
}

#[test]
fn report_uses_a_bandwidth_json_when_present() {
    let tmp = tempfile::tempdir().unwrap();
    let a = write_campaign(&tmp.path().join("a"), &Craft::default());
    let bw = bandwidth::BandwidthReport {
        kernel: "stream-triad".into(),
        machine_id: "x".into(),
        cpu_model: "test".into(),
        packages: 2,
        cores: 8,
        llc_bytes: 1 << 20,
        array_bytes: 1 << 26,
        elements: 1 << 23,
        reps: 10,
        bytes_per_element: 24,
        debug_build: false,
        timestamp: "now".into(),
        results: [1usize, 2, 4, 6, 8]
            .iter()
            .map(|&t| bandwidth::BandwidthPoint {
                threads: t,
                pin: "close".into(),
                requested_cpus: vec![],
                observed_cpus: vec![],
                oversubscribed: false,
                verified: None,
                best_gb_s: 10.0 * t as f64,
                median_gb_s: 9.0 * t as f64,
                worst_gb_s: 8.0 * t as f64,
                best_s: 0.01,
            })
            .collect(),
    };
    std::fs::write(a.join("bandwidth.json"), serde_json::to_string(&bw).unwrap()).unwrap();
    let out = tmp.path().join("r.md");
    report::run(ReportArgs { dirs: vec![a], out: out.clone(), pin: None }).unwrap();
    let md = std::fs::read_to_string(&out).unwrap();
    assert!(md.contains("STREAM triad ceiling"), "{md}");
    assert!(md.contains("% of ceiling"));
}

#[test]
fn bandwidth_smoke() {
    let args =
        bandwidth::BandwidthArgs { threads: vec![1, 2], pin: vec!["close".into()], size_mib: 2, reps: 2, out: None };
    let r = bandwidth::measure_all(&args).unwrap();
    assert_eq!(r.results.len(), 2);
    assert!(r.results.iter().all(|p| p.best_gb_s > 0.0 && p.best_gb_s >= p.worst_gb_s));
    assert_eq!(r.bytes_per_element, 24);
}

/// Run every analysis command on a real campaign: `MPM_ANALYSIS_DIR=... cargo test ... -- --ignored`.
#[test]
#[ignore]
fn on_campaign_from_env() {
    let Ok(dir) = std::env::var("MPM_ANALYSIS_DIR") else { return };
    let out = PathBuf::from(std::env::var("MPM_ANALYSIS_OUT").unwrap_or_else(|_| "/tmp/mpm-analysis".into()));
    figures::run(FiguresArgs { results: dir.clone().into(), out: out.join("figures"), pin: None }).unwrap();
    claims::run(claims::ClaimsArgs { results: dir.clone().into(), markdown: Some(out.join("claims.md")), pin: None })
        .unwrap();
    let code = regress::run(RegressArgs {
        json: Some(out.join("regress.json")),
        ..regress_args(Path::new(&dir), Path::new(&dir))
    })
    .unwrap();
    assert_eq!(code, 0);
    report::run(ReportArgs { dirs: vec![dir.clone().into(), dir.into()], out: out.join("report.md"), pin: None })
        .unwrap();
}
