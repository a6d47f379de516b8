//! Deterministic work counters: what each worker did in each sub-stage of the steps taken,
//! counted by the code that does it, and the bound on parallel efficiency that follows from
//! them alone ([`WorkCounts::bound`]), whatever the host.
//!
//! # What is counted
//!
//! Per worker and [`Substage`], summed over the steps ([`Work`]):
//!
//! * `particles`: particles the worker went over (P2G, the fused gather and re-map, the
//!   particle update; DD's binning passes, once per pass; the sparse grid's marking pass);
//! * `nodes_scattered`: node records of the worker's scatter target, which it scatters into:
//!   its copy of the whole grid (AE; zero already, cleared by the previous assembly), its
//!   patch's sub-grid (DD) or the global arrays (serial), both zeroed first;
//! * `nodes_assembled`: global node records the worker wrote in an assembly (AE: its range of
//!   the grid; DD: its rows of each patch, so a node on a face shared by two patches counts
//!   twice);
//! * `nodes_updated`: node records of the worker's part of the node passes (the grid update
//!   of Eq. 6, the re-map velocities);
//! * `part_bytes`: bytes of private grids (AE copies) or sub-grids (DD) the worker wrote
//!   (DD zeroing its sub-grid, in the scatters; AE clearing the records it summed that were
//!   not zero, in the assemblies) or read (summing them into the global arrays, in the
//!   assemblies);
//! * `atomic_bytes`: bytes the worker's atomic additions read and wrote in the global arrays
//!   (the atomic strategy: each particle's 8 node records, each value read and written by a
//!   compare-exchange, counted at the record's width; values that are zero are not sent, and
//!   at AVX-512 the P2G kernel sends a cell's run of particles at once, so fewer additions
//!   run than this counts).
//!
//! The colour strategy scatters straight into the global arrays, so it counts what serial
//! counts there (its workers' shares of the zeroing, the particles of their blocks) and its
//! binning passes, and nothing for copies or an assembly.
//!
//! The counts are made once per share of a phase from the sizes of the worker's part (a
//! chunk's length, a patch's particle count, a sub-grid's node count), never per particle,
//! so counting costs nothing measurable. They depend only on the particles and the grid,
//! so the same run gives the same counts on any machine, at any optimisation level, and a
//! change in them is a change of the algorithm (a lost balance, a grown assembly), not
//! noise. The injected slowdown ([`crate::SimConfig::inject_slowdown`]) is not work and is
//! not counted.
//!
//! # The bound
//!
//! Each count is weighted by the compulsory memory traffic it stands for, the bytes of the
//! roofline model ([`crate::roofline::COSTS`]): a particle by its sub-stage's particle bytes
//! (the binning, DD's or colour's: half of them per pass, as the table has its two passes
//! together), a scattered node record by the sub-stage's node bytes (zeroed, read and
//! written), an updated one by the node pass's, an assembled one by its record's size, plus
//! the part and atomic bytes. `W_w` is worker `w`'s sum; `W_1` what the serial solver moves
//! for the same steps (every particle once per particle pass, every stored node once per
//! node pass: from the same counts). Then
//!
//! ```text
//! efficiency <= W_1 / (T max_w W_w) = (1 - overhead) x balance,
//!     overhead = 1 - W_1 / sum_w W_w   (what the strategy adds: copies, sub-grid faces,
//!                                        assembly, binning, atomics)
//!     balance  = mean_w W_w / max_w W_w
//! ```
//!
//! a bound in the sense of a model (no barrier, no serial part, equal bandwidth per worker;
//! the colour strategy's 8 phases a scatter are counted together, so an uneven split within
//! a phase that evens out over the phases does not show):
//! the efficiency a perfect host would give the traffic, which the measured one can only
//! approach. The serial strategy's own counts give exactly `W_1` (tested).

use crate::parallel::{Counters, Exec, Tally as LaneTally, LANES};
use crate::roofline;
use crate::timers::Substage;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::sync::atomic::{AtomicU64, Ordering};

/// What one worker did in one sub-stage (over the steps counted). See the module docs.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Hash, Serialize, Deserialize)]
pub struct Work {
    /// Particles gone over.
    pub particles: u64,
    /// Node records of the scatter target zeroed and scattered into.
    pub nodes_scattered: u64,
    /// Global node records written by an assembly.
    pub nodes_assembled: u64,
    /// Node records of the node passes.
    pub nodes_updated: u64,
    /// Bytes of private grids or sub-grids written (scatter) or read (assembly).
    pub part_bytes: u64,
    /// Bytes of global records read and written by atomic additions.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub atomic_bytes: u64,
}

/// Whether `v` is 0 (a count left out of the JSON).
fn is_zero(v: &u64) -> bool {
    *v == 0
}

