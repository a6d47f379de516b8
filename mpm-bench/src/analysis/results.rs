//! Campaign folders on disk: finding them under a results tree and reading one (its
//! `runs.csv`, `manifest.json` and `bandwidth.json`) for the analysis commands.
//!
//! A campaign run under a scheduler may hold runs of several machines (a cluster's node
//! types). Runs of different machines are never analysed together: [`load_campaigns`] splits
//! a folder into one [`Campaign`] per machine fingerprint (`figures`, `claims` and `report`
//! take each apart), and [`load_campaign`] refuses a folder of several (`regress` compares
//! one machine with itself).

use super::select::{select, Configurations, LeftOut, RowFilter, INJECTED_LEFT_OUT};
use super::stats::{Analysis, StatsOptions};
use crate::campaign::store::csv::read_rows;
use crate::campaign::store::manifest::{self, Manifest};
use crate::campaign::store::record::Row;
use crate::campaign::store::repeats::first_per_run_key;
use crate::machine::bandwidth::{self, BandwidthReport};
use anyhow::{bail, Context, Result};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// A campaign folder read from disk.
#[derive(Clone, Debug)]
pub struct Campaign {
    /// The folder (holds `runs.csv`).
    pub dir: PathBuf,
    /// Its rows of one process (`ranks` = 1): everything the paper's analyses use (figures
    /// 7-14, claims, regress, ratios).
    pub rows: Vec<Row>,
    /// Its rows split over several MPI ranks: only the hybrid analysis
    /// ([`super::hybrid`]) reads them, together with `rows` as the one-process base.
    pub hybrid: Vec<Row>,
    /// `manifest.json`, when present and readable.
    pub manifest: Option<Manifest>,
    /// `bandwidth.json`, when present and readable.
    pub bandwidth: Option<BandwidthReport>,
    /// Rows the selection rule left out, and why ([`super::select`]).
    pub left_out: Vec<LeftOut>,
    /// The configuration (scenario, grid, physics, budget) of each model and optimisation
    /// level's rows.
    pub configurations: Configurations,
    /// The machine fingerprint of every row (when they name one).
    pub machine: Option<String>,
    /// The folder holds runs of other machines too (this is one machine's part of it).
    pub split: bool,
}

impl Campaign {
    /// Campaign id: the manifest's, else the rows', else the folder name.
    pub fn id(&self) -> String {
        self.manifest
            .as_ref()
            .map(|m| m.campaign_id.clone())
            .or_else(|| self.all_rows().next().map(|r| r.id.campaign_id.clone()).filter(|s| !s.is_empty()))
            .unwrap_or_else(|| self.dir.file_name().map(|f| f.to_string_lossy().into_owned()).unwrap_or_default())
    }

    /// Machine fingerprint: the rows', else the manifest's (`unknown` if neither has one).
    pub fn fingerprint(&self) -> String {
        self.machine
            .clone()
            .or_else(|| self.manifest.as_ref().map(|m| m.machine.fingerprint.clone()))
            .unwrap_or_else(|| "unknown".into())
    }

    /// The hardware class of the campaign's machine, from its manifest (`None` without a
    /// manifest, or with one older than the class).
    pub fn hardware_class(&self) -> Option<mpm_host::identity::HardwareClass> {
        let m = self.manifest.as_ref()?;
        m.machine_of(&self.fingerprint()).and_then(|i| i.hardware_class.clone())
    }

    /// Why this campaign's results do not compare with `other`'s (another hardware class, or
    /// another machine when a class is unknown); `None` when they do
    /// ([`crate::machine::fingerprint::incomparable`]).
    pub fn incomparable_with(&self, other: &Campaign) -> Option<String> {
        let (a, b) = (self.hardware_class(), other.hardware_class());
        crate::machine::fingerprint::incomparable((&self.fingerprint(), a.as_ref()), (&other.fingerprint(), b.as_ref()))
    }

    /// The campaign id, with the machine when the folder holds several: `smoke@54276cbdfe10`.
    pub fn label(&self) -> String {
        if self.split {
            format!("{}@{}", self.id(), self.fingerprint())
        } else {
            self.id()
        }
    }

    /// Say on stderr what the selection rule left out of `what` (figures, claims, regress,
    /// report) and why.
    pub fn note_left_out(&self, what: &str) {
        for l in &self.left_out {
            eprintln!("note: {}: {what} leaves out {}", self.dir.display(), l.describe());
        }
    }

