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
//! Shape functions are evaluated at the positions of step `k` throughout the step (positions
//! move only in the last pass). Both scatters go through the [`crate::strategy`]; every other
//! pass is split across workers by loop splitting. A parallel step is one parallel region of
//! the simulation's [`Team`] ([`crate::parallel`]); the sort into cell order runs before it,
//! on the pool's threads through rayon. The step allocates nothing once the grid has reached
//! its largest size and the first sort has sized its buffers, except rayon's job list for
//! the region's one `broadcast` (`T` entries; the count of such allocations does not depend
//! on the problem size).

use crate::blocks::BlockMap;
use crate::energy::{EnergyBalance, Partial};
use crate::error::SimError;
use crate::exchange::{reduce_partial, Exchange, ExchangeStats, OneProcess};
use crate::grid::{GridGeom, GridMode, GridSpec, NodeArrays, Records, Wall, WallLayers, P2G_WIDTH, REMAP_WIDTH};
use crate::inject::Injection;
use crate::locate::Located;
use crate::material::{BulkViscosity, Eos, Material, PointConsts};
use crate::math::{norm, Vec3};
use crate::node_index::NodeIndex;
use crate::order::{CellOrder, SORT_EVERY};
use crate::parallel::{Exec, RegionError, Team};
use crate::particles::Particles;
use crate::scenario::Setup;
use crate::simd::SimdLevel;
use crate::strategy::{DomainDecomposition, Engine, EngineState, Strategy};
use crate::timers::{StageTimes, Substage};
use crate::transfer;
use crate::work::{WorkCounts, WorkMeter};
use rayon::ThreadPool;
use serde::{Deserialize, Serialize};
use std::sync::Arc;
use std::time::Instant;

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
    /// total by more than this fraction ends the run with [`SimError::EnergyRise`]
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
    /// Halo sums, migration and reductions over ranks (one process: [`OneProcess`]).
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
    /// The work counters of every worker and sub-stage ([`crate::work`]).
    work: WorkMeter,
    /// The injected slowdown, when asked for and there is more than one worker.
    inject: Option<Injection>,
}

/// What a simulation takes from its set-up besides the particles.
struct Parts {
    material: Material,
    spec: GridSpec,
    walls: Vec<Wall>,
    spacing: Vec3,
}

/// The checks of a configuration every set-up makes, for a pool of `threads` threads (the
/// one check of the thread count against the strategy); the SIMD level it runs at.
fn check_config(config: &SimConfig, material: &Material, threads: usize) -> Result<SimdLevel, SimError> {
    config.strategy.check_threads(threads).map_err(SimError::Config)?;
    if !(config.cfl > 0.0 && config.cfl <= 1.0) {
        return Err(SimError::Config(format!("CFL number must be in (0, 1], got {}", config.cfl)));
    }
    if config.energy_rise_limit.is_nan() || config.energy_rise_limit <= 0.0 {
        return Err(SimError::Config(format!(
            "the energy rise limit must be a fraction > 0 (default {DEFAULT_ENERGY_RISE_LIMIT}; infinity turns the check off), got {}",
            config.energy_rise_limit
        )));
    }
    config.bulk_viscosity.validate()?;
    if !(0.0..1.0).contains(&config.inject_slowdown) {
        return Err(SimError::Config(format!(
            "the injected slowdown must be a fraction in [0, 1) (0 = off), got {}",
            config.inject_slowdown
        )));
    }
    material.validate()?;
    let simd = config.simd.unwrap_or_else(SimdLevel::detected);
    if !simd.is_available() {
        return Err(SimError::Config(format!(
            "this CPU cannot run the particle kernels at SIMD level {simd}: the widest it has is {}",
            SimdLevel::detected()
        )));
    }
    Ok(simd)
}

impl Simulation {
    /// Set up a simulation of `setup` with `config`, running on `pool`: the pool's thread
    /// count is the simulation's worker count (1 for the serial strategy, checked here).
    pub fn new(setup: Setup, config: SimConfig, pool: Arc<ThreadPool>) -> Result<Self, SimError> {
        Self::with_exchange(setup, config, pool, Box::new(OneProcess::default()))
    }

