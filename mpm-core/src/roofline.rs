//! How close each sub-stage of the step runs to the machine's limits: the bytes each
//! sub-stage must move and the floating-point operations it performs, counted from the code
//! ([`COSTS`]), and the rates a run achieved ([`achieved`]) from its stage seconds.
//!
//! **Bytes** are the compulsory traffic of one serial pass: every particle array the pass
//! reads once and writes once (`size_of` of its element), plus every node record it reads
//! or writes once (zeroing a scatter target counts as one write, the scatter as one read and
//! one write of each record, assuming a cell's records stay in cache while its particles go
//! through, as they do for particles in cell order). Traffic a strategy adds (AE copies, DD
//! sub-grids and their assembly) is not in the table: its per-node parts are the serial
//! ones, and the parallel rows are per worker.
//!
//! **Flops** are the additions, subtractions, multiplications, divisions and square roots
//! the code performs per particle (per node for the node loops), as written (in the useful
//! lanes of a vector form): comparisons,
//! selects, `min`/`max`, negations and constants formed once per block or step are not
//! counted. The material update is branch-free, so every particle costs the same whatever
//! its state. The test `material_flops_are_the_counted_ones` counts the material update's
//! operations by running it on a counting number type; the others are derived in the
//! comments of [`COSTS`] and checked against the kernels' shapes (8 nodes, `K` values).
//!
//! Per particle-step the node terms are weighted by nodes per particle (`nodes /
//! particles`, the mean stored nodes of the run): see [`StageCost::per_particle_step`].

use crate::timers::{StageTimes, Substage};
use serde::Serialize;

/// What one sub-stage moves and computes.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StageCost {
    /// The sub-stage.
    #[serde(skip)]
    pub substage: Substage,
    /// Bytes of particle arrays read and written, per particle.
    pub particle_bytes: f64,
    /// Bytes of node records read and written, per node.
    pub node_bytes: f64,
    /// Floating-point operations per particle.
    pub particle_flops: f64,
    /// Floating-point operations per node.
    pub node_flops: f64,
}

impl StageCost {
    /// Bytes and flops per particle-step with `nodes_per_particle` nodes per particle.
    pub fn per_particle_step(&self, nodes_per_particle: f64) -> (f64, f64) {
        (
            self.particle_bytes + self.node_bytes * nodes_per_particle,
            self.particle_flops + self.node_flops * nodes_per_particle,
        )
    }
}

/// Bytes of a 3-vector, a symmetric tensor, a scalar and a flag.
const V3: f64 = 24.0;
const SYM: f64 = 48.0;
const F: f64 = 8.0;
const FLAG: f64 = 1.0;
/// Bytes of a P2G, kinematic and re-map node record (8, 6 and 4 `f64`; the P2G record is
/// one cache line, the re-map record half of one, each with its last value unused).
const P2G_REC: f64 = 64.0;
const KIN_REC: f64 = 48.0;
const REMAP_REC: f64 = 32.0;

/// Bytes of a particle's cell and local coordinates ([`crate::locate::Located`]: 3 `u32`
/// and 3 `f64`).
const LOCATED: f64 = 12.0 + 24.0;

/// Flops of locating one particle ([`crate::locate`], once a step, booked to the scatter):
/// per axis `(x - o) * inv_dx` and `r = xi - c` (3, x 3 = 9).
pub const LOCATE_FLOPS: f64 = 9.0;

/// Flops of one shape-function evaluation from the local coordinates (`shape::at`, and its
/// lane forms in P2G and the particle update): per axis `1 - r` (3); per node `ny nz`,
/// `nx nyz`, `dx nyz`, `nx dy nz`, `nx ny dz` (7, x 8 = 56).
pub const SHAPE_FLOPS: f64 = 3.0 + 56.0;

/// Flops of the material update of one particle ([`crate::material::update_lanes`]: Jaumann
/// rotation, trial deviator, radial return, viscosity, both EOS evaluations, failure,
/// sound and signal speeds), as counted by `material_flops_are_the_counted_ones`.
pub const MATERIAL_FLOPS: f64 = 165.0;

