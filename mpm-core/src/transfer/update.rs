//! The particle update (Eqs. 7, 9, 12-15): positions, strain and spin increments from the
//! nodal velocities, the material update, and each worker's sums, in blocks of particles
//! at the SIMD level asked for.

use crate::energy::Partial;
use crate::grid::{records, GridGeom, NodeArrays, KIN_WIDTH, REMAP_WIDTH};
use crate::locate::Located;
use crate::material::{update_block, LaneState, PointConsts, PressureModel};
use crate::math::{Sym, Vec3};
use crate::node_index::{CellNodes, NodeIndex};
use crate::parallel::{partition, Exec, Split};
use crate::particles::Particles;
use crate::shape::Local;
use crate::simd::{array, Block, Real, SimdLevel, F4, F8, LANES, LANES8};

/// Eq. 12: the strain increment `dt sym(L)` of the velocity gradient `L` (`L[a][b] =
/// dv_a / dx_b`), in Voigt order.
#[inline(always)]
fn strain_increment<R: Real>(l: &[[R; 3]; 3], dt: f64) -> [R; 6] {
    let (dt, half_dt) = (R::splat(dt), R::splat(0.5 * dt));
    [
        dt * l[0][0],
        dt * l[1][1],
        dt * l[2][2],
        half_dt * (l[1][2] + l[2][1]),
        half_dt * (l[2][0] + l[0][2]),
        half_dt * (l[0][1] + l[1][0]),
    ]
}

/// Eqs. 7, 9, 12-15 and the reductions, by loop splitting: positions from the updated
/// nodal velocities, strain and spin increments from the re-mapped ones, then the material
/// update; worker `w` writes its sums to `partials[w]`.
///
/// The internal energy gains the work of the old stress over the strain increment of the
/// mid-step nodal velocity `(v_i(k) + v_i(k+1)) / 2`. The kinetic energy changes by
/// `dt sum_i f_i . (v_i(k) + v_i(k+1)) / 2` (the gather and the re-map use the same shape
/// functions), so kinetic plus internal energy changes exactly by the work of the body
/// forces: the energy balance holds to round-off (see [`crate::material::update_point`]).
///
/// The particles go through in blocks of [`LANES`] (of 8 at AVX-512): the increments of each
/// particle of a block from its nodes (read once per run of the block's particles in one
/// cell: particles in cell order, [`crate::order`], share their cell with their
/// neighbours), then the material update of the whole block at once
/// ([`crate::material::update_lanes`], vector instructions at the level `simd`, which must
/// be available on this CPU), then positions and sums particle by particle in order. Every
/// value is bitwise that of the particle-by-particle form.
#[allow(clippy::too_many_arguments)]
pub fn update<E: PressureModel + Sync>(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    located: &Located,
    nodes: &NodeArrays,
    particles: &mut Particles,
    consts: &PointConsts,
    eos: &E,
    dt: f64,
    partials: &mut [Partial],
    simd: SimdLevel,
) {
    assert!(simd.is_available(), "the particle update at SIMD level {simd}, which this CPU does not have");
    let n = particles.len();
    assert_eq!(located.len(), n, "one location per particle");
    let Particles { x, v, mass, rho, stress, eps_p, e_int, sound, failed } = particles;
    let (v, mass) = (&v[..], &mass[..]);
    let (kin, remap) = (&nodes.kin[..], &nodes.remap[..]);
    let t = exec.workers();
    let chunks = (
        Split::Even.of(x),
        Split::Even.of(rho),
        Split::Even.of(stress),
        Split::Even.of(eps_p),
        Split::Even.of(e_int),
        Split::Even.of(sound),
        Split::Even.of(failed),
        Split::Blocks(1).of(partials),
    );
    let tally = crate::work::Tally::of(exec);
    exec.for_each_chunk_mut(chunks, |w, (x, rho, stress, eps_p, e_int, sound, failed, acc)| {
        let r = partition(n, t, w);
        tally.particles(w, r.len());
        let mut chunk = UpdateChunk {
            inv_dx: geom.inv_dx,
            located,
            first: r.start,
            index: *index,
            kin,
            remap,
            consts,
            eos,
            dt,
            v: &v[r.clone()],
            mass: &mass[r],
            x,
            rho,
            stress,
            eps_p,
            e_int,
            sound,
            failed,
        };
        acc[0] = chunk.run(simd);
    });
}

