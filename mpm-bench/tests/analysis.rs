//! Integration tests of the analysis commands (stats, figures, claims, regress, report,
//! bandwidth) on crafted campaigns written with the real CSV writer.

use mpm_bench::analysis::claims::{self, Verdict};
use mpm_bench::analysis::regress::{self, Outcome, RegressArgs};
use mpm_bench::analysis::results::load_campaign;
use mpm_bench::analysis::stats::{Analysis, CellKey, Stage, StatsOptions};
use mpm_bench::campaign::manifest::{self, GitInfo, Manifest, SoftwareInfo, MANIFEST_VERSION};
use mpm_bench::campaign::record::{read_rows, CsvLog, Row, Status, SCHEMA_VERSION};
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
    /// Every repetition at this thread count failed (the solver crashed).
    fail_threads: Option<usize>,
    /// O0's parallel loss relative to O3's (below 1: O0 scales better).
    o0_loss: f64,
    /// Parallel efficiency of DD's grid stage.
    dd_grid_eff: f64,
    /// Parallel efficiency of AE's particle stage.
    ae_particle_eff: f64,
    /// Bytes of AE's nodal copies per extra thread and model number.
    ae_copy_bytes: f64,
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
            fail_threads: None,
            o0_loss: 0.3,
            dd_grid_eff: 0.9,
            ae_particle_eff: 0.93,
            ae_copy_bytes: 3e7,
        }
    }
}

