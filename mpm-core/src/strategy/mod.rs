//! How the nodal scatter is made race-free (paper Section 4, and two ways used since). This
//! is the only thing that differs between the solvers; every kernel (what a particle adds to
//! its 8 nodes, [`Kernel`]) is shared.
//!
//! | strategy | a particle's scatter goes to | assembly into the global arrays | extra memory | determinism |
//! |---|---|---|---|---|
//! | [`Strategy::Serial`] | the global arrays | none | none | bitwise, run after run |
//! | [`Strategy::ArrayExpansion`] | copy `j` of every scattered nodal array (thread `j`'s particle chunk) | `A = sum_j A_j`, parallel over nodes (Eq. 16) | `T` copies of the scattered records (108 B a node a thread) | bitwise for a thread count |
//! | [`Strategy::DomainDecomposition`] | sub-grid of the particle's patch (thread `j` = patch `j`) | patch by patch, parallel over the patch's local nodes | binning (8 B a particle), the sub-grids (shared faces twice) | bitwise for a thread count |
//! | [`Strategy::DdBalanced`] | as DD, patches cut at particle-count quantiles ([`cuts`]) | as DD | as DD, and each particle's cell (12 B) | bitwise for a thread count |
//! | [`Strategy::Colour`] | the global arrays, in the phase of its block's colour, from the worker holding the block ([`colour`]) | none | the block lists (4 B a particle, a count per block and thread) | bitwise for a thread count |
//! | [`Strategy::Atomic`] | the global arrays, by atomic additions, from the worker holding its chunk ([`atomic`]) | none | none | to round-off only: each node's sum in the order the additions land |
//!
//! Every parallel strategy splits the particle stage by loop splitting (thread `j` owns
//! particle chunk `j`) and reduces energies per thread in a fixed order. Every parallel phase
//! gives worker `j` share `j` ([`crate::parallel`]): results depend on the thread count,
//! never on timing, and a given strategy and thread count reproduces bitwise; the one
//! exception is the atomic strategy's scatter, whose sums take the order in which the
//! workers' additions reach each node ([`Strategy::is_deterministic`]).
//!
//! A strategy is a type implementing [`ScatterStrategy`] in its own file, plus one arm in
//! each exhaustive match over [`Strategy`] (below) and over the solver's `Engine` (its
//! variants and the `dispatch!` macro, also below). Nothing else in the crate names a
//! strategy.

pub mod array_expansion;
pub mod atomic;
pub mod colour;
pub mod cuts;
pub mod domain_decomposition;
mod kernel;
pub mod patch;
pub mod serial;

use crate::blocks::BlockMap;
use crate::grid::{GridGeom, Records};
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::parallel::Exec;
use serde::{Deserialize, Serialize};

pub use array_expansion::ArrayExpansion;
pub use atomic::Atomic;
pub use colour::BlockPlan;
pub use cuts::{imbalance, layouts, quantile_cuts, Cuts, LayoutChooser, PatchLoad, LAYOUT_SLACK};
pub use domain_decomposition::{patch_layout, Binning, DomainDecomposition};
pub use kernel::{Contribution, Cursors, Kernel, Target};
pub use patch::Patch;
pub use serial::Serial;

/// Which scatter strategy the solver uses: the one type for the solver, the `mpm` program,
/// the JSON summary, the campaign matrix, the CSV rows and the analysis.
///
/// Its serialised form is the short name (`serial`, `ae`, `dd`, `dd-balanced`, `colour`,
/// `atomic`); parsing also accepts the long names (`array-expansion`,
/// `domain-decomposition`). Adding a strategy means one arm here and its own file under
/// `strategy/`.
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
    /// Block colouring: blocks of cells in 8 colours, the blocks of one colour scattered at
    /// once straight into the global arrays ([`colour`]).
    #[serde(rename = "colour")]
    Colour,
    /// Atomic additions: every worker scatters its particle chunk straight into the global
    /// arrays with atomic adds ([`atomic`]).
    #[serde(rename = "atomic")]
    Atomic,
}

