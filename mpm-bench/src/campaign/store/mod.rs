//! What was recorded: the CSV row and its columns, the file, older schemas, rows repeating a
//! run, the manifest (with a bundle's record of its build), the campaign folder's lock and
//! its disk failing (full, read-only).

pub mod bundle;
pub mod columns;
pub mod csv;
pub mod disk;
pub mod filled;
pub mod legacy;
pub mod lock;
pub mod manifest;
pub mod record;
pub mod repeats;

/// The files a campaign folder records itself in: an output of another command (a verdict,
/// a report) is never written over one of them.
pub const RECORD_FILES: [&str; 6] =
    ["runs.csv", "manifest.json", "topology.xml", "bandwidth.json", "slurm-jobs.json", "ab.json"];

/// Refuse `path` as the output of `flag` when it is an existing campaign record
/// ([`RECORD_FILES`], or a file beside a `runs.csv`'s `json/` folder of run summaries):
/// writing there would destroy the results the command reads.
pub fn refuse_record_as_output(path: &std::path::Path, flag: &str) -> anyhow::Result<()> {
    let name = path.file_name().and_then(|n| n.to_str()).unwrap_or_default();
    let in_json = path.parent().is_some_and(|d| {
        d.file_name().is_some_and(|n| n == "json") && d.parent().is_some_and(|c| c.join("runs.csv").is_file())
    });
    if path.is_file() && (RECORD_FILES.contains(&name) || in_json) {
        anyhow::bail!(
            "{flag} {} is a campaign's own record: writing there would destroy the results; give another file",
            path.display()
        );
    }
    Ok(())
}
