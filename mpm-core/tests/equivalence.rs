//! Every parallel strategy (all of [`Strategy::ALL`] but serial) against the serial oracle at
//! every thread count, and bitwise reproducibility for a fixed strategy and thread count
//! (every strategy but atomic adds, [`Strategy::is_deterministic`]). Runs with more threads
//! than this machine has cores too (oversubscription must work).
//!
//! The tolerance against the serial oracle, a relative 1e-9 after tens of steps, is not a
//! bound derived from the summation order (differences of one step's sums, bounded node by
//! node in the strategies' unit tests, grow through the dynamics); it says the parallel runs
//! compute the serial run's physics, far below any physical difference.

mod common;

use common::*;
use mpm_core::scenario::taylor::TaylorBar;
use mpm_core::{GridMode, Particles, Setup, SimConfig, SimdLevel, Simulation, Strategy};

const THREADS: [usize; 6] = [1, 2, 3, 4, 6, 8];

fn run(setup: &Setup, strategy: Strategy, threads: usize, grid_mode: GridMode, steps: usize) -> Simulation {
    let config = SimConfig { strategy, grid_mode, ..Default::default() };
    let mut sim = Simulation::new(setup.clone(), config, pool(threads)).unwrap();
    for _ in 0..steps {
        sim.step(f64::INFINITY).unwrap();
    }
    sim
}

/// Largest difference over the largest magnitude, per field.
fn rel_diff<const N: usize>(a: &[[f64; N]], b: &[[f64; N]]) -> f64 {
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs())).max(f64::MIN_POSITIVE);
    let diff = a.iter().flatten().zip(b.iter().flatten()).fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
    diff / scale
}

fn assert_close(oracle: &Particles, other: &Particles, what: &str) {
    let dx = rel_diff(&oracle.x, &other.x);
    let dv = rel_diff(&oracle.v, &other.v);
    let ds = rel_diff(&oracle.stress, &other.stress);
    println!("{what}: positions {dx:.1e} velocities {dv:.1e} stresses {ds:.1e}");
    assert!(dx < 1e-9 && dv < 1e-9 && ds < 1e-9, "{what}: x {dx:e} v {dv:e} sigma {ds:e}");
    assert_eq!(oracle.failed, other.failed, "{what}: failure flags");
}

fn check_all(setup: &Setup, grid_mode: GridMode, steps: usize) {
    let oracle = run(setup, Strategy::Serial, 1, grid_mode, steps);
    for strategy in Strategy::ALL.into_iter().filter(|s| s.is_parallel()) {
        for threads in THREADS {
            let sim = run(setup, strategy, threads, grid_mode, steps);
            assert_eq!(sim.steps(), oracle.steps());
            assert!((sim.time() / oracle.time() - 1.0).abs() < 1e-9);
            assert_close(oracle.particles(), sim.particles(), &format!("{} {strategy} x{threads}", setup.model));
        }
    }
}

#[test]
fn parallel_strategies_match_serial_on_taylor_model1_after_50_steps() {
    let setup = TaylorBar::default().setup().unwrap();
    check_all(&setup, GridMode::Fixed, 50);
}

#[test]
fn parallel_strategies_match_serial_on_taylor_model1_with_the_adaptive_grid() {
    let setup = TaylorBar::default().setup().unwrap();
    check_all(&setup, GridMode::Adaptive, 20);
}

/// The two strategies used since the paper on Model 2 (244,341 particles), at 1-8 threads:
/// the colour strategy's blocks of 4 (2 threads) and 2 cells (8 threads), the atomic adds'
/// contention over a larger grid.
#[test]
fn colour_and_atomic_match_serial_on_taylor_model2() {
    let setup = TaylorBar { model: 2, ..TaylorBar::default() }.setup().unwrap();
    let steps = 10;
    let oracle = run(&setup, Strategy::Serial, 1, GridMode::Fixed, steps);
    for strategy in [Strategy::Colour, Strategy::Atomic] {
        for threads in [1, 2, 4, 8] {
            let sim = run(&setup, strategy, threads, GridMode::Fixed, steps);
            assert_close(oracle.particles(), sim.particles(), &format!("{} {strategy} x{threads}", setup.model));
        }
    }
}

#[test]
fn parallel_strategies_match_serial_on_a_free_flight_impact_after_50_steps() {
    let setup = mini_impact();
    let oracle = run(&setup, Strategy::Serial, 1, GridMode::Adaptive, 50);
    assert!(oracle.particles().failed_count() > 0, "the impact should fail some particles");
    check_all(&setup, GridMode::Adaptive, 50);
}

