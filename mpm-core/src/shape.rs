//! Trilinear (8-node hexahedral) shape functions `S_ip = N_i(x_p)` and their gradients
//! `G_ip = grad N_i(x_p)` on a regular grid of cubic cells (paper Section 1).
//!
//! A particle influences the 8 nodes of the cell that contains it. Node `q` of a cell,
//! `q = a + 2 b + 4 c` with `a, b, c` in `{0, 1}`, is the node at offset `(a, b, c)` from
//! the cell's lowest corner. Every scatter and gather in the crate uses this order.

use crate::math::Vec3;
use crate::simd::{array, Block, Real};

/// Shape function values and gradients of one particle at its 8 cell nodes.
#[derive(Clone, Copy, Debug)]
pub struct Shape {
    /// Cell index `(i, j, k)` in the grid's own cell numbering.
    pub cell: [usize; 3],
    /// `S_ip` for the 8 nodes (sums to 1).
    pub w: [f64; 8],
    /// `G_ip` for the 8 nodes (sums to 0).
    pub g: [Vec3; 8],
}

/// Evaluate the trilinear shape functions of the cell containing `x`.
///
/// `origin` is the grid's lowest corner, `inv_dx` the inverse cell size and `cells` the
/// cell counts. A point outside the grid is clamped into the nearest boundary cell (its
/// weights are then extrapolated); the solver checks containment separately, so this never
/// happens on a correct run.
#[inline(always)]
pub fn evaluate(x: Vec3, origin: Vec3, inv_dx: f64, cells: [usize; 3]) -> Shape {
    let (cell, r) = local_coords(x, origin, inv_dx, cells);
    at(cell, r, inv_dx)
}

/// The cell containing `x` (clamped as [`evaluate`] says) and the local coordinates `r` of
/// `x` in it per axis (`r = xi - cell`, `xi = (x - origin) / dx`): the first half of
/// [`evaluate`]. A step computes them once per particle ([`crate::locate`]).
#[inline(always)]
pub fn local_coords(x: Vec3, origin: Vec3, inv_dx: f64, cells: [usize; 3]) -> ([usize; 3], Vec3) {
    let mut cell = [0usize; 3];
    let mut r = [0.0; 3];
    for d in 0..3 {
        let xi = (x[d] - origin[d]) * inv_dx;
        let c = axis_cell(xi, cells[d]);
        cell[d] = c;
        r[d] = xi - cell_f64(c);
    }
    (cell, r)
}

/// The shape functions of the point at local coordinates `r` in `cell` (as
/// [`local_coords`] gives them): the second half of [`evaluate`], `n1 = r`, `n0 = 1 - r`.
#[inline(always)]
pub fn at(cell: [usize; 3], r: Vec3, inv_dx: f64) -> Shape {
    let (w, g) = weights(r.map(|r| 1.0 - r), r, inv_dx);
    Shape { cell, w, g }
}

/// The 8 weights and gradients from the local coordinates `n1 = r` and `n0 = 1 - r` per
/// axis: `S_q = N_a(r_x) N_b(r_y) N_c(r_z)`, `q = a + 2 b + 4 c`, and its gradient, each
/// product in the order written (so one point and a block's lanes get the same bits).
/// [`Local::node`] computes the same products for one node; a block evaluation built on it
/// made P2G 9-24 % slower (the loop below is unrolled, a loop over `q` was not), so the two
/// stay apart and the test `block_lanes_are_bitwise_the_one_point_evaluation` holds both to
/// [`evaluate`]'s bits.
#[inline(always)]
fn weights<R: Real>(n0: [R; 3], n1: [R; 3], inv_dx: f64) -> ([R; 8], [[R; 3]; 8]) {
    let grad = [R::splat(-inv_dx), R::splat(inv_dx)];
    let (nx, ny, nz) = ([n0[0], n1[0]], [n0[1], n1[1]], [n0[2], n1[2]]);
    let zero = R::splat(0.0);
    let mut w = [zero; 8];
    let mut g = [[zero; 3]; 8];
    for c in 0..2 {
        for b in 0..2 {
            for a in 0..2 {
                let q = a + 2 * b + 4 * c;
                let nyz = ny[b] * nz[c];
                w[q] = nx[a] * nyz;
                g[q] = [grad[a] * nyz, nx[a] * grad[b] * nz[c], nx[a] * ny[b] * grad[c]];
            }
        }
    }
    (w, g)
}

