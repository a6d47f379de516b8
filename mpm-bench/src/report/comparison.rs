//! `mpm-bench report`: the hardware report over one or more campaigns, written as one
//! self-contained HTML page (`index.html`, inline SVG figures and CSS, no scripts), the same
//! content as `report.md` (with the figures as SVG files beside it) and as `report.json`.
//!
//! With one campaign it describes that machine; with several, each is compared with the
//! first on their matching cells ([`crate::analysis::ratio`]): a headline per model, the
//! per-cell ratios and the cells left out. Then: time per step, throughput and ns per
//! particle-step; speedup and efficiency with the machines overlaid (oversubscribed points
//! hollow, busy-host points grey); peak memory; runs over several MPI ranks against total
//! cores ([`super::hybrid`], only when a campaign has such runs); the paper's claims per
//! machine ([`crate::analysis::claims`]); the machines side by side from each `manifest.json`.

use super::doc::{Block, Doc, Section};
use super::plot::svg_string;
use super::report_figures;
use super::sets::{combos, strategy_opt_pairs, Set};
use crate::analysis::claims;
use crate::analysis::hybrid::HybridAnalysis;
use crate::analysis::ratio::{self, Comparison};
use crate::analysis::results::load_campaigns;
use crate::analysis::select::RowFilter;
use crate::analysis::stats::{self, tag, Compare, Estimate, Stage, StatsOptions};
use crate::campaign::plan::preset::OptLevel;
use crate::campaign::store::record::{Row, Status};
use crate::util::median;
use anyhow::{bail, Context, Result};
use mpm_core::{Strategy, Substage};
use mpm_spec::summary::StageRoofline;
use serde::Serialize;
use std::path::PathBuf;

/// The hardware report: one campaign, or several compared with the first.
///
/// Each --results is a campaign folder (holding runs.csv) or a folder containing campaigns
/// (then the newest is used). Writes OUT/index.html (open it in a browser: one page, no
/// network needed), OUT/report.md with its SVG figures, and OUT/report.json.
///
/// Example: mpm-bench report --results results/aaa/quick --results results/bbb/quick --out cmp
#[derive(Debug, Clone)]
pub struct ReportOptions {
    /// A results set; repeat for a comparison (the first is the baseline A).
    pub dirs: Vec<PathBuf>,
    /// The folder to write index.html, report.md, report.json and the SVG figures into.
    pub out: PathBuf,
    /// Pinning policy to analyse when a campaign has several (default: close, else the first).
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy); left out by default, as by figures,
    /// claims and regress, so the page's claims are `mpm-bench claims`'s.
    pub include_noisy: bool,
    /// Also analyse rows that ran with an injected slowdown (`--inject-slowdown`, a test knob
    /// of the regression gate): never results, refused by default.
    pub include_injected: bool,
}

/// One comparison of the JSON: B against A.
#[derive(Serialize)]
pub struct Versus {
    /// Label of the baseline.
    pub a: String,
    /// Label of the compared set.
    pub b: String,
    /// What differs in the software that made the two sets (commits, dirty trees, solver
    /// binaries), in words; `None` when only the machines differ.
    pub software_differs: Option<String>,
    /// The ratios, headlines and cells left out.
    #[serde(flatten)]
    pub comparison: Comparison,
}

/// The software a set's rows were made with: commits (`-dirty` marked) and solver binaries.
fn software(set: &Set) -> (std::collections::BTreeSet<String>, std::collections::BTreeSet<String>) {
    let rows = set.campaign.all_rows();
    let mut commits = std::collections::BTreeSet::new();
    let mut bins = std::collections::BTreeSet::new();
    for r in rows {
        let short: String = r.id.git_commit.chars().take(12).collect();
        commits.insert(if r.id.git_dirty { format!("{short}-dirty") } else { short });
        bins.insert(format!("{} {}", r.opt(), r.id.binary_sha256));
    }
    (commits, bins)
}

