//! What a strategy's scatter loop hands the per-particle kernels: the node numberings it
//! walks ([`Cursors`]) and the node records the kernel adds to ([`Target`]), and the
//! kernel's side of the contract ([`Kernel`]).
//!
//! A kernel turns a particle's cell into its 8 node indices through the cursors and adds its
//! values to the records at those indices, one record at a time, through the target. The
//! strategies differ only in what they hand over: a slice of records it owns (serial, an AE
//! copy, a DD sub-grid), the global arrays shared by the workers of a colour phase
//! ([`super::colour`]), or an adder that sends each record's values to the global arrays by
//! atomic additions ([`super::atomic`]).

use crate::node_index::{CellNodes, NodeIndex};

/// What one particle adds to the 8 nodes of its cell (node order of [`crate::shape`]).
#[derive(Clone, Copy, Debug)]
pub struct Contribution<const K: usize> {
    /// The cell, in the global grid's numbering.
    pub cell: [usize; 3],
    /// Per node, `K` values.
    pub c: [[f64; K]; 8],
}

/// The node numberings a scatter loop walks: the scatter target's (the global arrays, an AE
/// copy of them, or a DD sub-grid) and, where it differs, the global grid's, which a kernel
/// reads nodal values from (the fused gather and re-map reads the nodal accelerations).
/// Each remembers the last cell's nodes ([`CellNodes`]).
///
/// A colour phase fences its cursors to the block being scattered ([`Cursors::fenced`]): a
/// cell outside the block panics before any of its nodes is handed out.
#[derive(Clone, Copy, Debug)]
pub struct Cursors<'a> {
    target: CellNodes<'a>,
    global: Option<CellNodes<'a>>,
    /// The cells every cell asked for must lie in: first cell and cells per axis.
    fence: Option<([usize; 3], [usize; 3])>,
}

impl<'a> Cursors<'a> {
    /// A loop whose target is numbered like the global grid (`index`): serial, AE, colour,
    /// atomic.
    pub fn global(index: NodeIndex<'a>) -> Self {
        Self { target: CellNodes::new(index), global: None, fence: None }
    }

    /// A loop whose target is numbered by `target` (a DD sub-grid) inside the grid `global`.
    pub fn split(target: NodeIndex<'a>, global: NodeIndex<'a>) -> Self {
        Self { target: CellNodes::new(target), global: Some(CellNodes::new(global)), fence: None }
    }

    /// These cursors, answering only for the cells `lo .. lo + len` (per axis): any other
    /// cell panics. Three comparisons a look-up.
    pub fn fenced(self, lo: [usize; 3], len: [usize; 3]) -> Self {
        Self { fence: Some((lo, len)), ..self }
    }

    /// Panic if `cell` lies outside the fence (if there is one).
    #[inline(always)]
    fn check(&self, cell: [usize; 3]) {
        if let Some((lo, len)) = self.fence {
            if (0..3).any(|d| cell[d].wrapping_sub(lo[d]) >= len[d]) {
                outside_fence(cell, lo, len);
            }
        }
    }

    /// The target's indices of the 8 nodes of `cell`.
    #[inline(always)]
    pub fn target(&mut self, cell: [usize; 3]) -> [usize; 8] {
        self.check(cell);
        self.target.get(cell)
    }

    /// The target's and the global grid's indices of the 8 nodes of `cell`.
    #[inline(always)]
    pub fn both(&mut self, cell: [usize; 3]) -> ([usize; 8], [usize; 8]) {
        self.check(cell);
        let t = self.target.get(cell);
        match &mut self.global {
            Some(g) => (t, g.get(cell)),
            None => (t, t),
        }
    }
}

#[cold]
#[inline(never)]
fn outside_fence(cell: [usize; 3], lo: [usize; 3], len: [usize; 3]) -> ! {
    panic!("a kernel asked for cell {cell:?} while scattering the block of cells {lo:?} + {len:?}")
}

/// Where a scatter kernel adds its values: node records reached one at a time by index.
///
/// A slice of records is one (`&mut data[i]`: serial, an AE copy, a DD sub-grid); the colour
/// phase's shared view of the global arrays and the atomic strategy's adder are the others.
/// `&mut self` keeps one record borrowed at a time: a kernel finishes with a record before it
/// asks for the next, which is what lets the adder send a record's values when the next is
/// asked for.
pub trait Target<const K: usize> {
    /// The record of node `i` (numbered as the cursors number the target), to add to.
    fn at(&mut self, i: usize) -> &mut [f64; K];
}

impl<const K: usize> Target<K> for [[f64; K]] {
    #[inline(always)]
    fn at(&mut self, i: usize) -> &mut [f64; K] {
        &mut self[i]
    }
}

/// The per-particle kernel of a scatter: what particle `p` adds to the 8 nodes of its cell.
///
/// The solver's kernels ([`crate::transfer::P2g`], and the fused gather and re-map) add
/// their values straight into the target's node records, `#[inline(always)]`, so that a
/// particle's 8 x `K` values stay in registers (returned as a [`Contribution`], the 448
/// bytes of a P2G particle went through the stack). Closures returning a [`Contribution`]
/// are kernels too, for tests and benchmarks.
///
/// A kernel reaches the target only at the indices the cursors give for the particle's cell
/// (every kernel of the crate does; the colour strategy's soundness rests on it, see
/// [`super::colour`]).
pub trait Kernel<const K: usize>: Sync {
    /// Add particle `p`'s values into `data`, whose nodes `nodes.target` numbers.
    fn scatter<D: Target<K> + ?Sized>(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut D);

    /// [`Kernel::scatter`] for every particle of `ids`, in order: a strategy's loop over its
    /// particles. A kernel may run the loop at a wider SIMD level ([`crate::transfer::P2g`]).
    #[inline(always)]
    fn scatter_all<D: Target<K> + ?Sized>(
        &self,
        ids: impl Iterator<Item = usize>,
        nodes: &mut Cursors<'_>,
        data: &mut D,
    ) {
        for p in ids {
            self.scatter(p, nodes, data);
        }
    }
}

impl<const K: usize, F: Fn(usize) -> Contribution<K> + Sync> Kernel<K> for F {
    #[inline(always)]
    fn scatter<D: Target<K> + ?Sized>(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut D) {
        add(nodes, data, &self(p));
    }
}

/// Add a particle's contribution at the nodes `nodes` gives its cell (every node of the
/// cell must be stored there).
#[inline(always)]
pub(crate) fn add<const K: usize, D: Target<K> + ?Sized>(nodes: &mut Cursors<'_>, data: &mut D, con: &Contribution<K>) {
    let idx = nodes.target(con.cell);
    for q in 0..8 {
        let d = data.at(idx[q]);
        for k in 0..K {
            d[k] += con.c[q][k];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A fenced cursor answers for the cells of its block and panics for any other.
    #[test]
    fn a_fenced_cursor_refuses_cells_outside_its_block() {
        let index = NodeIndex::Box { lo: [0; 3], dims: [9, 9, 9] };
        let mut nodes = Cursors::global(index).fenced([2, 4, 0], [2, 2, 2]);
        assert_eq!(nodes.target([3, 5, 1]), index.cell_nodes([3, 5, 1]));
        for outside in [[4, 4, 0], [1, 4, 0], [2, 6, 1], [2, 4, 2]] {
            let refused = std::panic::catch_unwind(move || nodes.target(outside));
            assert!(refused.is_err(), "cell {outside:?} outside the block");
        }
        let mut open = Cursors::global(index);
        assert_eq!(open.target([7, 7, 7]), index.cell_nodes([7, 7, 7]));
    }
}
