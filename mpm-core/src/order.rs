//! Particles kept in cell order: every few steps the particle arrays are sorted by the cell
//! each particle lies in, cells in Morton order (x the most significant axis), particles of
//! one cell in their previous order. Morton order of the cells is Morton order of the blocks
//! of 4^3 cells (the key's high bits) with each block's cells in Morton order (its low six),
//! the cells counted on the lattice of those blocks.
//!
//! Why: the scatters and the particle update read and write the 8 nodes of each particle's
//! cell. Neighbouring particles in memory then touch neighbouring nodes, so the node records
//! a block of particles needs stay in the caches while it goes through, and the repeated
//! cell look-ups of [`crate::node_index::CellNodes`] hit; and the particles of one cell are
//! neighbours in memory, so the particle update reads a run of them's 8 node records once
//! (`transfer::update`). The particles start in the order their
//! scenario made them (layer by layer); the debris of an impact mixes that order within tens
//! of steps.
//!
//! The sort is a function of the positions alone: the same positions give the same order
//! whatever the strategy and thread count, so the equivalence of the strategies is kept.
//! Blocks are counted on the anchor's lattice ([`GridGeom::start`]), so a refitted adaptive
//! grid does not move them. The permutation goes to the run's [`Exchange`], which keeps the
//! particles' global ids (index in the initial set) for dumps and for the scenarios'
//! figures that tell particles apart by id.
//!
//! It runs before a step, in the simulation's rayon pool (`install`), on its threads: keys,
//! sort (`par_sort_unstable` on unique keys: the result does not depend on the schedule),
//! then the arrays gathered component by component through one `f64` buffer. Its memory is
//! 16 bytes per particle (keys and that buffer), allocated at the first sort and kept. A key
//! is one `u64`: the particle's index in its low bits (as many as the count needs) and the
//! cell's Morton code above it, with as many bits per axis as are left (21 at most; 14 for a
//! million particles, 10 at the 2^32 particles a process may hold).

use crate::exchange::Exchange;
use crate::grid::GridGeom;
use crate::particles::Particles;
use crate::shape;
use rayon::prelude::*;

/// Default [`crate::SimConfig::sort_every`]: sort the particles before every 20th step
/// (and before the first).
pub const SORT_EVERY: u64 = 20;

/// Cells per block edge of the sort key (the sparse grid's blocks, [`crate::blocks`]): the
/// cells are counted from the first block of the anchor's lattice at or below the grid.
const BLOCK_CELLS: i64 = 4;

/// The most bits per axis of a cell coordinate in a key (3 x 21 = 63).
const MAX_AXIS_BITS: u32 = 21;

/// How a key of `n` particles splits its 64 bits: `(index bits, bits per axis)`. Cells
/// beyond `2^(bits per axis)` along an axis are clamped to the last (the order stays valid,
/// only less local there).
fn key_bits(n: usize) -> (u32, u32) {
    let index = (usize::BITS - n.saturating_sub(1).leading_zeros()).max(1);
    (index, ((64 - index) / 3).min(MAX_AXIS_BITS))
}

/// The sort's buffers, kept between sorts.
#[derive(Debug, Default)]
pub(crate) struct CellOrder {
    /// `key << 32 | index` per particle; after the sort, the old index of each new position.
    keys: Vec<u64>,
    /// One component of one particle array, gathered.
    scratch: Vec<f64>,
}

impl CellOrder {
    /// Bytes held.
    pub fn bytes(&self) -> usize {
        crate::capacity_bytes(&self.keys) + crate::capacity_bytes(&self.scratch)
    }