/// The counts of every sub-stage (serial step, dense grid), in [`Substage::ALL`] order.
pub const COSTS: [StageCost; 10] = [
    // reorder (crate::order, every SimConfig::sort_every steps): not counted. Its traffic is
    // per sort, not per step, and a sort of particles already in order reads the positions
    // and writes keys only; the table leaves it at zero, so its rates are not reported.
    StageCost {
        substage: Substage::Reorder,
        particle_bytes: 0.0,
        node_bytes: 0.0,
        particle_flops: 0.0,
        node_flops: 0.0,
    },
    // grid_fit: the adaptive grid's box from last step's bounding box (per step, not per
    // particle); the sparse grid's marking pass reads every position once.
    StageCost {
        substage: Substage::GridFit,
        particle_bytes: V3,
        node_bytes: 0.0,
        particle_flops: 0.0,
        node_flops: 0.0,
    },
    // binning (DD): the counting pass reads x and writes the patch (4 B), the writing pass
    // reads it and writes one Pindex slot (4 B).
    StageCost {
        substage: Substage::Binning,
        particle_bytes: V3 + 4.0 + 4.0 + 4.0,
        node_bytes: 0.0,
        particle_flops: 6.0,
        node_flops: 0.0,
    },
    // scatter: locating the particles (reads x, writes the cells and local coordinates),
    // then P2G (transfer::P2g without body force): reads those, v, mass, rho, stress;
    // zeroes, reads and writes the 64-byte records. Flops: locate, shape, V = m / rho (1),
    // per node sigma . G (9 mul + 6 add), m S (1), m S += (1), m S v (3 + 3), V t (3 + 3):
    // 29 x 8 (the useful lanes: the vector form's unused fourth lanes and its `m S * 1` are
    // not counted).
    StageCost {
        substage: Substage::Scatter,
        particle_bytes: V3 + 2.0 * LOCATED + V3 + 2.0 * F + SYM,
        node_bytes: 3.0 * P2G_REC,
        particle_flops: LOCATE_FLOPS + SHAPE_FLOPS + 1.0 + 8.0 * 29.0,
        node_flops: 0.0,
    },
    // assembly: none in the serial step (AE sums T copies, DD adds the sub-grids).
    StageCost {
        substage: Substage::Assembly,
        particle_bytes: 0.0,
        node_bytes: 0.0,
        particle_flops: 0.0,
        node_flops: 0.0,
    },
    // grid_update (Eq. 6): reads the P2G record, writes the kinematic one. Flops per node
    // with mass: 1 / m, and per axis f mask, (p + f dt) mask, p / m, f / m (6, x 3).
    StageCost {
        substage: Substage::GridUpdate,
        particle_bytes: 0.0,
        node_bytes: P2G_REC + KIN_REC,
        particle_flops: 0.0,
        node_flops: 1.0 + 18.0,
    },
    // gather: fused into the re-map scatter's pass (its time is there too).
    StageCost {
        substage: Substage::Gather,
        particle_bytes: 0.0,
        node_bytes: 0.0,
        particle_flops: 0.0,
        node_flops: 0.0,
    },
    // remap_scatter (the gather and Eq. 11 in one pass): reads the cells and local
    // coordinates, mass, v and writes v; reads the kinematic records, zeroes, reads and
    // writes the re-map ones. Flops: shape, sum S a (2 x 3 x 8), v += dt acc (2 x 3), m v
    // (3), m v S (2 x 3 x 8).
    StageCost {
        substage: Substage::RemapScatter,
        particle_bytes: LOCATED + 2.0 * V3 + F,
        node_bytes: KIN_REC + 3.0 * REMAP_REC,
        particle_flops: SHAPE_FLOPS + 48.0 + 6.0 + 3.0 + 48.0,
        node_flops: 0.0,
    },
    // remap_assembly (transfer::remap_velocity): reads the mass, reads and writes the
    // re-map and kinematic records. Flops per node: 1 / m, per axis inv mask and the
    // product (2), the mid-step velocity 0.5 (v - dt a + v') (4): 1 + 3 x 6.
    StageCost {
        substage: Substage::RemapAssembly,
        particle_bytes: 0.0,
        node_bytes: F + 2.0 * REMAP_REC + 2.0 * KIN_REC,
        particle_flops: 0.0,
        node_flops: 1.0 + 18.0,
    },
    // stress_update: reads and writes x, rho, stress, eps_p, e_int, sound, failed; reads v,
    // mass, the cells and local coordinates; reads the kinematic and re-map records. Flops:
    // shape; sum S v (48), both
    // gradients (2 x 9 x 2 x 8 = 288); the increments (2 x 9) and the spin (6); the
    // material; then x += dt v (6), |v|^2 (5), the energies (3 + 2), momentum (6), the
    // signal speed (sqrt and add: 2) and the finiteness sum (7).
    StageCost {
        substage: Substage::StressUpdate,
        particle_bytes: 2.0 * (V3 + 4.0 * F + SYM + FLAG) + V3 + F + LOCATED,
        node_bytes: KIN_REC + REMAP_REC,
        particle_flops: SHAPE_FLOPS + 48.0 + 288.0 + 18.0 + 6.0 + MATERIAL_FLOPS + 6.0 + 5.0 + 5.0 + 6.0 + 2.0 + 7.0,
        node_flops: 0.0,
    },
];

/// The cost of `s`.
pub fn cost(s: Substage) -> &'static StageCost {
    &COSTS[s as usize]
}