/// The counter lanes of a [`Work`].
const PARTICLES: usize = 0;
const SCATTERED: usize = 1;
const ASSEMBLED: usize = 2;
const UPDATED: usize = 3;
const PART_BYTES: usize = 4;
const ATOMIC_BYTES: usize = 5;
/// Lanes used of the [`LANES`] a worker has.
const WORK_LANES: usize = 6;
const _: () = assert!(WORK_LANES <= LANES);

impl Work {
    fn from_lanes(l: &[u64]) -> Self {
        Self {
            particles: l[PARTICLES],
            nodes_scattered: l[SCATTERED],
            nodes_assembled: l[ASSEMBLED],
            nodes_updated: l[UPDATED],
            part_bytes: l[PART_BYTES],
            atomic_bytes: l[ATOMIC_BYTES],
        }
    }

    /// The counter lanes, in [`Work::from_lanes`]'s order.
    fn lanes(&self) -> [u64; WORK_LANES] {
        let mut l = [0; WORK_LANES];
        l[PARTICLES] = self.particles;
        l[SCATTERED] = self.nodes_scattered;
        l[ASSEMBLED] = self.nodes_assembled;
        l[UPDATED] = self.nodes_updated;
        l[PART_BYTES] = self.part_bytes;
        l[ATOMIC_BYTES] = self.atomic_bytes;
        l
    }

    /// Whether nothing was counted.
    pub fn is_zero(&self) -> bool {
        *self == Work::default()
    }

    /// The sum of two counts.
    pub fn plus(&self, o: &Work) -> Work {
        Work {
            particles: self.particles + o.particles,
            nodes_scattered: self.nodes_scattered + o.nodes_scattered,
            nodes_assembled: self.nodes_assembled + o.nodes_assembled,
            nodes_updated: self.nodes_updated + o.nodes_updated,
            part_bytes: self.part_bytes + o.part_bytes,
            atomic_bytes: self.atomic_bytes + o.atomic_bytes,
        }
    }
}

/// How a phase's shares count their work: `Copy` and `Sync` (captured by the phase's
/// closure), one call per share and quantity, from the sizes of the share's part.
#[derive(Clone, Copy, Debug)]
pub struct Tally<'a>(LaneTally<'a>);

/// `usize` to `u64` (lossless on every target Rust supports here).
#[inline(always)]
fn n(x: usize) -> u64 {
    x as u64
}

impl<'a> Tally<'a> {
    /// The tally of `exec`'s phases (counting nothing when `exec` has no counters).
    pub fn of(exec: &Exec<'a>) -> Self {
        Self(exec.tally())
    }

    /// Worker `w` went over `count` particles.
    #[inline]
    pub fn particles(&self, w: usize, count: usize) {
        self.0.add(w, PARTICLES, n(count));
    }

    /// Worker `w` scattered into `records` node records of `record_bytes` bytes, which it
    /// zeroed first when they are a private grid or sub-grid of its own (`zeroed_private`:
    /// their bytes are part bytes).
    #[inline]
    pub fn scattered(&self, w: usize, records: usize, record_bytes: usize, zeroed_private: bool) {
        self.0.add(w, SCATTERED, n(records));
        if zeroed_private {
            self.0.add(w, PART_BYTES, n(records * record_bytes));
        }
    }

    /// Worker `w` wrote `records` global node records of `record_bytes` bytes in an assembly,
    /// reading or writing `part_records` records of private grids or sub-grids (AE: the
    /// records of every copy in its range, read, and those of them it cleared, written).
    #[inline]
    pub fn assembled(&self, w: usize, records: usize, part_records: usize, record_bytes: usize) {
        self.0.add(w, ASSEMBLED, n(records));
        self.0.add(w, PART_BYTES, n(part_records * record_bytes));
    }

    /// Worker `w` added to `records` global node records of `record_bytes` bytes by atomic
    /// additions (each record's values read and written once).
    #[inline]
    pub fn atomic(&self, w: usize, records: usize, record_bytes: usize) {
        self.0.add(w, ATOMIC_BYTES, n(2 * records * record_bytes));
    }

    /// Worker `w` went over `records` node records in a node pass.
    #[inline]
    pub fn updated(&self, w: usize, records: usize) {
        self.0.add(w, UPDATED, n(records));
    }
}

/// The work counters of a simulation: what the shares count in the current sub-stage
/// (`pending`, the executor's counters) and the totals per worker and sub-stage, into which
/// [`WorkMeter::close`] moves them at the end of each sub-stage. Allocated once.
#[derive(Debug)]
pub struct WorkMeter {
    pending: Counters,
    /// Per worker, per sub-stage ([`Substage::ALL`] order), the [`Work`] lanes. Written only
    /// by the driver between phases.
    totals: Box<[[[AtomicU64; WORK_LANES]; Substage::ALL.len()]]>,
}

