//! What a run needs from other processes when the problem is split over ranks: the
//! [`Collectives`] trait (reductions and a gather, also what the scenario figures need to
//! measure the whole set from its parts), the [`Exchange`] trait built on it (halo sums,
//! particle migration: what a step needs), the single-process identity of the collectives
//! [`SingleProcess`] and the exchange of one process [`OneProcess`], and the rank boxes ([`RankBoxes`]) every implementation cuts the lattice into.
//!
//! The library has no MPI code: a program implements [`Exchange`] with its message-passing
//! library (the `mpm` program does it with MPI behind its `mpi` feature) and hands it to
//! [`crate::Simulation::with_exchange`].
//!
//! ```text
//! rank box   lattice cells [lo, hi) per axis, cut along cell boundaries (first and last
//!            boxes open to -inf / +inf); a particle belongs to the box of its lattice cell
//! local grid the nodes of the box's cells inside the global grid (a box outside the grid
//!            gets the boundary cell next to it). The rank's particles (all inside its box
//!            at the start of a step) scatter there and read there, so the only nodes whose
//!            values need other ranks' contributions are the ones two local grids share:
//!            the node layer of a shared face, or a shared edge or corner. Summing those
//!            gives every rank the global nodal values on its whole local grid. A particle
//!            that round-off puts a hair outside its box is clamped into the box's boundary
//!            cell (its weights extrapolated by that hair)
//! ```
//!
//! Within one step particles move less than a cell (CFL <= 1), so they cross at most one
//! cut plane per axis and migrate only to ranks adjacent in the layout (diagonals included).

use crate::energy::Partial;
use crate::error::SimError;
use crate::grid::GridGeom;
use crate::math::Vec3;
use crate::particles::Particles;
use crate::strategy::domain_decomposition::patch_layout;

/// Collective operations over the ranks: every rank calls the same ones in the same order.
///
/// Sums over ranks must be done in rank order on every rank, so that every rank gets the
/// same value and reruns are bitwise equal. The step's reductions go through its
/// [`Exchange`], which counts them in its [`ExchangeStats`]; the scenario figures
/// ([`crate::scenario`]) take any implementation, so that a program can measure through
/// one that counts nothing (a measurement is not part of a step).
pub trait Collectives: Send {
    /// Number of ranks.
    fn ranks(&self) -> usize;

    /// This process's rank.
    fn rank(&self) -> usize;

    /// Element-wise sums over ranks, in rank order, on every rank.
    fn sum(&mut self, values: &mut [f64]) -> Result<(), SimError>;

    /// Element-wise sums of counts over ranks, on every rank.
    fn sum_counts(&mut self, values: &mut [u64]) -> Result<(), SimError>;

    /// Element-wise maxima over ranks, on every rank.
    fn max(&mut self, values: &mut [f64]) -> Result<(), SimError>;

    /// Every rank's `values` concatenated in rank order, on rank 0; `None` on the others.
    fn gather(&mut self, values: Vec<f64>) -> Result<Option<Vec<f64>>, SimError>;

    /// The sum over ranks of one count (this rank's `count`), on every rank.
    fn total(&mut self, count: usize) -> Result<usize, SimError> {
        let mut c = [count as u64];
        self.sum_counts(&mut c)?;
        Ok(c[0] as usize)
    }
}

/// The operations a distributed step calls, once per step each (never per particle),
/// besides the reductions of [`Collectives`].
pub trait Exchange: Collectives {
    /// Keep only the particles this rank owns (called once, before the first step).
    /// `ids` are the particles' indices in the whole initial set (a scenario built for this
    /// rank alone, [`crate::scenario::Pick`]); `None` when `particles` is the whole set.
    fn adopt(&mut self, particles: &mut Particles, ids: Option<Vec<u64>>) -> Result<(), SimError>;

    /// This rank's part of the `global` grid (see the module docs); the global grid itself
    /// for one rank.
    fn local_grid(&mut self, global: &GridGeom) -> GridGeom;

    /// Replace the nodal values on nodes shared with other ranks by their sums over ranks.
    /// `values` holds `width` values per node of `local` (the grid from
    /// [`Exchange::local_grid`]).
    fn sum_shared_nodes(&mut self, local: &GridGeom, values: &mut [f64], width: usize) -> Result<(), SimError>;

