//! Building the JSON summary of one `mpm run`: [`build`] takes the run's configuration and
//! counts from the [`Simulation`], its timing from the program's clock and the solver's stage
//! timers, placement from the pinned pool, and the scenario's figures; [`finish`] adds what
//! is known only at the end (the ranks' reports and the exchange figures they give, the
//! workers' noise, a paired run's blocks, the process's peak memory `VmHWM`, read by
//! [`peak_rss_bytes`]). The type itself, [`Summary`], and the meaning of each figure are in
//! [`mpm_spec::summary`], shared with the harness: each figure is computed here, once, in
//! the function of its group.

use mpm_core::grid::Occupancy;
use mpm_core::scenario::impact::{CloudFigures, History};
use mpm_core::scenario::plate::{PlateGeometry, PlateResult};
use mpm_core::scenario::taylor;
use mpm_core::{Simulation, StageTimes, Substage};
use mpm_host::identity::provenance_of_this_process;
use mpm_host::pinning::PinnedPool;
use mpm_spec::summary::{
    figures, load_imbalance, Balance, CheckpointReport, EndReason, EnergyReport, EosKind, Figures, HistoryPoint,
    ImpactFigures, Memory, NoiseReport, PairedReport, PatchCounts, Physics, Pinning, PlateFigures, Progress,
    RankReport, ScenarioFigures, Size, StageRoofline, StageSeconds, Summary, TaylorFigures, WallContact, WorkReport,
    LENGTH_CONVENTION, PLATE_CONFIGURATION,
};
use mpm_spec::{OptLevel, RunSpec, ScenarioKind};
use std::collections::BTreeMap;

/// Cargo's `opt-level` of this build (`3`, `0`, ...).
pub const CARGO_OPT_LEVEL: &str = env!("MPM_OPT_LEVEL");
/// Cargo profile directory of this build (`o3`, `o0`, `release`, `debug`).
pub const PROFILE: &str = env!("MPM_PROFILE");
/// Version of this crate.
pub const VERSION: &str = env!("CARGO_PKG_VERSION");
/// Target triple of this build.
pub const TARGET: &str = env!("MPM_TARGET");

/// Records the energy history of a run of unknown length in bounded memory: keeps every
/// `stride`-th step, doubling the stride when too many points pile up, plus the latest.
/// Saved whole in a checkpoint (its serialised form).
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct HistoryRecorder {
    points: Vec<HistoryPoint>,
    stride: u64,
    latest: Option<HistoryPoint>,
    cap: usize,
}

impl Default for HistoryRecorder {
    fn default() -> Self {
        Self::new()
    }
}

impl HistoryRecorder {
    /// An empty recorder (keeps at most 4096 points before thinning).
    pub fn new() -> Self {
        Self { points: Vec::new(), stride: 1, latest: None, cap: 4096 }
    }

    /// Record a step's state (call with step 0 first, then every step in order).
    pub fn record(&mut self, p: HistoryPoint) {
        if p.step.is_multiple_of(self.stride) {
            self.points.push(p);
            if self.points.len() > self.cap {
                self.stride *= 2;
                let s = self.stride;
                self.points.retain(|q| q.step % s == 0);
            }
        }
        self.latest = Some(p);
    }

    /// About `target` samples evenly spaced in steps, always with the first and the last
    /// recorded step.
    pub fn finish(&self, target: usize) -> Vec<HistoryPoint> {
        let target = target.max(2);
        let n = self.points.len();
        let mut out: Vec<HistoryPoint> = if n <= target {
            self.points.clone()
        } else {
            let mut v: Vec<HistoryPoint> =
                (0..target).map(|i| self.points[(i * (n - 1) + (target - 1) / 2) / (target - 1)]).collect();
            v.dedup_by_key(|p| p.step);
            v
        };
        if let Some(l) = self.latest {
            if out.last().map(|p| p.step) != Some(l.step) {
                out.push(l);
            }
        }
        out
    }
}

/// Peak resident memory of this process (`VmHWM` in `/proc/self/status`), bytes.
pub fn peak_rss_bytes() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    parse_vm_hwm(&status)
}

