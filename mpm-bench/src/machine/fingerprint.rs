//! The machine's two identities: its fingerprint (the `results/<fingerprint>/` folder, the
//! resume key) and its hardware class (what decides whether two campaigns compare), and the
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
//!
//! The *hardware class* ([`HardwareClass`], in the manifest's `machine.hardware_class`) is
//! the CPU (vendor, family, model, model name, architecture), sockets, cores, SMT, a memory
//! size class and the instruction-set levels the kernels use ([`hardware_class`]): the same
//! for every VM of one runner type, whatever its machine id, microcode or kernel. `regress`,
//! `report` and `ab` compare campaigns of one class ([`incomparable`]); campaigns recorded
//! before the class existed compare by fingerprint, as they always did.

use super::topology::{CacheLevel, Machine, NumaNode};
use crate::util::hex;
use mpm_host::identity::{memory_class_gib, HardwareClass, HostIdentity};
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
    /// The hardware class (`null` in manifests written before it existed).
    #[serde(default)]
    pub hardware_class: Option<HardwareClass>,
}

/// The hardware class of `m` (module docs): with this host's identity and ISA levels when
/// `m` is this host.
pub fn hardware_class(m: &Machine) -> HardwareClass {
    let identity = m.is_this_system.then(mpm_host::identity::read_host);
    let isa = if m.is_this_system { mpm_host::identity::read_kernel_isa() } else { Vec::new() };
    hardware_class_with(m, identity.as_ref(), isa)
}

/// The hardware class of `m` with the host identity `identity` (none for synthetic
/// machines: vendor, family and model read `unknown`) and the kernels' ISA levels `isa`.
pub fn hardware_class_with(m: &Machine, identity: Option<&HostIdentity>, isa: Vec<String>) -> HardwareClass {
    let id = |f: fn(&HostIdentity) -> &String| identity.map_or_else(|| "unknown".to_string(), |i| f(i).clone());
    HardwareClass {
        cpu_vendor: id(|i| &i.cpu_vendor),
        cpu_family: id(|i| &i.cpu_family),
        cpu_model: id(|i| &i.cpu_model),
        cpu_model_name: m.cpu_model.clone(),
        arch: std::env::consts::ARCH.into(),
        sockets: m.num_packages(),
        cores: m.num_cores(),
        smt: m.smt_width(),
        memory_class_gib: memory_class_gib(m.total_memory_bytes),
        isa,
    }
}

/// Why results of two machines, each a fingerprint and (when its manifest records one) a
/// hardware class, do not compare; `None` when they do: the same fingerprint, or the same
/// class. Without a class on either side (a manifest older than the class) only the
/// fingerprint can tell.
pub fn incomparable(a: (&str, Option<&HardwareClass>), b: (&str, Option<&HardwareClass>)) -> Option<String> {
    if a.0 == b.0 {
        return None;
    }
    match (a.1, b.1) {
        (Some(x), Some(y)) => {
            let d = x.differences(y);
            (!d.is_empty()).then(|| format!("different machines of another hardware class ({})", d.join("; ")))
        }
        _ => Some(format!(
            "different machines ({} vs {}) and no hardware class recorded to compare them by (a manifest older than \
             the class)",
            a.0, b.0
        )),
    }
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
        hardware_class: Some(hardware_class_with(
            m,
            identity.as_ref(),
            if m.is_this_system { mpm_host::identity::read_kernel_isa() } else { Vec::new() },
        )),
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

    /// Two hosts that differ only in their machine id (two VMs of one runner type), or in
    /// microcode and kernel, are two fingerprints of one hardware class: they compare.
    /// Another CPU model, core count or ISA level is another class: they do not.
    #[test]
    fn two_machine_ids_are_one_hardware_class() {
        let m = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let id = mpm_host::identity::parse_cpuinfo(
            "vendor_id : AuthenticAMD\ncpu family : 25\nmodel : 1\nstepping : 1\nmicrocode : 0xa0011d1\n",
        );
        let isa = vec!["avx2".to_string()];
        let mut a = id.clone();
        a.machine_id_sha256 = Some("aa".repeat(32));
        let mut b = id.clone();
        b.machine_id_sha256 = Some("bb".repeat(32));
        b.microcode = "0xa0011d5".into();
        b.kernel = "6.8.0".into();
        let (fa, fb) = (fingerprint_with(&m, Some(&a)), fingerprint_with(&m, Some(&b)));
        assert_ne!(fa, fb, "the exact host identity still tells them apart (provenance, resume)");
        let (ca, cb) = (hardware_class_with(&m, Some(&a), isa.clone()), hardware_class_with(&m, Some(&b), isa.clone()));
        assert_eq!(ca, cb);
        assert_eq!(incomparable((&fa, Some(&ca)), (&fb, Some(&cb))), None);
        // Another CPU model: incomparable, named.
        let mut c = b.clone();
        c.cpu_model = "17".into();
        let cc = hardware_class_with(&m, Some(&c), isa.clone());
        let why = incomparable((&fa, Some(&ca)), (&fingerprint_with(&m, Some(&c)), Some(&cc))).unwrap();
        assert!(why.contains("model 1 vs 17"), "{why}");
        // Another core count or ISA level: another class.
        let four = Machine::synthetic("pack:1 core:4 pu:1").unwrap();
        assert_ne!(hardware_class_with(&four, Some(&a), isa.clone()), ca);
        assert_ne!(hardware_class_with(&m, Some(&a), vec!["avx2".into(), "avx512f".into()]), ca);
        // Without a class on one side, only the fingerprint can tell.
        assert!(incomparable((&fa, None), (&fb, Some(&cb))).is_some());
        assert_eq!(incomparable((&fa, None), (&fa, None)), None);
    }
}
