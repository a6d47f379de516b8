//! What identifies the host and the build a measurement came from: the CPU (vendor, family,
//! model, stepping, microcode, per-level cache sizes, SMT state), a hash of `/etc/machine-id`,
//! the kernel, and the binary's commit, rustc and SHA-256 ([`Provenance`]): the types, and
//! the parsing of the kernel's texts. Reading them from `/proc` and `/sys` is the host
//! crate's (`mpm_host::identity`).

use serde::{Deserialize, Serialize};

/// One CPU cache level as the kernel lists it for CPU 0.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct CacheSize {
    /// Level (1, 2, 3, ...).
    pub level: u8,
    /// `data`, `instruction` or `unified`.
    pub kind: String,
    /// Size of one instance, bytes.
    pub size_bytes: u64,
}

/// The host as far as it changes a timing: CPU identity, caches, SMT, kernel and the
/// (hashed) machine id.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct HostIdentity {
    /// `/proc/cpuinfo` `vendor_id` (`GenuineIntel`, `AuthenticAMD`), or `CPU implementer`.
    pub cpu_vendor: String,
    /// `/proc/cpuinfo` `model name`.
    pub cpu_model_name: String,
    /// `cpu family` (or `CPU architecture`).
    pub cpu_family: String,
    /// `model` number (or `CPU part`).
    pub cpu_model: String,
    /// `stepping` (or `CPU revision`).
    pub cpu_stepping: String,
    /// `microcode` revision (`unknown` in most VMs and on ARM).
    pub microcode: String,
    /// Caches of CPU 0 from `/sys/devices/system/cpu/cpu0/cache/index*`.
    pub caches: Vec<CacheSize>,
    /// Simultaneous multithreading: `on`, `off`, or the kernel's control state
    /// (`notsupported`, `forceoff`, ...), `unknown` when not exposed.
    pub smt: String,
    /// SHA-256 of `/etc/machine-id` (the id itself is private), when present.
    pub machine_id_sha256: Option<String>,
    /// Kernel release (`/proc/sys/kernel/osrelease`).
    pub kernel: String,
}

impl HostIdentity {
    /// The fields that identify the machine, as one line for a fingerprint hash (the kernel
    /// is left out: an OS update does not make another machine).
    pub fn key(&self) -> String {
        let caches: Vec<String> =
            self.caches.iter().map(|c| format!("L{}-{}={}", c.level, c.kind, c.size_bytes)).collect();
        format!(
            "vendor={}|family={}|model={}|stepping={}|microcode={}|caches={}|smt={}|machine-id={}",
            self.cpu_vendor,
            self.cpu_family,
            self.cpu_model,
            self.cpu_stepping,
            self.microcode,
            caches.join(","),
            self.smt,
            self.machine_id_sha256.as_deref().unwrap_or("none")
        )
    }
}

/// CPU identity from the text of `/proc/cpuinfo` (the first processor's block; x86 and ARM
/// key names). Missing keys read `unknown`.
pub fn parse_cpuinfo(text: &str) -> HostIdentity {
    let first = text.split("\n\n").next().unwrap_or("");
    let get = |keys: &[&str]| -> String {
        keys.iter()
            .find_map(|k| {
                first.lines().find_map(|l| {
                    let (name, value) = l.split_once(':')?;
                    (name.trim() == *k).then(|| value.trim().to_string())
                })
            })
            .filter(|v| !v.is_empty())
            .unwrap_or_else(|| "unknown".into())
    };
    HostIdentity {
        cpu_vendor: get(&["vendor_id", "CPU implementer"]),
        cpu_model_name: get(&["model name", "Model", "Processor"]),
        cpu_family: get(&["cpu family", "CPU architecture"]),
        cpu_model: get(&["model", "CPU part"]),
        cpu_stepping: get(&["stepping", "CPU revision"]),
        microcode: get(&["microcode"]),
        ..HostIdentity::default()
    }
}

