//! What identifies the host and the build a measurement came from, in two identities:
//!
//! * the *host identity* ([`HostIdentity`]): the CPU (vendor, family, model, stepping,
//!   microcode, per-level cache sizes, SMT state), a hash of `/etc/machine-id`, the kernel,
//!   and this binary's commit, rustc and SHA-256 ([`Provenance`]). Exact: another VM of the
//!   same image and hardware has another one (its machine id). It names a results folder,
//!   decides whether a campaign may be resumed, and is the provenance of every summary;
//! * the *hardware class* ([`HardwareClass`]): what makes two hosts time the same code
//!   alike: the CPU model, sockets, cores, SMT, a memory size class and the instruction-set
//!   levels the kernels use. A hosted CI runner is a new VM per job: a new host of the same
//!   class. Comparing campaigns (`mpm-bench regress`, `report`, `ab`) goes by the class.
//!
//! Shared by `mpm` (the `provenance` block of every JSON summary) and the harness. Everything
//! is read from `/proc` and `/sys` where readable and `unknown` (or `None`) where not:
//! containers and VMs hide some of it, and a missing file is never an error.

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::io::Read;
use std::path::Path;

/// Version of the workspace's crates (one version for all: the `mpm` that writes a
/// checkpoint or a summary is this version).
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
/// Git commit of the workspace this binary was built from (`unknown` without git).
pub const GIT_COMMIT: &str = env!("MPM_GIT_COMMIT");
/// Its first 12 hex digits, with `-dirty` when [`GIT_DIRTY`] is `true` (`unknown` without
/// git): what `mpm --version` prints.
pub const GIT_COMMIT_SHORT: &str = env!("MPM_GIT_COMMIT_SHORT");
/// `true` / `false`: the work tree had uncommitted changes to tracked files when this binary
/// was built; `unknown` without git.
pub const GIT_DIRTY: &str = env!("MPM_GIT_DIRTY");
/// `rustc -V` of the compiler that built this binary.
pub const RUSTC: &str = env!("MPM_RUSTC");

pub use mpm_spec::identity::{parse_cache_size, parse_cpuinfo, smt_state, CacheSize, HostIdentity, Provenance};

/// This host's identity, read from `/proc` and `/sys`.
pub fn read_host() -> HostIdentity {
    let cpu = std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default();
    let mut id = parse_cpuinfo(&cpu);
    id.caches = read_caches(Path::new("/sys/devices/system/cpu/cpu0/cache"));
    id.smt = smt_state(
        read_trim("/sys/devices/system/cpu/smt/active").as_deref(),
        read_trim("/sys/devices/system/cpu/smt/control").as_deref(),
    );
    id.machine_id_sha256 = read_trim("/etc/machine-id").map(|m| sha256_hex(m.as_bytes()));
    id.kernel = read_trim("/proc/sys/kernel/osrelease").unwrap_or_else(|| "unknown".into());
    id
}

/// The instruction-set levels the solver's kernels dispatch on (`mpm_core::simd`: AVX2, and
/// AVX-512F beside it), as `/proc/cpuinfo` names them.
pub const KERNEL_ISA: [&str; 2] = ["avx2", "avx512f"];

/// Which of [`KERNEL_ISA`] the first processor's `flags` (or ARM's `Features`) line of a
/// `/proc/cpuinfo` text lists, in that order.
pub fn parse_kernel_isa(cpuinfo: &str) -> Vec<String> {
    let first = cpuinfo.split("\n\n").next().unwrap_or("");
    let flags: Vec<&str> = first
        .lines()
        .filter_map(|l| l.split_once(':').filter(|(k, _)| matches!(k.trim(), "flags" | "Features")))
        .flat_map(|(_, v)| v.split_whitespace())
        .collect();
    KERNEL_ISA.iter().filter(|f| flags.contains(f)).map(|f| f.to_string()).collect()
}

/// This host's [`KERNEL_ISA`] levels, from `/proc/cpuinfo` (none when unreadable).
pub fn read_kernel_isa() -> Vec<String> {
    parse_kernel_isa(&std::fs::read_to_string("/proc/cpuinfo").unwrap_or_default())
}

