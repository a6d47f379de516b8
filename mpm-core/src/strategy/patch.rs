//! One patch of a domain-decomposition layout: a box of cells and its sub-grid of nodes,
//! with the paper's maps between the sub-grid's local node ids and the global ones
//! (`globalnode`, `subnodefun`). The cuts ([`super::cuts`]) say where the patches lie; the
//! strategy ([`super::domain_decomposition`]) scatters into their sub-grids.

use crate::grid::GridGeom;
use crate::node_index::NodeIndex;

/// One patch: a box of cells and its sub-grid of nodes.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Patch {
    /// Position `[qx, qy, qz]` of the patch in the layout.
    pub index: [usize; 3],
    /// First cell (and first node) of the patch, in the grid's numbering.
    pub cell_lo: [usize; 3],
    /// Cells per axis (0 when the grid has fewer cells than patches along an axis).
    pub cells: [usize; 3],
}

impl Patch {
    /// Nodes per axis of the sub-grid.
    pub fn node_dims(&self) -> [usize; 3] {
        self.cells.map(|c| c + 1)
    }

    /// Nodes in the sub-grid.
    pub fn num_nodes(&self) -> usize {
        let d = self.node_dims();
        d[0] * d[1] * d[2]
    }

    /// Whether this patch is the lowest-numbered one holding local node `[a, b, c]`.
    ///
    /// Patches are numbered so that a lower layout position along any axis means a lower
    /// number, and neighbouring patches share only their boundary node planes. So a lower
    /// patch holds the node exactly when the node lies on a lower face that has a neighbour
    /// (`a == 0` with `qx > 0`, and so on); edge and corner nodes are covered by those faces.
    #[inline(always)]
    pub fn is_first_holder(&self, node: [usize; 3]) -> bool {
        (0..3).all(|d| node[d] > 0 || self.index[d] == 0)
    }

    /// The sub-grid's numbering on a dense grid: a box from the patch's first node.
    pub fn node_box(&self) -> NodeIndex<'static> {
        NodeIndex::Box { lo: self.cell_lo, dims: self.node_dims() }
    }

    /// The patch's last node (grid node coordinates, inclusive).
    pub fn node_hi(&self) -> [usize; 3] {
        std::array::from_fn(|d| self.cell_lo[d] + self.cells[d])
    }

    /// The paper's `globalnode(s, j)`: global node index of local node `s`.
    pub fn globalnode(&self, s: usize, geom: &GridGeom) -> usize {
        let d = self.node_dims();
        let (i, j, k) = (s % d[0], (s / d[0]) % d[1], s / (d[0] * d[1]));
        geom.node_index(self.cell_lo[0] + i, self.cell_lo[1] + j, self.cell_lo[2] + k)
    }

    /// The paper's `subnodefun(i, j)`: local id of global node `g`, if the sub-grid has it.
    pub fn subnodefun(&self, g: usize, geom: &GridGeom) -> Option<usize> {
        let n = geom.node_dims();
        let (i, j, k) = (g % n[0], (g / n[0]) % n[1], g / (n[0] * n[1]));
        let d = self.node_dims();
        let l = [i, j, k];
        let mut local = [0usize; 3];
        for a in 0..3 {
            if l[a] < self.cell_lo[a] || l[a] >= self.cell_lo[a] + d[a] {
                return None;
            }
            local[a] = l[a] - self.cell_lo[a];
        }
        Some(local[0] + d[0] * (local[1] + d[1] * local[2]))
    }
}
