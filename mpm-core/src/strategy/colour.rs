//! Block colouring: the scatter straight into the global arrays, race-free because blocks
//! of one colour share no node (the scheme of sparkl's `particle_to_grid`, Drake's MPM
//! transfer, and the paper's group's "alternated grid updating" of 2010).
//!
//! * **Blocks.** The grid's cells are cut into blocks of `B x B x B` cells ([`BlockPlan`]),
//!   on the lattice of the anchor (a block of cells `(i, j, k)` starts where the global cell
//!   coordinate is a multiple of `B`), so that the blocks are unions of the cell order's
//!   `4^3`-cell blocks or lie inside one ([`crate::order`]): after a sort a block's particles
//!   are consecutive.
//! * **The rule for `B`**: 4, halved (to 2, then 1) while the grid has fewer than
//!   [`BLOCKS_PER_WORKER`] blocks per colour and worker (`8 x 64 x T` blocks in all), so that
//!   each phase has enough blocks to split evenly among the workers. At `B = 4` a block's P2G
//!   records, `5^3 x 64` bytes, stay in the first-level cache while its particles go
//!   through. `B >= 1` always.
//! * **Colours.** Block `(bx, by, bz)` has colour `(bx & 1) + 2 (by & 1) + 4 (bz & 1)`. A
//!   block's particles lie in its cells, so they reach the nodes of its cells only, a box of
//!   `B + 1` nodes per axis. Two blocks of one colour differ by an even number, at least 2,
//!   of blocks along some axis, so their node boxes are at least `B - 1 >= 0` nodes apart
//!   there: they share no node (`same_colour_blocks_share_no_node` below checks every pair
//!   of a grid's blocks, node by node).
//! * **Binning**, every step ([`ScatterStrategy::prepare`]): a counting pass (loop splitting;
//!   worker `w` counts its particles per block in its own row), the column sums and each
//!   worker's write positions (prefix sums, on the driver), a writing pass (worker `w`
//!   writes its particles' ids at its positions). Each block's list holds its particles in
//!   ascending order, whatever the thread count. The block of a particle is computed from
//!   its position in both passes rather than stored, so the strategy's memory is one index a
//!   particle (plus a count per block and worker), not two. Binning rather than runs of the
//!   cell order: the particles leave their cells between sorts (every
//!   [`crate::SimConfig::sort_every`] steps, or never), and binning needs no order at all;
//!   its cost, two passes reading the positions, is what DD's binning pays.
//! * **The split of a phase**: the colour's blocks, in slot order (x fastest), are cut into
//!   one range per worker at the particle-count quantiles ([`quantile_cuts`], the balanced
//!   cuts' code, on the blocks' counts).
//! * **Scatter**: every worker zeroes its share of the global arrays (one phase); then 8
//!   phases, one per colour, in which each worker scatters the particles of its blocks of
//!   that colour, block after block, straight into the global arrays with the shared kernels
//!   ([`Kernel::scatter_all`] over a block's list), through cursors fenced to the block
//!   ([`Cursors::fenced`]: a particle outside its block panics instead of racing). No copy,
//!   no assembly, no exchange.
//!
//! **Determinism**: every node's sum is taken in a fixed order: over the colours in order
//! 0-7 (in each phase at most one block reaches the node) and, within the block, over its
//! particles in ascending index. The order depends on the block size, hence on the thread
//! count through the rule for `B`, and never on timing: a run reproduces bit for bit for a
//! given thread count. It is not the serial order (a node on a block face receives its
//! blocks' particles colour by colour), so the results agree with the serial solver's to
//! round-off.
//!
//! **Soundness**: the one place where several workers write one array at once is
//! [`Shared`], the view of the global records a colour phase's workers share; its `SAFETY`
//! argument rests on the colouring above, the fenced cursors and the phase structure. The
//! strategy type is private to the crate, so only the crate's kernels, which reach the target
//! only at the indices the cursors give, run under it.

use super::cuts::quantile_cuts;
use super::{Cursors, Kernel, ScatterStrategy, Target};
use crate::blocks::BlockMap;
use crate::grid::{GridGeom, Records};
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::parallel::{partition, DisjointSlice, Exec, Split};
use crate::work::Tally;
use std::mem::size_of;

/// Colours of the blocks (the parities of their three coordinates).
pub const COLOURS: usize = 8;
/// Largest block edge, in cells (the cell order's block edge).
pub const MAX_EDGE: usize = 4;
/// Blocks per colour and worker the rule for the block edge asks for ([`BlockPlan::new`]).
pub const BLOCKS_PER_WORKER: usize = 64;
/// Row padding (in `u32`) of the per-worker count table: one 64-byte cache line, as DD's
/// binning tables.
const ROW_STRIDE: usize = 16;

