//! The options of the tables made from JSON summaries (`impact-table`, `roofline-table`),
//! as clap parses them; each converts into its library options.

use std::path::PathBuf;

/// `mpm-bench impact-table`.
#[derive(clap::Args, Debug)]
pub struct ImpactTableArgs {
    /// Folder of the impact runs: one sub-folder per run holding `summary.json`.
    #[arg(long, value_name = "DIR", default_value = "results/impact")]
    pub results: PathBuf,
    /// Markdown template whose line `{{impact-table}}` is replaced by the table (needs --out).
    #[arg(long, value_name = "FILE", requires = "out")]
    pub template: Option<PathBuf>,
    /// Write the table (or the filled template) to FILE instead of stdout.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

impl From<ImpactTableArgs> for mpm_bench::report::impact_table::ImpactTableOptions {
    fn from(a: ImpactTableArgs) -> Self {
        Self { results: a.results, template: a.template, out: a.out }
    }
}

/// `mpm-bench roofline-table`.
#[derive(clap::Args, Debug)]
pub struct RooflineTableArgs {
    /// A run's summary (`mpm run ... --json FILE`), as `LABEL=FILE` or `FILE` (labelled by its
    /// file name); repeat for more runs, in the order of the table.
    #[arg(long = "summary", value_name = "[LABEL=]FILE", required = true)]
    pub summaries: Vec<String>,
    /// `mpm-bench bandwidth --out` of the same machine: each run's GB/s is also given as a
    /// share of the best STREAM triad at its worker count.
    #[arg(long, value_name = "FILE")]
    pub bandwidth: Option<PathBuf>,
    /// Write the table to FILE instead of stdout.
    #[arg(long, value_name = "FILE")]
    pub out: Option<PathBuf>,
}

impl From<RooflineTableArgs> for mpm_bench::report::roofline_table::RooflineTableOptions {
    fn from(a: RooflineTableArgs) -> Self {
        Self { summaries: a.summaries, bandwidth: a.bandwidth, out: a.out }
    }
}
