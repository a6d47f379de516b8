//! Where a campaign's runs run, behind one interface, [`Scheduler`], over the campaign state
//! every scheduler shares ([`state`]: the folder and the runs still to do, the books every
//! finished run is recorded in, the attempts' ids):
//!
//! * [`local::Local`]: here, one fresh child process after another;
//! * [`slurm::Slurm`]: Slurm job arrays, one task per run ([`array`]: the arrays;
//!   [`job`]: the run on its node, `mpm-bench job FILE`).
//!
//! Either way a finished run is one row appended to the campaign's `runs.csv`, and resume,
//! the memory guard, placement and its verification mean the same ([`crate::campaign::exec`]
//! runs one run). [`execute`] is a session: plan, open, schedule, close; [`interrupt`] is
//! Ctrl-C.

pub mod ab;
pub mod array;
pub mod execute;
pub mod interrupt;
pub mod job;
pub mod kind;
pub mod ledger;
pub mod local;
pub mod scheduler;
pub mod slurm;
pub mod state;

pub use execute::execute;
pub use interrupt::install_interrupt_handler;
pub use kind::SchedulerKind;
pub use scheduler::Scheduler;
pub use state::{ExecOptions, ExecSummary};
