//! The `mpm` program through its real binary: help, Table 2 counts, the JSON summary's keys,
//! strategies, pinning, oversubscription, bad input, VTU output, the impact and the plate.

use mpm_core::Strategy;
use mpm_spec::Summary;
use serde_json::Value;
use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};

const MPM: &str = env!("CARGO_BIN_EXE_mpm");

fn mpm(args: &[&str]) -> Output {
    Command::new(MPM).args(args).output().expect("cannot start the mpm binary")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Run `mpm run taylor <args> --json <dir>/out.json` and return the parsed summary.
fn run_json(args: &[&str]) -> (Value, Output) {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("out.json");
    let mut all = vec!["run", "taylor"];
    all.extend_from_slice(args);
    all.extend_from_slice(&["--json", json.to_str().unwrap()]);
    let out = mpm(&all);
    assert!(out.status.success(), "mpm {all:?} failed\nstdout:\n{}\nstderr:\n{}", text(&out.stdout), text(&out.stderr));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_no_temp_files(dir.path());
    (v, out)
}

fn assert_no_temp_files(dir: &Path) {
    let left: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with('.'))
        .collect();
    assert!(left.is_empty(), "temporary files left behind: {left:?}");
}

fn u(v: &Value, k: &str) -> u64 {
    v[k].as_u64().unwrap_or_else(|| panic!("{k} is not an unsigned integer: {}", v[k]))
}

fn f(v: &Value, k: &str) -> f64 {
    v[k].as_f64().unwrap_or_else(|| panic!("{k} is not a number: {}", v[k]))
}

fn cores() -> usize {
    std::thread::available_parallelism().map_or(1, |n| n.get())
}

#[test]
fn help_teaches_the_commands_and_every_flag() {
    let top = mpm(&["--help"]);
    assert!(top.status.success());
    let top = text(&top.stdout);
    assert!(top.contains("Run one explicit MPM simulation"), "{top}");
    assert!(top.contains("run "), "{top}");
    assert!(top.contains("mpm run taylor --model 1 --end-time 40e-6"), "{top}");
    assert!(top.contains("--strategy dd --threads 2 --cpus 0,1"), "{top}");

    let run = text(&mpm(&["run", "--help"]).stdout);
    assert!(run.contains("taylor"), "{run}");
    assert!(run.contains("--spec <FILE>") && run.contains("mpm run --spec run.toml"), "{run}");

    let out = mpm(&["run", "taylor", "--help"]);
    assert!(out.status.success());
    let h = text(&out.stdout);
    // Snapshot of the flag list, in order.
    let flags: Vec<String> = h
        .lines()
        // Option lines start within the first 6 columns; wrapped help text is indented more.
        .filter(|l| {
            let t = l.trim_start();
            t.starts_with('-') && l.len() - t.len() <= 6
        })
        .map(str::trim_start)
        .filter_map(|l| l.split([' ', ',']).find(|w| w.starts_with("--")).map(str::to_string))
        .collect();
    let expect = [
        "--model",
        "--velocity",
        "--eos",
        "--wall",
        "--end-time",
        "--steps",
        "--grid",
        "--cfl",
        "--q",
        "--energy-rise-limit",
        "--strategy",
        "--threads",
        "--cpus",
        "--warmup",
        "--json",
        "--vtk",
        "--every",
        "--vtk-format",
        "--quiet",
        "--ranks",
        "--rank-layout",
        "--split-wait",
        "--checkpoint-dir",
        "--checkpoint-every",
        "--paired-blocks",
        "--inject-slowdown",
        "--inject-step-slowdown",
        "--dump-state",
        "--print-spec",
        "--force",
        "--help",
        "--version",
    ];
    assert_eq!(flags, expect, "{h}");
    for must in [
        "m/s",
        "[default: 40]",
        "Default: 0.5 for",
        "0.2 for the plate",
        "[default: hugoniot]",
        "paper-printed",
        "safe only at small compression",
        "[default: 1.5,0.06]",
        "[default: 0.05]",
        "[default: frictionless]",
        "fixed for the Taylor bar",
        "[default: serial]",
        "[default: 100]",
        "<SECONDS>",
        "40e-6",
        "Examples:",
        "1,155,192",
        "mpirun -n R mpm run",
        "Default: the domain-decomposition layout",
        "mpm resume DIR",
        "[default: 10m]",
        "SIGUSR1",
        ".pvtu",
    ] {
        assert!(h.contains(must), "help lacks {must:?}:\n{h}");
    }
    let resume = text(&mpm(&["resume", "--help"]).stdout);
    for must in ["--older", "--spec <FILE>", "bit for bit", "mpirun -n 2 mpm resume ck", "damaged-step-N"] {
        assert!(resume.contains(must), "resume --help lacks {must:?}:\n{resume}");
    }
}

#[test]
fn table2_counts_of_models_1_to_3() {
    for (model, p, c, n) in
        [("1", 56_056, 49_152, 53_361), ("2", 244_341, 165_888, 175_273), ("3", 1_155_192, 1_022_208, 1_053_493)]
    {
        let (v, _) = run_json(&["--model", model, "--steps", "0", "--quiet"]);
        assert_eq!(u(&v, "particles"), p, "model {model}");
        assert_eq!(u(&v, "cells"), c, "model {model}");
        assert_eq!(u(&v, "nodes"), n, "model {model}");
        assert_eq!(u(&v, "steps"), 0);
        assert_eq!(v["end_reason"], "step_limit");
        assert!(v["ns_per_particle_step"].is_null());
        assert!((f(&v, "initial_length_m") - 25.4e-3).abs() < 1e-12);
    }
}

