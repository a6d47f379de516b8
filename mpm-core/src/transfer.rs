//! The per-particle and per-node kernels of the MUSL step (Eqs. 1-15), shared by every
//! strategy. The scatter kernels ([`p2g`], [`remap`]) say what one particle adds to its 8
//! nodes; the strategy decides where that goes. The other passes are split across workers
//! by loop splitting (particles) or by node rows (nodes), through an [`Exec`].
//!
//! They are public so that benchmarks measure exactly the code the solver runs.

use crate::blocks::{BlockMap, BLOCK, BLOCK_NODES};
use crate::energy::Partial;
use crate::grid::{CellNodes, GridGeom, NodeArrays, NodeIndex, WallLayers, KIN_WIDTH, P2G_WIDTH, REMAP_WIDTH};
use crate::material::{update_point, PointConsts, PointState, PressureModel};
use crate::math::{sym_mul_vec, Sym, Vec3};
use crate::parallel::{partition, Exec, Split};
use crate::particles::Particles;
use crate::strategy::{Contribution, Kernel};

/// Eqs. 1-5 for particle `p`: mass `m_p S_ip`, momentum `m_p v_p S_ip` and force
/// `-V_p sigma_p . G_ip + m_p S_ip b` at its 8 nodes, as `[m, p_x, p_y, p_z, f_x, f_y, f_z]`.
#[inline(always)]
pub fn p2g(geom: &GridGeom, particles: &Particles, body_force: Vec3, p: usize) -> Contribution<P2G_WIDTH> {
    let s = geom.shape(particles.x[p]);
    let m = particles.mass[p];
    let vol = m / particles.rho[p];
    let vp = particles.v[p];
    let stress = &particles.stress[p];
    let mut c = [[0.0; P2G_WIDTH]; 8];
    for q in 0..8 {
        let t = sym_mul_vec(stress, s.g[q]);
        let mw = m * s.w[q];
        c[q] = [
            mw,
            mw * vp[0],
            mw * vp[1],
            mw * vp[2],
            mw * body_force[0] - vol * t[0],
            mw * body_force[1] - vol * t[1],
            mw * body_force[2] - vol * t[2],
        ];
    }
    Contribution { cell: s.cell, c }
}

/// Eq. 11 for particle `p`: momentum `m_p v_p(k+1) S_ip` at its 8 nodes.
#[inline(always)]
pub fn remap(geom: &GridGeom, particles: &Particles, p: usize) -> Contribution<REMAP_WIDTH> {
    let s = geom.shape(particles.x[p]);
    let m = particles.mass[p];
    let v = particles.v[p];
    let mv = [m * v[0], m * v[1], m * v[2]];
    Contribution { cell: s.cell, c: s.w.map(|w| [mv[0] * w, mv[1] * w, mv[2] * w]) }
}

/// The P2G kernel ([`p2g`]) as a scatter [`Kernel`].
#[derive(Clone, Copy)]
pub struct P2g<'a> {
    /// The grid of this step.
    pub geom: &'a GridGeom,
    /// The particles at step `k`.
    pub particles: &'a Particles,
    /// Body force per unit mass (m/s^2).
    pub body_force: Vec3,
}

impl Kernel<P2G_WIDTH> for P2g<'_> {
    #[inline(always)]
    fn contribution(&self, p: usize) -> Contribution<P2G_WIDTH> {
        p2g(self.geom, self.particles, self.body_force, p)
    }
}

/// The re-map kernel ([`remap`]) as a scatter [`Kernel`].
#[derive(Clone, Copy)]
pub struct Remap<'a> {
    /// The grid of this step.
    pub geom: &'a GridGeom,
    /// The particles with their updated velocities.
    pub particles: &'a Particles,
}