/// Whether two sets were made by different software, in words.
fn software_difference(a: &Set, b: &Set) -> Option<String> {
    let ((ca, ba), (cb, bb)) = (software(a), software(b));
    let list = |s: &std::collections::BTreeSet<String>| s.iter().cloned().collect::<Vec<_>>().join(", ");
    let mut why = Vec::new();
    if ca != cb {
        why.push(format!("A was built from commit {}, B from {}", list(&ca), list(&cb)));
    } else if ca.iter().any(|c| c.ends_with("-dirty")) {
        why.push(format!("both from the uncommitted tree {}, which may differ", list(&ca)));
    }
    if ba != bb {
        why.push(format!("the solver binaries differ (A: {}; B: {})", list(&ba), list(&bb)));
    }
    (!why.is_empty()).then(|| why.join("; "))
}

/// The report: the page and the comparisons it states.
#[derive(Serialize)]
pub struct Report {
    /// Every comparison (empty with one campaign).
    pub comparisons: Vec<Versus>,
    /// The page (figures by file name).
    pub page: Doc,
}

fn table(caption: &str, head: &[&str], rows: Vec<Vec<String>>) -> Block {
    Block::Table { caption: caption.into(), head: head.iter().map(|h| h.to_string()).collect(), rows }
}

fn section(id: &str, title: &str, blocks: Vec<Block>) -> Section {
    Section { id: id.into(), title: title.into(), blocks }
}

/// Read every results set, analyse it and evaluate the claims; label each by its machine
/// fingerprint, plus the campaign id when a fingerprint repeats.
fn load_sets(args: &ReportOptions) -> Result<Vec<Set>> {
    if args.dirs.is_empty() {
        bail!("give at least one results folder: mpm-bench report --results DIR [--results DIR ...] --out OUT");
    }
    let mut sets = Vec::new();
    for d in &args.dirs {
        // A campaign of several machines (a cluster's node types): one set per machine.
        let parts = load_campaigns(d, &RowFilter::analysis(args.include_noisy).with_injected(args.include_injected))
            .with_context(|| format!("reading results {}", d.display()))?;
        for c in parts {
            c.note_left_out("report");
            let an = c.analyse(args.pin.as_deref());
            let hybrid = HybridAnalysis::from_rows(&c.rows, &c.hybrid, Some(&an.pin_policy), &StatsOptions::default());
            let cl = claims::evaluate(&c, &an);
            sets.push(Set { label: String::new(), campaign: c, analysis: an, hybrid, claims: cl });
        }
    }
    let fps: Vec<String> = sets.iter().map(|s| s.campaign.fingerprint()).collect();
    for (i, set) in sets.iter_mut().enumerate() {
        let dup = fps.iter().filter(|f| **f == fps[i]).count() > 1;
        set.label = if dup { format!("{}/{}", fps[i], set.campaign.id()) } else { fps[i].clone() };
    }
    Ok(sets)
}

/// The command and the sets (with their analysis notes).
fn sources(args: &ReportOptions, sets: &[Set]) -> Section {
    let cmd = format!(
        "Made with: mpm-bench report {} --out {}",
        args.dirs.iter().map(|d| format!("--results {}", d.display())).collect::<Vec<_>>().join(" "),
        args.out.display()
    );
    let mut items = Vec::new();
    for (i, set) in sets.iter().enumerate() {
        let role = if i == 0 && sets.len() > 1 { "A (baseline)".to_string() } else { format!("set {}", i + 1) };
        items.push(format!("{role}: {} from {}", set.label, set.campaign.dir.display()));
        items.extend(set.campaign.left_out.iter().map(|l| format!("{}: left out {}", set.label, l.describe())));
        items.extend(set.analysis.notes.iter().map(|n| format!("{}: note: {n}", set.label)));
    }
    let mut blocks = vec![Block::Para(cmd), Block::List(items)];
    if sets.len() < 2 {
        blocks.push(Block::Para("One results set: nothing is compared, the page describes one machine.".into()));
    }
    section("sources", "Sources", blocks)
}

/// `0.71x [0.69, 0.73]`, or `0.71x (n=1)` without an interval.
fn ratio_text(e: &Estimate) -> String {
    if e.degenerate() {
        format!("{:.2}x (n={})", e.value, e.reps)
    } else {
        format!("{:.2}x [{:.2}, {:.2}]", e.value, e.lo, e.hi)
    }
}

