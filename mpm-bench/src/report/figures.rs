//! `mpm-bench figures`: the paper's Figures 7-14 (speedup and efficiency of AE and DD, at O3
//! and without optimisation) and a memory figure, regenerated from a campaign's runs.csv.
//!
//! Every figure has the paper's three panels, (a) total computation, (b) grid-node stage,
//! (c) particle stage, with the number of threads (0-9) on x and one line per model
//! (Model1-Model4). Points are medians over repetitions; bars are 95 % bootstrap intervals
//! of the ratio of medians ([`crate::analysis::stats`]); with a single repetition there are no bars
//! and the footnote says so. Oversubscribed points (more threads than usable cores) are
//! drawn hollow, joined by dotted segments, and the footnote names them: they are time
//! sharing, not scaling. Configurations without an `ok` run (e.g. skipped by the memory
//! guard) are absent, never drawn as zero. Text uses the DejaVu Sans compiled into the
//! program ([`super::plot`]).
//!
//! Files: `fig07.{png,svg}` .. `fig14.{png,svg}`, `fig_memory.{png,svg}` and a `README.md`
//! saying which campaign and command made them; a campaign that ran block colouring or
//! atomic adds also gets `fig_strategies.{png,svg}`, every strategy side by side
//! ([`super::strategies`]). These use the one-process rows only; a
//! campaign with runs over several MPI ranks also gets `fig_hybrid.{png,svg}` (speedup
//! against total cores, [`super::hybrid`]).

use super::plot::{write_png_svg, Line, Panel};
use super::points::{memory_points, plot_point};
use crate::analysis::hybrid::HybridAnalysis;
use crate::analysis::results::{load_campaigns, Campaign};
use crate::analysis::select::{LeftOut, RowFilter};
use crate::analysis::stats::{parallel_strategies, tag, Analysis, CellKey, Stage, StatsOptions};
use anyhow::{Context, Result};
use mpm_core::Strategy;
use plotters::style::RGBColor;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Regenerate the paper's Figures 7-14 (and a memory figure) from a campaign.
///
/// Writes fig07..fig14 and fig_memory as PNG and SVG, plus a README.md naming the campaign
/// and the command. Speedup is T1/Tn and efficiency speedup/n (paper Eqs. 19-20), from
/// medians over repetitions with 95 % bootstrap interval bars; oversubscribed points are
/// hollow; skipped configurations are absent.
#[derive(Debug, Clone)]
pub struct FiguresOptions {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (e.g. results/
    /// or results/FINGERPRINT/): then the newest campaign (by runs.csv modification
    /// time) is used and named.
    pub results: PathBuf,
    /// Output folder (created if needed). A campaign with runs of several machines (a
    /// cluster's node types) gets one sub-folder per machine fingerprint.
    pub out: PathBuf,
    /// Pinning policy to plot when the campaign has several (default: close, else the first).
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), drawn grey; left out by default, as
    /// by claims, regress and report.
    pub include_noisy: bool,
    /// Also analyse rows that ran with an injected slowdown (`--inject-slowdown`, a test knob
    /// of the regression gate): never results, refused by default.
    pub include_injected: bool,
}

pub use super::points::Metric;

/// One of the paper's Figures 7-14.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct FigureSpec {
    /// Figure number (7-14).
    pub number: u32,
    /// The strategy plotted.
    pub strategy: Strategy,
    /// `o3` or `o0`.
    pub opt_level: &'static str,
    /// What is plotted.
    pub metric: Metric,
}

impl FigureSpec {
    /// File stem, `fig07` .. `fig14`.
    pub fn stem(&self) -> String {
        format!("fig{:02}", self.number)
    }

    /// The figure's title.
    pub fn title(&self) -> String {
        let what = match self.metric {
            Metric::Speedup => "Speedup",
            Metric::Efficiency => "Efficiency",
        };
        let strat = format!("{} ({})", self.strategy.label(), tag(self.strategy));
        let opt = if self.opt_level == "o3" { "with O3 optimisation" } else { "without optimisation" };
        format!("Fig. {}  {what} of {strat} {opt}", self.number)
    }
}

