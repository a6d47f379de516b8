//! Array expansion (AE, paper Section 4): every nodal array gets one copy per thread,
//! `Mg_list(N, nthreads)`. Thread `j` zeroes column `j` and scatters its contiguous chunk of
//! particles into it; then a parallel loop over nodes sums the columns in thread order,
//! `A(:) = sum_j A_list(:, j)` (Eq. 16). No races and no atomics; the memory grows with
//! `(T - 1) x` the nodal arrays, and the assembly with `N x T`.

use super::{Cursors, Kernel, ScatterStrategy};
use crate::blocks::BlockMap;
use crate::grid::{GridGeom, NodeIndex, Records};
use crate::math::Vec3;
use crate::parallel::{partition, Exec, Split};
use crate::work::Tally;
use std::mem::size_of;

/// The array-expansion strategy for `threads` threads (one copy of the arrays per thread).
#[derive(Clone, Copy, Debug)]
pub struct ArrayExpansion {
    threads: usize,
}

impl ArrayExpansion {
    /// State for `threads` threads.
    pub fn new(threads: usize) -> Self {
        Self { threads }
    }
}

/// Scatter particle chunk `j` into column `j` of `columns` (sized `N x T`, column-major;
/// `N` the grid's stored nodes, numbered by `index`).
pub fn scatter<const K: usize, F>(
    exec: &Exec<'_>,
    nn: usize,
    index: &NodeIndex<'_>,
    n: usize,
    columns: &mut Records<K>,
    kernel: &F,
) where
    F: Kernel<K>,
{
    let t = exec.workers();
    columns.resize(nn * t);
    let tally = Tally::of(exec);
    exec.for_each_chunk_mut(Split::Blocks(nn).of(columns), |j, column| {
        column.fill([0.0; K]);
        let mut nodes = Cursors::global(*index);
        let mine = partition(n, t, j);
        tally.particles(j, mine.len());
        tally.scattered(j, column.len(), size_of::<[f64; K]>(), true);
        kernel.scatter_all(mine, &mut nodes, column);
    });
}

/// Eq. 16: `global[i] = sum_j columns[j][i]`, summed in thread order, parallel over nodes.
pub fn assemble<const K: usize>(exec: &Exec<'_>, global: &mut [[f64; K]], columns: &[[f64; K]]) {
    let nn = global.len();
    let t = exec.workers();
    let tally = Tally::of(exec);
    exec.for_each_chunk_mut(Split::Even.of(global), |w, dst| {
        let r = partition(nn, t, w);
        tally.assembled(w, dst.len(), t * dst.len(), size_of::<[f64; K]>());
        dst.copy_from_slice(&columns[r.clone()]);
        for j in 1..t {
            let src = &columns[j * nn + r.start..j * nn + r.end];
            for (a, b) in dst.iter_mut().zip(src) {
                for k in 0..K {
                    a[k] += b[k];
                }
            }
        }
    });
}

impl ScatterStrategy for ArrayExpansion {
    fn reserve(&mut self, geom: &GridGeom, blocks: Option<&BlockMap>) -> usize {
        NodeIndex::of(geom, blocks).num_nodes() * self.threads
    }

    fn prepare(&mut self, _exec: &Exec<'_>, _geom: &GridGeom, _blocks: Option<&BlockMap>, _x: &[Vec3]) {}

    /// The columns are as long as `global`: the grid's nodes, or its stored nodes.
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        scatter(exec, global.len(), index, n, parts, kernel);
    }

    fn assemble<const K: usize>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        _index: &NodeIndex<'_>,
        global: &mut [[f64; K]],
        parts: &[[f64; K]],
    ) {
        assemble(exec, global, parts);
    }

    fn bytes(&self) -> usize {
        0
    }
}