/// The headline in words: faster or slower beyond the interval (or, with single
/// repetitions, beyond the margin of [`stats::compare`]), else no difference.
fn in_words(thr: &Estimate) -> String {
    match stats::compare(thr, &Estimate::point(1.0, 1)) {
        Compare::Greater => format!("B is {:.2}x as fast as A", thr.value),
        Compare::Less => format!("B is {:.2}x slower than A", 1.0 / thr.value),
        Compare::Within if thr.degenerate() => {
            format!("within {:.0} % (single repetitions: no interval)", 100.0 * stats::SINGLE_REP_MARGIN)
        }
        Compare::Within => "no difference beyond the 95 % interval".into(),
    }
}

/// The headline, the per-cell ratios and the cells left out, per comparison.
fn comparison_sections(sets: &[Set], cmps: &[Versus]) -> Vec<Section> {
    let mut head = vec![Block::Para(
        "Ratios B / A of the time per step (below 1: B is faster) and of the particle-steps per second (above 1: B is faster), total step. Per model: the median over the matching cells (model x strategy x threads x opt level x pinning measured on both, not oversubscribed on either) with a 95 % bootstrap interval that resamples every cell's repetitions.".into(),
    )];
    let (mut ratios, mut left) = (Vec::new(), Vec::new());
    for v in cmps {
        if let Some(why) = &v.software_differs {
            head.push(Block::Para(format!(
                "Machines and software differ between A = {} and B = {}: {why}. The ratios below mix the two \
                 effects; to compare hardware alone, run the same commit on both.",
                v.a, v.b
            )));
        }
        let rows = v.comparison.headlines.iter().map(|h| {
            vec![
                format!("Model{}", h.model),
                h.cells.to_string(),
                ratio_text(&h.time_ratio),
                ratio_text(&h.throughput_ratio),
                in_words(&h.throughput_ratio),
            ]
        });
        let caption = format!("B = {} over A = {}", v.b, v.a);
        let heads = ["model", "matching cells", "time per step B/A", "particle-steps/s B/A", "in words"];
        head.push(table(&caption, &heads, rows.collect()));
        if v.comparison.headlines.is_empty() {
            head.push(Block::Para(format!("{}: no matching cell, nothing to compare (see the cells left out).", v.b)));
        }
        ratios.extend(ratio_tables(v));
        left.push(left_out_table(v));
    }
    let _ = sets;
    vec![
        section("headline", "Headline", head),
        section("ratios", "Ratios per cell", ratios),
        section("left-out", "Cells left out of the comparison", left),
    ]
}

fn ratio_tables(v: &Versus) -> Vec<Block> {
    let mut models: Vec<u32> = v.comparison.cells.iter().map(|c| c.key.model).collect();
    models.dedup();
    models
        .into_iter()
        .map(|m| {
            let rows = v.comparison.cells.iter().filter(|c| c.key.model == m).map(|c| {
                vec![
                    tag(c.key.strategy),
                    c.key.opt_level.to_uppercase(),
                    c.key.threads.to_string(),
                    c.time_a.scale(1e3).show(3),
                    c.time_b.scale(1e3).show(3),
                    ratio_text(&c.time_ratio),
                    ratio_text(&c.throughput_ratio),
                    if c.noisy { "busy host".into() } else { String::new() },
                ]
            });
            let heads = ["strategy", "opt", "threads", "A ms/step", "B ms/step", "time B/A", "throughput B/A", "note"];
            table(&format!("Model{m}: B = {} over A = {}", v.b, v.a), &heads, rows.collect())
        })
        .collect()
}

fn left_out_table(v: &Versus) -> Block {
    let rows = v.comparison.left_out.iter().map(|l| vec![l.cell.clone(), l.reason.clone()]).collect();
    table(
        &format!("B = {} against A = {}: {} cells left out", v.b, v.a, v.comparison.left_out.len()),
        &["cell", "reason"],
        rows,
    )
}

