//! The memory a run may use where it runs, for the checks made before it allocates: the
//! least of what this process's cgroups let it take ([`crate::cgroup::memory_limit`]: the
//! headroom under the tightest limit of its cgroup and their ancestors, v1 or v2), what the
//! Slurm job it runs in was allocated, and what the host has available (`MemAvailable`),
//! with the one that binds, for the message that refuses a run. (Bytes for people:
//! [`crate::human::human_bytes`].)
//!
//! The Slurm job's memory is its allocation (`SLURM_MEM_PER_NODE`, or `SLURM_MEM_PER_CPU`
//! times `SLURM_CPUS_ON_NODE`, in MiB as Slurm writes them), read when `SLURM_JOB_ID` says
//! the process is in a job; 0 (the whole node's memory) sets no bound. What the job already
//! uses is not in the variables: where Slurm confines the job in a cgroup, that cgroup's
//! headroom tells it.

use std::path::Path;

use crate::cgroup::{memory_limit, CgroupMemory};
use crate::hostfile::{HostFileError, Root};
use crate::human::human_bytes;

/// What sets a bound on a run's memory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum MemorySource {
    /// A cgroup of this process: its headroom.
    Cgroup(CgroupMemory),
    /// The Slurm job: its allocation on this node.
    Slurm {
        /// The job id.
        job: String,
        /// The variables it comes from, as set (`SLURM_MEM_PER_NODE=4096`).
        from: String,
    },
    /// The host's `MemAvailable`.
    Host,
}

/// One bound on a run's memory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MemoryLimit {
    /// Bytes a run may use under it.
    pub bytes: u64,
    /// What sets it.
    pub source: MemorySource,
}

impl std::fmt::Display for MemoryLimit {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match &self.source {
            MemorySource::Cgroup(c) => write!(f, "{c}"),
            MemorySource::Slurm { job, from } => {
                write!(f, "the Slurm job {job} has {} ({from})", human_bytes(self.bytes))
            }
            MemorySource::Host => write!(f, "the host has {} available (MemAvailable)", human_bytes(self.bytes)),
        }
    }
}

/// The bounds on a run's memory here; the least binds.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MemoryBudget {
    /// Every bound found: the cgroup's and the Slurm job's where there are, the host's
    /// always, in that order.
    pub limits: Vec<MemoryLimit>,
}

impl MemoryBudget {
    /// The bound that binds: the least (of equal ones, the first).
    pub fn bound(&self) -> &MemoryLimit {
        let mut least = &self.limits[0];
        for l in &self.limits[1..] {
            if l.bytes < least.bytes {
                least = l;
            }
        }
        least
    }

    /// The memory a run may use, bytes: the least bound.
    pub fn bytes(&self) -> u64 {
        self.bound().bytes
    }
}

/// Why the memory a run may use is not known.
#[derive(Debug, thiserror::Error)]
pub enum MemoryError {
    /// A file of `/proc` or `/sys`.
    #[error(transparent)]
    Host(#[from] HostFileError),
    /// A Slurm variable that is not a number.
    #[error(
        "the Slurm variable {name} is {value:?}, not a whole number{}; this job's memory cannot be known: \
         check the job's --mem or --mem-per-cpu",
        if *.name == "SLURM_CPUS_ON_NODE" { "" } else { " of MiB" }
    )]
    Slurm {
        /// The variable.
        name: &'static str,
        /// Its value (empty when unset).
        value: String,
    },
}

