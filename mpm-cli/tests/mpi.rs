//! Runs split over MPI ranks (`mpirun -n R mpm run ...`) against one process: Model 1 and a
//! coarse impact over R = 1..4 ranks x T = 1, 2 threads (and every strategy inside the
//! ranks: serial, AE and DD over 1-4 ranks, colour and atomic over 2) end, after 50 steps,
//! at the state of the serial solver to 1e-9 (relative to the largest value of each
//! quantity), with particles moving between ranks on the way; an identical rerun is bitwise equal; rank 0's
//! summary lists every rank; `--split-wait` changes no bit and reports each rank's waiting;
//! particles leaving the fixed grid stop a run over ranks as they stop one process.
//!
//! The scenario figures over 2 and 3 ranks (measured across the ranks, no particle gathered)
//! are to the bit those one process computes from the run's own final state (its
//! `--dump-state`), match one process's run to round-off, and the impact's cloud history
//! and the plate's shock front are sampled at the steps one process samples them.
//!
//! Needs `mpirun` (Open MPI: `apt-get install openmpi-bin libopenmpi-dev`, see
//! scripts/bootstrap.sh).
#![cfg(feature = "mpi")]

use mpm_core::scenario::impact::{self, Impact};
use mpm_core::scenario::taylor::{self, TaylorBar};
use mpm_core::Setup;
use mpm_spec::Summary;
use std::path::Path;
use std::process::Command;

const MPM: &str = env!("CARGO_BIN_EXE_mpm");
const STEPS: &str = "50";

/// One particle of a `--dump-state` file: id, then position, velocity, stress.
type Record = (u64, [f64; 12]);

fn read_state(path: &Path) -> Vec<Record> {
    let bytes = std::fs::read(path).unwrap();
    assert_eq!(bytes.len() % 104, 0, "a state record is 104 bytes");
    bytes
        .chunks_exact(104)
        .map(|r| {
            let id = u64::from_le_bytes(r[..8].try_into().unwrap());
            (id, std::array::from_fn(|i| f64::from_le_bytes(r[8 + 8 * i..16 + 8 * i].try_into().unwrap())))
        })
        .collect()
}

