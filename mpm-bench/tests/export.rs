//! `mpm-bench export`: Bencher Metric Format and github-action-benchmark JSON checked against
//! the formats' published shapes, on a crafted campaign and on committed ones, with the numbers
//! the analysis gives and the refusals (an empty campaign, an unknown format, `--out` an
//! input).

mod common;

use common::{write_campaign, Craft, DD};
use mpm_bench::analysis::results::load_campaign;
use mpm_bench::analysis::select::RowFilter;
use mpm_bench::analysis::stats::Stage;
use mpm_bench::campaign::store::csv::{read_rows, CsvLog};
use mpm_core::Substage;
use mpm_spec::summary::WorkReport;
use serde_json::{json, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The keys a BMF metric may have (bencher.dev/bmf.json: `value` required, both bounds
/// optional numbers).
const BMF_KEYS: [&str; 3] = ["value", "lower_value", "upper_value"];

/// What is wrong with a document as Bencher Metric Format (empty: nothing). Encodes the
/// published JSON schema (an object of benchmarks, each an object of measures, each an
/// object with a number `value` and optional number `lower_value` and `upper_value`), plus
/// what a meaningful upload needs: non-empty names, finite numbers, both bounds or none and
/// `lower_value <= value <= upper_value`.
fn bmf_problems(doc: &Value) -> Vec<String> {
    let mut bad = Vec::new();
    let Some(benchmarks) = doc.as_object() else { return vec!["the document is not an object".into()] };
    if benchmarks.is_empty() {
        bad.push("no benchmark".into());
    }
    for (name, measures) in benchmarks {
        let Some(measures) = measures.as_object().filter(|m| !name.is_empty() && !m.is_empty()) else {
            bad.push(format!("benchmark '{name}': not a non-empty object under a non-empty name"));
            continue;
        };
        for (measure, metric) in measures {
            let at = format!("{name} / {measure}");
            let Some(m) = metric.as_object() else {
                bad.push(format!("{at}: the metric is not an object"));
                continue;
            };
            bad.extend(m.keys().filter(|k| !BMF_KEYS.contains(&k.as_str())).map(|k| format!("{at}: unknown key {k}")));
            let num = |k: &str| m.get(k).map(|v| v.as_f64().filter(|x| x.is_finite()));
            match (num("value"), num("lower_value"), num("upper_value")) {
                (Some(Some(_)), None, None) => {}
                (Some(Some(v)), Some(Some(lo)), Some(Some(hi))) => {
                    if !(lo <= v && v <= hi) {
                        bad.push(format!("{at}: not lower_value <= value <= upper_value ({lo}, {v}, {hi})"));
                    }
                }
                other => bad.push(format!("{at}: value, lower_value, upper_value not numbers as required: {other:?}")),
            }
        }
    }
    bad
}

/// What is wrong with a document as github-action-benchmark's custom JSON (empty: nothing):
/// a non-empty array of objects with a string `name` (unique), a string `unit`, a finite
/// number `value`, and optional strings `range` and `extra` (its `BenchmarkResult`: the
/// action keeps these five keys and refuses an array of none).
fn github_problems(doc: &Value) -> Vec<String> {
    let mut bad = Vec::new();
    let Some(entries) = doc.as_array() else { return vec!["the document is not an array".into()] };
    if entries.is_empty() {
        bad.push("no entry (the action fails on an empty file)".into());
    }
    let mut names = BTreeSet::new();
    for (i, e) in entries.iter().enumerate() {
        let Some(o) = e.as_object() else {
            bad.push(format!("entry {i}: not an object"));
            continue;
        };
        let text = |k: &str| o.get(k).and_then(Value::as_str);
        match text("name") {
            Some(n) if !n.is_empty() => {
                if !names.insert(n.to_string()) {
                    bad.push(format!("entry {i}: name '{n}' repeated"));
                }
            }
            _ => bad.push(format!("entry {i}: no string name")),
        }
        if text("unit").is_none_or(str::is_empty) {
            bad.push(format!("entry {i}: no string unit"));
        }
        if o.get("value").and_then(Value::as_f64).is_none_or(|v| !v.is_finite()) {
            bad.push(format!("entry {i}: value is not a finite number"));
        }
        for k in ["range", "extra"] {
            if o.get(k).is_some_and(|v| !v.is_string()) {
                bad.push(format!("entry {i}: {k} is not a string"));
            }
        }
        let known = ["name", "unit", "value", "range", "extra"];
        bad.extend(o.keys().filter(|k| !known.contains(&k.as_str())).map(|k| format!("entry {i}: unknown key {k}")));
    }
    bad
}

#[test]
fn the_format_checks_accept_the_published_shapes_and_reject_broken_ones() {
    // Documents in the shape of the formats' own documentation examples.
    let bmf = json!({
        "a_benchmark": { "latency": { "value": 12.5, "lower_value": 12.0, "upper_value": 13.25 },
                         "throughput": { "value": 4.0 } },
        "another": { "file-size": { "value": 7.0 } }
    });
    assert!(bmf_problems(&bmf).is_empty(), "{:?}", bmf_problems(&bmf));
    let gab = json!([
        { "name": "a load", "unit": "Percent", "value": 40 },
        { "name": "memory used", "unit": "Megabytes", "value": 90, "range": "3", "extra": "tooltip line\nanother" }
    ]);
    assert!(github_problems(&gab).is_empty(), "{:?}", github_problems(&gab));
    // Each rule bites.
    for broken in [
        json!([]),
        json!({}),
        json!({ "b": { "latency": { "lower_value": 1.0 } } }),
        json!({ "b": { "latency": { "value": "1" } } }),
        json!({ "b": { "latency": { "value": 2.0, "lower_value": 3.0, "upper_value": 4.0 } } }),
        json!({ "b": { "latency": { "value": 2.0, "lower_value": 1.0 } } }),
        json!({ "b": { "latency": { "value": 2.0, "median": 1.0 } } }),
    ] {
        assert!(!bmf_problems(&broken).is_empty(), "{broken}");
    }
    for broken in [
        json!({}),
        json!([]),
        json!([{ "name": "x", "value": 1 }]),
        json!([{ "name": "x", "unit": "s", "value": "1" }]),
        json!([{ "name": "x", "unit": "s", "value": 1 }, { "name": "x", "unit": "s", "value": 2 }]),
        json!([{ "name": "x", "unit": "s", "value": 1, "range": 3 }]),
    ] {
        assert!(!github_problems(&broken).is_empty(), "{broken}");
    }
}

/// `mpm-bench export ARGS`: the exit code, standard output and standard error.
fn export(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench")).arg("export").args(args).output().unwrap();
    let (stdout, stderr) = (String::from_utf8_lossy(&out.stdout).into_owned(), String::from_utf8_lossy(&out.stderr));
    assert!(!stderr.contains("panicked"), "{stderr}");
    (out.status.code().unwrap(), stdout, stderr.into_owned())
}

/// The document `mpm-bench export --results DIR --format FORMAT` prints (it must succeed).
fn exported(dir: &Path, format: &str) -> Value {
    let (code, stdout, stderr) = export(&["--results", dir.to_str().unwrap(), "--format", format]);
    assert_eq!(code, 0, "{stderr}");
    serde_json::from_str(&stdout).unwrap_or_else(|e| panic!("{format}: not JSON ({e}): {stdout}"))
}

/// A crafted campaign of Model 1, AE/DD/DD-balanced, 1 and 2 threads, 3 repetitions, whose
/// rows carry work counters: worker w of a t-thread run moved `1000 (w + 1) t` bytes in the
/// scatter and 10 in the assembly.
fn crafted(dir: &Path) -> PathBuf {
    let craft = Craft { models: vec![1], threads: vec![1, 2], ..Craft::default() };
    let dir = write_campaign(dir, &craft);
    let csv = dir.join("runs.csv");
    let mut rows = read_rows(&csv).unwrap();
    for r in &mut rows {
        let t = r.threads() as u64;
        let scatter: Vec<u64> = (0..t).map(|w| 1000 * (w + 1) * t).collect();
        let bytes = BTreeMap::from([(Substage::Scatter, scatter), (Substage::Assembly, vec![10; t as usize])]);
        r.measured_mut().work = Some(WorkReport { bytes, ..WorkReport::default() });
    }
    std::fs::remove_file(&csv).unwrap();
    let mut log = CsvLog::open(&csv).unwrap();
    for r in &rows {
        log.append(r).unwrap();
    }
    dir
}

#[test]
fn bmf_of_a_crafted_campaign_carries_the_analysis_numbers_under_stable_names() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = crafted(&tmp.path().join("fixture"));
    let doc = exported(&dir, "bmf");
    assert!(bmf_problems(&doc).is_empty(), "{:?}\n{doc:#}", bmf_problems(&doc));
    let names: BTreeSet<&str> = doc.as_object().unwrap().keys().map(String::as_str).collect();
    let want: BTreeSet<String> = ["ae", "dd", "dd-balanced"]
        .iter()
        .flat_map(|s| ["o0", "o3"].map(|o| [1, 2].map(|t| format!("taylor-m1-{s}-{o}-t{t}-close"))))
        .flatten()
        .collect();
    assert_eq!(names, want.iter().map(String::as_str).collect(), "{doc:#}");
    // The numbers are the analysis's estimates, the time in nanoseconds.
    let c = load_campaign(&dir, &RowFilter::analysis(false)).unwrap();
    let an = c.analyse(None);
    let p = an.point(1, DD, "o3", 2, Stage::Total).unwrap();
    let b = &doc["taylor-m1-dd-o3-t2-close"];
    let (eff, time) = (p.efficiency.unwrap(), p.time);
    assert!(!eff.degenerate() && !time.degenerate(), "3 repetitions give intervals");
    assert_eq!(b["parallel-efficiency"], json!({ "value": eff.value, "lower_value": eff.lo, "upper_value": eff.hi }));
    assert_eq!(
        b["latency"],
        json!({ "value": time.value * 1e9, "lower_value": time.lo * 1e9, "upper_value": time.hi * 1e9 })
    );
    // The busiest worker: 2000 x 2 + 10 bytes; exact, no interval.
    assert_eq!(b["work-bytes"], json!({ "value": 4010.0 }));
    // One thread: no efficiency (1 by definition), the rest as ever.
    let one = doc["taylor-m1-dd-o3-t1-close"].as_object().unwrap();
    assert_eq!(one.keys().collect::<Vec<_>>(), ["latency", "work-bytes"], "{one:?}");
    // The same campaign exports the same document (names and numbers are stable).
    assert_eq!(exported(&dir, "bmf"), doc);
}

#[test]
fn github_action_benchmark_files_split_by_direction() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = crafted(&tmp.path().join("fixture"));
    let bigger = exported(&dir, "github-action-benchmark-bigger");
    let smaller = exported(&dir, "github-action-benchmark-smaller");
    for doc in [&bigger, &smaller] {
        assert!(github_problems(doc).is_empty(), "{:?}\n{doc:#}", github_problems(doc));
    }
    // Bigger is better: the efficiencies of the 2-thread cells only.
    let names = |d: &Value| d.as_array().unwrap().iter().map(|e| e["name"].as_str().unwrap().to_string()).collect();
    let big: Vec<String> = names(&bigger);
    assert_eq!(big.len(), 6, "{big:?}");
    assert!(big.iter().all(|n| n.ends_with("-t2-close/efficiency")), "{big:?}");
    let e = bigger.as_array().unwrap().iter().find(|e| e["name"] == "taylor-m1-dd-o3-t2-close/efficiency").unwrap();
    assert_eq!(e["unit"], "fraction");
    assert!(e["range"].as_str().unwrap().starts_with("95 % CI ["), "{e}");
    // Smaller is better: time per step (ns) and work bytes of every cell.
    let small: Vec<String> = names(&smaller);
    assert_eq!(small.len(), 24, "{small:?}");
    let t = smaller.as_array().unwrap().iter().find(|e| e["name"] == "taylor-m1-dd-o3-t1-close/time-per-step").unwrap();
    assert_eq!(t["unit"], "ns/step");
    let w = smaller.as_array().unwrap().iter().find(|e| e["name"] == "taylor-m1-ae-o0-t2-close/work-bytes").unwrap();
    assert_eq!((w["unit"].as_str(), w["value"].as_f64(), w.get("range")), (Some("bytes"), Some(4010.0), None));
}

