//! Noise that can be seen: what each worker thread got of the wall time, from the kernel.
//!
//! * A thread's CPU time (`clock_gettime(CLOCK_THREAD_CPUTIME_ID)`: user and system time of
//!   the calling thread) and its context switches (`getrusage(RUSAGE_THREAD)`: voluntary,
//!   when it waited or yielded; involuntary, when the scheduler took its CPU away), read by
//!   each worker itself in one [`rayon::ThreadPool::broadcast`] ([`pool_usage`]).
//! * The hypervisor's steal per CPU, from `/proc/stat` ([`StatSnapshot`]; the harness uses
//!   the same reader for its host watch).
//!
//! [`UsageMeter`] takes both at the start and end of each measured span (a run's stepping
//! loop, a paired run's blocks of one solver) and gives a [`NoiseReport`]: per worker its
//! CPU time over the spans' wall time. During a step every worker works or waits actively
//! at the phase barriers (spinning, then yielding: both CPU time), so a share well below 1
//! means the worker was kept off its CPU by something outside the run: another process or
//! the hypervisor. (An SMT sibling's load or a throttled clock do not show here: those are
//! the noise that cannot be seen.)

use mpm_spec::summary::{NoiseReport, WorkerUsage};
use rayon::ThreadPool;
use std::collections::BTreeMap;
use std::time::Instant;

/// What the kernel says one thread has used so far.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ThreadUsage {
    /// CPU time, user and system (s).
    pub cpu_s: f64,
    /// Voluntary context switches.
    pub voluntary: u64,
    /// Involuntary context switches.
    pub involuntary: u64,
}

impl ThreadUsage {
    /// The calling thread's usage now (`None` when the kernel does not say).
    pub fn now() -> Option<Self> {
        let mut ts = libc::timespec { tv_sec: 0, tv_nsec: 0 };
        // SAFETY: `ts` is a valid, writable timespec; the clock id is a constant the kernel
        // knows (the calling thread's CPU-time clock).
        let rc = unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut ts) };
        if rc != 0 {
            return None;
        }
        // SAFETY: rusage is a plain struct of integers, for which all zeroes is a valid value.
        let mut ru: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: `ru` is a valid, writable rusage; RUSAGE_THREAD asks for the calling thread.
        let rc = unsafe { libc::getrusage(libc::RUSAGE_THREAD, &mut ru) };
        if rc != 0 {
            return None;
        }
        Some(Self {
            cpu_s: ts.tv_sec as f64 + ts.tv_nsec as f64 * 1e-9,
            voluntary: u64::try_from(ru.ru_nvcsw).unwrap_or(0),
            involuntary: u64::try_from(ru.ru_nivcsw).unwrap_or(0),
        })
    }

    /// `later - self`.
    fn until(&self, later: &Self) -> Self {
        Self {
            cpu_s: (later.cpu_s - self.cpu_s).max(0.0),
            voluntary: later.voluntary.saturating_sub(self.voluntary),
            involuntary: later.involuntary.saturating_sub(self.involuntary),
        }
    }

    fn add(&mut self, o: &Self) {
        self.cpu_s += o.cpu_s;
        self.voluntary += o.voluntary;
        self.involuntary += o.involuntary;
    }
}

/// Every worker's usage now, in worker order, each read by the worker itself.
pub fn pool_usage(pool: &ThreadPool) -> Vec<Option<ThreadUsage>> {
    pool.broadcast(|_| ThreadUsage::now())
}

/// Accumulated CPU time of one CPU (or all), in clock ticks.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct CpuTimes {
    /// Not idle and not waiting for I/O.
    pub busy: u64,
    /// Everything (steal included).
    pub total: u64,
    /// Stolen by the hypervisor.
    pub steal: u64,
}

/// One reading of `/proc/stat`: CPU times of all CPUs and of each, runnable tasks.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct StatSnapshot {
    /// The `cpu` line.
    pub all: CpuTimes,
    /// The `cpuN` lines.
    pub cpus: BTreeMap<usize, CpuTimes>,
    /// `procs_running`: runnable tasks, the reader included.
    pub procs_running: u32,
}

