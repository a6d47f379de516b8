//! The scenario of a run (Taylor bar, hypervelocity impact, plate impact) with its
//! parameters, their defaults and checks, and how each is built into a solver set-up.

use crate::SpecError;
use mpm_core::material::Eos;
use mpm_core::scenario::impact::{self, ImpactGeometry};
use mpm_core::scenario::plate::{self, PlateGeometry, PlateImpact};
use mpm_core::scenario::size::ModelSize;
use mpm_core::scenario::taylor::{self, TaylorBar};
use mpm_core::scenario::Pick;
use mpm_core::{GridMode, MgForm, SimError, WallKind, DEFAULT_CFL};
use serde::{Deserialize, Serialize};

/// The plate scenario's default CFL number: its shock speed is the measurement (a 3 km/s
/// shock runs 3.15 % fast at CFL 0.5 and 2.66 % at 0.2).
pub const PLATE_CFL: f64 = 0.2;

/// The fastest impact a scenario takes (m/s): its materials' models (Mie-Grüneisen,
/// Johnson-Cook, the spall failure) are fitted to shocks of a few km/s, the paper's
/// hypervelocity impact is 6.58 km/s; 100 km/s is already far outside what they describe.
pub const MAX_SPEED: f64 = 100e3;

/// The most particles a model may have: the domain-decomposition strategies number a
/// patch's particles with 32-bit indices (and the memory of so many is beyond any node
/// this program runs on: 173 bytes each).
pub const MAX_PARTICLES: u64 = u32::MAX as u64 - 1;

/// The finest particle spacing of the impact (m), mpm-core's own limit: finer is billions
/// of particles.
pub const MIN_IMPACT_SPACING: f64 = 0.05e-3;

/// Particles per cell along each axis of the impact, least and most (the plate's
/// `--particles-per-cell` range; the paper compares 2, 3 and 4 at 0.53 mm).
pub const IMPACT_PARTICLES_PER_CELL: (f64, f64) = (1.0, 8.0);

/// Which problem a run solves.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ScenarioKind {
    /// The Taylor bar (paper Section 3).
    #[default]
    Taylor,
    /// The hypervelocity impact (paper Section 6).
    Impact,
    /// The one-dimensional plate impact (shock validation).
    Plate,
}

impl ScenarioKind {
    /// Every kind.
    pub const ALL: [ScenarioKind; 3] = [ScenarioKind::Taylor, ScenarioKind::Impact, ScenarioKind::Plate];

    /// Its name in JSON, CSV and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            ScenarioKind::Taylor => "taylor",
            ScenarioKind::Impact => "impact",
            ScenarioKind::Plate => "plate",
        }
    }
}

impl std::fmt::Display for ScenarioKind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for ScenarioKind {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, String> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == s)
            .ok_or_else(|| format!("unknown scenario '{s}' (known: taylor, impact, plate)"))
    }
}

/// Contact condition at a rigid wall.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Contact {
    /// Only the normal velocity is stopped.
    #[default]
    Frictionless,
    /// Every velocity component is stopped.
    Sticking,
}

impl Contact {
    /// Its name (`frictionless`, `sticking`).
    pub fn name(self) -> &'static str {
        match self {
            Contact::Frictionless => "frictionless",
            Contact::Sticking => "sticking",
        }
    }
}

/// The Taylor bar: an OFHC copper cylinder hitting a rigid wall, as Model 1-4 of Table 2.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TaylorSpec {
    /// Model 1-4.
    pub model: u8,
    /// Impact speed towards the wall (m/s).
    pub velocity_m_s: f64,
    /// Contact at the wall.
    pub wall: Contact,
}

impl TaylorSpec {
    /// Model `model` at the default speed with a frictionless wall.
    pub fn model(model: u8) -> Self {
        Self { model, velocity_m_s: taylor::DEFAULT_VELOCITY, wall: Contact::Frictionless }
    }
}

/// The hypervelocity impact: a lead sphere on a lead plate.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImpactSpec {
    /// Particle lattice spacing (m).
    pub spacing_m: f64,
    /// Grid cell size (m).
    pub cell_m: f64,
    /// Impact speed of the sphere (m/s).
    pub velocity_m_s: f64,
}

impl Default for ImpactSpec {
    /// The paper's small model with 2.12 mm cells at 6.58 km/s.
    fn default() -> Self {
        Self { spacing_m: impact::DEFAULT_SPACING, cell_m: impact::DEFAULT_CELL, velocity_m_s: impact::IMPACT_VELOCITY }
    }
}