#[test]
fn same_strategy_and_thread_count_reproduce_bitwise() {
    let setup = mini_impact();
    for (strategy, threads) in [
        (Strategy::ArrayExpansion, 3),
        (Strategy::DomainDecomposition, 4),
        (Strategy::DomainDecomposition, 8),
        (Strategy::DdBalanced, 2),
        (Strategy::DdBalanced, 8),
        (Strategy::Colour, 1),
        (Strategy::Colour, 3),
        (Strategy::Colour, 8),
    ] {
        let a = run(&setup, strategy, threads, GridMode::Adaptive, 30);
        let b = run(&setup, strategy, threads, GridMode::Adaptive, 30);
        assert!(a.particles() == b.particles(), "{strategy} x{threads} is not bitwise reproducible");
        assert_eq!(a.diagnostics(), b.diagnostics());
    }
}

#[test]
fn dd_patches_follow_the_adaptive_grid() {
    let setup = mini_impact();
    let sim = run(&setup, Strategy::DomainDecomposition, 6, GridMode::Adaptive, 10);
    let dd = sim.domain_decomposition().unwrap();
    assert_eq!(dd.layout(), [2, 1, 3]);
    let cells: usize = dd.patches().iter().map(|p| p.cells.iter().product::<usize>()).sum();
    assert_eq!(cells, sim.geom().num_cells());
    let binned: u32 = (0..6).map(|j| dd.binning().patnp(j)).sum();
    assert_eq!(binned as usize, sim.particles().len());
}

/// Balanced cuts on the impact (a plate holding most particles, a sphere in flight): the
/// patches still tile the grid, every particle is binned, and the work is far more even
/// than with uniform cuts. Uniform cuts keep the paper's 2x2x2; balanced cuts leave the
/// plate's z planes uncut (a z plane on a cell boundary cannot split a plate two cells
/// thick evenly: 2x2x2 with balanced planes measured 1.43 before the layout was chosen).
#[test]
fn balanced_cuts_even_out_the_impact() {
    let setup = mini_impact();
    let mut imbalance = Vec::new();
    for strategy in [Strategy::DomainDecomposition, Strategy::DdBalanced] {
        let sim = run(&setup, strategy, 8, GridMode::Adaptive, 10);
        let dd = sim.domain_decomposition().unwrap();
        assert_eq!(dd.is_balanced(), strategy == Strategy::DdBalanced);
        if strategy == Strategy::DdBalanced {
            assert_eq!(dd.layout()[2], 1, "balanced layout {:?}", dd.layout());
            assert_eq!(dd.layout().iter().product::<usize>(), 8);
        } else {
            assert_eq!(dd.layout(), [2, 2, 2]);
        }
        let cells: usize = dd.patches().iter().map(|p| p.cells.iter().product::<usize>()).sum();
        assert_eq!(cells, sim.geom().num_cells());
        let binned: u32 = (0..8).map(|j| dd.binning().patnp(j)).sum();
        assert_eq!(binned as usize, sim.particles().len());
        assert_eq!(dd.load().steps, 10);
        println!(
            "{strategy} {:?}: imbalance mean {:.3} max {:.3}",
            dd.layout(),
            dd.load().imbalance_mean(),
            dd.load().imbalance_max
        );
        imbalance.push(dd.load().imbalance_max);
    }
    assert!(imbalance[1] < 0.7 * imbalance[0], "balanced {} uniform {}", imbalance[1], imbalance[0]);
    assert!(imbalance[1] < 1.15, "balanced imbalance {}", imbalance[1]);
}

/// The thread count is the pool's: a simulation built on a pool of 4 threads runs 4 workers
/// and saves 4 in its state; the serial strategy on a pool of 2 threads is refused where the
/// pool is handed in.
#[test]
fn the_thread_count_is_the_pools() {
    let setup = TaylorBar::default().setup().unwrap();
    let config = SimConfig { strategy: Strategy::ArrayExpansion, ..Default::default() };
    let mut sim = Simulation::new(setup.clone(), config, pool(4)).unwrap();
    sim.step(f64::INFINITY).unwrap();
    assert_eq!((sim.threads(), sim.state().threads), (4, 4));
    assert_eq!(sim.worker_busy().map(|b| b.len()), Some(4));
    assert_eq!(sim.work().threads(), 4);
    let err = Simulation::new(setup, SimConfig::default(), pool(2)).err().unwrap();
    assert!(err.to_string().contains("exactly 1 thread, not 2"), "{err}");
}