/// A block's coordinates in its cells, lane by lane: per axis the two linear factors
/// `[1 - r, r]`, and the two gradient factors `[-1/dx, 1/dx]` ([`local_at`]).
#[derive(Clone, Copy, Debug)]
pub struct Local<R> {
    n: [[R; 2]; 3],
    grad: [R; 2],
}

impl<R: Real> Local<R> {
    /// Node `q = a + 2 b + 4 c`'s weight `S_q` and gradient, with [`evaluate`]'s
    /// operations in its order (so each lane gets the bits [`evaluate`] gives its point).
    /// A loop over the nodes calls it at each node instead of keeping the 32 values of a
    /// [`BlockShape`]: the particle update's loop, where those went through the stack.
    #[inline(always)]
    pub fn node(&self, q: usize) -> (R, [R; 3]) {
        let (a, b, c) = (q & 1, (q >> 1) & 1, q >> 2);
        let [nx, ny, nz] = self.n;
        let nyz = ny[b] * nz[c];
        (nx[a] * nyz, [self.grad[a] * nyz, nx[a] * self.grad[b] * nz[c], nx[a] * ny[b] * self.grad[c]])
    }
}

/// The shape functions of a block of `N` particles at once ([`block_at`]): lane `l`
/// of every value is particle `l`'s.
#[derive(Clone, Copy, Debug)]
pub struct BlockShape<R, const N: usize> {
    /// Each particle's cell, as [`Shape::cell`].
    pub cell: [[usize; 3]; N],
    /// `S_ip` for the 8 nodes, a lane per particle.
    pub w: [R; 8],
    /// `G_ip` for the 8 nodes, a lane per particle.
    pub g: [[R; 3]; 8],
}

/// [`at`] for `N` points at once (lane `l` of `r` point `l`, in `cell[l]`): the weights and
/// gradients as vectors of `N` lanes, each lane computed with [`at`]'s operations in its
/// order, so lane `l` holds bitwise [`at`]`(cell[l], r(l))`'s values. The blocked P2G
/// evaluates its blocks so; the particle update takes [`local_at`] and [`Local::node`].
#[inline(always)]
pub fn block_at<R: Block<N>, const N: usize>(cell: [[usize; 3]; N], r: [R; 3], inv_dx: f64) -> BlockShape<R, N> {
    let one = R::splat(1.0);
    let n0: [R; 3] = array(|d| one - r[d]);
    let (w, g) = weights(n0, r, inv_dx);
    BlockShape { cell, w, g }
}

/// The [`Local`] coordinates of `N` points at the local coordinates `r`, a lane each, for a
/// loop that computes each node's weight where it uses it.
#[inline(always)]
pub fn local_at<R: Real>(r: [R; 3], inv_dx: f64) -> Local<R> {
    let one = R::splat(1.0);
    let n = [[one - r[0], r[0]], [one - r[1], r[1]], [one - r[2], r[2]]];
    Local { n, grad: [R::splat(-inv_dx), R::splat(inv_dx)] }
}

/// [`local_coords`] of `N` points at once, lane `l` point `x(l)`: each point's cell per axis
/// as a whole `f64` and its local coordinate, every value bitwise [`local_coords`]'s. The
/// cell is `min(floor(max(xi, 0)), cells - 1)` in vector instructions where
/// [`axis_cell`] takes `max(xi, 0)` through an integer conversion: the same whole number for
/// every `xi` (NaN: 0 both; below 2^63 the conversion truncates a non-negative number, its
/// floor; above, both end at `cells - 1`), exact in `f64` below 2^53 cells; at `xi = -0`
/// [`Real::max`] gives `+0` (its rule: `other` on a tie; `f64::max` leaves the sign open,
/// and a `-0` cell would flip the sign of `r = 0`: the tests hold it). Vector code only where the level has a rounding
/// instruction (AVX and up): on the baseline `floor` is a library call per lane, and
/// [`crate::locate`] takes [`local_coords`] there.
#[inline(always)]
pub(crate) fn local_coords_block<R: Block<N>, const N: usize>(
    x: impl Fn(usize) -> Vec3,
    origin: Vec3,
    inv_dx: f64,
    cells: [usize; 3],
) -> ([R; 3], [R; 3]) {
    let xi: [R; 3] = array(|d| (R::from_lanes(|l| x(l)[d]) - R::splat(origin[d])) * R::splat(inv_dx));
    let zero = R::splat(0.0);
    let cell: [R; 3] = array(|d| {
        let top = R::splat(cell_f64(cells[d] - 1));
        let c = xi[d].max(zero).floor();
        R::select(c.gt(top), top, c)
    });
    let r: [R; 3] = array(|d| xi[d] - cell[d]);
    (cell, r)
}

