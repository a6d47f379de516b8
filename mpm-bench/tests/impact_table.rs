//! `mpm-bench impact-table`: the Markdown table of the impact runs from mock summaries.

use mpm_bench::report::impact_table::{fill_template, load_runs, table, PLACEHOLDER};
use mpm_core::grid::Occupancy;
use mpm_core::scenario::impact::HistorySample;
use mpm_spec::identity::Provenance;
use mpm_spec::summary::{EnergyReport, ImpactFigures, ScenarioFigures, Summary};
use std::path::Path;

fn sample(time: f64) -> HistorySample {
    HistorySample {
        time,
        cloud_front: 0.1,
        cloud_front_robust: 0.09,
        cloud_width: 0.05,
        cloud_width_robust: 0.04,
        kinetic: 1.0,
        internal: 1.0,
        total: 2.0,
        failed: 3,
    }
}

/// A finished impact run's summary with every figure of the table set.
fn mock(dx: f64, spacing: f64) -> Summary {
    let mut s = Summary {
        provenance: Some(Provenance {
            git_commit: "0123456789abcdef".into(),
            git_dirty: Some(false),
            ..Provenance::default()
        }),
        ..Summary::default()
    };
    let f = &mut s.figures;
    f.size.particles = 847_888;
    f.size.dx_m = dx;
    f.size.final_nodes = 1_054_017;
    f.size.final_occupancy =
        Some(Occupancy { cells: 1_022_048, occupied_cells: 37_088, occupied_blocks: 982, block_cells: 8 });
    f.progress.steps = 273;
    f.progress.sim_time = 30.6e-6;
    f.timing.wall_s = 29.14;
    f.physics.failed_particles = 53_700;
    f.memory.peak_rss_bytes = Some(238 << 20);
    f.physics.energy = Some(EnergyReport {
        initial_total_j: 434_250.0,
        final_kinetic_j: 300_000.0,
        final_internal_j: 134_250.0,
        max_rise: 1.5e-14,
        max_fall: 2.0e-3,
        negative_internal_steps: 9,
        negative_internal_max: 41,
        negative_internal_final: 0,
        failed_energy_floors: 12,
        failed_energy_floor_j: 0.734,
        ..EnergyReport::default()
    });
    f.scenario = ScenarioFigures::Impact(ImpactFigures {
        spacing_m: Some(spacing),
        cloud_front_m: Some(0.14449),
        cloud_front_robust_m: Some(0.14302),
        cloud_width_m: Some(0.0869),
        cloud_width_robust_m: Some(0.084),
        hole_diameter_m: Some(0.0309),
        front_velocity_m_s: Some(6123.4),
        leading_debris_velocity_m_s: Some(6632.0),
        cloud_history: Some(vec![sample(0.0), sample(30.6e-6)]),
        ..ImpactFigures::default()
    });
    s
}

/// `s` with its cloud's figures changed by `f`.
fn with_cloud(mut s: Summary, f: impl FnOnce(&mut ImpactFigures)) -> Summary {
    if let ScenarioFigures::Impact(c) = &mut s.figures.scenario {
        f(c);
    }
    s
}

fn write(dir: &Path, name: &str, s: &Summary) {
    std::fs::create_dir_all(dir.join(name)).unwrap();
    std::fs::write(dir.join(name).join("summary.json"), serde_json::to_string_pretty(s).unwrap()).unwrap();
}

