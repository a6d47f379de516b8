//! The per-particle and per-node kernels of the MUSL step (Eqs. 1-15), shared by every
//! strategy. The scatter kernels ([`P2g`]; the gather fused with the re-map,
//! `GatherRemap`) add what one particle gives its 8 nodes into the node records the
//! strategy hands them; the strategy decides which particles and which records. The other
//! passes are split across workers by loop splitting (particles) or by node rows (nodes),
//! through an [`Exec`].
//!
//! They are public (the fused gather through [`gather_remap_serial`]) so that benchmarks
//! measure exactly the code the solver runs.

use crate::blocks::{BlockMap, BLOCK, BLOCK_NODES};
use crate::energy::Partial;
use crate::grid::{records, GridGeom, NodeArrays, WallLayers, KIN_WIDTH, P2G_WIDTH, REMAP_WIDTH};
use crate::locate::Located;
use crate::material::{update_block, LaneState, PointConsts, PressureModel};
use crate::math::{Sym, Vec3};
use crate::node_index::{CellNodes, NodeIndex};
use crate::parallel::{partition, DisjointSlice, Exec, Split};
use crate::particles::Particles;
use crate::simd::{array, Block, Real, SimdLevel, F4, F8, LANES, LANES8};
use crate::strategy::{Cursors, Kernel};

/// A scatter kernel's loop over a strategy's particles, which the kernel may run a block
/// of particles at a time ([`P2g`]: the shape functions of [`LANES`] particles as vectors,
/// [`Located::shape_block`], then each particle's additions to its 8 nodes).
trait Blocked<const K: usize> {
    /// Add the values of the particles `ids`, in order, into `data`.
    fn blocks(&self, ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut [[f64; K]]);
}

/// The next block of at most `N` particles of `ids` and how many there are (0: none left);
/// the lanes past them repeat the last one (their values are computed and not used).
#[inline(always)]
fn next_block<const N: usize>(ids: &mut impl Iterator<Item = usize>) -> ([usize; N], usize) {
    let mut k = [0usize; N];
    let mut len = 0;
    while len < N {
        match ids.next() {
            Some(p) => {
                k[len] = p;
                len += 1;
            }
            None => break,
        }
    }
    if len > 0 {
        let last = k[len - 1];
        for slot in &mut k[len..] {
            *slot = last;
        }
    }
    (k, len)
}

/// `kernel`'s loop over the particles `ids` at the level `simd`: the copy of the loop compiled
/// for AVX2 where that is asked for, the baseline one otherwise. AVX-512 runs it at AVX2
/// (P2G has a kernel of its own there, [`P2g`]): the records are added 4 lanes at a time, and
/// the loop compiled for AVX-512F (the P2G shape functions in blocks of 8) took longer, P2G
/// 0.83 and the gather/re-map 1.12 of the 4407a32 code's time against 0.76 and 1.02 at AVX2
/// (medians of 8 alternated runs each).
#[inline(always)]
fn scatter_at<const K: usize, Kn: Blocked<K>>(
    kernel: &Kn,
    simd: SimdLevel,
    ids: impl Iterator<Item = usize>,
    nodes: &mut Cursors<'_>,
    data: &mut [[f64; K]],
) {
    #[cfg(target_arch = "x86_64")]
    if simd >= SimdLevel::Avx2 {
        assert!(SimdLevel::Avx2.is_available(), "AVX2 asked for on a CPU without it");
        // SAFETY: `scatter_avx2` is compiled with AVX2 enabled, and the line above has just
        // checked (through `is_x86_feature_detected!`) that this CPU executes AVX2. The test
        // `dispatch_levels_agree_bitwise` runs both levels.
        unsafe { scatter_avx2(kernel, ids, nodes, data) };
        return;
    }
    kernel.blocks(ids, nodes, data);
}

