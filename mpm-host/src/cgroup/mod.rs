//! This process's cgroups as the kernel shows them: where its cgroup of a controller is
//! ([`locate`], cgroup v1 and v2 alike) and the limits it and its ancestors set: the
//! memory it may still take and its CPU quota ([`limits`]). Every file is read under a
//! [`crate::hostfile::Root`]: `/` for the real ones, a fixture tree in tests.

pub mod limits;
pub mod locate;

pub use limits::{cpu_quota, cpu_quota_at, memory_limit, CgroupMemory, CpuQuota};
pub use locate::{own_cgroup, CgroupVersion, OwnCgroup};

#[cfg(test)]
pub(crate) mod tests;
