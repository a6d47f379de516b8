//! The time step: [`Simulation::step`] runs the MUSL sequence of the module docs
//! ([`super`]) in `step_inner`, one function per stage, each charged with its time and its
//! work to its sub-stage ([`Substage`]) by the step's stopwatch ([`Lap`]).
//!
//! The exchange calls of the stages are no-ops for one process ([`crate::SingleProcess`]):
//! the sums and maxima over one rank leave every value as it is, bit for bit.

use super::{Diagnostics, Simulation};
use crate::energy::Partial;
use crate::error::SimError;
use crate::exchange::reduce_partial;
use crate::grid::{GridGeom, GridMode, NodeArrays, P2G_WIDTH, REMAP_WIDTH};
use crate::material::Eos;
use crate::node_index::NodeIndex;
use crate::parallel::{Exec, RegionError};
use crate::particles::Particles;
use crate::timers::{StageTimes, Substage};
use crate::transfer;
use crate::work::WorkMeter;
use std::sync::Arc;
use std::time::Instant;

/// Particles found outside the fixed grid after a step: how many (over every rank) and the
/// first of this rank's, if it has any.
type LeftGrid = Option<(u64, Option<usize>)>;

impl Simulation {
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
        self.sort_if_due();
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

    /// Every `sort_every` steps: the particles into cell order ([`crate::order`]), on the
    /// pool's threads, before the step's parallel region.
    fn sort_if_due(&mut self) {
        let every = self.config.sort_every;
        if every > 0 && self.steps.is_multiple_of(every) {
            let start = Instant::now();
            let Self { order, geom, particles, exchange, pool, .. } = self;
            pool.install(|| order.sort(geom, particles, exchange.as_mut()));
            self.times.add(Substage::Reorder, start.elapsed().as_secs_f64());
        }
    }

    /// One MUSL step of `min(dt_next, dt_max)` with `exec`'s workers: the grid-node stage,
    /// the particle stage, the checks (module docs of [`super`]).
    fn step_inner(&mut self, exec: &Exec<'_>, dt_max: f64) -> Result<(), SimError> {
        let step_no = self.steps + 1;
        let dt = self.dt_next.min(dt_max);
        // The shares count their work ([`crate::work`]); each lap books it, with the time
        // since the previous lap, to its sub-stage.
        let work = Arc::clone(&self.work);
        let exec = &exec.counting(work.pending());
        let mut lap = Lap::start(&work);

        // ---- grid-node stage (Eqs. 1-6) ---------------------------------------------
        self.fit_grid(exec, step_no)?;
        lap.lap(&mut self.times, Substage::GridFit);
        self.engine.prepare(exec, &self.geom, self.blocks.as_ref(), &self.particles.x);
        lap.lap(&mut self.times, Substage::Binning);
        self.scatter_p2g(exec);
        lap.lap(&mut self.times, Substage::Scatter);
        self.assemble_p2g(exec)?;
        lap.lap(&mut self.times, Substage::Assembly);
        self.update_grid(exec, dt);
        lap.lap(&mut self.times, Substage::GridUpdate);
        if self.inject_slowdown(exec) {
            lap.lap(&mut self.times, Substage::GridUpdate);
        }

        // ---- particle stage (Eqs. 7-15) ---------------------------------------------
        self.gather_remap(exec, dt);
        lap.lap(&mut self.times, Substage::RemapScatter);
        self.assemble_remap(exec, dt)?;
        lap.lap(&mut self.times, Substage::RemapAssembly);
        let total = self.update_particles(exec, dt)?;
        let left = self.left_grid(&total)?;
        lap.lap(&mut self.times, Substage::StressUpdate);

        // ---- checks and bookkeeping -------------------------------------------------
        self.check(step_no, &total, left)?;
        self.book_energy(step_no, dt, &total)?;
        self.advance(step_no, dt, &total)
    }

    /// The adaptive grid re-fitted to the last step's bounding box (this rank's part of it,
    /// its walls), the sparse grid's blocks, the node arrays sized for the grid.
    fn fit_grid(&mut self, exec: &Exec<'_>, step_no: u64) -> Result<(), SimError> {
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
        Ok(())
    }

    /// Each particle's cell and local coordinates (once for P2G, the gather and re-map and
    /// the update; booked to the scatter, the first of them), then the P2G scatter (Eqs.
    /// 1-5) through the strategy.
    fn scatter_p2g(&mut self, exec: &Exec<'_>) {
        let (geom, n) = (self.geom, self.particles.len());
        self.located.locate(exec, &geom, &self.particles.x, self.simd);
        let index = NodeIndex::of(&self.geom, self.blocks.as_ref());
        let (particles, located, body_force, simd) =
            (&self.particles, &self.located, self.config.body_force, self.simd);
        let (global, parts) = (&mut self.nodes.p2g, &mut self.p2g_parts);
        if body_force == [0.0; 3] {
            let p2g = transfer::P2g::<false> { geom: &geom, particles, located, body_force, simd };
            self.engine.scatter(exec, &geom, &index, n, global, parts, &p2g);
        } else {
            let p2g = transfer::P2g::<true> { geom: &geom, particles, located, body_force, simd };
            self.engine.scatter(exec, &geom, &index, n, global, parts, &p2g);
        }
    }

    /// The strategy's assembly of the P2G scatter, summed over the ranks sharing nodes.
    fn assemble_p2g(&mut self, exec: &Exec<'_>) -> Result<(), SimError> {
        let index = NodeIndex::of(&self.geom, self.blocks.as_ref());
        self.engine.assemble(exec, &self.geom, &index, &mut self.nodes.p2g, &mut self.p2g_parts);
        self.exchange.sum_shared_nodes(&self.geom, self.nodes.p2g.as_flattened_mut(), P2G_WIDTH)
    }