/// Parse `VmHWM:   123456 kB` out of a `/proc/<pid>/status` text, in bytes.
pub fn parse_vm_hwm(status: &str) -> Option<u64> {
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let mut it = line["VmHWM:".len()..].split_whitespace();
    let value: u64 = it.next()?.parse().ok()?;
    let unit = match it.next() {
        Some("kB") | None => 1024,
        Some("mB") | Some("MB") => 1024 * 1024,
        Some(_) => return None,
    };
    Some(value * unit)
}

/// Wall-clock figures measured by the program around the stepping loop (over every process
/// that ran a part of it, for a run continued from a checkpoint).
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Timing {
    /// Whole stepping loop, VTU output excluded (s).
    pub wall_s: f64,
    /// Time spent writing snapshots and pictures and sampling histories (s).
    pub output_s: f64,
    /// Steps counted as warm-up (the first ones; at most the steps taken).
    pub warmup_steps: u64,
    /// Loop wall time at the end of the warm-up (s).
    pub warmup_wall_s: f64,
    /// The solver's stage timers at the end of the warm-up.
    pub warmup_times: StageTimes,
    /// Each worker's busy seconds at the end of the warm-up (`None`: serial strategy).
    pub warmup_busy: Option<Vec<f64>>,
}

/// What the program knows about a run besides the [`Simulation`] itself.
#[derive(Debug)]
pub struct RunContext<'a> {
    /// The run as asked for, resolved (the warm-up used included).
    pub spec: &'a RunSpec,
    /// Cells of the initial grid.
    pub cells: usize,
    /// Nodes of the initial grid.
    pub nodes: usize,
    /// Why the loop stopped.
    pub end_reason: EndReason,
    /// Loop timing.
    pub timing: &'a Timing,
    /// The pool and its workers' placement.
    pub pool: &'a PinnedPool,
    /// Cores available to the process.
    pub available_cores: usize,
    /// Whether the run has more workers than cores (or than distinct pinned CPUs).
    pub oversubscribed: bool,
    /// The CPU quota of the process's cgroup, CPUs of time per period (`None`: none set).
    pub cpu_quota: Option<f64>,
    /// Energy history samples.
    pub history: Vec<HistoryPoint>,
    /// Model label (`Model1`, `impact-h0.53mm-dx2.12mm`, ...).
    pub model_name: String,
    /// Failed particles at the end, over every rank.
    pub failed_particles: usize,
    /// Taylor bar: figures at `t = 0` and at the end.
    pub taylor: Option<(taylor::TaylorFigures, taylor::TaylorFigures)>,
    /// Impact: the debris cloud's figures at the end.
    pub cloud: Option<CloudFigures>,
    /// Impact: the cloud's history.
    pub cloud_history: Option<History>,
    /// Plate: the plate and the shock measurements (`None` when the front was not tracked
    /// long enough).
    pub plate: Option<(PlateGeometry, Option<PlateResult>)>,
    /// The program's arguments.
    pub command_line: Vec<String>,
    /// Wall-clock start of the run, seconds since the Unix epoch.
    pub started_unix_s: f64,
    /// Checkpoints written and restarts (`None`: neither).
    pub checkpoint: Option<CheckpointReport>,
}
/// Build the summary of a finished run from its simulation and what the program
/// measured (`ctx`). The ranks' reports, the workers' noise, a paired run's blocks and the
/// peak memory are added last, by [`finish`].
pub fn build(sim: &Simulation, ctx: RunContext<'_>) -> Summary {
    let mut s = configuration(sim, &ctx);
    s.figures = Figures {
        size: size(sim, &ctx),
        progress: progress(sim, &ctx),
        timing: timing(sim, ctx.timing),
        balance: balance(sim, ctx.timing),
        memory: Memory { model_memory_bytes: sim.memory_bytes(), ..Memory::default() },
        physics: physics(sim, &ctx),
        work: WorkReport::of(&sim.work()),
        checkpoint: ctx.checkpoint.clone(),
        injected_s: sim.injected_seconds(),
        cpu_quota: ctx.cpu_quota,
        scenario: scenario_figures(sim, &ctx),
        ..Figures::default()
    };
    s.model_name = ctx.model_name;
    s.command_line = ctx.command_line;
    s.provenance = Some(provenance_of_this_process());
    s
}

