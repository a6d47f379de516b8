//! The gather (Eqs. 8, 10) fused with the MUSL re-map scatter (Eq. 11): one pass over the
//! particles that updates each particle's velocity from the nodal accelerations and scatters
//! its new momentum.

use super::{scatter_at, Blocked};
use crate::grid::{GridGeom, KIN_WIDTH, REMAP_WIDTH};
use crate::locate::Located;
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::parallel::DisjointSlice;
use crate::simd::{Real, SimdLevel, F4};
use crate::strategy::{Cursors, Kernel, Target};

/// The gather (Eqs. 8, 10: `v_p += dt sum_i S_ip a_i`) and the MUSL re-map scatter (Eq. 11:
/// `m_p v_p(k+1) S_ip` at the 8 nodes) of particle `p` in one pass: one shape evaluation, one
/// cell look-up, the particle's data read once. The strategy's scatter calls it once per
/// particle from the worker that owns it ([`crate::strategy::ScatterStrategy::scatter`]), so
/// the gather follows the re-map's partition (DD: the patch's particles).
pub(crate) struct GatherRemap<'a> {
    inv_dx: f64,
    /// `[v, a]` per node of the grid (numbered like the grid: `Cursors::both`'s second).
    kin: &'a [[f64; KIN_WIDTH]],
    located: &'a Located,
    mass: &'a [f64],
    /// The velocities, written by the worker that scatters each particle.
    v: DisjointSlice<'a, Vec3>,
    dt: f64,
    /// The instruction-set level of the scatter loop.
    simd: SimdLevel,
}

impl<'a> GatherRemap<'a> {
    /// The kernel over the particles `located` in `geom` with masses `mass` and velocities
    /// `v` (updated in place) for nodal accelerations in `kin`.
    pub(crate) fn new(
        geom: &GridGeom,
        kin: &'a [[f64; KIN_WIDTH]],
        located: &'a Located,
        mass: &'a [f64],
        v: &'a mut [Vec3],
        dt: f64,
        simd: SimdLevel,
    ) -> Self {
        assert!(located.len() == v.len() && v.len() == mass.len(), "one location, mass and velocity per particle");
        Self { inv_dx: geom.inv_dx, kin, located, mass, v: DisjointSlice::new(v), dt, simd }
    }
}

impl Blocked<REMAP_WIDTH> for GatherRemap<'_> {
    /// One particle at a time: this pass uses the weights only, whose evaluation per
    /// particle costs no more than a block's bookkeeping (measured: the blocked form was no
    /// faster, 1.02 of this one's time, median of 8 alternated runs; with the nodes'
    /// accelerations one broadcast per run of lanes in one cell, as the particle update
    /// takes them, 1.21).
    #[inline(always)]
    fn blocks<D: Target<REMAP_WIDTH> + ?Sized>(
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

impl Kernel<REMAP_WIDTH> for GatherRemap<'_> {
    #[inline(always)]
    fn scatter_all<D: Target<REMAP_WIDTH> + ?Sized>(
        &self,
        ids: impl Iterator<Item = usize>,
        nodes: &mut Cursors<'_>,
        data: &mut D,
    ) {
        scatter_at(self, self.simd, ids, nodes, data);
    }

    #[inline(always)]
    fn scatter<D: Target<REMAP_WIDTH> + ?Sized>(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut D) {
        let s = self.located.shape(p, self.inv_dx);
        let (target, grid) = nodes.both(s.cell);
        let mut acc = [0.0; 3];
        for q in 0..8 {
            let a = &self.kin[grid[q]];
            for k in 0..3 {
                acc[k] += s.w[q] * a[3 + k];
            }
        }
        // SAFETY: the kernel is crate-private and only the crate's strategies call it,
        // through `Engine::scatter`; each calls it exactly once per particle per scatter, on
        // the one worker that owns the particle (serial: 0..n; AE and atomic: worker j's
        // chunk `partition(n, T, j)`; DD: the ids in `Pindex(:, j)`, each particle in one
        // column; colour: the ids in the block lists, each particle in one block's list, each
        // block scattered by one worker in one phase). So no other reference to `v[p]`
        // exists during this call. Guarded by the test
        // `every_strategy_scatters_every_particle_once` (and the equivalence tests).
        let vp = unsafe { self.v.get_mut(p) };
        for k in 0..3 {
            vp[k] += self.dt * acc[k];
        }
        let m = self.mass[p];
        let mv = F4([m * vp[0], m * vp[1], m * vp[2], 0.0]);
        for q in 0..8 {
            let d = data.at(target[q]);
            *d = (F4(*d) + mv * F4::splat(s.w[q])).0;
        }
    }
}

