//! The work counters on a case small enough to count by hand: a confined column of 1,024
//! particles (8 x 8 x 16, two per cell along each axis) on a fixed grid of 4 x 4 x 12 cells
//! (5 x 5 x 13 = 325 nodes), two steps. Every expected value below is worked out from the
//! strategies' splits, not from the code under test.

mod common;

use common::{confined_column, elastic_copper, pool};
use mpm_core::{SimConfig, Simulation, Strategy, Substage, Work};

const STEPS: u64 = 2;
const PARTICLES: u64 = 1024;
const NODES: u64 = 325;

fn run(strategy: Strategy, threads: usize, inject: f64) -> Simulation {
    let dx = 1e-3;
    let setup = confined_column(elastic_copper(), 4.0 * dx, 8.0 * dx, dx, |_| [0.0, 0.0, -50.0]);
    assert_eq!(setup.particles.len() as u64, PARTICLES);
    let config = SimConfig { strategy, inject_slowdown: inject, ..SimConfig::default() };
    let mut sim = Simulation::new(setup, config, pool(threads)).unwrap();
    assert_eq!(sim.stored_nodes() as u64, NODES);
    for _ in 0..STEPS {
        sim.step(f64::INFINITY).unwrap();
    }
    sim
}

fn w(particles: u64, scattered: u64, assembled: u64, updated: u64, part_bytes: u64) -> Work {
    Work {
        particles,
        nodes_scattered: scattered,
        nodes_assembled: assembled,
        nodes_updated: updated,
        part_bytes,
        atomic_bytes: 0,
    }
}

/// Array expansion on 2 workers: each scatters its half of the particles into a whole copy
/// of the 325 nodes (64-byte P2G and 32-byte re-map records), zero already (nothing written
/// but the scatter); the assembly splits the 325 nodes 162 / 163, reads both copies of its
/// range and clears the records the particles touched: in cell order worker 0's particles
/// are the cells of z < 4 (node layers z = 0-4, nodes 0-124 of 25 a layer), worker 1's those
/// of 4 <= z < 8 (layers 4-8, nodes 100-224), so the assembly of nodes 0-161 clears 125 + 62
/// records, that of nodes 162-324 clears 63; the node passes split the 65 node rows of 5
/// nodes 32 / 33 (160 / 165 nodes).
#[test]
fn array_expansion_counts_by_hand() {
    let c = run(Strategy::ArrayExpansion, 2, 0.0).work();
    assert_eq!(c.threads(), 2);
    let s = STEPS;
    for (worker, asm, cleared, upd) in [(0, 162, 125 + 62, 160), (1, 163, 63, 165)] {
        let want = [
            (Substage::Scatter, w(512 * s, NODES * s, 0, 0, 0)),
            (Substage::Assembly, w(0, 0, asm * s, 0, (2 * asm + cleared) * s * 64)),
            (Substage::GridUpdate, w(0, 0, 0, upd * s, 0)),
            (Substage::RemapScatter, w(512 * s, NODES * s, 0, 0, 0)),
            (Substage::RemapAssembly, w(0, 0, asm * s, upd * s, (2 * asm + cleared) * s * 32)),
            (Substage::StressUpdate, w(512 * s, 0, 0, 0, 0)),
        ];
        assert_eq!(c.workers[worker], want.into_iter().collect(), "worker {worker}");
    }
}

/// Domain decomposition on 2 workers: layout 2 x 1 x 1 cuts the 4 cells along x in two, so
/// each patch holds 512 particles and a sub-grid of 3 x 5 x 13 = 195 nodes (the face at x = 2
/// in both); the binning goes over each worker's 512-particle chunk twice (count, write);
/// each patch's 65 rows of 3 nodes are assembled 32 / 33 rows per worker (96 / 99 nodes,
/// twice: one phase per patch).
#[test]
fn domain_decomposition_counts_by_hand() {
    let c = run(Strategy::DomainDecomposition, 2, 0.0).work();
    let s = STEPS;
    let sub = 195;
    for (worker, asm, upd) in [(0, 2 * 96, 160), (1, 2 * 99, 165)] {
        let want = [
            (Substage::Binning, w(2 * 512 * s, 0, 0, 0, 0)),
            (Substage::Scatter, w(512 * s, sub * s, 0, 0, sub * s * 64)),
            (Substage::Assembly, w(0, 0, asm * s, 0, asm * s * 64)),
            (Substage::GridUpdate, w(0, 0, 0, upd * s, 0)),
            (Substage::RemapScatter, w(512 * s, sub * s, 0, 0, sub * s * 32)),
            (Substage::RemapAssembly, w(0, 0, asm * s, upd * s, asm * s * 32)),
            (Substage::StressUpdate, w(512 * s, 0, 0, 0, 0)),
        ];
        assert_eq!(c.workers[worker], want.into_iter().collect(), "worker {worker}");
    }
    // The patches' shared face: 390 sub-grid nodes against 325, so the traffic bound is
    // below 1 although both workers are loaded alike.
    let b = c.bound().unwrap();
    assert!(b.overhead > 0.0 && b.efficiency_bound < 1.0 && b.balance > 0.97, "{b:?}");
}

