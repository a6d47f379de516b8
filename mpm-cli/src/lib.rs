//! # mpm-cli
//!
//! The `mpm` program (`src/bin/mpm/`: one simulation from the command line) and the library
//! it is built from:
//!
//! * [`summary`]: building the JSON summary of a run (the type, [`mpm_spec::Summary`], is
//!   the interface between `mpm` and the harness and lives in `mpm-spec` with the run spec);
//! * [`vtk`]: VTU snapshots and a `.pvd` collection for ParaView;
//! * [`picture`]: the radiograph-style view of the debris cloud and its history;
//! * [`distributed`]: one run over several processes (MPI, behind the solver's exchange).
//!
//! What `mpm` shares with the harness `mpm-bench` (the host's identity, pinned pools, usage,
//! atomic writes, locks, checkpoints, the paired design) is in `mpm-host`; the solver crate
//! `mpm-core` has no OS code.

pub mod distributed;
pub mod picture;
pub mod summary;
pub mod vtk;
