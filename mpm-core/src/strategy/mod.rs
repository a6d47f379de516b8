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
pub mod serial;

use crate::blocks::BlockMap;
use crate::grid::{CellNodes, GridGeom, NodeIndex};
use crate::math::Vec3;
use crate::parallel::Exec;
use serde::{Deserialize, Serialize};

pub use array_expansion::ArrayExpansion;
pub use cuts::{imbalance, layouts, quantile_cuts, Cuts, LayoutChooser, PatchLoad, LAYOUT_SLACK};
pub use domain_decomposition::{patch_layout, Binning, DomainDecomposition, Patch};
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

/// The per-particle kernel of a scatter: what particle `p` adds to its 8 nodes.
///
/// The solver's kernels are [`crate::transfer::P2g`] and [`crate::transfer::Remap`], whose
/// [`Kernel::contribution`] is `#[inline(always)]`, so every strategy's scatter loop
/// compiles with the kernel inlined. (Given as a closure, the kernel stayed out of line in
/// the DD scatter loop, and each particle's 8 x `K` values went through memory: the DD
/// scatter of Model 2 ran 20 % slower.) Closures are kernels too, for tests and benchmarks.
pub trait Kernel<const K: usize>: Sync {
    /// Particle `p`'s contribution.
    fn contribution(&self, p: usize) -> Contribution<K>;
}

impl<const K: usize, F: Fn(usize) -> Contribution<K> + Sync> Kernel<K> for F {
    #[inline(always)]
    fn contribution(&self, p: usize) -> Contribution<K> {
        self(p)
    }
}

/// Add a particle's contribution at the nodes `nodes` gives its cell (every node of the
/// cell must be stored there).
#[inline(always)]
pub(crate) fn add<const K: usize>(nodes: &mut CellNodes<'_>, data: &mut [[f64; K]], con: &Contribution<K>) {
    let idx = nodes.get(con.cell);
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

    /// Add `kernel.contribution(p)` of every particle `p < n`, either into `global` (zeroed
    /// first; its nodes numbered by `index`) or into `parts` for
    /// [`ScatterStrategy::assemble`] to sum into `global`.
    #[allow(clippy::too_many_arguments)]
    fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        index: &NodeIndex<'_>,
        n: usize,
        global: &mut [[f64; K]],
        parts: &mut Vec<[f64; K]>,
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
        parts: &[[f64; K]],
    );

    /// Bytes held by the strategy's own tables (not `parts`).
    fn bytes(&self) -> usize;
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
        parts: &mut Vec<[f64; K]>,
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
        parts: &[[f64; K]],
    ) {
        dispatch!(self, s => s.assemble(exec, geom, index, global, parts))
    }

    /// See [`ScatterStrategy::bytes`].
    pub fn bytes(&self) -> usize {
        dispatch!(self, s => s.bytes())
    }

    /// The domain-decomposition state, if this is DD (uniform or balanced cuts).
    pub fn domain_decomposition(&self) -> Option<&DomainDecomposition> {
        match self {
            Engine::Dd(dd) => Some(dd),
            Engine::Serial(_) | Engine::Ae(_) => None,
        }
    }
}