/// The paper's Figures 7-14.
pub const PAPER_FIGURES: [FigureSpec; 8] = [
    FigureSpec { number: 7, strategy: Strategy::ArrayExpansion, opt_level: "o3", metric: Metric::Speedup },
    FigureSpec { number: 8, strategy: Strategy::ArrayExpansion, opt_level: "o3", metric: Metric::Efficiency },
    FigureSpec { number: 9, strategy: Strategy::ArrayExpansion, opt_level: "o0", metric: Metric::Speedup },
    FigureSpec { number: 10, strategy: Strategy::ArrayExpansion, opt_level: "o0", metric: Metric::Efficiency },
    FigureSpec { number: 11, strategy: Strategy::DomainDecomposition, opt_level: "o3", metric: Metric::Speedup },
    FigureSpec { number: 12, strategy: Strategy::DomainDecomposition, opt_level: "o3", metric: Metric::Efficiency },
    FigureSpec { number: 13, strategy: Strategy::DomainDecomposition, opt_level: "o0", metric: Metric::Speedup },
    FigureSpec { number: 14, strategy: Strategy::DomainDecomposition, opt_level: "o0", metric: Metric::Efficiency },
];

/// Size of a figure in pixels.
pub const FIGURE_SIZE: (u32, u32) = (1800, 640);

/// Colour of model `m` (1-4).
pub fn model_colour(m: u32) -> RGBColor {
    match m {
        1 => RGBColor(31, 119, 180),
        2 => RGBColor(214, 39, 40),
        3 => RGBColor(44, 160, 44),
        4 => RGBColor(0, 0, 0),
        _ => RGBColor(148, 103, 189),
    }
}

fn marker_of(model: u32) -> usize {
    (model as usize + 3) % 4
}

/// One point a figure draws: a row of `points.csv`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct FigurePoint {
    /// File stem: `fig07` .. `fig14`, `fig_memory`, `fig_hybrid`.
    pub figure: String,
    /// Panel: `total`, `grid`, `particle` (Figures 7-14), `Model<n>` (memory) or the
    /// hybrid figure's `Model<n> <strategy> <opt>` row.
    pub panel: String,
    /// Model number.
    pub model: u32,
    /// Strategy.
    pub strategy: Strategy,
    /// Optimisation level.
    pub opt: String,
    /// Threads (of each rank).
    pub threads: usize,
    /// MPI ranks (1: one process; more only in `fig_hybrid`).
    pub ranks: usize,
    /// `speedup`, `efficiency` or `peak_memory_bytes`; in `fig_hybrid` also the shares of
    /// the wall time (`communication_percent`, `waiting_percent`, or
    /// `exchange_incl_wait_percent` where the waiting was not measured apart).
    pub metric: String,
    /// The value drawn (median; a ratio of medians for speedup and efficiency).
    pub value: f64,
    /// Its 95 % interval (equal to `value` with one repetition).
    pub lo: f64,
    /// Its 95 % interval.
    pub hi: f64,
    /// Repetitions behind it (processes, for a paired point).
    pub reps: usize,
    /// Which design the speedup or efficiency comes from: `separate` runs, or `paired`
    /// (1-thread and T-thread solvers in the same processes); `-` for memory.
    pub design: String,
    /// Drawn hollow: more threads than cores.
    pub oversubscribed: bool,
    /// Drawn grey: measured on a busy host.
    pub noisy: bool,
    /// Why it is crossed out (empty: plain data).
    pub flags: String,
}

