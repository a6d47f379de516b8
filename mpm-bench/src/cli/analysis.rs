//! The options of the commands that read recorded campaigns (`figures`, `claims`,
//! `regress`, `report`), as clap parses them; each converts into its library options.

use std::path::PathBuf;

/// Regenerate the paper's Figures 7-14 (and a memory figure) from a campaign.
///
/// Writes fig07..fig14 and fig_memory as PNG and SVG, plus a README.md naming the campaign
/// and the command. Speedup is T1/Tn and efficiency speedup/n (paper Eqs. 19-20), from
/// medians over repetitions with 95 % bootstrap interval bars; oversubscribed points are
/// hollow; skipped configurations are absent.
#[derive(clap::Args, Debug, Clone)]
pub struct FiguresArgs {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (e.g. results/
    /// or results/FINGERPRINT/): then the newest campaign (by runs.csv modification
    /// time) is used and named.
    #[arg(long)]
    pub results: PathBuf,
    /// Output folder (created if needed). A campaign with runs of several machines (a
    /// cluster's node types) gets one sub-folder per machine fingerprint.
    #[arg(long, default_value = "paper-figures")]
    pub out: PathBuf,
    /// Pinning policy to plot when the campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), drawn grey; left out by default, as
    /// by claims, regress and report.
    #[arg(long)]
    pub include_noisy: bool,
    /// Also analyse rows that ran with an injected slowdown (`--inject-slowdown`, a test knob
    /// of the regression gate): never results, refused by default.
    #[arg(long)]
    pub include_injected: bool,
}

impl From<FiguresArgs> for mpm_bench::report::figures::FiguresOptions {
    fn from(a: FiguresArgs) -> Self {
        Self {
            results: a.results,
            out: a.out,
            pin: a.pin,
            include_noisy: a.include_noisy,
            include_injected: a.include_injected,
        }
    }
}

/// Evaluate the paper's claims C1-C6 on a results set.
///
/// Prints, for each claim, holds / does not hold / cannot tell with the reason and the
/// numbers behind it. Only non-oversubscribed runs with more than one thread count as
/// evidence of scaling; differences must exceed the bootstrap interval (or 5 % with a single
/// repetition). "holds" needs a majority of the comparisons beyond the noise and none
/// against; with fewer than 3 repetitions per cell a verdict is marked "(indicative)". C5
/// (the socket effect) needs the same thread counts run with --bind close and --bind spread.
#[derive(clap::Args, Debug, Clone)]
pub struct ClaimsArgs {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (e.g.
    /// results/ or results/FINGERPRINT/): then the newest campaign is used.
    #[arg(long)]
    pub results: PathBuf,
    /// Also write the table and the evidence as Markdown to this file.
    #[arg(long)]
    pub markdown: Option<PathBuf>,
    /// Pinning policy to analyse when the campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), left out by default.
    #[arg(long)]
    pub include_noisy: bool,
    /// Also analyse rows that ran with an injected slowdown (`--inject-slowdown`, a test knob
    /// of the regression gate): never results, refused by default.
    #[arg(long)]
    pub include_injected: bool,
}

impl From<ClaimsArgs> for mpm_bench::analysis::claims::ClaimsOptions {
    fn from(a: ClaimsArgs) -> Self {
        Self {
            results: a.results,
            markdown: a.markdown,
            pin: a.pin,
            include_noisy: a.include_noisy,
            include_injected: a.include_injected,
        }
    }
}

/// Compare a campaign to a baseline and fail when efficiency or time per step regressed.
///
/// A check fails when it got worse than --tolerance AND the change is beyond the noise
/// (bootstrap p-value, Holm-corrected over all cells). A baseline cell missing, failed or
/// invalid in the current campaign fails too (unless --allow-missing). Exit code 0 = pass,
/// 1 = regression, 2 = error or incomparable (unreadable input, another hardware class without
/// --force, no cell in common). Use in CI with a committed baseline campaign.
#[derive(clap::Args, Debug, Clone)]
pub struct RegressArgs {
    /// Baseline results: a campaign folder (holding runs.csv) or a folder containing
    /// campaigns (then the newest is used).
    #[arg(long)]
    pub baseline: PathBuf,
    /// Current results, same forms as --baseline.
    #[arg(long)]
    pub current: PathBuf,
    /// Relative change tolerated before a check can fail (0.05 = 5 %).
    #[arg(long, default_value_t = 0.05)]
    pub tolerance: f64,
    /// Compare even when the hardware classes differ (another CPU model, core count, memory
    /// class or ISA level: the verdict then compares different hardware; use with care).
    /// Hosts of one class (another machine id, microcode or kernel) compare without it.
    #[arg(long)]
    pub force: bool,
    /// Write the machine-readable verdict here (JSON).
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// What a missing baseline (no folder, or no campaign in it) means: `fail` (exit 2, an
    /// error) or `pass` (exit 0, "no baseline yet; this run becomes it": a CI job's first
    /// run, which then stores its campaign as the baseline).
    #[arg(long, value_name = "WHAT", default_value = "fail", value_parser = ["fail", "pass"])]
    pub missing_baseline: String,
    /// Also check the current campaign's work counters exactly against a committed snapshot
    /// (`mpm-bench work-snapshot --write FILE`), naming the cell and sub-stage that changed.
    #[arg(long, value_name = "FILE")]
    pub work_snapshot: Option<PathBuf>,
    /// Stages to gate, comma-separated: total, grid, particle.
    #[arg(long, value_delimiter = ',', default_value = "total")]
    pub stages: Vec<String>,
    /// Also gate oversubscribed cells (more threads than cores; noisy).
    #[arg(long)]
    pub include_oversubscribed: bool,
    /// Pinning policy to compare when a campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), left out by default.
    #[arg(long)]
    pub include_noisy: bool,
    /// Do not fail when a baseline cell is missing, failed or invalid in the current
    /// campaign (such cells are still listed).
    #[arg(long)]
    pub allow_missing: bool,
    /// What to gate, comma-separated: efficiency (parallel efficiency), time (time per
    /// step), work (the work counters, exactly). Time per step follows the host's speed
    /// from one day to the next; a CI gate on a shared runner gates efficiency and work.
    #[arg(long, value_delimiter = ',', default_value = "efficiency,time,work")]
    pub metrics: Vec<String>,
    /// Append a Markdown summary of the verdict to FILE (e.g. "$GITHUB_STEP_SUMMARY").
    #[arg(long, value_name = "FILE")]
    pub markdown: Option<PathBuf>,
}

impl From<RegressArgs> for mpm_bench::analysis::regress::RegressOptions {
    fn from(a: RegressArgs) -> Self {
        Self {
            baseline: a.baseline,
            current: a.current,
            tolerance: a.tolerance,
            force: a.force,
            json: a.json,
            missing_baseline_passes: a.missing_baseline == "pass",
            work_snapshot: a.work_snapshot,
            stages: a.stages,
            include_oversubscribed: a.include_oversubscribed,
            pin: a.pin,
            include_noisy: a.include_noisy,
            allow_missing: a.allow_missing,
            metrics: a.metrics,
            markdown: a.markdown,
        }
    }
}

/// The hardware report: one campaign, or several compared with the first.
///
/// Each --results is a campaign folder (holding runs.csv) or a folder containing campaigns
/// (then the newest is used). Writes OUT/index.html (open it in a browser: one page, no
/// network needed), OUT/report.md with its SVG figures, and OUT/report.json.
///
/// Example: mpm-bench report --results results/aaa/quick --results results/bbb/quick --out cmp
#[derive(clap::Args, Debug, Clone)]
pub struct ReportArgs {
    /// A results set; repeat for a comparison (the first is the baseline A).
    #[arg(long = "results", required = true)]
    pub dirs: Vec<PathBuf>,
    /// The folder to write index.html, report.md, report.json and the SVG figures into.
    #[arg(long)]
    pub out: PathBuf,
    /// Pinning policy to analyse when a campaign has several (default: close, else the first).
    #[arg(long)]
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy); left out by default, as by figures,
    /// claims and regress, so the page's claims are `mpm-bench claims`'s.
    #[arg(long)]
    pub include_noisy: bool,
    /// Also analyse rows that ran with an injected slowdown (`--inject-slowdown`, a test knob
    /// of the regression gate): never results, refused by default.
    #[arg(long)]
    pub include_injected: bool,
}

impl From<ReportArgs> for mpm_bench::report::comparison::ReportOptions {
    fn from(a: ReportArgs) -> Self {
        Self {
            dirs: a.dirs,
            out: a.out,
            pin: a.pin,
            include_noisy: a.include_noisy,
            include_injected: a.include_injected,
        }
    }
}
