//! Run a Taylor bar model and print its figures: `cargo run --profile o3 --example taylor_quick -- MODEL STRATEGY THREADS [STEPS]`.
use mpm_core::{
    scenario::taylor::{measure, TaylorBar},
    SimConfig, Simulation,
};
fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    let model: u8 = a.get(1).map_or(Ok(1), |s| s.parse())?;
    let strategy = a.get(2).map_or(Ok(mpm_core::Strategy::Serial), |s| s.parse())?;
    let threads: usize = a.get(3).map_or(Ok(1), |s| s.parse())?;
    let max_steps: u64 = a.get(4).map_or(Ok(u64::MAX), |s| s.parse())?;
    let setup = TaylorBar { model, ..Default::default() }.setup()?;
    let spacing = setup.spacing;
    let pool = std::sync::Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build()?);
    let mut sim = Simulation::new(setup, SimConfig { strategy, ..Default::default() }, pool)?;
    let t = std::time::Instant::now();
    while sim.time() < 40e-6 * (1.0 - 1e-12) && sim.steps() < max_steps {
        sim.step(40e-6 - sim.time())?;
    }
    let wall = t.elapsed().as_secs_f64();
    let f = measure(sim.particles(), spacing);
    let n = sim.particles().len() as f64 * sim.steps() as f64;
    let tm = sim.times();
    println!(
        "steps {} t {:.3e} dt0 {:.3e} wall {:.2}s  ns/pstep {:.1} (grid {:.1} particle {:.1})",
        sim.steps(),
        sim.time(),
        sim.dt_first(),
        wall,
        wall * 1e9 / n,
        tm.grid_stage() * 1e9 / n,
        tm.particle_stage() * 1e9 / n
    );
    for (k, v) in tm.named() {
        print!("{k}={:.1} ", v * 1e9 / n);
    }
    println!();
    println!(
        "length {:.4} mm face {:.4} mm KE {:.4e}/{:.4e} IE {:.4e}",
        f.length * 1e3,
        f.face_diameter * 1e3,
        sim.diagnostics().kinetic,
        sim.initial().kinetic,
        sim.diagnostics().internal
    );
    Ok(())
}
