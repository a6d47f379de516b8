//! Each particle's cell and local coordinates in the step's grid, computed once a step.
//!
//! P2G, the fused gather and re-map, and the particle update all need each particle's cell
//! and its local coordinates `r` in it ([`crate::shape::local_coords`]); neither the grid
//! nor the positions change between P2G and the update's end (the update moves the
//! particles after it has read them). So [`Located::locate`] computes them once, before P2G,
//! in vector instructions over blocks of particles (split between the workers like the
//! update), and the three passes read them: the particle update's share of the step was
//! 14 % its own cell computation, lane by lane. The cells are kept as `u32` and the local
//! coordinates as `f64`, one array per axis each (a block of the update loads its local
//! coordinates as one vector an axis, and a block's cells convert to `u32` in one
//! instruction an axis). Every value is bitwise what the passes computed from the positions
//! before (`shape::local_coords`): the test `located_is_bitwise_local_coords` holds every
//! level to it.

use crate::grid::GridGeom;
use crate::math::Vec3;
use crate::parallel::{partition, Exec, Split};
use crate::shape::{self, local_coords, BlockShape, Local, Shape};
use crate::simd::{array, Block, SimdLevel, F4, F8, LANES, LANES8};

/// The cells and local coordinates of a step's particles (see the module).
#[derive(Clone, Debug, Default)]
pub struct Located {
    /// Particle `p`'s cell, one array per axis.
    cell: [Vec<u32>; 3],
    /// Particle `p`'s local coordinate in its cell, one array per axis.
    r: [Vec<f64>; 3],
}

impl Located {
    /// The particles at `x` located in `geom` on the calling thread, at the CPU's own SIMD
    /// level: for benchmarks and tests.
    pub fn of(geom: &GridGeom, x: &[Vec3]) -> Self {
        let mut located = Self::default();
        located.locate(&Exec::serial(), geom, x, SimdLevel::detected());
        located
    }

    /// Number of particles located.
    pub fn len(&self) -> usize {
        self.cell[0].len()
    }

    /// Bytes held.
    pub fn bytes(&self) -> usize {
        self.cell.iter().map(crate::capacity_bytes).sum::<usize>()
            + self.r.iter().map(crate::capacity_bytes).sum::<usize>()
    }

    /// Whether no particle is located.
    pub fn is_empty(&self) -> bool {
        self.cell[0].is_empty()
    }

    /// Locate the particles at `x` in `geom`: the work split between `exec`'s workers like
    /// the particle update's, at the level `simd` (which must be available on this CPU).
    /// The arrays keep their memory from step to step (they grow only when the particles
    /// do).
    pub fn locate(&mut self, exec: &Exec<'_>, geom: &GridGeom, x: &[Vec3], simd: SimdLevel) {
        assert!(simd.is_available(), "locating at SIMD level {simd}, which this CPU does not have");
        assert!(
            geom.cells.iter().all(|&c| c <= u32::MAX as usize),
            "a grid of {:?} cells: fewer than 2^32 cells an axis can be located",
            geom.cells
        );
        let n = x.len();
        for c in &mut self.cell {
            c.resize(n, 0);
        }
        for r in &mut self.r {
            r.resize(n, 0.0);
        }
        let ([cx, cy, cz], [rx, ry, rz]) = (&mut self.cell, &mut self.r);
        let t = exec.workers();
        let chunks = (
            Split::Even.of(cx),
            Split::Even.of(cy),
            Split::Even.of(cz),
            Split::Even.of(rx),
            Split::Even.of(ry),
            Split::Even.of(rz),
        );
        exec.for_each_chunk_mut(chunks, |w, (cx, cy, cz, rx, ry, rz)| {
            let mut out = Out { cell: [cx, cy, cz], r: [rx, ry, rz] };
            let x = &x[partition(n, t, w)];
            #[cfg(target_arch = "x86_64")]
            if simd >= SimdLevel::Avx2 {
                // SAFETY: `locate_avx2` and `locate_avx512` are compiled with AVX2, resp.
                // AVX-512F, enabled, and `simd.is_available()` was asserted above (through
                // `is_x86_feature_detected!`). The test `located_is_bitwise_local_coords`
                // runs every level the CPU has.
                unsafe {
                    if simd == SimdLevel::Avx512 {
                        locate_avx512(geom, x, &mut out);
                    } else {
                        locate_avx2(geom, x, &mut out);
                    }
                }
                return;
            }
            for (p, &xp) in x.iter().enumerate() {
                out.locate_one(p, xp, geom);
            }
        });
    }

