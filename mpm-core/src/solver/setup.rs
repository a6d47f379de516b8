//! Building a simulation: fresh from a scenario's set-up ([`Simulation::new`],
//! [`Simulation::with_exchange`]) or continued from a saved state ([`Simulation::state`],
//! [`Simulation::resume`]). Both take the pool the simulation runs on and check its thread
//! count against the strategy once, here.

use super::{Diagnostics, SimConfig, SimState, Simulation, DEFAULT_ENERGY_RISE_LIMIT};
use crate::blocks::BlockMap;
use crate::energy::{EnergyBalance, Partial};
use crate::error::SimError;
use crate::exchange::{Exchange, OneProcess};
use crate::grid::{GridGeom, GridMode, GridSpec, NodeArrays, Records, Wall, WallLayers};
use crate::inject::Injection;
use crate::locate::Located;
use crate::material::{Material, PointConsts};
use crate::math::{norm, Vec3};
use crate::node_index::NodeIndex;
use crate::order::CellOrder;
use crate::parallel::{Exec, Team};
use crate::particles::Particles;
use crate::scenario::Setup;
use crate::simd::SimdLevel;
use crate::strategy::{Engine, EngineState};
use crate::timers::StageTimes;
use crate::work::{WorkCounts, WorkMeter};
use rayon::ThreadPool;
use std::sync::Arc;

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
        let (initial, max_speed, mass) = whole_set(&particles, &global, &consts, exchange.as_mut())?;
        let dt = config.cfl * spec.dx / max_speed;
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
            mass_tol: 1e-12 * (mass / total as f64),
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
        let (blocks, nodes) = grid_arrays(config.grid_mode, &geom, &particles.x);
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
            // The counts go on with the workers they were counted on (a restart with another
            // strategy or thread count counts afresh, like the busy time).
            work: Arc::new(work_meter(threads, same.then_some(&state.work))),
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
}

/// The whole set's figures at the start: this rank's sums, counts and maxima of
/// `particles`, combined over the ranks by `exchange` (sums in rank order, maxima exact, so
/// the time step equals one process's). Returns the energies and momentum, the largest
/// signal speed `max_p(c_p + |v_p|)` and the total mass; a particle outside the grid `global`
/// is an error.
fn whole_set(
    particles: &Particles,
    global: &GridGeom,
    consts: &PointConsts,
    exchange: &mut dyn Exchange,
) -> Result<(Diagnostics, f64, f64), SimError> {
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
    let initial = Diagnostics {
        kinetic: sums[1],
        internal: sums[2],
        momentum: [sums[3], sums[4], sums[5]],
        negative_internal: counts[0],
    };
    Ok((initial, max_speed[0], sums[0]))
}

/// The sparse grid's blocks (`None` on a dense grid) and the node arrays, sized for the grid
/// `geom` of the particles at `x`.
fn grid_arrays(mode: GridMode, geom: &GridGeom, x: &[Vec3]) -> (Option<BlockMap>, NodeArrays) {
    let blocks = (mode == GridMode::Sparse).then(|| {
        let mut map = BlockMap::default();
        map.build(&Exec::serial(), geom, x);
        map
    });
    let mut nodes = NodeArrays::default();
    nodes.resize(NodeIndex::of(geom, blocks.as_ref()).num_nodes());
    (blocks, nodes)
}

/// Work counters for `threads` workers, going on from `saved` when given.
fn work_meter(threads: usize, saved: Option<&WorkCounts>) -> WorkMeter {
    let meter = WorkMeter::new(threads);
    if let Some(saved) = saved {
        meter.restore(saved);
    }
    meter
}
