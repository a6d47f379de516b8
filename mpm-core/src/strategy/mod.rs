//! How the nodal scatter is made race-free (paper Section 4). This is the only thing that
//! differs between the three solvers; every kernel (what a particle adds to its 8 nodes)
//! is shared.
//!
//! | strategy | scatter of a particle goes to | assembly into the global arrays | extra memory |
//! |---|---|---|---|
//! | [`Strategy::Serial`] | the global arrays | none | none |
//! | [`Strategy::ArrayExpansion`] | copy `j` of every nodal array (thread `j`'s particle chunk) | `A = sum_j A_j`, parallel over nodes (Eq. 16) | `(T - 1) x` the nodal arrays |
//! | [`Strategy::DomainDecomposition`] | sub-grid of the particle's patch (thread `j` = patch `j`) | patch by patch, parallel over the patch's local nodes | shared faces only |
//!
//! Both parallel strategies split the particle stage by loop splitting (thread `j` owns
//! particle chunk `j`) and reduce energies per thread in a fixed order. Every parallel phase
//! is one [`rayon::ThreadPool::broadcast`], so worker `j` always gets share `j`: results
//! depend on the thread count, never on work stealing, and a given strategy and thread count
//! reproduces bitwise.

pub mod array_expansion;
pub mod domain_decomposition;
pub mod serial;

use crate::grid::GridGeom;
use crate::team::Team;
use crate::timers::{Lap, StageTimes, Substage};
use rayon::ThreadPool;
use serde::{Deserialize, Serialize};

pub use domain_decomposition::{patch_layout, Binning, DomainDecomposition, Patch};

