//! A run split over MPI ranks: starting MPI (or saying that this build has none), the rank
//! boxes and the exchange, each rank's CPUs, and after the loop the final particles gathered
//! on rank 0 (for the summary's figures and `--dump-state`).

use crate::cli::RunOptions;
use anyhow::{bail, Context, Result};
use mpm_cli::distributed::{launcher_ranks, MPI_COMPILED};
use mpm_cli::pinning;
use mpm_cli::summary::RankReport;
use mpm_core::{Particles, Simulation};
use std::path::Path;

/// The ranks a run asks for: `--ranks` or the launcher's count; `None` for one process.
/// A build without MPI refuses more than one.
pub fn wanted(o: &RunOptions) -> Result<Option<usize>> {
    let launcher = launcher_ranks();
    let want = o.ranks.map(|r| r as usize).or(launcher).filter(|&r| r > 1);
    if want.is_none() && o.rank_layout.is_some_and(|l| l.iter().product::<usize>() > 1) {
        bail!("--rank-layout needs several ranks: start the run with `mpirun -n R mpm run ...`");
    }
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

#[cfg(feature = "mpi")]
/// One process's share of the final state in flat form: per particle the global id, then
/// the packed state.
pub fn pack_final(sim: &Simulation) -> Vec<f64> {
    let p = sim.particles();
    let ids = sim.exchange().global_ids();
    let mut out = Vec::with_capacity(p.len() * (mpm_core::particles::PACKED_WIDTH + 1));
    for i in 0..p.len() {
        out.push(ids.map_or(i as u64, |ids| ids[i]) as f64);
        p.pack(i, &mut out);
    }
    out
}

#[cfg(feature = "mpi")]
/// Particles from the flat records of every rank, in global id order.
pub fn unpack_sorted(records: &[f64]) -> Particles {
    let w = mpm_core::particles::PACKED_WIDTH + 1;
    let mut recs: Vec<&[f64]> = records.chunks_exact(w).collect();
    recs.sort_by(|a, b| a[0].total_cmp(&b[0]));
    let mut all = Particles::with_capacity(recs.len());
    for r in recs {
        all.push_packed(&r[1..]);
    }
    all
}

/// Write `particles` (in global id order) as `--dump-state` describes.
pub fn dump_state(path: &Path, particles: &Particles) -> Result<()> {
    let mut bytes = Vec::with_capacity(particles.len() * 104);
    for i in 0..particles.len() {
        bytes.extend_from_slice(&(i as u64).to_le_bytes());
        let values = particles.x[i].iter().chain(&particles.v[i]).chain(&particles.stress[i]);
        for v in values {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
    }
    mpm_cli::atomic::write_atomic(path, &bytes)
        .with_context(|| format!("cannot write the particle state to {}", path.display()))
}

/// The ranks of this run: MPI when started over several, else one process.
pub struct Ranks {
    #[cfg(feature = "mpi")]
    mpi: Option<with_mpi::Mpi>,
}

impl Ranks {
    /// Start MPI if the run asks for several ranks ([`wanted`]).
    pub fn start(o: &RunOptions) -> Result<Self> {
        let want = wanted(o)?;
        #[cfg(feature = "mpi")]
        return Ok(Self { mpi: want.map(|_| with_mpi::Mpi::start()).transpose()? });
        #[cfg(not(feature = "mpi"))]
        {
            debug_assert!(want.is_none(), "wanted() refuses several ranks without MPI");
            Ok(Self {})
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

    /// The exchange of this rank, `None` for one process.
    pub fn exchange(
        &self,
        _setup: &mpm_core::Setup,
        _layout: Option<[usize; 3]>,
    ) -> Result<Option<Box<dyn mpm_core::Exchange>>> {
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            return m.exchange(_setup, _layout).map(Some);
        }
        Ok(None)
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

    /// After the loop: every rank's particles, in global id order, on rank 0 (`None` on the
    /// other ranks); a copy of one process's particles (the caller avoids that copy).
    pub fn gather_final(&self, sim: &Simulation) -> Option<Particles> {
        #[cfg(feature = "mpi")]
        if let Some(m) = &self.mpi {
            return m.gather_on_lead(&pack_final(sim)).map(|all| unpack_sorted(&all.concat()));
        }
        Some(sim.particles().clone())
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
    use anyhow::{bail, Context, Result};
    use mpi::topology::Communicator;
    use mpi::traits::{Destination, Source};
    use mpm_cli::distributed::MpiExchange;
    use mpm_core::exchange::{rank_layout, uniform_cuts, RankBoxes};
    use mpm_core::{Exchange, GridGeom, Setup};

    /// MPI, started for the run (finalised when dropped).
    pub struct Mpi {
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
            Ok(Self { universe, rank, size })
        }

        /// The exchange of this rank: boxes of `layout` (default: the DD layout for the
        /// rank count) cut uniformly over the particles' initial bounding box.
        pub fn exchange(&self, setup: &Setup, layout: Option<[usize; 3]>) -> Result<Box<dyn Exchange>> {
            let (lo, hi) = setup.particles.bounding_box();
            let fit = GridGeom::fit(&setup.grid, lo, hi);
            let layout = layout.unwrap_or_else(|| rank_layout(self.size, fit.cells));
            let cuts = uniform_cuts(layout, &fit)?;
            let boxes = RankBoxes::new(cuts, setup.grid.anchor, 1.0 / setup.grid.dx)?;
            Ok(Box::new(MpiExchange::new(self.universe.world(), boxes)?))
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

        /// Every rank's `data`, in rank order, on rank 0 (`None` elsewhere).
        pub fn gather_on_lead(&self, data: &[f64]) -> Option<Vec<Vec<f64>>> {
            let world = self.universe.world();
            if self.rank != 0 {
                world.process_at_rank(0).send(data);
                return None;
            }
            let mut all = vec![data.to_vec()];
            for r in 1..self.size {
                all.push(world.process_at_rank(r as i32).receive_vec::<f64>().0);
            }
            Some(all)
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