/// Every point Figures 7-14 and the memory figure draw, in figure order.
pub fn figure_points(an: &Analysis) -> Vec<FigurePoint> {
    let mut out = Vec::new();
    for spec in &PAPER_FIGURES {
        for stage in Stage::ALL {
            for m in an.models() {
                for p in an.series(m, spec.strategy, spec.opt_level, stage) {
                    let e = match spec.metric {
                        Metric::Speedup => p.speedup,
                        Metric::Efficiency => p.efficiency,
                    };
                    let Some(e) = e else { continue };
                    out.push(FigurePoint {
                        figure: spec.stem(),
                        panel: stage.name().to_string(),
                        model: m,
                        strategy: spec.strategy,
                        opt: spec.opt_level.to_string(),
                        threads: p.key.threads,
                        ranks: 1,
                        metric: match spec.metric {
                            Metric::Speedup => "speedup",
                            Metric::Efficiency => "efficiency",
                        }
                        .into(),
                        value: e.value,
                        lo: e.lo,
                        hi: e.hi,
                        reps: e.reps,
                        design: p.design.name().into(),
                        oversubscribed: p.oversubscribed,
                        noisy: p.noisy,
                        flags: p.flags.join("; "),
                    });
                }
            }
        }
    }
    let o = StatsOptions::default();
    for m in an.models() {
        for strategy in parallel_strategies() {
            for opt in ["o3", "o0"] {
                for n in an.thread_counts() {
                    let key = CellKey::new(m, strategy, opt, n);
                    let (Some(cell), Some(e)) = (an.cells.get(&key), an.memory(&key, &o)) else { continue };
                    out.push(FigurePoint {
                        figure: "fig_memory".into(),
                        panel: format!("Model{m}"),
                        model: m,
                        strategy,
                        opt: opt.into(),
                        threads: n,
                        ranks: 1,
                        metric: "peak_memory_bytes".into(),
                        value: e.value,
                        lo: e.lo,
                        hi: e.hi,
                        reps: e.reps,
                        design: "-".into(),
                        oversubscribed: cell.oversubscribed,
                        noisy: cell.noisy > 0,
                        flags: String::new(),
                    });
                }
            }
        }
    }
    out
}

/// Every point the hybrid figure draws ([`super::hybrid::drawn`]), in panel order.
pub fn hybrid_points(h: &HybridAnalysis) -> Vec<FigurePoint> {
    super::hybrid::drawn(h)
        .into_iter()
        .map(|(p, metric, (value, lo, hi))| FigurePoint {
            figure: "fig_hybrid".into(),
            panel: format!("Model{} {} {}", p.key.model, tag(p.key.strategy), p.key.opt_level.to_uppercase()),
            model: p.key.model,
            strategy: p.key.strategy,
            opt: p.key.opt_level.clone(),
            threads: p.key.threads,
            ranks: p.key.ranks,
            metric: metric.into(),
            value,
            lo,
            hi,
            reps: p.reps,
            design: "separate".into(),
            oversubscribed: p.oversubscribed,
            noisy: p.noisy,
            flags: String::new(),
        })
        .collect()
}

/// Write `points` as CSV to `path`.
fn write_points(path: &Path, points: &[FigurePoint]) -> Result<()> {
    let mut w = csv::Writer::from_writer(Vec::new());
    for p in points {
        w.serialize(p)?;
    }
    let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
    mpm_host::atomic::write_atomic(path, &bytes).with_context(|| format!("cannot write {}", path.display()))
}

/// The three panels of one of Figures 7-14.
pub fn paper_panels(an: &Analysis, spec: &FigureSpec) -> Vec<Panel> {
    let models = {
        let mut m = an.models();
        if m.is_empty() {
            m = vec![1, 2, 3, 4];
        }
        m
    };
    let max_threads = an.thread_counts().into_iter().max().unwrap_or(8) as f64;
    let x_max = (max_threads + 1.0).max(9.0);
    Stage::ALL
        .iter()
        .map(|&stage| {
            let lines: Vec<Line> = models
                .iter()
                .map(|&m| Line {
                    label: format!("Model{m}"),
                    colour: model_colour(m),
                    marker: marker_of(m),
                    dashed: false,
                    points: an
                        .series(m, spec.strategy, spec.opt_level, stage)
                        .into_iter()
                        .filter_map(|p| plot_point(p, spec.metric))
                        .collect(),
                })
                .collect();
            let top = lines.iter().flat_map(|l| l.points.iter().map(|p| p.hi)).fold(0.0f64, f64::max);
            let (y_max, y_desc, ideal, flat) = match spec.metric {
                Metric::Speedup => ((top * 1.1).max(8.0).ceil(), "Speedup T1/Tn", Some(1.0), false),
                Metric::Efficiency => ((top * 1.1).max(1.2), "Efficiency (speedup / threads)", Some(1.0), true),
            };
            let mut notes = Vec::new();
            if lines.iter().all(|l| l.points.is_empty()) {
                notes.push(format!(
                    "no ok runs of {} {} in this campaign",
                    tag(spec.strategy),
                    spec.opt_level.to_uppercase()
                ));
            }
            Panel {
                title: stage.title().to_string(),
                y_desc: y_desc.into(),
                x_desc: "Number of threads".into(),
                x_max,
                y_max,
                ideal,
                ideal_flat: flat,
                lines,
                notes,
            }
        })
        .collect()
}

