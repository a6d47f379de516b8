//! The explicit MUSL time step (paper Section 1, Eqs. 1-15).
//!
//! ```text
//! step k -> k+1, dt = CFL dx / max_p(c_p + |v_p|)
//!   grid-node stage
//!     every sort_every steps: particles into cell order (crate::order)
//!     fit grid (adaptive) ; DD: bin particles into patches
//!     scatter  m_i, p_i = sum m_p v_p S_ip, f_i = -sum V_p sigma_p . G_ip (+ m_p S_ip b)   Eqs. 1-5
//!     nodes    p_i += f_i dt, walls zero p_i and f_i; v_i = p_i/m_i, a_i = f_i/m_i          Eq. 6
//!   particle stage
//!     gather   v_p += dt sum S_ip a_i                                                      Eqs. 8, 10
//!     re-map   p_i = sum m_p v_p S_ip, v_i = p_i/m_i, walls again                           Eq. 11
//!     update   x_p += dt sum S_ip v_i(k+1); d_eps, d_omega from re-mapped v_i;               Eqs. 7, 9, 12-15
//!              rho_p, Jaumann rotation, J2 + EOS (+ failure); energies, next dt, bounding box
//! ```
//!
//! [`Simulation::step`] runs these stages in this order, one function each (`step.rs`), and
//! charges each its time and work as the sub-stages of [`crate::timers`]; then it checks the
//! step (non-finite values, particles off the fixed grid, the energy balance) and takes it.
//! A simulation is built (`setup.rs`) with the pool it runs on: the pool's thread count is its
//! worker count.
//!
//! Shape functions are evaluated at the positions of step `k` throughout the step (positions
//! move only in the last pass). Both scatters go through the [`crate::strategy`]; every other
//! pass is split across workers by loop splitting. A parallel step is one parallel region of
//! the simulation's [`Team`] on its pool ([`crate::parallel`]); the sort into cell order runs
//! before it, on the pool's threads through rayon. The step allocates nothing once the grid
//! has reached its largest size and the first sort has sized its buffers, except rayon's job
//! list for the region's one `broadcast` (`T` entries; the count of such allocations does not
//! depend on the problem size).

mod setup;
mod step;

use crate::blocks::BlockMap;
use crate::energy::{EnergyBalance, Partial};
use crate::exchange::{Exchange, ExchangeStats};
use crate::grid::{GridGeom, GridMode, GridSpec, NodeArrays, Records, Wall, WallLayers, P2G_WIDTH, REMAP_WIDTH};
use crate::inject::Injection;
use crate::locate::Located;
use crate::material::{BulkViscosity, Material, PointConsts};
use crate::math::Vec3;
use crate::node_index::NodeIndex;
use crate::order::{CellOrder, SORT_EVERY};
use crate::parallel::Team;
use crate::particles::Particles;
use crate::simd::SimdLevel;
use crate::strategy::{DomainDecomposition, Engine, EngineState, Strategy};
use crate::timers::StageTimes;
use crate::work::{WorkCounts, WorkMeter};
use rayon::ThreadPool;
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Default CFL number. The paper does not give its value; 0.5 of the cell crossing time of
/// the fastest signal (`c_p + |v_p|`) keeps the explicit update stable through impacts and
/// leaves room for the stiffening of the Mie-Grüneisen EOS in strong compression.
pub const DEFAULT_CFL: f64 = 0.5;

/// Default [`SimConfig::energy_rise_limit`]: 5 % above the initial total energy.
pub const DEFAULT_ENERGY_RISE_LIMIT: f64 = 0.05;