/// The memory size class of a host with `mem_total_bytes` of memory as the kernel reports it
/// (`MemTotal`): the power of two of GiB at or above it (at least 1). `MemTotal` is the
/// installed memory less what the firmware and the kernel keep, a share that varies with the
/// kernel, its settings and the hypervisor (a 16 GiB VM reports 15.2-15.9 GiB): rounding to
/// the nearest GiB would split one VM size into two classes, rounding up to a power of two
/// does not. It merges sizes between two powers (24 and 32 GiB are one class), which is
/// harmless: memory size changes nothing in a run's speed while the run fits, and a run that
/// does not fit is skipped by the harness's memory guard and shows as a missing cell.
pub fn memory_class_gib(mem_total_bytes: u64) -> u64 {
    let gib = (mem_total_bytes as f64 / (1u64 << 30) as f64).ceil().max(1.0) as u64;
    gib.next_power_of_two()
}

/// The hardware class of a host (module docs): two campaigns of one class compare; another
/// machine id, microcode, kernel or cache report does not change it, another CPU model,
/// socket, core or SMT count, memory class or ISA level does.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct HardwareClass {
    /// `/proc/cpuinfo` `vendor_id` (or `CPU implementer`); `unknown` when not read.
    pub cpu_vendor: String,
    /// `cpu family` (or `CPU architecture`).
    pub cpu_family: String,
    /// `model` number (or `CPU part`).
    pub cpu_model: String,
    /// The CPU's model name (hwloc's, else `model name`).
    pub cpu_model_name: String,
    /// Architecture (`x86_64`, `aarch64`).
    pub arch: String,
    /// Packages (sockets) with usable PUs.
    pub sockets: usize,
    /// Physical cores with usable PUs.
    pub cores: usize,
    /// PUs per core (2 with SMT on).
    pub smt: usize,
    /// Memory size class, GiB ([`memory_class_gib`]).
    pub memory_class_gib: u64,
    /// The [`KERNEL_ISA`] levels the CPU has.
    pub isa: Vec<String>,
}

impl HardwareClass {
    /// The class as one line (every field, named).
    pub fn key(&self) -> String {
        format!(
            "vendor={}|family={}|model={}|name={}|arch={}|sockets={}|cores={}|smt={}|mem_class_gib={}|isa={}",
            self.cpu_vendor,
            self.cpu_family,
            self.cpu_model,
            self.cpu_model_name,
            self.arch,
            self.sockets,
            self.cores,
            self.smt,
            self.memory_class_gib,
            self.isa.join(",")
        )
    }

    /// A short id of the class: 12 hex digits of the SHA-256 of [`HardwareClass::key`].
    pub fn id(&self) -> String {
        sha256_hex(self.key().as_bytes())[..12].to_string()
    }

    /// What differs from `other`, field by field (`cores 2 vs 4`); empty when the classes
    /// are the same.
    pub fn differences(&self, other: &HardwareClass) -> Vec<String> {
        let text = |c: &HardwareClass| -> Vec<(String, String)> {
            c.key()
                .split('|')
                .filter_map(|kv| kv.split_once('=').map(|(k, v)| (k.to_string(), v.to_string())))
                .collect()
        };
        text(self)
            .into_iter()
            .zip(text(other))
            .filter(|(a, b)| a.1 != b.1)
            .map(|((name, a), (_, b))| format!("{name} {a} vs {b}"))
            .collect()
    }

    /// In words: `AMD EPYC (x86_64), 1 socket x 2 cores, SMT 1, 16 GiB class, avx2`.
    pub fn describe(&self) -> String {
        format!(
            "{} ({}), {} socket(s) x {} cores, SMT {}, {} GiB class, ISA {}",
            self.cpu_model_name,
            self.arch,
            self.sockets,
            self.cores,
            self.smt,
            self.memory_class_gib,
            if self.isa.is_empty() { "baseline".to_string() } else { self.isa.join("+") }
        )
    }
}

/// Cache levels under a `cpuN/cache` folder, sorted by level and kind.
pub fn read_caches(dir: &Path) -> Vec<CacheSize> {
    let mut out = Vec::new();
    let Ok(rd) = std::fs::read_dir(dir) else { return out };
    for e in rd.flatten() {
        let p = e.path();
        if !e.file_name().to_string_lossy().starts_with("index") {
            continue;
        }
        let level = read_trim(p.join("level")).and_then(|l| l.parse().ok());
        let size = read_trim(p.join("size")).and_then(|s| parse_cache_size(&s));
        if let (Some(level), Some(size_bytes)) = (level, size) {
            let kind = read_trim(p.join("type")).unwrap_or_else(|| "unknown".into()).to_ascii_lowercase();
            out.push(CacheSize { level, kind, size_bytes });
        }
    }
    out.sort_by(|a, b| (a.level, &a.kind).cmp(&(b.level, &b.kind)));
    out
}