/// Run `mpm run <args>` over `ranks` ranks (0: without mpirun) and return its state file's
/// bytes and its summary.
fn run(dir: &Path, name: &str, ranks: usize, args: &[&str]) -> (Vec<u8>, Summary) {
    let (state, json) = (dir.join(format!("{name}.bin")), dir.join(format!("{name}.json")));
    let mut all: Vec<String> = vec!["run".into()];
    all.extend(args.iter().map(|s| s.to_string()));
    all.extend(["--steps", STEPS, "--quiet", "--dump-state"].map(String::from));
    all.push(state.to_str().unwrap().into());
    all.push("--json".into());
    all.push(json.to_str().unwrap().into());
    let mut cmd = if ranks == 0 {
        Command::new(MPM)
    } else {
        let mut c = Command::new("mpirun");
        c.args(["--oversubscribe", "--allow-run-as-root", "-n", &ranks.to_string(), MPM]);
        c
    };
    let out = cmd.args(&all).output().expect("cannot start mpirun: install openmpi-bin (scripts/bootstrap.sh)");
    assert!(
        out.status.success(),
        "{ranks} rank(s): mpm {all:?} failed\nstdout:\n{}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
    let summary: Summary = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    (std::fs::read(&state).unwrap(), summary)
}

/// Largest difference of positions, velocities and stresses, each relative to the largest
/// magnitude of that quantity in `reference`.
fn relative_differences(reference: &[Record], other: &[Record]) -> [f64; 3] {
    assert_eq!(reference.len(), other.len(), "particle counts differ");
    let groups = [(0, 3), (3, 6), (6, 12)];
    std::array::from_fn(|g| {
        let (lo, hi) = groups[g];
        let scale = reference.iter().flat_map(|r| r.1[lo..hi].iter()).fold(0.0f64, |m, v| m.max(v.abs()));
        let diff = reference
            .iter()
            .zip(other)
            .flat_map(|(a, b)| {
                assert_eq!(a.0, b.0, "particle ids differ");
                (lo..hi).map(move |i| (a.1[i] - b.1[i]).abs())
            })
            .fold(0.0f64, f64::max);
        diff / scale.max(f64::MIN_POSITIVE)
    })
}

/// Every rank count and thread count against one serial process, layouts cut across the
/// direction of motion (z) so that particles cross between ranks.
fn check_equivalence(scenario: &[&str]) {
    let dir = tempfile::tempdir().unwrap();
    let serial: Vec<&str> = scenario.iter().copied().chain(["--strategy", "serial"]).collect();
    let (reference_bytes, reference_summary) = run(dir.path(), "serial", 0, &serial);
    let reference = read_state(dir.path().join("serial.bin").as_path());
    assert_eq!(reference.len(), reference_summary.figures.size.particles);
    assert!(!reference_bytes.is_empty());
    for (ranks, layout) in [(1, "1x1x1"), (2, "1x1x2"), (3, "1x1x3"), (4, "2x1x2")] {
        for threads in [1, 2] {
            let strategy = match (threads, ranks) {
                (1, _) => "serial",
                (_, 3) => "ae",
                _ => "dd",
            };
            let name = format!("r{ranks}t{threads}");
            let t = threads.to_string();
            let mut args: Vec<&str> = scenario.to_vec();
            args.extend(["--strategy", strategy, "--threads", &t]);
            if ranks > 1 {
                args.extend(["--rank-layout", layout]);
            }
            let (_, summary) = run(dir.path(), &name, ranks, &args);
            let state = read_state(&dir.path().join(format!("{name}.bin")));
            let d = relative_differences(&reference, &state);
            assert!(d.iter().all(|&x| x <= 1e-9), "{name} ({strategy}): relative differences {d:?} exceed 1e-9");
            assert_eq!(summary.figures.size.particles, reference_summary.figures.size.particles);
            if ranks > 1 {
                let reports = summary.ranks.as_ref().expect("rank 0's summary lists the ranks");
                assert_eq!(reports.len(), ranks);
                let migrated: u64 = reports.iter().map(|r| r.migrated).sum();
                assert!(migrated > 0, "{name}: no particle moved between ranks in {STEPS} steps");
                let held: usize = reports.iter().map(|r| r.particles).sum();
                assert_eq!(held, reference_summary.figures.size.particles);
                for r in reports {
                    assert_eq!(r.cpus.len(), threads, "{name}: rank {} CPUs {:?}", r.rank, r.cpus);
                    assert!(r.exchange.halo_bytes > 0 && r.exchange.seconds > 0.0, "{name}: rank {}", r.rank);
                    assert!(r.peak_rss_bytes.is_some_and(|b| b > 1_000_000), "{name}: rank {} memory", r.rank);
                }
            } else {
                assert!(summary.ranks.is_none());
            }
        }
    }
    // The strategies used since the paper inside each of 2 ranks of 2 threads.
    for strategy in ["colour", "atomic"] {
        let name = format!("r2t2-{strategy}");
        let args: Vec<&str> = scenario
            .iter()
            .copied()
            .chain(["--strategy", strategy, "--threads", "2", "--rank-layout", "1x1x2"])
            .collect();
        run(dir.path(), &name, 2, &args);
        let d = relative_differences(&reference, &read_state(&dir.path().join(format!("{name}.bin"))));
        assert!(d.iter().all(|&x| x <= 1e-9), "{name}: relative differences {d:?} exceed 1e-9");
    }
    // An identical rerun is bitwise equal.
    let args: Vec<&str> =
        scenario.iter().copied().chain(["--strategy", "dd", "--threads", "2", "--rank-layout", "1x1x3"]).collect();
    let (first, plain) = run(dir.path(), "again1", 3, &args);
    let (second, _) = run(dir.path(), "again2", 3, &args);
    assert!(first == second, "two identical runs over 3 ranks differ");
    // --split-wait only adds barriers: the same bits, and every rank reports its waiting
    // apart from the exchange time.
    let split: Vec<&str> = args.iter().copied().chain(["--split-wait"]).collect();
    let (third, timed) = run(dir.path(), "again3", 3, &split);
    assert!(first == third, "--split-wait changed the result");
    for r in plain.ranks.as_ref().unwrap() {
        assert_eq!(r.exchange.wait_seconds, None, "rank {}: waiting is not measured without --split-wait", r.rank);
    }
    for r in timed.ranks.as_ref().unwrap() {
        let wait = r.exchange.wait_seconds.unwrap_or_else(|| panic!("rank {}: no wait_seconds", r.rank));
        assert!(wait > 0.0 && r.exchange.seconds > 0.0, "rank {}: {:?}", r.rank, r.exchange);
    }
}

#[test]
fn model_1_over_one_to_four_ranks_matches_one_process() {
    check_equivalence(&["taylor", "--model", "1"]);
}

#[test]
fn coarse_impact_over_one_to_four_ranks_matches_one_process() {
    check_equivalence(&["impact", "--spacing", "2.12e-3", "--cell", "4.24e-3"]);
}

/// Particles leaving the fixed grid end a run over ranks at the step and with the count of
/// one process (over ranks the test runs on the reduced bounding box, since a rank's grid is
/// only its part).
#[test]
fn leaving_the_fixed_grid_over_ranks_fails_like_one_process() {
    let args = ["run", "taylor", "--model", "1", "--velocity", "3000", "--energy-rise-limit", "inf", "--quiet"];
    let what = |out: &std::process::Output| {
        assert!(!out.status.success(), "the run should fail: particles leave the grid");
        let err = String::from_utf8_lossy(&out.stderr).into_owned();
        let line = err.lines().find(|l| l.contains("left the fixed grid")).unwrap_or_else(|| panic!("stderr:\n{err}"));
        line[line.find("step ").unwrap()..line.find(" (particle").unwrap()].to_string()
    };
    let one = what(&Command::new(MPM).args(args).output().unwrap());
    let two = Command::new("mpirun")
        .args(["--oversubscribe", "--allow-run-as-root", "-n", "2", MPM])
        .args(args)
        .args(["--rank-layout", "2x1x1"])
        .output()
        .expect("cannot start mpirun: install openmpi-bin (scripts/bootstrap.sh)");
    assert_eq!(what(&two), one);
}

/// `|a - b|` within `tol` of the larger magnitude (equal values, zeros included, pass).
fn close(a: f64, b: f64, tol: f64) -> bool {
    a == b || (a - b).abs() <= tol * a.abs().max(b.abs())
}

/// The scenario figures of a summary by name (Taylor bar or impact; `NaN` when absent).
fn figures(s: &Summary) -> Vec<(&'static str, f64)> {
    let v = |x: Option<f64>| x.unwrap_or(f64::NAN);
    match s.scenario().name() {
        "taylor" => vec![
            ("initial_length_m", v(s.figures.scenario.taylor().and_then(|t| t.initial_length_m))),
            ("initial_face_diameter_m", v(s.figures.scenario.taylor().and_then(|t| t.initial_face_diameter_m))),
            ("final_length_m", v(s.figures.scenario.taylor().and_then(|t| t.final_length_m))),
            ("face_diameter_m", v(s.figures.scenario.taylor().and_then(|t| t.face_diameter_m))),
        ],
        _ => vec![
            ("cloud_front_m", v(s.figures.scenario.impact().and_then(|t| t.cloud_front_m))),
            ("cloud_front_robust_m", v(s.figures.scenario.impact().and_then(|t| t.cloud_front_robust_m))),
            ("cloud_width_m", v(s.figures.scenario.impact().and_then(|t| t.cloud_width_m))),
            ("cloud_width_robust_m", v(s.figures.scenario.impact().and_then(|t| t.cloud_width_robust_m))),
            ("hole_diameter_m", v(s.figures.scenario.impact().and_then(|t| t.hole_diameter_m))),
            ("leading_debris_velocity_m_s", v(s.figures.scenario.impact().and_then(|t| t.leading_debris_velocity_m_s))),
            ("debris_mass_kg", v(s.figures.scenario.impact().and_then(|t| t.debris_mass_kg))),
        ],
    }
}

/// The final figures one process computes from a whole state: `setup` (the scenario's
/// initial set, for the masses and the numbering) moved to the positions and velocities of
/// the `--dump-state` records `state`, measured by mpm-core's one-process functions.
fn figures_of_state(
    s: &Summary,
    mut setup: Setup,
    geometry: Option<impact::ImpactGeometry>,
    state: &[Record],
) -> Vec<(&'static str, f64)> {
    let p = &mut setup.particles;
    assert_eq!(p.len(), state.len());
    for (i, (id, r)) in state.iter().enumerate() {
        assert_eq!(*id, i as u64, "the state is in id order");
        p.x[i] = [r[0], r[1], r[2]];
        p.v[i] = [r[3], r[4], r[5]];
    }
    let mut whole = figures(s);
    match geometry {
        None => {
            let f = taylor::measure(p, setup.spacing);
            whole[2].1 = f.length;
            whole[3].1 = f.face_diameter;
        }
        Some(g) => {
            let f = impact::measure(p, &g);
            let values = [
                f.cloud_front,
                f.cloud_front_robust,
                f.cloud_width,
                f.cloud_width_robust,
                f.hole_diameter,
                f.leading_debris_velocity,
                f.debris_mass,
            ];
            for (w, v) in whole.iter_mut().zip(values) {
                w.1 = v;
            }
        }
    }
    whole
}

/// One process and 2 and 3 ranks (layouts across the motion, so particles migrate): the
/// figures over ranks are bitwise those of the run's own final state measured as one
/// process, and one process's run's to round-off; the impact's history has one process's
/// samples (the code before the figures were measured across ranks sampled only the end).
fn check_figures(scenario: &[&str], setup: &dyn Fn() -> (Setup, Option<impact::ImpactGeometry>)) {
    let dir = tempfile::tempdir().unwrap();
    let serial: Vec<&str> = scenario.iter().copied().chain(["--strategy", "serial"]).collect();
    let (_, one) = run(dir.path(), "one", 0, &serial);
    for (ranks, layout) in [(0, ""), (2, "1x1x2"), (3, "1x1x3")] {
        let name = format!("r{ranks}");
        let summary = if ranks == 0 {
            one.clone()
        } else {
            let args: Vec<&str> =
                scenario.iter().copied().chain(["--strategy", "serial", "--rank-layout", layout]).collect();
            run(dir.path(), &name, ranks, &args).1
        };
        let name = if ranks == 0 { "one" } else { name.as_str() };
        let state = read_state(&dir.path().join(format!("{name}.bin")));
        let (set, geometry) = setup();
        let got = figures(&summary);
        assert!(got.iter().all(|f| f.1.is_finite()), "{name}: {got:?}");
        let whole = figures_of_state(&summary, set, geometry, &state);
        for ((key, a), (_, b)) in got.iter().zip(&whole) {
            assert_eq!(a.to_bits(), b.to_bits(), "{name}: {key} {a} over ranks, {b} from the whole state");
        }
        for ((key, a), (_, b)) in got.iter().zip(&figures(&one)) {
            assert!(close(*a, *b, 1e-12), "{name}: {key} {a}, one process {b}");
        }
        assert_eq!(summary.figures.physics.failed_particles, one.figures.physics.failed_particles, "{name}");
        let history = |s: &Summary| s.figures.scenario.impact().and_then(|c| c.cloud_history.clone());
        let (Some(h), Some(h1)) = (history(&summary), history(&one)) else {
            assert!(geometry.is_none(), "{name}: an impact without its cloud history");
            continue;
        };
        assert!(h1.len() > 10, "one process sampled {} times", h1.len());
        assert_eq!(h.len(), h1.len(), "{name}: cloud history samples");
        for (a, b) in h.iter().zip(h1) {
            let pairs = [
                (a.time, b.time),
                (a.cloud_front, b.cloud_front),
                (a.cloud_front_robust, b.cloud_front_robust),
                (a.cloud_width, b.cloud_width),
                (a.cloud_width_robust, b.cloud_width_robust),
                (a.kinetic, b.kinetic),
                (a.internal, b.internal),
            ];
            assert!(pairs.iter().all(|&(x, y)| close(x, y, 1e-12)) && a.failed == b.failed, "{name}: {a:?} vs {b:?}");
        }
    }
}

#[test]
fn taylor_figures_over_ranks_are_the_whole_sets() {
    check_figures(&["taylor", "--model", "1"], &|| (TaylorBar::default().setup().unwrap(), None));
}

#[test]
fn impact_figures_and_history_over_ranks_are_the_whole_sets() {
    check_figures(&["impact", "--spacing", "2.12e-3", "--cell", "4.24e-3"], &|| {
        let (setup, g) = Impact { spacing: 2.12e-3, cell: 4.24e-3, ..Default::default() }.setup().unwrap();
        (setup, Some(g))
    });
}

/// The plate's shock front is tracked at every step over ranks as in one process: the same
/// front samples and shock speed (its path from slice sums over ranks, which differ from one
/// process's in the order of additions only).
#[test]
fn plate_shock_is_tracked_over_ranks_like_one_process() {
    let dir = tempfile::tempdir().unwrap();
    let json = |name: &str| dir.path().join(format!("{name}.json"));
    let summary =
        |name: &str| -> Summary { serde_json::from_str(&std::fs::read_to_string(json(name)).unwrap()).unwrap() };
    let args = ["run", "plate", "--quiet", "--json"];
    assert!(Command::new(MPM).args(args).arg(json("one")).status().unwrap().success());
    let two = Command::new("mpirun")
        .args(["--oversubscribe", "--allow-run-as-root", "-n", "2", MPM])
        .args(args)
        .arg(json("two"))
        .status()
        .expect("cannot start mpirun: install openmpi-bin (scripts/bootstrap.sh)");
    assert!(two.success());
    let (one, two) = (summary("one"), summary("two"));
    assert!(
        one.figures.scenario.plate().and_then(|t| t.shock_front_samples).is_some_and(|n| n > 100),
        "{:?}",
        one.figures.scenario.plate().and_then(|t| t.shock_front_samples)
    );
    assert_eq!(
        two.figures.scenario.plate().and_then(|t| t.shock_front_samples),
        one.figures.scenario.plate().and_then(|t| t.shock_front_samples)
    );
    let (a, b) = (
        two.figures.scenario.plate().and_then(|t| t.shock_speed_m_s).unwrap(),
        one.figures.scenario.plate().and_then(|t| t.shock_speed_m_s).unwrap(),
    );
    assert!(close(a, b, 1e-9), "shock speed {a} over ranks, {b} in one process");
    let (a, b) = (
        two.figures.scenario.plate().and_then(|t| t.shock_pressure_pa).unwrap(),
        one.figures.scenario.plate().and_then(|t| t.shock_pressure_pa).unwrap(),
    );
    assert!(close(a, b, 1e-9), "shock pressure {a} over ranks, {b} in one process");
}
