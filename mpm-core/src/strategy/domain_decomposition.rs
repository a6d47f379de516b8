//! Domain decomposition (DD, paper Section 4).
//!
//! The grid's cells are cut into `px x py x pz` uniform patches, one per thread (layouts
//! 1x1x1, 2x1x1, 2x2x1, 2x1x3, 2x2x2 for 1, 2, 4, 6, 8 threads; other counts get the
//! factorisation with the fewest duplicated nodes, see [`patch_layout`]). Every step:
//!
//! 1. **Binning**, in parallel ([`Binning`]): the particles are split into `T` contiguous
//!    groups; thread `t` counts its particles per patch, `patnp_th(t, j)`; the column sums
//!    are `patnp(j)`; `max(patnp)` sizes the index table `Pindex`; with prefix sums over
//!    `patnp_th` each thread writes its particles' ids into `Pindex(:, j)` without conflicts.
//!    `Pindex(i, j)` is the (1-based) id of the particle with local id `i` in patch `j`, and 0
//!    marks an empty slot, exactly as in the paper.
//! 2. **Scatter**: thread `j` scatters only patch `j`'s particles, only into sub-grid `j`,
//!    which holds every node of the patch's cells, including the nodes on faces shared with
//!    neighbouring patches. Local node `s` of patch `j` is global node `globalnode(s, j)`;
//!    [`Patch::subnodefun`] is the reverse map.
//! 3. **Assembly**: for each patch in turn, a parallel loop over its local nodes adds the
//!    sub-grid into the global arrays (within one patch every local node is a distinct global
//!    node, so the loop has no race). The global arrays are not zeroed first: a node's
//!    lowest-numbered patch (its *first* patch) stores its value, later patches add theirs.
//!    The patches cover the grid, so every node is stored once per assembly. Zeroing the
//!    global arrays first would double the bytes the assembly moves, and the assembly is
//!    bound by memory bandwidth.
//!
//! The MUSL re-map (Eq. 11) reuses the same binning, sub-grids and assembly. With the
//! adaptive grid the patches are re-cut over the particles' current bounding box every step,
//! which is the paper's load balance.
//!
//! **Balanced cuts** ([`Strategy::DdBalanced`](super::Strategy::DdBalanced), the paper's
//! "better load balance algorithm"): every step the cut planes are placed at the
//! particle-count quantiles ([`super::cuts`]; nested: x over all particles, y within each x
//! slab, z within each column), and the layout is chosen among the factorisations of the
//! thread count ([`LayoutChooser`]: the paper's layout unless another predicts a work
//! imbalance more than 2 % lower; a thin plate cannot be balanced by a layout that must cut
//! across its few cell planes). Before the binning, one parallel pass stores every
//! particle's cell and counts particles per cell plane along x, y and z (per-worker
//! histograms); the layout and the x cuts follow from their sums; for layouts cut along y
//! (z) a further pass over the stored cells counts per slab (column) and cell plane. The
//! binning then looks patches up from the stored cells; sub-grids, `Pindex` and assembly are
//! those of uniform cuts (the sub-grid node count, `(nx + px)(ny + py)(nz + pz)`, does not
//! depend on where the planes lie; the buffers are sized for the paper's layout and grow,
//! once, if another layout needs more nodes).
//!
//! **Sparse grid** ([`crate::GridMode::Sparse`]): a patch's sub-grid is the stored blocks
//! that meet the patch's nodes ([`BlockMap::restrict`], rebuilt every step), so a block cut
//! by a patch boundary is held by both patches, as a shared face is on the dense grid. The
//! assembly goes patch by patch, parallel over the patch's blocks, with the same
//! first-holder rule over the patch's nodes: every sum is the dense grid's, bit for bit.

use super::cuts::{Cuts, LayoutChooser, PatchLoad};
use super::patch::Patch;
use super::{Cursors, Kernel, ScatterStrategy};
use crate::blocks::{BlockMap, BLOCK, BLOCK_NODES};
use crate::grid::{GridGeom, Records};
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::parallel::{partition, DisjointSlice, Exec, Split};
use crate::work::Tally;
use std::mem::size_of;

/// The patch layout `[px, py, pz]` for `threads` patches over a grid of `cells`.
///
/// 1, 2, 4, 6 and 8 threads use the paper's layouts (1x1x1, 2x1x1, 2x2x1, 2x1x3, 2x2x2).
/// Other counts use the factorisation `px py pz = threads` that duplicates the fewest nodes
/// (the smallest total area of internal cuts), ties broken towards cutting z, then y.
pub fn patch_layout(threads: usize, cells: [usize; 3]) -> [usize; 3] {
    match threads {
        1 => [1, 1, 1],
        2 => [2, 1, 1],
        4 => [2, 2, 1],
        6 => [2, 1, 3],
        8 => [2, 2, 2],
        t => {
            let [nx, ny, nz] = cells.map(|c| c as u128 + 1);
            let mut best = ([1, 1, t], u128::MAX);
            for px in 1..=t {
                if t % px != 0 {
                    continue;
                }
                for py in 1..=t / px {
                    if (t / px) % py != 0 {
                        continue;
                    }
                    let pz = t / px / py;
                    let cost = (px as u128 - 1) * ny * nz + (py as u128 - 1) * nx * nz + (pz as u128 - 1) * nx * ny;
                    if cost < best.1 || (cost == best.1 && [pz, py] > [best.0[2], best.0[1]]) {
                        best = ([px, py, pz], cost);
                    }
                }
            }
            best.0
        }
    }
}

