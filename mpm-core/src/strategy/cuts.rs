//! Where the cut planes of a `px x py x pz` patch layout lie: uniform cuts (the paper's DD)
//! and balanced cuts (each plane at the particle-count quantile along its axis), and the
//! per-patch particle counts and work imbalance they give.
//!
//! Balanced cuts also choose their layout among the factorisations of the patch count
//! ([`LayoutChooser`]): the paper's layout unless another predicts a clearly smaller
//! imbalance.
//!
//! Cuts are nested: the `px - 1` x planes cut the whole grid into slabs, each slab has its
//! own `py - 1` y planes cutting it into columns, each column its own `pz - 1` z planes.
//! Every plane lies on a cell boundary. Patch `(qx, qy, qz)` is numbered
//! `qz + pz (qy + py qx)` (z fastest), as in [`super::domain_decomposition`], whose
//! sub-grids, `Pindex` and assembly work unchanged on nested cuts: a patch's lower
//! neighbours along any axis still have lower numbers.
//!
//! The cut computation is pure and serial ([`quantile_cuts`] for one axis, [`Cuts::cut_x`],
//! [`Cuts::cut_y`], [`Cuts::cut_z`] for the nested levels from per-slab histograms, and
//! [`Cuts::balanced`] from the particles' cells in one call, [`LayoutChooser`] for the
//! layout of balanced cuts) so that anything that needs
//! boxes of equal particle counts (the DD strategy every step, `mpm-bench imbalance`, rank
//! boxes of a distributed run) computes the same boxes. Its cost is O(cells along an axis x
//! patches); once the tables have reached their largest size it allocates nothing.

use super::patch::Patch;
use serde::{Deserialize, Serialize};

/// Place the `parts - 1` inner cut planes of one axis at the particle-count quantiles of
/// `hist` (particles per cell plane along the axis). `cuts` has `parts + 1` entries and
/// receives cell boundaries: `cuts[0] = 0`, `cuts[parts] = hist.len()`, non-decreasing.
///
/// Plane `q` goes to the boundary `b` whose particle count below, `sum(hist[..b])`, is
/// nearest to `q / parts` of the total (ties to the lower boundary). Then every part is made
/// at least one cell wide when the axis has at least `parts` cells (a plane is moved up past
/// its lower neighbour, or down to leave room for the parts above it). With no particles, or
/// when the uniform cuts of the paper's DD leave a smaller largest part (planes rounded to
/// cell boundaries one by one can lose to them), the cuts are uniform: balanced cuts are
/// never worse than uniform along one axis.
pub fn quantile_cuts(hist: &[u32], cuts: &mut [u32]) {
    assert!(cuts.len() >= 2, "cuts need parts + 1 >= 2 entries");
    let parts = cuts.len() - 1;
    let n = hist.len();
    let total: u64 = hist.iter().map(|&h| u64::from(h)).sum();
    if total == 0 {
        uniform_cuts(n, cuts);
        return;
    }
    let p = parts as u64;
    let (mut b, mut below) = (0usize, 0u64);
    cuts[0] = 0;
    for q in 1..parts {
        let target = q as u64 * total;
        // The lowest boundary with at least q/parts of the particles below it.
        while b < n && p * below < target {
            below += u64::from(hist[b]);
            b += 1;
        }
        let mut cut = b;
        if b > 0 {
            let lower = below - u64::from(hist[b - 1]);
            if target - p * lower <= p * below - target {
                cut = b - 1;
            }
        }
        cuts[q] = cut as u32;
    }
    cuts[parts] = n as u32;
    for q in 1..parts {
        let prev = cuts[q - 1];
        cuts[q] = if n >= parts { cuts[q].max(prev + 1).min((n - (parts - q)) as u32) } else { cuts[q].max(prev) };
    }
    // Each plane rounds to a cell boundary on its own, so the largest part can come out
    // above that of the uniform cuts; keep whichever is smaller (ties: the quantiles).
    if largest_part(hist, cuts.windows(2).map(|w| (w[0], w[1]))) > largest_part(hist, uniform_parts(n, parts)) {
        uniform_cuts(n, cuts);
    }
}

