//! What identifies the host and the build a measurement came from: the CPU (vendor, family,
//! model, stepping, microcode, per-level cache sizes, SMT state), a hash of `/etc/machine-id`,
//! the kernel, and this binary's commit, rustc and SHA-256 ([`Provenance`]).
//!
//! Shared by `mpm` (the `provenance` block of every JSON summary) and the harness (the
//! machine fingerprint that names a results folder and decides whether a campaign may be
//! resumed). Everything is read from `/proc` and `/sys` where readable and `unknown` (or
//! `None`) where not: containers and VMs hide some of it, and a missing file is never an
//! error.

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