/// Row padding (in `u32`) of the per-thread tables: one 64-byte cache line, so that threads
/// incrementing their own counters never share a line (sharing one makes every increment a
/// coherence miss: binning at 2 threads ran 1.5x slower than at 1 without the padding).
const ROW_STRIDE: usize = 16;

/// One parallel pass of loop splitting over the particles (`labels.len()` of them): worker
/// `w` stores `label(p).0` of each of its particles `p` in `labels[p]` and counts the bins
/// `label(p).1` in row `w` of `hist` (rows `stride` apart, the first `bins` entries zeroed
/// first). The DD counting pass.
fn label_and_count<S, F>(exec: &Exec<'_>, labels: &mut [S], hist: &mut [u32], stride: usize, bins: usize, label: &F)
where
    S: Send,
    F: Fn(usize) -> (S, usize) + Sync,
{
    let (n, t) = (labels.len(), exec.workers());
    let tally = Tally::of(exec);
    exec.for_each_chunk_mut((Split::Even.of(labels), Split::Blocks(stride).of(hist)), |w, (mine, row)| {
        tally.particles(w, mine.len());
        let row = &mut row[..bins];
        row.fill(0);
        for (slot, p) in mine.iter_mut().zip(partition(n, t, w)) {
            let (l, bin) = label(p);
            *slot = l;
            row[bin] += 1;
        }
    });
}

/// The paper's particle binning tables.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Binning {
    threads: usize,
    patches: usize,
    /// Patch of every particle (filled by the counting pass, read by the writing pass).
    patch_of: Vec<u32>,
    /// `patnp_th(t, j)`, row-major by thread, rows padded to [`ROW_STRIDE`] multiples.
    patnp_th: Vec<u32>,
    /// Distance between two threads' rows in `patnp_th` and `cursor`.
    stride: usize,
    /// Running write positions per thread and patch (prefix sums of `patnp_th`).
    cursor: Vec<u32>,
    /// `patnp(j)`.
    patnp: Vec<u32>,
    /// Rows of `Pindex` (= `max(patnp)`).
    rows: usize,
    /// `Pindex(i, j)`, column-major, 1-based particle ids, 0 = empty slot.
    pindex: Vec<u32>,
}

