//! The memory guard: every run's memory estimated before it starts (model sizes and the
//! memory model come from [`mpm_core::scenario::size`]), the memory available now, and the
//! verdict that records a run that would not fit as `skipped` instead of attempting it.
//!
//! Array expansion grows with every thread; a run that does not fit in 90 % of the memory
//! available now (or of `--mem-limit`) is skipped with the reason.

use crate::machine::topology::human_bytes;
use mpm_core::scenario::size::{ModelSize, IMPACT_MODELS};
use mpm_core::Strategy;
use mpm_spec::ScenarioKind;

/// The impact scenario's campaign models: `(particle spacing, cell size)` in metres of
/// model `m` (1-4, see [`IMPACT_MODELS`]).
pub fn impact_variant(m: u32) -> Option<(f64, f64)> {
    IMPACT_MODELS.get((m as usize).checked_sub(1)?).copied()
}

/// Size of `model` of `scenario` (`taylor`: Models 1-4 of Table 2; `impact`: the
/// [`impact_variant`]s, nodes of the adaptive grid around the debris cloud, an upper
/// estimate).
pub fn scenario_size(scenario: ScenarioKind, m: u32) -> Option<ModelSize> {
    if scenario == ScenarioKind::Impact {
        impact_variant(m).map(|(spacing, cell)| ModelSize::impact(spacing, cell))
    } else {
        ModelSize::taylor(u8::try_from(m).ok()?)
    }
}

/// Estimated peak memory of a run of `model` of `scenario`, bytes (the process baseline for
/// an unknown model).
pub fn estimate_memory(scenario: ScenarioKind, model: u32, strategy: Strategy, threads: usize) -> u64 {
    scenario_size(scenario, model).unwrap_or_default().memory_bytes(strategy, threads)
}

/// Memory of each extra MPI rank beyond its share of the model: the MPI library, its
/// buffers, a second copy of the program's code and heap set-up.
pub const RANK_OVERHEAD_BYTES: u64 = 64 << 20;

/// Estimated memory, summed over the ranks, of the run `spec` (`ranks` ranks of `threads`
/// threads each): the one-process model (split between the ranks, their overlaps small; no
/// rank gathers the particles, the figures are measured across the ranks) and
/// [`RANK_OVERHEAD_BYTES`] per extra rank.
pub fn estimate_run_memory(spec: &mpm_spec::RunSpec) -> u64 {
    let one = spec.scenario.size().memory_bytes(spec.strategy, spec.threads);
    one + (spec.ranks.max(1) as u64 - 1) * RANK_OVERHEAD_BYTES
}

pub use mpm_host::memory::available_memory;

/// Fraction of the available memory a run may use.
pub const MEMORY_HEADROOM: f64 = 0.9;

/// Why a run does not fit, or `None` when it does.
pub fn memory_verdict(estimate: u64, available: Option<u64>, limit: Option<u64>) -> Option<String> {
    let (cap, source) = match (available, limit) {
        (Some(a), Some(l)) if l < a => (l, "the --mem-limit"),
        (None, Some(l)) => (l, "the --mem-limit"),
        (Some(a), _) => (a, "memory available now"),
        (None, None) => return None,
    };
    let allowed = (cap as f64 * MEMORY_HEADROOM) as u64;
    (estimate > allowed).then(|| {
        format!(
            "memory guard: estimated {} exceeds {:.0}% of {} ({})",
            human_bytes(estimate),
            MEMORY_HEADROOM * 100.0,
            source,
            human_bytes(cap)
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_core::scenario::size::BYTES_PER_THREAD;

    #[test]
    fn memory_estimates_grow_with_ae_threads_only() {
        let ae1 = estimate_memory(ScenarioKind::Taylor, 4, Strategy::ArrayExpansion, 1);
        let ae8 = estimate_memory(ScenarioKind::Taylor, 4, Strategy::ArrayExpansion, 8);
        let dd1 = estimate_memory(ScenarioKind::Taylor, 4, Strategy::DomainDecomposition, 1);
        let dd8 = estimate_memory(ScenarioKind::Taylor, 4, Strategy::DomainDecomposition, 8);
        assert_eq!(ae8 - ae1, 7 * (108 * 8_302_185 + BYTES_PER_THREAD));
        assert_eq!(dd8 - dd1, 7 * BYTES_PER_THREAD);
        assert_eq!(scenario_size(ScenarioKind::Impact, 1).map(|s| s.particles), Some(847_888));
        assert_eq!(scenario_size(ScenarioKind::Taylor, 5), None);
        // The paper's 8 GB machine: Model 4 AE at 8 threads does not fit, DD does.
        assert!(memory_verdict(ae8, Some(8 << 30), None).is_some());
        assert!(memory_verdict(dd8, Some(8 << 30), None).is_none());
        assert!(memory_verdict(ae8, Some(64 << 30), Some(4 << 30)).is_some());
        assert!(memory_verdict(ae1, None, None).is_none());
    }
}
