//! The explicit MUSL time step (paper Section 1, Eqs. 1-15).
//!
//! ```text
//! step k -> k+1, dt = CFL dx / max_p(c_p + |v_p|)
//!   grid-node stage
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
//! pass is split across workers by loop splitting. The step allocates nothing once the grid
//! has reached its largest size (rayon's `broadcast` allocates one job list of `T` entries
//! per parallel phase; the count of such allocations does not depend on the problem size).

use crate::disjoint::{partition, DisjointSlice};
use crate::energy::Partial;
use crate::error::SimError;
use crate::grid::{GridGeom, GridMode, GridSpec, NodeArrays, Wall, WallLayers};
use crate::material::{update_point, Eos, Material, PointConsts, PointState, PressureModel};
use crate::math::{norm, sym_mul_vec, Vec3};
use crate::particles::Particles;
use crate::scenario::Setup;
use crate::strategy::{Contribution, Engine, Exec, Strategy};
use crate::timers::{Lap, StageTimes, Substage};
use rayon::ThreadPool;
use serde::Serialize;

/// Default CFL number. The paper does not give its value; 0.5 of the cell crossing time of
/// the fastest signal (`c_p + |v_p|`) keeps the explicit update stable through impacts and
/// leaves room for the stiffening of the Mie-Grüneisen EOS in strong compression.
pub const DEFAULT_CFL: f64 = 0.5;

/// Solver settings that are not part of the scenario.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SimConfig {
    /// Scatter strategy.
    pub strategy: Strategy,
    /// Worker threads (the pool passed to [`Simulation::step`] must have this many; 1 for
    /// the serial strategy).
    pub threads: usize,
    /// Fixed or adaptive grid.
    pub grid_mode: GridMode,
    /// CFL number in `(0, 1]`.
    pub cfl: f64,
    /// Body force per unit mass `b` of Eq. 5 (m/s^2); zero in the paper's problems.
    pub body_force: Vec3,
    /// A step whose total energy exceeds this multiple of the initial total energy is
    /// reported as a blow-up.
    pub blowup_factor: f64,
    /// Largest adaptive grid allowed (nodes).
    pub max_nodes: usize,
}

impl Default for SimConfig {
    fn default() -> Self {
        Self {
            strategy: Strategy::Serial,
            threads: 1,
            grid_mode: GridMode::Fixed,
            cfl: DEFAULT_CFL,
            body_force: [0.0; 3],
            blowup_factor: 2.0,
            max_nodes: 1 << 26,
        }
    }
}

/// Energies and momentum after a step.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize)]
pub struct Diagnostics {
    /// Kinetic energy (J).
    pub kinetic: f64,
    /// Internal energy (J).
    pub internal: f64,
    /// Linear momentum (kg m/s).
    pub momentum: Vec3,
}

/// An explicit MPM simulation: particles, grid, material, strategy state and timers.
pub struct Simulation {
    particles: Particles,
    material: Material,
    spec: GridSpec,
    walls: Vec<Wall>,
    wall_layers: WallLayers,
    config: SimConfig,
    geom: GridGeom,
    nodes: NodeArrays,
    engine: Engine,
    buf7: Vec<[f64; 7]>,
    buf3: Vec<[f64; 3]>,
    partials: Vec<Partial>,
    consts: PointConsts,
    mass_tol: f64,
    time: f64,
    steps: u64,
    dt_next: f64,
    dt_first: f64,
    bbox: (Vec3, Vec3),
    initial: Diagnostics,
    last: Diagnostics,
    node_steps: u128,
    times: StageTimes,
    poisoned: Option<u64>,
}

