//! One run: the solver binary, the child process (or the mock), the MPI launcher, the host
//! watch, and the run recorded as a row.

pub mod builds;
pub mod estimate;
pub mod launcher;
pub mod process;
pub mod run;
pub mod solver;
pub mod watch;
