//! The campaign layer: from a preset to one CSV row per `mpm` run, in four sub-layers (each
//! uses only those above it in this list, and the machine layer):
//!
//! * [`plan`]: the TOML presets ([`plan::preset`]), a preset and command-line overrides
//!   resolved into runs in a seeded order ([`plan::matrix`]), the memory guard
//!   ([`plan::memory`]);
//! * [`store`]: the CSV row, made of typed parts ([`store::record`]), its columns derived
//!   from the types ([`store::columns`], [`store::filled`]), the file read and appended
//!   ([`store::csv`]), rows of older schemas ([`store::legacy`]), the manifest of the
//!   machine and software ([`store::manifest`]) and the folder's lock ([`store::lock`]);
//! * [`exec`]: one run: the solver binaries ([`exec::solver`]), the child process and the
//!   mock ([`exec::process`]), the MPI launcher ([`exec::launcher`]), the host's load around
//!   it ([`exec::watch`]), and the run recorded as a row ([`exec::run`]); the duration
//!   estimate of a campaign ([`exec::estimate`]);
//! * [`schedule`]: where the runs run, behind one [`schedule::Scheduler`]: here
//!   ([`schedule::local`]) or as Slurm jobs ([`schedule::slurm`], [`schedule::job`]), over
//!   the state every scheduler shares ([`schedule::state`]); a session ([`schedule::execute`]).
//!
//! And [`measure`]: the measurements that run the solver in this process rather than as a
//! campaign (`mpm-bench paired`, `mpm-bench imbalance`) or run campaigns to measure the
//! gate (`mpm-bench calibrate`).
//!
//! It uses the machine layer ([`crate::machine`]) and nothing of analysis or report, except
//! [`measure::calibrate`], which runs the gate's campaigns and hands them to the analysis.

pub mod exec;
pub mod measure;
pub mod plan;
pub mod schedule;
pub mod store;