/// The summary's roofline charges bytes and rates only to the sub-stages that did work: a
/// serial run on the fixed grid bins nothing and re-fits no grid (their timers read a few
/// picoseconds, which with the cost table's bytes gave thousands of GB/s), DD on 2 threads
/// bins every particle; the particle loops have rates in both.
#[test]
fn the_roofline_charges_only_the_sub_stages_that_ran() {
    let stage = |v: &Value, s: &str| v["roofline"][s].clone();
    let (serial, _) = run_json(&["--model", "1", "--steps", "8", "--warmup", "2", "--quiet"]);
    for s in ["binning", "grid_fit", "assembly", "gather"] {
        let r = stage(&serial, s);
        assert_eq!(r["bytes_per_particle_step"].as_f64(), Some(0.0), "serial {s}: {r}");
        assert!(r["gb_per_s"].is_null() && r["gflop_per_s"].is_null(), "serial {s}: {r}");
    }
    let (dd, _) =
        run_json(&["--model", "1", "--steps", "8", "--warmup", "2", "--strategy", "dd", "--threads", "2", "--quiet"]);
    for (v, what) in [(&serial, "serial"), (&dd, "dd")] {
        for s in ["scatter", "remap_scatter", "stress_update"] {
            let gb = stage(v, s)["gb_per_s"].as_f64().unwrap_or_else(|| panic!("{what} {s}: {}", stage(v, s)));
            assert!(gb > 0.0 && gb < 1000.0, "{what} {s}: {gb} GB/s");
        }
    }
    let b = stage(&dd, "binning");
    assert!(
        b["bytes_per_particle_step"].as_f64().unwrap() > 0.0 && b["gb_per_s"].as_f64().is_some(),
        "dd binning: {b}"
    );
}

/// Model 4 builds in about 9 s and 2.7 GB here.
#[test]
fn table2_counts_of_model_4() {
    let (v, _) = run_json(&["--model", "4", "--steps", "0", "--quiet"]);
    assert_eq!(u(&v, "particles"), 12_416_320);
    assert_eq!(u(&v, "cells"), 8_177_664);
    assert_eq!(u(&v, "nodes"), 8_302_185);
}

const REQUIRED_KEYS: &[&str] = &[
    "spec",
    "roofline",
    "simd_level",
    "scenario",
    "model",
    "model_name",
    "strategy",
    "threads",
    "opt_level",
    "profile",
    "mpm_version",
    "debug_assertions",
    "target",
    "grid_mode",
    "eos",
    "material",
    "cfl",
    "wall",
    "velocity_m_s",
    "particles",
    "cells",
    "nodes",
    "mean_nodes",
    "final_nodes",
    "final_occupancy",
    "final_stored_nodes",
    "dx_m",
    "steps",
    "warmup_steps",
    "steady_steps",
    "dt_first",
    "dt_next",
    "sim_time",
    "end_time",
    "step_limit",
    "end_reason",
    "wall_s",
    "output_s",
    "grid_stage_s",
    "particle_stage_s",
    "substages",
    "steady_wall_s",
    "steady_grid_stage_s",
    "steady_particle_stage_s",
    "steady_substages",
    "steady_s_per_step",
    "ns_per_particle_step",
    "particle_steps_per_s",
    "worker_busy_s",
    "load_imbalance",
    "peak_rss_bytes",
    "peak_rss_sum_bytes",
    "comm_s_per_step",
    "comm_frac",
    "comm_bytes_per_step",
    "comm_messages_per_step",
    "model_memory_bytes",
    "requested_cpus",
    "observed_cpus",
    "worker_affinity",
    "pinned",
    "pinning_verified",
    "oversubscribed",
    "available_cores",
    "kinetic_energy_initial",
    "internal_energy_initial",
    "kinetic_energy",
    "internal_energy",
    "momentum_initial",
    "momentum",
    "failed_particles",
    "history",
    "bulk_viscosity",
    "energy_rise_limit",
    "energy",
    "initial_length_m",
    "final_length_m",
    "initial_face_diameter_m",
    "face_diameter_m",
    "length_convention",
    "command_line",
    "started_unix_s",
    "provenance",
    "work",
    "noise",
];

const SUBSTAGES: &[&str] = &[
    "reorder",
    "grid_fit",
    "binning",
    "scatter",
    "assembly",
    "grid_update",
    "gather",
    "remap_scatter",
    "remap_assembly",
    "stress_update",
];

fn keys(v: &Value) -> BTreeSet<String> {
    v.as_object().unwrap().keys().cloned().collect()
}