impl Binning {
    /// Bin `n` particles into `patches` patches with `exec.workers()` threads; `patch(p)` is
    /// particle `p`'s patch.
    pub fn build<F>(&mut self, exec: &Exec<'_>, n: usize, patches: usize, patch: &F)
    where
        F: Fn(usize) -> usize + Sync,
    {
        assert!(n < u32::MAX as usize, "more than 2^32 - 1 particles");
        let t = exec.workers();
        let stride = patches.div_ceil(ROW_STRIDE) * ROW_STRIDE;
        self.threads = t;
        self.patches = patches;
        self.stride = stride;
        self.patch_of.resize(n, 0);
        self.patnp_th.resize(t * stride, 0);
        self.cursor.resize(t * stride, 0);
        self.patnp.resize(patches, 0);

        // Counting pass: thread w counts its particles per patch in row w of patnp_th.
        label_and_count(exec, &mut self.patch_of, &mut self.patnp_th, stride, patches, &|p| {
            let j = patch(p);
            (j as u32, j)
        });

        // patnp = column sums; write cursors = exclusive prefix sums down each column.
        for j in 0..patches {
            let mut acc = 0u32;
            for w in 0..t {
                self.cursor[w * stride + j] = acc;
                acc += self.patnp_th[w * stride + j];
            }
            self.patnp[j] = acc;
        }
        self.rows = self.patnp.iter().copied().max().unwrap_or(0) as usize;
        let rows = self.rows;
        self.pindex.resize(rows * patches, 0);
        for j in 0..patches {
            self.pindex[j * rows + self.patnp[j] as usize..(j + 1) * rows].fill(0);
        }

        // Writing pass: every thread writes its particles' ids in its own rows of Pindex,
        // advancing its own row of write cursors.
        let pindex = DisjointSlice::new(&mut self.pindex);
        let patch_of = &self.patch_of;
        let tally = Tally::of(exec);
        exec.for_each_chunk_mut(Split::Blocks(stride).of(&mut self.cursor), |w, cur| {
            tally.particles(w, partition(n, t, w).len());
            for p in partition(n, t, w) {
                let j = patch_of[p] as usize;
                let slot = j * rows + cur[j] as usize;
                cur[j] += 1;
                // SAFETY: worker w's slots in column j are rows
                // [sum_{v<w} patnp_th(v, j), sum_{v<=w} patnp_th(v, j)): the cursor starts at
                // the first and advances once per particle of chunk w in patch j, and the
                // counting pass counted exactly those particles (same chunk, same patch_of).
                // So the slots of different workers are disjoint and each is written once.
                unsafe { *pindex.get_mut(slot) = p as u32 + 1 };
            }
        });
    }

    /// `patnp_th(t, j)`.
    pub fn patnp_th(&self, t: usize, j: usize) -> u32 {
        self.patnp_th[t * self.stride + j]
    }

    /// `patnp(j)`: particles in patch `j`.
    pub fn patnp(&self, j: usize) -> u32 {
        self.patnp[j]
    }

    /// Rows of `Pindex` (`max(patnp)`).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// `Pindex(i, j)`: 1-based id of the particle with local id `i` in patch `j`, 0 if empty.
    pub fn pindex(&self, i: usize, j: usize) -> u32 {
        self.pindex[j * self.rows + i]
    }

    /// The filled part of column `j` of `Pindex`.
    pub fn column(&self, j: usize) -> &[u32] {
        &self.pindex[j * self.rows..j * self.rows + self.patnp[j] as usize]
    }

    fn bytes(&self) -> usize {
        size_of::<u32>()
            * (self.patch_of.capacity()
                + self.patnp_th.capacity()
                + self.cursor.capacity()
                + self.patnp.capacity()
                + self.pindex.capacity())
    }
}

/// Domain-decomposition state: patches of the current grid, their sub-grid offsets and the
/// binning.
#[derive(Clone, Debug)]
pub struct DomainDecomposition {
    threads: usize,
    /// Cut planes at particle quantiles every step (else uniform).
    balanced: bool,
    layout: [usize; 3],
    cut_for: Option<GridGeom>,
    patches: Vec<Patch>,
    /// Start of each patch's sub-grid in the scatter buffer (`patches + 1` entries).
    offsets: Vec<usize>,
    /// The cut planes and the cell-to-patch tables.
    cuts: Cuts,
    binning: Binning,
    /// Balanced cuts: each particle's cell, stored by the histogram pass.
    cell_of: Vec<[u32; 3]>,
    /// Balanced cuts: per-worker histograms (rows of `hist_stride`).
    hist: Vec<u32>,
    /// Balanced cuts: the histogram summed over the workers.
    hist_sum: Vec<u32>,
    /// Balanced cuts: the layout of each step.
    chooser: LayoutChooser,
    /// Particles per patch over the steps binned.
    load: PatchLoad,
    /// On a sparse grid, each patch's stored blocks (its sub-grid); empty on a dense grid.
    patch_blocks: Vec<BlockMap>,
}

impl DomainDecomposition {
    /// State for `threads` uniform patches (one per thread): the paper's DD.
    pub fn new(threads: usize) -> Self {
        Self {
            threads,
            balanced: false,
            layout: [1, 1, 1],
            cut_for: None,
            patches: Vec::with_capacity(threads),
            offsets: Vec::with_capacity(threads + 1),
            cuts: Cuts::default(),
            binning: Binning::default(),
            cell_of: Vec::new(),
            hist: Vec::new(),
            hist_sum: Vec::new(),
            chooser: LayoutChooser::default(),
            load: PatchLoad::default(),
            patch_blocks: Vec::new(),
        }
    }

    /// State for `threads` patches whose cut planes sit at the particle-count quantiles,
    /// recomputed every step.
    pub fn balanced(threads: usize) -> Self {
        Self { balanced: true, ..Self::new(threads) }
    }

    /// Whether the cuts are balanced (else uniform).
    pub fn is_balanced(&self) -> bool {
        self.balanced
    }

    /// The patch layout in use.
    pub fn layout(&self) -> [usize; 3] {
        self.layout
    }

    /// The patches of the current grid.
    pub fn patches(&self) -> &[Patch] {
        &self.patches
    }

    /// The cut planes of the current step.
    pub fn cuts(&self) -> &Cuts {
        &self.cuts
    }

    /// The binning of the current step.
    pub fn binning(&self) -> &Binning {
        &self.binning
    }

    /// Particles per patch and work imbalance over the steps binned so far.
    pub fn load(&self) -> &PatchLoad {
        &self.load
    }

    /// What later steps depend on besides the grid and the particles (a saved state): the
    /// layout the balanced cuts' chooser holds and the load recorded so far. The patches,
    /// cuts and binning are recomputed every step from the particles.
    pub fn carried(&self) -> (Option<[usize; 3]>, PatchLoad) {
        (self.chooser.current(), self.load)
    }

    /// Take over what [`DomainDecomposition::carried`] returned.
    pub fn carry_on(&mut self, layout_in_use: Option<[usize; 3]>, load: PatchLoad) {
        self.chooser = LayoutChooser::resumed(layout_in_use);
        self.load = load;
    }

    /// Cut `geom` into uniform patches if the grid changed (no allocation once capacities
    /// are reached). Balanced cuts start from these and move the planes every step.
    pub fn cut(&mut self, geom: &GridGeom) {
        if self.cut_for == Some(*geom) {
            return;
        }
        self.layout = patch_layout(self.threads, geom.cells);
        self.cuts.uniform(self.layout, geom.cells);
        self.rebuild_patches();
        self.cut_for = Some(*geom);
    }

