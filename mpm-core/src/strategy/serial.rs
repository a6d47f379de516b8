//! The serial scatter: every particle straight into the global nodal arrays. It is the
//! oracle every parallel strategy is tested against.

use super::{Cursors, Kernel, ScatterStrategy};
use crate::grid::{GridGeom, Records};
use crate::node_index::NodeIndex;
use crate::parallel::Exec;
use crate::work::Tally;

/// The serial strategy: no state, no scatter buffer, no assembly.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

/// Zero `global` (numbered by `index`) and add `kernel(p)` for every particle in order.
pub fn scatter<const K: usize, F>(index: &NodeIndex<'_>, n: usize, global: &mut [[f64; K]], kernel: &F)
where
    F: Kernel<K>,
{
    global.fill([0.0; K]);
    let mut nodes = Cursors::global(*index);
    kernel.scatter_all(0..n, &mut nodes, global);
}

impl ScatterStrategy for Serial {
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        _parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        let tally = Tally::of(exec);
        tally.particles(0, n);
        tally.scattered(0, global.len(), std::mem::size_of::<[f64; K]>(), false);
        scatter(index, n, global, kernel);
    }
}
