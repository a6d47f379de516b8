//! The machine layer: what the harness knows about the computer it runs on, independent of
//! any campaign.
//!
//! * [`topology`]: packages, NUMA nodes, cores, PUs and caches as hwloc sees them;
//! * [`placement`]: the pinning policies and the CPU of each worker of a run;
//! * [`fingerprint`]: the machine's identity (the `results/<fingerprint>/` folder) and the
//!   machine part of a manifest;
//! * [`bandwidth`]: the memory-bandwidth ceiling (STREAM triad);
//! * [`load`]: the host's load around a run, the calibration, and the `host_noisy` rule.
//!
//! It uses nothing of the campaign, analysis or report layers.

pub mod bandwidth;
pub mod fingerprint;
pub mod load;
pub mod placement;
pub mod topology;
