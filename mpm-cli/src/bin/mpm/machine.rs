//! What the machine says about a run before anything is built ([`Plan::check`]: the CPU
//! list, the thread count against the cores and the cgroup's CPU quota, the memory
//! estimate against the memory the run may use where it runs), the CPUs of this rank's
//! workers ([`place_rank`]) and its pinned pool ([`start_pool`]).

use crate::ranks::Ranks;
use anyhow::{bail, Context, Result};
use mpm_host::cgroup::CpuQuota;
use mpm_host::human::human_bytes;
use mpm_host::memory::MemoryBudget;
use mpm_host::pinning::{self, PinnedPool};
use mpm_spec::RunSpec;

/// Worker threads per core beyond which a run is refused: more is not a measurement, and
/// `--threads 100000` would only bring the machine to its knees.
pub const MAX_THREADS_PER_CORE: usize = 16;

/// Steps beyond which a run is refused as one that would not end: the fastest models take
/// about a millisecond per step, so this many is more than a day; the paper's runs take
/// a few thousand.
pub const MAX_STEPS: u64 = 100_000_000;

/// Refuse a run expected to take more than [`MAX_STEPS`] steps with first time step
/// `dt_first` (s) (`force`: run anyway): an end time or a CFL number no run reaches.
pub fn check_progress(spec: &RunSpec, dt_first: f64, force: bool) -> Result<()> {
    let steps = spec.expected_steps(dt_first);
    if steps > MAX_STEPS && !force {
        let why = match spec.budget.end_time_s {
            Some(t) if spec.budget.steps.is_none_or(|n| n > MAX_STEPS) => {
                format!("the end time {t:e} s over the first time step {dt_first:e} s")
            }
            _ => "its --steps".to_string(),
        };
        bail!(
            "the run would take about {steps:.3e} steps ({why}), more than {MAX_STEPS:.0e}: at a millisecond per step \
             that is more than a day, a run that does not end. Give --steps N, a shorter --end-time, a larger --cfl \
             (the time step is CFL x cell / wave speed) or a lower --velocity, or --force to run anyway",
            steps = steps as f64
        );
    }
    Ok(())
}

/// What the machine says about the spec, checked before anything is built.
pub struct Plan {
    /// Cores available to this process.
    pub available_cores: usize,
    /// More workers than cores, or than distinct pinned CPUs.
    pub oversubscribed: bool,
    /// The CPU quota of this process's cgroup, CPUs of time per period (`None`: none).
    pub cpu_quota: Option<f64>,
}

impl Plan {
    /// Check the spec against this machine: the CPU list, a thread count not far beyond the
    /// cores, the memory estimate against the memory the run may use (unless `force`);
    /// warn (once) when the run is oversubscribed or its cgroup's CPU quota is below its
    /// thread count.
    pub fn check(spec: &RunSpec, force: bool) -> Result<Self> {
        let threads = spec.threads;
        if let Some(c) = &spec.cpus {
            pinning::validate_cpus(c, threads).context("invalid --cpus")?;
        }
        let available_cores = pinning::available_cores();
        let limit = MAX_THREADS_PER_CORE * available_cores.max(1);
        if threads > limit {
            bail!(
                "--threads {threads} is more than {MAX_THREADS_PER_CORE} per core of the {available_cores} core(s) \
                 here (at most {limit}): such a run measures nothing but time sharing; use at most {limit}"
            );
        }
        check_memory(spec, force)?;
        let distinct_cpus = spec.cpus.as_ref().map(|c| {
            let mut d = c.clone();
            d.sort_unstable();
            d.dedup();
            d.len()
        });
        let oversubscribed = threads > available_cores || distinct_cpus.is_some_and(|d| d < threads);
        if oversubscribed {
            warn_oversubscribed(threads, available_cores, distinct_cpus);
        }
        Ok(Self { available_cores, oversubscribed, cpu_quota: cpu_quota(threads) })
    }
}

/// The CPU quota of this process's cgroup as CPUs, warning when it is below `threads`
/// ([`quota_warning`]) or cannot be read.
fn cpu_quota(threads: usize) -> Option<f64> {
    match mpm_host::cgroup::cpu_quota() {
        Ok(Some(q)) => {
            if let Some(w) = quota_warning(&q, threads) {
                eprintln!("{w}");
            }
            Some(q.cpus())
        }
        Ok(None) => None,
        Err(e) => {
            eprintln!("warning: the CPU quota of this process's cgroup cannot be read ({e}); it is not recorded");
            None
        }
    }
}

/// The warning of a CPU quota `q` below `threads` worker threads (`None`: no warning).
fn quota_warning(q: &CpuQuota, threads: usize) -> Option<String> {
    (q.cpus() < threads as f64).then(|| {
        format!(
            "warning: CPU quota below the thread count: {q}, for {threads} worker thread(s); they share that time, so \
             timings of this run do not show parallel scaling (the summary records cpu_quota)"
        )
    })
}

/// Refuse a run whose estimated memory ([`RunSpec::process_memory_bytes`]: this process's
/// share of the model, both solvers of a paired run) exceeds what the run may use here
/// ([`mpm_host::memory::memory_budget`]: the least of the cgroup's headroom, the Slurm
/// job's memory and the host's available memory), before anything is allocated; `force`
/// tries anyway. A budget that cannot be known is a warning.
fn check_memory(spec: &RunSpec, force: bool) -> Result<()> {
    let budget = match mpm_host::memory::memory_budget() {
        Ok(b) => b,
        Err(e) => {
            eprintln!("warning: the memory this run may use cannot be known ({e}); it is not checked against it");
            return Ok(());
        }
    };
    match memory_refusal(spec, &budget) {
        Some(why) if !force => bail!(why),
        _ => Ok(()),
    }
}

