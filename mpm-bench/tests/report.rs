//! Integration tests of `mpm-bench report` on two crafted campaigns: the page parses as HTML
//! and has its sections, tables and inline figures; the Markdown matches its golden snapshot;
//! only cells measured on both machines are compared and the others are listed with why.

mod common;
use common::*;
use mpm_bench::analysis::results::load_campaign;
use mpm_bench::analysis::select::RowFilter;
use mpm_bench::report::comparison::{self as report, ReportOptions};
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
    let args =
        ReportOptions { dirs: vec![a, b], out: out.clone(), pin: None, include_noisy: false, include_injected: false };
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
    let r = report::build(&ReportOptions {
        dirs: vec![a],
        out: tmp.path().join("r"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    })
    .unwrap();
    assert!(r.comparisons.is_empty());
    assert!(r.page.sections.iter().all(|s| s.id != "headline"));
    assert!(r.page.sections.iter().any(|s| s.id == "machines"));
}

/// The Markdown, with the temporary folder and the host-dependent fingerprints replaced.
fn normalised_markdown(root: &Path, out: &Path) -> String {
    let mut md = std::fs::read_to_string(out.join("report.md")).unwrap();
    for (name, tag) in [("a", "<FP-A>"), ("b", "<FP-B>")] {
        md = md.replace(&load_campaign(&root.join(name), &RowFilter::analysis(false)).unwrap().fingerprint(), tag);
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

/// The claims on the page are `mpm-bench claims`'s, on a campaign with busy-host rows that
/// would change them: both leave those rows out by the same rule (and say so), and with
/// --include-noisy both keep them; verdict for verdict, C1 to C7.
#[test]
fn report_and_claims_agree_on_a_campaign_with_noisy_rows() {
    let tmp = tempfile::tempdir().unwrap();
    let dir = write_campaign(&tmp.path().join("c"), &Craft::default());
    // Every parallel DD repetition again, five times slower, on a busy host: with them DD no
    // longer scales better than AE (C1).
    let csv = dir.join("runs.csv");
    let extra: Vec<_> = mpm_bench::campaign::store::csv::read_rows(&csv)
        .unwrap()
        .into_iter()
        .filter(|r| {
            r.threads() > 1 && r.strategy() == DD && r.outcome.status == mpm_bench::campaign::store::record::Status::Ok
        })
        .flat_map(|r| {
            (10..16).map(move |rep| {
                let mut b = r.clone();
                b.run.rep = 100 * (r.run.rep + 1) + rep;
                // A new repetition: its own run key (a key written twice counts once).
                b.id.run_key = b.run.key().0;
                let m = &mut b.measured_mut().timing;
                for t in [&mut m.steady_s_per_step, &mut m.steady_grid_stage_s, &mut m.steady_particle_stage_s] {
                    *t = t.map(|t| 5.0 * t);
                }
                b.host.host_noisy = true;
                b.host.host_noise = "its CPUs 80 % busy with other work before the run".into();
                b
            })
        })
        .collect();
    let mut log = mpm_bench::campaign::store::csv::CsvLog::open(&csv).unwrap();
    for r in &extra {
        log.append(r).unwrap();
    }
    let bench = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_mpm-bench")).args(args).output().unwrap();
        assert!(o.status.success(), "{args:?}: {}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8_lossy(&o.stderr).into_owned()
    };
    let verdicts = |md: &str, first_col: usize| -> Vec<(String, String)> {
        md.lines()
            .filter_map(|l| {
                let cells: Vec<&str> = l.split('|').map(str::trim).collect();
                let id = cells.get(1)?;
                (id.len() == 2 && id.starts_with('C'))
                    .then(|| (id.to_string(), cells.get(first_col).unwrap_or(&"").trim_matches('*').to_string()))
            })
            .collect()
    };
    let mut seen = Vec::new();
    for noisy in [false, true] {
        let flag: &[&str] = if noisy { &["--include-noisy"] } else { &[] };
        let d = dir.to_str().unwrap();
        let md = tmp.path().join(format!("claims-{noisy}.md"));
        let err = bench(&[&["claims", "--results", d, "--markdown", md.to_str().unwrap()], flag].concat());
        assert_eq!(err.contains("row(s) measured on a busy host"), !noisy, "{err}");
        let out = tmp.path().join(format!("rep-{noisy}"));
        bench(&[&["report", "--results", d, "--out", out.to_str().unwrap()], flag].concat());
        let claims = verdicts(&std::fs::read_to_string(&md).unwrap(), 3);
        let page = std::fs::read_to_string(out.join("report.md")).unwrap();
        let section = page.split("Claims on ").nth(1).expect("the page's claims table");
        let on_page = verdicts(section, 2);
        assert_eq!(claims.len(), 7, "{claims:?}");
        assert_eq!(on_page, claims, "the page's claims are not claims'");
        assert_eq!(page.contains(&format!("left out {} row(s) measured on a busy host", extra.len())), !noisy);
        seen.push(claims);
    }
    assert_ne!(seen[0], seen[1], "the noisy rows were meant to change a verdict");
}

/// A comparison of sets made by different software says so in its title and headline: the
/// ratios mix machine and software.
#[test]
fn the_headline_says_when_the_software_differs() {
    let tmp = tempfile::tempdir().unwrap();
    let (a, b) = two_campaigns(tmp.path());
    let args = ReportOptions {
        dirs: vec![a.clone(), b.clone()],
        out: tmp.path().join("r"),
        pin: None,
        include_noisy: false,
        include_injected: false,
    };
    let same = report::build(&args).unwrap();
    assert!(same.page.title.starts_with("Hardware comparison"), "{}", same.page.title);
    assert!(same.comparisons[0].software_differs.is_none());
    let csv = b.join("runs.csv");
    let rows = mpm_bench::campaign::store::csv::read_rows(&csv).unwrap();
    std::fs::remove_file(&csv).unwrap();
    let mut log = mpm_bench::campaign::store::csv::CsvLog::open(&csv).unwrap();
    for mut r in rows {
        (r.id.git_commit, r.id.git_dirty) = ("0123456789abcdef".into(), true);
        log.append(&r).unwrap();
    }
    drop(log);
    let differs = report::build(&args).unwrap();
    assert!(differs.page.title.starts_with("Machines and software differ"), "{}", differs.page.title);
    let why = differs.comparisons[0].software_differs.clone().unwrap();
    assert!(why.contains("0123456789ab-dirty"), "{why}");
}