/// Block colouring on 2 workers: the grid of 4 x 4 x 12 cells has 192 blocks of one cell
/// (the rule: fewer than 8 x 64 x 2 blocks of 4 or 2), so each colour holds the cells of one
/// parity, 2 x 2 x 6 = 24 slots, the first 16 of them (z < 8) holding 8 particles each; the
/// quantile cut of each phase falls after slot 8 (64 particles each), so each worker
/// scatters 8 x 64 = 512 particles a scatter; the binning goes over each worker's
/// 512-particle chunk twice; the zeroing splits the 325 global records 162 / 163. Nothing
/// else: no copies, no assembly. The traffic bound is the serial traffic's less the binning.
#[test]
fn colour_counts_by_hand() {
    let c = run(Strategy::Colour, 2, 0.0).work();
    let s = STEPS;
    for (worker, zeroed, upd) in [(0, 162, 160), (1, 163, 165)] {
        let want = [
            (Substage::Binning, w(2 * 512 * s, 0, 0, 0, 0)),
            (Substage::Scatter, w(512 * s, zeroed * s, 0, 0, 0)),
            (Substage::GridUpdate, w(0, 0, 0, upd * s, 0)),
            (Substage::RemapScatter, w(512 * s, zeroed * s, 0, 0, 0)),
            (Substage::RemapAssembly, w(0, 0, 0, upd * s, 0)),
            (Substage::StressUpdate, w(512 * s, 0, 0, 0, 0)),
        ];
        assert_eq!(c.workers[worker], want.into_iter().collect(), "worker {worker}");
    }
    let b = c.bound().unwrap();
    let binning = 2 * PARTICLES * s * mpm_core::work::particle_bytes(Substage::Binning);
    assert_eq!(b.worker_bytes.iter().sum::<u64>(), b.serial_bytes + binning, "{b:?}");
    assert!(b.balance > 0.99 && b.efficiency_bound > 0.95, "{b:?}");
}

/// Atomic adds on 2 workers: each scatters its 512-particle chunk straight into the global
/// arrays, every particle's 8 records read and written by the atomic additions (64-byte
/// P2G and 32-byte re-map records); the zeroing splits the 325 global records 162 / 163;
/// no binning, no copies, no assembly.
#[test]
fn atomic_counts_by_hand() {
    let c = run(Strategy::Atomic, 2, 0.0).work();
    let s = STEPS;
    let atomic = |work: Work, record: u64| Work { atomic_bytes: 512 * s * 8 * 2 * record, ..work };
    for (worker, zeroed, upd) in [(0, 162, 160), (1, 163, 165)] {
        let want = [
            (Substage::Scatter, atomic(w(512 * s, zeroed * s, 0, 0, 0), 64)),
            (Substage::GridUpdate, w(0, 0, 0, upd * s, 0)),
            (Substage::RemapScatter, atomic(w(512 * s, zeroed * s, 0, 0, 0), 32)),
            (Substage::RemapAssembly, w(0, 0, 0, upd * s, 0)),
            (Substage::StressUpdate, w(512 * s, 0, 0, 0, 0)),
        ];
        assert_eq!(c.workers[worker], want.into_iter().collect(), "worker {worker}");
    }
    let b = c.bound().unwrap();
    assert_eq!(b.worker_bytes.iter().sum::<u64>(), b.serial_bytes + PARTICLES * s * 8 * 2 * (64 + 32), "{b:?}");
}

/// The serial strategy's counts are exactly the serial traffic `W_1` (bound 1); array
/// expansion on one worker pays its copy and assembly; every count is the same however often
/// the run is repeated, and the injected slowdown changes neither the counts nor a bit of
/// the state.
#[test]
fn serial_counts_are_the_reference_and_counts_repeat() {
    let serial = run(Strategy::Serial, 1, 0.0).work();
    let s = STEPS;
    let want = [
        (Substage::Scatter, w(PARTICLES * s, NODES * s, 0, 0, 0)),
        (Substage::GridUpdate, w(0, 0, 0, NODES * s, 0)),
        (Substage::RemapScatter, w(PARTICLES * s, NODES * s, 0, 0, 0)),
        (Substage::RemapAssembly, w(0, 0, 0, NODES * s, 0)),
        (Substage::StressUpdate, w(PARTICLES * s, 0, 0, 0, 0)),
    ];
    assert_eq!(serial.workers, vec![want.into_iter().collect()]);
    let b = serial.bound().unwrap();
    assert_eq!(b.worker_bytes, vec![b.serial_bytes]);
    assert_eq!(b.efficiency_bound, 1.0);
    let ae1 = run(Strategy::ArrayExpansion, 1, 0.0).work().bound().unwrap();
    assert_eq!(ae1.serial_bytes, b.serial_bytes, "W_1 follows from any strategy's counts");
    assert!(ae1.efficiency_bound < 1.0 && ae1.overhead > 0.0, "{ae1:?}");

    let plain = run(Strategy::DomainDecomposition, 2, 0.0);
    let injected = run(Strategy::DomainDecomposition, 2, 0.3);
    assert_eq!(plain.work(), injected.work(), "injected work is not counted");
    assert_eq!(plain.particles().x, injected.particles().x, "the state is bitwise the same");
    assert_eq!(plain.particles().stress, injected.particles().stress);
    assert!(injected.injected_seconds().is_some_and(|t| t > 0.0));
    assert_eq!(plain.injected_seconds(), None);
    assert_eq!(run(Strategy::DomainDecomposition, 1, 0.3).injected_seconds(), None, "one worker: nothing to add");
}

/// An injected slowdown outside [0, 1) is refused.
#[test]
fn a_bad_injection_is_refused() {
    let dx = 1e-3;
    for f in [1.0, -0.1, f64::NAN] {
        let setup = confined_column(elastic_copper(), 4.0 * dx, 8.0 * dx, dx, |_| [0.0; 3]);
        let config = SimConfig { strategy: Strategy::DomainDecomposition, inject_slowdown: f, ..SimConfig::default() };
        let err = Simulation::new(setup, config, pool(2)).err().unwrap().to_string();
        assert!(err.contains("injected slowdown"), "{err}");
    }
}