    /// Say on stderr that `what` (claims, regress) leaves out the rows over several ranks,
    /// when there are any.
    pub fn note_hybrid_left_out(&self, what: &str) {
        if !self.hybrid.is_empty() {
            eprintln!(
                "note: {}: {what} compares one-process runs only; left out {} row(s) over several MPI ranks \
                 (see `mpm-bench figures` / `report` for them against total cores)",
                self.dir.display(),
                self.hybrid.len()
            );
        }
    }

    /// Every row: one process, then several ranks.
    pub fn all_rows(&self) -> impl Iterator<Item = &Row> {
        self.rows.iter().chain(&self.hybrid)
    }

    /// Split `rows` into one-process rows and rows over several ranks.
    pub fn split(rows: Vec<Row>) -> (Vec<Row>, Vec<Row>) {
        rows.into_iter().partition(|r| !r.is_hybrid())
    }

    /// Analyse the rows with default options.
    pub fn analyse(&self, pin: Option<&str>) -> Analysis {
        Analysis::from_rows(&self.rows, pin, &StatsOptions::default())
    }
}

/// Every campaign folder (one holding `runs.csv`) at or below `dir`, at most three levels
/// deep (`results/<fingerprint>/<campaign>/runs.csv`), sorted by path.
pub fn find_campaigns(dir: &Path) -> Result<Vec<PathBuf>> {
    if !dir.exists() {
        bail!(
            "results folder {} does not exist: pass a campaign folder (with runs.csv) or a results folder \
             (e.g. results/), or run `mpm-bench run --preset smoke` first",
            dir.display()
        );
    }
    if !dir.is_dir() {
        if dir.file_name().is_some_and(|f| f == "runs.csv") {
            return Ok(vec![dir.parent().unwrap_or(Path::new(".")).to_path_buf()]);
        }
        bail!("{} is not a folder: pass a campaign folder (with runs.csv) or a results folder", dir.display());
    }
    let mut out = Vec::new();
    walk(dir, 0, &mut out)?;
    out.sort();
    Ok(out)
}

fn walk(dir: &Path, depth: usize, out: &mut Vec<PathBuf>) -> Result<()> {
    if dir.join("runs.csv").is_file() {
        out.push(dir.to_path_buf());
        return Ok(());
    }
    if depth >= 3 {
        return Ok(());
    }
    let rd = std::fs::read_dir(dir).with_context(|| format!("cannot list {}", dir.display()))?;
    for e in rd.flatten() {
        if e.file_type().is_ok_and(|t| t.is_dir()) {
            walk(&e.path(), depth + 1, out)?;
        }
    }
    Ok(())
}

/// The campaign `dir` names: `dir` itself when it holds `runs.csv`, else the campaign below
/// it whose `runs.csv` was modified last (named on stderr when there were several).
pub fn resolve_campaign(dir: &Path) -> Result<PathBuf> {
    let all = find_campaigns(dir)?;
    match all.len() {
        0 => bail!(
            "no runs.csv found in {} or its sub-folders (up to results/<fingerprint>/<campaign>/): \
             run `mpm-bench run --preset smoke` or pass the campaign folder",
            dir.display()
        ),
        1 => Ok(all.into_iter().next().expect("one")),
        n => {
            let newest = all
                .iter()
                .max_by_key(|d| std::fs::metadata(d.join("runs.csv")).and_then(|m| m.modified()).ok())
                .expect("non-empty")
                .clone();
            eprintln!(
                "note: {} holds {n} campaigns; using the newest, {} (pass a campaign folder to choose)",
                dir.display(),
                newest.display()
            );
            Ok(newest)
        }
    }
}

/// Read the campaign `dir` names (see [`resolve_campaign`]), which must hold the runs of one
/// machine (see [`load_campaigns`]).
pub fn load_campaign(dir: &Path, filter: &RowFilter) -> Result<Campaign> {
    let mut parts = load_campaigns(dir, filter)?;
    if parts.len() > 1 {
        let fps: Vec<String> = parts.iter().map(Campaign::fingerprint).collect();
        bail!(
            "{} holds runs of {} machines ({}): runs of different machines are never compared as one; `figures`, \
             `claims` and `report` take each machine apart",
            parts[0].dir.display(),
            parts.len(),
            fps.join(", ")
        );
    }
    Ok(parts.remove(0))
}

