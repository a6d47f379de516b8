//! The summary of a run for people (stdout), unless `--quiet`.

use mpm_cli::vtk::SnapshotWriter;
use mpm_host::human::group_digits;
use mpm_host::pinning;
use mpm_spec::summary::{EndReason, WallContact};
use mpm_spec::{ScenarioKind, Summary};
use std::path::Path;

/// Print the summary for people. A closed stdout (e.g. `| head`) must not panic: write
/// errors are ignored.
pub fn print_human(s: &Summary, json: Option<&Path>, snaps: Option<&SnapshotWriter>) {
    use std::io::Write;
    let mut lines = configuration(s);
    lines.extend(timing(s));
    lines.extend(physics(s));
    lines.extend(ranks(s));
    if let Some(w) = snaps {
        lines.push(format!("snapshots: {} VTU file(s), open {}", w.steps().len(), w.pvd_path().display()));
    }
    if let Some(j) = json {
        lines.push(format!("summary: {}", j.display()));
    }
    let mut stdout = std::io::stdout().lock();
    for line in lines {
        let _ = writeln!(stdout, "{line}");
    }
}

/// The model and the solver as run: counts, grid, strategy, threads, pinning, build.
fn configuration(s: &Summary) -> Vec<String> {
    let what = if s.scenario() == ScenarioKind::Taylor {
        format!("Taylor bar Model {}", s.model)
    } else {
        s.model_name.clone()
    };
    let model = format!(
        "{what} at {} m/s: {} particles, {} cells, {} nodes ({} grid, dx = {:.4} mm)",
        s.velocity_m_s,
        group_digits(s.figures.size.particles as u64),
        group_digits(s.figures.size.cells as u64),
        group_digits(s.figures.size.nodes as u64),
        s.grid_mode.name(),
        s.figures.size.dx_m * 1e3
    );
    let cpus = if s.pinning.pinned {
        format!(
            ", pinned to CPUs {} (observed {}{})",
            pinning::format_cpu_list(&s.pinning.requested_cpus),
            s.pinning.observed_cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(","),
            if s.pinning.pinning_verified == Some(true) { ", verified" } else { ", NOT as requested" }
        )
    } else {
        String::new()
    };
    let solver = format!(
        "solver: strategy {}, {} thread(s){}{}, {} build, {}, CFL {}{}",
        s.strategy,
        s.threads,
        cpus,
        if s.pinning.oversubscribed { " (oversubscribed)" } else { "" },
        s.opt_level,
        s.eos.name(),
        s.cfl,
        match s.wall {
            WallContact::None => String::new(),
            w => format!(", {} wall", w.name()),
        }
    );
    vec![model, solver]
}

/// Steps, wall time by stage, the steady state and the workers' balance.
fn timing(s: &Summary) -> Vec<String> {
    let reason = match s.figures.progress.end_reason {
        EndReason::EndTime => "end time reached",
        EndReason::StepLimit => "step limit reached",
    };
    let mut lines = vec![format!(
        "steps: {} to t = {:.3} µs ({reason}), dt first {:.3e} s",
        group_digits(s.figures.progress.steps),
        s.figures.progress.sim_time * 1e6,
        s.figures.progress.dt_first
    )];
    let total = s.figures.timing.grid_stage_s + s.figures.timing.particle_stage_s;
    let pct = |x: f64| if total > 0.0 { 100.0 * x / total } else { 0.0 };
    lines.push(format!(
        "wall time: {:.3} s; grid-node stage {:.3} s ({:.0} %), particle stage {:.3} s ({:.0} %)",
        s.figures.timing.wall_s,
        s.figures.timing.grid_stage_s,
        pct(s.figures.timing.grid_stage_s),
        s.figures.timing.particle_stage_s,
        pct(s.figures.timing.particle_stage_s)
    ));
    lines.push(match (s.figures.timing.ns_per_particle_step, s.figures.timing.particle_steps_per_s) {
        (Some(ns), Some(rate)) => format!(
            "steady state ({} steps after {} warm-up): {:.1} ns per particle-step, {:.3e} particle-steps/s, {:.3} ms per step",
            s.figures.progress.steady_steps,
            s.figures.progress.warmup_steps,
            ns,
            rate,
            s.figures.timing.steady_s_per_step.unwrap_or(0.0) * 1e3
        ),
        _ => "steady state: no steps after the warm-up".to_string(),
    });
    lines.extend(balance(s));
    lines.extend(checkpoints(s));
    lines.extend(efficiency_notes(s));
    lines
}