/// Particles in the fullest of the parts `[lo, hi)`.
fn largest_part(hist: &[u32], parts: impl Iterator<Item = (u32, u32)>) -> u64 {
    parts.map(|(lo, hi)| hist[lo as usize..hi as usize].iter().map(|&h| u64::from(h)).sum()).max().unwrap_or(0)
}

/// The parts `[lo, hi)` of uniform cuts of `n` cells.
fn uniform_parts(n: usize, parts: usize) -> impl Iterator<Item = (u32, u32)> {
    (0..parts).map(move |q| ((q * n / parts) as u32, ((q + 1) * n / parts) as u32))
}

/// Uniform cuts of `n` cells into `cuts.len() - 1` parts: boundary `q` at `q n / parts`.
pub fn uniform_cuts(n: usize, cuts: &mut [u32]) {
    let parts = cuts.len() - 1;
    for (q, c) in cuts.iter_mut().enumerate() {
        *c = (q * n / parts) as u32;
    }
}

/// The nested cut planes of one layout over one grid, with the cell-to-part tables that
/// find a cell's patch in three look-ups.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Cuts {
    layout: [usize; 3],
    cells: [usize; 3],
    /// `px + 1` x boundaries.
    x: Vec<u32>,
    /// `py + 1` y boundaries per x slab, slab after slab.
    y: Vec<u32>,
    /// `pz + 1` z boundaries per xy column (column `qy + py qx`), column after column.
    z: Vec<u32>,
    /// Slab of each x cell.
    part_x: Vec<u32>,
    /// Column-in-slab of each y cell, per slab (`qx ny + cy`).
    part_y: Vec<u32>,
    /// Patch-in-column of each z cell, per column (`(qy + py qx) nz + cz`).
    part_z: Vec<u32>,
}

/// Fill `part[cuts[q]..cuts[q + 1]]` with `q`.
fn fill_parts(cuts: &[u32], part: &mut [u32]) {
    for (q, w) in cuts.windows(2).enumerate() {
        part[w[0] as usize..w[1] as usize].fill(q as u32);
    }
}

impl Cuts {
    /// Size the tables for `layout` over a grid of `cells` (no allocation once the
    /// capacities are reached) and cut uniformly.
    pub fn uniform(&mut self, layout: [usize; 3], cells: [usize; 3]) {
        self.reset(layout, cells);
        let [px, py, pz] = layout;
        uniform_cuts(cells[0], &mut self.x);
        for s in 0..px {
            uniform_cuts(cells[1], &mut self.y[s * (py + 1)..(s + 1) * (py + 1)]);
        }
        for c in 0..px * py {
            uniform_cuts(cells[2], &mut self.z[c * (pz + 1)..(c + 1) * (pz + 1)]);
        }
        self.fill_tables();
    }

    /// Balanced cuts of `layout` over a grid of `cells` for particles in the cells
    /// `cell_of` (serial; the reference of the DD strategy's parallel passes and what a
    /// distributed run would use for its rank boxes). Allocates its histograms.
    pub fn balanced(cell_of: &[[u32; 3]], cells: [usize; 3], layout: [usize; 3]) -> Self {
        let mut cuts = Cuts::default();
        cuts.reset(layout, cells);
        let mut hist = vec![0u32; cuts.histogram_len(0)];
        cell_of.iter().for_each(|c| hist[cuts.bin(0, *c)] += 1);
        cuts.cut_x(&hist);
        for axis in 1..3 {
            hist.clear();
            hist.resize(cuts.histogram_len(axis), 0);
            cell_of.iter().for_each(|c| hist[cuts.bin(axis, *c)] += 1);
            cuts.cut_axis(axis, &hist);
        }
        cuts
    }

    /// Size the tables for `layout` over `cells` (boundaries not yet set).
    pub fn reset(&mut self, layout: [usize; 3], cells: [usize; 3]) {
        let [px, py, pz] = layout;
        self.layout = layout;
        self.cells = cells;
        self.x.resize(px + 1, 0);
        self.y.resize(px * (py + 1), 0);
        self.z.resize(px * py * (pz + 1), 0);
        self.part_x.resize(cells[0], 0);
        self.part_y.resize(px * cells[1], 0);
        self.part_z.resize(px * py * cells[2], 0);
    }

