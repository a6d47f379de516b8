//! Failure (paper Section 2, hypervelocity problem only): a particle fails when its
//! effective plastic strain reaches `eps_f` or its pressure drops below `p_min`. From then on
//! it carries no deviatoric stress and no tension: its pressure still comes from the EOS
//! (plus the artificial viscosity) but is clipped at `p >= 0` (see
//! [`super::update_point`]), so failed material still resists compression and cannot pass
//! through other material.
//!
//! # Internal energy
//!
//! The work of a step is charged at the stress of the step's start, so that kinetic plus
//! internal energy is conserved exactly (see [`super::update_point`]). Near the impact the
//! strain of one step reaches several percent and reverses within a step or two (first
//! contact, after the grid has pulled the plate into tension; the release after a pressure and
//! `q` peak), so a particle can give up more work than it had received: its energy goes
//! negative, by about `|dp dv| / 2` per step (a smaller CFL number or a cap on the volume
//! strain per step removes most of it, at two to three times the steps). A particle that still
//! carries stress pays the deficit back as it is loaded again; such particles are counted as
//! violations ([`crate::energy::EnergyBalance`]), not changed.
//!
//! A failed particle carries no deviator and no tension: once its pressure is clipped it does
//! no work, so a deficit it has at failure (or takes on later) is never paid back, and its
//! negative thermal pressure `gamma0 rho0 e < 0` keeps the EOS pressure below zero, so it stays
//! clipped: frozen below zero for the rest of the run (the particles with negative energy in
//! 764 of the 808 steps of the large impact run were such particles). Its internal energy is
//! then only heat, which cannot be negative: it is set to zero, with the pressure of that
//! state, and the energy added is reported (count and joules,
//! [`crate::energy::EnergyBalance::failed_floor_energy`]); the energy balance books it as a
//! known source, so its check of the scheme's own conservation stays exact.

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
