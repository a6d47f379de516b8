//! `mpm-bench report`: a hardware comparison over two or more results sets (usually
//! different machines), as Markdown with the figures it embeds written next to it.
//!
//! Sections: the machines side by side (from each campaign's `manifest.json`); the base time
//! `T_1` per model, strategy and optimisation level; speedup and efficiency per thread count
//! with their intervals (oversubscribed points marked); overlaid efficiency curves (one
//! figure per strategy and optimisation level, one panel per model, one line per machine);
//! the fraction of the STREAM-triad ceiling each stage reaches where the campaign holds a
//! `bandwidth.json` ([`crate::machine::bandwidth`], [`crate::analysis::traffic`]); and the
//! paper's claims per machine ([`crate::analysis::claims`]).

use super::plot::{series_colour, write_png_svg, Line, Panel, PlotPoint};
use crate::analysis::claims::{self, ClaimResult};
use crate::analysis::results::{load_campaign, Campaign};
use crate::analysis::stats::{parallel_strategies, tag, Analysis, Stage};
use crate::analysis::traffic::StageBytes;
use crate::campaign::record::Status;
use crate::machine::topology::human_bytes;
use anyhow::{bail, Context, Result};
use mpm_core::Strategy;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Compare machines: a Markdown report over two or more results sets.
///
/// Each DIR is a campaign folder (holding runs.csv) or a folder containing campaigns (then
/// the newest is used). The report puts the machine fingerprints side by side, tabulates T1,
/// speedup and efficiency per model and strategy, overlays the efficiency curves (PNG and
/// SVG written next to the Markdown), gives the fraction of the memory-bandwidth ceiling
/// when a bandwidth.json is present, and evaluates the paper's claims per machine.
#[derive(clap::Args, Debug, Clone)]
pub struct ReportArgs {
    /// Results sets to compare (one or more; two or more for a comparison).
    #[arg(required = true, num_args = 1..)]
    pub dirs: Vec<PathBuf>,
    /// The Markdown file to write; its figures go beside it (`<stem>-eff-ae-o3.png`, ...).
    #[arg(long)]
    pub out: PathBuf,
    /// Pinning policy to analyse when a campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
}

struct Set {
    label: String,
    campaign: Campaign,
    analysis: Analysis,
    claims: Vec<ClaimResult>,
}

fn md_escape(s: &str) -> String {
    s.replace('|', "\\|")
}

/// The head of a Markdown table: the `first` columns, then one column per set named by
/// `column`, and the separator line.
fn table_head(first: &[&str], sets: &[Set], column: impl Fn(&Set) -> String) -> String {
    let mut s = String::from("|");
    for c in first {
        // An empty head cell is written `| |`.
        s.push_str(&if c.is_empty() { " |".to_string() } else { format!(" {c} |") });
    }
    for set in sets {
        let _ = write!(s, " {} |", column(set));
    }
    s.push_str("\n|");
    s.push_str(&"---|".repeat(first.len() + sets.len()));
    s.push('\n');
    s
}

