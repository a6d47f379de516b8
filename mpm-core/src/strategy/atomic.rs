//! Atomic additions: every worker scatters its particle chunk (loop splitting) straight into
//! the global arrays, each value added with an atomic read-modify-write (the scheme of
//! Taichi on CPUs, GeoTaichi, ElastoPlasm.jl, Kokkos' atomic `ScatterView`, and the GPU
//! codes).
//!
//! A CPU has no atomic `f64` addition: the sum is a compare-exchange loop on the value's
//! bits as an [`AtomicU64`] ([`add`]): read the bits, add in `f64`, write the new bits if
//! nobody wrote in between, else retry with what they wrote. The kernel adds a particle's
//! values to a record of the worker's own ([`Adder`]); when it moves on to the next record,
//! the values are sent to the global record, one atomic addition per value that is not
//! zero (the unused last value of a record never is). The global arrays are seen as atomics
//! through one conversion ([`atomic_view`]). Every worker first zeroes its share of the
//! global arrays, in a phase of its own. No copy, no assembly, no memory beyond the global
//! arrays.
//!
//! **Results reproduce to round-off only.** Each node's value is the sum of the terms its
//! particles give (the serial solver's terms, bit for bit), but taken in the order in which
//! the workers' additions land, which changes from run to run. Any order of summing `n`
//! terms `t_i` gives the exact sum to within `gamma_{n-1} sum_i |t_i|`, `gamma_m = m u /
//! (1 - m u)` with `u = 2^-53` (Higham, *Accuracy and Stability of Numerical Algorithms*,
//! Section 4.2), so two orders (the serial solver's and this one's) differ by at most twice
//! that: the bound the tests check, node by node. At AVX-512 the P2G kernel adds the
//! particles of one cell in registers before it sends a record, which groups the terms
//! differently but keeps the bound (it holds for any grouping).
//!
//! Memory order: `Relaxed`. Atomicity of each read-modify-write does not depend on the
//! order, and the phase's barrier ([`Exec::run`] returns after every share finished)
//! orders every addition before anything that reads the arrays.

use super::{Cursors, Kernel, ScatterStrategy, Target};
use crate::grid::{GridGeom, Records};
use crate::node_index::NodeIndex;
use crate::parallel::{partition, Exec, Split};
use crate::work::Tally;
use std::mem::size_of;
use std::sync::atomic::{AtomicU64, Ordering};

/// The atomic strategy: no state, no scatter buffer, no assembly.
#[derive(Clone, Copy, Debug, Default)]
pub struct Atomic;

/// Add `v` to the `f64` whose bits `cell` holds, atomically (a compare-exchange loop).
#[inline(always)]
pub fn add(cell: &AtomicU64, v: f64) {
    let mut old = cell.load(Ordering::Relaxed);
    loop {
        let new = (f64::from_bits(old) + v).to_bits();
        match cell.compare_exchange_weak(old, new, Ordering::Relaxed, Ordering::Relaxed) {
            Ok(_) => return,
            Err(seen) => old = seen,
        }
    }
}

/// `records` as atomics, for as long as the exclusive borrow lasts.
pub fn atomic_view<const K: usize>(records: &mut [[f64; K]]) -> &[[AtomicU64; K]] {
    const { assert!(size_of::<AtomicU64>() == size_of::<f64>()) };
    let ptr = records.as_mut_ptr();
    assert!(ptr.cast::<AtomicU64>().is_aligned(), "node records at {ptr:p} are not aligned for 64-bit atomics");
    // SAFETY: `AtomicU64` has the size and bit validity of `u64` (std's documentation), so
    // of `f64`, whose every bit pattern is a valid `u64`; `[[AtomicU64; K]]` then has the
    // layout of `[[f64; K]]`, and the pointer's alignment for `AtomicU64` is checked above.
    // The view borrows `records` exclusively for its lifetime, so while it lives every access
    // to these bytes goes through it, hence through the atomics.
    unsafe { std::slice::from_raw_parts(ptr.cast::<[AtomicU64; K]>(), records.len()) }
}

/// A worker's way into the global records: the kernel adds to a record of the adder's own,
/// whose values go to the global record by atomic additions when the kernel asks for the
/// next record, or at [`Adder::finish`].
struct Adder<'a, const K: usize> {
    global: &'a [[AtomicU64; K]],
    /// The global record `record` goes to (`usize::MAX`: none).
    node: usize,
    record: [f64; K],
}

impl<'a, const K: usize> Adder<'a, K> {
    fn new(global: &'a [[AtomicU64; K]]) -> Self {
        Self { global, node: usize::MAX, record: [0.0; K] }
    }

    /// Send the pending record's values (those not zero) to its global record.
    #[inline(always)]
    fn send(&mut self) {
        if let Some(dst) = self.global.get(self.node) {
            for k in 0..K {
                let v = self.record[k];
                if v != 0.0 {
                    add(&dst[k], v);
                }
            }
        }
    }

    /// Send what is pending.
    fn finish(mut self) {
        self.send();
    }
}

impl<const K: usize> Target<K> for Adder<'_, K> {
    #[inline(always)]
    fn at(&mut self, i: usize) -> &mut [f64; K] {
        assert!(i < self.global.len(), "node {i} of {} records", self.global.len());
        self.send();
        self.node = i;
        self.record = [0.0; K];
        &mut self.record
    }
}

