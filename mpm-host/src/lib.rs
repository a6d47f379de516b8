//! # mpm-host
//!
//! What the two programs, `mpm` (crate `mpm-cli`) and the benchmark harness `mpm-bench`,
//! know of the host and do on it, in one library both build on:
//!
//! * [`identity`]: the host's identity (CPU, caches, SMT, machine id), its hardware class
//!   (what decides whether two hosts' timings compare) and the build's provenance (commit,
//!   dirty flag, rustc, binary SHA-256);
//! * [`memory`]: the memory a run may use here: the least of its cgroups' headroom, its
//!   Slurm job's allocation and the host's `MemAvailable`, with the one that binds;
//! * [`cgroup`]: this process's cgroup (v1 or v2) and the limits it and its ancestors set
//!   (memory, CPU quota), read through [`hostfile`] from `/` or a fixture tree;
//! * [`pinning`]: the rayon pool of a run with worker `j` pinned to CPU `j`, the workers'
//!   placement read back, and the one CPU-list parser;
//! * [`usage`]: what each worker thread got of the wall time (its CPU time, context
//!   switches, its CPU's steal), the noise a run can see;
//! * [`paired`]: solvers advancing in alternating timed blocks on their pinned pools (the
//!   paired design), in `mpm run` and in the harness's own process;
//! * [`slowdown`]: the injected step slowdown, a test knob that slows every worker alike;
//! * [`atomic`]: atomic file writes, synced with their folder;
//! * [`durable`]: `fsync` of files and folders whose failure is an error, and lines
//!   appended durably;
//! * [`lock`]: one writer per folder (`flock`, or a lock file where the file system has no
//!   `flock`): a campaign's, a run's checkpoints;
//! * [`fault`]: failures of `fsync` and `flock` injected by tests;
//! * [`checkpoint`]: checkpoint files (a TOML header, the particle arrays, a SHA-256) and
//!   the folder that keeps a run's last two, which `mpm` writes and both programs read;
//! * [`clock`]: the wall clock as both programs stamp files and rows with it;
//! * [`fonts`]: the font every figure is drawn with, compiled in, whatever the host has
//!   installed;
//! * [`human`]: bytes and counts printed for people.
//!
//! Reading `/proc` and `/sys`, pinning and `flock` live here; the solver crate `mpm-core` and
//! the contract crate `mpm-spec` have no OS code. No command-line parsing: errors are typed
//! (`thiserror`), with messages that say what to do, for the programs to report.

pub mod atomic;
pub mod cgroup;
pub mod checkpoint;
pub mod clock;
pub mod durable;
pub mod fault;
pub mod fonts;
pub mod hostfile;
pub mod human;
pub mod identity;
pub mod lock;
pub mod memory;
pub mod paired;
pub mod pinning;
pub mod slowdown;
pub mod usage;
