//! Blocked storage of the grid's nodes ([`crate::GridMode::Sparse`]): only the blocks of
//! [`BLOCK`]^3 nodes that a particle's cell touches are stored.
//!
//! The grid is the adaptive grid's box, but the debris cloud of an impact is a thin,
//! expanding shell with fragments far ahead and sideways: the box around it is 1-4 %
//! occupied (ARCHITECTURE.md, "Memory of the adaptive grid"), and a dense box of the large
//! impact model is 33 M nodes (8.3 GiB with the particles). Blocked, it is what the
//! particles touch.
//!
//! * Node `(i, j, k)` of the grid lies in block `(i, j, k) / BLOCK` at local index
//!   `i % BLOCK + BLOCK (j % BLOCK) + BLOCK^2 (k % BLOCK)`. A stored block has a *slot*; its
//!   nodes are `slot * BLOCK_NODES + local` in the compact node arrays.
//! * Every step, after the grid is fitted, one parallel pass marks the blocks of the 8 nodes
//!   of each particle's cell; a serial pass over the table numbers the marked blocks in
//!   table order. The numbering depends on the set of marked blocks only, not on the thread
//!   count or on timing.
//! * [`BlockMap::cell_nodes`] is the one place that turns a cell into 8 compact node indices;
//!   the kernels are those of the dense grid. A block not stored has no slot, and an index
//!   into it is out of bounds (a panic, never a silent write elsewhere).
//! * A map can also be restricted to a box of nodes ([`BlockMap::restrict`]): a DD patch's
//!   sub-grid is the stored blocks that meet the patch, numbered in the same order.
//!
//! A block at the grid's upper end can reach past the last node layer; those nodes are
//! stored but belong to no cell, and the node loops skip them ([`BlockMap::node_ranges`]).

use crate::capacity_bytes;
use crate::grid::GridGeom;
use crate::math::Vec3;
use crate::parallel::{partition, Exec};
use std::ops::Range;
use std::sync::atomic::{AtomicU8, Ordering};

/// Nodes per block along x, y and z (powers of two). On the impact (1.59 mm cells, 100
/// steps, DD on 2 threads, 3 interleaved runs on a noisy host) 8 x 4 x 2, 16 x 4 x 4 and
/// 32 x 4 x 2 were not clearly faster than 4 x 4 x 4, and blocks long along one axis store
/// more nodes of a shell whose normal points along it: the large model's limit is memory.
pub const BLOCK: [usize; 3] = [4, 4, 4];
/// Nodes per block.
pub const BLOCK_NODES: usize = BLOCK[0] * BLOCK[1] * BLOCK[2];
/// `log2(BLOCK)`.
const SHIFT: [u32; 3] = [BLOCK[0].trailing_zeros(), BLOCK[1].trailing_zeros(), BLOCK[2].trailing_zeros()];

/// Index within its block of the node at offset `(a, b, c)` from the block's first node.
#[inline(always)]
pub const fn local(a: usize, b: usize, c: usize) -> usize {
    a + BLOCK[0] * (b + BLOCK[1] * c)
}
/// Table entry of a block that is not stored.
const ABSENT: u32 = u32::MAX;

/// Which blocks of a grid's nodes are stored, and where.
#[derive(Debug, Default)]
pub struct BlockMap {
    /// First block of the table (block coordinates of the grid).
    lo: [usize; 3],
    /// Blocks per axis of the table.
    dims: [usize; 3],
    /// Slot of every block of the table, [`ABSENT`] if it is not stored.
    table: Vec<u32>,
    /// Block coordinates (of the grid) of every slot, in slot order.
    blocks: Vec<[u32; 3]>,
    /// The marking pass's flags, one per block of the table.
    marks: Vec<AtomicU8>,
}

impl Clone for BlockMap {
    fn clone(&self) -> Self {
        Self {
            lo: self.lo,
            dims: self.dims,
            table: self.table.clone(),
            blocks: self.blocks.clone(),
            marks: self.marks.iter().map(|m| AtomicU8::new(m.load(Ordering::Relaxed))).collect(),
        }
    }
}

/// The blocks along one axis that hold nodes `c` and `c + 1` of a cell's first node `c`.
#[inline(always)]
fn axis_blocks(c: usize, d: usize) -> (usize, usize) {
    (c >> SHIFT[d], (c + 1) >> SHIFT[d])
}

