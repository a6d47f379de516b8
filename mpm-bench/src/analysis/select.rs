//! Which rows an analysis uses: one rule for `figures`, `claims`, `regress` and `report`
//! ([`select`]), and what it left out and why ([`LeftOut`]), which every command prints.
//!
//! The rule, in order:
//! * rows that did not finish (`failed`, `invalid`, `skipped`) are kept as context only: an
//!   analysis takes no measurement from them, but says why their configuration has none;
//! * rows that ran with an injected slowdown (`inject_slowdown`, a test knob of `mpm-bench
//!   run` and `calibrate`) are never results: left out unless asked (`--include-injected`;
//!   `regress`, which compares them to test the gate, keeps them and says so), and a
//!   campaign of nothing else is refused ([`super::results::load_campaign`]);
//! * rows measured on a busy host (`host_noisy`: the host watch, or a worker that got less
//!   than 90 % of the wall time as CPU time) are left out unless asked (`--include-noisy`;
//!   figures then draw them grey);
//! * oversubscribed rows (more workers than cores: time sharing, not scaling) are left out
//!   unless the command asks for them (figures and the report draw them hollow, claims use
//!   them only to say "cannot tell");
//! * within one model and optimisation level every row must be the same run but for its
//!   strategy, threads, ranks, design (paired or not) and injected slowdown (scenario, grid,
//!   physics, budget): rows of another
//!   configuration than the one most rows of that model and level have (a resumed campaign
//!   with another step budget, say) are left out, with the keys that differ. Speedups never
//!   divide times of different budgets.

use crate::campaign::store::record::{Row, Status};
use serde::Serialize;
use serde_json::Value;
use std::collections::BTreeMap;

/// What a command asks the rule to keep.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RowFilter {
    /// Keep rows measured on a busy host.
    pub include_noisy: bool,
    /// Keep oversubscribed rows.
    pub include_oversubscribed: bool,
    /// Keep rows that ran with an injected slowdown (a test knob).
    pub include_injected: bool,
}

/// Why a row that ran with an injected slowdown is left out.
pub const INJECTED_LEFT_OUT: &str =
    "ran with an injected slowdown (inject_slowdown or inject_step_slowdown, a test knob: never a result; \
     --include-injected keeps them)";

/// Rows the rule left out for one reason.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct LeftOut {
    /// Why, in words, with what keeps them when something does.
    pub reason: String,
    /// How many rows.
    pub rows: usize,
}

impl RowFilter {
    /// What every analysis command keeps: oversubscribed rows (drawn hollow, never counted
    /// as scaling, not gated), and noisy ones when `include_noisy`.
    pub fn analysis(include_noisy: bool) -> Self {
        Self { include_noisy, include_oversubscribed: true, include_injected: false }
    }

    /// [`RowFilter::analysis`] that also keeps (`true`) rows with an injected slowdown.
    pub fn with_injected(self, include_injected: bool) -> Self {
        Self { include_injected, ..self }
    }
}

impl LeftOut {
    /// `3 row(s) measured on a busy host (host_noisy; --include-noisy keeps them)`.
    pub fn describe(&self) -> String {
        format!("{} row(s) {}", self.rows, self.reason)
    }

    /// `3 measured on a busy host`: the count and the reason without its remedy in
    /// parentheses, for a figure's footnote (the command prints the remedy).
    pub fn brief(&self) -> String {
        format!("{} {}", self.rows, self.reason.split(" (").next().unwrap_or(&self.reason))
    }
}

/// The leaves of `v` by their dotted path.
fn leaves(v: &Value, path: &str, out: &mut BTreeMap<String, Value>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                leaves(x, &if path.is_empty() { k.clone() } else { format!("{path}.{k}") }, out);
            }
        }
        x => {
            out.insert(path.to_string(), x.clone());
        }
    }
}

/// What must be equal between rows of one model and optimisation level: the run spec
/// without the strategy, threads, ranks, CPUs, outputs and the rank-only settings.
fn configuration(r: &Row) -> BTreeMap<String, Value> {
    let mut spec = r.run.spec.clone();
    spec.strategy = mpm_core::Strategy::Serial;
    spec.threads = 1;
    spec.ranks = 1;
    spec.rank_layout = None;
    spec.split_wait = false;
    spec.cpus = None;
    spec.outputs = Default::default();
    spec.paired = None;
    spec.inject_slowdown = None;
    spec.inject_step_slowdown = None;
    let mut out = BTreeMap::new();
    leaves(&serde_json::to_value(&spec).unwrap_or(Value::Null), "", &mut out);
    out
}

/// The keys whose values differ between two configurations, with both values.
fn differences(a: &BTreeMap<String, Value>, b: &BTreeMap<String, Value>) -> Vec<String> {
    let keys: std::collections::BTreeSet<&String> = a.keys().chain(b.keys()).collect();
    keys.into_iter()
        .filter(|k| a.get(*k) != b.get(*k))
        .map(|k| {
            let show = |v: Option<&Value>| v.map_or_else(|| "none".to_string(), |v| v.to_string());
            format!("{k} {} instead of {}", show(b.get(k)), show(a.get(k)))
        })
        .collect()
}

/// The configuration every kept row of one scenario, model and optimisation level shares
/// (flattened spec keys and values), by group.
pub type Configurations = BTreeMap<(String, u32, String), BTreeMap<String, Value>>;

/// The keys whose values differ between the configurations of the groups two campaigns
/// both have, as `Model1 o3: budget.steps 100 instead of 20` (`a` is the reference).
pub fn configuration_differences(a: &Configurations, b: &Configurations) -> Vec<String> {
    a.iter()
        .filter_map(|(g, ca)| {
            let cb = b.get(g)?;
            let d = differences(ca, cb);
            (!d.is_empty()).then(|| format!("{} Model{} {}: {}", g.0, g.1, g.2, d.join(", ")))
        })
        .collect()
}

