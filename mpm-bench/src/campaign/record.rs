//! One CSV row per run: [`Row`] is the single source of the header.
//!
//! Rows are appended and flushed (and synced) right after each run, so an interrupted
//! campaign keeps every finished run. Reading back ([`read_rows`]) checks the header first and
//! names any missing column.
//!
//! A torn last line (power loss, disk full, a kill in the middle of a write: no trailing
//! newline, or fewer fields than the header) is found before the file is parsed
//! ([`complete_len`]). Readers ([`read_rows`], used by every analysis command) warn and read
//! the complete rows; the campaign runner ([`repair_torn_tail`], also in [`CsvLog::open`])
//! moves the torn bytes to `runs.csv.torn-<time>`, says so, and redoes that run.
//!
//! Units are SI (seconds, bytes, joules, metres). Lists of CPUs are written space-separated
//! (`"0 1"`). Empty cells mean "not measured" (for example every measurement of a skipped row).

use crate::machine::load::{HostReading, Probe};
use anyhow::{bail, Context, Result};
use mpm_core::Strategy;
use serde::{Deserialize, Serialize};
use std::fs::{File, OpenOptions};
use std::io::{Read, Write};
use std::path::{Path, PathBuf};

/// Version of the row layout; bump it whenever a column is added, removed or renamed.
/// Schema 3 added the host's load and calibration (`host_*`, `calib_*`, `host_noisy`) and
/// the work imbalance of DD's cuts (`dd_work_imbalance`). Schema 4 added MPI ranks
/// (`ranks`, `threads_per_rank`, `launcher`, `rank_*`, `comm_*`, `migrated_particles`,
/// `peak_rss_sum_bytes`); `threads` became the run's total worker count (ranks x threads
/// per rank, equal to the old meaning at one rank). Schema 5 runs every row over several
/// ranks with `mpm run --split-wait` and records the waiting for other ranks apart
/// (`wait_s_per_step`, `wait_frac`); `comm_*` seconds are then the communication alone
/// (in schema-4 rows they include the waiting, and the `wait_*` columns read as empty).
pub const SCHEMA_VERSION: u32 = 5;

