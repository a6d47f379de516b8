//! Building the rayon pool of one run, with worker `j` pinned to CPU `cpus[j]`, and
//! verifying where the workers really are.
//!
//! The solver library never pins: `mpm` and the harness build the pool here and hand it to
//! the simulation ([`mpm_core::Simulation::step`]). Pinning happens inside each worker, in
//! [`rayon::ThreadPoolBuilder::start_handler`], before the worker takes any job. After the
//! pool is built, one [`rayon::ThreadPool::broadcast`] asks every worker for its actual
//! affinity mask (`sched_getaffinity`) and the CPU it runs on (`sched_getcpu`), so a
//! run records what it got, not what it asked for.
//!
//! CPU lists use the Linux/`taskset` syntax: comma-separated CPU numbers and inclusive
//! ranges, e.g. `0,1` or `0-3,6` (strides such as `0-7:2` are not supported).

use rayon::{ThreadPool, ThreadPoolBuildError, ThreadPoolBuilder};
use serde::{Deserialize, Serialize};
use std::sync::{Arc, Mutex};

/// Why a CPU list, a pinning or a pool was refused.
#[derive(Debug, thiserror::Error)]
pub enum PinError {
    /// An empty CPU list.
    #[error("empty CPU list: give CPU numbers like '0,1' or ranges like '0-3,6'")]
    EmptyList,
    /// A CPU list with an empty item (`0,,1`).
    #[error("CPU list '{list}' has an empty item: give CPU numbers like '0,1' or ranges like '0-3,6'")]
    EmptyItem {
        /// The list.
        list: String,
    },
    /// An item that is not a number (a negative one included: CPUs are numbered from 0).
    #[error(
        "'{item}' in CPU list '{list}' is not a CPU number: CPUs are numbered from 0 (use numbers like '0,1' or ranges \
         like '0-3,6')"
    )]
    NotANumber {
        /// The item.
        item: String,
        /// The list.
        list: String,
    },
    /// A range whose end is below its start.
    #[error("range '{item}' in CPU list '{list}' runs backwards: write it as '{end}-{start}'")]
    Backwards {
        /// The range.
        item: String,
        /// The list.
        list: String,
        /// Its first number.
        start: usize,
        /// Its last number.
        end: usize,
    },
    /// A range of more than 4096 CPUs.
    #[error("range '{item}' in CPU list '{list}' is too long (more than 4096 CPUs)")]
    TooLong {
        /// The range.
        item: String,
        /// The list.
        list: String,
    },
    /// Not one CPU per worker.
    #[error(
        "--cpus lists {} CPU(s) ({}) but the run has {threads} thread(s): give exactly one CPU per worker thread",
        .cpus.len(),
        .cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(",")
    )]
    Count {
        /// The CPUs listed.
        cpus: Vec<usize>,
        /// The worker threads.
        threads: usize,
    },
    /// A CPU the machine does not have.
    #[error(
        "CPU {cpu} does not exist on this machine: it has {configured} CPU(s), numbered 0-{} (usable by this process: {})",
        .configured - 1,
        format_cpu_list(.usable)
    )]
    Missing {
        /// The CPU.
        cpu: usize,
        /// CPUs configured on the machine.
        configured: usize,
        /// CPUs this process may run on.
        usable: Vec<usize>,
    },
    /// A CPU outside this process's affinity mask.
    #[error(
        "CPU {cpu} exists but this process may not run on it (its affinity mask allows {}): pick CPUs from that list",
        format_cpu_list(.usable)
    )]
    NotAllowed {
        /// The CPU.
        cpu: usize,
        /// CPUs this process may run on.
        usable: Vec<usize>,
    },
    /// The kernel did not say a thread's affinity mask.
    #[error("sched_getaffinity failed")]
    Affinity(#[source] std::io::Error),
    /// A pool of no threads.
    #[error("the pool needs at least 1 thread")]
    NoThreads,
    /// rayon could not start the workers.
    #[error("could not start a pool of {threads} worker thread(s)")]
    Pool {
        /// The worker threads asked for.
        threads: usize,
        /// rayon's error.
        source: ThreadPoolBuildError,
    },
    /// Workers that could not pin themselves (one line each).
    #[error("pinning failed: {}", .0.join("; "))]
    Pinning(Vec<String>),
    /// A worker that could not read its placement back.
    #[error("worker {worker}: reading its placement")]
    Placement {
        /// The worker.
        worker: usize,
        /// Why.
        source: Box<PinError>,
    },
}

