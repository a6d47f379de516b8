//! Atomic file writes: a temporary file beside the target, synced, then renamed over it, so
//! a reader never sees a half-written summary, manifest or snapshot list.

use std::io::Write;
use std::path::{Path, PathBuf};

/// A file that could not be written (its temporary file is removed).
#[derive(Debug, thiserror::Error)]
#[error("cannot write {path}")]
pub struct WriteError {
    /// The destination.
    pub path: PathBuf,
    /// What the system said.
    pub source: std::io::Error,
}

/// Whether `path` exists and is neither a regular file nor a directory: a device such as
/// `/dev/null` or `/dev/stdout`, a FIFO, a terminal. Such a destination is written in place:
/// renaming a file over it would replace it (run as root, `--json /dev/null` turned
/// `/dev/null` into a regular file for every process on the machine).
pub fn is_special(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// Write `bytes` to `path` atomically; on failure the temporary file is removed. A special
/// destination ([`is_special`]) is written in place instead.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let failed = |source| WriteError { path: path.to_path_buf(), source };
    if is_special(path) {
        return std::fs::write(path, bytes).map_err(failed);
    }
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
    result.map_err(failed)
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

    /// A device is written in place, never replaced by a rename (as root the rename
    /// succeeds and `/dev/null` becomes a regular file; otherwise it fails).
    #[test]
    fn dev_null_stays_a_device() {
        use std::os::unix::fs::FileTypeExt;
        let null = Path::new("/dev/null");
        assert!(is_special(null));
        write_atomic(null, b"{}").unwrap();
        assert!(std::fs::metadata(null).unwrap().file_type().is_char_device(), "/dev/null was replaced");
        assert!(!temp_path_for(null).exists());
        let dir = tempfile::tempdir().unwrap();
        assert!(!is_special(dir.path()) && !is_special(&dir.path().join("missing")));
    }
}
