//! The campaign's `runs.csv`: rows appended durably right after each run ([`CsvLog`],
//! through [`mpm_host::durable::Appender`]: a row is recorded once it is written and
//! `fdatasync`ed, and an `fsync` that fails is an error, the run not counted done), so an
//! interrupted campaign keeps every finished run, and read back
//! ([`read_rows`]) after a check of the header: this schema's columns, or files of CSV
//! schemas 1-7, converted ([`super::legacy`]); schema 8, whose columns are this schema's but
//! two, read with those empty.
//!
//! A torn last line (power loss, disk full, a kill in the middle of a write: no trailing
//! newline, or fewer fields than the header) is found before the file is parsed
//! ([`complete_len`]). Readers ([`read_rows`], used by every analysis command) warn and read
//! the complete rows; the campaign runner ([`repair_torn_tail`], also in [`CsvLog::open`])
//! moves the torn bytes to `runs.csv.torn-<time>`, says so, and redoes that run. Lines that
//! are not rows are set aside the same way ([`repair_garbage`]).

use super::disk::{self, DiskFull};
use crate::campaign::store::record::{Row, SCHEMA_VERSION};
use anyhow::{bail, Context, Result};
use mpm_host::durable::{AppendError, Appender};
use std::fs::OpenOptions;
use std::io::Read;
use std::path::{Path, PathBuf};

/// Length in bytes of the complete part of a results CSV: the header and every record that
/// ends in a newline and has as many fields as the header. What follows is a torn tail.
pub fn complete_len(bytes: &[u8]) -> usize {
    let mut len = bytes.iter().rposition(|&b| b == b'\n').map_or(0, |p| p + 1);
    loop {
        let mut r = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(&bytes[..len]);
        let width = match r.headers() {
            Ok(h) => h.len(),
            Err(_) => return len,
        };
        let mut last: Option<(usize, usize)> = None;
        let mut rec = csv::StringRecord::new();
        while let Ok(true) = r.read_record(&mut rec) {
            let start = rec.position().map_or(0, |p| p.byte() as usize);
            last = Some((start, rec.len()));
        }
        match last {
            Some((start, fields)) if fields < width && start < len => len = start,
            _ => return len,
        }
    }
}

/// A line of a results CSV that is not a row (a stray write, a hand edit, a line of another
/// program): set aside like a torn line, its run redone on resume.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Garbage {
    /// Line number in the file (1 = the header).
    pub line: u64,
    /// Why it is not a row.
    pub why: String,
    /// Its bytes, newline included.
    pub bytes: Vec<u8>,
}

/// The rows of a CSV's complete part and its garbage lines.
struct Parsed {
    schema: Schema,
    rows: Vec<Row>,
    garbage: Vec<Garbage>,
    /// Byte ranges of the header and of every good record, in order.
    good: Vec<std::ops::Range<usize>>,
}

/// Read every row of a results CSV, checking the header first (files of schemas 1-5 are
/// converted). A torn last line and garbage lines are left out with a warning (the file is
/// not changed; resuming the campaign moves them aside and redoes their runs).
pub fn read_rows(path: &Path) -> Result<Vec<Row>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot open {}", path.display()))?;
    let good = complete_len(&bytes);
    if good < bytes.len() {
        eprintln!(
            "warning: {} ends in a torn line ({} bytes: an interrupted write); reading the complete rows only \
             (resuming the campaign moves it aside and redoes that run)",
            path.display(),
            bytes.len() - good
        );
    }
    let parsed = parse_rows(&bytes[..good], path)?;
    warn_garbage(path, &parsed.garbage, "resuming the campaign moves them aside and redoes their runs");
    for warning in foreign_schema_warnings(path, parsed.schema, &parsed.rows) {
        eprintln!("{warning}");
    }
    Ok(parsed.rows)
}