impl WorkMeter {
    /// Zeroed counters for `workers` workers.
    pub fn new(workers: usize) -> Self {
        Self {
            pending: Counters::new(workers),
            totals: (0..workers).map(|_| std::array::from_fn(|_| std::array::from_fn(|_| AtomicU64::new(0)))).collect(),
        }
    }

    /// The counters the step's executor counts into ([`Exec::counting`]).
    pub fn pending(&self) -> &Counters {
        &self.pending
    }

    /// Book what was counted since the last close to sub-stage `s` (on the driver, between
    /// phases).
    pub fn close(&self, s: Substage) {
        for (w, row) in self.totals.iter().enumerate() {
            let lanes = self.pending.take(w);
            for (t, l) in row[s as usize].iter().zip(lanes) {
                if l != 0 {
                    t.fetch_add(l, Ordering::Relaxed);
                }
            }
        }
    }

    /// Add `saved`, the totals of a run this one continues ([`crate::Simulation::resume`]),
    /// worker by worker (a saved worker this meter lacks is dropped).
    pub fn restore(&self, saved: &WorkCounts) {
        for (row, stages) in self.totals.iter().zip(&saved.workers) {
            for (s, work) in stages {
                for (t, l) in row[*s as usize].iter().zip(work.lanes()) {
                    t.fetch_add(l, Ordering::Relaxed);
                }
            }
        }
    }

    /// The totals so far.
    pub fn counts(&self) -> WorkCounts {
        let workers = self
            .totals
            .iter()
            .map(|row| {
                Substage::ALL
                    .iter()
                    .map(|&s| {
                        let lanes: Vec<u64> = row[s as usize].iter().map(|a| a.load(Ordering::Relaxed)).collect();
                        (s, Work::from_lanes(&lanes))
                    })
                    .filter(|(_, w)| !w.is_zero())
                    .collect()
            })
            .collect();
        WorkCounts { workers }
    }
}

/// The work of every worker (worker order), per sub-stage (sub-stages without work left
/// out), over the steps counted.
#[derive(Clone, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct WorkCounts {
    /// One map per worker.
    pub workers: Vec<BTreeMap<Substage, Work>>,
}

/// The bound of [`WorkCounts::bound`] with its parts.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WorkBound {
    /// `W_1`: the bytes the serial solver moves for the same steps.
    pub serial_bytes: u64,
    /// `W_w` of every worker.
    pub worker_bytes: Vec<u64>,
    /// `mean W_w / max W_w` (1: every worker moved as much).
    pub balance: f64,
    /// `1 - W_1 / sum W_w`: the share of the traffic the strategy adds.
    pub overhead: f64,
    /// `W_1 / (T max W_w)`: the efficiency the traffic allows.
    pub efficiency_bound: f64,
}

/// The roofline table's bytes as an integer (every entry is a whole number of bytes).
fn whole(b: f64) -> u64 {
    debug_assert!(b >= 0.0 && b.fract() == 0.0, "{b} bytes");
    b as u64
}

/// Bytes a counted particle of sub-stage `s` stands for.
pub fn particle_bytes(s: Substage) -> u64 {
    let b = whole(roofline::cost(s).particle_bytes);
    // The binning's two passes are one entry of the table; each pass counts its particles.
    if s == Substage::Binning {
        b / 2
    } else {
        b
    }
}

/// Bytes a scattered (zeroed, read, written) or updated node record of `s` stands for: the
/// table's node bytes of the sub-stage.
pub fn node_bytes(s: Substage) -> u64 {
    whole(roofline::cost(s).node_bytes)
}

/// Bytes of a global record written by the assembly of sub-stage `s`.
pub fn assembled_record_bytes(s: Substage) -> u64 {
    let k = match s {
        Substage::Assembly => crate::grid::P2G_WIDTH,
        Substage::RemapAssembly => crate::grid::REMAP_WIDTH,
        _ => 0,
    };
    n(k * std::mem::size_of::<f64>())
}

impl Work {
    /// The bytes this work of sub-stage `s` stands for (see the module docs).
    pub fn bytes(&self, s: Substage) -> u64 {
        self.particles * particle_bytes(s)
            + (self.nodes_scattered + self.nodes_updated) * node_bytes(s)
            + self.nodes_assembled * assembled_record_bytes(s)
            + self.part_bytes
            + self.atomic_bytes
    }
}

impl WorkCounts {
    /// Workers counted.
    pub fn threads(&self) -> usize {
        self.workers.len()
    }

    /// Worker `w`'s work in sub-stage `s` (zero when it did none).
    pub fn get(&self, w: usize, s: Substage) -> Work {
        self.workers.get(w).and_then(|m| m.get(&s)).copied().unwrap_or_default()
    }

