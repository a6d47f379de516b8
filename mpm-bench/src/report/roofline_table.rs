//! The roofline table of a few runs (`mpm-bench roofline-table`), made only from their JSON
//! summaries (read as the typed [`Summary`]) and, when given, the STREAM ceiling of
//! `mpm-bench bandwidth`: per run and sub-stage of the steady state, the bytes and flops per
//! particle-step counted from the code ([`mpm_core::roofline`]), the time per particle-step
//! and the rates achieved, and the share of the ceiling at the run's worker count.
//!
//! The hardware report has the same section for the 1-thread runs of a campaign; this table
//! is for single runs (the README's Models 1-3 and the impact).

use anyhow::{bail, Context, Result};
use mpm_host::atomic::write_atomic;
use mpm_spec::summary::Summary;
use std::path::PathBuf;

use crate::machine::bandwidth;

/// `mpm-bench roofline-table`.
#[derive(Debug, Clone)]
pub struct RooflineTableOptions {
    /// A run's summary (`mpm run ... --json FILE`), as `LABEL=FILE` or `FILE` (labelled by its
    /// file name); repeat for more runs, in the order of the table.
    pub summaries: Vec<String>,
    /// `mpm-bench bandwidth --out` of the same machine: each run's GB/s is also given as a
    /// share of the best STREAM triad at its worker count.
    pub bandwidth: Option<PathBuf>,
    /// Write the table to FILE instead of stdout.
    pub out: Option<PathBuf>,
}

/// Below this time per particle-step (ns) a sub-stage counts as not run.
const NOT_RUN_NS: f64 = 0.05;

/// The columns of the table.
const HEAD: [&str; 8] = [
    "run",
    "sub-stage",
    "ns/particle-step",
    "bytes/particle-step",
    "flops/particle-step",
    "GB/s",
    "share of STREAM",
    "GFLOP/s",
];

/// `(label, summary)` of one `[LABEL=]FILE` argument.
fn load(arg: &str) -> Result<(String, Summary)> {
    let (label, file) = match arg.split_once('=') {
        Some((l, f)) if !l.is_empty() => (l.to_string(), PathBuf::from(f)),
        _ => {
            let f = PathBuf::from(arg);
            let stem = f.file_stem().map_or_else(|| arg.to_string(), |s| s.to_string_lossy().into_owned());
            (stem, f)
        }
    };
    let text = std::fs::read_to_string(&file).with_context(|| format!("cannot read the summary {}", file.display()))?;
    let summary: Summary = serde_json::from_str(&text).with_context(|| {
        format!("{} is not an mpm summary (write one with mpm run ... --json FILE)", file.display())
    })?;
    if summary.figures.timing.roofline.is_none() {
        bail!(
            "{} has no roofline (no steady steps, or written before the roofline existed): rerun it with more steps \
             than its warm-up",
            file.display()
        );
    }
    Ok((label, summary))
}

/// The Markdown table of `runs` against the STREAM ceiling `stream` (best GB/s by threads).
pub fn table(runs: &[(String, Summary)], stream: &dyn Fn(usize) -> Option<f64>) -> String {
    let mut out = format!("| {} |\n|{}\n", HEAD.join(" | "), "---|".repeat(HEAD.len()));
    for (label, s) in runs {
        let workers = s.threads.max(1);
        let ceiling = stream(workers);
        let Some(roofline) = &s.figures.timing.roofline else { continue };
        let mut total = (0.0, 0.0, 0.0);
        for (stage, r) in roofline {
            // A sub-stage without measurable time did not run in this configuration (the
            // binning and the grid's re-fit of a serial run on the fixed grid): its counted
            // cost is not part of this run's step.
            if r.ns_per_particle_step < NOT_RUN_NS {
                continue;
            }
            total = (
                total.0 + r.ns_per_particle_step,
                total.1 + r.bytes_per_particle_step,
                total.2 + r.flops_per_particle_step,
            );
            let rate = |x: Option<f64>| x.map_or("-".into(), |g| format!("{g:.2}"));
            let share = match (r.gb_per_s, ceiling) {
                (Some(g), Some(c)) if c > 0.0 => format!("{:.0} %", 100.0 * g / c),
                _ => "-".into(),
            };
            out.push_str(&format!(
                "| {label} | {} | {:.1} | {:.0} | {:.0} | {} | {share} | {} |\n",
                stage.name(),
                r.ns_per_particle_step,
                r.bytes_per_particle_step,
                r.flops_per_particle_step,
                rate(r.gb_per_s),
                rate(r.gflop_per_s),
            ));
        }
        let (ns, bytes, flops) = total;
        let gb = bytes / ns;
        let share = ceiling.map_or("-".into(), |c| format!("{:.0} %", 100.0 * gb / c));
        out.push_str(&format!(
            "| {label} | **step** ({} x{workers}, {} particles) | {ns:.1} | {bytes:.0} | {flops:.0} | {gb:.2} | {share} | {:.2} |\n",
            s.strategy,
            mpm_host::human::group_digits(s.figures.size.particles as u64),
            flops / ns,
        ));
    }
    out
}

/// `mpm-bench roofline-table`.
pub fn run(a: &RooflineTableOptions) -> Result<()> {
    let runs = a.summaries.iter().map(|s| load(s)).collect::<Result<Vec<_>>>()?;
    let bw = a.bandwidth.as_deref().map(bandwidth::read).transpose()?;
    let stream = |threads: usize| Some(bw.as_ref()?.ceiling(threads, "close")?.best_gb_s);
    let text = table(&runs, &stream);
    match &a.out {
        Some(path) => write_atomic(path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display())),
        None => {
            print!("{text}");
            Ok(())
        }
    }
}