fn machines_table(sets: &[Set]) -> String {
    let mut s = table_head(&[""], sets, |set| set.label.clone());
    type Getter = fn(&Set) -> String;
    let rows: Vec<(&str, Getter)> = vec![
        ("fingerprint", |x| format!("`{}`", x.campaign.fingerprint())),
        ("campaign", |x| format!("`{}`", x.campaign.id())),
        ("CPU", |x| x.campaign.manifest.as_ref().map_or("?".into(), |m| m.machine.cpu_model.clone())),
        ("sockets", |x| x.campaign.manifest.as_ref().map_or("?".into(), |m| m.machine.packages.to_string())),
        ("cores / PUs", |x| {
            x.campaign.manifest.as_ref().map_or("?".into(), |m| format!("{} / {}", m.machine.cores, m.machine.pus))
        }),
        ("NUMA nodes", |x| x.campaign.manifest.as_ref().map_or("?".into(), |m| m.machine.numa_nodes.len().to_string())),
        ("caches", |x| {
            x.campaign.manifest.as_ref().map_or("?".into(), |m| {
                m.machine
                    .caches
                    .iter()
                    .filter(|c| c.name != "L1i")
                    .map(|c| format!("{} {}x{}", c.name, c.count, human_bytes(c.size_bytes)))
                    .collect::<Vec<_>>()
                    .join(", ")
            })
        }),
        ("memory", |x| x.campaign.manifest.as_ref().map_or("?".into(), |m| human_bytes(m.machine.memory_bytes))),
        ("OS / kernel", |x| {
            x.campaign.manifest.as_ref().map_or("?".into(), |m| format!("{} / {}", m.machine.os, m.machine.kernel))
        }),
        ("governor", |x| x.campaign.manifest.as_ref().map_or("?".into(), |m| m.machine.cpu_governor.clone())),
        ("rustc", |x| x.campaign.manifest.as_ref().map_or("?".into(), |m| m.software.rustc.clone())),
        ("git commit", |x| {
            x.campaign.rows.first().map_or("?".into(), |r| {
                format!("{}{}", &r.git_commit[..r.git_commit.len().min(10)], if r.git_dirty { " (dirty)" } else { "" })
            })
        }),
        ("rows ok / not ok", |x| {
            let ok = x.campaign.rows.iter().filter(|r| r.status == Status::Ok).count();
            format!("{ok} / {}", x.campaign.rows.len() - ok)
        }),
        ("pinning", |x| x.analysis.pin_policy.clone()),
        ("STREAM triad best (1 thread / max)", |x| {
            x.campaign.bandwidth.as_ref().map_or("not measured".into(), |b| {
                let first = b.results.first().map_or(0.0, |p| p.best_gb_s);
                let max = b.results.iter().map(|p| p.best_gb_s).fold(0.0, f64::max);
                format!("{first:.1} / {max:.1} GB/s")
            })
        }),
    ];
    for (name, get) in rows {
        let _ = write!(s, "| {name} |");
        for set in sets {
            let _ = write!(s, " {} |", md_escape(&get(set)));
        }
        s.push('\n');
    }
    s
}

/// (model, parallel strategy, optimisation level) of every cell of any set: O3 before O0,
/// then by strategy name and model.
fn combos(sets: &[Set]) -> Vec<(u32, Strategy, String)> {
    let mut v: Vec<(u32, Strategy, String)> = sets
        .iter()
        .flat_map(|s| s.analysis.cells.keys().map(|k| (k.model, k.strategy, k.opt_level.clone())))
        .filter(|(_, st, _)| st.is_parallel())
        .collect();
    v.sort_by_key(|a| (a.2 == "o0", a.1.name(), a.0));
    v.dedup();
    v
}

/// (strategy, optimisation level) of the scaling tables and figures: AE and DD at O3, then
/// at O0.
fn strategy_opt_pairs() -> Vec<(Strategy, &'static str)> {
    ["o3", "o0"].into_iter().flat_map(|opt| parallel_strategies().map(move |s| (s, opt))).collect()
}

fn t1_table(sets: &[Set]) -> String {
    let mut s = table_head(&["model", "strategy", "opt"], sets, |set| format!("T1 {} (ms/step)", set.label));
    for (m, st, opt) in combos(sets) {
        let _ = write!(s, "| Model{m} | {} | {} |", tag(st), opt.to_uppercase());
        for set in sets {
            let cell =
                set.analysis.point(m, st, &opt, 1, Stage::Total).map_or("-".to_string(), |p| p.time.scale(1e3).show(2));
            let _ = write!(s, " {cell} |");
        }
        s.push('\n');
    }
    s
}