/// T1 and throughput at one thread and at the most threads each set ran without
/// oversubscription.
fn throughput_table(sets: &[Set]) -> Block {
    let mut rows = Vec::new();
    for (m, st, opt) in combos(sets, false) {
        for set in sets {
            let an = &set.analysis;
            let real: Vec<usize> = an
                .series(m, st, &opt, Stage::Total)
                .iter()
                .filter(|p| !p.oversubscribed)
                .map(|p| p.key.threads)
                .collect();
            for n in [real.first().copied(), real.last().copied().filter(|&n| n > 1)].into_iter().flatten() {
                let Some(p) = an.point(m, st, &opt, n, Stage::Total) else { continue };
                let parts = an.cells.get(&p.key).and_then(|c| c.particles);
                let per = |f: &dyn Fn(f64, f64) -> f64| {
                    parts.map_or("-".into(), |np| {
                        let e = Estimate {
                            value: f(p.time.value, np as f64),
                            lo: f(p.time.lo, np as f64).min(f(p.time.hi, np as f64)),
                            hi: f(p.time.lo, np as f64).max(f(p.time.hi, np as f64)),
                            reps: p.time.reps,
                        };
                        e.show(2)
                    })
                };
                rows.push(vec![
                    format!("Model{m}"),
                    tag(st),
                    opt.to_uppercase(),
                    set.label.clone(),
                    n.to_string(),
                    p.time.scale(1e3).show(3),
                    per(&|t, np| np / t / 1e6),
                    per(&|t, np| t / np * 1e9),
                ]);
            }
        }
    }
    let heads =
        ["model", "strategy", "opt", "machine", "threads", "ms/step", "M particle-steps/s", "ns per particle-step"];
    table("One thread and the most threads run without oversubscription", &heads, rows)
}

/// Speedup and efficiency per thread count, one table per strategy and opt level.
fn scaling_tables(sets: &[Set]) -> Vec<Block> {
    let mut threads: Vec<usize> = sets.iter().flat_map(|s| s.analysis.thread_counts()).filter(|&n| n > 1).collect();
    threads.sort_unstable();
    threads.dedup();
    let mut out = Vec::new();
    for (st, opt) in strategy_opt_pairs() {
        let models: Vec<u32> =
            combos(sets, true).into_iter().filter(|c| c.1 == st && c.2 == opt).map(|c| c.0).collect();
        if models.is_empty() || threads.is_empty() {
            continue;
        }
        let mut head = vec!["model".to_string(), "machine".to_string()];
        head.extend(threads.iter().map(|n| format!("{n} threads: speedup / efficiency")));
        let mut rows = Vec::new();
        for m in models {
            for set in sets {
                let mut r = vec![format!("Model{m}"), set.label.clone()];
                r.extend(threads.iter().map(|&n| match set.analysis.point(m, st, opt, n, Stage::Total) {
                    Some(p) => match (p.speedup, p.efficiency) {
                        (Some(sp), Some(e)) => format!(
                            "{} / {}{}{}",
                            sp.show(2),
                            e.show(2),
                            if p.oversubscribed { " *" } else { "" },
                            // Which design the numbers come from (separate runs are the default).
                            if p.design == crate::analysis::stats::Design::Paired { " (paired)" } else { "" }
                        ),
                        _ => "no T1".into(),
                    },
                    None => "-".into(),
                }));
                rows.push(r);
            }
        }
        out.push(Block::Table { caption: format!("{} {}", tag(st), opt.to_uppercase()), head, rows });
    }
    out
}

/// Median peak resident memory per cell and machine.
fn memory_section(sets: &[Set]) -> Section {
    let opts = StatsOptions::default();
    let mut keys: Vec<_> = sets.iter().flat_map(|s| s.analysis.cells.keys().cloned()).collect();
    keys.sort();
    keys.dedup();
    let rows = keys
        .iter()
        .map(|k| {
            let mut r = vec![k.to_string()];
            r.extend(sets.iter().map(|s| {
                s.analysis
                    .memory(k, &opts)
                    .map_or("-".into(), |e| format!("{} MiB", e.scale(1.0 / (1u64 << 20) as f64).show(0)))
            }));
            r
        })
        .collect();
    let mut head = vec!["cell".to_string()];
    head.extend(sets.iter().map(|s| format!("peak RSS {}", s.label)));
    section(
        "memory",
        "Memory",
        vec![
            Block::Para(
                "Peak resident memory of the solver process: median over repetitions with its 95 % bootstrap interval."
                    .into(),
            ),
            Block::Table { caption: String::new(), head, rows },
        ],
    )
}

