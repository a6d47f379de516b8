//! A run continued from its saved state ([`Simulation::state`] with the particles, into
//! [`Simulation::resume`]) is bit for bit the run that never stopped, for every strategy,
//! on the fixed, adaptive and sparse grids: particles, energies, the energy balance, the
//! mean node count, DD's patch load and the balanced cuts' layout (every strategy whose runs
//! reproduce bitwise; atomic adds' do not, and they continue to round-off). Another strategy
//! or thread count after the restart continues the same physics to round-off.

mod common;

use common::*;
use mpm_core::scenario::taylor::TaylorBar;
use mpm_core::{GridMode, OneProcess, Particles, SimConfig, SimState, Simulation, Strategy};

/// A configuration and the thread count of the pool it runs on.
#[derive(Clone)]
struct Run {
    config: SimConfig,
    threads: usize,
}

fn config(strategy: Strategy, threads: usize, grid_mode: GridMode) -> Run {
    Run { config: SimConfig { strategy, grid_mode, ..Default::default() }, threads }
}

/// A fresh simulation of `setup` as `run` says.
fn start(setup: &mpm_core::Setup, run: &Run) -> Simulation {
    Simulation::new(setup.clone(), run.config.clone(), pool(run.threads)).unwrap()
}

fn step(sim: &mut Simulation, steps: u64) {
    for _ in 0..steps {
        sim.step(f64::INFINITY).unwrap();
    }
}

/// `setup` stepped `first` steps under `before`, saved, dropped, continued under `after`
/// from the saved state and particles only, for `then` more steps.
fn continued(setup: &mpm_core::Setup, before: Run, after: Run, first: u64, then: u64) -> Simulation {
    let mut sim = start(setup, &before);
    step(&mut sim, first);
    let (state, particles) = (sim.state(), sim.particles().clone());
    // The particles' global ids: the cell order has moved them from their indices.
    let ids: Vec<u64> = (0..particles.len()).map(|p| sim.exchange().global_id(p)).collect();
    assert!(ids.iter().enumerate().any(|(p, &id)| id != p as u64), "the cell order moved no particle");
    drop(sim);
    // What a restart has: the set-up without particles, the saved state and particles.
    let bare = mpm_core::Setup { particles: Particles::default(), ..setup.clone() };
    let same = (before.config.strategy, before.threads) == (after.config.strategy, after.threads);
    let exchange = Box::new(OneProcess::default());
    let mut sim = Simulation::resume(
        bare,
        after.config,
        pool(after.threads),
        exchange,
        particles,
        Some(ids.clone()),
        state.clone(),
    )
    .unwrap();
    assert!((0..ids.len()).all(|p| sim.exchange().global_id(p) == ids[p]), "the ids are taken back");
    if same {
        // Taken back whole: the state before any step is the saved one (the balanced cuts'
        // layout in use included, which only a later step's choice would show).
        assert_eq!(untimed(sim.state()), untimed(state), "the state right after the restart");
    }
    step(&mut sim, then);
    sim
}

/// The state without what a clock measures.
fn untimed(mut s: SimState) -> SimState {
    s.times = Default::default();
    s.busy = s.busy.map(|b| vec![0.0; b.len()]);
    s
}

#[test]
fn a_continued_run_is_bitwise_the_uninterrupted_one() {
    let taylor = TaylorBar::default().setup().unwrap();
    let impact = mini_impact();
    let cases = [
        (&taylor, GridMode::Fixed, Strategy::Serial, 1),
        (&taylor, GridMode::Fixed, Strategy::DomainDecomposition, 2),
        (&taylor, GridMode::Adaptive, Strategy::ArrayExpansion, 3),
        (&impact, GridMode::Sparse, Strategy::Serial, 1),
        (&impact, GridMode::Sparse, Strategy::DomainDecomposition, 4),
        (&impact, GridMode::Adaptive, Strategy::DdBalanced, 8),
        (&impact, GridMode::Sparse, Strategy::DdBalanced, 6),
        (&taylor, GridMode::Fixed, Strategy::Colour, 2),
        (&impact, GridMode::Sparse, Strategy::Colour, 3),
    ];
    for (setup, grid, strategy, threads) in cases {
        let what = format!("{} {grid:?} {strategy} x{threads}", setup.model);
        let c = config(strategy, threads, grid);
        let mut whole = start(setup, &c);
        step(&mut whole, 30);
        let resumed = continued(setup, c.clone(), c, 13, 17);
        assert!(whole.particles() == resumed.particles(), "{what}: particles differ");
        assert_eq!(untimed(whole.state()), untimed(resumed.state()), "{what}: state");
        assert_eq!(whole.mean_nodes().to_bits(), resumed.mean_nodes().to_bits(), "{what}: mean nodes");
        assert_eq!(whole.stored_nodes(), resumed.stored_nodes(), "{what}: stored nodes");
        if let (Some(a), Some(b)) = (whole.domain_decomposition(), resumed.domain_decomposition()) {
            assert_eq!((a.layout(), a.load()), (b.layout(), b.load()), "{what}: DD layout and load");
        }
        let busy = resumed.worker_busy().map(|b| b.len());
        assert_eq!(busy, (threads > 1 || strategy != Strategy::Serial).then_some(threads), "{what}");
        assert!(resumed.times().total() > 0.0);
    }
}