fn scaling_table(sets: &[Set], strategy: Strategy, opt: &str) -> Option<String> {
    let threads: Vec<usize> = {
        let mut t: Vec<usize> = sets.iter().flat_map(|s| s.analysis.thread_counts()).filter(|&n| n > 1).collect();
        t.sort_unstable();
        t.dedup();
        t
    };
    let models: Vec<u32> = combos(sets).into_iter().filter(|c| c.1 == strategy && c.2 == opt).map(|c| c.0).collect();
    if models.is_empty() || threads.is_empty() {
        return None;
    }
    let mut s = String::from("| model | machine |");
    for n in &threads {
        let _ = write!(s, " {n} threads: speedup / efficiency |");
    }
    s.push_str("\n|---|---|");
    for _ in &threads {
        s.push_str("---|");
    }
    s.push('\n');
    for m in models {
        for set in sets {
            let _ = write!(s, "| Model{m} | {} |", set.label);
            for &n in &threads {
                let cell = match set.analysis.point(m, strategy, opt, n, Stage::Total) {
                    Some(p) => match (p.speedup, p.efficiency) {
                        (Some(sp), Some(e)) => {
                            format!("{} / {}{}", sp.show(2), e.show(2), if p.oversubscribed { " *" } else { "" })
                        }
                        _ => "no T1".into(),
                    },
                    None => "-".into(),
                };
                let _ = write!(s, " {cell} |");
            }
            s.push('\n');
        }
    }
    Some(s)
}

fn bandwidth_section(set: &Set) -> Option<String> {
    let bw = set.campaign.bandwidth.as_ref()?;
    let an = &set.analysis;
    let mut s = format!(
        "**{}**: STREAM triad ceiling (best of {} passes, 3 x {} arrays): {}.\n\n",
        set.label,
        bw.reps,
        human_bytes(bw.array_bytes),
        bw.results
            .iter()
            .map(|p| format!(
                "{}t {} {:.1} GB/s{}",
                p.threads,
                p.pin,
                p.best_gb_s,
                if p.oversubscribed { "*" } else { "" }
            ))
            .collect::<Vec<_>>()
            .join(", ")
    );
    s.push_str(
        "| model | strategy | opt | threads | grid-node stage: GB/s, % of ceiling (no-reuse bound) | particle stage: GB/s, % of ceiling (no-reuse bound) |\n|---|---|---|---|---|---|\n",
    );
    let mut any = false;
    for (key, cell) in &an.cells {
        let (Some(p), Some(nodes)) = (cell.particles, cell.mean_nodes) else { continue };
        let Some(ceiling) = bw.ceiling(key.threads, &an.pin_policy) else { continue };
        let bytes = StageBytes::estimate(key.strategy, key.threads, p as f64, nodes);
        let mut cols = Vec::new();
        for stage in [Stage::Grid, Stage::Particle] {
            let Some(pt) = an.point(key.model, key.strategy, &key.opt_level, key.threads, stage) else {
                cols.push("-".to_string());
                continue;
            };
            let (lo, hi) = bytes.of(stage);
            let (g_lo, g_hi) = (lo / pt.time.value / 1e9, hi / pt.time.value / 1e9);
            cols.push(format!(
                "{g_lo:.2} GB/s, {:.0} % ({:.0} %)",
                100.0 * g_lo / ceiling.best_gb_s,
                100.0 * g_hi / ceiling.best_gb_s
            ));
        }
        any = true;
        let _ = writeln!(
            s,
            "| Model{} | {} | {} | {}{} | {} | {} |",
            key.model,
            tag(key.strategy),
            key.opt_level.to_uppercase(),
            key.threads,
            if cell.oversubscribed { " *" } else { "" },
            cols[0],
            cols[1]
        );
    }
    if !any {
        s.push_str("| - | - | - | - | no cell with particle and node counts at a measured thread count | - |\n");
    }
    Some(s)
}

