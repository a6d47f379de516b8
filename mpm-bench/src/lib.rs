//! # mpm-bench
//!
//! The benchmark harness of the MPM parallelisation study. The `mpm` program it runs, the
//! JSON summary it reads and the pinning code both use live in the crate `mpm-cli`.
//!
//! * campaigns ([`topology`], [`matrix`], [`runner`], [`record`], [`manifest`]): runs
//!   campaigns of `mpm` processes over models x threads x strategies x optimisation levels,
//!   pinned the way the user asks, and records every run to CSV.
//! * analysis ([`stats`], [`figures`], [`claims`], [`regress`], [`report`], [`bandwidth`]):
//!   medians with bootstrap intervals, speedup and efficiency (paper Eqs. 19-20), the paper's
//!   Figures 7-14, a verdict on each of its claims C1-C6, a CI gate on parallel efficiency,
//!   hardware comparison reports and the STREAM-triad bandwidth ceiling; [`paired`]:
//!   parallel efficiency as paired ratios of interleaved blocks in one process, for noisy hosts.

pub mod bandwidth;
pub mod claims;
pub mod figures;
pub mod manifest;
pub mod matrix;
pub mod paired;
pub mod record;
pub mod regress;
pub mod report;
pub mod runner;
pub mod stats;
pub mod topology;
