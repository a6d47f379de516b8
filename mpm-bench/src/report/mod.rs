//! The report layer: figures and pages made from the analysis.
//!
//! * [`plot`]: panels, legends and PNG/SVG output;
//! * [`figures`]: the paper's Figures 7-14 and the memory figure;
//! * [`comparison`]: the hardware comparison report (Markdown with its figures).

pub mod comparison;
pub mod figures;
pub mod plot;
