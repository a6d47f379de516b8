//! Material models (paper Section 2): J2 plasticity with hardening `A + B eps_p^n`
//! ([`j2`]), a pressure from an equation of state ([`eos`]) and failure ([`failure`]).
//!
//! The stress update of one particle ([`update_point`]) follows the paper's Eq. 15: the old
//! stress is rotated by the Jaumann increment, the deviator takes an elastic trial step and
//! a radial return, the pressure comes from the EOS at the new density, and the internal
//! energy is advanced with the trapezoidal rule (the EOS energy term makes the new pressure
//! depend on the new energy; both are solved together in closed form because the
//! Mie-Grüneisen pressure is linear in energy). The update is generic over the EOS, so the
//! choice of EOS is dispatched once per particle chunk, never per particle.

pub mod eos;
pub mod failure;
pub mod j2;

pub use eos::{Eos, LinearEos, MgForm, MieGruneisen, PressureModel};
pub use failure::Failure;
pub use j2::Hardening;

use crate::math::{ddot, deviator, Sym, Vec3};
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
        PointConsts {
            g,
            rho0: self.density,
            hardening: self.hardening,
            failure: self.failure,
            four_thirds_g: 4.0 / 3.0 * g,
            c_failed: self.reference_sound_speed(),
        }
    }
}

