//! Bytes an MPM step moves per stage ([`StageBytes`]), so a report can say what fraction of
//! the memory-bandwidth ceiling ([`crate::machine::bandwidth`]) each stage reaches.
//!
//! Counted from `mpm-core/src/transfer.rs` and `mpm-core/src/strategy/*.rs`, with `P`
//! particles, `N` grid nodes (mean over the steps), `T` threads. Like STREAM, a read or a
//! write of a double counts 8 bytes and write-allocate traffic is not counted. Node records:
//! `p2g` = `[m, p, f]` 7 doubles = 56 B, `kin` = `[v, a]` 48 B, `remap` 24 B. Particle
//! fields: `x`, `v` 24 B each, `mass`, `rho`, `eps_p`, `e_int`, `sound` 8 B, `stress` 48 B,
//! `failed` 1 B. *copies* of the scatter arrays: `T` for AE (one column of all `N` nodes per
//! thread), about 1 for DD (the sub-grids together; shared faces neglected), 1 for serial,
//! colour and atomic (the global arrays themselves). Atomic adds move the serial bytes (a
//! record's compare-exchange additions hit it in cache while a cell's particles go through);
//! what they add is the additions' latency, not traffic.
//!
//! | pass | per particle | per node |
//! |---|---|---|
//! | DD binning (count + write `Pindex`) | x 24 + patch 4 + 4 + Pindex 4 = 36 | - |
//! | balanced cuts: histogram passes, binning from the stored cells | x 24 + cell 12, + 12 per y or z pass; count cell 12 + patch 4; write 4 + Pindex 4 = 60 (+12 per y/z pass) | - |
//! | colour binning (count, then write the block lists) | x 24 + x 24 + id 4 = 52 | - |
//! | P2G scatter (Eqs. 1-5) | x 24, v 24, mass 8, rho 8, stress 48 = 112 (+4 Pindex, DD) | zero 56 + read-modify-write 112 = 168 per copy |
//! | assembly (Eq. 16 / sub-grids) | - | AE 56 (T+1); DD read 56 + write 56 = 112 (each node stored by its first patch, added by the others: shared faces neglected); serial 0 |
//! | grid update (Eq. 6) | - | read p2g 56 + write kin 48 = 104 |
//! | **grid-node stage** | 112 (+40 DD, +64..88 balanced DD, +52 colour) | 168 copies + assembly + 104 |
//! | gather (Eqs. 8, 10) | x 24 + v r/w 48 = 72 | kin 48 |
//! | re-map scatter (Eq. 11) | x 24, v 24, mass 8 = 56 (+4 DD) | zero 24 + r/w 48 = 72 per copy |
//! | re-map assembly | - | AE 24 (T+1); DD 48; serial 0 |
//! | re-map velocity | - | p2g records 56 + remap r/w 48 = 104 |
//! | update (Eqs. 7, 9, 12-15) | x r/w 48, v 24, mass 8, rho 16, stress 96, eps_p 16, e_int 16, sound 16, failed 2 = 242 | kin 48 + remap 24 = 72 |
//! | **particle stage** | 370 (+4 DD) | 48 + 72 copies + assembly + 104 + 72 |
//!
//! These are *compulsory* bytes: every array streamed once per pass, as if the nodes a
//! particle touches were still in cache from its neighbours (particles are stored in
//! lattice order, so they mostly are). Without any reuse every particle would also move its
//! 8 nodes: P2G 8 x 56 x 2 = 896 B, gather 8 x 48 = 384 B, re-map 8 x 24 x 2 = 384 B,
//! update 8 x 72 = 576 B. [`StageBytes`] gives both bounds; the report's fraction of the
//! ceiling uses the compulsory bytes (a lower bound: a stage near 100 % is bandwidth bound)
//! and shows the no-reuse one beside it (above 100 % means the caches are doing their job).

use super::stats::Stage;
use mpm_core::Strategy;
use serde::Serialize;

/// Estimated bytes moved per step by each stage (see the module docs for the count).
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct StageBytes {
    /// Grid-node stage, compulsory traffic (bytes per step).
    pub grid_min: f64,
    /// Grid-node stage, no cache reuse between particles.
    pub grid_max: f64,
    /// Particle stage, compulsory traffic.
    pub particle_min: f64,
    /// Particle stage, no cache reuse between particles.
    pub particle_max: f64,
}

impl StageBytes {
    /// Bytes per step of `strategy` with `threads` workers, `particles` particles and `nodes`
    /// grid nodes.
    pub fn estimate(strategy: Strategy, threads: usize, particles: f64, nodes: f64) -> Self {
        let t = threads.max(1) as f64;
        // Balanced cuts: one more pass per cut axis besides x (cells written, then read).
        let cut_axes =
            mpm_core::strategy::patch_layout(threads.max(1), [1 << 20; 3])[1..].iter().filter(|&&p| p > 1).count();
        let (copies, asm7, asm3, dd_p, binning) = match strategy {
            Strategy::ArrayExpansion => (t, 56.0 * (t + 1.0), 24.0 * (t + 1.0), 0.0, 0.0),
            Strategy::DomainDecomposition => (1.0, 112.0, 48.0, 1.0, 40.0),
            Strategy::DdBalanced => (1.0, 112.0, 48.0, 1.0, 64.0 + 12.0 * cut_axes as f64),
            Strategy::Colour => (1.0, 0.0, 0.0, 0.0, 52.0),
            Strategy::Serial | Strategy::Atomic => (1.0, 0.0, 0.0, 0.0, 0.0),
        };
        let grid_min = particles * (112.0 + binning) + nodes * (168.0 * copies + asm7 + 104.0);
        let particle_min = particles * (370.0 + 4.0 * dd_p) + nodes * (48.0 + 72.0 * copies + asm3 + 104.0 + 72.0);
        Self {
            grid_min,
            grid_max: grid_min + particles * 896.0,
            particle_min,
            particle_max: particle_min + particles * (384.0 + 384.0 + 576.0),
        }
    }

    /// (compulsory, no-reuse) bytes per step of a stage.
    pub fn of(&self, stage: Stage) -> (f64, f64) {
        match stage {
            Stage::Total => (self.grid_min + self.particle_min, self.grid_max + self.particle_max),
            Stage::Grid => (self.grid_min, self.grid_max),
            Stage::Particle => (self.particle_min, self.particle_max),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn byte_model_counts() {
        let s = StageBytes::estimate(Strategy::Serial, 1, 1.0, 0.0);
        assert_eq!(s.grid_min, 112.0);
        assert_eq!(s.particle_min, 370.0);
        let ae = StageBytes::estimate(Strategy::ArrayExpansion, 4, 0.0, 1.0);
        assert_eq!(ae.grid_min, 168.0 * 4.0 + 56.0 * 5.0 + 104.0);
        let dd = StageBytes::estimate(Strategy::DomainDecomposition, 4, 0.0, 1.0);
        assert!(dd.grid_min < ae.grid_min);
        assert_eq!(dd.of(Stage::Total).0, dd.grid_min + dd.particle_min);
        let serial = StageBytes::estimate(Strategy::Serial, 1, 1.0, 1.0);
        assert_eq!(StageBytes::estimate(Strategy::Atomic, 4, 1.0, 1.0), serial);
        assert_eq!(StageBytes::estimate(Strategy::Colour, 4, 1.0, 1.0).grid_min, serial.grid_min + 52.0);
    }
}
