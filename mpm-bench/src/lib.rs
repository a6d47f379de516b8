//! # mpm-bench
//!
//! The benchmark harness of the MPM parallelisation study, in four layers (each uses only
//! the ones below it):
//!
//! * [`report`]: the paper's Figures 7-14, a memory figure and hardware comparison reports;
//! * [`analysis`]: medians with bootstrap intervals, speedup and efficiency (paper Eqs.
//!   19-20), a verdict on each of the paper's claims C1-C7, a CI gate on parallel
//!   efficiency and its calibration's verdicts, the statistics of the paired design: it
//!   reads what was recorded and runs no solver;
//! * [`campaign`]: presets resolved into runs (`plan`), each run a fresh `mpm` process pinned
//!   the way the user asks (`exec`), here or as Slurm jobs behind one scheduler interface
//!   (`schedule`), recorded to CSV with a manifest (`store`); and the measurements that run
//!   the solver in this process or run the gate's campaigns (`measure`);
//! * [`machine`]: the topology (hwloc), pinning policies, the machine fingerprint and the
//!   STREAM-triad bandwidth ceiling;
//!
//! and [`util`] below them all. The run's spec and its JSON summary (read back here, its
//! figures the CSV row's) are `mpm-spec`'s; what both programs know of the host (pinning,
//! atomic writes, locks, identity) is `mpm-host`'s; model sizes and memory estimates come
//! from `mpm-core`. The program's command line (clap) is the binary's (`src/main.rs`,
//! `src/cli/`): the library takes plain option structs.

pub mod analysis;
pub mod campaign;
pub mod machine;
pub mod report;
pub mod util;
