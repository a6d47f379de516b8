//! # mpm-core
//!
//! An explicit material point method (MPM) solver built to reproduce Huang, Zhang, Ma and
//! Wang, "Shared Memory OpenMP Parallelization of Explicit MPM and Its Application to
//! Hypervelocity Impact" (CMES 38(2), 2008). Equation numbers in the docs are the paper's.
//!
//! * the MUSL step (Eqs. 1-15) with trilinear shape functions and the Jaumann stress rate:
//!   [`solver`];
//! * J2 plasticity with hardening `A + B eps_p^n`, the Mie-Grüneisen EOS (Hugoniot-referenced
//!   by default; the paper's printed Eq. 18 on request), artificial bulk viscosity and
//!   failure: [`material`];
//! * the kernels of each phase of the step (P2G, the node passes, the gather fused with the
//!   re-map, the particle update), shared by every strategy: [`transfer`];
//! * the ways to do the nodal scatter, serial and the paper's array expansion and domain
//!   decomposition (uniform or balanced cuts), and two used since, block colouring and
//!   atomic adds, which is all that differs between them: [`strategy`];
//! * the parallel region a step runs in, its phases and the per-worker parts of shared
//!   arrays, with a safe API: [`parallel`];
//! * what a step needs from other processes when a run is split over ranks (halo sums,
//!   particle migration, reductions) and the collectives the scenario figures are measured
//!   with, as traits with a single-process no-op, and the rank boxes: [`exchange`];
//! * the Taylor bar Models 1-4 ([`scenario::taylor`]), the hypervelocity impact
//!   ([`scenario::impact`]) and a 1D plate impact checked against the Rankine-Hugoniot
//!   relations ([`scenario::plate`]).
//!
//! Units are SI throughout. The crate has no OS-specific code and starts no threads: the
//! caller builds the simulation with the [`rayon::ThreadPool`] to run on (and pins its
//! workers if it wants to); the pool's thread count is the simulation's worker count.
//!
//! ```
//! use mpm_core::{scenario::taylor::TaylorBar, SimConfig, Simulation, Strategy};
//! use std::sync::Arc;
//!
//! let setup = TaylorBar { model: 1, ..Default::default() }.setup()?;
//! assert_eq!(setup.particles.len(), 56_056);
//! let pool = Arc::new(rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap());
//! let config = SimConfig { strategy: Strategy::DomainDecomposition, ..Default::default() };
//! let mut sim = Simulation::new(setup, config, pool)?;
//! assert_eq!(sim.threads(), 2);
//! for _ in 0..3 {
//!     sim.step(f64::INFINITY)?;
//! }
//! assert!(sim.diagnostics().kinetic < sim.initial().kinetic);
//! println!("grid stage {:.3} s, particle stage {:.3} s", sim.times().grid_stage(), sim.times().particle_stage());
//! # Ok::<(), mpm_core::SimError>(())
//! ```

pub mod blocks;
pub mod energy;
pub mod error;
pub mod exchange;
pub mod grid;
mod inject;
pub mod locate;
pub mod material;
pub mod math;
pub mod node_index;
pub mod order;
pub mod parallel;
pub mod particles;
pub mod roofline;
pub mod scenario;
pub mod shape;
pub mod simd;
pub mod solver;
pub mod strategy;
pub mod timers;
pub mod transfer;
pub mod work;

pub use error::SimError;
pub use exchange::{Collectives, Exchange, OneProcess, RankBoxes, SingleProcess};
pub use grid::{GridGeom, GridMode, GridSpec, Wall, WallKind};
pub use material::{BulkViscosity, Material, MgForm};
pub use node_index::NodeIndex;
pub use particles::Particles;
pub use scenario::Setup;
pub use simd::SimdLevel;
pub use solver::{Diagnostics, SimConfig, SimState, Simulation, DEFAULT_CFL, DEFAULT_ENERGY_RISE_LIMIT};
pub use strategy::{EngineState, MemoryModel, Strategy};
pub use timers::{StageTimes, Substage};
pub use work::{Work, WorkBound, WorkCounts};

/// Bytes held by `v`'s allocation (its capacity, not its length).
pub(crate) fn capacity_bytes<T>(v: &Vec<T>) -> usize {
    v.capacity() * std::mem::size_of::<T>()
}

/// Helpers of the crate's unit tests.
#[cfg(test)]
pub(crate) mod testing {
    use std::sync::Arc;

    /// A rayon pool of `threads` threads, as a simulation or a team takes it.
    pub(crate) fn pool(threads: usize) -> Arc<rayon::ThreadPool> {
        Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap())
    }

    /// A reproducible stream of uniform numbers in `[0, 1)` (a 64-bit LCG, top 53 bits):
    /// the random inputs of the unit tests, the same on every machine.
    pub(crate) fn unit_stream(seed: u64) -> impl FnMut() -> f64 {
        let mut s = seed;
        move || {
            s = s.wrapping_mul(6364136223846793005).wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        }
    }
}
