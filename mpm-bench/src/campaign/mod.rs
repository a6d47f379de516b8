//! The campaign layer: from a preset to one CSV row per `mpm` run.
//!
//! * [`preset`]: the TOML presets and their value types;
//! * [`matrix`]: a preset and command-line overrides resolved into runs, in a seeded order;
//! * [`memory`]: the memory guard (sizes and estimates from `mpm-core`);
//! * [`solver`]: building, locating and hashing the `mpm` binaries;
//! * [`process`]: one run as a child process (and the mock runner for tests);
//! * [`paired`]: `mpm-bench paired`, the paired design measured in the harness's own process;
//! * [`launcher`]: the MPI launcher template of runs with several ranks;
//! * [`runner`]: the loop over the runs, with resume and Ctrl-C;
//! * [`scheduler`]: where the runs run: here, or as Slurm batch jobs ([`slurm`]: submit,
//!   wait, collect, cancel; [`job`]: one run on its node, `mpm-bench job FILE`);
//! * [`watch`]: the host's load and calibration around each run (`host_noisy`);
//! * [`record`]: the CSV row, made of typed parts, its columns derived by [`columns`];
//!   [`legacy`]: rows of CSV schemas 1-5; [`manifest`]: the machine and software of a
//!   campaign.
//!
//! It uses the machine layer ([`crate::machine`]) and nothing of analysis or report.

pub mod columns;
pub mod job;
pub mod launcher;
pub mod legacy;
pub mod lock;
pub mod manifest;
pub mod matrix;
pub mod memory;
pub mod paired;
pub mod preset;
pub mod process;
pub mod record;
pub mod runner;
pub mod scheduler;
pub mod slurm;
pub mod solver;
pub mod watch;