fn efficiency_figures(sets: &[Set], out: &Path) -> Result<Vec<(String, String)>> {
    let dir = out.parent().filter(|p| !p.as_os_str().is_empty()).unwrap_or(Path::new(".")).to_path_buf();
    let stem = out.file_stem().map_or("report".into(), |s| s.to_string_lossy().into_owned());
    let mut made = Vec::new();
    for (strategy, opt) in strategy_opt_pairs() {
        let models: Vec<u32> = {
            let mut m: Vec<u32> =
                combos(sets).into_iter().filter(|c| c.1 == strategy && c.2 == opt).map(|c| c.0).collect();
            m.dedup();
            m
        };
        if models.is_empty() {
            continue;
        }
        let max_threads = sets.iter().flat_map(|s| s.analysis.thread_counts()).max().unwrap_or(8) as f64;
        let mut panels = Vec::new();
        for &m in &models {
            let lines: Vec<Line> = sets
                .iter()
                .enumerate()
                .map(|(i, set)| Line {
                    label: set.label.clone(),
                    colour: series_colour(i),
                    marker: i,
                    dashed: false,
                    points: set
                        .analysis
                        .series(m, strategy, opt, Stage::Total)
                        .into_iter()
                        .filter_map(|p| {
                            let e = p.efficiency?;
                            Some(PlotPoint {
                                x: p.key.threads as f64,
                                y: e.value,
                                lo: e.lo,
                                hi: e.hi,
                                hollow: p.oversubscribed,
                                grey: p.noisy,
                            })
                        })
                        .collect(),
                })
                .collect();
            let top = lines.iter().flat_map(|l| l.points.iter().map(|p| p.hi)).fold(0.0f64, f64::max);
            panels.push(Panel {
                title: format!("Model{m}"),
                y_desc: "Efficiency (total)".into(),
                x_desc: "Number of threads".into(),
                x_max: (max_threads + 1.0).max(9.0),
                y_max: (top * 1.1).max(1.2),
                ideal: Some(1.0),
                ideal_flat: true,
                lines,
                notes: vec![],
            });
        }
        let cols = panels.len().min(4);
        let rows = panels.len().div_ceil(cols);
        let name = format!("{stem}-eff-{strategy}-{opt}");
        let title = format!(
            "Parallel efficiency of {} ({}), total step: machines overlaid",
            strategy.label(),
            opt.to_uppercase()
        );
        write_png_svg(
            &dir,
            &name,
            (460 * cols as u32 + 40, 140 + 440 * rows as u32),
            &title,
            &panels,
            (rows, cols),
            &["Hollow markers: more threads than cores (time sharing, not scaling). Bars: 95 % bootstrap intervals."
                .into()],
        )?;
        made.push((title, format!("{name}.png")));
    }
    Ok(made)
}

/// Read every results set, analyse it and evaluate the claims; label each by its machine
/// fingerprint, plus the campaign id when a fingerprint repeats.
fn load_sets(args: &ReportArgs) -> Result<Vec<Set>> {
    if args.dirs.is_empty() {
        bail!("give at least one results folder: mpm-bench report DIR DIR... --out report.md");
    }
    let mut sets = Vec::new();
    for d in &args.dirs {
        let c = load_campaign(d).with_context(|| format!("reading results {}", d.display()))?;
        let an = c.analyse(args.pin.as_deref());
        let cl = claims::evaluate(&c, &an);
        sets.push(Set { label: String::new(), campaign: c, analysis: an, claims: cl });
    }
    let fps: Vec<String> = sets.iter().map(|s| s.campaign.fingerprint()).collect();
    for (i, set) in sets.iter_mut().enumerate() {
        let dup = fps.iter().filter(|f| **f == fps[i]).count() > 1;
        set.label = if dup { format!("{}/{}", fps[i], set.campaign.id()) } else { fps[i].clone() };
    }
    Ok(sets)
}

/// Title, command and the sets compared (with their analysis notes).
fn header(args: &ReportArgs, sets: &[Set]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Hardware comparison: explicit MPM, array expansion vs domain decomposition\n");
    let _ = writeln!(
        s,
        "Made with `mpm-bench report {} --out {}` from:\n",
        args.dirs.iter().map(|d| d.display().to_string()).collect::<Vec<_>>().join(" "),
        args.out.display()
    );
    for set in sets {
        let _ = writeln!(s, "- `{}`: `{}`", set.label, set.campaign.dir.display());
        for n in &set.analysis.notes {
            let _ = writeln!(s, "  - note: {n}");
        }
    }
    if sets.len() < 2 {
        let _ = writeln!(s, "\n(One results set only: nothing is compared, the tables describe one machine.)");
    }
    s
}