/// The workers' busy time and the DD patches' work, when measured.
fn balance(s: &Summary) -> Vec<String> {
    let mut lines = Vec::new();
    if let (Some(busy), Some(imb)) = (&s.figures.balance.worker_busy_s, s.figures.balance.load_imbalance) {
        let list = busy.iter().map(|b| format!("{b:.3}")).collect::<Vec<_>>().join(" / ");
        let uneven_patches = s.figures.balance.dd_patch_particles.is_some_and(|p| p.imbalance_mean > 1.1);
        let note = if imb > 1.1 && !s.pinning.oversubscribed && !uneven_patches {
            " (unequal: a worker's CPU was slowed from outside this run; repeat it)"
        } else {
            ""
        };
        lines.push(format!("workers: busy {list} s in their shares, load imbalance {imb:.3}{note}"));
    }
    if let Some(p) = s.figures.balance.dd_patch_particles {
        lines.push(format!(
            "DD patches: {} / {:.0} / {} particles (min / mean / max), work imbalance {:.3} mean, {:.3} worst step",
            p.min, p.mean, p.max, p.imbalance_mean, p.imbalance_max
        ));
    }
    lines
}

/// The checkpoints written and the restarts, when there were any.
fn checkpoints(s: &Summary) -> Option<String> {
    s.figures.checkpoint.as_ref().map(|c| {
        let restarts = match c.restarts {
            0 => String::new(),
            n => format!(
                "; continued {n} time(s), from step(s) {}, {:.3} s of set-up",
                c.restart_steps.iter().map(u64::to_string).collect::<Vec<_>>().join(", "),
                c.restart_setup_s
            ),
        };
        format!(
            "checkpoints: {} written in {:.3} s (the last {}){restarts}; none of it in the times above",
            c.written,
            c.write_s,
            mpm_host::human::human_bytes(c.last_bytes)
        )
    })
}

/// What bounds or qualifies the parallel efficiency: the work counters' bound, a paired
/// measurement, workers kept off their CPUs, the injected slowdown.
fn efficiency_notes(s: &Summary) -> Vec<String> {
    let mut lines = Vec::new();
    if let Some(w) = s.figures.work.as_ref().filter(|w| w.worker_bytes.len() > 1) {
        lines.push(format!(
            "work counters: efficiency bound {:.3} from the traffic alone (balance {:.3}, the strategy's overhead {:.1} %)",
            w.efficiency_bound,
            w.balance,
            100.0 * w.overhead
        ));
    }
    if let Some(p) = &s.figures.paired {
        let lo = p.block_efficiency.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = p.block_efficiency.iter().copied().fold(f64::NEG_INFINITY, f64::max);
        lines.push(format!(
            "paired: efficiency {:.3} over {} blocks of {} step(s) against 1 thread (blocks {lo:.3} to {hi:.3}; \
             one process: its spread is not the run-to-run spread)",
            p.efficiency, p.blocks, p.block_steps
        ));
    }
    for (who, n) in [
        ("", s.figures.noise.as_ref()),
        ("paired reference: ", s.figures.paired.as_ref().and_then(|p| p.reference_noise.as_ref())),
    ] {
        if let Some(why) = n.and_then(|n| n.why()) {
            lines.push(format!("warning: {who}{why}: something else took its CPU; the timing is not this code's"));
        }
    }
    if let Some(f) = s.inject_slowdown {
        lines.push(format!(
            "TEST KNOB: an injected slowdown of {:.0} % ({:.3} s of extra work): these times are not a result",
            100.0 * f,
            s.figures.injected_s.unwrap_or(0.0)
        ));
    }
    if let Some(f) = s.inject_step_slowdown {
        lines.push(format!(
            "TEST KNOB: an injected step slowdown of {:.0} % ({:.3} s of waiting): these times are not a result",
            100.0 * f,
            s.figures.injected_step_s.unwrap_or(0.0)
        ));
    }
    lines
}

/// With several MPI ranks, one line per rank: CPUs, particles, time in the exchange and
/// traffic per step.
fn ranks(s: &Summary) -> Vec<String> {
    let Some(ranks) = &s.ranks else { return Vec::new() };
    ranks
        .iter()
        .map(|r| {
            let e = &r.exchange;
            let per_step = |x: u64| x as f64 / r.steps.max(1) as f64;
            format!(
                "rank {}: CPUs {:?}{}, {} particles ({} sent away), {}, exchange {:.3} s{}, peak RSS {}; per step {:.3} MiB halo in {:.0} messages, {:.0} migration messages",
                r.rank,
                r.cpus,
                if r.oversubscribed { " (shared: oversubscribed)" } else { "" },
                group_digits(r.particles as u64),
                group_digits(r.migrated),
                if r.busy_s > 0.0 { format!("busy {:.3} s", r.busy_s) } else { "busy not measured (serial)".to_string() },
                e.seconds,
                e.wait_seconds.map_or(String::new(), |w| format!(" (+ {w:.3} s waiting for other ranks)")),
                r.peak_rss_bytes.map_or("unknown".to_string(), |b| format!("{:.1} MiB", b as f64 / 1048576.0)),
                per_step(e.halo_bytes) / 1048576.0,
                per_step(e.halo_messages),
                per_step(e.migration_messages),
            )
        })
        .collect()
}

