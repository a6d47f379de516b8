//! Atomic file writes: a temporary file beside the target, written and `fsync`ed, renamed
//! over it, then its folder `fsync`ed ([`crate::durable`]), so a reader never sees a
//! half-written summary, manifest or snapshot list, and after a power loss the file holds
//! the new contents, not the old. A failure of any step is an error naming the file and the
//! step.

use std::io::Write;
use std::path::{Path, PathBuf};

use crate::durable::{folder_of, sync_file, sync_folder};

/// A file that could not be written (its temporary file is removed).
#[derive(Debug, thiserror::Error)]
#[error("cannot write {path}: {step}; check the free space, permissions and file system of its folder, then run again")]
pub struct WriteError {
    /// The destination.
    pub path: PathBuf,
    /// The step that failed.
    pub step: WriteStep,
    /// What the system said.
    pub source: std::io::Error,
}

/// The steps of [`write_atomic`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, thiserror::Error)]
pub enum WriteStep {
    /// Creating the temporary file.
    #[error("creating its temporary file beside it failed")]
    Create,
    /// Writing the temporary file.
    #[error("writing its temporary file failed")]
    Write,
    /// `fsync` of the temporary file.
    #[error("fsync of its temporary file failed")]
    SyncFile,
    /// Renaming the temporary file over the destination.
    #[error("renaming its temporary file over it failed")]
    Rename,
    /// `fsync` of the folder after the rename.
    #[error("fsync of its folder after the rename failed (the new contents may not survive a power loss)")]
    SyncFolder,
    /// Writing a special destination in place.
    #[error("writing it in place failed")]
    InPlace,
}

/// Whether `path` exists and is neither a regular file nor a directory: a device such as
/// `/dev/null` or `/dev/stdout`, a FIFO, a terminal. Such a destination is written in place:
/// renaming a file over it would replace it (run as root, `--json /dev/null` turned
/// `/dev/null` into a regular file for every process on the machine).
pub fn is_special(path: &Path) -> bool {
    std::fs::metadata(path).is_ok_and(|m| !m.is_file() && !m.is_dir())
}

/// Write `bytes` to `path` atomically and durably; on failure before the rename the
/// temporary file is removed. A special destination ([`is_special`]) is written in place
/// instead, and not synced (a terminal or a pipe cannot be).
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<(), WriteError> {
    let failed = |step| move |source| WriteError { path: path.to_path_buf(), step, source };
    if is_special(path) {
        return std::fs::write(path, bytes).map_err(failed(WriteStep::InPlace));
    }
    let tmp = temp_path_for(path);
    let result = (|| {
        let mut f = std::fs::File::create(&tmp).map_err(failed(WriteStep::Create))?;
        f.write_all(bytes).map_err(failed(WriteStep::Write))?;
        sync_file(&f).map_err(failed(WriteStep::SyncFile))?;
        std::fs::rename(&tmp, path).map_err(failed(WriteStep::Rename))
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    result?;
    sync_folder(folder_of(path)).map_err(failed(WriteStep::SyncFolder))
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

    /// An `fsync` that fails, of the file or of its folder after the rename, is an error
    /// naming the file and the step (injected: no unprivileged test can make a local file
    /// system fail one); the temporary file does not stay behind.
    #[test]
    fn a_failed_sync_is_an_error_naming_the_file() {
        use crate::fault::{inject, Fault};
        let dir = tempfile::tempdir().unwrap();
        let target = dir.path().join("manifest.json");
        for (fault, step) in [(Fault::SyncFile, WriteStep::SyncFile), (Fault::SyncFolder, WriteStep::SyncFolder)] {
            let _fault = inject(fault, libc::EIO);
            let err = write_atomic(&target, b"{}").unwrap_err();
            assert_eq!((err.step, &err.path), (step, &target), "{err}");
            assert_eq!(err.source.raw_os_error(), Some(libc::EIO));
            assert!(err.to_string().contains(&target.display().to_string()), "{err}");
            assert!(!temp_path_for(&target).exists());
        }
        let missing = dir.path().join("missing").join("a.json");
        assert_eq!(write_atomic(&missing, b"{}").unwrap_err().step, WriteStep::Create);
    }
}