/// Indices of the 8 nodes of `cell` in a box of nodes numbered `i + dims[0] (j + dims[1] k)`
/// (`dims` nodes per axis, `cell` counted from the box's first cell), in the order
/// `q = a + 2 b + 4 c` of [`Shape`]. The one node-index rule of every scatter and gather.
#[inline(always)]
pub fn cell_nodes(dims: [usize; 3], cell: [usize; 3]) -> [usize; 8] {
    let (sy, sz) = (dims[0], dims[0] * dims[1]);
    let b = cell[0] + sy * cell[1] + sz * cell[2];
    [b, b + 1, b + sy, b + sy + 1, b + sz, b + sz + 1, b + sz + sy, b + sz + sy + 1]
}

/// Cell index along one axis of a point at `xi` cell widths from the origin (clamped).
///
/// `floor` without calling it: `max(0)` first (which also maps NaN to 0), then the cast
/// truncates a non-negative number, which is its floor (and saturates above `usize::MAX`).
/// The result equals `xi.floor().max(0.0) as usize` for every `xi`; the baseline x86-64
/// target has no rounding instruction, so `floor` was a libm call, four times a step
/// for every particle and axis (12 % of the instructions of a Taylor bar step). The cast
/// goes through `i64` (one conversion instruction and a saturation check; a direct cast to
/// `usize` also handles 2^63 to 2^64, in seven more): the two agree below 2^63, and above
/// it both reach `cells - 1` through the `min` (any grid has fewer than 2^63 cells).
#[inline(always)]
pub fn axis_cell(xi: f64, cells: usize) -> usize {
    (xi.max(0.0) as i64 as usize).min(cells - 1)
}

/// A cell index as `f64`, exactly `c as f64`: through `i64` (one conversion instruction;
/// from `usize` the compiler adds the unsigned case's five), as a cell index is below 2^63.
#[inline(always)]
fn cell_f64(c: usize) -> f64 {
    c as i64 as f64
}