    /// Every worker's work in `s`, summed.
    pub fn stage_total(&self, s: Substage) -> Work {
        (0..self.threads()).fold(Work::default(), |a, w| a.plus(&self.get(w, s)))
    }

    /// Per sub-stage, every worker's bytes (worker order); sub-stages without work left out.
    pub fn bytes_by_stage(&self) -> BTreeMap<Substage, Vec<u64>> {
        Substage::ALL
            .iter()
            .map(|&s| (s, (0..self.threads()).map(|w| self.get(w, s).bytes(s)).collect::<Vec<u64>>()))
            .filter(|(_, v)| v.iter().any(|&b| b > 0))
            .collect()
    }

    /// `W_w`: every worker's bytes over all sub-stages.
    pub fn worker_bytes(&self) -> Vec<u64> {
        (0..self.threads()).map(|w| Substage::ALL.iter().map(|&s| self.get(w, s).bytes(s)).sum()).collect()
    }

    /// `W_1`: what the serial solver moves for the same steps: every particle once per
    /// particle pass (the marking pass, P2G, the gather and re-map, the update) and every
    /// stored node once per node pass (both scatters, the grid update, the re-map
    /// velocities), the stored nodes being those of the grid update's parts.
    pub fn serial_bytes(&self) -> u64 {
        use Substage::*;
        let particles: u64 = [GridFit, Scatter, RemapScatter, StressUpdate]
            .iter()
            .map(|&s| self.stage_total(s).particles * particle_bytes(s))
            .sum();
        let nodes = self.stage_total(GridUpdate).nodes_updated;
        let per_node: u64 = [Scatter, RemapScatter, GridUpdate, RemapAssembly].iter().map(|&s| node_bytes(s)).sum();
        particles + nodes * per_node
    }

    /// The efficiency the counted traffic allows, with its balance and overhead (`None`
    /// when nothing was counted).
    pub fn bound(&self) -> Option<WorkBound> {
        let w = self.worker_bytes();
        let max = w.iter().copied().max().filter(|&m| m > 0)?;
        let sum: u64 = w.iter().sum();
        let serial = self.serial_bytes();
        let t = w.len() as f64;
        Some(WorkBound {
            serial_bytes: serial,
            balance: sum as f64 / (t * max as f64),
            overhead: 1.0 - serial as f64 / sum as f64,
            efficiency_bound: serial as f64 / (t * max as f64),
            worker_bytes: w,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The table's entries the weights use are whole bytes.
    #[test]
    fn weights_are_whole_bytes() {
        for s in Substage::ALL {
            let c = roofline::cost(s);
            assert_eq!(c.particle_bytes.fract(), 0.0, "{s:?}");
            assert_eq!(c.node_bytes.fract(), 0.0, "{s:?}");
        }
        assert_eq!(particle_bytes(Substage::Binning) * 2, whole(roofline::cost(Substage::Binning).particle_bytes));
        assert_eq!(assembled_record_bytes(Substage::Assembly), 64);
        assert_eq!(assembled_record_bytes(Substage::RemapAssembly), 32);
    }

    /// Counts close into the sub-stage they were made in; the bound of a balanced pair
    /// without overhead is 1, of an unbalanced one the balance.
    #[test]
    fn closing_books_counts_to_their_stage() {
        let meter = WorkMeter::new(2);
        let exec = Exec::serial();
        let exec = exec.counting(meter.pending());
        let t = Tally::of(&exec);
        t.particles(0, 7);
        meter.close(Substage::Scatter);
        t.updated(0, 3);
        t.scattered(1, 5, 64, true);
        meter.close(Substage::GridUpdate);
        let c = meter.counts();
        assert_eq!(c.get(0, Substage::Scatter), Work { particles: 7, ..Work::default() });
        assert_eq!(c.get(0, Substage::GridUpdate), Work { nodes_updated: 3, ..Work::default() });
        assert_eq!(c.get(1, Substage::GridUpdate), Work { nodes_scattered: 5, part_bytes: 320, ..Work::default() });
        assert_eq!(c.workers[0].len(), 2, "sub-stages without work are left out");
        let even = WorkCounts {
            workers: vec![
                [(Substage::StressUpdate, Work { particles: 10, ..Work::default() })].into_iter().collect(),
                [(Substage::StressUpdate, Work { particles: 10, ..Work::default() })].into_iter().collect(),
            ],
        };
        let b = even.bound().unwrap();
        assert_eq!((b.balance, b.overhead, b.efficiency_bound), (1.0, 0.0, 1.0));
        let mut uneven = even.clone();
        uneven.workers[1].get_mut(&Substage::StressUpdate).unwrap().particles = 30;
        let b = uneven.bound().unwrap();
        assert_eq!(b.efficiency_bound, 40.0 / 60.0);
        assert_eq!(b.balance, b.efficiency_bound);
    }
}
