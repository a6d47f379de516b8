//! One CSV row per run: [`Row`] is the single source of the header.
//!
//! Rows are appended and flushed (and synced) right after each run, so an interrupted
//! campaign keeps every finished run. Reading back ([`read_rows`]) checks the header first and
//! names any missing column. A partial last line (a kill in the middle of a write) is cut off
//! when the file is opened for appending again ([`CsvLog::open`]).
//!
//! Units are SI (seconds, bytes, joules, metres). Lists of CPUs are written space-separated
//! (`"0 1"`). Empty cells mean "not measured" (for example every measurement of a skipped row).

use anyhow::{bail, Context, Result};
use mpm_core::Strategy;
use serde::{Deserialize, Serialize};
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// Version of the row layout; bump it whenever a column is added, removed or renamed.
pub const SCHEMA_VERSION: u32 = 3;

/// Columns added in schema 2; files of schema 1 lack them and still read (as empty).
const ADDED_IN_V2: [&str; 2] = ["worker_busy_s", "load_imbalance"];

/// Columns added in schema 3; older files lack them and still read (as empty).
const ADDED_IN_V3: [&str; 1] = ["dd_work_imbalance"];

/// Outcome of one run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// Ran to its step limit or end time; all checks passed.
    #[default]
    Ok,
    /// Not attempted (e.g. the memory guard); `reason` says why.
    Skipped,
    /// The solver exited non-zero, timed out, or wrote no usable summary.
    Failed,
    /// Ran, but a check failed (e.g. observed CPUs differ from the requested ones).
    Invalid,
}

impl Status {
    /// Lower-case name as written in the CSV.
    pub fn as_str(self) -> &'static str {
        match self {
            Status::Ok => "ok",
            Status::Skipped => "skipped",
            Status::Failed => "failed",
            Status::Invalid => "invalid",
        }
    }
}