/// The blocks of a grid: their edge, where they lie, and their numbering colour by colour
/// (the *slots*: colour 0's blocks first, each colour's in x-fastest order of its blocks).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct BlockPlan {
    /// `log2` of the edge `B`.
    shift: u32,
    /// Cells from the block lattice's last boundary at or below the grid's first cell to
    /// that cell, per axis: the block of cell `c` is `(c + offset) / B`.
    offset: [usize; 3],
    /// Blocks per axis.
    blocks: [usize; 3],
    /// The grid's cells per axis.
    cells: [usize; 3],
    /// First slot of each colour; the last entry is the slot count.
    first: [usize; COLOURS + 1],
}

impl BlockPlan {
    /// The plan for `geom` and `threads` workers by the module's rule: edge 4, halved while
    /// the grid has fewer than `8 x BLOCKS_PER_WORKER x threads` blocks, down to 1.
    pub fn new(geom: &GridGeom, threads: usize) -> Self {
        let want = COLOURS * BLOCKS_PER_WORKER * threads.max(1);
        let mut edge = MAX_EDGE;
        loop {
            let plan = Self::with_edge(geom, edge);
            if edge == 1 || plan.slots() >= want {
                return plan;
            }
            edge /= 2;
        }
    }

    /// The plan for `geom` with blocks of `edge` cells a side (a power of two).
    pub fn with_edge(geom: &GridGeom, edge: usize) -> Self {
        assert!(edge.is_power_of_two(), "a block edge of {edge} cells: use a power of two");
        let offset = std::array::from_fn(|d| geom.start[d].rem_euclid(edge as i64) as usize);
        let blocks = std::array::from_fn(|d| (geom.cells[d] + offset[d]).div_ceil(edge));
        let mut first = [0; COLOURS + 1];
        for c in 0..COLOURS {
            first[c + 1] = first[c] + colour_dims(blocks, c).iter().product::<usize>();
        }
        Self { shift: edge.trailing_zeros(), offset, blocks, cells: geom.cells, first }
    }

    /// Cells per block edge (`B`).
    pub fn edge(&self) -> usize {
        1 << self.shift
    }

    /// Blocks per axis.
    pub fn blocks(&self) -> [usize; 3] {
        self.blocks
    }

    /// Blocks in all (slots).
    pub fn slots(&self) -> usize {
        self.first[COLOURS]
    }

    /// The slots of colour `c`.
    pub fn colour_slots(&self, c: usize) -> std::ops::Range<usize> {
        self.first[c]..self.first[c + 1]
    }

    /// The colour of block `b`: the parities of its coordinates.
    #[inline(always)]
    pub fn colour(b: [usize; 3]) -> usize {
        (b[0] & 1) | (b[1] & 1) << 1 | (b[2] & 1) << 2
    }

    /// The block holding cell `cell`.
    #[inline(always)]
    pub fn block_of_cell(&self, cell: [usize; 3]) -> [usize; 3] {
        std::array::from_fn(|d| (cell[d] + self.offset[d]) >> self.shift)
    }

    /// The slot of block `b`.
    #[inline(always)]
    pub fn slot(&self, b: [usize; 3]) -> usize {
        let c = Self::colour(b);
        let dims = colour_dims(self.blocks, c);
        self.first[c] + (b[0] >> 1) + dims[0] * ((b[1] >> 1) + dims[1] * (b[2] >> 1))
    }

    /// The block in slot `s`.
    pub fn block(&self, s: usize) -> [usize; 3] {
        let c = (0..COLOURS).rfind(|&c| self.first[c] <= s).expect("slot 0 is colour 0's");
        let dims = colour_dims(self.blocks, c);
        let r = s - self.first[c];
        let h = [r % dims[0], (r / dims[0]) % dims[1], r / (dims[0] * dims[1])];
        std::array::from_fn(|d| 2 * h[d] + ((c >> d) & 1))
    }

    /// The cells of block `b` in the grid: first cell and cells per axis.
    pub fn cells_of(&self, b: [usize; 3]) -> ([usize; 3], [usize; 3]) {
        let e = self.edge();
        let lo: [usize; 3] = std::array::from_fn(|d| (b[d] * e).saturating_sub(self.offset[d]));
        let len = std::array::from_fn(|d| ((b[d] + 1) * e - self.offset[d]).min(self.cells[d]) - lo[d]);
        (lo, len)
    }

