//! Ctrl-C and SIGTERM: the first asks a run to stop between steps, with the error it ends
//! with (exit status 130, no summary written); a second ends the process at once.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Raised when the user interrupts the run.
#[derive(Debug, thiserror::Error)]
#[error("interrupted at step {0} (Ctrl-C or SIGTERM); no summary written")]
pub struct Interrupted(pub u64);

/// What a second interrupt prints before the process ends.
pub const AT_ONCE: &str = "a second interrupt: mpm stops at once, writing nothing more";

/// Ctrl-C, SIGTERM or SIGHUP stops the run between steps and writes nothing; a second one
/// ends the process at once (exit status 130), whatever it is doing (a long step, a
/// checkpoint being written: the checkpoint folder keeps its last complete one).
pub fn install_interrupt_handler() -> Arc<AtomicBool> {
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&interrupted);
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            eprintln!("{AT_ONCE}");
            std::process::exit(130);
        }
    });
    interrupted
}
