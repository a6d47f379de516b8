//! The serial scatter: every particle straight into the global nodal arrays. It is the
//! oracle every parallel strategy is tested against.

use super::{Contribution, NodeBox};
use crate::grid::GridGeom;

/// Zero `global` and add `kernel(p)` for every particle in order.
pub fn scatter<const K: usize, F>(geom: &GridGeom, n: usize, global: &mut [[f64; K]], kernel: &F)
where
    F: Fn(usize) -> Contribution<K>,
{
    global.fill([0.0; K]);
    let bx = NodeBox::grid(geom);
    for p in 0..n {
        bx.add(global, &kernel(p));
    }
}