#[test]
fn json_has_exactly_the_golden_keys() {
    let (v, out) = run_json(&["--model", "1", "--steps", "12", "--quiet"]);
    let want: BTreeSet<String> = REQUIRED_KEYS.iter().map(|s| s.to_string()).collect();
    assert_eq!(keys(&v), want);
    assert!(out.stdout.is_empty(), "--quiet printed: {}", text(&out.stdout));
    let sub: Vec<&str> = v["substages"].as_object().unwrap().keys().map(String::as_str).collect();
    assert_eq!(sub, SUBSTAGES, "in execution order");
    assert_eq!(v["scenario"], "taylor");
    assert_eq!(v["strategy"], "serial");
    assert_eq!(u(&v, "threads"), 1);
    // The build script exports the level this test (and so the binary) was built with.
    assert_eq!(v["opt_level"], concat!("o", env!("MPM_OPT_LEVEL")));
    assert_eq!(v["profile"], env!("MPM_PROFILE"));
    assert_eq!(v["eos"], "mie-gruneisen (hugoniot form)");
    assert_eq!(f(&v["bulk_viscosity"], "c1"), 1.5);
    assert_eq!(f(&v["bulk_viscosity"], "c2"), 0.06);
    assert_eq!(f(&v, "energy_rise_limit"), 0.05);
    let o = &v["final_occupancy"];
    assert_eq!(u(o, "cells") as usize, u(&v, "cells") as usize, "Model 1's grid is fixed");
    assert!(u(o, "occupied_cells") > 0 && u(o, "occupied_cells") < u(o, "cells"), "{o}");
    assert!(u(o, "occupied_blocks") * 512 >= u(o, "occupied_cells"), "{o}");
    let e = &v["energy"];
    assert_eq!(f(e, "initial_kinetic_j"), f(&v, "kinetic_energy_initial"));
    assert_eq!(f(e, "final_internal_j"), f(&v, "internal_energy"));
    assert!((f(e, "final_total_j") / f(e, "initial_total_j") - 1.0).abs() < 1e-9, "{e}");
    assert!(f(e, "max_rise") < 1e-9 && f(e, "max_fall") < 1e-9, "{e}");
    assert_eq!(u(e, "negative_internal_steps"), 0);
    assert_eq!(v["wall"], "frictionless");
    assert_eq!(v["grid_mode"], "fixed");
    assert_eq!(u(&v, "steps"), 12);
    assert_eq!(u(&v, "step_limit"), 12);
    assert!(v["end_time"].is_null());
    assert_eq!(v["end_reason"], "step_limit");
    assert_eq!(u(&v, "warmup_steps"), 1, "default warm-up min(5, 12/10)");
    assert_eq!(u(&v, "steady_steps"), 11);
    assert!(f(&v, "ns_per_particle_step") > 0.0);
    assert!(u(&v, "peak_rss_bytes") > 10_000_000);
    assert!(v["requested_cpus"].as_array().unwrap().is_empty());
    assert!(v["observed_cpus"].as_array().unwrap().is_empty());
    assert_eq!(v["worker_affinity"].as_array().unwrap().len(), 1);
    assert!(v["worker_busy_s"].is_null() && v["load_imbalance"].is_null(), "the serial strategy has no team");
    assert_eq!(v["momentum"].as_array().unwrap().len(), 3);
    let h = v["history"].as_array().unwrap();
    assert_eq!(h.len(), 13);
    assert_eq!(u(&h[0], "step"), 0);
    assert_eq!(u(&h[12], "step"), 12);
    assert!(f(&h[12], "internal") > 0.0);
    let k0 = f(&v, "kinetic_energy_initial");
    assert!((k0 - 0.5 * 10.28e-3 * 40.0 * 40.0).abs() < 0.01 * k0, "{k0}");
    assert!(f(&v, "kinetic_energy") < k0);
}

/// Every summary names its source: host identity and kernel, rustc, commit and dirty flag of
/// the build, and the SHA-256 of the very binary that ran; `--version` names commit and profile.
#[test]
fn summary_and_version_carry_provenance() {
    let (v, _) = run_json(&["--model", "1", "--steps", "1", "--quiet"]);
    let p = &v["provenance"];
    let want = mpm_host::identity::sha256_file(Path::new(MPM)).unwrap();
    assert_eq!(p["binary_sha256"], want.as_str(), "{p}");
    assert_eq!(p["git_commit"], mpm_host::identity::GIT_COMMIT);
    assert!(p["git_commit"].as_str().unwrap().len() == 40 || p["git_commit"] == "unknown", "{p}");
    assert!(p["git_dirty"].is_boolean() || p["git_dirty"].is_null(), "{p}");
    assert!(p["rustc"].as_str().unwrap().starts_with("rustc "), "{p}");
    let host = &p["host"];
    let kernel = std::fs::read_to_string("/proc/sys/kernel/osrelease").unwrap();
    assert_eq!(host["kernel"], kernel.trim());
    for k in ["cpu_vendor", "cpu_family", "cpu_model", "cpu_stepping", "microcode", "smt"] {
        assert!(host[k].as_str().is_some_and(|s| !s.is_empty()), "{k}: {host}");
    }
    assert!(host["caches"].is_array(), "{host}");
    if Path::new("/etc/machine-id").is_file() {
        assert_eq!(host["machine_id_sha256"].as_str().unwrap().len(), 64, "{host}");
    }
    assert!(v["command_line"].as_array().unwrap().iter().any(|a| a == "--steps"));
    let out = mpm(&["--version"]);
    let line = text(&out.stdout);
    assert!(out.status.success());
    let commit: String = mpm_host::identity::GIT_COMMIT.chars().take(12).collect();
    assert!(line.contains(&format!("commit {commit}")), "{line}");
    assert!(line.contains(&format!("profile {}", env!("MPM_PROFILE"))), "{line}");
}

/// The harness reads the summary back as the typed [`Summary`]: every key the program
/// writes parses, the strategy as the typed value, and writing it again gives the same JSON.
#[test]
fn summary_reads_back_as_the_typed_summary() {
    let (v, _) = run_json(&["--model", "1", "--steps", "3", "--strategy", "dd", "--threads", "2", "--quiet"]);
    let s: Summary = serde_json::from_value(v.clone()).unwrap();
    assert_eq!(s.strategy, Strategy::DomainDecomposition);
    assert_eq!(s.figures.progress.end_reason.name(), v["end_reason"]);
    assert_eq!(serde_json::to_value(&s).unwrap(), v);
}

