//! The one interface of the places runs run in.

use super::state::CampaignState;
use anyhow::Result;

/// Where the runs of a campaign run: here ([`super::local::Local`]) or as Slurm jobs
/// ([`super::slurm::Slurm`]). A scheduler runs (or submits and collects) the runs of
/// `state`'s plan still to do and records each finished run's row in `state`'s books, in
/// any order; it stops early when the session is interrupted (saying so in the books'
/// counts).
pub trait Scheduler {
    /// Run the runs still to do.
    fn run_all(&mut self, state: &mut CampaignState<'_>) -> Result<()>;
}
