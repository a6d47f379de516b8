//! The options of `mpm-bench export`, as clap parses them, converted into
//! [`mpm_bench::report::export::ExportOptions`].

use mpm_bench::report::export::{ExportOptions, Format};
use std::path::PathBuf;

/// `--format`'s value, with the library's message when it is not one.
fn parse_format(s: &str) -> Result<Format, String> {
    Format::parse(s).map_err(|e| e.to_string())
}

/// The arguments of `mpm-bench export`.
#[derive(clap::Args, Debug, Clone)]
pub struct ExportArgs {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (e.g. results/
    /// or results/FINGERPRINT/): then the newest campaign is used and named on stderr.
    #[arg(long)]
    pub results: PathBuf,
    /// bmf (Bencher Metric Format, for `bencher run --adapter json`),
    /// github-action-benchmark-bigger (the efficiencies, for tool customBiggerIsBetter) or
    /// github-action-benchmark-smaller (time per step and work bytes, for tool
    /// customSmallerIsBetter).
    #[arg(long, value_parser = parse_format, value_name = "FORMAT")]
    pub format: Format,
    /// Write to FILE (atomically) instead of standard output; never one of the campaign's
    /// own files.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
    /// Stages to export, comma-separated: total (the whole step), grid, particle. A stage
    /// other than total gets `/<stage>` appended to the benchmark name.
    #[arg(long, value_delimiter = ',', default_value = "total")]
    pub stages: Vec<String>,
    /// Keep rows measured on a busy host (host_noisy), left out by default as by regress
    /// and report.
    #[arg(long)]
    pub include_noisy: bool,
}

impl From<ExportArgs> for ExportOptions {
    fn from(a: ExportArgs) -> Self {
        Self { results: a.results, format: a.format, out: a.out, stages: a.stages, include_noisy: a.include_noisy }
    }
}
