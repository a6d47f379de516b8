//! `mpm-bench export`: a campaign's numbers per cell for the benchmark dashboards CI
//! engineers already run, Bencher (its Metric Format, BMF) and github-action-benchmark (its
//! `customBiggerIsBetter` / `customSmallerIsBetter` JSON).
//!
//! # What is exported
//!
//! One benchmark per cell of the campaign's one-process rows and stage asked (`--stages`,
//! default the whole step), named stably from the cell's key,
//! `<scenario>-m<model>-<strategy>-<opt>-t<threads>-<pin>` (`taylor-m1-dd-o3-t2-close`), with
//! `/<stage>` appended for the grid-node and particle stages (`.../grid`). The name holds
//! nothing that changes between runs of the same configuration (no machine id, no campaign
//! folder, no date), so a dashboard draws one line per cell across commits. Each benchmark
//! carries:
//!
//! * the parallel efficiency (cells of more than one thread): [`crate::analysis::stats`]'s
//!   point estimate and interval, the one `regress`, `claims` and `report` use (the paired
//!   design's interval over processes, or the separate design's bootstrap interval);
//! * the time per step: the same analysis's median over repetitions with its bootstrap
//!   interval;
//! * the work bytes (whole step only): the bytes the busiest worker moved over the run, summed
//!   over its sub-stages, from the deterministic work counters ([`mpm_core::work`]) that
//!   `regress` compares exactly; no interval, since every repetition counts the same bytes.
//!   One number per cell rather than one per sub-stage: a dashboard line that moves says the
//!   work changed, and `regress --metrics work` or `work-snapshot --check` name the sub-stage.
//!
//! An estimate of a single repetition (or a paired cell of one process) is exported without
//! its interval: it has none. Oversubscribed cells (time sharing, not scaling) are left out,
//! and a flagged efficiency (a speedup above the cores the run had) is not exported; a note
//! on standard error says so. Rows are selected as by `regress` and `report` (noisy rows left
//! out unless `--include-noisy`, rows with an injected slowdown never exported).
//!
//! # The two formats
//!
//! * BMF: `{ "<benchmark>": { "<measure>": { "value", "lower_value", "upper_value" } } }`
//!   with the measures `latency` (Bencher's built-in Latency measure, in nanoseconds: the time
//!   per step is the latency of one step, and the built-in measure comes with its unit and
//!   charts), `parallel-efficiency` (a fraction, 1 = perfect scaling) and `work-bytes`
//!   (bytes); Bencher creates the last two on the first upload.
//! * github-action-benchmark: an array of `{ "name", "unit", "value", "range", "extra" }`.
//!   That tool takes one direction per file, so the format is split in two:
//!   `github-action-benchmark-bigger` (the efficiencies, for `tool: customBiggerIsBetter`) and
//!   `github-action-benchmark-smaller` (time per step in ns and work bytes, for `tool:
//!   customSmallerIsBetter`). The names are `<benchmark>/efficiency`, `<benchmark>/time-per-step`
//!   and `<benchmark>/work-bytes`; `range` is the interval as `95 % CI [lo, hi]`, `extra` the
//!   design and the repetitions.
//!
//! A file with nothing in it is refused (an empty campaign, or a direction without an entry):
//! both tools reject an upload of no benchmark, and an empty file would hide a broken job.

use crate::analysis::regress::worker_totals;
use crate::analysis::results::{load_campaign, resolve_campaign, Campaign};
use crate::analysis::select::RowFilter;
use crate::analysis::stats::{Analysis, Cell, CellKey, Design, Estimate, Point, Stage};
use anyhow::{Context, Result};
use mpm_host::atomic::write_atomic;
use serde_json::{json, Map, Value};
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// The formats `export` writes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Format {
    /// Bencher Metric Format JSON (`bencher run --adapter json`).
    Bmf,
    /// github-action-benchmark's `customBiggerIsBetter` array: the efficiencies.
    GithubBigger,
    /// github-action-benchmark's `customSmallerIsBetter` array: time per step and work bytes.
    GithubSmaller,
}

