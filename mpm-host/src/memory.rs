//! Memory of this machine as a new process sees it, for the checks made before a run
//! allocates: `MemAvailable`, capped by a cgroup v2 limit. (Bytes for people:
//! [`crate::human::human_bytes`].)

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

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn this_machine_has_memory_available() {
        assert!(available_memory().is_some_and(|m| m > 0));
    }
}