/// Parse a CPU list such as `0,1`, `3` or `0-3,6` into CPU numbers, in the given order
/// (ranges expand upwards). Whitespace around items is ignored. Duplicates are kept: two
/// workers on one CPU is legal, if rarely wise.
pub fn parse_cpu_list(s: &str) -> Result<Vec<usize>, PinError> {
    let s = s.trim();
    if s.is_empty() {
        return Err(PinError::EmptyList);
    }
    let mut out = Vec::new();
    for item in s.split(',') {
        let item = item.trim();
        if item.is_empty() {
            return Err(PinError::EmptyItem { list: s.into() });
        }
        let not_a_number = || PinError::NotANumber { item: item.into(), list: s.into() };
        let num = |t: &str| t.trim().parse::<usize>().map_err(|_| not_a_number());
        if item.starts_with('-') {
            // `-1` is not a range with no start: a negative number.
            return Err(not_a_number());
        }
        match item.split_once('-') {
            Some((a, b)) => {
                let (a, b) = (num(a)?, num(b)?);
                let range = || (item.to_string(), s.to_string());
                if a > b {
                    let (item, list) = range();
                    return Err(PinError::Backwards { item, list, start: a, end: b });
                }
                if b - a > 4096 {
                    let (item, list) = range();
                    return Err(PinError::TooLong { item, list });
                }
                out.extend(a..=b);
            }
            None => out.push(num(item)?),
        }
    }
    Ok(out)
}

/// Format CPU numbers compactly, e.g. `[0, 1, 2, 3, 6]` -> `0-3,6` (sorted, deduplicated).
pub fn format_cpu_list(cpus: &[usize]) -> String {
    let mut v = cpus.to_vec();
    v.sort_unstable();
    v.dedup();
    let mut parts = Vec::new();
    let mut i = 0;
    while i < v.len() {
        let mut j = i;
        while j + 1 < v.len() && v[j + 1] == v[j] + 1 {
            j += 1;
        }
        parts.push(if j > i { format!("{}-{}", v[i], v[j]) } else { v[i].to_string() });
        i = j + 1;
    }
    parts.join(",")
}

/// CPUs configured on the machine (`sysconf(_SC_NPROCESSORS_CONF)`); CPU numbers run from
/// 0 to this minus one.
pub fn configured_cpus() -> usize {
    // SAFETY: sysconf only reads a system constant; it has no memory-safety preconditions.
    let n = unsafe { libc::sysconf(libc::_SC_NPROCESSORS_CONF) };
    if n > 0 {
        n as usize
    } else {
        usable_cpus().map_or(1, |v| v.iter().max().map_or(1, |m| m + 1))
    }
}

/// The affinity mask of the calling thread as a sorted CPU list.
pub fn current_affinity() -> Result<Vec<usize>, PinError> {
    // SAFETY: cpu_set_t is a plain bit array for which all-zero is a valid (empty) value.
    let mut set: libc::cpu_set_t = unsafe { std::mem::zeroed() };
    // SAFETY: `set` is a valid, writable cpu_set_t and we pass its exact size; pid 0 means
    // the calling thread.
    let rc = unsafe { libc::sched_getaffinity(0, std::mem::size_of::<libc::cpu_set_t>(), &mut set) };
    if rc != 0 {
        return Err(PinError::Affinity(std::io::Error::last_os_error()));
    }
    let max = 8 * std::mem::size_of::<libc::cpu_set_t>();
    // SAFETY: CPU_ISSET only reads `set`, and every index is below CPU_SETSIZE.
    Ok((0..max).filter(|&c| unsafe { libc::CPU_ISSET(c, &set) }).collect())
}

/// The CPU the calling thread runs on now (`sched_getcpu`), if the kernel says.
pub fn current_cpu() -> Option<usize> {
    // SAFETY: sched_getcpu takes no arguments and only returns a number.
    let c = unsafe { libc::sched_getcpu() };
    (c >= 0).then_some(c as usize)
}

/// CPUs this process may run on: the affinity mask of the calling thread (the main thread
/// before any pinning, i.e. what `taskset` or the container allows).
pub fn usable_cpus() -> Result<Vec<usize>, PinError> {
    current_affinity()
}