impl Simulation {
    /// Set up a simulation of `setup` with `config`.
    pub fn new(setup: Setup, config: SimConfig) -> Result<Self, SimError> {
        if config.threads == 0 {
            return Err(SimError::Config("threads must be at least 1".into()));
        }
        if config.strategy == Strategy::Serial && config.threads != 1 {
            return Err(SimError::Config(format!(
                "the serial strategy runs on 1 thread, not {}: use strategy 'ae' or 'dd' for more",
                config.threads
            )));
        }
        if !(config.cfl > 0.0 && config.cfl <= 1.0) {
            return Err(SimError::Config(format!(
                "CFL number must be in (0, 1], got {}",
                config.cfl
            )));
        }
        if setup.particles.is_empty() {
            return Err(SimError::Config("the scenario has no particles".into()));
        }
        let Setup {
            particles,
            material,
            grid: spec,
            walls,
            ..
        } = setup;
        let bbox = particles.bounding_box();
        let geom = match config.grid_mode {
            GridMode::Fixed => GridGeom::fixed(&spec),
            GridMode::Adaptive => GridGeom::fit(&spec, bbox.0, bbox.1),
        };
        if let Some(p) = particles.x.iter().position(|&x| !geom.contains(x)) {
            return Err(SimError::Config(format!(
                "particle {p} at {:?} m lies outside the grid; use the adaptive grid or a larger grid",
                particles.x[p]
            )));
        }
        let mean_mass = particles.total_mass() / particles.len() as f64;
        let mut wall_layers = WallLayers::with_capacity(walls.len());
        wall_layers.resolve(&walls, &geom);
        let mut nodes = NodeArrays::default();
        nodes.resize(geom.num_nodes());
        let initial = Diagnostics {
            kinetic: particles.kinetic_energy(),
            internal: particles.internal_energy(),
            momentum: particles.momentum(),
        };
        let max_speed = particles
            .sound
            .iter()
            .zip(&particles.v)
            .map(|(c, v)| c + norm(*v))
            .fold(0.0, f64::max);
        let dt = config.cfl * spec.dx / max_speed;
        Ok(Self {
            engine: Engine::new(config.strategy, config.threads),
            partials: vec![Partial::default(); config.threads],
            consts: material.consts(),
            mass_tol: 1e-12 * mean_mass,
            particles,
            material,
            spec,
            walls,
            wall_layers,
            geom,
            nodes,
            buf7: Vec::new(),
            buf3: Vec::new(),
            time: 0.0,
            steps: 0,
            dt_next: dt,
            dt_first: dt,
            bbox,
            initial,
            last: initial,
            node_steps: 0,
            times: StageTimes::default(),
            poisoned: None,
            config,
        })
    }

    /// The particles.
    pub fn particles(&self) -> &Particles {
        &self.particles
    }

    /// Mutable particles (for tests and custom initial conditions; do not resize).
    pub fn particles_mut(&mut self) -> &mut Particles {
        &mut self.particles
    }

    /// The material.
    pub fn material(&self) -> &Material {
        &self.material
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.config
    }

    /// The grid of the last step (the initial grid before the first step).
    pub fn geom(&self) -> &GridGeom {
        &self.geom
    }

    /// The scenario's grid specification.
    pub fn grid_spec(&self) -> &GridSpec {
        &self.spec
    }

