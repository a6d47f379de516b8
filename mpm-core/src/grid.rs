//! The background grid: a regular Cartesian grid of cubic cells (paper Section 1), in one
//! of two modes (paper Section 4, "Load balance"):
//!
//! * [`GridMode::Fixed`]: the grid given by the scenario (for the Taylor bar exactly the
//!   cell and node counts of Table 2). A particle leaving it is an error.
//! * [`GridMode::Adaptive`]: every step the grid is re-fitted to the particles' current
//!   bounding box with the same cell size. Nodes stay on one lattice (anchored at the
//!   scenario's grid origin), so walls keep falling on node layers.
//! * [`GridMode::Sparse`]: the adaptive grid, storing only the blocks of nodes that the
//!   particles' cells touch ([`crate::blocks`]). Results are bitwise those of the adaptive
//!   grid for every strategy and thread count; memory follows the particles, not their box.
//!
//! Node arrays are contiguous: on a dense grid indexed `i + (nx+1) (j + (ny+1) k)`, on a
//! sparse one by block slot ([`NodeIndex`](crate::NodeIndex) says which). They only grow: a smaller grid reuses
//! the capacity, so steady-state steps do not allocate.

use crate::capacity_bytes;
use crate::math::Vec3;
use crate::shape::{self, Shape};
use serde::{Deserialize, Serialize};

/// Values per node of the P2G scatter (Eqs. 1-5): mass, momentum (3), force (3), and one
/// unused value that makes the record 64 bytes, one cache line ([`Records`]).
pub const P2G_WIDTH: usize = 8;
/// Values per node after the grid update (Eq. 6): velocity (3), acceleration (3).
pub const KIN_WIDTH: usize = 6;
/// Values per node of the MUSL re-map (Eq. 11): momentum (3), turned into velocity, and one
/// unused value, so that a record is one 4-lane vector (32 bytes, half a cache line).
pub const REMAP_WIDTH: usize = 4;

/// How the grid follows the particles.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum GridMode {
    /// The scenario's grid, unchanged.
    #[default]
    Fixed,
    /// Re-fitted to the particles' bounding box every step.
    Adaptive,
    /// Adaptive, storing only the blocks of nodes the particles touch.
    Sparse,
}

impl GridMode {
    /// Stable name (`fixed` / `adaptive`).
    pub fn name(self) -> &'static str {
        match self {
            GridMode::Fixed => "fixed",
            GridMode::Adaptive => "adaptive",
            GridMode::Sparse => "sparse",
        }
    }

    /// Whether the grid is re-fitted to the particles every step.
    pub fn is_adaptive(self) -> bool {
        match self {
            GridMode::Fixed => false,
            GridMode::Adaptive | GridMode::Sparse => true,
        }
    }
}

impl std::str::FromStr for GridMode {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "fixed" => Ok(GridMode::Fixed),
            "adaptive" => Ok(GridMode::Adaptive),
            "sparse" => Ok(GridMode::Sparse),
            _ => Err(format!("unknown grid mode '{s}': use 'fixed', 'adaptive' or 'sparse'")),
        }
    }
}

/// The grid a scenario asks for.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GridSpec {
    /// Cell size (m).
    pub dx: f64,
    /// A point of the node lattice (the fixed grid's lowest corner).
    pub anchor: Vec3,
    /// Cells of the fixed grid per axis, starting at `anchor`.
    pub cells: [usize; 3],
}

/// Geometry of the grid during one step.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GridGeom {
    /// Cell size (m).
    pub dx: f64,
    /// `1 / dx`.
    pub inv_dx: f64,
    /// Lowest corner (m).
    pub origin: Vec3,
    /// Cells per axis.
    pub cells: [usize; 3],
    /// Lattice index of node `(0, 0, 0)` relative to the anchor.
    pub start: [i64; 3],
}

impl GridGeom {
    /// The fixed grid of `spec`.
    pub fn fixed(spec: &GridSpec) -> Self {
        Self { dx: spec.dx, inv_dx: 1.0 / spec.dx, origin: spec.anchor, cells: spec.cells, start: [0; 3] }
    }

