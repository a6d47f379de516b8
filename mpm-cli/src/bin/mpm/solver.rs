//! The simulation a spec asks for: its solver settings ([`sim_config`]), built from a fresh
//! set-up ([`simulation`]) or taken back from a checkpoint ([`resumed`]).

use anyhow::{Context, Result};
use mpm_core::{Exchange, OneProcess, Particles, SimConfig, SimState, Simulation};
use mpm_spec::RunSpec;

/// The solver settings the spec asks for: strategy, threads, grid, physics, the injected
/// slowdown.
pub fn sim_config(spec: &RunSpec) -> SimConfig {
    SimConfig {
        strategy: spec.strategy,
        threads: spec.threads,
        grid_mode: spec.grid,
        cfl: spec.physics.cfl,
        bulk_viscosity: spec.physics.q,
        energy_rise_limit: spec.physics.energy_rise_limit.as_f64(),
        inject_slowdown: spec.inject_slowdown.unwrap_or(0.0),
        ..SimConfig::default()
    }
}

/// The simulation of a built scenario as the spec asks ([`sim_config`]).
pub fn simulation(spec: &RunSpec, setup: mpm_core::Setup, exchange: Option<Box<dyn Exchange>>) -> Result<Simulation> {
    let config = sim_config(spec);
    match exchange {
        Some(exchange) => Simulation::with_exchange(setup, config, exchange),
        None => Simulation::new(setup, config),
    }
    .context("cannot set up the simulation")
}

/// The simulation of a scenario built without its particles, continued from a checkpoint's
/// particles (`ids`: their global ids, where saved) and solver state, as the spec asks.
pub fn resumed(
    spec: &RunSpec,
    setup: mpm_core::Setup,
    exchange: Option<Box<dyn Exchange>>,
    particles: Particles,
    ids: Option<Vec<u64>>,
    state: SimState,
) -> Result<Simulation> {
    let exchange = exchange.unwrap_or_else(|| Box::new(OneProcess::default()));
    Simulation::resume(setup, sim_config(spec), exchange, particles, ids, state)
        .context("cannot continue the simulation from the checkpoint")
}
