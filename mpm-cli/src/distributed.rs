//! Runs split over MPI ranks: the launcher's rank count (read from the environment, so a
//! build without MPI can say what is wrong) and, with the `mpi` feature, [`MpiExchange`],
//! the implementation of `mpm-core`'s [`mpm_core::Exchange`] with MPI, and
//! [`MpiCollectives`], its reductions and gather without the exchange's bookkeeping (what
//! the program measures the scenario's figures with).
//!
//! Per step the exchange sends, to each rank whose local grid (the nodes of its box's cells,
//! [`mpm_core::exchange::RankBoxes::node_range`]) meets this rank's, the nodal values on
//! the nodes they share (a face's node layer, an edge or a corner; twice: after the P2G
//! scatter and after the re-map), one message per adjacent rank with the particles that
//! crossed into its box (its length, found by a probe, is the count), and takes part in
//! three small reductions (sums in rank order, counts, maxima). Halo messages are
//! non-blocking: every receive and send of a phase is posted before any is waited for. The
//! buffers are kept from step to step; a step allocates nothing once they have reached
//! their largest size.

/// Ranks the launcher started, from `OMPI_COMM_WORLD_SIZE` (Open MPI) or `PMI_SIZE`
/// (MPICH, Slurm); `None` outside a launcher.
pub fn launcher_ranks() -> Option<usize> {
    ["OMPI_COMM_WORLD_SIZE", "PMI_SIZE"].iter().find_map(|v| std::env::var(v).ok()?.parse().ok())
}

/// Whether this build has the MPI implementation.
pub const MPI_COMPILED: bool = cfg!(feature = "mpi");

#[cfg(feature = "mpi")]
pub use mpi_impl::{MpiCollectives, MpiExchange};

#[cfg(feature = "mpi")]
mod mpi_impl {
    use mpi::collective::SystemOperation;
    use mpi::datatype::{Equivalence, PartitionMut};
    use mpi::request::Request;
    use mpi::topology::{Communicator, Rank, SimpleCommunicator};
    use mpi::traits::{CommunicatorCollectives, Destination, Root, Source};
    use mpm_core::exchange::{ExchangeStats, RankBoxes};
    use mpm_core::particles::PACKED_WIDTH;
    use mpm_core::{Collectives, Exchange, GridGeom, Particles, SimError};
    use std::time::Instant;

    /// Values per migrating particle: its state and its global id.
    const RECORD: usize = PACKED_WIDTH + 1;

    /// Peers whose requests a phase holds on the stack (the 26 neighbours of an interior
    /// box fit); more (many boxes clipped onto the grid's boundary cell) go to the heap.
    const STACK_PEERS: usize = 32;

    /// Tags of the two kinds of point-to-point messages.
    const HALO: i32 = 1;
    const MIGRATION: i32 = 2;

    /// Global ids of a rank's particles: 4 bytes each while every id fits in 32 bits (sets
    /// of fewer than 2^32 particles), 8 bytes from the first one that does not.
    enum Ids {
        Narrow(Vec<u32>),
        Wide(Vec<u64>),
    }

    impl Ids {
        fn new(ids: Vec<u64>) -> Self {
            match ids.iter().map(|&id| u32::try_from(id)).collect() {
                Ok(narrow) => Ids::Narrow(narrow),
                Err(_) => Ids::Wide(ids),
            }
        }

        fn get(&self, p: usize) -> u64 {
            match self {
                Ids::Narrow(v) => u64::from(v[p]),
                Ids::Wide(v) => v[p],
            }
        }

        fn swap_remove(&mut self, p: usize) {
            match self {
                Ids::Narrow(v) => _ = v.swap_remove(p),
                Ids::Wide(v) => _ = v.swap_remove(p),
            }
        }

        /// Room for `additional` more, growing by at least 1/16 (as the particles do).
        fn reserve_headroom(&mut self, additional: usize) {
            fn reserve<T>(v: &mut Vec<T>, additional: usize) {
                if v.capacity() - v.len() < additional {
                    v.reserve_exact(additional.max(v.len() / 16));
                }
            }
            match self {
                Ids::Narrow(v) => reserve(v, additional),
                Ids::Wide(v) => reserve(v, additional),
            }
        }

