//! Criterion micro-benchmarks of the solver's kernels on the Taylor bar:
#![allow(missing_docs)] // criterion_group! generates undocumented items
//! locating the particles (cells and local coordinates), P2G scatter, the gather fused with the re-map scatter, stress update (serial, Model 1,
//! at the widest SIMD level of the CPU), and the parallel strategies'
//! own work: AE's P2G scatter with its assembly, DD binning and DD assembly (Model 2, 2
//! threads). The parallel
//! kernels run as phases of one parallel region of a `Team`, as in the solver's step.
//!
//! `cargo bench -p mpm-core --bench kernels` (the `bench` profile inherits `release`).

use criterion::{criterion_group, criterion_main, BatchSize, Criterion, Throughput};
use mpm_core::locate::Located;
use mpm_core::material::Eos;
use mpm_core::parallel::{Exec, Team};
use mpm_core::scenario::taylor::TaylorBar;
use mpm_core::strategy::{array_expansion, serial, DomainDecomposition, ScatterStrategy};
use mpm_core::{transfer, NodeIndex, SimConfig, Simulation};
use std::hint::black_box;
use std::sync::Arc;
use std::time::{Duration, Instant};

/// A simulation of `model` after a few steps, so nodes and stresses are not trivial.
fn warmed(model: u8) -> Simulation {
    let setup = TaylorBar { model, ..Default::default() }.setup().unwrap();
    let pool = Arc::new(rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap());
    let mut sim = Simulation::new(setup, SimConfig::default(), pool).unwrap();
    for _ in 0..5 {
        sim.step(f64::INFINITY).unwrap();
    }
    sim
}

fn serial_kernels(c: &mut Criterion) {
    let sim = warmed(1);
    let geom = *sim.geom();
    let particles = sim.particles().clone();
    let n = particles.len();
    let mut g = c.benchmark_group("model1-serial");
    g.throughput(Throughput::Elements(n as u64));
    g.sample_size(20);

    let index = NodeIndex::of(&geom, None);
    let mut out = vec![[0.0; 8]; geom.num_nodes()];
    let simd = mpm_core::SimdLevel::detected();
    let mut located = Located::default();
    g.bench_function("locate", |b| b.iter(|| located.locate(&Exec::serial(), &geom, black_box(&particles.x), simd)));
    let (particles, located) = (&particles, &located);
    let p2g = transfer::P2g::<false> { geom: &geom, particles, located, body_force: [0.0; 3], simd };
    g.bench_function("p2g_scatter", |b| b.iter(|| serial::scatter(&index, n, &mut out, black_box(&p2g))));

    let kin = sim.nodes().kin.clone();
    let mut v = particles.v.clone();
    let mut remap = vec![[0.0; 4]; geom.num_nodes()];
    g.bench_function("gather_remap_scatter", |b| {
        b.iter(|| {
            let m = &particles.mass;
            transfer::gather_remap_serial(&geom, &index, black_box(&kin), located, m, &mut v, 0.0, &mut remap)
        })
    });

    let consts = *sim.point_consts();
    let Eos::MieGruneisen(eos) = sim.material().eos else { unreachable!("copper uses Mie-Grüneisen") };
    let mut partials = vec![Default::default(); 1];
    g.bench_function("stress_update", |b| {
        b.iter_batched_ref(
            || particles.clone(),
            |p| {
                transfer::update(
                    &Exec::serial(),
                    &geom,
                    &index,
                    located,
                    sim.nodes(),
                    p,
                    &consts,
                    &eos,
                    1e-9,
                    &mut partials,
                    mpm_core::SimdLevel::detected(),
                )
            },
            BatchSize::LargeInput,
        )
    });
    g.finish();
}

/// Time `iters` runs of `kernel` as phases of one region of `team` (workers awake between
/// phases, as in a step).
fn in_region(team: &Team, iters: u64, mut kernel: impl FnMut(&Exec<'_>) + Send) -> Duration {
    team.region(|exec| {
        let start = Instant::now();
        for _ in 0..iters {
            kernel(exec);
        }
        start.elapsed()
    })
    .expect("one region of the team at a time")
}

fn strategy_kernels(c: &mut Criterion) {
    let sim = warmed(2);
    let geom = *sim.geom();
    let x = sim.particles().x.clone();
    let threads = 2;
    let team = Team::new(Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap()));
    let nn = geom.num_nodes();
    let mut g = c.benchmark_group("model2-2threads");
    g.sample_size(20);

    // AE's P2G round trip: each worker's half of the particles into its copy, then the
    // copies summed (and cleared for the next scatter), as in a step.
    let mut global = vec![[0.0; 8]; nn];
    let index = NodeIndex::of(&geom, None);
    let particles = sim.particles();
    let simd = mpm_core::SimdLevel::detected();
    let mut located = Located::default();
    located.locate(&Exec::serial(), &geom, &particles.x, simd);
    let p2g = transfer::P2g::<false> { geom: &geom, particles, located: &located, body_force: [0.0; 3], simd };
    let mut copies = mpm_core::grid::Records::<8>::zeroed(threads * nn);
    g.throughput(Throughput::Elements(x.len() as u64));
    g.bench_function("ae_p2g_scatter_assembly", |b| {
        b.iter_custom(|iters| {
            in_region(&team, iters, |exec| {
                array_expansion::scatter(exec, nn, &index, x.len(), &mut copies, black_box(&p2g));
                array_expansion::assemble(exec, &mut global, &mut copies);
            })
        })
    });

    let mut dd = DomainDecomposition::new(threads);
    g.throughput(Throughput::Elements(x.len() as u64));
    g.bench_function("dd_binning", |b| {
        b.iter_custom(|iters| in_region(&team, iters, |exec| dd.prepare(exec, &geom, None, black_box(&x))))
    });

    let mut subgrids = vec![[1.0; 8]; dd.subgrid_nodes()];
    g.throughput(Throughput::Elements(nn as u64));
    g.bench_function("dd_assembly", |b| {
        b.iter_custom(|iters| {
            in_region(&team, iters, |exec| {
                dd.assemble(exec, &geom, &NodeIndex::of(&geom, None), &mut global, black_box(&mut subgrids))
            })
        })
    });
    g.finish();
}

criterion_group!(benches, serial_kernels, strategy_kernels);
criterion_main!(benches);