#[test]
fn out_writes_the_file_and_stdout_stays_clean() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = crafted(&tmp.path().join("fixture"));
    let file = tmp.path().join("bmf.json");
    let (code, stdout, stderr) =
        export(&["--results", dir.to_str().unwrap(), "--format", "bmf", "--out", file.to_str().unwrap()]);
    assert_eq!(code, 0, "{stderr}");
    assert!(stdout.is_empty() && stderr.contains("wrote"), "{stdout}\n{stderr}");
    let written: Value = serde_json::from_str(&std::fs::read_to_string(&file).unwrap()).unwrap();
    assert_eq!(written, exported(&dir, "bmf"));
}

#[test]
fn stages_other_than_the_total_are_named_apart() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = crafted(&tmp.path().join("fixture"));
    let (code, stdout, stderr) =
        export(&["--results", dir.to_str().unwrap(), "--format", "bmf", "--stages", "total,grid"]);
    assert_eq!(code, 0, "{stderr}");
    let doc: Value = serde_json::from_str(&stdout).unwrap();
    assert!(bmf_problems(&doc).is_empty(), "{:?}", bmf_problems(&doc));
    let grid = doc["taylor-m1-dd-o3-t2-close/grid"].as_object().unwrap();
    assert!(grid.contains_key("parallel-efficiency") && !grid.contains_key("work-bytes"), "{grid:?}");
    assert!(doc.get("taylor-m1-dd-o3-t2-close").is_some());
}