/// The memory the Slurm job of this process was allocated on this node, bytes, with the
/// variables it comes from; `None` outside a job or where the job has the whole node.
fn slurm_memory(env: &dyn Fn(&str) -> Option<String>) -> Result<Option<MemoryLimit>, MemoryError> {
    let Some(job) = env("SLURM_JOB_ID") else { return Ok(None) };
    let number =
        |name: &'static str, value: String| value.trim().parse::<u64>().map_err(|_| MemoryError::Slurm { name, value });
    let (mib, from) = if let Some(v) = env("SLURM_MEM_PER_NODE") {
        (number("SLURM_MEM_PER_NODE", v.clone())?, format!("SLURM_MEM_PER_NODE={}", v.trim()))
    } else if let Some(v) = env("SLURM_MEM_PER_CPU") {
        let per_cpu = number("SLURM_MEM_PER_CPU", v.clone())?;
        let cpus = env("SLURM_CPUS_ON_NODE").unwrap_or_default();
        let n = number("SLURM_CPUS_ON_NODE", cpus.clone())?;
        (per_cpu.saturating_mul(n), format!("SLURM_MEM_PER_CPU={} x SLURM_CPUS_ON_NODE={}", v.trim(), cpus.trim()))
    } else {
        return Ok(None);
    };
    let source = MemorySource::Slurm { job, from };
    Ok((mib > 0).then(|| MemoryLimit { bytes: mib.saturating_mul(1 << 20), source }))
}

/// `MemAvailable` of `/proc/meminfo` under `root`, bytes.
fn host_available(root: Root<'_>) -> Result<u64, HostFileError> {
    let kib = root.parse_required("/proc/meminfo", "a MemAvailable line in kB", |text| {
        let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
        line.split_whitespace().nth(1)?.parse::<u64>().ok()
    })?;
    Ok(kib.saturating_mul(1024))
}

/// The memory budget read under `root` (`/`, or a fixture tree) with the environment
/// `env`.
pub fn memory_budget_at(root: &Path, env: &dyn Fn(&str) -> Option<String>) -> Result<MemoryBudget, MemoryError> {
    let root = Root::at(root);
    let mut limits = Vec::new();
    if let Some(c) = memory_limit(root)? {
        limits.push(MemoryLimit { bytes: c.headroom(), source: MemorySource::Cgroup(c) });
    }
    limits.extend(slurm_memory(env)?);
    limits.push(MemoryLimit { bytes: host_available(root)?, source: MemorySource::Host });
    Ok(MemoryBudget { limits })
}

/// The memory a run may use here now: [`memory_budget_at`] `/` with this process's
/// environment.
pub fn memory_budget() -> Result<MemoryBudget, MemoryError> {
    memory_budget_at(Path::new("/"), &|name| std::env::var(name).ok())
}

