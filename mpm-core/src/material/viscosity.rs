//! Artificial bulk viscosity (shock capturing; paper Section 2 as restated in the spec):
//! while a particle is compressed (`tr D < 0`, `D` the rate of deformation) its pressure
//! gains
//!
//! ```text
//! q = rho dx^2 c1 (tr D)^2 - rho dx c c2 tr D
//! ```
//!
//! (von Neumann-Richtmyer quadratic term plus Landshoff linear term; `dx` the cell size,
//! `c` the sound speed), and `q = 0` in expansion. Its work `-q dV` enters the internal
//! energy like the pressure's, so it turns the kinetic energy lost in a shock into heat.
//!
//! With `Q = c1 dx |tr D| + c2 c` (so that `q = rho dx |tr D| Q`) the explicit update stays
//! stable for `dt <= dx / (Q + sqrt(Q^2 + c^2))`; the stress update reports that signal
//! speed in place of `c` for the next time step.

use crate::error::SimError;
use serde::{Deserialize, Serialize};

/// Default quadratic coefficient `c1`.
pub const DEFAULT_C1: f64 = 1.5;
/// Default linear coefficient `c2`.
pub const DEFAULT_C2: f64 = 0.06;

/// The coefficients of the artificial bulk viscosity; `c1 = c2 = 0` turns it off.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BulkViscosity {
    /// Quadratic coefficient `c1` (default 1.5).
    pub c1: f64,
    /// Linear coefficient `c2` (default 0.06).
    pub c2: f64,
}

impl Default for BulkViscosity {
    fn default() -> Self {
        Self { c1: DEFAULT_C1, c2: DEFAULT_C2 }
    }
}

impl BulkViscosity {
    /// No artificial viscosity.
    pub const OFF: BulkViscosity = BulkViscosity { c1: 0.0, c2: 0.0 };

    /// Whether either term is on.
    pub fn is_on(&self) -> bool {
        self.c1 > 0.0 || self.c2 > 0.0
    }

    /// Both coefficients finite and non-negative.
    pub fn validate(&self) -> Result<(), SimError> {
        for (name, v) in [("c1 (quadratic)", self.c1), ("c2 (linear)", self.c2)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(SimError::Config(format!(
                    "the bulk viscosity coefficient {name} must be a finite number >= 0, got {v}; \
                     the usual values are c1 = {DEFAULT_C1}, c2 = {DEFAULT_C2}, and 0/0 turns it off"
                )));
            }
        }
        Ok(())
    }

    /// The coefficients on a grid of cell size `dx`, as the stress update uses them.
    pub fn on_grid(&self, dx: f64) -> ViscosityTerms {
        ViscosityTerms { c1_dx: self.c1 * dx, c2: self.c2, dx }
    }
}

/// The viscosity on one grid, precomputed for the hot loop (all zero: off).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ViscosityTerms {
    /// `c1 dx` (m).
    pub c1_dx: f64,
    /// `c2`.
    pub c2: f64,
    /// Cell size `dx` (m).
    pub dx: f64,
}

impl ViscosityTerms {
    /// `q` (Pa) and `Q = c1 dx |tr D| + c2 c` (m/s) of a particle of density `rho` and sound
    /// speed `c` deforming at the volumetric rate `tr_d` (1/s); `(0, 0)` in expansion.
    #[inline(always)]
    pub fn q(&self, rho: f64, c: f64, tr_d: f64) -> (f64, f64) {
        if tr_d >= 0.0 {
            return (0.0, 0.0);
        }
        let rate = -tr_d;
        let big_q = self.c1_dx * rate + self.c2 * c;
        (rho * self.dx * rate * big_q, big_q)
    }
}

/// The speed that limits the stable time step of a particle with sound speed `c` and
/// viscosity speed `Q` (from [`ViscosityTerms::q`]): `Q + sqrt(Q^2 + c^2)`, which is `c`
/// without viscosity.
#[inline(always)]
pub fn signal_speed(big_q: f64, c: f64) -> f64 {
    big_q + (big_q * big_q + c * c).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn q_is_positive_in_compression_and_zero_in_tension() {
        let t = BulkViscosity::default().on_grid(2e-3);
        let (rho, c) = (11350.0, 2092.0);
        // tr D = -1e5 /s: q = rho dx^2 c1 (tr D)^2 - rho dx c c2 tr D
        // = 11350 * 4e-6 * 1.5 * 1e10 + 11350 * 2e-3 * 2092 * 0.06 * 1e5 = 681e6 + 284.9e6 Pa.
        let (q, big_q) = t.q(rho, c, -1e5);
        let expect = 11350.0 * 4e-6 * 1.5 * 1e10 + 11350.0 * 2e-3 * 2092.0 * 0.06 * 1e5;
        assert!((q / expect - 1.0).abs() < 1e-12, "{q} vs {expect}");
        assert!(q > 0.0);
        // Q = c1 dx |tr D| + c2 c = 300 + 125.52 m/s; the signal speed exceeds c.
        assert!((big_q - (300.0 + 125.52)).abs() < 1e-9, "{big_q}");
        assert!((signal_speed(big_q, c) - (big_q + (big_q * big_q + c * c).sqrt())).abs() < 1e-9);
        assert_eq!(signal_speed(0.0, c), c);
        // Expansion and rest: no viscosity.
        assert_eq!(t.q(rho, c, 1e5), (0.0, 0.0));
        assert_eq!(t.q(rho, c, 0.0), (0.0, 0.0));
        // Off: nothing in compression either.
        assert_eq!(BulkViscosity::OFF.on_grid(2e-3).q(rho, c, -1e5), (0.0, 0.0));
    }

    #[test]
    fn invalid_coefficients_are_rejected_with_advice() {
        assert!(BulkViscosity::default().validate().is_ok());
        assert!(BulkViscosity::OFF.validate().is_ok());
        for bad in [BulkViscosity { c1: -1.0, c2: 0.06 }, BulkViscosity { c1: 1.5, c2: f64::NAN }] {
            let e = bad.validate().unwrap_err().to_string();
            assert!(e.contains("0/0 turns it off"), "{e}");
        }
    }
}
