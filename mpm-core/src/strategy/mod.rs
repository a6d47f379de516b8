//! How the nodal scatter is made race-free (paper Section 4). This is the only thing that
//! differs between the three solvers; every kernel (what a particle adds to its 8 nodes)
//! is shared.
//!
//! | strategy | scatter of a particle goes to | assembly into the global arrays | extra memory |
//! |---|---|---|---|
//! | [`Strategy::Serial`] | the global arrays | none | none |
//! | [`Strategy::ArrayExpansion`] | copy `j` of every nodal array (thread `j`'s particle chunk) | `A = sum_j A_j`, parallel over nodes (Eq. 16) | `(T - 1) x` the nodal arrays |
//! | [`Strategy::DomainDecomposition`] | sub-grid of the particle's patch (thread `j` = patch `j`) | patch by patch, parallel over the patch's local nodes | shared faces only |
//! | [`Strategy::DdBalanced`] | as DD, patches cut at particle-count quantiles ([`cuts`]) | as DD | as DD |
//!
//! Both parallel strategies split the particle stage by loop splitting (thread `j` owns
//! particle chunk `j`) and reduce energies per thread in a fixed order. Every parallel phase
//! gives worker `j` share `j` ([`crate::parallel`]): results depend on the thread count,
//! never on timing, and a given strategy and thread count reproduces bitwise.
//!
//! A strategy is a type implementing [`ScatterStrategy`] in its own file, plus one arm in
//! each exhaustive match over [`Strategy`] (below) and over the solver's `Engine` (its
//! variants and the `dispatch!` macro, also below). Nothing else in the crate names a
//! strategy.

pub mod array_expansion;
pub mod cuts;
pub mod domain_decomposition;
pub mod patch;
pub mod serial;

use crate::blocks::BlockMap;
use crate::grid::{GridGeom, Records};
use crate::math::Vec3;
use crate::node_index::{CellNodes, NodeIndex};
use crate::parallel::Exec;
use serde::{Deserialize, Serialize};

pub use array_expansion::ArrayExpansion;
pub use cuts::{imbalance, layouts, quantile_cuts, Cuts, LayoutChooser, PatchLoad, LAYOUT_SLACK};
pub use domain_decomposition::{patch_layout, Binning, DomainDecomposition};
pub use patch::Patch;
pub use serial::Serial;

/// Which scatter strategy the solver uses: the one type for the solver, the `mpm` program,
/// the JSON summary, the campaign matrix, the CSV rows and the analysis.
///
/// Its serialised form is the short name (`serial`, `ae`, `dd`, `dd-balanced`); parsing also accepts the
/// long names (`array-expansion`, `domain-decomposition`). Adding a strategy means one arm
/// here and its own file under `strategy/`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize, Default)]
pub enum Strategy {
    /// One thread, scatter straight into the global arrays (the oracle).
    #[default]
    #[serde(rename = "serial")]
    Serial,
    /// Array expansion: one copy of every nodal array per thread.
    #[serde(rename = "ae", alias = "array-expansion")]
    ArrayExpansion,
    /// Domain decomposition: one patch (sub-grid) per thread.
    #[serde(rename = "dd", alias = "domain-decomposition")]
    DomainDecomposition,
    /// Domain decomposition with balanced cuts: the same layouts, cut planes at the
    /// particle-count quantiles every step ([`cuts`]).
    #[serde(rename = "dd-balanced")]
    DdBalanced,
}

/// How a strategy's memory grows with the thread count `T` (paper claim C2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum MemoryModel {
    /// No memory beyond the global nodal arrays.
    None,
    /// A copy of the scattered nodal arrays per thread: grows linearly with `T`.
    PerThreadCopies,
    /// Sub-grids whose shared faces are duplicated: nearly constant in `T`.
    SharedFaces,
}

impl Strategy {
    /// Every strategy, in a fixed order (serial first).
    pub const ALL: [Strategy; 4] =
        [Strategy::Serial, Strategy::ArrayExpansion, Strategy::DomainDecomposition, Strategy::DdBalanced];