    /// Set up this rank's part of a simulation split over ranks by `exchange`.
    ///
    /// `setup` holds either the whole set (the rank keeps the particles of its box) or only
    /// this rank's part of it ([`crate::scenario::Pick`], which never holds the whole set);
    /// the initial figures (dt, energies, grid) are the whole set's, through the exchange's
    /// reductions.
    pub fn with_exchange(
        setup: Setup,
        config: SimConfig,
        pool: Arc<ThreadPool>,
        mut exchange: Box<dyn Exchange>,
    ) -> Result<Self, SimError> {
        let simd = check_config(&config, &setup.material, pool.current_num_threads())?;
        let total = setup.part.as_ref().map_or(setup.particles.len() as u64, |p| p.total);
        if total == 0 {
            return Err(SimError::Config("the scenario has no particles".into()));
        }
        let Setup { mut particles, material, grid: spec, walls, spacing, part, .. } = setup;
        let (bbox, ids) = match part {
            Some(p) => ((p.lo, p.hi), Some(p.ids)),
            None => (particles.bounding_box(), None),
        };
        let global = match config.grid_mode {
            GridMode::Fixed => GridGeom::fixed(&spec),
            GridMode::Adaptive | GridMode::Sparse => GridGeom::fit(&spec, bbox.0, bbox.1),
        };
        if config.grid_mode == GridMode::Sparse && exchange.ranks() > 1 {
            return Err(SimError::Config(format!(
                "the sparse grid runs in one process only, not over {} ranks: use the adaptive grid (--grid adaptive) with several ranks",
                exchange.ranks()
            )));
        }
        exchange.adopt(&mut particles, ids)?;
        let consts = material.consts().with_viscosity(config.bulk_viscosity, spec.dx);
        // The whole set's figures: this rank's sums, counts and maxima, combined over the
        // ranks (sums in rank order, maxima exact, so dt equals one process's).
        let outside = particles.x.iter().position(|&x| !global.contains(x));
        let negative = particles.e_int.iter().filter(|&&e| e < -consts.energy_tolerance).count() as u64;
        let mut counts = [negative, u64::from(outside.is_some())];
        exchange.sum_counts(&mut counts)?;
        if counts[1] > 0 {
            return Err(SimError::Config(match outside {
                Some(p) => format!(
                    "particle {} at {:?} m lies outside the grid; use the adaptive grid or a larger grid",
                    exchange.global_id(p),
                    particles.x[p]
                ),
                None => "particles of another rank lie outside the grid; use the adaptive grid or a larger grid".into(),
            }));
        }
        let momentum = particles.momentum();
        let mut sums = [
            particles.total_mass(),
            particles.kinetic_energy(),
            particles.internal_energy(),
            momentum[0],
            momentum[1],
            momentum[2],
        ];
        exchange.sum(&mut sums)?;
        let mut max_speed = [particles.sound.iter().zip(&particles.v).map(|(c, v)| c + norm(*v)).fold(0.0, f64::max)];
        exchange.max(&mut max_speed)?;
        let mean_mass = sums[0] / total as f64;
        let initial = Diagnostics {
            kinetic: sums[1],
            internal: sums[2],
            momentum: [sums[3], sums[4], sums[5]],
            negative_internal: counts[0],
        };
        let dt = config.cfl * spec.dx / max_speed[0];
        let geom = exchange.local_grid(&global);
        let state = SimState {
            strategy: config.strategy,
            threads: pool.current_num_threads(),
            steps: 0,
            time: 0.0,
            dt_next: dt,
            dt_first: dt,
            bbox,
            initial,
            last: initial,
            balance: EnergyBalance::new(initial.total()),
            node_steps: 0,
            mass_tol: 1e-12 * mean_mass,
            total,
            migrated: 0,
            global,
            geom,
            times: StageTimes::default(),
            busy: None,
            engine: EngineState::default(),
            // The set-up's own reductions.
            exchange: exchange.stats(),
            work: WorkCounts::default(),
        };
        Ok(Self::assemble(Parts { material, spec, walls, spacing }, config, pool, exchange, particles, simd, state))
    }