    /// Move the particles that left this rank's box to their new owners and take in the
    /// ones that arrived; returns how many left.
    fn migrate(&mut self, particles: &mut Particles) -> Result<usize, SimError>;

    /// Global id (index in the initial set) of this rank's particle `p`.
    fn global_id(&self, p: usize) -> u64;

    /// The particles were put in another order ([`crate::order`]): this rank's new particle
    /// `i` is its old particle `order[i]`. The ids follow their particles.
    fn reorder(&mut self, order: &[u64]);

    /// Traffic and time of the exchange so far (zero for one process).
    fn stats(&self) -> ExchangeStats {
        ExchangeStats::default()
    }

    /// Memory the exchange holds for this rank's particles (their ids), in bytes.
    fn bytes(&self) -> usize {
        0
    }

    /// Continue counting from `stats`, the traffic of a saved run's steps
    /// ([`crate::Simulation::resume`]; nothing to do for one process).
    fn resume_stats(&mut self, _stats: ExchangeStats) {}
}

/// What an [`Exchange`] sent and how long it took, summed over the steps taken.
#[derive(Clone, Copy, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ExchangeStats {
    /// Bytes sent for halo sums (shared nodes, both scatters).
    pub halo_bytes: u64,
    /// Messages sent for halo sums.
    pub halo_messages: u64,
    /// Bytes sent moving particles (counts and states).
    pub migration_bytes: u64,
    /// Messages sent moving particles.
    pub migration_messages: u64,
    /// Bytes each rank contributed to reductions.
    pub reduction_bytes: u64,
    /// Reductions (collective calls).
    pub reductions: u64,
    /// Seconds spent in the exchange (packing, messages, and waiting for other ranks unless
    /// `wait_seconds` is measured).
    pub seconds: f64,
    /// Seconds spent waiting for the other ranks to arrive at an exchange, measured by a
    /// barrier in front of each exchange operation (`mpm run --split-wait`), and then not
    /// in `seconds`; `None` when not measured. The wait is load imbalance between ranks (or
    /// a rank slowed from outside), not the cost of communicating.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub wait_seconds: Option<f64>,
}

/// One process: every operation is the identity.
#[derive(Clone, Copy, Debug, Default)]
pub struct SingleProcess;

/// The collectives of one process, where every operation is the identity.
macro_rules! identity_collectives {
    ($t:ty) => {
        impl Collectives for $t {
            fn ranks(&self) -> usize {
                1
            }
            fn rank(&self) -> usize {
                0
            }
            fn sum(&mut self, _: &mut [f64]) -> Result<(), SimError> {
                Ok(())
            }
            fn sum_counts(&mut self, _: &mut [u64]) -> Result<(), SimError> {
                Ok(())
            }
            fn max(&mut self, _: &mut [f64]) -> Result<(), SimError> {
                Ok(())
            }
            fn gather(&mut self, values: Vec<f64>) -> Result<Option<Vec<f64>>, SimError> {
                Ok(Some(values))
            }
        }
    };
}

identity_collectives!(SingleProcess);

/// The exchange of a run in one process: no other rank, so every operation but the ids is
/// the identity. It keeps the particles' global ids once the cell order
/// ([`crate::order`]) has moved them (4 bytes a particle, and as much again while they are
/// permuted; none before the first move).
#[derive(Clone, Debug, Default)]
pub struct OneProcess {
    /// Global id of each particle; empty while every particle is at its index. One process
    /// holds fewer than 2^32 particles (the cell order packs indices in 32 bits).
    ids: Vec<u32>,
    /// The ids being permuted.
    scratch: Vec<u32>,
}

identity_collectives!(OneProcess);

