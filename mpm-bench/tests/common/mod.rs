//! Helpers shared by the integration tests: crafted campaigns (rows, manifest) with known
//! speedups, efficiencies and memory, written to a folder as the harness would.
#![allow(dead_code)]

use mpm_bench::campaign::plan::matrix::PlannedRun;
use mpm_bench::campaign::store::csv::CsvLog;
use mpm_bench::campaign::store::manifest::{self, GitInfo, Manifest, SoftwareInfo, MANIFEST_VERSION};
use mpm_bench::campaign::store::record::{Row, Status, SCHEMA_VERSION};
use mpm_bench::machine::fingerprint;
use mpm_bench::machine::topology::Machine;
use mpm_core::Strategy;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

pub const AE: Strategy = Strategy::ArrayExpansion;
pub const DD: Strategy = Strategy::DomainDecomposition;
pub const DDB: Strategy = Strategy::DdBalanced;

/// How a crafted campaign is made.
#[derive(Clone)]
pub struct Craft {
    /// hwloc synthetic topology of the manifest (None: no manifest).
    pub topo: Option<&'static str>,
    pub models: Vec<u32>,
    pub threads: Vec<usize>,
    /// Threads above this are oversubscribed.
    pub cores: usize,
    /// Cores per socket (efficiency drops past it).
    pub per_socket: usize,
    pub reps: u32,
    /// Multiplicative noise per repetition.
    pub noise: Vec<f64>,
    /// Factor on every time with more than one thread.
    pub slow_parallel: f64,
    /// Factor on every time.
    pub slow_all: f64,
    /// Skip Model4 AE at 4+ threads (memory guard).
    pub skip_m4_ae: bool,
    pub pin: &'static str,
    /// Every repetition at this thread count failed (the solver crashed).
    pub fail_threads: Option<usize>,
    /// O0's parallel loss relative to O3's (below 1: O0 scales better).
    pub o0_loss: f64,
    /// Parallel efficiency of DD's grid stage.
    pub dd_grid_eff: f64,
    /// Parallel efficiency of AE's particle stage.
    pub ae_particle_eff: f64,
    /// Bytes of AE's nodal copies per extra thread and model number.
    pub ae_copy_bytes: f64,
}

impl Default for Craft {
    fn default() -> Self {
        Self {
            topo: Some("pack:2 core:4 pu:1"),
            models: vec![1, 2, 3, 4],
            threads: vec![1, 2, 4, 6, 8],
            cores: 8,
            per_socket: 4,
            reps: 3,
            noise: vec![1.0, 1.01, 0.99],
            slow_parallel: 1.0,
            slow_all: 1.0,
            skip_m4_ae: true,
            pin: "close",
            fail_threads: None,
            o0_loss: 0.3,
            dd_grid_eff: 0.9,
            ae_particle_eff: 0.93,
            ae_copy_bytes: 3e7,
        }
    }
}

/// Stage efficiencies of the crafted machine: DD beats AE, more so for larger models; AE's
/// grid stage is its bottleneck; O0 scales better than O3; crossing a socket costs 20 %.
pub fn eff(model: u32, strategy: Strategy, opt: &str, particle: bool, n: usize, c: &Craft) -> f64 {
    if n == 1 {
        return 1.0;
    }
    let mut e = match (strategy, particle) {
        (AE, false) => 0.75 - 0.1 * model as f64,
        (AE, true) => c.ae_particle_eff,
        // Balanced cuts: less waiting for the fullest patch (claim C7).
        (DDB, false) => c.dd_grid_eff + 0.05,
        (DDB, true) => 0.97,
        (_, false) => c.dd_grid_eff,
        (_, true) => 0.95,
    };
    if opt == "o0" {
        e = 1.0 - c.o0_loss * (1.0 - e);
    }
    if n > c.per_socket {
        e *= 0.8;
    }
    e
}

pub fn fingerprint(topo: Option<&str>) -> String {
    topo.map(|t| fingerprint::fingerprint(&Machine::synthetic(t).unwrap())).unwrap_or_else(|| "nomanifest".into())
}

