//! What a run writes besides its summary on stdout: the JSON summary (reserved before the
//! run, written only when it succeeds), VTU snapshots and radiograph pictures, with the time
//! spent writing them (left out of the run's wall time).

use anyhow::{bail, Context, Result};
use mpm_cli::picture::{write_history_plot, write_radiograph, RadiographNotes};
use mpm_cli::vtk::SnapshotWriter;
use mpm_core::scenario::impact::{self, History, ImpactGeometry};
use mpm_core::Simulation;
use mpm_host::atomic;
use mpm_spec::{RunSpec, Summary};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The files of one run and the time spent writing them during and after the loop.
pub struct Outputs {
    json: Option<PendingFile>,
    snapshots: Option<SnapshotWriter>,
    /// A snapshot every this many steps.
    every: u64,
    /// Radiograph directory and interval (impact only).
    radiographs: Option<(PathBuf, Option<u64>)>,
    /// Time spent writing snapshots and pictures after the loop started.
    pub spent: Duration,
}

impl Outputs {
    /// Check and reserve every output before the run: the JSON summary's file, the snapshot
    /// directory, the radiograph directory. `written`: the snapshots `(step, time, file)`
    /// the collection of a run continued from a checkpoint already lists (none for a fresh
    /// run). `rank`: this process's rank; the ranks other than 0 of a run over several
    /// write their pieces of the snapshots only.
    pub fn open(spec: &RunSpec, written: Vec<(u64, f64, String)>, rank: usize) -> Result<Self> {
        let o = &spec.outputs;
        let lead = rank == 0;
        let json = o.json.as_deref().filter(|_| lead).map(PendingFile::reserve).transpose()?;
        let name = spec.scenario.kind().name();
        let snapshots = o
            .vtk
            .as_ref()
            .map(|v| {
                SnapshotWriter::resumed(&v.dir, name, v.encoding, written.clone())
                    .map(|w| w.over_ranks(rank, spec.ranks))
            })
            .transpose()?;
        let radiographs = o.radiograph.as_ref().filter(|_| lead).map(|r| (r.dir.clone(), r.every));
        if let Some((dir, _)) = &radiographs {
            std::fs::create_dir_all(dir)
                .with_context(|| format!("cannot create the radiograph directory {}", dir.display()))?;
        }
        let every = o.vtk.as_ref().map_or(1, |v| v.every);
        Ok(Self { json, snapshots, every, radiographs, spent: Duration::ZERO })
    }

    /// The snapshot of the initial state (before the timed loop).
    pub fn initial(&mut self, sim: &Simulation) -> Result<()> {
        match self.snapshots.as_mut() {
            Some(w) => Ok(w.write(0, 0.0, sim.particles())?),
            None => Ok(()),
        }
    }

    /// After a step: a snapshot every `--every` steps and a radiograph every
    /// `--radiograph-every` steps, timed.
    pub fn after_step(&mut self, sim: &Simulation, geometry: Option<&ImpactGeometry>) -> Result<()> {
        let step = sim.steps();
        if let Some(w) = self.snapshots.as_mut().filter(|_| step.is_multiple_of(self.every)) {
            let t0 = Instant::now();
            w.write(step, sim.time(), sim.particles())?;
            self.spent += t0.elapsed();
        }
        if let (Some((dir, Some(k))), Some(g)) = (&self.radiographs, geometry) {
            if step.is_multiple_of(*k) {
                let t0 = Instant::now();
                radiograph_png(dir, sim, g, &format!("radiograph_{step:06}.png"))?;
                self.spent += t0.elapsed();
            }
        }
        Ok(())
    }

    /// After the loop: the final snapshot and the final radiograph (its path printed unless
    /// `quiet`), timed.
    pub fn finish(&mut self, sim: &Simulation, geometry: Option<&ImpactGeometry>, quiet: bool) -> Result<()> {
        let t0 = Instant::now();
        if let Some(w) = self.snapshots.as_mut() {
            w.write(sim.steps(), sim.time(), sim.particles())?;
        }
        if let (Some((dir, _)), Some(g)) = (&self.radiographs, geometry) {
            let path = radiograph_png(dir, sim, g, "radiograph_final.png")?;
            if !quiet {
                eprintln!("radiograph: {}", path.display());
            }
        }
        self.spent += t0.elapsed();
        Ok(())
    }

