//! The scenario's own figures: one variant per scenario, tagged by the summary's key
//! `scenario` (`taylor`, `impact`, `plate`), its fields top-level keys of the summary. A new
//! scenario is a variant here with its figures, beside its [`crate::Scenario`] variant and
//! its core module.

use crate::scenario::ScenarioKind;
use mpm_core::scenario::impact::HistorySample;
use serde::{Deserialize, Serialize};

/// The figures of the run's scenario.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "scenario", rename_all = "lowercase")]
pub enum ScenarioFigures {
    /// The Taylor bar: lengths and the impact face.
    Taylor(TaylorFigures),
    /// The hypervelocity impact: the debris cloud.
    Impact(ImpactFigures),
    /// The plate impact: the shock against Rankine-Hugoniot.
    Plate(PlateFigures),
}

impl Default for ScenarioFigures {
    fn default() -> Self {
        ScenarioFigures::Taylor(TaylorFigures::default())
    }
}

impl ScenarioFigures {
    /// The scenario.
    pub fn kind(&self) -> ScenarioKind {
        match self {
            ScenarioFigures::Taylor(_) => ScenarioKind::Taylor,
            ScenarioFigures::Impact(_) => ScenarioKind::Impact,
            ScenarioFigures::Plate(_) => ScenarioKind::Plate,
        }
    }

    /// Empty figures of a scenario of `kind` (nothing measured yet).
    pub fn empty(kind: ScenarioKind) -> Self {
        match kind {
            ScenarioKind::Taylor => ScenarioFigures::Taylor(TaylorFigures::default()),
            ScenarioKind::Impact => ScenarioFigures::Impact(ImpactFigures::default()),
            ScenarioKind::Plate => ScenarioFigures::Plate(PlateFigures::default()),
        }
    }

    /// The Taylor bar's figures, if the run was one.
    pub fn taylor(&self) -> Option<&TaylorFigures> {
        match self {
            ScenarioFigures::Taylor(t) => Some(t),
            _ => None,
        }
    }

    /// The impact's figures, if the run was one.
    pub fn impact(&self) -> Option<&ImpactFigures> {
        match self {
            ScenarioFigures::Impact(i) => Some(i),
            _ => None,
        }
    }

    /// The plate's figures, if the run was one.
    pub fn plate(&self) -> Option<&PlateFigures> {
        match self {
            ScenarioFigures::Plate(p) => Some(p),
            _ => None,
        }
    }
}

/// Taylor bar lengths, measured by [`mpm_core::scenario::taylor::measure`] (the summary's
/// `length_convention` says how).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct TaylorFigures {
    /// Length at `t = 0` (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_length_m: Option<f64>,
    /// Length at the end (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub final_length_m: Option<f64>,
    /// Impact-face diameter at `t = 0` (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub initial_face_diameter_m: Option<f64>,
    /// Impact-face diameter at the end (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub face_diameter_m: Option<f64>,
}

/// The debris cloud, measured by [`mpm_core::scenario::impact::measure`] from particle
/// centres; the robust variants ignore the outermost 0.1 % of the debris mass.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct ImpactFigures {
    /// Distance of the debris cloud's leading edge from the plate's rear face (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cloud_front_m: Option<f64>,
    /// Leading edge ignoring the foremost 0.1 % of the debris mass (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cloud_front_robust_m: Option<f64>,
    /// Largest debris diameter normal to the flight direction (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cloud_width_m: Option<f64>,
    /// Diameter containing 99.9 % of the debris mass (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cloud_width_robust_m: Option<f64>,
    /// Diameter of the hole in the plate (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub hole_diameter_m: Option<f64>,
    /// The speed at which the robust front moved, the least-squares slope of
    /// `cloud_history`'s robust front over the last quarter of the run (m/s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub front_velocity_m_s: Option<f64>,
    /// Debris mass beyond the rear face (kg).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub debris_mass_kg: Option<f64>,
    /// Particle lattice spacing (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub spacing_m: Option<f64>,
    /// Mass-weighted z-velocity of the debris beyond the robust front at the end (m/s): how
    /// fast the leading 0.1 % of the debris moves now.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub leading_debris_velocity_m_s: Option<f64>,
    /// The cloud's figures and the energies about every microsecond and at the end: a
    /// record of the run's course, not a CSV column.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub cloud_history: Option<Vec<HistorySample>>,
}

/// The plate's shock ([`mpm_core::scenario::plate::ShockTracker`]) against its
/// Rankine-Hugoniot values (the summary's `plate_configuration` says what was run).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default)]
pub struct PlateFigures {
    /// Slab length (m).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub slab_length_m: Option<f64>,
    /// Measured shock speed relative to the undisturbed slab (m/s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shock_speed_m_s: Option<f64>,
    /// Shocked normal stress `-sigma_zz`, volume average behind the front (Pa).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shock_pressure_pa: Option<f64>,
    /// Shocked mean pressure `-tr(sigma)/3`, volume average (Pa).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shock_mean_pressure_pa: Option<f64>,
    /// Particle velocity jump across the shock (m/s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particle_velocity_m_s: Option<f64>,
    /// Rankine-Hugoniot shock speed `c0 + s u_p` (m/s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rh_shock_speed_m_s: Option<f64>,
    /// Rankine-Hugoniot pressure `rho0 U_s u_p` (Pa).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rh_pressure_pa: Option<f64>,
    /// Rankine-Hugoniot particle velocity (the impact speed, m/s).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub rh_particle_velocity_m_s: Option<f64>,
    /// `shock_speed_m_s / rh_shock_speed_m_s - 1`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shock_speed_rel_error: Option<f64>,
    /// `shock_pressure_pa / rh_pressure_pa - 1`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shock_pressure_rel_error: Option<f64>,
    /// `particle_velocity_m_s / rh_particle_velocity_m_s - 1`.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub particle_velocity_rel_error: Option<f64>,
    /// Front samples in the shock tracker's path.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub shock_front_samples: Option<usize>,
}