        /// New id `i` is old id `order[i]`, through `scratch`.
        fn permute(&mut self, order: &[u64], scratch: &mut Vec<u64>) {
            scratch.clear();
            scratch.extend(order.iter().map(|&o| self.get(o as usize)));
            match self {
                // Every id was narrow before, and the permutation only moves them.
                Ids::Narrow(v) => v.iter_mut().zip(scratch.iter()).for_each(|(id, &s)| *id = s as u32),
                Ids::Wide(v) => v.copy_from_slice(scratch),
            }
        }

        fn push(&mut self, id: u64) {
            match self {
                Ids::Narrow(v) => match u32::try_from(id) {
                    Ok(id) => v.push(id),
                    Err(_) => {
                        let mut wide: Vec<u64> = v.iter().map(|&i| u64::from(i)).collect();
                        wide.push(id);
                        *self = Ids::Wide(wide);
                    }
                },
                Ids::Wide(v) => v.push(id),
            }
        }
    }

    /// The nodes this rank shares with rank `rank`: a box of local node indices
    /// (inclusive ranges per axis).
    #[derive(Clone, Debug)]
    struct Link {
        rank: usize,
        nodes: [(usize, usize); 3],
    }

    /// [`Collectives`] over an MPI communicator, counting nothing: what the program measures
    /// the scenario's figures with, and what [`MpiExchange`] books its reductions around.
    pub struct MpiCollectives {
        world: SimpleCommunicator,
        rank: usize,
        size: usize,
        /// Every rank's values of a sum, in rank order.
        gathered: Vec<f64>,
        scratch_f64: Vec<f64>,
        scratch_u64: Vec<u64>,
    }

    impl MpiCollectives {
        /// The collectives of this process in `world`. Refused unless MPI was started with
        /// at least `MPI_THREAD_SERIALIZED`: the value is `Send` (the step calls MPI from a
        /// pool worker), which is sound only at that level.
        pub fn new(world: SimpleCommunicator) -> Result<Self, SimError> {
            if mpi::environment::threading_support() < mpi::Threading::Serialized {
                return Err(SimError::Config(
                    "MPI was started without MPI_THREAD_SERIALIZED; the step calls MPI from a pool worker \
                     (start it with mpi::initialize_with_threading(Threading::Serialized))"
                        .into(),
                ));
            }
            let (rank, size) = (world.rank() as usize, world.size() as usize);
            Ok(Self { world, rank, size, gathered: Vec::new(), scratch_f64: Vec::new(), scratch_u64: Vec::new() })
        }

        /// The communicator.
        pub fn world(&self) -> &SimpleCommunicator {
            &self.world
        }
    }

    // SAFETY: the communicator handle is only used through `&mut self` (or `&self` of an
    // owner borrowed mutably for the call), so by one thread at a time, and MPI runs with at
    // least MPI_THREAD_SERIALIZED (checked by `MpiCollectives::new`, the only way to make
    // one, which `MpiExchange::new` goes through), which allows calls from any thread as
    // long as they do not overlap. Guarded by `collectives_refuse_mpi_below_serialized`
    // (the check) and the equivalence tests (mpm-cli/tests/mpi.rs), where the step and the
    // measurements call MPI from a pool worker.
    unsafe impl Send for MpiCollectives {}

    impl Collectives for MpiCollectives {
        fn ranks(&self) -> usize {
            self.size
        }

        fn rank(&self) -> usize {
            self.rank
        }

        fn sum(&mut self, values: &mut [f64]) -> Result<(), SimError> {
            let n = values.len();
            self.gathered.resize(n * self.size, 0.0);
            self.world.all_gather_into(&values[..], &mut self.gathered[..]);
            values.fill(0.0);
            for r in 0..self.size {
                for (v, g) in values.iter_mut().zip(&self.gathered[r * n..(r + 1) * n]) {
                    *v += g;
                }
            }
            Ok(())
        }

        fn sum_counts(&mut self, values: &mut [u64]) -> Result<(), SimError> {
            all_reduce(&self.world, values, &mut self.scratch_u64, SystemOperation::sum());
            Ok(())
        }

        fn max(&mut self, values: &mut [f64]) -> Result<(), SimError> {
            all_reduce(&self.world, values, &mut self.scratch_f64, SystemOperation::max());
            Ok(())
        }