/// One run of the campaign (one CSV row). Field order is column order.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Row {
    // ---- identity ----
    /// [`SCHEMA_VERSION`] of the writer.
    pub schema_version: u32,
    /// Campaign id (folder name).
    pub campaign_id: String,
    /// Unique id of the run within the campaign: configuration key plus attempt number.
    pub run_id: String,
    /// Time the run ended (RFC 3339, UTC).
    pub timestamp: String,
    /// Git commit of the harness' workspace (`unknown` outside a repository).
    pub git_commit: String,
    /// Whether the work tree had uncommitted changes.
    pub git_dirty: bool,
    /// Machine fingerprint id (see `manifest`).
    pub machine_id: String,
    /// SHA-256 (first 16 hex digits) of the solver binary that ran.
    pub binary_sha256: String,
    /// Seed of the shuffled run order of the session that ran this row.
    pub seed: u64,
    /// Position of the run in that session's order (0-based).
    pub order_index: usize,

    // ---- configuration ----
    /// Scenario (`taylor`).
    pub scenario: String,
    /// Model number (1-4).
    pub model: u32,
    /// Particles.
    pub particles: Option<u64>,
    /// Grid cells (initial grid).
    pub cells: Option<u64>,
    /// Grid nodes (initial grid).
    pub nodes: Option<u64>,
    /// Mean number of grid nodes over the steps (differs from `nodes` on the adaptive grid).
    pub mean_nodes: Option<f64>,
    /// `fixed` or `adaptive`.
    pub grid_mode: String,
    /// `serial`, `ae` (array expansion) or `dd` (domain decomposition).
    pub strategy: Strategy,
    /// `o3` or `o0` (the Cargo profile of the solver binary).
    pub opt_level: String,
    /// Worker threads.
    pub threads: usize,
    /// Pinning policy label (`close`, `spread`, `none`, or a CPU list).
    pub pin_policy: String,
    /// CPU requested for each worker (space-separated; empty when not pinned).
    pub requested_cpus: String,
    /// CPU each worker observed itself on (space-separated).
    pub observed_cpus: String,
    /// More threads than usable cores (time sharing: not a scaling point).
    pub oversubscribed: bool,
    /// Repetition index (0-based).
    pub rep: u32,
    /// Warm-up steps excluded from the steady-state figure.
    pub warmup_steps: u64,
    /// Step limit of the run, if it had one.
    pub step_limit: Option<u64>,
    /// Simulated end time of the run, if it had one (s).
    pub end_time_s: Option<f64>,
    /// Steps taken.
    pub steps: Option<u64>,
    /// Simulated time reached (s).
    pub sim_time_s: Option<f64>,
    /// Why the run stopped: `end_time` or `step_limit`.
    pub end_reason: String,
    /// First time step (s).
    pub dt_first_s: Option<f64>,

    // ---- measurements ----
    /// Solver's wall time of the time loop (s).
    pub wall_s: Option<f64>,
    /// Wall time of the child process as the harness saw it, set-up included (s).
    pub process_wall_s: Option<f64>,
    /// Grid-node stage (paper Eqs. 1-6), s.
    pub grid_stage_s: Option<f64>,
    /// Particle stage (paper Eqs. 7-15), s.
    pub particle_stage_s: Option<f64>,
    /// Sub-stage: adaptive grid re-fit / DD re-cut (s).
    pub sub_grid_fit_s: Option<f64>,
    /// Sub-stage: DD particle binning (s).
    pub sub_binning_s: Option<f64>,
    /// Sub-stage: P2G scatter of mass, momentum, force (s).
    pub sub_scatter_s: Option<f64>,
    /// Sub-stage: assembly of per-thread copies / sub-grids (s).
    pub sub_assembly_s: Option<f64>,
    /// Sub-stage: nodal update and boundary conditions (s).
    pub sub_grid_update_s: Option<f64>,
    /// Sub-stage: G2P gather of nodal accelerations (s).
    pub sub_gather_s: Option<f64>,
    /// Sub-stage: MUSL re-map scatter (s).
    pub sub_remap_scatter_s: Option<f64>,
    /// Sub-stage: MUSL re-map assembly (s).
    pub sub_remap_assembly_s: Option<f64>,
    /// Sub-stage: positions, strains, stress update (s).
    pub sub_stress_update_s: Option<f64>,
    /// Steady-state wall time per step, warm-up excluded (s).
    pub steady_s_per_step: Option<f64>,
    /// Wall time per particle per step (ns).
    pub ns_per_particle_step: Option<f64>,
    /// Particle-steps per second.
    pub particle_steps_per_s: Option<f64>,
    /// Steady-state busy seconds of each worker in its shares of the parallel phases
    /// (space-separated, worker order; empty for the serial strategy). Since schema 2.
    #[serde(default)]
    pub worker_busy_s: String,
    /// Largest worker busy time over the mean (1 = balanced; well above 1 on a
    /// non-oversubscribed run: a worker's CPU was slowed from outside the run). Since schema 2.
    #[serde(default)]
    pub load_imbalance: Option<f64>,
    /// DD and balanced DD: the most particles in a patch over the mean per patch, averaged
    /// over the run's steps (the summary's `dd_patch_particles.imbalance_mean`; a property
    /// of the cuts, not of the machine). Since schema 3.
    #[serde(default)]
    pub dd_work_imbalance: Option<f64>,
    /// Peak resident memory of the solver process (VmHWM read by the solver), bytes.
    pub peak_rss_bytes: Option<u64>,
    /// The memory guard's estimate for this run, bytes.
    pub mem_estimate_bytes: u64,
    /// Exit code of the solver process (empty when it did not run or died by a signal).
    pub exit_code: Option<i32>,

    // ---- physics checksums ----
    /// Initial kinetic energy (J).
    pub kinetic_energy_initial_j: Option<f64>,
    /// Final kinetic energy (J).
    pub kinetic_energy_j: Option<f64>,
    /// Final internal energy (J).
    pub internal_energy_j: Option<f64>,
    /// Taylor bar: initial length (m).
    pub initial_length_m: Option<f64>,
    /// Taylor bar: final length (m).
    pub final_length_m: Option<f64>,
    /// Taylor bar: impact-face diameter (m).
    pub face_diameter_m: Option<f64>,
    /// Impact: debris-cloud leading edge beyond the plate's rear face (m).
    pub cloud_front_m: Option<f64>,
    /// Impact: debris-cloud width normal to the flight direction (m).
    pub cloud_width_m: Option<f64>,
    /// Failed particles at the end.
    pub failed_particles: Option<u64>,

    // ---- status ----
    /// `ok`, `skipped`, `failed` or `invalid`.
    pub status: Status,
    /// Why a row is not `ok` (empty when it is).
    pub reason: String,
}

