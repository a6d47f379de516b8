//! Trilinear (8-node hexahedral) shape functions `S_ip = N_i(x_p)` and their gradients
//! `G_ip = grad N_i(x_p)` on a regular grid of cubic cells (paper Section 1).
//!
//! A particle influences the 8 nodes of the cell that contains it. Node `q` of a cell,
//! `q = a + 2 b + 4 c` with `a, b, c` in `{0, 1}`, is the node at offset `(a, b, c)` from
//! the cell's lowest corner. Every scatter and gather in the crate uses this order.

use crate::math::Vec3;

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
    let mut cell = [0usize; 3];
    let mut n0 = [0.0; 3];
    let mut n1 = [0.0; 3];
    for d in 0..3 {
        let xi = (x[d] - origin[d]) * inv_dx;
        let c = axis_cell(xi, cells[d]);
        let r = xi - c as f64;
        cell[d] = c;
        n0[d] = 1.0 - r;
        n1[d] = r;
    }
    let (gx, gy, gz) = (inv_dx, inv_dx, inv_dx);
    let nx = [n0[0], n1[0]];
    let ny = [n0[1], n1[1]];
    let nz = [n0[2], n1[2]];
    let dx = [-gx, gx];
    let dy = [-gy, gy];
    let dz = [-gz, gz];
    let mut w = [0.0; 8];
    let mut g = [[0.0; 3]; 8];
    for c in 0..2 {
        for b in 0..2 {
            for a in 0..2 {
                let q = a + 2 * b + 4 * c;
                let nyz = ny[b] * nz[c];
                w[q] = nx[a] * nyz;
                g[q] = [dx[a] * nyz, nx[a] * dy[b] * nz[c], nx[a] * ny[b] * dz[c]];
            }
        }
    }
    Shape { cell, w, g }
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
/// for every particle and axis (12 % of the instructions of a Taylor bar step).
#[inline(always)]
pub fn axis_cell(xi: f64, cells: usize) -> usize {
    (xi.max(0.0) as usize).min(cells - 1)
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