/// The fused gather and re-map scatter over every particle in order into `remap` (zeroed
/// first; numbered by `index`), on the calling thread: the serial strategy's pass, for
/// benchmarks (the particles `located` in `geom`, e.g. by [`Located::of`]).
#[allow(clippy::too_many_arguments)]
pub fn gather_remap_serial(
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    kin: &[[f64; KIN_WIDTH]],
    located: &Located,
    mass: &[f64],
    v: &mut [Vec3],
    dt: f64,
    remap: &mut [[f64; REMAP_WIDTH]],
) {
    let n = located.len();
    let kernel = GatherRemap::new(geom, kin, located, mass, v, dt, SimdLevel::detected());
    crate::strategy::serial::scatter(index, n, remap, &kernel);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::transfer::testing::scatter_inputs;

    /// The fused gather and re-map's loop at every level this CPU has gives every velocity
    /// and every re-map record bitwise what the one-particle form gives, for id lists of every length, out of order,
    /// in cell order and in runs of one cell, with random nodal velocities and accelerations.
    #[test]
    fn gather_remap_loops_are_bitwise_the_one_particle_form() {
        let geom = GridGeom::fixed(&GridSpec { dx: 4.0 / 7.0, anchor: [0.0; 3], cells: [6, 5, 7] });
        let index = NodeIndex::of(&geom, None);
        let (pt, [stride, by_cell, runs]) = scatter_inputs(&geom);
        let mut unit = crate::testing::unit_stream(5);
        let kin: Vec<[f64; KIN_WIDTH]> =
            (0..index.num_nodes()).map(|_| std::array::from_fn(|_| 100.0 * (unit() - 0.5))).collect();
        let located = Located::of(&geom, &pt.x);
        let dt = 3.7e-3;
        for (list, order) in [("stride", &stride), ("cell order", &by_cell), ("runs", &runs)] {
            for len in (0..=9).chain([order.len()]) {
                let ids = &order[..len];
                let run = |simd: SimdLevel, all: bool| {
                    let mut v = pt.v.clone();
                    let mut data = vec![[0.0; REMAP_WIDTH]; index.num_nodes()];
                    let k = GatherRemap::new(&geom, &kin, &located, &pt.mass, &mut v, dt, simd);
                    let mut nodes = Cursors::global(index);
                    if all {
                        k.scatter_all(ids.iter().copied(), &mut nodes, &mut data[..]);
                    } else {
                        for &p in ids {
                            k.scatter(p, &mut nodes, &mut data[..]);
                        }
                    }
                    (v, data)
                };
                let (v1, d1) = run(SimdLevel::Baseline, false);
                for simd in SimdLevel::ALL.into_iter().filter(|l| l.is_available()) {
                    let (vl, dl) = run(simd, true);
                    for (p, (a, b)) in vl.iter().zip(&v1).enumerate() {
                        let (a, b) = (a.map(f64::to_bits), b.map(f64::to_bits));
                        assert_eq!(a, b, "{list}, {len} at {simd}: velocity of {p}");
                    }
                    for (i, (a, b)) in dl.iter().zip(&d1).enumerate() {
                        assert_eq!(a.map(f64::to_bits), b.map(f64::to_bits), "{list}, {len} at {simd}: node {i}");
                    }
                }
            }
        }
    }
}