    /// The smallest grid on `spec`'s lattice whose cells contain every point of `[lo, hi]`.
    pub fn fit(spec: &GridSpec, lo: Vec3, hi: Vec3) -> Self {
        let inv = 1.0 / spec.dx;
        let mut start = [0i64; 3];
        let mut cells = [0usize; 3];
        let mut origin = [0.0; 3];
        for d in 0..3 {
            let s = ((lo[d] - spec.anchor[d]) * inv).floor() as i64;
            let e = ((hi[d] - spec.anchor[d]) * inv).floor() as i64 + 1;
            start[d] = s;
            cells[d] = (e - s).max(1) as usize;
            origin[d] = spec.anchor[d] + s as f64 * spec.dx;
        }
        Self { dx: spec.dx, inv_dx: inv, origin, cells, start }
    }

    /// Nodes per axis (`cells + 1`).
    pub fn node_dims(&self) -> [usize; 3] {
        [self.cells[0] + 1, self.cells[1] + 1, self.cells[2] + 1]
    }

    /// Number of nodes.
    pub fn num_nodes(&self) -> usize {
        let n = self.node_dims();
        n[0] * n[1] * n[2]
    }

    /// Number of cells.
    pub fn num_cells(&self) -> usize {
        self.cells[0] * self.cells[1] * self.cells[2]
    }

    /// Linear index of node `(i, j, k)`.
    #[inline(always)]
    pub fn node_index(&self, i: usize, j: usize, k: usize) -> usize {
        let n = self.node_dims();
        i + n[0] * (j + n[1] * k)
    }

    /// Global indices of the 8 nodes of `cell`, in shape-function order.
    #[inline(always)]
    pub fn cell_nodes(&self, cell: [usize; 3]) -> [usize; 8] {
        shape::cell_nodes(self.node_dims(), cell)
    }

    /// Position of node `(i, j, k)`.
    pub fn node_position(&self, i: usize, j: usize, k: usize) -> Vec3 {
        [self.origin[0] + i as f64 * self.dx, self.origin[1] + j as f64 * self.dx, self.origin[2] + k as f64 * self.dx]
    }

    /// Shape functions of the cell containing `x` (paper's `S_ip`, `G_ip`).
    #[inline(always)]
    pub fn shape(&self, x: Vec3) -> Shape {
        shape::evaluate(x, self.origin, self.inv_dx, self.cells)
    }

    /// The cell containing `x` (clamped like [`GridGeom::shape`]).
    #[inline(always)]
    pub fn shape_cell(&self, x: Vec3) -> [usize; 3] {
        shape::cell_of(x, self.origin, self.inv_dx, self.cells)
    }

    /// Whether `x` lies in a cell of this grid.
    #[inline(always)]
    pub fn contains(&self, x: Vec3) -> bool {
        (0..3).all(|d| {
            let xi = (x[d] - self.origin[d]) * self.inv_dx;
            xi >= 0.0 && xi < self.cells[d] as f64
        })
    }

    /// Node layer index along `axis` of the plane `axis = coord`, if it is a node layer of
    /// this grid.
    pub fn layer_of(&self, axis: usize, coord: f64) -> Option<usize> {
        let l = ((coord - self.origin[axis]) * self.inv_dx).round();
        let on_lattice = (self.origin[axis] + l * self.dx - coord).abs() <= 1e-9 * self.dx;
        (on_lattice && l >= 0.0 && l <= self.cells[axis] as f64).then_some(l as usize)
    }
}

/// The records of the 8 nodes `idx` in `data`, with one bounds check for the 8 (on the
/// largest index: each index is at most that, so the compiler drops the other 7).
#[inline(always)]
pub fn records<'a, T, const K: usize>(data: &'a [[T; K]], idx: &[usize; 8]) -> [&'a [T; K]; 8] {
    let top = idx.iter().fold(0, |m, &i| m.max(i));
    let data = &data[..=top];
    [
        &data[idx[0]],
        &data[idx[1]],
        &data[idx[2]],
        &data[idx[3]],
        &data[idx[4]],
        &data[idx[5]],
        &data[idx[6]],
        &data[idx[7]],
    ]
}

/// What a wall does to the nodes on it (paper Eq. 6: momentum and force are zeroed).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum WallKind {
    /// Frictionless: the normal component is zeroed.
    #[default]
    Slip,
    /// Sticking: every component is zeroed.
    Stick,
}