/// Stage efficiencies of the crafted machine: DD beats AE, more so for larger models; AE's
/// grid stage is its bottleneck; O0 scales better than O3; crossing a socket costs 20 %.
fn eff(model: u32, strategy: Strategy, opt: &str, particle: bool, n: usize, c: &Craft) -> f64 {
    if n == 1 {
        return 1.0;
    }
    let mut e = match (strategy, particle) {
        (AE, false) => 0.75 - 0.1 * model as f64,
        (AE, true) => c.ae_particle_eff,
        // Balanced cuts: less waiting for the fullest patch (claim C7).
        (DDB, false) => c.dd_grid_eff + 0.05,
        (DDB, true) => 0.97,
        (_, false) => c.dd_grid_eff,
        (_, true) => 0.95,
    };
    if opt == "o0" {
        e = 1.0 - c.o0_loss * (1.0 - e);
    }
    if n > c.per_socket {
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
                        let g = g1 * k / (n as f64 * eff(m, strategy, opt, false, n, c));
                        let p = p1 * k / (n as f64 * eff(m, strategy, opt, true, n, c));
                        let mem = 1e8 * m as f64
                            + if strategy == AE { c.ae_copy_bytes * m as f64 * (n - 1) as f64 } else { 1e6 };
                        let skip = c.skip_m4_ae && m == 4 && strategy == AE && n >= 4;
                        let steps = 10u64;
                        if c.fail_threads == Some(n) && !skip {
                            log.append(&failed_row(dir, &fp, m, strategy, opt, n, rep)).unwrap();
                            continue;
                        }
                        let row = Row {
                            schema_version: SCHEMA_VERSION,
                            campaign_id: dir.file_name().unwrap().to_string_lossy().into_owned(),
                            run_id: format!("m{m}-{strategy}-{opt}-t{n}-{}-r{rep}", c.pin),
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

/// A repetition whose solver crashed.
fn failed_row(dir: &Path, fp: &str, model: u32, strategy: Strategy, opt: &str, threads: usize, rep: u32) -> Row {
    Row {
        schema_version: SCHEMA_VERSION,
        campaign_id: dir.file_name().unwrap().to_string_lossy().into_owned(),
        run_id: format!("m{model}-{strategy}-{opt}-t{threads}-r{rep}"),
        machine_id: fp.into(),
        scenario: "taylor".into(),
        model,
        grid_mode: "fixed".into(),
        strategy,
        opt_level: opt.into(),
        threads,
        pin_policy: "close".into(),
        rep,
        status: Status::Failed,
        reason: "solver exited with status 101".into(),
        ..Row::default()
    }
}

/// The manifest of a crafted campaign on the hwloc synthetic topology `t` (16 GiB).
fn write_manifest(dir: &Path, t: &str) {
    let machine = Machine::synthetic(t).unwrap();
    let mut info = fingerprint::machine_info(&machine);
    info.memory_bytes = 16 << 30;
    let m = Manifest {
        manifest_version: MANIFEST_VERSION,
        campaign_id: dir.file_name().unwrap().to_string_lossy().into_owned(),
        reference: false,
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
    let c = load_campaign(&dir).unwrap();
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
        let c = load_campaign(&dir).unwrap();
        let r = &claims::evaluate(&c, &c.analyse(None))[claim];
        assert_eq!(r.verdict, want, "case {k}: {} {}: {:?}", r.id, r.reason, r.evidence);
    }
}

#[test]
fn holds_needs_a_majority_and_intervals() {
    let tmp = tempfile::tempdir().unwrap();
    // O0 only a little better: AE's comparisons support C4, DD's are within the noise.
    let dir = write_campaign(&tmp.path().join("a"), &Craft { o0_loss: 0.5, ..Craft::default() });
    let c = load_campaign(&dir).unwrap();
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
    let c = load_campaign(&dir).unwrap();
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
        include_noisy: false,
        allow_missing: false,
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

/// Rows measured on a busy host (`host_noisy`) are left out of regress and claims unless
/// `--include-noisy`, and their points are grey in the figures.
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
        .filter(|r| r.threads > 1 && r.status == Status::Ok)
        .flat_map(|r| {
            (10..13).map(move |rep| Row {
                rep,
                run_id: format!("{}-busy{rep}", r.run_id),
                steady_s_per_step: r.steady_s_per_step.map(|t| 3.0 * t),
                grid_stage_s: r.grid_stage_s.map(|t| 3.0 * t),
                particle_stage_s: r.particle_stage_s.map(|t| 3.0 * t),
                host_noisy: true,
                host_noise: "its CPUs 60 % busy with other work before the run".into(),
                ..r.clone()
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
    let r = regress::evaluate(&RegressArgs { include_noisy: true, ..regress_args(&base, &cur) }).unwrap();
    let slow: Vec<_> = r.checks.iter().filter(|c| c.current_reps > c.baseline_reps).collect();
    assert!(!slow.is_empty(), "with --include-noisy the slow rows count: {}", r.reason);
    assert!(slow.iter().any(|c| c.worse_by > 0.5), "the slow rows move the medians: {}", r.reason);
    let quiet = load_campaign(&cur).unwrap().without_noisy(false);
    assert_eq!(quiet.rows.len(), load_campaign(&base).unwrap().rows.len());
    assert_eq!(load_campaign(&cur).unwrap().without_noisy(true).rows.len(), quiet.rows.len() + extra.len());
    // Figures keep every row; the noisy cells' points are grey, the others not.
    let an = analysis(&cur);
    let spec = figures::PAPER_FIGURES.iter().find(|f| f.number == 8).unwrap();
    let pts: Vec<_> =
        figures::paper_panels(&an, spec).into_iter().flat_map(|p| p.lines).flat_map(|l| l.points).collect();
    assert!(pts.iter().any(|p| p.grey) && pts.iter().any(|p| !p.grey));
    assert!(pts.iter().all(|p| p.grey == (p.x > 1.0)), "grey exactly where noisy rows are");
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
    assert_eq!(regress::run(args.clone()).unwrap(), 2);
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["verdict"], "incomparable");
    assert!(v["reason"].as_str().unwrap().contains("different machines"), "{v}");
    args.force = true;
    assert_eq!(regress::run(args).unwrap(), 0);
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
    // 0: the same campaign.
    let (code, text) = regress_cli(&base, &base, &[]);
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
    let (code, text) = regress_cli(&base, &base, &["--tolerance", "3"]);
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
    claims::run(claims::ClaimsArgs {
        results: dir.clone().into(),
        markdown: Some(out.join("claims.md")),
        pin: None,
        include_noisy: false,
    })
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