    /// Particle `p`'s cell.
    #[inline(always)]
    pub fn cell(&self, p: usize) -> [usize; 3] {
        [self.cell[0][p] as usize, self.cell[1][p] as usize, self.cell[2][p] as usize]
    }

    /// Particle `p`'s local coordinates.
    #[inline(always)]
    pub fn r(&self, p: usize) -> Vec3 {
        [self.r[0][p], self.r[1][p], self.r[2][p]]
    }

    /// Particle `p`'s shape functions in a grid of cells `1 / inv_dx` wide (bitwise
    /// [`GridGeom::shape`] of its position).
    #[inline(always)]
    pub fn shape(&self, p: usize, inv_dx: f64) -> Shape {
        shape::at(self.cell(p), self.r(p), inv_dx)
    }

    /// The local coordinates of the particles `k[0], .., k[N - 1]` as vectors, lane `l`
    /// particle `k[l]` (one load per axis where `k[l] = k[0] + l`).
    #[inline(always)]
    fn r_block<R: Block<N>, const N: usize>(&self, k: &[usize; N]) -> [R; 3] {
        let contiguous = (1..N).all(|l| k[l] == k[0] + l);
        array(|d| {
            let r = &self.r[d];
            if contiguous {
                R::from_array(r[k[0]..k[0] + N].try_into().expect("N values"))
            } else {
                R::from_lanes(|l| r[k[l]])
            }
        })
    }

    /// [`Located::shape`] of the particles `k[0], .., k[N - 1]` at once, a lane each
    /// ([`shape::block_at`]).
    #[inline(always)]
    pub fn shape_block<R: Block<N>, const N: usize>(&self, k: &[usize; N], inv_dx: f64) -> BlockShape<R, N> {
        shape::block_at(array(|l| self.cell(k[l])), self.r_block(k), inv_dx)
    }

    /// The cells and [`Local`] coordinates of the particles `k[0], .., k[N - 1]`, a lane each
    /// ([`shape::local_at`]).
    #[inline(always)]
    pub fn local_block<R: Block<N>, const N: usize>(&self, k: &[usize; N], inv_dx: f64) -> ([[u32; 3]; N], Local<R>) {
        let cell = array(|l| [self.cell[0][k[l]], self.cell[1][k[l]], self.cell[2][k[l]]]);
        (cell, shape::local_at(self.r_block(k), inv_dx))
    }
}

/// 2^52: the `f64` whose last mantissa bit is 1.
const TWO_52: f64 = 4_503_599_627_370_496.0;

/// One worker's part of the arrays.
struct Out<'a> {
    cell: [&'a mut [u32]; 3],
    r: [&'a mut [f64]; 3],
}

impl Out<'_> {
    /// Particle `p` at `x`, one at a time ([`local_coords`]): the baseline level's pass and
    /// the blocks' remainder.
    #[inline(always)]
    fn locate_one(&mut self, p: usize, x: Vec3, geom: &GridGeom) {
        let (cell, r) = local_coords(x, geom.origin, geom.inv_dx, geom.cells);
        for d in 0..3 {
            self.cell[d][p] = cell[d] as u32;
            self.r[d][p] = r[d];
        }
    }
}

/// [`locate_blocks`] in blocks of 4 compiled for AVX2.
///
/// # Safety
/// The CPU must execute AVX2 (`SimdLevel::Avx2.is_available()`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn locate_avx2(geom: &GridGeom, x: &[Vec3], out: &mut Out<'_>) {
    locate_blocks::<F4, LANES>(geom, x, out);
}

