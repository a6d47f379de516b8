//! Kinetic and internal energy (paper Section 1, step 10).
//!
//! Inside a time step the energies are reduced in parallel: every worker sums its own
//! particle chunk into its own slot and the slots are added in worker order, so a given
//! thread count always gives the same bits. The functions here are the plain sums used
//! for initial values and by tests.

use crate::math::Vec3;

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
    /// Particles outside the (fixed) grid after the position update.
    pub outside: u64,
    /// The first particle outside the grid, if any.
    pub first_outside: Option<usize>,
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
            outside: 0,
            first_outside: None,
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
        self.outside += other.outside;
        if self.first_outside.is_none() {
            self.first_outside = other.first_outside;
        }
    }
}
