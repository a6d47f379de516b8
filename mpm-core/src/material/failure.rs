//! Failure (paper Section 2, hypervelocity problem only): a particle fails when its
//! effective plastic strain reaches `eps_f` or its pressure drops below `p_min`. From then on
//! it carries no deviatoric stress and no tension: its pressure still comes from the EOS
//! (plus the artificial viscosity) but is clipped at `p >= 0` (see
//! [`super::update_point`]), so failed material still resists compression and cannot pass
//! through other material.

use serde::Serialize;

/// Failure thresholds.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct Failure {
    /// Effective plastic strain at failure.
    pub eps_f: f64,
    /// Pressure cutoff (Pa, negative = tension).
    pub p_min: f64,
}

impl Failure {
    /// Whether a particle with plastic strain `eps_p` and pressure `p` fails.
    #[inline(always)]
    pub fn fails(&self, eps_p: f64, p: f64) -> bool {
        eps_p >= self.eps_f || p < self.p_min
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn thresholds() {
        let f = Failure { eps_f: 3.0, p_min: -1500e6 };
        assert!(!f.fails(2.99, -1499e6));
        assert!(f.fails(3.0, 0.0));
        assert!(f.fails(0.0, -1501e6));
    }
}
