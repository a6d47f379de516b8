//! Small fixed-size vector and tensor helpers.
//!
//! Vectors are `[f64; 3]`. Symmetric tensors (stress, strain increments) are stored in
//! Voigt order `[xx, yy, zz, yz, zx, xy]`, which is also the order of the stress columns in
//! every output of this workspace.

use crate::simd::Real;

/// A 3-vector in SI units.
pub type Vec3 = [f64; 3];

/// A symmetric 3x3 tensor in Voigt order `[xx, yy, zz, yz, zx, xy]`.
pub type Sym = [f64; 6];

/// Euclidean norm of a 3-vector.
#[inline(always)]
pub fn norm(a: Vec3) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}

/// Trace of a symmetric tensor (of one particle, `f64`, or of a block, [`crate::simd::F4`]).
#[inline(always)]
pub fn trace<R: Real>(s: &[R; 6]) -> R {
    s[0] + s[1] + s[2]
}

/// Deviatoric part `s - tr(s)/3 I`.
#[inline(always)]
pub fn deviator<R: Real>(s: &[R; 6]) -> [R; 6] {
    let m = trace(s) / R::splat(3.0);
    [s[0] - m, s[1] - m, s[2] - m, s[3], s[4], s[5]]
}

/// Double contraction `a : b` of two symmetric tensors.
#[inline(always)]
pub fn ddot<R: Real>(a: &[R; 6], b: &[R; 6]) -> R {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2] + R::splat(2.0) * (a[3] * b[3] + a[4] * b[4] + a[5] * b[5])
}

/// Von Mises equivalent `sqrt(3/2 s:s)` of a deviatoric tensor `s`.
#[inline(always)]
pub fn von_mises<R: Real>(dev: &[R; 6]) -> R {
    (R::splat(1.5) * ddot(dev, dev)).sqrt()
}

/// `sigma . t` for a symmetric `sigma` (traction on the plane with normal `t`).
#[inline(always)]
pub fn sym_mul_vec(s: &Sym, t: Vec3) -> Vec3 {
    [
        s[0] * t[0] + s[5] * t[1] + s[4] * t[2],
        s[5] * t[0] + s[1] * t[1] + s[3] * t[2],
        s[4] * t[0] + s[3] * t[1] + s[2] * t[2],
    ]
}

/// Jaumann rotation increment `w.s - s.w` (paper Eq. 15) for a spin increment `w` given by
/// its three independent components `[w_yz, w_zx, w_xy]` (`w_ab = -w_ba`).
///
/// The result is symmetric; it is returned in Voigt order.
#[inline(always)]
pub fn jaumann<R: Real>(s: &[R; 6], w: [R; 3]) -> [R; 6] {
    let (wyz, wzx, wxy) = (w[0], w[1], w[2]);
    // Full matrices: W = [[0, wxy, -wzx], [-wxy, 0, wyz], [wzx, -wyz, 0]]
    // S = [[sxx, sxy, szx], [sxy, syy, syz], [szx, syz, szz]]
    let (sxx, syy, szz, syz, szx, sxy) = (s[0], s[1], s[2], s[3], s[4], s[5]);
    // M = W S
    let m00 = wxy * sxy - wzx * szx;
    let m01 = wxy * syy - wzx * syz;
    let m02 = wxy * syz - wzx * szz;
    let m10 = -wxy * sxx + wyz * szx;
    let m11 = -wxy * sxy + wyz * syz;
    let m12 = -wxy * szx + wyz * szz;
    let m20 = wzx * sxx - wyz * sxy;
    let m21 = wzx * sxy - wyz * syy;
    let m22 = wzx * szx - wyz * syz;
    // W S - S W = M + M^T (since S W = -(W S)^T for antisymmetric W)
    let two = R::splat(2.0);
    [two * m00, two * m11, two * m22, m12 + m21, m20 + m02, m01 + m10]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn full(s: &Sym) -> [[f64; 3]; 3] {
        [[s[0], s[5], s[4]], [s[5], s[1], s[3]], [s[4], s[3], s[2]]]
    }

    #[test]
    fn jaumann_matches_matrix_products() {
        let s: Sym = [1.0, -2.0, 3.0, 0.4, -0.7, 1.3];
        let w: Vec3 = [0.3, -0.2, 0.5];
        let wm = [[0.0, w[2], -w[1]], [-w[2], 0.0, w[0]], [w[1], -w[0], 0.0]];
        let sm = full(&s);
        let mut r = [[0.0; 3]; 3];
        for a in 0..3 {
            for b in 0..3 {
                for k in 0..3 {
                    r[a][b] += wm[a][k] * sm[k][b] - sm[a][k] * wm[k][b];
                }
            }
        }
        let j = jaumann(&s, w);
        let jm = full(&j);
        for a in 0..3 {
            for b in 0..3 {
                assert!((jm[a][b] - r[a][b]).abs() < 1e-14, "({a},{b})");
            }
        }
        // A rotation increment does not change the trace.
        assert!(trace(&j).abs() < 1e-14);
    }

    #[test]
    fn von_mises_of_uniaxial_deviator_is_the_stress() {
        let sigma: Sym = [5.0, 0.0, 0.0, 0.0, 0.0, 0.0];
        assert!((von_mises(&deviator(&sigma)) - 5.0).abs() < 1e-12);
    }
}
