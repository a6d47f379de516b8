//! Material models (paper Section 2): J2 plasticity with hardening `A + B eps_p^n`
//! ([`j2`]), a pressure from an equation of state ([`eos`]) plus an artificial bulk
//! viscosity ([`viscosity`]), and failure ([`failure`]).
//!
//! The stress update of one particle ([`update_point`]) follows the paper's Eq. 15: the old
//! stress is rotated by the Jaumann increment, the deviator takes an elastic trial step and
//! a radial return, the internal energy gains the work of the stress that acted in the step,
//! the pressure comes from the EOS at the new density and energy, and the viscosity `q` is
//! added in compression. A failed particle keeps only its pressure, clipped at zero. The
//! update is generic over the EOS, so the choice of EOS is dispatched once per particle
//! chunk, never per particle.

pub mod eos;
pub mod failure;
pub mod j2;
pub mod viscosity;

pub use eos::{Eos, LinearEos, MgForm, MieGruneisen, PressureModel};
pub use failure::Failure;
pub use j2::Hardening;
pub use viscosity::{BulkViscosity, ViscosityTerms};

use crate::error::SimError;
use crate::math::{ddot, deviator, Sym, Vec3};
use crate::simd::{array, Block, Real, F4, LANES, LANES8};
use serde::Serialize;

/// A material: elastic constants, hardening, EOS and optional failure.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Material {
    /// Human-readable name.
    pub name: String,
    /// Reference density `rho0` (kg/m^3).
    pub density: f64,
    /// Young's modulus (Pa).
    pub youngs: f64,
    /// Poisson's ratio.
    pub poisson: f64,
    /// Yield stress `A + B eps_p^n` (Eq. 17).
    pub hardening: Hardening,
    /// Pressure model.
    pub eos: Eos,
    /// Failure criterion (hypervelocity problem only).
    pub failure: Option<Failure>,
}

impl Material {
    /// OFHC copper of the Taylor bar (paper Table 1) with the Mie-Grüneisen EOS in `form`.
    pub fn ofhc_copper(form: MgForm) -> Self {
        let density = 8930.0;
        Self {
            name: "OFHC copper (Table 1)".into(),
            density,
            youngs: 117.0e9,
            poisson: 0.35,
            hardening: Hardening { a: 157.0e6, b: 425.0e6, n: 1.0 },
            eos: Eos::MieGruneisen(MieGruneisen { rho0: density, c0: 3940.0, s: 1.49, gamma0: 1.96, form }),
            failure: None,
        }
    }

    /// Lead of the hypervelocity impact (paper Table 3), with failure.
    pub fn lead(form: MgForm) -> Self {
        let density = 11350.0;
        Self {
            name: "lead (Table 3)".into(),
            density,
            youngs: 22.4e9,
            poisson: 0.42,
            hardening: Hardening { a: 12.0e6, b: 125.0e6, n: 1.0 },
            eos: Eos::MieGruneisen(MieGruneisen { rho0: density, c0: 2092.0, s: 1.45, gamma0: 2.0, form }),
            failure: Some(Failure { eps_f: 3.0, p_min: -1500.0e6 }),
        }
    }

    /// A linear-elastic material (no yield, linear EOS with the bulk modulus of `E`, `nu`),
    /// for the analytical validation problems.
    pub fn elastic(name: &str, density: f64, youngs: f64, poisson: f64) -> Self {
        let bulk = youngs / (3.0 * (1.0 - 2.0 * poisson));
        Self {
            name: name.into(),
            density,
            youngs,
            poisson,
            hardening: Hardening { a: f64::INFINITY, b: 0.0, n: 1.0 },
            eos: Eos::Linear(LinearEos { bulk }),
            failure: None,
        }
    }

    /// Shear modulus `G = E / (2 (1 + nu))`.
    pub fn shear_modulus(&self) -> f64 {
        self.youngs / (2.0 * (1.0 + self.poisson))
    }

    /// Bulk modulus `K = E / (3 (1 - 2 nu))` of the elastic constants.
    pub fn bulk_modulus(&self) -> f64 {
        self.youngs / (3.0 * (1.0 - 2.0 * self.poisson))
    }

    /// Longitudinal (P-wave, uniaxial-strain) speed `sqrt((K + 4G/3) / rho0)`.
    pub fn p_wave_speed(&self) -> f64 {
        ((self.bulk_modulus() + 4.0 / 3.0 * self.shear_modulus()) / self.density).sqrt()
    }

    /// Sound speed at the reference state, as used for the first time step: the larger of
    /// the elastic P-wave speed and the EOS bulk speed plus the shear contribution.
    pub fn reference_sound_speed(&self) -> f64 {
        let k_eos = self.eos.reference_bulk_modulus();
        let k = k_eos.max(self.bulk_modulus());
        ((k + 4.0 / 3.0 * self.shear_modulus()) / self.density).sqrt()
    }

    /// The constants the stress update needs, precomputed.
    pub fn consts(&self) -> PointConsts {
        let g = self.shear_modulus();
        let c = self.reference_sound_speed();
        PointConsts {
            g,
            rho0: self.density,
            inv_rho0: 1.0 / self.density,
            hardening: self.hardening,
            failure: self.failure,
            four_thirds_g: 4.0 / 3.0 * g,
            viscosity: ViscosityTerms::default(),
            energy_tolerance: NEGATIVE_ENERGY_TOLERANCE * c * c,
        }
    }

