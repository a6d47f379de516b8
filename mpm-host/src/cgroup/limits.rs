//! The limits this process's cgroups set: the memory a process may still take and the
//! CPUs it may use, the tightest over its cgroup and every ancestor up to the mount's root
//! (a limit of an ancestor binds all below it).
//!
//! Memory. cgroup v2: `memory.max` (`max`: none) of each level that has the file (the root
//! has none, nor a cgroup whose parent does not enable the memory controller). cgroup v1:
//! `memory.limit_in_bytes`, where the kernel writes "no limit" as the largest count of
//! pages it can hold (9223372036854771712 with 4 KiB pages). What a run may still take at a
//! level is its limit less what the level uses now: `memory.current` (v1:
//! `memory.usage_in_bytes`, which counts the descendants as v2's does) less the file cache
//! the kernel reclaims before it would kill (`inactive_file` of `memory.stat`, v1:
//! `total_inactive_file`), the working set by which the kubelet judges a container. The
//! headroom, not the limit: the limit binds this process together with every other process
//! of its cgroup (the harness beside its runs, the other tasks of a Slurm job) and the
//! pages they already hold. A `memory.stat` that is not there counts no cache (the
//! headroom is then, if anything, too small). cgroup v1 with `memory.use_hierarchy` 0
//! (where an ancestor's limit does not bind its children, a mode newer kernels no longer
//! offer) is read the same way, erring on the small side too.
//!
//! CPUs. cgroup v2: `cpu.max`, `quota period` in microseconds (`max period`: none); cgroup
//! v1: `cpu.cfs_quota_us` (`-1`: none) over `cpu.cfs_period_us`. The quota is `quota /
//! period` CPUs of time per period, however many CPUs the process may run on.

use std::path::Path;

use super::locate::{own_cgroup, CgroupVersion, OwnCgroup};
use crate::hostfile::{HostFileError, Root};
use crate::human::human_bytes;

/// The first v1 memory limit read as "no limit": the kernel's largest page count times the
/// page size, for pages up to 1 MiB, is above it.
const V1_UNLIMITED: u64 = i64::MAX as u64 - (1 << 20);

/// The memory a cgroup lets this process take.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CgroupMemory {
    /// The cgroup that binds (this process's or an ancestor), as `/proc/self/cgroup` names
    /// it.
    pub cgroup: String,
    /// Its interface.
    pub version: CgroupVersion,
    /// Its limit, bytes.
    pub limit: u64,
    /// What it uses now, less the reclaimable file cache, bytes.
    pub in_use: u64,
}

impl CgroupMemory {
    /// What may still be taken: the limit less what is in use.
    pub fn headroom(&self) -> u64 {
        self.limit.saturating_sub(self.in_use)
    }
}

impl std::fmt::Display for CgroupMemory {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the cgroup {} allows {} more (its limit {}, {} in use)",
            self.cgroup,
            human_bytes(self.headroom()),
            human_bytes(self.limit),
            human_bytes(self.in_use)
        )
    }
}

/// A CPU quota of a cgroup.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CpuQuota {
    /// The cgroup that sets it (this process's or an ancestor).
    pub cgroup: String,
    /// Its interface.
    pub version: CgroupVersion,
    /// CPU time allowed per period, microseconds.
    pub quota_us: u64,
    /// The period, microseconds.
    pub period_us: u64,
}

impl CpuQuota {
    /// The quota as a number of CPUs (1.5: one and a half CPUs' time).
    pub fn cpus(&self) -> f64 {
        self.quota_us as f64 / self.period_us as f64
    }
}

impl std::fmt::Display for CpuQuota {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "the cgroup {} allows {} CPUs ({} us every {} us)",
            self.cgroup,
            self.cpus(),
            self.quota_us,
            self.period_us
        )
    }
}

/// A whole number.
fn number(s: &str) -> Option<u64> {
    s.parse().ok()
}

/// The value of `key` in a `memory.stat` text (0 when it has none).
fn stat_value(text: &str, key: &str) -> Option<u64> {
    for line in text.lines() {
        if let Some((k, v)) = line.split_once(' ') {
            if k == key {
                return number(v.trim());
            }
        }
    }
    Some(0)
}

