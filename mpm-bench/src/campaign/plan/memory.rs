//! The memory guard: every run's memory estimated before it starts (model sizes and the
//! memory model come from [`mpm_core::scenario::size`]), the memory available now, and the
//! verdict that records a run that would not fit as `skipped` instead of attempting it.
//!
//! Array expansion grows with every thread, and a paired run holds two solvers (both
//! counted: [`mpm_spec::RunSpec::process_memory_bytes`]); a run that does not fit in 90 % of
//! the memory it may use here now ([`mpm_host::memory::memory_budget`]: the least of this
//! process's cgroup headroom, its Slurm job's memory and the host's available memory) or of
//! `--mem-limit` is skipped with the reason, naming the bound.

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

/// Estimated memory, summed over the ranks (all on this node), of the run `spec`: each
/// process's [`mpm_spec::RunSpec::process_memory_bytes`] (its share of the model, the MPI
/// library with several ranks, and the one-thread reference solver of a paired run).
pub fn estimate_run_memory(spec: &mpm_spec::RunSpec) -> u64 {
    spec.process_memory_bytes().saturating_mul(spec.ranks.max(1) as u64)
}

pub use mpm_host::memory::MemoryLimit;

/// The bound on the memory a run may use here now: the least of
/// [`mpm_host::memory::memory_budget`]'s; `None` when it cannot be known.
pub fn memory_here() -> Option<MemoryLimit> {
    mpm_host::memory::memory_budget().ok().map(|b| b.bound().clone())
}

/// Fraction of the available memory a run may use.
pub const MEMORY_HEADROOM: f64 = 0.9;

/// Why a run of `estimate` bytes does not fit under the bound `here` ([`memory_here`]) or
/// the `--mem-limit` `limit`, the lesser of them, or `None` when it does.
pub fn memory_verdict(estimate: u64, here: Option<&MemoryLimit>, limit: Option<u64>) -> Option<String> {
    let (cap, source) = match (here, limit) {
        (Some(h), Some(l)) if l < h.bytes => (l, "the --mem-limit".to_string()),
        (None, Some(l)) => (l, "the --mem-limit".to_string()),
        (Some(h), _) => (h.bytes, format!("the memory it may use here: {h}")),
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
    use crate::campaign::plan::matrix::PlannedRun;
    use mpm_core::scenario::size::BYTES_PER_THREAD;
    use mpm_host::memory::MemorySource;

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
        let host = |bytes| MemoryLimit { bytes, source: MemorySource::Host };
        assert!(memory_verdict(ae8, Some(&host(8 << 30)), None).is_some());
        assert!(memory_verdict(dd8, Some(&host(8 << 30)), None).is_none());
        assert!(memory_verdict(ae8, Some(&host(64 << 30)), Some(4 << 30)).is_some());
        assert!(memory_verdict(ae1, None, None).is_none());
    }

    /// A paired run's estimate counts both solvers (the spec's own estimate of a process),
    /// a run over ranks every rank's share and MPI library; the verdict names the bound
    /// that binds (here a Slurm job's memory).
    #[test]
    fn paired_runs_count_both_solvers_and_the_verdict_names_the_bound() {
        let mut run = PlannedRun::taylor(3, Strategy::ArrayExpansion, mpm_spec::OptLevel::O3, 4, 10);
        let alone = estimate_run_memory(&run.spec);
        run.spec.paired = Some(mpm_spec::spec::Paired { blocks: 4 });
        let paired = estimate_run_memory(&run.spec);
        assert_eq!(paired, run.spec.process_memory_bytes());
        let reference = estimate_memory(ScenarioKind::Taylor, 3, Strategy::ArrayExpansion, 1);
        assert!(paired > alone + reference / 2, "{paired} against {alone} and a reference of {reference}");
        run.spec.paired = None;
        run.spec.ranks = 2;
        assert_eq!(estimate_run_memory(&run.spec), 2 * run.spec.process_memory_bytes());
        let job = MemoryLimit {
            bytes: paired,
            source: MemorySource::Slurm { job: "42".into(), from: "SLURM_MEM_PER_NODE=1".into() },
        };
        let why = memory_verdict(paired, Some(&job), None).unwrap();
        assert!(why.contains("may use here: the Slurm job 42 has"), "{why}");
        assert!(memory_verdict(paired, Some(&job), Some(paired / 2)).unwrap().contains("--mem-limit"));
    }
}