/// What identifies a configuration for resuming: two rows with the same key ran the same
/// thing.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct RunKey(pub String);

impl Row {
    /// The CSV header, in column order.
    pub fn header() -> Vec<String> {
        let mut w = csv::WriterBuilder::new().has_headers(true).from_writer(Vec::new());
        w.serialize(Row::default()).expect("a default row serialises");
        let bytes = w.into_inner().expect("in-memory writer");
        let mut r = csv::ReaderBuilder::new().has_headers(true).from_reader(bytes.as_slice());
        r.headers().expect("header line").iter().map(str::to_string).collect()
    }

    /// Resume key of this row's configuration.
    pub fn key(&self) -> RunKey {
        run_key(
            self.model,
            self.strategy,
            &self.opt_level,
            self.threads,
            &self.pin_policy,
            self.rep,
            &self.grid_mode,
            self.warmup_steps,
            self.step_limit,
            self.end_time_s,
        )
    }
}

/// Build a resume key from the configuration fields.
#[allow(clippy::too_many_arguments)]
pub fn run_key(
    model: u32,
    strategy: Strategy,
    opt: &str,
    threads: usize,
    pin: &str,
    rep: u32,
    grid: &str,
    warmup: u64,
    step_limit: Option<u64>,
    end_time: Option<f64>,
) -> RunKey {
    let budget = match (step_limit, end_time) {
        (Some(n), Some(t)) => format!("n{n}+t{t:e}"),
        (Some(n), None) => format!("n{n}"),
        (None, Some(t)) => format!("t{t:e}"),
        (None, None) => "unbounded".into(),
    };
    RunKey(format!("m{model}-{strategy}-{opt}-t{threads}-{pin}-{grid}-w{warmup}-{budget}-r{rep}"))
}

/// Space-separated CPU list for a CSV cell.
pub fn cpus_cell(cpus: &[usize]) -> String {
    cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(" ")
}

/// Parse a CSV CPU cell back.
pub fn parse_cpus_cell(s: &str) -> Vec<usize> {
    s.split_whitespace().filter_map(|t| t.parse().ok()).collect()
}

