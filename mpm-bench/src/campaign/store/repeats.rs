//! Results that repeat a run: a run key of more than one `ok` row. Each planned run has its
//! own key ([`crate::campaign::plan::matrix::PlannedRun::key`], repetitions included), and
//! the campaign runner writes one `ok` row per key; a second one comes from outside the
//! runner's bookkeeping (two campaigns appended into one folder, rows copied in by hand, a
//! run adopted twice). Counted twice it would be two repetitions of one measurement, so the
//! analyses count the first row of each key only ([`first_per_run_key`]) and say which keys
//! they left rows of out. Rows that did not finish (`failed`, `invalid`, `skipped`) are
//! attempts, several per key by design (a failed run is run again), and stay. Rows of
//! different machines are never repeats of each other (the analyses take each machine's
//! rows apart).

use crate::campaign::plan::matrix::RunKey;
use crate::campaign::store::record::{Row, Status};
use std::collections::{BTreeMap, HashSet};
use std::path::Path;

/// How many keys a warning names before it gives only their count.
const NAMED_KEYS: usize = 5;

/// `rows` with every `ok` row whose run key an earlier `ok` row of its machine already has
/// left out, and the keys repeated with their number of `ok` rows. A key and its short form
/// (the 16-digit keys of older campaigns, [`RunKey::short`]) are one run's. Rows without a
/// key (none of a file this harness reads) are kept.
pub fn split_repeats(rows: Vec<Row>) -> (Vec<Row>, BTreeMap<String, usize>) {
    let mut seen = HashSet::new();
    let mut repeated: BTreeMap<String, usize> = BTreeMap::new();
    let mut kept = Vec::with_capacity(rows.len());
    for r in rows {
        let counted = r.outcome.status == Status::Ok && !r.id.run_key.is_empty();
        let key = RunKey(r.id.run_key.clone()).short().0;
        if !counted || seen.insert((r.id.machine_id.clone(), key)) {
            kept.push(r);
        } else {
            *repeated.entry(r.id.run_key.clone()).or_insert(1) += 1;
        }
    }
    (kept, repeated)
}

/// [`split_repeats`], warning on stderr about the keys of `path` (the file read) repeated.
pub fn first_per_run_key(rows: Vec<Row>, path: &Path) -> Vec<Row> {
    let (kept, repeated) = split_repeats(rows);
    if let Some(warning) = repeats_warning(path, &repeated) {
        eprintln!("{warning}");
    }
    kept
}

/// The warning about `repeated` keys of `path`, if any.
fn repeats_warning(path: &Path, repeated: &BTreeMap<String, usize>) -> Option<String> {
    if repeated.is_empty() {
        return None;
    }
    let mut named: Vec<String> =
        repeated.iter().take(NAMED_KEYS).map(|(key, n)| format!("{key} ({n} ok rows)")).collect();
    if repeated.len() > NAMED_KEYS {
        named.push(format!("and {} more key(s)", repeated.len() - NAMED_KEYS));
    }
    Some(format!(
        "warning: {} repeats the run key of {} run(s): {}; counting the first ok row of each once (a run \
         written twice is one measurement, not two repetitions): look for two campaigns written into one \
         folder, or move the extra rows aside",
        path.display(),
        repeated.len(),
        named.join(", ")
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::plan::matrix::PlannedRun;
    use mpm_core::Strategy;
    use mpm_spec::OptLevel;

    /// A finished Taylor run of `model` with wall time `wall_s`, status `status`.
    fn row(model: u32, status: Status, wall_s: f64) -> Row {
        let mut r = Row::planned(PlannedRun::taylor(model, Strategy::DomainDecomposition, OptLevel::O3, 2, 10));
        r.outcome.status = status;
        r.measured_mut().timing.wall_s = wall_s;
        r
    }

    /// A key of three `ok` rows counts its first only, named with its count; failed
    /// attempts of a key stay; other keys are untouched.
    #[test]
    fn a_repeated_key_counts_its_first_ok_row_once() {
        let rows = vec![
            row(1, Status::Failed, 0.0),
            row(1, Status::Ok, 1.0),
            row(2, Status::Ok, 5.0),
            row(1, Status::Ok, 2.0),
            row(1, Status::Failed, 0.0),
            row(1, Status::Ok, 3.0),
        ];
        let key = rows[1].id.run_key.clone();
        let (kept, repeated) = split_repeats(rows.clone());
        assert_eq!(kept, vec![rows[0].clone(), rows[1].clone(), rows[2].clone(), rows[4].clone()]);
        assert_eq!(repeated, BTreeMap::from([(key.clone(), 3)]));
        let warning = repeats_warning(Path::new("c/runs.csv"), &repeated).unwrap();
        assert!(warning.contains("c/runs.csv") && warning.contains(&format!("{key} (3 ok rows)")), "{warning}");
        let mut elsewhere = row(1, Status::Ok, 1.0);
        elsewhere.id.machine_id = "other".into();
        let (kept, repeated) = split_repeats(vec![row(1, Status::Ok, 1.0), row(2, Status::Ok, 1.0), elsewhere]);
        assert_eq!((kept.len(), repeated.len()), (3, 0), "one key on two machines is no repeat");
        assert_eq!(repeats_warning(Path::new("x"), &repeated), None);
    }

    /// An older row's 16-digit key and a newer row's whole key of the same run are one run.
    #[test]
    fn a_short_key_and_its_whole_key_are_one_run() {
        let old = {
            let mut r = row(1, Status::Ok, 1.0);
            r.id.run_key = RunKey(r.id.run_key.clone()).short().0;
            r
        };
        let new = row(1, Status::Ok, 2.0);
        assert!(new.id.run_key.len() > old.id.run_key.len());
        let (kept, repeated) = split_repeats(vec![old.clone(), new, row(2, Status::Ok, 1.0)]);
        assert_eq!((kept[0].clone(), kept.len(), repeated.len()), (old, 2, 1));
    }

    /// Many repeated keys: the first few named, the rest counted.
    #[test]
    fn many_repeated_keys_are_counted() {
        let repeated: BTreeMap<String, usize> = (0..8).map(|i| (format!("k{i}"), 2)).collect();
        let warning = repeats_warning(Path::new("runs.csv"), &repeated).unwrap();
        assert!(warning.contains("of 8 run(s)") && warning.contains("and 3 more key(s)"), "{warning}");
        assert!(!warning.contains("k5"), "{warning}");
    }
}
