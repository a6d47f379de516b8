//! Integration tests of the campaign harness: matrix expansion, resume, skip and
//! oversubscription flags, the CSV header, CLI errors (all with the mock runner), and one
//! real end-to-end smoke campaign through the `mpm-bench` binary and the real `mpm` solver.

use mpm_bench::analysis::select::RowFilter;
use mpm_bench::campaign::exec::process::MockRunner;
use mpm_bench::campaign::exec::solver::Solver;
use mpm_bench::campaign::plan::matrix::{Campaign, Overrides};
use mpm_bench::campaign::plan::memory;
use mpm_bench::campaign::plan::preset::{self, OptLevel};
use mpm_bench::campaign::schedule;
use mpm_bench::campaign::schedule::ExecOptions;
use mpm_bench::campaign::store::csv::read_rows;
use mpm_bench::campaign::store::record::{Row, Status};
use mpm_bench::machine::fingerprint;
use mpm_bench::machine::placement::PinPolicy;
use mpm_bench::machine::topology::Machine;
use mpm_core::{Strategy, Substage};
use mpm_spec::summary::EndReason;
use std::collections::HashSet;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

fn campaign(name: &str, ov: &Overrides) -> Campaign {
    let (p, src) = preset::load_preset(name, None).unwrap();
    Campaign::resolve(p, src, ov).unwrap()
}

fn mock_solvers(c: &Campaign) -> Vec<Solver> {
    c.opts.iter().map(|&opt| Solver { opt, path: "mock".into(), sha256: "0123456789abcdef".into() }).collect()
}

/// A two-core, one-socket machine (like the development machine), independent of the host.
fn laptop() -> Machine {
    Machine::synthetic("pack:1 core:2 pu:1").unwrap()
}

fn opts(out: &Path) -> ExecOptions {
    ExecOptions { out_root: out.to_path_buf(), quiet: true, command: "test".into(), ..ExecOptions::default() }
}

fn run_mock(c: &Campaign, m: &Machine, out: &Path, r: &mut MockRunner) -> schedule::ExecSummary {
    let flag = AtomicBool::new(false);
    schedule::execute(c, m, &mock_solvers(c), r, &opts(out), &flag).unwrap()
}

/// Run `c` on `m` into `out` with the mock runner interrupted after 3 runs.
fn interrupted_after_3(c: &Campaign, m: &Machine, out: &Path) -> schedule::ExecSummary {
    let flag = Arc::new(AtomicBool::new(false));
    let mut r = MockRunner { interrupt_after: Some((3, flag.clone())), ..MockRunner::default() };
    schedule::execute(c, m, &mock_solvers(c), &mut r, &opts(out), &flag).unwrap()
}

#[test]
fn matrix_expansion_covers_every_cell() {
    let quick = campaign("quick", &Overrides::default());
    let runs = quick.expand();
    // Every cell but Model 4 at O0 (excluded: it alone would take the budget), 3 repetitions
    // (what claims needs for intervals).
    assert_eq!(quick.reps, 3);
    assert_eq!(runs.len(), 3 * (4 * 5 * 2 * 2 - 5 * 2));
    let keys: HashSet<_> = runs.iter().map(|r| r.key()).collect();
    assert_eq!(keys.len(), runs.len(), "every run has its own key");
    for m in 1..=4 {
        for opt in [OptLevel::O3, OptLevel::O0] {
            for s in [Strategy::ArrayExpansion, Strategy::DomainDecomposition] {
                for t in [1, 2, 4, 6, 8] {
                    let any = runs
                        .iter()
                        .any(|r| r.model == m && r.opt == opt && r.spec.strategy == s && r.spec.threads == t);
                    assert_eq!(any, !(m == 4 && opt == OptLevel::O0), "Model{m} {opt} {s} {t}");
                }
            }
        }
    }
    // Budgets: the most specific override wins; Model 4 gets the fewest steps.
    let b43 = quick.budget_for(4, OptLevel::O3);
    let b13 = quick.budget_for(1, OptLevel::O3);
    assert!(b43.steps.unwrap() < b13.steps.unwrap());
    assert!(b43.warmup.unwrap() < b43.steps.unwrap().max(1));

    let paper = campaign("paper", &Overrides::default());
    assert_eq!(paper.expand().len(), 4 * 5 * 2 * 2 * paper.reps as usize);
    assert!(paper.expand().iter().all(|r| r.spec.budget.end_time_s == Some(4e-5) && r.spec.budget.steps.is_none()));

    // Serial pairs with one thread only.
    let ov =
        Overrides { strategies: Some(vec![Strategy::Serial, Strategy::DomainDecomposition]), ..Overrides::default() };
    let c = campaign("smoke", &ov);
    assert!(c.expand().iter().all(|r| r.spec.strategy != Strategy::Serial || r.spec.threads == 1));
    assert_eq!(c.expand().iter().filter(|r| r.spec.strategy == Strategy::Serial).count(), 2);
}

#[test]
fn overrides_change_the_campaign_id_but_not_the_seed() {
    let plain = campaign("smoke", &Overrides::default());
    assert_eq!(plain.id, "smoke");
    let ov =
        Overrides { models: Some(vec![1, 2]), threads: Some(vec![1, 2, 4]), steps: Some(3), ..Overrides::default() };
    let c = campaign("smoke", &ov);
    assert_eq!(c.id, "smoke_m1-2_t1-2-4_n3");
    assert!(c.expand().iter().all(|r| r.spec.budget.steps == Some(3)));
    let seeded = campaign("smoke", &Overrides { seed: Some(99), ..Overrides::default() });
    assert_eq!(seeded.id, "smoke");
    assert_eq!(seeded.seed, 99);
    // Errors are clear.
    let (p, s) = preset::load_preset("smoke", None).unwrap();
    let e = Campaign::resolve(p.clone(), s.clone(), &Overrides { models: Some(vec![5]), ..Overrides::default() })
        .unwrap_err()
        .to_string();
    assert!(e.contains("unknown model 5"), "{e}");
    let e =
        Campaign::resolve(p, s, &Overrides { threads: Some(vec![0]), ..Overrides::default() }).unwrap_err().to_string();
    assert!(e.contains("at least 1"), "{e}");
    let e = preset::load_preset("nope", None).unwrap_err().to_string();
    assert!(e.contains("unknown preset 'nope'"), "{e}");
}

#[test]
fn order_is_seeded_interleaved_and_complete() {
    let ov = Overrides { reps: Some(3), ..Overrides::default() };
    let c = campaign("quick", &ov);
    let a = c.ordered(5);
    assert_eq!(a, c.ordered(5));
    assert_ne!(a, c.ordered(6));
    assert_ne!(a, c.expand());
    let n = a.len() / 3;
    // Repetition by repetition: every configuration once before any repeats.
    for (i, r) in a.iter().enumerate() {
        assert_eq!(r.rep as usize, i / n);
    }
    let mut sorted: Vec<_> = a.iter().map(|r| r.key()).collect();
    sorted.sort();
    let mut want: Vec<_> = c.expand().iter().map(|r| r.key()).collect();
    want.sort();
    assert_eq!(sorted, want);
}

#[test]
fn resume_adds_nothing_and_interrupts_keep_rows() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let m = laptop();
    // Interrupted after 3 runs: exactly 3 valid rows.
    let s = interrupted_after_3(&c, &m, dir.path());
    assert!(s.counts.interrupted);
    assert_eq!(s.counts.written, 3);
    let csv = s.dir.join("runs.csv");
    assert_eq!(read_rows(&csv).unwrap().len(), 3);
    // Resume: the other 5 only.
    let mut r = MockRunner::default();
    let s = run_mock(&c, &m, dir.path(), &mut r);
    assert_eq!((s.counts.already_done, s.counts.written, r.calls.len()), (3, 5, 5));
    let rows = read_rows(&csv).unwrap();
    assert_eq!(rows.len(), 8);
    let keys: HashSet<_> = rows.iter().map(Row::key).collect();
    assert_eq!(keys.len(), 8);
    assert!(rows.iter().all(|r| r.outcome.status == Status::Ok && r.id.campaign_id == "smoke"));
    // Again: nothing to do, and nothing rewritten.
    let before = std::fs::read(s.dir.join("manifest.json")).unwrap();
    let mut r = MockRunner::default();
    let s = run_mock(&c, &m, dir.path(), &mut r);
    assert_eq!((s.counts.written, r.calls.len()), (0, 0));
    assert_eq!(read_rows(&csv).unwrap().len(), 8);
    assert_eq!(std::fs::read(s.dir.join("manifest.json")).unwrap(), before, "a no-op run rewrote the manifest");
    // Manifest and sessions: one per session that ran something, each with its machine.
    let man = mpm_bench::campaign::store::manifest::read(&s.dir.join("manifest.json")).unwrap();
    assert_eq!(man.sessions.len(), 2);
    assert!(man
        .sessions
        .iter()
        .all(|s| s.machine.as_ref().is_some_and(|mi| mi.fingerprint == man.machine.fingerprint)));
    assert_eq!(man.machine.fingerprint, fingerprint::fingerprint(&m));
    assert!(s.dir.starts_with(dir.path().join(&man.machine.fingerprint)));
}

/// The resume key is the whole planned run: a preset whose only change is its scenario
/// (Taylor Model 1 -> the impact's model 1, same name, same folder) runs again instead of
/// presenting the Taylor row as the impact's; run once more, nothing is left to do. A
/// physics option of the preset is a new run too.
/// A campaign of an older harness, whose rows carry the 16-digit short form of the resume key,
/// resumes: its rows count as the runs they name, the runs still to do run once, and their
/// rows carry the whole SHA-256.
#[test]
fn a_campaign_with_short_keys_resumes() {
    use mpm_bench::campaign::store::csv::CsvLog;
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let m = laptop();
    let s = interrupted_after_3(&c, &m, dir.path());
    let csv = s.dir.join("runs.csv");
    let old: Vec<Row> = read_rows(&csv)
        .unwrap()
        .into_iter()
        .map(|mut r| {
            r.id.run_key = r.key().short().0;
            r
        })
        .collect();
    std::fs::remove_file(&csv).unwrap();
    let mut log = CsvLog::open(&csv).unwrap();
    old.iter().for_each(|r| log.append(r).unwrap());
    drop(log);
    let mut r = MockRunner::default();
    let s = run_mock(&c, &m, dir.path(), &mut r);
    assert_eq!((s.counts.already_done, s.counts.written, r.calls.len()), (3, 5, 5));
    let rows = read_rows(&csv).unwrap();
    assert_eq!(rows.iter().filter(|r| r.key().is_short()).count(), 3, "the old rows are left as they were");
    let new: Vec<&Row> = rows.iter().filter(|r| !r.key().is_short()).collect();
    assert_eq!(new.len(), 5);
    assert!(new.iter().all(|r| r.id.run_key.split_once("-r").is_some_and(|(h, _)| h.len() == 64)));
    let runs: HashSet<_> = rows.iter().map(|r| r.key().short()).collect();
    assert_eq!(runs.len(), 8, "one row per run");
}

#[test]
fn changing_only_the_scenario_runs_again() {
    let dir = tempfile::tempdir().unwrap();
    let text = |scenario: &str, extra: &str| {
        format!(
            "name = \"holetest\"\nscenario = \"{scenario}\"\nmodels = [1]\nthreads = [1]\nstrategies = [\"dd\"]\n\
             opt = [\"o3\"]\n{extra}[budget]\nsteps = 3\nwarmup = 1\n"
        )
    };
    let resolve =
        |t: String| Campaign::resolve(preset::parse_preset(&t).unwrap(), "file".into(), &Overrides::default()).unwrap();
    let taylor = resolve(text("taylor", ""));
    let s = run_mock(&taylor, &laptop(), dir.path(), &mut MockRunner::default());
    assert_eq!(s.counts.written, 1);
    let impact = resolve(text("impact", ""));
    let mut r = MockRunner::default();
    let s2 = run_mock(&impact, &laptop(), dir.path(), &mut r);
    assert_eq!(s2.dir, s.dir, "the same campaign folder");
    assert_eq!(s2.counts.written, 1, "the impact is not the Taylor bar's row");
    assert!(matches!(r.calls[0].spec.scenario, mpm_spec::Scenario::Impact(_)));
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    let kinds: Vec<_> = rows.iter().map(|r| r.scenario()).collect();
    assert_eq!(kinds, [mpm_spec::ScenarioKind::Taylor, mpm_spec::ScenarioKind::Impact]);
    assert_ne!(rows[0].key(), rows[1].key());
    assert_eq!(run_mock(&impact, &laptop(), dir.path(), &mut MockRunner::default()).counts.written, 0);
    let q = resolve(text("impact", "[physics]\nq = { c1 = 1.0, c2 = 0.06 }\n"));
    assert_eq!(run_mock(&q, &laptop(), dir.path(), &mut MockRunner::default()).counts.written, 1);
}