impl Exchange for OneProcess {
    fn adopt(&mut self, particles: &mut Particles, ids: Option<Vec<u64>>) -> Result<(), SimError> {
        if let Some(ids) = ids {
            if ids.len() != particles.len() {
                return Err(SimError::Config(format!(
                    "{} particle ids for {} particles; build the set-up with one id per particle",
                    ids.len(),
                    particles.len()
                )));
            }
            self.ids = ids
                .into_iter()
                .map(|id| {
                    u32::try_from(id).map_err(|_| {
                        SimError::Config(format!(
                            "particle id {id} does not fit in 32 bits: one process holds fewer than 2^32 particles"
                        ))
                    })
                })
                .collect::<Result<_, _>>()?;
        }
        Ok(())
    }
    fn local_grid(&mut self, global: &GridGeom) -> GridGeom {
        *global
    }
    fn sum_shared_nodes(&mut self, _: &GridGeom, _: &mut [f64], _: usize) -> Result<(), SimError> {
        Ok(())
    }
    fn migrate(&mut self, _: &mut Particles) -> Result<usize, SimError> {
        Ok(0)
    }
    fn global_id(&self, p: usize) -> u64 {
        self.ids.get(p).map_or(p as u64, |&id| u64::from(id))
    }
    fn reorder(&mut self, order: &[u64]) {
        // The order's indices are those of this process's particles: below 2^32.
        if self.ids.is_empty() {
            self.ids.extend(order.iter().map(|&o| o as u32));
            // The next permutation's buffer now: a step allocates nothing after the first.
            self.scratch.reserve_exact(order.len());
            return;
        }
        self.scratch.clear();
        self.scratch.extend(order.iter().map(|&o| self.ids[o as usize]));
        std::mem::swap(&mut self.ids, &mut self.scratch);
    }
    fn bytes(&self) -> usize {
        crate::capacity_bytes(&self.ids) + crate::capacity_bytes(&self.scratch)
    }
}

/// Combine the step totals of every rank: sums of energies, momentum and counts, the
/// largest speed and the bounding box (exact, so the next dt and the adaptive grid equal
/// one process's).
pub(crate) fn reduce_partial(ex: &mut dyn Exchange, t: &mut Partial) -> Result<(), SimError> {
    let mut sums = [t.kinetic, t.internal, t.momentum[0], t.momentum[1], t.momentum[2], t.failed_floor_energy];
    ex.sum(&mut sums)?;
    [t.kinetic, t.internal, t.failed_floor_energy] = [sums[0], sums[1], sums[5]];
    t.momentum = [sums[2], sums[3], sums[4]];
    let mut counts = [t.non_finite, t.negative_internal, t.failed_floors];
    ex.sum_counts(&mut counts)?;
    [t.non_finite, t.negative_internal, t.failed_floors] = counts;
    let mut maxima = [t.max_speed, -t.lo[0], -t.lo[1], -t.lo[2], t.hi[0], t.hi[1], t.hi[2]];
    ex.max(&mut maxima)?;
    t.max_speed = maxima[0];
    t.lo = [-maxima[1], -maxima[2], -maxima[3]];
    t.hi = [maxima[4], maxima[5], maxima[6]];
    Ok(())
}

/// The layout `[rx, ry, rz]` of `ranks` boxes over a grid of `cells`: the same choice as
/// the domain decomposition's patch layout ([`patch_layout`]).
pub fn rank_layout(ranks: usize, cells: [usize; 3]) -> [usize; 3] {
    patch_layout(ranks, cells)
}

/// Cut planes of a layout over `geom`: for each axis, the `parts - 1` internal planes as
/// lattice cell indices (relative to the grid's anchor), uniform in cells.
///
/// The planes are the first cells of boxes 1.. along the axis; a balanced cut can replace
/// this function without changing [`RankBoxes`].
pub fn uniform_cuts(layout: [usize; 3], geom: &GridGeom) -> Result<[Vec<i64>; 3], SimError> {
    let mut cuts: [Vec<i64>; 3] = Default::default();
    for d in 0..3 {
        let (parts, cells) = (layout[d], geom.cells[d]);
        if parts == 0 || parts > cells {
            return Err(SimError::Config(format!(
                "a rank layout of {parts} boxes along axis {d} needs at least {parts} cells there, the grid has {cells}; choose another --rank-layout"
            )));
        }
        cuts[d] = (1..parts).map(|q| geom.start[d] + (q * cells / parts) as i64).collect();
    }
    Ok(cuts)
}

/// The boxes of the ranks: internal cut planes per axis; rank `r` has layout coordinates
/// with z fastest (`r = qz + rz (qy + ry qx)`), like the DD patches.
#[derive(Clone, Debug, PartialEq)]
pub struct RankBoxes {
    /// Internal cut planes per axis (lattice cell indices, increasing).
    pub cuts: [Vec<i64>; 3],
    /// Lattice anchor of the grid (m).
    pub anchor: Vec3,
    /// `1 / dx`.
    pub inv_dx: f64,
}