impl BlockMap {
    /// Store the blocks that the cells of the particles at `x` touch on `geom` (the cell of
    /// each is [`GridGeom::shape_cell`]'s), numbered in table order. Parallel over the
    /// particles; no allocation once the table and slot list have reached their largest
    /// sizes.
    pub fn build(&mut self, exec: &Exec<'_>, geom: &GridGeom, x: &[Vec3]) {
        let nodes = geom.node_dims();
        self.lo = [0; 3];
        self.dims = std::array::from_fn(|d| nodes[d].div_ceil(BLOCK[d]));
        let len = self.dims.iter().product();
        if self.marks.len() < len {
            self.marks.resize_with(len, || AtomicU8::new(0));
        }
        for m in &mut self.marks[..len] {
            *m.get_mut() = 0;
        }
        let (n, t) = (x.len(), exec.workers());
        let (marks, dims) = (&self.marks[..len], self.dims);
        let cells = geom.cells;
        let tally = crate::work::Tally::of(exec);
        exec.run(|w| {
            tally.particles(w, partition(n, t, w).len());
            // Neighbouring particles often share a cell: skip a repeat. (Compared as one
            // linear index: comparing the arrays went through the stack and stalled.)
            let mut last = usize::MAX;
            for p in partition(n, t, w) {
                let c = geom.shape_cell(x[p]);
                let key = c[0] + cells[0] * (c[1] + cells[1] * c[2]);
                if key == last {
                    continue;
                }
                last = key;
                let (bx, by, bz) = (axis_blocks(c[0], 0), axis_blocks(c[1], 1), axis_blocks(c[2], 2));
                for k in [bz.0, bz.1] {
                    for j in [by.0, by.1] {
                        for i in [bx.0, bx.1] {
                            // Relaxed is enough: the flags are read after the phase's
                            // barrier, and every writer writes the same value.
                            let m = &marks[i + dims[0] * (j + dims[1] * k)];
                            if m.load(Ordering::Relaxed) == 0 {
                                m.store(1, Ordering::Relaxed);
                            }
                        }
                    }
                }
            }
        });
        self.table.clear();
        self.table.resize(len, ABSENT);
        self.blocks.clear();
        let mut slot = 0u32;
        for b in 0..len {
            if *self.marks[b].get_mut() != 0 {
                self.table[b] = slot;
                let at = self.coords(b);
                self.blocks.push(at);
                slot += 1;
            }
        }
    }

    /// This map restricted to the blocks that meet the node box `lo ..= hi` (grid node
    /// coordinates), numbered in `global`'s order: a DD patch's sub-grid.
    pub fn restrict(&mut self, global: &BlockMap, lo: [usize; 3], hi: [usize; 3]) {
        self.lo = std::array::from_fn(|d| lo[d] >> SHIFT[d]);
        self.dims = std::array::from_fn(|d| (hi[d] >> SHIFT[d]) + 1 - self.lo[d]);
        self.table.clear();
        self.table.resize(self.dims.iter().product(), ABSENT);
        self.blocks.clear();
        let mut slot = 0u32;
        for k in 0..self.dims[2] {
            for j in 0..self.dims[1] {
                for i in 0..self.dims[0] {
                    let g = [self.lo[0] + i, self.lo[1] + j, self.lo[2] + k];
                    if global.slot(g).is_some() {
                        self.table[i + self.dims[0] * (j + self.dims[1] * k)] = slot;
                        self.blocks.push(g.map(|v| v as u32));
                        slot += 1;
                    }
                }
            }
        }
    }

    /// Block coordinates of table entry `b`.
    fn coords(&self, b: usize) -> [u32; 3] {
        let (i, j, k) = (b % self.dims[0], (b / self.dims[0]) % self.dims[1], b / (self.dims[0] * self.dims[1]));
        [self.lo[0] + i, self.lo[1] + j, self.lo[2] + k].map(|v| v as u32)
    }

    /// Slot of the block at grid block coordinates `g`, if stored.
    pub fn slot(&self, g: [usize; 3]) -> Option<usize> {
        let mut b = 0;
        for d in (0..3).rev() {
            let l = g[d].checked_sub(self.lo[d]).filter(|&l| l < self.dims[d])?;
            b = b * self.dims[d] + l;
        }
        let s = self.table[b];
        (s != ABSENT).then_some(s as usize)
    }

    /// Stored blocks.
    pub fn len(&self) -> usize {
        self.blocks.len()
    }

    /// Whether no block is stored.
    pub fn is_empty(&self) -> bool {
        self.blocks.is_empty()
    }

    /// Stored nodes (`len() * BLOCK_NODES`): the length of the compact node arrays.
    pub fn num_nodes(&self) -> usize {
        self.blocks.len() * BLOCK_NODES
    }