/// Placeholders of the per-lane node records of a block before they are looked up.
static NO_KIN: [f64; KIN_WIDTH] = [0.0; KIN_WIDTH];
static NO_REMAP: [f64; REMAP_WIDTH] = [0.0; REMAP_WIDTH];

/// One worker's particles in [`update`]: the shared node arrays and its own particle parts.
struct UpdateChunk<'a, E> {
    inv_dx: f64,
    /// The particles' cells and local coordinates (all of them: the chunk's from `first`).
    located: &'a Located,
    /// The chunk's first particle.
    first: usize,
    index: NodeIndex<'a>,
    kin: &'a [[f64; KIN_WIDTH]],
    remap: &'a [[f64; REMAP_WIDTH]],
    consts: &'a PointConsts,
    eos: &'a E,
    dt: f64,
    v: &'a [Vec3],
    mass: &'a [f64],
    x: &'a mut [Vec3],
    rho: &'a mut [f64],
    stress: &'a mut [Sym],
    eps_p: &'a mut [f64],
    e_int: &'a mut [f64],
    sound: &'a mut [f64],
    failed: &'a mut [bool],
}

impl<E: PressureModel> UpdateChunk<'_, E> {
    /// The chunk's update at level `simd` (checked available by [`update`]); its sums.
    fn run(&mut self, simd: SimdLevel) -> Partial {
        let linear = self.consts.hardening.n == 1.0;
        #[cfg(target_arch = "x86_64")]
        if simd >= SimdLevel::Avx2 {
            assert!(simd.is_available(), "SIMD level {simd} asked for on a CPU without it");
            // SAFETY: `run_avx2` and `run_avx512` are compiled with AVX2, resp. AVX-512F,
            // enabled, and the line above has just checked (through
            // `is_x86_feature_detected!`) that this CPU executes the level called. The test
            // `dispatch_levels_agree_bitwise` runs every level the CPU has; a call on a CPU
            // without it would stop at the assertion, not at an illegal instruction.
            return unsafe {
                match (simd, linear) {
                    (SimdLevel::Avx512, true) => self.run_avx512::<true>(),
                    (SimdLevel::Avx512, false) => self.run_avx512::<false>(),
                    (_, true) => self.run_avx2::<true>(),
                    (_, false) => self.run_avx2::<false>(),
                }
            };
        }
        #[cfg(not(target_arch = "x86_64"))]
        let _ = simd;
        if linear {
            self.run_lanes::<F4, LANES, true>()
        } else {
            self.run_lanes::<F4, LANES, false>()
        }
    }

    /// [`UpdateChunk::run_lanes`] in blocks of 4 compiled for AVX2.
    ///
    /// # Safety
    /// The CPU must execute AVX2 (`SimdLevel::Avx2.is_available()`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn run_avx2<const LINEAR: bool>(&mut self) -> Partial {
        self.run_lanes::<F4, LANES, LINEAR>()
    }

    /// [`UpdateChunk::run_lanes`] in blocks of 8 compiled for AVX-512F.
    ///
    /// # Safety
    /// The CPU must execute AVX-512F (`SimdLevel::Avx512.is_available()`).
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f,avx2")]
    unsafe fn run_avx512<const LINEAR: bool>(&mut self) -> Partial {
        self.run_lanes::<F8, LANES8, LINEAR>()
    }

    /// The chunk in blocks of `N` particles (the last block's unused lanes repeat its last
    /// particle and are not written back). Every quantity of a block is one `R` ([`F4`] or
    /// [`F8`]), lane `l` particle `l`: the shape functions, the sums over the 8 nodes (the
    /// nodes' values by one broadcast per run of lanes in one cell), the increments, the
    /// material update; then positions and sums particle by particle, in order. Each lane
    /// computes its particle's values with the operations, in the order, of
    /// `shape::evaluate` and the scalar sums.
    #[inline(always)]
    fn run_lanes<R: Block<N>, const N: usize, const LINEAR: bool>(&mut self) -> Partial {
        let dt = self.dt;
        let n = self.x.len();
        let inv_dx = self.inv_dx;
        let mut sum = Partial::default();
        let mut nodes = CellNodes::new(self.index);
        let mut start = 0;
        while start < n {
            let len = N.min(n - start);
            let k: [usize; N] = array(|l| start + l.min(len - 1));
            // The block's cells and local coordinates, the nodes of each lane's cell; the
            // weights and gradients node by node in `BlockNodes::sums` (keeping the 32 values
            // of a whole `BlockShape` took 4-9 % longer at AVX-512: they went through the
            // stack).
            let (cells, local) = self.located.local_block::<R, N>(&k.map(|k| self.first + k), inv_dx);
            let block = BlockNodes::<R, N>::of(&cells, &mut nodes, self.kin, self.remap);
            let (vx, lv, lm) = block.sums(&local);
            let (de, dw, de_mid) = increments(&lv, &lm, dt);
            let state = self.state::<R, N>(&k);
            let (out, signal, floor) = update_block::<R, E, LINEAR>(self.consts, self.eos, dt, de, de_mid, dw, state);
            self.store(start, len, &BlockOut::of(&out, &vx, signal, floor), &mut sum);
            start += len;
        }
        sum
    }

    /// The material state of the block's particles `k`, lane `l` particle `k[l]`.
    #[inline(always)]
    fn state<R: Block<N>, const N: usize>(&self, k: &[usize; N]) -> LaneState<R> {
        LaneState {
            stress: array(|i| R::from_lanes(|l| self.stress[k[l]][i])),
            eps_p: R::from_lanes(|l| self.eps_p[k[l]]),
            e_int: R::from_lanes(|l| self.e_int[k[l]]),
            rho: R::from_lanes(|l| self.rho[k[l]]),
            sound: R::from_lanes(|l| self.sound[k[l]]),
            failed: R::mask_from(|l| self.failed[k[l]]),
        }
    }

    /// The block's `len` particles from `start`, particle by particle in order: the new state,
    /// the position (Eq. 7) and their terms of the sums.
    #[inline(always)]
    fn store<const N: usize>(&mut self, start: usize, len: usize, b: &BlockOut<N>, sum: &mut Partial) {
        let dt = self.dt;
        for l in 0..len {
            let k = start + l;
            let st: Sym = std::array::from_fn(|i| b.stress[i][l]);
            self.stress[k] = st;
            let e = b.e_int[l];
            self.eps_p[k] = b.eps_p[l];
            self.e_int[k] = e;
            self.rho[k] = b.rho[l];
            self.sound[k] = b.sound[l];
            self.failed[k] = b.failed[l];
            let xp = &mut self.x[k];
            for a in 0..3 {
                xp[a] += dt * b.vx[a][l];
            }
            let vp = self.v[k];
            let m = self.mass[k];
            let v2 = vp[0] * vp[0] + vp[1] * vp[1] + vp[2] * vp[2];
            sum.kinetic += 0.5 * m * v2;
            sum.internal += m * e;
            sum.negative_internal += u64::from(e < -self.consts.energy_tolerance);
            if b.floor[l] > 0.0 {
                sum.failed_floors += 1;
                sum.failed_floor_energy += m * b.floor[l];
            }
            for a in 0..3 {
                sum.momentum[a] += m * vp[a];
                sum.lo[a] = sum.lo[a].min(xp[a]);
                sum.hi[a] = sum.hi[a].max(xp[a]);
            }
            sum.max_speed = sum.max_speed.max(b.signal[l] + v2.sqrt());
            let finite = (xp[0] + xp[1] + xp[2] + v2 + st[0] + st[1] + st[2] + e).is_finite();
            if !finite {
                sum.non_finite += 1;
            }
        }
    }
}

