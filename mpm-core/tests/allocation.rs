//! The time step does not allocate in steady state. A counting global allocator checks it:
//! the serial step allocates nothing at all; the parallel steps allocate only rayon's
//! per-broadcast job lists, a count that does not depend on the problem size.

use mpm_core::scenario::taylor::TaylorBar;
use mpm_core::{GridMode, SimConfig, Simulation, Strategy};
use std::alloc::{GlobalAlloc, Layout, System};
use std::sync::atomic::{AtomicUsize, Ordering};

struct Counting;

static ALLOCATIONS: AtomicUsize = AtomicUsize::new(0);

// SAFETY: forwards to the system allocator unchanged; only counts calls.
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        // SAFETY: same contract as the caller's.
        unsafe { System.dealloc(ptr, layout) }
    }
    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.fetch_add(1, Ordering::Relaxed);
        // SAFETY: same contract as the caller's.
        unsafe { System.realloc(ptr, layout, new_size) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_per_step(model: u8, strategy: Strategy, threads: usize, grid: GridMode) -> f64 {
    let setup = TaylorBar { model, ..Default::default() }.setup().unwrap();
    // Sorts into cell order before steps 1, 8 and 15: the window below holds two of them.
    let config = SimConfig { strategy, grid_mode: grid, sort_every: SORT_EVERY, ..Default::default() };
    let pool = std::sync::Arc::new(rayon::ThreadPoolBuilder::new().num_threads(threads).build().unwrap());
    let mut sim = Simulation::new(setup, config, pool).unwrap();
    let warmup = 5;
    for _ in 0..warmup {
        sim.step(f64::INFINITY).unwrap();
    }
    let before = ALLOCATIONS.load(Ordering::Relaxed);
    // Across sorts into cell order: the sorts after the first allocate nothing either.
    let steps = 10;
    assert!((warmup..warmup + steps).any(|s| s % SORT_EVERY == 0));
    for _ in 0..steps {
        sim.step(f64::INFINITY).unwrap();
    }
    (ALLOCATIONS.load(Ordering::Relaxed) - before) as f64 / steps as f64
}

/// The sort interval of these runs (shorter than the default, so that the window of
/// steady steps holds sorts).
const SORT_EVERY: u64 = 7;

#[test]
fn steady_state_steps_do_not_allocate() {
    // Fixed, adaptive and sparse grids, serial: not a single allocation.
    assert_eq!(allocations_per_step(1, Strategy::Serial, 1, GridMode::Fixed), 0.0);
    assert_eq!(allocations_per_step(1, Strategy::Serial, 1, GridMode::Adaptive), 0.0);
    assert_eq!(allocations_per_step(1, Strategy::Serial, 1, GridMode::Sparse), 0.0);
    // Parallel: a step is one parallel region (`Team::region`, one rayon broadcast), whose
    // job list is the one allocation, whatever the strategy, threads and model size.
    for (strategy, threads) in [
        (Strategy::ArrayExpansion, 2),
        (Strategy::DomainDecomposition, 2),
        (Strategy::DomainDecomposition, 4),
        (Strategy::DdBalanced, 2),
        (Strategy::DdBalanced, 8),
        (Strategy::Colour, 2),
        (Strategy::Colour, 8),
        (Strategy::Atomic, 2),
    ] {
        assert_eq!(allocations_per_step(1, strategy, threads, GridMode::Sparse), 1.0, "{strategy} x{threads}, sparse");
        let small = allocations_per_step(1, strategy, threads, GridMode::Fixed);
        let large = allocations_per_step(2, strategy, threads, GridMode::Fixed);
        println!("{strategy} x{threads}: {small} allocations/step (Model 1), {large} (Model 2)");
        assert_eq!(small, 1.0, "{strategy} x{threads}: {small} allocations per step");
        assert_eq!(large, 1.0, "{strategy} x{threads}: allocations must not scale with the problem");
    }
}