        fn gather(&mut self, values: Vec<f64>) -> Result<Option<Vec<f64>>, SimError> {
            // MPI counts and displacements are `int`s.
            let too_many = |n: usize| SimError::Exchange(format!("{n} values are too many for one MPI gather"));
            let count = Rank::try_from(values.len()).map_err(|_| too_many(values.len()))?;
            let root = self.world.process_at_rank(0);
            if self.rank != 0 {
                root.gather_into(&count);
                root.gather_varcount_into(&values[..]);
                return Ok(None);
            }
            let mut counts: Vec<Rank> = vec![0; self.size];
            root.gather_into_root(&count, &mut counts[..]);
            let total: usize = counts.iter().map(|&c| c as usize).sum();
            Rank::try_from(total).map_err(|_| too_many(total))?;
            let displs: Vec<Rank> = counts
                .iter()
                .scan(0, |at, &c| {
                    let d = *at;
                    *at += c;
                    Some(d)
                })
                .collect();
            let mut all = vec![0.0; total];
            root.gather_varcount_into_root(&values[..], &mut PartitionMut::new(&mut all[..], &counts[..], &displs[..]));
            Ok(Some(all))
        }
    }

    /// [`Exchange`] over an MPI communicator.
    pub struct MpiExchange {
        /// The reductions (booked in `stats` here).
        collectives: MpiCollectives,
        rank: usize,
        boxes: RankBoxes,
        /// This rank's box in lattice coordinates ([`RankBoxes::lattice_bounds`]), and the
        /// axes along which it is bounded (the others need no test).
        bounds: [(f64, f64); 3],
        bounded: Vec<usize>,
        /// Ranks adjacent in the layout (the only possible destinations of a particle).
        adjacent: Vec<usize>,
        ids: Ids,
        /// The ids being permuted ([`Exchange::reorder`]).
        id_scratch: Vec<u64>,
        /// Links of the current global grid, increasing rank, and their ranks.
        links: Vec<Link>,
        peers: Vec<usize>,
        links_for: Option<GridGeom>,
        /// Local node indices on any link, increasing, and this rank's values there.
        shared: Vec<usize>,
        saved: Vec<f64>,
        send: Vec<Vec<f64>>,
        recv: Vec<Vec<f64>>,
        stats: ExchangeStats,
        /// Time a barrier in front of each operation as waiting (see [`Self::split_wait`]).
        split_wait: bool,
    }