/// Runs over several MPI ranks, per set that has them: the table and the figure against
/// total cores. `None` when no set has such runs.
fn hybrid_section(sets: &[Set]) -> Result<Option<Section>> {
    let [communication, waiting] = super::hybrid::EXCHANGE_NOTES;
    let mut blocks = vec![Block::Para(format!(
        "Runs split over MPI ranks, each rank with its own pinned threads: time per step, speedup against one rank of \
         one thread and efficiency over the total cores (ranks x threads per rank), the shares of the wall time spent \
         communicating and waiting for other ranks (apart: the waiting is not the exchange's cost; - (1 rank): \
         nothing to wait for), the bytes all ranks sent per step and the peak memory summed over the ranks. Medians \
         with 95 % bootstrap intervals. *: oversubscribed. These runs are not part of the tables, figures, ratios \
         and claims above, which compare one-process runs only. {} {communication} {waiting}",
        super::hybrid::FOOTNOTE
    ))];
    for (i, set) in sets.iter().enumerate().filter(|(_, s)| !s.hybrid.points.is_empty()) {
        let (head, rows) = super::hybrid::table(&set.hybrid);
        blocks.push(Block::Table { caption: format!("Hybrid runs on {}", set.label), head, rows });
        blocks.extend(set.hybrid.notes.iter().map(|n| Block::Para(format!("{}: note: {n}", set.label))));
        let (panels, grid) = super::hybrid::panels(&set.hybrid);
        let title = format!("{} on {}", super::hybrid::TITLE, set.label);
        let svg = svg_string(super::hybrid::size(grid.0), &title, &panels, grid, &super::hybrid::footnotes())?;
        blocks.push(Block::Figure { title, file: format!("hybrid-{}.svg", i + 1), svg });
    }
    Ok((blocks.len() > 1).then(|| section("hybrid", "Hybrid MPI x threads: speedup against total cores", blocks)))
}

/// How close each sub-stage runs to the machine's limits: for each set, the one-thread O3
/// runs of every model (DD, else serial, else AE), per sub-stage the bytes and flops per
/// particle-step counted from the code (`mpm_core::roofline`), the achieved GB/s against the
/// one-thread STREAM triad ceiling of the campaign's `bandwidth.json` and the achieved
/// GFLOP/s against one core's peak (clock x flops per cycle of the kernels' SIMD level).
fn roofline_section(sets: &[Set]) -> Section {
    let mut blocks = vec![Block::Para(
        "Per sub-stage of the steady state, one thread, O3: bytes and flops per particle-step counted from the \
         code (mpm_core::roofline; node terms weighted by the run's nodes per particle), the achieved rates \
         (medians over repetitions), their share of the one-thread STREAM triad ceiling (bandwidth.json of the \
         campaign) and of one core's peak (the clock /proc/cpuinfo reports times the flops per cycle of the \
         kernels' SIMD level: 8 with AVX2, 4 with SSE2, no fused multiply-add). The stages far from both \
         ceilings are bound by latency and instruction count, not by the machine's limits."
            .into(),
    )];
    for set in sets {
        let stream = set
            .campaign
            .bandwidth
            .as_ref()
            .and_then(|b| b.results.iter().filter(|p| p.threads == 1).map(|p| p.best_gb_s).reduce(f64::max));
        let mhz = set.campaign.manifest.as_ref().and_then(|m| m.machine.cpu_mhz);
        let mut rows = Vec::new();
        for m in set.analysis.models() {
            let Some((st, rs)) = roofline_rows(set, m) else { continue };
            rows.extend(roofline_table_rows(m, st, &rs, stream, mhz));
        }
        let caption = format!(
            "Roofline on {} (STREAM 1 thread: {}; core peak: {})",
            set.label,
            stream
                .map_or("not measured (run mpm-bench bandwidth --out <campaign>/bandwidth.json)".into(), |g| format!(
                    "{g:.1} GB/s"
                )),
            mhz.map_or("clock not reported".into(), |f| format!("{f:.0} MHz x flops per cycle"))
        );
        let heads = [
            "run",
            "sub-stage",
            "bytes/particle-step",
            "flops/particle-step",
            "GB/s",
            "of STREAM",
            "GFLOP/s",
            "of peak",
        ];
        if rows.is_empty() {
            blocks.push(Block::Para(format!(
                "{}: no one-thread O3 run with roofline figures (CSV schema 6).",
                set.label
            )));
        } else {
            blocks.push(table(&caption, &heads, rows));
        }
    }
    section("roofline", "Roofline: how far each stage is from the machine's limits", blocks)
}