/// The committed campaigns the export is checked on: a paired smoke campaign with work
/// counters, and the quick campaign of five repetitions.
fn committed() -> Vec<PathBuf> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..").join("results");
    ["b69c7f58c6fa/hardware-class/a/b69c7f58c6fa/smoke", "54276cbdfe10/quick"].iter().map(|p| root.join(p)).collect()
}

#[test]
fn committed_campaigns_export_in_every_format() {
    for dir in committed() {
        let csv = std::fs::read(dir.join("runs.csv")).unwrap();
        let bmf = exported(&dir, "bmf");
        assert!(bmf_problems(&bmf).is_empty(), "{}: {:?}", dir.display(), bmf_problems(&bmf));
        let names: Vec<&String> = bmf.as_object().unwrap().keys().collect();
        let shape = |n: &str| {
            let parts: Vec<&str> = n.split('-').collect();
            parts.len() >= 6 && parts[0] == "taylor" && parts[1].starts_with('m') && n.contains("-t")
        };
        assert!(names.iter().all(|n| shape(n)), "{}: {names:?}", dir.display());
        let with_interval = bmf
            .as_object()
            .unwrap()
            .values()
            .flat_map(|m| m.as_object().unwrap().values())
            .filter(|m| m.get("lower_value").is_some())
            .count();
        // The smoke campaign has one repetition a cell (no interval); the quick one has more.
        assert!(with_interval > 0 || dir.ends_with("smoke"), "{}: no interval exported", dir.display());
        assert!(bmf.as_object().unwrap().values().any(|m| m.get("work-bytes").is_some()), "{}", dir.display());
        for format in ["github-action-benchmark-bigger", "github-action-benchmark-smaller"] {
            let doc = exported(&dir, format);
            assert!(github_problems(&doc).is_empty(), "{} {format}: {:?}", dir.display(), github_problems(&doc));
        }
        assert_eq!(std::fs::read(dir.join("runs.csv")).unwrap(), csv, "the committed campaign is only read");
    }
}

