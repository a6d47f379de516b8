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

/// `dir/.name.tmp.<pid>` for a target `dir/name` (this process's id).
pub fn temp_path_for(path: &Path) -> PathBuf {
    temp_path_for_pid(path, std::process::id())
}

/// `dir/.name.tmp.<pid>` for a target `dir/name` written by process `pid` (the harness
/// removes a killed child's leftover with it).
pub fn temp_path_for_pid(path: &Path, pid: u32) -> PathBuf {
    let name = path.file_name().map(|n| n.to_string_lossy().into_owned()).unwrap_or_else(|| "out".into());
    path.with_file_name(format!(".{name}.tmp.{pid}"))
}

/// The process id of a temporary file named by [`temp_path_for_pid`] (`None` for any other
/// name).
pub fn temp_file_pid(file_name: &str) -> Option<u32> {
    let (stem, pid) = file_name.rsplit_once(".tmp.")?;
    (stem.starts_with('.') && stem.len() > 1).then_some(())?;
    pid.parse().ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn temp_names_carry_the_writer_pid() {
        let p = temp_path_for_pid(Path::new("/x/run.json"), 4321);
        assert_eq!(p, Path::new("/x/.run.json.tmp.4321"));
        assert_eq!(temp_file_pid(".run.json.tmp.4321"), Some(4321));
        assert_eq!(temp_file_pid("run.json.tmp.4321"), None, "not one of ours: no leading dot");
        assert_eq!(temp_file_pid(".run.json.tmp.x"), None);
        assert_eq!(temp_file_pid("runs.csv"), None);
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("a.json");
        write_atomic(&target, b"{}").unwrap();
        assert_eq!(std::fs::read(&target).unwrap(), b"{}");
        assert!(!temp_path_for(&target).exists());
    }
}
