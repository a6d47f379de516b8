//! Property tests of the harness's readers of user files: presets (TOML), a campaign's
//! `runs.csv` (arbitrary bytes, truncations, a column removed) and `manifest.json`
//! (arbitrary bytes, truncations, a key removed). Each ends in a clear error or in exactly
//! the values the file gave: never a panic, never a value read other than written. Each
//! property's case count is set in its `proptest!` block (256); the file runs in seconds.

mod common;

use common::*;
use mpm_bench::campaign::plan::matrix::{Campaign, Overrides};
use mpm_bench::campaign::plan::preset::parse_preset;
use mpm_bench::campaign::store::csv::{read_rows, CsvLog};
use mpm_bench::campaign::store::manifest;
use mpm_bench::campaign::store::record::Row;
use mpm_core::Strategy;
use proptest::prelude::*;
use std::path::Path;

/// The smoke preset's text, with `threads = [1, 2]` as its threads line.
const SMOKE: &str = include_str!("../../configs/smoke.toml");

/// A campaign's `runs.csv` of three rows (ok, failed, ok) in `dir`: its bytes and rows.
fn small_csv(dir: &Path) -> (Vec<u8>, Vec<Row>) {
    let fp = fingerprint(None);
    let mut rows = vec![
        planned_row(dir, &fp, 1, Strategy::DomainDecomposition, "o3", 2, 0, "close", 10),
        failed_row(dir, &fp, 2, Strategy::ArrayExpansion, "o0", 1, 0),
        planned_row(dir, &fp, 3, Strategy::DomainDecomposition, "o3", 1, 1, "close", 10),
    ];
    for i in [0, 2] {
        let f = rows[i].measured_mut();
        f.timing.wall_s = 0.125 * (i + 1) as f64;
        f.progress.steps = 10;
    }
    let path = dir.join("runs.csv");
    let mut log = CsvLog::open(&path).unwrap();
    for r in &rows {
        log.append(r).unwrap();
    }
    (std::fs::read(&path).unwrap(), rows)
}

/// `bytes` written to `runs.csv` in a fresh folder, read back.
fn read_csv_bytes(bytes: &[u8]) -> anyhow::Result<Vec<Row>> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("runs.csv");
    std::fs::write(&path, bytes).unwrap();
    read_rows(&path)
}