/// Solver settings that are not part of the scenario.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SimConfig {
    /// Scatter strategy. Its worker count is the thread count of the pool the simulation
    /// is built with ([`Simulation::new`]): 1 for the serial strategy.
    pub strategy: Strategy,
    /// Fixed or adaptive grid.
    pub grid_mode: GridMode,
    /// CFL number in `(0, 1]`.
    pub cfl: f64,
    /// Body force per unit mass `b` of Eq. 5 (m/s^2); zero in the paper's problems.
    pub body_force: Vec3,
    /// A step whose total energy exceeds this multiple of the initial total energy is
    /// reported as a blow-up.
    pub blowup_factor: f64,
    /// A step after which the total energy (less the body forces' work) exceeds the initial
    /// total by more than this fraction ends the run with
    /// [`SimError::EnergyRise`](crate::SimError::EnergyRise)
    /// (default 0.05; `f64::INFINITY` turns the check off). See [`EnergyBalance`].
    pub energy_rise_limit: f64,
    /// Artificial bulk viscosity (shock capturing), on by default with `c1 = 1.5`,
    /// `c2 = 0.06` and the cell size as length; [`BulkViscosity::OFF`] turns it off.
    pub bulk_viscosity: BulkViscosity,
    /// Largest adaptive grid allowed (nodes).
    pub max_nodes: usize,
    /// The instruction-set level of the particle kernels ([`crate::simd`]); `None` (the
    /// default): the widest this CPU has. Every level gives bitwise the same results.
    pub simd: Option<SimdLevel>,
    /// Sort the particles into cell order ([`crate::order`]) before the first step and
    /// then before every `sort_every`-th step; 0: never (the scenario's order stays).
    /// Default [`SORT_EVERY`].
    pub sort_every: u64,
    /// A test knob, 0 (off) by default: every worker but the first does extra work in the
    /// grid-node stage of every step, so that the parallel efficiency drops by about this
    /// fraction (in [0, 1)); a one-thread run is unchanged. Results are bitwise those
    /// without it; only the time changes. Such a run is never a result (see
    /// `mpm run --inject-slowdown`).
    pub inject_slowdown: f64,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            strategy: Strategy::Serial,
            grid_mode: GridMode::Fixed,
            cfl: DEFAULT_CFL,
            body_force: [0.0; 3],
            blowup_factor: 2.0,
            energy_rise_limit: DEFAULT_ENERGY_RISE_LIMIT,
            bulk_viscosity: BulkViscosity::default(),
            max_nodes: 1 << 26,
            simd: None,
            sort_every: SORT_EVERY,
            inject_slowdown: 0.0,
        }
    }
}

/// Energies and momentum after a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Diagnostics {
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Internal energy (J).
    pub internal: f64,
    /// Linear momentum (kg m/s).
    pub momentum: Vec3,
    /// Particles with negative specific internal energy.
    pub negative_internal: u64,
}

impl Diagnostics {
    /// Total energy, kinetic plus internal (J).
    pub fn total(&self) -> f64 {
        self.kinetic + self.internal
    }
}

/// Everything a simulation carries from one step to the next besides its particles and
/// what its set-up gives again (material, grid specification, walls): with the particles
/// (in their order) it continues a run bit for bit ([`Simulation::state`],
/// [`Simulation::resume`]). Node arrays, sparse blocks, DD patches and binning are not in
/// it: every step recomputes them from the particles.
///
/// The figures a summary reports of the steps taken are here too (the energy balance, the
/// mean stored nodes, the stage timers, the workers' busy time, the particles that changed
/// rank and the exchange's traffic), so that a continued run reports the whole run.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SimState {
    /// The strategy the state was saved with.
    pub strategy: Strategy,
    /// Worker threads it was saved with (its pool's thread count).
    pub threads: usize,
    /// Steps taken.
    pub steps: u64,
    /// Simulated time (s).
    pub time: f64,
    /// The CFL time step of the next step (s).
    pub dt_next: f64,
    /// The first time step (s).
    pub dt_first: f64,
    /// Bounding box of the whole set after the last step (the adaptive grid's next box).
    pub bbox: (Vec3, Vec3),
    /// Energies and momentum at the start.
    pub initial: Diagnostics,
    /// Energies and momentum after the last step.
    pub last: Diagnostics,
    /// The energy balance so far.
    pub balance: EnergyBalance,
    /// Stored nodes summed over the steps taken (for the mean).
    pub node_steps: u64,
    /// Mass below which a node counts as empty (from the initial mean particle mass).
    pub mass_tol: f64,
    /// Particles of the whole problem, over every rank.
    pub total: u64,
    /// Particles that left this rank over the steps taken.
    pub migrated: u64,
    /// The whole problem's grid of the last step.
    pub global: GridGeom,
    /// This rank's part of it.
    pub geom: GridGeom,
    /// Stage timers over the steps taken.
    pub times: StageTimes,
    /// Each worker's busy seconds over the steps taken (`None`: serial).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub busy: Option<Vec<f64>>,
    /// What the strategy carries ([`EngineState`]).
    pub engine: EngineState,
    /// This rank's exchange traffic so far (zero for one process).
    pub exchange: ExchangeStats,
    /// What each worker did in each sub-stage over the steps taken ([`crate::work`]).
    #[serde(default)]
    pub work: WorkCounts,
}