/// Parse `/proc/stat` (`None` when it has no `cpu` line).
pub fn parse_proc_stat(text: &str) -> Option<StatSnapshot> {
    let mut snap = StatSnapshot::default();
    let mut seen_all = false;
    for line in text.lines() {
        let mut it = line.split_whitespace();
        let Some(name) = it.next() else { continue };
        if name == "procs_running" {
            snap.procs_running = it.next().and_then(|v| v.parse().ok()).unwrap_or(0);
        } else if let Some(id) = name.strip_prefix("cpu") {
            // user nice system idle iowait irq softirq steal (guest time is inside user).
            let v: Vec<u64> = it.take(8).map(|x| x.parse().unwrap_or(0)).collect();
            let get = |i: usize| v.get(i).copied().unwrap_or(0);
            let total: u64 = v.iter().sum();
            let t = CpuTimes { busy: total.saturating_sub(get(3) + get(4)), total, steal: get(7) };
            if id.is_empty() {
                snap.all = t;
                seen_all = true;
            } else if let Ok(n) = id.parse() {
                snap.cpus.insert(n, t);
            }
        }
    }
    seen_all.then_some(snap)
}

impl StatSnapshot {
    /// This host now (`None` without `/proc/stat`).
    pub fn read() -> Option<Self> {
        parse_proc_stat(&std::fs::read_to_string("/proc/stat").ok()?)
    }

    /// Fraction of the CPU time that the hypervisor stole between `self` and `later`.
    pub fn steal_since(&self, later: &Self) -> Option<f64> {
        let dt = later.all.total.checked_sub(self.all.total)?;
        (dt > 0).then(|| later.all.steal.saturating_sub(self.all.steal) as f64 / dt as f64)
    }

    /// Ticks of CPU `cpu` between `self` and `later`: (stolen, all).
    pub fn cpu_ticks_since(&self, later: &Self, cpu: usize) -> Option<(u64, u64)> {
        let (a, b) = (self.cpus.get(&cpu)?, later.cpus.get(&cpu)?);
        Some((b.steal.saturating_sub(a.steal), b.total.checked_sub(a.total)?))
    }

    /// Mean busy fraction of `cpus` (all CPUs when empty) between `self` and `later`.
    pub fn busy_since(&self, later: &Self, cpus: &[usize]) -> Option<f64> {
        let ids: Vec<usize> = if cpus.is_empty() { self.cpus.keys().copied().collect() } else { cpus.to_vec() };
        let fr: Vec<f64> = ids
            .iter()
            .filter_map(|c| {
                let (a, b) = (self.cpus.get(c)?, later.cpus.get(c)?);
                let dt = b.total.checked_sub(a.total)?;
                (dt > 0).then(|| b.busy.saturating_sub(a.busy) as f64 / dt as f64)
            })
            .collect();
        (!fr.is_empty()).then(|| fr.iter().sum::<f64>() / fr.len() as f64)
    }
}

/// A span being measured: its start.
struct Open {
    t0: Instant,
    usage: Vec<Option<ThreadUsage>>,
    stat: Option<StatSnapshot>,
}

/// The usage of a pool's workers over one or more spans ([`UsageMeter::begin`] ..
/// [`UsageMeter::end`]), summed.
pub struct UsageMeter {
    /// The CPU of each worker when pinned (its steal is that CPU's), else empty.
    cpus: Vec<usize>,
    wall_s: f64,
    /// Per worker, the usage summed over the spans (`None` once a reading failed).
    used: Vec<Option<ThreadUsage>>,
    /// Per worker, steal and all ticks of its CPU over the spans.
    ticks: Vec<(u64, u64)>,
    open: Option<Open>,
}

impl UsageMeter {
    /// A meter for a pool of `workers` workers, pinned to `cpus` (worker order; empty when
    /// not pinned).
    pub fn new(workers: usize, cpus: &[usize]) -> Self {
        Self {
            cpus: cpus.to_vec(),
            wall_s: 0.0,
            used: vec![Some(ThreadUsage::default()); workers],
            ticks: vec![(0, 0); workers],
            open: None,
        }
    }

    /// Start a span (outside the timed work: one broadcast and a read of `/proc/stat`).
    pub fn begin(&mut self, pool: &ThreadPool) {
        let stat = if self.cpus.is_empty() { None } else { StatSnapshot::read() };
        let usage = pool_usage(pool);
        self.open = Some(Open { t0: Instant::now(), usage, stat });
    }

    /// End the span begun last.
    pub fn end(&mut self, pool: &ThreadPool) {
        let Some(open) = self.open.take() else { return };
        let wall = open.t0.elapsed().as_secs_f64();
        let usage = pool_usage(pool);
        let stat = if self.cpus.is_empty() { None } else { StatSnapshot::read() };
        self.wall_s += wall;
        for (w, sum) in self.used.iter_mut().enumerate() {
            match (sum.as_mut(), open.usage.get(w).copied().flatten(), usage.get(w).copied().flatten()) {
                (Some(s), Some(a), Some(b)) => s.add(&a.until(&b)),
                _ => *sum = None,
            }
        }
        if let (Some(a), Some(b)) = (&open.stat, &stat) {
            for (w, t) in self.ticks.iter_mut().enumerate() {
                if let Some((s, all)) = self.cpus.get(w).and_then(|&c| a.cpu_ticks_since(b, c)) {
                    t.0 += s;
                    t.1 += all;
                }
            }
        }
    }

