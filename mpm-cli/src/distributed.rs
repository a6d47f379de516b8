//! Runs split over MPI ranks: the launcher's rank count (read from the environment, so a
//! build without MPI can say what is wrong) and, with the `mpi` feature, [`MpiExchange`],
//! the implementation of `mpm-core`'s [`mpm_core::Exchange`] with MPI.
//!
//! Per step the exchange sends, to each rank whose local grid overlaps this rank's, the
//! nodal values on the overlap (twice: after the P2G scatter and after the re-map), the
//! particles that crossed into a neighbouring box (a count, then the states), and takes part
//! in three small reductions (sums in rank order, counts, maxima). Point-to-point messages
//! are non-blocking: every receive and send of a phase is posted before any is waited for.

/// Ranks the launcher started, from `OMPI_COMM_WORLD_SIZE` (Open MPI) or `PMI_SIZE`
/// (MPICH, Slurm); `None` outside a launcher.
pub fn launcher_ranks() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"].iter().find_map(|v| std::env::var(v).ok()?.parse().ok())
}

/// Whether this build has the MPI implementation.
pub const MPI_COMPILED: bool = cfg!(feature = "mpi");

#[cfg(feature = "mpi")]
pub use mpi_impl::MpiExchange;

#[cfg(feature = "mpi")]
mod mpi_impl {
    use mpi::collective::SystemOperation;
    use mpi::topology::{Communicator, SimpleCommunicator};
    use mpi::traits::{CommunicatorCollectives, Destination, Source};
    use mpm_core::exchange::{ExchangeStats, RankBoxes};
    use mpm_core::particles::PACKED_WIDTH;
    use mpm_core::{Exchange, GridGeom, Particles, SimError};
    use std::time::Instant;

    /// Values per migrating particle: its state and its global id.
    const RECORD: usize = PACKED_WIDTH + 1;

    /// The nodes this rank shares with rank `rank`: a box of local node indices
    /// (inclusive ranges per axis).
    #[derive(Clone, Debug)]
    struct Link {
        rank: usize,
        nodes: [(usize, usize); 3],
    }

    /// [`Exchange`] over an MPI communicator.
    pub struct MpiExchange {
        world: SimpleCommunicator,
        rank: usize,
        boxes: RankBoxes,
        /// Ranks adjacent in the layout (the only possible destinations of a particle).
        adjacent: Vec<usize>,
        ids: Vec<u64>,
        /// Links of the current global grid, increasing rank.
        links: Vec<Link>,
        links_for: Option<GridGeom>,
        /// Local node indices on any link, increasing, and this rank's values there.
        shared: Vec<usize>,
        saved: Vec<f64>,
        send: Vec<Vec<f64>>,
        recv: Vec<Vec<f64>>,
        counts_out: Vec<u64>,
        counts_in: Vec<u64>,
        gather: Vec<f64>,
        stats: ExchangeStats,
    }

    impl MpiExchange {
        /// The exchange of this process in `world`, with rank boxes `boxes` (one per rank).
        pub fn new(world: SimpleCommunicator, boxes: RankBoxes) -> Result<Self, SimError> {
            let (rank, size) = (world.rank() as usize, world.size() as usize);
            if mpi::environment::threading_support() < mpi::Threading::Serialized {
                return Err(SimError::Config(
                    "MPI was started without MPI_THREAD_SERIALIZED; the step calls MPI from a pool worker".into(),
                ));
            }
            if boxes.ranks() != size {
                return Err(SimError::Config(format!(
                    "the rank layout {:?} has {} boxes but mpirun started {size} ranks; give a layout whose product is {size}",
                    boxes.layout(),
                    boxes.ranks()
                )));
            }
            let adjacent = boxes.neighbours(rank);
            let n = adjacent.len();
            Ok(Self {
                world,
                rank,
                boxes,
                ids: Vec::new(),
                links: Vec::new(),
                links_for: None,
                shared: Vec::new(),
                saved: Vec::new(),
                send: vec![Vec::new(); n],
                recv: vec![Vec::new(); n],
                counts_out: vec![0; n],
                counts_in: vec![0; n],
                gather: Vec::new(),
                stats: ExchangeStats::default(),
                adjacent,
            })
        }

        /// The communicator.
        pub fn world(&self) -> &SimpleCommunicator {
            &self.world
        }

