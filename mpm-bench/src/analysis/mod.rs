//! The analysis layer: numbers and verdicts from recorded campaigns.
//!
//! * [`results`]: campaign folders read from disk;
//! * [`stats`]: medians, bootstrap intervals, speedup and efficiency per configuration;
//! * [`traffic`]: the bytes an MPM step moves per stage;
//! * [`hybrid`]: MPI ranks x threads: speedup and efficiency against total cores;
//! * [`ratio`]: campaign B over campaign A on their matching cells, headline per model;
//! * [`claims`]: the paper's claims C1-C6 tested; [`regress`]: the CI gate;
//! * [`calibrate`]: the gate's own false-alarm rate and detection power, measured by running
//!   its campaign (clean and with an injected slowdown) on this host;
//! * [`paired`]: statistics of the paired design (intervals over processes, the comparison
//!   of two campaigns, `mpm-bench paired`'s report);
//! * [`imbalance`]: DD work imbalance of uniform and balanced cuts predicted over a run.
//!
//! It reads what the campaign and machine layers record and draws nothing.

pub mod calibrate;
pub mod claims;
pub mod hybrid;
pub mod imbalance;
pub mod paired;
pub mod ratio;
pub mod regress;
pub mod results;
pub mod select;
pub mod stats;
pub mod traffic;