/// The memory limit at one level (`None`: it sets none).
fn memory_at(
    root: Root<'_>,
    version: CgroupVersion,
    name: &str,
    dir: &Path,
) -> Result<Option<CgroupMemory>, HostFileError> {
    let (max, current, cache) = match version {
        CgroupVersion::V2 => ("memory.max", "memory.current", "inactive_file"),
        CgroupVersion::V1 => ("memory.limit_in_bytes", "memory.usage_in_bytes", "total_inactive_file"),
    };
    let limit = root.parse(dir.join(max), "a number of bytes or max", |s| match s {
        "max" => Some(None),
        s => number(s).map(|n| (version == CgroupVersion::V2 || n < V1_UNLIMITED).then_some(n)),
    })?;
    let Some(Some(limit)) = limit else { return Ok(None) };
    let used = root.parse_required(dir.join(current), "a number of bytes", number)?;
    let cache = root.parse(dir.join("memory.stat"), "lines of key and number", |s| stat_value(s, cache))?;
    let in_use = used.saturating_sub(cache.unwrap_or(0));
    Ok(Some(CgroupMemory { cgroup: name.to_string(), version, limit, in_use }))
}

/// The CPU quota at one level (`None`: it sets none).
fn cpu_at(root: Root<'_>, version: CgroupVersion, name: &str, dir: &Path) -> Result<Option<CpuQuota>, HostFileError> {
    let period = |s: &str| number(s.trim()).filter(|&p| p > 0);
    let quota = match version {
        CgroupVersion::V2 => root.parse(dir.join("cpu.max"), "a quota (or max) and a period", |s| {
            let (quota, p) = s.split_once(' ')?;
            let p = period(p)?;
            if quota == "max" {
                Some(None)
            } else {
                Some(Some((number(quota)?, p)))
            }
        })?,
        CgroupVersion::V1 => {
            let quota = root.parse(dir.join("cpu.cfs_quota_us"), "a number of microseconds or -1", |s| {
                if s == "-1" {
                    Some(None)
                } else {
                    number(s).map(Some)
                }
            })?;
            match quota {
                Some(Some(q)) => Some(Some((
                    q,
                    root.parse_required(dir.join("cpu.cfs_period_us"), "a number of microseconds", period)?,
                ))),
                _ => None,
            }
        }
    };
    Ok(quota.flatten().map(|(quota_us, period_us)| CpuQuota { cgroup: name.to_string(), version, quota_us, period_us }))
}

/// Each level's value by `at` (given its name and folder), this cgroup first.
fn each_level<T>(
    own: &OwnCgroup,
    at: impl Fn(&str, &Path) -> Result<Option<T>, HostFileError>,
) -> Result<Vec<T>, HostFileError> {
    let mut found = Vec::new();
    for (name, dir) in own.levels() {
        found.extend(at(&name, &dir)?);
    }
    Ok(found)
}

/// The memory this process's cgroups let it take: the level with the least headroom;
/// `None` when no visible cgroup sets a limit.
pub fn memory_limit(root: Root<'_>) -> Result<Option<CgroupMemory>, HostFileError> {
    let Some(own) = own_cgroup(root, "memory")? else { return Ok(None) };
    Ok(each_level(&own, |name, dir| memory_at(root, own.version, name, dir))?
        .into_iter()
        .min_by_key(CgroupMemory::headroom))
}

/// The CPU quota of this process's cgroups: the level with the fewest CPUs; `None` when
/// no visible cgroup sets one.
pub fn cpu_quota_at(root: Root<'_>) -> Result<Option<CpuQuota>, HostFileError> {
    let Some(own) = own_cgroup(root, "cpu")? else { return Ok(None) };
    Ok(each_level(&own, |name, dir| cpu_at(root, own.version, name, dir))?
        .into_iter()
        .min_by(|a, b| a.cpus().total_cmp(&b.cpus())))
}

/// The CPU quota of this process's cgroups, as [`cpu_quota_at`] reads it under `/`: a
/// quota below a run's thread count shares the CPUs' time between its threads.
pub fn cpu_quota() -> Result<Option<CpuQuota>, HostFileError> {
    cpu_quota_at(Root::real())
}
