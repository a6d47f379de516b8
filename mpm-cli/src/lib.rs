//! # mpm-cli
//!
//! The `mpm` program (`src/bin/mpm/`: one simulation from the command line) and what it
//! shares with the benchmark harness `mpm-bench`:
//!
//! * [`summary`]: the JSON summary of a run, one serde type that `mpm` writes and the
//!   harness reads back (the interface between the two programs);
//! * [`pinning`]: the rayon pool of a run with worker `j` pinned to CPU `j`, the workers'
//!   placement read back, and the one CPU-list parser;
//! * [`vtk`]: VTU snapshots and a `.pvd` collection for ParaView;
//! * [`picture`]: the embedded font of every figure and the radiograph-style view of the
//!   debris cloud;
//! * [`atomic`]: atomic file writes.
//!
//! Pinning and measurement policy (affinity, `/proc/self/status`) live here; the solver crate
//! `mpm-core` has no OS code.

pub mod atomic;
pub mod picture;
pub mod pinning;
pub mod summary;
pub mod vtk;