/// What a run achieved in one sub-stage.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Achieved {
    /// The sub-stage's name ([`Substage::name`]).
    pub substage: &'static str,
    /// Bytes per particle-step ([`COSTS`], node terms weighted by nodes per particle).
    pub bytes_per_particle_step: f64,
    /// Flops per particle-step.
    pub flops_per_particle_step: f64,
    /// Nanoseconds per particle-step.
    pub ns_per_particle_step: f64,
    /// Achieved bandwidth (10^9 bytes per second); `None` when the sub-stage took no time or
    /// moves nothing.
    pub gb_per_s: Option<f64>,
    /// Achieved rate (10^9 flops per second); `None` as above.
    pub gflop_per_s: Option<f64>,
}

/// The rates of every sub-stage of a run of `particles` particles over `steps` steps with
/// `nodes` stored nodes on average, from its sub-stage seconds `times` (the whole run's or
/// the steady steps', matching `steps`). `ran(s)` says whether the sub-stage did work in
/// the run (its [`crate::work`] counters are not zero): one that did not moved nothing, and
/// gets no bytes, no flops and no rates (the binning and the grid's re-fit of a serial run on
/// a fixed grid are timed around nothing, a few picoseconds per particle-step, and the cost
/// table's bytes over that time gave thousands of GB/s). Pure: the same inputs give the same
/// figures.
pub fn achieved(
    times: &StageTimes,
    particles: u64,
    nodes: f64,
    steps: u64,
    ran: impl Fn(Substage) -> bool,
) -> [Achieved; 10] {
    let particle_steps = particles as f64 * steps as f64;
    let per_particle = if particles > 0 { nodes / particles as f64 } else { 0.0 };
    std::array::from_fn(|i| {
        let s = Substage::ALL[i];
        let (bytes, flops) = if ran(s) { COSTS[i].per_particle_step(per_particle) } else { (0.0, 0.0) };
        let seconds = times.get(s);
        let rate = |per: f64| (seconds > 0.0 && per > 0.0).then(|| per * particle_steps / seconds / 1e9);
        Achieved {
            substage: s.name(),
            bytes_per_particle_step: bytes,
            flops_per_particle_step: flops,
            ns_per_particle_step: if particle_steps > 0.0 { seconds / particle_steps * 1e9 } else { 0.0 },
            gb_per_s: rate(bytes),
            gflop_per_s: rate(flops),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::material::{BulkViscosity, Material, MgForm, PressureModel};
    use crate::simd::Real;
    use std::cell::Cell;

    thread_local! {
        static FLOPS: Cell<u64> = const { Cell::new(0) };
    }

    /// An `f64` that counts the arithmetic done on it.
    #[derive(Clone, Copy, Debug, Default, PartialEq)]
    struct Counted(f64);

    fn tick() {
        FLOPS.with(|c| c.set(c.get() + 1));
    }

    macro_rules! counted_op {
        ($trait:ident, $method:ident, $op:tt) => {
            impl std::ops::$trait for Counted {
                type Output = Counted;
                fn $method(self, o: Counted) -> Counted {
                    tick();
                    Counted(self.0 $op o.0)
                }
            }
        };
    }
    counted_op!(Add, add, +);
    counted_op!(Sub, sub, -);
    counted_op!(Mul, mul, *);
    counted_op!(Div, div, /);

    impl std::ops::Neg for Counted {
        type Output = Counted;
        fn neg(self) -> Counted {
            Counted(-self.0)
        }
    }

    impl Real for Counted {
        type Mask = bool;
        fn splat(v: f64) -> Self {
            Counted(v)
        }
        fn sqrt(self) -> Self {
            tick();
            Counted(self.0.sqrt())
        }
        fn max(self, o: Self) -> Self {
            Counted(self.0.max(o.0))
        }
        fn le(self, o: Self) -> bool {
            self.0 <= o.0
        }
        fn lt(self, o: Self) -> bool {
            self.0 < o.0
        }
        fn ge(self, o: Self) -> bool {
            self.0 >= o.0
        }
        fn gt(self, o: Self) -> bool {
            self.0 > o.0
        }
        fn select(m: bool, a: Self, b: Self) -> Self {
            if m {
                a
            } else {
                b
            }
        }
        fn mask(v: bool) -> bool {
            v
        }
        const WIDTH: usize = 1;
        fn lane(self, _l: usize) -> f64 {
            self.0
        }
        fn from_lanes(mut f: impl FnMut(usize) -> f64) -> Self {
            Counted(f(0))
        }
    }

    /// The operations of one particle's material update, counted while it runs: the same for
    /// an elastic, a plastic, a failing and a failed particle (branch-free), for both
    /// materials of the paper, and equal to [`MATERIAL_FLOPS`].
    #[test]
    fn material_flops_are_the_counted_ones() {
        for m in [Material::ofhc_copper(MgForm::Hugoniot), Material::lead(MgForm::Hugoniot)] {
            let crate::material::Eos::MieGruneisen(eos) = m.eos else { unreachable!() };
            let c = m.consts().with_viscosity(BulkViscosity::default(), 1e-3);
            for (de, failed) in [(1e-6, false), (-3e-2, false), (4e-2, false), (1e-3, true)] {
                let count = count_update(&c, &eos, de, failed, m.density);
                assert_eq!(count as f64, MATERIAL_FLOPS, "{}: de {de}, failed {failed}", m.name);
            }
        }
    }

    fn count_update<E: PressureModel>(
        c: &crate::material::PointConsts,
        eos: &E,
        de: f64,
        failed: bool,
        rho: f64,
    ) -> u64 {
        let s = |v: f64| Counted(v);
        let state = crate::material::LaneState {
            stress: [-1e8, -2e8, 3e7, 1e6, -2e6, 5e5].map(s),
            eps_p: s(0.1),
            e_int: s(100.0),
            rho: s(rho),
            sound: s(4000.0),
            failed,
        };
        let d = [de, -0.3 * de, 0.2 * de, 0.1 * de, -0.05 * de, 0.02 * de].map(s);
        FLOPS.with(|c| c.set(0));
        let _ = crate::material::update_block::<Counted, E, true>(c, eos, 1e-8, d, d, [0.01 * de; 3].map(s), state);
        FLOPS.with(Cell::get)
    }

    /// The node and particle passes' bytes are the element sizes of the arrays their code
    /// touches: a change of a record or particle array's type changes these.
    #[test]
    fn bytes_follow_the_array_layouts() {
        use crate::grid::{KIN_WIDTH, P2G_WIDTH, REMAP_WIDTH};
        use crate::math::{Sym, Vec3};
        use std::mem::size_of;
        assert_eq!(P2G_REC as usize, P2G_WIDTH * size_of::<f64>());
        assert_eq!(KIN_REC as usize, KIN_WIDTH * size_of::<f64>());
        assert_eq!(REMAP_REC as usize, REMAP_WIDTH * size_of::<f64>());
        assert_eq!(
            (V3 as usize, SYM as usize, FLAG as usize),
            (size_of::<Vec3>(), size_of::<Sym>(), size_of::<bool>())
        );
        // The stress update reads and writes 7 particle arrays and reads 2 more: every array
        // of `Particles`, so its bytes are a particle's bytes plus the 7 written back.
        let mut p = crate::Particles::default();
        p.push([0.0; 3], [0.0; 3], 1.0, 1.0, 1.0);
        p.shrink_to_fit();
        // Written: x, rho, stress, eps_p, e_int, sound, failed.
        let written = V3 + F + SYM + 4.0 * F + FLAG - F;
        // And the particle's cell and local coordinates (`Located`'s arrays), read.
        let geom = crate::grid::GridGeom::fixed(&crate::grid::GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [1; 3] });
        let located = crate::locate::Located::of(&geom, &[[0.5; 3]; 64]);
        assert_eq!(located.bytes() as f64, 64.0 * LOCATED, "64 particles located");
        assert_eq!(cost(Substage::StressUpdate).particle_bytes, p.bytes() as f64 + written + LOCATED);
    }

    #[test]
    fn achieved_rates_are_the_counts_over_the_time() {
        let mut t = StageTimes::default();
        t.add(Substage::Scatter, 2.0);
        t.add(Substage::GridUpdate, 0.5);
        let a = achieved(&t, 1000, 500.0, 100, |_| true);
        let scatter = &a[Substage::Scatter as usize];
        let c = cost(Substage::Scatter);
        let bytes = c.particle_bytes + c.node_bytes * 0.5;
        assert_eq!(scatter.bytes_per_particle_step, bytes);
        assert!((scatter.gb_per_s.unwrap() - bytes * 1e5 / 2.0 / 1e9).abs() < 1e-15);
        assert!((scatter.gflop_per_s.unwrap() - c.particle_flops * 1e5 / 2.0 / 1e9).abs() < 1e-15);
        assert_eq!(scatter.ns_per_particle_step, 2.0 / 1e5 * 1e9);
        // Node loops: per node, weighted by nodes per particle.
        let g = &a[Substage::GridUpdate as usize];
        assert_eq!(g.flops_per_particle_step, 19.0 * 0.5);
        // No time or nothing moved: no rate.
        assert_eq!(a[Substage::Gather as usize].gb_per_s, None);
        assert_eq!(a[Substage::Assembly as usize].gflop_per_s, None);
        assert_eq!(a.map(|x| x.substage), Substage::ALL.map(Substage::name));
    }
}
