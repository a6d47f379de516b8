//! Equations of state: the Mie-Grüneisen EOS of paper Eq. 18 (in the paper's printed form,
//! the default, or the LS-DYNA form) and a linear EOS for validation problems.
//!
//! With `mu = rho/rho0 - 1` and `E` the internal energy per initial volume:
//!
//! * paper form, `mu > 0`:
//!   `p = rho0 c0^2 mu (1 + mu) / [1 - (s - 1) mu]^2 * (1 - gamma0 mu / 2) + gamma0 E`
//! * LS-DYNA form, `mu > 0`:
//!   `p = rho0 c0^2 mu [1 + (1 - gamma0/2) mu] / [1 - (s - 1) mu]^2 + gamma0 E`
//! * both, `mu <= 0`: `p = rho0 c0^2 mu + gamma0 E`
//!
//! The two forms agree to second order in `mu` and differ by `rho0 c0^2 gamma0 mu^3 / 2`
//! over the denominator; both are continuous (with their first derivative) at `mu = 0`.

use serde::Serialize;

/// Which printed form of the Mie-Grüneisen EOS to use.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum MgForm {
    /// Eq. 18 exactly as the paper prints it (the default).
    #[default]
    Paper,
    /// The common LS-DYNA form (numerator `rho0 c0^2 mu [1 + (1 - gamma0/2) mu]`).
    LsDyna,
}

impl MgForm {
    /// Stable name (`paper` / `lsdyna`).
    pub fn name(self) -> &'static str {
        match self {
            MgForm::Paper => "paper",
            MgForm::LsDyna => "lsdyna",
        }
    }
}

impl std::str::FromStr for MgForm {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "paper" => Ok(MgForm::Paper),
            "lsdyna" | "ls-dyna" => Ok(MgForm::LsDyna),
            _ => Err(format!("unknown EOS form '{s}': use 'paper' or 'lsdyna'")),
        }
    }
}

/// A pressure model usable in the stress update.
pub trait PressureModel {
    /// New pressure and `dp/dmu` at compression `mu`, where the new specific internal
    /// energy is `e_known - p_new * dv / 2` (trapezoidal energy update; `dv` is the change of
    /// specific volume `1/rho_new - 1/rho_old`).
    fn pressure(&self, mu: f64, e_known: f64, dv: f64) -> (f64, f64);
}

/// Mie-Grüneisen parameters (paper Tables 1 and 3).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct MieGruneisen {
    /// Reference density (kg/m^3).
    pub rho0: f64,
    /// Bulk sound speed `c0` (m/s).
    pub c0: f64,
    /// Slope `s` of the shock-velocity / particle-velocity line.
    pub s: f64,
    /// Grüneisen coefficient `gamma0`.
    pub gamma0: f64,
    /// Printed form.
    pub form: MgForm,
}

impl MieGruneisen {
    /// The energy-independent part `p_c(mu)` and its derivative `dp_c/dmu`.
    #[inline(always)]
    pub fn cold(&self, mu: f64) -> (f64, f64) {
        let k0 = self.rho0 * self.c0 * self.c0;
        if mu <= 0.0 {
            return (k0 * mu, k0);
        }
        let d = 1.0 - (self.s - 1.0) * mu;
        let inv_d2 = 1.0 / (d * d);
        let (f, df) = match self.form {
            MgForm::Paper => {
                let a = mu + mu * mu;
                let b = 1.0 - 0.5 * self.gamma0 * mu;
                (a * b, (1.0 + 2.0 * mu) * b - a * 0.5 * self.gamma0)
            }
            MgForm::LsDyna => {
                let c = 1.0 - 0.5 * self.gamma0;
                (mu + c * mu * mu, 1.0 + 2.0 * c * mu)
            }
        };
        // d/dmu [f / d^2] = f'/d^2 + 2 (s - 1) f / d^3
        (k0 * f * inv_d2, k0 * (df * inv_d2 + 2.0 * (self.s - 1.0) * f * inv_d2 / d))
    }

    /// Pressure at compression `mu` and internal energy per initial volume `e_vol` (Eq. 18).
    pub fn pressure_at(&self, mu: f64, e_vol: f64) -> f64 {
        self.cold(mu).0 + self.gamma0 * e_vol
    }
}

