//! The memory a run will need, estimated from its spec before anything is built: what
//! `mpm` checks against the memory available where it runs (and the harness against the
//! memory of its host), the model's size from [`mpm_core::scenario::size`].

use crate::RunSpec;
use mpm_core::scenario::size::BASE_BYTES;

/// Memory of an MPI rank besides its share of the model: the MPI library, its buffers.
pub const RANK_OVERHEAD_BYTES: u64 = 64 << 20;

impl RunSpec {
    /// Estimated peak memory of one process (one rank) of this run, bytes: its share of
    /// the model on `threads` workers (the whole model in one process), the MPI library's
    /// [`RANK_OVERHEAD_BYTES`] with several ranks, and in a paired run the one-thread
    /// reference solver built beside the `threads`-thread one (its model and scatter
    /// arrays and its worker; the process's baseline is counted once).
    pub fn process_memory_bytes(&self) -> u64 {
        let size = self.scenario.size();
        let whole = size.memory_bytes(self.strategy, self.threads);
        let share = match self.ranks {
            0 | 1 => whole,
            r => whole / r as u64 + RANK_OVERHEAD_BYTES,
        };
        let reference = match self.paired {
            Some(_) => size.memory_bytes(self.strategy, 1).saturating_sub(BASE_BYTES),
            None => 0,
        };
        share.saturating_add(reference)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenario::TaylorSpec;
    use crate::spec::Paired;
    use crate::Scenario;
    use mpm_core::scenario::size::ModelSize;
    use mpm_core::Strategy;

    /// A paired run counts both solvers: the `T`-thread one and its one-thread reference,
    /// the process's baseline once; over ranks each process holds its share and the MPI
    /// library.
    #[test]
    fn a_paired_run_counts_both_solvers() {
        let mut s = RunSpec::new(Scenario::Taylor(TaylorSpec::model(2))).unwrap();
        s.strategy = Strategy::ArrayExpansion;
        s.threads = 4;
        let size = ModelSize::taylor(2).unwrap();
        let one = s.process_memory_bytes();
        assert_eq!(one, size.memory_bytes(Strategy::ArrayExpansion, 4));
        s.paired = Some(Paired { blocks: 4 });
        let reference = size.memory_bytes(Strategy::ArrayExpansion, 1) - BASE_BYTES;
        assert_eq!(s.process_memory_bytes(), one + reference);
        assert!(reference > size.particles * 100, "the reference holds a whole model");
        s.paired = None;
        s.ranks = 2;
        assert_eq!(s.process_memory_bytes(), one / 2 + RANK_OVERHEAD_BYTES);
    }
}