/// Complete `s` with what the program knows only at the very end ([`Summary::finish`]):
/// every rank's report (`None` at one rank), the workers' CPU time, a paired run's blocks,
/// and this process's peak memory, read now, after everything else.
pub fn finish(
    s: &mut Summary,
    ranks: Option<Vec<RankReport>>,
    noise: Option<NoiseReport>,
    paired: Option<PairedReport>,
) {
    s.finish(ranks, noise, paired, peak_rss_bytes());
}

/// The run as configured: spec, model, strategy, build, material, placement and settings.
fn configuration(sim: &Simulation, ctx: &RunContext<'_>) -> Summary {
    let cfg = sim.config();
    Summary {
        spec: Some(ctx.spec.clone()),
        model: ctx.spec.scenario.model(),
        strategy: cfg.strategy,
        threads: ctx.pool.pool.current_num_threads(),
        opt_level: OptLevel::of_cargo(CARGO_OPT_LEVEL).unwrap_or_default(),
        profile: PROFILE.to_string(),
        mpm_version: VERSION.to_string(),
        debug_assertions: cfg!(debug_assertions),
        target: TARGET.to_string(),
        grid_mode: cfg.grid_mode,
        eos: EosKind::of(&sim.material().eos),
        material: sim.material().name.clone(),
        cfl: cfg.cfl,
        wall: WallContact::of(&ctx.spec.scenario),
        velocity_m_s: ctx.spec.scenario.velocity(),
        end_time: ctx.spec.budget.end_time_s,
        step_limit: ctx.spec.budget.steps,
        pinning: Pinning {
            requested_cpus: ctx.pool.requested.clone(),
            observed_cpus: ctx.pool.observed_cpus(),
            worker_affinity: ctx.pool.affinities(),
            pinned: ctx.pool.pinned(),
            pinning_verified: ctx.pool.verified(),
            oversubscribed: ctx.oversubscribed,
            available_cores: ctx.available_cores,
        },
        bulk_viscosity: Some(cfg.bulk_viscosity),
        energy_rise_limit: cfg.energy_rise_limit.is_finite().then_some(cfg.energy_rise_limit),
        length_convention: ctx.taylor.map(|_| LENGTH_CONVENTION.to_string()),
        plate_configuration: ctx.plate.as_ref().map(|_| PLATE_CONFIGURATION.to_string()),
        started_unix_s: ctx.started_unix_s,
        inject_slowdown: ctx.spec.inject_slowdown,
        inject_step_slowdown: ctx.spec.inject_step_slowdown,
        ..Summary::default()
    }
}

/// The problem's size.
fn size(sim: &Simulation, ctx: &RunContext<'_>) -> Size {
    Size {
        particles: sim.total_particles(),
        cells: ctx.cells,
        nodes: ctx.nodes,
        mean_nodes: sim.mean_nodes(),
        final_nodes: sim.global_geom().num_nodes(),
        final_stored_nodes: Some(sim.stored_nodes()),
        // Only a process holding every particle can count the cells they occupy.
        final_occupancy: (sim.particles().len() == sim.total_particles())
            .then(|| Occupancy::of(sim.global_geom(), &sim.particles().x)),
        dx_m: sim.geom().dx,
    }
}

/// Steps, time steps and time reached.
fn progress(sim: &Simulation, ctx: &RunContext<'_>) -> Progress {
    let warmup = ctx.timing.warmup_steps.min(sim.steps());
    Progress {
        steps: sim.steps(),
        warmup_steps: warmup,
        steady_steps: sim.steps() - warmup,
        dt_first: sim.dt_first(),
        dt_next: sim.dt_next(),
        sim_time: sim.time(),
        end_reason: ctx.end_reason,
    }
}