/// The balanced cuts keep a layout while it stays within the slack of the best (the
/// hysteresis): a restart must carry the layout in use, or it may pick another. On the mini
/// impact at 6 threads the chooser moves off the paper's layout and holds it.
#[test]
fn the_balanced_layout_in_use_survives_a_restart() {
    let impact = mini_impact();
    let c = config(Strategy::DdBalanced, 6, GridMode::Adaptive);
    let mut whole = start(&impact, &c);
    let mut layouts = Vec::new();
    for _ in 0..40 {
        whole.step(f64::INFINITY).unwrap();
        layouts.push(whole.domain_decomposition().unwrap().layout());
    }
    for split in [5, 11, 23] {
        let resumed = continued(&impact, c.clone(), c.clone(), split, 40 - split);
        assert!(whole.particles() == resumed.particles(), "split at {split}");
        assert_eq!(whole.domain_decomposition().unwrap().load(), resumed.domain_decomposition().unwrap().load());
    }
    println!("layouts over 40 steps: {layouts:?}");
}

/// Another strategy or thread count after the restart: the same physics, to round-off.
#[test]
fn another_strategy_after_a_restart_agrees_to_round_off() {
    let taylor = TaylorBar::default().setup().unwrap();
    let serial = config(Strategy::Serial, 1, GridMode::Fixed);
    let mut whole = start(&taylor, &serial);
    step(&mut whole, 40);
    for other in [
        config(Strategy::DomainDecomposition, 2, GridMode::Fixed),
        config(Strategy::ArrayExpansion, 3, GridMode::Fixed),
        config(Strategy::Colour, 2, GridMode::Fixed),
        config(Strategy::Atomic, 2, GridMode::Fixed),
    ] {
        let what = format!("serial -> {} x{}", other.config.strategy, other.threads);
        let resumed = continued(&taylor, serial.clone(), other, 20, 20);
        let rel = |a: f64, b: f64| ((a - b) / a).abs();
        let (a, b) = (whole.diagnostics(), resumed.diagnostics());
        let (dk, du) = (rel(a.kinetic, b.kinetic), rel(a.internal, b.internal));
        let dx = whole
            .particles()
            .x
            .iter()
            .zip(&resumed.particles().x)
            .flat_map(|(p, q)| (0..3).map(move |d| (p[d] - q[d]).abs()))
            .fold(0.0f64, f64::max)
            / 25.4e-3;
        println!("{what}: kinetic {dk:.1e}, internal {du:.1e}, positions {dx:.1e} of the bar's length");
        assert!(dk < 1e-9 && du < 1e-9 && dx < 1e-9, "{what}: {dk:e} {du:e} {dx:e}");
        assert_eq!(resumed.steps(), 40);
        assert!(resumed.domain_decomposition().is_none_or(|dd| dd.load().steps == 20), "{what}: DD's load restarts");
    }
}

#[test]
fn particles_of_another_run_are_refused() {
    let taylor = TaylorBar::default().setup().unwrap();
    let c = config(Strategy::Serial, 1, GridMode::Fixed);
    let sim = start(&taylor, &c);
    let mut particles = sim.particles().clone();
    particles.swap_remove(0);
    let bare = mpm_core::Setup { particles: Particles::default(), ..taylor };
    let exchange = Box::new(OneProcess::default());
    let err = Simulation::resume(bare, c.config, pool(1), exchange, particles, None, sim.state()).err().unwrap();
    assert!(err.to_string().contains("different runs"), "{err}");
}