    /// Patches and sub-grid offsets from the cuts.
    fn rebuild_patches(&mut self) {
        self.patches.clear();
        self.offsets.clear();
        let mut off = 0;
        self.offsets.push(0);
        // Patches are numbered z fastest (q_z + p_z (q_y + p_y q_x)), so that with the
        // Taylor bar's octant particle numbering (x halves first) patch j and particle
        // chunk j lie in the same region for the paper's 2, 4 and 8-thread layouts.
        for j in 0..self.cuts.patches() {
            let p = self.cuts.patch(j);
            off += p.num_nodes();
            self.patches.push(p);
            self.offsets.push(off);
        }
    }

    /// Balanced cuts for the particles at `x` on `geom` (the patches must have been cut for
    /// `geom`): the histogram passes described in the module page, the layout, then the
    /// patches.
    fn cut_balanced(&mut self, exec: &Exec<'_>, geom: &GridGeom, x: &[Vec3]) {
        let (n, t) = (x.len(), exec.workers());
        let [nx, ny, nz] = geom.cells;
        let row_len = |len: usize| len.div_ceil(ROW_STRIDE).max(1) * ROW_STRIDE;
        // Every particle's cell and per-worker counts per cell plane along x, y and z (one
        // row of nx + ny + nz per worker), in one pass.
        let stride = row_len(nx + ny + nz);
        self.cell_of.resize(n, [0; 3]);
        self.hist.resize(t * stride, 0);
        let cells = &mut self.cell_of;
        let tally = Tally::of(exec);
        exec.for_each_chunk_mut((Split::Even.of(cells), Split::Blocks(stride).of(&mut self.hist)), |w, (mine, row)| {
            tally.particles(w, mine.len());
            let row = &mut row[..nx + ny + nz];
            row.fill(0);
            for (slot, p) in mine.iter_mut().zip(partition(n, t, w)) {
                let c = geom.shape_cell(x[p]);
                *slot = c.map(|v| v as u32);
                row[c[0]] += 1;
                row[nx + c[1]] += 1;
                row[nx + ny + c[2]] += 1;
            }
        });
        self.sum_rows(nx + ny + nz, t, stride);
        let marginals = {
            let (hx, rest) = self.hist_sum.split_at(nx);
            let (hy, hz) = rest.split_at(ny);
            [hx, hy, hz]
        };
        let layout = self.chooser.choose(self.threads, patch_layout(self.threads, geom.cells), marginals);
        if layout != self.cuts.layout() {
            self.cuts.uniform(layout, geom.cells);
        }
        self.layout = layout;
        self.cuts.cut_axis(0, &self.hist_sum[..nx]);
        // Per slab (column) and y (z) cell plane, for the axes that are cut.
        for axis in (1..3).filter(|&a| layout[a] > 1) {
            let len = self.cuts.histogram_len(axis);
            let stride = row_len(len);
            self.hist.resize(t * stride, 0);
            let (cuts, cell_of) = (&self.cuts, &self.cell_of);
            exec.for_each_chunk_mut(Split::Blocks(stride).of(&mut self.hist[..t * stride]), |w, row| {
                tally.particles(w, partition(n, t, w).len());
                let row = &mut row[..len];
                row.fill(0);
                for p in partition(n, t, w) {
                    row[cuts.bin(axis, cell_of[p])] += 1;
                }
            });
            self.sum_rows(len, t, stride);
            self.cuts.cut_axis(axis, &self.hist_sum);
        }
        self.rebuild_patches();
    }

    /// Sum the first `len` entries of the workers' histogram rows (`stride` apart) into
    /// `hist_sum`.
    fn sum_rows(&mut self, len: usize, workers: usize, stride: usize) {
        self.hist_sum.clear();
        self.hist_sum.extend_from_slice(&self.hist[..len]);
        for w in 1..workers {
            for (s, h) in self.hist_sum.iter_mut().zip(&self.hist[w * stride..w * stride + len]) {
                *s += h;
            }
        }
    }

    /// Patch of the cell `c`.
    #[inline(always)]
    pub fn patch_of_cell(&self, c: [usize; 3]) -> usize {
        self.cuts.patch_of_cell(c)
    }

    /// Nodes in all sub-grids together.
    pub fn subgrid_nodes(&self) -> usize {
        *self.offsets.last().unwrap_or(&0)
    }

    /// On a sparse grid (`blocks`), each patch's sub-grid is the stored blocks meeting it:
    /// restrict the grid's map to every patch and size the sub-grids accordingly. On a dense
    /// grid the sub-grids are the patches' node boxes ([`Self::rebuild_patches`]).
    fn fit_subgrids(&mut self, blocks: Option<&BlockMap>) {
        let Some(global) = blocks else {
            self.patch_blocks.clear();
            return;
        };
        self.patch_blocks.resize_with(self.patches.len(), BlockMap::default);
        self.offsets.clear();
        self.offsets.push(0);
        let mut off = 0;
        for (patch, map) in self.patches.iter().zip(&mut self.patch_blocks) {
            map.restrict(global, patch.cell_lo, patch.node_hi());
            off += map.num_nodes();
            self.offsets.push(off);
        }
    }