/// Warnings about rows whose `schema_version` is not one of the schemas their file's
/// columns are (a row of a newer harness, which this one may misread; a row of another
/// version appended to the file), one per version.
fn foreign_schema_warnings(path: &Path, schema: Schema, rows: &[Row]) -> Vec<String> {
    let (versions, columns) = match schema {
        Schema::Flat => (1..=5, "schemas 1-5"),
        Schema::Renamed => (6..=7, "schemas 6-7"),
        Schema::Current => (8..=SCHEMA_VERSION, "schemas 8-10"),
    };
    let mut foreign: std::collections::BTreeMap<u32, usize> = std::collections::BTreeMap::new();
    for r in rows.iter().filter(|r| !versions.contains(&r.id.schema_version)) {
        *foreign.entry(r.id.schema_version).or_default() += 1;
    }
    foreign
        .into_iter()
        .map(|(v, n)| {
            if v > SCHEMA_VERSION {
                format!(
                    "warning: {}: {n} row(s) of CSV schema {v}, newer than this harness's {SCHEMA_VERSION}: read \
                     with the columns this version knows, their values may be misread; analyse them with the \
                     harness version that wrote them",
                    path.display()
                )
            } else {
                format!(
                    "warning: {}: {n} row(s) say CSV schema {v} in a file of the columns of {columns}: rows of \
                     another harness version appended to it? check them, or move them aside",
                    path.display()
                )
            }
        })
        .collect()
}

fn warn_garbage(path: &Path, garbage: &[Garbage], then: &str) {
    if garbage.is_empty() {
        return;
    }
    let lines: Vec<String> = garbage.iter().map(|g| format!("line {}: {}", g.line, g.why)).collect();
    eprintln!(
        "warning: {} has {} line(s) that are not rows, left out ({then}): {}",
        path.display(),
        garbage.len(),
        lines.join("; ")
    );
}

/// Move garbage lines of `path` (lines that are not rows of its schema) to
/// `<name>.garbage-<UTC time>` beside it and rewrite the file with its rows only; say so on
/// stderr. Returns the new file, if any. Call after [`repair_torn_tail`].
pub fn repair_garbage(path: &Path) -> Result<Option<PathBuf>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let good = complete_len(&bytes);
    let parsed = parse_rows(&bytes[..good], path)?;
    if parsed.garbage.is_empty() {
        return Ok(None);
    }
    let stamp: String = crate::util::now_rfc3339().chars().filter(|c| c.is_ascii_alphanumeric()).collect();
    let name = path.file_name().map_or_else(|| "runs.csv".into(), |n| n.to_string_lossy().into_owned());
    let aside = path.with_file_name(format!("{name}.garbage-{stamp}"));
    let set_aside: Vec<u8> = parsed.garbage.iter().flat_map(|g| g.bytes.iter().copied()).collect();
    mpm_host::atomic::write_atomic(&aside, &set_aside)?;
    let mut kept: Vec<u8> = parsed.good.iter().flat_map(|r| bytes[r.clone()].iter().copied()).collect();
    kept.extend_from_slice(&bytes[good..]);
    mpm_host::atomic::write_atomic(path, &kept)?;
    warn_garbage(path, &parsed.garbage, &format!("moved to {}; their runs will be redone", aside.display()));
    Ok(Some(aside))
}

/// Move a torn tail of `path` (see [`complete_len`]) to `<name>.torn-<UTC time>` beside it
/// and cut the file to its complete rows; say so on stderr. Returns the new file, if any.
pub fn repair_torn_tail(path: &Path) -> Result<Option<PathBuf>> {
    let bytes = std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))?;
    let good = complete_len(&bytes);
    if good == bytes.len() {
        return Ok(None);
    }
    let stamp: String = crate::util::now_rfc3339().chars().filter(|c| c.is_ascii_alphanumeric()).collect();
    let name = path.file_name().map_or_else(|| "runs.csv".into(), |n| n.to_string_lossy().into_owned());
    let aside = path.with_file_name(format!("{name}.torn-{stamp}"));
    mpm_host::atomic::write_atomic(&aside, &bytes[good..])?;
    let f = OpenOptions::new().write(true).open(path).with_context(|| format!("cannot repair {}", path.display()))?;
    f.set_len(good as u64).with_context(|| format!("cannot repair {}", path.display()))?;
    mpm_host::durable::sync_file(&f).with_context(|| {
        format!("cannot sync {} after cutting its torn line: check the file system and run again", path.display())
    })?;
    eprintln!(
        "warning: {} ended in a torn line (an interrupted write); moved it to {}; its run will be redone",
        path.display(),
        aside.display()
    );
    Ok(Some(aside))
}

