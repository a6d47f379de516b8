//! Array expansion (AE, paper Section 4): every nodal array gets one copy per thread,
//! `Mg_list(N, nthreads)`. Thread `j` scatters its contiguous chunk of particles into column
//! `j`; then a parallel loop over nodes sums the columns in thread order,
//! `A(:) = sum_j A_list(:, j)` (Eq. 16). No races and no atomics; the memory grows with
//! `(T - 1) x` the nodal arrays, and the assembly with `N x T`.
//!
//! The columns are zero between steps: the assembly, which reads every record of every
//! column, sets each record it read back to zero if it is not (bit for bit), so the scatter
//! starts from zeroed columns without writing `N x T` zeros. On the Taylor bar's fixed grid
//! most records are never scattered into (Model 3: 16 % of its cells hold particles),
//! so the zeroing writes back only the records the particles touched, where a fill of every
//! column wrote them all; and the assembly goes over its range in blocks that stay in the
//! L1 cache between the columns, so the global records are written once, not re-read for
//! every column after the first. Both keep every sum's order: the results are bitwise those
//! of zeroing and summing column after column. The columns' zero state is kept by
//! [`Records::resize`] (new records are zero) and holds at the first step (`Records::zeroed`).

use super::{Cursors, Kernel, ScatterStrategy};
use crate::blocks::BlockMap;
use crate::grid::{GridGeom, Records};
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::parallel::{partition, Exec, Split, Table};
use crate::work::Tally;
use std::mem::size_of;

/// The array-expansion strategy for `threads` threads (one copy of the arrays per thread).
#[derive(Clone, Copy, Debug)]
pub struct ArrayExpansion {
    threads: usize,
}

impl ArrayExpansion {
    /// State for `threads` threads.
    pub fn new(threads: usize) -> Self {
        Self { threads }
    }
}

/// Scatter particle chunk `j` into column `j` of `columns` (sized `N x T`, column-major;
/// `N` the grid's stored nodes, numbered by `index`). The columns must be zero, as
/// [`assemble`] leaves them.
pub fn scatter<const K: usize, F>(
    exec: &Exec<'_>,
    nn: usize,
    index: &NodeIndex<'_>,
    n: usize,
    columns: &mut Records<K>,
    kernel: &F,
) where
    F: Kernel<K>,
{
    let t = exec.workers();
    columns.resize(nn * t);
    debug_assert!(columns.iter().all(is_zero), "array expansion's columns are zero");
    let tally = Tally::of(exec);
    exec.for_each_chunk_mut(Split::Blocks(nn).of(columns), |j, column| {
        let mut nodes = Cursors::global(*index);
        let mine = partition(n, t, j);
        tally.particles(j, mine.len());
        tally.scattered(j, column.len(), size_of::<[f64; K]>(), false);
        kernel.scatter_all(mine, &mut nodes, column);
    });
}

/// Bytes of global records an assembly block holds: it stays in L1 while the columns are
/// added to it.
const BLOCK_BYTES: usize = 8192;

/// Eq. 16: `global[i] = sum_j columns[j][i]`, summed in thread order, parallel over nodes;
/// every record of `columns` is zero afterwards (see the module docs).
pub fn assemble<const K: usize>(exec: &Exec<'_>, global: &mut [[f64; K]], columns: &mut [[f64; K]]) {
    let nn = global.len();
    let t = exec.workers();
    let tally = Tally::of(exec);
    let block = (BLOCK_BYTES / size_of::<[f64; K]>()).max(1);
    exec.for_each_chunk_mut((Split::Even.of(global), Table::of(columns, nn, t)), |w, (dst, mut cols)| {
        let mut cleared = 0;
        for start in (0..dst.len()).step_by(block) {
            let end = (start + block).min(dst.len());
            let dst = &mut dst[start..end];
            for j in 0..t {
                let src = &mut cols.column(j)[start..end];
                if j == 0 {
                    dst.copy_from_slice(src);
                } else {
                    for (a, b) in dst.iter_mut().zip(src.iter()) {
                        for k in 0..K {
                            a[k] += b[k];
                        }
                    }
                }
                cleared += clear(src);
            }
        }
        tally.assembled(w, dst.len(), t * dst.len() + cleared, size_of::<[f64; K]>());
    });
}

