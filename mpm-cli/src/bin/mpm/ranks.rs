//! A run split over MPI ranks: starting MPI (or saying that this build has none), the rank
//! boxes and the exchange, each rank's CPUs, the collectives the scenario's figures are
//! measured with, and after the loop the `--dump-state` file (the only output that needs
//! every particle in one place: the ranks stream their particles to rank 0, which places
//! each record in the file's bytes at its global id).

use anyhow::{bail, Context, Result};
use mpm_cli::distributed::{launcher_ranks, MPI_COMPILED};
use mpm_core::scenario::Pick;
use mpm_core::{Collectives, Exchange, MgForm, Particles, Simulation, SingleProcess};
use mpm_host::pinning;
use mpm_spec::scenario::Prepared;
use mpm_spec::summary::RankReport;
use mpm_spec::Scenario;
use std::path::Path;

/// The ranks a run asks for (`requested`: `--ranks` or the spec's `ranks`; else the
/// launcher's count); `None` for one process. A build without MPI refuses more than one,
/// and a count that differs from what the launcher started is refused.
pub fn wanted(requested: Option<usize>) -> Result<Option<usize>> {
    let launcher = launcher_ranks();
    if let (Some(1), Some(l)) = (requested, launcher.filter(|&l| l > 1)) {
        bail!("the run asks for 1 rank but mpirun started {l}: give the same count to both (--ranks, or the spec's `ranks`)");
    }
    let want = requested.or(launcher).filter(|&r| r > 1);
    match want {
        Some(r) if !MPI_COMPILED => bail!(
            "MPI is not compiled into this mpm, so it cannot run over {r} ranks; rebuild with the `mpi` feature \
             (`cargo build --profile o3 -p mpm-cli --features mpi`, needs libopenmpi-dev and libclang) or run one process"
        ),
        Some(r) if launcher.is_some_and(|l| l != r) => {
            bail!("--ranks {r} but mpirun started {} ranks; give the same count to both", launcher.unwrap_or(1))
        }
        Some(r) if launcher.is_none() => bail!("--ranks {r} needs a launcher: start the run with `mpirun -n {r} mpm run ...`"),
        _ => Ok(want),
    }
}

/// This rank's CPUs for `threads` workers inside the `mask` the launcher gave it, and
/// whether they are shared with another rank (oversubscribed), given every rank's host and
/// mask (`others`, in rank order, this rank's included at `rank`).
///
/// Ranks of one host with disjoint masks (the launcher bound them) use their own mask.
/// Ranks that share one mask (an unbound launcher) take disjoint slices of it by their rank
/// on the host when it has room for all of them; otherwise the CPUs are shared and flagged.
pub fn place(rank: usize, threads: usize, others: &[(u64, Vec<usize>)]) -> (Vec<usize>, bool) {
    let (host, mask) = (&others[rank].0, &others[rank].1);
    let overlaps = |m: &Vec<usize>| m.iter().any(|c| mask.contains(c));
    let sharing: Vec<usize> =
        (0..others.len()).filter(|&r| r != rank && others[r].0 == *host && overlaps(&others[r].1)).collect();
    if sharing.is_empty() && mask.len() >= threads {
        return (mask[..threads].to_vec(), false);
    }
    let local = sharing.iter().filter(|&&r| r < rank).count();
    let all_same = sharing.iter().all(|&r| others[r].1 == *mask);
    if all_same && mask.len() >= (sharing.len() + 1) * threads {
        return (mask[local * threads..(local + 1) * threads].to_vec(), false);
    }
    ((0..threads).map(|j| mask[(local * threads + j) % mask.len()]).collect(), true)
}

/// Values of a `--dump-state` record: the particle's global id, then its position,
/// velocity and stress.
const RECORD_VALUES: usize = 13;
/// Bytes of a record: the id as a little-endian u64, then 12 little-endian f64.
const RECORD_BYTES: usize = 8 * RECORD_VALUES;

/// The values of particle `p` a record holds after its id: position, velocity, stress.
fn state_values(particles: &Particles, p: usize) -> impl Iterator<Item = f64> + '_ {
    particles.x[p].iter().chain(&particles.v[p]).chain(&particles.stress[p]).copied()
}

/// Write the record of particle `id` with its `values` ([`state_values`]) into `out`.
fn put_record(out: &mut [u8], id: u64, values: impl Iterator<Item = f64>) {
    out[..8].copy_from_slice(&id.to_le_bytes());
    for (k, v) in values.enumerate() {
        out[8 + 8 * k..16 + 8 * k].copy_from_slice(&v.to_le_bytes());
    }
}

