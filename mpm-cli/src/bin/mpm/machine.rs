//! What the machine says about a run before anything is built ([`Plan::check`]: the CPU
//! list, the thread count against the cores, the memory estimate against the memory
//! available), the CPUs of this rank's workers ([`place_rank`]) and its pinned pool
//! ([`start_pool`]).

use crate::ranks::Ranks;
use anyhow::{bail, Context, Result};
use mpm_host::pinning::{self, PinnedPool};
use mpm_spec::RunSpec;

/// Worker threads per core beyond which a run is refused: more is not a measurement, and
/// `--threads 100000` would only bring the machine to its knees.
pub const MAX_THREADS_PER_CORE: usize = 16;

/// Memory of an MPI rank besides its share of the model: the MPI library, its buffers.
const RANK_OVERHEAD_BYTES: u64 = 64 << 20;

/// What the machine says about the spec, checked before anything is built.
pub struct Plan {
    /// Cores available to this process.
    pub available_cores: usize,
    /// More workers than cores, or than distinct pinned CPUs.
    pub oversubscribed: bool,
}

impl Plan {
    /// Check the spec against this machine: the CPU list, a thread count not far beyond the
    /// cores, the memory estimate against the memory available (unless `force`); warn (once)
    /// when the run is oversubscribed.
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
        Ok(Self { available_cores, oversubscribed })
    }
}

/// Refuse a run whose estimated memory (per rank: its share of the model plus the MPI
/// process's own) exceeds the memory available now, before anything is allocated; `force`
/// tries anyway.
fn check_memory(spec: &RunSpec, force: bool) -> Result<()> {
    let whole = spec.scenario.size().memory_bytes(spec.strategy, spec.threads);
    let estimate = if spec.ranks > 1 { whole / spec.ranks as u64 + RANK_OVERHEAD_BYTES } else { whole };
    let Some(available) = mpm_host::memory::available_memory() else { return Ok(()) };
    if estimate > available && !force {
        bail!(
            "the run needs about {} ({}, {} with {} thread(s){}) but {} is available: use a smaller model \
             (e.g. a coarser --spacing or larger --cell), fewer threads with ae, or --force to try anyway",
            mpm_host::human::human_bytes(estimate),
            spec.scenario.describe(),
            spec.strategy,
            spec.threads,
            if spec.ranks > 1 { format!(", per rank of {}", spec.ranks) } else { String::new() },
            mpm_host::human::human_bytes(available)
        );
    }
    Ok(())
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