/// Zero `global` (a phase, split evenly), then every worker's chunk of `n` particles
/// `kernel.scatter_all` straight into it by atomic additions (module docs).
pub fn scatter<const K: usize, F>(exec: &Exec<'_>, index: &NodeIndex<'_>, n: usize, global: &mut [[f64; K]], kernel: &F)
where
    F: Kernel<K>,
{
    let (t, tally, record) = (exec.workers(), Tally::of(exec), size_of::<[f64; K]>());
    exec.for_each_chunk_mut(Split::Even.of(global), |w, part| {
        part.fill([0.0; K]);
        tally.scattered(w, part.len(), record, false);
    });
    let view = atomic_view(global);
    exec.run(|w| {
        let mine = partition(n, t, w);
        tally.particles(w, mine.len());
        tally.atomic(w, 8 * mine.len(), record);
        let mut nodes = Cursors::global(*index);
        let mut adder = Adder::new(view);
        kernel.scatter_all(mine, &mut nodes, &mut adder);
        adder.finish();
    });
}

impl ScatterStrategy for Atomic {
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        _parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        scatter(exec, index, n, global, kernel);
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::math::Vec3;
    use crate::parallel::Team;
    use crate::strategy::Contribution;

    fn in_region<R: Send>(threads: usize, f: impl FnOnce(&Exec<'_>) -> R + Send) -> R {
        Team::new(crate::testing::pool(threads)).region(f).unwrap()
    }

    /// `gamma_m = m u / (1 - m u)`, `u = 2^-53`: the relative error bound of a sum of
    /// `m + 1` terms in any order (module docs).
    fn gamma(m: usize) -> f64 {
        let mu = m as f64 * f64::EPSILON / 2.0;
        mu / (1.0 - mu)
    }

    /// Against the serial scatter, node by node and value by value: the two sums of the same
    /// `n` terms differ by at most `2 gamma_{n-1} sum |t_i|` (module docs), with `n` and
    /// `sum |t_i|` counted for each node from the terms. Terms of mixed signs and magnitudes
    /// over 7 decades, many particles a node (few cells), at 1-8 threads, 5 runs each.
    #[test]
    fn sums_are_the_serial_sums_to_the_bound_of_summation_order() {
        let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [4, 3, 5] });
        let mut unit = crate::testing::unit_stream(31);
        let x: Vec<Vec3> = (0..20_000).map(|_| [4.0 * unit(), 3.0 * unit(), 5.0 * unit()]).collect();
        let values: Vec<[[f64; 2]; 8]> = x
            .iter()
            .map(|_| std::array::from_fn(|_| [unit() - 0.5, 10f64.powf(7.0 * unit()) * (unit() - 0.3)]))
            .collect();
        let kernel = |p: usize| Contribution::<2> { cell: geom.shape_cell(x[p]), c: values[p] };
        let index = NodeIndex::of(&geom, None);
        let nn = geom.num_nodes();
        let mut serial = vec![[0.0; 2]; nn];
        crate::strategy::serial::scatter(&index, x.len(), &mut serial, &kernel);
        // Per node: terms and the sum of their magnitudes.
        let (mut terms, mut magnitude) = (vec![0usize; nn], vec![[0.0f64; 2]; nn]);
        for (p, &xp) in x.iter().enumerate() {
            let idx = index.cell_nodes(geom.shape_cell(xp));
            for q in 0..8 {
                terms[idx[q]] += 1;
                for k in 0..2 {
                    magnitude[idx[q]][k] += values[p][q][k].abs();
                }
            }
        }
        let mut worst = 0.0f64;
        for threads in [1, 2, 3, 4, 8] {
            for run in 0..5 {
                let mut global = vec![[f64::NAN; 2]; nn];
                in_region(threads, |exec| scatter(exec, &index, x.len(), &mut global, &kernel));
                for i in 0..nn {
                    for k in 0..2 {
                        // The magnitudes' own floating-point sum is within gamma_n of the exact.
                        let n = terms[i];
                        let bound = 2.0 * gamma(n.saturating_sub(1)) * magnitude[i][k] * (1.0 + gamma(n));
                        let diff = (global[i][k] - serial[i][k]).abs();
                        assert!(
                            diff <= bound,
                            "{threads} threads, run {run}: node {i} value {k}: {} vs serial {} ({} terms): {diff:e} > {bound:e}",
                            global[i][k],
                            serial[i][k],
                            terms[i]
                        );
                        if bound > 0.0 {
                            worst = worst.max(diff / bound);
                        }
                    }
                }
            }
        }
        println!("largest difference from the serial sums: {worst:.3} of the bound");
    }

    /// Every addition lands: with every worker adding to the same 8 records at once (all
    /// particles in one cell), whole-number terms make every order's sum exact, so a single
    /// addition lost to a race (a read and a write that another worker's write fell between)
    /// shows as a sum short of the count. Rounds are repeated, and more workers than cores
    /// run, so that on a busy host too workers are preempted between a read and its write
    /// (a plain load and store in place of the compare-exchange fails this).
    #[test]
    fn no_addition_is_lost_under_contention() {
        let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [2, 2, 2] });
        let index = NodeIndex::of(&geom, None);
        let n = 200_000;
        let kernel = |p: usize| Contribution::<4> { cell: [1, 0, 1], c: [[1.0, (p % 7) as f64, 2.0, 0.0]; 8] };
        let sevens: f64 = (0..n).map(|p| (p % 7) as f64).sum();
        for threads in [2, 4, 8, 16] {
            for round in 0..8 {
                let mut global = vec![[0.0; 4]; geom.num_nodes()];
                in_region(threads, |exec| scatter(exec, &index, n, &mut global, &kernel));
                for &i in &index.cell_nodes([1, 0, 1]) {
                    assert_eq!(
                        global[i],
                        [n as f64, sevens, 2.0 * n as f64, 0.0],
                        "{threads} threads, round {round}: node {i} lost additions"
                    );
                }
            }
        }
    }
}