/// The scenario's figures, energies and memory.
fn physics(s: &Summary) -> Vec<String> {
    let mut lines = Vec::new();
    let bar = s.figures.scenario.taylor().cloned().unwrap_or_default();
    if let (Some(l0), Some(l), Some(d)) = (bar.initial_length_m, bar.final_length_m, bar.face_diameter_m) {
        lines.push(format!(
            "bar: length {:.3} mm (initial {:.3} mm), impact-face diameter {:.3} mm",
            l * 1e3,
            l0 * 1e3,
            d * 1e3
        ));
    }
    let cloud = s.figures.scenario.impact().cloned().unwrap_or_default();
    if let (Some(front), Some(width)) = (cloud.cloud_front_m, cloud.cloud_width_m) {
        lines.push(format!(
            "debris cloud: leading edge {:.2} mm behind the plate (robust {} mm), width {:.2} mm (robust {} mm), hole {} mm, front velocity {} m/s (fitted), leading debris {} m/s",
            front * 1e3,
            measured(cloud.cloud_front_robust_m, 1e3, 2),
            width * 1e3,
            measured(cloud.cloud_width_robust_m, 1e3, 2),
            measured(cloud.hole_diameter_m, 1e3, 2),
            measured(cloud.front_velocity_m_s, 1.0, 0),
            measured(cloud.leading_debris_velocity_m_s, 1.0, 0)
        ));
    }
    lines.extend(shock(s));
    lines.push(format!(
        "energy: kinetic {:.4} J (initial {:.4} J), internal {:.4} J; failed particles {}",
        s.figures.physics.kinetic_energy,
        s.figures.physics.kinetic_energy_initial,
        s.figures.physics.internal_energy,
        s.figures.physics.failed_particles
    ));
    if let Some(e) = &s.figures.physics.energy {
        lines.push(format!(
            "energy balance: total {:.4} J -> {:.4} J, largest rise {:.2e} (step {}), largest fall {:.2e} (step {}); negative internal energy after {} step(s) (at most {} particles); failed particles' negative energy set to zero {} time(s), adding {:.4} J",
            e.initial_total_j,
            e.final_total_j,
            e.max_rise,
            e.max_rise_step,
            e.max_fall,
            e.max_fall_step,
            e.negative_internal_steps,
            e.negative_internal_max,
            e.failed_energy_floors,
            e.failed_energy_floor_j
        ));
    }
    lines.push(format!(
        "memory: peak RSS {}, model {:.1} MiB",
        s.figures.memory.peak_rss_bytes.map_or("unknown".into(), |b| format!("{:.1} MiB", b as f64 / 1048576.0)),
        s.figures.memory.model_memory_bytes as f64 / 1048576.0
    ));
    if let Some(o) = s.figures.size.final_occupancy {
        let stored = s.sparse_stored_nodes().map_or_else(String::new, |n| {
            format!(" in its box, {} stored ({} grid)", group_digits(n as u64), s.grid_mode.name())
        });
        lines.push(format!(
            "final grid: {} nodes{stored}; particles in {} of its {} cells ({:.1} %) and in {} blocks of {}^3 cells",
            group_digits(s.figures.size.final_nodes as u64),
            group_digits(o.occupied_cells),
            group_digits(o.cells),
            100.0 * o.occupied_cells as f64 / o.cells.max(1) as f64,
            group_digits(o.occupied_blocks),
            o.block_cells
        ));
    }
    lines
}

/// The plate's shock, measured against Rankine-Hugoniot.
fn shock(s: &Summary) -> Vec<String> {
    let Some(plate) = s.figures.scenario.plate() else { return Vec::new() };
    let (Some(us_rh), Some(p_rh), Some(up_rh)) =
        (plate.rh_shock_speed_m_s, plate.rh_pressure_pa, plate.rh_particle_velocity_m_s)
    else {
        return Vec::new();
    };
    let (Some(us), Some(p), Some(up)) = (plate.shock_speed_m_s, plate.shock_pressure_pa, plate.particle_velocity_m_s)
    else {
        return vec![format!(
            "shock: not measured (the front was not tracked long enough; run to the default end time); Rankine-Hugoniot: U_s {us_rh:.1} m/s, p {:.3} GPa, u_p {up_rh:.1} m/s",
            p_rh * 1e-9
        )];
    };
    let pct = |a: f64, b: f64| 100.0 * (a / b - 1.0);
    vec![
        "shock (measured vs Rankine-Hugoniot):".to_string(),
        format!("  shock speed      {us:10.1} m/s  vs {us_rh:10.1} m/s  ({:+.2} %)", pct(us, us_rh)),
        format!("  pressure -s_zz   {:10.3} GPa  vs {:10.3} GPa  ({:+.2} %)", p * 1e-9, p_rh * 1e-9, pct(p, p_rh)),
        format!("  particle vel.    {up:10.1} m/s  vs {up_rh:10.1} m/s  ({:+.2} %)", pct(up, up_rh)),
    ]
}

/// A figure `v` times `scale` with `decimals`, or `n/a` where the run gives none or none
/// that is a number (a hole no row of particles spans, a front fitted to too few samples).
fn measured(v: Option<f64>, scale: f64, decimals: usize) -> String {
    match v.map(|v| v * scale) {
        Some(x) if x.is_finite() => format!("{x:.decimals$}"),
        _ => "n/a".into(),
    }
}