    /// The grid nodes block `b`'s particles can reach: the nodes of its cells, `lo ..= hi`.
    pub fn nodes_of(&self, b: [usize; 3]) -> ([usize; 3], [usize; 3]) {
        let (lo, len) = self.cells_of(b);
        (lo, std::array::from_fn(|d| lo[d] + len[d]))
    }
}

/// Blocks of colour `c` per axis among `blocks`: those with the colour's parity.
#[inline(always)]
fn colour_dims(blocks: [usize; 3], c: usize) -> [usize; 3] {
    std::array::from_fn(|d| (blocks[d] + 1 - ((c >> d) & 1)) / 2)
}

/// The work imbalance of a colour step for particles in the cells `cells` on `plan` with
/// `threads` workers: the 8 phases' fullest shares summed over their mean shares summed (a
/// colour step takes as long as the sum of its phases' slowest workers). Serial, the
/// reference of the strategy's split and what `mpm-bench imbalance` reports. 1 with no
/// particles.
pub fn imbalance(plan: &BlockPlan, cells: impl Iterator<Item = [usize; 3]>, threads: usize) -> f64 {
    let mut counts = vec![0u32; plan.slots()];
    for c in cells {
        counts[plan.slot(plan.block_of_cell(c))] += 1;
    }
    let mut cuts = vec![0u32; threads + 1];
    let (mut fullest, mut total) = (0u64, 0u64);
    for c in 0..COLOURS {
        let hist = &counts[plan.colour_slots(c)];
        quantile_cuts(hist, &mut cuts);
        let share = |w: usize| hist[cuts[w] as usize..cuts[w + 1] as usize].iter().map(|&n| u64::from(n)).sum::<u64>();
        fullest += (0..threads).map(share).max().unwrap_or(0);
        total += hist.iter().map(|&n| u64::from(n)).sum::<u64>();
    }
    if total == 0 {
        1.0
    } else {
        fullest as f64 * threads as f64 / total as f64
    }
}

/// The colour strategy's state: the plan of the current grid and the step's block lists.
#[derive(Clone, Debug)]
pub(crate) struct Colour {
    threads: usize,
    plan: BlockPlan,
    /// The grid the plan was made for.
    plan_for: Option<GridGeom>,
    /// Particles in the block lists (the step's particle count).
    binned: usize,
    /// Per worker (rows `stride` apart), its particles per slot; then its write positions.
    table: Vec<u32>,
    stride: usize,
    /// Particles per slot.
    counts: Vec<u32>,
    /// Start of each slot's list in `ids` (`slots + 1` entries).
    offsets: Vec<u32>,
    /// The particles of every block, slot after slot, ascending within a block.
    ids: Vec<u32>,
    /// Per colour, `workers + 1` boundaries of the workers' slot ranges (from the colour's
    /// first slot).
    cuts: Vec<u32>,
}

impl Colour {
    /// State for `threads` workers.
    pub(crate) fn new(threads: usize) -> Self {
        Self {
            threads,
            plan: BlockPlan::default(),
            plan_for: None,
            binned: 0,
            table: Vec::new(),
            stride: 0,
            counts: Vec::new(),
            offsets: Vec::new(),
            ids: Vec::new(),
            cuts: Vec::new(),
        }
    }

    /// Plan the blocks of `geom` if the grid changed.
    fn plan(&mut self, geom: &GridGeom) {
        if self.plan_for != Some(*geom) {
            self.plan = BlockPlan::new(geom, self.threads);
            self.plan_for = Some(*geom);
        }
    }

