//! # mpm-bench
//!
//! The benchmark harness of the MPM parallelisation study, and the `mpm` program.
//!
//! * `mpm` ([`summary`], [`vtk`], [`pinning`]): runs one simulation, pins its workers,
//!   writes the JSON summary and VTU snapshots.
//! * `mpm-bench` ([`topology`], [`matrix`], [`runner`], [`record`], [`manifest`]): runs
//!   campaigns of `mpm` processes over models x threads x strategies x optimisation levels,
//!   pinned the way the user asks, and records every run to CSV.
//!
//! Pinning and measurement policy live here; the solver crate `mpm-core` has no OS code.

pub mod manifest;
pub mod matrix;
pub mod picture;
pub mod pinning;
pub mod record;
pub mod runner;
pub mod summary;
pub mod topology;
pub mod vtk;
