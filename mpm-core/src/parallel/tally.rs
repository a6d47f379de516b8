//! Per-worker counters that the shares of a phase add to: accounting of the work each
//! worker did ([`crate::work`]), not part of the team's protocol.
//!
//! Every worker has its own row of [`LANES`] counters on cache lines of its own (a worker
//! adds to its row once per phase, so rows sharing a line would turn each addition into a
//! coherence miss). A share adds through a [`Tally`] (`Copy` and `Sync`, so a phase's closure
//! can capture it); the driver reads the rows between phases, after the phase's barrier has
//! ordered every share's additions before it, so relaxed atomics are enough. Like the team's
//! busy counters these are std atomics also under loom.

use std::sync::atomic::{AtomicU64, Ordering};

/// Counters per worker.
pub const LANES: usize = 8;

/// One worker's counters, alone on its cache lines.
#[repr(align(128))]
struct Row([AtomicU64; LANES]);

impl Default for Row {
    fn default() -> Self {
        Self(std::array::from_fn(|_| AtomicU64::new(0)))
    }
}

/// [`LANES`] counters for each of a fixed number of workers.
pub struct Counters {
    rows: Box<[Row]>,
}

impl std::fmt::Debug for Counters {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Counters").field("workers", &self.rows.len()).finish()
    }
}

impl Counters {
    /// Zeroed counters for `workers` workers (the one allocation; none afterwards).
    pub fn new(workers: usize) -> Self {
        Self { rows: (0..workers).map(|_| Row::default()).collect() }
    }

    /// Workers counted.
    pub fn workers(&self) -> usize {
        self.rows.len()
    }

    /// Worker `w`'s counters, set back to zero. Call between phases (not from a share).
    pub fn take(&self, w: usize) -> [u64; LANES] {
        std::array::from_fn(|k| self.rows[w].0[k].swap(0, Ordering::Relaxed))
    }
}

/// What a phase's shares add to: the counters of the executor that runs the phase, or
/// nothing (an executor without counters).
#[derive(Clone, Copy, Debug, Default)]
pub struct Tally<'a> {
    counters: Option<&'a Counters>,
}

impl<'a> Tally<'a> {
    /// A tally into `counters`.
    pub(super) fn of(counters: Option<&'a Counters>) -> Self {
        Self { counters }
    }

    /// Add `value` to counter `lane` of worker `w` (nothing when the tally counts nothing).
    /// Once per share and quantity, never per particle: one relaxed addition to a line the
    /// worker owns.
    #[inline]
    pub fn add(&self, w: usize, lane: usize, value: u64) {
        if let Some(c) = self.counters {
            if value != 0 {
                c.rows[w].0[lane].fetch_add(value, Ordering::Relaxed);
            }
        }
    }

    /// Whether the additions go anywhere.
    pub fn counts(&self) -> bool {
        self.counters.is_some()
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::super::{Exec, Team};
    use super::*;

    /// Every share's additions reach its own row, in a team region and serially; a tally
    /// without counters drops them; `take` empties the row.
    #[test]
    fn shares_add_to_their_own_rows() {
        for workers in [1, 2, 3] {
            let counters = Counters::new(workers);
            let phase = |exec: &Exec<'_>| {
                let exec = exec.counting(&counters);
                let tally = exec.tally();
                exec.run(|w| {
                    tally.add(w, 0, 10 + w as u64);
                    tally.add(w, 3, 1);
                });
                exec.run(|w| tally.add(w, 3, 1));
            };
            if workers == 1 {
                phase(&Exec::serial());
            } else {
                Team::new(crate::testing::pool(workers)).region(phase).unwrap();
            }
            for w in 0..workers {
                let row = counters.take(w);
                assert_eq!((row[0], row[3]), (10 + w as u64, 2), "{workers} workers, worker {w}");
                assert_eq!(counters.take(w), [0; LANES]);
            }
        }
        let none = Exec::serial().tally();
        assert!(!none.counts());
        none.add(0, 0, 1);
    }
}