/// Per-material constants used in the hot loop.
#[derive(Clone, Copy, Debug)]
pub struct PointConsts {
    /// Shear modulus (Pa).
    pub g: f64,
    /// Reference density (kg/m^3).
    pub rho0: f64,
    /// Yield stress law.
    pub hardening: Hardening,
    /// Failure thresholds.
    pub failure: Option<Failure>,
    /// `4 G / 3` (Pa).
    pub four_thirds_g: f64,
    /// Sound speed kept by a failed particle (it still limits the time step).
    pub c_failed: f64,
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
/// of Eqs. 12-13 (paper Eqs. 14, 15, 17, 18).
#[inline(always)]
pub fn update_point<E: PressureModel>(c: &PointConsts, eos: &E, de: &Sym, dw: Vec3, st: PointState<'_>) {
    let rho_old = *st.rho;
    let rho_new = rho_old / (1.0 + de[0] + de[1] + de[2]); // Eq. 14
    *st.rho = rho_new;
    if *st.failed {
        *st.sound = c.c_failed;
        return;
    }
    let sigma = *st.stress;
    let p_old = -(sigma[0] + sigma[1] + sigma[2]) / 3.0;
    // Jaumann rotation of the old stress (Eq. 15); its deviator is the rotated s_old.
    let rot = crate::math::jaumann(&sigma, dw);
    let s_rot = deviator(&[
        sigma[0] + rot[0],
        sigma[1] + rot[1],
        sigma[2] + rot[2],
        sigma[3] + rot[3],
        sigma[4] + rot[4],
        sigma[5] + rot[5],
    ]);
    let de_dev = deviator(de);
    let two_g = 2.0 * c.g;
    let trial: Sym = std::array::from_fn(|i| s_rot[i] + two_g * de_dev[i]);
    let (s_new, eps_p_new) = j2::radial_return(trial, *st.eps_p, c.g, &c.hardening);
    *st.eps_p = eps_p_new;

    // Internal energy (per unit mass), trapezoidal in stress:
    // e_new = e_old + s_mid:de / rho_mid - (p_old + p_new)/2 * (1/rho_new - 1/rho_old)
    let s_mid: Sym = std::array::from_fn(|i| 0.5 * (s_rot[i] + s_new[i]));
    let rho_mid = 0.5 * (rho_old + rho_new);
    let dv = 1.0 / rho_new - 1.0 / rho_old;
    let e_known = *st.e_int + ddot(&s_mid, &de_dev) / rho_mid - 0.5 * p_old * dv;
    let mu = rho_new / c.rho0 - 1.0;
    let (p_new, dp_dmu) = eos.pressure(mu, e_known, dv);
    let e_new = e_known - 0.5 * p_new * dv;
    *st.e_int = e_new;

    // Sound speed for the next step: c^2 = dp/drho + (4G/3)/rho.
    let c2 = (dp_dmu / c.rho0).max(0.0) + c.four_thirds_g / rho_new;
    *st.sound = c2.sqrt();

    if let Some(f) = c.failure {
        if f.fails(eps_p_new, p_new) {
            *st.failed = true;
            *st.stress = [0.0; 6];
            return;
        }
    }
    *st.stress = [s_new[0] - p_new, s_new[1] - p_new, s_new[2] - p_new, s_new[3], s_new[4], s_new[5]];
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::{trace, von_mises};

    fn state() -> (Sym, f64, f64, f64, f64, bool) {
        ([0.0; 6], 0.0, 0.0, 8930.0, 0.0, false)
    }

    #[test]
    fn copper_derived_constants_match_the_paper() {
        let m = Material::ofhc_copper(MgForm::Paper);
        assert!((m.bulk_modulus() / 1e9 - 130.0).abs() < 0.05);
        assert!((m.shear_modulus() / 1e9 - 43.33).abs() < 0.01);
        assert!((m.p_wave_speed() - 4586.0).abs() < 1.0);
        assert!(((m.youngs / m.density).sqrt() - 3620.0).abs() < 1.0);
    }

    #[test]
    fn elastic_uniaxial_strain_gives_lame_stresses() {
        let m = Material::elastic("e", 8930.0, 117e9, 0.35);
        let c = m.consts();
        let Eos::Linear(eos) = m.eos else { unreachable!() };
        let (mut s, mut ep, mut e, mut rho, mut snd, mut f) = state();
        let eps = -1e-5;
        update_point(
            &c,
            &eos,
            &[0.0, 0.0, eps, 0.0, 0.0, 0.0],
            [0.0; 3],
            PointState {
                stress: &mut s,
                eps_p: &mut ep,
                e_int: &mut e,
                rho: &mut rho,
                sound: &mut snd,
                failed: &mut f,
            },
        );
        let k = m.bulk_modulus();
        let g = m.shear_modulus();
        // sigma_zz = (K + 4G/3) eps (to first order), sigma_xx = (K - 2G/3) eps
        assert!((s[2] / ((k + 4.0 / 3.0 * g) * eps) - 1.0).abs() < 1e-4, "{s:?}");
        assert!((s[0] / ((k - 2.0 / 3.0 * g) * eps) - 1.0).abs() < 1e-4, "{s:?}");
        // Stored energy 1/2 sigma eps per volume.
        let w = 0.5 * (k + 4.0 / 3.0 * g) * eps * eps / 8930.0;
        assert!((e / w - 1.0).abs() < 1e-3, "{e} vs {w}");
        assert!((snd - m.p_wave_speed()).abs() / m.p_wave_speed() < 1e-4);
    }

    #[test]
    fn plastic_shear_lands_on_the_hardened_surface() {
        let m = Material::ofhc_copper(MgForm::Paper);
        let c = m.consts();
        let Eos::MieGruneisen(eos) = m.eos else { unreachable!() };
        let (mut s, mut ep, mut e, mut rho, mut snd, mut f) = state();
        for _ in 0..20 {
            update_point(
                &c,
                &eos,
                &[0.0, 0.0, 0.0, 0.0, 0.0, 1e-3],
                [0.0; 3],
                PointState {
                    stress: &mut s,
                    eps_p: &mut ep,
                    e_int: &mut e,
                    rho: &mut rho,
                    sound: &mut snd,
                    failed: &mut f,
                },
            );
        }
        assert!(ep > 0.0);
        let j = von_mises(&deviator(&s));
        let y = m.hardening.yield_stress(ep);
        assert!((j - y).abs() / y < 1e-12, "J={j} yield={y}");
        // Pure shear keeps the density, so the pressure is the Grüneisen term of the plastic
        // heating alone: p = gamma0 rho0 e.
        assert_eq!(rho, 8930.0);
        let p = -trace(&s) / 3.0;
        assert!((p - 1.96 * 8930.0 * e).abs() < 1e-9 * p, "p = {p}, gamma0 rho0 e = {}", 1.96 * 8930.0 * e);
        assert!(e > 0.0, "plastic work heats the material");
    }

    #[test]
    fn lead_fails_in_tension_below_p_min_and_then_carries_no_stress() {
        let m = Material::lead(MgForm::Paper);
        let c = m.consts();
        let Eos::MieGruneisen(eos) = m.eos else { unreachable!() };
        let (mut s, mut ep, mut e, _, mut snd, mut f) = state();
        let mut rho = 11350.0;
        // 3 % volumetric expansion: p = rho0 c0^2 mu ~ -1.5 GPa at mu ~ -0.03.
        for _ in 0..10 {
            update_point(
                &c,
                &eos,
                &[0.004, 0.004, 0.004, 0.0, 0.0, 0.0],
                [0.0; 3],
                PointState {
                    stress: &mut s,
                    eps_p: &mut ep,
                    e_int: &mut e,
                    rho: &mut rho,
                    sound: &mut snd,
                    failed: &mut f,
                },
            );
        }
        assert!(f, "particle should have failed in tension");
        assert_eq!(s, [0.0; 6]);
    }
}