impl Kernel<REMAP_WIDTH> for Remap<'_> {
    #[inline(always)]
    fn contribution(&self, p: usize) -> Contribution<REMAP_WIDTH> {
        remap(self.geom, self.particles, p)
    }
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
    exec.for_each_chunk_mut(node_split(geom, index).of(out), |w, mine| {
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
    exec.for_each_chunk_mut((split.of(remap), split.of(kin)), |w, (remap, kin)| {
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

/// Eqs. 8, 10: `v_p += dt sum_i S_ip a_i`, by loop splitting (`kin` numbered by `index`).
pub fn gather(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    kin: &[[f64; KIN_WIDTH]],
    x: &[Vec3],
    v: &mut [Vec3],
    dt: f64,
) {
    assert_eq!(x.len(), v.len(), "one velocity per position");
    let n = x.len();
    let t = exec.workers();
    exec.for_each_chunk_mut(Split::Even.of(v), |w, vw| {
        let mut nodes = CellNodes::new(*index);
        for (vp, xp) in vw.iter_mut().zip(&x[partition(n, t, w)]) {
            let s = geom.shape(*xp);
            let idx = nodes.get(s.cell);
            let mut acc = [0.0; 3];
            for q in 0..8 {
                let a = &kin[idx[q]];
                for k in 0..3 {
                    acc[k] += s.w[q] * a[3 + k];
                }
            }
            for k in 0..3 {
                vp[k] += dt * acc[k];
            }
        }
    });
}

/// The gradients `L[a][b] = sum_q v_q[a] G_q[b]` of two nodal velocity fields at once: the
/// re-mapped velocity (`remap`, Eq. 12) and the mid-step velocity (`kin[3..6]` after
/// [`remap_velocity`]), whose gradient gives the work of the stress. `nodes(q)` returns node
/// `q`'s `(remap, kin)` rows.
///
/// On x86-64 the six components are summed as three pairs in SSE2 registers (18 sums in 9
/// registers, with room for the operands). As two scalar loops the 18 sums did not fit the
/// registers of the baseline target and spilled: the mid-step gradient alone made the Taylor
/// bar step 6.7 % slower. Each sum adds the same products (`mulpd`, then `addpd`: no fused
/// multiply-add) in the same order `q = 0..8` as the scalar form
/// ([`gradients_scalar`], used elsewhere), so both give bitwise the same results.
#[cfg(target_arch = "x86_64")]
#[inline(always)]
fn gradients<'n>(
    g: &[Vec3; 8],
    nodes: impl Fn(usize) -> (&'n [f64; REMAP_WIDTH], &'n [f64; KIN_WIDTH]),
) -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
    use std::arch::x86_64::{
        _mm_add_pd, _mm_cvtsd_f64, _mm_mul_pd, _mm_set1_pd, _mm_set_pd, _mm_setzero_pd, _mm_unpackhi_pd,
    };
    // SAFETY: these are SSE2 intrinsics, and SSE2 is part of every x86-64 target (the
    // `target_arch` gate above), so the instructions exist; none of them reads or writes
    // memory through a pointer (operands are values). The test
    // `simd_gradients_equal_the_scalar_form_bitwise` checks the result against
    // `gradients_scalar`.
    unsafe {
        // acc[b][c]: along b, components (2c, 2c + 1) of the stacked field [remap, mid].
        let mut acc = [[_mm_setzero_pd(); 3]; 3];
        for q in 0..8 {
            let (vr, vk) = nodes(q);
            let pairs = [_mm_set_pd(vr[1], vr[0]), _mm_set_pd(vk[3], vr[2]), _mm_set_pd(vk[5], vk[4])];
            for b in 0..3 {
                let gb = _mm_set1_pd(g[q][b]);
                for c in 0..3 {
                    acc[b][c] = _mm_add_pd(acc[b][c], _mm_mul_pd(pairs[c], gb));
                }
            }
        }
        let mut out = [[0.0; 3]; 6];
        for b in 0..3 {
            for c in 0..3 {
                out[2 * c][b] = _mm_cvtsd_f64(acc[b][c]);
                out[2 * c + 1][b] = _mm_cvtsd_f64(_mm_unpackhi_pd(acc[b][c], acc[b][c]));
            }
        }
        ([out[0], out[1], out[2]], [out[3], out[4], out[5]])
    }
}

/// [`gradients`] in plain scalar code: the form on other targets, and the reference the
/// SSE2 form is tested against.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline(always)]
fn gradients_scalar<'n>(
    g: &[Vec3; 8],
    nodes: impl Fn(usize) -> (&'n [f64; REMAP_WIDTH], &'n [f64; KIN_WIDTH]),
) -> ([[f64; 3]; 3], [[f64; 3]; 3]) {
    let mut l = [[0.0; 3]; 3];
    let mut lm = [[0.0; 3]; 3];
    for q in 0..8 {
        let (vr, vk) = nodes(q);
        for a in 0..3 {
            for b in 0..3 {
                l[a][b] += vr[a] * g[q][b];
                lm[a][b] += vk[3 + a] * g[q][b];
            }
        }
    }
    (l, lm)
}

#[cfg(not(target_arch = "x86_64"))]
use gradients_scalar as gradients;

/// Eq. 12: the strain increment `dt sym(L)` of the velocity gradient `L` (`L[a][b] =
/// dv_a / dx_b`), in Voigt order.
#[inline(always)]
fn strain_increment(l: &[[f64; 3]; 3], dt: f64) -> Sym {
    let half_dt = 0.5 * dt;
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
#[allow(clippy::too_many_arguments)]
pub fn update<E: PressureModel + Sync>(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    nodes: &NodeArrays,
    particles: &mut Particles,
    consts: &PointConsts,
    eos: &E,
    dt: f64,
    partials: &mut [Partial],
) {
    let n = particles.len();
    let Particles { x, v, mass, rho, stress, eps_p, e_int, sound, failed } = particles;
    let (v, mass) = (&v[..], &mass[..]);
    let (kin, remap) = (&nodes.kin, &nodes.remap);
    let half_dt = 0.5 * dt;
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
    exec.for_each_chunk_mut(chunks, |w, (x, rho, stress, eps_p, e_int, sound, failed, acc)| {
        let r = partition(n, t, w);
        let mut sum = Partial::default();
        let mut nodes = CellNodes::new(*index);
        for k in 0..r.len() {
            let p = r.start + k;
            let s = geom.shape(x[k]);
            let idx = nodes.get(s.cell);
            let mut vx = [0.0; 3];
            for q in 0..8 {
                let vn = &kin[idx[q]];
                for a in 0..3 {
                    vx[a] += s.w[q] * vn[a];
                }
            }
            let (l, lm) = gradients(&s.g, |q| (&remap[idx[q]], &kin[idx[q]]));
            let de = strain_increment(&l, dt);
            let dw = [half_dt * (l[1][2] - l[2][1]), half_dt * (l[2][0] - l[0][2]), half_dt * (l[0][1] - l[1][0])];
            let de_mid = strain_increment(&lm, dt);
            let (signal, floor) = update_point(
                consts,
                eos,
                &de,
                &de_mid,
                dw,
                dt,
                PointState {
                    stress: &mut stress[k],
                    eps_p: &mut eps_p[k],
                    e_int: &mut e_int[k],
                    rho: &mut rho[k],
                    sound: &mut sound[k],
                    failed: &mut failed[k],
                },
            );
            let xp = &mut x[k];
            for a in 0..3 {
                xp[a] += dt * vx[a];
            }
            let vp = v[p];
            let m = mass[p];
            let v2 = vp[0] * vp[0] + vp[1] * vp[1] + vp[2] * vp[2];
            sum.kinetic += 0.5 * m * v2;
            sum.internal += m * e_int[k];
            sum.negative_internal += u64::from(e_int[k] < -consts.energy_tolerance);
            if floor > 0.0 {
                sum.failed_floors += 1;
                sum.failed_floor_energy += m * floor;
            }
            for a in 0..3 {
                sum.momentum[a] += m * vp[a];
                sum.lo[a] = sum.lo[a].min(xp[a]);
                sum.hi[a] = sum.hi[a].max(xp[a]);
            }
            sum.max_speed = sum.max_speed.max(signal + v2.sqrt());
            let finite =
                (xp[0] + xp[1] + xp[2] + v2 + stress[k][0] + stress[k][1] + stress[k][2] + e_int[k]).is_finite();
            if !finite {
                sum.non_finite += 1;
            }
        }
        acc[0] = sum;
    });
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::shape;

    /// Deterministic test values spread over many magnitudes and both signs.
    fn value(i: usize) -> f64 {
        let u = ((i as f64 + 0.5) * 12.9898).sin() * 43758.5453;
        let f = u - u.floor();
        (f - 0.5) * 10f64.powi((i % 9) as i32 - 4)
    }

    /// The SSE2 form sums the same products in the same order as the scalar form: any
    /// reordering or fused multiply-add would change the last bits of some of these sums.
    #[test]
    fn simd_gradients_equal_the_scalar_form_bitwise() {
        let mut k = 0;
        let mut next = || {
            k += 1;
            value(k)
        };
        for _ in 0..2000 {
            let x = [next().abs() * 3.0, next().abs() * 3.0, next().abs() * 3.0];
            let s = shape::evaluate(x, [0.0; 3], 1.7, [100, 100, 100]);
            let remap: [[f64; REMAP_WIDTH]; 8] = std::array::from_fn(|_| std::array::from_fn(|_| next()));
            let kin: [[f64; KIN_WIDTH]; 8] = std::array::from_fn(|_| std::array::from_fn(|_| next()));
            let a = gradients(&s.g, |q| (&remap[q], &kin[q]));
            let b = gradients_scalar(&s.g, |q| (&remap[q], &kin[q]));
            for (fa, fb) in [(a.0, b.0), (a.1, b.1)] {
                for i in 0..3 {
                    for j in 0..3 {
                        assert_eq!(fa[i][j].to_bits(), fb[i][j].to_bits(), "component {i}{j} at x = {x:?}");
                    }
                }
            }
        }
    }
}