        /// Recompute the links for a new global grid.
        fn link(&mut self, global: &GridGeom) {
            let mine = self.boxes.node_range(self.rank, global);
            let local = self.boxes.local_grid(self.rank, global);
            self.links.clear();
            for q in 0..self.boxes.ranks() {
                if q == self.rank {
                    continue;
                }
                let theirs = self.boxes.node_range(q, global);
                let mut nodes = [(0, 0); 3];
                let overlaps = (0..3).all(|d| {
                    let (lo, hi) = (mine[d].0.max(theirs[d].0), mine[d].1.min(theirs[d].1));
                    nodes[d] = (lo.wrapping_sub(mine[d].0), hi.wrapping_sub(mine[d].0));
                    lo <= hi
                });
                if overlaps {
                    self.links.push(Link { rank: q, nodes });
                }
            }
            let mut mark = vec![false; local.num_nodes()];
            for l in &self.links {
                for_each_node(&local, l.nodes, |i| mark[i] = true);
            }
            self.shared = (0..mark.len()).filter(|&i| mark[i]).collect();
            self.links_for = Some(*global);
            let n = self.links.len().max(self.adjacent.len());
            self.send.resize(n, Vec::new());
            self.recv.resize(n, Vec::new());
        }

        /// Post every receive and send of one phase and wait for all of them. `recv[i]` must
        /// already have the size of the message from `peers[i]`.
        fn swap(&mut self, peers: &[usize], tag: i32) {
            let world = &self.world;
            let (send, recv) = (&self.send, &mut self.recv);
            mpi::request::scope(|scope| {
                let mut requests = Vec::with_capacity(2 * peers.len());
                for (&q, buf) in peers.iter().zip(recv.iter_mut()) {
                    let p = world.process_at_rank(q as i32);
                    requests.push(p.immediate_receive_into_with_tag(scope, &mut buf[..], tag));
                }
                for (&q, buf) in peers.iter().zip(send.iter()) {
                    let p = world.process_at_rank(q as i32);
                    requests.push(p.immediate_send_with_tag(scope, &buf[..], tag));
                }
                for r in requests {
                    r.wait();
                }
            });
        }

        /// Element-wise `op` over ranks (exact operations only: integer sums, maxima).
        fn all_reduce<T: mpi::datatype::Equivalence + Copy>(&mut self, values: &mut [T], op: SystemOperation) {
            let t0 = Instant::now();
            let mine = values.to_vec();
            self.world.all_reduce_into(&mine[..], values, op);
            self.stats.reduction_bytes += std::mem::size_of_val(values) as u64;
            self.stats.reductions += 1;
            self.stats.seconds += t0.elapsed().as_secs_f64();
        }

        /// Exchange the counts of particles leaving for each adjacent rank.
        fn swap_counts(&mut self) {
            let world = &self.world;
            let (out, inc) = (&self.counts_out, &mut self.counts_in);
            mpi::request::scope(|scope| {
                let mut requests = Vec::with_capacity(2 * self.adjacent.len());
                for (&q, c) in self.adjacent.iter().zip(inc.iter_mut()) {
                    requests.push(world.process_at_rank(q as i32).immediate_receive_into_with_tag(scope, c, 3));
                }
                for (&q, c) in self.adjacent.iter().zip(out.iter()) {
                    requests.push(world.process_at_rank(q as i32).immediate_send_with_tag(scope, c, 3));
                }
                for r in requests {
                    r.wait();
                }
            });
        }
    }

    // SAFETY: the communicator handle is only used through `&mut self`, so by one thread at
    // a time, and `new` checks that MPI runs with MPI_THREAD_SERIALIZED, which allows calls
    // from any thread as long as they do not overlap. Covered by the equivalence tests
    // (mpm-cli/tests/mpi.rs), where the step calls MPI from a pool worker.
    unsafe impl Send for MpiExchange {}

    /// Call `f` with the linear index of every node of `geom` in the box `nodes`.
    fn for_each_node(geom: &GridGeom, nodes: [(usize, usize); 3], mut f: impl FnMut(usize)) {
        for k in nodes[2].0..=nodes[2].1 {
            for j in nodes[1].0..=nodes[1].1 {
                let row = geom.node_index(0, j, k);
                for i in nodes[0].0..=nodes[0].1 {
                    f(row + i);
                }
            }
        }
    }

    impl Exchange for MpiExchange {
        fn ranks(&self) -> usize {
            self.boxes.ranks()
        }

        fn rank(&self) -> usize {
            self.rank
        }

        fn adopt(&mut self, particles: &mut Particles) -> Result<(), SimError> {
            let owners: Vec<usize> = particles.x.iter().map(|&x| self.boxes.owner(x)).collect();
            self.ids = (0..owners.len() as u64).filter(|&p| owners[p as usize] == self.rank).collect();
            particles.retain_indices(|p| owners[p] == self.rank);
            Ok(())
        }

        fn local_grid(&mut self, global: &GridGeom) -> GridGeom {
            if self.links_for != Some(*global) {
                self.link(global);
            }
            self.boxes.local_grid(self.rank, global)
        }

