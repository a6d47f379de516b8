//! Particle lattices: points at the centres of a regular lattice's cells, kept when they
//! lie inside a body.

use crate::math::Vec3;

/// Centres of an `n[0] x n[1] x n[2]` lattice of cells spanning `[lo, lo + n h]`, in
/// x-fastest order, filtered by `keep`.
pub fn cell_centred(lo: Vec3, h: Vec3, n: [usize; 3], keep: impl Fn(Vec3) -> bool) -> Vec<Vec3> {
    let mut out = Vec::new();
    for_each_cell_centre(lo, h, n, |p| {
        if keep(p) {
            out.push(p);
        }
    });
    out
}

/// Call `f` with the centres of [`cell_centred`]'s lattice, in the same order, without
/// collecting them.
pub fn for_each_cell_centre(lo: Vec3, h: Vec3, n: [usize; 3], mut f: impl FnMut(Vec3)) {
    for k in 0..n[2] {
        for j in 0..n[1] {
            for i in 0..n[0] {
                f([lo[0] + (i as f64 + 0.5) * h[0], lo[1] + (j as f64 + 0.5) * h[1], lo[2] + (k as f64 + 0.5) * h[2]]);
            }
        }
    }
}