/// Copy the campaign folder `from` to `to` (files of the top level and `json/`).
fn copy_campaign(from: &Path, to: &Path) {
    std::fs::create_dir_all(to.join("json")).unwrap();
    for sub in ["", "json"] {
        for e in std::fs::read_dir(from.join(sub)).unwrap().flatten() {
            if e.file_type().unwrap().is_file() {
                std::fs::copy(e.path(), to.join(sub).join(e.file_name())).unwrap();
            }
        }
    }
}

/// The resume rule: a campaign copied into the folder of another machine's fingerprint is
/// not resumed there (a new folder `<id>-2` starts, said in one line) unless
/// `--resume-foreign`; rows of other solver binaries are not resumed either; a reference
/// campaign is never resumed.
#[test]
fn foreign_and_reference_campaigns_are_not_resumed() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let (a, b) = (laptop(), Machine::synthetic("pack:1 core:4 pu:1").unwrap());
    let s = interrupted_after_3(&c, &a, dir.path());
    let copied = schedule::state::campaign_dir(dir.path(), &b, &c);
    assert_ne!(copied, s.dir);
    copy_campaign(&s.dir, &copied);
    // On machine b: the copy is another machine's; a new folder takes all 8 runs.
    let mut r = MockRunner::default();
    let s = run_mock(&c, &b, dir.path(), &mut r);
    assert_eq!(s.dir, copied.with_file_name("smoke-2"));
    assert_eq!((s.counts.already_done, r.calls.len()), (0, 8));
    assert_eq!(read_rows(&copied.join("runs.csv")).unwrap().len(), 3, "the copy was not touched");
    // With --resume-foreign the copy is resumed: the other 5 runs.
    let o = ExecOptions { resume_foreign: true, ..opts(dir.path()) };
    let mut r = MockRunner::default();
    let s = schedule::execute(&c, &b, &mock_solvers(&c), &mut r, &o, &AtomicBool::new(false)).unwrap();
    assert_eq!((s.dir.as_path(), s.counts.already_done, r.calls.len()), (copied.as_path(), 3, 5));
    // Same machine, rebuilt solver: not resumed either.
    let rebuilt: Vec<Solver> =
        mock_solvers(&c).into_iter().map(|s| Solver { sha256: "fedcba9876543210".into(), ..s }).collect();
    let mut r = MockRunner::default();
    let s = schedule::execute(&c, &a, &rebuilt, &mut r, &opts(dir.path()), &AtomicBool::new(false)).unwrap();
    assert!(s.dir.ends_with("smoke-2") && r.calls.len() == 8, "{}", s.dir.display());
    // A reference campaign is refused even with --resume-foreign.
    let mpath = copied.join("manifest.json");
    let mut man = mpm_bench::campaign::store::manifest::read(&mpath).unwrap();
    man.reference = true;
    mpm_bench::campaign::store::manifest::write(&mpath, &man).unwrap();
    let mut r = MockRunner::default();
    let s = schedule::execute(&c, &b, &mock_solvers(&c), &mut r, &o, &AtomicBool::new(false)).unwrap();
    assert_eq!(s.dir, copied.with_file_name("smoke-2"));
    assert_eq!(r.calls.len(), 0, "smoke-2 of machine b is complete and resumable");
}

/// With the host watch on, every run row records the host's load before and after it, the
/// steal during it and the calibration ratio, and is flagged exactly by the rule; the
/// session's start calibration is in the manifest.
#[test]
fn host_load_is_recorded_around_every_run() {
    use mpm_bench::campaign::exec::watch::WatchSettings;
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let m = laptop();
    let w = WatchSettings {
        window: std::time::Duration::from_millis(60),
        calibrate_every: 3,
        start_window: std::time::Duration::from_millis(10),
    };
    let o = ExecOptions { watch: Some(w), ..opts(dir.path()) };
    let s =
        schedule::execute(&c, &m, &mock_solvers(&c), &mut MockRunner::default(), &o, &AtomicBool::new(false)).unwrap();
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 8);
    for r in &rows {
        assert!(r.host.host_load1_before.is_some() && r.host.host_load1_after.is_some(), "{}", r.id.run_id);
        assert!(r.host.host_others_running_before.is_some() && r.host.host_others_running_after.is_some());
        assert!(
            r.host.host_cpus_busy_before.is_some_and(|b| (0.0..=1.0).contains(&b)),
            "{:?}",
            r.host.host_cpus_busy_before
        );
        assert!(
            r.host.host_cpus_busy_after.is_some()
                && r.host.calib_spin_ratio.is_some()
                && r.host.calib_copy_ratio.is_some()
        );
        let why = r.host.reading().noise(r.threads(), m.usable_pus().len());
        assert_eq!(r.host.host_noisy, why.is_some());
        assert_eq!(r.host.host_noise, why.unwrap_or_default());
    }
    let man = mpm_bench::campaign::store::manifest::read(&s.dir.join("manifest.json")).unwrap();
    assert!(man.sessions[0].calibration.is_some_and(|c| c.spin_s > 0.0 && c.copy_s > 0.0));
}

#[test]
fn memory_guard_skips_with_a_reason() {
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { mem_limit: Some(10 << 20), ..Overrides::default() };
    let c = campaign("smoke", &ov);
    let mut r = MockRunner::default();
    let s = run_mock(&c, &laptop(), dir.path(), &mut r);
    assert_eq!(r.calls.len(), 0, "skipped runs are not attempted");
    assert_eq!(s.counts.skipped, 8);
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert!(rows.iter().all(|r| r.outcome.status == Status::Skipped && r.outcome.reason.contains("memory guard")));
    assert!(rows
        .iter()
        .all(|r| r.measured.as_ref().map(|f| f.timing.wall_s).is_none() && r.outcome.mem_estimate_bytes > 10 << 20));
    // AE grows with threads: with a limit between, Model 4 AE at 8 threads is skipped while DD runs.
    let est_dd = memory::estimate_memory(mpm_spec::ScenarioKind::Taylor, 4, Strategy::DomainDecomposition, 8);
    let est_ae = memory::estimate_memory(mpm_spec::ScenarioKind::Taylor, 4, Strategy::ArrayExpansion, 8);
    assert!(est_ae > est_dd);
    assert!(memory::memory_verdict(est_ae, None, Some(est_ae)).is_some());
    assert!(memory::memory_verdict(est_dd, None, Some(est_ae)).is_none());
}

#[test]
fn oversubscribed_invalid_and_failed_rows_are_flagged() {
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { threads: Some(vec![1, 2, 4]), opt: Some(vec![OptLevel::O3]), ..Overrides::default() };
    let c = campaign("smoke", &ov);
    let mut r = MockRunner {
        wrong_cpus_when: Some("dd o3 2 thr".into()),
        fail_when: Some("ae o3 1 thr".into()),
        ..MockRunner::default()
    };
    let s = run_mock(&c, &laptop(), dir.path(), &mut r);
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 6);
    for row in &rows {
        assert_eq!(row.placement.oversubscribed, row.threads() > 2, "{}", row.id.run_id);
        if row.threads() == 4 {
            // OpenMP close with more threads than places: consecutive threads share a place.
            assert_eq!(row.placement.requested_cpus, [0, 0, 1, 1]);
        }
    }
    let invalid: Vec<_> = rows.iter().filter(|r| r.outcome.status == Status::Invalid).collect();
    assert_eq!(invalid.len(), 1);
    assert!(
        invalid[0].outcome.reason.contains("requested CPUs [0 1], observed [1 2]"),
        "{}",
        invalid[0].outcome.reason
    );
    let failed: Vec<_> = rows.iter().filter(|r| r.outcome.status == Status::Failed).collect();
    assert_eq!(failed.len(), 1);
    assert!(failed[0].outcome.reason.contains("exited with code 1"), "{}", failed[0].outcome.reason);
    assert_eq!(s.counts.oversubscribed, 2);
    // --retry-failed runs the two bad ones again (new attempt ids), nothing else.
    let mut r = MockRunner::default();
    let flag = AtomicBool::new(false);
    let o = ExecOptions { retry_failed: true, ..opts(dir.path()) };
    let s = schedule::execute(&c, &laptop(), &mock_solvers(&c), &mut r, &o, &flag).unwrap();
    assert_eq!(s.counts.written, 2);
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert!(rows.iter().any(|r| r.id.run_id.ends_with("-a1")));
}

#[test]
fn pinning_none_passes_no_cpus() {
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { pin: Some(vec![PinPolicy::None]), opt: Some(vec![OptLevel::O3]), ..Overrides::default() };
    let c = campaign("smoke", &ov);
    let mut r = MockRunner::default();
    let s = run_mock(&c, &laptop(), dir.path(), &mut r);
    assert!(r.calls.iter().all(|c| c.spec.cpus.is_none()));
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert!(rows
        .iter()
        .all(|r| r.outcome.status == Status::Ok && r.placement.requested_cpus.is_empty() && r.pin_label() == "none"));
}