    /// Check that the constants describe a material the solver can run: a clear error naming
    /// the constant and the admissible range otherwise.
    pub fn validate(&self) -> Result<(), SimError> {
        let bad = |problem: String| Err(SimError::Material { name: self.name.clone(), problem });
        let positive = |what: &str, v: f64| {
            if v.is_finite() && v > 0.0 {
                Ok(())
            } else {
                bad(format!("{what} must be a finite number > 0, got {v}"))
            }
        };
        positive("the density (kg/m^3)", self.density)?;
        positive("Young's modulus E (Pa)", self.youngs)?;
        if !(self.poisson > 0.0 && self.poisson < 0.5) {
            return bad(format!("Poisson's ratio must lie strictly between 0 and 0.5, got {}", self.poisson));
        }
        let h = &self.hardening;
        if h.a.is_nan() || h.a <= 0.0 {
            return bad(format!(
                "the initial yield stress A must be > 0 Pa (infinite for an elastic material), got {}",
                h.a
            ));
        }
        if !(h.b.is_finite() && h.b >= 0.0) {
            return bad(format!("the hardening modulus B must be a finite number >= 0 Pa, got {}", h.b));
        }
        positive("the hardening exponent n", h.n)?;
        match self.eos {
            Eos::MieGruneisen(m) => {
                if (m.rho0 / self.density - 1.0).abs() > 1e-12 {
                    return bad(format!(
                        "the Mie-Grüneisen reference density rho0 = {} must equal the material density {}",
                        m.rho0, self.density
                    ));
                }
                positive("the bulk sound speed c0 (m/s)", m.c0)?;
                if !(m.s.is_finite() && m.s >= 1.0) {
                    return bad(format!("the Hugoniot slope s must be a finite number >= 1, got {}", m.s));
                }
                if !(m.gamma0.is_finite() && m.gamma0 >= 0.0) {
                    return bad(format!(
                        "the Grüneisen coefficient gamma0 must be a finite number >= 0, got {}",
                        m.gamma0
                    ));
                }
            }
            Eos::Linear(l) => positive("the bulk modulus K of the linear EOS (Pa)", l.bulk)?,
        }
        if let Some(f) = self.failure {
            positive("the failure plastic strain eps_f", f.eps_f)?;
            if !(f.p_min.is_finite() && f.p_min <= 0.0) {
                return bad(format!("the failure pressure p_min must be a finite tension (<= 0 Pa), got {}", f.p_min));
            }
        }
        Ok(())
    }
}

/// A particle's specific internal energy counts as negative below `-NEGATIVE_ENERGY_TOLERANCE
/// c^2` (`c` the material's reference sound speed; lead 0.05 J/kg, copper 0.2 J/kg). The work
/// of a step is the old stress times the step's strain (see [`update_point`]), so where an
/// elastic strain reverses a particle's energy lags its stored elastic energy by about
/// `c^2 de^2 / 2` for a strain step `de`: below this tolerance for steps up to 1.4e-4, as in
/// the elastic parts of the Taylor bar (whose most negative energy is 0.06 J/kg, 2.6e-9 c^2).
pub const NEGATIVE_ENERGY_TOLERANCE: f64 = 1e-8;

/// Per-material constants used in the hot loop.
#[derive(Clone, Copy, Debug)]
pub struct PointConsts {
    /// Shear modulus (Pa).
    pub g: f64,
    /// Reference density (kg/m^3).
    pub rho0: f64,
    /// `1 / rho0`: the update multiplies by it (a division costs the vector unit about ten
    /// times a multiplication, and the update had twelve).
    pub inv_rho0: f64,
    /// Yield stress law.
    pub hardening: Hardening,
    /// Failure thresholds.
    pub failure: Option<Failure>,
    /// `4 G / 3` (Pa).
    pub four_thirds_g: f64,
    /// Artificial bulk viscosity on the simulation's grid (off in [`Material::consts`]).
    pub viscosity: ViscosityTerms,
    /// Specific internal energies above `-energy_tolerance` (J/kg) count as not negative:
    /// [`NEGATIVE_ENERGY_TOLERANCE`] times the squared reference sound speed.
    pub energy_tolerance: f64,
}

impl PointConsts {
    /// The same constants with the artificial bulk viscosity `v` on a grid of cell size `dx`.
    pub fn with_viscosity(self, v: BulkViscosity, dx: f64) -> Self {
        Self { viscosity: v.on_grid(dx), ..self }
    }
}

/// State of one particle touched by the stress update.
pub struct PointState<'a> {
    /// Cauchy stress (Pa).
    pub stress: &'a mut Sym,
    /// Effective plastic strain.
    pub eps_p: &'a mut f64,
    /// Specific internal energy (J/kg).
    pub e_int: &'a mut f64,
    /// Density (kg/m^3).
    pub rho: &'a mut f64,
    /// Sound speed (m/s).
    pub sound: &'a mut f64,
    /// Failure flag.
    pub failed: &'a mut bool,
}