/// The node values of a block: the block in runs of lanes in one cell (particles of a cell
/// are neighbours: the cell order, `crate::order`), each run's 8 node records looked up
/// once. Each node value of the block is then built from one broadcast per run (lanes from
/// the run's first on take the run's value), not gathered lane by lane.
struct BlockNodes<'a, R: Real, const N: usize> {
    /// Runs in the block (at least 1).
    runs: usize,
    /// Per run, its cell's 8 records of `[v, a]` (of `[v, v_mid]` after the re-map).
    kin: [[&'a [f64; KIN_WIDTH]; 8]; N],
    /// Per run, its cell's 8 re-mapped velocity records.
    remap: [[&'a [f64; REMAP_WIDTH]; 8]; N],
    /// Per run, the lanes from its first on.
    from: [R::Mask; N],
}

impl<'a, R: Block<N>, const N: usize> BlockNodes<'a, R, N> {
    /// The runs of the block whose lanes lie in `cells`, their records out of `kin` and
    /// `remap` through `nodes`.
    #[inline(always)]
    fn of(
        cells: &[[u32; 3]; N],
        nodes: &mut CellNodes<'_>,
        kin: &'a [[f64; KIN_WIDTH]],
        remap: &'a [[f64; REMAP_WIDTH]],
    ) -> Self {
        let mut first = [0usize; N];
        let mut runs = 1;
        for l in 1..N {
            if cells[l] != cells[l - 1] {
                first[runs] = l;
                runs += 1;
            }
        }
        let mut block = Self { runs, kin: [[&NO_KIN; 8]; N], remap: [[&NO_REMAP; 8]; N], from: [R::mask(true); N] };
        for r in 0..runs {
            let idx = nodes.get(cells[first[r]].map(|c| c as usize));
            block.kin[r] = records(kin, &idx);
            block.remap[r] = records(remap, &idx);
            block.from[r] = R::mask_from(|l| l >= first[r]);
        }
        block
    }

    /// The sums over the 8 nodes with the weights and gradients of `local`: the velocity of
    /// Eq. 7, the gradient of the re-mapped velocity (Eq. 12) and of the mid-step velocity.
    #[inline(always)]
    #[allow(clippy::type_complexity)]
    fn sums(&self, local: &Local<R>) -> ([R; 3], [[R; 3]; 3], [[R; 3]; 3]) {
        let zero = R::splat(0.0);
        let mut vx = [zero; 3];
        let mut lv = [[zero; 3]; 3];
        let mut lm = [[zero; 3]; 3];
        for q in 0..8 {
            let (w, gq) = local.node(q);
            let mut kin_q: [R; KIN_WIDTH] = array(|i| R::splat(self.kin[0][q][i]));
            let mut remap_q: [R; 3] = array(|i| R::splat(self.remap[0][q][i]));
            for r in 1..self.runs {
                for i in 0..KIN_WIDTH {
                    kin_q[i] = R::select(self.from[r], R::splat(self.kin[r][q][i]), kin_q[i]);
                }
                for i in 0..3 {
                    remap_q[i] = R::select(self.from[r], R::splat(self.remap[r][q][i]), remap_q[i]);
                }
            }
            for i in 0..3 {
                // Eq. 7's velocity, Eq. 12's gradient, the mid-step gradient.
                vx[i] = vx[i] + w * kin_q[i];
                for j in 0..3 {
                    lv[i][j] = lv[i][j] + remap_q[i] * gq[j];
                    lm[i][j] = lm[i][j] + kin_q[3 + i] * gq[j];
                }
            }
        }
        (vx, lv, lm)
    }
}

/// The strain increment (Eq. 12), the spin increment and the mid-step strain increment of
/// the velocity gradients `lv` (re-mapped) and `lm` (mid-step).
#[inline(always)]
fn increments<R: Real>(lv: &[[R; 3]; 3], lm: &[[R; 3]; 3], dt: f64) -> ([R; 6], [R; 3], [R; 6]) {
    let de = strain_increment(lv, dt);
    let half_dt = R::splat(0.5 * dt);
    let dw = [half_dt * (lv[1][2] - lv[2][1]), half_dt * (lv[2][0] - lv[0][2]), half_dt * (lv[0][1] - lv[1][0])];
    let de_mid = strain_increment(lm, dt);
    (de, dw, de_mid)
}

/// A block's results, every lane out of the registers once (see `Block::to_array`), for
/// [`UpdateChunk::store`] to take particle by particle.
struct BlockOut<const N: usize> {
    stress: [[f64; N]; 6],
    /// Eq. 7's velocity.
    vx: [[f64; N]; 3],
    eps_p: [f64; N],
    e_int: [f64; N],
    rho: [f64; N],
    sound: [f64; N],
    failed: [bool; N],
    /// The signal speed.
    signal: [f64; N],
    /// The energy the failed-particle rule added.
    floor: [f64; N],
}

impl<const N: usize> BlockOut<N> {
    /// The material update's `out`, `signal` and `floor` and the velocity `vx`.
    #[inline(always)]
    fn of<R: Block<N>>(out: &LaneState<R>, vx: &[R; 3], signal: R, floor: R) -> Self {
        Self {
            stress: std::array::from_fn(|i| out.stress[i].to_array()),
            vx: std::array::from_fn(|a| vx[a].to_array()),
            eps_p: out.eps_p.to_array(),
            e_int: out.e_int.to_array(),
            rho: out.rho.to_array(),
            sound: out.sound.to_array(),
            failed: R::mask_bools(out.failed),
            signal: signal.to_array(),
            floor: floor.to_array(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The particle update of a cell-ordered Taylor bar (blocks whose lanes lie in one, two or
    /// more cells: each run of one cell's lanes takes its nodes' values by one broadcast)
    /// gives every particle bitwise what the same update gives it alone (a block of one
    /// lane, one run), at every SIMD level this CPU has. A lane given another run's node
    /// values, or a run's lanes cut or joined wrongly, fails it.
    #[test]
    fn update_in_runs_of_one_cell_is_bitwise_each_particle_alone() {
        use crate::material::Eos;
        let setup = crate::scenario::taylor::TaylorBar::default().setup().unwrap();
        let mut sim = crate::Simulation::new(setup, crate::SimConfig::default(), crate::testing::pool(1)).unwrap();
        for _ in 0..3 {
            sim.step(f64::INFINITY).unwrap();
        }
        let geom = *sim.geom();
        let index = NodeIndex::of(&geom, None);
        let consts = *sim.point_consts();
        let Eos::MieGruneisen(eos) = sim.material().eos else { unreachable!("copper uses Mie-Grüneisen") };
        // 2000 particles in cell order (the solver sorted them before its first step).
        let mut some = Particles::default();
        let mut packed = Vec::new();
        for p in 0..2000 {
            packed.clear();
            sim.particles().pack(p, &mut packed);
            some.push_packed(&packed);
        }
        let cell = |p: &Particles, i| geom.shape(p.x[i]).cell;
        let shared = (1..some.len()).filter(|&i| cell(&some, i) == cell(&some, i - 1)).count();
        assert!(4 * shared > 3 * some.len(), "the particles are not in runs of one cell: {shared} of 2000 share");
        let dt = 2e-9;
        let update_at = |p: &mut Particles, simd| {
            let mut partials = vec![Partial::default(); 1];
            let located = Located::of(&geom, &p.x);
            update(&Exec::serial(), &geom, &index, &located, sim.nodes(), p, &consts, &eos, dt, &mut partials, simd);
        };
        for simd in SimdLevel::ALL.into_iter().filter(|l| l.is_available()) {
            let mut all = some.clone();
            update_at(&mut all, simd);
            for i in 0..some.len() {
                let mut alone = Particles::default();
                packed.clear();
                some.pack(i, &mut packed);
                alone.push_packed(&packed);
                update_at(&mut alone, simd);
                packed.clear();
                all.pack(i, &mut packed);
                let mut want = Vec::new();
                alone.pack(0, &mut want);
                let same = packed.iter().zip(&want).all(|(a, b)| a.to_bits() == b.to_bits());
                assert!(same, "particle {i} at {simd}: in its block {packed:?}, alone {want:?}");
            }
        }
    }
}