pub fn write_campaign(dir: &Path, c: &Craft) -> PathBuf {
    std::fs::create_dir_all(dir).unwrap();
    let fp = fingerprint(c.topo);
    let mut log = CsvLog::open(&dir.join("runs.csv")).unwrap();
    for &m in &c.models {
        let (g1, p1) = (0.004 * m as f64, 0.006 * m as f64);
        for strategy in [AE, DD, DDB] {
            for opt in ["o3", "o0"] {
                let slow = if opt == "o0" { 5.0 } else { 1.0 };
                for &n in &c.threads {
                    for rep in 0..c.reps {
                        let noise = c.noise[rep as usize % c.noise.len()];
                        let par = if n > 1 { c.slow_parallel } else { 1.0 };
                        let k = slow * noise * par * c.slow_all;
                        let g = g1 * k / (n as f64 * eff(m, strategy, opt, false, n, c));
                        let p = p1 * k / (n as f64 * eff(m, strategy, opt, true, n, c));
                        let mem = 1e8 * m as f64
                            + if strategy == AE { c.ae_copy_bytes * m as f64 * (n - 1) as f64 } else { 1e6 };
                        let skip = c.skip_m4_ae && m == 4 && strategy == AE && n >= 4;
                        let steps = 10u64;
                        if c.fail_threads == Some(n) && !skip {
                            log.append(&failed_row(dir, &fp, m, strategy, opt, n, rep)).unwrap();
                            continue;
                        }
                        let mut row = planned_row(dir, &fp, m, strategy, opt, n, rep, c.pin, steps);
                        row.placement.oversubscribed = n > c.cores;
                        row.outcome.mem_estimate_bytes = if skip { 9_500_000_000 } else { mem as u64 };
                        if skip {
                            row.outcome.status = Status::Skipped;
                            row.outcome.reason = "memory guard: estimated 9.5 GiB exceeds the limit".into();
                        } else {
                            let f = row.measured_mut();
                            f.size.particles = 10_000 * m as usize;
                            f.size.nodes = 5_000 * m as usize;
                            f.size.mean_nodes = 5_000.0 * m as f64;
                            f.progress.steps = steps;
                            f.progress.steady_steps = steps;
                            let t = &mut f.timing;
                            t.wall_s = (g + p) * steps as f64;
                            t.grid_stage_s = g * steps as f64;
                            t.particle_stage_s = p * steps as f64;
                            t.steady_wall_s = t.wall_s;
                            t.steady_grid_stage_s = Some(t.grid_stage_s);
                            t.steady_particle_stage_s = Some(t.particle_stage_s);
                            t.steady_s_per_step = Some(g + p);
                            f.memory.peak_rss_bytes = Some(mem as u64);
                            let imbalance = match strategy {
                                DD => Some(1.0 + 0.05 * (n - 1) as f64),
                                DDB => Some(1.0 + 0.002 * (n - 1) as f64),
                                _ => None,
                            };
                            f.balance.dd_patch_particles = imbalance.map(|imbalance_mean| {
                                mpm_spec::summary::PatchCounts { imbalance_mean, ..Default::default() }
                            });
                        }
                        log.append(&row).unwrap();
                    }
                }
            }
        }
    }
    if let Some(t) = c.topo {
        write_manifest(dir, t);
    }
    dir.to_path_buf()
}

/// The row of a planned Taylor run of a crafted campaign in `dir`, nothing measured yet.
#[allow(clippy::too_many_arguments)]
pub fn planned_row(
    dir: &Path,
    fp: &str,
    model: u32,
    strategy: Strategy,
    opt: &str,
    threads: usize,
    rep: u32,
    pin: &str,
    steps: u64,
) -> Row {
    let mut run = PlannedRun::taylor(model, strategy, opt.parse().unwrap(), threads, steps);
    run.rep = rep;
    run.pin = pin.parse().unwrap();
    let mut row = Row::planned(run);
    row.id.campaign_id = dir.file_name().unwrap().to_string_lossy().into_owned();
    row.id.run_id = format!("m{model}-{strategy}-{opt}-t{threads}-{pin}-r{rep}");
    row.id.machine_id = fp.into();
    assert_eq!(row.id.schema_version, SCHEMA_VERSION);
    row
}

/// A repetition whose solver crashed.
pub fn failed_row(dir: &Path, fp: &str, model: u32, strategy: Strategy, opt: &str, threads: usize, rep: u32) -> Row {
    let mut row = planned_row(dir, fp, model, strategy, opt, threads, rep, "close", 10);
    row.outcome.status = Status::Failed;
    row.outcome.reason = "solver exited with status 101".into();
    row
}

/// The manifest of a crafted campaign on the hwloc synthetic topology `t` (16 GiB).
pub fn write_manifest(dir: &Path, t: &str) {
    let machine = Machine::synthetic(t).unwrap();
    let mut info = fingerprint::machine_info(&machine);
    info.memory_bytes = 16 << 30;
    // Fixed host facts, so that reports of crafted campaigns are the same on every machine.
    (info.os, info.kernel, info.arch, info.cpu_governor) =
        ("Test OS".into(), "6.1.0-test".into(), "x86_64".into(), "performance".into());
    if let Some(h) = info.hardware_class.as_mut() {
        h.arch = "x86_64".into();
    }
    let m = Manifest {
        manifest_version: MANIFEST_VERSION,
        campaign_id: dir.file_name().unwrap().to_string_lossy().into_owned(),
        reference: false,
        campaign: serde_json::Value::Null,
        machine: info,
        software: SoftwareInfo {
            rustc: "rustc test".into(),
            cargo_profiles: serde_json::Value::Null,
            rustflags: String::new(),
            binaries: vec![],
            env: BTreeMap::new(),
            hwloc_api: "2.9.0".into(),
            harness_version: "test".into(),
            git: GitInfo::default(),
            mpi_launcher: None,
        },
        sessions: vec![],
        nodes: BTreeMap::new(),
    };
    manifest::write(&dir.join("manifest.json"), &m).unwrap();
}
