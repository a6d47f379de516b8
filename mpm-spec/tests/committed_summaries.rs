//! Every JSON summary committed under `results/` (campaign runs, impact, roofline,
//! physics-cost, ...) still reads with today's [`Summary`], whatever version of `mpm`
//! wrote it.

use mpm_spec::Summary;
use std::path::{Path, PathBuf};

/// The JSON files under `dir` that are run summaries (they name their scenario and wall
/// time); manifests, bandwidth, calibration, report and paired-measurement files are not.
fn summaries(dir: &Path) -> Vec<PathBuf> {
    let mut found = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        for e in std::fs::read_dir(&d).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "json") {
                let v: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap();
                if v.get("scenario").is_some() && v.get("wall_s").is_some() {
                    found.push(p);
                }
            }
        }
    }
    found.sort();
    found
}

#[test]
fn every_committed_summary_reads() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results");
    let files = summaries(&root);
    assert!(files.len() >= 400, "found {}", files.len());
    for f in &files {
        let text = std::fs::read_to_string(f).unwrap();
        let s: Summary = serde_json::from_str(&text).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        // What it read writes back the figures it was given.
        let back = serde_json::to_value(&s).unwrap();
        let orig: serde_json::Value = serde_json::from_str(&text).unwrap();
        for key in ["wall_s", "particles", "steps", "kinetic_energy"] {
            assert_eq!(back.get(key), orig.get(key), "{}: {key}", f.display());
        }
    }
}