/// Update density, stress, plastic strain, internal energy, sound speed and failure of one
/// particle for the strain increment `de` and spin increment `dw` (`[w_yz, w_zx, w_xy]`)
/// of Eqs. 12-13 over the time step `dt` (paper Eqs. 14, 15, 17, 18). Returns the speed that
/// limits the next time step: the sound speed, raised by the artificial viscosity in
/// compression (see [`viscosity`]).
///
/// Internal energy: `e += sigma_old : de_mid / rho_old`, the work of the stress that acted in
/// this step (the step's nodal forces came from `sigma_old` and the volume `m / rho_old`)
/// over the strain increment `de_mid` of the mid-step nodal velocity `(v_i(k) + v_i(k+1)) / 2`
/// (see [`crate::transfer::update`]). That is exactly the work the kinetic energy lost to the
/// stress in the step, so kinetic plus internal energy is conserved to round-off: a shock
/// turns kinetic energy into heat and nothing is lost or created (the trapezoidal rule,
/// `(sigma_old + sigma_new) / 2 : de`, counts work of a stress that has not acted yet and
/// creates energy where the stress jumps, as at an impact). The new pressure then follows
/// from the EOS at the new density and energy. The stored stress is the total stress
/// `s - (p + q) I`, so the viscosity's work enters the energy like the pressure's. A failed
/// particle has `s = 0` and its `p + q` clipped at `>= 0`.
///
/// A failed particle's internal energy is not allowed to stay negative: see
/// [`failure`], "Internal energy". The second value returned is the specific energy (J/kg) that rule
/// added in this step (0 almost always).
#[inline(always)]
pub fn update_point<E: PressureModel>(
    c: &PointConsts,
    eos: &E,
    de: &Sym,
    de_mid: &Sym,
    dw: Vec3,
    dt: f64,
    st: PointState<'_>,
) -> (f64, f64) {
    let rho_old = *st.rho;
    let tr_de = de[0] + de[1] + de[2];
    let rho_new = rho_old / (1.0 + tr_de); // Eq. 14
    *st.rho = rho_new;
    let sigma = *st.stress;
    let e_new = *st.e_int + ddot(&sigma, de_mid) / rho_old;
    *st.e_int = e_new;
    let mut failed = *st.failed;
    let s_new = if failed {
        [0.0; 6]
    } else {
        // Jaumann rotation of the old stress (Eq. 15), elastic trial deviator, radial return.
        let rot = crate::math::jaumann(&sigma, dw);
        let s_rot = deviator(&std::array::from_fn(|i| sigma[i] + rot[i]));
        let de_dev = deviator(de);
        let two_g = 2.0 * c.g;
        let trial = std::array::from_fn(|i| s_rot[i] + two_g * de_dev[i]);
        let (s_new, eps_p_new) = j2::radial_return(trial, *st.eps_p, c.g, &c.hardening);
        *st.eps_p = eps_p_new;
        s_new
    };
    let (q, big_q) = c.viscosity.q(rho_new, *st.sound, tr_de * (1.0 / dt));
    let mu_new = rho_new * c.inv_rho0 - 1.0;
    let (mut p, mut dp_dmu) = eos.pressure(mu_new, e_new);
    if !failed && c.failure.is_some_and(|f| f.fails(*st.eps_p, p)) {
        failed = true;
        *st.failed = true;
    }
    let mut floor = 0.0;
    if failed && e_new < 0.0 {
        // See failure.rs, "Internal energy": the deficit is added (and reported by the caller), the pressure
        // is that of the heat-free state.
        floor = -e_new;
        *st.e_int = 0.0;
        (p, dp_dmu) = eos.pressure(mu_new, 0.0);
    }
    *st.stress = if failed {
        let p_total = (p + q).max(0.0);
        [-p_total, -p_total, -p_total, 0.0, 0.0, 0.0]
    } else {
        let p_total = p + q;
        [s_new[0] - p_total, s_new[1] - p_total, s_new[2] - p_total, s_new[3], s_new[4], s_new[5]]
    };

    // Sound speed for the next step: c^2 = dp/drho, plus (4G/3)/rho while the particle
    // carries shear stress.
    let shear = if failed { 0.0 } else { c.four_thirds_g / rho_new };
    let sound = ((dp_dmu * c.inv_rho0).max(0.0) + shear).sqrt();
    *st.sound = sound;
    (viscosity::signal_speed(big_q, sound), floor)
}

/// The state of [`LANES`] particles, one array per variable and component (lane `l` is
/// particle `l` of the block), for [`update_lanes`].
#[derive(Clone, Copy, Debug, Default)]
pub struct Lanes {
    /// Strain increment `de` per Voigt component.
    pub de: [[f64; LANES]; 6],
    /// Strain increment of the mid-step velocity, per Voigt component.
    pub de_mid: [[f64; LANES]; 6],
    /// Spin increment `[w_yz, w_zx, w_xy]`.
    pub dw: [[f64; LANES]; 3],
    /// Cauchy stress per Voigt component (in: old, out: new).
    pub stress: [[f64; LANES]; 6],
    /// Effective plastic strain (in and out).
    pub eps_p: [f64; LANES],
    /// Specific internal energy (in and out).
    pub e_int: [f64; LANES],
    /// Density (in and out).
    pub rho: [f64; LANES],
    /// Sound speed (in and out).
    pub sound: [f64; LANES],
    /// Failure flag (in and out).
    pub failed: [bool; LANES],
    /// Out: the signal speed ([`update_point`]'s first value).
    pub signal: [f64; LANES],
    /// Out: the energy the failed-particle rule added ([`update_point`]'s second value).
    pub floor: [f64; LANES],
}