/// Apply the rule to `rows`: the rows an analysis uses (measured ones and not-ok context),
/// what was left out, and each group's configuration.
pub fn select(rows: Vec<Row>, f: &RowFilter) -> (Vec<Row>, Vec<LeftOut>, Configurations) {
    let mut left: BTreeMap<String, usize> = BTreeMap::new();
    let mut kept = Vec::with_capacity(rows.len());
    for r in rows {
        let ok = r.outcome.status == Status::Ok;
        let why = if !ok {
            None
        } else if r.injected().is_some() && !f.include_injected {
            Some(INJECTED_LEFT_OUT.to_string())
        } else if r.host.host_noisy && !f.include_noisy {
            Some("measured on a busy host (host_noisy; --include-noisy keeps them)".to_string())
        } else if r.placement.oversubscribed && !f.include_oversubscribed {
            Some("oversubscribed (more workers than cores: time sharing, not scaling)".to_string())
        } else {
            None
        };
        match why {
            Some(w) => *left.entry(w).or_default() += 1,
            None => kept.push(r),
        }
    }
    // One configuration per model, scenario and optimisation level: the most common.
    let mut groups: BTreeMap<(String, u32, String), Vec<BTreeMap<String, Value>>> = BTreeMap::new();
    for r in &kept {
        groups.entry(group(r)).or_default().push(configuration(r));
    }
    let mut majority: Configurations = BTreeMap::new();
    for (g, confs) in groups {
        let mut counts: Vec<(usize, usize)> = Vec::new(); // (count, first index)
        for (i, c) in confs.iter().enumerate() {
            match counts.iter_mut().find(|(_, j)| confs[*j] == *c) {
                Some(e) => e.0 += 1,
                None => counts.push((1, i)),
            }
        }
        let best = counts.iter().max_by_key(|(n, j)| (*n, std::cmp::Reverse(*j))).map(|&(_, j)| j).unwrap_or(0);
        majority.insert(g, confs[best].clone());
    }
    kept.retain(|r| {
        let want = &majority[&group(r)];
        let have = configuration(r);
        if &have == want {
            return true;
        }
        let d = differences(want, &have);
        let reason = format!(
            "of another configuration than the rest of {} {} ({})",
            r.run.describe().split(' ').next().unwrap_or_default(),
            r.opt(),
            d.join(", ")
        );
        *left.entry(reason).or_default() += 1;
        false
    });
    (kept, left.into_iter().map(|(reason, rows)| LeftOut { reason, rows }).collect(), majority)
}

fn group(r: &Row) -> (String, u32, String) {
    (r.scenario().name().to_string(), r.model(), r.opt().to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::plan::matrix::PlannedRun;
    use crate::campaign::plan::preset::OptLevel;
    use mpm_core::Strategy;

    fn row(threads: usize, steps: u64) -> Row {
        let mut r = Row::planned(PlannedRun::taylor(1, Strategy::DomainDecomposition, OptLevel::O3, threads, steps));
        r.outcome.status = Status::Ok;
        r
    }

    /// Noisy and oversubscribed rows go unless asked, each counted with its
    /// reason; rows that did not finish stay as context; a row of another budget in a
    /// model's series goes, naming the key.
    #[test]
    fn one_rule_with_its_reasons() {
        let mut noisy = row(2, 10);
        noisy.host.host_noisy = true;
        let mut over = row(4, 10);
        over.placement.oversubscribed = true;
        let mut failed = row(2, 10);
        failed.outcome.status = Status::Failed;
        let rows = vec![row(1, 10), row(2, 10), noisy, over, failed, row(2, 20)];
        let (kept, left, configs) = select(rows.clone(), &RowFilter::default());
        assert_eq!(configs.len(), 1);
        assert_eq!(kept.len(), 3, "two measured and one failed");
        assert_eq!(left.len(), 3, "{left:?}");
        assert!(left.iter().any(|l| l.reason.contains("busy host") && l.rows == 1));
        assert!(left.iter().any(|l| l.reason.contains("oversubscribed")));
        let budget = left.iter().find(|l| l.reason.contains("another configuration")).unwrap();
        assert!(budget.reason.contains("budget.steps 20 instead of 10"), "{}", budget.reason);
        let all = RowFilter { include_noisy: true, include_oversubscribed: true, include_injected: true };
        let (kept, left, _) = select(rows, &all);
        assert_eq!((kept.len(), left.len()), (5, 1));
    }

    /// A row with an injected slowdown is never a result: left out, with its reason, unless
    /// asked for; it is not "another configuration" (the injection and the paired design are
    /// not part of it), so a campaign with it compares with one without.
    #[test]
    fn injected_rows_are_left_out_unless_asked() {
        let mut inj = row(2, 10);
        inj.run.spec.inject_slowdown = Some(0.1);
        let mut paired = row(2, 10);
        paired.run.spec.paired = Some(mpm_spec::spec::Paired { blocks: 4 });
        let rows = vec![row(1, 10), inj.clone(), paired];
        let (kept, left, configs) = select(rows.clone(), &RowFilter::analysis(false));
        assert_eq!(kept.len(), 2);
        assert_eq!(left, vec![LeftOut { reason: INJECTED_LEFT_OUT.into(), rows: 1 }]);
        let (kept, left, _) = select(rows, &RowFilter::analysis(false).with_injected(true));
        assert_eq!((kept.len(), left.len()), (3, 0));
        let (_, _, alone) = select(vec![inj], &RowFilter::analysis(false).with_injected(true));
        assert!(configuration_differences(&configs, &alone).is_empty());
    }
}