    /// Short name: `serial`, `ae`, `dd`, `dd-balanced` (CLI value, JSON and CSV field).
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::ArrayExpansion => "ae",
            Strategy::DomainDecomposition => "dd",
            Strategy::DdBalanced => "dd-balanced",
        }
    }

    /// Name for people (figure legends, report headings).
    pub fn label(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::ArrayExpansion => "array expansion",
            Strategy::DomainDecomposition => "domain decomposition",
            Strategy::DdBalanced => "domain decomposition, balanced cuts",
        }
    }

    /// Whether the strategy runs on more than one thread (serial means exactly one).
    pub fn is_parallel(self) -> bool {
        match self {
            Strategy::Serial => false,
            Strategy::ArrayExpansion | Strategy::DomainDecomposition | Strategy::DdBalanced => true,
        }
    }

    /// How its memory grows with the thread count.
    pub fn memory_model(self) -> MemoryModel {
        match self {
            Strategy::Serial => MemoryModel::None,
            Strategy::ArrayExpansion => MemoryModel::PerThreadCopies,
            Strategy::DomainDecomposition | Strategy::DdBalanced => MemoryModel::SharedFaces,
        }
    }

    /// Check a thread count for this strategy: serial runs on exactly one thread, the
    /// parallel strategies on at least one.
    pub fn check_threads(self, threads: usize) -> Result<(), String> {
        match (self.is_parallel(), threads) {
            (_, 0) => Err("the thread count must be at least 1".into()),
            (false, t) if t > 1 => Err(format!(
                "the serial strategy runs on exactly 1 thread, not {t}: use --strategy ae, dd or dd-balanced for more threads"
            )),
            _ => Ok(()),
        }
    }
}

impl std::fmt::Display for Strategy {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl std::str::FromStr for Strategy {
    type Err = String;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "serial" => Ok(Strategy::Serial),
            "ae" | "array-expansion" => Ok(Strategy::ArrayExpansion),
            "dd" | "domain-decomposition" => Ok(Strategy::DomainDecomposition),
            "dd-balanced" => Ok(Strategy::DdBalanced),
            _ => {
                let names: Vec<&str> = Strategy::ALL.iter().map(|s| s.name()).collect();
                Err(format!("unknown strategy '{s}': use one of {}", names.join(", ")))
            }
        }
    }
}

/// What one particle adds to the 8 nodes of its cell (node order of [`crate::shape`]).
#[derive(Clone, Copy, Debug)]
pub struct Contribution<const K: usize> {
    /// The cell, in the global grid's numbering.
    pub cell: [usize; 3],
    /// Per node, `K` values.
    pub c: [[f64; K]; 8],
}

/// The node numberings a scatter loop walks: the scatter target's (the global arrays, an AE
/// copy of them, or a DD sub-grid) and, where it differs, the global grid's, which a kernel
/// reads nodal values from (the fused gather and re-map reads the nodal accelerations).
/// Each remembers the last cell's nodes ([`CellNodes`]).
#[derive(Clone, Copy, Debug)]
pub struct Cursors<'a> {
    target: CellNodes<'a>,
    global: Option<CellNodes<'a>>,
}

impl<'a> Cursors<'a> {
    /// A loop whose target is numbered like the global grid (`index`): serial and AE.
    pub fn global(index: NodeIndex<'a>) -> Self {
        Self { target: CellNodes::new(index), global: None }
    }

    /// A loop whose target is numbered by `target` (a DD sub-grid) inside the grid `global`.
    pub fn split(target: NodeIndex<'a>, global: NodeIndex<'a>) -> Self {
        Self { target: CellNodes::new(target), global: Some(CellNodes::new(global)) }
    }

    /// The target's indices of the 8 nodes of `cell`.
    #[inline(always)]
    pub fn target(&mut self, cell: [usize; 3]) -> [usize; 8] {
        self.target.get(cell)
    }

    /// The target's and the global grid's indices of the 8 nodes of `cell`.
    #[inline(always)]
    pub fn both(&mut self, cell: [usize; 3]) -> ([usize; 8], [usize; 8]) {
        let t = self.target.get(cell);
        match &mut self.global {
            Some(g) => (t, g.get(cell)),
            None => (t, t),
        }
    }
}

/// The per-particle kernel of a scatter: what particle `p` adds to the 8 nodes of its cell.
///
/// The solver's kernels ([`crate::transfer::P2g`], and the fused gather and re-map) add
/// their values straight into the target's node records, `#[inline(always)]`, so that a
/// particle's 8 x `K` values stay in registers (returned as a [`Contribution`], the 448
/// bytes of a P2G particle went through the stack). Closures returning a [`Contribution`]
/// are kernels too, for tests and benchmarks.
pub trait Kernel<const K: usize>: Sync {
    /// Add particle `p`'s values into `data`, whose nodes `nodes.target` numbers.
    fn scatter(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut [[f64; K]]);

    /// [`Kernel::scatter`] for every particle of `ids`, in order: a strategy's loop over its
    /// particles. A kernel may run the loop at a wider SIMD level ([`crate::transfer::P2g`]).
    #[inline(always)]
    fn scatter_all(&self, ids: impl Iterator<Item = usize>, nodes: &mut Cursors<'_>, data: &mut [[f64; K]]) {
        for p in ids {
            self.scatter(p, nodes, data);
        }
    }
}