    /// Block coordinates of slot `s`.
    #[inline(always)]
    pub fn block(&self, s: usize) -> [usize; 3] {
        self.blocks[s].map(|v| v as usize)
    }

    /// Compact indices of the 8 nodes of `cell` (the grid's cell numbering), in the order of
    /// [`crate::shape`]. The cell's blocks must be stored.
    ///
    /// Branch-free: 8 table look-ups, most of them of the same entry. (A separate path for
    /// cells inside one block, 27 of 64, cost more in mispredicted branches than it saved.)
    #[inline(always)]
    pub fn cell_nodes(&self, cell: [usize; 3]) -> [usize; 8] {
        const M: [usize; 3] = [BLOCK[0] - 1, BLOCK[1] - 1, BLOCK[2] - 1];
        let (sy, sz) = (self.dims[0], self.dims[0] * self.dims[1]);
        let b: [usize; 3] = std::array::from_fn(|d| (cell[d] >> SHIFT[d]) - self.lo[d]);
        let l: [usize; 3] = std::array::from_fn(|d| cell[d] & M[d]);
        let first = b[0] + sy * b[1] + sz * b[2];
        // Along an axis where the cell's first node is a block's last, its second node is
        // the next block's first.
        let next = [usize::from(l[0] == M[0]), sy * usize::from(l[1] == M[1]), sz * usize::from(l[2] == M[2])];
        let lx = [local(l[0], 0, 0), local((l[0] + 1) & M[0], 0, 0)];
        let ly = [local(0, l[1], 0), local(0, (l[1] + 1) & M[1], 0)];
        let lz = [local(0, 0, l[2]), local(0, 0, (l[2] + 1) & M[2])];
        std::array::from_fn(|q| {
            let (a, bb, c) = (q & 1, (q >> 1) & 1, q >> 2);
            let block = first + a * next[0] + bb * next[1] + c * next[2];
            self.table[block] as usize * BLOCK_NODES + lx[a] + ly[bb] + lz[c]
        })
    }

    /// A number that tells the cells of this map's blocks apart (one comparison instead of
    /// three; comparing the arrays went through the stack and stalled).
    #[inline(always)]
    pub fn cell_key(&self, cell: [usize; 3]) -> usize {
        let l: [usize; 3] = std::array::from_fn(|d| cell[d] - (self.lo[d] << SHIFT[d]));
        l[0] + (self.dims[0] << SHIFT[0]) * (l[1] + (self.dims[1] << SHIFT[1]) * l[2])
    }

    /// The node range of block `block` (block coordinates) along each axis, clipped to
    /// `lo ..= hi` (grid node coordinates), as block-local `start..end`; empty if the block
    /// does not meet the box.
    #[inline]
    pub fn node_ranges(block: [usize; 3], lo: [usize; 3], hi: [usize; 3]) -> [Range<usize>; 3] {
        std::array::from_fn(|d| {
            let first = block[d] * BLOCK[d];
            let start = lo[d].saturating_sub(first).min(BLOCK[d]);
            let end = (hi[d] + 1).saturating_sub(first).min(BLOCK[d]);
            start..end.max(start)
        })
    }

    /// The nodes of block `block` (block coordinates) that lie in the node box `lo ..= hi`
    /// (grid node coordinates), a row along x at a time: `f(first, locals)` with `first` the
    /// row's first node as an offset `[a, b, c]` from the block's first node and `locals`
    /// the row's block-local indices (consecutive).
    #[inline]
    pub fn rows_in(block: [usize; 3], lo: [usize; 3], hi: [usize; 3], mut f: impl FnMut([usize; 3], Range<usize>)) {
        let [ri, rj, rk] = Self::node_ranges(block, lo, hi);
        for c in rk {
            for b in rj.clone() {
                f([ri.start, b, c], local(ri.start, b, c)..local(ri.end, b, c));
            }
        }
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        capacity_bytes(&self.table) + capacity_bytes(&self.blocks) + capacity_bytes(&self.marks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::shape;

    fn grid(cells: [usize; 3]) -> GridGeom {
        GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells })
    }

    /// Particles in three far-apart clusters, one on block edges.
    fn clusters() -> Vec<Vec3> {
        let mut x = Vec::new();
        for (i, c) in [[1.5, 1.5, 1.5], [3.5, 7.5, 3.2], [17.9, 11.2, 22.6]].iter().enumerate() {
            for k in 0..20 {
                let f = k as f64 * 0.05;
                x.push([c[0] + f, c[1] - f * (i as f64), c[2] + 0.3 * f]);
            }
        }
        x
    }

