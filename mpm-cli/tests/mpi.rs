//! Runs split over MPI ranks (`mpirun -n R mpm run ...`) against one process: Model 1 and a
//! coarse impact over R = 1..4 ranks x T = 1, 2 threads end, after 50 steps, at the state of
//! the serial solver to 1e-9 (relative to the largest value of each quantity), with
//! particles moving between ranks on the way; an identical rerun is bitwise equal; rank 0's
//! summary lists every rank; `--split-wait` changes no bit and reports each rank's waiting;
//! particles leaving the fixed grid stop a run over ranks as they stop one process.
//!
//! Needs `mpirun` (Open MPI: `apt-get install openmpi-bin libopenmpi-dev`, see
//! scripts/bootstrap.sh).
#![cfg(feature = "mpi")]

use mpm_cli::summary::Summary;
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
    assert_eq!(reference.len(), reference_summary.particles);
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
            assert_eq!(summary.particles, reference_summary.particles);
            if ranks > 1 {
                let reports = summary.ranks.as_ref().expect("rank 0's summary lists the ranks");
                assert_eq!(reports.len(), ranks);
                let migrated: u64 = reports.iter().map(|r| r.migrated).sum();
                assert!(migrated > 0, "{name}: no particle moved between ranks in {STEPS} steps");
                let held: usize = reports.iter().map(|r| r.particles).sum();
                assert_eq!(held, reference_summary.particles);
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