/// The plate impact: a lead slab onto a rigid wall in a laterally confined column.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PlateSpec {
    /// Impact speed towards the wall (m/s).
    pub velocity_m_s: f64,
    /// Slab length along z (m).
    pub length_m: f64,
    /// Grid cell size (m).
    pub cell_m: f64,
    /// Particles per cell along each axis (1-8).
    pub particles_per_cell: u8,
}

impl Default for PlateSpec {
    fn default() -> Self {
        Self {
            velocity_m_s: plate::DEFAULT_VELOCITY,
            length_m: plate::DEFAULT_LENGTH,
            cell_m: plate::DEFAULT_CELL,
            particles_per_cell: plate::DEFAULT_PARTICLES_PER_CELL as u8,
        }
    }
}

/// The problem a run solves, with its parameters (`kind` names it in files).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "kind", rename_all = "lowercase")]
pub enum Scenario {
    /// The Taylor bar.
    Taylor(TaylorSpec),
    /// The hypervelocity impact.
    Impact(ImpactSpec),
    /// The plate impact.
    Plate(PlateSpec),
}

/// A scenario built and ready to run: the solver's set-up and what the measurements need.
pub struct Prepared {
    /// Particles, grid, material, walls.
    pub setup: mpm_core::Setup,
    /// The impact's geometry (its figures and history).
    pub impact: Option<ImpactGeometry>,
    /// The plate's geometry (its shock measurements).
    pub plate: Option<PlateGeometry>,
}

impl Scenario {
    /// Which scenario.
    pub fn kind(&self) -> ScenarioKind {
        match self {
            Scenario::Taylor(_) => ScenarioKind::Taylor,
            Scenario::Impact(_) => ScenarioKind::Impact,
            Scenario::Plate(_) => ScenarioKind::Plate,
        }
    }

    /// A few words for people: `Taylor bar Model 1`, `impact, spacing 0.53 mm, cell 2.12 mm`.
    pub fn describe(&self) -> String {
        match self {
            Scenario::Taylor(t) => format!("Taylor bar Model {}", t.model),
            Scenario::Impact(i) => format!("impact, spacing {} mm, cell {} mm", i.spacing_m * 1e3, i.cell_m * 1e3),
            Scenario::Plate(p) => format!(
                "plate impact at {} m/s, slab {} mm, cell {} mm",
                p.velocity_m_s,
                p.length_m * 1e3,
                p.cell_m * 1e3
            ),
        }
    }

    /// The Taylor bar's model number (0 for the other scenarios).
    pub fn model(&self) -> u8 {
        match self {
            Scenario::Taylor(t) => t.model,
            Scenario::Impact(_) | Scenario::Plate(_) => 0,
        }
    }

    /// Impact speed (m/s).
    pub fn velocity(&self) -> f64 {
        match self {
            Scenario::Taylor(t) => t.velocity_m_s,
            Scenario::Impact(i) => i.velocity_m_s,
            Scenario::Plate(p) => p.velocity_m_s,
        }
    }

    /// The end time without a budget: the paper's (Taylor bar 40 µs, impact 30.6 µs), or for
    /// the plate when the shock has crossed [`plate::END_FRACTION`] of the slab.
    pub fn default_end_time(&self) -> Result<f64, SpecError> {
        Ok(match self {
            Scenario::Taylor(_) => taylor::DEFAULT_END_TIME,
            Scenario::Impact(_) => impact::DEFAULT_END_TIME,
            Scenario::Plate(p) => {
                // From the slab's length and the lead's Hugoniot, without building the slab
                // (the checks first: a slab too large for memory is refused by its size).
                self.check()?;
                let imp = plate_of(p, MgForm::default());
                let Eos::MieGruneisen(eos) = imp.material().eos else {
                    return Err(SpecError::Scenario(SimError::Config(
                        "the plate's lead has no Mie-Grüneisen EOS".into(),
                    )));
                };
                let length = (p.length_m / p.cell_m).round() * p.cell_m;
                PlateGeometry { velocity: p.velocity_m_s, length, cell: p.cell_m, eos }.end_time()
            }
        })
    }

    /// The grid by default: the scenario's fixed grid for the Taylor bar and the plate; for
    /// the impact the sparse grid in one process, the adaptive grid over several ranks.
    pub fn default_grid(&self, ranks: usize) -> GridMode {
        match self {
            Scenario::Taylor(_) | Scenario::Plate(_) => GridMode::Fixed,
            Scenario::Impact(_) if ranks > 1 => GridMode::Adaptive,
            Scenario::Impact(_) => GridMode::Sparse,
        }
    }

    /// The CFL number by default: 0.5, or [`PLATE_CFL`] for the plate.
    pub fn default_cfl(&self) -> f64 {
        match self {
            Scenario::Plate(_) => PLATE_CFL,
            Scenario::Taylor(_) | Scenario::Impact(_) => DEFAULT_CFL,
        }
    }

