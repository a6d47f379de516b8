//! The P2G scatter (Eqs. 1-5): what a particle gives its 8 nodes, in blocks of particles, or
//! at AVX-512 one particle at a time with its nodes in the lanes (`p2g512`).

use super::{next_block, scatter_at, Blocked};
use crate::grid::{GridGeom, P2G_WIDTH};
use crate::locate::Located;
use crate::math::Vec3;
use crate::particles::Particles;
use crate::simd::{array, Block, Real, SimdLevel, F4, LANES};
use crate::strategy::{Cursors, Kernel, Target};

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
    fn blocks<D: Target<P2G_WIDTH> + ?Sized>(
        &self,
        mut ids: impl Iterator<Item = usize>,
        nodes: &mut Cursors<'_>,
        data: &mut D,
    ) {
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
                    let d = data.at(idx[q]);
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
    fn scatter<D: Target<P2G_WIDTH> + ?Sized>(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut D) {
        self.blocks(std::iter::once(p), nodes, data);
    }

    #[inline(always)]
    fn scatter_all<D: Target<P2G_WIDTH> + ?Sized>(
        &self,
        ids: impl Iterator<Item = usize>,
        nodes: &mut Cursors<'_>,
        data: &mut D,
    ) {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::node_index::NodeIndex;
    use crate::transfer::testing::scatter_inputs;

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
                k.scatter_all(ids.iter().copied(), &mut nodes, &mut data[..]);
            } else {
                for &p in ids {
                    k.scatter(p, &mut nodes, &mut data[..]);
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
