//! Model sizes and memory estimates without building a model: what a benchmark harness
//! needs to plan runs (the memory guard, progress estimates, the rows of skipped runs).
//!
//! * Taylor bar Models 1-4: the counts of [`taylor::ModelSpec`] (Table 2).
//! * Impact: the particles of [`impact::Impact::setup`], counted without seeding them
//!   ([`impact::Impact::particle_counts`]), and
//!   the nodes of the adaptive grid around the debris cloud at 30.6 µs (about
//!   160 x 160 x 220 mm, measured on the small model), an upper estimate.
//! * Memory ([`ModelSize::memory_bytes`]): bytes per particle and per node fitted to the
//!   solver's own [`crate::Simulation::memory_bytes`] on Models 1-3 (serial: 137 B per
//!   particle + 162 B per node, the node records of 64 + 48 + 32 bytes and the grid's flags,
//!   reproduced all three to 0.002 %), plus the 36 B per particle of the step's cells and
//!   local coordinates ([`crate::locate`], added since). Array expansion keeps one private 108-byte copy of the
//!   scattered node records per worker (Model 2 at 1 and 4 threads: exactly 108 and 432 B
//!   per node), so it grows with every thread; domain decomposition adds binning (8 B per
//!   particle) and sub-grid records (108-113 B per node at 1-4 threads) that barely depend on
//!   the thread count ([`Strategy::memory_model`]). Block colouring and atomic adds scatter
//!   into the global arrays and hold nothing beyond them but, for colouring, its block lists:
//!   one 4-byte index a particle, and a 4-byte count per block and worker (blocks of at
//!   least 2^3 cells on grids of the models' sizes: at most half a byte a node a worker).

use super::{impact, taylor};
use crate::strategy::{MemoryModel, Strategy};

/// Bytes per particle (state, stress, strain, material history: 137; the step's cell and
/// local coordinates: 36).
pub const BYTES_PER_PARTICLE: u64 = 137 + 36;
/// Bytes per grid node (the P2G, kinematic and re-map records, flags).
pub const BYTES_PER_NODE: u64 = 162;
/// Extra bytes per node for each AE worker (its private copy of the scattered records).
pub const AE_BYTES_PER_NODE_PER_THREAD: u64 = 108;
/// DD binning overhead per particle (patch index, permutation).
pub const DD_BYTES_PER_PARTICLE: u64 = 8;
/// DD sub-grid overhead per node (the patches' records, shared faces held twice).
pub const DD_BYTES_PER_NODE: u64 = 112;
/// Block colouring's lists per particle (its index in its block's list).
pub const COLOUR_BYTES_PER_PARTICLE: u64 = 4;
/// Process baseline (binary, runtime, allocator), plus [`BYTES_PER_THREAD`] per worker.
pub const BASE_BYTES: u64 = 16 << 20;
/// Per-worker slack (stack pages touched, DD halo growth with the patch count).
pub const BYTES_PER_THREAD: u64 = 2 << 20;

/// The impact models of a campaign, numbered 1-4: `(particle spacing, cell size)` in
/// metres. 1-3 are the paper's small model (0.53 mm spacing, 847,888 particles) with its
/// three cell sizes 2.12 / 1.59 / 1.06 mm; 4 is the large model (0.21 mm, 13.5 M particles,
/// 1.0 mm cells).
pub const IMPACT_MODELS: [(f64, f64); 4] =
    [(0.53e-3, 2.12e-3), (0.53e-3, 1.59e-3), (0.53e-3, 1.06e-3), (0.21e-3, 1.0e-3)];

/// Extent of the adaptive grid around the impact's debris cloud at 30.6 µs (m).
const IMPACT_CLOUD_BOX: [f64; 3] = [0.16, 0.16, 0.22];

/// Particle and node counts of a model.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ModelSize {
    /// Particles.
    pub particles: u64,
    /// Grid nodes.
    pub nodes: u64,
}

impl ModelSize {
    /// Taylor bar Model `model` (1-4): Table 2's particles and fixed-grid nodes.
    pub fn taylor(model: u8) -> Option<Self> {
        let spec = taylor::ModelSpec::get(model).ok()?;
        Some(Self { particles: spec.particles() as u64, nodes: spec.nodes() as u64 })
    }