/// Wall time, stage times and the steady state after the warm-up (see the module docs).
fn timing(sim: &Simulation, t: &Timing) -> figures::Timing {
    let particles = sim.total_particles();
    let steady_steps = sim.steps() - t.warmup_steps.min(sim.steps());
    let steady_times = sim.times().since(&t.warmup_times);
    let steady_wall = (t.wall_s - t.warmup_wall_s).max(0.0);
    let pstep = particles as f64 * steady_steps as f64;
    let (ns, rate) = if steady_steps > 0 && steady_wall > 0.0 {
        (Some(steady_wall * 1e9 / pstep), Some(pstep / steady_wall))
    } else {
        (None, None)
    };
    figures::Timing {
        wall_s: t.wall_s,
        output_s: t.output_s,
        grid_stage_s: sim.times().grid_stage(),
        particle_stage_s: sim.times().particle_stage(),
        substages: StageSeconds::from_times(sim.times()),
        steady_wall_s: steady_wall,
        steady_grid_stage_s: Some(steady_times.grid_stage()),
        steady_particle_stage_s: Some(steady_times.particle_stage()),
        steady_substages: StageSeconds::from_times(&steady_times),
        simd_level: Some(sim.simd_level()),
        roofline: (steady_steps > 0).then(|| roofline(sim, &steady_times, steady_steps)),
        steady_s_per_step: (steady_steps > 0).then(|| steady_wall / steady_steps as f64),
        ns_per_particle_step: ns,
        particle_steps_per_s: rate,
    }
}

/// Per sub-stage, the bytes and flops per particle-step of the steady state and the rates
/// they ran at.
fn roofline(sim: &Simulation, steady: &StageTimes, steady_steps: u64) -> BTreeMap<Substage, StageRoofline> {
    let work = sim.work();
    let ran = |st| !work.stage_total(st).is_zero();
    mpm_core::roofline::achieved(steady, sim.total_particles() as u64, sim.mean_nodes(), steady_steps, ran)
        .iter()
        .zip(Substage::ALL)
        .map(|(a, st)| {
            let r = StageRoofline {
                bytes_per_particle_step: a.bytes_per_particle_step,
                flops_per_particle_step: a.flops_per_particle_step,
                ns_per_particle_step: a.ns_per_particle_step,
                gb_per_s: a.gb_per_s,
                gflop_per_s: a.gflop_per_s,
            };
            (st, r)
        })
        .collect()
}

/// The workers' busy times over the steady state and DD's patches.
fn balance(sim: &Simulation, t: &Timing) -> Balance {
    let busy: Option<Vec<f64>> = sim.worker_busy().map(|now| match &t.warmup_busy {
        Some(w) => now.iter().zip(w).map(|(a, b)| (a - b).max(0.0)).collect(),
        None => now,
    });
    Balance {
        load_imbalance: busy.as_deref().and_then(load_imbalance),
        worker_busy_s: busy,
        dd_layout: sim.domain_decomposition().map(|dd| dd.layout()),
        dd_patch_particles: sim.domain_decomposition().map(|dd| PatchCounts::from(dd.load())),
    }
}

/// Energies, momentum, failures and the energy bookkeeping.
fn physics(sim: &Simulation, ctx: &RunContext<'_>) -> Physics {
    let (init, last) = (sim.initial(), sim.diagnostics());
    Physics {
        kinetic_energy_initial: init.kinetic,
        internal_energy_initial: init.internal,
        kinetic_energy: last.kinetic,
        internal_energy: last.internal,
        momentum_initial: init.momentum,
        momentum: last.momentum,
        failed_particles: ctx.failed_particles,
        energy: Some(EnergyReport::of(sim)),
        history: ctx.history.clone(),
    }
}