/// An explicit MPM simulation: particles, grid, material, strategy state and timers.
pub struct Simulation {
    particles: Particles,
    spacing: Vec3,
    material: Material,
    spec: GridSpec,
    /// The whole problem's grid; `geom` is this rank's part of it (the same with one rank).
    global: GridGeom,
    /// Halo sums, migration and reductions over ranks (one process:
    /// [`OneProcess`](crate::OneProcess)).
    exchange: Box<dyn Exchange>,
    /// Particles that left this rank over the steps taken.
    migrated: u64,
    /// Particles of the whole problem, over every rank (constant).
    total: u64,
    walls: Vec<Wall>,
    wall_layers: WallLayers,
    config: SimConfig,
    geom: GridGeom,
    nodes: NodeArrays,
    /// The blocks of nodes stored this step ([`GridMode::Sparse`]); `None` on a dense grid.
    blocks: Option<BlockMap>,
    engine: Engine,
    /// Each worker's part of the P2G scatter before assembly (AE copies or DD sub-grids);
    /// empty for the serial strategy, which scatters into `nodes.p2g` directly.
    p2g_parts: Records<P2G_WIDTH>,
    /// The same for the re-map scatter.
    remap_parts: Records<REMAP_WIDTH>,
    partials: Vec<Partial>,
    /// The particles' cells and local coordinates in this step's grid (computed before P2G).
    located: Located,
    consts: PointConsts,
    mass_tol: f64,
    time: f64,
    steps: u64,
    dt_next: f64,
    dt_first: f64,
    bbox: (Vec3, Vec3),
    initial: Diagnostics,
    last: Diagnostics,
    balance: EnergyBalance,
    node_steps: u128,
    times: StageTimes,
    poisoned: Option<u64>,
    /// Whether [`Simulation::release_grid_arrays`] freed the arrays a step needs.
    released: bool,
    /// The instruction-set level the particle kernels run at (available on this CPU).
    simd: SimdLevel,
    /// The pool the simulation runs on: its thread count is the simulation's worker count.
    pool: Arc<ThreadPool>,
    /// The buffers of the cell order's sort.
    order: CellOrder,
    /// The workers of the parallel strategies, built once on `pool`; `None` for the serial
    /// strategy.
    /// Shared (`Arc`) only so that a step can hold the team while it borrows the rest of
    /// the simulation mutably.
    team: Option<Arc<Team>>,
    /// Busy seconds of the workers before this process took over a saved run (same
    /// worker count), added to the team's own.
    busy_before: Option<Vec<f64>>,
    /// The work counters of every worker and sub-stage ([`crate::work`]). Shared (`Arc`)
    /// only so that a step can count into them while it borrows the rest of the simulation
    /// mutably.
    work: Arc<WorkMeter>,
    /// The injected slowdown, when asked for and there is more than one worker.
    inject: Option<Injection>,
}

impl Simulation {
    /// The particles.
    pub fn particles(&self) -> &Particles {
        &self.particles
    }

    /// Mutable particles (for tests and custom initial conditions; do not resize).
    pub fn particles_mut(&mut self) -> &mut Particles {
        &mut self.particles
    }

    /// The scenario's particle lattice spacing per axis (m).
    pub fn spacing(&self) -> Vec3 {
        self.spacing
    }

    /// The material.
    pub fn material(&self) -> &Material {
        &self.material
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The pool the simulation runs on.
    pub fn pool(&self) -> &Arc<ThreadPool> {
        &self.pool
    }

    /// Worker threads: the pool's thread count.
    pub fn threads(&self) -> usize {
        self.pool.current_num_threads()
    }

    /// The grid of the last step (the initial grid before the first step); with several
    /// ranks, this rank's part of it.
    pub fn geom(&self) -> &GridGeom {
        &self.geom
    }

    /// The whole problem's grid of the last step (equal to [`Simulation::geom`] with one
    /// rank).
    pub fn global_geom(&self) -> &GridGeom {
        &self.global
    }

    /// The exchange between ranks the simulation runs with.
    pub fn exchange(&self) -> &dyn Exchange {
        self.exchange.as_ref()
    }

    /// Particles that left this rank for another over the steps taken (0 with one rank).
    pub fn migrated(&self) -> u64 {
        self.migrated
    }

    /// Particles of the whole problem, over every rank (`particles().len()` with one rank;
    /// constant: particles move between ranks but are neither created nor destroyed).
    pub fn total_particles(&self) -> usize {
        self.total as usize
    }

    /// The scenario's grid specification.
    pub fn grid_spec(&self) -> &GridSpec {
        &self.spec
    }

    /// Nodal arrays of the last step, numbered by [`Simulation::node_index`].
    pub fn nodes(&self) -> &NodeArrays {
        &self.nodes
    }

    /// The particles' cells and local coordinates in the last step's grid (at the step's
    /// start: the particles have moved since).
    pub fn located(&self) -> &Located {
        &self.located
    }

    /// How the nodal arrays are numbered: the dense grid, or its stored blocks
    /// ([`GridMode::Sparse`]).
    pub fn node_index(&self) -> NodeIndex<'_> {
        NodeIndex::of(&self.geom, self.blocks.as_ref())
    }

