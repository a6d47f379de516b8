//! The campaigns a report describes ([`Set`]: each with its analysis, hybrid analysis and
//! claims) and what the report's sections and figures take from them.

use crate::analysis::claims::ClaimResult;
use crate::analysis::hybrid::HybridAnalysis;
use crate::analysis::results::Campaign;
use crate::analysis::stats::{parallel_strategies, Analysis};
use crate::campaign::store::record::Status;
use mpm_core::Strategy;

/// One campaign with its analysis and claims.
pub(super) struct Set {
    pub(super) label: String,
    pub(super) campaign: Campaign,
    pub(super) analysis: Analysis,
    pub(super) hybrid: HybridAnalysis,
    pub(super) claims: Vec<ClaimResult>,
}

/// (model, strategy, opt) of every measured cell of any set, O3 first.
pub(super) fn combos(sets: &[Set], parallel_only: bool) -> Vec<(u32, Strategy, String)> {
    let mut v: Vec<(u32, Strategy, String)> = sets
        .iter()
        .flat_map(|s| s.analysis.cells.keys().map(|k| (k.model, k.strategy, k.opt_level.clone())))
        .filter(|(_, st, _)| !parallel_only || st.is_parallel())
        .collect();
    v.sort_by_key(|a| (a.2 == "o0", a.1.name(), a.0));
    v.dedup();
    v
}

/// (strategy, opt) of the scaling tables and figures: the parallel strategies at O3, then O0.
pub(super) fn strategy_opt_pairs() -> Vec<(Strategy, &'static str)> {
    ["o3", "o0"].into_iter().flat_map(|opt| parallel_strategies().map(move |s| (s, opt))).collect()
}

/// Count of ok and not-ok rows of a campaign.
pub(super) fn row_counts(c: &Campaign) -> String {
    let ok = c.all_rows().filter(|r| r.outcome.status == Status::Ok).count();
    format!("{ok} / {}", c.rows.len() + c.hybrid.len() - ok)
}