/// The scenario's own figures: the bar's lengths, the impact's cloud, the plate's shock
/// against Rankine-Hugoniot.
fn scenario_figures(sim: &Simulation, ctx: &RunContext<'_>) -> ScenarioFigures {
    match ctx.spec.scenario.kind() {
        ScenarioKind::Taylor => ScenarioFigures::Taylor(match ctx.taylor {
            Some((f0, f)) => TaylorFigures {
                initial_length_m: Some(f0.length),
                final_length_m: Some(f.length),
                initial_face_diameter_m: Some(f0.face_diameter),
                face_diameter_m: Some(f.face_diameter),
            },
            None => TaylorFigures::default(),
        }),
        ScenarioKind::Impact => ScenarioFigures::Impact(impact_figures(sim, ctx)),
        ScenarioKind::Plate => ScenarioFigures::Plate(plate_figures(ctx)),
    }
}

/// The impact's debris cloud at the end and its history.
fn impact_figures(sim: &Simulation, ctx: &RunContext<'_>) -> ImpactFigures {
    let mut i = ImpactFigures::default();
    if let Some(c) = &ctx.cloud {
        i.cloud_front_m = Some(c.cloud_front);
        i.cloud_front_robust_m = Some(c.cloud_front_robust);
        i.cloud_width_m = Some(c.cloud_width);
        i.cloud_width_robust_m = Some(c.cloud_width_robust);
        i.hole_diameter_m = Some(c.hole_diameter);
        i.leading_debris_velocity_m_s = Some(c.leading_debris_velocity);
        i.debris_mass_kg = Some(c.debris_mass);
        i.spacing_m = Some(sim.spacing()[0]);
    }
    if let Some(h) = &ctx.cloud_history {
        i.front_velocity_m_s = h.front_velocity();
        i.cloud_history = Some(h.samples.clone());
    }
    i
}

/// The plate's shock against its Rankine-Hugoniot values.
fn plate_figures(ctx: &RunContext<'_>) -> PlateFigures {
    let Some((g, result)) = &ctx.plate else { return PlateFigures::default() };
    let t = g.theory();
    let mut p = PlateFigures {
        slab_length_m: Some(g.length),
        rh_shock_speed_m_s: Some(t.shock_speed),
        rh_pressure_pa: Some(t.pressure),
        rh_particle_velocity_m_s: Some(t.particle_velocity),
        ..PlateFigures::default()
    };
    if let Some(r) = result {
        let rel = |a: f64, b: f64| a / b - 1.0;
        p.shock_speed_m_s = Some(r.shock_speed);
        p.shock_pressure_pa = Some(r.shocked.normal_stress);
        p.shock_mean_pressure_pa = Some(r.shocked.pressure);
        p.particle_velocity_m_s = Some(r.shocked.particle_velocity);
        p.shock_speed_rel_error = Some(rel(r.shock_speed, t.shock_speed));
        p.shock_pressure_rel_error = Some(rel(r.shocked.normal_stress, t.pressure));
        p.particle_velocity_rel_error = Some(rel(r.shocked.particle_velocity, t.particle_velocity));
        p.shock_front_samples = Some(r.samples);
    }
    p
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn vm_hwm_is_parsed_in_bytes() {
        let s = "Name:\tmpm\nVmPeak:\t  200 kB\nVmHWM:\t   123456 kB\nVmRSS:\t 1 kB\n";
        assert_eq!(parse_vm_hwm(s), Some(123_456 * 1024));
        assert_eq!(parse_vm_hwm("VmRSS: 1 kB\n"), None);
        assert!(peak_rss_bytes().unwrap() > 0);
    }

    fn pt(step: u64) -> HistoryPoint {
        HistoryPoint { step, time: step as f64, kinetic: 0.0, internal: 0.0 }
    }

    #[test]
    fn history_keeps_first_and_last_and_about_the_target() {
        for n in [0u64, 1, 5, 199, 200, 201, 1000, 12_345, 100_000] {
            let mut h = HistoryRecorder::new();
            for s in 0..=n {
                h.record(pt(s));
            }
            let v = h.finish(200);
            assert_eq!(v.first().unwrap().step, 0, "n={n}");
            assert_eq!(v.last().unwrap().step, n, "n={n}");
            assert!(v.len() <= 202, "n={n}: {}", v.len());
            assert!(v.len() as u64 >= (n + 1).min(150), "n={n}: {}", v.len());
            assert!(v.windows(2).all(|w| w[0].step < w[1].step));
        }
    }
}