/// Provenance of this process: this host, this binary and the build constants.
pub fn provenance_of_this_process() -> Provenance {
    Provenance {
        host: read_host(),
        rustc: RUSTC.to_string(),
        git_commit: GIT_COMMIT.to_string(),
        git_dirty: GIT_DIRTY.parse().ok(),
        binary_sha256: this_binary_sha256(),
    }
}

/// SHA-256 of the running binary, lower-case hex (`unknown` if it cannot be read).
pub fn this_binary_sha256() -> String {
    // /proc/self/exe opens the running image even if the file was rebuilt meanwhile.
    let proc_exe = Path::new("/proc/self/exe");
    let exe = if proc_exe.exists() { Some(proc_exe.to_path_buf()) } else { std::env::current_exe().ok() };
    exe.and_then(|p| sha256_file(&p).ok()).unwrap_or_else(|| "unknown".into())
}

/// SHA-256 of `bytes`, lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// SHA-256 of a file, lower-case hex.
pub fn sha256_file(path: &Path) -> std::io::Result<String> {
    let mut f = std::fs::File::open(path)?;
    let mut h = Sha256::new();
    let mut buf = vec![0u8; 1 << 16];
    loop {
        let n = f.read(&mut buf)?;
        if n == 0 {
            break;
        }
        h.update(&buf[..n]);
    }
    Ok(hex(&h.finalize()))
}

/// Lower-case hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn read_trim(p: impl AsRef<Path>) -> Option<String> {
    std::fs::read_to_string(p).ok().map(|s| s.trim().to_string()).filter(|s| !s.is_empty())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kernel_isa_and_memory_class() {
        let text = "processor : 0\nflags : fpu sse2 avx avx2 fma avx512f avx512dq\n\nprocessor : 1\nflags : fpu\n";
        assert_eq!(parse_kernel_isa(text), ["avx2", "avx512f"]);
        assert_eq!(parse_kernel_isa("processor : 0\nflags : fpu sse2 avx2\n"), ["avx2"]);
        assert!(parse_kernel_isa("processor : 0\nFeatures : fp asimd\n").is_empty());
        let gib = 1u64 << 30;
        // A 16 GiB VM reports a little less; so does a 24 GiB one (one class with 32 GiB).
        assert_eq!(memory_class_gib(15 * gib + gib / 2), 16);
        assert_eq!(memory_class_gib(16 * gib), 16);
        assert_eq!(memory_class_gib(23 * gib), 32);
        assert_eq!(memory_class_gib(0), 1);
    }

    #[test]
    fn class_differences_name_the_fields() {
        let a = HardwareClass { cpu_model_name: "X".into(), cores: 2, ..HardwareClass::default() };
        let b = HardwareClass { cores: 4, ..a.clone() };
        assert_eq!(a.differences(&a), Vec::<String>::new());
        assert_eq!(a.differences(&b), ["cores 2 vs 4"]);
        assert_ne!(a.id(), b.id());
        assert_eq!(a.id().len(), 12);
    }

    #[test]
    fn caches_read_from_a_sysfs_like_folder() {
        let dir = tempfile::tempdir().unwrap();
        for (i, (level, kind, size)) in [(1, "Data", "32K"), (2, "Unified", "1024K")].iter().enumerate() {
            let d = dir.path().join(format!("index{i}"));
            std::fs::create_dir(&d).unwrap();
            std::fs::write(d.join("level"), format!("{level}\n")).unwrap();
            std::fs::write(d.join("type"), format!("{kind}\n")).unwrap();
            std::fs::write(d.join("size"), format!("{size}\n")).unwrap();
        }
        let c = read_caches(dir.path());
        assert_eq!(
            c,
            vec![
                CacheSize { level: 1, kind: "data".into(), size_bytes: 32 << 10 },
                CacheSize { level: 2, kind: "unified".into(), size_bytes: 1 << 20 }
            ]
        );
    }
}