/// [`update_point`] for the [`LANES`] particles of `b` at once, without branches on the
/// particles' state: both sides of every decision (compression or expansion, yield, failure,
/// the EOS's three ranges) are computed and selected lane by lane, with `update_point`'s
/// operations in its order, so every lane's result is bitwise `update_point`'s (test
/// `lanes_are_bitwise_update_point`). Each operation is one on all lanes ([`F4`]): two
/// instructions of two lanes on the baseline x86-64 target, one of four where the step runs
/// it with AVX2 ([`crate::simd`]).
///
/// `LINEAR` says the hardening exponent is 1 (both paper materials), whose radial return is
/// closed-form; otherwise each lane takes the Newton iteration of [`j2::radial_return`].
#[inline(always)]
pub fn update_lanes<E: PressureModel, const LINEAR: bool>(c: &PointConsts, eos: &E, dt: f64, b: &mut Lanes) {
    let f4 = |a: [f64; LANES]| F4(a);
    let state = LaneState {
        stress: b.stress.map(f4),
        eps_p: f4(b.eps_p),
        e_int: f4(b.e_int),
        rho: f4(b.rho),
        sound: f4(b.sound),
        failed: F4::mask_from(|l| b.failed[l]),
    };
    let (out, signal, floor) =
        update_block::<F4, E, LINEAR>(c, eos, dt, b.de.map(f4), b.de_mid.map(f4), b.dw.map(f4), state);
    b.stress = out.stress.map(|v| v.0);
    b.eps_p = out.eps_p.0;
    b.e_int = out.e_int.0;
    b.rho = out.rho.0;
    b.sound = out.sound.0;
    b.failed = F4::mask_bools(out.failed);
    b.signal = signal.0;
    b.floor = floor.0;
}

/// A particle's (`f64`) or a block's ([`F4`]) state in [`update_block`].
#[derive(Clone, Copy)]
pub(crate) struct LaneState<R: Real> {
    pub stress: [R; 6],
    pub eps_p: R,
    pub e_int: R,
    pub rho: R,
    pub sound: R,
    pub failed: R::Mask,
}