    /// The report over every span measured, flagged below `threshold` (`None` when nothing
    /// was measured or a worker's usage could not be read).
    pub fn report(&self, threshold: f64) -> Option<NoiseReport> {
        if self.wall_s <= 0.0 {
            return None;
        }
        let workers = self
            .used
            .iter()
            .zip(&self.ticks)
            .map(|(u, &(steal, all))| {
                let u = (*u)?;
                Some(WorkerUsage {
                    cpu_s: u.cpu_s,
                    cpu_share: u.cpu_s / self.wall_s,
                    involuntary_switches: u.involuntary,
                    voluntary_switches: u.voluntary,
                    steal_frac: (all > 0).then(|| steal as f64 / all as f64),
                })
            })
            .collect::<Option<Vec<_>>>()?;
        Some(NoiseReport::new(self.wall_s, workers, threshold))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    const STAT: &str = "cpu  100 0 50 800 10 0 0 40 0 0\ncpu0 60 0 30 400 5 0 0 20 0 0\n\
        cpu1 40 0 20 400 5 0 0 20 0 0\nintr 1 2 3\nprocs_running 3\nprocs_blocked 0\n";

    #[test]
    fn proc_stat_is_parsed() {
        let s = parse_proc_stat(STAT).unwrap();
        assert_eq!(s.all, CpuTimes { busy: 190, total: 1000, steal: 40 });
        assert_eq!(s.cpus[&0], CpuTimes { busy: 110, total: 515, steal: 20 });
        assert_eq!(s.procs_running, 3);
        assert!(parse_proc_stat("intr 1\n").is_none());
        let mut later = s.clone();
        later.all = CpuTimes { busy: 290, total: 1200, steal: 60 };
        later.cpus.insert(0, CpuTimes { busy: 210, total: 615, steal: 20 });
        later.cpus.insert(1, CpuTimes { busy: 80, total: 585, steal: 30 });
        assert_eq!(s.steal_since(&later), Some(0.1));
        assert_eq!(s.busy_since(&later, &[0]), Some(1.0));
        assert_eq!(s.busy_since(&later, &[]), Some(0.5));
        assert_eq!(s.busy_since(&later, &[7]), None);
        assert_eq!(s.cpu_ticks_since(&later, 1), Some((10, 100)));
        assert_eq!(s.cpu_ticks_since(&later, 7), None);
        assert_eq!(s.steal_since(&s), None, "no time passed");
    }

    /// A thread that burns CPU sees its CPU time advance; the meter sums a busy worker's
    /// time and an idle worker's nothing, and flags the idle one.
    #[test]
    fn cpu_time_is_the_threads_own() {
        let a = ThreadUsage::now().unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        while ThreadUsage::now().unwrap().cpu_s - a.cpu_s < 0.02 && Instant::now() < deadline {
            std::hint::black_box((0..1000u64).sum::<u64>());
        }
        assert!(ThreadUsage::now().unwrap().cpu_s - a.cpu_s >= 0.02, "20 ms of spinning is CPU time");

        let pool = rayon::ThreadPoolBuilder::new().num_threads(2).build().unwrap();
        assert_eq!(pool_usage(&pool).len(), 2);
        let mut m = UsageMeter::new(2, &[]);
        m.begin(&pool);
        // Worker 0 spins 50 ms of its own CPU time, worker 1 sleeps.
        pool.broadcast(|c| {
            if c.index() == 0 {
                let a = ThreadUsage::now().unwrap();
                while ThreadUsage::now().unwrap().cpu_s - a.cpu_s < 0.05 {}
            } else {
                std::thread::sleep(Duration::from_millis(20));
            }
        });
        m.end(&pool);
        let r = m.report(0.9).unwrap();
        assert!(r.workers[0].cpu_s >= 0.05, "{r:?}");
        assert!(r.workers[1].cpu_s < r.workers[0].cpu_s, "{r:?}");
        assert!(r.low_cpu_share && r.why().unwrap().contains("worker 1"), "{r:?}");
        assert!(r.workers.iter().all(|w| w.steal_frac.is_none()), "not pinned: no CPU to read steal of");
        assert!(UsageMeter::new(1, &[]).report(0.9).is_none(), "nothing measured");
    }
}