impl<const K: usize, F: Fn(usize) -> Contribution<K> + Sync> Kernel<K> for F {
    #[inline(always)]
    fn scatter(&self, p: usize, nodes: &mut Cursors<'_>, data: &mut [[f64; K]]) {
        add(nodes, data, &self(p));
    }
}

/// Add a particle's contribution at the nodes `nodes` gives its cell (every node of the
/// cell must be stored there).
#[inline(always)]
pub(crate) fn add<const K: usize>(nodes: &mut Cursors<'_>, data: &mut [[f64; K]], con: &Contribution<K>) {
    let idx = nodes.target(con.cell);
    for q in 0..8 {
        let d = &mut data[idx[q]];
        for k in 0..K {
            d[k] += con.c[q][k];
        }
    }
}

/// What a scatter strategy does. The solver calls, every step: [`prepare`] once, then for
/// each of the two scatters (P2G, re-map) [`scatter`] and [`assemble`], timing them as the
/// `scatter` and `assembly` sub-stages.
///
/// `parts` is the strategy's own scatter target (per-thread copies, sub-grids), kept by the
/// solver between steps so that steady-state steps do not allocate.
///
/// [`prepare`]: ScatterStrategy::prepare
/// [`scatter`]: ScatterStrategy::scatter
/// [`assemble`]: ScatterStrategy::assemble
pub trait ScatterStrategy {
    /// Get ready for `geom`, whose nodes are stored in `blocks` if it is sparse (re-cut
    /// whatever depends on the grid), and return the length of `parts` the scatter will need
    /// (0 if it scatters straight into the global arrays).
    fn reserve(&mut self, geom: &GridGeom, blocks: Option<&BlockMap>) -> usize;

    /// Per-step work before the first scatter, given the particle positions `x` and, on a
    /// sparse grid, the blocks stored this step.
    fn prepare(&mut self, exec: &Exec<'_>, geom: &GridGeom, blocks: Option<&BlockMap>, x: &[Vec3]);

    /// Call `kernel.scatter` once for every particle `p < n`, each from one worker, either
    /// into `global` (zeroed first; its nodes numbered by `index`) or into `parts` for
    /// [`ScatterStrategy::assemble`] to sum into `global`. (The crate's fused gather and
    /// re-map kernel writes particle `p`'s velocity from the worker that scatters `p`, and
    /// relies on this: every particle once, by one worker.)
    #[allow(clippy::too_many_arguments)]
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>;

    /// Make `global` the sum of what [`ScatterStrategy::scatter`] put into `parts` (nothing
    /// to do if it scattered into `global`).
    fn assemble<const K: usize>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        global: &mut [[f64; K]],
        parts: &mut [[f64; K]],
    );

    /// Bytes held by the strategy's own tables (not `parts`).
    fn bytes(&self) -> usize;
}

/// What a strategy carries from one step to the next beyond the grid and the particles
/// (part of a saved [`crate::solver::SimState`]): serial and AE carry nothing; DD carries
/// the load recorded so far and, with balanced cuts, the layout the chooser holds (its
/// hysteresis decides the next step's layout).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct EngineState {
    /// DD with balanced cuts: the layout in use (`None` before the first step, and for the
    /// other strategies).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dd_layout_in_use: Option<[usize; 3]>,
    /// DD: particles per patch recorded over the steps taken.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dd_load: Option<PatchLoad>,
}

/// The strategy of a simulation, with its per-simulation state.
#[derive(Debug)]
pub(crate) enum Engine {
    Serial(Serial),
    Ae(ArrayExpansion),
    Dd(Box<DomainDecomposition>),
}

/// Run `$body` with `$s` bound to the engine's strategy (one arm per strategy).
macro_rules! dispatch {
    ($engine:expr, $s:ident => $body:expr) => {
        match $engine {
            Engine::Serial($s) => $body,
            Engine::Ae($s) => $body,
            Engine::Dd($s) => $body,
        }
    };
}

impl Engine {
    pub fn new(strategy: Strategy, threads: usize) -> Self {
        match strategy {
            Strategy::Serial => Engine::Serial(Serial),
            Strategy::ArrayExpansion => Engine::Ae(ArrayExpansion::new(threads)),
            Strategy::DomainDecomposition => Engine::Dd(Box::new(DomainDecomposition::new(threads))),
            Strategy::DdBalanced => Engine::Dd(Box::new(DomainDecomposition::balanced(threads))),
        }
    }

    /// See [`ScatterStrategy::reserve`].
    pub fn reserve(&mut self, geom: &GridGeom, blocks: Option<&BlockMap>) -> usize {
        dispatch!(self, s => s.reserve(geom, blocks))
    }