/// [`locate_blocks`] in blocks of 8 compiled for AVX-512F.
///
/// # Safety
/// The CPU must execute AVX-512F (`SimdLevel::Avx512.is_available()`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f,avx2")]
unsafe fn locate_avx512(geom: &GridGeom, x: &[Vec3], out: &mut Out<'_>) {
    locate_blocks::<F8, LANES8>(geom, x, out);
}

/// The particles at `x` in blocks of `N` ([`shape::local_coords_block`]), the last few one
/// at a time.
#[inline(always)]
fn locate_blocks<R: Block<N>, const N: usize>(geom: &GridGeom, x: &[Vec3], out: &mut Out<'_>) {
    let n = x.len();
    let mut start = 0;
    while start + N <= n {
        let (cell, r) = shape::local_coords_block::<R, N>(|l| x[start + l], geom.origin, geom.inv_dx, geom.cells);
        for d in 0..3 {
            out.r[d][start..start + N].copy_from_slice(&r[d].to_array());
            // A whole number `c` below 2^32 as `u32`: the low bits of `c + 2^52`, whose
            // mantissa holds `c` exactly (vector additions and a narrowing; `as u32` is a
            // saturating conversion, which the compiler left lane by lane).
            let c = (cell[d] + R::splat(TWO_52)).to_array();
            let to = &mut out.cell[d][start..start + N];
            for l in 0..N {
                to[l] = c[l].to_bits() as u32;
            }
        }
        start += N;
    }
    for p in start..n {
        out.locate_one(p, x[p], geom);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::parallel::Team;

    /// Every level's cells and local coordinates are bitwise `shape::local_coords`' for
    /// points inside the grid, on cell faces, at `-0`, clamped from outside it on every side,
    /// and NaN, in chunks of every length (the blocks and the one-at-a-time rest), on 1 and
    /// 2 workers.
    #[test]
    fn located_is_bitwise_local_coords() {
        let geom = GridGeom::fixed(&GridSpec { anchor: [-0.3, 0.0, 2.0], dx: 1.0 / 7.0, cells: [5, 6, 9] });
        let mut unit = crate::testing::unit_stream(11);
        let mut x: Vec<Vec3> = (0..301)
            .map(|_| {
                std::array::from_fn(|d| geom.origin[d] + (geom.cells[d] as f64 + 2.0) * unit() * geom.dx - geom.dx)
            })
            .collect();
        // On faces (r = 0), at -0 (origin 0 on y), far outside, NaN.
        x.push([geom.origin[0] + 2.0 * geom.dx, -0.0, geom.origin[2] + 9.0 * geom.dx]);
        x.push([geom.origin[0] + geom.dx, -0.0, geom.origin[2]]);
        x.push([1e300, -1e300, f64::INFINITY]);
        x.push([f64::NAN, f64::NEG_INFINITY, 2f64.powi(64)]);
        x.rotate_right(4);
        for simd in SimdLevel::ALL.into_iter().filter(|s| s.is_available()) {
            for workers in [1, 2] {
                let team = Team::new(crate::testing::pool(workers));
                for len in [0, 1, 3, 4, 7, 8, 9, 17, x.len()] {
                    let mut located = Located::default();
                    team.region(|exec| located.locate(exec, &geom, &x[..len], simd)).unwrap();
                    assert_eq!(located.len(), len);
                    for (p, &xp) in x[..len].iter().enumerate() {
                        let (cell, r) = local_coords(xp, geom.origin, geom.inv_dx, geom.cells);
                        assert_eq!(located.cell(p), cell, "cell of {p} at {xp:?}, {simd}, {workers} workers");
                        let got = located.r(p).map(f64::to_bits);
                        assert_eq!(got, r.map(f64::to_bits), "r of {p} at {xp:?}, {simd}, {workers} workers");
                    }
                }
            }
        }
    }
}