/// [`scatter_at`]'s loop compiled for AVX2.
///
/// # Safety
/// The CPU must execute AVX2 (`SimdLevel::Avx2.is_available()`).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn scatter_avx2<const K: usize, Kn: Blocked<K>>(
    kernel: &Kn,
    ids: impl Iterator<Item = usize>,
    nodes: &mut Cursors<'_>,
    data: &mut [[f64; K]],
) {
    kernel.blocks(ids, nodes, data);
}

/// The P2G kernel (Eqs. 1-5) as a scatter [`Kernel`]: particle `p` adds mass `m_p S_ip`,
/// momentum `m_p v_p S_ip` and force `-V_p sigma_p . G_ip + m_p S_ip b` to its 8 nodes,
/// straight into their 64-byte records `[m, p_x, p_y, p_z | f_x, f_y, f_z, 0]`, each half one
/// [`F4`] (one AVX2 register): `m S [1, v]` and `sigma . G = S_x G_x + S_y G_y + S_z G_z`
/// with the columns `S_b` of the stress, each lane summed in [`crate::math::sym_mul_vec`]'s
/// order, so every value is bitwise the scalar form's. `BODY` says whether the body force
/// `b` is on; without it (the paper's problems) its terms are not computed (`f -= V t`,
/// bitwise `f += 0 - V t`). The strategy's loop runs at the level `simd` (which must be
/// available on this CPU), in blocks of [`LANES`] particles: the block's shape functions,
/// `V = m / rho` and `m S` as [`F4`]s, one lane per particle (each lane bitwise the
/// one-particle value), then each particle's 8 node records in order. Against the
/// particle-at-a-time form (4407a32), P2G took 0.76 of the time (median of 8 alternated
/// runs of serial Model 1; test `blocked_p2g_is_bitwise_one_particle_at_a_time`). At
/// AVX-512 the loop is `p2g512`'s instead: one particle at a time with its 8 nodes in the 8
/// lanes of a register and an 8 x 8 transpose into the records, bitwise the same sums, 0.62
/// of the blocked form's time.
#[derive(Clone, Copy)]
pub struct P2g<'a, const BODY: bool> {
    /// The grid of this step.
    pub geom: &'a GridGeom,
    /// The particles at step `k`.
    pub particles: &'a Particles,
    /// Their cells and local coordinates in `geom`.
    pub located: &'a Located,
    /// Body force per unit mass (m/s^2); ignored unless `BODY`.
    pub body_force: Vec3,
    /// The instruction-set level of the scatter loop.
    pub simd: SimdLevel,
}

impl<const BODY: bool> Blocked<P2G_WIDTH> for P2g<'_, BODY> {
    #[inline(always)]
    fn blocks(&self, mut ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut [[f64; P2G_WIDTH]]) {
        let pt = self.particles;
        let b = F4([self.body_force[0], self.body_force[1], self.body_force[2], 0.0]);
        loop {
            let (k, len) = next_block::<LANES>(&mut ids);
            if len == 0 {
                return;
            }
            let s = self.located.shape_block::<F4, LANES>(&k, self.geom.inv_dx);
            let m = F4::from_lanes(|l| pt.mass[k[l]]);
            // Out of the registers once (see `Block::to_array`).
            let vol = (m / F4::from_lanes(|l| pt.rho[k[l]])).to_array();
            let mw: [[f64; LANES]; 8] = array(|q| (m * s.w[q]).to_array());
            for (l, &p) in k[..len].iter().enumerate() {
                let idx = nodes.target(s.cell[l]);
                let vol = F4::splat(vol[l]);
                let vp = pt.v[p];
                let st = &pt.stress[p];
                // sigma . g = S_x g_x + S_y g_y + S_z g_z: the columns of the stress in Voigt order.
                let columns =
                    [F4([st[0], st[5], st[4], 0.0]), F4([st[5], st[1], st[3], 0.0]), F4([st[4], st[3], st[2], 0.0])];
                let one_v = F4([1.0, vp[0], vp[1], vp[2]]);
                for q in 0..8 {
                    let g = &s.g[q];
                    let t = columns[0] * F4::splat(g[0].lane(l))
                        + columns[1] * F4::splat(g[1].lane(l))
                        + columns[2] * F4::splat(g[2].lane(l));
                    let mw = F4::splat(mw[q][l]);
                    let d = &mut data[idx[q]];
                    let lo = F4([d[0], d[1], d[2], d[3]]) + mw * one_v;
                    let f = F4([d[4], d[5], d[6], d[7]]);
                    let hi = if BODY { f + (mw * b - vol * t) } else { f - vol * t };
                    *d = [lo.0[0], lo.0[1], lo.0[2], lo.0[3], hi.0[0], hi.0[1], hi.0[2], hi.0[3]];
                }
            }
        }
    }
}

