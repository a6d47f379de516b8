//! Ctrl-C: the handler that asks a run to stop between steps, and the error it ends with
//! (exit status 130, no summary written).

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;

/// Raised when the user interrupts the run.
#[derive(Debug, thiserror::Error)]
#[error("interrupted at step {0} (Ctrl-C); no summary written")]
pub struct Interrupted(pub u64);

/// Ctrl-C stops the run between steps and writes nothing; a second Ctrl-C ends the process
/// at once.
pub fn install_interrupt_handler() -> Arc<AtomicBool> {
    let interrupted = Arc::new(AtomicBool::new(false));
    let flag = Arc::clone(&interrupted);
    let _ = ctrlc::set_handler(move || {
        if flag.swap(true, Ordering::SeqCst) {
            std::process::exit(130);
        }
    });
    interrupted
}