/// The ok one-thread O3 rows of Model `m` with roofline figures, of the first strategy that
/// has some (DD, serial, AE).
fn roofline_rows(set: &Set, m: u32) -> Option<(Strategy, Vec<&Row>)> {
    [Strategy::DomainDecomposition, Strategy::Serial, Strategy::ArrayExpansion].into_iter().find_map(|st| {
        let r: Vec<&Row> = set
            .campaign
            .rows
            .iter()
            .filter(|r| {
                r.model() == m
                    && r.strategy() == st
                    && r.threads() == 1
                    && r.opt() == OptLevel::O3
                    && r.outcome.status == Status::Ok
                    && r.measured.as_ref().and_then(|f| f.timing.roofline.as_ref()).is_some_and(|m| !m.is_empty())
            })
            .collect();
        (!r.is_empty()).then_some((st, r))
    })
}

/// The roofline table's rows of Model `m` run by `st` (`rs`): per sub-stage its counted
/// bytes and flops, the median rates and their shares of the `stream` ceiling and of the
/// core's peak at `mhz`.
fn roofline_table_rows(m: u32, st: Strategy, rs: &[&Row], stream: Option<f64>, mhz: Option<f64>) -> Vec<Vec<String>> {
    let per_particle = median(
        &rs.iter()
            .filter_map(|r| r.measured.as_ref().map(|f| f.size.mean_nodes / f.size.particles as f64))
            .collect::<Vec<_>>(),
    );
    let peak = rs
        .iter()
        .find_map(|r| r.measured.as_ref()?.timing.simd_level)
        .zip(mhz)
        .map(|(l, f)| f * 1e-3 * l.flops_per_cycle());
    let share = |x: Option<f64>, of: Option<f64>| match (x, of) {
        (Some(x), Some(c)) if c > 0.0 => format!("{:.0} %", 100.0 * x / c),
        _ => "-".into(),
    };
    let mut rows = Vec::new();
    for s in Substage::ALL {
        let (bytes, flops) = mpm_core::roofline::cost(s).per_particle_step(per_particle);
        let med = |f: &dyn Fn(&StageRoofline) -> Option<f64>| {
            let v: Vec<f64> =
                rs.iter().filter_map(|r| r.measured.as_ref()?.timing.roofline.as_ref()?.get(&s).and_then(f)).collect();
            (!v.is_empty()).then(|| median(&v))
        };
        let (gb, gf) = (med(&|r| r.gb_per_s), med(&|r| r.gflop_per_s));
        if gb.is_none() && gf.is_none() {
            continue;
        }
        rows.push(vec![
            format!("Model{m} {}", tag(st)),
            s.name().to_string(),
            format!("{bytes:.0}"),
            format!("{flops:.0}"),
            gb.map_or("-".into(), |g| format!("{g:.2}")),
            share(gb, stream),
            gf.map_or("-".into(), |g| format!("{g:.2}")),
            share(gf, peak),
        ]);
    }
    rows
}

