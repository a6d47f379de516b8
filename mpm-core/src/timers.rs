//! Stage timers: the paper's split into the grid-node stage (Eqs. 1-6) and the particle
//! stage (Eqs. 7-15), with finer sub-stages. Ten `Instant::now()` calls a step: cheap
//! enough to leave on in every run.

use serde::{Deserialize, Serialize};

/// One sub-stage of the MUSL step, in execution order (which is also its order: `Ord`).
/// Serialised by its [`Substage::name`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Substage {
    /// Sorting the particles into cell order ([`crate::order`]), every
    /// [`crate::SimConfig::sort_every`] steps (0 in the others).
    Reorder,
    /// Re-fitting the adaptive grid and (DD) re-cutting the patches.
    GridFit,
    /// DD particle binning (`patnp_th`, `patnp`, `Pindex`).
    Binning,
    /// Scatter of mass, momentum and force to the nodes (Eqs. 1-5).
    Scatter,
    /// Summing per-thread copies (AE, Eq. 16) or sub-grids (DD) into the global arrays.
    Assembly,
    /// Nodal momentum update and boundary conditions (Eq. 6).
    GridUpdate,
    /// Particle velocity update from nodal accelerations (Eqs. 8, 10). Since the gather runs
    /// inside the re-map scatter's pass (one pass over the particles), its time is counted
    /// there and this sub-stage stays at 0; it is kept so that summaries keep their keys.
    Gather,
    /// MUSL re-map scatter of particle momentum (Eq. 11), with the gather (Eqs. 8, 10) of
    /// each particle just before its scatter.
    RemapScatter,
    /// Assembly of the re-mapped momentum and nodal velocities (Eq. 11).
    RemapAssembly,
    /// Positions, strain and spin increments, density, stress, energies (Eqs. 7, 9, 12-15).
    StressUpdate,
}

impl Substage {
    /// Every sub-stage in execution order.
    pub const ALL: [Substage; 10] = [
        Substage::Reorder,
        Substage::GridFit,
        Substage::Binning,
        Substage::Scatter,
        Substage::Assembly,
        Substage::GridUpdate,
        Substage::Gather,
        Substage::RemapScatter,
        Substage::RemapAssembly,
        Substage::StressUpdate,
    ];

    /// Stable snake_case name used in JSON and CSV.
    pub fn name(self) -> &'static str {
        match self {
            Substage::Reorder => "reorder",
            Substage::GridFit => "grid_fit",
            Substage::Binning => "binning",
            Substage::Scatter => "scatter",
            Substage::Assembly => "assembly",
            Substage::GridUpdate => "grid_update",
            Substage::Gather => "gather",
            Substage::RemapScatter => "remap_scatter",
            Substage::RemapAssembly => "remap_assembly",
            Substage::StressUpdate => "stress_update",
        }
    }

    /// Whether the sub-stage belongs to the paper's grid-node stage (else: particle stage).
    pub fn is_grid_stage(self) -> bool {
        matches!(
            self,
            Substage::Reorder
                | Substage::GridFit
                | Substage::Binning
                | Substage::Scatter
                | Substage::Assembly
                | Substage::GridUpdate
        )
    }
}

/// Accumulated seconds per sub-stage.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct StageTimes {
    seconds: [f64; 10],
}

impl StageTimes {
    /// Seconds spent in `s`.
    pub fn get(&self, s: Substage) -> f64 {
        self.seconds[s as usize]
    }

    /// Add `secs` to `s`.
    pub fn add(&mut self, s: Substage, secs: f64) {
        self.seconds[s as usize] += secs;
    }

    /// The paper's grid-node stage (Eqs. 1-6), seconds.
    pub fn grid_stage(&self) -> f64 {
        Substage::ALL.iter().filter(|s| s.is_grid_stage()).map(|&s| self.get(s)).sum()
    }

    /// The paper's particle stage (Eqs. 7-15), seconds.
    pub fn particle_stage(&self) -> f64 {
        Substage::ALL.iter().filter(|s| !s.is_grid_stage()).map(|&s| self.get(s)).sum()
    }

    /// Both stages, seconds.
    pub fn total(&self) -> f64 {
        self.seconds.iter().sum()
    }

    /// `self - earlier`, per sub-stage (for excluding warm-up steps).
    pub fn since(&self, earlier: &StageTimes) -> StageTimes {
        StageTimes { seconds: std::array::from_fn(|i| self.seconds[i] - earlier.seconds[i]) }
    }

    /// `(name, seconds)` for every sub-stage.
    pub fn named(&self) -> impl Iterator<Item = (&'static str, f64)> + '_ {
        Substage::ALL.iter().map(|&s| (s.name(), self.get(s)))
    }
}

impl Serialize for StageTimes {
    fn serialize<S: serde::Serializer>(&self, ser: S) -> Result<S::Ok, S::Error> {
        use serde::ser::SerializeMap;
        let mut m = ser.serialize_map(Some(Substage::ALL.len()))?;
        for (k, v) in self.named() {
            m.serialize_entry(k, &v)?;
        }
        m.end()
    }
}

/// Reads what [`Serialize`] writes: every sub-stage by its name (a missing one is an error,
/// so a saved state cannot silently lose a stage's time).
impl<'de> Deserialize<'de> for StageTimes {
    fn deserialize<D: serde::Deserializer<'de>>(de: D) -> Result<Self, D::Error> {
        let named = std::collections::BTreeMap::<Substage, f64>::deserialize(de)?;
        let mut times = StageTimes::default();
        for s in Substage::ALL {
            let secs = named.get(&s).ok_or_else(|| serde::de::Error::missing_field(s.name()))?;
            times.add(s, *secs);
        }
        Ok(times)
    }
}
