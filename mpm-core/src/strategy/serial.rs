//! The serial scatter: every particle straight into the global nodal arrays. It is the
//! oracle every parallel strategy is tested against.

use super::{Kernel, NodeBox, ScatterStrategy};
use crate::grid::GridGeom;
use crate::math::Vec3;
use crate::parallel::Exec;

/// The serial strategy: no state, no scatter buffer, no assembly.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

/// Zero `global` and add `kernel(p)` for every particle in order.
pub fn scatter<const K: usize, F>(geom: &GridGeom, n: usize, global: &mut [[f64; K]], kernel: &F)
where
    F: Kernel<K>,
{
    global.fill([0.0; K]);
    let bx = NodeBox::grid(geom);
    for p in 0..n {
        bx.add(global, &kernel.contribution(p));
    }
}

impl ScatterStrategy for Serial {
    fn reserve(&mut self, _geom: &GridGeom) -> usize {
        0
    }

    fn prepare(&mut self, _exec: &Exec<'_>, _geom: &GridGeom, _x: &[Vec3]) {}

    fn scatter<const K: usize, F>(
        &self,
        _exec: &Exec<'_>,
        geom: &GridGeom,
        n: usize,
        global: &mut [[f64; K]],
        _parts: &mut Vec<[f64; K]>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        scatter(geom, n, global, kernel);
    }

    fn assemble<const K: usize>(
        &self,
        _exec: &Exec<'_>,
        _geom: &GridGeom,
        _global: &mut [[f64; K]],
        _parts: &[[f64; K]],
    ) {
    }

    fn bytes(&self) -> usize {
        0
    }
}