/// Snapshot of the CSV header: changing it must be deliberate (bump SCHEMA_VERSION when old
/// readers would misread it). The spec's columns come from `mpm_spec::RunSpec` itself.
#[test]
fn csv_header_snapshot() {
    assert_eq!(mpm_bench::campaign::store::record::SCHEMA_VERSION, 10);
    let want = "schema_version,campaign_id,run_id,run_key,timestamp,git_commit,git_dirty,machine_id,node,job_id,\
binary_sha256,seed,order_index,spec_version,scenario.kind,scenario.model,scenario.velocity_m_s,\
scenario.wall,scenario.spacing_m,scenario.cell_m,scenario.length_m,scenario.particles_per_cell,\
strategy,threads,ranks,rank_layout,grid,physics.eos,physics.q.c1,physics.q.c2,physics.cfl,\
physics.energy_rise_limit,budget.steps,budget.end_time_s,budget.warmup,split_wait,paired.blocks,\
inject_slowdown,inject_step_slowdown,model,opt,pin,launcher,rep,requested_cpus,observed_cpus,rank_cpus,oversubscribed,physical_cores,\
particles,cells,nodes,mean_nodes,final_nodes,final_stored_nodes,final_occupancy.cells,\
final_occupancy.occupied_cells,final_occupancy.occupied_blocks,final_occupancy.block_cells,dx_m,\
steps,warmup_steps,steady_steps,dt_first,dt_next,sim_time,end_reason,wall_s,output_s,grid_stage_s,\
particle_stage_s,substages.reorder,substages.grid_fit,substages.binning,substages.scatter,\
substages.assembly,substages.grid_update,substages.gather,substages.remap_scatter,\
substages.remap_assembly,substages.stress_update,steady_wall_s,steady_grid_stage_s,\
steady_particle_stage_s,steady_substages.reorder,steady_substages.grid_fit,steady_substages.binning,\
steady_substages.scatter,steady_substages.assembly,steady_substages.grid_update,\
steady_substages.gather,steady_substages.remap_scatter,steady_substages.remap_assembly,\
steady_substages.stress_update,simd_level,roofline.reorder.bytes_per_particle_step,\
roofline.reorder.flops_per_particle_step,roofline.reorder.ns_per_particle_step,\
roofline.reorder.gb_per_s,roofline.reorder.gflop_per_s,roofline.grid_fit.bytes_per_particle_step,\
roofline.grid_fit.flops_per_particle_step,roofline.grid_fit.ns_per_particle_step,\
roofline.grid_fit.gb_per_s,roofline.grid_fit.gflop_per_s,roofline.binning.bytes_per_particle_step,\
roofline.binning.flops_per_particle_step,roofline.binning.ns_per_particle_step,\
roofline.binning.gb_per_s,roofline.binning.gflop_per_s,roofline.scatter.bytes_per_particle_step,\
roofline.scatter.flops_per_particle_step,roofline.scatter.ns_per_particle_step,\
roofline.scatter.gb_per_s,roofline.scatter.gflop_per_s,roofline.assembly.bytes_per_particle_step,\
roofline.assembly.flops_per_particle_step,roofline.assembly.ns_per_particle_step,\
roofline.assembly.gb_per_s,roofline.assembly.gflop_per_s,\
roofline.grid_update.bytes_per_particle_step,roofline.grid_update.flops_per_particle_step,\
roofline.grid_update.ns_per_particle_step,roofline.grid_update.gb_per_s,\
roofline.grid_update.gflop_per_s,roofline.gather.bytes_per_particle_step,\
roofline.gather.flops_per_particle_step,roofline.gather.ns_per_particle_step,\
roofline.gather.gb_per_s,roofline.gather.gflop_per_s,roofline.remap_scatter.bytes_per_particle_step,\
roofline.remap_scatter.flops_per_particle_step,roofline.remap_scatter.ns_per_particle_step,\
roofline.remap_scatter.gb_per_s,roofline.remap_scatter.gflop_per_s,\
roofline.remap_assembly.bytes_per_particle_step,roofline.remap_assembly.flops_per_particle_step,\
roofline.remap_assembly.ns_per_particle_step,roofline.remap_assembly.gb_per_s,\
roofline.remap_assembly.gflop_per_s,roofline.stress_update.bytes_per_particle_step,\
roofline.stress_update.flops_per_particle_step,roofline.stress_update.ns_per_particle_step,\
roofline.stress_update.gb_per_s,roofline.stress_update.gflop_per_s,steady_s_per_step,\
ns_per_particle_step,particle_steps_per_s,worker_busy_s,load_imbalance,dd_layout,\
dd_patch_particles.min,dd_patch_particles.mean,dd_patch_particles.max,\
dd_patch_particles.imbalance_mean,dd_patch_particles.imbalance_max,peak_rss_bytes,\
peak_rss_sum_bytes,model_memory_bytes,kinetic_energy_initial,internal_energy_initial,kinetic_energy,\
internal_energy,momentum_initial,momentum,failed_particles,energy.initial_kinetic_j,\
energy.initial_internal_j,energy.initial_total_j,energy.final_kinetic_j,energy.final_internal_j,\
energy.final_total_j,energy.body_force_work_j,energy.max_rise,energy.max_rise_step,energy.max_fall,\
energy.max_fall_step,energy.negative_internal_final,energy.negative_internal_max,\
energy.negative_internal_steps,energy.first_negative_internal_step,energy.failed_energy_floors,\
energy.failed_energy_floor_j,rank_particles,rank_busy_imbalance,migrated_particles,comm_s_per_step,\
comm_frac,wait_s_per_step,wait_frac,comm_bytes_per_step,comm_messages_per_step,work.bytes.reorder,\
work.bytes.grid_fit,work.bytes.binning,work.bytes.scatter,work.bytes.assembly,\
work.bytes.grid_update,work.bytes.gather,work.bytes.remap_scatter,work.bytes.remap_assembly,\
work.bytes.stress_update,work.worker_bytes,work.serial_bytes,work.balance,work.overhead,\
work.efficiency_bound,noise.wall_s,noise.workers.cpu_s,noise.workers.cpu_share,\
noise.workers.involuntary_switches,noise.workers.voluntary_switches,noise.workers.steal_frac,\
noise.min_cpu_share,noise.threshold,noise.low_cpu_share,cpu_quota,paired.reference_threads,\
measured.paired.blocks,paired.block_steps,paired.reference_cpus,paired.t1_s_per_step,\
paired.tt_s_per_step,paired.reference_first,paired.block_efficiency,paired.efficiency,\
paired.reference_steady_substages.reorder,paired.reference_steady_substages.grid_fit,\
paired.reference_steady_substages.binning,paired.reference_steady_substages.scatter,\
paired.reference_steady_substages.assembly,paired.reference_steady_substages.grid_update,\
paired.reference_steady_substages.gather,paired.reference_steady_substages.remap_scatter,\
paired.reference_steady_substages.remap_assembly,paired.reference_steady_substages.stress_update,\
paired.reference_noise.wall_s,paired.reference_noise.workers.cpu_s,\
paired.reference_noise.workers.cpu_share,paired.reference_noise.workers.involuntary_switches,\
paired.reference_noise.workers.voluntary_switches,paired.reference_noise.workers.steal_frac,\
paired.reference_noise.min_cpu_share,paired.reference_noise.threshold,\
paired.reference_noise.low_cpu_share,paired.max_position_difference,paired.reference_grid_stage_s,\
paired.reference_particle_stage_s,checkpoint.written,checkpoint.write_s,checkpoint.last_bytes,\
checkpoint.restarts,checkpoint.restart_steps,checkpoint.restart_setup_s,injected_s,injected_step_s,scenario,\
initial_length_m,final_length_m,initial_face_diameter_m,face_diameter_m,cloud_front_m,\
cloud_front_robust_m,cloud_width_m,cloud_width_robust_m,hole_diameter_m,front_velocity_m_s,\
debris_mass_kg,spacing_m,leading_debris_velocity_m_s,slab_length_m,shock_speed_m_s,\
shock_pressure_pa,shock_mean_pressure_pa,particle_velocity_m_s,rh_shock_speed_m_s,rh_pressure_pa,\
rh_particle_velocity_m_s,shock_speed_rel_error,shock_pressure_rel_error,particle_velocity_rel_error,\
shock_front_samples,host_load1_before,host_load1_after,host_others_running_before,\
host_others_running_after,host_cpus_busy_before,host_cpus_busy_after,host_steal_frac,\
calib_spin_ratio,calib_copy_ratio,host_noisy,host_noise,status,reason,exit_code,process_wall_s,\
mem_estimate_bytes,lost_compute_s";
    assert_eq!(Row::header().join(","), want);
}

#[test]
fn resume_refuses_a_csv_with_missing_columns() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let m = laptop();
    let d = schedule::state::campaign_dir(dir.path(), &m, &c);
    std::fs::create_dir_all(&d).unwrap();
    std::fs::write(d.join("runs.csv"), "schema_version,campaign_id,model\n1,smoke,1\n").unwrap();
    let flag = AtomicBool::new(false);
    let e =
        schedule::execute(&c, &m, &mock_solvers(&c), &mut MockRunner::default(), &opts(dir.path()), &flag).unwrap_err();
    let msg = format!("{e:#}");
    assert!(msg.contains("missing column") && msg.contains("observed_cpus"), "{msg}");
    // The old file is untouched.
    assert_eq!(std::fs::read_to_string(d.join("runs.csv")).unwrap(), "schema_version,campaign_id,model\n1,smoke,1\n");
    // A file of this schema without one of its columns (host_noise) is refused, naming it:
    // its rows would read that column as its default, not as written.
    let header: Vec<String> = Row::header().into_iter().filter(|h| h != "host_noise").collect();
    std::fs::write(d.join("runs.csv"), header.join(",") + "\n").unwrap();
    let e =
        schedule::execute(&c, &m, &mock_solvers(&c), &mut MockRunner::default(), &opts(dir.path()), &flag).unwrap_err();
    assert!(format!("{e:#}").contains("lacks 1 column(s) of CSV schema 10 (host_noise)"), "{e:#}");
    // A readable file of an older schema (the header of the committed schema-7 campaign) is
    // not appended to: a new folder starts.
    let v7 =
        std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/54276cbdfe10/quick/runs.csv"))
            .unwrap();
    std::fs::write(d.join("runs.csv"), v7.lines().next().unwrap().to_string() + "\n").unwrap();
    let mut r = MockRunner::default();
    let s = schedule::execute(&c, &m, &mock_solvers(&c), &mut r, &opts(dir.path()), &flag).unwrap();
    assert_eq!((s.dir, r.calls.len()), (d.with_file_name("smoke-2"), 8));
}

fn bench() -> Command {
    Command::new(env!("CARGO_BIN_EXE_mpm-bench"))
}

/// `mpm-bench topology` on the paper's two quad-core sockets prints OpenMP's placement for
/// every binding, and `--pin` / `--places` / `@places` are understood.
#[test]
fn topology_prints_openmp_placements() {
    let table = |extra: &[&str]| {
        let mut args = vec!["topology", "--synthetic", "pack:2 core:4 pu:1", "--threads", "2,4,8"];
        args.extend_from_slice(extra);
        let out = bench().args(&args).output().unwrap();
        assert!(out.status.success(), "{args:?}: {}", String::from_utf8_lossy(&out.stderr));
        String::from_utf8(out.stdout).unwrap()
    };
    let row = |text: &str, threads: &str| -> String {
        text.lines().find(|l| l.split_whitespace().next() == Some(threads)).unwrap_or_default().to_string()
    };
    let spread = table(&["--places", "cores", "--bind", "spread"]);
    assert!(spread.contains("Places cores (8): {0},{1},{2},{3},{4},{5},{6},{7}"), "{spread}");
    assert_eq!(row(&spread, "4").split_whitespace().nth(1), Some("0,2,4,6"), "{spread}");
    assert_eq!(row(&spread, "2").split_whitespace().nth(1), Some("0,4"), "{spread}");
    let close = table(&["--pin", "close"]);
    assert_eq!(row(&close, "4").split_whitespace().nth(1), Some("0,1,2,3"), "{close}");
    let primary = table(&["--bind", "primary"]);
    assert_eq!(row(&primary, "2").split_whitespace().collect::<Vec<_>>(), ["2", "0,0", "*"], "{primary}");
    let sockets = table(&["--bind", "close", "--places", "sockets"]);
    assert!(sockets.contains("close@sockets"), "{sockets}");
    assert_eq!(row(&sockets, "4").split_whitespace().nth(1), Some("0,1,4,5"), "{sockets}");
    let all = table(&[]);
    for b in ["close", "spread", "primary", "none"] {
        assert!(all.lines().any(|l| l.starts_with("threads") && l.contains(b)), "{all}");
    }
    // Ranks: each rank's slice of the placement of all its workers.
    let ranks = table(&["--bind", "spread", "--ranks", "2"]);
    assert!(ranks.lines().any(|l| l.trim() == "spread           2 x 2   0,2 | 4,6"), "{ranks}");
    assert!(
        ranks.lines().any(|l| l.trim() == "spread           2 x 8   0,1,2,3,4,5,6,7 | 0,1,2,3,4,5,6,7 *"),
        "{ranks}"
    );
    fails_cleanly(&["topology", "--ranks", "0"], "at least 1");
    fails_cleanly(&["topology", "--places", "bogus"], "unknown places");
    fails_cleanly(&["topology", "--bind", "sideways"], "unknown binding");
}

fn fails_cleanly(args: &[&str], needle: &str) {
    let out = bench().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success(), "{args:?} should fail");
    assert!(err.contains(needle), "{args:?}: stderr {err}");
    assert!(!err.contains("panicked"), "{args:?}: {err}");
}

/// Negative numbers are values, refused naming the flag; absurd sizes are refused before
/// anything is planned; an output is never written over a campaign's own record.
#[test]
fn negative_absurd_and_self_destroying_input_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let run = |extra: &[&str]| -> Vec<String> {
        ["run", "--preset", "smoke", "--mock", "--dry-run", "--out", out]
            .iter()
            .chain(extra)
            .map(|s| s.to_string())
            .collect()
    };
    let fails = |args: Vec<String>, needle: &str| {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        fails_cleanly(&a, needle);
        let err = String::from_utf8_lossy(&bench().args(&a).output().unwrap().stderr).into_owned();
        assert!(!err.contains("unexpected argument") && !err.contains("invalid digit"), "{a:?}: {err}");
    };
    fails(run(&["--reps", "-1"]), "--reps <N>: -1 is negative");
    fails(run(&["--steps", "-1"]), "-1 is negative");
    fails(run(&["--warmup", "-1"]), "-1 is negative");
    fails(run(&["--threads", "-2"]), "-2");
    fails(run(&["--inject-slowdown", "-0.1"]), "fraction");
    fails(run(&["--reps", "100000"]), "more than the 1000 a campaign plans");
    fails(run(&["--mem-limit", "0"]), "would skip every run");
    fails(["paired", "--blocks", "-3"].map(String::from).to_vec(), "-3 is negative");
    fails(["calibrate", "--preset", "ci", "--reps", "-2"].map(String::from).to_vec(), "-2 is negative");
    // A Cargo profile for a level that cannot be one: refused naming the variable.
    let bad = bench()
        .args(["run", "--preset", "smoke", "--no-build", "--quiet", "--out", out])
        .env_remove("MPM_BENCH_SOLVER_O3")
        .env_remove("MPM_BENCH_SOLVER_O0")
        .env("MPM_BENCH_CARGO_PROFILE_O3", "o3 --offline")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&bad.stderr);
    assert_eq!(bad.status.code(), Some(2), "{err}");
    assert!(err.contains("MPM_BENCH_CARGO_PROFILE_O3=\"o3 --offline\" is not a Cargo profile name"), "{err}");
    // regress --json over the campaign's runs.csv: refused, the file untouched.
    let camp = write_campaign_for_regress(dir.path());
    let csv = camp.join("runs.csv");
    let before = std::fs::read(&csv).unwrap();
    let c = camp.to_str().unwrap();
    fails(
        ["regress", "--baseline", c, "--current", c, "--tolerance", "-0.05"].map(String::from).to_vec(),
        "out of range",
    );
    fails(
        ["regress", "--baseline", c, "--current", c, "--json", csv.to_str().unwrap()].map(String::from).to_vec(),
        "is a campaign's own record",
    );
    let md = camp.join("manifest.json");
    fails(
        ["regress", "--baseline", c, "--current", c, "--markdown", md.to_str().unwrap()].map(String::from).to_vec(),
        "is a campaign's own record",
    );
    assert_eq!(std::fs::read(&csv).unwrap(), before, "runs.csv untouched");
}

