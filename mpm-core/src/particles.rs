//! Particles as a structure of arrays (one `Vec` per state variable).
//!
//! Particles carry every state variable of the method (paper Section 1): position,
//! velocity, mass, density, Cauchy stress, effective plastic strain, internal energy and a
//! failure flag, plus the current sound speed (for the time step). A hot loop reads only the
//! arrays it needs, and a parallel phase splits each array into the same disjoint chunks.

use crate::capacity_bytes;
use crate::math::{Sym, Vec3};

/// Run `$op` with `$a` bound to each of the nine arrays of `$p` in turn (their element types
/// differ, so a closure cannot do it).
macro_rules! each_array {
    ($p:expr, $a:ident => $op:expr) => {
        each_array!(@ $p, $a => $op; x v mass rho stress eps_p e_int sound failed)
    };
    (@ $p:expr, $a:ident => $op:expr; $($field:ident)*) => {{
        $({
            let $a = &mut $p.$field;
            $op;
        })*
    }};
}

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

/// Values per particle in [`Particles::pack`]'s flat form: position (3), velocity (3), mass,
/// density, stress (6), plastic strain, internal energy, sound speed, failure flag.
pub const PACKED_WIDTH: usize = 18;

impl Particles {
    /// Append particle `p`'s state to `out` as [`PACKED_WIDTH`] values (for moving it to
    /// another process).
    pub fn pack(&self, p: usize, out: &mut Vec<f64>) {
        out.extend_from_slice(&self.x[p]);
        out.extend_from_slice(&self.v[p]);
        out.push(self.mass[p]);
        out.push(self.rho[p]);
        out.extend_from_slice(&self.stress[p]);
        out.push(self.eps_p[p]);
        out.push(self.e_int[p]);
        out.push(self.sound[p]);
        out.push(if self.failed[p] { 1.0 } else { 0.0 });
    }

    /// Append a particle from [`PACKED_WIDTH`] values written by [`Particles::pack`].
    ///
    /// # Panics
    /// If `v` is not [`PACKED_WIDTH`] long (a caller's framing error).
    pub fn push_packed(&mut self, v: &[f64]) {
        self.push([0.0; 3], [0.0; 3], 0.0, 0.0, 0.0);
        self.set_packed(self.len() - 1, v);
    }

    /// Overwrite particle `p` with [`PACKED_WIDTH`] values written by [`Particles::pack`].
    ///
    /// # Panics
    /// If `v` is not [`PACKED_WIDTH`] long (a caller's framing error) or `p` is out of range.
    pub fn set_packed(&mut self, p: usize, v: &[f64]) {
        assert_eq!(v.len(), PACKED_WIDTH, "a packed particle has {PACKED_WIDTH} values");
        self.x[p] = [v[0], v[1], v[2]];
        self.v[p] = [v[3], v[4], v[5]];
        self.mass[p] = v[6];
        self.rho[p] = v[7];
        self.stress[p] = [v[8], v[9], v[10], v[11], v[12], v[13]];
        self.eps_p[p] = v[14];
        self.e_int[p] = v[15];
        self.sound[p] = v[16];
        self.failed[p] = v[17] != 0.0;
    }

    /// Remove particle `p`, moving the last particle into its place (no allocation).
    pub fn swap_remove(&mut self, p: usize) {
        each_array!(self, a => { a.swap_remove(p); });
    }

    /// Room for `additional` more particles. When the arrays must grow they grow by at
    /// least 1/16 of their length, not to twice it as a `push` would: a rank's set gains a
    /// few particles per step (migration), and should neither reallocate every step nor
    /// hold room for twice its particles.
    pub fn reserve_headroom(&mut self, additional: usize) {
        if self.x.capacity() - self.len() >= additional {
            return;
        }
        let n = additional.max(self.len() / 16);
        each_array!(self, a => a.reserve_exact(n));
    }

    /// Release the arrays' unused capacity.
    pub fn shrink_to_fit(&mut self) {
        each_array!(self, a => a.shrink_to_fit());
    }

    /// Keep the particles for which `keep(p)` is true, in their order.
    pub fn retain_indices(&mut self, mut keep: impl FnMut(usize) -> bool) {
        let mask: Vec<bool> = (0..self.len()).map(&mut keep).collect();
        fn retain<T>(v: &mut Vec<T>, mask: &[bool]) {
            let mut i = 0;
            v.retain(|_| {
                i += 1;
                mask[i - 1]
            });
        }
        each_array!(self, a => retain(a, &mask));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pack_round_trip_and_swap_remove() {
        let mut a = Particles::with_capacity(3);
        for i in 0..3 {
            let f = i as f64;
            a.push([f, f + 0.5, f + 0.25], [1.0, 2.0, f], 1.0 + f, 7800.0, 4000.0);
            a.stress[i] = [f, 1.0, 2.0, 3.0, 4.0, 5.0];
            a.e_int[i] = 10.0 * f;
        }
        a.failed[1] = true;
        let mut buf = Vec::new();
        a.pack(1, &mut buf);
        assert_eq!(buf.len(), PACKED_WIDTH);
        let mut b = Particles::default();
        b.push_packed(&buf);
        assert_eq!(b.x[0], a.x[1]);
        assert_eq!(b.stress[0], a.stress[1]);
        assert!(b.failed[0]);
        let mut again = Vec::new();
        b.pack(0, &mut again);
        assert_eq!(again, buf);
        let mut c = a.clone();
        c.set_packed(2, &buf);
        assert_eq!((c.x[2], c.e_int[2], c.failed[2]), (a.x[1], a.e_int[1], true));
        a.swap_remove(0);
        assert_eq!(a.len(), 2);
        assert_eq!(a.x[0], [2.0, 2.5, 2.25]);
        a.retain_indices(|p| p == 1);
        assert_eq!(a.len(), 1);
        assert!(a.failed[0]);
        a.shrink_to_fit();
        assert_eq!(a.bytes(), 137, "one particle: 2 x 24 + 48 + 5 x 8 + 1 bytes");
    }

    #[test]
    fn headroom_grows_by_a_sixteenth_not_by_doubling() {
        let mut a = Particles::with_capacity(64);
        for _ in 0..64 {
            a.push([0.0; 3], [0.0; 3], 1.0, 1.0, 1.0);
        }
        a.reserve_headroom(1);
        assert_eq!(a.x.capacity(), 68);
        assert_eq!(a.failed.capacity(), 68);
        let before = a.bytes();
        a.reserve_headroom(4);
        assert_eq!(a.bytes(), before, "room enough: nothing reallocated");
        a.reserve_headroom(10);
        assert_eq!(a.x.capacity(), 74);
    }
}