/// Write the `--dump-state` file's `bytes`.
fn write_state(path: &Path, bytes: &[u8]) -> Result<()> {
    mpm_host::atomic::write_atomic(path, bytes)
        .with_context(|| format!("cannot write the particle state to {}", path.display()))
}

/// The ranks of this run: MPI when started over several, else one process.
pub struct Ranks {
    #[cfg(feature = "mpi")]
    mpi: Option<with_mpi::Mpi>,
    /// The collectives of one process (the identity).
    single: SingleProcess,
}

impl Ranks {
    /// Start MPI if the run asks for several ranks ([`wanted`]).
    pub fn start(requested: Option<usize>) -> Result<Self> {
        let want = wanted(requested)?;
        #[cfg(feature = "mpi")]
        return Ok(Self { mpi: want.map(|_| with_mpi::Mpi::start()).transpose()?, single: SingleProcess });
        #[cfg(not(feature = "mpi"))]
        {
            debug_assert!(want.is_none(), "wanted() refuses several ranks without MPI");
            Ok(Self { single: SingleProcess })
        }
    }

    /// This process's rank (0 for one process).
    pub fn rank(&self) -> usize {
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            return m.rank;
        }
        0
    }

    /// Number of ranks.
    pub fn size(&self) -> usize {
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            return m.size;
        }
        1
    }

    /// The scenario built for this process, and its exchange (`None` for one process).
    ///
    /// Over several ranks no process holds the whole set: a first pass generates it only
    /// to find its bounding box, over which the rank boxes of `layout` (default: the DD
    /// layout for the rank count) are cut uniformly; the second builds the particles of this
    /// rank's box alone, numbered as in the whole set. With `bare` (a run continued from a
    /// checkpoint, whose particles come from it) the scenario is built without particles,
    /// over the same rank boxes.
    pub fn build(
        &self,
        scenario: &Scenario,
        eos: MgForm,
        _layout: Option<[usize; 3]>,
        _split_wait: bool,
        bare: bool,
    ) -> Result<(Prepared, Option<Box<dyn Exchange>>)> {
        let what = || format!("cannot set up the {}", scenario.describe());
        let census = || scenario.build(eos, Pick::Where(&|_| false)).with_context(what);
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            let census = census()?;
            let part = census.setup.part.as_ref().context("a picked set-up describes the whole set")?;
            if part.total == 0 {
                bail!("the scenario has no particles; check its size options");
            }
            let boxes = m.boxes(&census.setup.grid, (part.lo, part.hi), _layout)?;
            let rank = m.rank;
            let prepared = if bare {
                census
            } else {
                scenario.build(eos, Pick::Where(&|x| boxes.owner(x) == rank)).with_context(what)?
            };
            return Ok((prepared, Some(m.exchange(boxes, _split_wait)?)));
        }
        let prepared = if bare { census()? } else { scenario.build(eos, Pick::All).with_context(what)? };
        Ok((prepared, None))
    }

    /// This rank's CPUs for `threads` workers and whether ranks share CPUs ([`place`]).
    pub fn rank_cpus(&self, threads: usize) -> Result<(Vec<usize>, bool)> {
        let mask = pinning::usable_cpus()?;
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            return Ok(place(m.rank, threads, &m.all_masks(&mask)));
        }
        Ok(place(0, threads, &[(0, mask)]))
    }

    /// What the scenario's figures are measured with: MPI's collectives (which count
    /// nothing in the exchange's statistics) over several ranks, the identity for one.
    pub fn collectives(&mut self) -> &mut dyn Collectives {
        #[cfg(feature = "mpi")]
        if let Some(m) = &mut self.mpi {
            return &mut m.collectives;
        }
        &mut self.single
    }

    /// After the loop: write `--dump-state`, every particle's record in global id order.
    /// Over several ranks (collective) the simulation's grid arrays are released first (the
    /// run is over) and rank 0 receives the other ranks' particles in messages straight
    /// into the file's bytes (104 per particle), never into particle arrays; the other
    /// ranks write nothing.
    pub fn dump_state(&self, sim: &mut Simulation, path: &Path) -> Result<()> {
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            sim.release_grid_arrays();
            return match m.gather_states(sim)? {
                Some(bytes) => write_state(path, &bytes),
                None => Ok(()),
            };
        }
        // In global id order: the cell order ([`mpm_core::order`]) has moved the particles.
        let (p, ids) = (sim.particles(), sim.exchange());
        let mut bytes = vec![0u8; p.len() * RECORD_BYTES];
        for i in 0..p.len() {
            let id = ids.global_id(i);
            let at = id as usize * RECORD_BYTES;
            put_record(&mut bytes[at..at + RECORD_BYTES], id, state_values(p, i));
        }
        write_state(path, &bytes)
    }

    /// Every rank's `report` on rank 0 (`None` on the other ranks).
    pub fn gather_reports(&self, report: RankReport) -> Result<Option<Vec<RankReport>>> {
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            let Some(texts) = m.gather_text(&serde_json::to_string(&report)?)? else { return Ok(None) };
            return texts
                .iter()
                .map(|t| serde_json::from_str(t).context("a rank's report is not valid JSON"))
                .collect::<Result<_>>()
                .map(Some);
        }
        Ok(Some(vec![report]))
    }
}