/// A small finished mock campaign under `root`: its folder.
fn write_campaign_for_regress(root: &Path) -> PathBuf {
    let out = root.join("camp");
    let o = bench()
        .args(["run", "--preset", "smoke", "--mock", "--quiet", "--out", out.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let csv = mpm_bench::analysis::results::find_campaigns(&out).unwrap();
    csv[0].clone()
}

#[test]
fn cli_errors_are_clear() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    fails_cleanly(&["run", "--preset", "nope", "--mock", "--out", out], "unknown preset 'nope'");
    fails_cleanly(&["run", "--preset", "smoke", "--models", "5", "--mock", "--out", out], "unknown model 5");
    fails_cleanly(&["run", "--preset", "smoke", "--threads", "0,2", "--mock", "--out", out], "at least 1");
    fails_cleanly(
        &["run", "--preset", "smoke", "--ranks", "0,2", "--mock", "--out", out],
        "rank counts must be at least 1",
    );
    fails_cleanly(&["run", "--preset", "smoke", "--ranks", "1,x", "--mock", "--out", out], "'x' is not a rank count");
    fails_cleanly(
        &["run", "--preset", "hybrid", "--launcher", "mpirun -n 2", "--mock", "--out", out],
        "no {ranks} placeholder",
    );
    fails_cleanly(&["run", "--preset", "smoke", "--pin", "0,x", "--mock", "--out", out], "bad CPU list");
    fails_cleanly(&["run", "--preset", "smoke", "--pin", "9999", "--mock", "--out", out], "cannot use");
    fails_cleanly(&["run", "--preset", "smoke", "--mock", "--out", "/proc/no-such-dir"], "output folder");
    // A Slurm option without Slurm: refused naming it.
    for (flag, given) in [
        ("--partition", &["--partition", "p"][..]),
        ("--detach", &["--detach"]),
        ("--sbatch-arg", &["--sbatch-arg=--qos=normal"]),
    ] {
        let args: Vec<&str> = ["run", "--preset", "smoke"]
            .into_iter()
            .chain(given.iter().copied())
            .chain(["--mock", "--out", out])
            .collect();
        fails_cleanly(&args, &format!("{flag} is an option of --scheduler slurm"));
    }
    fails_cleanly(&["run", "--preset", "smoke", "--scheduler", "slurm", "--mock", "--out", out], "cannot go to Slurm");
    fails_cleanly(
        &["run", "--preset", "smoke", "--scheduler", "slurm", "--sbatch-arg=--requeue", "--out", out],
        "--sbatch-arg '--requeue' is refused: --requeue is set by the harness",
    );
    fails_cleanly(&["run", "--preset", "smoke", "--scheduler", "pbs", "--out", out], "invalid value 'pbs'");
    fails_cleanly(&["topology", "--pin", "0,x"], "bad CPU list");
    fails_cleanly(&["paired", "--model", "7"], "Models 1-4");
    fails_cleanly(&["paired", "--threads", "0"], "use 2 or more");
    fails_cleanly(&["paired", "--strategies", "ae,zz"], "unknown strategy 'zz'");
    fails_cleanly(&["paired", "--pin", "0,x"], "bad CPU list");
    let help = bench().args(["run", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    for flag in [
        "--preset",
        "--models",
        "--threads",
        "--ranks",
        "--launcher",
        "--strategies",
        "--opt",
        "--reps",
        "--pin",
        "--steps",
        "--end-time",
        "--out",
        "--seed",
        "--dry-run",
        "--scheduler",
        "--partition",
        "--max-jobs",
        "--detach",
        "--poll-interval",
        "--sbatch-arg",
        "Examples",
    ] {
        assert!(help.contains(flag), "help lacks {flag}");
    }
}

/// The manycore preset's dry run on this machine: the thread counts above its usable cores
/// are skipped and said, none is planned oversubscribed. `--skip-above-cores` does the same
/// for any preset, refuses a campaign left with nothing, and `--assume-cores` plans (and
/// estimates) for another machine.
#[test]
fn thread_counts_above_the_cores_are_skipped_not_oversubscribed() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let cores = Machine::detect().unwrap().num_cores();
    let dry = |args: &[&str]| {
        let o = bench().args(["run", "--dry-run", "--out", out]).args(args).output().unwrap();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        (String::from_utf8(o.stdout).unwrap(), String::from_utf8(o.stderr).unwrap())
    };
    let planned = |listing: &str| -> Vec<usize> {
        let runs: Vec<&str> = listing.lines().filter(|l| l.contains(" thr pin ")).collect();
        assert!(runs.iter().all(|l| !l.contains("oversubscribed")), "{listing}");
        let mut t: Vec<usize> =
            runs.iter().filter_map(|l| l.split(" thr pin").next()?.split(' ').next_back()?.parse().ok()).collect();
        t.sort_unstable();
        t.dedup();
        t
    };
    let (listing, err) = dry(&["--preset", "manycore"]);
    let above: Vec<String> = [1, 2, 4, 8, 16].iter().filter(|&&t| t > cores).map(|t| t.to_string()).collect();
    if !above.is_empty() {
        let note = format!(
            "note: {cores} usable core(s) here: the runs of {} threads are skipped, not run oversubscribed",
            above.join("/")
        );
        assert!(err.contains(&note), "{err}");
    }
    let threads = planned(&listing);
    assert!(!threads.is_empty() && threads.iter().all(|&t| t <= cores), "{threads:?} on {cores} cores");
    // Any preset, with the flag; and as for a machine of 4096 cores, estimated (mock solver).
    let (listing, err) = dry(&["--preset", "smoke", "--threads", "1,4096", "--skip-above-cores"]);
    assert!(err.contains("the runs of 4096 threads are skipped"), "{err}");
    assert_eq!(planned(&listing), vec![1]);
    let (listing, _) =
        dry(&["--preset", "smoke", "--threads", "1,4096", "--skip-above-cores", "--assume-cores", "4096", "--mock"]);
    assert!(listing.contains("planned for a machine of 4096 usable core(s)"), "{listing}");
    assert!(
        listing.lines().any(|l| l.starts_with("estimated duration: about") && l.contains("on 4096 core(s)")),
        "{listing}"
    );
    assert_eq!(planned(&listing), vec![1, 4096]);
    fails_cleanly(
        &["run", "--preset", "smoke", "--threads", "4096", "--skip-above-cores", "--dry-run", "--out", out],
        "nothing is left to run",
    );
    fails_cleanly(&["run", "--preset", "smoke", "--assume-cores", "16", "--out", out], "--dry-run");
}

#[test]
fn cli_mock_campaign_resumes_and_topology_prints() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let args = ["run", "--preset", "smoke", "--threads", "1,4", "--mock", "--out", out];
    let first = bench().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&first.stderr);
    assert!(first.status.success(), "{err}");
    assert!(err.contains("8 rows written"), "{err}");
    assert_eq!(err.matches("oversubscribed (time sharing").count(), 1, "said once: {err}");
    // scripts/reproduce.sh reads the campaign folder from standard output.
    let stdout = String::from_utf8_lossy(&first.stdout);
    let folder = stdout.lines().find_map(|l| l.strip_prefix("campaign folder: ")).expect("campaign folder line");
    assert!(Path::new(folder).join("runs.csv").is_file(), "{folder}");
    let second = bench().args(args).output().unwrap();
    assert!(String::from_utf8_lossy(&second.stderr).contains("0 rows written"));
    let topo = bench().arg("topology").output().unwrap();
    let text = String::from_utf8_lossy(&topo.stdout);
    assert!(topo.status.success());
    for want in ["Package", "Core", "close", "spread", "none", "Caches"] {
        assert!(text.contains(want), "topology lacks {want}: {text}");
    }
}

/// The one real end-to-end test: the smoke preset (Model 1, 1-2 threads, AE and DD, O3 and
/// O0, a few steps) through the `mpm-bench` binary, which builds or finds both `mpm`
/// binaries itself, into a temporary folder. Then a second run must add nothing.
#[test]
fn end_to_end_smoke_campaign_with_the_real_solver() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let t0 = std::time::Instant::now();
    let first = bench().args(["run", "--preset", "smoke", "--out", out, "--quiet"]).output().unwrap();
    let err = String::from_utf8_lossy(&first.stderr);
    assert!(first.status.success(), "smoke campaign failed: {err}");
    eprintln!("smoke campaign (with builds): {:.1} s", t0.elapsed().as_secs_f64());
    let m = Machine::detect().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let d = schedule::state::campaign_dir(dir.path(), &m, &c);
    let rows = read_rows(&d.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), c.expand().len());
    for r in &rows {
        assert_eq!(r.outcome.status, Status::Ok, "{}: {}", r.id.run_id, r.outcome.reason);
        assert_eq!(r.measured.as_ref().map(|f| f.size.particles as u64), Some(56_056));
        assert_eq!(r.measured.as_ref().map(|f| f.progress.steps), r.run.spec.budget.steps, "{}", r.id.run_id);
        assert_eq!(r.measured.as_ref().map(|f| f.progress.end_reason), Some(EndReason::StepLimit));
        for (name, v) in [
            ("wall_s", r.measured.as_ref().map(|f| f.timing.wall_s)),
            ("process_wall_s", r.outcome.process_wall_s),
            ("grid_stage_s", r.measured.as_ref().map(|f| f.timing.grid_stage_s)),
            ("particle_stage_s", r.measured.as_ref().map(|f| f.timing.particle_stage_s)),
            (
                "substages.scatter",
                r.measured.as_ref().map(|f| f.timing.substages.clone()).unwrap_or_default().get(Substage::Scatter),
            ),
            (
                "substages.stress_update",
                r.measured.as_ref().map(|f| f.timing.substages.clone()).unwrap_or_default().get(Substage::StressUpdate),
            ),
            ("steady_grid_stage_s", r.measured.as_ref().and_then(|f| f.timing.steady_grid_stage_s)),
            ("steady_particle_stage_s", r.measured.as_ref().and_then(|f| f.timing.steady_particle_stage_s)),
            ("steady_s_per_step", r.measured.as_ref().and_then(|f| f.timing.steady_s_per_step)),
            ("ns_per_particle_step", r.measured.as_ref().and_then(|f| f.timing.ns_per_particle_step)),
            ("kinetic_energy_j", r.measured.as_ref().map(|f| f.physics.kinetic_energy)),
            ("final_length_m", r.measured.as_ref().and_then(|f| f.scenario.taylor()?.final_length_m)),
            ("face_diameter_m", r.measured.as_ref().and_then(|f| f.scenario.taylor()?.face_diameter_m)),
        ] {
            assert!(v.is_some_and(|x| x.is_finite() && x >= 0.0), "{}: {name} = {v:?}", r.id.run_id);
        }
        assert!(r.measured.as_ref().and_then(|f| f.memory.peak_rss_bytes).is_some_and(|b| b > 1 << 20));
        assert!(!r.placement.requested_cpus.is_empty() && r.placement.requested_cpus == r.placement.observed_cpus);
        assert_eq!(r.id.binary_sha256.len(), 16);
        assert_ne!(r.id.git_commit, "");
    }
    let opts: HashSet<_> = rows.iter().map(|r| (r.opt(), r.id.binary_sha256.clone())).collect();
    assert_eq!(opts.len(), 2, "o3 and o0 are different binaries");
    for f in ["manifest.json", "topology.xml"] {
        assert!(d.join(f).is_file(), "{f}");
    }
    let man = mpm_bench::campaign::store::manifest::read(&d.join("manifest.json")).unwrap();
    assert_eq!(man.software.binaries.len(), 2);
    // Each level built with its Cargo profile (scripts/test.sh names o3-test for o3, and the
    // tests' own build of it in MPM_BENCH_SOLVER_O3; o0 is built here), where the manifest
    // says, with the variable that chose it.
    for (level, b) in [("o3", &man.software.binaries[0]), ("o0", &man.software.binaries[1])] {
        let key = format!("MPM_BENCH_CARGO_PROFILE_{}", level.to_ascii_uppercase());
        let profile = std::env::var(&key).unwrap_or_else(|_| level.to_string());
        assert_eq!(b.opt_level, level);
        assert!(b.path.ends_with(&format!("/{profile}/mpm")), "{level}: {} (profile {profile})", b.path);
        assert_eq!(man.software.env.get(&key), std::env::var(&key).ok().as_ref(), "{key} recorded");
    }
    // Resume: nothing added.
    let second = bench().args(["run", "--preset", "smoke", "--out", out, "--quiet", "--no-build"]).output().unwrap();
    assert!(second.status.success(), "{}", String::from_utf8_lossy(&second.stderr));
    assert_eq!(read_rows(&d.join("runs.csv")).unwrap().len(), rows.len());
}