/// Columns added since schema 1; older files lack them and still read (as empty / false;
/// `ranks` as 1 and `threads_per_rank` as `threads`).
const ADDED_SINCE_V1: [&str; 28] = [
    // schema 2
    "worker_busy_s",
    "load_imbalance",
    // schema 3
    "host_load1_before",
    "host_load1_after",
    "host_others_running_before",
    "host_others_running_after",
    "host_cpus_busy_before",
    "host_cpus_busy_after",
    "host_steal_frac",
    "calib_spin_ratio",
    "calib_copy_ratio",
    "host_noisy",
    "host_noise",
    "dd_work_imbalance",
    // schema 4
    "ranks",
    "threads_per_rank",
    "launcher",
    "rank_cpus",
    "rank_particles",
    "rank_busy_imbalance",
    "migrated_particles",
    "comm_s_per_step",
    "comm_frac",
    "comm_bytes_per_step",
    "comm_messages_per_step",
    "peak_rss_sum_bytes",
    // schema 5
    "wait_s_per_step",
    "wait_frac",
];

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
    /// Worker threads of the whole run: ranks x threads per rank (at one rank, the process's
    /// threads). Oversubscription and the host-noise rule count these against the cores.
    pub threads: usize,
    /// MPI ranks (1: one process started directly). Since schema 4.
    #[serde(default = "one")]
    pub ranks: usize,
    /// Worker threads of each rank (the solver's `--threads`). Since schema 4 (read as
    /// `threads` from older files).
    #[serde(default)]
    pub threads_per_rank: usize,
    /// The launcher command of a run with several ranks (empty at one rank). Since schema 4.
    #[serde(default)]
    pub launcher: String,
    /// Pinning policy label (`close`, `spread`, `none`, or a CPU list).
    pub pin_policy: String,
    /// CPU requested for each worker (space-separated; empty when not pinned). With several
    /// ranks: the CPU set handed to the launcher as its affinity mask, ascending; rank r's
    /// workers are asked to take its r-th slice of `threads_per_rank` CPUs.
    pub requested_cpus: String,
    /// CPU each worker observed itself on (space-separated); with several ranks every
    /// rank's workers, rank by rank.
    pub observed_cpus: String,
    /// With several ranks: each rank's observed CPUs, ranks separated by `|` (`"0|1"`).
    /// Since schema 4.
    #[serde(default)]
    pub rank_cpus: String,
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
    /// Peak resident memory of the solver process (VmHWM read by the solver at its exit),
    /// bytes; with several ranks rank 0's (rows of solvers before the figures were measured
    /// across the ranks include rank 0's gathering every particle).
    pub peak_rss_bytes: Option<u64>,
    /// Peak resident memory summed over the ranks (each rank's VmHWM at its exit; in rows of
    /// older solvers at the end of its time steps); equal to `peak_rss_bytes` at one rank.
    /// Since schema 4.
    #[serde(default)]
    pub peak_rss_sum_bytes: Option<u64>,
    /// With several ranks: each rank's particles at the end (space-separated, rank order).
    /// Since schema 4.
    #[serde(default)]
    pub rank_particles: String,
    /// With several ranks: the largest rank busy time over the mean (1 = balanced). Since
    /// schema 4.
    #[serde(default)]
    pub rank_busy_imbalance: Option<f64>,
    /// With several ranks: particles that moved to another rank over the run, all ranks.
    /// Since schema 4.
    #[serde(default)]
    pub migrated_particles: Option<u64>,
    /// With several ranks: seconds in the exchange per step (packing, messages, reductions),
    /// of the rank that spent the most (the maximum over ranks), over all steps taken
    /// (warm-up included). 0 at one rank. Since schema 5 the communication alone (the runs
    /// use `--split-wait`, and the waiting is in `wait_s_per_step`); in schema-4 rows, whose
    /// `wait_s_per_step` is empty, it includes waiting for the other ranks. Since schema 4.
    #[serde(default)]
    pub comm_s_per_step: Option<f64>,
    /// That rank's exchange seconds over the run's wall time (with or without the waiting,
    /// as `comm_s_per_step`). Since schema 4.
    #[serde(default)]
    pub comm_frac: Option<f64>,
    /// With several ranks: seconds per step spent waiting for other ranks at the barrier in
    /// front of each exchange operation (`mpm run --split-wait`, the ranks'
    /// `exchange.wait_seconds`), of the rank that waited the most (the maximum over ranks,
    /// like `comm_s_per_step`, taken on its own: the two may come from different ranks), over
    /// all steps taken. Load imbalance or a CPU taken by another process, not the cost of
    /// the exchange. Empty at one rank (no other rank to wait for), when a rank did not
    /// report it, and in rows before schema 5 (not measured). Since schema 5.
    #[serde(default)]
    pub wait_s_per_step: Option<f64>,
    /// That rank's waiting over the run's wall time. Since schema 5.
    #[serde(default)]
    pub wait_frac: Option<f64>,
    /// Bytes sent per step, summed over the ranks: halo sums, migration and reductions.
    /// Since schema 4.
    #[serde(default)]
    pub comm_bytes_per_step: Option<f64>,
    /// Messages (point-to-point and collective calls) per step, summed over the ranks.
    /// Since schema 4.
    #[serde(default)]
    pub comm_messages_per_step: Option<f64>,
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

    // ---- host load (since schema 3; see `machine::load` for the rule) ----
    /// 1-minute load average just before the run.
    #[serde(default)]
    pub host_load1_before: Option<f64>,
    /// 1-minute load average just after the run.
    #[serde(default)]
    pub host_load1_after: Option<f64>,
    /// Other runnable tasks in a quiet window just before the run (median of samples).
    #[serde(default)]
    pub host_others_running_before: Option<u32>,
    /// Other runnable tasks in a quiet window just after the run.
    #[serde(default)]
    pub host_others_running_after: Option<u32>,
    /// Busy fraction of the run's CPUs (all CPUs when not pinned) with other work in the
    /// window before the run.
    #[serde(default)]
    pub host_cpus_busy_before: Option<f64>,
    /// The same in the window after the run.
    #[serde(default)]
    pub host_cpus_busy_after: Option<f64>,
    /// Fraction of the CPU time stolen by the hypervisor during the run.
    #[serde(default)]
    pub host_steal_frac: Option<f64>,
    /// The spin calibration last taken before the run over the session start's.
    #[serde(default)]
    pub calib_spin_ratio: Option<f64>,
    /// The memory-copy calibration over the session start's.
    #[serde(default)]
    pub calib_copy_ratio: Option<f64>,
    /// The host was busy around the run: left out of claims and regress unless
    /// `--include-noisy`, grey in figures.
    #[serde(default)]
    pub host_noisy: bool,
    /// Why the row is `host_noisy` (empty when it is not).
    #[serde(default)]
    pub host_noise: String,

    // ---- status ----
    /// `ok`, `skipped`, `failed` or `invalid`.
    pub status: Status,
    /// Why a row is not `ok` (empty when it is).
    pub reason: String,
}