    /// Eq. 6 and the walls ([`transfer::grid_update`]).
    fn update_grid(&mut self, exec: &Exec<'_>, dt: f64) {
        let index = NodeIndex::of(&self.geom, self.blocks.as_ref());
        transfer::grid_update(exec, &self.geom, &index, &self.wall_layers, &mut self.nodes, dt, self.mass_tol);
    }

    /// The injected slowdown's extra work, if one is asked for; whether it ran.
    fn inject_slowdown(&mut self, exec: &Exec<'_>) -> bool {
        let so_far = self.times.total();
        let Some(inject) = &mut self.inject else { return false };
        inject.run(exec, so_far);
        true
    }

    /// The gather (Eqs. 8, 10) inside the re-map scatter (Eq. 11), particle by particle,
    /// through the strategy: its time is the re-map scatter's (`Substage::Gather` stays 0).
    fn gather_remap(&mut self, exec: &Exec<'_>, dt: f64) {
        let (geom, n) = (self.geom, self.particles.len());
        let index = NodeIndex::of(&geom, self.blocks.as_ref());
        let NodeArrays { kin, remap, .. } = &mut self.nodes;
        let Particles { v, mass, .. } = &mut self.particles;
        let gather_remap = transfer::GatherRemap::new(&geom, kin, &self.located, mass, v, dt, self.simd);
        self.engine.scatter(exec, &geom, &index, n, remap, &mut self.remap_parts, &gather_remap);
    }

    /// The strategy's assembly of the re-map scatter, summed over the ranks sharing nodes,
    /// and the re-mapped velocities with the walls ([`transfer::remap_velocity`]).
    fn assemble_remap(&mut self, exec: &Exec<'_>, dt: f64) -> Result<(), SimError> {
        let index = NodeIndex::of(&self.geom, self.blocks.as_ref());
        self.engine.assemble(exec, &self.geom, &index, &mut self.nodes.remap, &mut self.remap_parts);
        self.exchange.sum_shared_nodes(&self.geom, self.nodes.remap.as_flattened_mut(), REMAP_WIDTH)?;
        transfer::remap_velocity(exec, &self.geom, &index, &self.wall_layers, &mut self.nodes, dt, self.mass_tol);
        Ok(())
    }

    /// The particle update (Eqs. 7, 9, 12-15, [`transfer::update`]) with the material's EOS;
    /// the workers' sums, combined in worker order and over the ranks.
    fn update_particles(&mut self, exec: &Exec<'_>, dt: f64) -> Result<Partial, SimError> {
        let geom = self.geom;
        let index = NodeIndex::of(&geom, self.blocks.as_ref());
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
        Ok(total)
    }

    /// The particles that left the fixed grid. The fixed grid is a box: every particle is in
    /// it exactly when the corners of the (exact, whole-set) bounding box `total.lo`,
    /// `total.hi` are. Only when they are not are the particles outside found and counted,
    /// on every rank alike (over ranks `geom` is this rank's part of the grid, which
    /// particles leave for a neighbour's, so the test is on the global grid).
    fn left_grid(&mut self, total: &Partial) -> Result<LeftGrid, SimError> {
        if self.config.grid_mode != GridMode::Fixed
            || (self.global.contains(total.lo) && self.global.contains(total.hi))
        {
            return Ok(None);
        }
        let mut outside = self.particles.x.iter().enumerate().filter(|(_, &x)| !self.global.contains(x));
        let first = outside.next().map(|(p, _)| p);
        let mut count = [first.map_or(0, |_| 1 + outside.count() as u64)];
        self.exchange.sum_counts(&mut count)?;
        Ok(Some((count[0], first)))
    }

    /// The step's errors: non-finite values, particles off the fixed grid, a blow-up of the
    /// total energy.
    fn check(&self, step_no: u64, total: &Partial, left: LeftGrid) -> Result<(), SimError> {
        let cfl = self.config.cfl;
        if total.non_finite > 0 || !(total.kinetic + total.internal).is_finite() {
            return Err(SimError::NonFinite { step: step_no, count: total.non_finite.max(1), cfl });
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
            return Err(SimError::EnergyBlowUp { step: step_no, ratio: e / e0, cfl });
        }
        Ok(())
    }

    /// The step's terms of the energy balance (the body forces' work, the failed particles'
    /// floor); an error when the total energy rose past the limit.
    fn book_energy(&mut self, step_no: u64, dt: f64, total: &Partial) -> Result<(), SimError> {
        self.balance.add_body_force_work(self.config.body_force, self.last.momentum, total.momentum, dt);
        self.balance.add_failed_floor(total.failed_floor_energy, total.failed_floors);
        let rise = self.balance.record(step_no, total.kinetic + total.internal, total.negative_internal);
        if rise > self.config.energy_rise_limit {
            let (limit, cfl) = (self.config.energy_rise_limit, self.config.cfl);
            return Err(SimError::EnergyRise { step: step_no, rise, limit, cfl });
        }
        Ok(())
    }

    /// The step taken: the figures after it, the next box and time step, the particles that
    /// moved to another rank handed over.
    fn advance(&mut self, step_no: u64, dt: f64, total: &Partial) -> Result<(), SimError> {
        self.last = Diagnostics {
            kinetic: total.kinetic,
            internal: total.internal,
            momentum: total.momentum,
            negative_internal: total.negative_internal,
        };
        self.bbox = (total.lo, total.hi);
        self.time += dt;
        self.steps = step_no;
        self.dt_next = self.config.cfl * self.geom.dx / total.max_speed;
        self.migrated += self.exchange.migrate(&mut self.particles)? as u64;
        Ok(())
    }
}

/// The step's stopwatch: charges elapsed time, and the work counted meanwhile, to
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