    /// Length of the histogram that sets the cuts along `axis`: `nx` cell planes for x,
    /// `ny` per slab for y, `nz` per column for z.
    pub fn histogram_len(&self, axis: usize) -> usize {
        let [px, py, _] = self.layout;
        match axis {
            0 => self.cells[0],
            1 => px * self.cells[1],
            _ => px * py * self.cells[2],
        }
    }

    /// The histogram bin of a particle in cell `c` for the cuts along `axis` (the x cuts
    /// and, for z, the y cuts must be set already).
    #[inline(always)]
    pub fn bin(&self, axis: usize, c: [u32; 3]) -> usize {
        let [_, py, _] = self.layout;
        let qx = || self.part_x[c[0] as usize] as usize;
        match axis {
            0 => c[0] as usize,
            1 => qx() * self.cells[1] + c[1] as usize,
            _ => {
                let s = qx();
                let qy = self.part_y[s * self.cells[1] + c[1] as usize] as usize;
                (qy + py * s) * self.cells[2] + c[2] as usize
            }
        }
    }

    /// Set the x cuts from particles per x cell plane (`nx` entries).
    pub fn cut_x(&mut self, hist: &[u32]) {
        self.cut_axis(0, hist);
    }

    /// Set each slab's y cuts from its particles per y cell plane (`px ny` entries, slab
    /// after slab, binned by [`Cuts::bin`]).
    pub fn cut_y(&mut self, hist: &[u32]) {
        self.cut_axis(1, hist);
    }

    /// Set each column's z cuts from its particles per z cell plane (`px py nz` entries).
    pub fn cut_z(&mut self, hist: &[u32]) {
        self.cut_axis(2, hist);
    }

    /// Set the cuts along `axis` from its histogram and refresh that axis's part table.
    pub fn cut_axis(&mut self, axis: usize, hist: &[u32]) {
        assert_eq!(hist.len(), self.histogram_len(axis), "histogram of axis {axis} has the wrong length");
        let n = self.cells[axis];
        let parts = self.layout[axis];
        let (cuts, table) = match axis {
            0 => (&mut self.x, &mut self.part_x),
            1 => (&mut self.y, &mut self.part_y),
            _ => (&mut self.z, &mut self.part_z),
        };
        for (g, (c, t)) in cuts.chunks_exact_mut(parts + 1).zip(table.chunks_exact_mut(n.max(1))).enumerate() {
            quantile_cuts(&hist[g * n..(g + 1) * n], c);
            if n > 0 {
                fill_parts(c, t);
            }
        }
    }

    fn fill_tables(&mut self) {
        let n = self.cells;
        let [px, py, pz] = self.layout;
        fill_parts(&self.x, &mut self.part_x);
        for s in 0..px {
            fill_parts(&self.y[s * (py + 1)..(s + 1) * (py + 1)], &mut self.part_y[s * n[1]..(s + 1) * n[1]]);
        }
        for c in 0..px * py {
            fill_parts(&self.z[c * (pz + 1)..(c + 1) * (pz + 1)], &mut self.part_z[c * n[2]..(c + 1) * n[2]]);
        }
    }

    /// The layout `[px, py, pz]`.
    pub fn layout(&self) -> [usize; 3] {
        self.layout
    }

    /// The grid's cells per axis the cuts were made for.
    pub fn cells(&self) -> [usize; 3] {
        self.cells
    }

    /// Number of patches.
    pub fn patches(&self) -> usize {
        self.layout.iter().product()
    }

    /// The x boundaries (`px + 1`).
    pub fn x_cuts(&self) -> &[u32] {
        &self.x
    }

    /// The y boundaries of slab `qx` (`py + 1`).
    pub fn y_cuts(&self, qx: usize) -> &[u32] {
        let py = self.layout[1];
        &self.y[qx * (py + 1)..(qx + 1) * (py + 1)]
    }

    /// The z boundaries of column `(qx, qy)` (`pz + 1`).
    pub fn z_cuts(&self, qx: usize, qy: usize) -> &[u32] {
        let [_, py, pz] = self.layout;
        let c = qy + py * qx;
        &self.z[c * (pz + 1)..(c + 1) * (pz + 1)]
    }