    /// The simulation of `state` (with this rank's grid `state.geom`) and `particles`: the
    /// arrays a step needs, sized for that grid (so that memory figures are right before the
    /// first step and the first step does not allocate either), the strategy (continuing
    /// from `state.engine` when it is the one the state was saved with), the team.
    fn assemble(
        parts: Parts,
        config: SimConfig,
        pool: Arc<ThreadPool>,
        mut exchange: Box<dyn Exchange>,
        particles: Particles,
        simd: SimdLevel,
        state: SimState,
    ) -> Self {
        let Parts { material, spec, walls, spacing } = parts;
        let threads = pool.current_num_threads();
        let geom = state.geom;
        let consts = material.consts().with_viscosity(config.bulk_viscosity, spec.dx);
        let mut wall_layers = WallLayers::with_capacity(walls.len());
        wall_layers.resolve(&walls, &geom);
        let blocks = (config.grid_mode == GridMode::Sparse).then(|| {
            let mut map = BlockMap::default();
            map.build(&Exec::serial(), &geom, &particles.x);
            map
        });
        let mut nodes = NodeArrays::default();
        nodes.resize(NodeIndex::of(&geom, blocks.as_ref()).num_nodes());
        let mut engine = Engine::new(config.strategy, threads);
        let parts_len = engine.reserve(&geom, blocks.as_ref());
        let same = state.strategy == config.strategy && state.threads == threads;
        if same {
            engine.restore(&state.engine);
        }
        exchange.resume_stats(state.exchange);
        Self {
            engine,
            spacing,
            partials: vec![Partial::default(); threads],
            located: Located::default(),
            consts,
            mass_tol: state.mass_tol,
            particles,
            material,
            spec,
            global: state.global,
            exchange,
            migrated: state.migrated,
            total: state.total,
            walls,
            wall_layers,
            geom,
            nodes,
            blocks,
            p2g_parts: Records::zeroed(parts_len),
            remap_parts: Records::zeroed(parts_len),
            time: state.time,
            steps: state.steps,
            dt_next: state.dt_next,
            dt_first: state.dt_first,
            bbox: state.bbox,
            initial: state.initial,
            last: state.last,
            balance: state.balance,
            node_steps: u128::from(state.node_steps),
            times: state.times,
            poisoned: None,
            released: false,
            simd,
            order: CellOrder::default(),
            team: config.strategy.is_parallel().then(|| Arc::new(Team::new(Arc::clone(&pool)))),
            pool,
            busy_before: state.busy.filter(|b| same && b.len() == threads),
            work: {
                // The counts go on with the workers they were counted on (a restart with
                // another strategy or thread count counts afresh, like the busy time).
                let meter = WorkMeter::new(threads);
                if same {
                    meter.restore(&state.work);
                }
                meter
            },
            inject: (config.inject_slowdown > 0.0 && config.strategy.is_parallel() && threads > 1)
                .then(|| Injection::new(config.inject_slowdown)),
            config,
        }
    }

    /// What this simulation carries from one step to the next besides its particles
    /// ([`SimState`]); with [`Simulation::particles`] (and, over ranks, each particle's
    /// [`Exchange::global_id`]) it is what [`Simulation::resume`] continues from.
    pub fn state(&self) -> SimState {
        SimState {
            strategy: self.config.strategy,
            threads: self.threads(),
            steps: self.steps,
            time: self.time,
            dt_next: self.dt_next,
            dt_first: self.dt_first,
            bbox: self.bbox,
            initial: self.initial,
            last: self.last,
            balance: self.balance,
            // A u64 holds a mean of 10^9 nodes over 10^10 steps.
            node_steps: u64::try_from(self.node_steps).unwrap_or(u64::MAX),
            mass_tol: self.mass_tol,
            total: self.total,
            migrated: self.migrated,
            global: self.global,
            geom: self.geom,
            times: self.times,
            busy: self.worker_busy(),
            engine: self.engine.state(),
            exchange: self.exchange.stats(),
            work: self.work.counts(),
        }
    }