    /// Nodal arrays of the last step.
    pub fn nodes(&self) -> &NodeArrays {
        &self.nodes
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

    /// Mean node count over the steps taken (the initial count before any step).
    pub fn mean_nodes(&self) -> f64 {
        if self.steps == 0 {
            self.geom.num_nodes() as f64
        } else {
            self.node_steps as f64 / self.steps as f64
        }
    }

    /// Domain-decomposition state, if the strategy is DD.
    pub fn domain_decomposition(&self) -> Option<&crate::strategy::DomainDecomposition> {
        match &self.engine {
            Engine::Dd(dd) => Some(dd),
            _ => None,
        }
    }

    /// Bytes held by particles, nodal arrays, scatter buffers and strategy tables.
    pub fn memory_bytes(&self) -> usize {
        self.particles.bytes()
            + self.nodes.bytes()
            + self.buf7.capacity() * 56
            + self.buf3.capacity() * 24
            + self.engine.bytes()
    }

    /// Advance one step of at most `dt_max` seconds inside `pool`.
    ///
    /// On error the state is left as the failing step made it and further steps return
    /// [`SimError::Poisoned`].
    pub fn step(&mut self, pool: &ThreadPool, dt_max: f64) -> Result<(), SimError> {
        if let Some(s) = self.poisoned {
            return Err(SimError::Poisoned(s));
        }
        let want = self.config.threads;
        if self.config.strategy != Strategy::Serial && pool.current_num_threads() != want {
            return Err(SimError::PoolSize {
                got: pool.current_num_threads(),
                want,
            });
        }
        let result = pool.install(|| self.step_inner(pool, dt_max));
        if result.is_err() {
            self.poisoned = Some(self.steps + 1);
        }
        result
    }

    fn step_inner(&mut self, pool: &ThreadPool, dt_max: f64) -> Result<(), SimError> {
        let step_no = self.steps + 1;
        let dt = self.dt_next.min(dt_max);
        let exec = Exec::new(pool, self.config.strategy);
        let mut lap = Lap::start();

        // ---- grid-node stage -------------------------------------------------------
        if self.config.grid_mode == GridMode::Adaptive {
            let geom = GridGeom::fit(&self.spec, self.bbox.0, self.bbox.1);
            if geom.num_nodes() > self.config.max_nodes {
                return Err(SimError::GridTooLarge {
                    step: step_no,
                    nodes: geom.num_nodes(),
                    limit: self.config.max_nodes,
                });
            }
            if geom != self.geom {
                self.geom = geom;
                self.nodes.resize(geom.num_nodes());
                self.wall_layers.resolve(&self.walls, &geom);
            }
        }
        self.node_steps += self.geom.num_nodes() as u128;
        lap.lap(&mut self.times, Substage::GridFit);
        self.engine.prepare(&exec, &self.geom, &self.particles.x);
        lap.lap(&mut self.times, Substage::Binning);

        let geom = self.geom;
        let n = self.particles.len();
        {
            let Particles {
                x,
                v,
                mass,
                rho,
                stress,
                ..
            } = &self.particles;
            let bf = self.config.body_force;
            let p2g = |p: usize| {
                let s = geom.shape(x[p]);
                let m = mass[p];
                let vol = m / rho[p];
                let vp = v[p];
                let mut c = [[0.0; 7]; 8];
                for q in 0..8 {
                    let w = s.w[q];
                    let t = sym_mul_vec(&stress[p], s.g[q]);
                    let mw = m * w;
                    c[q] = [
                        mw,
                        mw * vp[0],
                        mw * vp[1],
                        mw * vp[2],
                        mw * bf[0] - vol * t[0],
                        mw * bf[1] - vol * t[1],
                        mw * bf[2] - vol * t[2],
                    ];
                }
                Contribution { cell: s.cell, c }
            };
            self.engine.scatter(
                &exec,
                &geom,
                n,
                &mut self.nodes.p2g,
                &mut self.buf7,
                &p2g,
                &mut self.times,
                &mut lap,
                (Substage::Scatter, Substage::Assembly),
            );
        }
        grid_update(
            &exec,
            &geom,
            &self.wall_layers,
            &mut self.nodes,
            dt,
            self.mass_tol,
        );
        lap.lap(&mut self.times, Substage::GridUpdate);

        // ---- particle stage --------------------------------------------------------
        gather(
            &exec,
            &geom,
            &self.nodes.kin,
            &self.particles.x,
            &mut self.particles.v,
            dt,
        );
        lap.lap(&mut self.times, Substage::Gather);
        {
            let Particles { x, v, mass, .. } = &self.particles;
            let remap = |p: usize| {
                let s = geom.shape(x[p]);
                let mv = [mass[p] * v[p][0], mass[p] * v[p][1], mass[p] * v[p][2]];
                Contribution {
                    cell: s.cell,
                    c: s.w.map(|w| [mv[0] * w, mv[1] * w, mv[2] * w]),
                }
            };
            self.engine.scatter(
                &exec,
                &geom,
                n,
                &mut self.nodes.remap,
                &mut self.buf3,
                &remap,
                &mut self.times,
                &mut lap,
                (Substage::RemapScatter, Substage::RemapAssembly),
            );
        }
        remap_velocity(
            &exec,
            &geom,
            &self.wall_layers,
            &mut self.nodes,
            self.mass_tol,
        );
        lap.lap(&mut self.times, Substage::RemapAssembly);

        let fixed = self.config.grid_mode == GridMode::Fixed;
        match self.material.eos {
            Eos::MieGruneisen(ref m) => update_pass(
                &exec,
                &geom,
                &self.nodes,
                &mut self.particles,
                &self.consts,
                m,
                dt,
                fixed,
                &mut self.partials,
            ),
            Eos::Linear(ref l) => update_pass(
                &exec,
                &geom,
                &self.nodes,
                &mut self.particles,
                &self.consts,
                l,
                dt,
                fixed,
                &mut self.partials,
            ),
        }
        let mut total = Partial::default();
        for p in &self.partials[..exec.workers] {
            total.merge(p);
        }
        lap.lap(&mut self.times, Substage::StressUpdate);

        // ---- checks and bookkeeping ------------------------------------------------
        if total.non_finite > 0 || !(total.kinetic + total.internal).is_finite() {
            return Err(SimError::NonFinite {
                step: step_no,
                count: total.non_finite.max(1),
                cfl: self.config.cfl,
            });
        }
        if total.outside > 0 {
            let first = total.first_outside.unwrap_or(0);
            return Err(SimError::LeftGrid {
                step: step_no,
                count: total.outside,
                first,
                position: self.particles.x[first],
            });
        }
        let e0 = self.initial.kinetic + self.initial.internal;
        let e = total.kinetic + total.internal;
        if e0 > 0.0 && e > self.config.blowup_factor * e0 {
            return Err(SimError::EnergyBlowUp {
                step: step_no,
                ratio: e / e0,
                cfl: self.config.cfl,
            });
        }
        self.last = Diagnostics {
            kinetic: total.kinetic,
            internal: total.internal,
            momentum: total.momentum,
        };
        self.bbox = (total.lo, total.hi);
        self.time += dt;
        self.steps = step_no;
        self.dt_next = self.config.cfl * geom.dx / total.max_speed;
        Ok(())
    }
}

/// Node strides `[1, sy, sz]` and the 8 node offsets of a cell, in shape-function order.
#[inline(always)]
fn cell_nodes(geom: &GridGeom, cell: [usize; 3]) -> [usize; 8] {
    let n = geom.node_dims();
    let (sy, sz) = (n[0], n[0] * n[1]);
    let b = cell[0] + sy * cell[1] + sz * cell[2];
    [
        b,
        b + 1,
        b + sy,
        b + sy + 1,
        b + sz,
        b + sz + 1,
        b + sz + sy,
        b + sz + sy + 1,
    ]
}

/// Eq. 6 and the walls: `p += f dt`; wall nodes lose the constrained components of `p`
/// and `f`; `v = p/m`, `a = f/m` (zero on massless nodes). Parallel over node rows.
fn grid_update(
    exec: &Exec<'_>,
    geom: &GridGeom,
    walls: &WallLayers,
    nodes: &mut NodeArrays,
    dt: f64,
    tol: f64,
) {
    let d = geom.node_dims();
    let rows = d[1] * d[2];
    let has_x = walls.x_layers().next().is_some();
    let p2g = &nodes.p2g;
    let kin = DisjointSlice::new(&mut nodes.kin[..]);
    exec.run(|w| {
        let r = partition(rows, exec.workers, w);
        // SAFETY: workers own disjoint row ranges, hence disjoint node ranges.
        let out = unsafe { kin.range_mut(r.start * d[0]..r.end * d[0]) };
        for (ri, row) in r.clone().enumerate() {
            let mask_row = walls.row_mask(row % d[1], row / d[1]);
            for i in 0..d[0] {
                let a = &p2g[row * d[0] + i];
                let mask = walls.node_mask(mask_row, i, has_x);
                let m = a[0];
                let o = &mut out[ri * d[0] + i];
                if m > tol {
                    let inv = 1.0 / m;
                    for k in 0..3 {
                        let f = a[4 + k] * mask[k];
                        let p = (a[1 + k] + a[4 + k] * dt) * mask[k];
                        o[k] = p * inv;
                        o[3 + k] = f * inv;
                    }
                } else {
                    *o = [0.0; 6];
                }
            }
        }
    });
}

/// Eq. 11, second half: `v_i = p_i / m_i` with the walls applied again, in place.
fn remap_velocity(
    exec: &Exec<'_>,
    geom: &GridGeom,
    walls: &WallLayers,
    nodes: &mut NodeArrays,
    tol: f64,
) {
    let d = geom.node_dims();
    let rows = d[1] * d[2];
    let has_x = walls.x_layers().next().is_some();
    let p2g = &nodes.p2g;
    let remap = DisjointSlice::new(&mut nodes.remap[..]);
    exec.run(|w| {
        let r = partition(rows, exec.workers, w);
        // SAFETY: workers own disjoint row ranges, hence disjoint node ranges.
        let out = unsafe { remap.range_mut(r.start * d[0]..r.end * d[0]) };
        for (ri, row) in r.clone().enumerate() {
            let mask_row = walls.row_mask(row % d[1], row / d[1]);
            for i in 0..d[0] {
                let m = p2g[row * d[0] + i][0];
                let mask = walls.node_mask(mask_row, i, has_x);
                let o = &mut out[ri * d[0] + i];
                if m > tol {
                    let inv = 1.0 / m;
                    for k in 0..3 {
                        o[k] *= inv * mask[k];
                    }
                } else {
                    *o = [0.0; 3];
                }
            }
        }
    });
}

/// Eqs. 8, 10: `v_p += dt sum_i S_ip a_i`, by loop splitting.
fn gather(exec: &Exec<'_>, geom: &GridGeom, kin: &[[f64; 6]], x: &[Vec3], v: &mut [Vec3], dt: f64) {
    let n = x.len();
    let vs = DisjointSlice::new(v);
    exec.run(|w| {
        let r = partition(n, exec.workers, w);
        // SAFETY: workers own disjoint particle chunks.
        let vw = unsafe { vs.range_mut(r.clone()) };
        for (vp, xp) in vw.iter_mut().zip(&x[r]) {
            let s = geom.shape(*xp);
            let idx = cell_nodes(geom, s.cell);
            let mut acc = [0.0; 3];
            for q in 0..8 {
                let a = &kin[idx[q]];
                for k in 0..3 {
                    acc[k] += s.w[q] * a[3 + k];
                }
            }
            for k in 0..3 {
                vp[k] += dt * acc[k];
            }
        }
    });
}

/// Eqs. 7, 9, 12-15 and the reductions, by loop splitting: positions from the updated
/// nodal velocities, strain and spin increments from the re-mapped ones, then the material
/// update; worker `w` writes its sums to `partials[w]`.
#[allow(clippy::too_many_arguments)]
fn update_pass<E: PressureModel + Sync>(
    exec: &Exec<'_>,
    geom: &GridGeom,
    nodes: &NodeArrays,
    particles: &mut Particles,
    consts: &PointConsts,
    eos: &E,
    dt: f64,
    fixed: bool,
    partials: &mut [Partial],
) {
    let n = particles.len();
    let Particles {
        x,
        v,
        mass,
        rho,
        stress,
        eps_p,
        e_int,
        sound,
        failed,
    } = particles;
    let (v, mass) = (&v[..], &mass[..]);
    let xs = DisjointSlice::new(&mut x[..]);
    let rhos = DisjointSlice::new(&mut rho[..]);
    let stresses = DisjointSlice::new(&mut stress[..]);
    let eps = DisjointSlice::new(&mut eps_p[..]);
    let es = DisjointSlice::new(&mut e_int[..]);
    let sounds = DisjointSlice::new(&mut sound[..]);
    let fails = DisjointSlice::new(&mut failed[..]);
    let parts = DisjointSlice::new(partials);
    let (kin, remap) = (&nodes.kin, &nodes.remap);
    let half_dt = 0.5 * dt;
    exec.run(|w| {
        let r = partition(n, exec.workers, w);
        // SAFETY: worker w owns particle chunk r of every array and partial slot w.
        let (x, rho, stress, eps_p, e_int, sound, failed, acc) = unsafe {
            (
                xs.range_mut(r.clone()),
                rhos.range_mut(r.clone()),
                stresses.range_mut(r.clone()),
                eps.range_mut(r.clone()),
                es.range_mut(r.clone()),
                sounds.range_mut(r.clone()),
                fails.range_mut(r.clone()),
                parts.get_mut(w),
            )
        };
        let mut sum = Partial::default();
        for k in 0..r.len() {
            let p = r.start + k;
            let s = geom.shape(x[k]);
            let idx = cell_nodes(geom, s.cell);
            let mut vx = [0.0; 3];
            let mut l = [[0.0; 3]; 3];
            for q in 0..8 {
                let vn = &kin[idx[q]];
                let vr = &remap[idx[q]];
                let g = s.g[q];
                for a in 0..3 {
                    vx[a] += s.w[q] * vn[a];
                    for b in 0..3 {
                        l[a][b] += vr[a] * g[b];
                    }
                }
            }
            let de = [
                dt * l[0][0],
                dt * l[1][1],
                dt * l[2][2],
                half_dt * (l[1][2] + l[2][1]),
                half_dt * (l[2][0] + l[0][2]),
                half_dt * (l[0][1] + l[1][0]),
            ];
            let dw = [
                half_dt * (l[1][2] - l[2][1]),
                half_dt * (l[2][0] - l[0][2]),
                half_dt * (l[0][1] - l[1][0]),
            ];
            update_point(
                consts,
                eos,
                &de,
                dw,
                PointState {
                    stress: &mut stress[k],
                    eps_p: &mut eps_p[k],
                    e_int: &mut e_int[k],
                    rho: &mut rho[k],
                    sound: &mut sound[k],
                    failed: &mut failed[k],
                },
            );
            let xp = &mut x[k];
            for a in 0..3 {
                xp[a] += dt * vx[a];
            }
            let vp = v[p];
            let m = mass[p];
            let v2 = vp[0] * vp[0] + vp[1] * vp[1] + vp[2] * vp[2];
            sum.kinetic += 0.5 * m * v2;
            sum.internal += m * e_int[k];
            for a in 0..3 {
                sum.momentum[a] += m * vp[a];
                sum.lo[a] = sum.lo[a].min(xp[a]);
                sum.hi[a] = sum.hi[a].max(xp[a]);
            }
            sum.max_speed = sum.max_speed.max(sound[k] + v2.sqrt());
            let finite = (xp[0]
                + xp[1]
                + xp[2]
                + v2
                + stress[k][0]
                + stress[k][1]
                + stress[k][2]
                + e_int[k])
                .is_finite();
            if !finite {
                sum.non_finite += 1;
            }
            if fixed && !geom.contains(*xp) {
                sum.outside += 1;
                sum.first_outside.get_or_insert(p);
            }
        }
        *acc = sum;
    });
}