/// The bytes of [`memory_budget`]; `None` when it is not known (the error is dropped:
/// callers that report why use [`memory_budget`]).
pub fn available_memory() -> Option<u64> {
    memory_budget().ok().map(|b| b.bytes())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::cgroup::tests::v2_tree;
    use std::collections::HashMap;

    const GIB: u64 = 1 << 30;

    #[test]
    fn this_machine_has_memory_available() {
        assert!(available_memory().is_some_and(|m| m > 0));
        let budget = memory_budget().unwrap();
        assert!(matches!(budget.limits.last(), Some(MemoryLimit { source: MemorySource::Host, .. })));
    }

    /// An environment of `vars`.
    fn env(vars: &[(&str, &str)]) -> impl Fn(&str) -> Option<String> {
        let vars: HashMap<String, String> = vars.iter().map(|(k, v)| (k.to_string(), v.to_string())).collect();
        move |name| vars.get(name).cloned()
    }

    /// The Slurm job's memory: per node, or per CPU times the CPUs on the node, in MiB;
    /// none outside a job or for a job with the whole node; a value not a number is an
    /// error naming the variable.
    #[test]
    fn slurm_variables() {
        let job = |vars: &[(&str, &str)]| {
            let mut all = vec![("SLURM_JOB_ID", "42")];
            all.extend_from_slice(vars);
            slurm_memory(&env(&all))
        };
        let l = job(&[("SLURM_MEM_PER_NODE", "4096")]).unwrap().unwrap();
        assert_eq!(l.bytes, 4 * GIB);
        assert_eq!(l.to_string(), "the Slurm job 42 has 4 GiB (SLURM_MEM_PER_NODE=4096)");
        let l = job(&[("SLURM_MEM_PER_CPU", "1536"), ("SLURM_CPUS_ON_NODE", "2")]).unwrap().unwrap();
        assert_eq!(l.bytes, 3 * GIB);
        assert!(l.to_string().contains("SLURM_MEM_PER_CPU=1536 x SLURM_CPUS_ON_NODE=2"), "{l}");
        assert_eq!(job(&[("SLURM_MEM_PER_NODE", "0")]).unwrap(), None, "the whole node");
        assert_eq!(job(&[]).unwrap(), None, "no memory asked");
        assert_eq!(slurm_memory(&env(&[("SLURM_MEM_PER_NODE", "4096")])).unwrap(), None, "not in a job");
        for (vars, name) in [
            (&[("SLURM_MEM_PER_NODE", "4G")][..], "SLURM_MEM_PER_NODE"),
            (&[("SLURM_MEM_PER_CPU", "x")][..], "SLURM_MEM_PER_CPU"),
            (&[("SLURM_MEM_PER_CPU", "1024")][..], "SLURM_CPUS_ON_NODE"),
        ] {
            let err = job(vars).unwrap_err();
            assert!(matches!(&err, MemoryError::Slurm { name: n, .. } if *n == name), "{err}");
            assert!(err.to_string().contains(name) && err.to_string().contains("--mem"), "{err}");
        }
    }

    /// The least of the cgroup's headroom (1.5 GiB here), the Slurm job's memory and the
    /// host's available memory binds, whichever it is.
    #[test]
    fn the_least_binds() {
        let s = "/system.slice/foo.service";
        let tree = |avail_kib: u64| {
            let meminfo = format!("MemTotal: 99999999 kB\nMemAvailable: {avail_kib} kB\n");
            let files = [(s, "memory.max", "2147483648"), (s, "memory.current", "536870912")];
            let dir = v2_tree(s, &files);
            std::fs::create_dir_all(dir.path().join("proc")).unwrap();
            std::fs::write(dir.path().join("proc/meminfo"), meminfo).unwrap();
            dir
        };
        let in_job = |mib: &str| env(&[("SLURM_JOB_ID", "7"), ("SLURM_MEM_PER_NODE", mib)]);
        let cases: [(u64, &str, u64, &str); 3] = [
            (4 << 20, "4096", 3 * GIB / 2, "the cgroup /system.slice/foo.service allows 1.5 GiB more"),
            (4 << 20, "1024", GIB, "the Slurm job 7 has 1 GiB"),
            (1 << 20, "4096", GIB, "the host has 1 GiB available"),
        ];
        for (avail_kib, slurm_mib, bytes, says) in cases {
            let dir = tree(avail_kib);
            let budget = memory_budget_at(dir.path(), &in_job(slurm_mib)).unwrap();
            assert_eq!(budget.limits.len(), 3);
            assert_eq!(budget.bytes(), bytes, "{budget:?}");
            assert!(budget.bound().to_string().starts_with(says), "{}", budget.bound());
        }
    }

    /// No cgroup, no job: the host binds; no `/proc/meminfo` is an error naming it.
    #[test]
    fn without_cgroup_the_host_binds() {
        let dir = crate::hostfile::fixture(&[("/proc/meminfo", "MemAvailable:   2048 kB\n")]);
        let budget = memory_budget_at(dir.path(), &env(&[])).unwrap();
        assert_eq!(budget.limits, [MemoryLimit { bytes: 2 << 20, source: MemorySource::Host }]);
        let empty = tempfile::tempdir().unwrap();
        let err = memory_budget_at(empty.path(), &env(&[])).unwrap_err();
        assert!(err.to_string().contains("proc/meminfo"), "{err}");
    }
}