    /// The block lists of the particles at `x` on the planned grid `geom`, and each phase's
    /// split among the workers (module docs, "Binning").
    fn bin(&mut self, exec: &Exec<'_>, geom: &GridGeom, x: &[Vec3]) {
        assert!(x.len() < u32::MAX as usize, "more than 2^32 - 1 particles");
        let (plan, n, t) = (self.plan, x.len(), exec.workers());
        let slots = plan.slots();
        let stride = slots.div_ceil(ROW_STRIDE) * ROW_STRIDE;
        let slot_of = |p: usize| plan.slot(plan.block_of_cell(geom.shape_cell(x[p])));
        self.stride = stride;
        self.table.resize(t * stride, 0);
        self.counts.resize(slots, 0);
        self.offsets.resize(slots + 1, 0);
        self.ids.resize(n, 0);
        self.binned = n;
        let tally = Tally::of(exec);
        exec.for_each_chunk_mut(Split::Blocks(stride).of(&mut self.table), |w, row| {
            let row = &mut row[..slots];
            row.fill(0);
            let mine = partition(n, t, w);
            tally.particles(w, mine.len());
            for p in mine {
                row[slot_of(p)] += 1;
            }
        });
        // Column sums, list starts, and each worker's first write position in each list.
        let mut at = 0u32;
        for s in 0..slots {
            self.offsets[s] = at;
            for w in 0..t {
                let count = self.table[w * stride + s];
                self.table[w * stride + s] = at;
                at += count;
            }
            self.counts[s] = at - self.offsets[s];
        }
        self.offsets[slots] = at;
        let ids = DisjointSlice::new(&mut self.ids);
        exec.for_each_chunk_mut(Split::Blocks(stride).of(&mut self.table), |w, cursor| {
            let mine = partition(n, t, w);
            tally.particles(w, mine.len());
            for p in mine {
                let s = slot_of(p);
                let i = cursor[s] as usize;
                cursor[s] += 1;
                // SAFETY: worker w's positions in slot s's list are
                // [offsets[s] + sum_{v<w} count(v, s), offsets[s] + sum_{v<=w} count(v, s)):
                // the cursor starts at the first and advances once per particle of chunk w in
                // slot s, and the counting pass counted exactly those particles (the same
                // chunk, the same slot function of the same positions). So the positions of
                // different workers are disjoint and each is written once.
                unsafe { *ids.get_mut(i) = p as u32 };
            }
        });
        self.cuts.resize(COLOURS * (t + 1), 0);
        for c in 0..COLOURS {
            quantile_cuts(&self.counts[plan.colour_slots(c)], &mut self.cuts[c * (t + 1)..(c + 1) * (t + 1)]);
        }
    }

    /// Worker `w`'s scatter in the phase of colour `c`: the particles of its blocks of that
    /// colour, block after block, into the shared global records. Returns the particles.
    fn scatter_phase<const K: usize, F: Kernel<K>>(
        &self,
        c: usize,
        w: usize,
        index: &NodeIndex<'_>,
        global: &DisjointSlice<'_, [f64; K]>,
        kernel: &F,
    ) -> usize {
        let t = self.cuts.len() / COLOURS - 1;
        let (first, cuts) = (self.plan.colour_slots(c).start, &self.cuts[c * (t + 1)..(c + 1) * (t + 1)]);
        let mut scattered = 0;
        for s in first + cuts[w] as usize..first + cuts[w + 1] as usize {
            let list = &self.ids[self.offsets[s] as usize..self.offsets[s + 1] as usize];
            if list.is_empty() {
                continue;
            }
            let b = self.plan.block(s);
            debug_assert_eq!(BlockPlan::colour(b), c, "slot {s} of colour {c}'s phase holds block {b:?}");
            let (lo, len) = self.plan.cells_of(b);
            let mut nodes = Cursors::global(*index).fenced(lo, len);
            let mut target = Shared { records: global };
            kernel.scatter_all(list.iter().map(|&p| p as usize), &mut nodes, &mut target);
            scattered += list.len();
        }
        scattered
    }
}

/// The global records as the workers of one colour phase share them: each worker reaches
/// the nodes of the block it is scattering, one record at a time.
struct Shared<'s, 'a, const K: usize> {
    records: &'s DisjointSlice<'a, [f64; K]>,
}

impl<const K: usize> Target<K> for Shared<'_, '_, K> {
    #[inline(always)]
    fn at(&mut self, i: usize) -> &mut [f64; K] {
        // SAFETY: a `Shared` exists only inside `Colour::scatter_phase`, for one block `b` of
        // the phase's colour, on the one worker whose slot range holds `b` (the phase's cuts
        // give the workers disjoint ranges of the colour's slots). `i` comes from the block's
        // cursors (the crate's kernels reach the target only at the cursors' indices, and the
        // type is private to the crate), which are fenced to `b`'s cells, so record `i` is a
        // node of `b`'s cells. Blocks of one colour share no node (module docs; test
        // `same_colour_blocks_share_no_node`), so no other worker of the phase reaches record
        // `i`; the phases, and the zeroing before them, are separate `Exec::run` calls, each
        // returning after every share finished. Within the worker, `&mut self` keeps one
        // record borrowed at a time. `get_mut` checks the bounds.
        unsafe { self.records.get_mut(i) }
    }
}

