//! Particles as a structure of arrays (one `Vec` per state variable).
//!
//! Particles carry every state variable of the method (paper Section 1): position,
//! velocity, mass, density, Cauchy stress, effective plastic strain, internal energy and a
//! failure flag, plus the current sound speed (for the time step). A hot loop reads only the
//! arrays it needs, and a parallel phase splits each array into the same disjoint chunks.

use crate::capacity_bytes;
use crate::math::{Sym, Vec3};

/// The particle state, one array per variable, all of the same length.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Particles {
    /// Position `x_p` (m).
    pub x: Vec<Vec3>,
    /// Velocity `v_p` (m/s).
    pub v: Vec<Vec3>,
    /// Mass `m_p` (kg), constant.
    pub mass: Vec<f64>,
    /// Current density `rho_p` (kg/m^3); the volume is `m_p / rho_p`.
    pub rho: Vec<f64>,
    /// Cauchy stress in Voigt order `[xx, yy, zz, yz, zx, xy]` (Pa), tension positive.
    pub stress: Vec<Sym>,
    /// Effective plastic strain.
    pub eps_p: Vec<f64>,
    /// Specific internal energy (J/kg).
    pub e_int: Vec<f64>,
    /// Current sound speed (m/s), used for the next time step.
    pub sound: Vec<f64>,
    /// Failure flag: once set, the particle carries no stress.
    pub failed: Vec<bool>,
}

impl Particles {
    /// An empty set with room for `n` particles.
    pub fn with_capacity(n: usize) -> Self {
        Self {
            x: Vec::with_capacity(n),
            v: Vec::with_capacity(n),
            mass: Vec::with_capacity(n),
            rho: Vec::with_capacity(n),
            stress: Vec::with_capacity(n),
            eps_p: Vec::with_capacity(n),
            e_int: Vec::with_capacity(n),
            sound: Vec::with_capacity(n),
            failed: Vec::with_capacity(n),
        }
    }

    /// Add a stress-free particle at rest in its reference state.
    pub fn push(&mut self, x: Vec3, v: Vec3, mass: f64, rho: f64, sound: f64) {
        self.x.push(x);
        self.v.push(v);
        self.mass.push(mass);
        self.rho.push(rho);
        self.stress.push([0.0; 6]);
        self.eps_p.push(0.0);
        self.e_int.push(0.0);
        self.sound.push(sound);
        self.failed.push(false);
    }

    /// Number of particles.
    pub fn len(&self) -> usize {
        self.x.len()
    }

    /// Whether there are no particles.
    pub fn is_empty(&self) -> bool {
        self.x.is_empty()
    }

    /// Total mass (kg).
    pub fn total_mass(&self) -> f64 {
        self.mass.iter().sum()
    }

    /// Total linear momentum `sum m_p v_p` (kg m/s).
    pub fn momentum(&self) -> Vec3 {
        let mut p = [0.0; 3];
        for (m, v) in self.mass.iter().zip(&self.v) {
            for d in 0..3 {
                p[d] += m * v[d];
            }
        }
        p
    }

    /// Total kinetic energy (J).
    pub fn kinetic_energy(&self) -> f64 {
        crate::energy::kinetic(&self.mass, &self.v)
    }

    /// Total internal energy (J).
    pub fn internal_energy(&self) -> f64 {
        crate::energy::internal(&self.mass, &self.e_int)
    }

    /// Smallest and largest coordinate of any particle, per axis.
    pub fn bounding_box(&self) -> (Vec3, Vec3) {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for x in &self.x {
            for d in 0..3 {
                lo[d] = lo[d].min(x[d]);
                hi[d] = hi[d].max(x[d]);
            }
        }
        (lo, hi)
    }

    /// Number of failed particles.
    pub fn failed_count(&self) -> usize {
        self.failed.iter().filter(|&&f| f).count()
    }

    /// Memory held by the arrays (bytes, by capacity).
    pub fn bytes(&self) -> usize {
        capacity_bytes(&self.x)
            + capacity_bytes(&self.v)
            + capacity_bytes(&self.mass)
            + capacity_bytes(&self.rho)
            + capacity_bytes(&self.stress)
            + capacity_bytes(&self.eps_p)
            + capacity_bytes(&self.e_int)
            + capacity_bytes(&self.sound)
            + capacity_bytes(&self.failed)
    }
}