/// An error's message, which must say something.
fn clear(e: &anyhow::Error) -> Result<(), TestCaseError> {
    let msg = format!("{e:#}");
    prop_assert!(msg.len() > 10, "an unclear error: {msg:?}");
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    /// Arbitrary text as a preset: an error or a preset, never a panic; a preset that
    /// parses resolves into a campaign or an error.
    #[test]
    fn any_text_as_a_preset(text in "(?s).{0,300}") {
        match parse_preset(&text) {
            Ok(p) => {
                if let Err(e) = Campaign::resolve(p, "prop".into(), &Overrides::default()) {
                    clear(&e)?;
                }
            }
            Err(e) => clear(&e)?,
        }
    }

    /// The smoke preset with any list of thread counts (negative, zero, repeated, huge):
    /// refused with a clear error, or a campaign of exactly those counts, each at least 1
    /// and none twice.
    #[test]
    fn any_thread_counts_in_a_preset(threads in prop::collection::vec(-3i64..5_000_000_000, 0..5)) {
        let list: Vec<String> = threads.iter().map(i64::to_string).collect();
        let text = SMOKE.replace("threads = [1, 2]", &format!("threads = [{}]", list.join(", ")));
        match parse_preset(&text).and_then(|p| Campaign::resolve(p, "prop".into(), &Overrides::default())) {
            Ok(c) => {
                let read: Vec<i64> = c.threads.iter().map(|&t| t as i64).collect();
                prop_assert_eq!(&read, &threads);
                prop_assert!(c.threads.iter().all(|&t| t >= 1));
                let mut distinct = c.threads.clone();
                distinct.sort_unstable();
                distinct.dedup();
                prop_assert_eq!(distinct.len(), c.threads.len());
            }
            Err(e) => clear(&e)?,
        }
    }

    /// The smoke preset with one line removed: a campaign or a clear error, never a panic.
    #[test]
    fn a_preset_without_a_line(line in 0usize..40) {
        let text: Vec<&str> = SMOKE.lines().collect();
        let line = line % text.len();
        let cut = [&text[..line], &text[line + 1..]].concat().join("\n");
        match parse_preset(&cut).and_then(|p| Campaign::resolve(p, "prop".into(), &Overrides::default())) {
            Ok(c) => prop_assert!(!c.expand().is_empty()),
            Err(e) => clear(&e)?,
        }
    }

    /// Arbitrary bytes as runs.csv: rows or a clear error, never a panic.
    #[test]
    fn any_bytes_as_runs_csv(bytes in prop::collection::vec(any::<u8>(), 0..400)) {
        if let Err(e) = read_csv_bytes(&bytes) {
            clear(&e)?;
        }
    }

    /// runs.csv cut anywhere: the rows it still holds whole, exactly as written (a torn
    /// last line left out), or a clear error (the header itself cut).
    #[test]
    fn a_truncated_runs_csv(cut in any::<prop::sample::Index>()) {
        let dir = tempfile::tempdir().unwrap();
        let (bytes, rows) = small_csv(dir.path());
        let at = cut.index(bytes.len() + 1);
        match read_csv_bytes(&bytes[..at]) {
            Ok(read) => {
                prop_assert!(read.len() <= rows.len());
                prop_assert_eq!(&read[..], &rows[..read.len()]);
                if at == bytes.len() {
                    prop_assert_eq!(read.len(), rows.len());
                }
            }
            Err(e) => clear(&e)?,
        }
    }

    /// runs.csv without one of its columns: a clear error, or rows each exactly as written
    /// in every other column and not recorded (empty) or as written in the missing one; a
    /// row that cannot be read without it is left out (with a warning), never misread.
    #[test]
    fn a_runs_csv_without_a_column(column in any::<prop::sample::Index>()) {
        let dir = tempfile::tempdir().unwrap();
        let (bytes, rows) = small_csv(dir.path());
        let mut r = csv::ReaderBuilder::new().has_headers(false).from_reader(&bytes[..]);
        let records: Vec<csv::StringRecord> = r.records().map(Result::unwrap).collect();
        let drop = column.index(records[0].len());
        let mut w = csv::Writer::from_writer(Vec::new());
        for rec in &records {
            w.write_record(rec.iter().enumerate().filter(|(i, _)| *i != drop).map(|(_, c)| c)).unwrap();
        }
        match read_csv_bytes(&w.into_inner().unwrap()) {
            Ok(read) => {
                let want: Vec<Vec<String>> = rows.iter().map(|r| r.record().unwrap()).collect();
                let mut next = 0;
                for got in read.iter().map(|r| r.record().unwrap()) {
                    let same = |w: &Vec<String>| {
                        got.iter().zip(w).enumerate().all(|(i, (g, w))| g == w || (i == drop && g.is_empty()))
                    };
                    let at = want[next..].iter().position(same);
                    prop_assert!(at.is_some(), "a row misread without column {}: {:?}", Row::header()[drop], got);
                    next += at.unwrap() + 1;
                }
            }
            Err(e) => clear(&e)?,
        }
    }

    /// Arbitrary bytes, a cut anywhere, or one key removed as manifest.json: the manifest
    /// (the whole file only, or without a key its reader defaults) or a clear error.
    #[test]
    fn a_damaged_manifest(bytes in prop::collection::vec(any::<u8>(), 0..300), cut in any::<prop::sample::Index>(), key in any::<prop::sample::Index>()) {
        let dir = tempfile::tempdir().unwrap();
        let campaign = dir.path().join("c");
        std::fs::create_dir_all(&campaign).unwrap();
        write_manifest(&campaign, "pack:1 core:2 pu:1");
        let path = campaign.join("manifest.json");
        let good = std::fs::read(&path).unwrap();
        let whole = manifest::read(&path).unwrap();
        std::fs::write(&path, &bytes).unwrap();
        if let Err(e) = manifest::read(&path) {
            clear(&e)?;
        }
        let at = cut.index(good.len());
        std::fs::write(&path, &good[..at]).unwrap();
        match manifest::read(&path) {
            Ok(_) => prop_assert!(good[at..].iter().all(u8::is_ascii_whitespace), "a cut manifest read at {}", at),
            Err(e) => clear(&e)?,
        }
        let mut tree: serde_json::Value = serde_json::from_slice(&good).unwrap();
        let keys: Vec<String> = tree.as_object().unwrap().keys().cloned().collect();
        let removed = keys[key.index(keys.len())].clone();
        tree.as_object_mut().unwrap().remove(&removed);
        std::fs::write(&path, serde_json::to_vec(&tree).unwrap()).unwrap();
        match manifest::read(&path) {
            Ok(m) if removed != "campaign_id" => prop_assert_eq!(m.campaign_id, whole.campaign_id.clone()),
            Ok(m) => prop_assert!(m.campaign_id.is_empty()),
            Err(e) => {
                clear(&e)?;
                let msg = format!("{e:#}");
                prop_assert!(msg.contains(&removed), "the error does not name {}: {}", removed, msg);
            }
        }
    }
}
