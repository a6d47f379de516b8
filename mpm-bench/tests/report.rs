//! Integration tests of `mpm-bench report` on two crafted campaigns: the page parses as HTML
//! and has its sections, tables and inline figures; the Markdown matches its golden snapshot;
//! only cells measured on both machines are compared and the others are listed with why.

mod common;
use common::*;
use mpm_bench::analysis::results::load_campaign;
use mpm_bench::report::comparison::{self as report, ReportArgs};
use scraper::{Html, Selector};
use std::path::{Path, PathBuf};

/// Campaign A (2 sockets x 4 cores, 1-8 threads, Models 1-4) and B (1 socket x 2 cores,
/// 1-4 threads, Models 1-3, every time x 0.8): B is 1.25x as fast on the cells both ran.
fn two_campaigns(root: &Path) -> (PathBuf, PathBuf) {
    let a = write_campaign(&root.join("a"), &Craft::default());
    let b = write_campaign(
        &root.join("b"),
        &Craft {
            topo: Some("pack:1 core:2 pu:1"),
            models: vec![1, 2, 3],
            threads: vec![1, 2, 4],
            cores: 2,
            per_socket: 2,
            slow_all: 0.8,
            ..Craft::default()
        },
    );
    (a, b)
}

fn write_report(root: &Path) -> (PathBuf, report::Report) {
    let (a, b) = two_campaigns(root);
    let out = root.join("rep");
    let args = ReportArgs { dirs: vec![a, b], out: out.clone(), pin: None };
    report::run(args.clone()).unwrap();
    (out, report::build(&args).unwrap())
}

#[test]
fn comparison_uses_only_matching_cells_and_lists_the_others() {
    let tmp = tempfile::tempdir().unwrap();
    let (_, r) = write_report(tmp.path());
    let v = &r.comparisons[0].comparison;
    // Models 1-3 x (AE, DD, DD-balanced) x (O3, O0) x (1, 2 threads).
    assert_eq!(v.cells.len(), 3 * 3 * 2 * 2);
    assert!(v.cells.iter().all(|c| c.key.threads <= 2 && c.key.model <= 3));
    assert_eq!(v.headlines.len(), 3);
    for h in &v.headlines {
        assert_eq!(h.cells, 12);
        assert!((h.time_ratio.value - 0.8).abs() < 1e-9, "{h:?}");
        assert!((h.throughput_ratio.value - 1.25).abs() < 1e-9, "{h:?}");
        assert!(h.time_ratio.lo <= 0.8 && h.time_ratio.hi >= 0.8);
    }
    let why = |cell: &str| v.left_out.iter().find(|l| l.cell == cell).map(|l| l.reason.clone()).unwrap_or_default();
    assert!(why("Model1 AE O3 4t").contains("oversubscribed on B"), "{:?}", v.left_out);
    assert!(why("Model1 DD O3 8t").contains("not in B"));
    assert!(why("Model4 DD O3 1t").contains("not in B"));
    assert!(why("Model4 AE O3 4t").contains("not measured on A"));
    // Every cell of either campaign is compared or left out, never both.
    assert_eq!(v.cells.len() + v.left_out.len(), 4 * 3 * 2 * 5);
}

fn count(doc: &Html, css: &str) -> usize {
    doc.select(&Selector::parse(css).unwrap()).count()
}

#[test]
fn the_page_parses_and_has_its_sections_tables_and_inline_figures() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, _) = write_report(tmp.path());
    let html = std::fs::read_to_string(out.join("index.html")).unwrap();
    let doc = Html::parse_document(&html);
    assert!(doc.errors.is_empty(), "{:?}", doc.errors);
    for id in ["sources", "headline", "ratios", "left-out", "throughput", "scaling", "memory", "claims", "machines"] {
        assert_eq!(count(&doc, &format!("section#{id} > h2")), 1, "section {id}");
    }
    assert_eq!(count(&doc, "section#headline table tbody tr"), 3);
    assert_eq!(count(&doc, "section#ratios table"), 3);
    assert!(count(&doc, "section#left-out table tbody tr") > 0);
    // Throughput and scaling figures per parallel strategy and opt level, inline SVG.
    assert_eq!(count(&doc, "section#throughput figure svg"), 6);
    assert_eq!(count(&doc, "section#scaling figure svg"), 6);
    assert_eq!(count(&doc, "section#machines thead th"), 3, "machines side by side");
    assert_eq!(count(&doc, "script") + count(&doc, "link") + count(&doc, "img"), 0, "self-contained, no scripts");
    assert!(!html.contains("src=\"http") && !html.contains("href=\"http"), "no network resources");
    let md = std::fs::read_to_string(out.join("report.md")).unwrap();
    assert!(md.contains("(scaling-dd-o3.svg)") && out.join("scaling-dd-o3.svg").is_file());
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap();
    assert_eq!(json["comparisons"][0]["headlines"].as_array().unwrap().len(), 3);
}

#[test]
fn one_campaign_is_described_without_a_comparison() {
    let tmp = tempfile::tempdir().unwrap();
    let a = write_campaign(&tmp.path().join("a"), &Craft::default());
    let r = report::build(&ReportArgs { dirs: vec![a], out: tmp.path().join("r"), pin: None }).unwrap();
    assert!(r.comparisons.is_empty());
    assert!(r.page.sections.iter().all(|s| s.id != "headline"));
    assert!(r.page.sections.iter().any(|s| s.id == "machines"));
}

/// The Markdown, with the temporary folder and the host-dependent fingerprints replaced.
fn normalised_markdown(root: &Path, out: &Path) -> String {
    let mut md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for (name, tag) in [("a", "<FP-A>"), ("b", "<FP-B>")] {
        md = md.replace(&load_campaign(&root.join(name)).unwrap().fingerprint(), tag);
    }
    md.replace(&root.display().to_string(), "<TMP>")
}

/// Regenerate with `UPDATE_GOLDEN=1 cargo test -p mpm-bench --test report`.
#[test]
fn markdown_matches_the_golden_snapshot() {
    let tmp = tempfile::tempdir().unwrap();
    let (out, _) = write_report(tmp.path());
    let md = normalised_markdown(tmp.path(), &out);
    let golden = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/golden/report.md");
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        std::fs::create_dir_all(golden.parent().unwrap()).unwrap();
        std::fs::write(&golden, &md).unwrap();
    }
    let want = std::fs::read_to_string(&golden).expect("tests/golden/report.md: run with UPDATE_GOLDEN=1 once");
    assert!(md == want, "report.md differs from {}: rerun with UPDATE_GOLDEN=1 and review the diff", golden.display());
}