impl<const BODY: bool> Kernel<P2G_WIDTH> for P2g<'_, BODY> {
    #[inline(always)]
    fn scatter(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut [[f64; P2G_WIDTH]]) {
        self.blocks(std::iter::once(p), nodes, data);
    }

    #[inline(always)]
    fn scatter_all(&self, ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut [[f64; P2G_WIDTH]]) {
        #[cfg(target_arch = "x86_64")]
        if self.simd >= SimdLevel::Avx512 {
            assert!(SimdLevel::Avx512.is_available(), "AVX-512 asked for on a CPU without it");
            // SAFETY: `p2g512::scatter` is compiled with AVX-512F, and the line above has
            // just checked that this CPU executes it.
            unsafe { p2g512::scatter(self, ids, nodes, data) };
            return;
        }
        scatter_at(self, self.simd, ids, nodes, data);
    }
}

#[cfg(target_arch = "x86_64")]
mod p2g512;

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
    fn blocks(&self, ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut [[f64; REMAP_WIDTH]]) {
        for p in ids {
            self.scatter(p, nodes, data);
        }
    }
}

impl Kernel<REMAP_WIDTH> for GatherRemap<'_> {
    #[inline(always)]
    fn scatter_all(&self, ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut [[f64; REMAP_WIDTH]]) {
        scatter_at(self, self.simd, ids, nodes, data);
    }

    #[inline(always)]
    fn scatter(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut [[f64; REMAP_WIDTH]]) {
        let s = self.located.shape(p, self.inv_dx);
        let (target, grid) = nodes.both(s.cell);
        let mut acc = [0.0; 3];
        for q in 0..8 {
            let a = &self.kin[grid[q]];
            for k in 0..3 {
                acc[k] += s.w[q] * a[3 + k];
            }
        }
        // SAFETY: the kernel is crate-private and only the crate's three strategies call it,
        // through `Engine::scatter`; each calls it exactly once per particle per scatter, on
        // the one worker that owns the particle (serial: 0..n; AE: worker j's chunk
        // `partition(n, T, j)`; DD: the ids in `Pindex(:, j)`, each particle in one column).
        // So no other reference to `v[p]` exists during this call. Guarded by the test
        // `every_strategy_scatters_every_particle_once` (and the equivalence tests).
        let vp = unsafe { self.v.get_mut(p) };
        for k in 0..3 {
            vp[k] += self.dt * acc[k];
        }
        let m = self.mass[p];
        let mv = F4([m * vp[0], m * vp[1], m * vp[2], 0.0]);
        for q in 0..8 {
            let d = &mut data[target[q]];
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

/// How the node loops split a grid's nodes between workers: node rows of a dense grid, or
/// the blocks of a sparse one (whole parts of the node arrays either way).
fn node_split(geom: &GridGeom, index: &NodeIndex<'_>) -> Split<'static> {
    match index {
        NodeIndex::Box { lo, dims } => {
            assert!(*lo == [0; 3] && *dims == geom.node_dims(), "the node loops run over the whole grid");
            Split::EvenRows(dims[0])
        }
        NodeIndex::Blocks(_) => Split::EvenRows(BLOCK_NODES),
    }
}

/// Visit every node of the grid with its wall mask (1 = free component, 0 = constrained),
/// parallel over node rows (dense) or blocks (sparse): `f(node, mask, &mut out[node])`.
fn for_each_node<T, F>(exec: &Exec<'_>, geom: &GridGeom, index: &NodeIndex<'_>, walls: &WallLayers, out: &mut [T], f: F)
where
    T: Send,
    F: Fn(usize, Vec3, &mut T) + Sync,
{
    let t = exec.workers();
    let tally = crate::work::Tally::of(exec);
    exec.for_each_chunk_mut(node_split(geom, index).of(out), |w, mine| {
        tally.updated(w, mine.len());
        visit_nodes(geom, index, walls, w, t, |n, mask, local| f(n, mask, &mut mine[local]));
    });
}

/// Worker `w`'s nodes out of `t` (the split of [`node_split`]): `f(node, mask, local)` for
/// each node of the grid, `local` its index within the worker's part. On a sparse grid the
/// stored nodes past the grid's last node layer (in blocks at its upper end) are skipped.
#[inline(always)]
fn visit_nodes(
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    walls: &WallLayers,
    w: usize,
    t: usize,
    mut f: impl FnMut(usize, Vec3, usize),
) {
    let d = geom.node_dims();
    let has_x = walls.x_layers().next().is_some();
    match index {
        NodeIndex::Box { .. } => {
            for (ri, row) in partition(d[1] * d[2], t, w).enumerate() {
                let mask_row = walls.row_mask(row % d[1], row / d[1]);
                for i in 0..d[0] {
                    f(row * d[0] + i, walls.node_mask(mask_row, i, has_x), ri * d[0] + i);
                }
            }
        }
        NodeIndex::Blocks(map) => {
            let parts = partition(map.len(), t, w);
            let first = parts.start;
            for s in parts {
                let b = map.block(s);
                BlockMap::rows_in(b, [0; 3], geom.cells, |[a0, bb, c], locals| {
                    let mask_row = walls.row_mask(b[1] * BLOCK[1] + bb, b[2] * BLOCK[2] + c);
                    for (a, l) in (a0..).zip(locals) {
                        let mask = walls.node_mask(mask_row, b[0] * BLOCK[0] + a, has_x);
                        f(s * BLOCK_NODES + l, mask, (s - first) * BLOCK_NODES + l);
                    }
                });
            }
        }
    }
}

/// Eq. 6 and the walls: `p += f dt`; wall nodes lose the constrained components of `p`
/// and `f`; `v = p/m`, `a = f/m` (zero on massless nodes). Parallel over node rows.
pub fn grid_update(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    walls: &WallLayers,
    nodes: &mut NodeArrays,
    dt: f64,
    tol: f64,
) {
    let NodeArrays { p2g, kin, .. } = nodes;
    let p2g = &p2g[..];
    for_each_node(exec, geom, index, walls, kin, |n, mask, o| {
        let a = &p2g[n];
        let m = a[0];
        if m > tol {
            let inv = 1.0 / m;
            for k in 0..3 {
                let f = a[4 + k] * mask[k];
                let p = (a[1 + k] + a[4 + k] * dt) * mask[k];
                o[k] = p * inv;
                o[3 + k] = f * inv;
            }
        } else {
            *o = [0.0; KIN_WIDTH];
        }
    });
}

/// Eq. 11, second half: `v_i = p_i / m_i` with the walls applied again, in place. Also
/// replaces the acceleration in `kin` (used by the gather, which has run) by the mid-step
/// velocity `(v_i(k) + v_i(k+1)) / 2 = (v - dt a + v_remap) / 2`, whose gradient the
/// particle update needs for the work of the stress: once per node here instead of once per
/// particle and node there.
pub fn remap_velocity(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    walls: &WallLayers,
    nodes: &mut NodeArrays,
    dt: f64,
    tol: f64,
) {
    let NodeArrays { p2g, kin, remap } = nodes;
    let p2g = &p2g[..];
    let t = exec.workers();
    let split = node_split(geom, index);
    let tally = crate::work::Tally::of(exec);
    exec.for_each_chunk_mut((split.of(remap), split.of(kin)), |w, (remap, kin)| {
        tally.updated(w, remap.len());
        visit_nodes(geom, index, walls, w, t, |n, mask, local| {
            let (o, kn) = (&mut remap[local], &mut kin[local]);
            let m = p2g[n][0];
            if m > tol {
                let inv = 1.0 / m;
                for k in 0..3 {
                    o[k] *= inv * mask[k];
                }
            } else {
                *o = [0.0; REMAP_WIDTH];
            }
            for k in 0..3 {
                kn[3 + k] = 0.5 * (kn[k] - dt * kn[3 + k] + o[k]);
            }
        });
    });
}

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
            // weights and gradients node by node in the loop below (keeping the 32 values of
            // a whole `BlockShape` took 4-9 % longer at AVX-512: they went through the stack).
            let (cells, local) = self.located.local_block::<R, N>(&k.map(|k| self.first + k), inv_dx);
            // The block in runs of lanes in one cell (particles of a cell are neighbours: the
            // cell order, `crate::order`): each run's 8 node records looked up once, and each
            // node value of a block built from one broadcast per run (lanes from the run's
            // first on take the run's value), not gathered lane by lane.
            let mut first = [0usize; N];
            let mut runs = 1;
            for l in 1..N {
                if cells[l] != cells[l - 1] {
                    first[runs] = l;
                    runs += 1;
                }
            }
            let mut kin = [[&NO_KIN; 8]; N];
            let mut remap = [[&NO_REMAP; 8]; N];
            let mut from = [R::mask(true); N];
            for r in 0..runs {
                let idx = nodes.get(cells[first[r]].map(|c| c as usize));
                kin[r] = records(self.kin, &idx);
                remap[r] = records(self.remap, &idx);
                from[r] = R::mask_from(|l| l >= first[r]);
            }
            let zero = R::splat(0.0);
            let mut vx = [zero; 3];
            let mut lv = [[zero; 3]; 3];
            let mut lm = [[zero; 3]; 3];
            for q in 0..8 {
                let (w, gq) = local.node(q);
                let mut kin_q: [R; KIN_WIDTH] = array(|i| R::splat(kin[0][q][i]));
                let mut remap_q: [R; 3] = array(|i| R::splat(remap[0][q][i]));
                for r in 1..runs {
                    for i in 0..KIN_WIDTH {
                        kin_q[i] = R::select(from[r], R::splat(kin[r][q][i]), kin_q[i]);
                    }
                    for i in 0..3 {
                        remap_q[i] = R::select(from[r], R::splat(remap[r][q][i]), remap_q[i]);
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
            let de = strain_increment(&lv, dt);
            let half_dt = R::splat(0.5 * dt);
            let dw =
                [half_dt * (lv[1][2] - lv[2][1]), half_dt * (lv[2][0] - lv[0][2]), half_dt * (lv[0][1] - lv[1][0])];
            let de_mid = strain_increment(&lm, dt);
            let state = LaneState {
                stress: array(|i| R::from_lanes(|l| self.stress[k[l]][i])),
                eps_p: R::from_lanes(|l| self.eps_p[k[l]]),
                e_int: R::from_lanes(|l| self.e_int[k[l]]),
                rho: R::from_lanes(|l| self.rho[k[l]]),
                sound: R::from_lanes(|l| self.sound[k[l]]),
                failed: R::mask_from(|l| self.failed[k[l]]),
            };
            let (out, signal, floor) = update_block::<R, E, LINEAR>(self.consts, self.eos, dt, de, de_mid, dw, state);
            // Every lane out of the registers once, then particle by particle.
            let stress: [[f64; N]; 6] = std::array::from_fn(|i| out.stress[i].to_array());
            let vx: [[f64; N]; 3] = std::array::from_fn(|a| vx[a].to_array());
            let (eps_p, e_int, rho, sound) =
                (out.eps_p.to_array(), out.e_int.to_array(), out.rho.to_array(), out.sound.to_array());
            let (failed, signal, floor) = (R::mask_bools(out.failed), signal.to_array(), floor.to_array());
            for l in 0..len {
                let k = start + l;
                let st: Sym = std::array::from_fn(|i| stress[i][l]);
                self.stress[k] = st;
                let e = e_int[l];
                self.eps_p[k] = eps_p[l];
                self.e_int[k] = e;
                self.rho[k] = rho[l];
                self.sound[k] = sound[l];
                self.failed[k] = failed[l];
                let xp = &mut self.x[k];
                for a in 0..3 {
                    xp[a] += dt * vx[a][l];
                }
                let vp = self.v[k];
                let m = self.mass[k];
                let v2 = vp[0] * vp[0] + vp[1] * vp[1] + vp[2] * vp[2];
                sum.kinetic += 0.5 * m * v2;
                sum.internal += m * e;
                sum.negative_internal += u64::from(e < -self.consts.energy_tolerance);
                if floor[l] > 0.0 {
                    sum.failed_floors += 1;
                    sum.failed_floor_energy += m * floor[l];
                }
                for a in 0..3 {
                    sum.momentum[a] += m * vp[a];
                    sum.lo[a] = sum.lo[a].min(xp[a]);
                    sum.hi[a] = sum.hi[a].max(xp[a]);
                }
                sum.max_speed = sum.max_speed.max(signal[l] + v2.sqrt());
                let finite = (xp[0] + xp[1] + xp[2] + v2 + st[0] + st[1] + st[2] + e).is_finite();
                if !finite {
                    sum.non_finite += 1;
                }
            }
            start += len;
        }
        sum
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::strategy::Kernel;

    /// The scatter tests' 85 particles on `geom` (6 x 5 x 7 cells of 4/7, anchored at 0): 61
    /// spread at random in 3 x 2.5 x 3.5, then 8 in each of three cells; random velocities, masses,
    /// densities and stresses. And three id lists: out of order (a stride through the
    /// particles, as a DD column lists its ids), in cell order (`crate::order`'s runs), the
    /// three cells' runs alone.
    fn scatter_inputs(geom: &GridGeom) -> (Particles, [Vec<usize>; 3]) {
        let mut unit = crate::testing::unit_stream(3);
        let (spread, n) = (61, 85);
        let mut pt = Particles::with_capacity(n);
        for _ in 0..spread {
            let x = [3.0 * unit(), 2.5 * unit(), 3.5 * unit()];
            pt.push(x, [unit() - 0.5, unit() - 0.5, unit() - 0.5], 0.1 + unit(), 7000.0 + 1000.0 * unit(), 4000.0);
        }
        for cell in [[1.0, 1.0, 1.0], [2.0, 3.0, 4.0], [5.0, 4.0, 6.0]] {
            for _ in 0..8 {
                let x = std::array::from_fn(|d| (cell[d] + 0.05 + 0.9 * unit()) * geom.dx);
                pt.push(x, [unit() - 0.5, unit() - 0.5, unit() - 0.5], 0.1 + unit(), 7000.0 + 1000.0 * unit(), 4000.0);
            }
        }
        for st in pt.stress.iter_mut() {
            *st = std::array::from_fn(|_| 1e8 * (unit() - 0.5));
        }
        let stride: Vec<usize> = (0..n).map(|i| (i * 19) % n).collect();
        let mut by_cell: Vec<usize> = (0..n).collect();
        by_cell.sort_by_key(|&p| {
            let c = geom.shape(pt.x[p]).cell;
            [c[2], c[1], c[0]]
        });
        let runs: Vec<usize> = (spread..n).collect();
        (pt, [stride, by_cell, runs])
    }

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
                        k.scatter_all(ids.iter().copied(), &mut nodes, &mut data);
                    } else {
                        for &p in ids {
                            k.scatter(p, &mut nodes, &mut data);
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

    /// The blocked P2G (shape functions 4 particles at a time; at AVX-512, `p2g512`'s
    /// particle at a time with its 8 nodes in the lanes) gives every node bitwise what the
    /// same particles give one at a time through the blocked form (blocks of one: at
    /// AVX-512 this holds the two kernels to each other), for id lists of every length
    /// modulo the block (partial last blocks), out of order, in cell order and in runs of 8
    /// particles per cell (the solver's order: a block's particles then add to the same
    /// records one after the other), repeating no particle, with and without body force, at
    /// every SIMD level this CPU has. A lane mixed up between particles of a block, or a
    /// partial block dropped or padded into the sums, fails it.
    #[test]
    fn blocked_p2g_is_bitwise_one_particle_at_a_time() {
        // Cells of 4/7: `1/dx` no power of two, so a product of the gradient's factors taken in
        // another order changes bits.
        let geom = GridGeom::fixed(&GridSpec { dx: 4.0 / 7.0, anchor: [0.0; 3], cells: [6, 5, 7] });
        let index = NodeIndex::of(&geom, None);
        let (pt, [stride, by_cell, runs]) = scatter_inputs(&geom);
        let levels: Vec<SimdLevel> = SimdLevel::ALL.into_iter().filter(|l| l.is_available()).collect();
        fn run<K: Kernel<P2G_WIDTH>>(k: &K, index: &NodeIndex<'_>, ids: &[usize], blocked: bool) -> Vec<[f64; 8]> {
            let mut data = vec![[0.0; P2G_WIDTH]; index.num_nodes()];
            let mut nodes = Cursors::global(*index);
            if blocked {
                k.scatter_all(ids.iter().copied(), &mut nodes, &mut data);
            } else {
                for &p in ids {
                    k.scatter(p, &mut nodes, &mut data);
                }
            }
            data
        }
        let located = Located::of(&geom, &pt.x);
        for (list, order) in [("stride", &stride), ("cell order", &by_cell), ("runs", &runs)] {
            for len in (0..=9).chain([order.len()]) {
                let ids = &order[..len];
                for &simd in &levels {
                    let (particles, located) = (&pt, &located);
                    let plain = P2g::<false> { geom: &geom, particles, located, body_force: [0.0; 3], simd };
                    let body = P2g::<true> { geom: &geom, particles, located, body_force: [0.0, -9.81, 1.5], simd };
                    for (what, blocked, single) in [
                        ("no body force", run(&plain, &index, ids, true), run(&plain, &index, ids, false)),
                        ("body force", run(&body, &index, ids, true), run(&body, &index, ids, false)),
                    ] {
                        for (i, (b, s)) in blocked.iter().zip(&single).enumerate() {
                            let same = b.iter().zip(s).all(|(x, y)| x.to_bits() == y.to_bits());
                            assert!(
                            same,
                            "{what}, {list}, {len} particles at {simd}: node {i}: blocked {b:?} vs one at a time {s:?}"
                        );
                        }
                    }
                    if len > 0 {
                        let mass: f64 = run(&plain, &index, ids, true).iter().map(|d| d[0]).sum();
                        let want: f64 = ids.iter().map(|&p| pt.mass[p]).sum();
                        assert!(
                            (mass - want).abs() <= 1e-12 * want,
                            "{list}, {len} particles at {simd}: mass {mass} vs {want}"
                        );
                    }
                }
            }
        }
    }
}
