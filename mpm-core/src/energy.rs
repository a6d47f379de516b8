//! Kinetic and internal energy (paper Section 1, step 10) and the energy balance of a run.
//!
//! Inside a time step the energies are reduced in parallel: every worker sums its own
//! particle chunk into its own slot and the slots are added in worker order, so a given
//! thread count always gives the same bits. The functions here are the plain sums used
//! for initial values and by tests.
//!
//! [`EnergyBalance`] follows the total energy step by step: `E = K + U` against its initial
//! value `E0` plus the work `W` of the body forces (zero in the paper's problems; rigid walls
//! at rest do no work). The equations conserve `E - W` (a shock turns kinetic into internal
//! energy); the scheme loses a little, and a rise means it creates energy. The solver stops a
//! run whose rise `(E - W - E0) / E0` exceeds `SimConfig::energy_rise_limit`.

use crate::math::Vec3;
use serde::{Deserialize, Serialize};

/// `sum_p 1/2 m_p |v_p|^2` (J).
pub fn kinetic(mass: &[f64], v: &[Vec3]) -> f64 {
    mass.iter().zip(v).map(|(m, v)| 0.5 * m * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2])).sum()
}

/// `sum_p m_p e_p` (J), with `e_p` the specific internal energy.
pub fn internal(mass: &[f64], e: &[f64]) -> f64 {
    mass.iter().zip(e).map(|(m, e)| m * e).sum()
}

/// Per-worker partial sums of one step's particle update, added in worker order.
#[derive(Clone, Copy, Debug)]
pub struct Partial {
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Internal energy (J).
    pub internal: f64,
    /// Linear momentum (kg m/s).
    pub momentum: Vec3,
    /// Largest `c_p + |v_p|` (m/s), for the next time step.
    pub max_speed: f64,
    /// Smallest coordinates of the updated positions.
    pub lo: Vec3,
    /// Largest coordinates of the updated positions.
    pub hi: Vec3,
    /// Particles with a non-finite position, velocity, stress or energy.
    pub non_finite: u64,
    /// Particles with negative specific internal energy.
    pub negative_internal: u64,
    /// Failed particles whose negative internal energy was set to zero in this step
    /// ([`crate::material::failure`]).
    pub failed_floors: u64,
    /// The energy that added (J).
    pub failed_floor_energy: f64,
}

impl Default for Partial {
    fn default() -> Self {
        Self {
            kinetic: 0.0,
            internal: 0.0,
            momentum: [0.0; 3],
            max_speed: 0.0,
            lo: [f64::INFINITY; 3],
            hi: [f64::NEG_INFINITY; 3],
            non_finite: 0,
            negative_internal: 0,
            failed_floors: 0,
            failed_floor_energy: 0.0,
        }
    }
}

impl Partial {
    /// Fold `other` (a later worker's slot) into `self`.
    pub fn merge(&mut self, other: &Partial) {
        self.kinetic += other.kinetic;
        self.internal += other.internal;
        for d in 0..3 {
            self.momentum[d] += other.momentum[d];
            self.lo[d] = self.lo[d].min(other.lo[d]);
            self.hi[d] = self.hi[d].max(other.hi[d]);
        }
        self.max_speed = self.max_speed.max(other.max_speed);
        self.non_finite += other.non_finite;
        self.negative_internal += other.negative_internal;
        self.failed_floors += other.failed_floors;
        self.failed_floor_energy += other.failed_floor_energy;
    }
}