    impl MpiExchange {
        /// The exchange of this process in `world`, with rank boxes `boxes` (one per rank).
        pub fn new(world: SimpleCommunicator, boxes: RankBoxes) -> Result<Self, SimError> {
            let (rank, size) = (world.rank() as usize, world.size() as usize);
            let collectives = MpiCollectives::new(world)?;
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
                collectives,
                rank,
                bounds: boxes.lattice_bounds(rank),
                bounded: (0..3)
                    .filter(|&d| boxes.lattice_bounds(rank)[d] != (f64::NEG_INFINITY, f64::INFINITY))
                    .collect(),
                boxes,
                ids: Ids::Narrow(Vec::new()),
                id_scratch: Vec::new(),
                links: Vec::new(),
                peers: Vec::new(),
                links_for: None,
                shared: Vec::new(),
                saved: Vec::new(),
                send: vec![Vec::new(); n],
                recv: vec![Vec::new(); n],
                stats: ExchangeStats::default(),
                split_wait: false,
                adjacent,
            })
        }

        /// Put a barrier in front of every exchange operation and count the time spent in it
        /// as `wait_seconds`, not as exchange time: separates waiting for a slower rank
        /// (load imbalance, a CPU taken by another process) from the communication itself.
        /// The barrier is a global synchronisation the step does not need otherwise: cheap
        /// at a few ranks, a measurement aid at many.
        pub fn split_wait(mut self, on: bool) -> Self {
            self.split_wait = on;
            self.stats.wait_seconds = on.then_some(0.0);
            self
        }

        /// The start of an exchange operation: with [`Self::split_wait`], wait at a barrier
        /// first and book that time as waiting.
        fn arrive(&mut self) -> Instant {
            if self.split_wait {
                let t = Instant::now();
                self.collectives.world.barrier();
                *self.stats.wait_seconds.get_or_insert(0.0) += t.elapsed().as_secs_f64();
            }
            Instant::now()
        }

        /// Book one reduction of this rank's `bytes` that began at `t0` (from [`Self::arrive`]).
        fn reduced(&mut self, t0: Instant, bytes: usize) {
            self.stats.reduction_bytes += bytes as u64;
            self.stats.reductions += 1;
            self.stats.seconds += t0.elapsed().as_secs_f64();
        }

        /// The communicator.
        pub fn world(&self) -> &SimpleCommunicator {
            self.collectives.world()
        }

        /// Book around the reduction `op` on this rank's `values` (their bytes).
        fn booked<T>(
            &mut self,
            values: &mut [T],
            op: impl FnOnce(&mut MpiCollectives, &mut [T]) -> Result<(), SimError>,
        ) -> Result<(), SimError> {
            let t0 = self.arrive();
            op(&mut self.collectives, values)?;
            self.reduced(t0, std::mem::size_of_val(values));
            Ok(())
        }

        /// Recompute the links for a new global grid: the nodes this rank's local grid
        /// shares with each other rank's, in this rank's local numbering.
        fn link(&mut self, global: &GridGeom) {
            let mine = self.boxes.node_range(self.rank, global);
            let offset = mine.map(|r| r.0);
            let local = self.boxes.local_grid(self.rank, global);
            self.links.clear();
            for q in (0..self.boxes.ranks()).filter(|&q| q != self.rank) {
                let theirs = self.boxes.node_range(q, global);
                let mut nodes = [(0, 0); 3];
                let overlaps = (0..3).all(|d| {
                    let (lo, hi) = (mine[d].0.max(theirs[d].0), mine[d].1.min(theirs[d].1));
                    nodes[d] = (lo.wrapping_sub(offset[d]), hi.wrapping_sub(offset[d]));
                    lo <= hi
                });
                if overlaps {
                    self.links.push(Link { rank: q, nodes });
                }
            }
            self.peers.clear();
            self.peers.extend(self.links.iter().map(|l| l.rank));
            // A node on an edge or corner is on several links: listed once.
            self.shared.clear();
            for l in &self.links {
                for_each_node(&local, l.nodes, |i| self.shared.push(i));
            }
            self.shared.sort_unstable();
            self.shared.dedup();
            self.links_for = Some(*global);
            let n = self.links.len().max(self.adjacent.len());
            if self.send.len() < n {
                self.send.resize(n, Vec::new());
                self.recv.resize(n, Vec::new());
            }
        }

        /// Whether `x` lies in this rank's box (the same answer as `boxes.owner(x) == rank`
        /// for finite positions, without its floor and search).
        #[inline]
        fn in_box(&self, x: [f64; 3]) -> bool {
            self.bounded.iter().all(|&d| {
                let xi = (x[d] - self.boxes.anchor[d]) * self.boxes.inv_dx;
                xi >= self.bounds[d].0 && xi < self.bounds[d].1
            })
        }
    }

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

    /// Requests of one phase: on the stack for up to [`STACK_PEERS`] peers each way.
    struct Pending<'a, S: mpi::request::Scope<'a>> {
        stack: [Option<Request<'a, [f64], S>>; 2 * STACK_PEERS],
        len: usize,
        heap: Vec<Request<'a, [f64], S>>,
    }

    impl<'a, S: mpi::request::Scope<'a>> Pending<'a, S> {
        fn new() -> Self {
            Self { stack: std::array::from_fn(|_| None), len: 0, heap: Vec::new() }
        }

        fn hold(&mut self, r: Request<'a, [f64], S>) {
            if self.len < self.stack.len() {
                self.stack[self.len] = Some(r);
                self.len += 1;
            } else {
                self.heap.push(r);
            }
        }

        fn wait_all(self) {
            for r in self.stack.into_iter().flatten().chain(self.heap) {
                r.wait_without_status();
            }
        }
    }

    /// Post a receive into `recv[i]` (already of the message's size) and a send of
    /// `send[i]` for every `peers[i]`, then wait for all of them: every request is posted
    /// before any is waited for.
    fn swap(world: &SimpleCommunicator, peers: &[usize], send: &[Vec<f64>], recv: &mut [Vec<f64>], tag: i32) {
        mpi::request::scope(|scope| {
            let mut pending = Pending::new();
            for (&q, buf) in peers.iter().zip(recv.iter_mut()) {
                pending.hold(world.process_at_rank(q as i32).immediate_receive_into_with_tag(scope, &mut buf[..], tag));
            }
            for (&q, buf) in peers.iter().zip(send) {
                pending.hold(world.process_at_rank(q as i32).immediate_send_with_tag(scope, &buf[..], tag));
            }
            pending.wait_all();
        });
    }

    /// Element-wise `op` over ranks (exact operations only: integer sums, maxima), through
    /// a kept copy of the input.
    fn all_reduce<T: Equivalence + Copy>(
        world: &SimpleCommunicator,
        values: &mut [T],
        copy: &mut Vec<T>,
        op: SystemOperation,
    ) {
        copy.clear();
        copy.extend_from_slice(values);
        world.all_reduce_into(&copy[..], values, op);
    }

    /// The reductions of [`MpiCollectives`], each booked in the exchange's statistics.
    impl Collectives for MpiExchange {
        fn ranks(&self) -> usize {
            self.boxes.ranks()
        }

        fn rank(&self) -> usize {
            self.rank
        }

        fn sum(&mut self, values: &mut [f64]) -> Result<(), SimError> {
            self.booked(values, |c, v| c.sum(v))
        }

        fn sum_counts(&mut self, values: &mut [u64]) -> Result<(), SimError> {
            self.booked(values, |c, v| c.sum_counts(v))
        }

        fn max(&mut self, values: &mut [f64]) -> Result<(), SimError> {
            self.booked(values, |c, v| c.max(v))
        }

        fn gather(&mut self, values: Vec<f64>) -> Result<Option<Vec<f64>>, SimError> {
            let (t0, bytes) = (self.arrive(), std::mem::size_of_val(&values[..]));
            let all = self.collectives.gather(values)?;
            self.reduced(t0, bytes);
            Ok(all)
        }
    }

    impl Exchange for MpiExchange {
        fn adopt(&mut self, particles: &mut Particles, ids: Option<Vec<u64>>) -> Result<(), SimError> {
            let ids = ids.unwrap_or_else(|| (0..particles.len() as u64).collect());
            if ids.len() != particles.len() {
                return Err(SimError::Config(format!(
                    "{} particle ids for {} particles; build the set-up with one id per particle",
                    ids.len(),
                    particles.len()
                )));
            }
            let mine: Vec<bool> = particles.x.iter().map(|&x| self.boxes.owner(x) == self.rank).collect();
            if mine.iter().all(|&m| m) {
                self.ids = Ids::new(ids);
                return Ok(());
            }
            particles.retain_indices(|p| mine[p]);
            particles.shrink_to_fit();
            self.ids = Ids::new(ids.into_iter().zip(&mine).filter(|(_, &m)| m).map(|(id, _)| id).collect());
            Ok(())
        }

        fn local_grid(&mut self, global: &GridGeom) -> GridGeom {
            if self.links_for != Some(*global) {
                self.link(global);
            }
            self.boxes.local_grid(self.rank, global)
        }

        fn sum_shared_nodes(&mut self, local: &GridGeom, values: &mut [f64], width: usize) -> Result<(), SimError> {
            let t0 = self.arrive();
            for (l, (send, recv)) in self.links.iter().zip(self.send.iter_mut().zip(self.recv.iter_mut())) {
                send.clear();
                for_each_node(local, l.nodes, |i| send.extend_from_slice(&values[i * width..(i + 1) * width]));
                recv.resize(send.len(), 0.0);
                self.stats.halo_bytes += (send.len() * 8) as u64;
            }
            self.stats.halo_messages += self.links.len() as u64;
            swap(&self.collectives.world, &self.peers, &self.send, &mut self.recv, HALO);
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
            let split = self.links.partition_point(|l| l.rank < self.rank);
            for (l, recv) in self.links[..split].iter().zip(&self.recv) {
                add_link(values, l, recv);
            }
            for (s, &i) in self.shared.iter().enumerate() {
                for c in 0..width {
                    values[i * width + c] += self.saved[s * width + c];
                }
            }
            for (l, recv) in self.links[split..].iter().zip(&self.recv[split..]) {
                add_link(values, l, recv);
            }
            self.stats.seconds += t0.elapsed().as_secs_f64();
            Ok(())
        }

        fn migrate(&mut self, particles: &mut Particles) -> Result<usize, SimError> {
            let t0 = self.arrive();
            let n_adj = self.adjacent.len();
            for b in &mut self.send[..n_adj] {
                b.clear();
            }
            let mut left = 0;
            for p in (0..particles.len()).rev() {
                if self.in_box(particles.x[p]) {
                    continue;
                }
                let owner = self.boxes.owner(particles.x[p]);
                if owner == self.rank {
                    continue;
                }
                let Ok(slot) = self.adjacent.binary_search(&owner) else {
                    return Err(SimError::Exchange(format!(
                        "particle {} at {:?} m moved from rank {} to rank {owner}, which is not adjacent; the rank boxes are too thin for the step (use fewer ranks along that axis)",
                        self.ids.get(p), particles.x[p], self.rank
                    )));
                };
                particles.pack(p, &mut self.send[slot]);
                self.send[slot].push(self.ids.get(p) as f64);
                particles.swap_remove(p);
                self.ids.swap_remove(p);
                left += 1;
            }
            // One message per adjacent rank, empty when no particle goes there; its length,
            // read by a probe, says how many particles it carries.
            let (world, adjacent) = (&self.collectives.world, &self.adjacent);
            let (send, recv) = (&self.send[..n_adj], &mut self.recv[..n_adj]);
            mpi::request::scope(|scope| {
                let mut pending = Pending::new();
                for (&q, buf) in adjacent.iter().zip(send) {
                    pending.hold(world.process_at_rank(q as i32).immediate_send_with_tag(scope, &buf[..], MIGRATION));
                }
                for (&q, buf) in adjacent.iter().zip(recv.iter_mut()) {
                    let (message, status) = world.process_at_rank(q as i32).matched_probe_with_tag(MIGRATION);
                    buf.resize(status.count(f64::equivalent_datatype()) as usize, 0.0);
                    message.matched_receive_into(&mut buf[..]);
                }
                pending.wait_all();
            });
            let arriving: usize = self.recv[..n_adj].iter().map(|r| r.len() / RECORD).sum();
            particles.reserve_headroom(arriving);
            self.ids.reserve_headroom(arriving);
            for r in &self.recv[..n_adj] {
                for rec in r.chunks_exact(RECORD) {
                    particles.push_packed(&rec[..PACKED_WIDTH]);
                    self.ids.push(rec[PACKED_WIDTH] as u64);
                }
            }
            let sent: usize = self.send[..n_adj].iter().map(Vec::len).sum();
            self.stats.migration_bytes += (sent * 8) as u64;
            self.stats.migration_messages += n_adj as u64;
            self.stats.seconds += t0.elapsed().as_secs_f64();
            Ok(left)
        }

        fn global_id(&self, p: usize) -> u64 {
            self.ids.get(p)
        }

        fn reorder(&mut self, order: &[u64]) {
            self.ids.permute(order, &mut self.id_scratch);
        }

        fn stats(&self) -> ExchangeStats {
            self.stats
        }

        fn resume_stats(&mut self, stats: ExchangeStats) {
            // The waiting is measured exactly when this run splits it out (`--split-wait`).
            let wait_seconds = self.split_wait.then(|| stats.wait_seconds.unwrap_or(0.0));
            self.stats = ExchangeStats { wait_seconds, ..stats };
        }
    }

    #[cfg(test)]
    mod tests {
        use super::{Ids, MpiCollectives};

        /// MPI started single-threaded (in this test process, as a singleton): the
        /// collectives, which are `Send`, cannot be made. The only test of this binary that
        /// starts MPI (once per process).
        #[test]
        fn collectives_refuse_mpi_below_serialized() {
            let (universe, provided) =
                mpi::initialize_with_threading(mpi::Threading::Single).expect("MPI starts as a singleton");
            assert_eq!(provided, mpi::Threading::Single, "this test needs MPI to provide the level asked");
            let err = MpiCollectives::new(universe.world()).err().expect("refused below MPI_THREAD_SERIALIZED");
            assert!(err.to_string().contains("MPI_THREAD_SERIALIZED"), "{err}");
        }

        #[test]
        fn ids_stay_narrow_until_one_does_not_fit_and_keep_their_values() {
            let mut ids = Ids::new(vec![7, 3, 9]);
            assert!(matches!(ids, Ids::Narrow(_)));
            ids.swap_remove(0);
            ids.reserve_headroom(2);
            ids.push(11);
            assert!(matches!(ids, Ids::Narrow(_)));
            ids.push(1 << 40);
            assert!(matches!(ids, Ids::Wide(_)));
            assert_eq!((0..4).map(|p| ids.get(p)).collect::<Vec<_>>(), [9, 3, 11, 1 << 40]);
            ids.permute(&[3, 0, 2, 1], &mut Vec::new());
            assert_eq!((0..4).map(|p| ids.get(p)).collect::<Vec<_>>(), [1 << 40, 9, 11, 3]);
            assert!(matches!(Ids::new(vec![1, u64::MAX]), Ids::Wide(_)));
        }
    }
}