    /// The impact at lattice `spacing` with grid `cell` (m): its particles, and the nodes of
    /// the adaptive grid around the debris cloud at the paper's comparison time.
    pub fn impact(spacing: f64, cell: f64) -> Self {
        let (plate, sphere) = impact::Impact { spacing, cell, ..impact::Impact::default() }.particle_counts();
        let n = |len: f64| (len / cell).ceil() as u64 + 1;
        let nodes = IMPACT_CLOUD_BOX.iter().map(|&len| n(len)).product();
        Self { particles: (plate + sphere) as u64, nodes }
    }

    /// Estimated peak memory of a run of this model with `strategy` on `threads` workers
    /// (bytes; see the module docs for the constants). The zero-sized model gives the
    /// process baseline.
    pub fn memory_bytes(&self, strategy: Strategy, threads: usize) -> u64 {
        let t = threads.max(1) as u64;
        let base = BASE_BYTES + t * BYTES_PER_THREAD;
        let model = self.particles * BYTES_PER_PARTICLE + self.nodes * BYTES_PER_NODE;
        let scatter = match strategy.memory_model() {
            // The block lists and a count per block (of at least 8 cells) and worker.
            MemoryModel::None if strategy == Strategy::Colour => {
                self.particles * COLOUR_BYTES_PER_PARTICLE + t * self.nodes / 2
            }
            MemoryModel::None => 0,
            MemoryModel::PerThreadCopies => t * AE_BYTES_PER_NODE_PER_THREAD * self.nodes,
            MemoryModel::SharedFaces => self.particles * DD_BYTES_PER_PARTICLE + self.nodes * DD_BYTES_PER_NODE,
        };
        base + model + scatter
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn taylor_sizes_are_table_2() {
        assert_eq!(ModelSize::taylor(1), Some(ModelSize { particles: 56_056, nodes: 53_361 }));
        assert_eq!(ModelSize::taylor(4), Some(ModelSize { particles: 12_416_320, nodes: 8_302_185 }));
        assert_eq!(ModelSize::taylor(5), None);
    }

    /// The count without seeding equals the seeded set-up (coarse and the paper's small
    /// model), and the large model's documented count.
    #[test]
    fn impact_particles_are_counted_exactly() {
        for spacing in [2.0e-3, 0.53e-3] {
            let (setup, _) = impact::Impact { spacing, ..impact::Impact::default() }.setup().unwrap();
            assert_eq!(ModelSize::impact(spacing, 2.12e-3).particles, setup.particles.len() as u64, "{spacing}");
        }
        assert_eq!(ModelSize::impact(0.53e-3, 2.12e-3).particles, 847_888);
        assert_eq!(ModelSize::impact(0.21e-3, 1.0e-3).particles, 13_542_030);
        assert_eq!(ModelSize::impact(0.53e-3, 2.12e-3).nodes, 77 * 77 * 105);
    }

    #[test]
    fn memory_grows_with_ae_threads_only() {
        let m4 = ModelSize::taylor(4).unwrap();
        let (ae1, ae8) = (m4.memory_bytes(Strategy::ArrayExpansion, 1), m4.memory_bytes(Strategy::ArrayExpansion, 8));
        let dd1 = m4.memory_bytes(Strategy::DomainDecomposition, 1);
        let dd8 = m4.memory_bytes(Strategy::DomainDecomposition, 8);
        assert_eq!(ae8 - ae1, 7 * (108 * 8_302_185 + BYTES_PER_THREAD));
        assert_eq!(dd8 - dd1, 7 * BYTES_PER_THREAD);
        assert!(m4.memory_bytes(Strategy::Serial, 1) < dd1);
        // Atomic adds hold what serial holds; colouring its lists besides, under 2 %.
        let serial = m4.memory_bytes(Strategy::Serial, 1);
        assert_eq!(m4.memory_bytes(Strategy::Atomic, 8) - serial, 7 * BYTES_PER_THREAD);
        let colour = m4.memory_bytes(Strategy::Colour, 2) - m4.memory_bytes(Strategy::Serial, 2);
        assert_eq!(colour, 4 * 12_416_320 + 8_302_185);
        assert!((colour as f64) < 0.02 * serial as f64);
        assert_eq!(ModelSize::default().memory_bytes(Strategy::Serial, 2), BASE_BYTES + 2 * BYTES_PER_THREAD);
    }
}