    /// See [`ScatterStrategy::prepare`].
    pub fn prepare(&mut self, exec: &Exec<'_>, geom: &GridGeom, blocks: Option<&BlockMap>, x: &[Vec3]) {
        dispatch!(self, s => s.prepare(exec, geom, blocks, x))
    }

    /// See [`ScatterStrategy::scatter`].
    #[inline]
    #[allow(clippy::too_many_arguments)]
    pub fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        parts: &mut Records<K>,
        kernel: &F,
    ) where
        F: Kernel<K>,
    {
        dispatch!(self, s => s.scatter(exec, geom, index, n, global, parts, kernel))
    }

    /// See [`ScatterStrategy::assemble`].
    #[inline]
    pub fn assemble<const K: usize>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        global: &mut [[f64; K]],
        parts: &mut [[f64; K]],
    ) {
        dispatch!(self, s => s.assemble(exec, geom, index, global, parts))
    }

    /// See [`ScatterStrategy::bytes`].
    pub fn bytes(&self) -> usize {
        dispatch!(self, s => s.bytes())
    }

    /// What later steps of this engine depend on ([`EngineState`]).
    pub fn state(&self) -> EngineState {
        match self {
            Engine::Dd(dd) => {
                let (layout_in_use, load) = dd.carried();
                EngineState { dd_layout_in_use: layout_in_use, dd_load: Some(load) }
            }
            Engine::Serial(_) | Engine::Ae(_) => EngineState::default(),
        }
    }

    /// Continue from `state`, saved by an engine of the same strategy and thread count.
    pub fn restore(&mut self, state: &EngineState) {
        if let (Engine::Dd(dd), Some(load)) = (self, state.dd_load) {
            dd.carry_on(state.dd_layout_in_use, load);
        }
    }

    /// The domain-decomposition state, if this is DD (uniform or balanced cuts).
    pub fn domain_decomposition(&self) -> Option<&DomainDecomposition> {
        match self {
            Engine::Dd(dd) => Some(dd),
            Engine::Serial(_) | Engine::Ae(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::parallel::Team;
    use std::sync::atomic::{AtomicU32, Ordering};

    /// What the fused gather and re-map relies on for its writes to particle velocities:
    /// every strategy's scatter calls the kernel exactly once per particle, for every thread
    /// count, on dense and sparse grids (a particle visited twice, by two workers or one,
    /// or never, fails this).
    #[test]
    fn every_strategy_scatters_every_particle_once() {
        let geom = GridGeom::fixed(&GridSpec { dx: 1.0, anchor: [0.0; 3], cells: [13, 9, 11] });
        let mut unit = crate::testing::unit_stream(99);
        let x: Vec<Vec3> = (0..5000).map(|_| [13.0 * unit(), 9.0 * unit(), 4.0 + 7.0 * unit()]).collect();
        let mut map = BlockMap::default();
        map.build(&Exec::serial(), &geom, &x);
        for blocks in [None, Some(&map)] {
            let index = NodeIndex::of(&geom, blocks);
            for strategy in Strategy::ALL {
                for threads in if strategy.is_parallel() { vec![1, 2, 3, 4, 6, 8] } else { vec![1] } {
                    let visits: Vec<AtomicU32> = (0..x.len()).map(|_| AtomicU32::new(0)).collect();
                    let kernel = |p: usize| {
                        visits[p].fetch_add(1, Ordering::Relaxed);
                        Contribution::<1> { cell: geom.shape_cell(x[p]), c: [[1.0]; 8] }
                    };
                    let mut engine = Engine::new(strategy, threads);
                    let len = engine.reserve(&geom, blocks);
                    let (mut global, mut parts) =
                        (vec![[0.0; 1]; index.num_nodes()], crate::grid::Records::<1>::zeroed(len));
                    let mut run = |exec: &Exec<'_>| {
                        engine.prepare(exec, &geom, blocks, &x);
                        engine.scatter(exec, &geom, &index, x.len(), &mut global, &mut parts, &kernel);
                        engine.assemble(exec, &geom, &index, &mut global, &mut parts);
                    };
                    if strategy.is_parallel() {
                        Team::new(crate::testing::pool(threads)).region(run).unwrap();
                    } else {
                        run(&Exec::serial());
                    }
                    let what = format!("{strategy} x{threads}, sparse {}", blocks.is_some());
                    assert!(visits.iter().all(|v| v.load(Ordering::Relaxed) == 1), "{what}");
                    // And the sums carry 8 per particle, once each.
                    assert_eq!(global.iter().map(|g| g[0]).sum::<f64>(), 8.0 * x.len() as f64, "{what}");
                }
            }
        }
    }
}