#[test]
fn refusals_are_clear_and_non_zero() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = crafted(&tmp.path().join("fixture"));
    let d = dir.to_str().unwrap();
    // An unknown format, and github-action-benchmark without its direction.
    let (code, _, stderr) = export(&["--results", d, "--format", "xml"]);
    assert!(code != 0 && stderr.contains("unknown format 'xml'") && stderr.contains("bmf"), "{stderr}");
    let (code, _, stderr) = export(&["--results", d, "--format", "github-action-benchmark"]);
    assert!(code != 0 && stderr.contains("one direction per file"), "{stderr}");
    // --out naming the campaign's own rows: refused, the rows untouched.
    let csv = std::fs::read(dir.join("runs.csv")).unwrap();
    let out = dir.join(".").join("runs.csv");
    let (code, _, stderr) = export(&["--results", d, "--format", "bmf", "--out", out.to_str().unwrap()]);
    assert!(code != 0 && stderr.contains("is the campaign's own runs.csv"), "{stderr}");
    assert_eq!(std::fs::read(dir.join("runs.csv")).unwrap(), csv);
    // An empty campaign: a runs.csv of no row.
    let empty = tmp.path().join("empty");
    std::fs::create_dir_all(&empty).unwrap();
    drop(CsvLog::open(&empty.join("runs.csv")).unwrap());
    let (code, stdout, stderr) = export(&["--results", empty.to_str().unwrap(), "--format", "bmf"]);
    assert!(code != 0 && stdout.is_empty() && stderr.contains("nothing to export"), "{stdout}\n{stderr}");
    // One-thread cells only: no efficiency for the bigger-is-better file.
    let serial =
        write_campaign(&tmp.path().join("one"), &Craft { models: vec![1], threads: vec![1], ..Craft::default() });
    let s = serial.to_str().unwrap();
    let (code, _, stderr) = export(&["--results", s, "--format", "github-action-benchmark-bigger"]);
    assert!(code != 0 && stderr.contains("no cell of more than one thread"), "{stderr}");
    assert_eq!(export(&["--results", s, "--format", "github-action-benchmark-smaller"]).0, 0);
}

#[test]
fn help_teaches_the_formats_and_the_names() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench")).args(["export", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&out.stdout);
    for needle in [
        "bmf",
        "github-action-benchmark-bigger",
        "customSmallerIsBetter",
        "latency",
        "taylor-m1-dd-o3-t2-close",
        "bencher run",
    ] {
        assert!(help.contains(needle), "{needle} missing from:\n{help}");
    }
}