/// Checkpoints in a campaign, with the real solver: a campaign interrupted (SIGINT) in the
/// middle of a run, then resumed with a time-out shorter than the run, continues the run from
/// its checkpoints attempt after attempt until it ends; its row records the restarts and the
/// compute time lost, the failed attempts' rows say they timed out, the checkpoints are
/// removed, and the physics are bitwise those of the run made in one go.
#[test]
fn interrupted_and_timed_out_runs_continue_from_their_checkpoints() {
    let dir = tempfile::tempdir().unwrap();
    let preset = dir.path().join("ckpt.toml");
    std::fs::write(
        &preset,
        "name = \"ckpt\"\ndescription = \"checkpoints\"\nscenario = \"taylor\"\nmodels = [1]\nthreads = [1]\n\
         strategies = [\"serial\"]\nopt = [\"o3\"]\nreps = 1\npin = \"close\"\ngrid = \"fixed\"\nseed = 1\n\
         timeout = \"3s\"\ncheckpoint_every = 10\n\n[budget]\nsteps = 400\nwarmup = 2\n",
    )
    .unwrap();
    let out = dir.path().join("out");
    let args = ["run", "--preset", preset.to_str().unwrap(), "--out", out.to_str().unwrap(), "--quiet"];
    let (p, src) = preset::load_preset(preset.to_str().unwrap(), None).unwrap();
    let c = Campaign::resolve(p, src, &Overrides::default()).unwrap();
    assert_eq!(c.checkpoint_every, Some(mpm_spec::spec::CheckpointEvery::Steps(10)));
    let d = schedule::state::campaign_dir(&out, &Machine::detect().unwrap(), &c);
    let checkpoints = d.join("checkpoints");
    let has_checkpoint = || {
        std::fs::read_dir(&checkpoints).is_ok_and(|rd| {
            rd.flatten().any(|e| {
                std::fs::read_dir(e.path())
                    .is_ok_and(|r| r.flatten().any(|f| f.file_name().to_string_lossy().starts_with("step-")))
            })
        })
    };
    // 1. Interrupted once the run has a checkpoint: no row, the attempt's loss booked.
    let child = bench().args(args).stderr(std::process::Stdio::null()).spawn().unwrap();
    let t0 = std::time::Instant::now();
    while !has_checkpoint() {
        assert!(t0.elapsed().as_secs() < 900, "no checkpoint after 15 minutes (building mpm included)");
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap().success());
    assert_eq!(child.wait_with_output().unwrap().status.code(), Some(130));
    let csv = d.join("runs.csv");
    assert!(read_rows(&csv).map_or(true, |r| r.is_empty()), "an interrupted run writes no row");
    let log = std::fs::read_dir(&checkpoints)
        .unwrap()
        .flatten()
        .find(|e| e.file_name().to_string_lossy().ends_with(".attempts.json"))
        .unwrap()
        .path();
    assert!(std::fs::read_to_string(&log).unwrap().contains("interrupted"));
    // 2. Resumed until the run ends, every attempt cut by the 3 s time-out but for the last.
    // About 4 attempts on a quiet 2-core host; on a loaded one each attempt gets less CPU
    // and fewer steps, but every attempt continues from the last checkpoint, so the run
    // still ends (the restarts count below proves the continuation), only later.
    let mut sessions = 0;
    while !read_rows(&csv).unwrap_or_default().iter().any(|r| r.outcome.status == Status::Ok) {
        sessions += 1;
        assert!(
            sessions <= 60,
            "the run never finished: {:?}",
            read_rows(&csv).unwrap_or_default().iter().map(|r| r.outcome.reason.clone()).collect::<Vec<_>>()
        );
        let r = bench().args(args).args(["--no-build", "--allow-failures"]).output().unwrap();
        assert!(r.status.success(), "{}", String::from_utf8_lossy(&r.stderr));
    }
    let rows = read_rows(&csv).unwrap();
    let (ok, failed): (Vec<&Row>, Vec<&Row>) = rows.iter().partition(|r| r.outcome.status == Status::Ok);
    assert_eq!(ok.len(), 1);
    let ok = ok[0];
    assert_eq!(ok.measured.as_ref().map(|f| f.progress.steps), Some(400));
    assert_eq!(
        ok.measured.as_ref().and_then(|f| f.checkpoint.as_ref().map(|c| c.restarts)),
        Some(1 + failed.len() as u32),
        "every attempt after the first continued"
    );
    assert!(
        ok.measured.as_ref().and_then(|f| f.checkpoint.as_ref().map(|c| c.written)).is_some_and(|n| n >= 39),
        "{:?}",
        ok.measured.as_ref().and_then(|f| f.checkpoint.as_ref().map(|c| c.written))
    );
    assert!(
        ok.measured.as_ref().and_then(|f| f.checkpoint.as_ref().map(|c| c.write_s)).is_some_and(|s| s > 0.0)
            && ok
                .measured
                .as_ref()
                .and_then(|f| f.checkpoint.as_ref().map(|c| c.restart_setup_s))
                .is_some_and(|s| s > 0.0)
    );
    let lost = ok.outcome.lost_compute_s.unwrap();
    for f in &failed {
        assert!(f.outcome.reason.contains("timed out"), "{}", f.outcome.reason);
        assert!(f.outcome.lost_compute_s.is_some_and(|l| l > 0.0 && l <= lost));
    }
    assert!(lost > 0.0 && lost < 3.5 * (1 + failed.len()) as f64, "lost {lost} s over {} attempts", 1 + failed.len());
    assert!(std::fs::read_dir(&checkpoints).unwrap().next().is_none(), "a finished run's checkpoints are removed");
    // 3. The physics of the run made in one go, bit for bit.
    let man = mpm_bench::campaign::store::manifest::read(&d.join("manifest.json")).unwrap();
    let mpm = &man.software.binaries[0].path;
    let json = dir.path().join("whole.json");
    let whole = Command::new(mpm)
        .args(["run", "taylor", "--model", "1", "--steps", "400", "--warmup", "2", "--quiet", "--json"])
        .arg(&json)
        .output()
        .unwrap();
    assert!(whole.status.success());
    let s: mpm_spec::Summary = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(
        ok.measured.as_ref().map(|f| f.physics.kinetic_energy).map(f64::to_bits),
        Some(s.figures.physics.kinetic_energy.to_bits())
    );
    assert_eq!(
        ok.measured.as_ref().map(|f| f.physics.internal_energy).map(f64::to_bits),
        Some(s.figures.physics.internal_energy.to_bits())
    );
    assert_eq!(
        ok.measured.as_ref().and_then(|f| f.scenario.taylor()?.final_length_m).map(f64::to_bits),
        s.figures.scenario.taylor().and_then(|t| t.final_length_m).map(f64::to_bits)
    );
    assert_eq!(
        ok.measured.as_ref().map(|f| f.size.mean_nodes).map(f64::to_bits),
        Some(s.figures.size.mean_nodes.to_bits())
    );
}

