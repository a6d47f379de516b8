//! Shared arrays cut into one part per worker.
//!
//! A phase's closure is a shared `Fn(w)`: Rust cannot see that worker `w` touches only part
//! `w` of an array, so the parts are reached through a raw pointer ([`DisjointSlice`]).
//! The safe way in is [`Exec::for_each_chunk_mut`](super::Exec::for_each_chunk_mut) with a
//! [`Split`]: the split is checked once per phase (parts in bounds, parts of different
//! workers disjoint), and each worker receives its own part exactly once.

use super::partition;
use std::marker::PhantomData;
use std::ops::Range;

/// How an array is cut into one part per worker (`T` workers, part `w` for worker `w`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Split<'s> {
    /// Loop splitting: part `w` is [`partition`]`(len, T, w)`.
    Even,
    /// Loop splitting over rows of the given length: the rows are split as by
    /// [`Split::Even`], part `w` is whole rows. The array length must be a whole number of
    /// rows.
    EvenRows(usize),
    /// Fixed-size blocks: part `w` is `w * size .. (w + 1) * size` (a per-worker copy, a
    /// per-worker table row). The array must hold at least `T` blocks.
    Blocks(usize),
    /// Given boundaries: part `w` is `offsets[w] .. offsets[w + 1]`. `offsets` must have
    /// `T + 1` non-decreasing entries, the last at most the array length.
    Offsets(&'s [usize]),
}

impl<'s> Split<'s> {
    /// Cut `slice` this way.
    pub fn of<T>(self, slice: &mut [T]) -> Parts<'_, 's, T> {
        Parts { slice: DisjointSlice::new(slice), split: self }
    }

    /// Panic unless the parts of `workers` workers lie in `0..len` and are disjoint.
    fn check(&self, len: usize, workers: usize) {
        match *self {
            // `partition` stays in 0..len and both its ends grow with w.
            Split::Even => {}
            Split::EvenRows(row) => {
                assert!(row > 0 && len.is_multiple_of(row), "an array of {len} is not a whole number of rows of {row}");
            }
            Split::Blocks(size) => assert!(
                size.checked_mul(workers).is_some_and(|n| n <= len),
                "{workers} blocks of {size} do not fit in an array of {len}"
            ),
            Split::Offsets(o) => {
                assert_eq!(o.len(), workers + 1, "a split for {workers} workers needs {} offsets", workers + 1);
                assert!(o.windows(2).all(|p| p[0] <= p[1]), "split offsets must not decrease: {o:?}");
                assert!(o[workers] <= len, "split offsets end at {} past the array's {len}", o[workers]);
            }
        }
    }

    /// Part `w` of `workers` for an array of `len` (checked by [`Split::check`]).
    #[inline]
    fn range(&self, len: usize, w: usize, workers: usize) -> Range<usize> {
        match *self {
            Split::Even => partition(len, workers, w),
            Split::EvenRows(row) => {
                let r = partition(len / row, workers, w);
                r.start * row..r.end * row
            }
            Split::Blocks(size) => w * size..(w + 1) * size,
            Split::Offsets(o) => o[w]..o[w + 1],
        }
    }
}

/// An array and its [`Split`]: worker `w` of a phase gets part `w` as a `&mut [T]`.
pub struct Parts<'a, 's, T> {
    slice: DisjointSlice<'a, T>,
    split: Split<'s>,
}

mod sealed {
    /// The workings of a [`ChunkSet`](super::ChunkSet), out of reach outside the crate: the
    /// safety of `part` rests on the checks of this module's types only.
    pub trait Sealed: Sync {
        /// What one worker receives.
        type Part;

        /// Panic unless the parts of `workers` workers are in bounds and pairwise disjoint.
        fn check(&self, workers: usize);

        /// Part `w` of `workers`.
        ///
        /// # Safety
        /// `check` passed for the same `workers`, and part `w` is taken at most once while
        /// the borrow the set was made from lasts.
        unsafe fn part(&self, w: usize, workers: usize) -> Self::Part;
    }
}

/// One or more arrays handed out part by part: a [`Parts`] or a tuple of up to eight.
/// Worker `w` receives part `w` of every member (a `&mut [T]`, or a tuple of them).
pub trait ChunkSet: sealed::Sealed {}

impl<C: sealed::Sealed> ChunkSet for C {}

impl<'a, T: Send> sealed::Sealed for Parts<'a, '_, T> {
    type Part = &'a mut [T];

    fn check(&self, workers: usize) {
        self.split.check(self.slice.len(), workers);
    }

    #[inline]
    unsafe fn part(&self, w: usize, workers: usize) -> &'a mut [T] {
        // SAFETY: the checked split gives different workers disjoint ranges, and the caller
        // takes part w once: no element is reached through two references.
        unsafe { self.slice.range_mut(self.split.range(self.slice.len(), w, workers)) }
    }
}

