//! The report layer: figures and pages made from the analysis.
//!
//! * [`plot`]: panels, legends and PNG/SVG output;
//! * [`figures`]: the paper's Figures 7-14 and the memory figure;
//! * [`hybrid`]: the hybrid MPI x threads figure and table (speedup vs total cores);
//! * [`comparison`]: the hardware report over one or more campaigns (one page as HTML,
//!   Markdown and JSON), built on [`doc`], the page model and its renderings;
//! * [`impact_table`]: the table of the committed impact runs;
//! * [`roofline_table`]: the roofline table of single runs, from their summaries;
//! * [`imbalance`]: the figure of predicted DD work imbalance, uniform vs balanced cuts;
//! * [`strategies`]: every strategy side by side (a figure) and the measured choice per model;
//! * [`export`]: a campaign's efficiency, time per step and work bytes per cell for the
//!   benchmark dashboards (Bencher's BMF, github-action-benchmark's JSON).

pub mod comparison;
pub mod doc;
pub mod export;
pub mod figures;
pub mod hybrid;
pub mod imbalance;
pub mod impact_table;
mod machines;
pub mod plot;
mod points;
mod report_figures;
pub mod roofline_table;
mod sets;
pub mod strategies;
