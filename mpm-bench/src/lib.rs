//! # mpm-bench
//!
//! The benchmark harness of the MPM parallelisation study, in four layers (each uses only
//! the ones below it):
//!
//! * [`report`]: the paper's Figures 7-14, a memory figure and hardware comparison reports;
//! * [`analysis`]: medians with bootstrap intervals, speedup and efficiency (paper Eqs.
//!   19-20), a verdict on each of the paper's claims C1-C6, a CI gate on parallel
//!   efficiency, and paired in-process efficiency measurements for noisy hosts;
//! * [`campaign`]: presets resolved into runs, each run a fresh `mpm` process pinned the way
//!   the user asks, recorded to CSV with a manifest;
//! * [`machine`]: the topology (hwloc), pinning policies, the machine fingerprint and the
//!   STREAM-triad bandwidth ceiling;
//!
//! and [`util`] below them all. The `mpm` program, its JSON summary (read back here) and the
//! pinning code both programs use live in the crate `mpm-cli`; model sizes and memory
//! estimates come from `mpm-core`.

pub mod analysis;
pub mod campaign;
pub mod machine;
pub mod report;
pub mod util;
