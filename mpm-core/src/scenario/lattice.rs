//! Particle lattices: points at the centres of a regular lattice's cells, kept when they
//! lie inside a body.

use crate::math::Vec3;

/// Centres of an `n[0] x n[1] x n[2]` lattice of cells spanning `[lo, lo + n h]`, in
/// x-fastest order, filtered by `keep`.
pub fn cell_centred(lo: Vec3, h: Vec3, n: [usize; 3], keep: impl Fn(Vec3) -> bool) -> Vec<Vec3> {
    let mut out = Vec::new();
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                let p =
                    [lo[0] + (i as f64 + 0.5) * h[0], lo[1] + (j as f64 + 0.5) * h[1], lo[2] + (k as f64 + 0.5) * h[2]];
                if keep(p) {
                    out.push(p);
                }
            }
        }
    }
    out
}
