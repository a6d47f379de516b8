//! Durable files: what a call says it wrote is on the disk when it returns, or the call
//! fails, naming the file. `fsync` of the file makes its contents durable; `fsync` of its
//! folder makes a new or renamed name in it durable (without it, a power loss can bring back
//! the folder's old entry: the old contents of a file replaced by a rename, or no file at
//! all). [`crate::atomic`] writes whole files this way; [`Appender`] appends lines.
//!
//! An `fsync` that fails is an error, never ignored: after it the kernel may have dropped
//! the unwritten pages and a later `fsync` may succeed without them, so the caller must not
//! count what it wrote as recorded. One failure of a folder's `fsync` is not an error:
//! `EINVAL`, which a file system that cannot sync folders at all answers (the folder's
//! entries are then as durable as that file system makes them, and no call can do more).

use std::fs::{File, OpenOptions};
use std::io::Write;
use std::path::{Path, PathBuf};

use crate::fault::{injected, Fault};

/// `fsync` of `file`: its contents and metadata on the disk.
pub fn sync_file(file: &File) -> std::io::Result<()> {
    match injected(Fault::SyncFile) {
        Some(e) => Err(e),
        None => file.sync_all(),
    }
}

/// `fdatasync` of `file`: its contents (and the size they need) on the disk.
pub fn sync_data(file: &File) -> std::io::Result<()> {
    match injected(Fault::SyncFile) {
        Some(e) => Err(e),
        None => file.sync_data(),
    }
}

/// `fsync` of the folder `dir`, so that the names in it are on the disk; `EINVAL` (a file
/// system that cannot sync a folder) counts as done.
pub fn sync_folder(dir: &Path) -> std::io::Result<()> {
    let result = match injected(Fault::SyncFolder) {
        Some(e) => Err(e),
        None => File::open(dir).and_then(|d| d.sync_all()),
    };
    match result {
        Err(e) if e.raw_os_error() == Some(libc::EINVAL) => Ok(()),
        other => other,
    }
}

/// The folder holding `path` (`.` for a bare file name).
pub fn folder_of(path: &Path) -> &Path {
    match path.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

/// Why a line was not appended durably.
#[derive(Debug, thiserror::Error)]
pub enum AppendError {
    /// The file cannot be opened or created.
    #[error("cannot open {path} for appending: {source}; check that its folder exists and is writable")]
    Open {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A new file's name cannot be made durable.
    #[error(
        "cannot sync the folder {dir} after creating {path} in it: {source}; the file may vanish on a power \
         loss: check the file system (full, read-only, failing?) and run again"
    )]
    SyncFolder {
        /// The file created.
        path: PathBuf,
        /// Its folder.
        dir: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The line cannot be written.
    #[error("cannot append to {path}: {source}; free space or choose another folder, then run again")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The line was written but cannot be made durable.
    #[error(
        "cannot sync {path} after appending to it: {source}; the line may not be on the disk and is not \
         recorded: check the file system (full, read-only, failing?) and run again"
    )]
    Sync {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
}

/// A file appended to durably, one line at a time: each [`Appender::append`] returns once
/// its bytes are written and `fdatasync`ed, or fails. After a failure the file may end in a
/// part of the line (a torn tail, for its reader to repair or refuse), and the line must
/// not be counted as recorded.
#[derive(Debug)]
pub struct Appender {
    file: File,
    path: PathBuf,
}

impl Appender {
    /// Open `path` for reading and appending. A file that does not exist is created and its
    /// folder synced, so that its name survives a power loss.
    pub fn open(path: &Path) -> Result<Self, AppendError> {
        let open = |create_new| OpenOptions::new().read(true).append(true).create_new(create_new).open(path);
        let failed = |source| AppendError::Open { path: path.to_path_buf(), source };
        let file = match open(true) {
            Ok(file) => {
                let dir = folder_of(path);
                sync_folder(dir).map_err(|source| AppendError::SyncFolder {
                    path: path.to_path_buf(),
                    dir: dir.to_path_buf(),
                    source,
                })?;
                file
            }
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => open(false).map_err(failed)?,
            Err(e) => return Err(failed(e)),
        };
        Ok(Self { file, path: path.to_path_buf() })
    }