/// Whether every value of `record` is `+0.0` (all bits zero: `-0.0` is not).
#[inline]
fn is_zero<const K: usize>(record: &[f64; K]) -> bool {
    record.iter().fold(0, |acc, v| acc | v.to_bits()) == 0
}

/// Set every record of `records` that is not all zero bits to zero; return how many were.
/// Records already zero are not written, so their cache lines stay clean.
#[inline]
fn clear<const K: usize>(records: &mut [[f64; K]]) -> usize {
    let mut cleared = 0;
    for r in records {
        if !is_zero(r) {
            *r = [0.0; K];
            cleared += 1;
        }
    }
    cleared
}

impl ScatterStrategy for ArrayExpansion {
    fn reserve(&mut self, geom: &GridGeom, blocks: Option<&BlockMap>) -> usize {
        NodeIndex::of(geom, blocks).num_nodes() * self.threads
    }

    fn prepare(&mut self, _exec: &Exec<'_>, _geom: &GridGeom, _blocks: Option<&BlockMap>, _x: &[Vec3]) {}

    /// The columns are as long as `global`: the grid's nodes, or its stored nodes.
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        scatter(exec, global.len(), index, n, parts, kernel);
    }

    fn assemble<const K: usize>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        _index: &NodeIndex<'_>,
        global: &mut [[f64; K]],
        parts: &mut [[f64; K]],
    ) {
        assemble(exec, global, parts);
    }

    fn bytes(&self) -> usize {
        0
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::parallel::Team;
    use crate::strategy::Contribution;

    /// Steps through the same columns, the grid changing size between them: every assembly
    /// gives bitwise the sums of that step's scatter alone, each column the sum of its
    /// thread's particles in order and the columns summed in thread order, and leaves every
    /// record of every column zero bits, so the next scatter needs no fill. Without the
    /// assembly's clearing a step would add the previous step's values; without the zero
    /// state kept across a resize, a step on a new grid would too.
    #[test]
    fn assembly_gives_each_steps_sums_alone_and_leaves_the_columns_zero() {
        let mut unit = crate::testing::unit_stream(17);
        for threads in [1, 2, 3, 4] {
            let team = Team::new(crate::testing::pool(threads));
            let mut columns = Records::<2>::zeroed(0);
            for (step, cells) in [[6, 5, 7], [6, 5, 7], [7, 5, 7], [4, 5, 6], [6, 5, 7]].into_iter().enumerate() {
                let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells });
                let index = NodeIndex::of(&geom, None);
                let nn = index.num_nodes();
                let span = cells.map(|c| c as f64);
                let x: Vec<Vec3> = (0..700).map(|_| std::array::from_fn(|d| span[d] * unit())).collect();
                let values: Vec<[[f64; 2]; 8]> =
                    x.iter().map(|_| std::array::from_fn(|_| [unit() - 0.5, 1e3 * (unit() - 0.3)])).collect();
                let kernel = |p: usize| Contribution::<2> { cell: geom.shape_cell(x[p]), c: values[p] };
                // The reference: each thread's chunk into its own zeroed copy, in order, then
                // the copies added in thread order.
                let mut want = vec![[0.0; 2]; nn];
                for j in 0..threads {
                    let mut copy = vec![[0.0; 2]; nn];
                    for p in partition(x.len(), threads, j) {
                        let idx = index.cell_nodes(geom.shape_cell(x[p]));
                        for q in 0..8 {
                            for k in 0..2 {
                                copy[idx[q]][k] += values[p][q][k];
                            }
                        }
                    }
                    for (w, c) in want.iter_mut().zip(&copy) {
                        if j == 0 {
                            *w = *c;
                        } else {
                            w[0] += c[0];
                            w[1] += c[1];
                        }
                    }
                }
                let mut global = vec![[f64::NAN; 2]; nn];
                let run = |exec: &Exec<'_>| {
                    scatter(exec, nn, &index, x.len(), &mut columns, &kernel);
                    assemble(exec, &mut global, &mut columns);
                };
                team.region(run).unwrap();
                let what = format!("{threads} threads, step {step} on {cells:?} cells");
                for (i, (g, w)) in global.iter().zip(&want).enumerate() {
                    assert_eq!(g.map(f64::to_bits), w.map(f64::to_bits), "{what}: node {i}");
                }
                assert_eq!(columns.len(), nn * threads, "{what}");
                assert!(columns.iter().all(|r| r.iter().all(|v| v.to_bits() == 0)), "{what}: columns left non-zero");
            }
        }
    }
}
