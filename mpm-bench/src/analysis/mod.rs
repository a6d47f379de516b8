//! The analysis layer: numbers and verdicts from recorded campaigns.
//!
//! * [`results`]: campaign folders read from disk;
//! * [`stats`]: medians, bootstrap intervals, speedup and efficiency per configuration;
//! * [`traffic`]: the bytes an MPM step moves per stage;
//! * [`hybrid`]: MPI ranks x threads: speedup and efficiency against total cores;
//! * [`ratio`]: campaign B over campaign A on their matching cells, headline per model;
//! * [`claims`]: the paper's claims C1-C6 tested; [`regress`]: the CI gate against a stored
//!   baseline; [`ab`]: the CI gate on two builds measured side by side; [`work_snapshot`]:
//!   the work counters against a committed snapshot;
//! * [`strategies`]: the strategies used since the paper against DD and AE, and the
//!   measured choice of strategy per model;
//! * [`calibrate`]: the gate's own false-alarm rate and detection power, from the campaigns
//!   `crate::campaign::measure::calibrate` ran on this host (clean and with an injected
//!   slowdown);
//! * [`estimate`]: a point estimate with its interval;
//! * [`paired`]: statistics of the paired design (intervals over processes, the comparison
//!   of two campaigns); [`paired_report`]: `mpm-bench paired`'s report.
//!
//! It reads what the campaign and machine layers record (and what the campaign layer's
//! measurements return) and draws nothing; it runs no solver.

pub mod ab;
pub mod calibrate;
pub mod calibrate_ab;
pub mod claims;
pub mod estimate;
pub mod hybrid;
pub mod paired;
pub mod paired_report;
pub mod ratio;
pub mod regress;
pub mod results;
pub mod select;
pub mod stats;
pub mod strategies;
pub mod traffic;
pub mod work_snapshot;