    /// Particle and node counts for the memory estimate (the impact's nodes: the adaptive
    /// grid around the debris cloud at the paper's comparison time, an upper estimate).
    pub fn size(&self) -> ModelSize {
        match self {
            Scenario::Taylor(t) => ModelSize::taylor(t.model).unwrap_or_default(),
            Scenario::Impact(i) => ModelSize::impact(i.spacing_m, i.cell_m),
            Scenario::Plate(p) => {
                let per_cell = u64::from(p.particles_per_cell).pow(3);
                let cells_z = (p.length_m / p.cell_m).round().max(0.0) as u64;
                let columns = (plate::COLUMN_CELLS as u64).pow(2);
                // The grid runs to twice the slab's length (the slab moves onto the wall).
                let nodes = (plate::COLUMN_CELLS as u64 + 1).pow(2) * (2 * cells_z + 1);
                ModelSize { particles: per_cell * columns * cells_z, nodes }
            }
        }
    }

    /// Every check of the parameters, naming the key and the flag: ranges, a model a run
    /// can be built from (its particles counted in closed form, never generated: a spacing
    /// of a nanometre is refused at once) and whose figures mean something.
    pub fn check(&self) -> Result<(), SpecError> {
        match self {
            Scenario::Taylor(t) => {
                if !(1..=4).contains(&t.model) {
                    return Err(invalid(
                        "scenario.model",
                        "--model",
                        format!("the Taylor bar has Models 1-4 (Table 2), got {}", t.model),
                    ));
                }
                speed("scenario.velocity_m_s", t.velocity_m_s, false)
            }
            Scenario::Impact(i) => check_impact(i),
            Scenario::Plate(p) => check_plate(p),
        }
    }

    /// Build the scenario with the Mie-Grüneisen form `eos`, keeping the particles `pick`
    /// asks for (all of them, or one rank's).
    pub fn build(&self, eos: MgForm, pick: Pick<'_>) -> Result<Prepared, SimError> {
        match self {
            Scenario::Taylor(t) => {
                let bar = TaylorBar {
                    model: t.model,
                    velocity: t.velocity_m_s,
                    eos,
                    wall: match t.wall {
                        Contact::Frictionless => WallKind::Slip,
                        Contact::Sticking => WallKind::Stick,
                    },
                };
                Ok(Prepared { setup: bar.setup_picked(pick)?, impact: None, plate: None })
            }
            Scenario::Impact(i) => {
                let imp = impact::Impact { spacing: i.spacing_m, cell: i.cell_m, velocity: i.velocity_m_s, eos };
                let (setup, geometry) = imp.setup_picked(pick)?;
                Ok(Prepared { setup, impact: Some(geometry), plate: None })
            }
            Scenario::Plate(p) => {
                let (setup, geometry) = plate_of(p, eos).setup_picked(pick)?;
                Ok(Prepared { setup, impact: None, plate: Some(geometry) })
            }
        }
    }
}

/// The error of a value out of range.
fn invalid(key: &'static str, flag: &'static str, why: String) -> SpecError {
    SpecError::Invalid { key, flag, why }
}

/// A finite length or speed > 0.
fn positive(key: &'static str, flag: &'static str, v: f64, what: &str) -> Result<(), SpecError> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(invalid(key, flag, format!("{what} must be a finite number > 0, got {v}")))
    }
}

/// An impact speed: finite, at most [`MAX_SPEED`], and > 0 where `strictly` (else >= 0).
fn speed(key: &'static str, v: f64, strictly: bool) -> Result<(), SpecError> {
    let low = if strictly { v > 0.0 } else { v >= 0.0 };
    if !(v.is_finite() && low) {
        let bound = if strictly { "> 0" } else { ">= 0" };
        return Err(invalid(
            key,
            "--velocity",
            format!("the impact speed must be a finite number of m/s {bound} (towards the wall), got {v}"),
        ));
    }
    if v > MAX_SPEED {
        return Err(invalid(
            key,
            "--velocity",
            format!(
                "{v} m/s is beyond what the materials' models describe (fitted to shocks of a few km/s; the paper's \
                 impact is 6580 m/s): give at most {MAX_SPEED} m/s"
            ),
        ));
    }
    Ok(())
}