    /// Every node of every particle's cell has a distinct compact index that names the same
    /// grid node as the dense numbering, in the same order; the blocks stored are exactly
    /// those such nodes lie in.
    #[test]
    fn cell_nodes_name_the_same_nodes_as_the_dense_grid() {
        let geom = grid([19, 13, 25]);
        let x = clusters();
        let mut map = BlockMap::default();
        map.build(&Exec::serial(), &geom, &x);
        let mut dense_of = vec![usize::MAX; map.num_nodes()];
        let mut touched = std::collections::BTreeSet::new();
        for &p in &x {
            let cell = geom.shape_cell(p);
            let dense = geom.cell_nodes(cell);
            let compact = map.cell_nodes(cell);
            for q in 0..8 {
                let n = geom.node_dims();
                let (i, j, k) = (dense[q] % n[0], (dense[q] / n[0]) % n[1], dense[q] / (n[0] * n[1]));
                let block = [i / BLOCK[0], j / BLOCK[1], k / BLOCK[2]];
                touched.insert(block);
                let s = map.slot(block).unwrap();
                assert_eq!(
                    compact[q],
                    s * BLOCK_NODES + i % BLOCK[0] + BLOCK[0] * (j % BLOCK[1] + BLOCK[1] * (k % BLOCK[2]))
                );
                assert!(dense_of[compact[q]] == usize::MAX || dense_of[compact[q]] == dense[q]);
                dense_of[compact[q]] = dense[q];
            }
        }
        assert_eq!(map.len(), touched.len(), "only the touched blocks are stored");
        // Slots are numbered in table order (x fastest).
        let listed: Vec<[usize; 3]> = (0..map.len()).map(|s| map.block(s)).collect();
        let mut want: Vec<[usize; 3]> = touched.into_iter().collect();
        want.sort_by_key(|b| [b[2], b[1], b[0]]);
        assert_eq!(listed, want);
        // The single-block fast path and the general path agree with the dense order.
        assert_eq!(shape::cell_nodes([4, 4, 4], [0, 0, 0]), map_of_one_block().cell_nodes([0, 0, 0]));
    }

    fn map_of_one_block() -> BlockMap {
        let mut map = BlockMap::default();
        map.build(&Exec::serial(), &grid([2, 2, 2]), &[[0.5; 3]]);
        map
    }

    /// The marks and numbering do not depend on the thread count.
    #[test]
    fn numbering_is_the_same_for_any_thread_count() {
        let geom = grid([19, 13, 25]);
        let x = clusters();
        let mut one = BlockMap::default();
        one.build(&Exec::serial(), &geom, &x);
        for threads in [2, 3, 5] {
            let team = crate::parallel::Team::new(crate::testing::pool(threads));
            let mut many = BlockMap::default();
            team.region(|exec| many.build(exec, &geom, &x)).unwrap();
            assert_eq!((many.table.clone(), many.blocks.clone()), (one.table.clone(), one.blocks.clone()));
        }
    }

    /// A restriction holds the stored blocks meeting the box, and indexes them like the
    /// global map does, shifted to its own slots.
    #[test]
    fn restriction_to_a_patch_keeps_the_blocks_it_meets() {
        let geom = grid([19, 13, 25]);
        let x = clusters();
        let mut global = BlockMap::default();
        global.build(&Exec::serial(), &geom, &x);
        let mut patch = BlockMap::default();
        let (lo, hi) = ([2, 0, 0], [19, 13, 12]);
        patch.restrict(&global, lo, hi);
        for s in 0..patch.len() {
            let b = patch.block(s);
            assert!(global.slot(b).is_some());
            assert!(BlockMap::node_ranges(b, lo, hi).iter().all(|r| !r.is_empty()));
        }
        let want = (0..global.len())
            .filter(|&s| BlockMap::node_ranges(global.block(s), lo, hi).iter().all(|r| !r.is_empty()))
            .count();
        assert_eq!(patch.len(), want);
        for &p in &x {
            let c = geom.shape_cell(p);
            if (0..3).all(|d| c[d] >= lo[d] && c[d] < hi[d]) {
                let (a, b) = (global.cell_nodes(c), patch.cell_nodes(c));
                for q in 0..8 {
                    assert_eq!(a[q] % BLOCK_NODES, b[q] % BLOCK_NODES);
                }
            }
        }
        assert_eq!(BlockMap::node_ranges([0, 1, 3], [2, 0, 0], [5, 13, 12]), [2..4, 0..4, 0..1]);
    }
}
