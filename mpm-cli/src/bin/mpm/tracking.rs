//! What a run measures while it steps besides the energy history ([`Tracking`]: the impact's
//! cloud history, the plate's shock front) and the scenario's figures of the final state
//! ([`FinalFigures`]), each measured over every rank's particles.

use crate::checkpointing::SavedCloud;
use anyhow::{bail, Result};
use mpm_core::scenario::impact::{self, CloudFigures, History, ImpactGeometry, DEFAULT_HISTORY_INTERVAL};
use mpm_core::scenario::plate::{PlateGeometry, PlateResult, ShockTracker};
use mpm_core::scenario::taylor::{self, TaylorFigures};
use mpm_core::{Collectives, Simulation};

/// What a run measures while it steps besides the energy history: the impact's cloud
/// history, the plate's shock front. Over several ranks every rank tracks them, since the
/// measurements are collective (rank 0 holds the cloud history's samples).
pub struct Tracking {
    /// The impact: its cloud history and geometry.
    pub cloud: Option<(History, ImpactGeometry)>,
    /// The plate: its shock tracker.
    shock: Option<ShockTracker>,
}

impl Tracking {
    /// Nothing tracked yet, for the scenario's geometries.
    pub fn new(impact: Option<ImpactGeometry>, plate: Option<PlateGeometry>) -> Result<Self> {
        let cloud = match impact {
            Some(g) => Some((History::new(DEFAULT_HISTORY_INTERVAL)?, g)),
            None => None,
        };
        Ok(Self { cloud, shock: plate.map(ShockTracker::new) })
    }

    /// The tracking a checkpoint saved, on the scenario's geometries.
    pub fn restored(
        cloud: Option<SavedCloud>,
        shock_path: Option<Vec<[f64; 2]>>,
        impact: Option<ImpactGeometry>,
        plate: Option<PlateGeometry>,
    ) -> Result<Self> {
        let cloud = match (impact, cloud) {
            (Some(g), Some(c)) => Some((History::resumed(c.interval, c.samples, c.last_time)?, g)),
            (None, None) => None,
            _ => bail!("the checkpoint's cloud history does not fit the scenario"),
        };
        let shock = match (plate, shock_path) {
            (Some(geometry), Some(path)) => {
                Some(ShockTracker { geometry, path: path.into_iter().map(|[t, z]| (t, z)).collect() })
            }
            (None, None) => None,
            _ => bail!("the checkpoint's shock tracker does not fit the scenario"),
        };
        Ok(Self { cloud, shock })
    }

    /// What a checkpoint saves of it.
    pub fn saved(&self) -> (Option<SavedCloud>, Option<Vec<[f64; 2]>>) {
        let cloud = self.cloud.as_ref().map(|(h, _)| SavedCloud {
            interval: h.interval,
            samples: h.samples.clone(),
            last_time: h.last_time(),
        });
        (cloud, self.shock.as_ref().map(|t| t.path.iter().map(|&(t, z)| [t, z]).collect()))
    }

    /// Sample the current state (the history only when a new interval has begun).
    pub fn observe(&mut self, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<()> {
        if let Some((h, g)) = &mut self.cloud {
            h.observe(sim, g, ranks)?;
        }
        if let Some(t) = &mut self.shock {
            t.observe(sim, ranks)?;
        }
        Ok(())
    }

    /// The last history sample at the final state, from its `figures`.
    pub fn finish(&mut self, sim: &Simulation, figures: &FinalFigures) {
        if let Some((h, _)) = &mut self.cloud {
            h.finish(sim, figures.cloud.as_ref(), figures.failed);
        }
    }
}

/// The scenario's figures of the final state, measured over every rank's particles:
/// collective (every rank calls it), without gathering the particles themselves.
pub struct FinalFigures {
    /// Failed particles.
    pub failed: usize,
    /// The Taylor bar's.
    pub taylor: Option<TaylorFigures>,
    /// The debris cloud (rank 0 only).
    pub cloud: Option<CloudFigures>,
    /// The plate's.
    pub plate: Option<PlateResult>,
}

/// The Taylor bar's figures of `sim` now (collective), when the run is a bar (`taylor`).
pub fn bar_figures(taylor: bool, sim: &Simulation, ranks: &mut dyn Collectives) -> Result<Option<TaylorFigures>> {
    Ok(taylor.then(|| taylor::measure_over(sim.particles(), sim.spacing(), ranks)).transpose()?)
}

impl FinalFigures {
    /// Measure them (collective).
    pub fn measure(sim: &Simulation, taylor: bool, tracking: &Tracking, ranks: &mut dyn Collectives) -> Result<Self> {
        let failed = ranks.total(sim.particles().failed_count())?;
        let taylor = bar_figures(taylor, sim, ranks)?;
        let cloud = match &tracking.cloud {
            Some((_, g)) => impact::measure_over(sim.particles(), |p| sim.exchange().global_id(p), g, ranks)?,
            None => None,
        };
        let plate = match &tracking.shock {
            Some(t) => t.result(sim, ranks)?,
            None => None,
        };
        Ok(Self { failed, taylor, cloud, plate })
    }
}