/// Why `export` refuses to write.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum ExportError {
    /// A `--format` it does not know.
    #[error(
        "unknown format '{0}': use bmf (Bencher), github-action-benchmark-bigger (efficiency) or \
         github-action-benchmark-smaller (time per step, work bytes)"
    )]
    UnknownFormat(String),
    /// `github-action-benchmark` without a direction.
    #[error(
        "github-action-benchmark takes one direction per file: use github-action-benchmark-bigger (the \
         efficiencies, tool customBiggerIsBetter) and github-action-benchmark-smaller (time per step and work \
         bytes, tool customSmallerIsBetter), one file each"
    )]
    OneDirectionPerFile,
    /// `--out` names a file the export reads.
    #[error("--out {0} is the campaign's own {1}: write the export to another file")]
    OutIsInput(PathBuf, &'static str),
    /// No measured cell, or none for the format's direction.
    #[error("{dir}: nothing to export as {format}: {why}")]
    Empty {
        /// The campaign folder.
        dir: PathBuf,
        /// The format asked.
        format: &'static str,
        /// What is missing, and what to do.
        why: String,
    },
}

impl Format {
    /// Parse a `--format` value.
    pub fn parse(s: &str) -> Result<Self, ExportError> {
        match s.trim().to_ascii_lowercase().as_str() {
            "bmf" | "bencher" => Ok(Format::Bmf),
            "github-action-benchmark-bigger" => Ok(Format::GithubBigger),
            "github-action-benchmark-smaller" => Ok(Format::GithubSmaller),
            "github-action-benchmark" => Err(ExportError::OneDirectionPerFile),
            _ => Err(ExportError::UnknownFormat(s.to_string())),
        }
    }

    /// Its `--format` name.
    pub fn name(self) -> &'static str {
        match self {
            Format::Bmf => "bmf",
            Format::GithubBigger => "github-action-benchmark-bigger",
            Format::GithubSmaller => "github-action-benchmark-smaller",
        }
    }
}

/// The options of `mpm-bench export`.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (the newest).
    pub results: PathBuf,
    /// What to write.
    pub format: Format,
    /// Where (standard output when `None`).
    pub out: Option<PathBuf>,
    /// Stages to export: total, grid, particle.
    pub stages: Vec<String>,
    /// Keep rows measured on a busy host.
    pub include_noisy: bool,
}

/// One benchmark: a cell and a stage, with its numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    /// The stable benchmark name.
    pub name: String,
    /// Parallel efficiency (cells of more than one thread, not flagged).
    pub efficiency: Option<Estimate>,
    /// Time per step (s).
    pub time: Estimate,
    /// The busiest worker's bytes over the run (whole step only, when counted).
    pub work_bytes: Option<u64>,
    /// Where the efficiency comes from.
    pub design: Design,
}

/// What a campaign exports: its entries in key order, and notes for standard error.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Export {
    /// One per cell and stage.
    pub entries: Vec<Entry>,
    /// What was left out, and why.
    pub notes: Vec<String>,
}

/// The stable benchmark name of a cell and stage.
pub fn benchmark_name(scenario: &str, key: &CellKey, pin: &str, stage: Stage) -> String {
    let base = format!("{scenario}-m{}-{}-{}-t{}-{pin}", key.model, key.strategy.name(), key.opt_level, key.threads);
    match stage {
        Stage::Total => base,
        other => format!("{base}/{other}"),
    }
}

/// The busiest worker's bytes of a cell, when its repetitions counted the same work (`Err`:
/// a note saying why not).
fn work_bytes(key: &CellKey, cell: &Cell) -> Result<Option<u64>, String> {
    let Some(first) = cell.work.first() else { return Ok(None) };
    if cell.work.iter().any(|w| w != first) {
        return Err(format!("{key}: its repetitions counted different work; no work bytes exported"));
    }
    Ok(worker_totals(first).into_iter().max())
}