/// Ctrl-C (SIGINT) in the middle of a campaign leaves a valid CSV with every finished run,
/// and the same command later completes the campaign.
#[test]
fn sigint_leaves_a_valid_csv_and_the_campaign_resumes() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let args = ["run", "--preset", "smoke", "--mock", "--out", out, "--quiet"];
    let child =
        bench().args(args).env("MPM_BENCH_MOCK_DELAY_MS", "400").stderr(std::process::Stdio::null()).spawn().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let d = schedule::state::campaign_dir(dir.path(), &Machine::detect().unwrap(), &c);
    // Interrupt once the first row is written (the start calibration takes about a second).
    for _ in 0..600 {
        if std::fs::read_to_string(d.join("runs.csv")).is_ok_and(|t| t.lines().count() >= 2) {
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    let killed = Command::new("kill").args(["-INT", &child.id().to_string()]).status().unwrap();
    assert!(killed.success());
    let status = child.wait_with_output().unwrap().status;
    assert_eq!(status.code(), Some(130), "an interrupted campaign exits 130");
    let rows = read_rows(&d.join("runs.csv")).unwrap();
    assert!(!rows.is_empty() && rows.len() < 8, "{} rows", rows.len());
    let man = mpm_bench::campaign::store::manifest::read(&d.join("manifest.json")).unwrap();
    assert!(man.sessions[0].counts.interrupted);
    let again = bench().args(args).output().unwrap();
    assert!(again.status.success());
    let rows = read_rows(&d.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 8);
    assert_eq!(rows.iter().map(Row::key).collect::<HashSet<_>>().len(), 8);
}

/// A torn last line of runs.csv (a write cut short) is moved aside before the file is
/// parsed, the analysis commands read around it with a warning, and resuming redoes that run:
/// the campaign completes with no duplicate and no lost row.
#[test]
fn torn_last_line_is_moved_aside_and_the_campaign_completes() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let m = laptop();
    let s = interrupted_after_3(&c, &m, dir.path());
    let csv = s.dir.join("runs.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    let last = text.lines().last().unwrap();
    let torn = format!("{}{}", &text[..text.len() - last.len() - 1], &last[..last.len() / 2]);
    std::fs::write(&csv, &torn).unwrap();
    let claims = bench().args(["claims", "--results", s.dir.to_str().unwrap()]).output().unwrap();
    let err = String::from_utf8_lossy(&claims.stderr);
    assert!(claims.status.success(), "claims failed on a torn file: {err}");
    assert!(err.contains("torn line"), "{err}");
    assert_eq!(std::fs::read_to_string(&csv).unwrap(), torn, "analysis must not change the file");
    let mut r = MockRunner::default();
    let s = run_mock(&c, &m, dir.path(), &mut r);
    assert_eq!((s.counts.already_done, r.calls.len()), (2, 6), "the torn run is redone");
    let rows = read_rows(&csv).unwrap();
    assert_eq!(rows.len(), 8);
    assert_eq!(rows.iter().map(Row::key).collect::<HashSet<_>>().len(), 8, "no duplicate");
    let aside: Vec<_> = std::fs::read_dir(&s.dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("runs.csv.torn-"))
        .collect();
    assert_eq!(aside.len(), 1);
    assert_eq!(std::fs::read_to_string(aside[0].path()).unwrap(), &last[..last.len() / 2]);
}

/// A stand-in for `mpm`: reserves its summary file the way `mpm` does
/// (`.<name>.tmp.<pid>`), writes its pid to `$FAKE_PIDFILE`, then fails at once
/// (`$FAKE_FAIL` set) or runs for five minutes.
const FAKE_SOLVER: &str = r#"#!/bin/sh
while [ $# -gt 0 ]; do
    if [ "$1" = --spec ]; then spec="$2"; fi
    shift
done
json=$(sed -n 's/^json = "\(.*\)"$/\1/p' "$spec")
: > "$(dirname "$json")/.$(basename "$json").tmp.$$"
echo $$ > "$FAKE_PIDFILE.part" && mv "$FAKE_PIDFILE.part" "$FAKE_PIDFILE"
if [ -n "$FAKE_FAIL" ]; then exit 3; fi
exec sleep 300
"#;

/// `mpm-bench run` of one configuration with the fake solver in `dir`, into `dir/out`.
fn fake_campaign(dir: &Path, fail: bool) -> Command {
    use std::os::unix::fs::PermissionsExt;
    let solver = dir.join("fake-mpm");
    if !solver.exists() {
        std::fs::write(&solver, FAKE_SOLVER).unwrap();
        std::fs::set_permissions(&solver, std::fs::Permissions::from_mode(0o755)).unwrap();
    }
    let _ = std::fs::remove_file(dir.join("pid"));
    let mut cmd = bench();
    cmd.args(["run", "--preset", "smoke", "--models", "1", "--threads", "1", "--strategies", "dd", "--opt", "o3"])
        .args(["--no-build", "--quiet", "--out", dir.join("out").to_str().unwrap()])
        .env("MPM_BENCH_SOLVER_O3", &solver)
        .env("FAKE_PIDFILE", dir.join("pid"))
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null());
    if fail {
        cmd.env("FAKE_FAIL", "1");
    }
    cmd
}

/// The pid the fake solver wrote (waits up to 20 s for it).
fn fake_solver_pid(dir: &Path) -> i32 {
    for _ in 0..400 {
        if let Some(pid) = std::fs::read_to_string(dir.join("pid")).ok().and_then(|s| s.trim().parse().ok()) {
            return pid;
        }
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
    panic!("the fake solver did not start");
}

/// Whether process `pid` is gone (or a zombie waiting for its new parent to reap it),
/// waiting up to 5 s.
fn gone(pid: i32) -> bool {
    for _ in 0..100 {
        match std::fs::read_to_string(format!("/proc/{pid}/stat")) {
            Err(_) => return true,
            Ok(stat) if stat.rsplit_once(')').is_some_and(|(_, rest)| rest.trim_start().starts_with('Z')) => {
                return true
            }
            Ok(_) => std::thread::sleep(std::time::Duration::from_millis(50)),
        }
    }
    false
}

/// Temporary files (`.<name>.tmp.<pid>`) anywhere under `dir`.
fn temp_files(dir: &Path) -> Vec<std::path::PathBuf> {
    let mut out = Vec::new();
    for e in std::fs::read_dir(dir).into_iter().flatten().flatten() {
        let p = e.path();
        if p.is_dir() {
            out.extend(temp_files(&p));
        } else if mpm_host::atomic::temp_file_pid(&e.file_name().to_string_lossy()).is_some() {
            out.push(p);
        }
    }
    out
}

/// SIGKILL of the harness takes its solver child with it (parent-death signal); the child's
/// temporary file is swept when the campaign is opened again.
#[test]
fn sigkill_of_the_harness_leaves_no_solver_running() {
    let dir = tempfile::tempdir().unwrap();
    let mut harness = fake_campaign(dir.path(), false).spawn().unwrap();
    let solver = fake_solver_pid(dir.path());
    harness.kill().unwrap();
    harness.wait().unwrap();
    assert!(gone(solver), "solver {solver} still runs after SIGKILL of the harness");
    assert_eq!(temp_files(dir.path()).len(), 1, "the killed solver's reserved file is left");
    let again = fake_campaign(dir.path(), true).status().unwrap();
    assert_eq!(again.code(), Some(1), "the fake solver fails: a failed run exits 1");
    assert_eq!(temp_files(dir.path()), Vec::<std::path::PathBuf>::new(), "stale temporary files are swept");
}

/// SIGTERM and SIGINT stop the campaign (exit 130), kill the solver and leave no temporary
/// file behind.
#[test]
fn sigterm_and_sigint_leave_no_temporary_files() {
    for signal in ["-TERM", "-INT"] {
        let dir = tempfile::tempdir().unwrap();
        let mut harness = fake_campaign(dir.path(), false).spawn().unwrap();
        let solver = fake_solver_pid(dir.path());
        assert!(Command::new("kill").args([signal, &harness.id().to_string()]).status().unwrap().success());
        assert_eq!(harness.wait().unwrap().code(), Some(130), "{signal}");
        assert!(gone(solver), "{signal}: solver still runs");
        assert_eq!(temp_files(dir.path()), Vec::<std::path::PathBuf>::new(), "{signal}");
    }
}

/// The hybrid preset with the mock solver on a two-core machine: ranks x threads rows, the
/// launcher in front of `mpm` for two ranks only (no `--cpus`, the CPU set as its mask,
/// `--split-wait`), 2 x 2 flagged oversubscribed, the exchange and waiting columns filled
/// (the waiting empty at one rank), resume by rank count; the one-process analyses never
/// see the rows over two ranks, the hybrid one does.
#[test]
fn hybrid_mock_campaign_records_ranks_and_keeps_them_out_of_the_paper_analyses() {
    use mpm_bench::analysis::hybrid::HybridAnalysis;
    use mpm_bench::analysis::results::load_campaign;
    use mpm_bench::analysis::stats::{Analysis, StatsOptions};
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { launcher: Some("mpirun --bind-to none -n {ranks}".into()), ..Overrides::default() };
    let c = campaign("hybrid", &ov);
    let mut r = MockRunner::default();
    let s = run_mock(&c, &laptop(), dir.path(), &mut r);
    assert_eq!(r.calls.len(), c.expand().len());
    for call in &r.calls {
        let (program, args) = call.command_line();
        assert_eq!(args[args.len() - 3..], ["run", "--spec", call.spec_path.to_str().unwrap()]);
        if call.spec.ranks == 1 {
            assert_eq!((program.as_str(), &call.launcher, &call.mask), ("mock", &None, &None));
            assert!(call.spec.cpus.is_some());
            assert!(!call.spec.split_wait, "mpm refuses split_wait at one rank");
        } else {
            assert_eq!(program, "mpirun");
            assert_eq!(args[..4], ["--bind-to", "none", "-n", "2"]);
            assert!(call.spec.cpus.is_none(), "every rank would take the same list");
            assert!(call.spec.split_wait, "waiting measured apart from communication");
            assert_eq!(call.mask, Some(vec![0, 1]));
        }
    }
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), c.expand().len());
    for row in &rows {
        assert_eq!(row.outcome.status, Status::Ok, "{}: {}", row.id.run_id, row.outcome.reason);
        assert_eq!(row.threads(), row.ranks() * row.threads_per_rank(), "threads counts every worker");
        assert_eq!(row.placement.oversubscribed, row.threads() > 2, "{}", row.id.run_id);
        if row.ranks() == 2 {
            assert_eq!(row.run.launcher.as_deref(), Some("mpirun --bind-to none -n 2"));
            assert_eq!(row.placement.requested_cpus, [0, 1]);
            assert_eq!(row.placement.rank_cpus.len(), 2);
            assert!(row.measured.as_ref().and_then(|f| f.communication.comm_bytes_per_step).is_some_and(|b| b > 0.0));
            assert!(row.measured.as_ref().and_then(|f| f.communication.comm_frac).is_some_and(|f| f > 0.0 && f < 1.0));
            assert!(
                row.measured.as_ref().and_then(|f| f.communication.wait_frac).is_some_and(|f| f > 0.0 && f < 1.0)
                    && row.measured.as_ref().and_then(|f| f.communication.wait_s_per_step).is_some()
            );
            assert!(!row.comm_includes_wait());
            assert!(
                row.measured.as_ref().and_then(|f| f.memory.peak_rss_sum_bytes).unwrap()
                    > row.measured.as_ref().and_then(|f| f.memory.peak_rss_bytes).unwrap()
            );
        } else {
            assert_eq!(
                (row.run.launcher.as_deref(), row.measured.as_ref().and_then(|f| f.communication.comm_bytes_per_step)),
                (None, Some(0.0))
            );
            assert_eq!(
                (
                    row.measured.as_ref().and_then(|f| f.communication.wait_s_per_step),
                    row.measured.as_ref().and_then(|f| f.communication.wait_frac)
                ),
                (None, None),
                "nothing to wait for at one rank"
            );
        }
    }
    assert_eq!(s.counts.oversubscribed, rows.iter().filter(|r| r.ranks() == 2 && r.threads_per_rank() == 2).count());
    // Resume: nothing new; another rank count is a new configuration.
    assert_eq!(run_mock(&c, &laptop(), dir.path(), &mut MockRunner::default()).counts.written, 0);

    let camp = load_campaign(&s.dir, &RowFilter::analysis(false)).unwrap();
    assert!(camp.rows.iter().all(|r| r.ranks() == 1) && !camp.rows.is_empty());
    assert_eq!(camp.hybrid.len(), rows.iter().filter(|r| r.ranks() == 2).count());
    let an = Analysis::from_rows(&camp.rows, None, &StatsOptions::default());
    assert!(an.cells.keys().all(|k| k.threads <= 2), "no 2 x 2 cell among the one-process cells");
    let h = HybridAnalysis::from_rows(&camp.rows, &camp.hybrid, None, &StatsOptions::default());
    assert_eq!(h.rank_counts(), vec![1, 2]);
    for m in [1, 3] {
        let two = h.line(m, Strategy::DomainDecomposition, "o3", 2);
        assert_eq!(two.iter().map(|p| p.cores()).collect::<Vec<_>>(), vec![2, 4]);
        assert!(two.iter().all(|p| p.speedup.is_some() && p.comm_frac.is_some_and(|f| f > 0.0)));
        assert!(two.iter().all(|p| p.wait_frac.is_some_and(|f| f > 0.0) && !p.comm_includes_wait));
        assert!(two[1].oversubscribed && !two[0].oversubscribed);
        let one = h.line(m, Strategy::DomainDecomposition, "o3", 1);
        assert_eq!(one[0].speedup.unwrap().value, 1.0);
    }
    // Figures: the paper's from one-process rows, fig_hybrid from all.
    let out = dir.path().join("figs");
    let files = mpm_bench::report::figures::write_all(&camp, &an, &out, "test").unwrap();
    assert!(files.iter().any(|f| f.ends_with("fig_hybrid.png")));
    assert!(std::fs::read_to_string(out.join("README.md")).unwrap().contains("over several MPI ranks"));
    // points.csv lists fig_hybrid's points too: the value drawn, with its ranks.
    let points: Vec<std::collections::HashMap<String, String>> =
        csv::Reader::from_path(out.join("points.csv")).unwrap().deserialize().map(Result::unwrap).collect();
    let drawn = h.line(1, Strategy::DomainDecomposition, "o3", 2)[0];
    let point = points
        .iter()
        .find(|p| {
            p["figure"] == "fig_hybrid" && p["panel"] == "Model1 DD O3" && p["metric"] == "speedup" && p["ranks"] == "2"
        })
        .expect("fig_hybrid's 2 x 1 speedup in points.csv");
    assert_eq!(
        (point["threads"].as_str(), point["value"].parse::<f64>().unwrap()),
        ("1", drawn.speedup.unwrap().value)
    );
    assert!(points.iter().any(|p| p["figure"] == "fig_hybrid" && p["metric"] == "waiting_percent"));
    assert!(points.iter().filter(|p| p["figure"] != "fig_hybrid").all(|p| p["ranks"] == "1"));
    // regress: a current campaign without the rows over two ranks misses no baseline cell
    // (those rows are not cells of the one-process comparison), and says what it left out.
    let cur = dir.path().join("current");
    copy_campaign(&s.dir, &cur);
    std::fs::remove_file(cur.join("runs.csv")).unwrap();
    let mut log = mpm_bench::campaign::store::csv::CsvLog::open(&cur.join("runs.csv")).unwrap();
    for r in rows.iter().filter(|r| r.ranks() == 1) {
        log.append(r).unwrap();
    }
    drop(log);
    let o = bench()
        .args(["regress", "--baseline", s.dir.to_str().unwrap(), "--current", cur.to_str().unwrap()])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(0), "{err}\n{}", String::from_utf8_lossy(&o.stdout));
    assert!(err.contains("row(s) over several MPI ranks"), "{err}");
}

/// A launcher that cannot start: the row fails with the reason, and the campaign goes on
/// (the hints for Open MPI's refusals are tested in `campaign::launcher`).
#[test]
fn hybrid_launcher_failures_are_recorded() {
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides {
        models: Some(vec![1]),
        ranks: Some(vec![2]),
        threads: Some(vec![1]),
        reps: Some(1),
        launcher: Some("/nonexistent/mpirun -n {ranks}".into()),
        ..Overrides::default()
    };
    let c = campaign("hybrid", &ov);
    let flag = AtomicBool::new(false);
    let mut r = mpm_bench::campaign::exec::process::ProcessRunner::new(Arc::new(AtomicBool::new(false)));
    let solvers = vec![Solver { opt: OptLevel::O3, path: "mpm".into(), sha256: "0123456789abcdef".into() }];
    let s = schedule::execute(&c, &laptop(), &solvers, &mut r, &opts(dir.path()), &flag).unwrap();
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 1);
    assert_eq!(rows[0].outcome.status, Status::Failed);
    assert!(
        rows[0].outcome.reason.contains("cannot start the launcher /nonexistent/mpirun"),
        "{}",
        rows[0].outcome.reason
    );
    assert_eq!(rows[0].ranks(), 2);
}

