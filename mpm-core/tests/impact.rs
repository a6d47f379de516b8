//! A coarse hypervelocity impact (about 10,000 particles): conservation of mass, momentum
//! and energy, failure, sane debris-cloud measurements and histories, and AE / DD against
//! the serial solver.

mod common;

use common::pool;
use mpm_core::scenario::impact::{
    measure, History, Impact, ImpactGeometry, DEFAULT_HISTORY_INTERVAL, PLATE_SIDE, SPHERE_RADIUS,
};
use mpm_core::{GridMode, Setup, SimConfig, Simulation, SingleProcess, Strategy};

fn coarse() -> (Setup, ImpactGeometry) {
    Impact { spacing: 2.5e-3, cell: 5.0e-3, ..Default::default() }.setup().unwrap()
}

fn config(strategy: Strategy) -> SimConfig {
    SimConfig { strategy, grid_mode: GridMode::Adaptive, ..Default::default() }
}

#[test]
fn coarse_impact_conserves_mass_momentum_and_energy_fails_material_and_measures_a_cloud() {
    let (setup, geometry) = coarse();
    let n = setup.particles.len();
    assert!((5_000..20_000).contains(&n), "{n} particles");
    let mass = setup.particles.total_mass();
    let mut sim = Simulation::new(setup, config(Strategy::Serial), pool(1)).unwrap();
    let p0 = sim.initial().momentum;
    let ke0 = sim.initial().kinetic;
    let end = 30.6e-6;
    let mut history = History::new(DEFAULT_HISTORY_INTERVAL).unwrap();
    assert!(history.observe(&sim, &geometry, &mut SingleProcess).unwrap(), "the initial state is the first sample");
    while sim.time() < end * (1.0 - 1e-12) {
        sim.step(end - sim.time()).unwrap();
        history.observe(&sim, &geometry, &mut SingleProcess).unwrap();
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
    history.finish(&sim, Some(&f), failed);
    let d = sim.diagnostics();
    let balance = sim.energy_balance();
    let peak_internal = history.samples.iter().map(|s| s.internal).fold(0.0, f64::max);
    let front_velocity = history.front_velocity().expect("enough samples");
    println!(
        "{} steps, {failed} failed, KE/KE0 {:.4}, IE/KE0 {:.4} (peak {:.4}), {balance:?}\n{f:?}\nfront velocity {front_velocity:.0} m/s",
        sim.steps(),
        d.kinetic / ke0,
        d.internal / ke0,
        peak_internal / ke0
    );
    // Energy: kinetic plus internal energy is conserved (the issue asks 3 %; the scheme
    // conserves it to round-off).
    assert!(balance.max_rise < 1e-9 && balance.max_fall < 1e-9, "{balance:?}");
    assert!((d.total() / ke0 - 1.0).abs() < 1e-9);
    // No negative internal energy, except for a few particles in the first steps of the
    // contact, where a particle's energy lags the work of its stress by half a step.
    assert_eq!(d.negative_internal, 0, "negative internal energy at the end");
    assert!(balance.negative_internal_steps <= 5, "{balance:?}");
    assert!(balance.negative_internal_max as usize * 100 < n, "{balance:?}");
    // The shock heats the sphere and the plug: at the peak a fifth of the kinetic energy is
    // internal energy; the expanding debris turns most of it back into kinetic energy.
    assert!(peak_internal > 0.1 * ke0 && peak_internal < 0.5 * ke0, "peak internal energy {peak_internal}");
    assert!(d.internal > 0.01 * ke0 && d.internal < 0.3 * ke0, "internal energy {}", d.internal);
    assert!(d.internal > 0.0 && d.kinetic < ke0);
    // The cloud.
    assert!(f.debris_particles > 50);
    assert!(f.cloud_front > 0.05 && f.cloud_front < 0.25, "front {} m", f.cloud_front);
    assert!(f.cloud_front_robust <= f.cloud_front && f.cloud_front_robust > 0.5 * f.cloud_front);
    // A debris cloud from a thin plate is about as wide as it is long.
    assert!(f.cloud_width > 2.0 * SPHERE_RADIUS && f.cloud_width < 1.5 * f.cloud_front, "width {} m", f.cloud_width);
    assert!(f.cloud_width_robust <= f.cloud_width);
    assert!(f.hole_diameter > 2.0 * SPHERE_RADIUS && f.hole_diameter < 0.5 * PLATE_SIDE, "hole {} m", f.hole_diameter);
    let v = 6580.0;
    assert!(f.leading_debris_velocity > 0.5 * v && f.leading_debris_velocity < v, "{}", f.leading_debris_velocity);
    // The front moved at about the leading debris' speed, slower than the projectile, and
    // its position agrees with its velocity: 30.6 us at the front velocity from the rear face
    // at about 2 us, when the debris appeared.
    assert!(front_velocity > 0.5 * v && front_velocity < v, "front velocity {front_velocity}");
    assert!((front_velocity / f.leading_debris_velocity - 1.0).abs() < 0.1);
    assert!((f.cloud_front_robust / (front_velocity * (end - 2e-6)) - 1.0).abs() < 0.1, "{}", f.cloud_front_robust);
    // The history: a sample per microsecond from 0 to the end, energies as the solver's.
    let s = &history.samples;
    assert_eq!(s.len(), 32, "{} samples", s.len());
    assert_eq!((s[0].time, s[0].cloud_front, s[0].failed), (0.0, 0.0, 0));
    assert!(s.windows(2).all(|w| w[1].time > w[0].time && w[1].time - w[0].time < 1.5e-6));
    let last = s.last().unwrap();
    assert_eq!((last.time, last.total, last.failed), (sim.time(), d.total(), failed));
    assert!(s.iter().all(|x| (x.total / ke0 - 1.0).abs() < 1e-9));
}

#[test]
fn failed_particles_keep_no_negative_internal_energy_and_the_balance_books_what_that_adds() {
    // About 4.7 particles per cell along each axis, as the large model (0.21 mm spacing, 1 mm
    // cells), which left up to 60 particles below zero to the end: failed particles whose
    // work deficit (see mpm_core::material::failure) froze once their pressure was clipped.
    let (setup, _) = Impact { spacing: 1.06e-3, cell: 5.0e-3, ..Default::default() }.setup().unwrap();
    let mut sim = Simulation::new(setup, config(Strategy::Serial), pool(1)).unwrap();
    let end = 30.6e-6;
    while sim.time() < end * (1.0 - 1e-12) {
        sim.step(end - sim.time()).unwrap();
    }
    let (b, d, e0) = (*sim.energy_balance(), sim.diagnostics(), sim.initial().total());
    println!("{} steps, {b:?}", sim.steps());
    let p = sim.particles();
    let failed_negative = p.failed.iter().zip(&p.e_int).filter(|(&f, &e)| f && e < 0.0).count();
    assert_eq!(failed_negative, 0, "failed particles below zero at the end");
    assert_eq!(d.negative_internal, 0, "negative internal energy at the end");
    // The rule acted, and what it added is a few joules, booked: the scheme itself still
    // conserves kinetic plus internal energy to round-off.
    assert!(b.failed_floors > 0 && b.failed_floor_energy > 0.0, "{b:?}");
    assert!(b.failed_floor_energy < 1e-4 * e0, "{b:?}");
    assert!((d.total() - b.failed_floor_energy - e0).abs() < 1e-9 * e0);
    assert!(b.max_rise < 1e-9 && b.max_fall < 1e-9, "{b:?}");
    // Intact particles below zero (the work lag of the first contact steps) stay counted:
    // 20 of the 130 steps, all among the first 26 (the first 6 us).
    assert!(b.negative_internal_steps * 4 < sim.steps(), "{b:?}");
}

#[test]
fn coarse_impact_parallel_strategies_match_serial() {
    let (setup, _) = coarse();
    let run = |strategy, threads| {
        let mut sim = Simulation::new(setup.clone(), config(strategy), pool(threads)).unwrap();
        for _ in 0..40 {
            sim.step(f64::INFINITY).unwrap();
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
        (Strategy::Colour, 2),
        (Strategy::Colour, 5),
        (Strategy::Atomic, 2),
        (Strategy::Atomic, 4),
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
