//! The one place where workers of a parallel phase write into shared arrays.
//!
//! Every parallel phase of the solver is a [`rayon::ThreadPool::broadcast`]: worker `j` of
//! `T` runs once and owns part `j` of a fixed partition (a particle chunk, an array-expansion
//! copy, a domain-decomposition patch, a range of node rows). Rust cannot see from a shared
//! `Fn` closure that those parts are disjoint, so [`DisjointSlice`] hands out the parts
//! through a raw pointer. Its methods are `unsafe`; each caller states in a `// SAFETY:`
//! comment why no two workers touch the same element, and the strategy-equivalence tests
//! (every strategy against the serial oracle at 1-8 threads, plus bitwise reproducibility)
//! fail if a partition ever overlaps.
//!
//! [`partition`] is the partition every phase uses.

use std::marker::PhantomData;
use std::ops::Range;

/// Part `j` of `n` items split into `parts` contiguous, nearly equal ranges, in order.
///
/// The ranges cover `0..n` exactly once (tested below); part sizes differ by at most one.
#[inline]
pub fn partition(n: usize, parts: usize, j: usize) -> Range<usize> {
    debug_assert!(j < parts);
    let start = (n as u128 * j as u128 / parts as u128) as usize;
    let end = (n as u128 * (j as u128 + 1) / parts as u128) as usize;
    start..end
}

/// A mutable slice shared by the workers of one parallel phase, each of which writes only
/// elements no other worker reads or writes during that phase.
pub struct DisjointSlice<'a, T> {
    ptr: *mut T,
    len: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: a `DisjointSlice` is only a capability to reach elements of a slice that is
// exclusively borrowed for 'a; sending or sharing it between threads is sound for `T: Send`
// because every access goes through the `unsafe` methods below, whose callers guarantee
// that no element is reached by two threads at once.
unsafe impl<T: Send> Sync for DisjointSlice<'_, T> {}
// SAFETY: as above.
unsafe impl<T: Send> Send for DisjointSlice<'_, T> {}

impl<'a, T> DisjointSlice<'a, T> {
    /// Borrow `slice` exclusively for the phase.
    pub fn new(slice: &'a mut [T]) -> Self {
        Self { ptr: slice.as_mut_ptr(), len: slice.len(), _borrow: PhantomData }
    }

    /// Number of elements.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the slice is empty.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// The sub-slice `range`.
    ///
    /// # Safety
    /// While the returned slice is alive, no other thread (and no other returned reference)
    /// may read or write any element of `range`.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn range_mut(&self, range: Range<usize>) -> &'a mut [T] {
        assert!(range.start <= range.end && range.end <= self.len, "range out of bounds");
        // SAFETY: in bounds (checked above); exclusivity is the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(range.start), range.end - range.start) }
    }

    /// Element `i`.
    ///
    /// # Safety
    /// While the returned reference is alive, no other thread may read or write element `i`.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn get_mut(&self, i: usize) -> &'a mut T {
        assert!(i < self.len, "index out of bounds");
        // SAFETY: in bounds (checked above); exclusivity is the caller's contract.
        unsafe { &mut *self.ptr.add(i) }
    }
}

#[cfg(test)]
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

    #[test]
    fn workers_writing_their_parts_fill_the_slice_once() {
        let pool = rayon::ThreadPoolBuilder::new().num_threads(5).build().unwrap();
        let mut data = vec![0u32; 1001];
        {
            let shared = DisjointSlice::new(&mut data);
            pool.broadcast(|ctx| {
                let r = partition(shared.len(), ctx.num_threads(), ctx.index());
                // SAFETY: partition parts are disjoint and each broadcast index runs once.
                let part = unsafe { shared.range_mut(r) };
                for v in part {
                    *v += 1 + ctx.index() as u32;
                }
            });
        }
        for (i, v) in data.iter().enumerate() {
            let owner = (0..5).find(|&j| partition(1001, 5, j).contains(&i)).unwrap();
            assert_eq!(*v, 1 + owner as u32);
        }
    }
}