/// The real thing: a tiny hybrid campaign (Model 1, ranks 1,2 x threads 1,2, a few steps)
/// through the `mpm-bench` binary, `mpm` started by `mpirun --oversubscribe
/// --allow-run-as-root` for two ranks; rows over two ranks with exchange bytes and the
/// waiting measured apart (`--split-wait`; empty at one rank), then the figures
/// (fig_hybrid) and the report's hybrid section with communication and waiting apart.
#[test]
fn end_to_end_hybrid_campaign_with_mpirun() {
    // No skip: CI has MPI (scripts/bootstrap.sh installs it), and the `mpm` this campaign
    // builds has the `mpi` feature by default; without either the test fails, saying why.
    let has_mpirun = Command::new("mpirun").arg("--version").output().is_ok_and(|o| o.status.success());
    assert!(has_mpirun, "mpirun not found: install openmpi-bin (scripts/bootstrap.sh does)");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let launcher = "mpirun --bind-to none --oversubscribe --allow-run-as-root -n {ranks}";
    let args = [
        "run",
        "--preset",
        "hybrid",
        "--models",
        "1",
        "--reps",
        "1",
        "--steps",
        "6",
        "--warmup",
        "1",
        "--out",
        out,
        "--quiet",
        "--launcher",
        launcher,
    ];
    let run = bench().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&run.stderr);
    assert!(run.status.success(), "hybrid campaign failed: {err}");
    let stdout = String::from_utf8_lossy(&run.stdout);
    let folder = stdout.lines().find_map(|l| l.strip_prefix("campaign folder: ")).expect("campaign folder line");
    let rows = read_rows(&Path::new(folder).join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 4);
    let pus = Machine::detect().unwrap().usable_pus().len();
    for r in &rows {
        assert_eq!(r.outcome.status, Status::Ok, "{}: {}", r.id.run_id, r.outcome.reason);
        assert_eq!(r.measured.as_ref().map(|f| f.size.particles as u64), Some(56_056));
        assert_eq!(r.measured.as_ref().map(|f| f.progress.steps), Some(6));
        assert_eq!(r.threads(), r.ranks() * r.threads_per_rank());
        assert_eq!(r.placement.oversubscribed, r.threads() > pus, "{}", r.id.run_id);
        assert!(r
            .measured
            .as_ref()
            .and_then(|f| f.scenario.taylor()?.final_length_m)
            .is_some_and(|l| l > 0.0 && l.is_finite()));
        if r.ranks() == 2 {
            assert!(
                r.measured.as_ref().and_then(|f| f.communication.comm_bytes_per_step).is_some_and(|b| b > 0.0),
                "{}: {:?}",
                r.id.run_id,
                r.measured.as_ref().and_then(|f| f.communication.comm_bytes_per_step)
            );
            assert!(r.measured.as_ref().and_then(|f| f.communication.comm_messages_per_step).is_some_and(|m| m > 0.0));
            let (comm, wait) = (
                r.measured.as_ref().and_then(|f| f.communication.comm_frac).unwrap(),
                r.measured.as_ref().and_then(|f| f.communication.wait_frac).unwrap_or(f64::NAN),
            );
            assert!(
                comm > 0.0 && comm < 1.0 && (0.0..1.0).contains(&wait),
                "{}: comm {comm}, wait {wait}",
                r.id.run_id
            );
            assert!(r.measured.as_ref().and_then(|f| f.communication.wait_s_per_step).is_some_and(|w| w >= 0.0));
            let per_rank = &r.measured.as_ref().map(|f| f.communication.rank_particles.clone()).unwrap_or_default();
            assert_eq!(per_rank.len(), 2);
            assert_eq!(per_rank.iter().sum::<u64>(), 56_056);
            assert_eq!(r.placement.rank_cpus.len(), 2);
            assert!(
                r.measured.as_ref().and_then(|f| f.memory.peak_rss_sum_bytes)
                    > r.measured.as_ref().and_then(|f| f.memory.peak_rss_bytes)
            );
            let launcher = r.run.launcher.as_deref().unwrap_or_default();
            assert!(launcher.starts_with("mpirun") && launcher.ends_with("-n 2"), "{launcher}");
        } else {
            assert_eq!(
                (
                    r.measured.as_ref().and_then(|f| f.communication.wait_s_per_step),
                    r.measured.as_ref().and_then(|f| f.communication.wait_frac)
                ),
                (None, None),
                "{}",
                r.id.run_id
            );
        }
    }
    // The same physics either way: the final bar length agrees to 1e-9 across the layouts.
    let lengths: Vec<f64> =
        rows.iter().filter_map(|r| r.measured.as_ref().and_then(|f| f.scenario.taylor()?.final_length_m)).collect();
    assert!(lengths.iter().all(|l| (l - lengths[0]).abs() <= 1e-9 * lengths[0]), "{lengths:?}");
    let man = mpm_bench::campaign::store::manifest::read(&Path::new(folder).join("manifest.json")).unwrap();
    let version = man.software.mpi_launcher.unwrap_or_default();
    assert!(version.contains("mpirun") || version.contains("MPI"), "launcher version in the manifest: {version}");
    let figs = dir.path().join("figs");
    // The rows of a test run on a busy machine may be flagged host_noisy: drawn anyway.
    let f = bench()
        .args(["figures", "--results", folder, "--out", figs.to_str().unwrap(), "--include-noisy"])
        .output()
        .unwrap();
    assert!(f.status.success(), "{}", String::from_utf8_lossy(&f.stderr));
    for name in ["fig_hybrid.png", "fig_hybrid.svg", "fig07.png"] {
        assert!(figs.join(name).is_file(), "{name}");
    }
    let rep = dir.path().join("report");
    let o = bench()
        .args(["report", "--results", folder, "--out", rep.to_str().unwrap(), "--include-noisy"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let md = std::fs::read_to_string(rep.join("report.md")).unwrap();
    assert!(md.contains("Hybrid MPI x threads") && md.contains("2 x 1"), "{md}");
    assert!(md.contains("| waiting for other ranks (% of wall) |"), "{md}");
    let two_by_one = md.lines().find(|l| l.starts_with("| Model1 DD O3 | 2 x 1 |")).expect("2 x 1 in the table");
    assert!(!two_by_one.contains("not measured") && !two_by_one.contains("incl. waiting"), "{two_by_one}");
}

/// Two campaigns into one folder at once: the second refuses, naming the first's pid, and
/// writes nothing; with --wait it waits and then has nothing to do. No run twice, no
/// duplicate run id.
#[test]
fn concurrent_campaigns_into_one_folder_run_nothing_twice() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let args = ["run", "--preset", "smoke", "--mock", "--quiet", "--out", out];
    let mut first = bench()
        .args(args)
        .env("MPM_BENCH_MOCK_DELAY_MS", "300")
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    std::thread::sleep(std::time::Duration::from_millis(700));
    let second = bench().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&second.stderr);
    assert_eq!(second.status.code(), Some(1), "{err}");
    assert!(err.contains(&format!("in use by mpm-bench pid {}", first.id())) && err.contains("--wait"), "{err}");
    let waiting = bench().args(args).arg("--wait").output().unwrap();
    let werr = String::from_utf8_lossy(&waiting.stderr);
    assert!(first.wait().unwrap().success());
    assert!(waiting.status.success() && werr.contains("waiting for the campaign folder"), "{werr}");
    assert!(werr.contains("0 rows written"), "{werr}");
    let folder = String::from_utf8_lossy(&waiting.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("campaign folder: ").map(str::to_string))
        .unwrap();
    let rows = read_rows(&Path::new(&folder).join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 8);
    let ids: HashSet<_> = rows.iter().map(|r| r.id.run_id.clone()).collect();
    let keys: HashSet<_> = rows.iter().map(|r| r.key()).collect();
    assert_eq!((ids.len(), keys.len()), (8, 8), "a run twice");
}

/// Exit codes a CI job can use: 1 when a run of this invocation failed (0 with
/// --allow-failures), and resuming runs the failed ones again; 2 for bad input (a timeout of
/// zero, a warm-up not shorter than the steps).
#[test]
fn exit_codes_say_failed_runs_and_bad_input() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().to_str().unwrap();
    let args = ["run", "--preset", "smoke", "--mock", "--quiet", "--out", out];
    let r = bench().args(args).env("MPM_BENCH_MOCK_FAIL", "dd o3 2 thr").output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(1), "{err}");
    assert!(err.contains("1 run(s) of this invocation failed"), "{err}");
    let again = bench().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&again.stderr);
    assert_eq!(again.status.code(), Some(0), "{err}");
    assert!(err.contains("1 rows written"), "the failed run is run again: {err}");
    let r = bench()
        .args(["run", "--preset", "smoke", "--mock", "--quiet", "--allow-failures", "--out"])
        .arg(dir.path().join("b"))
        .env("MPM_BENCH_MOCK_FAIL", "ae")
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(0), "{}", String::from_utf8_lossy(&r.stderr));
    let bad = dir.path().join("zero.toml");
    let preset = include_str!("../../configs/smoke.toml").replace("timeout = \"5m\"", "timeout = \"0s\"");
    std::fs::write(&bad, preset).unwrap();
    let r = bench().args(["run", "--preset", bad.to_str().unwrap(), "--mock", "--out", out]).output().unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("would stop every run at once"), "{err}");
    let r = bench()
        .args(["run", "--preset", "smoke", "--steps", "5", "--warmup", "9", "--mock", "--out", out])
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&r.stderr);
    assert_eq!(r.status.code(), Some(2), "{err}");
    assert!(err.contains("--warmup") && err.contains("no steady-state steps"), "{err}");
}

/// A line of runs.csv that is not a row is set aside like a torn line: readers read the
/// rest with a warning, a resumed campaign moves it to runs.csv.garbage-<time> and runs
/// that configuration again.
#[test]
fn a_garbage_line_is_set_aside_and_its_run_redone() {
    let dir = tempfile::tempdir().unwrap();
    let c = campaign("smoke", &Overrides::default());
    let s = run_mock(&c, &laptop(), dir.path(), &mut MockRunner::default());
    let csv = s.dir.join("runs.csv");
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines: Vec<&str> = text.lines().collect();
    lines[3] = "a,b,c,d";
    std::fs::write(&csv, lines.join("\n") + "\n").unwrap();
    let rows = read_rows(&csv).unwrap();
    assert_eq!(rows.len(), 7, "the other rows read");
    let mut r = MockRunner::default();
    let s2 = run_mock(&c, &laptop(), dir.path(), &mut r);
    assert_eq!((s2.counts.written, r.calls.len()), (1, 1), "that run alone is redone");
    assert_eq!(read_rows(&csv).unwrap().len(), 8);
    let aside: Vec<_> = std::fs::read_dir(&s.dir)
        .unwrap()
        .flatten()
        .filter(|e| e.file_name().to_string_lossy().starts_with("runs.csv.garbage-"))
        .collect();
    assert_eq!(aside.len(), 1);
    assert_eq!(std::fs::read_to_string(aside[0].path()).unwrap(), "a,b,c,d\n");
}

/// `mpm-bench job FILE` (what a Slurm job runs on its node) refuses a solver binary other
/// than the one the campaign hashed, saying so, after recording where it ran; it writes no row.
#[test]
fn a_job_refuses_another_solver_binary_than_the_campaigns() {
    use mpm_bench::campaign::schedule::job::{self, JobFile};
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("camp").join("json");
    std::fs::create_dir_all(&json).unwrap();
    let solver = dir.path().join("mpm");
    std::fs::write(&solver, "#!/bin/sh\nexit 0\n").unwrap();
    let c = campaign("smoke", &Overrides::default());
    let run = c.expand().remove(0);
    let file = JobFile {
        campaign: c,
        timeout: None,
        git: Default::default(),
        solver: Solver { opt: run.opt, path: solver.clone(), sha256: "ab".repeat(32) },
        run,
        order_index: 0,
        run_id: "r0".into(),
        watch: None,
    };
    let path = job::job_path(&json, "r0");
    job::write_json(&path, &file).unwrap();
    let out = bench().args(["job"]).arg(&path).output().unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(
        err.contains("is not the one the campaign was submitted with") && err.contains("shared filesystem"),
        "{err}"
    );
    let started = job::read_started(&json, "r0").unwrap();
    assert_eq!(started.fingerprint, fingerprint::fingerprint(&Machine::detect().unwrap()));
    assert!(dir.path().join("camp/nodes").join(format!("{}.json", started.fingerprint)).is_file());
    assert_eq!(job::read_row(&json, "r0").unwrap(), None);
}

/// `calibrate` on the mock runner: 3 clean and 2 injected campaigns of the ci preset (paired
/// cells) give 3 A/A and 6 injected comparisons; a 30 % injected loss is detected every time
/// (the mock's spread between processes is 3 %), no A/A pair fails, the smallest detectable
/// change and the gate's wall time are measured, and calibration.json has its keys.
#[test]
fn calibrate_counts_false_alarms_and_detections_on_the_mock() {
    use mpm_bench::analysis::calibrate::judge;
    use mpm_bench::campaign::measure::calibrate::{run_campaigns, CalibrateOptions};
    let dir = tempfile::tempdir().unwrap();
    let args = CalibrateOptions {
        preset: "ci".into(),
        clean: 3,
        injected: 2,
        inject_slowdown: 0.3,
        budget: None,
        tolerance: 0.05,
        metrics: vec!["efficiency".into(), "work".into()],
        out: dir.path().to_path_buf(),
        json: None,
        no_build: true,
        quiet: true,
        mock: true,
        design_ab: false,
        inject_step_slowdown: 0.1,
        reps: None,
        seed: None,
    };
    let c = campaign("ci", &Overrides::default());
    let flag = AtomicBool::new(false);
    let campaigns =
        run_campaigns(&args, &laptop(), &mock_solvers(&c), &mut MockRunner::default(), None, &flag).unwrap();
    let cal = judge(&args, &laptop(), campaigns).unwrap();
    assert_eq!((cal.aa_comparisons, cal.injected_comparisons), (3, 6));
    assert_eq!((cal.false_alarms, cal.detected), (0, 6), "{:#?}", cal.comparisons);
    assert_eq!(cal.campaigns.iter().filter(|c| c.kind == "injected").count(), 2);
    let loss = cal.measured_injected_loss.unwrap();
    assert!((loss - 0.3).abs() < 0.05, "the injected campaigns lost {loss}");
    let mdc = cal.min_detectable_change.unwrap();
    assert!(mdc > 0.05 && mdc < 0.3, "{mdc}");
    // A loss in every cell at once is found by the mean over the four cells: smaller, but
    // never below the tolerance.
    let pooled = cal.min_detectable_change_pooled.unwrap();
    assert!(pooled >= 0.05 && pooled < mdc, "pooled {pooled} vs one cell {mdc}");
    assert!(cal.comparisons.iter().all(|c| c.pooled_ratio.is_some() && c.efficiency_ratios.len() == 4));
    assert!(cal.gate_wall_s > 0.0 && cal.recommended_reps.is_some());
    assert_eq!(cal.cells.len(), 4, "Models 1-2 x AE, DD at 2 threads");
    // Every injected comparison failed on efficiency, naming the injection.
    for cmp in cal.comparisons.iter().filter(|c| c.kind == "injected") {
        assert!(cmp.reason.contains("injected slowdown of 30 %"), "{}", cmp.reason);
        assert!(cmp.efficiency_ratios.values().all(|r| *r < 0.8), "{:?}", cmp.efficiency_ratios);
    }
    let json = serde_json::to_value(&cal).unwrap();
    for key in [
        "aa_comparisons",
        "false_alarms",
        "injected_slowdown",
        "injected_comparisons",
        "detected",
        "min_detectable_change",
        "min_detectable_change_pooled",
        "gate_wall_s",
        "recommended_reps",
        "recommended_blocks",
        "method",
    ] {
        assert!(json.get(key).is_some(), "calibration.json lacks {key}");
    }
}