/// Footnotes common to the figures of a campaign.
pub fn footnotes(c: &Campaign, an: &Analysis) -> Vec<String> {
    let reps = an.max_reps();
    let bars = if reps >= 2 {
        format!(
            "Points: medians over up to {reps} repetitions; bars: 95 % bootstrap intervals of the ratio of medians."
        )
    } else {
        "Points: single repetitions (no interval: repeat runs with --reps to get error bars).".to_string()
    };
    let hollow = if an.any_oversubscribed() {
        " Hollow markers, dotted lines: more threads than cores — time sharing, not scaling."
    } else {
        ""
    };
    let paired = an.points.iter().any(|p| p.design == crate::analysis::stats::Design::Paired);
    let mut out = Vec::new();
    if paired {
        out.push(
            "Paired cells (design `paired` in points.csv): speedup and efficiency from the 1-thread and T-thread \
             solvers of the same processes, points the geometric mean over processes, bars the 95 % interval over \
             processes (Student t)."
                .to_string(),
        );
    }
    let missing = if c.left_out.is_empty() {
        "no ok run (e.g. skipped by the memory guard)".to_string()
    } else {
        "no ok run kept (skipped by the memory guard, or every repetition left out)".to_string()
    };
    let left: Vec<String> = c.left_out.iter().map(LeftOut::brief).collect();
    let left = if left.is_empty() { String::new() } else { format!("; left out: {}", left.join(", ")) };
    out.extend([
        format!("{bars}{hollow} Missing points: {missing}."),
        format!(
            "Campaign {} on machine {} ({} rows drawn{left}, pinning '{}'); T1 = the same strategy on 1 thread.",
            c.id(),
            c.fingerprint(),
            c.rows.len(),
            an.pin_policy
        ),
    ]);
    out
}

/// The memory panel of model `m`: AE and DD (solid O3, dashed O0), in MiB for small models.
fn memory_panel(an: &Analysis, m: u32, x_max: f64) -> Panel {
    let mut lines = Vec::new();
    let mut notes = Vec::new();
    let mut top = 0.0f64;
    for (si, strat) in parallel_strategies().enumerate() {
        for opt in ["o3", "o0"] {
            let (pts, skipped) = memory_points(an, m, strat, opt);
            if !skipped.is_empty() {
                notes.push(format!(
                    "{} {}: no run at {} thread(s) (skipped/failed)",
                    tag(strat),
                    opt.to_uppercase(),
                    skipped.join(", ")
                ));
            }
            if pts.is_empty() {
                continue;
            }
            top = pts.iter().map(|p| p.hi).fold(top, f64::max);
            let o0 = opt == "o0";
            lines.push(Line {
                label: format!("{} {}", tag(strat), opt.to_uppercase()),
                colour: match (si, o0) {
                    (0, false) => RGBColor(31, 119, 180),
                    (0, true) => RGBColor(120, 180, 230),
                    (_, false) => RGBColor(214, 39, 40),
                    (_, true) => RGBColor(255, 127, 14),
                },
                marker: si + 2 * o0 as usize,
                dashed: o0,
                points: pts,
            });
        }
    }
    // GiB, or MiB for small models.
    let (unit, k) = if top < 1.0 { ("MiB", 1024.0) } else { ("GiB", 1.0) };
    for l in &mut lines {
        for p in &mut l.points {
            (p.y, p.lo, p.hi) = (p.y * k, p.lo * k, p.hi * k);
        }
    }
    let y_desc = format!("Peak resident memory ({unit})");
    Panel::of_threads(format!("Model{m}"), y_desc, x_max, (top * k * 1.6).max(0.05), lines, notes)
}