fn one() -> usize {
    1
}

impl Row {
    /// Whether the run was split over several MPI ranks (kept out of the one-process
    /// analyses: figures 7-14, claims, regress).
    pub fn is_hybrid(&self) -> bool {
        self.ranks > 1
    }

    /// Whether this row's exchange seconds (`comm_*`) include waiting for the other ranks:
    /// a run over several ranks without the waiting measured apart (rows before schema 5,
    /// or a rank that did not report it).
    pub fn comm_includes_wait(&self) -> bool {
        self.is_hybrid() && self.wait_s_per_step.is_none()
    }

    /// Threads of each rank: `threads_per_rank`, or `threads` for rows written before
    /// schema 4 (one process).
    pub fn per_rank_threads(&self) -> usize {
        if self.threads_per_rank == 0 {
            self.threads / self.ranks.max(1)
        } else {
            self.threads_per_rank
        }
    }

    /// The host reading this row records.
    pub fn host_reading(&self) -> HostReading {
        let probe = |load1, others_running, cpus_busy| Probe { load1, others_running, cpus_busy };
        HostReading {
            before: probe(self.host_load1_before, self.host_others_running_before, self.host_cpus_busy_before),
            after: probe(self.host_load1_after, self.host_others_running_after, self.host_cpus_busy_after),
            steal: self.host_steal_frac,
            spin_ratio: self.calib_spin_ratio,
            copy_ratio: self.calib_copy_ratio,
        }
    }

    /// Record `h` and flag the row by the `host_noisy` rule for a host of `pus` usable PUs.
    pub fn set_host(&mut self, h: &HostReading, pus: usize) {
        self.host_load1_before = h.before.load1;
        self.host_load1_after = h.after.load1;
        self.host_others_running_before = h.before.others_running;
        self.host_others_running_after = h.after.others_running;
        self.host_cpus_busy_before = h.before.cpus_busy;
        self.host_cpus_busy_after = h.after.cpus_busy;
        self.host_steal_frac = h.steal;
        self.calib_spin_ratio = h.spin_ratio;
        self.calib_copy_ratio = h.copy_ratio;
        let why = h.noise(self.threads, pus);
        self.host_noisy = why.is_some();
        self.host_noise = why.unwrap_or_default();
    }
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
            self.ranks.max(1),
            self.per_rank_threads(),
            &self.pin_policy,
            self.rep,
            &self.grid_mode,
            self.warmup_steps,
            self.step_limit,
            self.end_time_s,
        )
    }
}

/// Build a resume key from the configuration fields (`threads` per rank). One rank keeps the
/// key of schema 3 (`...-t2-...`); several add the rank count (`...-t2-ranks2-...`).
#[allow(clippy::too_many_arguments)]
pub fn run_key(
    model: u32,
    strategy: Strategy,
    opt: &str,
    ranks: usize,
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
    let ranks = if ranks > 1 { format!("-ranks{ranks}") } else { String::new() };
    RunKey(format!("m{model}-{strategy}-{opt}-t{threads}{ranks}-{pin}-{grid}-w{warmup}-{budget}-r{rep}"))
}