/// `32K`, `1024K`, `32M`, `512` (bytes) as bytes.
pub fn parse_cache_size(s: &str) -> Option<u64> {
    let s = s.trim();
    let (num, mult) = match s.chars().last()? {
        'K' | 'k' => (&s[..s.len() - 1], 1u64 << 10),
        'M' | 'm' => (&s[..s.len() - 1], 1 << 20),
        'G' | 'g' => (&s[..s.len() - 1], 1 << 30),
        _ => (s, 1),
    };
    num.trim().parse::<u64>().ok().map(|n| n * mult)
}

/// SMT state from the kernel's `smt/active` (`1`/`0`) and `smt/control` (`on`, `off`,
/// `forceoff`, `notsupported`, `notimplemented`).
pub fn smt_state(active: Option<&str>, control: Option<&str>) -> String {
    match (active, control) {
        (_, Some(c)) if c != "on" && c != "off" => c.to_string(),
        (Some("1"), _) => "on".into(),
        (Some("0"), _) => "off".into(),
        (None, Some(c)) => c.to_string(),
        _ => "unknown".into(),
    }
}

/// Where a binary and its build came from, written into every JSON summary (by
/// `mpm_host::identity::provenance_of_this_process`).
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct Provenance {
    /// The host the run ran on (kernel included).
    pub host: HostIdentity,
    /// `rustc -V` of the compiler that built `mpm`.
    pub rustc: String,
    /// Git commit `mpm` was built from (`unknown` without git).
    pub git_commit: String,
    /// Uncommitted changes when it was built (`None` when unknown).
    pub git_dirty: Option<bool>,
    /// SHA-256 of the running executable (`/proc/self/exe`: the image that runs, even if
    /// its file was replaced since), hex; `unknown` if unreadable.
    pub binary_sha256: String,
}

#[cfg(test)]
mod tests {
    use super::*;

    const X86: &str = "processor\t: 0\nvendor_id\t: GenuineIntel\ncpu family\t: 6\nmodel\t\t: 15\n\
        model name\t: Intel(R) Xeon(R) CPU E5355 @ 2.66GHz\nstepping\t: 7\nmicrocode\t: 0x6b\n\n\
        processor\t: 1\nvendor_id\t: OtherVendor\n";

    #[test]
    fn cpuinfo_first_block_is_parsed() {
        let id = parse_cpuinfo(X86);
        assert_eq!(id.cpu_vendor, "GenuineIntel");
        assert_eq!(id.cpu_family, "6");
        assert_eq!(id.cpu_model, "15");
        assert_eq!(id.cpu_stepping, "7");
        assert_eq!(id.microcode, "0x6b");
        assert_eq!(id.cpu_model_name, "Intel(R) Xeon(R) CPU E5355 @ 2.66GHz");
        let arm = parse_cpuinfo("processor : 0\nCPU implementer : 0x41\nCPU part : 0xd0c\nCPU revision : 1\n");
        assert_eq!((arm.cpu_vendor.as_str(), arm.cpu_model.as_str()), ("0x41", "0xd0c"));
        assert_eq!(arm.microcode, "unknown");
    }

    #[test]
    fn cache_sizes_and_smt() {
        assert_eq!(parse_cache_size("32K"), Some(32 << 10));
        assert_eq!(parse_cache_size("32768K"), Some(32 << 20));
        assert_eq!(parse_cache_size("4M"), Some(4 << 20));
        assert_eq!(parse_cache_size("x"), None);
        assert_eq!(smt_state(Some("1"), Some("on")), "on");
        assert_eq!(smt_state(Some("0"), Some("off")), "off");
        assert_eq!(smt_state(Some("0"), Some("notsupported")), "notsupported");
        assert_eq!(smt_state(None, None), "unknown");
    }

    #[test]
    fn key_changes_with_each_identity_field() {
        let a = parse_cpuinfo(X86);
        let mut b = a.clone();
        b.microcode = "0x6c".into();
        assert_ne!(a.key(), b.key());
        let mut c = a.clone();
        c.machine_id_sha256 = Some("0123abcd".into());
        assert_ne!(a.key(), c.key());
        let mut d = a.clone();
        d.kernel = "6.1".into();
        assert_eq!(a.key(), d.key(), "the kernel is not part of the machine");
    }
}