#[test]
fn table_has_one_row_per_run_in_model_and_cell_order() {
    let dir = tempfile::tempdir().unwrap();
    let mut large = mock(1.0e-3, 0.21e-3);
    (large.figures.size.particles, large.figures.timing.wall_s) = (13_542_030, 1500.0);
    write(dir.path(), "large", &large);
    write(dir.path(), "small-1.06", &mock(1.06e-3, 0.53e-3));
    write(dir.path(), "small-2.12", &mock(2.12e-3, 0.53e-3));
    // A folder without a summary (a run in progress) is not a row.
    std::fs::create_dir_all(dir.path().join("empty")).unwrap();
    let runs = load_runs(dir.path()).unwrap();
    let names: Vec<&str> = runs.iter().map(|r| r.name.as_str()).collect();
    assert_eq!(names, ["small-2.12", "small-1.06", "large"]);
    let t = table(&runs);
    let lines: Vec<&str> = t.lines().collect();
    assert_eq!(lines.len(), 5, "{t}");
    assert!(lines[0].starts_with("| run | spacing | cell |") && lines[0].contains("peak RSS"), "{t}");
    assert_eq!(lines[0].matches('|').count(), lines[2].matches('|').count());
    assert_eq!(
        lines[2],
        "| small-2.12 | 0.53 mm | 2.12 mm | 847,888 | 273 | 30.6 µs | 29.1 s | 144.5 (143.0) mm | 86.9 (84.0) mm \
         | 30.9 mm | 6123 m/s | 6632 m/s | 434.2 kJ | 300.0 kJ | 134.2 kJ | 1.5e-14 / 2.0e-3 | 9 (41; 0) | 12 (7.34e-1 J) \
         | 53,700 | 238 MiB | 1,054,017 (3.6 %) | 0123456 |"
    );
    assert!(lines[4].starts_with("| large | 0.21 mm | 1.00 mm | 13,542,030 |") && lines[4].contains("| 25.0 min |"));
}

#[test]
fn missing_figures_are_dashes_and_old_summaries_have_no_fitted_front_velocity() {
    let dir = tempfile::tempdir().unwrap();
    // A summary written before the history: its front_velocity_m_s was the leading debris's.
    let mut old = with_cloud(mock(2.12e-3, 0.53e-3), |c| {
        c.cloud_history = None;
        c.leading_debris_velocity_m_s = None;
    });
    old.figures.physics.energy = None;
    let mut json: serde_json::Value = serde_json::to_value(&old).unwrap();
    for key in ["bulk_viscosity", "energy_rise_limit", "energy", "provenance"] {
        json.as_object_mut().unwrap().remove(key);
    }
    std::fs::create_dir_all(dir.path().join("old")).unwrap();
    std::fs::write(dir.path().join("old/summary.json"), json.to_string()).unwrap();
    let t = table(&load_runs(dir.path()).unwrap());
    let row = t.lines().nth(2).unwrap();
    assert!(
        row.contains("| 30.9 mm | - | - | - | - | - | - | - | - | 53,700 | 238 MiB | 1,054,017 (3.6 %) | - |"),
        "{row}"
    );
}

#[test]
fn template_gets_the_table_and_bad_input_is_an_error() {
    let filled = fill_template(&format!("# Title\n\nprose\n\n{PLACEHOLDER}\n\nmore\n"), "| a |\n|---|\n").unwrap();
    assert_eq!(filled, "# Title\n\nprose\n\n| a |\n|---|\n\nmore\n");
    assert!(fill_template("no table here\n", "| a |\n").is_err());
    assert!(fill_template(&format!("{PLACEHOLDER}\n{PLACEHOLDER}\n"), "| a |\n").is_err());
    let dir = tempfile::tempdir().unwrap();
    let e = load_runs(dir.path()).unwrap_err().to_string();
    assert!(e.contains("scripts/impact-runs.sh"), "{e}");
    write(dir.path(), "taylor", &Summary::default());
    let e = load_runs(dir.path()).unwrap_err().to_string();
    assert!(e.contains("not an impact"), "{e}");
}

/// A run from uncommitted sources says so in its row, so it cannot pass for a committed result.
#[test]
fn a_dirty_build_is_marked_in_the_commit_column() {
    let dir = tempfile::tempdir().unwrap();
    let mut s = mock(2.12e-3, 0.53e-3);
    s.provenance.as_mut().unwrap().git_dirty = Some(true);
    write(dir.path(), "small", &s);
    let mut old = mock(1.06e-3, 0.53e-3);
    old.provenance = None;
    write(dir.path(), "old", &old);
    let t = table(&load_runs(dir.path()).unwrap());
    let rows: Vec<&str> = t.lines().skip(2).collect();
    assert!(rows[0].ends_with("| 0123456-dirty |"), "{t}");
    assert!(rows[1].ends_with("| - |"), "{t}");
}