/// Panels of the memory figure: one per model.
pub fn memory_panels(an: &Analysis) -> Vec<Panel> {
    let mut models = an.models();
    if models.is_empty() {
        models = vec![1];
    }
    let max_threads = an.thread_counts().into_iter().max().unwrap_or(8) as f64;
    models.iter().map(|&m| memory_panel(an, m, (max_threads + 1.0).max(9.0))).collect()
}

/// Write Figures 7-14, the memory figure and the README into `out`. Returns the files.
pub fn write_all(c: &Campaign, an: &Analysis, out: &Path, command: &str) -> Result<Vec<PathBuf>> {
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create the output folder {}: choose a writable --out", out.display()))?;
    let probe = out.join(".write-test");
    std::fs::write(&probe, b"")
        .with_context(|| format!("cannot write into {}: choose a writable --out", out.display()))?;
    let _ = std::fs::remove_file(&probe);
    let notes = footnotes(c, an);
    let mut files = Vec::new();
    for spec in &PAPER_FIGURES {
        let panels = paper_panels(an, spec);
        files.extend(write_png_svg(out, &spec.stem(), FIGURE_SIZE, &spec.title(), &panels, (1, 3), &notes)?);
    }
    let mem = memory_panels(an);
    let cols = mem.len().clamp(1, 2);
    let rows = mem.len().div_ceil(cols);
    let mut mem_notes = vec![
        "Peak resident memory (VmHWM of the solver process), median over repetitions. AE keeps one copy of the nodal arrays per thread; DD one sub-grid per patch (claims C2, C6).".to_string(),
    ];
    mem_notes.push(notes[1].clone());
    files.extend(write_png_svg(
        out,
        "fig_memory",
        (1400, 120 + 460 * rows as u32),
        "Peak memory vs threads: array expansion (AE) vs domain decomposition (DD)",
        &mem,
        (rows, cols),
        &mem_notes,
    )?);
    if super::strategies::wanted(an) {
        files.extend(super::strategies::write(out, an, &notes)?);
    }
    let hybrid = HybridAnalysis::from_rows(&c.rows, &c.hybrid, Some(&an.pin_policy), &StatsOptions::default());
    if !hybrid.points.is_empty() {
        let (panels, grid) = super::hybrid::panels(&hybrid);
        let mut notes = super::hybrid::footnotes();
        notes.push(format!(
            "Campaign {} on machine {} ({} rows over several ranks, pinning '{}').",
            c.id(),
            c.fingerprint(),
            c.hybrid.len(),
            hybrid.pin_policy
        ));
        notes.extend(hybrid.notes.iter().map(|n| format!("Note: {n}")));
        files.extend(write_png_svg(
            out,
            "fig_hybrid",
            super::hybrid::size(grid.0),
            super::hybrid::TITLE,
            &panels,
            grid,
            &notes,
        )?);
    }
    let points = out.join("points.csv");
    write_points(&points, &[figure_points(an), hybrid_points(&hybrid)].concat())?;
    files.push(points);
    let readme = out.join("README.md");
    std::fs::write(&readme, readme_text(c, an, &hybrid, command))
        .with_context(|| format!("cannot write {}", readme.display()))?;
    files.push(readme);
    Ok(files)
}