/// The cell containing `x` (same clamping as [`evaluate`]).
#[inline(always)]
pub fn cell_of(x: Vec3, origin: Vec3, inv_dx: f64, cells: [usize; 3]) -> [usize; 3] {
    std::array::from_fn(|d| axis_cell((x[d] - origin[d]) * inv_dx, cells[d]))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn partition_of_unity_and_zero_gradient_sum() {
        let s = evaluate([0.37, 1.21, 2.05], [0.0; 3], 2.0, [4, 4, 8]);
        assert_eq!(s.cell, [0, 2, 4]);
        let sum: f64 = s.w.iter().sum();
        assert!((sum - 1.0).abs() < 1e-14);
        for d in 0..3 {
            let gs: f64 = s.g.iter().map(|g| g[d]).sum();
            assert!(gs.abs() < 1e-12);
        }
    }

    /// Every lane of a block evaluation (whole through `block_at`, and node by node through
    /// `local_at`) is bitwise the one-point evaluation of its point, and so are the block's
    /// cells and local coordinates (`local_coords_block`, the vector form of the cells), for
    /// points inside the grid, on cell faces, at `-0`, clamped from outside it and NaN, at 4
    /// and 8 lanes.
    #[test]
    fn block_lanes_are_bitwise_the_one_point_evaluation() {
        use crate::simd::{F4, F8};
        let (origin, inv_dx, cells) = ([-0.3, 0.0, 2.0], 7.0, [5, 6, 9]);
        let mut unit = crate::testing::unit_stream(7);
        // Inside, on the lattice (r = 0), and up to a cell outside on every side (clamped).
        let mut points: Vec<Vec3> = (0..200)
            .map(|_| std::array::from_fn(|d| origin[d] + (cells[d] as f64 + 2.0) * unit() / inv_dx - 1.0 / inv_dx))
            .collect();
        points.push([origin[0] + 2.0 / inv_dx, -0.0, origin[2] + 9.0 / inv_dx]);
        points.push([f64::NAN, 1e300, -f64::INFINITY]);
        fn check<R: Block<N>, const N: usize>(points: &[Vec3], origin: Vec3, inv_dx: f64, cells: [usize; 3]) {
            for chunk in points.chunks(N) {
                let x = |l: usize| chunk[l.min(chunk.len() - 1)];
                let (cell_f, r) = local_coords_block::<R, N>(x, origin, inv_dx, cells);
                let cell: [[usize; 3]; N] = std::array::from_fn(|l| local_coords(x(l), origin, inv_dx, cells).0);
                let b = block_at::<R, N>(cell, r, inv_dx);
                let local = local_at(r, inv_dx);
                for (l, &x) in chunk.iter().enumerate() {
                    let (one_cell, one_r) = local_coords(x, origin, inv_dx, cells);
                    for d in 0..3 {
                        assert_eq!(cell_f[d].lane(l), one_cell[d] as f64, "cell {d} of lane {l} at {x:?}");
                        assert_eq!(r[d].lane(l).to_bits(), one_r[d].to_bits(), "r {d} of lane {l} at {x:?}");
                    }
                    let one = evaluate(x, origin, inv_dx, cells);
                    assert_eq!(b.cell[l], one.cell, "cell of lane {l} at {x:?}");
                    for q in 0..8 {
                        let (w, g) = local.node(q);
                        assert_eq!(b.w[q].lane(l).to_bits(), one.w[q].to_bits(), "w[{q}] of lane {l} at {x:?}");
                        assert_eq!(w.lane(l).to_bits(), one.w[q].to_bits(), "node({q}) w of lane {l} at {x:?}");
                        for d in 0..3 {
                            let (got, want) = (b.g[q][d].lane(l), one.g[q][d]);
                            assert_eq!(got.to_bits(), want.to_bits(), "g[{q}][{d}] of lane {l} at {x:?}");
                            let got = g[d].lane(l);
                            assert_eq!(got.to_bits(), want.to_bits(), "node({q}) g[{d}] of lane {l} at {x:?}");
                        }
                    }
                }
            }
        }
        check::<F4, 4>(&points, origin, inv_dx, cells);
        if crate::simd::avx512_for_test("the 8-lane blocks") {
            check::<F8, 8>(&points, origin, inv_dx, cells);
        }
    }

    /// The cell along an axis is the floor clamped to the grid, for NaN, infinities,
    /// signed zeros, exact integers, the float just below one, and past 2^63 and 2^64.
    #[test]
    fn axis_cell_is_the_clamped_floor() {
        let below_one = 1.0 - f64::EPSILON / 2.0;
        let xs = [
            f64::NAN,
            f64::NEG_INFINITY,
            -1e300,
            -2.5,
            -0.0,
            0.0,
            below_one,
            1.0,
            3.999999,
            4.0,
            17.0,
            2f64.powi(62),
            2f64.powi(63),
            2f64.powi(64),
            1e300,
            f64::INFINITY,
        ];
        for cells in [1, 5, 1 << 40] {
            for x in xs {
                let want = if x.is_nan() { 0 } else { (x.floor().max(0.0) as usize).min(cells - 1) };
                assert_eq!(axis_cell(x, cells), want, "x = {x}, cells = {cells}");
            }
        }
    }

    /// Node `q` of a cell is the node at offset `(q & 1, (q >> 1) & 1, q >> 2)`.
    #[test]
    fn cell_nodes_follow_the_shape_function_order() {
        let dims = [4, 3, 5];
        let index = |n: [usize; 3]| n[0] + dims[0] * (n[1] + dims[1] * n[2]);
        for cell in [[0, 0, 0], [2, 1, 3], [1, 0, 2]] {
            let idx = cell_nodes(dims, cell);
            for (q, &i) in idx.iter().enumerate() {
                let off = [q & 1, (q >> 1) & 1, q >> 2];
                assert_eq!(i, index(std::array::from_fn(|d| cell[d] + off[d])), "cell {cell:?} node {q}");
            }
        }
    }

    #[test]
    fn reproduces_linear_fields_and_their_gradients() {
        // A linear field f(x) = 3 + 2x - y + 0.5z sampled at the nodes is interpolated
        // exactly and its gradient is recovered exactly.
        let f = |p: Vec3| 3.0 + 2.0 * p[0] - p[1] + 0.5 * p[2];
        let (origin, dx) = ([-1.0, -2.0, 0.5], 0.25);
        let x = [-0.83, -1.61, 1.17];
        let s = evaluate(x, origin, 1.0 / dx, [10, 10, 10]);
        let mut val = 0.0;
        let mut grad = [0.0; 3];
        for q in 0..8 {
            let off = [q & 1, (q >> 1) & 1, (q >> 2) & 1];
            let node: Vec3 = std::array::from_fn(|d| origin[d] + (s.cell[d] + off[d]) as f64 * dx);
            val += s.w[q] * f(node);
            for d in 0..3 {
                grad[d] += s.g[q][d] * f(node);
            }
        }
        assert!((val - f(x)).abs() < 1e-12);
        for (d, e) in [2.0, -1.0, 0.5].iter().enumerate() {
            assert!((grad[d] - e).abs() < 1e-11);
        }
    }
}
