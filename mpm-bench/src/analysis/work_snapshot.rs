//! The work counters against a committed snapshot: `ci/work-baseline.json`, the counters of
//! the gate's cells ([`WorkSnapshot`]), checked exactly on any machine ([`check`]).
//!
//! Every run counts, per worker and sub-stage, the bytes its work stands for
//! ([`mpm_core::work`]): a function of the particles, the grid, the strategy, the thread count
//! and the steps taken, never of the host, the optimisation level or the timing. So the
//! counters of a cell are a fixed number for a given commit, like the output of a snapshot
//! test: a change of the code that makes a worker move more (or fewer) bytes in a sub-stage
//! shows as a changed count, on the noisiest CI runner, in one run. `mpm-bench work-snapshot
//! --write FILE` records them from one run per cell (a reviewed commit, like any snapshot);
//! `--check FILE` runs the cells again and compares exactly; `regress --work-snapshot FILE`
//! and `ab --work-snapshot FILE` compare the rows they already have. Any difference, more or
//! less, fails the check, naming the cell and the sub-stage: an intended change is committed
//! with the snapshot rewritten.
//!
//! A cell is matched by its scenario, model, strategy, optimisation level and threads and
//! compared only when it ran the snapshot's steps (the counts add up over the steps);
//! cells of the campaign that the snapshot does not hold are listed, not failed.

use super::stats::CellKey;
use crate::campaign::store::record::{Row, Status};
use anyhow::{bail, Context, Result};
use mpm_core::Substage;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// Version of the snapshot file's layout.
pub const SNAPSHOT_VERSION: u32 = 1;

/// The counters of one cell.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SnapshotCell {
    /// The scenario (`taylor`, `impact`).
    pub scenario: String,
    /// The cell, e.g. `Model1 DD O3 2t`.
    pub cell: String,
    /// Steps the run took (the counters add up over them).
    pub steps: u64,
    /// Per sub-stage, the bytes each worker's work stands for (worker order).
    pub bytes: BTreeMap<Substage, Vec<u64>>,
}

/// `ci/work-baseline.json`: the work counters of a preset's cells.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkSnapshot {
    /// [`SNAPSHOT_VERSION`].
    pub snapshot_version: u32,
    /// The preset the cells come from.
    pub preset: String,
    /// The command that wrote it.
    pub command: String,
    /// What the file is, for a reader who finds it in the repository.
    pub about: String,
    /// The cells, in cell order.
    pub cells: Vec<SnapshotCell>,
}

/// What [`WorkSnapshot::about`] says.
pub const ABOUT: &str = "Work counters of the gate's cells (bytes per sub-stage and worker, over every step of one \
    run): the same on every machine for a given commit. Checked exactly by `mpm-bench work-snapshot --check`, \
    `regress --work-snapshot` and `ab --work-snapshot`; an intended change is committed with this file rewritten \
    by `mpm-bench work-snapshot --write`.";

/// A cell's counters that differ from the snapshot's.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SnapshotChange {
    /// The cell.
    pub cell: String,
    /// What differs, sub-stage by sub-stage.
    pub changes: Vec<String>,
}

/// The check of a campaign's counters against a snapshot.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SnapshotCheck {
    /// The snapshot file.
    pub file: String,
    /// Cells compared.
    pub compared: usize,
    /// Cells whose counters differ (they fail the check).
    pub changed: Vec<SnapshotChange>,
    /// Cells of the campaign the snapshot does not hold, or holds for other steps (not
    /// compared).
    pub not_in_snapshot: Vec<String>,
    /// Cells of the snapshot the campaign did not measure.
    pub not_measured: Vec<String>,
}

impl SnapshotCheck {
    /// Whether the counters match: no cell changed and at least one compared.
    pub fn passed(&self) -> bool {
        self.changed.is_empty() && self.compared > 0
    }

    /// In one sentence.
    pub fn summary(&self) -> String {
        if !self.changed.is_empty() {
            let first = &self.changed[0];
            format!(
                "work counters differ from the snapshot {} in {} of {} cell(s), first {}: {} (if intended, rewrite it \
                 with `mpm-bench work-snapshot --write {}` and commit it)",
                self.file,
                self.changed.len(),
                self.compared,
                first.cell,
                first.changes.join("; "),
                self.file
            )
        } else if self.compared == 0 {
            format!("no cell of the snapshot {} was measured with its steps: nothing compared", self.file)
        } else {
            format!("work counters equal to the snapshot {} in all {} cell(s)", self.file, self.compared)
        }
    }
}

