//! The particle snapshots read by VTK itself (the readers ParaView and VisIt are built on),
//! not only by the project's own decoder: every encoding (ascii, binary, compressed) of one
//! process, and the `.pvtu` files of 2 MPI ranks, checked by `scripts/vtk-check.py` with the
//! `vtk` wheel against the run's final particle state (`--dump-state`): point count, field
//! names and values.
//!
//! Needs the wheel in the tools' venv (`scripts/bootstrap.sh` installs it into
//! `~/.cache/mpm-bench-tools/venv`, or `$MPM_TOOLS_DIR/venv`): without it the tests fail,
//! saying so; they never skip.

use std::path::{Path, PathBuf};
use std::process::Command;

const MPM: &str = env!("CARGO_BIN_EXE_mpm");

/// The checker, beside the other scripts.
const CHECKER: &str = concat!(env!("CARGO_MANIFEST_DIR"), "/../scripts/vtk-check.py");

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// The tools venv's Python, which the bootstrap gives the `vtk` wheel.
fn python() -> PathBuf {
    let tools = std::env::var_os("MPM_TOOLS_DIR").map(PathBuf::from).unwrap_or_else(|| {
        PathBuf::from(std::env::var_os("HOME").expect("HOME is not set")).join(".cache/mpm-bench-tools")
    });
    let python = tools.join("venv/bin/python");
    assert!(
        python.is_file(),
        "{} is missing: run scripts/bootstrap.sh (it installs VTK's Python wheel, which these tests read the snapshots with)",
        python.display()
    );
    python
}

/// `launcher` (empty: none) + `mpm run taylor --model 1` for 10 steps with snapshots every
/// 5 steps in `encoding` into `dir/vtk` and its final state into `dir/state.bin`; then the
/// checker on them.
fn read_by_vtk(dir: &Path, launcher: &[&str], ranks: usize, encoding: &str) {
    let (vtk, state) = (dir.join("vtk"), dir.join("state.bin"));
    let mut all: Vec<&str> = launcher.to_vec();
    all.extend([MPM, "run", "taylor", "--model", "1", "--steps", "10", "--quiet", "--vtk"]);
    all.extend([vtk.to_str().unwrap(), "--every", "5", "--vtk-format", encoding]);
    all.extend(["--dump-state", state.to_str().unwrap()]);
    let out = Command::new(all[0]).args(&all[1..]).output().unwrap();
    assert!(out.status.success(), "{all:?} failed:\n{}", text(&out.stderr));
    let pvd = vtk.join("taylor.pvd");
    let out = Command::new(python())
        .arg(CHECKER)
        .args([pvd.to_str().unwrap(), state.to_str().unwrap(), "--ranks", &ranks.to_string()])
        .args(["--encoding", encoding])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "VTK's check of the {encoding} snapshots over {ranks} rank(s) failed (exit {:?}):\n{}{}",
        out.status.code(),
        text(&out.stdout),
        text(&out.stderr)
    );
    println!("{}", text(&out.stdout).trim());
}

#[test]
fn every_encoding_of_one_process_is_read_by_vtk_as_the_run_left_it() {
    for encoding in ["ascii", "binary", "compressed"] {
        let dir = tempfile::tempdir().unwrap();
        read_by_vtk(dir.path(), &[], 1, encoding);
    }
}

/// The pieces of 2 ranks and their `.pvtu`, read by `vtkXMLPUnstructuredGridReader`.
#[cfg(feature = "mpi")]
#[test]
fn the_pvtu_files_of_two_ranks_are_read_by_vtk_as_the_run_left_them() {
    let dir = tempfile::tempdir().unwrap();
    let mpirun = ["mpirun", "--oversubscribe", "--allow-run-as-root", "-n", "2"];
    read_by_vtk(dir.path(), &mpirun, 2, "compressed");
}