macro_rules! tuple_chunk_set {
    ($($member:ident $index:tt),+) => {
        impl<$($member: sealed::Sealed),+> sealed::Sealed for ($($member,)+) {
            type Part = ($($member::Part,)+);

            fn check(&self, workers: usize) {
                $(self.$index.check(workers);)+
            }

            #[inline]
            unsafe fn part(&self, w: usize, workers: usize) -> Self::Part {
                // SAFETY: the caller's contract for the tuple is the contract of each member.
                unsafe { ($(self.$index.part(w, workers),)+) }
            }
        }
    };
}

tuple_chunk_set!(A 0, B 1);
tuple_chunk_set!(A 0, B 1, C 2);
tuple_chunk_set!(A 0, B 1, C 2, D 3);
tuple_chunk_set!(A 0, B 1, C 2, D 3, E 4);
tuple_chunk_set!(A 0, B 1, C 2, D 3, E 4, F 5);
tuple_chunk_set!(A 0, B 1, C 2, D 3, E 4, F 5, G 6);
tuple_chunk_set!(A 0, B 1, C 2, D 3, E 4, F 5, G 6, H 7);

/// A column-major table in a slice: `columns` columns of `rows` elements each (the slice's
/// first `rows * columns` elements), cut by rows: worker `w` of `T` receives rows
/// [`partition`]`(rows, T, w)` of every column ([`TableRows`]). Array expansion's per-thread
/// copies read this way: worker `w` sums (and clears) its range of nodes in every copy.
pub struct Table<'a, T> {
    slice: DisjointSlice<'a, T>,
    rows: usize,
    columns: usize,
}

impl<'a, T> Table<'a, T> {
    /// `slice` as `columns` columns of `rows` elements (checked when a phase takes it).
    pub fn of(slice: &'a mut [T], rows: usize, columns: usize) -> Self {
        Self { slice: DisjointSlice::new(slice), rows, columns }
    }
}

/// Worker `w`'s rows of every column of a [`Table`]: one column's part at a time.
pub struct TableRows<'a, T> {
    ptr: *mut T,
    rows: usize,
    columns: usize,
    range: Range<usize>,
    _borrow: PhantomData<&'a mut [T]>,
}

impl<T> TableRows<'_, T> {
    /// Number of columns.
    pub fn columns(&self) -> usize {
        self.columns
    }

    /// This worker's rows of column `j` (the first of them is row `range.start`).
    #[inline]
    pub fn column(&mut self, j: usize) -> &mut [T] {
        assert!(j < self.columns, "column {j} of a table of {}", self.columns);
        // SAFETY: the table's check put every column's rows inside the borrowed slice; the
        // range is this worker's rows, which no other worker's part holds in any column (the
        // ranges of `partition` are disjoint), and `&mut self` keeps one column's slice alive
        // at a time.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(j * self.rows + self.range.start), self.range.len()) }
    }
}

impl<'a, T: Send> sealed::Sealed for Table<'a, T> {
    type Part = TableRows<'a, T>;

    fn check(&self, _workers: usize) {
        assert!(
            self.rows.checked_mul(self.columns).is_some_and(|n| n <= self.slice.len()),
            "{} columns of {} rows do not fit in an array of {}",
            self.columns,
            self.rows,
            self.slice.len()
        );
    }

    #[inline]
    unsafe fn part(&self, w: usize, workers: usize) -> TableRows<'a, T> {
        // No reference is made here: the part keeps the raw pointer, and `TableRows::column`
        // makes a slice of worker w's rows of one column only (in bounds by `check`; disjoint
        // from every other worker's rows, `partition`'s ranges being disjoint; part w taken
        // once by the caller's contract).
        let range = partition(self.rows, workers, w);
        TableRows { ptr: self.slice.ptr, rows: self.rows, columns: self.columns, range, _borrow: PhantomData }
    }
}

/// A mutable slice shared by the workers of one parallel phase, each of which reaches only
/// elements no other worker reads or writes during that phase.
///
/// Crate-internal: [`Parts`] uses it under a checked [`Split`]; the domain decomposition uses
/// it directly where a worker's elements are not one range (see the `SAFETY` comments there).
pub(crate) struct DisjointSlice<'a, T> {
    ptr: *mut T,
    len: usize,
    _borrow: PhantomData<&'a mut [T]>,
}

// SAFETY: a `DisjointSlice` is a capability to reach elements of a slice that is exclusively
// borrowed for 'a. Sharing it between threads hands `&mut T` to other threads, which is sound
// for `T: Send`, and every access goes through the `unsafe` methods below, whose callers
// guarantee that no element is reached by two threads (or two live references) at once.
unsafe impl<T: Send> Sync for DisjointSlice<'_, T> {}
// SAFETY: as above.
unsafe impl<T: Send> Send for DisjointSlice<'_, T> {}

impl<'a, T> DisjointSlice<'a, T> {
    /// Borrow `slice` exclusively for the phase.
    pub(crate) fn new(slice: &'a mut [T]) -> Self {
        Self { ptr: slice.as_mut_ptr(), len: slice.len(), _borrow: PhantomData }
    }