/// The impact's parameters: a spacing mpm-core builds, 1-8 particles per cell along each
/// axis, a plate at least one cell thick (else its hole and the cloud are not resolved and
/// the hole reads as none).
fn check_impact(i: &ImpactSpec) -> Result<(), SpecError> {
    positive("scenario.spacing_m", "--spacing", i.spacing_m, "the particle spacing (m)")?;
    positive("scenario.cell_m", "--cell", i.cell_m, "the cell size (m)")?;
    speed("scenario.velocity_m_s", i.velocity_m_s, false)?;
    if i.spacing_m < MIN_IMPACT_SPACING {
        return Err(invalid(
            "scenario.spacing_m",
            "--spacing",
            format!(
                "a particle spacing of {} m would need billions of particles: give {MIN_IMPACT_SPACING} m or more \
                 (0.53e-3 is the paper's small model, 0.21e-3 its large one)",
                i.spacing_m
            ),
        ));
    }
    let (least, most) = IMPACT_PARTICLES_PER_CELL;
    let per_cell = i.cell_m / i.spacing_m;
    if !(least..=most).contains(&per_cell) {
        return Err(invalid(
            "scenario.cell_m",
            "--cell",
            format!(
                "a cell of {} m holds {per_cell:.3} particles of spacing {} m along each axis: give a cell of {least} to \
                 {most} spacings ({:e} to {:e} m; the paper uses 4, --cell {:e})",
                i.cell_m,
                i.spacing_m,
                least * i.spacing_m,
                most * i.spacing_m,
                4.0 * i.spacing_m
            ),
        ));
    }
    if i.cell_m > impact::PLATE_THICKNESS {
        return Err(invalid(
            "scenario.cell_m",
            "--cell",
            format!(
                "a cell of {} m is thicker than the {} m plate: the hole and the debris cloud would not be resolved; \
                 give at most {} m (the paper's cells are 1.06e-3 to 2.12e-3 m)",
                i.cell_m,
                impact::PLATE_THICKNESS,
                impact::PLATE_THICKNESS
            ),
        ));
    }
    Ok(())
}

/// The plate's parameters: a slab of at least the cells its measurements need, and not
/// more particles than a run can hold ([`MAX_PARTICLES`]).
fn check_plate(p: &PlateSpec) -> Result<(), SpecError> {
    speed("scenario.velocity_m_s", p.velocity_m_s, true)?;
    positive("scenario.length_m", "--length", p.length_m, "the slab length (m)")?;
    positive("scenario.cell_m", "--cell", p.cell_m, "the cell size (m)")?;
    if !(1..=8).contains(&p.particles_per_cell) {
        return Err(invalid(
            "scenario.particles_per_cell",
            "--particles-per-cell",
            format!("give 1 to 8 particles per cell and axis, got {}", p.particles_per_cell),
        ));
    }
    let cells = (p.length_m / p.cell_m).round();
    let least = 8.0 * plate::MARGIN_CELLS;
    if cells < least {
        return Err(invalid(
            "scenario.length_m",
            "--length / --cell",
            format!(
                "a {} m slab is only {cells} cells of {} m long; the shock measurements need at least {least} cells: \
                 give a longer slab or smaller cells (e.g. --cell {:e})",
                p.length_m,
                p.cell_m,
                p.length_m / least
            ),
        ));
    }
    let particles = f64::from(p.particles_per_cell).powi(3) * (plate::COLUMN_CELLS as f64).powi(2) * cells;
    if particles > MAX_PARTICLES as f64 {
        return Err(invalid(
            "scenario.cell_m",
            "--length / --cell",
            format!(
                "a {} m slab of {} m cells would have {particles:.3e} particles, more than the {MAX_PARTICLES} a run \
                 can hold: give larger cells, a shorter slab or fewer --particles-per-cell",
                p.length_m, p.cell_m
            ),
        ));
    }
    Ok(())
}

fn plate_of(p: &PlateSpec, eos: MgForm) -> PlateImpact {
    PlateImpact {
        velocity: p.velocity_m_s,
        length: p.length_m,
        cell: p.cell_m,
        particles_per_cell: usize::from(p.particles_per_cell),
        eos,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_core::scenario::Pick;

    /// The memory estimate's plate size is the built plate's.
    #[test]
    fn plate_size_counts_the_built_particles() {
        let s = Scenario::Plate(PlateSpec { length_m: 40e-3, cell_m: 1e-3, ..PlateSpec::default() });
        let built = s.build(MgForm::Hugoniot, Pick::All).unwrap();
        assert_eq!(s.size().particles, built.setup.particles.len() as u64);
        assert!(s.size().nodes > 0);
    }

    #[test]
    fn bad_parameters_name_their_flag() {
        let s = Scenario::Impact(ImpactSpec { cell_m: -1.0, ..ImpactSpec::default() });
        let err = s.check().unwrap_err().to_string();
        assert!(err.contains("--cell") && err.contains("-1"), "{err}");
        let s = Scenario::Taylor(TaylorSpec::model(5));
        assert!(s.check().unwrap_err().to_string().contains("--model"));
    }
}
