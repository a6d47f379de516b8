//! Signals: Ctrl-C (SIGINT), SIGHUP and SIGTERM ask a run to stop between steps, SIGUSR1 and
//! SIGTERM ask a run with a checkpoint folder for a last checkpoint before it stops (a batch
//! system's time limit: `sbatch --signal=USR1@120`, or its SIGTERM); a second SIGINT, SIGHUP
//! or SIGTERM ends the process at once.
//!
//! | signal            | run with `--checkpoint-dir`                  | run without          |
//! |-------------------|----------------------------------------------|----------------------|
//! | SIGTERM           | last checkpoint after the step, exit 75      | stop, exit 130       |
//! | SIGUSR1           | last checkpoint after the step, exit 75      | ignored (a note)     |
//! | SIGINT, SIGHUP    | stop between steps, exit 130                 | stop, exit 130       |
//! | a second SIGINT, SIGHUP or SIGTERM | at once, exit 130           | at once, exit 130    |
//!
//! Before the run steps (its set-up) SIGINT, SIGHUP and SIGTERM end it at once (exit 130);
//! a SIGUSR1 then is kept for the loop. The signals are blocked in every thread and taken by
//! one thread that waits for them ([`listen`]): no code runs inside a signal handler.

use nix::sys::signal::{SigSet, Signal};
use std::sync::atomic::{AtomicBool, AtomicU8, Ordering};

/// Raised when the user interrupts the run.
#[derive(Debug, thiserror::Error)]
#[error("interrupted at step {0} (Ctrl-C or SIGTERM); no summary written")]
pub struct Interrupted(pub u64);

/// The exit status of a run stopped after its last checkpoint ([`LastCheckpoint`]): 75,
/// `EX_TEMPFAIL` of `sysexits.h` ("try again later": `mpm resume` continues it).
pub const LAST_CHECKPOINT_EXIT: i32 = 75;

/// Raised when a run stops on SIGTERM or SIGUSR1 after writing its last checkpoint.
#[derive(Debug, thiserror::Error)]
#[error(
    "stopped at step {step} on SIGTERM or SIGUSR1 after writing its last checkpoint into {dir}; \
     `mpm resume {dir}` continues the run; no summary written"
)]
pub struct LastCheckpoint {
    /// The step of the last checkpoint.
    pub step: u64,
    /// The checkpoint folder.
    pub dir: String,
}

/// What a second interrupt prints before the process ends.
pub const AT_ONCE: &str = "a second interrupt: mpm stops at once, writing nothing more";

/// No request yet.
const NONE: u8 = 0;
/// SIGTERM: a last checkpoint when the run has a folder for it, else stop.
const TERM: u8 = 1;
/// SIGUSR1: a last checkpoint when the run has a folder for it, else nothing.
const USR1: u8 = 2;
/// SIGINT or SIGHUP: stop.
const INT: u8 = 3;

/// The first request received (one of the constants above).
static REQUEST: AtomicU8 = AtomicU8::new(NONE);
/// Whether the stepping loop has begun (before it, SIGINT, SIGHUP or SIGTERM end at once).
static ARMED: AtomicBool = AtomicBool::new(false);

/// Block SIGINT, SIGHUP, SIGTERM and SIGUSR1 in this thread (and so in every thread started
/// after it: call it first) and take them in a thread of their own. Where they cannot be
/// blocked they keep their default actions (they end the process).
pub fn listen() {
    let mut set = SigSet::empty();
    for s in [Signal::SIGINT, Signal::SIGHUP, Signal::SIGTERM, Signal::SIGUSR1] {
        set.add(s);
    }
    if set.thread_block().is_err() {
        return;
    }
    let _ = std::thread::Builder::new().name("mpm-signals".into()).spawn(move || {
        while let Ok(signal) = set.wait() {
            on_signal(signal);
        }
    });
}

/// Record a signal, or end the process when it asks for that.
fn on_signal(signal: Signal) {
    if signal == Signal::SIGUSR1 {
        // Asking again for the last checkpoint changes nothing.
        let _ = REQUEST.compare_exchange(NONE, USR1, Ordering::SeqCst, Ordering::SeqCst);
        return;
    }
    let kind = if signal == Signal::SIGTERM { TERM } else { INT };
    if !ARMED.load(Ordering::SeqCst) {
        eprintln!("interrupted ({signal}) before the run began stepping: mpm stops at once, writing nothing");
        std::process::exit(130);
    }
    if REQUEST.compare_exchange(NONE, kind, Ordering::SeqCst, Ordering::SeqCst).is_err() {
        eprintln!("{AT_ONCE}");
        std::process::exit(130);
    }
}

/// What the stepping loop asks of the signals received: the run's view of them.
pub struct Requests {
    /// Whether the run has a checkpoint folder (SIGTERM and SIGUSR1 then ask for a last
    /// checkpoint).
    checkpointing: bool,
}

impl Requests {
    /// The stepping loop begins (SIGINT, SIGHUP and SIGTERM no longer end the process at
    /// once), for a run with a checkpoint folder or without.
    pub fn arm(checkpointing: bool) -> Self {
        ARMED.store(true, Ordering::SeqCst);
        Self { checkpointing }
    }

    /// Whether to stop now, without a checkpoint: SIGINT or SIGHUP, or SIGTERM to a run
    /// without a checkpoint folder. A SIGUSR1 to such a run is dropped here, with a note.
    pub fn stop_now(&self) -> bool {
        match REQUEST.load(Ordering::SeqCst) {
            INT => true,
            TERM => !self.checkpointing,
            USR1 if !self.checkpointing => {
                if REQUEST.compare_exchange(USR1, NONE, Ordering::SeqCst, Ordering::SeqCst).is_ok() {
                    eprintln!(
                        "note: SIGUSR1 asks for a last checkpoint, but this run has no --checkpoint-dir: it goes on"
                    );
                }
                false
            }
            _ => false,
        }
    }

    /// Whether this process was asked for a last checkpoint (SIGTERM or SIGUSR1 to a run
    /// with a checkpoint folder).
    pub fn last_checkpoint(&self) -> bool {
        self.checkpointing && matches!(REQUEST.load(Ordering::SeqCst), TERM | USR1)
    }
}