/// The header of a CSV's complete part.
fn file_header(bytes: &[u8], path: &Path) -> Result<Vec<String>> {
    let mut r = csv::ReaderBuilder::new().has_headers(true).from_reader(bytes);
    Ok(r.headers()
        .with_context(|| format!("cannot read the header of {}", path.display()))?
        .iter()
        .map(str::to_string)
        .collect())
}

/// Which rows a header holds.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Schema {
    /// Schemas 1-5: flat rows ([`super::legacy::LegacyRow`]).
    Flat,
    /// Schemas 6-7: this layout under older names ([`super::legacy::v7_as_current`]).
    Renamed,
    /// This schema.
    Current,
}

/// Check the header of `path`: this schema's columns (in any order, a subset read as
/// absent), a schema 6-7 file, or a schema 1-5 file.
fn schema_of(have: &[String], path: &Path) -> Result<Schema> {
    if !have.iter().any(|c| c == "run_key") {
        super::legacy::check_legacy_header(have, path)?;
        return Ok(Schema::Flat);
    }
    let (schema, names) = if super::legacy::is_v7_header(have) {
        (Schema::Renamed, super::legacy::v7_header_as_current(have))
    } else {
        (Schema::Current, have.to_vec())
    };
    let want = Row::header();
    if let Some(extra) = names.iter().find(|c| !want.contains(c)) {
        bail!(
            "{} has the column `{extra}`, which this harness (CSV schema {SCHEMA_VERSION}) does not know: it \
             was written by a newer version; read it with that one, or move it aside",
            path.display()
        );
    }
    // A file of this schema has every column: one without some (cut by hand or by another
    // program) would read them as their defaults (a wall time of 0), never as written.
    // A schema-8 or 9 file lacks only the columns later schemas added: those read as empty.
    let missing: Vec<&String> = want.iter().filter(|c| !names.contains(c)).collect();
    let added = super::legacy::ADDED_IN_V9.iter().chain(&super::legacy::ADDED_IN_V10);
    let only_newer = missing.iter().all(|c| added.clone().any(|a| a == c));
    if schema == Schema::Current && !missing.is_empty() && !only_newer {
        let named: Vec<&str> = missing.iter().take(5).map(|c| c.as_str()).collect();
        bail!(
            "{} lacks {} column(s) of CSV schema {SCHEMA_VERSION} ({}{}): its rows cannot be read as written; \
             restore the file from a copy, or move it aside",
            path.display(),
            missing.len(),
            named.join(", "),
            if missing.len() > named.len() { ", ..." } else { "" }
        );
    }
    Ok(schema)
}

/// The records of a CSV's complete part: each with its start byte, its line, and the record
/// or why it could not be read.
type Records = Vec<(usize, u64, Result<csv::StringRecord, String>)>;

fn records(bytes: &[u8]) -> Records {
    let mut r = csv::ReaderBuilder::new().has_headers(true).flexible(true).from_reader(bytes);
    let mut records = Vec::new();
    let mut rec = csv::StringRecord::new();
    loop {
        let start = r.position().byte() as usize;
        let line = r.position().line();
        match r.read_record(&mut rec) {
            Ok(true) => records.push((start, line, Ok(rec.clone()))),
            Ok(false) => break,
            Err(e) => {
                records.push((start, line, Err(e.to_string())));
                break;
            }
        }
    }
    records
}

/// Parse the rows of a CSV's complete part, checking the header first ([`schema_of`]). A
/// record with another number of fields than the header, or whose cells are not a row, is
/// garbage.
fn parse_rows(bytes: &[u8], path: &Path) -> Result<Parsed> {
    let have = file_header(bytes, path)?;
    let schema = schema_of(&have, path)?;
    let headers = csv::StringRecord::from(have.clone());
    let renamed = super::legacy::v7_header_as_current(&have);
    let records = records(bytes);
    let mut parsed = Parsed { schema, rows: Vec::new(), garbage: Vec::new(), good: Vec::new() };
    let header_end = records.first().map_or(bytes.len(), |(s, _, _)| *s);
    parsed.good.push(0..header_end);
    for (i, (start, line, rec)) in records.iter().enumerate() {
        let end = records.get(i + 1).map_or(bytes.len(), |(s, _, _)| *s);
        let row = rec.as_ref().map_err(String::clone).and_then(|rec| {
            if rec.len() != headers.len() {
                return Err(format!("{} fields, the header has {}", rec.len(), headers.len()));
            }
            let row = match schema {
                Schema::Flat => super::legacy::parse_legacy_record(&headers, rec),
                Schema::Renamed => Row::layout().parse::<Row>(&renamed, &super::legacy::v7_as_current(&have, rec)),
                Schema::Current => Row::layout().parse::<Row>(&have, rec),
            };
            row.map_err(|e| format!("{e:#}"))
        });
        match row {
            Ok(row) => {
                parsed.rows.push(row);
                parsed.good.push(*start..end);
            }
            Err(why) => parsed.garbage.push(Garbage { line: *line, why, bytes: bytes[*start..end].to_vec() }),
        }
    }
    Ok(parsed)
}