#[cfg(feature = "mpi")]
mod with_mpi {
    use super::{put_record, state_values, RECORD_BYTES, RECORD_VALUES};
    use anyhow::{bail, Context, Result};
    use mpi::datatype::Equivalence;
    use mpi::topology::Communicator;
    use mpi::traits::{Destination, Source};
    use mpm_cli::distributed::{MpiCollectives, MpiExchange};
    use mpm_core::exchange::{rank_layout, uniform_cuts, RankBoxes};
    use mpm_core::math::Vec3;
    use mpm_core::{Exchange, GridGeom, GridSpec, Simulation};

    /// Particles per message of the state dump's gather.
    const GATHER_CHUNK: usize = 1 << 16;
    /// Tag of the state dump's messages.
    const GATHER: i32 = 7;

    /// MPI, started for the run (finalised when dropped).
    pub struct Mpi {
        /// Declared first, so dropped before the universe finalises MPI.
        pub collectives: MpiCollectives,
        universe: mpi::environment::Universe,
        /// This process's rank.
        pub rank: usize,
        /// Ranks.
        pub size: usize,
    }

    impl Mpi {
        /// Start MPI.
        pub fn start() -> Result<Self> {
            // The step calls MPI from a pool worker, one call at a time.
            let Some((universe, _)) = mpi::initialize_with_threading(mpi::Threading::Serialized) else {
                bail!("MPI was already started in this process")
            };
            let world = universe.world();
            let (rank, size) = (world.rank() as usize, world.size() as usize);
            Ok(Self { collectives: MpiCollectives::new(world)?, universe, rank, size })
        }

        /// The rank boxes of `layout` (default: the DD layout for the rank count) cut
        /// uniformly over the grid of `spec` fitted to the whole set's bounding box `bbox`.
        pub fn boxes(&self, spec: &GridSpec, bbox: (Vec3, Vec3), layout: Option<[usize; 3]>) -> Result<RankBoxes> {
            let fit = GridGeom::fit(spec, bbox.0, bbox.1);
            let layout = layout.unwrap_or_else(|| rank_layout(self.size, fit.cells));
            let cuts = uniform_cuts(layout, &fit)?;
            Ok(RankBoxes::new(cuts, spec.anchor, 1.0 / spec.dx)?)
        }

        /// The exchange of this rank over `boxes` (`split_wait`: see
        /// [`MpiExchange::split_wait`]).
        pub fn exchange(&self, boxes: RankBoxes, split_wait: bool) -> Result<Box<dyn Exchange>> {
            Ok(Box::new(MpiExchange::new(self.universe.world(), boxes)?.split_wait(split_wait)))
        }

        /// Every rank's host (a hash of its name) and CPU mask, in rank order.
        pub fn all_masks(&self, mask: &[usize]) -> Vec<(u64, Vec<usize>)> {
            use mpi::traits::CommunicatorCollectives;
            use std::hash::{Hash, Hasher};
            const WORDS: usize = 16;
            let mut h = std::collections::hash_map::DefaultHasher::new();
            std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default().trim().hash(&mut h);
            let mut mine = [0u64; WORDS + 1];
            mine[0] = h.finish();
            for &c in mask.iter().filter(|&&c| c < 64 * WORDS) {
                mine[1 + c / 64] |= 1 << (c % 64);
            }
            let mut all = vec![0u64; (WORDS + 1) * self.size];
            self.universe.world().all_gather_into(&mine[..], &mut all[..]);
            all.chunks_exact(WORDS + 1)
                .map(|r| (r[0], (0..64 * WORDS).filter(|&c| r[1 + c / 64] >> (c % 64) & 1 == 1).collect()))
                .collect()
        }

