//! The machine's identity: its fingerprint (the `results/<fingerprint>/` folder) and the
//! machine part of a campaign's manifest.
//!
//! The *machine fingerprint* is a short, stable hash (12 hex digits of SHA-256) of the CPU
//! model, packages, cores, PUs, memory (rounded to GiB) and operating system (name and
//! version, not the kernel build), and, for this host, of its [`HostIdentity`]: CPU vendor,
//! family, model, stepping and microcode, per-level cache sizes, SMT state and a hash of
//! `/etc/machine-id`. Results of the same machine land in the same `results/<fingerprint>/`
//! folder and are comparable; another machine (another VM with the same CPU name string
//! included, through its machine id) gets another. The folder name stays 12 hex digits; the
//! manifest keeps the facts behind it.

use super::topology::{CacheLevel, Machine, NumaNode};
use crate::util::hex;
use mpm_host::identity::HostIdentity;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::path::Path;

/// The machine part of the manifest.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct MachineInfo {
    /// Short stable hash (see module docs).
    pub fingerprint: String,
    /// CPU model.
    pub cpu_model: String,
    /// Packages (sockets).
    pub packages: usize,
    /// Physical cores (usable).
    pub cores: usize,
    /// PUs / hardware threads (usable).
    pub pus: usize,
    /// PUs per core.
    pub smt_width: usize,
    /// NUMA nodes with local memory and CPUs.
    pub numa_nodes: Vec<NumaNode>,
    /// CPU caches.
    pub caches: Vec<CacheLevel>,
    /// Total memory, bytes.
    pub memory_bytes: u64,
    /// Operating system (`/etc/os-release` PRETTY_NAME).
    pub os: String,
    /// Kernel release.
    pub kernel: String,
    /// Architecture (`x86_64`, `aarch64`, ...).
    pub arch: String,
    /// CPU frequency governor(s), `unknown` when not readable (VMs, containers).
    pub cpu_governor: String,
    /// The first CPU's clock as `/proc/cpuinfo` reports it (MHz; in a VM the host's nominal
    /// one); `null` when not reported or in manifests written before it existed.
    #[serde(default)]
    pub cpu_mhz: Option<f64>,
    /// Full topology as plain data.
    pub topology: Machine,
    /// CPU identity, caches, SMT, hashed machine id (`null` in manifests written before
    /// it existed, and for synthetic machines).
    #[serde(default)]
    pub identity: Option<HostIdentity>,
}

/// Stable fingerprint of a machine (12 hex digits): of `m` and, when `m` is this host, of
/// its [`HostIdentity`].
pub fn fingerprint(m: &Machine) -> String {
    let identity = m.is_this_system.then(mpm_host::identity::read_host);
    fingerprint_with(m, identity.as_ref())
}

/// Fingerprint of `m` with the host identity `identity` (none for synthetic machines).
pub fn fingerprint_with(m: &Machine, identity: Option<&HostIdentity>) -> String {
    let mem_gib = (m.total_memory_bytes as f64 / (1u64 << 30) as f64).round() as u64;
    let key = format!(
        "cpu={}|packages={}|cores={}|pus={}|mem_gib={}|os={}|arch={}",
        m.cpu_model,
        m.num_packages(),
        m.num_cores(),
        m.usable_pus().len(),
        mem_gib,
        os_name(),
        std::env::consts::ARCH
    );
    let key = match identity {
        Some(id) => format!("{key}|{}", id.key()),
        None => key,
    };
    hex(&Sha256::digest(key.as_bytes()))[..12].to_string()
}

/// Machine part of the manifest for `m` (this host).
pub fn machine_info(m: &Machine) -> MachineInfo {
    let identity = m.is_this_system.then(mpm_host::identity::read_host);
    MachineInfo {
        fingerprint: fingerprint_with(m, identity.as_ref()),
        cpu_model: m.cpu_model.clone(),
        packages: m.num_packages(),
        cores: m.num_cores(),
        pus: m.usable_pus().len(),
        smt_width: m.smt_width(),
        numa_nodes: m.numa_nodes.clone(),
        caches: m.caches.clone(),
        memory_bytes: m.total_memory_bytes,
        os: os_name(),
        kernel: read_trim("/proc/sys/kernel/osrelease").unwrap_or_else(|| "unknown".into()),
        arch: std::env::consts::ARCH.into(),
        cpu_governor: governor(),
        cpu_mhz: m.is_this_system.then(cpu_mhz).flatten(),
        topology: m.clone(),
        identity,
    }
}

/// `cpu MHz` of the first processor in `/proc/cpuinfo`.
fn cpu_mhz() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    text.lines().find_map(|l| l.strip_prefix("cpu MHz")?.split(':').nth(1)?.trim().parse().ok())
}

fn os_name() -> String {
    std::fs::read_to_string("/etc/os-release")
        .ok()
        .and_then(|t| t.lines().find_map(|l| l.strip_prefix("PRETTY_NAME=").map(|v| v.trim_matches('"').to_string())))
        .unwrap_or_else(|| std::env::consts::OS.to_string())
}

fn governor() -> String {
    let mut govs: Vec<String> = Vec::new();
    if let Ok(rd) = std::fs::read_dir("/sys/devices/system/cpu") {
        for e in rd.flatten() {
            if let Some(g) = read_trim(e.path().join("cpufreq/scaling_governor")) {
                if !govs.contains(&g) {
                    govs.push(g);
                }
            }
        }
    }
    if govs.is_empty() {
        "unknown (cpufreq not exposed)".into()
    } else {
        govs.sort();
        govs.join(",")
    }
}

fn read_trim(p: impl AsRef<Path>) -> Option<String> {
    std::fs::read_to_string(p).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprint_is_stable_and_short() {
        let m = Machine::synthetic("pack:2 core:4 pu:2").unwrap();
        let a = fingerprint(&m);
        assert_eq!(a.len(), 12);
        assert_eq!(a, fingerprint(&m));
        let other = Machine::synthetic("pack:1 core:4 pu:2").unwrap();
        assert_ne!(a, fingerprint(&other));
    }

    /// Two hosts alike in CPU name, counts and memory but of another CPU stepping, microcode,
    /// cache size or machine id get different fingerprints.
    #[test]
    fn identity_separates_look_alike_hosts() {
        let m = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let id = mpm_host::identity::parse_cpuinfo(
            "vendor_id : AuthenticAMD\ncpu family : 25\nmodel : 17\nstepping : 1\nmicrocode : 0x1000065\n",
        );
        let base = fingerprint_with(&m, Some(&id));
        assert_eq!(base.len(), 12);
        assert_ne!(base, fingerprint_with(&m, None));
        let mut other = id.clone();
        other.cpu_stepping = "2".into();
        assert_ne!(base, fingerprint_with(&m, Some(&other)));
        let mut other = id.clone();
        other.machine_id_sha256 = Some("ab".repeat(32));
        assert_ne!(base, fingerprint_with(&m, Some(&other)));
        let mut other = id.clone();
        other.caches.push(mpm_host::identity::CacheSize { level: 3, kind: "unified".into(), size_bytes: 1 << 25 });
        assert_ne!(base, fingerprint_with(&m, Some(&other)));
    }
}