impl std::str::FromStr for WallKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "slip" | "frictionless" => Ok(WallKind::Slip),
            "stick" | "sticking" => Ok(WallKind::Stick),
            _ => Err(format!("unknown wall kind '{s}': use 'frictionless' or 'sticking'")),
        }
    }
}

/// A rigid planar wall `x[axis] = position`, acting on the node layer in that plane.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Wall {
    /// Normal axis (0, 1, 2).
    pub axis: usize,
    /// Plane coordinate (m); must lie on the grid lattice.
    pub position: f64,
    /// Slip or stick.
    pub kind: WallKind,
}

impl Wall {
    /// Component mask (1 = free, 0 = zeroed) of the nodes on the wall.
    pub fn mask(&self) -> Vec3 {
        match self.kind {
            WallKind::Stick => [0.0; 3],
            WallKind::Slip => {
                let mut m = [1.0; 3];
                m[self.axis] = 0.0;
                m
            }
        }
    }
}

/// The walls resolved to node layers of the current grid.
#[derive(Clone, Debug, Default)]
pub struct WallLayers {
    /// `(axis, layer, mask)` for every wall that meets the grid.
    layers: Vec<(usize, usize, Vec3)>,
}

impl WallLayers {
    /// Room for `n` walls.
    pub fn with_capacity(n: usize) -> Self {
        Self { layers: Vec::with_capacity(n) }
    }

    /// Resolve `walls` on `geom` (no allocation once capacity is reserved).
    pub fn resolve(&mut self, walls: &[Wall], geom: &GridGeom) {
        self.layers.clear();
        for w in walls {
            if let Some(l) = geom.layer_of(w.axis, w.position) {
                self.layers.push((w.axis, l, w.mask()));
            }
        }
    }

    /// Mask of the node row `(j, k)` from walls normal to y and z.
    #[inline]
    pub fn row_mask(&self, j: usize, k: usize) -> Vec3 {
        let mut m = [1.0; 3];
        for &(axis, l, mask) in &self.layers {
            if (axis == 1 && l == j) || (axis == 2 && l == k) {
                for d in 0..3 {
                    m[d] *= mask[d];
                }
            }
        }
        m
    }

    /// Walls normal to x: `(layer, mask)`.
    #[inline]
    pub fn x_layers(&self) -> impl Iterator<Item = (usize, Vec3)> + '_ {
        self.layers.iter().filter(|l| l.0 == 0).map(|l| (l.1, l.2))
    }

    /// Mask of node `i` in a row with mask `row`.
    #[inline(always)]
    pub fn node_mask(&self, row: Vec3, i: usize, has_x: bool) -> Vec3 {
        if !has_x {
            return row;
        }
        let mut m = row;
        for (l, mask) in self.x_layers() {
            if l == i {
                for d in 0..3 {
                    m[d] *= mask[d];
                }
            }
        }
        m
    }
}

/// Node records of `K` values, the array starting on a 64-byte boundary (a cache line), so
/// that an 8-value record (the P2G record) is exactly one cache line and never two. Reads
/// and writes as a slice of records (`Deref`). The storage is a `Vec<f64>` with up to 7
/// values of slack in front, viewed in whole records (`bytemuck::cast_slice`, checked):
/// no unsafe code here.
#[derive(Clone, Debug, Default)]
pub struct Records<const K: usize> {
    buf: Vec<f64>,
    /// Values of slack before the first record (where the 64-byte boundary is).
    off: usize,
    len: usize,
}

impl<const K: usize> Records<K> {
    /// `n` zeroed records.
    pub fn zeroed(n: usize) -> Self {
        let mut r = Self::default();
        r.resize(n);
        r
    }