/// Which scatter strategy the solver uses: the one type for the solver, the `mpm` program,
/// the JSON summary, the campaign matrix, the CSV rows and the analysis.
///
/// Its serialised form is the short name (`serial`, `ae`, `dd`); parsing also accepts the
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
    pub const ALL: [Strategy; 3] = [Strategy::Serial, Strategy::ArrayExpansion, Strategy::DomainDecomposition];

    /// Short name: `serial`, `ae`, `dd` (CLI value, JSON and CSV field).
    pub fn name(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::ArrayExpansion => "ae",
            Strategy::DomainDecomposition => "dd",
        }
    }

    /// Name for people (figure legends, report headings).
    pub fn label(self) -> &'static str {
        match self {
            Strategy::Serial => "serial",
            Strategy::ArrayExpansion => "array expansion",
            Strategy::DomainDecomposition => "domain decomposition",
        }
    }

    /// Whether the strategy runs on more than one thread (serial means exactly one).
    pub fn is_parallel(self) -> bool {
        match self {
            Strategy::Serial => false,
            Strategy::ArrayExpansion | Strategy::DomainDecomposition => true,
        }
    }

    /// How its memory grows with the thread count.
    pub fn memory_model(self) -> MemoryModel {
        match self {
            Strategy::Serial => MemoryModel::None,
            Strategy::ArrayExpansion => MemoryModel::PerThreadCopies,
            Strategy::DomainDecomposition => MemoryModel::SharedFaces,
        }
    }

    /// Check a thread count for this strategy: serial runs on exactly one thread, the
    /// parallel strategies on at least one.
    pub fn check_threads(self, threads: usize) -> Result<(), String> {
        match (self.is_parallel(), threads) {
            (_, 0) => Err("the thread count must be at least 1".into()),
            (false, t) if t > 1 => Err(format!(
                "the serial strategy runs on exactly 1 thread, not {t}: use --strategy ae or dd for more threads"
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

/// A box of nodes with its own contiguous numbering: the global grid, an AE copy (the same
/// box) or a DD sub-grid.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct NodeBox {
    /// Global index of the box's first node (also its first cell).
    pub lo: [usize; 3],
    /// Nodes per axis.
    pub dims: [usize; 3],
}

impl NodeBox {
    /// The whole grid.
    pub fn grid(geom: &GridGeom) -> Self {
        Self { lo: [0; 3], dims: geom.node_dims() }
    }

    /// Add a particle's contribution (its cell must lie in the box).
    #[inline(always)]
    pub fn add<const K: usize>(&self, data: &mut [[f64; K]], con: &Contribution<K>) {
        let (sy, sz) = (self.dims[0], self.dims[0] * self.dims[1]);
        let base = (con.cell[0] - self.lo[0]) + sy * (con.cell[1] - self.lo[1]) + sz * (con.cell[2] - self.lo[2]);
        let idx =
            [base, base + 1, base + sy, base + sy + 1, base + sz, base + sz + 1, base + sz + sy, base + sz + sy + 1];
        for q in 0..8 {
            let d = &mut data[idx[q]];
            for k in 0..K {
                d[k] += con.c[q][k];
            }
        }
    }
}

/// Runs a phase on every worker: `f(j)` once for each `j` in `0..workers`.
pub struct Exec<'a> {
    kind: ExecKind<'a>,
    /// Number of workers (shares).
    pub workers: usize,
}

enum ExecKind<'a> {
    Serial,
    Pool(&'a ThreadPool),
    Team(&'a Team),
}

impl<'a> Exec<'a> {
    /// The executor of `strategy` in `pool`: one share on the calling thread for the serial
    /// strategy, one `broadcast` per phase otherwise (worker `j` runs share `j`).
    pub fn new(pool: &'a ThreadPool, strategy: Strategy) -> Self {
        match strategy {
            Strategy::Serial => Self::serial(),
            _ => Self { kind: ExecKind::Pool(pool), workers: pool.current_num_threads() },
        }
    }

    /// One share, run on the calling thread.
    pub fn serial() -> Self {
        Self { kind: ExecKind::Serial, workers: 1 }
    }

    /// Phases run by a [`Team`] whose workers stay awake between phases (call from the
    /// team's driver, worker 0).
    pub fn team(team: &'a Team) -> Self {
        Self { kind: ExecKind::Team(team), workers: team.workers() }
    }

    /// Run `f(j)` for every worker `j`, worker `j` on pool thread `j`.
    #[inline]
    pub fn run<F: Fn(usize) + Sync>(&self, f: F) {
        match self.kind {
            ExecKind::Serial => f(0),
            ExecKind::Pool(pool) => {
                pool.broadcast(|ctx| f(ctx.index()));
            }
            ExecKind::Team(team) => team.run(&f),
        }
    }
}

/// The strategy's per-simulation state.
#[derive(Debug)]
pub(crate) enum Engine {
    Serial,
    Ae(usize),
    Dd(Box<DomainDecomposition>),
}

impl Engine {
    pub fn new(strategy: Strategy, threads: usize) -> Self {
        match strategy {
            Strategy::Serial => Engine::Serial,
            Strategy::ArrayExpansion => Engine::Ae(threads),
            Strategy::DomainDecomposition => Engine::Dd(Box::new(DomainDecomposition::new(threads))),
        }
    }

    /// Cut DD patches for `geom` and return the scatter buffer length the strategy needs
    /// (nodes x threads for AE, all sub-grids for DD, 0 for serial).
    pub fn reserve(&mut self, geom: &GridGeom) -> usize {
        match self {
            Engine::Serial => 0,
            Engine::Ae(threads) => geom.num_nodes() * *threads,
            Engine::Dd(dd) => {
                dd.cut(geom);
                dd.subgrid_nodes()
            }
        }
    }

    /// Per-step preparation: DD re-cuts its patches when the grid changed and bins the
    /// particles (`patch_of_point` gives a position's patch).
    pub fn prepare(&mut self, exec: &Exec<'_>, geom: &GridGeom, x: &[crate::math::Vec3]) {
        if let Engine::Dd(dd) = self {
            dd.prepare(exec, geom, x);
        }
    }

    /// Scatter every particle's `kernel(p)` into `global` (zeroed first), using `buf` for
    /// the per-thread copies or sub-grids, and charge the scatter and assembly times.
    #[allow(clippy::too_many_arguments)]
    pub fn scatter<const K: usize, F>(
        &self,
        exec: &Exec<'_>,
        geom: &GridGeom,
        n: usize,
        global: &mut [[f64; K]],
        buf: &mut Vec<[f64; K]>,
        kernel: &F,
        times: &mut StageTimes,
        lap: &mut Lap,
        stages: (Substage, Substage),
    ) where
        F: Fn(usize) -> Contribution<K> + Sync,
    {
        match self {
            Engine::Serial => {
                serial::scatter(geom, n, global, kernel);
                lap.lap(times, stages.0);
                lap.lap(times, stages.1);
            }
            Engine::Ae(_) => {
                array_expansion::scatter(exec, geom, n, buf, kernel);
                lap.lap(times, stages.0);
                array_expansion::assemble(exec, global, buf);
                lap.lap(times, stages.1);
            }
            Engine::Dd(dd) => {
                dd.scatter(exec, buf, kernel);
                lap.lap(times, stages.0);
                dd.assemble(exec, geom, global, buf);
                lap.lap(times, stages.1);
            }
        }
    }

    /// Bytes held by the strategy's own index structures (not the scatter buffers).
    pub fn bytes(&self) -> usize {
        match self {
            Engine::Dd(dd) => dd.bytes(),
            _ => 0,
        }
    }
}