    /// Continue a run from its saved `state` and `particles` (in the order they were saved):
    /// the next step is bitwise the one the saved simulation would have taken, when
    /// `config` and `pool` have the strategy and thread count `state` was saved with. Another
    /// strategy or thread count continues the same physics (to round-off, as any two of them agree)
    /// and starts its strategy's own figures (DD's patch load) and the workers' busy time
    /// afresh.
    ///
    /// `setup` gives what a state does not hold: the material, the grid specification, the
    /// walls and the spacing (its particles, if any, are not used: build it with
    /// [`crate::scenario::Pick::Where`] keeping none). Over ranks `exchange` is this rank's,
    /// with the rank boxes of the saved run, and `ids` the saved particles' global ids
    /// ([`Exchange::global_id`]); `None` when each particle's id is its index (one process
    /// before the cell order has moved any, [`crate::order`]).
    pub fn resume(
        setup: Setup,
        config: SimConfig,
        pool: Arc<ThreadPool>,
        mut exchange: Box<dyn Exchange>,
        mut particles: Particles,
        ids: Option<Vec<u64>>,
        state: SimState,
    ) -> Result<Self, SimError> {
        let simd = check_config(&config, &setup.material, pool.current_num_threads())?;
        let Setup { material, grid: spec, walls, spacing, .. } = setup;
        if exchange.ranks() == 1 && particles.len() as u64 != state.total {
            return Err(SimError::Config(format!(
                "the saved state has {} particles but the run it continues had {}: the particles and the state belong to different runs",
                particles.len(),
                state.total
            )));
        }
        if config.grid_mode == GridMode::Sparse && exchange.ranks() > 1 {
            return Err(SimError::Config("the sparse grid runs in one process only".into()));
        }
        let kept = particles.len();
        exchange.adopt(&mut particles, ids)?;
        if particles.len() != kept {
            return Err(SimError::Config(format!(
                "{} of this rank's {kept} saved particles lie outside its box: continue the run with the rank layout it was saved with",
                kept - particles.len()
            )));
        }
        let geom = exchange.local_grid(&state.global);
        if geom != state.geom {
            return Err(SimError::Config(
                "this rank's part of the grid differs from the saved one: continue the run with the rank count and layout it was saved with".into(),
            ));
        }
        Ok(Self::assemble(Parts { material, spec, walls, spacing }, config, pool, exchange, particles, simd, state))
    }

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
    /// [`SimError::Released`].
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

    /// Advance one step of at most `dt_max` seconds on the simulation's pool.
    ///
    /// The step runs on the pool's threads (serial: inside the pool's `install`; AE and DD:
    /// one parallel region of the simulation's team). A caller that steps many times should
    /// call this from inside the pool's `install` itself ([`Simulation::pool`]), which saves
    /// a hand-over to the pool per step (100-300 µs measured). On error the state is left as
    /// the failing step made it and further steps return [`SimError::Poisoned`].
    pub fn step(&mut self, dt_max: f64) -> Result<(), SimError> {
        if let Some(s) = self.poisoned {
            return Err(SimError::Poisoned(s));
        }
        if self.released {
            return Err(SimError::Released(self.steps));
        }
        let every = self.config.sort_every;
        if every > 0 && self.steps.is_multiple_of(every) {
            let start = std::time::Instant::now();
            let Self { order, geom, particles, exchange, pool, .. } = self;
            pool.install(|| order.sort(geom, particles, exchange.as_mut()));
            self.times.add(Substage::Reorder, start.elapsed().as_secs_f64());
        }
        let result = match self.team.clone() {
            None => Arc::clone(&self.pool).install(|| self.step_inner(&Exec::serial(), dt_max)),
            // One parallel region: worker 0 drives the step, the other workers serve its
            // phases and stay awake in between.
            Some(team) => match team.region(|exec| self.step_inner(exec, dt_max)) {
                Ok(result) => result,
                Err(RegionError::Busy) => {
                    unreachable!("only a step enters the simulation's team, and steps take &mut self")
                }
            },
        };
        if result.is_err() {
            self.poisoned = Some(self.steps + 1);
        }
        result
    }