    /// Patch `j`'s sub-grid numbering.
    #[inline]
    fn subgrid_index(&self, j: usize) -> NodeIndex<'_> {
        match self.patch_blocks.get(j) {
            Some(map) => NodeIndex::Blocks(map),
            None => self.patches[j].node_box(),
        }
    }

    /// The sparse assembly: for each patch in turn, parallel over its blocks, store each of
    /// the patch's nodes into `global` (numbered by `grid`) where the patch is the node's
    /// first, add it elsewhere: the dense assembly's rule, node by node.
    fn assemble_blocks<const K: usize>(
        &self,
        exec: &Exec<'_>,
        grid: &BlockMap,
        global: &mut [[f64; K]],
        subgrids: &[[f64; K]],
    ) {
        let t = exec.workers();
        let out = DisjointSlice::new(global);
        let tally = Tally::of(exec);
        for (j, (patch, map)) in self.patches.iter().zip(&self.patch_blocks).enumerate() {
            let sub = &subgrids[self.offsets[j]..self.offsets[j + 1]];
            let (lo, hi) = (patch.cell_lo, patch.node_hi());
            exec.run(|w| {
                let mut nodes = 0;
                for s in partition(map.len(), t, w) {
                    let b = map.block(s);
                    let g = grid.slot(b).expect("a patch's blocks are stored in the grid's map");
                    // SAFETY: a patch's map lists distinct blocks of the grid (one per table
                    // entry of its box), so their slots in the grid's map, and the node
                    // ranges below, are distinct; workers take disjoint ranges of the
                    // patch's blocks (one partition), and the patches are assembled one
                    // phase after another.
                    let dst = unsafe { out.range_mut(g * BLOCK_NODES..(g + 1) * BLOCK_NODES) };
                    let src = &sub[s * BLOCK_NODES..(s + 1) * BLOCK_NODES];
                    BlockMap::rows_in(b, lo, hi, |[a0, bb, c], locals| {
                        // The node's position in the patch, as `is_first_holder` takes it.
                        let (py, pz) = (b[1] * BLOCK[1] + bb - lo[1], b[2] * BLOCK[2] + c - lo[2]);
                        nodes += locals.len();
                        for (a, l) in (a0..).zip(locals) {
                            if patch.is_first_holder([b[0] * BLOCK[0] + a - lo[0], py, pz]) {
                                dst[l] = src[l];
                            } else {
                                for v in 0..K {
                                    dst[l][v] += src[l][v];
                                }
                            }
                        }
                    });
                }
                tally.assembled(w, nodes, nodes, std::mem::size_of::<[f64; K]>());
            });
        }
    }
}

/// The DD strategy: [`ScatterStrategy::prepare`] cuts the patches for the grid (if it
/// changed) and bins the particles; the scatter fills the sub-grids; the assembly adds them
/// into the global arrays patch by patch.
impl ScatterStrategy for DomainDecomposition {
    fn reserve(&mut self, geom: &GridGeom, blocks: Option<&BlockMap>) -> usize {
        self.cut(geom);
        self.fit_subgrids(blocks);
        self.subgrid_nodes()
    }

    /// Cut the patches for `geom` (if it changed), bin the particles at `x` and, on a
    /// sparse grid, find each patch's blocks.
    fn prepare(&mut self, exec: &Exec<'_>, geom: &GridGeom, blocks: Option<&BlockMap>, x: &[Vec3]) {
        self.cut(geom);
        if self.balanced {
            self.cut_balanced(exec, geom, x);
        }
        let g = *geom;
        let mut binning = std::mem::take(&mut self.binning);
        {
            let (cuts, cell_of) = (&self.cuts, &self.cell_of);
            if self.balanced {
                let patch = |p: usize| cuts.patch_of_cell(cell_of[p].map(|v| v as usize));
                binning.build(exec, x.len(), self.patches.len(), &patch);
            } else {
                let patch = |p: usize| cuts.patch_of_cell(g.shape_cell(x[p]));
                binning.build(exec, x.len(), self.patches.len(), &patch);
            }
        }
        self.load.record(&binning.patnp);
        self.binning = binning;
        self.fit_subgrids(blocks);
    }