fn readme_text(c: &Campaign, an: &Analysis, hybrid: &HybridAnalysis, command: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Figures 7-14 of the paper, regenerated\n");
    let _ = writeln!(s, "Made from campaign `{}` on machine `{}`:", c.id(), c.fingerprint());
    let _ = writeln!(
        s,
        "`{}` ({} rows drawn, pinning `{}`).\n",
        c.dir.join("runs.csv").display(),
        c.rows.len(),
        an.pin_policy
    );
    if !c.left_out.is_empty() {
        let _ = writeln!(s, "Rows left out by the analysis (the same rule as `claims`, `regress` and `report`):\n");
        for l in &c.left_out {
            let _ = writeln!(s, "- {}", l.describe());
        }
        let _ = writeln!(s);
    }
    let _ = writeln!(s, "Command:\n\n```sh\n{command}\n```\n");
    if let Some(m) = &c.manifest {
        let _ = writeln!(
            s,
            "Machine: {}, {} socket(s), {} cores, {} PUs, {:.1} GiB; {}; {}.\n",
            m.machine.cpu_model,
            m.machine.packages,
            m.machine.cores,
            m.machine.pus,
            m.machine.memory_bytes as f64 / (1u64 << 30) as f64,
            m.machine.os,
            m.software.rustc
        );
    }
    file_table(&mut s, an, hybrid);
    let _ = writeln!(s);
    if !c.hybrid.is_empty() {
        let _ = writeln!(
            s,
            "Figures 7-14 and the memory figure use the {} one-process rows only; the {} rows over several MPI \
             ranks are in fig_hybrid, against total cores (ranks x threads per rank).\n",
            c.rows.len(),
            c.hybrid.len()
        );
    }
    let _ = writeln!(
        s,
        "Each of Figures 7-14 has three panels: (a) total computation (steady-state time per step), \
         (b) grid-node stage, (c) particle stage (stage seconds per step). Speedup = T1/Tn, efficiency = \
         speedup/n (paper Eqs. 19-20), ratios of medians over repetitions; bars are 95 % percentile-bootstrap \
         intervals (2000 resamples, fixed seed), absent with a single repetition. Hollow markers joined by \
         dotted lines are oversubscribed runs (more threads than usable cores: time sharing, not scaling). \
         Configurations without an `ok` run are absent, not zero."
    );
    let unmeasured = an.unmeasured();
    if !unmeasured.is_empty() {
        let _ = writeln!(s, "\nConfigurations without a measurement:\n");
        for (k, cell) in unmeasured {
            let why = cell.not_ok.first().map(|(st, r)| format!("{}: {r}", st.as_str())).unwrap_or_default();
            let _ = writeln!(s, "- {k}: {why}");
        }
    }
    for n in &an.notes {
        let _ = writeln!(s, "\nNote: {n}");
    }
    s
}

/// The README's table of the files `figures` writes (the strategies and hybrid figures only
/// where drawn).
fn file_table(s: &mut String, an: &Analysis, hybrid: &HybridAnalysis) {
    let _ = writeln!(s, "| file | content |\n|---|---|");
    for spec in &PAPER_FIGURES {
        let _ = writeln!(s, "| {}.png / .svg | {} |", spec.stem(), spec.title());
    }
    let _ = writeln!(s, "| fig_memory.png / .svg | Peak memory vs threads, AE vs DD, per model (claims C2, C6) |");
    let _ = writeln!(
        s,
        "| points.csv | every point of these figures: figure, panel, model, strategy, opt level, threads, metric, value, interval, repetitions, flags |"
    );
    if super::strategies::wanted(an) {
        let _ = writeln!(s, "| {}.png / .svg | {} |", super::strategies::STEM, super::strategies::TITLE);
    }
    if !hybrid.points.is_empty() {
        let _ = writeln!(
            s,
            "| fig_hybrid.png / .svg | Hybrid MPI x threads: speedup, efficiency, communication and waiting for other ranks (% of wall time, apart) vs total cores, one line per rank count |"
        );
    }
}

/// `mpm-bench figures`.
pub fn run(args: FiguresOptions) -> Result<()> {
    let parts =
        load_campaigns(&args.results, &RowFilter::analysis(args.include_noisy).with_injected(args.include_injected))?;
    let mut command = format!("mpm-bench figures --results {} --out {}", args.results.display(), args.out.display());
    if let Some(p) = &args.pin {
        let _ = write!(command, " --pin {p}");
    }
    for c in &parts {
        // Runs of several machines: each machine's figures apart, never one line over both.
        let out = if c.split { args.out.join(c.fingerprint()) } else { args.out.clone() };
        c.note_left_out("figures");
        let an = c.analyse(args.pin.as_deref());
        if an.points.is_empty() {
            eprintln!("warning: campaign {} has no ok run: the figures will be empty", c.label());
        }
        let files = write_all(c, &an, &out, &command)?;
        println!("campaign {} ({}): wrote {} files to {}", c.label(), c.dir.display(), files.len(), out.display());
        for f in files {
            println!("  {}", f.display());
        }
    }
    Ok(())
}
