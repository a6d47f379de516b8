//! # mpm-cli
//!
//! The `mpm` program (`src/bin/mpm/`: one simulation from the command line) and what it
//! shares with the benchmark harness `mpm-bench`:
//!
//! * [`summary`]: building the JSON summary of a run (the type, [`mpm_spec::Summary`], is
//!   the interface between the two programs and lives in `mpm-spec` with the run spec);
//! * [`memory`]: the memory available to a new process, and bytes for people;
//! * [`pinning`]: the rayon pool of a run with worker `j` pinned to CPU `j`, the workers'
//!   placement read back, and the one CPU-list parser;
//! * [`vtk`]: VTU snapshots and a `.pvd` collection for ParaView;
//! * [`picture`]: the embedded font of every figure, the radiograph-style view of the
//!   debris cloud and its history;
//! * [`atomic`]: atomic file writes;
//! * [`checkpoint`]: checkpoint files (a TOML header, the particle arrays, a SHA-256) and
//!   the folder that keeps a run's last two;
//! * [`lock`]: one writer per folder (`flock`): a campaign's, a run's checkpoints;
//! * [`identity`]: the host's identity (CPU, caches, SMT, machine id) and the build's
//!   provenance (commit, dirty flag, rustc, binary SHA-256);
//! * [`usage`]: what each worker thread got of the wall time (its CPU time, context
//!   switches, its CPU's steal), the noise a run can see;
//! * [`paired`]: solvers advancing in alternating timed blocks (the paired design);
//! * [`group_digits`]: counts printed for people (`1,234,567`).
//!
//! Pinning and measurement policy (affinity, `/proc/self/status`) live here; the solver crate
//! `mpm-core` has no OS code.

pub mod atomic;
pub mod checkpoint;
pub mod distributed;
pub mod identity;
pub mod lock;
pub mod memory;
pub mod paired;
pub mod picture;
pub mod pinning;
pub mod summary;
pub mod usage;
pub mod vtk;

/// `1234567` as `1,234,567`.
pub fn group_digits(n: u64) -> String {
    let s = n.to_string();
    let mut out = String::new();
    for (i, c) in s.chars().enumerate() {
        if i > 0 && (s.len() - i).is_multiple_of(3) {
            out.push(',');
        }
        out.push(c);
    }
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn digits_are_grouped_by_three() {
        assert_eq!(super::group_digits(0), "0");
        assert_eq!(super::group_digits(999), "999");
        assert_eq!(super::group_digits(1_000), "1,000");
        assert_eq!(super::group_digits(13_542_030), "13,542,030");
    }
}