    /// Resize to `n` records (new ones zero), keeping the values of the first ones. When the
    /// storage must grow, its capacity becomes `n` plus an eighth, not the doubling of
    /// `Vec::resize`: the node arrays of a growing debris cloud grow step after step, and
    /// doubling would leave up to half of their memory unused (the large impact model's
    /// budget is 3 GiB). They never shrink, so steady-state steps do not allocate.
    pub fn resize(&mut self, n: usize) {
        const SLACK: usize = 7;
        if n == 0 {
            // Nothing to hold (the serial strategy's scatter buffers): no allocation.
            self.len = 0;
            return;
        }
        if n * K + SLACK > self.buf.capacity() {
            let want = (n + n / 8) * K + SLACK;
            let mut buf = Vec::with_capacity(want);
            buf.resize(want, 0.0);
            let off = buf.as_ptr().align_offset(64).min(SLACK);
            let keep = self.len.min(n) * K;
            buf[off..off + keep].copy_from_slice(&self.buf[self.off..self.off + keep]);
            (self.buf, self.off) = (buf, off);
        } else if n > self.len {
            let end = self.off + n * K;
            if self.buf.len() < end {
                self.buf.resize(end, 0.0);
            }
            self.buf[self.off + self.len * K..end].fill(0.0);
        }
        self.len = n;
    }

    /// Bytes held (by capacity).
    pub fn bytes(&self) -> usize {
        capacity_bytes(&self.buf)
    }
}

impl<const K: usize> std::ops::Deref for Records<K> {
    type Target = [[f64; K]];
    fn deref(&self) -> &[[f64; K]] {
        bytemuck::cast_slice(&self.buf[self.off..self.off + self.len * K])
    }
}

impl<const K: usize> std::ops::DerefMut for Records<K> {
    fn deref_mut(&mut self) -> &mut [[f64; K]] {
        bytemuck::cast_slice_mut(&mut self.buf[self.off..self.off + self.len * K])
    }
}

/// Nodal arrays of the global grid.
#[derive(Clone, Debug, Default)]
pub struct NodeArrays {
    /// `[m, p_x, p_y, p_z, f_x, f_y, f_z, 0]` per node: the scatter of Eqs. 1-5, one cache
    /// line per node.
    pub p2g: Records<P2G_WIDTH>,
    /// `[v_x, v_y, v_z, a_x, a_y, a_z]` per node after Eq. 6: `v = p(k+1)/m`, `a = f/m`.
    /// After the re-map ([`crate::transfer::remap_velocity`]) the last three hold the
    /// mid-step velocity `(v_i(k) + v_i(k+1)) / 2` instead of `a`.
    pub kin: Records<KIN_WIDTH>,
    /// Re-mapped momentum of Eq. 11, turned into the re-mapped velocity in place (`[p, 0]`).
    pub remap: Records<REMAP_WIDTH>,
}

impl NodeArrays {
    /// Resize to `n` nodes, growing capacity only when needed (by an eighth more than
    /// needed).
    pub fn resize(&mut self, n: usize) {
        self.p2g.resize(n);
        self.kin.resize(n);
        self.remap.resize(n);
    }

    /// Bytes held (by capacity).
    pub fn bytes(&self) -> usize {
        self.p2g.bytes() + self.kin.bytes() + self.remap.bytes()
    }
}

/// Cells per axis of the blocks [`Occupancy`] counts.
pub const OCCUPANCY_BLOCK: usize = 8;

/// How much of a grid the particles occupy: the figure that says what a sparse (blocked)
/// grid would hold instead of the whole box. Measured outside the time step (it allocates
/// one bit per cell).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Occupancy {
    /// Cells of the grid.
    pub cells: u64,
    /// Cells holding at least one particle.
    pub occupied_cells: u64,
    /// Blocks of [`OCCUPANCY_BLOCK`]^3 cells (aligned on the grid's first cell) holding at
    /// least one particle.
    pub occupied_blocks: u64,
    /// Cells along an edge of those blocks.
    pub block_cells: u64,
}