/// The ci preset (paired, 8 blocks) on the mock, Model 1, 3 repetitions: every row of two
/// threads is a paired run with its blocks; the analysis takes the cells' efficiencies from
/// the paired design with an interval over the 3 processes; with one repetition the interval
/// is the process's blocks' and is marked so.
#[test]
fn paired_cells_are_recorded_block_by_block_and_analysed_over_processes() {
    use mpm_bench::analysis::results::load_campaign;
    use mpm_bench::analysis::stats::{Design, Stage};
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { models: Some(vec![1]), reps: Some(3), ..Overrides::default() };
    let c = campaign("ci", &ov);
    let mut r = MockRunner::default();
    let s = run_mock(&c, &laptop(), dir.path(), &mut r);
    assert!(r.calls.iter().all(|c| c.spec.paired == Some(mpm_spec::spec::Paired { blocks: 8 })));
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert_eq!(rows.len(), 6);
    for row in &rows {
        assert!(row.is_paired(), "{}", row.run.describe());
        assert_eq!(
            (
                row.measured.as_ref().and_then(|f| f.paired.as_ref().map(|p| p.blocks)),
                row.measured.as_ref().and_then(|f| f.paired.as_ref().map(|p| p.block_steps))
            ),
            (Some(8), Some(10))
        );
        assert_eq!(
            row.measured
                .as_ref()
                .map(|f| f.paired.as_ref().map(|p| p.t1_s_per_step.clone()).unwrap_or_default())
                .unwrap_or_default()
                .len(),
            8
        );
        assert!(
            row.measured.as_ref().and_then(|f| f.work.as_ref().map(|w| w.efficiency_bound)).is_some()
                && !row
                    .measured
                    .as_ref()
                    .map(|f| f.work.as_ref().map(|w| w.bytes.clone()).unwrap_or_default())
                    .unwrap_or_default()
                    .is_empty()
        );
        assert_eq!(
            row.measured
                .as_ref()
                .map(|f| -> Vec<_> {
                    f.noise.as_ref().map(|n| n.workers.iter().map(|w| w.cpu_share).collect()).unwrap_or_default()
                })
                .unwrap_or_default()
                .len(),
            2
        );
    }
    let an = load_campaign(&s.dir, &RowFilter::analysis(false)).unwrap().analyse(None);
    let p = an.point(1, Strategy::ArrayExpansion, "o3", 2, Stage::Total).unwrap();
    assert_eq!((p.design, p.within_process_only), (Design::Paired, false));
    let e = p.efficiency.unwrap();
    assert_eq!(e.reps, 3);
    assert!(e.lo < e.value && e.value < e.hi && (e.value - 0.9).abs() < 0.1, "{e:?}");
    assert_eq!(p.speedup.unwrap().value, 2.0 * e.value);
    assert!(an.notes.iter().any(|n| n.contains("paired design")), "{:?}", an.notes);

    let one = tempfile::tempdir().unwrap();
    let c1 = campaign("ci", &Overrides { models: Some(vec![1]), reps: Some(1), ..Overrides::default() });
    let s1 = run_mock(&c1, &laptop(), one.path(), &mut MockRunner::default());
    let an = load_campaign(&s1.dir, &RowFilter::analysis(false)).unwrap().analyse(None);
    let p = an.point(1, Strategy::DomainDecomposition, "o3", 2, Stage::Total).unwrap();
    assert!(p.within_process_only && p.efficiency.unwrap().reps == 1);
    assert!(an.notes.iter().any(|n| n.contains("one process only")), "{:?}", an.notes);
    let w = mpm_bench::analysis::claims::few_repetitions(&an).unwrap();
    assert!(w.contains("fewer than 3 repetitions") && w.contains("indicative"), "{w}");
}

/// A campaign with an injected slowdown: its name and every row say so, the rows carry the
/// injected work's time; figures, claims and report refuse it unless --include-injected;
/// regress compares it with a clean campaign and fails on the efficiency, naming the
/// injection.
#[test]
fn injected_slowdown_is_marked_refused_and_caught_by_regress() {
    use mpm_bench::analysis::claims::{self, ClaimsOptions};
    use mpm_bench::analysis::regress::{self, RegressOptions};
    use mpm_bench::report::comparison::{self, ReportOptions};
    use mpm_bench::report::figures::{self, FiguresOptions};
    let dir = tempfile::tempdir().unwrap();
    let base = Overrides { models: Some(vec![1]), reps: Some(4), ..Overrides::default() };
    let clean = run_mock(&campaign("ci", &base), &laptop(), dir.path(), &mut MockRunner::default());
    let ov = Overrides { inject_slowdown: Some(0.2), ..base };
    let c = campaign("ci", &ov);
    assert!(c.id.contains("inject0.2"), "{}", c.id);
    let s = run_mock(&c, &laptop(), dir.path(), &mut MockRunner::default());
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    assert!(rows
        .iter()
        .all(|r| r.injected() == Some(0.2) && r.measured.as_ref().and_then(|f| f.injected_s).is_some_and(|t| t > 0.0)));
    let header = std::fs::read_to_string(s.dir.join("runs.csv")).unwrap();
    assert!(header.lines().next().unwrap().split(',').any(|c| c == "inject_slowdown"));

    let out = dir.path().join("figs");
    let fig = |include_injected| FiguresOptions {
        results: s.dir.clone(),
        out: out.clone(),
        pin: None,
        include_noisy: false,
        include_injected,
    };
    let err = format!("{:#}", figures::run(fig(false)).unwrap_err());
    assert!(err.contains("injected slowdown") && err.contains("--include-injected"), "{err}");
    figures::run(fig(true)).unwrap();
    let claims_args = ClaimsOptions {
        results: s.dir.clone(),
        markdown: None,
        pin: None,
        include_noisy: false,
        include_injected: false,
    };
    assert!(format!("{:#}", claims::run(claims_args).unwrap_err()).contains("--include-injected"));
    let rep = ReportOptions {
        dirs: vec![s.dir.clone()],
        out: dir.path().join("rep"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    };
    assert!(format!("{:#}", comparison::build(&rep).err().unwrap()).contains("--include-injected"));

    let args =
        RegressOptions { metrics: vec!["efficiency".into(), "work".into()], ..RegressOptions::new(&clean.dir, &s.dir) };
    let r = regress::evaluate(&args).unwrap();
    assert_eq!(r.verdict, "fail", "{}", r.reason);
    assert_eq!(r.regressions.len(), 3, "both cells' paired efficiency and their mean: {:#?}", r.checks);
    assert!(r.regressions.iter().all(|c| c.design == mpm_bench::analysis::stats::Design::Paired));
    let pooled = r.regressions.iter().find(|c| c.cell.key().is_none()).expect("the pooled check");
    assert_eq!(pooled.cell.to_string(), "mean of 2 cells");
    assert_eq!((pooled.baseline_reps, pooled.current_reps), (8, 8), "4 processes a cell, 2 cells");
    assert!((pooled.ratio.value - 0.8).abs() < 0.05, "{:?}", pooled.ratio);
    assert_eq!(r.gated_checks, 3);
    assert!(r.reason.contains("injected slowdown of 20 %"), "{}", r.reason);
    assert_eq!(r.current_injected, Some(0.2));
    assert!(r.work_checks.iter().all(|w| w.outcome == regress::Outcome::Unchanged), "injected work is not work");
}

/// A run whose worker got half the wall time as CPU time is flagged host_noisy with the
/// share, counted in the session's summary, and left out of the analyses by default.
#[test]
fn a_worker_short_of_cpu_time_flags_the_row() {
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { opt: Some(vec![OptLevel::O3]), ..Overrides::default() };
    let c = campaign("smoke", &ov);
    let mut r = MockRunner { low_cpu_when: Some(" dd ".into()), ..MockRunner::default() };
    let s = run_mock(&c, &laptop(), dir.path(), &mut r);
    let rows = read_rows(&s.dir.join("runs.csv")).unwrap();
    for row in &rows {
        let dd = row.strategy() == Strategy::DomainDecomposition;
        assert_eq!(row.host.host_noisy, dd, "{}", row.run.describe());
        if dd {
            assert!(row.host.host_noise.contains("50 % of the wall time as CPU time"), "{}", row.host.host_noise);
            assert_eq!(row.measured.as_ref().and_then(|f| f.cpu_share_min()), Some(0.5));
        }
    }
    assert_eq!(s.counts.noisy, rows.iter().filter(|r| r.host.host_noisy).count());
    assert!(s.report().contains(&format!("{} flagged noisy", s.counts.noisy)));
}

/// The work counters are gated exactly: one byte more in one worker's assembly of one cell
/// fails the gate on any host, naming the sub-stage; less passes as an improvement. Through
/// the binary: `--json -` puts the verdict on standard output (the lines for people on
/// standard error) and `--markdown` appends the summary to a file.
#[test]
fn regress_gates_the_work_counters_exactly() {
    use mpm_bench::campaign::store::csv::CsvLog;
    let dir = tempfile::tempdir().unwrap();
    let ov = Overrides { models: Some(vec![1]), reps: Some(3), ..Overrides::default() };
    let base = run_mock(&campaign("ci", &ov), &laptop(), &dir.path().join("a"), &mut MockRunner::default());
    let cur = run_mock(&campaign("ci", &ov), &laptop(), &dir.path().join("b"), &mut MockRunner::default());
    let edit = |delta: i64| {
        let path = cur.dir.join("runs.csv");
        let mut rows = read_rows(&path).unwrap();
        for r in rows.iter_mut().filter(|r| r.strategy() == Strategy::DomainDecomposition) {
            let work = r.measured.as_mut().and_then(|f| f.work.as_mut()).unwrap();
            let v = work.bytes.get_mut(&Substage::Assembly).unwrap();
            v[1] = v[1].checked_add_signed(delta).unwrap();
        }
        std::fs::remove_file(&path).unwrap();
        let mut log = CsvLog::open(&path).unwrap();
        for r in &rows {
            log.append(r).unwrap();
        }
    };
    let gate = |extra: &[&str]| {
        let md = dir.path().join("summary.md");
        let mut cmd = bench();
        cmd.args(["regress", "--baseline"]).arg(&base.dir).arg("--current").arg(&cur.dir);
        cmd.args(["--metrics", "efficiency,work", "--json", "-", "--markdown"]).arg(&md).args(extra);
        let out = cmd.output().unwrap();
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).expect("the JSON verdict on stdout");
        (out.status.code(), v, std::fs::read_to_string(&md).unwrap(), String::from_utf8_lossy(&out.stderr).into_owned())
    };
    let (code, v, md, _) = gate(&[]);
    assert_eq!(code, Some(0), "{v}");
    assert!(md.contains("### Parallel-efficiency gate: PASS") && md.contains("| equal |"), "{md}");
    edit(1);
    let (code, v, md, err) = gate(&[]);
    assert_eq!(code, Some(1), "{v}");
    let w = &v["work_regressions"];
    assert_eq!(w.as_array().unwrap().len(), 1, "{v}");
    assert!(w[0]["changes"][0].as_str().unwrap().starts_with("assembly: busiest worker"), "{w}");
    assert!(md.contains("### Parallel-efficiency gate: FAIL") && md.contains("**more work**"), "{md}");
    assert!(err.contains("MORE WORK") && err.contains("verdict: fail"), "{err}");
    edit(-2);
    let (code, v, _, _) = gate(&[]);
    assert_eq!(code, Some(0), "{v}");
    assert_eq!(v["work_checks"].as_array().unwrap().iter().filter(|w| w["outcome"] == "improved").count(), 1);
}