/// What differs between two runs' counters (per sub-stage, per worker: bytes), one line per
/// sub-stage that differs, and whether a worker or the total moved more (`.1`) or less
/// (`.2`) bytes anywhere.
pub fn work_changes(
    base: &BTreeMap<Substage, Vec<u64>>,
    cur: &BTreeMap<Substage, Vec<u64>>,
) -> (Vec<String>, bool, bool) {
    let max = |v: &[u64]| v.iter().copied().max().unwrap_or(0);
    let mut changes = Vec::new();
    let (mut more, mut less) = (false, false);
    for s in Substage::ALL {
        let empty = Vec::new();
        let (x, y) = (base.get(&s).unwrap_or(&empty), cur.get(&s).unwrap_or(&empty));
        if x == y {
            continue;
        }
        let (mx, my, sx, sy) = (max(x), max(y), x.iter().sum::<u64>(), y.iter().sum::<u64>());
        more |= my > mx || sy > sx;
        less |= my < mx || sy < sx;
        let pct = |a: u64, b: u64| {
            if a > 0 {
                format!("{:+.1} %", 100.0 * (b as f64 / a as f64 - 1.0))
            } else {
                "new".into()
            }
        };
        changes.push(format!(
            "{}: busiest worker {mx} -> {my} B ({}), all workers {sx} -> {sy} B ({})",
            s.name(),
            pct(mx, my),
            pct(sx, sy)
        ));
    }
    let workers = |m: &BTreeMap<Substage, Vec<u64>>| m.values().map(Vec::len).max().unwrap_or(0);
    if workers(base) != workers(cur) {
        more = true;
        changes.push(format!("{} workers counted, {} before", workers(cur), workers(base)));
    }
    (changes, more, less)
}

/// The counters of the `ok` rows of `rows` with counters, one entry per cell (the first
/// row's; the rows of a cell must count the same work).
pub fn cells_of(rows: &[Row]) -> Result<Vec<SnapshotCell>> {
    let mut out: BTreeMap<(String, CellKey), SnapshotCell> = BTreeMap::new();
    for r in rows.iter().filter(|r| r.outcome.status == Status::Ok) {
        let Some(f) = r.measured.as_ref() else { continue };
        let Some(w) = f.work.as_ref().filter(|w| !w.bytes.is_empty()) else { continue };
        let key = CellKey::new(r.model(), r.strategy(), r.opt().as_str(), r.threads());
        let entry = SnapshotCell {
            scenario: r.scenario().to_string(),
            cell: key.to_string(),
            steps: f.progress.steps,
            bytes: w.bytes.clone(),
        };
        match out.get(&(entry.scenario.clone(), key.clone())) {
            Some(first) if first != &entry => bail!(
                "the rows of {} counted different work (the counters must repeat exactly: a solver bug?)",
                entry.cell
            ),
            Some(_) => {}
            None => {
                out.insert((entry.scenario.clone(), key), entry);
            }
        }
    }
    Ok(out.into_values().collect())
}

/// Compare `cells` (a campaign's, [`cells_of`]) with `snapshot` (read from `file`) exactly.
pub fn check(snapshot: &WorkSnapshot, file: &Path, cells: &[SnapshotCell]) -> SnapshotCheck {
    let mut out = SnapshotCheck {
        file: file.display().to_string(),
        compared: 0,
        changed: Vec::new(),
        not_in_snapshot: Vec::new(),
        not_measured: Vec::new(),
    };
    for c in cells {
        let Some(s) = snapshot.cells.iter().find(|s| s.scenario == c.scenario && s.cell == c.cell) else {
            out.not_in_snapshot.push(format!("{} {}", c.scenario, c.cell));
            continue;
        };
        if s.steps != c.steps {
            out.not_in_snapshot
                .push(format!("{} {} ({} steps, the snapshot's {})", c.scenario, c.cell, c.steps, s.steps));
            continue;
        }
        out.compared += 1;
        let (changes, _, _) = work_changes(&s.bytes, &c.bytes);
        if !changes.is_empty() {
            out.changed.push(SnapshotChange { cell: format!("{} {}", c.scenario, c.cell), changes });
        }
    }
    for s in &snapshot.cells {
        if !cells.iter().any(|c| c.scenario == s.scenario && c.cell == s.cell) {
            out.not_measured.push(format!("{} {}", s.scenario, s.cell));
        }
    }
    out
}

