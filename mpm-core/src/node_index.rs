//! How the nodes of a grid, or of a part of it, are numbered in the node arrays: a dense
//! box (the whole grid, or a domain-decomposition sub-grid) or the stored blocks of a sparse
//! grid ([`crate::blocks`]). Every scatter and gather turns a cell into its 8 nodes' indices
//! through a [`NodeIndex`]; a loop over particles through a [`CellNodes`], which remembers
//! the last cell.

use crate::blocks::BlockMap;
use crate::grid::GridGeom;
use crate::shape;

/// Where the nodes of a grid, or of a part of it, are stored: the rule that turns a cell
/// into the indices of its 8 nodes in every scatter and gather.
#[derive(Clone, Copy, Debug)]
pub enum NodeIndex<'a> {
    /// A dense box of `dims` nodes from grid node `lo`, numbered `i + dims[0] (j + dims[1] k)`
    /// (the whole grid: `lo = 0`, `dims` its node counts).
    Box {
        /// Grid node of the box's first node (also its first cell).
        lo: [usize; 3],
        /// Nodes per axis.
        dims: [usize; 3],
    },
    /// Stored blocks ([`crate::GridMode::Sparse`]).
    Blocks(&'a BlockMap),
}

impl<'a> NodeIndex<'a> {
    /// The whole grid `geom`, stored densely or in `blocks`.
    pub fn of(geom: &GridGeom, blocks: Option<&'a BlockMap>) -> Self {
        match blocks {
            Some(map) => NodeIndex::Blocks(map),
            None => NodeIndex::Box { lo: [0; 3], dims: geom.node_dims() },
        }
    }

    /// Nodes numbered: the box's, or the stored blocks'.
    pub fn num_nodes(&self) -> usize {
        match self {
            NodeIndex::Box { dims, .. } => dims.iter().product(),
            NodeIndex::Blocks(map) => map.num_nodes(),
        }
    }

    /// Indices of the 8 nodes of `cell` (the grid's cell numbering), in the order of
    /// [`crate::shape`].
    #[inline(always)]
    pub fn cell_nodes(&self, cell: [usize; 3]) -> [usize; 8] {
        match self {
            NodeIndex::Box { lo, dims } => shape::cell_nodes(*dims, std::array::from_fn(|d| cell[d] - lo[d])),
            NodeIndex::Blocks(map) => map.cell_nodes(cell),
        }
    }
}

/// [`NodeIndex::cell_nodes`] for a loop over particles, remembering the last cell's nodes.
/// Neighbouring particles often share a cell (4-5 in a row along x in the impact's
/// lattices), and on the sparse grid a repeat then skips the block look-ups; on a dense grid
/// the indices are computed every time (8 additions).
#[derive(Clone, Copy, Debug)]
pub struct CellNodes<'a> {
    index: NodeIndex<'a>,
    key: usize,
    nodes: [usize; 8],
}

impl<'a> CellNodes<'a> {
    /// A cursor over `index` with no cell remembered.
    pub fn new(index: NodeIndex<'a>) -> Self {
        Self { index, key: usize::MAX, nodes: [0; 8] }
    }

    /// Indices of the 8 nodes of `cell`, as [`NodeIndex::cell_nodes`].
    #[inline(always)]
    pub fn get(&mut self, cell: [usize; 3]) -> [usize; 8] {
        match self.index {
            NodeIndex::Box { .. } => self.index.cell_nodes(cell),
            NodeIndex::Blocks(map) => {
                let key = map.cell_key(cell);
                if key != self.key {
                    self.key = key;
                    self.nodes = map.cell_nodes(cell);
                }
                self.nodes
            }
        }
    }
}