/// The entry of one point of `an` (pinning `pin`), with a note when part of it is left out.
fn entry(an: &Analysis, p: &Point, scenario: &str, notes: &mut Vec<String>) -> Entry {
    let cell = &an.cells[&p.key];
    let efficiency = p.efficiency.filter(|e| p.key.threads > 1 && e.value.is_finite() && e.value > 0.0);
    if efficiency.is_some() && !p.flags.is_empty() {
        notes.push(format!("{} {}: efficiency not exported ({})", p.key, p.stage, p.flags.join("; ")));
    }
    let work_bytes = match p.stage {
        Stage::Total => work_bytes(&p.key, cell).unwrap_or_else(|why| {
            notes.push(why);
            None
        }),
        _ => None,
    };
    Entry {
        name: benchmark_name(scenario, &p.key, &an.pin_policy, p.stage),
        efficiency: efficiency.filter(|_| p.flags.is_empty()),
        time: p.time,
        work_bytes,
        design: p.design,
    }
}

/// The entries of a loaded campaign for `stages`: every pinning policy of its one-process
/// rows, every measured cell that is not oversubscribed.
pub fn collect(c: &Campaign, stages: &[Stage]) -> Export {
    let mut out = Export::default();
    let scenarios: BTreeMap<u32, &'static str> = c.rows.iter().map(|r| (r.model(), r.scenario().name())).collect();
    let pins: BTreeSet<String> = c.rows.iter().map(|r| r.pin_label()).collect();
    let mut over = BTreeSet::new();
    for pin in &pins {
        let an = c.analyse(Some(pin));
        for p in an.points.iter().filter(|p| stages.contains(&p.stage)) {
            if p.oversubscribed {
                over.insert(format!("{} ({pin})", p.key));
                continue;
            }
            let scenario = scenarios.get(&p.key.model).copied().unwrap_or("taylor");
            out.entries.push(entry(&an, p, scenario, &mut out.notes));
        }
    }
    if !over.is_empty() {
        let n = over.len();
        let mut named: Vec<String> = over.into_iter().take(4).collect();
        if n > named.len() {
            named.push("...".into());
        }
        out.notes.push(format!(
            "{n} oversubscribed cell(s) left out (more threads than cores: time sharing, not scaling): {}",
            named.join(", ")
        ));
    }
    if !c.hybrid.is_empty() {
        out.notes.push(format!("{} row(s) over several MPI ranks left out (one-process cells only)", c.hybrid.len()));
    }
    out
}

/// A BMF metric: the value, with its interval when it has one.
fn bmf_metric(e: &Estimate, k: f64) -> Value {
    if e.degenerate() {
        json!({ "value": e.value * k })
    } else {
        json!({ "value": e.value * k, "lower_value": e.lo * k, "upper_value": e.hi * k })
    }
}

/// The export as Bencher Metric Format JSON.
pub fn bmf(x: &Export) -> Value {
    let mut root = Map::new();
    for e in &x.entries {
        let mut measures = Map::new();
        measures.insert("latency".into(), bmf_metric(&e.time, 1e9));
        if let Some(eff) = &e.efficiency {
            measures.insert("parallel-efficiency".into(), bmf_metric(eff, 1.0));
        }
        if let Some(w) = e.work_bytes {
            measures.insert("work-bytes".into(), json!({ "value": w as f64 }));
        }
        root.insert(e.name.clone(), Value::Object(measures));
    }
    Value::Object(root)
}

/// One github-action-benchmark entry of an estimate (scaled by `k`), with its interval as
/// `range` when it has one.
fn github_entry(name: String, unit: &str, est: &Estimate, k: f64, extra: String) -> Value {
    let mut v = json!({ "name": name, "unit": unit, "value": est.value * k, "extra": extra });
    if !est.degenerate() {
        v["range"] = json!(format!("95 % CI [{}, {}]", est.lo * k, est.hi * k));
    }
    v
}

/// What an entry's `extra` says: the design and the repetitions behind the numbers.
fn extra(e: &Entry, est: &Estimate) -> String {
    let n = est.reps;
    let unit = if e.design == Design::Paired { "process(es)" } else { "repetition(s)" };
    let interval = if est.degenerate() { "no interval" } else { "95 % interval" };
    format!("design: {}; {n} {unit}; {interval}", e.design.name())
}