impl PressureModel for MieGruneisen {
    #[inline(always)]
    fn pressure(&self, mu: f64, e_known: f64, dv: f64) -> (f64, f64) {
        let (pc, dpc) = self.cold(mu);
        // p = pc + gamma0 rho0 (e_known - p dv / 2)  =>  p (1 + gamma0 rho0 dv / 2) = ...
        let g = self.gamma0 * self.rho0;
        ((pc + g * e_known) / (1.0 + 0.5 * g * dv), dpc)
    }
}

/// A linear EOS `p = K mu` (validation problems; energy-independent).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LinearEos {
    /// Bulk modulus (Pa).
    pub bulk: f64,
}

impl PressureModel for LinearEos {
    #[inline(always)]
    fn pressure(&self, mu: f64, _e_known: f64, _dv: f64) -> (f64, f64) {
        (self.bulk * mu, self.bulk)
    }
}

/// The pressure model of a material.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
#[serde(tag = "kind", rename_all = "snake_case")]
pub enum Eos {
    /// Mie-Grüneisen (Eq. 18).
    MieGruneisen(MieGruneisen),
    /// Linear, for validation.
    Linear(LinearEos),
}

impl Eos {
    /// Bulk modulus at the reference state (`rho0 c0^2` or `K`).
    pub fn reference_bulk_modulus(&self) -> f64 {
        match self {
            Eos::MieGruneisen(m) => m.rho0 * m.c0 * m.c0,
            Eos::Linear(l) => l.bulk,
        }
    }

    /// A short description naming the form (recorded with every run).
    pub fn describe(&self) -> String {
        match self {
            Eos::MieGruneisen(m) => format!("mie-gruneisen ({} form)", m.form.name()),
            Eos::Linear(_) => "linear".into(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn lead(form: MgForm) -> MieGruneisen {
        MieGruneisen { rho0: 11350.0, c0: 2092.0, s: 1.45, gamma0: 2.0, form }
    }

    #[test]
    fn continuous_with_its_slope_at_mu_zero() {
        for form in [MgForm::Paper, MgForm::LsDyna] {
            let m = lead(form);
            let e = 3.0e8;
            let h = 1e-9;
            let below = m.pressure_at(-h, e);
            let at = m.pressure_at(0.0, e);
            let above = m.pressure_at(h, e);
            assert!((at - m.gamma0 * e).abs() < 1e-6);
            let k0 = m.rho0 * m.c0 * m.c0;
            // Jumps across 0 are of order k0 * h, never a step.
            assert!((above - at).abs() < 2.0 * k0 * h, "{form:?}");
            assert!((at - below).abs() < 2.0 * k0 * h, "{form:?}");
            let (_, d_minus) = m.cold(-1e-12);
            let (_, d_plus) = m.cold(1e-12);
            assert!((d_plus / d_minus - 1.0).abs() < 1e-9, "{form:?}");
        }
    }

    #[test]
    fn paper_and_lsdyna_forms_differ_only_at_third_order() {
        let (p, l) = (lead(MgForm::Paper), lead(MgForm::LsDyna));
        let k0 = p.rho0 * p.c0 * p.c0;
        for mu in [0.01, 0.1, 0.3] {
            let d = 1.0 - (p.s - 1.0) * mu;
            let diff = l.cold(mu).0 - p.cold(mu).0;
            let expected = k0 * p.gamma0 * mu.powi(3) / 2.0 / (d * d);
            assert!((diff - expected).abs() < 1e-9 * k0, "mu={mu}");
        }
    }

    #[test]
    fn derivative_matches_finite_difference() {
        for form in [MgForm::Paper, MgForm::LsDyna] {
            let m = lead(form);
            for mu in [-0.05, 0.02, 0.2, 0.4] {
                let h = 1e-7;
                let fd = (m.cold(mu + h).0 - m.cold(mu - h).0) / (2.0 * h);
                let (_, d) = m.cold(mu);
                assert!((fd - d).abs() / d.abs() < 1e-6, "{form:?} mu={mu}");
            }
        }
    }

    #[test]
    fn implicit_energy_update_is_consistent() {
        let m = lead(MgForm::Paper);
        let (mu, e_known, dv) = (0.1, 1.0e4, -2e-6);
        let (p, _) = m.pressure(mu, e_known, dv);
        let e_new = e_known - 0.5 * p * dv;
        assert!((p - m.pressure_at(mu, m.rho0 * e_new)).abs() < 1e-6 * p.abs());
    }
}