/// Space-separated CPU list for a CSV cell.
pub fn cpus_cell(cpus: &[usize]) -> String {
    cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(" ")
}

/// Parse a CSV CPU cell back.
pub fn parse_cpus_cell(s: &str) -> Vec<usize> {
    s.split_whitespace().filter_map(|t| t.parse().ok()).collect()
}

/// Length in bytes of the complete part of a results CSV: the header and every record that
/// ends in a newline and has as many fields as the header. What follows is a torn tail.
pub fn complete_len(bytes: &[u8]) -> usize {
    let mut len = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    loop {
        let mut r = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(&bytes[..len]);
        let width = match r.headers() {
            Ok(h) => h.len(),
            Err(_) => return len,
        };
        let mut last: Option<(usize, usize)> = None;
        let mut rec = csv::StringRecord::new();
        while let Ok(true) = r.read_record(&mut rec) {
            let start = rec.position().map_or(0, |p| p.byte() as usize);
            last = Some((start, rec.len()));
        }
        match last {
            Some((start, fields)) if fields < width && start < len => len = start,
            _ => return len,
        }
    }
}

/// Read every row of a results CSV, checking the header first. A torn last line is left
/// out with a warning (the file is not changed).
pub fn read_rows(path: &Path) -> Result<Vec<Row>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot open {}", path.display()))?;
    let good = complete_len(&bytes);
    if good < bytes.len() {
        eprintln!(
            "warning: {} ends in a torn line ({} bytes: an interrupted write); reading the complete rows only \
             (resuming the campaign moves it aside and redoes that run)",
            path.display(),
            bytes.len() - good
        );
    }
    parse_rows(&bytes[..good], path)
}

/// Move a torn tail of `path` (see [`complete_len`]) to `<name>.torn-<UTC time>` beside it
/// and cut the file to its complete rows; say so on stderr. Returns the new file, if any.
pub fn repair_torn_tail(path: &Path) -> Result<Option<PathBuf>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let good = complete_len(&bytes);
    if good == bytes.len() {
        return Ok(None);
    }
    let stamp: String = crate::util::now_rfc3339().chars().filter(|c| c.is_ascii_alphanumeric()).collect();
    let name = path.file_name().map_or_else(|| "runs.csv".into(), |n| n.to_string_lossy().into_owned());
    let aside = path.with_file_name(format!("{name}.torn-{stamp}"));
    mpm_cli::atomic::write_atomic(&aside, &bytes[good..])?;
    let f = OpenOptions::new().write(true).open(path).with_context(|| format!("cannot repair {}", path.display()))?;
    f.set_len(good as u64).with_context(|| format!("cannot repair {}", path.display()))?;
    f.sync_all().ok();
    eprintln!(
        "warning: {} ended in a torn line (an interrupted write); moved it to {}; its run will be redone",
        path.display(),
        aside.display()
    );
    Ok(Some(aside))
}

