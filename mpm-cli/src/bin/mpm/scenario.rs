//! The scenario a run asks for (Taylor bar or impact) and its model, built from the options.

use crate::cli::{EosArg, ImpactArgs, RunOptions, TaylorArgs, WallArg};
use anyhow::{Context, Result};
use mpm_core::scenario::impact;
use mpm_core::scenario::taylor::{self, TaylorBar};
use mpm_core::{GridMode, MgForm, WallKind};
use std::path::Path;

/// The scenario a run was asked for.
pub enum ScenarioRun {
    Taylor(TaylorArgs),
    Impact(ImpactArgs),
}

/// A scenario built and ready to run.
pub struct Prepared {
    pub setup: mpm_core::Setup,
    pub model: u8,
    pub velocity: f64,
    pub wall: &'static str,
    pub taylor: Option<(taylor::TaylorFigures, [f64; 3])>,
    pub impact: Option<impact::ImpactGeometry>,
}

pub fn eos_of(e: EosArg) -> MgForm {
    match e {
        EosArg::Paper => MgForm::Paper,
        EosArg::Lsdyna => MgForm::LsDyna,
    }
}

impl ScenarioRun {
    pub fn options(&self) -> &RunOptions {
        match self {
            ScenarioRun::Taylor(a) => &a.run,
            ScenarioRun::Impact(a) => &a.run,
        }
    }

    pub fn name(&self) -> &'static str {
        match self {
            ScenarioRun::Taylor(_) => "taylor",
            ScenarioRun::Impact(_) => "impact",
        }
    }

    pub fn describe(&self) -> String {
        match self {
            ScenarioRun::Taylor(a) => format!("Taylor bar Model {}", a.model),
            ScenarioRun::Impact(a) => {
                format!("impact, spacing {} mm, cell {} mm", a.spacing * 1e3, a.cell * 1e3)
            }
        }
    }

    pub fn default_end_time(&self) -> f64 {
        match self {
            ScenarioRun::Taylor(_) => taylor::DEFAULT_END_TIME,
            ScenarioRun::Impact(_) => impact::DEFAULT_END_TIME,
        }
    }

    pub fn default_grid(&self) -> GridMode {
        match self {
            ScenarioRun::Taylor(_) => GridMode::Fixed,
            ScenarioRun::Impact(_) => GridMode::Adaptive,
        }
    }

    pub fn build(&self) -> Result<Prepared> {
        match self {
            ScenarioRun::Taylor(args) => {
                let bar = TaylorBar {
                    model: args.model,
                    velocity: args.velocity,
                    eos: eos_of(args.eos),
                    wall: match args.wall {
                        WallArg::Frictionless => WallKind::Slip,
                        WallArg::Sticking => WallKind::Stick,
                    },
                };
                let setup = bar.setup().with_context(|| format!("cannot set up Taylor bar Model {}", args.model))?;
                let figures = taylor::measure(&setup.particles, setup.spacing);
                let spacing = setup.spacing;
                Ok(Prepared {
                    setup,
                    model: args.model,
                    velocity: args.velocity,
                    wall: args.wall.name(),
                    taylor: Some((figures, spacing)),
                    impact: None,
                })
            }
            ScenarioRun::Impact(args) => {
                let imp = impact::Impact {
                    spacing: args.spacing,
                    cell: args.cell,
                    velocity: args.velocity,
                    eos: eos_of(args.eos),
                };
                let (setup, geometry) = imp.setup().context("cannot set up the impact")?;
                Ok(Prepared {
                    setup,
                    model: 0,
                    velocity: args.velocity,
                    wall: "none",
                    taylor: None,
                    impact: Some(geometry),
                })
            }
        }
    }

    /// Radiograph directory and interval (impact only).
    pub fn radiograph(&self) -> Option<(&Path, Option<u64>)> {
        match self {
            ScenarioRun::Impact(a) => a.radiograph.as_deref().map(|d| (d, a.radiograph_every)),
            ScenarioRun::Taylor(_) => None,
        }
    }
}