/// Read a snapshot file.
pub fn read(path: &Path) -> Result<WorkSnapshot> {
    let text = std::fs::read_to_string(path).with_context(|| {
        format!(
            "cannot read the work snapshot {}: give the committed file (ci/work-baseline.json), or write one with \
             `mpm-bench work-snapshot --write FILE`",
            path.display()
        )
    })?;
    let s: WorkSnapshot = serde_json::from_str(&text)
        .with_context(|| format!("{} is not a work snapshot (mpm-bench work-snapshot --write)", path.display()))?;
    if s.snapshot_version != SNAPSHOT_VERSION {
        bail!(
            "{} is a work snapshot of layout {} (this harness reads {SNAPSHOT_VERSION}): rewrite it with \
             `mpm-bench work-snapshot --write`",
            path.display(),
            s.snapshot_version
        );
    }
    Ok(s)
}

/// Write `snapshot` to `path` (atomically, pretty JSON with a final newline).
pub fn write(path: &Path, snapshot: &WorkSnapshot) -> Result<()> {
    if let Some(parent) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    let text = serde_json::to_string_pretty(snapshot)? + "\n";
    mpm_host::atomic::write_atomic(path, text.as_bytes()).with_context(|| format!("cannot write {}", path.display()))
}

/// Check the `ok` rows of a campaign against the snapshot at `path`.
pub fn check_rows(path: &Path, rows: &[Row]) -> Result<SnapshotCheck> {
    let snapshot = read(path)?;
    Ok(check(&snapshot, path, &cells_of(rows)?))
}

/// The snapshot of `rows` (a campaign of `preset` made by `command`).
pub fn snapshot_of(rows: &[Row], preset: &str, command: &str) -> Result<WorkSnapshot> {
    let cells = cells_of(rows)?;
    if cells.is_empty() {
        bail!("no run with work counters: nothing to write (did every run fail? see the campaign's runs.csv)");
    }
    Ok(WorkSnapshot {
        snapshot_version: SNAPSHOT_VERSION,
        preset: preset.into(),
        command: command.into(),
        about: ABOUT.into(),
        cells,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cell(name: &str, scatter: Vec<u64>) -> SnapshotCell {
        SnapshotCell {
            scenario: "taylor".into(),
            cell: name.into(),
            steps: 83,
            bytes: [(Substage::Scatter, scatter), (Substage::Assembly, vec![10, 10])].into_iter().collect(),
        }
    }

    fn snapshot(cells: Vec<SnapshotCell>) -> WorkSnapshot {
        WorkSnapshot { snapshot_version: 1, preset: "ci".into(), command: "t".into(), about: ABOUT.into(), cells }
    }

    /// The check compares exactly and names the cell and the sub-stage that changed; a cell
    /// of other steps or outside the snapshot is listed, not compared.
    #[test]
    fn the_check_names_the_changed_cell_and_sub_stage() {
        let snap = snapshot(vec![cell("Model1 AE O3 2t", vec![100, 100]), cell("Model1 DD O3 2t", vec![60, 50])]);
        let f = Path::new("ci/work-baseline.json");
        let same = check(&snap, f, &snap.cells);
        assert!(same.passed(), "{}", same.summary());
        assert_eq!(same.compared, 2);
        let mut moved = snap.cells.clone();
        moved[1].bytes.insert(Substage::Scatter, vec![60, 51]);
        let c = check(&snap, f, &moved);
        assert!(!c.passed());
        assert_eq!(c.changed.len(), 1);
        assert_eq!(c.changed[0].cell, "taylor Model1 DD O3 2t");
        assert!(c.changed[0].changes[0].starts_with("scatter: busiest worker 60 -> 60 B"), "{:?}", c.changed);
        assert!(c.summary().contains("Model1 DD O3 2t: scatter") && c.summary().contains("--write"), "{}", c.summary());
        // Fewer bytes fail the snapshot too (it is a snapshot, not a bound).
        let mut less = snap.cells.clone();
        less[0].bytes.insert(Substage::Assembly, vec![10, 9]);
        assert!(check(&snap, f, &less).changed[0].changes[0].starts_with("assembly"));
        // Another step count: not compared; a cell outside: listed.
        let mut other = snap.cells.clone();
        other[0].steps = 20;
        other.push(cell("Model2 AE O3 2t", vec![1, 1]));
        let c = check(&snap, f, &other);
        assert_eq!((c.compared, c.changed.len(), c.not_in_snapshot.len()), (1, 0, 2));
        assert!(c.not_in_snapshot[0].contains("20 steps, the snapshot's 83"), "{:?}", c.not_in_snapshot);
        assert!(check(&snap, f, &[]).not_measured.len() == 2 && !check(&snap, f, &[]).passed());
    }
}