impl ScatterStrategy for Colour {
    fn reserve(&mut self, geom: &GridGeom, _blocks: Option<&BlockMap>) -> usize {
        self.plan(geom);
        0
    }

    /// Plan the blocks for `geom` (if it changed) and bin the particles at `x`.
    fn prepare(&mut self, exec: &Exec<'_>, geom: &GridGeom, _blocks: Option<&BlockMap>, x: &[Vec3]) {
        self.plan(geom);
        self.bin(exec, geom, x);
    }

    /// Zero `global`, then the 8 colour phases (module docs, "Scatter").
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        _parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        assert!(
            self.plan_for == Some(*geom) && self.binned == n && self.cuts.len() == COLOURS * (exec.workers() + 1),
            "colour scatter of {n} particles on a grid or with workers the blocks were not binned for"
        );
        let tally = Tally::of(exec);
        exec.for_each_chunk_mut(Split::Even.of(global), |w, part| {
            part.fill([0.0; K]);
            tally.scattered(w, part.len(), size_of::<[f64; K]>(), false);
        });
        let shared = DisjointSlice::new(global);
        for c in 0..COLOURS {
            exec.run(|w| tally.particles(w, self.scatter_phase(c, w, index, &shared, kernel)));
        }
    }

    fn bytes(&self) -> usize {
        crate::capacity_bytes(&self.table)
            + crate::capacity_bytes(&self.counts)
            + crate::capacity_bytes(&self.offsets)
            + crate::capacity_bytes(&self.ids)
            + crate::capacity_bytes(&self.cuts)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::parallel::Team;
    use crate::strategy::Contribution;

    fn grid(cells: [usize; 3], start: [i64; 3]) -> GridGeom {
        GridGeom { start, ..GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells }) }
    }

    /// What the colour phases' shared writes rest on: on grids of several shapes and
    /// offsets from the anchor's lattice, for every block edge, no node is reached by two
    /// blocks of one colour (each block's node box marked node by node); and the slots number
    /// every block once, colour by colour, and every cell lies in the block the plan gives it.
    #[test]
    fn same_colour_blocks_share_no_node() {
        let shapes =
            [([7, 5, 9], [0, 0, 0]), ([16, 3, 1], [-3, 5, 2]), ([1, 1, 1], [1, 1, 1]), ([9, 12, 10], [2, -1, 0])];
        for (cells, start) in shapes {
            let geom = grid(cells, start);
            let nodes = geom.node_dims();
            for edge in [1, 2, 4, 8] {
                let plan = BlockPlan::with_edge(&geom, edge);
                let what = format!("{cells:?} cells from {start:?}, edge {edge}");
                let mut owner = vec![[None; COLOURS]; geom.num_nodes()];
                let [bx, by, bz] = plan.blocks();
                for b in (0..bz).flat_map(|k| (0..by).flat_map(move |j| (0..bx).map(move |i| [i, j, k]))) {
                    let c = BlockPlan::colour(b);
                    let (lo, hi) = plan.nodes_of(b);
                    for k in lo[2]..=hi[2] {
                        for j in lo[1]..=hi[1] {
                            for i in lo[0]..=hi[0] {
                                let mark = &mut owner[i + nodes[0] * (j + nodes[1] * k)][c];
                                if let Some(other) = mark.replace(b) {
                                    panic!("{what}: node {:?} is reached by blocks {other:?} and {b:?}, both of colour {c}", [i, j, k]);
                                }
                            }
                        }
                    }
                }
                let mut seen = vec![false; plan.slots()];
                for s in 0..plan.slots() {
                    let b = plan.block(s);
                    assert_eq!(plan.slot(b), s, "{what}: block {b:?}");
                    assert!(plan.colour_slots(BlockPlan::colour(b)).contains(&s), "{what}: slot {s}");
                    assert!(!std::mem::replace(&mut seen[s], true), "{what}: slot {s} twice");
                }
                assert_eq!(plan.slots(), bx * by * bz, "{what}");
                for k in 0..cells[2] {
                    for j in 0..cells[1] {
                        for i in 0..cells[0] {
                            let (lo, len) = plan.cells_of(plan.block_of_cell([i, j, k]));
                            assert!((0..3).all(|d| [i, j, k][d] >= lo[d] && [i, j, k][d] < lo[d] + len[d]), "{what}");
                        }
                    }
                }
            }
        }
    }

    /// The rule: edge 4 on a grid large enough for the threads, smaller edges otherwise,
    /// never below 1; blocks aligned to the anchor's lattice.
    #[test]
    fn block_edge_follows_the_grid_and_the_threads() {
        let model1 = grid([32, 32, 48], [0; 3]);
        assert_eq!(BlockPlan::new(&model1, 1).edge(), 4, "768 blocks of 4");
        assert_eq!(BlockPlan::new(&model1, 2).edge(), 2, "768 < 1024 blocks of 4");
        let model2 = grid([48, 48, 72], [0; 3]);
        assert_eq!(BlockPlan::new(&model2, 2).edge(), 4);
        assert_eq!(BlockPlan::new(&grid([3, 2, 2], [0; 3]), 8).edge(), 1);
        let shifted = BlockPlan::with_edge(&grid([10, 10, 10], [-1, 6, 4]), 4);
        assert_eq!(shifted.block_of_cell([0, 0, 0]), [0, 0, 0]);
        assert_eq!(shifted.block_of_cell([1, 2, 4]), [1, 1, 1], "lattice boundaries at cells 1, 2 and 0, 4");
        assert_eq!(shifted.blocks(), [4, 3, 3], "13, 12 and 10 cells of the lattice");
    }

    /// Run `f` in a parallel region of `threads` workers.
    fn in_region<R: Send>(threads: usize, f: impl FnOnce(&Exec<'_>) -> R + Send) -> R {
        Team::new(crate::testing::pool(threads)).region(f).unwrap()
    }

    /// The block lists hold every particle once, in its block, ascending, whatever the
    /// thread count; every node's sum is taken colour by colour, then in particle order, so
    /// the scatter gives bitwise the sums of that order computed serially, for every thread
    /// count with the same block edge; the phases' splits follow the quantiles.
    #[test]
    fn scatter_sums_each_node_colour_by_colour_in_particle_order() {
        let geom = grid([11, 9, 13], [0; 3]);
        let mut unit = crate::testing::unit_stream(7);
        let x: Vec<Vec3> = (0..3000).map(|_| [11.0 * unit(), 9.0 * unit(), 13.0 * unit()]).collect();
        let values: Vec<[[f64; 2]; 8]> =
            x.iter().map(|_| std::array::from_fn(|_| [unit() - 0.5, 1e3 * unit()])).collect();
        let kernel = |p: usize| Contribution::<2> { cell: geom.shape_cell(x[p]), c: values[p] };
        let index = NodeIndex::of(&geom, None);
        for threads in [1, 2, 3, 5, 8] {
            let mut colour = Colour::new(threads);
            colour.reserve(&geom, None);
            let plan = colour.plan;
            // The reference: colour by colour, each block's particles in ascending order.
            let mut want = vec![[0.0; 2]; geom.num_nodes()];
            for c in 0..COLOURS {
                for p in 0..x.len() {
                    let b = plan.block_of_cell(geom.shape_cell(x[p]));
                    if BlockPlan::colour(b) == c {
                        let idx = index.cell_nodes(geom.shape_cell(x[p]));
                        for q in 0..8 {
                            for k in 0..2 {
                                want[idx[q]][k] += values[p][q][k];
                            }
                        }
                    }
                }
            }
            let mut global = vec![[f64::NAN; 2]; geom.num_nodes()];
            in_region(threads, |exec| {
                colour.prepare(exec, &geom, None, &x);
                colour.scatter(exec, &geom, &index, x.len(), &mut global, &mut Records::zeroed(0), &kernel);
            });
            for (i, (g, w)) in global.iter().zip(&want).enumerate() {
                assert_eq!(
                    g.map(f64::to_bits),
                    w.map(f64::to_bits),
                    "{threads} threads (edge {}): node {i}",
                    plan.edge()
                );
            }
            let mut listed = vec![0; x.len()];
            for s in 0..plan.slots() {
                let list = &colour.ids[colour.offsets[s] as usize..colour.offsets[s + 1] as usize];
                assert!(list.windows(2).all(|w| w[0] < w[1]), "ascending within a block");
                for &p in list {
                    assert_eq!(plan.slot(plan.block_of_cell(geom.shape_cell(x[p as usize]))), s);
                    listed[p as usize] += 1;
                }
            }
            assert!(listed.iter().all(|&l| l == 1));
            let cells: Vec<[usize; 3]> = x.iter().map(|&p| geom.shape_cell(p)).collect();
            let predicted = imbalance(&plan, cells.into_iter(), threads);
            assert!((1.0..1.25).contains(&predicted), "{threads} threads: imbalance {predicted}");
        }
    }
}
