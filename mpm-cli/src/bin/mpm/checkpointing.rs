//! A run's checkpoints from the program's side: what it saves besides the simulation's own
//! state ([`Saved`]: the spec, the initial grid, the timing so far, the histories and
//! trackers, the snapshots written), when ([`Checkpointer::due`]), and how every rank
//! writes its part into one checkpoint ([`Checkpointer::write`]). The file format and the
//! folder are `mpm_host::checkpoint`'s.

use anyhow::{anyhow, Context, Result};
use mpm_cli::summary::{HistoryRecorder, Timing};
use mpm_core::scenario::impact::HistorySample;
use mpm_core::scenario::taylor::TaylorFigures;
use mpm_core::{Collectives, SimState, Simulation};
use mpm_host::checkpoint::{write_file, Folder, Meta};
use mpm_spec::spec::CheckpointEvery;
use mpm_spec::summary::CheckpointReport;
use mpm_spec::RunSpec;
use serde::{Deserialize, Serialize};
use std::path::Path;
use std::time::{Duration, Instant};

/// The impact's cloud history as saved: its interval, samples and the time of the last
/// sample (which decides the next).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SavedCloud {
    /// Interval between samples (s).
    pub interval: f64,
    /// The samples (rank 0's; empty on the other ranks).
    pub samples: Vec<HistorySample>,
    /// Time of the last sample taken.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub last_time: Option<f64>,
}

/// A VTU snapshot already written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SavedSnapshot {
    /// Its step.
    pub step: u64,
    /// Its simulated time (s).
    pub time: f64,
    /// Its file name in the snapshot folder.
    pub file: String,
}

/// What the program records of a run besides the simulation and its trackers: what the
/// summary reports that the simulation does not hold.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RunLog {
    /// Cells of the initial grid.
    pub cells: usize,
    /// Nodes of the initial grid.
    pub nodes: usize,
    /// Wall-clock start of the run (its first process), seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// The command line that started the run.
    pub command_line: Vec<String>,
    /// The loop's timing so far (output, checkpoint writes and restarts left out).
    pub timing: Timing,
    /// Checkpoints written and restarts so far.
    pub report: CheckpointReport,
    /// The energy history.
    pub history: HistoryRecorder,
    /// Taylor bar: the figures at t = 0.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_taylor: Option<TaylorFigures>,
}

/// What the program carries through a run besides the simulation: its [`RunLog`], what
/// decides the trackers' later samples, and the snapshots written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Carried {
    /// The run's log.
    pub log: RunLog,
    /// Impact: the cloud history.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub cloud: Option<SavedCloud>,
    /// Plate: the shock front's path `(t, z)`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub shock_path: Option<Vec<[f64; 2]>>,
    /// The VTU snapshots written so far.
    #[serde(default)]
    pub snapshots: Vec<SavedSnapshot>,
}

/// The `[state]` table of every rank's checkpoint file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Saved {
    /// The run, resolved (warm-up included).
    pub spec: RunSpec,
    /// The simulation's state on this rank.
    pub sim: SimState,
    /// The program's.
    pub program: Carried,
}

impl Saved {
    /// As the header's `[state]` table.
    pub fn to_table(&self) -> Result<toml::Table> {
        toml::Table::try_from(self).context("cannot put the run's state into the checkpoint")
    }

    /// From a header's `[state]` table.
    pub fn from_table(table: toml::Table) -> Result<Self> {
        table.try_into().context("the checkpoint's state does not read as this mpm's (written by another version?)")
    }
}

/// Writes a run's checkpoints into its folder: when they are due, every rank its part, then
/// rank 0 completes the checkpoint. Its time is kept apart from the loop's.
pub struct Checkpointer {
    folder: Folder,
    every: CheckpointEvery,
    /// The last checkpoint, or the start of this process's loop.
    since: Instant,
    /// Time spent writing checkpoints in this process.
    pub spent: Duration,
    meta: Meta,
}

impl Checkpointer {
    /// The checkpoints of `spec` into `dir`, every `every`; the folder is created (rank 0)
    /// and checked writable now, not at the first checkpoint.
    pub fn new(dir: &Path, every: CheckpointEvery, spec: &RunSpec, rank: usize, binary_sha256: String) -> Result<Self> {
        if rank == 0 {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create the checkpoint folder {}", dir.display()))?;
            let probe = dir.join(format!(".mpm-write-test.{}", std::process::id()));
            std::fs::File::create(&probe)
                .with_context(|| format!("the checkpoint folder {} is not writable", dir.display()))?;
            let _ = std::fs::remove_file(&probe);
        }
        Ok(Self {
            folder: Folder::new(dir),
            every,
            since: Instant::now(),
            spent: Duration::ZERO,
            meta: Meta {
                rank,
                ranks: spec.ranks,
                step: 0,
                time_s: 0.0,
                spec_key: mpm_host::checkpoint::run_key(spec),
                binary_sha256,
            },
        })
    }