/// Parse the rows of a CSV's complete part, checking the header first.
fn parse_rows(bytes: &[u8], path: &Path) -> Result<Vec<Row>> {
    let mut r = csv::ReaderBuilder::new().has_headers(true).from_reader(bytes);
    let have: Vec<String> = r
        .headers()
        .with_context(|| format!("cannot read the header of {}", path.display()))?
        .iter()
        .map(str::to_string)
        .collect();
    let want = Row::header();
    let missing: Vec<&str> = want
        .iter()
        .filter(|c| !have.contains(c) && !ADDED_SINCE_V1.contains(&c.as_str()))
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
    /// harness' header; a torn last line is moved aside first ([`repair_torn_tail`]).
    pub fn open(path: &Path) -> Result<Self> {
        if path.is_file() {
            repair_torn_tail(path)?;
        }
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
            // Validate every row, then demand this schema's exact header: rows appended
            // under another header would be misread.
            parse_rows(&text, path)?;
            let have: Vec<String> =
                csv::Reader::from_reader(text.as_slice()).headers()?.iter().map(str::to_string).collect();
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
        // A torn last line is moved aside on reopen.
        std::fs::OpenOptions::new().append(true).open(&p).unwrap().write_all(b"1,abc,").unwrap();
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row).unwrap();
        assert_eq!(read_rows(&p).unwrap().len(), 2);
        let aside: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with("runs.csv.torn-"))
            .collect();
        assert_eq!(aside.len(), 1);
        assert_eq!(std::fs::read(aside[0].path()).unwrap(), b"1,abc,");
    }

    /// Both kinds of torn tail are found before parsing: no trailing newline, and a line
    /// with fewer fields than the header; readers skip them, the repair moves them aside.
    #[test]
    fn torn_tails_are_found_read_around_and_moved_aside() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let row = Row { schema_version: SCHEMA_VERSION, model: 1, threads: 2, wall_s: Some(0.5), ..Row::default() };
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row).unwrap();
        log.append(&Row { model: 2, ..row.clone() }).unwrap();
        drop(log);
        let good = std::fs::read(&p).unwrap();
        assert_eq!(complete_len(&good), good.len());
        let line = String::from_utf8(good.clone()).unwrap().lines().last().unwrap().to_string();
        let half = &line[..line.len() / 2];
        for tail in [half.to_string(), format!("{half}\n"), line.clone()] {
            let torn = [good.as_slice(), tail.as_bytes()].concat();
            assert_eq!(complete_len(&torn), good.len(), "{tail:?}");
            std::fs::write(&p, &torn).unwrap();
            assert_eq!(read_rows(&p).unwrap().len(), 2, "the reader reads around {tail:?}");
            assert_eq!(std::fs::read(&p).unwrap(), torn, "reading changes nothing");
            let aside = repair_torn_tail(&p).unwrap().unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), good);
            assert_eq!(std::fs::read(&aside).unwrap(), tail.as_bytes());
            std::fs::remove_file(aside).unwrap();
        }
        assert_eq!(repair_torn_tail(&p).unwrap(), None);
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

    /// The committed reference campaign (schema 2) still reads, every row quiet and one
    /// process (its threads per rank are its threads, its keys those of schema 3).
    #[test]
    fn committed_schema_2_campaign_reads() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/d02fbfc20d44/quick/runs.csv");
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows.len(), 80);
        assert!(rows.iter().all(|r| r.schema_version == 2 && !r.host_noisy && r.host_steal_frac.is_none()));
        assert!(rows.iter().all(|r| r.ranks == 1 && !r.is_hybrid() && r.per_rank_threads() == r.threads));
        assert!(rows.iter().all(|r| r.run_id.starts_with(&r.key().0)), "resume keys of one rank are unchanged");
    }

    /// The host-noise rule counts every worker of the run (ranks x threads per rank) against
    /// the PUs: two ranks of one thread leave no CPU free on two PUs.
    #[test]
    fn host_noise_counts_ranks_times_threads() {
        let reading = HostReading {
            before: Probe { load1: None, others_running: Some(1), cpus_busy: Some(0.0) },
            after: Probe { load1: None, others_running: Some(0), cpus_busy: Some(0.0) },
            ..HostReading::default()
        };
        let mut one = Row { threads: 1, ranks: 1, threads_per_rank: 1, ..Row::default() };
        one.set_host(&reading, 2);
        assert!(!one.host_noisy, "{}", one.host_noise);
        let mut two = Row { threads: 2, ranks: 2, threads_per_rank: 1, ..Row::default() };
        two.set_host(&reading, 2);
        assert!(two.host_noisy && two.host_noise.contains("0 free CPU"), "{}", two.host_noise);
    }

    /// Resume keys tell ranks apart; one rank keeps the key of schema 3.
    #[test]
    fn keys_include_ranks() {
        let one = Row { model: 1, threads: 2, ranks: 1, threads_per_rank: 2, ..Row::default() };
        let two = Row { threads: 4, ranks: 2, ..one.clone() };
        let two_by_one = Row { threads: 2, ranks: 2, threads_per_rank: 1, ..one.clone() };
        assert_ne!(one.key(), two.key());
        assert_ne!(two.key(), two_by_one.key());
        assert_ne!(one.key(), two_by_one.key(), "same total workers, different configuration");
        assert!(one.key().0.contains("-t2-") && !one.key().0.contains("ranks"), "{}", one.key().0);
        assert!(two.key().0.contains("-t2-ranks2-"), "{}", two.key().0);
        // A schema-3 row (no threads_per_rank column: 0) keys as its threads.
        let old = Row { threads_per_rank: 0, ranks: 1, ..one.clone() };
        assert_eq!(old.key(), one.key());
    }

    /// A schema-1 file (without the load-imbalance columns) still reads: its rows get
    /// empty values there and everything else intact. Appending to it is refused.
    #[test]
    fn schema_1_files_still_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        // Read back from a file without the column, `ranks` is 1 (one process).
        let row = Row {
            schema_version: 1,
            campaign_id: "old".into(),
            model: 2,
            ranks: 1,
            wall_s: Some(1.5),
            ..Row::default()
        };
        // Without the columns added since schema 1.
        let old = csv_without(&row, &ADDED_SINCE_V1);
        assert!(!old.lines().next().unwrap().contains("load_imbalance"));
        std::fs::write(&p, old).unwrap();
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![row]);
        assert!(CsvLog::open(&p).is_err(), "appending schema-5 rows to a schema-1 file must be refused");
    }

    /// `row` as a CSV file (header and one line) without the columns `drop` (none of the
    /// row's cells may hold a comma).
    fn csv_without(row: &Row, drop: &[&str]) -> String {
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(row).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let header = Row::header();
        let idx: Vec<usize> = drop.iter().map(|c| header.iter().position(|h| h == c).unwrap()).collect();
        let keep = |line: &str| {
            line.split(',').enumerate().filter(|(i, _)| !idx.contains(i)).map(|(_, c)| c).collect::<Vec<_>>().join(",")
        };
        text.lines().map(|l| keep(l) + "\n").collect()
    }

    /// A row over two ranks with the waiting measured apart: schema 5's `wait_*` columns
    /// round-trip. The same row in a schema-4 file (no `wait_*` columns) reads with them
    /// empty, its exchange seconds flagged as including the waiting, and the file is not
    /// appended to (its header is not this schema's).
    #[test]
    fn wait_columns_round_trip_and_are_empty_in_schema_4_files() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let row = Row {
            schema_version: SCHEMA_VERSION,
            model: 3,
            threads: 2,
            ranks: 2,
            threads_per_rank: 1,
            launcher: "mpirun -n 2".into(),
            comm_s_per_step: Some(0.004),
            comm_frac: Some(0.031),
            wait_s_per_step: Some(0.008),
            wait_frac: Some(0.062),
            ..Row::default()
        };
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row).unwrap();
        drop(log);
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![row.clone()]);
        assert!(!rows[0].comm_includes_wait());
        let four = Row { schema_version: 4, ..row };
        std::fs::write(&p, csv_without(&four, &["wait_s_per_step", "wait_frac"])).unwrap();
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![Row { wait_s_per_step: None, wait_frac: None, ..four }]);
        assert!(rows[0].comm_includes_wait() && rows[0].comm_frac == Some(0.031));
        assert!(CsvLog::open(&p).is_err(), "appending schema-5 rows to a schema-4 file must be refused");
    }

    /// The committed hybrid reference campaign (schema 4) still reads: no waiting measured,
    /// so every row over two ranks has its exchange seconds flagged as including it.
    #[test]
    fn committed_schema_4_hybrid_campaign_reads() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/5b9efbec6a3d/hybrid/runs.csv");
        let rows = read_rows(&p).unwrap();
        assert!(rows.iter().all(|r| r.schema_version == 4 && r.wait_s_per_step.is_none() && r.wait_frac.is_none()));
        let two: Vec<&Row> = rows.iter().filter(|r| r.ranks == 2).collect();
        assert!(!two.is_empty() && two.len() < rows.len());
        assert!(two.iter().all(|r| r.comm_includes_wait() && r.comm_frac.is_some_and(|f| f > 0.0)));
        assert!(rows.iter().filter(|r| r.ranks == 1).all(|r| !r.comm_includes_wait()));
    }
}