    /// Sort `particles` into cell order on `geom` (the grid of the last step: a particle
    /// outside it counts in its nearest cell) and tell `exchange` the permutation. Returns
    /// whether anything moved. Runs on the current rayon pool.
    pub fn sort(&mut self, geom: &GridGeom, particles: &mut Particles, exchange: &mut dyn Exchange) -> bool {
        let n = particles.len();
        assert!(
            n <= u32::MAX as usize,
            "the cell order packs particle indices in 32 bits: at most 2^32 particles a process"
        );
        // Both buffers at once, so that only the first sort allocates.
        self.keys.resize(n, 0);
        self.scratch.resize(n, 0.0);
        let x = &particles.x;
        let (index_bits, axis_bits) = key_bits(n);
        self.keys.par_iter_mut().enumerate().with_min_len(4096).for_each(|(i, k)| {
            *k = (cell_key(geom, x[i], axis_bits) << index_bits) | i as u64;
        });
        self.keys.par_sort_unstable();
        let order = &mut self.keys;
        let index_mask = (1u64 << index_bits) - 1;
        order.par_iter_mut().with_min_len(4096).for_each(|k| *k &= index_mask);
        if order.par_iter().enumerate().all(|(i, &k)| k == i as u64) {
            return false;
        }
        let Particles { x, v, mass, rho, stress, eps_p, e_int, sound, failed } = particles;
        gather(x, order, &mut self.scratch);
        gather(v, order, &mut self.scratch);
        gather(bytemuck::cast_slice_mut::<f64, [f64; 1]>(mass), order, &mut self.scratch);
        gather(bytemuck::cast_slice_mut::<f64, [f64; 1]>(rho), order, &mut self.scratch);
        gather(stress, order, &mut self.scratch);
        gather(bytemuck::cast_slice_mut::<f64, [f64; 1]>(eps_p), order, &mut self.scratch);
        gather(bytemuck::cast_slice_mut::<f64, [f64; 1]>(e_int), order, &mut self.scratch);
        gather(bytemuck::cast_slice_mut::<f64, [f64; 1]>(sound), order, &mut self.scratch);
        let scratch = &mut self.scratch;
        scratch.par_iter_mut().zip(order.par_iter()).with_min_len(4096).for_each(|(s, &o)| {
            *s = if failed[o as usize] { 1.0 } else { 0.0 };
        });
        failed.par_iter_mut().zip(scratch.par_iter()).with_min_len(4096).for_each(|(f, &s)| *f = s != 0.0);
        exchange.reorder(order);
        true
    }
}

/// `data[i] = old data[order[i]]`, one component at a time through `scratch`.
fn gather<const K: usize>(data: &mut [[f64; K]], order: &[u64], scratch: &mut [f64]) {
    for c in 0..K {
        scratch.par_iter_mut().zip(order.par_iter()).with_min_len(4096).for_each(|(s, &o)| *s = data[o as usize][c]);
        data.par_iter_mut().zip(scratch.par_iter()).with_min_len(4096).for_each(|(d, &s)| d[c] = s);
    }
}

/// The Morton code, `bits` bits per axis, of the cell of `geom` holding `x` (x's bits the
/// most significant of each triple), the cells counted on the lattice of the blocks of
/// [`BLOCK_CELLS`]^3 cells: its top bits are the block's Morton code, its low six the cell's
/// in the block.
fn cell_key(geom: &GridGeom, x: crate::math::Vec3, bits: u32) -> u64 {
    let cell = shape::cell_of(x, geom.origin, geom.inv_dx, geom.cells);
    let max = (1i64 << bits) - 1;
    let c: [u64; 3] = std::array::from_fn(|d| {
        let first = geom.start[d].div_euclid(BLOCK_CELLS) * BLOCK_CELLS;
        (geom.start[d] + cell[d] as i64 - first).clamp(0, max) as u64
    });
    spread(c[0], bits) << 2 | spread(c[1], bits) << 1 | spread(c[2], bits)
}

