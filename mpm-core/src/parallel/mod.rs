//! The parallel primitives of the solver: a [`Team`] of the workers of a pool (one per pool
//! thread) that runs a whole time step as one parallel region, the [`Exec`] that runs the
//! step's phases on it, and [`Exec::for_each_chunk_mut`], which hands worker `w` part `w` of
//! shared arrays.
//!
//! Every parallel phase follows one pattern: worker `w` of `T` runs share `w` once, on pool
//! thread `w`, and owns part `w` of a fixed [`Split`] of the arrays it writes (a particle
//! chunk, an array-expansion copy, a domain-decomposition sub-grid, a range of node rows).
//! The split depends only on `T` and the array sizes, never on timing, so a given strategy
//! and thread count reproduce bitwise.
//!
//! The public API is safe:
//!
//! * [`Team::region`] is the only way into a parallel region, on the pool the team was built
//!   with. It refuses a second entry while a region runs, and returns (or unwinds) only after
//!   every worker has left, whatever the region's closure does, panics included.
//! * [`Exec::run`] runs a phase and returns after every share finished (a barrier); a panic
//!   in any share is re-raised on the caller after the other shares finished.
//! * [`Exec::for_each_chunk_mut`] checks the split once per phase and hands each worker its
//!   own `&mut` part; no caller needs `unsafe`.
//! * [`Exec::tally`] gives the shares per-worker [`Counters`] to add their work to (once per
//!   share, on lines the worker owns; [`crate::work`] says what is counted).
//!
//! The unsafe code lives in `crew.rs` (the team's protocol: the phase closure is shared with
//! the workers through a raw pointer; its lifetime is guarded by the barrier) and in
//! `disjoint.rs` (a slice shared by the workers of a phase, reached part by part).
//! `sync.rs` picks the atomics and cells the protocol uses: std's in normal builds, loom's
//! model-checked ones under `--cfg loom` (`RUSTFLAGS="--cfg loom" cargo test -p mpm-core
//! --lib parallel::`).

mod crew;
mod disjoint;
mod exec;
mod sync;
mod tally;
mod team;

pub(crate) use disjoint::DisjointSlice;
pub use disjoint::{ChunkSet, Parts, Split, Table, TableRows};
pub use exec::Exec;
pub use tally::{Counters, Tally, LANES};
pub use team::{RegionError, Team};

use std::ops::Range;

/// Part `j` of `n` items split into `parts` contiguous, nearly equal ranges, in order.
///
/// The ranges cover `0..n` exactly once (tested below); part sizes differ by at most one;
/// both ends grow with `j`, so parts of different `j` never overlap.
#[inline]
pub fn partition(n: usize, parts: usize, j: usize) -> Range<usize> {
    debug_assert!(j < parts);
    let start = (n as u128 * j as u128 / parts as u128) as usize;
    let end = (n as u128 * (j as u128 + 1) / parts as u128) as usize;
    start..end
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::*;

    #[test]
    fn partition_covers_every_index_exactly_once() {
        for n in [0usize, 1, 2, 7, 16, 100, 56_056, 1_000_003] {
            for parts in 1..=12 {
                let mut next = 0;
                for j in 0..parts {
                    let r = partition(n, parts, j);
                    assert_eq!(r.start, next, "n={n} parts={parts} j={j}");
                    assert!(r.len() <= n / parts + 1);
                    next = r.end;
                }
                assert_eq!(next, n);
            }
        }
    }
}
