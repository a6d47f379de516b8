//! Array expansion (AE, paper Section 4): every nodal array gets one copy per thread,
//! `Mg_list(N, nthreads)`. Thread `j` zeroes column `j` and scatters its contiguous chunk of
//! particles into it; then a parallel loop over nodes sums the columns in thread order,
//! `A(:) = sum_j A_list(:, j)` (Eq. 16). No races and no atomics; the memory grows with
//! `(T - 1) x` the nodal arrays, and the assembly with `N x T`.

use super::{Contribution, Exec, NodeBox};
use crate::disjoint::{partition, DisjointSlice};
use crate::grid::GridGeom;

/// Scatter particle chunk `j` into column `j` of `buf` (sized `N x T`, column-major).
pub fn scatter<const K: usize, F>(exec: &Exec<'_>, geom: &GridGeom, n: usize, buf: &mut Vec<[f64; K]>, kernel: &F)
where
    F: Fn(usize) -> Contribution<K> + Sync,
{
    let nn = geom.num_nodes();
    let t = exec.workers;
    buf.resize(nn * t, [0.0; K]);
    let bx = NodeBox::grid(geom);
    let columns = DisjointSlice::new(&mut buf[..]);
    exec.run(|j| {
        // SAFETY: column j (nodes j*nn..(j+1)*nn) is touched only by worker j, and every
        // broadcast index runs exactly once.
        let column = unsafe { columns.range_mut(j * nn..(j + 1) * nn) };
        column.fill([0.0; K]);
        for p in partition(n, t, j) {
            bx.add(column, &kernel(p));
        }
    });
}

/// Eq. 16: `global[i] = sum_j buf[j][i]`, summed in thread order, parallel over nodes.
pub fn assemble<const K: usize>(exec: &Exec<'_>, global: &mut [[f64; K]], buf: &[[f64; K]]) {
    let nn = global.len();
    let t = exec.workers;
    let out = DisjointSlice::new(global);
    exec.run(|w| {
        let r = partition(nn, t, w);
        // SAFETY: partition ranges are disjoint and each worker index runs once.
        let dst = unsafe { out.range_mut(r.clone()) };
        dst.copy_from_slice(&buf[r.clone()]);
        for j in 1..t {
            let src = &buf[j * nn + r.start..j * nn + r.end];
            for (a, b) in dst.iter_mut().zip(src) {
                for k in 0..K {
                    a[k] += b[k];
                }
            }
        }
    });
}