    /// Append `bytes` in one write, then `fdatasync` the file.
    pub fn append(&mut self, bytes: &[u8]) -> Result<(), AppendError> {
        let path = || self.path.clone();
        self.file.write_all(bytes).map_err(|source| AppendError::Write { path: path(), source })?;
        sync_data(&self.file).map_err(|source| AppendError::Sync { path: path(), source })
    }

    /// Append `line` and its line end (added unless `line` ends with one), durably.
    pub fn append_line(&mut self, line: &str) -> Result<(), AppendError> {
        if line.ends_with('\n') {
            self.append(line.as_bytes())
        } else {
            self.append(format!("{line}\n").as_bytes())
        }
    }

    /// The open file, to read what it holds (reads start where the last one ended; appends
    /// go to the end whatever the position).
    pub fn file(&mut self) -> &mut File {
        &mut self.file
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fault::inject;
    use std::io::Read;

    /// Lines appended are all there, in order, each with one line end; a file reopened
    /// keeps them and takes more.
    #[test]
    fn lines_are_appended_in_order() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("runs.csv");
        let mut log = Appender::open(&path).unwrap();
        log.append_line("a,b").unwrap();
        log.append_line("1,2\n").unwrap();
        drop(log);
        let mut log = Appender::open(&path).unwrap();
        let mut text = String::new();
        log.file().read_to_string(&mut text).unwrap();
        assert_eq!(text, "a,b\n1,2\n");
        log.append(b"3,4\n").unwrap();
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "a,b\n1,2\n3,4\n");
        assert_eq!(log.path(), path);
    }

    /// An `fsync` that fails (injected: no unprivileged test can make a local file system
    /// fail one) is an error naming the file, and says the line is not recorded.
    #[test]
    fn a_failed_sync_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("runs.csv");
        let mut log = Appender::open(&path).unwrap();
        let fault = inject(Fault::SyncFile, libc::EIO);
        let err = log.append_line("1,2").unwrap_err();
        assert!(matches!(&err, AppendError::Sync { path: p, .. } if p == &path), "{err:?}");
        let msg = err.to_string();
        assert!(msg.contains(&path.display().to_string()) && msg.contains("not recorded"), "{msg}");
        drop(fault);
        log.append_line("3,4").unwrap();
    }

    /// A new file's folder is synced, and a failure of that is an error naming both; a
    /// folder that cannot be synced at all (`EINVAL`) is not.
    #[test]
    fn a_new_file_syncs_its_folder() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("runs.csv");
        let fault = inject(Fault::SyncFolder, libc::EIO);
        let err = Appender::open(&path).unwrap_err();
        assert!(matches!(&err, AppendError::SyncFolder { dir: d, .. } if d == dir.path()), "{err:?}");
        assert!(err.to_string().contains(&path.display().to_string()), "{err}");
        drop(fault);
        let _unsupported = inject(Fault::SyncFolder, libc::EINVAL);
        std::fs::remove_file(&path).unwrap();
        Appender::open(&path).unwrap();
        assert_eq!(folder_of(Path::new("runs.csv")), Path::new("."));
    }

    /// A write that fails (a full device: `/dev/full` answers every write with `ENOSPC`)
    /// is an error naming the file.
    #[test]
    fn a_full_device_is_a_write_error() {
        let mut full = Appender::open(Path::new("/dev/full")).unwrap();
        let err = full.append_line("1,2").unwrap_err();
        assert!(matches!(&err, AppendError::Write { source, .. } if source.raw_os_error() == Some(libc::ENOSPC)));
        assert!(err.to_string().contains("/dev/full"), "{err}");
    }

    /// A file that cannot be opened is an error naming it.
    #[test]
    fn a_missing_folder_is_an_error_naming_the_file() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("missing").join("runs.csv");
        let err = Appender::open(&path).unwrap_err();
        assert!(matches!(&err, AppendError::Open { .. }) && err.to_string().contains("missing/runs.csv"), "{err}");
    }
}