/// Why `spec` does not fit in `budget`, naming the bound that binds (`None`: it fits).
fn memory_refusal(spec: &RunSpec, budget: &MemoryBudget) -> Option<String> {
    let estimate = spec.process_memory_bytes();
    let bound = budget.bound();
    (estimate > bound.bytes).then(|| {
        let mut what = format!("{}, {} with {} thread(s)", spec.scenario.describe(), spec.strategy, spec.threads);
        if spec.paired.is_some() {
            what += " and its 1-thread reference (a paired run builds both)";
        }
        if spec.ranks > 1 {
            what += &format!(", per rank of {}", spec.ranks);
        }
        format!(
            "the run needs about {} ({what}) but {bound}: use a smaller model (e.g. a coarser --spacing or larger \
             --cell), fewer threads with ae, or --force to try anyway",
            human_bytes(estimate)
        )
    })
}

/// The oversubscription warning: timings of this run do not show parallel scaling.
fn warn_oversubscribed(threads: usize, available_cores: usize, distinct_cpus: Option<usize>) {
    match distinct_cpus {
        Some(d) if d < threads && threads <= available_cores => eprintln!(
            "warning: oversubscribed: {threads} threads on {d} pinned CPU(s); timings of this run do not show parallel scaling"
        ),
        _ => eprintln!(
            "warning: oversubscribed: {threads} threads on {available_cores} cores; timings of this run do not show parallel scaling"
        ),
    }
}

/// The CPUs of this process's workers: the spec's, or with several ranks and none given,
/// a slice of the CPUs the launcher gave this rank ([`Ranks::rank_cpus`]); and whether ranks
/// share CPUs (flagged).
pub fn place_rank(spec: &RunSpec, plan: &mut Plan, ranks: &Ranks) -> Result<(Option<Vec<usize>>, bool)> {
    if ranks.size() == 1 || spec.cpus.is_some() {
        return Ok((spec.cpus.clone(), false));
    }
    let (cpus, shared) = ranks.rank_cpus(spec.threads)?;
    if shared {
        eprintln!(
            "warning: oversubscribed: rank {} shares CPUs {cpus:?} with other ranks; timings of this run do not show parallel scaling",
            ranks.rank()
        );
        plan.oversubscribed = true;
    }
    Ok((Some(cpus), shared))
}

/// The pool of the run, pinned as planned; a worker not where it was asked to be is a
/// warning (and the summary says `pinning_verified = false`).
pub fn start_pool(threads: usize, cpus: Option<&[usize]>) -> Result<PinnedPool> {
    let pool = pinning::build_pool(threads, cpus)?;
    let mismatches = pool.mismatches();
    if !mismatches.is_empty() {
        eprintln!(
            "warning: pinning not as requested (the run is marked pinning_verified = false): {}",
            mismatches.join("; ")
        );
    }
    Ok(pool)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_host::cgroup::{CgroupMemory, CgroupVersion};
    use mpm_host::memory::{MemoryLimit, MemorySource};
    use mpm_spec::scenario::TaylorSpec;
    use mpm_spec::spec::Paired;

    const GIB: u64 = 1 << 30;

    /// A budget of the host's `host` bytes, under a cgroup allowing `cgroup` more.
    fn budget(cgroup: u64, host: u64) -> MemoryBudget {
        let c =
            CgroupMemory { cgroup: "/slurm/uid_0/job_7".into(), version: CgroupVersion::V2, limit: cgroup, in_use: 0 };
        MemoryBudget {
            limits: vec![
                MemoryLimit { bytes: cgroup, source: MemorySource::Cgroup(c) },
                MemoryLimit { bytes: host, source: MemorySource::Host },
            ],
        }
    }

    /// The refusal names the bound that binds, the cgroup's or the host's, and says what to
    /// change; a paired run counts its reference solver and says so.
    #[test]
    fn the_refusal_names_the_bound() {
        let mut spec = RunSpec::new(mpm_spec::Scenario::Taylor(TaylorSpec::model(3))).unwrap();
        let need = spec.process_memory_bytes();
        assert!(need > GIB / 4 && need < GIB, "{need}");
        let why = memory_refusal(&spec, &budget(GIB / 4, 64 * GIB)).unwrap();
        assert!(why.contains("but the cgroup /slurm/uid_0/job_7 allows 256 MiB more"), "{why}");
        assert!(why.contains("--force") && why.contains("Taylor bar Model 3"), "{why}");
        let why = memory_refusal(&spec, &budget(64 * GIB, GIB / 4)).unwrap();
        assert!(why.contains("but the host has 256 MiB available (MemAvailable)"), "{why}");
        assert_eq!(memory_refusal(&spec, &budget(GIB, 64 * GIB)), None);
        spec.strategy = mpm_core::Strategy::DomainDecomposition;
        spec.threads = 2;
        let alone = spec.process_memory_bytes();
        spec.paired = Some(Paired { blocks: 2 });
        let paired = spec.process_memory_bytes();
        assert!(paired > alone + alone / 2, "both solvers: {paired} against {alone}");
        let why = memory_refusal(&spec, &budget(paired - 1, 64 * GIB)).unwrap();
        assert!(why.contains("its 1-thread reference"), "{why}");
    }

    /// A quota below the thread count is a warning naming it; at or above, none.
    #[test]
    fn a_quota_below_the_threads_is_named() {
        let q = CpuQuota {
            cgroup: "/docker/abc".into(),
            version: CgroupVersion::V1,
            quota_us: 150_000,
            period_us: 100_000,
        };
        let w = quota_warning(&q, 2).unwrap();
        assert!(w.contains("the cgroup /docker/abc allows 1.5 CPUs") && w.contains("2 worker thread(s)"), "{w}");
        assert_eq!(quota_warning(&q, 1), None);
    }
}