/// A summary's `spec` re-runs the run: `mpm run --spec summary.json` gives every figure of
/// the first run bit for bit (same strategy and threads), and echoes the same spec but for
/// the summary's path. `--print-spec` prints the spec the flags make, which runs the same.
#[test]
fn a_summarys_spec_repeats_the_run_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let a = dir.path().join("a.json");
    let args = ["run", "taylor", "--model", "1", "--steps", "15", "--strategy", "dd", "--threads", "2", "--quiet"];
    let out = mpm(&[&args[..], &["--cfl", "0.4", "--q", "1.2,0.1", "--json", a.to_str().unwrap()]].concat());
    assert!(out.status.success(), "{}", text(&out.stderr));
    let b = dir.path().join("b.json");
    let out = mpm(&["run", "--spec", a.to_str().unwrap(), "--json", b.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(out.stdout.is_empty(), "the spec's quiet applies");
    let (va, vb): (Value, Value) = (
        serde_json::from_str(&std::fs::read_to_string(&a).unwrap()).unwrap(),
        serde_json::from_str(&std::fs::read_to_string(&b).unwrap()).unwrap(),
    );
    for k in [
        "steps",
        "sim_time",
        "dt_first",
        "dt_next",
        "kinetic_energy",
        "internal_energy",
        "momentum",
        "final_length_m",
        "face_diameter_m",
        "history",
        "energy",
        "cfl",
        "bulk_viscosity",
        "particles",
        "dd_patch_particles",
    ] {
        assert_eq!(va[k], vb[k], "{k} differs");
    }
    assert_eq!(f(&va, "cfl"), 0.4);
    let (mut sa, sb) = (va["spec"].clone(), vb["spec"].clone());
    assert_eq!(sa["budget"]["warmup"], 1, "the resolved warm-up is echoed");
    sa["outputs"]["json"] = sb["outputs"]["json"].clone();
    assert_eq!(sa, sb);
    // --print-spec: the TOML of the flags' spec, which runs the same as the flags.
    let out = mpm(&[&args[..], &["--cfl", "0.4", "--q", "1.2,0.1", "--print-spec"]].concat());
    assert!(out.status.success(), "{}", text(&out.stderr));
    let toml = dir.path().join("run.toml");
    std::fs::write(&toml, &out.stdout).unwrap();
    let c = dir.path().join("c.json");
    let out = mpm(&["run", "--spec", toml.to_str().unwrap(), "--json", c.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let vc: Value = serde_json::from_str(&std::fs::read_to_string(&c).unwrap()).unwrap();
    assert_eq!(va["final_length_m"], vc["final_length_m"]);
    assert_eq!(va["kinetic_energy"], vc["kinetic_energy"]);
}

/// A spec file with an unknown key, another version, an out-of-range value or a missing
/// file is refused, naming what is wrong, and writes no summary.
#[test]
fn bad_spec_files_are_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let out = mpm(&["run", "taylor", "--model", "1", "--steps", "2", "--print-spec"]);
    let good = text(&out.stdout);
    let json = dir.path().join("never.json");
    for (edit, says) in [
        (good.replace("threads = 1", "threads = 1\nthreds = 2"), "threds"),
        (good.replace("spec_version = 1", "spec_version = 9"), "spec_version 9"),
        (good.replace("cfl = 0.5", "cfl = 2.0"), "--cfl"),
        (good.replace("model = 1", "model = 7"), "--model"),
        (good.replace("strategy = \"serial\"", "strategy = \"dd\"\ncpus = [0, 1]"), "--cpus"),
    ] {
        let f = dir.path().join("bad.toml");
        std::fs::write(&f, edit).unwrap();
        let out = mpm(&["run", "--spec", f.to_str().unwrap(), "--json", json.to_str().unwrap()]);
        let err = text(&out.stderr);
        assert!(!out.status.success() && err.contains(says), "{says}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        assert!(!json.exists());
    }
    let out = mpm(&["run", "--spec", dir.path().join("missing.toml").to_str().unwrap()]);
    assert!(!out.status.success() && text(&out.stderr).contains("cannot read the spec file"));
    let out = mpm(&["run"]);
    assert!(!out.status.success() && text(&out.stderr).contains("--spec"), "{}", text(&out.stderr));
}

#[test]
fn end_time_run_lands_exactly_on_the_end_time() {
    let (v, out) = run_json(&["--model", "1", "--end-time", "1e-6"]);
    assert_eq!(v["end_reason"], "end_time");
    assert!((f(&v, "sim_time") - 1e-6).abs() < 1e-18, "{}", v["sim_time"]);
    assert_eq!(f(&v, "end_time"), 1e-6);
    assert!(v["step_limit"].is_null());
    let s = text(&out.stdout);
    assert!(s.contains("ns per particle-step"), "{s}");
    assert!(s.contains("final") || s.contains("length"), "{s}");
}

#[test]
fn dd_on_two_pinned_workers_reports_their_cpus_and_stage_times() {
    let (v, _) =
        run_json(&["--model", "1", "--steps", "20", "--strategy", "dd", "--threads", "2", "--cpus", "0,1", "--quiet"]);
    assert_eq!(v["strategy"], "dd");
    assert_eq!(u(&v, "threads"), 2);
    assert_eq!(v["requested_cpus"], serde_json::json!([0, 1]));
    assert_eq!(v["observed_cpus"], serde_json::json!([0, 1]));
    assert_eq!(v["worker_affinity"], serde_json::json!([[0], [1]]));
    assert_eq!(v["pinning_verified"], true);
    assert_eq!(v["dd_layout"], serde_json::json!([2, 1, 1]));
    assert!(f(&v, "grid_stage_s") > 0.0);
    assert!(f(&v, "particle_stage_s") > 0.0);
    for s in ["binning", "scatter", "assembly", "remap_scatter", "stress_update"] {
        assert!(v["substages"][s].as_f64().unwrap() > 0.0, "{s}");
    }
    // Both workers worked in the steady steps, and no more than the steady wall time.
    let busy: Vec<f64> = v["worker_busy_s"].as_array().unwrap().iter().map(|b| b.as_f64().unwrap()).collect();
    assert_eq!(busy.len(), 2);
    assert!(busy.iter().all(|&b| b > 0.0 && b <= f(&v, "steady_wall_s")), "{busy:?}");
    let imbalance = f(&v, "load_imbalance");
    let max = busy.iter().copied().fold(0.0, f64::max);
    assert!((imbalance - max / (0.5 * (busy[0] + busy[1]))).abs() < 1e-12, "{imbalance}");
    let p = &v["dd_patch_particles"];
    assert!(u(p, "min") <= u(p, "max") && f(p, "mean") == 0.5 * u(&v, "particles") as f64, "{p}");
    assert!(f(p, "imbalance_mean") >= 1.0 && f(p, "imbalance_max") >= f(p, "imbalance_mean"), "{p}");
    let mut want: BTreeSet<String> = REQUIRED_KEYS.iter().map(|s| s.to_string()).collect();
    want.insert("dd_layout".into());
    want.insert("dd_patch_particles".into());
    assert_eq!(keys(&v), want);
}

/// A paired run: the 2-thread solver's summary with a `paired` section (the blocks of both
/// solvers and their ratios), the injected slowdown recorded with the extra work's time,
/// the work counters of both workers and their CPU time against the wall; a step budget
/// that does not divide into the blocks is refused before anything runs.
#[test]
fn paired_run_reports_its_blocks_work_and_injected_slowdown() {
    let paired = |steps: &'static str| {
        [
            "--model",
            "1",
            "--strategy",
            "dd",
            "--threads",
            "2",
            "--steps",
            steps,
            "--warmup",
            "1",
            "--paired-blocks",
            "3",
        ]
    };
    let mut args = paired("7").to_vec();
    args.extend(["--inject-slowdown", "0.2", "--quiet"]);
    let (v, _) = run_json(&args);
    let p = &v["paired"];
    assert_eq!((u(p, "blocks"), u(p, "block_steps"), u(&v, "steps")), (3, 2, 7));
    let list = |k: &str| p[k].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect::<Vec<f64>>();
    let (t1, tt, e) = (list("t1_s_per_step"), list("tt_s_per_step"), list("block_efficiency"));
    assert_eq!((t1.len(), tt.len(), e.len()), (3, 3, 3));
    for b in 0..3 {
        assert!((e[b] - t1[b] / (2.0 * tt[b])).abs() < 1e-12 * e[b], "block {b}");
    }
    let geo = (e.iter().map(|x| x.ln()).sum::<f64>() / 3.0).exp();
    assert!((f(p, "efficiency") - geo).abs() < 1e-12);
    assert!(f(p, "max_position_difference") < 1e-9, "the two solvers ran the same steps");
    assert_eq!(v["spec"]["paired"]["blocks"], 3);
    assert_eq!((f(&v, "inject_slowdown"), v["spec"]["inject_slowdown"].as_f64()), (0.2, Some(0.2)));
    assert!(f(&v, "injected_s") > 0.0);
    let w = &v["work"];
    assert_eq!(w["worker_bytes"].as_array().unwrap().len(), 2);
    assert!(f(w, "efficiency_bound") > 0.0 && f(w, "efficiency_bound") <= 1.0, "{w}");
    assert_eq!(v["noise"]["workers"].as_array().unwrap().len(), 2);
    assert_eq!(p["reference_noise"]["workers"].as_array().unwrap().len(), 1);

    let mut args = vec!["run", "taylor"];
    args.extend(paired("8"));
    let bad = mpm(&args);
    assert_eq!(bad.status.code(), Some(1));
    let err = text(&bad.stderr);
    assert!(err.contains("not a multiple of 3") && err.contains("--steps 7"), "{err}");
}

/// Balanced cuts run as a strategy of their own and report their patch counts.
#[test]
fn dd_balanced_runs_and_reports_its_patch_counts() {
    let (v, _) = run_json(&["--model", "1", "--steps", "5", "--strategy", "dd-balanced", "--threads", "4", "--quiet"]);
    assert_eq!(v["strategy"], "dd-balanced");
    assert_eq!(v["dd_layout"], serde_json::json!([2, 2, 1]));
    let p = &v["dd_patch_particles"];
    assert!(f(p, "imbalance_max") < 1.1, "the bar is symmetric: balanced cuts split it evenly, {p}");
    let s: Summary = serde_json::from_value(v.clone()).unwrap();
    assert_eq!(s.strategy, Strategy::DdBalanced);
}

/// The two strategies used since the paper run, scatter straight into the global arrays (no
/// assembly, no part bytes) and report their work: colour's binning, atomic's atomic bytes.
#[test]
fn colour_and_atomic_run_without_an_assembly() {
    for strategy in ["colour", "atomic"] {
        let (v, _) = run_json(&["--model", "1", "--steps", "5", "--strategy", strategy, "--threads", "2", "--quiet"]);
        assert_eq!(v["strategy"], strategy);
        let s: Summary = serde_json::from_value(v.clone()).unwrap();
        assert_eq!(s.strategy.name(), strategy);
        let work = s.figures.work.as_ref().expect("work counters");
        let stages = &work.workers[1];
        assert!(!stages.contains_key(&mpm_core::Substage::Assembly), "{strategy}: {stages:?}");
        assert!(stages.values().all(|w| w.part_bytes == 0), "{strategy}: {stages:?}");
        let binned = stages.contains_key(&mpm_core::Substage::Binning);
        let atomics = stages.values().any(|w| w.atomic_bytes > 0);
        assert_eq!((binned, atomics), (strategy == "colour", strategy == "atomic"), "{strategy}: {stages:?}");
        assert!(v.get("dd_layout").is_none(), "{strategy}");
    }
}

#[test]
fn ae_on_two_workers_runs() {
    let (v, _) = run_json(&["--model", "1", "--steps", "20", "--strategy", "ae", "--threads", "2", "--quiet"]);
    assert_eq!(v["strategy"], "ae");
    assert_eq!(u(&v, "steps"), 20);
    assert!(f(&v, "wall_s") > 0.0);
    assert!(v["substages"]["assembly"].as_f64().unwrap() > 0.0);
    assert!(v.get("dd_layout").is_none() && v.get("dd_patch_particles").is_none());
}

#[test]
fn more_threads_than_cores_works_and_is_flagged() {
    let threads = (cores() + 1).max(4);
    let t = threads.to_string();
    let (v, out) = run_json(&["--model", "1", "--steps", "5", "--strategy", "dd", "--threads", &t, "--quiet"]);
    assert_eq!(v["oversubscribed"], true);
    assert_eq!(u(&v, "threads"), threads as u64);
    let err = text(&out.stderr);
    let line = format!("oversubscribed: {threads} threads on {} cores", cores());
    assert!(err.contains(&line), "{err}");
    assert_eq!(err.matches("oversubscribed").count(), 1, "{err}");
}

/// A bad invocation: non-zero exit, a message containing `says`, no panic, no JSON.
fn rejects(args: &[&str], says: &str) {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("never.json");
    let mut all = vec!["run", "taylor"];
    all.extend_from_slice(args);
    if !args.contains(&"--json") {
        all.extend_from_slice(&["--json", json.to_str().unwrap()]);
    }
    let out = mpm(&all);
    let err = text(&out.stderr);
    assert!(!out.status.success(), "{all:?} succeeded");
    assert!(err.contains(says), "{all:?}: stderr lacks {says:?}:\n{err}");
    assert!(!err.contains("panicked"), "{all:?} panicked:\n{err}");
    assert!(!json.exists(), "{all:?} wrote a summary");
    assert_no_temp_files(dir.path());
}

#[test]
fn several_ranks_without_a_launcher_or_without_mpi_is_a_clear_error() {
    let says = if cfg!(feature = "mpi") { "needs a launcher" } else { "MPI is not compiled into this mpm" };
    rejects(&["--model", "1", "--ranks", "2", "--steps", "0"], says);
    rejects(&["--model", "1", "--rank-layout", "2x1x1", "--steps", "0"], "needs several ranks");
    rejects(&["--model", "1", "--split-wait", "--steps", "0"], "no other rank to wait for");
    rejects(&["--model", "1", "--rank-layout", "2x1", "--steps", "0"], "not a rank layout");
}

#[test]
fn bad_input_is_a_clear_error() {
    rejects(&["--model", "5", "--steps", "0"], "--model");
    rejects(&["--model", "5", "--steps", "0"], "1..=4");
    rejects(&["--steps", "0"], "--model");
    rejects(&["--model", "1", "--threads", "0"], "at least 1");
    rejects(&["--model", "1", "--threads", "2"], "use --strategy ae, dd, dd-balanced, colour or atomic");
    rejects(&["--model", "1", "--strategy", "dd", "--threads", "2", "--cpus", "0,99"], "CPU 99 does not exist");
    rejects(&["--model", "1", "--strategy", "dd", "--threads", "2", "--cpus", "0"], "one CPU per worker");
    rejects(&["--model", "1", "--strategy", "dd", "--threads", "2", "--cpus", "0,x"], "not a CPU number");
    rejects(&["--model", "1", "--end-time", "-1e-6"], "end time must be a positive");
    rejects(&["--model", "1", "--cfl", "1.5"], "CFL number must be in (0, 1]");
    rejects(&["--model", "1", "--velocity", "-3"], "impact speed");
    rejects(&["--model", "1", "--every", "10"], "--vtk");
    rejects(&["--model", "1", "--steps", "5", "--warmup", "5"], "no steady-state steps");
    rejects(&["--model", "1", "--strategy", "bogus"], "invalid value 'bogus'");
    rejects(&["--model", "1", "--q", "1.5"], "two numbers C1,C2");
    rejects(&["--model", "1", "--q", "-1,0"], "finite number >= 0");
    rejects(&["--model", "1", "--energy-rise-limit", "0"], "energy rise limit");
    rejects(&["--model", "1", "--eos", "ideal-gas"], "invalid value 'ideal-gas'");
    // Negative numbers reach the range checks, not clap's "unexpected argument".
    rejects(&["--model", "1", "--threads", "-1"], "the thread count must be at least 1");
    rejects(&["--model", "1", "--steps", "-5"], "-5 is negative");
    rejects(&["--model", "-1"], "-1 is not in 1..=4");
    rejects(&["--model", "1", "--cfl", "-0.5"], "invalid physics.cfl (--cfl)");
    rejects(&["--model", "1", "--strategy", "dd", "--threads", "100000"], "more than 16 per core");
}

/// Before it allocates, mpm estimates the run's memory and refuses one beyond the memory
/// it may use, saying both (and which bound binds), and what to change; negative sizes get
/// the range check.
#[test]
fn runs_that_cannot_fit_or_have_negative_sizes_are_refused_before_allocating() {
    let start = std::time::Instant::now();
    let out = mpm(&["run", "impact", "--spacing", "0.05e-3", "--cell", "0.2e-3", "--steps", "1", "--quiet"]);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    // The refusal names the bound that binds: the host's, a cgroup's or a Slurm job's.
    let bound = ["the host has", "the cgroup ", "the Slurm job "].iter().any(|b| err.contains(b));
    assert!(err.contains("the run needs about") && bound && err.contains("--force"), "{err}");
    assert!(!err.contains("memory allocation") && !err.contains("panicked"), "{err}");
    assert!(start.elapsed().as_secs_f64() < 5.0, "refused before building anything");
    let out = mpm(&["run", "impact", "--cell", "-1", "--steps", "1"]);
    let err = text(&out.stderr);
    assert!(!out.status.success() && err.contains("invalid scenario.cell_m (--cell)") && err.contains("-1"), "{err}");
}

/// `--eos paper` is the printed form, `--eos lsdyna` the Hugoniot form; `--q 0,0` turns the
/// viscosity off; an infinite energy-rise limit is written as `null`.
#[test]
fn eos_aliases_and_physics_options_reach_the_summary() {
    let (v, _) = run_json(&["--model", "1", "--steps", "2", "--quiet", "--eos", "paper", "--q", "0,0"]);
    assert_eq!(v["eos"], "mie-gruneisen (paper-printed form)");
    assert_eq!(f(&v["bulk_viscosity"], "c1"), 0.0);
    assert_eq!(f(&v["bulk_viscosity"], "c2"), 0.0);
    let (v, _) =
        run_json(&["--model", "1", "--steps", "2", "--quiet", "--eos", "lsdyna", "--energy-rise-limit", "inf"]);
    assert_eq!(v["eos"], "mie-gruneisen (hugoniot form)");
    assert!(v["energy_rise_limit"].is_null());
    assert_eq!(f(&v, "cfl"), 0.5);
}

/// A limit below round-off stops the run at the first step whose energy rose at all.
#[test]
fn energy_rise_above_the_limit_stops_the_run_without_a_summary() {
    solver_fails(&["--model", "1", "--energy-rise-limit", "1e-300", "--steps", "100"], "total energy rose");
}

/// The plate at 3 km/s (default slab, CFL 0.2): shock speed within 3 % and shocked pressure
/// within 5 % of Rankine-Hugoniot, from the JSON; the human summary prints both.
#[test]
fn plate_at_3_km_s_matches_rankine_hugoniot() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("plate.json");
    let out = mpm(&["run", "plate", "--velocity", "3000", "--json", json.to_str().unwrap()]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let v: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["scenario"], "plate");
    assert_eq!(f(&v, "cfl"), 0.2);
    assert_eq!(v["end_reason"], "end_time");
    assert!(v["plate_configuration"].as_str().unwrap().contains("rigid wall"));
    let rel = |a: &str, b: &str| f(&v, a) / f(&v, b) - 1.0;
    assert_eq!(f(&v, "rh_shock_speed_m_s"), 2092.0 + 1.45 * 3000.0);
    assert!(rel("shock_speed_m_s", "rh_shock_speed_m_s").abs() < 0.03, "{}", v["shock_speed_m_s"]);
    assert!(rel("shock_pressure_pa", "rh_pressure_pa").abs() < 0.05, "{}", v["shock_pressure_pa"]);
    assert!(rel("particle_velocity_m_s", "rh_particle_velocity_m_s").abs() < 0.02);
    assert_eq!(f(&v, "shock_speed_rel_error"), rel("shock_speed_m_s", "rh_shock_speed_m_s"));
    assert!(f(&v["energy"], "max_rise") < 1e-9 && f(&v["energy"], "max_fall") < 1e-9);
    let s = text(&out.stdout);
    assert!(s.contains("measured vs Rankine-Hugoniot") && s.contains("shock speed"), "{s}");
    serde_json::from_value::<Summary>(v).unwrap();
}

#[test]
fn unwritable_json_path_is_detected_before_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("no/such/dir/x.json");
    let start = std::time::Instant::now();
    // Without the early check this would run Model 1 to 40 µs (seconds) first.
    let out = mpm(&["run", "taylor", "--model", "1", "--json", missing.to_str().unwrap()]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("does not exist"), "{err}");
    assert!(!err.contains("panicked"));
    assert!(start.elapsed().as_secs_f64() < 2.0, "the check came late");
    assert!(!missing.exists());
    rejects(&["--model", "1", "--json", dir.path().to_str().unwrap()], "is a directory");
}