/// An append-only CSV log: header written once, every row written and synced before
/// [`CsvLog::append`] returns.
pub struct CsvLog {
    log: Appender,
}

impl CsvLog {
    /// Open (creating if needed) `path` for appending. An existing file must carry this
    /// harness' header; a torn last line and garbage lines are moved aside first
    /// ([`repair_torn_tail`], [`repair_garbage`]).
    pub fn open(path: &Path) -> Result<Self> {
        if path.is_file() {
            repair_torn_tail(path)?;
            // Rewrites the file (by a rename): before the handle below is opened.
            repair_garbage(path)?;
        }
        let mut log = Appender::open(path)?;
        let mut text = Vec::new();
        log.file().read_to_end(&mut text).with_context(|| format!("cannot read {}", path.display()))?;
        if text.is_empty() {
            log.append(&csv_line(Row::header())?)?;
        } else {
            // Demand this schema's exact header: rows appended under another header would be
            // misread.
            if file_header(&text, path)? != Row::header() {
                bail!(
                    "{} was written by another version of the harness (its columns differ from schema version \
                     {SCHEMA_VERSION}); new rows cannot be appended to it: move it aside, write to another \
                     --out, or run with --fresh",
                    path.display()
                );
            }
        }
        Ok(Self { log })
    }

    /// Append one row and make it durable. An error (a write or an `fsync` that failed)
    /// means the row is not recorded: its run is not done. What was written of it is cut
    /// back out, so the file ends in its last recorded row (no torn line, and no row that a
    /// later reader would take as recorded although its `fsync` failed); a full disk is a
    /// [`DiskFull`].
    pub fn append(&mut self, row: &Row) -> Result<()> {
        let line = csv_line(row.record()?)?;
        let path = self.log.path().to_path_buf();
        let len =
            self.log.file().metadata().with_context(|| format!("cannot read the size of {}", path.display()))?.len();
        let Err(e) = self.log.append(&line) else {
            return Ok(());
        };
        let file = self.log.file();
        let uncut = file.set_len(len).and_then(|()| mpm_host::durable::sync_data(file)).err().map(|cut| {
            format!(
                "what was written of it could not be cut back out durably ({cut}): resuming the campaign sets it aside"
            )
        });
        let source = match &e {
            AppendError::Write { source, .. } | AppendError::Sync { source, .. } => Some(source),
            _ => None,
        };
        if let Some(why) = source.and_then(disk::full) {
            let what = format!("the row of run {} could not be appended to {}", row.id.run_id, path.display());
            let what = uncut.map_or(what.clone(), |uncut| format!("{what}; {uncut}"));
            return Err(DiskFull { folder: mpm_host::durable::folder_of(&path).to_path_buf(), why, what }.into());
        }
        let e = anyhow::Error::new(e);
        Err(match uncut {
            Some(uncut) => e.context(uncut),
            None => e,
        })
    }

    /// Path of the log.
    pub fn path(&self) -> &Path {
        self.log.path()
    }
}

