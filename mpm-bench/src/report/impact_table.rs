//! The table of the committed impact runs (`results/impact/README.md`), made only from the
//! runs' JSON summaries (read as the typed [`Summary`]): `mpm-bench impact-table`.
//!
//! A results folder holds one sub-folder per run with its `summary.json`
//! (`scripts/impact-runs.sh` writes them). The table has one row per run, the small model
//! (coarser spacing) first, then by decreasing cell size. A figure a summary lacks (one
//! written before the figure existed) shows as `-`.

use anyhow::{bail, Context, Result};
use mpm_host::atomic::write_atomic;
use mpm_host::human::group_digits;
use mpm_spec::identity::Provenance;
use mpm_spec::summary::{EnergyReport, ImpactFigures, Summary};
use std::path::{Path, PathBuf};

/// The line of a template that the table replaces.
pub const PLACEHOLDER: &str = "{{impact-table}}";

/// `mpm-bench impact-table`.
#[derive(Debug, Clone)]
pub struct ImpactTableOptions {
    /// Folder of the impact runs: one sub-folder per run holding `summary.json`.
    pub results: PathBuf,
    /// Markdown template whose line `{{impact-table}}` is replaced by the table (needs --out).
    pub template: Option<PathBuf>,
    /// Write the table (or the filled template) to FILE instead of stdout.
    pub out: Option<PathBuf>,
}

/// One run: its folder name and summary.
#[derive(Clone, Debug)]
pub struct ImpactRun {
    /// The sub-folder's name.
    pub name: String,
    /// Its `summary.json`.
    pub summary: Summary,
}

/// Every `<dir>/<run>/summary.json`, small model first, then by decreasing cell size.
pub fn load_runs(dir: &Path) -> Result<Vec<ImpactRun>> {
    let entries =
        std::fs::read_dir(dir).with_context(|| format!("cannot read the impact results folder {}", dir.display()))?;
    let mut runs = Vec::new();
    for entry in entries {
        let path = entry?.path();
        let file = path.join("summary.json");
        if !file.is_file() {
            continue;
        }
        let text = std::fs::read_to_string(&file).with_context(|| format!("cannot read {}", file.display()))?;
        let summary: Summary = serde_json::from_str(&text)
            .with_context(|| format!("{} is not an mpm summary (rerun that impact)", file.display()))?;
        if summary.scenario() != mpm_spec::ScenarioKind::Impact {
            bail!(
                "{} is a {} run, not an impact: remove it from {}",
                file.display(),
                summary.scenario(),
                dir.display()
            );
        }
        let name = path.file_name().map_or_else(String::new, |n| n.to_string_lossy().into_owned());
        runs.push(ImpactRun { name, summary });
    }
    if runs.is_empty() {
        bail!("no <run>/summary.json under {}: make the runs first (scripts/impact-runs.sh)", dir.display());
    }
    let spacing = |r: &ImpactRun| r.summary.figures.scenario.impact().and_then(|c| c.spacing_m).unwrap_or(0.0);
    let key = |r: &ImpactRun| (-spacing(r), -r.summary.figures.size.dx_m);
    runs.sort_by(|a, b| key(a).partial_cmp(&key(b)).unwrap_or(std::cmp::Ordering::Equal).then(a.name.cmp(&b.name)));
    Ok(runs)
}

/// `x` with `digits` decimals after scaling by `scale`, then `unit`; `-` when missing.
fn num(x: Option<f64>, scale: f64, digits: usize, unit: &str) -> String {
    match x {
        Some(v) if v.is_finite() => format!("{:.digits$}{unit}", v * scale),
        _ => "-".into(),
    }
}

/// Extreme and robust value of a length in mm: `144.5 (143.0) mm`.
fn pair_mm(extreme: Option<f64>, robust: Option<f64>) -> String {
    match (extreme, robust) {
        (None, None) => "-".into(),
        _ => format!("{} ({}) mm", num(extreme, 1e3, 1, ""), num(robust, 1e3, 1, "")),
    }
}

fn wall(s: f64) -> String {
    if s < 120.0 {
        format!("{s:.1} s")
    } else {
        format!("{:.1} min", s / 60.0)
    }
}

fn memory(bytes: Option<u64>) -> String {
    match bytes {
        Some(b) if b >= 1 << 30 => format!("{:.2} GiB", b as f64 / (1u64 << 30) as f64),
        Some(b) => format!("{:.0} MiB", b as f64 / (1u64 << 20) as f64),
        None => "-".into(),
    }
}

/// The short commit the run's binary was built from, `-dirty` when its sources were not
/// committed; `-` for a summary without provenance.
fn commit(p: Option<&Provenance>) -> String {
    match p {
        Some(p) => {
            let short: String = p.git_commit.chars().take(7).collect();
            match p.git_dirty {
                Some(false) => short,
                Some(true) => format!("{short}-dirty"),
                None => format!("{short} (dirty unknown)"),
            }
        }
        None => "-".into(),
    }
}