/// The sparse grid stores only the blocks of nodes the particles touch, and gives bitwise the
/// adaptive grid's results for every strategy and thread count (atomic adds: to round-off,
/// as two of their runs on one grid): on the mini impact with a
/// fragment flying off far ahead and sideways (so that most of the box is empty), and on
/// the Taylor bar, whose wall lies on the grid's lowest node layer.
#[test]
fn sparse_grid_is_bitwise_the_adaptive_grid() {
    let mut impact = mini_impact();
    let p = &mut impact.particles;
    let (m, rho, c) = (p.mass[0], p.rho[0], p.sound[0]);
    for i in 0..6 {
        let f = i as f64 * 4e-4;
        p.push([0.03 + f, 0.021 - f, 0.012 + f], [900.0, -500.0, 2500.0], m, rho, c);
    }
    let taylor = TaylorBar::default().setup().unwrap();
    let runs = std::iter::once((Strategy::Serial, 1))
        .chain(Strategy::ALL.into_iter().filter(|s| s.is_parallel()).flat_map(|s| THREADS.map(|t| (s, t))));
    for (strategy, threads) in runs {
        for (setup, steps) in [(&impact, 30), (&taylor, 8)] {
            let dense = run(setup, strategy, threads, GridMode::Adaptive, steps);
            let sparse = run(setup, strategy, threads, GridMode::Sparse, steps);
            let what = format!("{} {strategy} x{threads}", setup.model);
            if strategy.is_deterministic() {
                assert!(dense.particles() == sparse.particles(), "{what}: the sparse grid changed the particles");
                assert_eq!(dense.diagnostics(), sparse.diagnostics(), "{what}");
            } else {
                assert_close(dense.particles(), sparse.particles(), &what);
            }
            assert_eq!(dense.geom(), sparse.geom(), "{what}");
            if setup.model == "mini-impact" {
                assert!(
                    4 * sparse.stored_nodes() < dense.stored_nodes(),
                    "{what}: {} nodes stored of {}",
                    sparse.stored_nodes(),
                    dense.stored_nodes()
                );
            }
        }
    }
}

/// Every bit of every particle array.
fn bits(p: &Particles) -> Vec<u64> {
    let flat = |v: &[[f64; 3]]| v.iter().flatten().map(|x| x.to_bits()).collect::<Vec<_>>();
    let mut out = [flat(&p.x), flat(&p.v)].concat();
    out.extend(p.stress.iter().flatten().map(|x| x.to_bits()));
    for a in [&p.rho, &p.eps_p, &p.e_int, &p.sound, &p.mass] {
        out.extend(a.iter().map(|x| x.to_bits()));
    }
    out.extend(p.failed.iter().map(|&f| u64::from(f)));
    out
}

/// The particle kernels at the baseline instruction set and at every wider level this CPU
/// has (AVX2 in blocks of 4, AVX-512 in blocks of 8) give bitwise the same results: the same
/// operations in the same order on every lane, no fused multiply-add (see `mpm_core::simd`).
/// On the Taylor bar (plastic flow at the wall) and the mini impact (failure, the heat-free
/// rule, strong compression), serial, DD and colour (the kernels writing through its shared
/// view of the global arrays). A CPU with neither wide level fails the test:
/// there would be nothing to compare.
#[test]
fn dispatch_levels_agree_bitwise() {
    let widest = SimdLevel::detected();
    println!("widest SIMD level of this CPU: {widest}");
    let wide_levels: Vec<SimdLevel> =
        SimdLevel::ALL.into_iter().filter(|l| *l != SimdLevel::Baseline && l.is_available()).collect();
    assert!(!wide_levels.is_empty(), "this CPU has no SIMD level beyond the baseline: nothing to compare");
    let cases = [(TaylorBar::default().setup().unwrap(), GridMode::Fixed, 40), (mini_impact(), GridMode::Adaptive, 40)];
    for (setup, grid_mode, steps) in &cases {
        for (strategy, threads) in [(Strategy::Serial, 1), (Strategy::DomainDecomposition, 2), (Strategy::Colour, 2)] {
            let at = |simd| {
                let config = SimConfig { strategy, grid_mode: *grid_mode, simd: Some(simd), ..Default::default() };
                let mut sim = Simulation::new(setup.clone(), config, pool(threads)).unwrap();
                assert_eq!(sim.simd_level(), simd);
                for _ in 0..*steps {
                    sim.step(f64::INFINITY).unwrap();
                }
                sim
            };
            let base = at(SimdLevel::Baseline);
            for &level in &wide_levels {
                let wide = at(level);
                let what = format!("{} {strategy} x{threads}: baseline vs {level}", setup.model);
                assert!(bits(base.particles()) == bits(wide.particles()), "{what}: particles differ");
                assert_eq!(base.diagnostics(), wide.diagnostics(), "{what}");
            }
            if setup.model == "mini-impact" {
                assert!(base.particles().failed_count() > 0, "the impact should fail particles");
            }
        }
    }
}
