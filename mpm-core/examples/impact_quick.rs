//! Run the hypervelocity impact and print the debris-cloud figures:
//! `cargo run --profile o3 --example impact_quick -- [CELL_MM] [STRATEGY] [THREADS] [SPACING_MM]`.
use mpm_core::scenario::impact::{measure, Impact, DEFAULT_END_TIME};
use mpm_core::{GridMode, SimConfig, Simulation};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    let cell: f64 = a.get(1).map_or(Ok(2.12), |s| s.parse())?;
    let strategy = a.get(2).map_or(Ok(mpm_core::Strategy::DomainDecomposition), |s| s.parse())?;
    let threads: usize = a.get(3).map_or(Ok(2), |s| s.parse())?;
    let spacing: f64 = a.get(4).map_or(Ok(0.53), |s| s.parse())?;
    let (setup, geometry) = Impact { cell: cell * 1e-3, spacing: spacing * 1e-3, ..Default::default() }.setup()?;
    println!("{} particles", setup.particles.len());
    let config = SimConfig { strategy, grid_mode: GridMode::Adaptive, ..Default::default() };
    let pool = std::sync::Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build()?);
    let mut sim = Simulation::new(setup, config, pool)?;
    let t = std::time::Instant::now();
    while sim.time() < DEFAULT_END_TIME * (1.0 - 1e-12) {
        sim.step(DEFAULT_END_TIME - sim.time())?;
    }
    let f = measure(sim.particles(), &geometry);
    println!(
        "{} steps in {:.1} s, mean nodes {:.0}, failed {}",
        sim.steps(),
        t.elapsed().as_secs_f64(),
        sim.mean_nodes(),
        sim.particles().failed_count()
    );
    println!("{f:#?}");
    Ok(())
}