/// Cores available to this process: [`std::thread::available_parallelism`] (affinity mask
/// and cgroup CPU quota).
pub fn available_cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

/// Check a requested CPU list against the thread count and the machine: one CPU per
/// worker, every CPU present and usable by this process.
pub fn validate_cpus(cpus: &[usize], threads: usize) -> Result<(), PinError> {
    if cpus.len() != threads {
        return Err(PinError::Count { cpus: cpus.to_vec(), threads });
    }
    let configured = configured_cpus();
    let usable = usable_cpus()?;
    for &cpu in cpus {
        if cpu >= configured {
            return Err(PinError::Missing { cpu, configured, usable });
        }
        if !usable.contains(&cpu) {
            return Err(PinError::NotAllowed { cpu, usable });
        }
    }
    Ok(())
}

/// Where one worker of the pool really is, read back by the worker itself.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct WorkerPlacement {
    /// Worker index `j` (rayon's thread index).
    pub worker: usize,
    /// The CPU it was asked to run on (`None` when not pinned).
    pub requested: Option<usize>,
    /// Its affinity mask after pinning.
    pub affinity: Vec<usize>,
    /// The CPU it was running on when asked (`sched_getcpu`).
    pub cpu: Option<usize>,
}

/// The pool of one run and what its workers report about their placement.
#[derive(Debug)]
pub struct PinnedPool {
    /// The pool, with exactly the requested number of workers (shared with the simulation
    /// that runs on it).
    pub pool: Arc<ThreadPool>,
    /// The requested CPU list (empty when not pinned).
    pub requested: Vec<usize>,
    /// One entry per worker, in worker order.
    pub workers: Vec<WorkerPlacement>,
}

impl PinnedPool {
    /// Whether workers were pinned.
    pub fn pinned(&self) -> bool {
        !self.requested.is_empty()
    }

    /// The CPU each worker was observed on, in worker order; empty when not pinned (an
    /// unpinned worker's CPU says nothing about where it will run).
    pub fn observed_cpus(&self) -> Vec<usize> {
        if !self.pinned() {
            return Vec::new();
        }
        self.workers.iter().map(|w| w.cpu.unwrap_or(usize::MAX)).collect()
    }

    /// Each worker's affinity mask, in worker order.
    pub fn affinities(&self) -> Vec<Vec<usize>> {
        self.workers.iter().map(|w| w.affinity.clone()).collect()
    }

    /// For a pinned pool: whether every worker's mask is exactly `{cpus[j]}` and it runs
    /// there. `None` when not pinned.
    pub fn verified(&self) -> Option<bool> {
        self.pinned()
            .then(|| self.workers.iter().all(|w| w.requested.is_some_and(|r| w.affinity == [r] && w.cpu == Some(r))))
    }

    /// Human-readable mismatches of a pinned pool (empty when all is well).
    pub fn mismatches(&self) -> Vec<String> {
        self.workers
            .iter()
            .filter_map(|w| {
                let r = w.requested?;
                (w.affinity != [r] || w.cpu != Some(r)).then(|| {
                    format!(
                        "worker {} asked for CPU {r} but has affinity {{{}}} and runs on {}",
                        w.worker,
                        format_cpu_list(&w.affinity),
                        w.cpu.map_or("an unknown CPU".into(), |c| format!("CPU {c}"))
                    )
                })
            })
            .collect()
    }
}

