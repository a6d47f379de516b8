//! Ctrl-C / SIGTERM ([`install_interrupt_handler`]): the run in progress is stopped and not
//! recorded; every finished run is already in the CSV, so the campaign resumes later. A
//! second Ctrl-C kills the live child process, cancels this invocation's Slurm jobs and
//! exits at once.

use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::{Arc, OnceLock};

// ------------------------------------------------------------------------------------------
// Interrupts
// ------------------------------------------------------------------------------------------

static INTERRUPTED: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// Install (once per process) a Ctrl-C / SIGTERM handler that raises the returned flag; a
/// second Ctrl-C exits at once (every finished row is already on disk).
pub fn install_interrupt_handler() -> Arc<AtomicBool> {
    INTERRUPTED
        .get_or_init(|| {
            let flag = Arc::new(AtomicBool::new(false));
            let count = Arc::new(AtomicUsize::new(0));
            let f = flag.clone();
            let result = ctrlc::set_handler(move || {
                f.store(true, Ordering::SeqCst);
                if count.fetch_add(1, Ordering::SeqCst) >= 1 {
                    crate::campaign::exec::process::kill_live_child();
                    super::slurm::cancel_submitted();
                    eprintln!("\ninterrupted twice: exiting now (finished rows are in the CSV)");
                    std::process::exit(130);
                }
                eprintln!("\ninterrupt: stopping after cleaning up the current run (Ctrl-C again to quit at once)");
            });
            if let Err(e) = result {
                eprintln!("warning: cannot install the Ctrl-C handler: {e}");
            }
            flag
        })
        .clone()
}