    /// Thread `j` zeroes sub-grid `j` of `subgrids` and scatters patch `j`'s particles into it.
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        _geom: &GridGeom,
        index: &NodeIndex<'_>,
        _n: usize,
        _global: &mut [[f64; K]],
        subgrids: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        subgrids.resize(self.subgrid_nodes());
        let tally = Tally::of(exec);
        exec.for_each_chunk_mut(Split::Offsets(&self.offsets).of(subgrids), |j, sub| {
            sub.fill([0.0; K]);
            let mut nodes = Cursors::split(self.subgrid_index(j), *index);
            let column = self.binning.column(j);
            tally.particles(j, column.len());
            tally.scattered(j, sub.len(), size_of::<[f64; K]>(), true);
            kernel.scatter_all(column.iter().map(|&id| id as usize - 1), &mut nodes, sub);
        });
    }

    /// For each patch in turn, parallel over the patch's local node rows: store the
    /// sub-grid into `global` at the nodes whose first patch it is, add it elsewhere.
    fn assemble<const K: usize>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        global: &mut [[f64; K]],
        subgrids: &mut [[f64; K]],
    ) {
        // The row ranges below are disjoint, and inside `global`, only for the grid the
        // patches were cut for, and only if every patch lies inside that grid (the cuts'
        // invariant, checked here because the writes below rely on it).
        assert!(self.cut_for == Some(*geom), "DD assembly on a grid the patches were not cut for");
        for p in &self.patches {
            assert!(
                (0..3).all(|d| p.cell_lo[d] + p.cells[d] <= geom.cells[d]),
                "DD assembly: patch {:?} (cells {:?} from {:?}) reaches outside the grid of {:?} cells",
                p.index,
                p.cells,
                p.cell_lo,
                geom.cells
            );
        }
        if let NodeIndex::Blocks(grid) = index {
            assert_eq!(self.patch_blocks.len(), self.patches.len(), "DD assembly on a sparse grid before its blocks");
            return self.assemble_blocks(exec, grid, global, subgrids);
        }
        let t = exec.workers();
        let out = DisjointSlice::new(global);
        let tally = Tally::of(exec);
        for (j, patch) in self.patches.iter().enumerate() {
            let d = patch.node_dims();
            let rows = d[1] * d[2];
            let sub = &subgrids[self.offsets[j]..self.offsets[j + 1]];
            exec.run(|w| {
                let mine = partition(rows, t, w);
                tally.assembled(w, mine.len() * d[0], mine.len() * d[0], size_of::<[f64; K]>());
                for r in mine {
                    let (lj, lk) = (r % d[1], r / d[1]);
                    let g0 = geom.node_index(patch.cell_lo[0], patch.cell_lo[1] + lj, patch.cell_lo[2] + lk);
                    // SAFETY: the patches were cut for `geom` and lie inside it (both asserted
                    // above), so local row
                    // (lj, lk) of this patch is the d[0] nodes of global row (lo_y + lj,
                    // lo_z + lk) from x = lo_x, inside that row: distinct local rows are
                    // disjoint global ranges. Workers take disjoint local rows (one
                    // partition) and the patches are assembled one phase after another.
                    let dst = unsafe { out.range_mut(g0..g0 + d[0]) };
                    let src = &sub[r * d[0]..(r + 1) * d[0]];
                    // Along a row only the first node can have a lower patch in x.
                    let stored_from = if !patch.is_first_holder([1, lj, lk]) {
                        d[0]
                    } else {
                        usize::from(!patch.is_first_holder([0, lj, lk]))
                    };
                    let (added, stored) = dst.split_at_mut(stored_from);
                    stored.copy_from_slice(&src[stored_from..]);
                    for (a, b) in added.iter_mut().zip(src) {
                        for k in 0..K {
                            a[k] += b[k];
                        }
                    }
                }
            });
        }
    }

    fn bytes(&self) -> usize {
        self.binning.bytes()
            + self.cuts.bytes()
            + crate::capacity_bytes(&self.cell_of)
            + crate::capacity_bytes(&self.hist)
            + crate::capacity_bytes(&self.hist_sum)
            + self.patch_blocks.iter().map(BlockMap::bytes).sum::<usize>()
            + crate::capacity_bytes(&self.patch_blocks)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::parallel::Team;

    /// Run `f` in a parallel region of `threads` workers: the executor the solver uses.
    fn in_region<R: Send>(threads: usize, f: impl FnOnce(&Exec<'_>) -> R + Send) -> R {
        Team::new(crate::testing::pool(threads)).region(f).unwrap()
    }

    /// The paper's worked example: 16 particles, 4 patches, 4 threads.
    #[test]
    fn reproduces_the_papers_binning_example() {
        let membership: [&[usize]; 4] = [&[2, 3, 5, 11], &[1, 6, 7, 16], &[8, 10, 14], &[4, 9, 12, 13, 15]];
        let patch_of = |p: usize| membership.iter().position(|m| m.contains(&(p + 1))).unwrap();
        let mut b = Binning::default();
        in_region(4, |exec| b.build(exec, 16, 4, &patch_of));

        let patnp_th: Vec<Vec<u32>> = (0..4).map(|t| (0..4).map(|j| b.patnp_th(t, j)).collect()).collect();
        assert_eq!(patnp_th, vec![vec![2, 1, 0, 1], vec![1, 2, 1, 0], vec![1, 0, 1, 2], vec![0, 1, 1, 2]]);
        assert_eq!((0..4).map(|j| b.patnp(j)).collect::<Vec<_>>(), vec![4, 4, 3, 5]);
        assert_eq!(b.rows(), 5);
        let pindex: Vec<Vec<u32>> = (0..5).map(|i| (0..4).map(|j| b.pindex(i, j)).collect()).collect();
        assert_eq!(
            pindex,
            vec![vec![2, 1, 8, 4], vec![3, 6, 10, 9], vec![5, 7, 14, 12], vec![11, 16, 0, 13], vec![0, 0, 0, 15]]
        );
    }

    #[test]
    fn binning_lists_every_particle_once_for_any_thread_count() {
        for threads in [1, 2, 3, 5, 8] {
            let mut b = Binning::default();
            let n = 10_007;
            let patch = |p: usize| (p * 7919) % threads;
            in_region(threads, |exec| b.build(exec, n, threads, &patch));
            let mut seen = vec![0u8; n];
            for j in 0..threads {
                let col = b.column(j);
                assert!(col.windows(2).all(|w| w[0] < w[1]), "ids ascend within a patch");
                for &id in col {
                    assert_eq!(patch(id as usize - 1), j);
                    seen[id as usize - 1] += 1;
                }
            }
            assert!(seen.iter().all(|&s| s == 1));
        }
    }

    #[test]
    fn paper_layouts_and_factorisations() {
        let cells = [32, 32, 48];
        assert_eq!(patch_layout(6, cells), [2, 1, 3]);
        assert_eq!(patch_layout(8, cells), [2, 2, 2]);
        assert_eq!(patch_layout(3, cells), [1, 1, 3]);
        assert_eq!(patch_layout(12, [10, 10, 100]).iter().product::<usize>(), 12);
    }

    #[test]
    fn patches_cover_the_grid_and_node_maps_are_inverse() {
        let spec = GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [5, 3, 7] };
        let geom = GridGeom::fixed(&spec);
        for threads in [1, 2, 3, 4, 6, 8] {
            let mut dd = DomainDecomposition::new(threads);
            dd.cut(&geom);
            assert_eq!(dd.patches().len(), threads);
            let cells: usize = dd.patches().iter().map(|p| p.cells.iter().product::<usize>()).sum();
            assert_eq!(cells, geom.num_cells());
            let mut covered = vec![false; geom.num_nodes()];
            for p in dd.patches() {
                for s in 0..p.num_nodes() {
                    let g = p.globalnode(s, &geom);
                    assert_eq!(p.subnodefun(g, &geom), Some(s));
                    covered[g] = true;
                }
            }
            assert!(covered.iter().all(|&c| c));
            // Every cell's patch contains the cell.
            for k in 0..7 {
                for j in 0..3 {
                    for i in 0..5 {
                        let p = dd.patches()[dd.patch_of_cell([i, j, k])];
                        for (d, c) in [i, j, k].into_iter().enumerate() {
                            assert!(c >= p.cell_lo[d] && c < p.cell_lo[d] + p.cells[d]);
                        }
                    }
                }
            }
        }
    }

    /// The assembly stores each node once (at its first patch) and adds the rest, without
    /// zeroing: starting from a global array full of NaN it must give exactly the sum of
    /// every patch's sub-grid, for every layout, also when the grid has fewer cells than
    /// patches along an axis (zero-cell patches share a node plane with their neighbours).
    /// A node stored twice, added to stale data or never written fails this.
    #[test]
    fn assembly_without_zeroing_sums_every_subgrid_exactly_once() {
        for cells in [[5, 3, 7], [1, 1, 2], [4, 1, 1]] {
            let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells });
            for threads in [1, 2, 3, 4, 6, 8] {
                let mut dd = DomainDecomposition::new(threads);
                dd.cut(&geom);
                check_assembly(&dd, &geom, threads);
            }
        }
    }

    /// A patch that reaches outside the grid (a broken cut) stops the assembly before its
    /// unchecked writes: its last row would run past the global array or into the next row.
    #[test]
    #[should_panic(expected = "reaches outside the grid")]
    fn assembly_refuses_a_patch_outside_the_grid() {
        let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [4, 3, 2] });
        let mut dd = DomainDecomposition::new(2);
        dd.cut(&geom);
        dd.patches[1].cells[0] += 1;
        let mut buf = vec![[0.0; 2]; dd.subgrid_nodes() + 64];
        let mut global = vec![[0.0; 2]; geom.num_nodes()];
        in_region(2, |exec| dd.assemble(exec, &geom, &NodeIndex::of(&geom, None), &mut global, &mut buf));
    }

    /// Assemble a sub-grid buffer of distinct values into a NaN-filled global array and
    /// compare with the sum over every patch's nodes.
    fn check_assembly(dd: &DomainDecomposition, geom: &GridGeom, threads: usize) {
        // Distinct small integers and halves: their sums are exact, so equality is exact.
        let mut buf: Vec<[f64; 2]> = (0..dd.subgrid_nodes()).map(|i| [1.0 + i as f64, -0.5 * i as f64]).collect();
        let mut want = vec![[0.0; 2]; geom.num_nodes()];
        for (j, p) in dd.patches().iter().enumerate() {
            for s in 0..p.num_nodes() {
                let g = p.globalnode(s, geom);
                for k in 0..2 {
                    want[g][k] += buf[dd.offsets[j] + s][k];
                }
            }
        }
        let mut global = vec![[f64::NAN; 2]; geom.num_nodes()];
        in_region(threads, |exec| dd.assemble(exec, geom, &NodeIndex::of(geom, None), &mut global, &mut buf));
        assert_eq!(global, want, "cells {:?}, {threads} threads, balanced {}", geom.cells, dd.is_balanced());
    }

    /// On a sparse grid each patch's sub-grid is the stored blocks meeting it; the assembly
    /// must store or add each patch's nodes exactly once into the grid's blocks, for every
    /// layout (uniform and balanced cuts), over NaN-filled global arrays.
    #[test]
    fn sparse_assembly_sums_every_patch_block_exactly_once() {
        // The particles fill 9 x 7 x 11 cells of a larger grid.
        let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [25, 19, 31] });
        let x = clustered(3000);
        let mut grid = BlockMap::default();
        grid.build(&Exec::serial(), &geom, &x);
        assert!(grid.num_nodes() < geom.num_nodes(), "the test wants a grid with blocks left out");
        for balanced in [false, true] {
            for threads in [1, 2, 3, 4, 6, 8] {
                let mut dd =
                    if balanced { DomainDecomposition::balanced(threads) } else { DomainDecomposition::new(threads) };
                dd.reserve(&geom, Some(&grid));
                in_region(threads, |exec| dd.prepare(exec, &geom, Some(&grid), &x));
                let mut buf: Vec<[f64; 2]> =
                    (0..dd.subgrid_nodes()).map(|i| [1.0 + i as f64, -0.5 * i as f64]).collect();
                let mut want = vec![[0.0; 2]; grid.num_nodes()];
                for (j, (p, map)) in dd.patches().iter().zip(&dd.patch_blocks).enumerate() {
                    for s in 0..map.len() {
                        let b = map.block(s);
                        let g = grid.slot(b).unwrap();
                        BlockMap::rows_in(b, p.cell_lo, p.node_hi(), |_, locals| {
                            for l in locals {
                                for k in 0..2 {
                                    want[g * BLOCK_NODES + l][k] += buf[dd.offsets[j] + s * BLOCK_NODES + l][k];
                                }
                            }
                        });
                    }
                }
                let mut global = vec![[f64::NAN; 2]; grid.num_nodes()];
                in_region(threads, |exec| dd.assemble(exec, &geom, &NodeIndex::Blocks(&grid), &mut global, &mut buf));
                for s in 0..grid.len() {
                    BlockMap::rows_in(grid.block(s), [0; 3], geom.cells, |_, locals| {
                        for l in locals {
                            let n = s * BLOCK_NODES + l;
                            assert_eq!(global[n], want[n], "node {n}, {threads} threads, balanced {balanced}");
                        }
                    });
                }
            }
        }
    }

    /// Particles in a dense block plus a sparse spread over a 9 x 7 x 11 grid.
    fn clustered(n: usize) -> Vec<Vec3> {
        let mut unit = crate::testing::unit_stream(12345);
        (0..n)
            .map(|i| {
                if i % 5 == 0 {
                    [9.0 * unit(), 7.0 * unit(), 11.0 * unit()]
                } else {
                    [1.0 + 6.0 * unit(), 1.0 + 4.0 * unit(), 3.0 + 6.0 * unit()]
                }
            })
            .collect()
    }

    /// The parallel histogram passes give the serial reference's cuts for every thread
    /// count; the binning lists every particle once, in the patch holding its cell; the
    /// assembly stays exact on nested (non-aligned) cuts; and the cuts balance the block.
    #[test]
    fn balanced_cuts_match_the_serial_reference_and_assemble_exactly() {
        let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [9, 7, 11] });
        let x = clustered(4000);
        let cell_of: Vec<[u32; 3]> = x.iter().map(|&p| geom.shape_cell(p).map(|v| v as u32)).collect();
        for threads in [1, 2, 3, 4, 6, 8] {
            let mut dd = DomainDecomposition::balanced(threads);
            dd.reserve(&geom, None);
            in_region(threads, |exec| dd.prepare(exec, &geom, None, &x));
            assert_eq!(dd.cuts(), &Cuts::balanced(&cell_of, geom.cells, dd.layout()), "{threads} threads");
            let mut listed = 0;
            for (j, p) in dd.patches().iter().enumerate() {
                for &id in dd.binning().column(j) {
                    let c = geom.shape_cell(x[id as usize - 1]);
                    assert!((0..3).all(|d| c[d] >= p.cell_lo[d] && c[d] < p.cell_lo[d] + p.cells[d]));
                    listed += 1;
                }
            }
            assert_eq!(listed, x.len());
            check_assembly(&dd, &geom, threads);
            let counts: Vec<u32> = (0..threads).map(|j| dd.binning().patnp(j)).collect();
            let imbalance = super::super::cuts::imbalance(&counts).unwrap();
            assert!(imbalance < 1.2, "{threads} threads: {counts:?}");
            assert_eq!(dd.load().steps, 1);
        }
    }
}