impl RankBoxes {
    /// Boxes from cut planes (each axis strictly increasing).
    pub fn new(cuts: [Vec<i64>; 3], anchor: Vec3, inv_dx: f64) -> Result<Self, SimError> {
        if cuts.iter().any(|c| c.windows(2).any(|w| w[0] >= w[1])) {
            return Err(SimError::Config("rank cut planes must increase along every axis".into()));
        }
        Ok(Self { cuts, anchor, inv_dx })
    }

    /// Boxes per axis.
    pub fn layout(&self) -> [usize; 3] {
        std::array::from_fn(|d| self.cuts[d].len() + 1)
    }

    /// Number of boxes.
    pub fn ranks(&self) -> usize {
        self.layout().iter().product()
    }

    /// Layout coordinates of rank `r`.
    pub fn coords(&self, r: usize) -> [usize; 3] {
        let l = self.layout();
        [r / (l[1] * l[2]), (r / l[2]) % l[1], r % l[2]]
    }

    /// Rank at layout coordinates `q`.
    pub fn rank_at(&self, q: [usize; 3]) -> usize {
        let l = self.layout();
        q[2] + l[2] * (q[1] + l[1] * q[0])
    }

    /// The rank owning position `x` (the box of its lattice cell).
    #[inline]
    pub fn owner(&self, x: Vec3) -> usize {
        let q = std::array::from_fn(|d| {
            let cell = ((x[d] - self.anchor[d]) * self.inv_dx).floor() as i64;
            self.cuts[d].partition_point(|&c| c <= cell)
        });
        self.rank_at(q)
    }

    /// Ranks adjacent to `r` in the layout (diagonals included, `r` excluded), increasing.
    pub fn neighbours(&self, r: usize) -> Vec<usize> {
        let (l, q) = (self.layout(), self.coords(r));
        let mut out = Vec::new();
        for a in q[0].saturating_sub(1)..=(q[0] + 1).min(l[0] - 1) {
            for b in q[1].saturating_sub(1)..=(q[1] + 1).min(l[1] - 1) {
                for c in q[2].saturating_sub(1)..=(q[2] + 1).min(l[2] - 1) {
                    out.push(self.rank_at([a, b, c]));
                }
            }
        }
        out.retain(|&s| s != r);
        out.sort_unstable();
        out
    }

    /// Lattice coordinates (cell widths from the anchor) of rank `r`'s box per axis, as a
    /// half-open interval `[lo, hi)` (infinite at the open ends): `x` is in the box exactly
    /// when `lo <= (x - anchor) / dx < hi` on every axis, the same test as [`RankBoxes::owner`]
    /// without its floor and search.
    pub fn lattice_bounds(&self, r: usize) -> [(f64, f64); 3] {
        let q = self.coords(r);
        std::array::from_fn(|d| {
            let lo = if q[d] == 0 { f64::NEG_INFINITY } else { self.cuts[d][q[d] - 1] as f64 };
            let hi = if q[d] == self.cuts[d].len() { f64::INFINITY } else { self.cuts[d][q[d]] as f64 };
            (lo, hi)
        })
    }

    /// Rank `r`'s local grid inside `global` as node ranges `[lo, hi]` (inclusive, global
    /// node indices): the nodes of its box's cells, clipped to the grid (at least one cell
    /// wide, so a box outside the grid gets the boundary cell next to it). Neighbours'
    /// ranges share one node layer across each cut plane.
    pub fn node_range(&self, r: usize, global: &GridGeom) -> [(usize, usize); 3] {
        let q = self.coords(r);
        std::array::from_fn(|d| {
            let n = global.cells[d] as i64;
            let lo = if q[d] == 0 { i64::MIN / 2 } else { self.cuts[d][q[d] - 1] - global.start[d] };
            let hi = if q[d] == self.cuts[d].len() { i64::MAX / 2 } else { self.cuts[d][q[d]] - global.start[d] };
            let c0 = lo.clamp(0, n - 1);
            let c1 = hi.clamp(c0 + 1, n);
            (c0 as usize, c1 as usize)
        })
    }