    /// Patch number of cell `c` (z fastest: `qz + pz (qy + py qx)`).
    #[inline(always)]
    pub fn patch_of_cell(&self, c: [usize; 3]) -> usize {
        let [_, py, pz] = self.layout;
        let n = self.cells;
        let qx = self.part_x[c[0]] as usize;
        let col = self.part_y[qx * n[1] + c[1]] as usize + py * qx;
        self.part_z[col * n[2] + c[2]] as usize + pz * col
    }

    /// Patch `j`: its layout position and box of cells.
    pub fn patch(&self, j: usize) -> Patch {
        let [_, py, pz] = self.layout;
        let q = [j / (py * pz), (j / pz) % py, j % pz];
        let bounds =
            [&self.x[q[0]..q[0] + 2], &self.y_cuts(q[0])[q[1]..q[1] + 2], &self.z_cuts(q[0], q[1])[q[2]..q[2] + 2]];
        Patch { index: q, cell_lo: bounds.map(|b| b[0] as usize), cells: bounds.map(|b| (b[1] - b[0]) as usize) }
    }

    /// Particles per patch for particles in the cells `cell_of` (`counts` has one entry per
    /// patch).
    pub fn count(&self, cell_of: &[[u32; 3]], counts: &mut [u32]) {
        counts.fill(0);
        for c in cell_of {
            counts[self.patch_of_cell(c.map(|v| v as usize))] += 1;
        }
    }

    /// Bytes held by the tables.
    pub fn bytes(&self) -> usize {
        [&self.x, &self.y, &self.z, &self.part_x, &self.part_y, &self.part_z]
            .iter()
            .map(|v| crate::capacity_bytes(v))
            .sum()
    }
}

/// Every layout `[px, py, pz]` of `threads` patches (`px py pz = threads`), px outermost,
/// then py.
pub fn layouts(threads: usize) -> impl Iterator<Item = [usize; 3]> {
    (1..=threads).filter(move |px| threads.is_multiple_of(*px)).flat_map(move |px| {
        let rest = threads / px;
        (1..=rest).filter(move |py| rest.is_multiple_of(*py)).map(move |py| [px, py, rest / py])
    })
}

/// How far a layout's predicted imbalance may lie above the best layout's (relative) and
/// still be kept: the paper's layout first, then the layout in use. Without the slack the
/// layout would flip between near-equal candidates from step to step.
pub const LAYOUT_SLACK: f64 = 0.02;

/// Chooses the layout of balanced cuts every step: predicts each layout's work imbalance
/// from the particles per cell plane along each axis (one histogram per axis, from the
/// pass that stores the particles' cells) and takes the paper's layout unless another does
/// better by more than [`LAYOUT_SLACK`].
///
/// Why the layout must be free: a fixed layout can only be as balanced as its thinnest cut
/// axis allows. The impact's plate is three cells thick at 2.12 mm cells, so the 2x2x2
/// layout of 8 threads must cut three cell planes into two parts along z, which leaves at
/// best 2/3 of the plate in one part (imbalance about 1.3 whatever the planes); 4x2x1 cuts
/// only across the plate and balances it.
///
/// The prediction of a layout is the product over the axes of the one-axis imbalance of
/// quantile cuts of that axis's histogram (largest part times parts over the total): exact
/// when the particle density is a product of one-axis densities, and an upper estimate for
/// nested cuts otherwise, since each slab and column gets its own planes. Its cost is
/// O(layouts x cells along an axis), serial; it allocates nothing once its scratch has grown.
#[derive(Clone, Debug, Default)]
pub struct LayoutChooser {
    current: Option<[usize; 3]>,
    scratch: Vec<u32>,
}

impl LayoutChooser {
    /// The layout in use (`None` before the first choice).
    pub fn current(&self) -> Option<[usize; 3]> {
        self.current
    }

    /// A chooser whose layout in use is `current` (a run continued from a saved state
    /// keeps the layout the hysteresis held, see [`LayoutChooser::choose`]).
    pub fn resumed(current: Option<[usize; 3]>) -> Self {
        Self { current, scratch: Vec::new() }
    }