/// Build a pool of `threads` workers named `mpm-worker-j`; with `cpus`, worker `j` pins
/// itself to `cpus[j]` when it starts. Validates `cpus` first ([`validate_cpus`]) and fails
/// if any worker could not pin itself. Then reads back every worker's placement.
pub fn build_pool(threads: usize, cpus: Option<&[usize]>) -> Result<PinnedPool, PinError> {
    if threads == 0 {
        return Err(PinError::NoThreads);
    }
    if let Some(c) = cpus {
        validate_cpus(c, threads)?;
    }
    let requested: Vec<usize> = cpus.map(<[usize]>::to_vec).unwrap_or_default();
    let failures: Arc<Mutex<Vec<String>>> = Arc::default();
    let mut builder = ThreadPoolBuilder::new().num_threads(threads).thread_name(|j| format!("mpm-worker-{j}"));
    if !requested.is_empty() {
        let plan = Arc::new(requested.clone());
        let fails = Arc::clone(&failures);
        builder = builder.start_handler(move |j| {
            let cpu = plan[j];
            if !core_affinity::set_for_current(core_affinity::CoreId { id: cpu }) {
                let err = std::io::Error::last_os_error();
                fails
                    .lock()
                    .unwrap_or_else(|e| e.into_inner())
                    .push(format!("worker {j} could not pin itself to CPU {cpu}: {err}"));
            }
        });
    }
    let pool = builder.build().map_err(|source| PinError::Pool { threads, source })?;
    // Every worker has run its start handler before it takes the broadcast job.
    let placements = pool.broadcast(|_| Ok::<_, PinError>((current_affinity()?, current_cpu())));
    let failures = std::mem::take(&mut *failures.lock().unwrap_or_else(|e| e.into_inner()));
    if !failures.is_empty() {
        return Err(PinError::Pinning(failures));
    }
    let workers = placements
        .into_iter()
        .enumerate()
        .map(|(j, r)| {
            let (affinity, cpu) = r.map_err(|e| PinError::Placement { worker: j, source: Box::new(e) })?;
            Ok(WorkerPlacement { worker: j, requested: requested.get(j).copied(), affinity, cpu })
        })
        .collect::<Result<Vec<_>, PinError>>()?;
    Ok(PinnedPool { pool: Arc::new(pool), requested, workers })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_single_numbers_lists_and_ranges() {
        assert_eq!(parse_cpu_list("0").unwrap(), vec![0]);
        assert_eq!(parse_cpu_list("0,1").unwrap(), vec![0, 1]);
        assert_eq!(parse_cpu_list("1,0").unwrap(), vec![1, 0]);
        assert_eq!(parse_cpu_list("0-3,6").unwrap(), vec![0, 1, 2, 3, 6]);
        assert_eq!(parse_cpu_list(" 2 - 4 , 8 ").unwrap(), vec![2, 3, 4, 8]);
        assert_eq!(parse_cpu_list("5-5").unwrap(), vec![5]);
        assert_eq!(parse_cpu_list("0,0").unwrap(), vec![0, 0]);
    }

    #[test]
    fn rejects_malformed_lists_with_a_message() {
        for (bad, says) in [
            ("", "empty CPU list"),
            ("  ", "empty CPU list"),
            ("0,,1", "empty item"),
            ("0,", "empty item"),
            ("a", "not a CPU number"),
            ("-1", "'-1' in CPU list '-1' is not a CPU number: CPUs are numbered from 0"),
            ("-1,0", "'-1' in CPU list '-1,0'"),
            ("1-", "not a CPU number"),
            ("3-1", "runs backwards"),
            ("0-3:2", "not a CPU number"),
        ] {
            let e = parse_cpu_list(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad:?}: {e}");
        }
    }

    #[test]
    fn formats_compactly() {
        assert_eq!(format_cpu_list(&[0, 1, 2, 3, 6]), "0-3,6");
        assert_eq!(format_cpu_list(&[3, 1, 2, 9, 8, 1]), "1-3,8-9");
        assert_eq!(format_cpu_list(&[]), "");
        assert_eq!(format_cpu_list(&[4]), "4");
    }

    #[test]
    fn validation_checks_length_and_existence() {
        let e = validate_cpus(&[0], 2).unwrap_err().to_string();
        assert!(e.contains("one CPU per worker"), "{e}");
        let e = validate_cpus(&[0, 100_000], 2).unwrap_err().to_string();
        assert!(e.contains("CPU 100000 does not exist"), "{e}");
        let first = usable_cpus().unwrap()[0];
        validate_cpus(&[first], 1).unwrap();
    }

    #[test]
    fn pinned_pool_reports_its_workers_on_their_cpus() {
        let cpu = usable_cpus().unwrap()[0];
        let p = build_pool(1, Some(&[cpu])).unwrap();
        assert_eq!(p.workers.len(), 1);
        assert_eq!(p.observed_cpus(), vec![cpu]);
        assert_eq!(p.affinities(), vec![vec![cpu]]);
        assert_eq!(p.verified(), Some(true));
        assert!(p.mismatches().is_empty());
        let free = build_pool(2, None).unwrap();
        assert_eq!(free.pool.current_num_threads(), 2);
        assert!(free.observed_cpus().is_empty());
        assert_eq!(free.verified(), None);
    }
}