    /// Whether a checkpoint is due after the step just taken. Collective over ranks when
    /// the interval is a duration (the ranks' clocks differ: rank 0's decides).
    pub fn due(&self, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<bool> {
        match self.every {
            CheckpointEvery::Steps(n) => Ok(sim.steps().is_multiple_of(n)),
            CheckpointEvery::Duration(d) => {
                let mine = ranks.rank() == 0 && self.since.elapsed() >= d;
                if ranks.ranks() == 1 {
                    return Ok(mine);
                }
                let mut flag = [u64::from(mine)];
                ranks.sum_counts(&mut flag)?;
                Ok(flag[0] > 0)
            }
        }
    }

    /// Write the checkpoint of `sim`'s current step with the program's `program` state:
    /// rank 0 opens the partial folder, every rank writes its file, rank 0 completes it
    /// (collective). A checkpoint that cannot be written is a warning, not the end of the
    /// run: the previous ones stay valid. Returns the checkpoint's bytes over all ranks.
    pub fn write(
        &mut self,
        spec: &RunSpec,
        sim: &Simulation,
        program: Carried,
        ranks: &mut dyn Collectives,
    ) -> Result<Option<u64>> {
        let t0 = Instant::now();
        let result = self.write_parts(spec, sim, program, ranks);
        self.spent += t0.elapsed();
        self.since = Instant::now();
        match result {
            Ok(bytes) => Ok(Some(bytes)),
            Err(Failure::Here(e)) => {
                eprintln!(
                    "warning: the checkpoint of step {} was not written ({e:#}); the run goes on, its older checkpoints stay valid",
                    sim.steps()
                );
                Ok(None)
            }
            Err(Failure::Elsewhere) => {
                if ranks.rank() == 0 {
                    eprintln!(
                        "warning: the checkpoint of step {} was not written (another rank could not write its part); the run goes on",
                        sim.steps()
                    );
                }
                Ok(None)
            }
            Err(Failure::Collective(e)) => Err(e),
        }
    }

    fn write_parts(
        &mut self,
        spec: &RunSpec,
        sim: &Simulation,
        program: Carried,
        ranks: &mut dyn Collectives,
    ) -> Result<u64, Failure> {
        let step = sim.steps();
        let rank = ranks.rank();
        // 1. Rank 0 opens the partial folder; the others wait for it.
        let opened = if rank == 0 { self.folder.begin(step).map(|_| ()).map_err(Into::into) } else { Ok(()) };
        agree(ranks, opened)?;
        // 2. Every rank its file.
        let meta = Meta { step, time_s: sim.time(), ..self.meta.clone() };
        let saved = Saved { spec: spec.clone(), sim: sim.state(), program };
        let path = self.folder.partial(step).join(format!("rank-{rank:04}.ckpt"));
        let written = saved.to_table().and_then(|state| {
            // The global ids, over ranks and wherever the cell order has moved a particle
            // from its index (mpm_core::order); none while every id is its index.
            let id = |p| sim.exchange().global_id(p);
            let n = sim.particles().len();
            let ids =
                (ranks.ranks() > 1 || (0..n).any(|p| id(p) != p as u64)).then(|| (0..n).map(id).collect::<Vec<u64>>());
            Ok(write_file(&path, &meta, state, sim.particles(), ids.as_deref())?)
        });
        let mut bytes = [*written.as_ref().unwrap_or(&0)];
        agree(ranks, written.map(|_| ()))?;
        ranks.sum_counts(&mut bytes).map_err(|e| Failure::Collective(e.into()))?;
        // 3. Rank 0 completes it.
        let committed = if rank == 0 { self.folder.commit(step).map(|_| ()).map_err(Into::into) } else { Ok(()) };
        agree(ranks, committed)?;
        Ok(bytes[0])
    }
}

/// Why a checkpoint was not written.
enum Failure {
    /// This rank failed (the error).
    Here(anyhow::Error),
    /// Another rank did.
    Elsewhere,
    /// The ranks could not agree (an MPI error: the run cannot go on).
    Collective(anyhow::Error),
}

/// Every rank's `result` combined (collective): `Ok` when all succeeded.
fn agree(ranks: &mut dyn Collectives, result: Result<()>) -> Result<(), Failure> {
    let mut failed = [u64::from(result.is_err())];
    ranks.sum_counts(&mut failed).map_err(|e| Failure::Collective(anyhow!(e)))?;
    match result {
        Err(e) => Err(Failure::Here(e)),
        Ok(()) if failed[0] > 0 => Err(Failure::Elsewhere),
        Ok(()) => Ok(()),
    }
}