        /// The `--dump-state` file's bytes on rank 0 (`None` elsewhere): every rank's
        /// particles streamed in messages of [`GATHER_CHUNK`] records, an empty one ending
        /// a rank's, each record placed at its global id. A rank holds one message beyond
        /// its own particles, rank 0 the file's bytes besides.
        pub fn gather_states(&self, sim: &Simulation) -> Result<Option<Vec<u8>>> {
            let world = self.collectives.world();
            let (p, ids) = (sim.particles(), sim.exchange());
            let mut buf = Vec::with_capacity(GATHER_CHUNK.min(p.len()) * RECORD_VALUES);
            if self.rank != 0 {
                for start in (0..p.len()).step_by(GATHER_CHUNK) {
                    buf.clear();
                    for i in start..(start + GATHER_CHUNK).min(p.len()) {
                        buf.push(ids.global_id(i) as f64);
                        buf.extend(state_values(p, i));
                    }
                    world.process_at_rank(0).send_with_tag(&buf[..], GATHER);
                }
                world.process_at_rank(0).send_with_tag(&buf[..0], GATHER);
                return Ok(None);
            }
            let total = sim.total_particles();
            let mut bytes = vec![0u8; total * RECORD_BYTES];
            let mut placed = vec![false; total];
            let mut place = |id: u64, values: &mut dyn Iterator<Item = f64>| -> Result<()> {
                match placed.get_mut(id as usize) {
                    Some(seen @ false) => *seen = true,
                    _ => bail!("the state dump got particle {id} twice or out of range (of {total}); the run's exchange lost track of its particles"),
                }
                let at = id as usize * RECORD_BYTES;
                put_record(&mut bytes[at..at + RECORD_BYTES], id, values);
                Ok(())
            };
            for i in 0..p.len() {
                place(ids.global_id(i), &mut state_values(p, i))?;
            }
            for r in 1..self.size {
                loop {
                    let (message, status) = world.process_at_rank(r as i32).matched_probe_with_tag(GATHER);
                    buf.resize(status.count(f64::equivalent_datatype()) as usize, 0.0);
                    message.matched_receive_into(&mut buf[..]);
                    if buf.is_empty() {
                        break;
                    }
                    for rec in buf.chunks_exact(RECORD_VALUES) {
                        place(rec[0] as u64, &mut rec[1..].iter().copied())?;
                    }
                }
            }
            if placed.iter().any(|&seen| !seen) {
                bail!("the state dump is missing particles; the run's exchange lost track of some");
            }
            Ok(Some(bytes))
        }

        /// Every rank's `text`, in rank order, on rank 0.
        pub fn gather_text(&self, text: &str) -> Result<Option<Vec<String>>> {
            let world = self.universe.world();
            if self.rank != 0 {
                world.process_at_rank(0).send(text.as_bytes());
                return Ok(None);
            }
            let mut all = vec![text.to_string()];
            for r in 1..self.size {
                let bytes = world.process_at_rank(r as i32).receive_vec::<u8>().0;
                all.push(String::from_utf8(bytes).context("a rank sent a report that is not UTF-8")?);
            }
            Ok(Some(all))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::place;

    #[test]
    fn ranks_are_placed_on_disjoint_cpus_or_flagged() {
        // Bound by the launcher: each rank its own core.
        let bound = [(7, vec![0]), (7, vec![1])];
        assert_eq!(place(1, 1, &bound), (vec![1], false));
        // Unbound, room for all: disjoint slices by rank on the host.
        let free = [(7, vec![0, 1, 2, 3]), (7, vec![0, 1, 2, 3])];
        assert_eq!(place(0, 2, &free), (vec![0, 1], false));
        assert_eq!(place(1, 2, &free), (vec![2, 3], false));
        // Unbound, too few CPUs: shared and flagged.
        let few = [(7, vec![0, 1]), (7, vec![0, 1]), (7, vec![0, 1])];
        assert_eq!(place(2, 1, &few), (vec![0], true));
        // Another host's CPUs do not count.
        let two_hosts = [(7, vec![0, 1]), (8, vec![0, 1])];
        assert_eq!(place(1, 2, &two_hosts), (vec![0, 1], false));
    }
}