/// `--json /dev/null` (discard the summary) works and leaves the device a device: writing
/// the summary by a rename over it would, run as root (as CI is), replace `/dev/null` with
/// a regular file for the whole machine.
#[test]
fn json_to_dev_null_leaves_the_device_alone() {
    use std::os::unix::fs::FileTypeExt;
    let out = mpm(&["run", "taylor", "--model", "1", "--steps", "2", "--quiet", "--json", "/dev/null"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let meta = std::fs::metadata("/dev/null").unwrap();
    assert!(meta.file_type().is_char_device(), "mpm replaced /dev/null with a regular file");
}

/// A Taylor run with `args` that the solver stops: exit status 1, the step and `says` in the
/// message, no summary.
fn solver_fails(args: &[&str], says: &str) {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("x.json");
    let mut all = vec!["run", "taylor", "--quiet", "--json", json.to_str().unwrap()];
    all.extend_from_slice(args);
    let out = mpm(&all);
    let err = text(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "{err}");
    assert!(err.contains("the simulation failed"), "{err}");
    assert!(err.contains("step "), "{err}");
    assert!(err.contains(says), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    assert!(!json.exists());
    assert_no_temp_files(dir.path());
}

#[test]
fn solver_failure_prints_the_step_and_writes_no_summary() {
    // 500 m/s with CFL 1 splashes copper out of the fixed grid within ~100 steps.
    solver_fails(&["--model", "1", "--velocity", "500", "--cfl", "1", "--steps", "400"], "left the fixed grid");
}

#[test]
fn vtk_snapshots_and_pvd_are_written() {
    let dir = tempfile::tempdir().unwrap();
    let vtk: PathBuf = dir.path().join("snaps");
    let (v, _) =
        run_json(&["--model", "1", "--steps", "20", "--vtk", vtk.to_str().unwrap(), "--every", "10", "--quiet"]);
    assert!(f(&v, "output_s") > 0.0);
    let mut names: Vec<String> =
        std::fs::read_dir(&vtk).unwrap().map(|e| e.unwrap().file_name().to_string_lossy().into_owned()).collect();
    names.sort();
    assert_eq!(names, ["taylor.pvd", "taylor_000000.vtu", "taylor_000010.vtu", "taylor_000020.vtu"]);
    let pvd = std::fs::read_to_string(vtk.join("taylor.pvd")).unwrap();
    assert_eq!(pvd.matches("<DataSet ").count(), 3, "{pvd}");
    for n in ["taylor_000000.vtu", "taylor_000010.vtu", "taylor_000020.vtu"] {
        assert!(pvd.contains(&format!("file=\"{n}\"")), "{pvd}");
    }
    // Compressed by default: the XML is text, the appended data binary.
    let vtu = text(&std::fs::read(vtk.join("taylor_000020.vtu")).unwrap());
    assert!(vtu.contains(r#"compressor="vtkZLibDataCompressor""#));
    assert!(vtu.contains(r#"<Piece NumberOfPoints="56056" NumberOfCells="56056">"#));
    assert!(vtu.contains(r#"Name="CYCLE" NumberOfTuples="1" format="ascii">20<"#));
}

#[test]
fn impact_run_reports_the_cloud_and_draws_a_radiograph() {
    let dir = tempfile::tempdir().unwrap();
    let json = dir.path().join("impact.json");
    let pics = dir.path().join("pictures");
    let out = Command::new(env!("CARGO_BIN_EXE_mpm"))
        .args(["run", "impact", "--spacing", "2.5e-3", "--cell", "5e-3", "--strategy", "dd", "--threads", "2"])
        .args(["--end-time", "10e-6", "--quiet", "--json"])
        .arg(&json)
        .arg("--radiograph")
        .arg(&pics)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(v["scenario"], "impact");
    assert_eq!(v["grid_mode"], "sparse", "the impact's default grid");
    let (stored, boxed) = (v["final_stored_nodes"].as_u64().unwrap(), v["final_nodes"].as_u64().unwrap());
    assert!(stored > 0 && stored <= boxed + 64 * 64, "stored {stored} of {boxed}");
    for key in [
        "cloud_front_m",
        "cloud_front_robust_m",
        "cloud_width_m",
        "cloud_width_robust_m",
        "hole_diameter_m",
        "front_velocity_m_s",
        "leading_debris_velocity_m_s",
    ] {
        let x = v[key].as_f64().unwrap_or_else(|| panic!("{key} missing"));
        assert!(x.is_finite() && x > 0.0, "{key} = {x}");
    }
    assert!(v["failed_particles"].as_u64().unwrap() > 0);
    // A sample in every microsecond from t = 0, and the end.
    let h = v["cloud_history"].as_array().unwrap();
    assert_eq!(h.len(), 11, "{h:?}");
    assert_eq!(h[0]["time"].as_f64(), Some(0.0));
    assert_eq!(h[10]["time"].as_f64(), v["sim_time"].as_f64());
    assert_eq!(h[10]["cloud_front_robust"].as_f64(), v["cloud_front_robust_m"].as_f64());
    assert!(h.windows(2).all(|w| w[0]["time"].as_f64() < w[1]["time"].as_f64()));
    for k in ["cloud_front", "cloud_width", "cloud_width_robust", "kinetic", "internal", "total", "failed"] {
        assert!(h[10][k].as_f64().is_some(), "{k}");
    }
    for name in ["radiograph_final.png", "history.png"] {
        let png = std::fs::read(pics.join(name)).unwrap();
        assert_eq!(&png[1..4], b"PNG", "{name}");
    }
    serde_json::from_value::<Summary>(v).unwrap();
}
