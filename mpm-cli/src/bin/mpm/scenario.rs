//! The scenario a run asks for (Taylor bar, impact or plate) and its model, built from the
//! options.

use crate::cli::{EosArg, ImpactArgs, PlateArgs, RunOptions, TaylorArgs, WallArg};
use anyhow::{Context, Result};
use mpm_core::scenario::impact;
use mpm_core::scenario::plate::{PlateGeometry, PlateImpact};
use mpm_core::scenario::taylor::{self, TaylorBar};
use mpm_core::scenario::Pick;
use mpm_core::{GridMode, MgForm, WallKind, DEFAULT_CFL};
use std::path::Path;

/// The plate scenario's default CFL number (see `--cfl`): its shock speed is the measurement.
pub const PLATE_CFL: f64 = 0.2;

/// The scenario a run was asked for.
pub enum ScenarioRun {
    Taylor(TaylorArgs),
    Impact(ImpactArgs),
    Plate(PlateArgs),
}

/// A scenario built and ready to run.
pub struct Prepared {
    pub setup: mpm_core::Setup,
    pub model: u8,
    pub velocity: f64,
    pub wall: &'static str,
    /// Whether the run measures a Taylor bar (its figures come from the simulation's
    /// particles at the start and the end).
    pub taylor: bool,
    pub impact: Option<impact::ImpactGeometry>,
    pub plate: Option<PlateGeometry>,
}

pub fn eos_of(e: EosArg) -> MgForm {
    match e {
        EosArg::Hugoniot => MgForm::Hugoniot,
        EosArg::PaperPrinted => MgForm::PaperPrinted,
    }
}

fn plate_of(args: &PlateArgs) -> PlateImpact {
    PlateImpact {
        velocity: args.velocity,
        length: args.length,
        cell: args.cell,
        particles_per_cell: usize::from(args.particles_per_cell),
        eos: eos_of(args.eos.eos),
    }
}

/// Build the plate of `args`.
fn plate_setup(args: &PlateArgs) -> Result<(mpm_core::Setup, PlateGeometry)> {
    plate_of(args).setup().context("cannot set up the plate impact")
}

impl ScenarioRun {
    pub fn options(&self) -> &RunOptions {
        match self {
            ScenarioRun::Taylor(a) => &a.run,
            ScenarioRun::Impact(a) => &a.run,
            ScenarioRun::Plate(a) => &a.run,
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            ScenarioRun::Taylor(_) => "taylor",
            ScenarioRun::Impact(_) => "impact",
            ScenarioRun::Plate(_) => "plate",
        }
    }

    pub fn describe(&self) -> String {
        match self {
            ScenarioRun::Taylor(a) => format!("Taylor bar Model {}", a.model),
            ScenarioRun::Impact(a) => {
                format!("impact, spacing {} mm, cell {} mm", a.spacing * 1e3, a.cell * 1e3)
            }
            ScenarioRun::Plate(a) => {
                format!("plate impact at {} m/s, slab {} mm, cell {} mm", a.velocity, a.length * 1e3, a.cell * 1e3)
            }
        }
    }

    /// The end time without `--end-time` and `--steps`: the paper's, or for the plate when
    /// the shock has crossed [`mpm_core::scenario::plate::END_FRACTION`] of the slab.
    pub fn default_end_time(&self) -> Result<f64> {
        Ok(match self {
            ScenarioRun::Taylor(_) => taylor::DEFAULT_END_TIME,
            ScenarioRun::Impact(_) => impact::DEFAULT_END_TIME,
            ScenarioRun::Plate(a) => plate_setup(a)?.1.end_time(),
        })
    }

    /// The grid when `--grid` is not given; `distributed` for a run over several ranks,
    /// which the sparse grid does not support.
    pub fn default_grid(&self, distributed: bool) -> GridMode {
        match self {
            ScenarioRun::Taylor(_) | ScenarioRun::Plate(_) => GridMode::Fixed,
            ScenarioRun::Impact(_) if distributed => GridMode::Adaptive,
            ScenarioRun::Impact(_) => GridMode::Sparse,
        }
    }

    /// The CFL number: `--cfl`, else the scenario's default.
    pub fn cfl(&self) -> f64 {
        let default = match self {
            ScenarioRun::Plate(_) => PLATE_CFL,
            ScenarioRun::Taylor(_) | ScenarioRun::Impact(_) => DEFAULT_CFL,
        };
        self.options().cfl.unwrap_or(default)
    }

    /// Build the scenario, with the particles `pick` asks for.
    pub fn build(&self, pick: Pick<'_>) -> Result<Prepared> {
        match self {
            ScenarioRun::Taylor(args) => {
                let bar = TaylorBar {
                    model: args.model,
                    velocity: args.velocity,
                    eos: eos_of(args.eos.eos),
                    wall: match args.wall {
                        WallArg::Frictionless => WallKind::Slip,
                        WallArg::Sticking => WallKind::Stick,
                    },
                };
                let setup =
                    bar.setup_picked(pick).with_context(|| format!("cannot set up Taylor bar Model {}", args.model))?;
                Ok(Prepared {
                    setup,
                    model: args.model,
                    velocity: args.velocity,
                    wall: args.wall.name(),
                    taylor: true,
                    impact: None,
                    plate: None,
                })
            }
            ScenarioRun::Impact(args) => {
                let imp = impact::Impact {
                    spacing: args.spacing,
                    cell: args.cell,
                    velocity: args.velocity,
                    eos: eos_of(args.eos.eos),
                };
                let (setup, geometry) = imp.setup_picked(pick).context("cannot set up the impact")?;
                Ok(Prepared {
                    setup,
                    model: 0,
                    velocity: args.velocity,
                    wall: "none",
                    taylor: false,
                    impact: Some(geometry),
                    plate: None,
                })
            }
            ScenarioRun::Plate(args) => {
                let (setup, geometry) = plate_of(args).setup_picked(pick).context("cannot set up the plate impact")?;
                Ok(Prepared {
                    setup,
                    model: 0,
                    velocity: args.velocity,
                    wall: "frictionless",
                    taylor: false,
                    impact: None,
                    plate: Some(geometry),
                })
            }
        }
    }

    /// Radiograph directory and interval (impact only).
    pub fn radiograph(&self) -> Option<(&Path, Option<u64>)> {
        match self {
            ScenarioRun::Impact(a) => a.radiograph.as_deref().map(|d| (d, a.radiograph_every)),
            ScenarioRun::Taylor(_) | ScenarioRun::Plate(_) => None,
        }
    }
}