/// The columns of the table.
const HEAD: [&str; 22] = [
    "run",
    "spacing",
    "cell",
    "particles",
    "steps",
    "t",
    "wall",
    "leading edge (robust)",
    "width (robust)",
    "hole",
    "front velocity (fitted)",
    "leading debris velocity",
    "energy: initial total",
    "final kinetic",
    "final internal",
    "largest rise / fall",
    "negative internal energy: steps (most particles; at end)",
    "failed-particle floors (energy)",
    "failed",
    "peak RSS",
    "final grid: nodes (cells with particles); stored",
    "commit",
];

/// One row of the table.
fn row(r: &ImpactRun) -> Vec<String> {
    let s = &r.summary;
    let e = s.figures.physics.energy.as_ref();
    let kj = |f: fn(&EnergyReport) -> f64| num(e.map(f), 1e-3, 1, " kJ");
    // Before the cloud history existed, front_velocity_m_s held the leading debris's speed:
    // only a summary with a history has the fitted front velocity.
    let none = ImpactFigures::default();
    let c = s.figures.scenario.impact().unwrap_or(&none);
    let fitted = c.cloud_history.as_ref().and(c.front_velocity_m_s);
    vec![
        r.name.clone(),
        num(c.spacing_m, 1e3, 2, " mm"),
        num(Some(s.figures.size.dx_m), 1e3, 2, " mm"),
        group_digits(s.figures.size.particles as u64),
        group_digits(s.figures.progress.steps),
        num(Some(s.figures.progress.sim_time), 1e6, 1, " µs"),
        wall(s.figures.timing.wall_s),
        pair_mm(c.cloud_front_m, c.cloud_front_robust_m),
        pair_mm(c.cloud_width_m, c.cloud_width_robust_m),
        num(c.hole_diameter_m, 1e3, 1, " mm"),
        num(fitted, 1.0, 0, " m/s"),
        num(c.leading_debris_velocity_m_s, 1.0, 0, " m/s"),
        kj(|e| e.initial_total_j),
        kj(|e| e.final_kinetic_j),
        kj(|e| e.final_internal_j),
        e.map_or("-".into(), |e| format!("{:.1e} / {:.1e}", e.max_rise, e.max_fall)),
        e.map_or("-".into(), |e| {
            format!("{} ({}; {})", e.negative_internal_steps, e.negative_internal_max, e.negative_internal_final)
        }),
        e.map_or("-".into(), |e| match e.failed_energy_floors {
            0 => "0".into(),
            n => format!("{n} ({:.2e} J)", e.failed_energy_floor_j),
        }),
        group_digits(s.figures.physics.failed_particles as u64),
        memory(s.figures.memory.peak_rss_bytes),
        s.figures.size.final_occupancy.map_or_else(
            || group_digits(s.figures.size.final_nodes as u64),
            |o| {
                let share = 100.0 * o.occupied_cells as f64 / o.cells.max(1) as f64;
                let stored = s
                    .sparse_stored_nodes()
                    .map_or_else(String::new, |n| format!("; {} stored", group_digits(n as u64)));
                format!("{} ({share:.1} %){stored}", group_digits(s.figures.size.final_nodes as u64))
            },
        ),
        commit(s.provenance.as_ref()),
    ]
}

/// The Markdown table of `runs`.
pub fn table(runs: &[ImpactRun]) -> String {
    let mut out = format!("| {} |\n|{}\n", HEAD.join(" | "), "---|".repeat(HEAD.len()));
    for r in runs {
        out.push_str(&format!("| {} |\n", row(r).join(" | ")));
    }
    out
}

/// `template` with its placeholder line replaced by `table`.
pub fn fill_template(template: &str, table: &str) -> Result<String> {
    let lines = template.lines().filter(|l| l.trim() == PLACEHOLDER).count();
    if lines != 1 {
        bail!("the template must have exactly one line {PLACEHOLDER}, it has {lines}");
    }
    let mut out = String::new();
    for line in template.lines() {
        if line.trim() == PLACEHOLDER {
            out.push_str(table);
        } else {
            out.push_str(line);
            out.push('\n');
        }
    }
    Ok(out)
}

/// `mpm-bench impact-table`.
pub fn run(args: ImpactTableOptions) -> Result<()> {
    let table = table(&load_runs(&args.results)?);
    let text = match &args.template {
        Some(t) => {
            let template =
                std::fs::read_to_string(t).with_context(|| format!("cannot read the template {}", t.display()))?;
            fill_template(&template, &table)?
        }
        None => table,
    };
    match &args.out {
        Some(out) => write_atomic(out, text.as_bytes()).with_context(|| format!("cannot write {}", out.display())),
        None => {
            use std::io::Write;
            std::io::stdout().write_all(text.as_bytes()).context("cannot write to stdout")
        }
    }
}