/// The body of [`update_lanes`]: [`update_point`] without branches, for one `f64` or a block.
/// Returns the new state, the signal speed and the energy the failed-particle rule added.
#[inline(always)]
pub(crate) fn update_block<R: Real, E: PressureModel, const LINEAR: bool>(
    c: &PointConsts,
    eos: &E,
    dt: f64,
    de: [R; 6],
    de_mid: [R; 6],
    dw: [R; 3],
    st: LaneState<R>,
) -> (LaneState<R>, R, R) {
    let zero = R::splat(0.0);
    let rho_old = st.rho;
    let tr_de = de[0] + de[1] + de[2];
    let rho_new = rho_old / (R::splat(1.0) + tr_de); // Eq. 14
    let sigma = st.stress;
    let e_new = st.e_int + ddot(&sigma, &de_mid) / rho_old;
    let failed = st.failed;
    // Jaumann rotation, elastic trial deviator, radial return: computed for every lane, a
    // failed one discards them.
    let rot = crate::math::jaumann(&sigma, dw);
    let s_rot = deviator(&array(|i| sigma[i] + rot[i]));
    let de_dev = deviator(&de);
    let two_g = R::splat(2.0 * c.g);
    let trial: [R; 6] = array(|i| s_rot[i] + two_g * de_dev[i]);
    let (s_ret, eps_ret): ([R; 6], R) = if LINEAR {
        // j2::radial_return for n = 1: `3.0 * g * d` is `(3.0 * g) * d`.
        let j = crate::math::von_mises(&trial);
        let y0 = R::splat(c.hardening.a) + R::splat(c.hardening.b) * st.eps_p;
        let d = (j - y0) * R::splat(1.0 / (3.0 * c.g + c.hardening.b));
        let scale = (j - R::splat(3.0 * c.g) * d) / j;
        let elastic = j.le(y0);
        (array(|i| R::select(elastic, trial[i], trial[i] * scale)), R::select(elastic, st.eps_p, st.eps_p + d))
    } else {
        let mut s = [[0.0; LANES8]; 6];
        let mut e = [0.0; LANES8];
        for l in 0..R::WIDTH {
            let (sl, el) = j2::radial_return(array(|i| trial[i].lane(l)), st.eps_p.lane(l), c.g, &c.hardening);
            for i in 0..6 {
                s[i][l] = sl[i];
            }
            e[l] = el;
        }
        (array(|i| R::from_lanes(|l| s[i][l])), R::from_lanes(|l| e[l]))
    };
    let eps_p_new = R::select(failed, st.eps_p, eps_ret);
    // ViscosityTerms::q without its branch.
    let v = c.viscosity;
    let tr_d = tr_de * R::splat(1.0 / dt);
    let rate = -tr_d;
    let big_q_c = R::splat(v.c1_dx) * rate + R::splat(v.c2) * st.sound;
    let q_c = rho_new * R::splat(v.dx) * rate * big_q_c;
    let expanding = tr_d.ge(zero);
    let (q, big_q) = (R::select(expanding, zero, q_c), R::select(expanding, zero, big_q_c));
    let mu_new = rho_new * R::splat(c.inv_rho0) - R::splat(1.0);
    let [(p_e, dp_e), (p_0, dp_0)] = eos.pressure_and_heat_free(mu_new, e_new);
    let fails = match c.failure {
        Some(f) => eps_p_new.ge(R::splat(f.eps_f)) | p_e.lt(R::splat(f.p_min)),
        None => R::mask(false),
    };
    let failed_new = failed | fails;
    let heat_free = failed_new & e_new.lt(zero);
    let (p, dp_dmu) = (R::select(heat_free, p_0, p_e), R::select(heat_free, dp_0, dp_e));
    let floor = R::select(heat_free, -e_new, zero);
    let e_out = R::select(heat_free, zero, e_new);
    let p_total = p + q;
    let p_clipped = -(p_total.max(zero));
    let stress = array(|i| {
        if i < 3 {
            R::select(failed_new, p_clipped, s_ret[i] - p_total)
        } else {
            R::select(failed_new, zero, s_ret[i])
        }
    });
    let shear = R::select(failed_new, zero, R::splat(c.four_thirds_g) / rho_new);
    let sound = ((dp_dmu * R::splat(c.inv_rho0)).max(zero) + shear).sqrt();
    let signal = big_q + (big_q * big_q + sound * sound).sqrt();
    let out = LaneState { stress, eps_p: eps_p_new, e_int: e_out, rho: rho_new, sound, failed: failed_new };
    (out, signal, floor)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{trace, von_mises};
    use crate::testing::unit_stream;

    /// A time step for the unit tests (s).
    const DT: f64 = 1e-8;

    /// One particle's state.
    struct Point {
        s: Sym,
        eps_p: f64,
        e: f64,
        rho: f64,
        sound: f64,
        failed: bool,
    }

    impl Point {
        fn at_rest(m: &Material) -> Self {
            Self { s: [0.0; 6], eps_p: 0.0, e: 0.0, rho: m.density, sound: m.reference_sound_speed(), failed: false }
        }

        /// One stress update with strain increment `de`, also at mid-step (a steady rate),
        /// no spin; the signal speed.
        fn step<E: PressureModel>(&mut self, c: &PointConsts, eos: &E, de: Sym) -> f64 {
            self.step_floor(c, eos, de).0
        }

        /// [`Point::step`], also returning the energy the failed-particle rule added.
        fn step_floor<E: PressureModel>(&mut self, c: &PointConsts, eos: &E, de: Sym) -> (f64, f64) {
            update_point(
                c,
                eos,
                &de,
                &de,
                [0.0; 3],
                DT,
                PointState {
                    stress: &mut self.s,
                    eps_p: &mut self.eps_p,
                    e_int: &mut self.e,
                    rho: &mut self.rho,
                    sound: &mut self.sound,
                    failed: &mut self.failed,
                },
            )
        }

        fn pressure(&self) -> f64 {
            -trace(&self.s) / 3.0
        }
    }

    fn mg(m: &Material) -> MieGruneisen {
        let Eos::MieGruneisen(eos) = m.eos else { unreachable!("{} uses Mie-Grüneisen", m.name) };
        eos
    }

    fn uniform(e: f64) -> Sym {
        [e, e, e, 0.0, 0.0, 0.0]
    }

    #[test]
    fn copper_derived_constants_match_the_paper() {
        let m = Material::ofhc_copper(MgForm::Hugoniot);
        assert!((m.bulk_modulus() / 1e9 - 130.0).abs() < 0.05);
        assert!((m.shear_modulus() / 1e9 - 43.33).abs() < 0.01);
        assert!((m.p_wave_speed() - 4586.0).abs() < 1.0);
        assert!(((m.youngs / m.density).sqrt() - 3620.0).abs() < 1.0);
    }

    #[test]
    fn elastic_uniaxial_strain_gives_lame_stresses_and_stores_the_work() {
        let m = Material::elastic("e", 8930.0, 117e9, 0.35);
        let Eos::Linear(eos) = m.eos else { unreachable!() };
        let mut pt = Point::at_rest(&m);
        let (eps, n) = (-1e-5, 100);
        let mut work = 0.0;
        for _ in 0..n {
            // The energy gains the old stress times the increment, per unit mass.
            let (s_old, rho_old) = (pt.s, pt.rho);
            pt.step(&m.consts(), &eos, [0.0, 0.0, eps / n as f64, 0.0, 0.0, 0.0]);
            work += s_old[2] * eps / n as f64 / rho_old;
            assert!((pt.e - work).abs() <= 1e-14 * work, "{} vs {work}", pt.e);
        }
        let s = pt.s;
        let k = m.bulk_modulus();
        let g = m.shear_modulus();
        // sigma_zz = (K + 4G/3) eps (to first order), sigma_xx = (K - 2G/3) eps
        assert!((s[2] / ((k + 4.0 / 3.0 * g) * eps) - 1.0).abs() < 1e-4, "{s:?}");
        assert!((s[0] / ((k - 2.0 / 3.0 * g) * eps) - 1.0).abs() < 1e-4, "{s:?}");
        // Stored energy 1/2 sigma eps per volume, to the 1/n of the lagging stress.
        let w = 0.5 * (k + 4.0 / 3.0 * g) * eps * eps / 8930.0;
        assert!((pt.e / (w * (1.0 - 1.0 / n as f64)) - 1.0).abs() < 1e-3, "{} vs {w}", pt.e);
        assert!((pt.sound - m.p_wave_speed()).abs() / m.p_wave_speed() < 1e-4);
    }

    #[test]
    fn plastic_shear_lands_on_the_hardened_surface() {
        let m = Material::ofhc_copper(MgForm::Hugoniot);
        let (c, eos) = (m.consts(), mg(&m));
        let mut pt = Point::at_rest(&m);
        for _ in 0..20 {
            pt.step(&c, &eos, [0.0, 0.0, 0.0, 0.0, 0.0, 1e-3]);
        }
        assert!(pt.eps_p > 0.0);
        let j = von_mises(&deviator(&pt.s));
        let y = m.hardening.yield_stress(pt.eps_p);
        assert!((j - y).abs() / y < 1e-12, "J={j} yield={y}");
        // Pure shear keeps the density, so the pressure is the Grüneisen term of the plastic
        // heating alone: p = gamma0 rho0 e.
        assert_eq!(pt.rho, 8930.0);
        let (p, e) = (pt.pressure(), pt.e);
        assert!((p - 1.96 * 8930.0 * e).abs() < 1e-9 * p, "p = {p}, gamma0 rho0 e = {}", 1.96 * 8930.0 * e);
        assert!(e > 0.0, "plastic work heats the material");
    }

    #[test]
    fn lead_fails_in_tension_below_p_min_and_then_carries_no_stress() {
        let m = Material::lead(MgForm::Hugoniot);
        let (c, eos) = (m.consts(), mg(&m));
        let mut pt = Point::at_rest(&m);
        // 3 % volumetric expansion: p = rho0 c0^2 mu ~ -1.5 GPa at mu ~ -0.03.
        for _ in 0..10 {
            pt.step(&c, &eos, uniform(0.004));
        }
        assert!(pt.failed, "particle should have failed in tension");
        assert_eq!(pt.s, [0.0; 6]);
        // Lead in strong compression keeps its stiffness: no failure on p < p_min.
        let mut pt = Point::at_rest(&m);
        for _ in 0..60 {
            pt.step(&c, &eos, uniform(-0.004));
        }
        assert!(pt.rho > 1.9 * m.density && !pt.failed && pt.pressure() > 50e9, "{} Pa", pt.pressure());
    }

    #[test]
    fn failed_particle_keeps_its_pressure_in_compression_and_carries_no_tension() {
        let m = Material::lead(MgForm::Hugoniot);
        let (c, eos) = (m.consts(), mg(&m));
        let mut pt = Point { failed: true, ..Point::at_rest(&m) };
        // Compression, with shear: the stress is a pure pressure from the EOS.
        for _ in 0..10 {
            pt.step(&c, &eos, [-0.001, -0.0005, -0.0002, 0.0003, 0.0, -0.0002]);
        }
        let mu = pt.rho / m.density - 1.0;
        let p = pt.pressure();
        assert!(p > 0.0);
        assert!(pt.s[0] == pt.s[1] && pt.s[1] == pt.s[2] && pt.s[3..] == [0.0; 3], "no deviator: {:?}", pt.s);
        assert!((p - eos.pressure_at(mu, m.density * pt.e)).abs() < 1e-9 * p, "p = EOS(mu, E)");
        assert_eq!(pt.eps_p, 0.0, "no plastic flow once failed");
        assert!(pt.e > 0.0, "compression heats it");
        // Expansion well past the reference density: the EOS gives tension, the particle none.
        for _ in 0..10 {
            pt.step(&c, &eos, uniform(0.001));
        }
        assert!(pt.rho < m.density && eos.pressure_at(pt.rho / m.density - 1.0, m.density * pt.e) < 0.0);
        assert_eq!(pt.s, [0.0; 6], "clipped at p >= 0: {:?}", pt.s);
        // Once separated, it does no work and keeps its energy, in tension and back.
        let e_sep = pt.e;
        for de in [0.003, -0.002, 0.001] {
            pt.step(&c, &eos, uniform(de));
            assert_eq!((pt.s, pt.e), ([0.0; 6], e_sep));
        }
    }

    #[test]
    fn a_failed_particles_negative_energy_is_set_to_zero_and_reported_an_intact_ones_is_not() {
        let m = Material::lead(MgForm::Hugoniot);
        let (c, eos) = (m.consts(), mg(&m));
        // A failed particle left 2 kJ/kg below zero by the work lag, pulled apart: clipped
        // to no stress, it would keep the deficit for ever; its energy becomes zero instead,
        // and the step reports what that added.
        let mut pt = Point { failed: true, e: -2.0e3, ..Point::at_rest(&m) };
        let (_, added) = pt.step_floor(&c, &eos, uniform(1e-4));
        assert_eq!((pt.e, added, pt.s), (0.0, 2.0e3, [0.0; 6]));
        // The same in compression: the pressure is that of the state without heat.
        let mut pt = Point { failed: true, e: -2.0e3, ..Point::at_rest(&m) };
        let (_, added) = pt.step_floor(&c, &eos, uniform(-1e-3));
        let mu = pt.rho / m.density - 1.0;
        assert_eq!((pt.e, added), (0.0, 2.0e3));
        assert!((pt.pressure() - eos.pressure_at(mu, 0.0)).abs() < 1e-9 * pt.pressure(), "{}", pt.pressure());
        // Energy above zero is untouched, and nothing is reported.
        let mut pt = Point { failed: true, e: 5.0e3, ..Point::at_rest(&m) };
        assert_eq!(pt.step_floor(&c, &eos, uniform(1e-4)).1, 0.0);
        assert_eq!(pt.e, 5.0e3);
        // A particle that still carries stress keeps its deficit (it pays it back as it is
        // loaded again; the solver counts it as a violation).
        let mut pt = Point { e: -2.0e3, ..Point::at_rest(&m) };
        assert_eq!(pt.step_floor(&c, &eos, uniform(1e-4)).1, 0.0);
        assert_eq!((pt.e, pt.failed), (-2.0e3, false));
    }

    #[test]
    fn bulk_viscosity_adds_pressure_in_compression_only_and_its_work_to_the_energy() {
        let m = Material::lead(MgForm::Hugoniot);
        let eos = mg(&m);
        let off = m.consts();
        let on = off.with_viscosity(BulkViscosity::default(), 2e-3);
        // Compression at tr D = -3e-3 / 1e-8 s = -3e5 /s.
        let (mut a, mut b) = (Point::at_rest(&m), Point::at_rest(&m));
        let speed_off = a.step(&off, &eos, uniform(-1e-3));
        let speed_on = b.step(&on, &eos, uniform(-1e-3));
        let (q, big_q) = on.viscosity.q(b.rho, m.reference_sound_speed(), -3e-3 / DT);
        assert!(q > 0.0);
        // From rest no work was done yet: the same EOS pressure, plus q.
        assert_eq!((a.e, b.e), (0.0, 0.0));
        assert!((b.pressure() - a.pressure() - q).abs() < 1e-12 * b.pressure());
        assert_eq!(speed_off, a.sound);
        assert!((speed_on - viscosity::signal_speed(big_q, b.sound)).abs() < 1e-9 * speed_on);
        assert!(speed_on > b.sound);
        // The next step's work includes q's: e_on - e_off = q tr(de) / rho (compression).
        let rho = b.rho;
        a.step(&off, &eos, uniform(-1e-3));
        b.step(&on, &eos, uniform(-1e-3));
        assert!(((b.e - a.e) / (q * 3e-3 / rho) - 1.0).abs() < 1e-9, "{} vs {}", b.e - a.e, q * 3e-3 / rho);
        // Expansion: identical with and without viscosity.
        let (mut a, mut b) = (Point::at_rest(&m), Point::at_rest(&m));
        let (sa, sb) = (a.step(&off, &eos, uniform(1e-3)), b.step(&on, &eos, uniform(1e-3)));
        assert_eq!((a.s, a.e, sa), (b.s, b.e, sb));
    }

    /// A block of random states: strains over three and a half decades, stresses up to
    /// 2 GPa of either sign, some plastic strain, energies slightly negative to large,
    /// densities 0.7-2.3 times the reference, a fifth of the lanes failed.
    fn random_block(m: &Material, mut u: &mut impl FnMut() -> f64) -> Lanes {
        let signed = |scale: f64, u: &mut dyn FnMut() -> f64| (2.0 * u() - 1.0) * scale * 10f64.powf(-3.0 * u());
        let mut b = Lanes::default();
        for l in 0..LANES {
            let strain = 10f64.powf(-5.0 + 3.5 * u());
            for i in 0..6 {
                b.de[i][l] = signed(strain, &mut u);
                b.de_mid[i][l] = signed(strain, &mut u);
                b.stress[i][l] = signed(2.0e9, &mut u);
            }
            for i in 0..3 {
                b.dw[i][l] = signed(strain, &mut u);
            }
            b.eps_p[l] = if u() < 0.3 { 0.0 } else { 3.2 * u() };
            b.e_int[l] = -3.0e3 + 1.0e5 * u() * u();
            b.rho[l] = m.density * (0.7 + 1.6 * u());
            b.sound[l] = m.reference_sound_speed() * (0.5 + u());
            b.failed[l] = u() < 0.2;
        }
        b
    }

    /// Blocks of random states through `update_lanes` and, lane by lane, through
    /// `update_point`: every output bitwise equal.
    fn check_lanes<E: PressureModel, const LINEAR: bool>(m: &Material, c: &PointConsts, eos: &E, seed: u64) {
        let mut u = unit_stream(seed);
        let mut yielded = 0;
        let mut failures = 0;
        for _ in 0..3000 {
            let mut b = random_block(m, &mut u);
            let before = b;
            update_lanes::<E, LINEAR>(c, eos, DT, &mut b);
            for l in 0..LANES {
                let mut s: Sym = std::array::from_fn(|i| before.stress[i][l]);
                let (mut eps_p, mut e, mut rho, mut sound, mut failed) =
                    (before.eps_p[l], before.e_int[l], before.rho[l], before.sound[l], before.failed[l]);
                let de: Sym = std::array::from_fn(|i| before.de[i][l]);
                let de_mid: Sym = std::array::from_fn(|i| before.de_mid[i][l]);
                let dw: Vec3 = std::array::from_fn(|i| before.dw[i][l]);
                let (signal, floor) = update_point(
                    c,
                    eos,
                    &de,
                    &de_mid,
                    dw,
                    DT,
                    PointState {
                        stress: &mut s,
                        eps_p: &mut eps_p,
                        e_int: &mut e,
                        rho: &mut rho,
                        sound: &mut sound,
                        failed: &mut failed,
                    },
                );
                yielded += usize::from(eps_p > before.eps_p[l]);
                failures += usize::from(failed && !before.failed[l]);
                let got = [b.eps_p[l], b.e_int[l], b.rho[l], b.sound[l], b.signal[l], b.floor[l]];
                let want = [eps_p, e, rho, sound, signal, floor];
                for (i, (g, w)) in got.iter().zip(&want).enumerate() {
                    assert_eq!(g.to_bits(), w.to_bits(), "{}: value {i} of lane {l}: {g} vs {w}", m.name);
                }
                for i in 0..6 {
                    assert_eq!(b.stress[i][l].to_bits(), s[i].to_bits(), "{}: stress {i} of lane {l}", m.name);
                }
                assert_eq!(b.failed[l], failed, "{}: failure flag of lane {l}", m.name);
            }
        }
        // The states cover the branches: plastic flow, and (with failure) new failures.
        assert!(yielded > 100, "{}: {yielded} lanes yielded", m.name);
        assert!(m.failure.is_none() || failures > 100, "{}: {failures} lanes failed", m.name);
    }

    /// The 8-lane block (the AVX-512 level's) against two 4-lane blocks of the same states
    /// (checked against `update_point` by `check_lanes`): every output bitwise equal.
    fn check_block8<E: PressureModel, const LINEAR: bool>(m: &Material, c: &PointConsts, eos: &E, seed: u64) {
        use crate::simd::F8;
        if !crate::simd::avx512_for_test(&format!("the 8-lane block of {}", m.name)) {
            return;
        }
        let mut u = unit_stream(seed);
        for _ in 0..1000 {
            let halves = [random_block(m, &mut u), random_block(m, &mut u)];
            let f8 = |f: &dyn Fn(&Lanes, usize) -> f64| {
                <F8 as crate::simd::Block<8>>::from_array(std::array::from_fn(|l| f(&halves[l / LANES], l % LANES)))
            };
            let state = LaneState {
                stress: std::array::from_fn(|i| f8(&|b, l| b.stress[i][l])),
                eps_p: f8(&|b, l| b.eps_p[l]),
                e_int: f8(&|b, l| b.e_int[l]),
                rho: f8(&|b, l| b.rho[l]),
                sound: f8(&|b, l| b.sound[l]),
                failed: <F8 as crate::simd::Block<8>>::mask_from(|l| halves[l / LANES].failed[l % LANES]),
            };
            let de = std::array::from_fn(|i| f8(&|b, l| b.de[i][l]));
            let de_mid = std::array::from_fn(|i| f8(&|b, l| b.de_mid[i][l]));
            let dw = std::array::from_fn(|i| f8(&|b, l| b.dw[i][l]));
            let (out, signal, floor) = update_block::<F8, E, LINEAR>(c, eos, DT, de, de_mid, dw, state);
            for (h, half) in halves.iter().enumerate() {
                let mut b = *half;
                update_lanes::<E, LINEAR>(c, eos, DT, &mut b);
                for l in 0..LANES {
                    let w = h * LANES + l;
                    let got = [out.eps_p, out.e_int, out.rho, out.sound, signal, floor].map(|v| v.lane(w));
                    let want = [b.eps_p[l], b.e_int[l], b.rho[l], b.sound[l], b.signal[l], b.floor[l]];
                    for (i, (g, x)) in got.iter().zip(&want).enumerate() {
                        assert_eq!(g.to_bits(), x.to_bits(), "{}: value {i} of lane {w}: {g} vs {x}", m.name);
                    }
                    for i in 0..6 {
                        assert_eq!(out.stress[i].lane(w).to_bits(), b.stress[i][l].to_bits(), "{}: stress {i}", m.name);
                    }
                    assert_eq!(F8::mask_bools(out.failed)[w], b.failed[l], "{}: failure flag of lane {w}", m.name);
                }
            }
        }
    }

    #[test]
    fn lanes_are_bitwise_update_point() {
        let q = BulkViscosity::default();
        for form in MgForm::ALL {
            for m in [Material::ofhc_copper(form), Material::lead(form)] {
                let eos = mg(&m);
                check_lanes::<_, true>(&m, &m.consts(), &eos, 1);
                check_lanes::<_, true>(&m, &m.consts().with_viscosity(q, 1e-3), &eos, 2);
                check_block8::<_, true>(&m, &m.consts().with_viscosity(q, 1e-3), &eos, 5);
            }
        }
        // Power-law hardening: the lanes take the Newton return one by one.
        let m =
            Material { hardening: Hardening { a: 90e6, b: 292e6, n: 0.31 }, ..Material::ofhc_copper(MgForm::Hugoniot) };
        check_lanes::<_, false>(&m, &m.consts().with_viscosity(q, 1e-3), &mg(&m), 3);
        check_block8::<_, false>(&m, &m.consts().with_viscosity(q, 1e-3), &mg(&m), 6);
        let e = Material::elastic("e", 8930.0, 117e9, 0.35);
        let Eos::Linear(lin) = e.eos else { unreachable!() };
        // An elastic material never yields: check only the bits.
        let mut soft = e.clone();
        soft.hardening = Hardening { a: 50e6, b: 0.0, n: 1.0 };
        check_lanes::<_, true>(&soft, &soft.consts().with_viscosity(q, 1e-3), &lin, 4);
    }

    #[test]
    fn paper_materials_are_valid_and_bad_constants_are_named() {
        for m in [
            Material::ofhc_copper(MgForm::Hugoniot),
            Material::lead(MgForm::PaperPrinted),
            Material::elastic("e", 1000.0, 1e6, 0.3),
        ] {
            m.validate().unwrap();
        }
        let lead = Material::lead(MgForm::Hugoniot);
        let with_eos = |f: &dyn Fn(&mut MieGruneisen)| {
            let mut eos = mg(&lead);
            f(&mut eos);
            Material { eos: Eos::MieGruneisen(eos), ..lead.clone() }
        };
        let cases = [
            (Material { youngs: 0.0, ..lead.clone() }, "Young's modulus"),
            (Material { poisson: 0.5, ..lead.clone() }, "Poisson's ratio"),
            (Material { poisson: -0.1, ..lead.clone() }, "Poisson's ratio"),
            (Material { density: -1.0, ..lead.clone() }, "density"),
            (with_eos(&|e| e.s = 0.9), "slope s"),
            (with_eos(&|e| e.c0 = 0.0), "c0"),
            (with_eos(&|e| e.rho0 = 8930.0), "reference density"),
            (with_eos(&|e| e.gamma0 = f64::NAN), "gamma0"),
            (Material { failure: Some(Failure { eps_f: 3.0, p_min: 1e6 }), ..lead.clone() }, "p_min"),
            (Material { hardening: Hardening { a: 0.0, b: 1.0, n: 1.0 }, ..lead.clone() }, "yield stress A"),
        ];
        for (m, what) in cases {
            let e = m.validate().unwrap_err();
            assert!(matches!(e, SimError::Material { .. }), "{e:?}");
            let msg = e.to_string();
            assert!(msg.contains(what) && msg.contains("lead"), "{what}: {msg}");
        }
    }
}