/// Read every row of a results CSV, checking the header first.
pub fn read_rows(path: &Path) -> Result<Vec<Row>> {
    let mut r = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_path(path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    let have: Vec<String> = r
        .headers()
        .with_context(|| format!("cannot read the header of {}", path.display()))?
        .iter()
        .map(str::to_string)
        .collect();
    let want = Row::header();
    let missing: Vec<&str> = want
        .iter()
        .filter(|c| !have.contains(c) && !ADDED_IN_V2.contains(&c.as_str()) && !ADDED_IN_V3.contains(&c.as_str()))
        .map(String::as_str)
        .collect();
    if !missing.is_empty() {
        bail!(
            "{} is missing column(s) {} (this harness writes schema version {SCHEMA_VERSION}); \
             it was written by another version: move it aside or run with --fresh",
            path.display(),
            missing.join(", ")
        );
    }
    let mut rows = Vec::new();
    for (i, rec) in r.deserialize::<Row>().enumerate() {
        rows.push(rec.with_context(|| format!("{}: bad row {}", path.display(), i + 2))?);
    }
    Ok(rows)
}

/// An append-only CSV log: header written once, every row flushed and synced.
pub struct CsvLog {
    path: PathBuf,
    file: File,
}

impl CsvLog {
    /// Open (creating if needed) `path` for appending. An existing file must carry this
    /// harness' header; a partial last line left by a kill is cut off.
    pub fn open(path: &Path) -> Result<Self> {
        let mut file = OpenOptions::new()
            .read(true)
            .append(true)
            .create(true)
            .open(path)
            .with_context(|| format!("cannot open {} for appending", path.display()))?;
        let mut text = Vec::new();
        file.read_to_end(&mut text).with_context(|| format!("cannot read {}", path.display()))?;
        if text.is_empty() {
            let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
            w.write_record(Row::header())?;
            let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
            file.write_all(&bytes).with_context(|| format!("cannot write {}", path.display()))?;
            file.sync_data().ok();
        } else {
            if text.last() != Some(&b'\n') {
                let keep = text.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
                eprintln!("warning: {} ended in a partial line (interrupted write); dropping it", path.display());
                file.set_len(keep as u64).with_context(|| format!("cannot repair {}", path.display()))?;
                file.seek(SeekFrom::End(0))?;
            }
            // Validate every row, then demand this schema's exact header: rows appended
            // under another header would be misread.
            read_rows(path)?;
            let have: Vec<String> = csv::Reader::from_path(path)?.headers()?.iter().map(str::to_string).collect();
            if have != Row::header() {
                bail!(
                    "{} was written by another version of the harness (its columns differ from schema version \
                     {SCHEMA_VERSION}); new rows cannot be appended to it: move it aside, write to another \
                     --out, or run with --fresh",
                    path.display()
                );
            }
        }
        Ok(Self { path: path.to_path_buf(), file })
    }

    /// Append one row and make it durable.
    pub fn append(&mut self, row: &Row) -> Result<()> {
        let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
        w.serialize(row)?;
        let bytes = w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))?;
        self.file.write_all(&bytes).with_context(|| format!("cannot append to {}", self.path.display()))?;
        self.file.flush()?;
        self.file.sync_data().ok();
        Ok(())
    }

    /// Path of the log.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_complete_and_round_trips() {
        let h = Row::header();
        for col in ["campaign_id", "requested_cpus", "observed_cpus", "oversubscribed", "status", "reason"] {
            assert!(h.iter().any(|c| c == col), "{col}");
        }
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let mut log = CsvLog::open(&p).unwrap();
        let row = Row {
            schema_version: SCHEMA_VERSION,
            model: 2,
            threads: 4,
            requested_cpus: cpus_cell(&[0, 1, 0, 1]),
            status: Status::Skipped,
            reason: "memory, guard".into(),
            wall_s: Some(1.5),
            ..Row::default()
        };
        log.append(&row).unwrap();
        drop(log);
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![row.clone()]);
        assert_eq!(parse_cpus_cell(&rows[0].requested_cpus), vec![0, 1, 0, 1]);
        // A torn last line is dropped on reopen.
        std::fs::OpenOptions::new().append(true).open(&p).unwrap().write_all(b"1,abc,").unwrap();
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row).unwrap();
        assert_eq!(read_rows(&p).unwrap().len(), 2);
    }

    #[test]
    fn missing_columns_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        std::fs::write(&p, "schema_version,campaign_id\n1,x\n").unwrap();
        let err = format!("{:#}", read_rows(&p).unwrap_err());
        assert!(err.contains("missing column"), "{err}");
        assert!(err.contains("observed_cpus"), "{err}");
    }

    /// A schema-1 file (without the load-imbalance columns) still reads: its rows get
    /// empty values there and everything else intact. Appending to it is refused.
    #[test]
    fn schema_1_files_still_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let row = Row { schema_version: 1, campaign_id: "old".into(), model: 2, wall_s: Some(1.5), ..Row::default() };
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(&row).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        // Drop the two schema-2 columns from header and row.
        let drop = |line: &str, idx: &[usize]| {
            line.split(',').enumerate().filter(|(i, _)| !idx.contains(i)).map(|(_, c)| c).collect::<Vec<_>>().join(",")
        };
        let header = Row::header();
        let idx: Vec<usize> =
            ADDED_IN_V2.iter().chain(&ADDED_IN_V3).map(|c| header.iter().position(|h| h == c).unwrap()).collect();
        let old: String = text.lines().map(|l| drop(l, &idx) + "\n").collect();
        assert!(!old.lines().next().unwrap().contains("load_imbalance"));
        std::fs::write(&p, old).unwrap();
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![row]);
        assert!(CsvLog::open(&p).is_err(), "appending schema-2 rows to a schema-1 file must be refused");
    }
}