    /// Predicted work imbalance of `layout` for the histograms `marginals` (particles per
    /// cell plane along x, y and z); 1 without particles.
    pub fn predict(&mut self, marginals: [&[u32]; 3], layout: [usize; 3]) -> f64 {
        let mut product = 1.0;
        for (hist, &parts) in marginals.iter().zip(&layout) {
            let total: u64 = hist.iter().map(|&h| u64::from(h)).sum();
            if parts == 1 || total == 0 {
                continue;
            }
            self.scratch.resize(parts + 1, 0);
            quantile_cuts(hist, &mut self.scratch);
            let largest = largest_part(hist, self.scratch.windows(2).map(|w| (w[0], w[1])));
            product *= largest as f64 * parts as f64 / total as f64;
        }
        product
    }

    /// The layout for this step among [`layouts`]`(threads)`: `preferred` (the paper's) if
    /// its prediction is within [`LAYOUT_SLACK`] of the best, else the layout in use if it
    /// is, else the best (ties: the earlier in [`layouts`] order).
    pub fn choose(&mut self, threads: usize, preferred: [usize; 3], marginals: [&[u32]; 3]) -> [usize; 3] {
        let mut best = (preferred, self.predict(marginals, preferred));
        for layout in layouts(threads) {
            let p = self.predict(marginals, layout);
            if p < best.1 {
                best = (layout, p);
            }
        }
        let bound = best.1 * (1.0 + LAYOUT_SLACK);
        let keep = |me: &mut Self, l: [usize; 3]| me.predict(marginals, l) <= bound;
        let current = self.current;
        let chosen = if keep(self, preferred) {
            preferred
        } else {
            match current {
                Some(c) if c.iter().product::<usize>() == threads && keep(self, c) => c,
                _ => best.0,
            }
        };
        self.current = Some(chosen);
        chosen
    }
}

/// Work imbalance of one step: the largest patch's particle count over the mean (1 when the
/// patches are equal; `None` without particles).
pub fn imbalance(counts: &[u32]) -> Option<f64> {
    let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
    let max = counts.iter().copied().max()?;
    (total > 0).then(|| f64::from(max) * counts.len() as f64 / total as f64)
}

/// Per-patch particle counts and work imbalance accumulated over the steps of a run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct PatchLoad {
    /// Steps recorded.
    pub steps: u64,
    /// Fewest particles in a patch, over every patch and step.
    pub min: u32,
    /// Most particles in a patch, over every patch and step.
    pub max: u32,
    /// Sum over the steps of the mean particles per patch.
    mean_sum: f64,
    /// Sum over the steps of the step's imbalance (max / mean).
    imbalance_sum: f64,
    /// Largest imbalance of a step.
    pub imbalance_max: f64,
}

impl PatchLoad {
    /// Record one step's per-patch particle counts (steps without particles are skipped).
    pub fn record(&mut self, counts: &[u32]) {
        let Some(imb) = imbalance(counts) else { return };
        let total: u64 = counts.iter().map(|&c| u64::from(c)).sum();
        let (lo, hi) = counts.iter().fold((u32::MAX, 0), |(lo, hi), &c| (lo.min(c), hi.max(c)));
        self.min = if self.steps == 0 { lo } else { self.min.min(lo) };
        self.max = self.max.max(hi);
        self.mean_sum += total as f64 / counts.len() as f64;
        self.imbalance_sum += imb;
        self.imbalance_max = self.imbalance_max.max(imb);
        self.steps += 1;
    }