    /// Nodes stored on the last step's grid: every node of a dense grid, the stored blocks'
    /// nodes of a sparse one.
    pub fn stored_nodes(&self) -> usize {
        self.node_index().num_nodes()
    }

    /// Simulated time (s).
    pub fn time(&self) -> f64 {
        self.time
    }

    /// Steps taken.
    pub fn steps(&self) -> u64 {
        self.steps
    }

    /// The CFL time step the next step will take (s).
    pub fn dt_next(&self) -> f64 {
        self.dt_next
    }

    /// The first time step (s).
    pub fn dt_first(&self) -> f64 {
        self.dt_first
    }

    /// Accumulated stage times.
    pub fn times(&self) -> &StageTimes {
        &self.times
    }

    /// Energies and momentum at the start.
    pub fn initial(&self) -> Diagnostics {
        self.initial
    }

    /// Energies and momentum after the last step.
    pub fn diagnostics(&self) -> Diagnostics {
        self.last
    }

    /// The energy balance over the steps taken: largest rise and fall of the total energy,
    /// negative internal energies.
    pub fn energy_balance(&self) -> &EnergyBalance {
        &self.balance
    }

    /// The instruction-set level the particle kernels run at ([`SimConfig::simd`], or the
    /// widest this CPU has).
    pub fn simd_level(&self) -> SimdLevel {
        self.simd
    }

    /// The per-particle constants the stress update runs with (material and viscosity).
    pub fn point_consts(&self) -> &PointConsts {
        &self.consts
    }

    /// Mean count of stored nodes over the steps taken (the initial count before any
    /// step).
    pub fn mean_nodes(&self) -> f64 {
        if self.steps == 0 {
            self.stored_nodes() as f64
        } else {
            self.node_steps as f64 / self.steps as f64
        }
    }

    /// Seconds each worker has spent in its shares of the parallel phases, over every step
    /// taken (worker order); `None` for the serial strategy, which has no team.
    ///
    /// The time outside the shares is serial work of worker 0 and barrier waiting. The
    /// largest over the mean is the load imbalance: the strategies give every worker an
    /// equal share, so a large value means a worker's CPU was slowed from outside the run.
    pub fn worker_busy(&self) -> Option<Vec<f64>> {
        let team = self.team.as_ref()?;
        Some(match &self.busy_before {
            Some(before) => team.busy_seconds().zip(before).map(|(now, b)| b + now).collect(),
            None => team.busy_seconds().collect(),
        })
    }

    /// What each worker did in each sub-stage over the steps taken ([`crate::work`]): the
    /// deterministic counts, the same on any machine.
    pub fn work(&self) -> WorkCounts {
        self.work.counts()
    }

    /// Seconds of injected extra work over the steps taken (`None` when no slowdown is
    /// injected: [`SimConfig::inject_slowdown`] is 0, or the run has one worker).
    pub fn injected_seconds(&self) -> Option<f64> {
        self.inject.as_ref().map(|i| i.total_seconds)
    }

    /// Domain-decomposition state, if the strategy is DD.
    pub fn domain_decomposition(&self) -> Option<&DomainDecomposition> {
        self.engine.domain_decomposition()
    }

    /// Bytes held by particles, nodal arrays, scatter buffers, strategy tables and the
    /// particles' cells and local coordinates.
    pub fn memory_bytes(&self) -> usize {
        self.particles.bytes()
            + self.nodes.bytes()
            + self.p2g_parts.bytes()
            + self.remap_parts.bytes()
            + self.engine.bytes()
            + self.blocks.as_ref().map_or(0, BlockMap::bytes)
            + self.order.bytes()
            + self.exchange.bytes()
            + self.located.bytes()
    }

    /// After the last step: free the node arrays, the strategy's scatter buffers and the
    /// particles' cells and local coordinates, which only a step uses, so that whatever the
    /// caller does next with the particles (gather every rank's for a state dump) does not
    /// stack on them. The particles, the figures and the strategy's tables stay;
    /// [`Simulation::memory_bytes`] drops accordingly. A further step returns
    /// [`SimError::Released`](crate::SimError::Released).
    pub fn release_grid_arrays(&mut self) {
        self.nodes = NodeArrays::default();
        if let Some(map) = &mut self.blocks {
            *map = BlockMap::default();
        }
        self.p2g_parts = Records::default();
        self.remap_parts = Records::default();
        self.located = Located::default();
        self.released = true;
    }
}
