//! The per-particle and per-node kernels of the MUSL step (Eqs. 1-15), shared by every
//! strategy, one module per phase:
//!
//! * [`p2g`]: the P2G scatter kernel (Eqs. 1-5), [`P2g`];
//! * [`nodes`]: the node passes, the grid update (Eq. 6, [`grid_update`]) and the re-map's
//!   velocities (Eq. 11, [`remap_velocity`]);
//! * [`gather_remap`]: the gather (Eqs. 8, 10) fused with the re-map scatter (Eq. 11);
//! * [`update`](mod@update): the particle update (Eqs. 7, 9, 12-15), [`update()`].
//!
//! The scatter kernels add what one particle gives its 8 nodes into the node records the
//! strategy hands them; the strategy decides which particles and which records. The other
//! passes are split across workers by loop splitting (particles) or by node rows (nodes),
//! through an [`Exec`](crate::parallel::Exec). This module holds what the scatter kernels
//! share: their loop over a strategy's particles, at the SIMD level asked for.
//!
//! They are public (the fused gather through [`gather_remap_serial`]) so that benchmarks
//! measure exactly the code the solver runs.

pub mod gather_remap;
pub mod nodes;
pub mod p2g;
pub mod update;

pub use gather_remap::gather_remap_serial;
pub(crate) use gather_remap::GatherRemap;
pub use nodes::{grid_update, remap_velocity};
pub use p2g::P2g;
pub use update::update;

use crate::simd::SimdLevel;
use crate::strategy::{Cursors, Target};

/// A scatter kernel's loop over a strategy's particles, which the kernel may run a block
/// of particles at a time ([`P2g`]: the shape functions of [`LANES`](crate::simd::LANES)
/// particles as vectors, [`Located::shape_block`](crate::locate::Located::shape_block), then
/// each particle's additions to its 8 nodes).
trait Blocked<const K: usize> {
    /// Add the values of the particles `ids`, in order, into `data`.
    fn blocks<D: Target<K> + ?Sized>(&self, ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut D);
}

/// The next block of at most `N` particles of `ids` and how many there are (0: none left);
/// the lanes past them repeat the last one (their values are computed and not used).
#[inline(always)]
fn next_block<const N: usize>(ids: &mut impl Iterator<Item = usize>) -> ([usize; N], usize) {
    let mut k = [0usize; N];
    let mut len = 0;
    while len < N {
        match ids.next() {
            Some(p) => {
                k[len] = p;
                len += 1;
            }
            None => break,
        }
    }
    if len > 0 {
        let last = k[len - 1];
        for slot in &mut k[len..] {
            *slot = last;
        }
    }
    (k, len)
}

/// `kernel`'s loop over the particles `ids` at the level `simd`: the copy of the loop compiled
/// for AVX2 where that is asked for, the baseline one otherwise. AVX-512 runs it at AVX2
/// (P2G has a kernel of its own there, [`P2g`]): the records are added 4 lanes at a time, and
/// the loop compiled for AVX-512F (the P2G shape functions in blocks of 8) took longer, P2G
/// 0.83 and the gather/re-map 1.12 of the 4407a32 code's time against 0.76 and 1.02 at AVX2
/// (medians of 8 alternated runs each).
#[inline(always)]
fn scatter_at<const K: usize, Kn: Blocked<K>, D: Target<K> + ?Sized>(
    kernel: &Kn,
    simd: SimdLevel,
    ids: impl Iterator<Item = usize>,
    nodes: &mut Cursors<'_>,
    data: &mut D,
) {
    #[cfg(target_arch = "x86_64")]
    if simd >= SimdLevel::Avx2 {
        assert!(SimdLevel::Avx2.is_available(), "AVX2 asked for on a CPU without it");
        // SAFETY: `scatter_avx2` is compiled with AVX2 enabled, and the line above has just
        // checked (through `is_x86_feature_detected!`) that this CPU executes AVX2. The test
        // `dispatch_levels_agree_bitwise` runs both levels.
        unsafe { scatter_avx2(kernel, ids, nodes, data) };
        return;
    }
    kernel.blocks(ids, nodes, data);
}

/// [`scatter_at`]'s loop compiled for AVX2.
///
/// # Safety
/// The CPU must execute AVX2 (`SimdLevel::Avx2.is_available()`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn scatter_avx2<const K: usize, Kn: Blocked<K>, D: Target<K> + ?Sized>(
    kernel: &Kn,
    ids: impl Iterator<Item = usize>,
    nodes: &mut Cursors<'_>,
    data: &mut D,
) {
    kernel.blocks(ids, nodes, data);
}

/// Inputs of the scatter kernels' tests.
#[cfg(test)]
mod testing {
    use crate::grid::GridGeom;
    use crate::particles::Particles;

    /// The scatter tests' 85 particles on `geom` (6 x 5 x 7 cells of 4/7, anchored at 0): 61
    /// spread at random in 3 x 2.5 x 3.5, then 8 in each of three cells; random velocities, masses,
    /// densities and stresses. And three id lists: out of order (a stride through the
    /// particles, as a DD column lists its ids), in cell order (`crate::order`'s runs), the
    /// three cells' runs alone.
    pub(super) fn scatter_inputs(geom: &GridGeom) -> (Particles, [Vec<usize>; 3]) {
        let mut unit = crate::testing::unit_stream(3);
        let (spread, n) = (61, 85);
        let mut pt = Particles::with_capacity(n);
        for _ in 0..spread {
            let x = [3.0 * unit(), 2.5 * unit(), 3.5 * unit()];
            pt.push(x, [unit() - 0.5, unit() - 0.5, unit() - 0.5], 0.1 + unit(), 7000.0 + 1000.0 * unit(), 4000.0);
        }
        for cell in [[1.0, 1.0, 1.0], [2.0, 3.0, 4.0], [5.0, 4.0, 6.0]] {
            for _ in 0..8 {
                let x = std::array::from_fn(|d| (cell[d] + 0.05 + 0.9 * unit()) * geom.dx);
                pt.push(x, [unit() - 0.5, unit() - 0.5, unit() - 0.5], 0.1 + unit(), 7000.0 + 1000.0 * unit(), 4000.0);
            }
        }
        for st in pt.stress.iter_mut() {
            *st = std::array::from_fn(|_| 1e8 * (unit() - 0.5));
        }
        let stride: Vec<usize> = (0..n).map(|i| (i * 19) % n).collect();
        let mut by_cell: Vec<usize> = (0..n).collect();
        by_cell.sort_by_key(|&p| {
            let c = geom.shape(pt.x[p]).cell;
            [c[2], c[1], c[0]]
        });
        let runs: Vec<usize> = (spread..n).collect();
        (pt, [stride, by_cell, runs])
    }
}