    /// Mean particles per patch over the steps (0 before any step).
    pub fn mean(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.mean_sum / self.steps as f64
        }
    }

    /// Mean over the steps of the work imbalance max / mean (0 before any step).
    pub fn imbalance_mean(&self) -> f64 {
        if self.steps == 0 {
            0.0
        } else {
            self.imbalance_sum / self.steps as f64
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// SplitMix64, for reproducible random test data.
    struct SplitMix(u64);

    impl SplitMix {
        fn below(&mut self, n: usize) -> usize {
            self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
            let mut z = self.0;
            z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
            z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
            if n == 0 {
                0
            } else {
                ((z ^ (z >> 31)) % n as u64) as usize
            }
        }
    }

    fn cuts_of(hist: &[u32], parts: usize) -> Vec<u32> {
        let mut c = vec![0; parts + 1];
        quantile_cuts(hist, &mut c);
        c
    }

    #[test]
    fn cuts_sit_at_the_particle_quantiles() {
        // 100 particles evenly over 10 planes: the uniform cuts.
        assert_eq!(cuts_of(&[10; 10], 2), vec![0, 5, 10]);
        assert_eq!(cuts_of(&[10; 10], 5), vec![0, 2, 4, 6, 8, 10]);
        // Everything in the last 4 planes of 12: the cuts share out those 4 planes.
        let mut h = [0; 12];
        h[8..].fill(25);
        assert_eq!(cuts_of(&h, 2), vec![0, 10, 12]);
        assert_eq!(cuts_of(&h, 4), vec![0, 9, 10, 11, 12]);
        // Nearest boundary: 1 + 1 + 6 + 2 = 10, half is 5: below 2 planes 2, below 3 planes 8;
        // |2 - 5| = 3 ties |8 - 5| = 3 -> the lower boundary.
        assert_eq!(cuts_of(&[1, 1, 6, 2], 2), vec![0, 2, 4]);
        assert_eq!(cuts_of(&[1, 1, 7, 1], 2), vec![0, 2, 4]);
        // 1 + 3 = 4 below 2 planes, 5 below 3: exactly half -> 3.
        assert_eq!(cuts_of(&[1, 3, 1, 5], 2), vec![0, 3, 4]);
    }

    #[test]
    fn empty_histograms_and_one_cell_give_valid_cuts() {
        // No particles: uniform cuts.
        assert_eq!(cuts_of(&[0; 9], 3), vec![0, 3, 6, 9]);
        // Every particle in one plane: one part gets it, every part keeps one plane.
        let mut h = [0; 7];
        h[3] = 1000;
        assert_eq!(cuts_of(&h, 2), vec![0, 3, 7]);
        assert_eq!(cuts_of(&h, 3), vec![0, 3, 4, 7]);
        h = [0; 7];
        h[0] = 5;
        assert_eq!(cuts_of(&h, 3), vec![0, 1, 2, 7]);
        h = [0; 7];
        h[6] = 5;
        assert_eq!(cuts_of(&h, 3), vec![0, 5, 6, 7]);
        // Fewer planes than parts: non-decreasing, some parts empty.
        assert_eq!(cuts_of(&[4], 2), vec![0, 0, 1]);
        assert_eq!(cuts_of(&[], 2), vec![0, 0, 0]);
    }

    /// Random histograms: cuts start at 0, end at n, lie on boundaries, leave every part at
    /// least one plane when n >= parts, and no single plane could be moved to a boundary
    /// nearer its quantile without breaking those rules.
    #[test]
    fn cuts_are_boundaries_with_every_part_at_least_one_plane() {
        let mut rng = SplitMix(7);
        for _ in 0..2000 {
            let n = rng.below(20);
            let parts = 1 + rng.below(5);
            let hist: Vec<u32> = (0..n).map(|_| if rng.below(3) == 0 { 0 } else { rng.below(50) as u32 }).collect();
            let c = cuts_of(&hist, parts);
            assert_eq!(c[0], 0);
            assert_eq!(c[parts] as usize, n);
            for w in c.windows(2) {
                assert!(w[0] <= w[1], "{hist:?} -> {c:?}");
                if n >= parts {
                    assert!(w[1] > w[0], "a part without a cell: {hist:?} -> {c:?}");
                }
            }
            assert!(
                largest_part(&hist, c.windows(2).map(|w| (w[0], w[1]))) <= largest_part(&hist, uniform_parts(n, parts)),
                "worse than uniform: {hist:?} -> {c:?}"
            );
            // Balance: no part holds more than the ideal share plus the largest plane (a
            // plane cannot be split; the one-cell rule only moves cuts to one-plane parts).
            let total: u32 = hist.iter().sum();
            if total > 0 && n >= parts {
                let big = *hist.iter().max().unwrap() as f64;
                for w in c.windows(2) {
                    let part: u32 = hist[w[0] as usize..w[1] as usize].iter().sum();
                    assert!(part as f64 <= total as f64 / parts as f64 + big, "{hist:?} -> {c:?}");
                }
            }
        }
    }

    /// The nested cuts tile the grid: every cell's patch contains it, patches are numbered
    /// z fastest, and balanced cuts of clustered particles are far better than uniform.
    #[test]
    fn nested_cuts_tile_the_grid_and_balance_clusters() {
        let cells = [12, 9, 10];
        let mut rng = SplitMix(11);
        // A dense slab-shaped cluster (the impact's plate) plus a few scattered particles.
        let cell_of: Vec<[u32; 3]> = (0..5000)
            .map(|i| {
                if i % 10 == 0 {
                    [rng.below(12), rng.below(9), rng.below(10)].map(|v| v as u32)
                } else {
                    [rng.below(12) as u32, 2 + rng.below(4) as u32, 4 + rng.below(6) as u32]
                }
            })
            .collect();
        for layout in [[1, 1, 1], [2, 1, 1], [2, 2, 1], [2, 1, 3], [2, 2, 2], [1, 1, 3]] {
            let bal = Cuts::balanced(&cell_of, cells, layout);
            let mut uni = Cuts::default();
            uni.uniform(layout, cells);
            for cuts in [&bal, &uni] {
                let total: usize = (0..cuts.patches()).map(|j| cuts.patch(j).cells.iter().product::<usize>()).sum();
                assert_eq!(total, cells.iter().product::<usize>());
                for (i, j, k) in (0..12).flat_map(|i| (0..9).flat_map(move |j| (0..10).map(move |k| (i, j, k)))) {
                    let pj = cuts.patch_of_cell([i, j, k]);
                    let p = cuts.patch(pj);
                    assert_eq!(pj, p.index[2] + layout[2] * (p.index[1] + layout[1] * p.index[0]));
                    for (d, c) in [i, j, k].into_iter().enumerate() {
                        assert!(c >= p.cell_lo[d] && c < p.cell_lo[d] + p.cells[d], "{layout:?} cell {i},{j},{k}");
                    }
                }
            }
            let mut counts = vec![0; bal.patches()];
            bal.count(&cell_of, &mut counts);
            let b = imbalance(&counts).unwrap();
            uni.count(&cell_of, &mut counts);
            let u = imbalance(&counts).unwrap();
            assert!(b <= u + 1e-12, "{layout:?}: balanced {b} uniform {u}");
            assert!(b < 1.25, "{layout:?}: balanced imbalance {b}");
        }
    }

    #[test]
    fn layouts_are_every_factorisation_once() {
        for t in 1..=12 {
            let all: Vec<[usize; 3]> = layouts(t).collect();
            assert!(all.iter().all(|l| l.iter().product::<usize>() == t), "{t}: {all:?}");
            let mut unique = all.clone();
            unique.sort();
            unique.dedup();
            assert_eq!(unique.len(), all.len(), "{t}: {all:?}");
            let brute = (1..=t).flat_map(|a| (1..=t).flat_map(move |b| (1..=t).map(move |c| [a, b, c])));
            assert_eq!(brute.filter(|l| l.iter().product::<usize>() == t).count(), all.len(), "{t}");
        }
        assert_eq!(layouts(8).count(), 10);
        assert!(layouts(6).any(|l| l == [2, 1, 3]));
    }

    /// A plate three cells thick along z, spread evenly over 40 x 40 cells in x and y: the
    /// paper's 2x2x2 layout must cut three z planes into two parts (about 4/3), so the
    /// chooser leaves z uncut; an even cube keeps the paper's layout; the layout in use is
    /// kept while within the slack.
    #[test]
    fn the_chooser_avoids_cutting_a_thin_plate() {
        let (hx, hy, hz) = (vec![300u32; 40], vec![300u32; 40], vec![0, 0, 4000, 4000, 4000, 0]);
        let mut ch = LayoutChooser::default();
        let paper = [2, 2, 2];
        let p = ch.predict([&hx, &hy, &hz], paper);
        assert!((p - 4.0 / 3.0).abs() < 1e-12, "{p}");
        let chosen = ch.choose(8, paper, [&hx, &hy, &hz]);
        assert_eq!(chosen[2], 1, "{chosen:?}");
        assert!(ch.predict([&hx, &hy, &hz], chosen) <= 1.0 + 1e-12);
        assert_eq!(ch.current(), Some(chosen));
        // Evenly spread: every layout predicts 1, the paper's is kept.
        let even = vec![100u32; 16];
        let mut ch = LayoutChooser::default();
        assert_eq!(ch.choose(8, paper, [&even, &even, &even]), paper);
        assert_eq!(ch.choose(6, [2, 1, 3], [&even, &even, &even[..15]]), [2, 1, 3]);
        // Hysteresis: with the paper's layout out of reach, the layout in use stays while
        // its prediction is within the slack of the best, and goes when it is not.
        let mut ch = LayoutChooser::default();
        assert_eq!(ch.choose(8, paper, [&hx, &hy, &hz]), [1, 8, 1], "first of the ties");
        let heavy = |extra: u32| (0..40).map(|i| if i == 0 { 300 + extra } else { 300 }).collect::<Vec<u32>>();
        let hy1 = heavy(20); // 1x8x1 predicts 1520 / 1502.5 = 1.012, 8x1x1 predicts 1
        assert!((ch.predict([&hx, &hy1, &hz], [1, 8, 1]) - 1520.0 / 1502.5).abs() < 1e-12);
        assert_eq!(LayoutChooser::default().choose(8, paper, [&hx, &hy1, &hz]), [8, 1, 1]);
        assert_eq!(ch.choose(8, paper, [&hx, &hy1, &hz]), [1, 8, 1], "kept within the slack");
        // A chooser continued from a saved run's layout in use decides as the saved one.
        let mut resumed = LayoutChooser::resumed(Some([1, 8, 1]));
        assert_eq!(resumed.choose(8, paper, [&hx, &hy1, &hz]), [1, 8, 1], "the hysteresis survives a restart");
        let hy2 = heavy(200); // 1x8x1 predicts 1.117: beyond the slack
        assert_eq!(ch.choose(8, paper, [&hx, &hy2, &hz]), [8, 1, 1]);
        // No particles: the paper's layout.
        let mut ch = LayoutChooser::default();
        assert_eq!(ch.choose(8, paper, [&[0; 4], &[0; 4], &[0; 4]]), paper);
    }

    /// The prediction bounds the nested balanced cuts it stands for on product-shaped
    /// clusters (exact up to cell rounding there).
    #[test]
    fn predictions_match_nested_cuts_of_separable_clusters() {
        let cells = [16, 12, 6];
        let mut rng = SplitMix(5);
        let cell_of: Vec<[u32; 3]> =
            (0..20_000).map(|_| [rng.below(16) as u32, rng.below(12) as u32, 2 + rng.below(3) as u32]).collect();
        let marg: Vec<Vec<u32>> = (0..3)
            .map(|a| {
                let mut h = vec![0u32; cells[a]];
                cell_of.iter().for_each(|c| h[c[a] as usize] += 1);
                h
            })
            .collect();
        let mut ch = LayoutChooser::default();
        for layout in layouts(8) {
            let predicted = ch.predict([&marg[0], &marg[1], &marg[2]], layout);
            let cuts = Cuts::balanced(&cell_of, cells, layout);
            let mut counts = vec![0; 8];
            cuts.count(&cell_of, &mut counts);
            let actual = imbalance(&counts).unwrap();
            assert!(actual <= predicted * 1.05, "{layout:?}: actual {actual} predicted {predicted}");
        }
    }

    #[test]
    fn patch_load_accumulates_counts_and_imbalance() {
        let mut load = PatchLoad::default();
        load.record(&[10, 30]);
        load.record(&[20, 20]);
        load.record(&[0, 0]);
        assert_eq!((load.steps, load.min, load.max), (2, 10, 30));
        assert_eq!(load.mean(), 20.0);
        assert_eq!(load.imbalance_max, 1.5);
        assert_eq!(load.imbalance_mean(), 1.25);
        assert_eq!(imbalance(&[]), None);
    }
}