impl Occupancy {
    /// The occupancy of `geom` by the particles at `x` (each counted in the cell
    /// [`GridGeom::shape_cell`] gives it).
    pub fn of(geom: &GridGeom, x: &[Vec3]) -> Self {
        let b = OCCUPANCY_BLOCK;
        let blocks_per_axis: [usize; 3] = std::array::from_fn(|d| geom.cells[d].div_ceil(b));
        let mut cells = vec![0u64; geom.num_cells().div_ceil(64)];
        let mut blocks = vec![0u64; (blocks_per_axis[0] * blocks_per_axis[1] * blocks_per_axis[2]).div_ceil(64)];
        let set = |bits: &mut [u64], i: usize| bits[i / 64] |= 1 << (i % 64);
        for &p in x {
            let c = geom.shape_cell(p);
            set(&mut cells, c[0] + geom.cells[0] * (c[1] + geom.cells[1] * c[2]));
            let k: [usize; 3] = std::array::from_fn(|d| c[d] / b);
            set(&mut blocks, k[0] + blocks_per_axis[0] * (k[1] + blocks_per_axis[1] * k[2]));
        }
        let count = |bits: &[u64]| bits.iter().map(|w| u64::from(w.count_ones())).sum();
        Self {
            cells: geom.num_cells() as u64,
            occupied_cells: count(&cells),
            occupied_blocks: count(&blocks),
            block_cells: b as u64,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fit_stays_on_the_lattice_and_contains_the_box() {
        let spec = GridSpec { dx: 0.5, anchor: [-1.0, -1.0, 0.0], cells: [4, 4, 4] };
        let g = GridGeom::fit(&spec, [0.1, -0.9, 0.0], [1.4, 0.0, 3.0]);
        assert_eq!(g.start, [2, 0, 0]);
        assert_eq!(g.origin, [0.0, -1.0, 0.0]);
        assert_eq!(g.cells, [3, 3, 7]);
        assert!(g.contains([1.4, 0.0, 3.0]));
        assert!(g.contains([0.1, -0.9, 0.0]));
        assert_eq!(g.layer_of(2, 0.0), Some(0));
        assert_eq!(g.layer_of(2, 0.2), None);
    }

    #[test]
    fn occupancy_counts_distinct_cells_and_blocks() {
        let spec = GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [20, 10, 10] };
        let g = GridGeom::fixed(&spec);
        // Two particles in cell (0,0,0), one in (7,7,7) (same block), one in (8,0,0) and one
        // in (19,9,9) (two more blocks).
        let x = [[0.2, 0.2, 0.2], [0.7, 0.1, 0.9], [7.5, 7.5, 7.5], [8.1, 0.5, 0.5], [19.5, 9.5, 9.5]];
        let o = Occupancy::of(&g, &x);
        assert_eq!(o, Occupancy { cells: 2000, occupied_cells: 4, occupied_blocks: 3, block_cells: 8 });
        assert_eq!(Occupancy::of(&g, &[]).occupied_cells, 0);
    }

    /// Records start on a cache line at every size, keep their values when the storage
    /// grows, grow by an eighth, and reuse the storage when they shrink and grow again.
    #[test]
    fn records_are_cache_line_aligned_and_keep_their_values() {
        let mut r = Records::<8>::default();
        for n in [1usize, 3, 17, 100, 1000, 5000, 20_000] {
            let before: Vec<[f64; 8]> = r.to_vec();
            r.resize(n);
            assert_eq!(r.len(), n);
            assert_eq!(r.as_ptr() as usize % 64, 0, "{n} records");
            assert_eq!(&r[..before.len()], &before[..], "values kept growing to {n}");
            assert!(r[before.len()..].iter().all(|v| *v == [0.0; 8]), "new records are zero");
            for (i, v) in r.iter_mut().enumerate() {
                v[i % 8] = i as f64 + 0.5;
            }
            assert!(r.bytes() <= (n + n / 8) * 64 + 56, "{n}: {} bytes", r.bytes());
        }
        let (ptr, bytes) = (r.as_ptr(), r.bytes());
        r.resize(10);
        r.resize(20_000);
        assert_eq!((r.as_ptr(), r.bytes()), (ptr, bytes), "shrinking and regrowing reallocates nothing");
        assert!(r[10..].iter().all(|v| *v == [0.0; 8]), "regrown records are zero");
    }

    #[test]
    fn wall_masks_combine() {
        let spec = GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [2, 2, 2] };
        let g = GridGeom::fixed(&spec);
        let walls = [
            Wall { axis: 2, position: 0.0, kind: WallKind::Slip },
            Wall { axis: 0, position: 2.0, kind: WallKind::Slip },
        ];
        let mut wl = WallLayers::with_capacity(2);
        wl.resolve(&walls, &g);
        let row = wl.row_mask(1, 0);
        assert_eq!(row, [1.0, 1.0, 0.0]);
        assert_eq!(wl.node_mask(row, 2, true), [0.0, 1.0, 0.0]);
        assert_eq!(wl.node_mask(wl.row_mask(1, 1), 0, true), [1.0; 3]);
    }
}