/// `cells` as one CSV line, its line end included.
fn csv_line(cells: Vec<String>) -> Result<Vec<u8>> {
    let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
    w.write_record(cells)?;
    w.into_inner().map_err(|e| anyhow::anyhow!("{e}"))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::campaign::plan::matrix::PlannedRun;
    use crate::campaign::store::legacy::{legacy_header, LegacyRow, ADDED_SINCE_V1};
    use crate::campaign::store::record::Status;
    use mpm_core::Strategy;
    use mpm_core::Substage;
    use mpm_spec::scenario::ImpactSpec;
    use mpm_spec::summary::{EndReason, StageSeconds};
    use mpm_spec::OptLevel;
    use mpm_spec::Scenario;
    use std::io::Write;

    /// A planned Taylor run of `model`, `threads` threads, DD, o3, 10 steps.
    fn row(model: u32, threads: usize) -> Row {
        Row::planned(PlannedRun::taylor(model, Strategy::DomainDecomposition, OptLevel::O3, threads, 10))
    }

    #[test]
    fn header_is_complete_and_rows_round_trip_bit_for_bit() {
        let h = Row::header();
        for col in [
            "run_key",
            "scenario.kind",
            "physics.cfl",
            "budget.steps",
            "requested_cpus",
            "substages.scatter",
            "steady_grid_stage_s",
            "status",
        ] {
            assert!(h.iter().any(|c| c == col), "{col}");
        }
        assert!(!h.iter().any(|c| c.starts_with("outputs") || c == "cpus"), "outputs and cpus are not columns");
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let mut log = CsvLog::open(&p).unwrap();
        let mut r = row(2, 4);
        r.run.spec.physics.cfl = 0.1 + 0.2;
        r.run.spec.rank_layout = Some([2, 1, 1]);
        r.placement.requested_cpus = vec![0, 1, 0, 1];
        r.placement.rank_cpus = vec![vec![0, 1], vec![2, 3]];
        let f = r.measured_mut();
        f.timing.wall_s = 1.0 / 3.0;
        f.timing.substages = StageSeconds([(Substage::Scatter, 0.25)].into_iter().collect());
        f.progress.end_reason = EndReason::EndTime;
        r.outcome.status = Status::Skipped;
        r.outcome.reason = "memory, guard".into();
        log.append(&r).unwrap();
        let mut impact = r.clone();
        impact.run.spec.scenario = Scenario::Impact(ImpactSpec::default());
        log.append(&impact).unwrap();
        drop(log);
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows, vec![r, impact]);
        // A torn last line is moved aside on reopen.
        std::fs::OpenOptions::new().append(true).open(&p).unwrap().write_all(b"1,abc,").unwrap();
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row(1, 1)).unwrap();
        assert_eq!(read_rows(&p).unwrap().len(), 3);
        let aside: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .filter(|e| e.file_name().to_string_lossy().starts_with("runs.csv.torn-"))
            .collect();
        assert_eq!(aside.len(), 1);
        assert_eq!(std::fs::read(aside[0].path()).unwrap(), b"1,abc,");
    }

    /// An `fsync` of a row that fails (injected: no unprivileged test can make a local file
    /// system fail one) is an error naming the file and saying the row is not recorded; the
    /// next row, once the disk answers again, is appended after it.
    #[test]
    fn a_failed_sync_of_a_row_is_an_error() {
        use mpm_host::fault::{inject, Fault};
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row(1, 1)).unwrap();
        let fault = inject(Fault::SyncFile, libc::EIO);
        let err = format!("{:#}", log.append(&row(2, 1)).unwrap_err());
        assert!(err.contains(&p.display().to_string()) && err.contains("not recorded"), "{err}");
        drop(fault);
        log.append(&row(3, 1)).unwrap();
        assert_eq!(log.path(), p);
        // The row whose sync failed was cut back out: a reader would count it recorded.
        let models: Vec<u32> = read_rows(&p).unwrap().iter().map(Row::model).collect();
        assert_eq!(models, [1, 3]);
        // A sync that finds the disk full (NFS reports ENOSPC there) names the full disk.
        let full = inject(Fault::SyncFile, libc::ENOSPC);
        let err = format!("{:#}", log.append(&row(4, 1)).unwrap_err());
        assert!(err.starts_with(&format!("the disk holding {} is full", dir.path().display())), "{err}");
        drop(full);
        assert_eq!(read_rows(&p).unwrap().len(), 2);
        let _fault = inject(Fault::SyncFile, libc::EIO);
        std::fs::write(&p, [std::fs::read(&p).unwrap(), b"1,torn".to_vec()].concat()).unwrap();
        assert!(CsvLog::open(&p).is_err(), "a torn tail cut without its sync is an error");
    }

    /// Both kinds of torn tail are found before parsing: no trailing newline, and a line
    /// with fewer fields than the header; readers skip them, the repair moves them aside.
    #[test]
    fn torn_tails_are_found_read_around_and_moved_aside() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let mut log = CsvLog::open(&p).unwrap();
        log.append(&row(1, 2)).unwrap();
        log.append(&row(2, 2)).unwrap();
        drop(log);
        let good = std::fs::read(&p).unwrap();
        assert_eq!(complete_len(&good), good.len());
        let line = String::from_utf8(good.clone()).unwrap().lines().last().unwrap().to_string();
        let half = &line[..line.len() / 2];
        for tail in [half.to_string(), format!("{half}\n"), line.clone()] {
            let torn = [good.as_slice(), tail.as_bytes()].concat();
            assert_eq!(complete_len(&torn), good.len(), "{tail:?}");
            std::fs::write(&p, &torn).unwrap();
            assert_eq!(read_rows(&p).unwrap().len(), 2, "the reader reads around {tail:?}");
            assert_eq!(std::fs::read(&p).unwrap(), torn, "reading changes nothing");
            let aside = repair_torn_tail(&p).unwrap().unwrap();
            assert_eq!(std::fs::read(&p).unwrap(), good);
            assert_eq!(std::fs::read(&aside).unwrap(), tail.as_bytes());
            std::fs::remove_file(aside).unwrap();
        }
        assert_eq!(repair_torn_tail(&p).unwrap(), None);
    }

    /// Rows of a newer schema, and rows of an older one among this schema's columns, are
    /// read with a warning naming the version and what to do; this schema's rows are not.
    #[test]
    fn rows_of_a_foreign_schema_are_flagged() {
        let p = Path::new("c/runs.csv");
        let mut future = row(1, 1);
        future.id.schema_version = SCHEMA_VERSION + 1;
        let mut old = row(2, 1);
        old.id.schema_version = 3;
        let rows = vec![row(1, 2), future.clone(), future, old];
        let w = foreign_schema_warnings(p, Schema::Current, &rows);
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(w[0].contains("c/runs.csv: 1 row(s) say CSV schema 3") && w[0].contains("move them aside"), "{w:?}");
        let newer = format!("2 row(s) of CSV schema {}, newer", SCHEMA_VERSION + 1);
        assert!(w[1].contains(&newer) && w[1].contains("harness version that wrote them"), "{w:?}");
        assert!(foreign_schema_warnings(p, Schema::Current, &rows[..1]).is_empty());
        let mut v7 = row(1, 1);
        v7.id.schema_version = 7;
        assert!(foreign_schema_warnings(p, Schema::Renamed, &[v7]).is_empty());
    }

    #[test]
    fn missing_and_unknown_columns_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        std::fs::write(&p, "schema_version,campaign_id\n1,x\n").unwrap();
        let err = format!("{:#}", read_rows(&p).unwrap_err());
        assert!(err.contains("missing column"), "{err}");
        assert!(err.contains("observed_cpus"), "{err}");
        std::fs::write(&p, "schema_version,run_key,from_the_future\n6,k,1\n").unwrap();
        let err = format!("{:#}", read_rows(&p).unwrap_err());
        assert!(err.contains("from_the_future") && err.contains("newer version"), "{err}");
        // This schema without one of its columns: refused, naming it.
        let header: Vec<String> = Row::header().into_iter().filter(|c| c != "wall_s").collect();
        std::fs::write(&p, header.join(",") + "\n").unwrap();
        let err = format!("{:#}", read_rows(&p).unwrap_err());
        assert!(err.contains("lacks 1 column(s)") && err.contains("(wall_s)"), "{err}");
    }

    /// `row` as a legacy CSV file (header and one line) without the columns `drop` (none of
    /// the row's cells may hold a comma).
    fn legacy_csv_without(row: &LegacyRow, drop: &[&str]) -> String {
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(row).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        let header = legacy_header();
        let idx: Vec<usize> = drop.iter().map(|c| header.iter().position(|h| h == c).unwrap()).collect();
        let keep = |line: &str| {
            line.split(',').enumerate().filter(|(i, _)| !idx.contains(i)).map(|(_, c)| c).collect::<Vec<_>>().join(",")
        };
        text.lines().map(|l| keep(l) + "\n").collect()
    }

    /// A schema-1 file (without the columns added since) still reads: its row converted,
    /// one process, the rest intact. Appending to it is refused.
    #[test]
    fn schema_1_files_still_read() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let old = LegacyRow {
            schema_version: 1,
            campaign_id: "old".into(),
            model: 2,
            strategy: Strategy::ArrayExpansion,
            opt_level: "o0".into(),
            threads: 2,
            pin_policy: "close".into(),
            grid_mode: "fixed".into(),
            step_limit: Some(20),
            warmup_steps: 2,
            sub_scatter_s: Some(0.5),
            wall_s: Some(1.5),
            ..LegacyRow::default()
        };
        std::fs::write(&p, legacy_csv_without(&old, &ADDED_SINCE_V1)).unwrap();
        let rows = read_rows(&p).unwrap();
        assert_eq!(rows.len(), 1);
        let r = &rows[0];
        assert_eq!(
            (r.id.schema_version, r.model(), r.strategy(), r.opt()),
            (1, 2, Strategy::ArrayExpansion, OptLevel::O0)
        );
        assert_eq!((r.threads(), r.ranks(), r.run.spec.budget.steps), (2, 1, Some(20)));
        assert_eq!(r.measured.as_ref().map(|f| f.timing.wall_s), Some(1.5));
        assert_eq!(
            r.measured.as_ref().map(|f| f.timing.substages.clone()).unwrap_or_default().get(Substage::Scatter),
            Some(0.5)
        );
        assert_eq!(
            r.measured.as_ref().and_then(|f| f.timing.steady_grid_stage_s),
            None,
            "not recorded before schema 6"
        );
        assert!(CsvLog::open(&p).is_err(), "appending schema-6 rows to a schema-1 file must be refused");
    }

    /// The same row over two ranks in a schema-4 file (no `wait_*` columns) reads with them
    /// empty and its exchange seconds flagged as including the waiting.
    #[test]
    fn schema_4_rows_have_no_waiting() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("runs.csv");
        let old = LegacyRow {
            schema_version: 4,
            model: 3,
            strategy: Strategy::DomainDecomposition,
            opt_level: "o3".into(),
            pin_policy: "close".into(),
            threads: 2,
            ranks: 2,
            threads_per_rank: 1,
            launcher: "mpirun -n 2".into(),
            comm_frac: Some(0.031),
            ..LegacyRow::default()
        };
        std::fs::write(&p, legacy_csv_without(&old, &["wait_s_per_step", "wait_frac"])).unwrap();
        let rows = read_rows(&p).unwrap();
        let r = &rows[0];
        assert_eq!((r.ranks(), r.threads_per_rank(), r.threads()), (2, 1, 2));
        assert!(r.comm_includes_wait() && r.measured.as_ref().and_then(|f| f.communication.comm_frac) == Some(0.031));
        assert!(!r.run.spec.split_wait, "schema 4 ran without it");
    }

    /// Every campaign folder committed under results/ reads, whatever its schema: every
    /// row converts, the one-process rows and the rows over ranks as they were recorded.
    #[test]
    fn every_committed_campaign_reads() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results");
        let mut found = 0;
        let mut stack = vec![root];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else if p.file_name().is_some_and(|n| n == "runs.csv") {
                    let rows = read_rows(&p).unwrap_or_else(|e| panic!("{}: {e:#}", p.display()));
                    assert!(!rows.is_empty(), "{}", p.display());
                    assert!(rows.iter().all(|r| r.id.run_key.ends_with(&format!("-r{}", r.run.rep))));
                    found += 1;
                }
            }
        }
        assert!(found >= 5, "found {found} campaigns");
        // Schema 2 (before the host's noise columns existed: read as not noisy).
        let r5 = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/d02fbfc20d44/quick_m1-2-3_t1-2_o3_r5/runs.csv");
        let rows = read_rows(&r5).unwrap();
        assert_eq!(rows.len(), 60);
        assert!(rows.iter().all(|r| r.id.schema_version == 2 && !r.host.host_noisy && r.ranks() == 1));
        // Schema 7 (renamed into this schema's columns): the reference quick campaign, made at
        // a clean commit.
        let quick = Path::new(env!("CARGO_MANIFEST_DIR")).join("../results/54276cbdfe10/quick/runs.csv");
        let rows = read_rows(&quick).unwrap();
        assert_eq!(rows.len(), 210);
        assert!(rows.iter().all(|r| r.id.schema_version == 7 && !r.id.git_dirty && r.ranks() == 1));
    }
}
