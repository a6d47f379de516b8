//! [`Exec`]: runs a phase on every worker, on the calling thread (serial) or on the crew of
//! the current parallel region.

use super::crew::Crew;
use super::disjoint::ChunkSet;
use super::tally::{Counters, Tally};
use std::marker::PhantomData;

/// Runs a phase on every worker: share `w` once for each `w` in `0..workers()`, and returns
/// when all shares have finished (a barrier).
///
/// Made by [`Exec::serial`] (one share, on the calling thread) or handed to the closure of
/// [`Team::region`](super::Team::region) (share `w` on pool thread `w`). An `Exec` is neither
/// `Send` nor `Sync`: it stays on the thread that drives the phases, and a phase's shares
/// (which must be `Sync`) cannot capture it, so phases never nest.
pub struct Exec<'a> {
    kind: Kind<'a>,
    workers: usize,
    /// Where the shares' [`Tally`] adds (none: the tally counts nothing).
    counters: Option<&'a Counters>,
    _driver_only: PhantomData<*const ()>,
}

#[derive(Clone, Copy)]
enum Kind<'a> {
    Serial,
    Crew(&'a Crew),
}

impl Exec<'static> {
    /// One share, run on the calling thread.
    pub fn serial() -> Self {
        Self { kind: Kind::Serial, workers: 1, counters: None, _driver_only: PhantomData }
    }
}

impl<'a> Exec<'a> {
    /// The executor of `crew`'s current region: only [`Team::region`](super::Team::region)
    /// makes one, on the region's driver.
    pub(super) fn team(crew: &'a Crew) -> Self {
        Self { kind: Kind::Crew(crew), workers: crew.workers(), counters: None, _driver_only: PhantomData }
    }

    /// This executor with its shares' tallies adding to `counters` (one row per worker).
    pub fn counting<'b>(&'b self, counters: &'b Counters) -> Exec<'b> {
        assert!(
            counters.workers() >= self.workers,
            "{} worker(s) counted by {} row(s) of counters",
            self.workers,
            counters.workers()
        );
        Exec { kind: self.kind, workers: self.workers, counters: Some(counters), _driver_only: PhantomData }
    }

    /// What a share adds its counts to: this executor's counters, if it has any. `Copy` and
    /// `Sync`, so a phase's closure captures it.
    pub fn tally(&self) -> Tally<'a> {
        Tally::of(self.counters)
    }

    /// Number of workers (shares per phase).
    pub fn workers(&self) -> usize {
        self.workers
    }

    /// Run `f(w)` for every worker `w`, worker `w` on pool thread `w`; return when all have
    /// finished. A panic in a share is re-raised here after every share has finished.
    #[inline]
    pub fn run<F: Fn(usize) + Sync>(&self, f: F) {
        match self.kind {
            Kind::Serial => f(0),
            // SAFETY: `Crew::run` must be called by the driver of the crew's current region,
            // not from inside one of its phases. An `Exec` of this kind is made only by
            // `Team::region`, on its driver, and lives no longer than the region; it cannot
            // leave the driver's thread (neither `Send` nor `Sync`), and a share cannot
            // capture it (shares are `Sync`), so this call is the driver's, between phases.
            Kind::Crew(crew) => unsafe { crew.run(&f) },
        }
    }

    /// Run a phase in which worker `w` gets part `w` of every array in `chunks` (a
    /// [`Parts`](super::Parts) made by [`Split::of`](super::Split::of), or a tuple of them):
    /// `f(w, part)`.
    ///
    /// The splits are checked before the phase starts (a split whose parts would overlap or
    /// leave the array panics here), so each element is reached by one worker only.
    #[inline]
    pub fn for_each_chunk_mut<C, F>(&self, chunks: C, f: F)
    where
        C: ChunkSet,
        F: Fn(usize, C::Part) + Sync,
    {
        let workers = self.workers;
        chunks.check(workers);
        self.run(|w| {
            // SAFETY: `check` passed for `workers`, and `run` calls share w exactly once for
            // every w in 0..workers, so part w is taken once. `chunks` was moved into this
            // call, so no part is taken again after the phase while its borrow lasts.
            let part = unsafe { chunks.part(w, workers) };
            f(w, part);
        });
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::super::{partition, Split, Team};
    use super::*;

    /// Every worker writes its own part of three arrays cut three ways; each element is
    /// written once, by its owner, with the serial and the team executors.
    #[test]
    fn every_element_is_written_once_by_its_owner() {
        for workers in [1, 2, 3, 5] {
            let n = 1001;
            let mut even = vec![0usize; n];
            let mut blocks = vec![0usize; 4 * workers];
            let offsets: Vec<usize> = (0..=workers).map(|w| w * w).collect();
            let mut ragged = vec![0usize; workers * workers];
            let mut phase = |exec: &Exec<'_>| {
                exec.for_each_chunk_mut(
                    (
                        Split::Even.of(&mut even),
                        Split::Blocks(4).of(&mut blocks),
                        Split::Offsets(&offsets).of(&mut ragged),
                    ),
                    |w, (e, b, r)| {
                        for v in e.iter_mut().chain(b).chain(r) {
                            *v += w + 1;
                        }
                    },
                )
            };
            if workers == 1 {
                phase(&Exec::serial());
            } else {
                Team::new(crate::testing::pool(workers)).region(phase).unwrap();
            }
            for (i, v) in even.iter().enumerate() {
                let owner = (0..workers).find(|&w| partition(n, workers, w).contains(&i)).unwrap();
                assert_eq!(*v, owner + 1, "{workers} workers, even element {i}");
            }
            for (i, v) in blocks.iter().enumerate() {
                assert_eq!(*v, i / 4 + 1, "{workers} workers, block element {i}");
            }
            for (i, v) in ragged.iter().enumerate() {
                let owner = (0..workers).find(|&w| (offsets[w]..offsets[w + 1]).contains(&i)).unwrap();
                assert_eq!(*v, owner + 1, "{workers} workers, ragged element {i}");
            }
        }
    }
}