/// The low `bits` bits of `v` (at most [`MAX_AXIS_BITS`]) spread to every third bit: bit
/// `i` to bit `3 i`, by five shift-or-mask steps instead of one step per bit (the bit by bit
/// loop was half the cost of the keys).
fn spread(v: u64, bits: u32) -> u64 {
    debug_assert!(bits <= MAX_AXIS_BITS);
    let mut x = v & ((1u64 << bits) - 1);
    x = (x | x << 32) & 0x001f_0000_0000_ffff;
    x = (x | x << 16) & 0x001f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    x = (x | x << 2) & 0x1249_2492_4924_9249;
    x
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::exchange::OneProcess;
    use crate::grid::GridSpec;

    fn particles(xs: &[[f64; 3]]) -> Particles {
        let mut p = Particles::default();
        for (i, &x) in xs.iter().enumerate() {
            let f = i as f64;
            p.push(x, [f, -f, 2.0 * f], 1.0 + f, 1000.0 + f, 10.0 + f);
            p.stress[i] = [f, 2.0 * f, 3.0 * f, 4.0 * f, 5.0 * f, 6.0 * f];
            p.eps_p[i] = 0.5 * f;
            p.e_int[i] = 7.0 * f;
            p.failed[i] = i % 3 == 0;
        }
        p
    }

    #[test]
    fn morton_code_of_cells_interleaves_x_first() {
        assert_eq!(spread(0b101, 3), 0b001_000_001);
        assert_eq!(spread(0b111, 2), 0b001_001, "only the asked bits");
        // Against the definition (bit i to bit 3 i), bit by bit.
        let by_bits = |v: u64, bits: u32| (0..bits).fold(0, |out, b| out | (v >> b & 1) << (3 * b));
        let mut unit = crate::testing::unit_stream(5);
        let values = (0..4096).chain((0..2000).map(|_| (unit() * f64::from(1u32 << 21)) as u64)).chain([(1 << 21) - 1]);
        for v in values {
            for bits in [1, 10, 16, 21] {
                assert_eq!(spread(v, bits), by_bits(v, bits), "v = {v:#b}, {bits} bits");
            }
        }
        let spec = GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [16, 16, 16] };
        let g = GridGeom::fixed(&spec);
        let key = |x| cell_key(&g, x, 10);
        assert_eq!(key([0.5, 0.5, 0.5]), 0);
        assert_eq!(key([0.5, 0.5, 1.5]), 0b001);
        assert_eq!(key([0.5, 1.5, 0.5]), 0b010);
        assert_eq!(key([1.5, 0.5, 0.5]), 0b100);
        assert_eq!(key([3.9, 3.9, 3.9]), 0b111_111, "the last cell of the first block of 4^3");
        assert_eq!(key([4.5, 0.5, 0.5]), 0b100_000_000, "the next block's first cell after it");
        assert_eq!(key([0.5, 4.5, 0.5]), 0b010_000_000);
        assert_eq!(key([0.5, 0.5, 4.5]), 0b001_000_000);
        assert_eq!(key([-5.0, 0.5, 99.0]), 0b001_001_001_001, "outside: the nearest cell (0, 0, 15)");
        assert_eq!(cell_key(&g, [0.5, 0.5, 99.0], 2), 0b001_001, "beyond 2^bits cells: the last");
        // A grid starting off the blocks' lattice counts its cells from the block below.
        let shifted = GridGeom { start: [2, 0, 0], ..g };
        assert_eq!(cell_key(&shifted, [1.5, 0.5, 0.5], 10), 0b001_001 << 2, "cell 1 is lattice cell 3");
    }

    #[test]
    fn key_keeps_every_index_and_at_most_21_bits_per_axis() {
        assert_eq!(key_bits(0), (1, 21));
        assert_eq!(key_bits(1), (1, 21));
        assert_eq!(key_bits(2), (1, 21));
        assert_eq!(key_bits(3), (2, 20));
        assert_eq!(key_bits(56_056), (16, 16));
        assert_eq!(key_bits(1 << 20), (20, 14));
        assert_eq!(key_bits((1 << 20) + 1), (21, 14));
        assert_eq!(key_bits(1 << 32), (32, 10));
    }

    /// Every particle's whole state moves with it, cells come out in Morton order and
    /// particles of one cell keep their order; the exchange learns the permutation.
    #[test]
    fn sort_moves_whole_particles_into_cell_order() {
        let xs = [[4.5, 0.5, 0.5], [0.5, 4.5, 0.5], [0.5, 0.5, 0.5], [4.6, 0.4, 0.4], [1.5, 1.5, 1.5], [0.5, 0.5, 4.5]];
        let before = particles(&xs);
        let mut p = before.clone();
        let g = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [16, 16, 16] });
        let mut ex = OneProcess::default();
        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        let mut order = CellOrder::default();
        assert!(pool.install(|| order.sort(&g, &mut p, &mut ex)));
        let want = [2, 4, 5, 1, 0, 3];
        for (i, &o) in want.iter().enumerate() {
            assert_eq!(p.x[i], before.x[o]);
            assert_eq!(p.v[i], before.v[o]);
            assert_eq!(p.mass[i], before.mass[o]);
            assert_eq!(p.rho[i], before.rho[o]);
            assert_eq!(p.stress[i], before.stress[o]);
            assert_eq!(p.eps_p[i], before.eps_p[o]);
            assert_eq!(p.e_int[i], before.e_int[o]);
            assert_eq!(p.sound[i], before.sound[o]);
            assert_eq!(p.failed[i], before.failed[o]);
            assert_eq!(ex.global_id(i), o as u64);
        }
        // Sorted already: nothing moves, the ids stay.
        assert!(!pool.install(|| order.sort(&g, &mut p, &mut ex)));
        assert_eq!((0..6).map(|i| ex.global_id(i)).collect::<Vec<_>>(), want.map(|o| o as u64));
        // Moved again: the ids compose. The particle now at (0.5, 0.5, 0.5) goes first, ahead of
        // (1.5, 1.5, 1.5) in the same block (a block order would have kept them as they were).
        p.x.swap(0, 5);
        assert!(pool.install(|| order.sort(&g, &mut p, &mut ex)));
        assert_eq!((0..6).map(|i| ex.global_id(i)).collect::<Vec<_>>(), [3, 4, 5, 1, 2, 0]);
        assert_eq!((p.v[0], p.v[1]), (before.v[3], before.v[4]), "the velocity stays with the particle");
    }
}
