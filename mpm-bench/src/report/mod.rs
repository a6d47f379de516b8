//! The report layer: figures and pages made from the analysis.
//!
//! * [`plot`]: panels, legends and PNG/SVG output;
//! * [`figures`]: the paper's Figures 7-14 and the memory figure;
//! * [`comparison`]: the hardware comparison report (Markdown with its figures);
//! * [`impact_table`]: the table of the committed impact runs;
//! * [`imbalance`]: the figure of predicted DD work imbalance, uniform vs balanced cuts.

pub mod comparison;
pub mod figures;
pub mod imbalance;
pub mod impact_table;
pub mod plot;