    fn step_inner(&mut self, exec: &Exec<'_>, dt_max: f64) -> Result<(), SimError> {
        let step_no = self.steps + 1;
        let dt = self.dt_next.min(dt_max);
        // The shares count their work ([`crate::work`]); each lap books it to its sub-stage.
        let exec = &exec.counting(self.work.pending());
        let mut lap = Lap::start(&self.work);

        // ---- grid-node stage -------------------------------------------------------
        if self.config.grid_mode.is_adaptive() {
            let global = GridGeom::fit(&self.spec, self.bbox.0, self.bbox.1);
            if global.num_nodes() > self.config.max_nodes {
                return Err(SimError::GridTooLarge {
                    step: step_no,
                    nodes: global.num_nodes(),
                    limit: self.config.max_nodes,
                });
            }
            self.global = global;
            let geom = self.exchange.local_grid(&global);
            if geom != self.geom {
                self.geom = geom;
                self.wall_layers.resolve(&self.walls, &geom);
            }
        }
        if let Some(map) = &mut self.blocks {
            map.build(exec, &self.geom, &self.particles.x);
        }
        // Unchanged length (a dense grid that kept its box): nothing to do.
        self.nodes.resize(self.stored_nodes());
        self.node_steps += self.stored_nodes() as u128;
        lap.lap(&mut self.times, Substage::GridFit);
        self.engine.prepare(exec, &self.geom, self.blocks.as_ref(), &self.particles.x);
        lap.lap(&mut self.times, Substage::Binning);

        let geom = self.geom;
        let index = NodeIndex::of(&geom, self.blocks.as_ref());
        let n = self.particles.len();
        // The exchange calls below are no-ops for one process (`SingleProcess`): the sums and
        // maxima over one rank leave every value as it is, bit for bit.
        // Each particle's cell and local coordinates, once for P2G, the gather and re-map
        // and the update (booked to the scatter, the first of them).
        self.located.locate(exec, &geom, &self.particles.x, self.simd);
        let (particles, located, body_force) = (&self.particles, &self.located, self.config.body_force);
        if body_force == [0.0; 3] {
            let p2g = transfer::P2g::<false> { geom: &geom, particles, located, body_force, simd: self.simd };
            self.engine.scatter(exec, &geom, &index, n, &mut self.nodes.p2g, &mut self.p2g_parts, &p2g);
        } else {
            let p2g = transfer::P2g::<true> { geom: &geom, particles, located, body_force, simd: self.simd };
            self.engine.scatter(exec, &geom, &index, n, &mut self.nodes.p2g, &mut self.p2g_parts, &p2g);
        }
        lap.lap(&mut self.times, Substage::Scatter);
        self.engine.assemble(exec, &geom, &index, &mut self.nodes.p2g, &mut self.p2g_parts);
        self.exchange.sum_shared_nodes(&geom, self.nodes.p2g.as_flattened_mut(), P2G_WIDTH)?;
        lap.lap(&mut self.times, Substage::Assembly);
        transfer::grid_update(exec, &geom, &index, &self.wall_layers, &mut self.nodes, dt, self.mass_tol);
        lap.lap(&mut self.times, Substage::GridUpdate);
        if let Some(inject) = &mut self.inject {
            inject.run(exec, self.times.total());
            lap.lap(&mut self.times, Substage::GridUpdate);
        }

        // ---- particle stage --------------------------------------------------------
        // The gather (Eqs. 8, 10) runs inside the re-map scatter (Eq. 11), particle by
        // particle: its time is the re-map scatter's (`Substage::Gather` stays 0).
        let NodeArrays { kin, remap, .. } = &mut self.nodes;
        let Particles { v, mass, .. } = &mut self.particles;
        let gather_remap = transfer::GatherRemap::new(&geom, kin, &self.located, mass, v, dt, self.simd);
        self.engine.scatter(exec, &geom, &index, n, remap, &mut self.remap_parts, &gather_remap);
        lap.lap(&mut self.times, Substage::RemapScatter);
        self.engine.assemble(exec, &geom, &index, &mut self.nodes.remap, &mut self.remap_parts);
        self.exchange.sum_shared_nodes(&geom, self.nodes.remap.as_flattened_mut(), REMAP_WIDTH)?;
        transfer::remap_velocity(exec, &geom, &index, &self.wall_layers, &mut self.nodes, dt, self.mass_tol);
        lap.lap(&mut self.times, Substage::RemapAssembly);

        let (nodes, particles, consts, partials) = (&self.nodes, &mut self.particles, &self.consts, &mut self.partials);
        let (simd, located) = (self.simd, &self.located);
        match self.material.eos {
            Eos::MieGruneisen(ref m) => {
                transfer::update(exec, &geom, &index, located, nodes, particles, consts, m, dt, partials, simd)
            }
            Eos::Linear(ref l) => {
                transfer::update(exec, &geom, &index, located, nodes, particles, consts, l, dt, partials, simd)
            }
        }
        let mut total = Partial::default();
        for p in &self.partials[..exec.workers()] {
            total.merge(p);
        }
        reduce_partial(self.exchange.as_mut(), &mut total)?;
        // The fixed grid is a box: every particle is in it exactly when the corners of the
        // (exact, whole-set) bounding box are. Only when they are not are the particles
        // outside found and counted, on every rank alike (over ranks `geom` is this rank's
        // part of the grid, which particles leave for a neighbour's, so the test is on the
        // global grid).
        let mut left = None;
        if self.config.grid_mode == GridMode::Fixed
            && !(self.global.contains(total.lo) && self.global.contains(total.hi))
        {
            let mut outside = self.particles.x.iter().enumerate().filter(|(_, &x)| !self.global.contains(x));
            let first = outside.next().map(|(p, _)| p);
            let mut count = [first.map_or(0, |_| 1 + outside.count() as u64)];
            self.exchange.sum_counts(&mut count)?;
            left = Some((count[0], first));
        }
        lap.lap(&mut self.times, Substage::StressUpdate);

        // ---- checks and bookkeeping ------------------------------------------------
        if total.non_finite > 0 || !(total.kinetic + total.internal).is_finite() {
            return Err(SimError::NonFinite { step: step_no, count: total.non_finite.max(1), cfl: self.config.cfl });
        }
        if let Some((count, first)) = left.filter(|&(count, _)| count > 0) {
            return Err(SimError::LeftGrid {
                step: step_no,
                count,
                first: first.unwrap_or(0),
                // With several ranks the particles outside may all be other ranks'.
                position: first.map_or([f64::NAN; 3], |p| self.particles.x[p]),
            });
        }
        let e0 = self.initial.kinetic + self.initial.internal;
        let e = total.kinetic + total.internal;
        if e0 > 0.0 && e > self.config.blowup_factor * e0 {
            return Err(SimError::EnergyBlowUp { step: step_no, ratio: e / e0, cfl: self.config.cfl });
        }
        self.balance.add_body_force_work(self.config.body_force, self.last.momentum, total.momentum, dt);
        self.balance.add_failed_floor(total.failed_floor_energy, total.failed_floors);
        let rise = self.balance.record(step_no, e, total.negative_internal);
        if rise > self.config.energy_rise_limit {
            let (limit, cfl) = (self.config.energy_rise_limit, self.config.cfl);
            return Err(SimError::EnergyRise { step: step_no, rise, limit, cfl });
        }
        self.last = Diagnostics {
            kinetic: total.kinetic,
            internal: total.internal,
            momentum: total.momentum,
            negative_internal: total.negative_internal,
        };
        self.bbox = (total.lo, total.hi);
        self.time += dt;
        self.steps = step_no;
        self.dt_next = self.config.cfl * geom.dx / total.max_speed;
        self.migrated += self.exchange.migrate(&mut self.particles)? as u64;
        Ok(())
    }
}

/// A running stopwatch that charges elapsed time, and the work counted meanwhile, to
/// sub-stages.
struct Lap<'w> {
    last: Instant,
    work: &'w WorkMeter,
}

impl<'w> Lap<'w> {
    fn start(work: &'w WorkMeter) -> Self {
        Self { last: Instant::now(), work }
    }

    /// Charge the time since the previous lap, and the work counted since, to `s`.
    fn lap(&mut self, times: &mut StageTimes, s: Substage) {
        let now = Instant::now();
        times.add(s, (now - self.last).as_secs_f64());
        self.work.close(s);
        self.last = now;
    }
}
