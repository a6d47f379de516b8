//! Memory of this machine as a new process sees it, for the checks made before a run
//! allocates: `MemAvailable`, capped by a cgroup v2 limit.

/// Memory available to a new process now, bytes: `MemAvailable`, capped by a cgroup v2
/// `memory.max` when one is set; `None` when `/proc/meminfo` cannot be read.
pub fn available_memory() -> Option<u64> {
    let meminfo = std::fs::read_to_string("/proc/meminfo").ok()?;
    let avail = meminfo
        .lines()
        .find(|l| l.starts_with("MemAvailable:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse::<u64>().ok())?
        * 1024;
    let cg = std::fs::read_to_string("/sys/fs/cgroup/memory.max").ok().and_then(|s| s.trim().parse::<u64>().ok());
    let used = std::fs::read_to_string("/sys/fs/cgroup/memory.current")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .unwrap_or(0);
    Some(match cg {
        Some(max) => avail.min(max.saturating_sub(used)),
        None => avail,
    })
}

/// Bytes for people in binary units: `512 B`, `1.5 KiB`, `350 MiB`, `8 GiB`.
pub fn human_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u + 1 < UNITS.len() {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else if v >= 100.0 || v.fract() < 0.05 {
        format!("{v:.0} {}", UNITS[u])
    } else {
        format!("{v:.1} {}", UNITS[u])
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_read_in_binary_units() {
        assert_eq!(human_bytes(512), "512 B");
        assert_eq!(human_bytes(1536), "1.5 KiB");
        assert_eq!(human_bytes(8_912_896_000), "8.3 GiB");
        assert_eq!(human_bytes(350 << 20), "350 MiB");
        assert!(available_memory().is_some_and(|m| m > 0));
    }
}