    /// Rank `r`'s local grid inside `global`.
    pub fn local_grid(&self, r: usize, global: &GridGeom) -> GridGeom {
        let range = self.node_range(r, global);
        let mut g = *global;
        for d in 0..3 {
            let (c0, c1) = range[d];
            g.start[d] = global.start[d] + c0 as i64;
            g.cells[d] = c1 - c0;
            g.origin[d] = global.origin[d] + c0 as f64 * global.dx;
        }
        g
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;

    /// The step calls the exchange for one process too: its reductions must leave every
    /// value bit for bit (signed zeros and infinite bounds included).
    #[test]
    fn one_process_reductions_change_no_bit() {
        let before = Partial {
            kinetic: 1.0 / 3.0,
            internal: -2.5e-300,
            momentum: [-0.0, 7.0e-17, -1.0e30],
            max_speed: 4321.123,
            lo: [-0.0, f64::INFINITY, -3.25],
            hi: [0.0, f64::NEG_INFINITY, 1e-310],
            non_finite: 2,
            negative_internal: 17,
            failed_floors: 5,
            failed_floor_energy: 0.125,
        };
        let mut after = before;
        reduce_partial(&mut OneProcess::default(), &mut after).unwrap();
        let bits = |p: &Partial| {
            let f = [p.kinetic, p.internal, p.max_speed, p.failed_floor_energy];
            let v = [p.momentum, p.lo, p.hi].concat();
            (
                f.map(f64::to_bits),
                v.iter().map(|x| x.to_bits()).collect::<Vec<_>>(),
                [p.non_finite, p.negative_internal, p.failed_floors],
            )
        };
        assert_eq!(bits(&after), bits(&before));
    }

    fn grid() -> GridGeom {
        GridGeom::fixed(&GridSpec { dx: 0.5, anchor: [1.0, 0.0, 0.0], cells: [8, 4, 2] })
    }

    #[test]
    fn owners_partition_the_lattice_and_local_grids_cover_the_boxes() {
        let g = grid();
        let boxes = RankBoxes::new(uniform_cuts([2, 2, 1], &g).unwrap(), g.origin, g.inv_dx).unwrap();
        assert_eq!(boxes.cuts, [vec![4], vec![2], vec![]]);
        assert_eq!(boxes.ranks(), 4);
        assert_eq!(boxes.owner([1.1, 0.1, 0.1]), 0);
        assert_eq!(boxes.owner([3.0, 0.1, 0.1]), 2); // x lattice cell 4 is the second box
        assert_eq!(boxes.owner([2.99, 1.2, 0.1]), 1);
        assert_eq!(boxes.owner([-50.0, 9.0, 0.1]), 1); // outside the grid: nearest box
        for r in 0..4 {
            assert_eq!(boxes.rank_at(boxes.coords(r)), r);
            assert_eq!(boxes.neighbours(r).len(), 3);
        }
        // Local grids share one node layer across each cut: x node 4, y node 2.
        assert_eq!(boxes.node_range(0, &g), [(0, 4), (0, 2), (0, 2)]);
        assert_eq!(boxes.node_range(3, &g), [(4, 8), (2, 4), (0, 2)]);
        assert_eq!(
            boxes.lattice_bounds(2),
            [(4.0, f64::INFINITY), (f64::NEG_INFINITY, 2.0), (f64::NEG_INFINITY, f64::INFINITY)]
        );
        // The box test of the bounds agrees with the owner, also on the cut planes.
        for x in [[3.0, 0.1, 0.1], [2.9999999, 1.0, 0.1], [3.0, 1.0, 0.1], [-7.0, 4.0, 0.3]] {
            for r in 0..4 {
                let inside = boxes.lattice_bounds(r).iter().enumerate().all(|(d, &(lo, hi))| {
                    let xi = (x[d] - boxes.anchor[d]) * boxes.inv_dx;
                    xi >= lo && xi < hi
                });
                assert_eq!(inside, boxes.owner(x) == r, "{x:?} rank {r}");
            }
        }
        let l = boxes.local_grid(3, &g);
        assert_eq!((l.cells, l.start), ([4, 2, 2], [4, 2, 0]));
        assert_eq!(l.node_position(0, 0, 0), g.node_position(4, 2, 0));
        // A box beyond the grid gets the boundary cell.
        let small = GridGeom { cells: [3, 4, 2], ..g };
        assert_eq!(boxes.node_range(2, &small)[0], (2, 3));
    }

    #[test]
    fn too_many_boxes_for_the_grid_is_an_error() {
        assert!(uniform_cuts([1, 5, 1], &grid()).is_err());
        assert!(RankBoxes::new([vec![3, 3], vec![], vec![]], [0.0; 3], 1.0).is_err());
    }
}
