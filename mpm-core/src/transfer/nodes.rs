//! The node passes of the step, split across workers by node rows (dense grid) or blocks
//! (sparse grid): the grid update (Eq. 6) and the re-map's velocities (Eq. 11), each with the
//! walls.

use crate::blocks::{BlockMap, BLOCK, BLOCK_NODES};
use crate::grid::{GridGeom, NodeArrays, WallLayers, KIN_WIDTH, REMAP_WIDTH};
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::parallel::{partition, Exec, Split};

/// How the node loops split a grid's nodes between workers: node rows of a dense grid, or
/// the blocks of a sparse one (whole parts of the node arrays either way).
fn node_split(geom: &GridGeom, index: &NodeIndex<'_>) -> Split<'static> {
    match index {
        NodeIndex::Box { lo, dims } => {
            assert!(*lo == [0; 3] && *dims == geom.node_dims(), "the node loops run over the whole grid");
            Split::EvenRows(dims[0])
        }
        NodeIndex::Blocks(_) => Split::EvenRows(BLOCK_NODES),
    }
}

/// Visit every node of the grid with its wall mask (1 = free component, 0 = constrained),
/// parallel over node rows (dense) or blocks (sparse): `f(node, mask, &mut out[node])`.
fn for_each_node<T, F>(exec: &Exec<'_>, geom: &GridGeom, index: &NodeIndex<'_>, walls: &WallLayers, out: &mut [T], f: F)
where
    T: Send,
    F: Fn(usize, Vec3, &mut T) + Sync,
{
    let t = exec.workers();
    let tally = crate::work::Tally::of(exec);
    exec.for_each_chunk_mut(node_split(geom, index).of(out), |w, mine| {
        tally.updated(w, mine.len());
        visit_nodes(geom, index, walls, w, t, |n, mask, local| f(n, mask, &mut mine[local]));
    });
}

/// Worker `w`'s nodes out of `t` (the split of [`node_split`]): `f(node, mask, local)` for
/// each node of the grid, `local` its index within the worker's part. On a sparse grid the
/// stored nodes past the grid's last node layer (in blocks at its upper end) are skipped.
#[inline(always)]
fn visit_nodes(
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    walls: &WallLayers,
    w: usize,
    t: usize,
    mut f: impl FnMut(usize, Vec3, usize),
) {
    let d = geom.node_dims();
    let has_x = walls.x_layers().next().is_some();
    match index {
        NodeIndex::Box { .. } => {
            for (ri, row) in partition(d[1] * d[2], t, w).enumerate() {
                let mask_row = walls.row_mask(row % d[1], row / d[1]);
                for i in 0..d[0] {
                    f(row * d[0] + i, walls.node_mask(mask_row, i, has_x), ri * d[0] + i);
                }
            }
        }
        NodeIndex::Blocks(map) => {
            let parts = partition(map.len(), t, w);
            let first = parts.start;
            for s in parts {
                let b = map.block(s);
                BlockMap::rows_in(b, [0; 3], geom.cells, |[a0, bb, c], locals| {
                    let mask_row = walls.row_mask(b[1] * BLOCK[1] + bb, b[2] * BLOCK[2] + c);
                    for (a, l) in (a0..).zip(locals) {
                        let mask = walls.node_mask(mask_row, b[0] * BLOCK[0] + a, has_x);
                        f(s * BLOCK_NODES + l, mask, (s - first) * BLOCK_NODES + l);
                    }
                });
            }
        }
    }
}

/// Eq. 6 and the walls: `p += f dt`; wall nodes lose the constrained components of `p`
/// and `f`; `v = p/m`, `a = f/m` (zero on massless nodes). Parallel over node rows.
pub fn grid_update(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    walls: &WallLayers,
    nodes: &mut NodeArrays,
    dt: f64,
    tol: f64,
) {
    let NodeArrays { p2g, kin, .. } = nodes;
    let p2g = &p2g[..];
    for_each_node(exec, geom, index, walls, kin, |n, mask, o| {
        let a = &p2g[n];
        let m = a[0];
        if m > tol {
            let inv = 1.0 / m;
            for k in 0..3 {
                let f = a[4 + k] * mask[k];
                let p = (a[1 + k] + a[4 + k] * dt) * mask[k];
                o[k] = p * inv;
                o[3 + k] = f * inv;
            }
        } else {
            *o = [0.0; KIN_WIDTH];
        }
    });
}

/// Eq. 11, second half: `v_i = p_i / m_i` with the walls applied again, in place. Also
/// replaces the acceleration in `kin` (used by the gather, which has run) by the mid-step
/// velocity `(v_i(k) + v_i(k+1)) / 2 = (v - dt a + v_remap) / 2`, whose gradient the
/// particle update needs for the work of the stress: once per node here instead of once per
/// particle and node there.
pub fn remap_velocity(
    exec: &Exec<'_>,
    geom: &GridGeom,
    index: &NodeIndex<'_>,
    walls: &WallLayers,
    nodes: &mut NodeArrays,
    dt: f64,
    tol: f64,
) {
    let NodeArrays { p2g, kin, remap } = nodes;
    let p2g = &p2g[..];
    let t = exec.workers();
    let split = node_split(geom, index);
    let tally = crate::work::Tally::of(exec);
    exec.for_each_chunk_mut((split.of(remap), split.of(kin)), |w, (remap, kin)| {
        tally.updated(w, remap.len());
        visit_nodes(geom, index, walls, w, t, |n, mask, local| {
            let (o, kn) = (&mut remap[local], &mut kin[local]);
            let m = p2g[n][0];
            if m > tol {
                let inv = 1.0 / m;
                for k in 0..3 {
                    o[k] *= inv * mask[k];
                }
            } else {
                *o = [0.0; REMAP_WIDTH];
            }
            for k in 0..3 {
                kn[3 + k] = 0.5 * (kn[k] - dt * kn[3 + k] + o[k]);
            }
        });
    });
}
