//! A coarse hypervelocity impact (about 10,000 particles): conservation, failure, sane
//! debris-cloud measurements, and AE / DD against the serial solver.

mod common;

use common::pool;
use mpm_core::scenario::impact::{measure, Impact, ImpactGeometry, PLATE_SIDE, SPHERE_RADIUS};
use mpm_core::{GridMode, Setup, SimConfig, Simulation, Strategy};

fn coarse() -> (Setup, ImpactGeometry) {
    Impact { spacing: 2.5e-3, cell: 5.0e-3, ..Default::default() }.setup().unwrap()
}

fn config(strategy: Strategy, threads: usize) -> SimConfig {
    SimConfig { strategy, threads, grid_mode: GridMode::Adaptive, ..Default::default() }
}

#[test]
fn coarse_impact_conserves_mass_and_momentum_fails_material_and_measures_a_cloud() {
    let (setup, geometry) = coarse();
    let n = setup.particles.len();
    assert!((5_000..20_000).contains(&n), "{n} particles");
    let mass = setup.particles.total_mass();
    let mut sim = Simulation::new(setup, config(Strategy::Serial, 1)).unwrap();
    let pool = pool(1);
    let p0 = sim.initial().momentum;
    let end = 30.6e-6;
    while sim.time() < end * (1.0 - 1e-12) {
        sim.step(&pool, end - sim.time()).unwrap();
        // Mass: the grid carries exactly the particles' mass (Eq. 1, partition of unity).
        let grid_mass: f64 = sim.nodes().p2g[..sim.geom().num_nodes()].iter().map(|n| n[0]).sum();
        assert!((grid_mass / mass - 1.0).abs() < 1e-12, "grid mass {grid_mass} vs {mass}");
        // Momentum: no walls, so it is conserved to round-off for the whole run.
        let p = sim.diagnostics().momentum;
        for d in 0..3 {
            assert!((p[d] - p0[d]).abs() < 1e-10 * p0[2].abs(), "momentum {d}: {} vs {}", p[d], p0[d]);
        }
    }
    let failed = sim.particles().failed_count();
    assert!(failed > 0, "hypervelocity impact must fail material");
    let f = measure(sim.particles(), &geometry);
    println!("{} steps, {failed} failed, {f:?}", sim.steps());
    assert!(f.debris_particles > 50);
    assert!(f.cloud_front > 0.05 && f.cloud_front < 0.25, "front {} m", f.cloud_front);
    assert!(f.cloud_front_robust <= f.cloud_front && f.cloud_front_robust > 0.5 * f.cloud_front);
    assert!(f.cloud_width > 2.0 * SPHERE_RADIUS && f.cloud_width < PLATE_SIDE, "width {} m", f.cloud_width);
    assert!(f.cloud_width_robust <= f.cloud_width);
    assert!(f.hole_diameter > 2.0 * SPHERE_RADIUS && f.hole_diameter < 0.5 * PLATE_SIDE, "hole {} m", f.hole_diameter);
    assert!(f.front_velocity > 0.5 * 6580.0 && f.front_velocity < 1.2 * 6580.0, "front velocity {}", f.front_velocity);
    // The cloud's leading edge moves with about its velocity over the run.
    assert!(f.cloud_front < f.front_velocity * end * 1.1);
}

#[test]
fn coarse_impact_ae_and_dd_match_serial() {
    let (setup, _) = coarse();
    let run = |strategy, threads| {
        let mut sim = Simulation::new(setup.clone(), config(strategy, threads)).unwrap();
        let pool = pool(threads);
        for _ in 0..40 {
            sim.step(&pool, f64::INFINITY).unwrap();
        }
        sim
    };
    let oracle = run(Strategy::Serial, 1);
    let scale = oracle.particles().x.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    let vscale = oracle.particles().v.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    for (strategy, threads) in [
        (Strategy::ArrayExpansion, 2),
        (Strategy::ArrayExpansion, 3),
        (Strategy::DomainDecomposition, 2),
        (Strategy::DomainDecomposition, 6),
    ] {
        let sim = run(strategy, threads);
        let dx = oracle
            .particles()
            .x
            .iter()
            .flatten()
            .zip(sim.particles().x.iter().flatten())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        let dv = oracle
            .particles()
            .v
            .iter()
            .flatten()
            .zip(sim.particles().v.iter().flatten())
            .fold(0.0f64, |m, (a, b)| m.max((a - b).abs()));
        assert!(dx / scale < 1e-9 && dv / vscale < 1e-9, "{strategy} x{threads}: {:e} {:e}", dx / scale, dv / vscale);
        assert_eq!(oracle.particles().failed, sim.particles().failed, "{strategy} x{threads}: failure flags");
    }
}