/// The export as a github-action-benchmark array of one direction.
pub fn github(x: &Export, bigger: bool) -> Value {
    let mut out = Vec::new();
    for e in &x.entries {
        if bigger {
            if let Some(eff) = &e.efficiency {
                out.push(github_entry(format!("{}/efficiency", e.name), "fraction", eff, 1.0, extra(e, eff)));
            }
            continue;
        }
        let time_extra = format!("time per step, median; {}", extra(e, &e.time));
        out.push(github_entry(format!("{}/time-per-step", e.name), "ns/step", &e.time, 1e9, time_extra));
        if let Some(w) = e.work_bytes {
            out.push(json!({
                "name": format!("{}/work-bytes", e.name),
                "unit": "bytes",
                "value": w as f64,
                "extra": "the busiest worker's bytes over the run (work counters: exact, the same on every run)",
            }));
        }
    }
    Value::Array(out)
}

/// The files of a campaign folder the export reads.
const INPUTS: [&str; 4] = ["runs.csv", "manifest.json", "bandwidth.json", "topology.xml"];

/// `path` made absolute through its folder (which must exist), so that two spellings of one
/// file compare equal.
fn canonical(path: &Path) -> Option<PathBuf> {
    if let Ok(p) = path.canonicalize() {
        return Some(p);
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new("."));
    Some(parent.canonicalize().ok()?.join(path.file_name()?))
}

/// Refuse an `--out` that is one of the campaign's own files.
pub fn check_out(out: &Path, campaign_dir: &Path) -> Result<(), ExportError> {
    let Some(o) = canonical(out) else { return Ok(()) };
    for name in INPUTS {
        if canonical(&campaign_dir.join(name)).is_some_and(|i| i == o) {
            return Err(ExportError::OutIsInput(out.to_path_buf(), name));
        }
    }
    Ok(())
}

/// The document of `format`, refused when it would hold no benchmark.
pub fn render(x: &Export, format: Format, dir: &Path) -> Result<Value, ExportError> {
    let empty = |why: &str| ExportError::Empty { dir: dir.to_path_buf(), format: format.name(), why: why.into() };
    if x.entries.is_empty() {
        return Err(empty(
            "the campaign has no measured one-process cell (no `ok` row left after the selection); run or finish \
             the campaign first (`mpm-bench run` resumes it)",
        ));
    }
    let doc = match format {
        Format::Bmf => bmf(x),
        Format::GithubBigger => github(x, true),
        Format::GithubSmaller => github(x, false),
    };
    if doc.as_array().is_some_and(Vec::is_empty) {
        return Err(empty(
            "no cell of more than one thread with an efficiency (a one-thread base and a parallel cell are needed); \
             github-action-benchmark-smaller still has the times",
        ));
    }
    Ok(doc)
}

/// `mpm-bench export`: read the campaign, write the document to `--out` or standard output,
/// the notes to standard error.
pub fn run(opts: &ExportOptions) -> Result<()> {
    let stages: Vec<Stage> = opts.stages.iter().map(|s| Stage::parse(s)).collect::<Result<_>>()?;
    let dir = resolve_campaign(&opts.results)?;
    if let Some(out) = &opts.out {
        check_out(out, &dir)?;
    }
    let campaign = load_campaign(&dir, &RowFilter::analysis(opts.include_noisy)).context("reading --results")?;
    campaign.note_left_out("export");
    let x = collect(&campaign, &stages);
    for n in &x.notes {
        eprintln!("note: {}: {n}", dir.display());
    }
    let doc = render(&x, opts.format, &dir)?;
    let count = doc.as_array().map_or_else(|| doc.as_object().map_or(0, Map::len), Vec::len);
    let text = serde_json::to_string_pretty(&doc)? + "\n";
    match &opts.out {
        Some(out) => {
            write_atomic(out, text.as_bytes())
                .with_context(|| format!("cannot write {}: choose a writable --out", out.display()))?;
            eprintln!("wrote {} ({count} entries, {})", out.display(), opts.format.name());
        }
        None => {
            use std::io::Write;
            std::io::stdout().write_all(text.as_bytes())?;
        }
    }
    Ok(())
}