        fn sum_shared_nodes(&mut self, local: &GridGeom, values: &mut [f64], width: usize) -> Result<(), SimError> {
            let t0 = Instant::now();
            let links = std::mem::take(&mut self.links);
            for (l, (send, recv)) in links.iter().zip(self.send.iter_mut().zip(self.recv.iter_mut())) {
                send.clear();
                for_each_node(local, l.nodes, |i| send.extend_from_slice(&values[i * width..(i + 1) * width]));
                recv.resize(send.len(), 0.0);
                self.stats.halo_bytes += (send.len() * 8) as u64;
            }
            self.stats.halo_messages += links.len() as u64;
            let peers: Vec<usize> = links.iter().map(|l| l.rank).collect();
            self.swap(&peers, 1);
            // Every shared node becomes the sum of the ranks' values in rank order, the
            // same on every rank that holds it.
            self.saved.clear();
            for &i in &self.shared {
                self.saved.extend_from_slice(&values[i * width..(i + 1) * width]);
                values[i * width..(i + 1) * width].fill(0.0);
            }
            let add_link = |values: &mut [f64], l: &Link, recv: &[f64]| {
                let mut at = 0;
                for_each_node(local, l.nodes, |i| {
                    for c in 0..width {
                        values[i * width + c] += recv[at + c];
                    }
                    at += width;
                });
            };
            let split = links.partition_point(|l| l.rank < self.rank);
            for (l, recv) in links[..split].iter().zip(&self.recv) {
                add_link(values, l, recv);
            }
            for (s, &i) in self.shared.iter().enumerate() {
                for c in 0..width {
                    values[i * width + c] += self.saved[s * width + c];
                }
            }
            for (l, recv) in links[split..].iter().zip(&self.recv[split..]) {
                add_link(values, l, recv);
            }
            self.links = links;
            self.stats.seconds += t0.elapsed().as_secs_f64();
            Ok(())
        }

        fn sum(&mut self, values: &mut [f64]) -> Result<(), SimError> {
            let t0 = Instant::now();
            let n = values.len();
            self.gather.resize(n * self.ranks(), 0.0);
            self.world.all_gather_into(&values[..], &mut self.gather[..]);
            values.fill(0.0);
            for r in 0..self.ranks() {
                for (v, g) in values.iter_mut().zip(&self.gather[r * n..(r + 1) * n]) {
                    *v += g;
                }
            }
            self.stats.reduction_bytes += (n * 8) as u64;
            self.stats.reductions += 1;
            self.stats.seconds += t0.elapsed().as_secs_f64();
            Ok(())
        }

        fn sum_counts(&mut self, values: &mut [u64]) -> Result<(), SimError> {
            self.all_reduce(values, SystemOperation::sum());
            Ok(())
        }

        fn max(&mut self, values: &mut [f64]) -> Result<(), SimError> {
            self.all_reduce(values, SystemOperation::max());
            Ok(())
        }

        fn migrate(&mut self, particles: &mut Particles) -> Result<usize, SimError> {
            let t0 = Instant::now();
            let n_adj = self.adjacent.len();
            for b in &mut self.send[..n_adj] {
                b.clear();
            }
            let mut left = 0;
            for p in (0..particles.len()).rev() {
                let owner = self.boxes.owner(particles.x[p]);
                if owner == self.rank {
                    continue;
                }
                let Ok(slot) = self.adjacent.binary_search(&owner) else {
                    return Err(SimError::Exchange(format!(
                        "particle {} at {:?} m moved from rank {} to rank {owner}, which is not adjacent; the rank boxes are too thin for the step (use fewer ranks along that axis)",
                        self.ids[p], particles.x[p], self.rank
                    )));
                };
                particles.pack(p, &mut self.send[slot]);
                self.send[slot].push(self.ids[p] as f64);
                particles.swap_remove(p);
                self.ids.swap_remove(p);
                left += 1;
            }
            for (c, b) in self.counts_out.iter_mut().zip(&self.send) {
                *c = (b.len() / RECORD) as u64;
            }
            self.swap_counts();
            for (r, &c) in self.recv.iter_mut().zip(&self.counts_in) {
                r.resize(c as usize * RECORD, 0.0);
            }
            let adjacent = std::mem::take(&mut self.adjacent);
            self.swap(&adjacent, 2);
            self.adjacent = adjacent;
            for r in &self.recv[..n_adj] {
                for rec in r.chunks_exact(RECORD) {
                    particles.push_packed(&rec[..PACKED_WIDTH]);
                    self.ids.push(rec[PACKED_WIDTH] as u64);
                }
            }
            let sent: usize = self.send[..n_adj].iter().map(Vec::len).sum();
            self.stats.migration_bytes += (sent * 8 + n_adj * 8) as u64;
            self.stats.migration_messages += 2 * n_adj as u64;
            self.stats.seconds += t0.elapsed().as_secs_f64();
            Ok(left)
        }

        fn global_ids(&self) -> Option<&[u64]> {
            Some(&self.ids)
        }

        fn stats(&self) -> ExchangeStats {
            self.stats
        }
    }
}