/// The verdicts side by side, then each set's reasons and evidence.
fn claims_section(sets: &[Set]) -> Section {
    let mut head = vec!["claim".to_string()];
    head.extend(sets.iter().map(|s| s.label.clone()));
    let rows = claims::CLAIMS
        .iter()
        .enumerate()
        .map(|(i, (id, text))| {
            let mut r = vec![format!("{id}: {text}")];
            r.extend(sets.iter().map(|s| s.claims[i].verdict_label()));
            r
        })
        .collect();
    let mut blocks = vec![Block::Table { caption: String::new(), head, rows }];
    for set in sets {
        let rows = set
            .claims
            .iter()
            .map(|c| vec![c.id.to_string(), c.verdict_label(), c.reason.clone(), c.evidence.join("; ")])
            .collect();
        blocks.push(table(&format!("Claims on {}", set.label), &["claim", "verdict", "reason", "evidence"], rows));
    }
    section("claims", "The paper's claims per machine", blocks)
}

/// Build the report: the page and the comparisons.
pub fn build(args: &ReportOptions) -> Result<Report> {
    let sets = load_sets(args)?;
    let opts = StatsOptions::default();
    let comparisons: Vec<Versus> = sets[1..]
        .iter()
        .map(|b| Versus {
            a: sets[0].label.clone(),
            b: b.label.clone(),
            software_differs: software_difference(&sets[0], b),
            comparison: ratio::compare(&sets[0].analysis, &b.analysis, &opts),
        })
        .collect();
    let names = sets.iter().map(|s| s.label.as_str()).collect::<Vec<_>>().join(" vs ");
    let title = if comparisons.iter().any(|v| v.software_differs.is_some()) {
        format!("Machines and software differ: {names}")
    } else if sets.len() > 1 {
        format!("Hardware comparison: {names}")
    } else {
        format!("Hardware report: {}", sets[0].label)
    };
    let mut page = Doc { title, sections: vec![sources(args, &sets)] };
    if sets.len() > 1 {
        page.sections.extend(comparison_sections(&sets, &comparisons));
    }
    let mut thr = vec![
        Block::Para("Throughput is particles x steps per second of wall time (steady state, total step); its inverse per particle is the time per particle-step. Medians with 95 % bootstrap intervals; (n=1) marks a single repetition.".into()),
        throughput_table(&sets),
    ];
    thr.extend(report_figures::throughput_figures(&sets)?);
    page.sections.push(section("throughput", "Time per step and throughput", thr));
    let mut sc = vec![Block::Para("Speedup T1/Tn and efficiency speedup/n (paper Eqs. 19-20), ratios of medians with 95 % bootstrap intervals. *: oversubscribed (more threads than cores: time sharing, not scaling); in the figures such points are hollow, and points measured on a busy host are grey.".into())];
    sc.extend(scaling_tables(&sets));
    sc.extend(report_figures::scaling_figures(&sets)?);
    page.sections.push(section("scaling", "Speedup and efficiency, machines overlaid", sc));
    page.sections.push(memory_section(&sets));
    page.sections.push(roofline_section(&sets));
    page.sections.extend(hybrid_section(&sets)?);
    page.sections.push(claims_section(&sets));
    page.sections.push(super::strategies::section(&sets));
    page.sections.push(super::machines::machines_section(&sets));
    Ok(Report { comparisons, page })
}

/// `mpm-bench report`.
pub fn run(args: ReportOptions) -> Result<()> {
    std::fs::create_dir_all(&args.out)
        .with_context(|| format!("cannot create {} for --out: choose a writable folder", args.out.display()))?;
    let report = build(&args)?;
    let write = |name: &str, text: &str| {
        let p = args.out.join(name);
        std::fs::write(&p, text).with_context(|| format!("cannot write {}: choose a writable --out", p.display()))
    };
    for (file, svg) in report.page.figures() {
        write(file, svg)?;
    }
    write("report.md", &report.page.to_markdown())?;
    write("report.json", &serde_json::to_string_pretty(&report)?)?;
    write("index.html", &report.page.to_html())?;
    println!("{}", args.out.join("index.html").display());
    Ok(())
}
