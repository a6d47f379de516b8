//! J2 (von Mises) plasticity with isotropic hardening `sigma_y = A + B eps_p^n` (Eq. 17),
//! integrated by the radial return.

use crate::math::{von_mises, Sym};
use serde::Serialize;

/// Yield stress `A + B eps_p^n` (Pa).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Hardening {
    /// Initial yield stress `A` (Pa); `f64::INFINITY` for a purely elastic material.
    pub a: f64,
    /// Hardening modulus `B` (Pa).
    pub b: f64,
    /// Hardening exponent `n` (both of the paper's materials have `n = 1`).
    pub n: f64,
}

impl Hardening {
    /// `A + B eps_p^n`.
    #[inline(always)]
    pub fn yield_stress(&self, eps_p: f64) -> f64 {
        if self.n == 1.0 {
            self.a + self.b * eps_p
        } else {
            self.a + self.b * eps_p.powf(self.n)
        }
    }

    /// `d sigma_y / d eps_p`.
    #[inline]
    pub fn slope(&self, eps_p: f64) -> f64 {
        if self.n == 1.0 {
            self.b
        } else {
            self.b * self.n * eps_p.max(1e-12).powf(self.n - 1.0)
        }
    }
}

/// Radial return of a trial deviator `s_trial` with shear modulus `g` and effective
/// plastic strain `eps_p`: returns the new deviator and plastic strain.
///
/// If the trial von Mises stress `J = sqrt(3/2 s:s)` is above the yield stress, the
/// plastic increment `d` solves `J - 3 G d = sigma_y(eps_p + d)` (closed form for `n = 1`,
/// Newton otherwise) and the deviator is scaled back onto the hardened surface.
#[inline(always)]
pub fn radial_return(s_trial: Sym, eps_p: f64, g: f64, h: &Hardening) -> (Sym, f64) {
    let j = von_mises(&s_trial);
    let y0 = h.yield_stress(eps_p);
    if j <= y0 {
        return (s_trial, eps_p);
    }
    let d = if h.n == 1.0 {
        // Times the reciprocal: the particle update forms it once for all particles.
        (j - y0) * (1.0 / (3.0 * g + h.b))
    } else {
        let mut d = (j - y0) / (3.0 * g + h.slope(eps_p));
        for _ in 0..30 {
            let r = j - 3.0 * g * d - h.yield_stress(eps_p + d);
            let dr = -3.0 * g - h.slope(eps_p + d);
            let step = r / dr;
            d = (d - step).max(0.0);
            if step.abs() <= 1e-14 * (1.0 + d) {
                break;
            }
        }
        d
    };
    let scale = (j - 3.0 * g * d) / j;
    (s_trial.map(|v| v * scale), eps_p + d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elastic_trial_is_unchanged() {
        let h = Hardening { a: 100.0, b: 10.0, n: 1.0 };
        let s = [10.0, -5.0, -5.0, 0.0, 0.0, 1.0];
        assert_eq!(radial_return(s, 0.0, 1e3, &h), (s, 0.0));
    }

    #[test]
    fn return_lands_on_the_hardened_surface_linear_and_power_law() {
        for n in [1.0, 0.5, 0.26] {
            let h = Hardening { a: 157e6, b: 425e6, n };
            let g = 43.3e9;
            let s = [900e6, -300e6, -600e6, 50e6, -20e6, 400e6];
            let (s_new, ep) = radial_return(s, 0.02, g, &h);
            assert!(ep > 0.02);
            let j_new = von_mises(&s_new);
            let y = h.yield_stress(ep);
            assert!((j_new - y).abs() / y < 1e-10, "n={n}: J={j_new} y={y}");
            // Consistency: J_trial - 3 G d = yield.
            let d = ep - 0.02;
            assert!((von_mises(&s) - 3.0 * g * d - y).abs() / y < 1e-10);
            // Radial: the direction is kept.
            let ratio = s_new[0] / s[0];
            for i in 0..6 {
                assert!((s_new[i] - ratio * s[i]).abs() < 1e-6 * s[i].abs().max(1.0));
            }
        }
    }
}