/// The energy balance of a run so far (see the module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EnergyBalance {
    /// Initial total energy `E0 = K0 + U0` (J).
    pub initial_total: f64,
    /// Work of the body forces so far `W` (J).
    pub external_work: f64,
    /// Energy added so far by setting failed particles' negative internal energy to zero
    /// `F` (J; [`crate::material::failure`]): a known source, like `W`.
    pub failed_floor_energy: f64,
    /// How many times a failed particle's energy was set to zero.
    pub failed_floors: u64,
    /// Largest relative rise `(E - W - E0) / E0` after any step (0 if it never rose).
    pub max_rise: f64,
    /// The step of the largest rise (0: none).
    pub max_rise_step: u64,
    /// Largest relative fall `(E0 + W - E) / E0` after any step (0 if it never fell).
    pub max_fall: f64,
    /// The step of the largest fall (0: none).
    pub max_fall_step: u64,
    /// Most particles with negative internal energy after any one step.
    pub negative_internal_max: u64,
    /// Steps after which at least one particle had negative internal energy.
    pub negative_internal_steps: u64,
    /// The first such step, if any.
    pub first_negative_internal_step: Option<u64>,
}

impl EnergyBalance {
    /// A balance starting from the total energy `initial_total` (J).
    pub fn new(initial_total: f64) -> Self {
        Self { initial_total, ..Self::default() }
    }

    /// `(E - W - F - E0) / E0` for the total energy `total`; 0 when `E0 = 0` (nothing to
    /// compare with).
    pub fn relative_change(&self, total: f64) -> f64 {
        if self.initial_total > 0.0 {
            (total - self.external_work - self.failed_floor_energy - self.initial_total) / self.initial_total
        } else {
            0.0
        }
    }

    /// Add the work `W += dt b . P_mid` of a uniform body force `b` (m/s^2) during a step in
    /// which the momentum went from `p_old` to `p_new` (kg m/s).
    pub fn add_body_force_work(&mut self, body_force: Vec3, p_old: Vec3, p_new: Vec3, dt: f64) {
        let mut w = 0.0;
        for d in 0..3 {
            w += body_force[d] * 0.5 * (p_old[d] + p_new[d]);
        }
        self.external_work += dt * w;
    }

    /// Book `energy` (J) added in a step by `count` failed particles whose negative internal
    /// energy was set to zero.
    pub fn add_failed_floor(&mut self, energy: f64, count: u64) {
        self.failed_floor_energy += energy;
        self.failed_floors += count;
    }

    /// Record step `step` with total energy `total` and `negative_internal` particles of
    /// negative internal energy; returns the relative change `(E - W - E0) / E0`.
    pub fn record(&mut self, step: u64, total: f64, negative_internal: u64) -> f64 {
        let change = self.relative_change(total);
        if change > self.max_rise {
            (self.max_rise, self.max_rise_step) = (change, step);
        }
        if -change > self.max_fall {
            (self.max_fall, self.max_fall_step) = (-change, step);
        }
        if negative_internal > 0 {
            self.negative_internal_max = self.negative_internal_max.max(negative_internal);
            self.negative_internal_steps += 1;
            self.first_negative_internal_step.get_or_insert(step);
        }
        change
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn balance_tracks_extremes_negative_energy_and_external_work() {
        let mut b = EnergyBalance::new(100.0);
        assert_eq!(b.record(1, 99.0, 0), -0.01);
        assert_eq!(b.record(2, 103.0, 2), 0.03);
        assert_eq!(b.record(3, 97.0, 5), -0.03);
        assert_eq!(b.record(4, 101.0, 0), 0.01);
        assert_eq!((b.max_rise, b.max_rise_step), (0.03, 2));
        assert_eq!((b.max_fall, b.max_fall_step), (0.03, 3));
        assert_eq!((b.negative_internal_max, b.negative_internal_steps), (5, 2));
        assert_eq!(b.first_negative_internal_step, Some(2));
        // A body force b = 10 m/s^2 along z on a momentum of 2 kg m/s for 0.5 s: W = 10 J,
        // which the balance credits: E = 110 J is no change.
        b.add_body_force_work([0.0, 0.0, 10.0], [0.0, 0.0, 1.0], [0.0, 0.0, 3.0], 0.5);
        assert_eq!(b.external_work, 10.0);
        assert_eq!(b.relative_change(110.0), 0.0);
        // Nothing to compare with when the run starts without energy.
        assert_eq!(EnergyBalance::new(0.0).record(1, 5.0, 0), 0.0);
    }
}