    /// Number of elements.
    pub(crate) fn len(&self) -> usize {
        self.len
    }

    /// The sub-slice `range`.
    ///
    /// # Safety
    /// No element of `range` is reached through another reference (on any thread) while
    /// the returned slice is alive.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn range_mut(&self, range: Range<usize>) -> &'a mut [T] {
        assert!(range.start <= range.end && range.end <= self.len, "range out of bounds");
        // SAFETY: in bounds (checked above) of a slice borrowed exclusively for 'a;
        // exclusivity among the workers is the caller's contract.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(range.start), range.end - range.start) }
    }

    /// Element `i`.
    ///
    /// # Safety
    /// Element `i` is not reached through another reference (on any thread) while the
    /// returned reference is alive.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub(crate) unsafe fn get_mut(&self, i: usize) -> &'a mut T {
        assert!(i < self.len, "index out of bounds");
        // SAFETY: in bounds (checked above); exclusivity is the caller's contract.
        unsafe { &mut *self.ptr.add(i) }
    }
}

#[cfg(all(test, not(loom)))]
mod tests {
    use super::sealed::Sealed;
    use super::*;

    /// For every split kind and worker count: the checked parts are in bounds, pairwise
    /// disjoint and (for the covering kinds) cover the array.
    #[test]
    fn checked_splits_give_disjoint_parts() {
        let offsets = [0usize, 0, 3, 3, 10, 17];
        for workers in 1..=5 {
            let o = &offsets[..=workers];
            for (split, len, covers) in [
                (Split::Even, 17, true),
                (Split::EvenRows(4), 20, true),
                (Split::Blocks(3), 3 * workers + 1, false),
                (Split::Offsets(o), 17, false),
            ] {
                split.check(len, workers);
                let mut owner = vec![None; len];
                for w in 0..workers {
                    for i in split.range(len, w, workers) {
                        assert_eq!(owner[i], None, "{split:?}: element {i} in two parts");
                        owner[i] = Some(w);
                    }
                }
                if covers {
                    assert!(owner.iter().all(Option::is_some), "{split:?} leaves elements out");
                }
            }
        }
    }

    /// A table's parts: worker `w` reaches rows `partition(rows, T, w)` of every column and
    /// nothing else, so every element of the table is reached by exactly one worker (an
    /// element past the table by none); a table larger than its array is refused.
    #[test]
    fn table_parts_are_each_workers_rows_of_every_column() {
        for (rows, columns) in [(7, 3), (1, 4), (10, 1), (0, 2)] {
            for workers in 1..=5 {
                let mut owner = vec![usize::MAX; rows * columns + 2];
                let table = Table::of(&mut owner, rows, columns);
                table.check(workers);
                for w in 0..workers {
                    // SAFETY: checked for `workers`; each part taken once, used alone.
                    let mut part = unsafe { table.part(w, workers) };
                    assert_eq!(part.columns(), columns);
                    for j in 0..columns {
                        for (i, o) in part.column(j).iter_mut().enumerate() {
                            assert_eq!(*o, usize::MAX, "{rows} x {columns}, {workers} workers: element reached twice");
                            *o = w * 1000 + j * 100 + i;
                        }
                    }
                }
                for j in 0..columns {
                    for w in 0..workers {
                        for (i, r) in partition(rows, workers, w).enumerate() {
                            assert_eq!(
                                owner[j * rows + r],
                                w * 1000 + j * 100 + i,
                                "{rows} x {columns}: row {r} of column {j}"
                            );
                        }
                    }
                }
                assert!(owner[rows * columns..].iter().all(|&o| o == usize::MAX), "a part reached past the table");
            }
        }
        let mut small = [0u8; 5];
        let refused = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| Table::of(&mut small, 3, 2).check(2)));
        assert!(refused.is_err(), "3 x 2 table in 5 elements");
    }

    /// Splits whose parts would overlap or leave the array are refused before any worker
    /// starts.
    #[test]
    fn bad_splits_are_refused() {
        let refused = |split: Split<'_>, len: usize, workers: usize| {
            std::panic::catch_unwind(|| split.check(len, workers)).is_err()
        };
        assert!(refused(Split::Offsets(&[0, 5, 3]), 10, 2), "decreasing offsets");
        assert!(refused(Split::Offsets(&[0, 5, 11]), 10, 2), "past the end");
        assert!(refused(Split::Offsets(&[0, 5]), 10, 2), "too few offsets");
        assert!(refused(Split::Blocks(4), 7, 2), "blocks past the end");
        assert!(refused(Split::Blocks(usize::MAX), 7, 2), "overflowing blocks");
        assert!(refused(Split::EvenRows(3), 10, 2), "not whole rows");
        assert!(refused(Split::EvenRows(0), 0, 2), "empty rows");
    }
}