/// A file beside a campaign's `runs.csv` read by `read`: `None` when absent, or (with a
/// warning) when it cannot be read.
fn read_beside<T>(path: &Path, read: impl FnOnce(&Path) -> Result<T>) -> Option<T> {
    if !path.is_file() {
        return None;
    }
    read(path).map_err(|e| eprintln!("warning: ignoring {}: {e:#}", path.display())).ok()
}

/// Read the campaign `dir` names (see [`resolve_campaign`]): rows (a run key's first `ok`
/// row only, [`first_per_run_key`]), manifest, bandwidth; one
/// [`Campaign`] per machine fingerprint of its rows, in fingerprint order (one for a campaign
/// run on one machine); in each, the rows an analysis uses by the one rule of
/// [`super::select`] with `filter`, and what it left out. A machine's part takes its manifest
/// machine from the manifest's `nodes` (a scheduler's node types); rows that name no machine
/// (a job that never reached a node) join the one machine, or are left out when there are
/// several.
pub fn load_campaigns(dir: &Path, filter: &RowFilter) -> Result<Vec<Campaign>> {
    let dir = resolve_campaign(dir)?;
    let csv = dir.join("runs.csv");
    let all = first_per_run_key(read_rows(&csv)?, &csv);
    let manifest = read_beside(&dir.join("manifest.json"), manifest::read);
    let bandwidth = read_beside(&dir.join("bandwidth.json"), bandwidth::read);
    let mut by_machine: BTreeMap<String, Vec<Row>> = BTreeMap::new();
    let mut nameless = Vec::new();
    for r in all {
        if r.id.machine_id.is_empty() {
            nameless.push(r);
        } else {
            by_machine.entry(r.id.machine_id.clone()).or_default().push(r);
        }
    }
    let split = by_machine.len() > 1;
    let mut groups: Vec<(Option<String>, Vec<Row>)> = by_machine.into_iter().map(|(f, r)| (Some(f), r)).collect();
    let mut unplaced = None;
    match groups.as_mut_slice() {
        [] => groups.push((None, nameless)),
        [(_, rows)] => rows.extend(nameless),
        _ if !nameless.is_empty() => {
            unplaced = Some(LeftOut {
                reason: "that name no machine (jobs that never reached a node), in a campaign of several machines"
                    .into(),
                rows: nameless.len(),
            });
        }
        _ => {}
    }
    let parts = groups
        .into_iter()
        .map(|(fp, rows)| {
            let (rows, mut left_out, configurations) = select(rows, filter);
            refuse_only_injected(&dir, &rows, &left_out)?;
            left_out.extend(unplaced.clone());
            let mut manifest = manifest.clone();
            if let (Some(m), Some(fp)) = (manifest.as_mut(), fp.as_deref()) {
                if let Some(node) = m.nodes.get(fp) {
                    m.machine = node.machine.clone();
                }
            }
            // bandwidth.json is measured on one machine: it belongs to that machine's part.
            let bandwidth = bandwidth.clone().filter(|b| !split || fp.as_deref().is_none_or(|f| b.machine_id == f));
            let (rows, hybrid) = Campaign::split(rows);
            Ok(Campaign {
                dir: dir.clone(),
                rows,
                hybrid,
                manifest,
                bandwidth,
                left_out,
                configurations,
                machine: fp,
                split,
            })
        })
        .collect::<Result<Vec<_>>>()?;
    Ok(parts)
}

/// A campaign (or a machine's part of it) whose every measured row ran with an injected
/// slowdown is refused unless the filter kept them: its numbers are a test of the gate,
/// never a result.
fn refuse_only_injected(dir: &Path, rows: &[Row], left_out: &[LeftOut]) -> Result<()> {
    let injected = left_out.iter().find(|l| l.reason == INJECTED_LEFT_OUT).map_or(0, |l| l.rows);
    if injected > 0 && !rows.iter().any(|r| r.outcome.status == crate::campaign::store::record::Status::Ok) {
        bail!(
            "{}: its {injected} measured row(s) all ran with an injected slowdown (`--inject-slowdown`, a test knob \
             of the regression gate): their times are not results; pass --include-injected to look at them anyway",
            dir.display()
        );
    }
    Ok(())
}