    /// With `--radiograph DIR`: the cloud's history as `DIR/history.png` (its path printed
    /// unless `quiet`), timed.
    pub fn history_plot(&mut self, history: &History, quiet: bool) -> Result<()> {
        if let Some((dir, _)) = &self.radiographs {
            let t0 = Instant::now();
            let path = dir.join("history.png");
            write_history_plot(&path, &history.samples, (900, 600))?;
            self.spent += t0.elapsed();
            if !quiet {
                eprintln!("history: {}", path.display());
            }
        }
        Ok(())
    }

    /// Write the JSON summary into its reserved file (nothing without `--json`).
    pub fn commit_json(&mut self, summary: &Summary) -> Result<()> {
        if let Some(p) = self.json.take() {
            let mut text = serde_json::to_string_pretty(summary)?;
            text.push('\n');
            p.commit(text.as_bytes())?;
        }
        Ok(())
    }

    /// The snapshot writer, when `--vtk` was given.
    pub fn snapshots(&self) -> Option<&SnapshotWriter> {
        self.snapshots.as_ref()
    }
}

/// A JSON output reserved before the run: a temporary file in the target directory that
/// becomes the summary by a rename when the run succeeds, and is removed otherwise (`None`
/// for a device such as `/dev/null`, written in place: [`atomic::is_special`]).
struct PendingFile {
    tmp: Option<PathBuf>,
    dest: PathBuf,
    done: bool,
}

impl PendingFile {
    fn reserve(dest: &Path) -> Result<Self> {
        if dest.is_dir() {
            bail!("cannot write the JSON summary to {}: it is a directory; give a file name", dest.display());
        }
        let parent = match dest.parent() {
            Some(p) if !p.as_os_str().is_empty() => p,
            _ => Path::new("."),
        };
        if !parent.is_dir() {
            bail!(
                "cannot write the JSON summary to {}: directory {} does not exist (create it first)",
                dest.display(),
                parent.display()
            );
        }
        if atomic::is_special(dest) {
            std::fs::OpenOptions::new()
                .write(true)
                .open(dest)
                .with_context(|| format!("cannot write the JSON summary to {}", dest.display()))?;
            return Ok(Self { tmp: None, dest: dest.to_path_buf(), done: false });
        }
        let tmp = atomic::temp_path_for(dest);
        std::fs::File::create(&tmp).with_context(|| {
            format!(
                "cannot write the JSON summary to {}: directory {} is not writable",
                dest.display(),
                parent.display()
            )
        })?;
        Ok(Self { tmp: Some(tmp), dest: dest.to_path_buf(), done: false })
    }

    fn commit(mut self, bytes: &[u8]) -> Result<()> {
        atomic::write_atomic(&self.dest, bytes).context("cannot write the JSON summary")?;
        self.done = true;
        Ok(())
    }
}

impl Drop for PendingFile {
    fn drop(&mut self) {
        if let Some(tmp) = self.tmp.as_ref().filter(|_| !self.done) {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// Write a radiograph of the current state into `dir`.
fn radiograph_png(dir: &Path, sim: &Simulation, geometry: &ImpactGeometry, name: &str) -> Result<PathBuf> {
    let f = impact::measure(sim.particles(), geometry);
    let notes = RadiographNotes {
        time: sim.time(),
        plate_faces: (0.0, geometry.rear_face),
        lines: vec![
            format!(
                "leading edge {:.1} mm behind the plate (robust {:.1} mm)",
                f.cloud_front * 1e3,
                f.cloud_front_robust * 1e3
            ),
            format!(
                "width {:.1} mm (robust {:.1} mm), hole {:.1} mm",
                f.cloud_width * 1e3,
                f.cloud_width_robust * 1e3,
                f.hole_diameter * 1e3
            ),
        ],
    };
    let path = dir.join(name);
    write_radiograph(&path, sim.particles(), sim.spacing()[0], &notes, (900, 900))?;
    Ok(path)
}