/// How a strategy's memory grows with the thread count `T` (paper claim C2).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
pub enum MemoryModel {
    /// No memory beyond the global nodal arrays (the colour strategy's block lists aside,
    /// one index a particle): the serial solver's at every thread count.
    None,
    /// A copy of the scattered nodal arrays per thread: grows linearly with `T`.
    PerThreadCopies,
    /// Sub-grids whose shared faces are duplicated: nearly constant in `T`.
    SharedFaces,
}

impl Strategy {
    /// Every strategy, in a fixed order (serial first, then the paper's two, then the two
    /// used since).
    pub const ALL: [Strategy; 6] = [
        Strategy::Serial,
        Strategy::ArrayExpansion,
        Strategy::DomainDecomposition,
        Strategy::DdBalanced,
        Strategy::Colour,
        Strategy::Atomic,
    ];

    /// Short name: `serial`, `ae`, `dd`, `dd-balanced`, `colour`, `atomic` (CLI value, JSON
    /// and CSV field).
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::ArrayExpansion => "ae",
            Strategy::DomainDecomposition => "dd",
            Strategy::DdBalanced => "dd-balanced",
            Strategy::Colour => "colour",
            Strategy::Atomic => "atomic",
        }
    }

    /// Name for people (figure legends, report headings).
    pub fn label(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::ArrayExpansion => "array expansion",
            Strategy::DomainDecomposition => "domain decomposition",
            Strategy::DdBalanced => "domain decomposition, balanced cuts",
            Strategy::Colour => "block colouring",
            Strategy::Atomic => "atomic adds",
        }
    }

    /// Whether the strategy runs on more than one thread (serial means exactly one).
    pub fn is_parallel(self) -> bool {
        match self {
            Strategy::Serial => false,
            Strategy::ArrayExpansion
            | Strategy::DomainDecomposition
            | Strategy::DdBalanced
            | Strategy::Colour
            | Strategy::Atomic => true,
        }
    }

    /// Whether a run reproduces bit for bit for a given thread count (every strategy but
    /// atomic adds, whose sums take the order in which the additions land).
    pub fn is_deterministic(self) -> bool {
        match self {
            Strategy::Atomic => false,
            Strategy::Serial
            | Strategy::ArrayExpansion
            | Strategy::DomainDecomposition
            | Strategy::DdBalanced
            | Strategy::Colour => true,
        }
    }

    /// How its memory grows with the thread count.
    pub fn memory_model(self) -> MemoryModel {
        match self {
            Strategy::Serial | Strategy::Colour | Strategy::Atomic => MemoryModel::None,
            Strategy::ArrayExpansion => MemoryModel::PerThreadCopies,
            Strategy::DomainDecomposition | Strategy::DdBalanced => MemoryModel::SharedFaces,
        }
    }

    /// The short names of the parallel strategies, as a sentence lists them (`ae, dd, ... or
    /// atomic`).
    pub fn parallel_names() -> String {
        let names: Vec<&str> = Strategy::ALL.iter().filter(|s| s.is_parallel()).map(|s| s.name()).collect();
        match names.split_last() {
            Some((last, rest)) if !rest.is_empty() => format!("{} or {last}", rest.join(", ")),
            _ => names.join(""),
        }
    }

    /// Check a thread count for this strategy: serial runs on exactly one thread, the
    /// parallel strategies on at least one.
    pub fn check_threads(self, threads: usize) -> Result<(), String> {
        match (self.is_parallel(), threads) {
            (_, 0) => Err("the thread count must be at least 1".into()),
            (false, t) if t > 1 => Err(format!(
                "the serial strategy runs on exactly 1 thread, not {t}: use --strategy {} for more threads",
                Strategy::parallel_names()
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
            "ae" | "array-expansion" => Ok(Strategy::ArrayExpansion),
            "dd" | "domain-decomposition" => Ok(Strategy::DomainDecomposition),
            _ => Strategy::ALL.into_iter().find(|x| x.name() == s).ok_or_else(|| {
                let names: Vec<&str> = Strategy::ALL.iter().map(|s| s.name()).collect();
                format!("unknown strategy '{s}': use one of {}", names.join(", "))
            }),
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
    /// (0, the default, if it scatters straight into the global arrays).
    fn reserve(&mut self, _geom: &GridGeom, _blocks: Option<&BlockMap>) -> usize {
        0
    }

    /// Per-step work before the first scatter, given the particle positions `x` and, on a
    /// sparse grid, the blocks stored this step (none by default).
    fn prepare(&mut self, _exec: &Exec<'_>, _geom: &GridGeom, _blocks: Option<&BlockMap>, _x: &[Vec3]) {}

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
    /// to do, the default, if it scattered into `global`).
    fn assemble<const K: usize>(
        &self,
        _exec: &Exec<'_>,
        _geom: &GridGeom,
        _index: &NodeIndex<'_>,
        _global: &mut [[f64; K]],
        _parts: &mut [[f64; K]],
    ) {
    }

    /// Bytes held by the strategy's own tables (not `parts`; none by default).
    fn bytes(&self) -> usize {
        0
    }
}

/// What a strategy carries from one step to the next beyond the grid and the particles
/// (part of a saved [`crate::solver::SimState`]): serial, AE, colour and atomic carry
/// nothing (colour re-bins its blocks every step); DD carries the load recorded so far and,
/// with balanced cuts, the layout the chooser holds (its hysteresis decides the next step's
/// layout).
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
    Colour(Box<colour::Colour>),
    Atomic(Atomic),
}

/// Run `$body` with `$s` bound to the engine's strategy (one arm per strategy).
macro_rules! dispatch {
    ($engine:expr, $s:ident => $body:expr) => {
        match $engine {
            Engine::Serial($s) => $body,
            Engine::Ae($s) => $body,
            Engine::Dd($s) => $body,
            Engine::Colour($s) => $body,
            Engine::Atomic($s) => $body,
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
            Strategy::Colour => Engine::Colour(Box::new(colour::Colour::new(threads))),
            Strategy::Atomic => Engine::Atomic(Atomic),
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
            Engine::Serial(_) | Engine::Ae(_) | Engine::Colour(_) | Engine::Atomic(_) => EngineState::default(),
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
            Engine::Serial(_) | Engine::Ae(_) | Engine::Colour(_) | Engine::Atomic(_) => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::grid::GridSpec;
    use crate::parallel::Team;
    use std::sync::atomic::{AtomicU32, Ordering};

    /// Every strategy parses back from its short name; the long names of the paper's two
    /// parse too; the refusal of the serial strategy's second thread names every parallel
    /// strategy.
    #[test]
    fn names_parse_back() {
        for s in Strategy::ALL {
            assert_eq!(s.name().parse::<Strategy>(), Ok(s));
            assert_eq!(s.to_string(), s.name());
        }
        assert_eq!("array-expansion".parse::<Strategy>(), Ok(Strategy::ArrayExpansion));
        assert_eq!("domain-decomposition".parse::<Strategy>(), Ok(Strategy::DomainDecomposition));
        assert!("color"
            .parse::<Strategy>()
            .unwrap_err()
            .contains("use one of serial, ae, dd, dd-balanced, colour, atomic"));
        let refused = Strategy::Serial.check_threads(2).unwrap_err();
        assert!(
            refused.ends_with("use --strategy ae, dd, dd-balanced, colour or atomic for more threads"),
            "{refused}"
        );
        assert!(Strategy::ALL.iter().filter(|s| !s.is_deterministic()).eq(&[Strategy::Atomic]));
    }

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
