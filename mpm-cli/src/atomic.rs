//! Atomic file writes: a temporary file beside the target, synced, then renamed over it, so
//! a reader never sees a half-written summary, manifest or snapshot list.

use anyhow::{Context, Result};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Write `bytes` to `path` atomically; on failure the temporary file is removed.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = temp_path_for(path);
    let result = (|| -> std::io::Result<()> {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result.with_context(|| format!("cannot write {}", path.display()))
}

/// Measure-print-save for the report commands (`bandwidth`, `paired`): create the parent
/// folder of `out` before measuring (so a bad path fails at once, not after the run), then
/// run `measure`, print `table` of its result and write it to `out` as pretty JSON.
/// `flag` names the option that gave `out`, for the error messages.
pub fn measure_and_report<T: serde::Serialize>(
    out: Option<&Path>,
    flag: &str,
    measure: impl FnOnce() -> Result<T>,
    table: impl FnOnce(&T) -> String,
) -> Result<()> {
    if let Some(parent) = out.and_then(Path::parent).filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {} for {flag}: choose a writable path", parent.display()))?;
    }
    let report = measure()?;
    print!("{}", table(&report));
    if let Some(out) = out {
        write_atomic(out, serde_json::to_string_pretty(&report)?.as_bytes())
            .with_context(|| format!("cannot write {}: choose a writable {flag}", out.display()))?;
        println!("wrote {}", out.display());
    }
    Ok(())
}

/// `dir/.name.tmp.<pid>` for a target `dir/name`.
pub fn temp_path_for(path: &Path) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    path.with_file_name(format!(".{name}.tmp.{}", std::process::id()))
}