/// T1, then speedup and efficiency per strategy and optimisation level.
fn timing_sections(sets: &[Set]) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "## Base time T1 (one thread, steady-state time per step)\n\nMedians over repetitions with 95 % bootstrap intervals; `(n=1)` marks a single repetition (no interval).\n\n{}",
        t1_table(sets)
    );
    let _ = writeln!(
        s,
        "## Speedup and efficiency (total step)\n\nSpeedup T1/Tn and efficiency speedup/n (paper Eqs. 19-20), ratios of medians with 95 % bootstrap intervals. `*`: oversubscribed (more threads than cores: time sharing, not scaling).\n"
    );
    for (st, opt) in strategy_opt_pairs() {
        if let Some(t) = scaling_table(sets, st, opt) {
            let _ = writeln!(s, "### {} {}\n\n{t}", tag(st), opt.to_uppercase());
        }
    }
    s
}

/// The fraction of the bandwidth ceiling per set that has a `bandwidth.json`.
fn bandwidth_sections(sets: &[Set]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "## Fraction of the memory-bandwidth ceiling\n");
    let mut any_bw = false;
    for set in sets {
        if let Some(t) = bandwidth_section(set) {
            any_bw = true;
            let _ = writeln!(s, "{t}");
        }
    }
    if any_bw {
        let _ = writeln!(
            s,
            "Bytes per step are estimated from the kernels (see `mpm-bench/src/analysis/traffic.rs`): the first figure counts each array streamed once per pass (compulsory traffic), the one in brackets counts every particle's 8 nodes as moved from memory (no cache reuse). Stage times are per step, from the campaign's medians.\n"
        );
    } else {
        let _ = writeln!(
            s,
            "No `bandwidth.json` in these campaigns: run `mpm-bench bandwidth --out results/<fingerprint>/<campaign>/bandwidth.json` to add the ceiling.\n"
        );
    }
    s
}

/// The verdicts side by side, then each set's evidence.
fn claims_sections(sets: &[Set]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "## The paper's claims per machine\n");
    s.push_str(&table_head(&["claim"], sets, |set| set.label.clone()));
    for (i, (id, text)) in claims::CLAIMS.iter().enumerate() {
        let _ = write!(s, "| {id}: {text} |");
        for set in sets {
            let _ = write!(s, " **{}** |", set.claims[i].verdict_label());
        }
        s.push('\n');
    }
    for set in sets {
        let _ = writeln!(s, "\n### Claims on `{}`\n\n{}", set.label, claims::markdown(&set.claims, "####"));
    }
    s
}

/// Build the Markdown report (and write its figures beside `out`).
pub fn build(args: &ReportArgs) -> Result<String> {
    let sets = load_sets(args)?;
    let mut s = header(args, &sets);
    let _ = writeln!(s, "\n## Machines\n\n{}", machines_table(&sets));
    s.push_str(&timing_sections(&sets));
    let figs = efficiency_figures(&sets, &args.out)?;
    if !figs.is_empty() {
        let _ = writeln!(s, "## Efficiency curves, machines overlaid\n");
        for (title, file) in figs {
            let _ = writeln!(s, "![{title}]({file})\n");
        }
    }
    s.push_str(&bandwidth_sections(&sets));
    s.push_str(&claims_sections(&sets));
    Ok(s)
}

/// `mpm-bench report`.
pub fn run(args: ReportArgs) -> Result<()> {
    if let Some(parent) = args.out.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {} for --out: choose a writable path", parent.display()))?;
    }
    let text = build(&args)?;
    std::fs::write(&args.out, text)
        .with_context(|| format!("cannot write {}: choose a writable --out", args.out.display()))?;
    println!("wrote {} (figures beside it)", args.out.display());
    Ok(())
}
