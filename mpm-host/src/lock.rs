//! One writer per folder: an advisory lock (`flock`) on `<folder>/.lock`, held while a
//! process writes into the folder and released when it ends, however it ends (the kernel
//! drops the lock with the last open handle, so a killed process leaves no stale lock). The
//! file names the holder (program, pid, host), so a second writer can say who is there.
//!
//! The harness locks a campaign folder with it, `mpm` a run's checkpoint folder (the ranks
//! of an MPI run killed with its launcher can outlive it by a moment, still writing).

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// The lock of a folder, held until dropped.
#[derive(Debug)]
pub struct FolderLock {
    _file: File,
    path: PathBuf,
}

/// Why a folder's lock was not taken.
#[derive(Debug, thiserror::Error)]
pub enum LockError {
    /// Another process holds it (its note: program, pid, host).
    #[error("in use by {0}")]
    Busy(String),
    /// The folder or its lock file cannot be made or locked.
    #[error("cannot lock {path}: {source}")]
    Io {
        /// The lock file (or the folder).
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// Try to take the exclusive lock of `file` without blocking: `Ok(true)` when taken.
fn try_flock(file: &File) -> std::io::Result<bool> {
    // SAFETY: flock(2) on a file descriptor this `File` owns and keeps open for the call;
    // no memory is passed.
    let rc = unsafe { libc::flock(file.as_raw_fd(), libc::LOCK_EX | libc::LOCK_NB) };
    if rc == 0 {
        return Ok(true);
    }
    let e = std::io::Error::last_os_error();
    match e.raw_os_error() {
        Some(libc::EWOULDBLOCK) => Ok(false),
        _ => Err(e),
    }
}

impl FolderLock {
    /// Take the lock of `dir` (created if needed) for `program`. Held by another process:
    /// wait for it up to `wait` (`None`: as long as it takes), calling `waiting` with the
    /// holder once when the wait begins, then [`LockError::Busy`].
    pub fn acquire(
        dir: &Path,
        program: &str,
        wait: Option<Duration>,
        mut waiting: impl FnMut(&str),
    ) -> Result<Self, LockError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| LockError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let path = dir.join(".lock");
        let mut file =
            OpenOptions::new().read(true).write(true).create(true).truncate(false).open(&path).map_err(io(&path))?;
        let start = Instant::now();
        let mut said = false;
        while !try_flock(&file).map_err(io(&path))? {
            let mut holder = String::new();
            let _ = file.rewind().and_then(|()| file.read_to_string(&mut holder));
            let holder = holder.trim().to_string();
            let who = if holder.is_empty() { "another process".to_string() } else { holder };
            if wait.is_some_and(|w| start.elapsed() >= w) {
                return Err(LockError::Busy(who));
            }
            if !said {
                waiting(&who);
                said = true;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let note = format!("{program} pid {} on {}\n", std::process::id(), host.trim());
        file.set_len(0).and_then(|()| file.rewind()).and_then(|()| file.write_all(note.as_bytes())).ok();
        Ok(Self { _file: file, path })
    }

    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second lock of the folder in this process (another open file description, as
    /// another process would have) is refused, naming the holder, after waiting as long as
    /// asked; once the first is dropped it is taken.
    #[test]
    fn a_held_folder_is_refused_with_its_holder_then_free() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::acquire(dir.path(), "mpm", Some(Duration::ZERO), |_| {}).unwrap();
        let mut told = None;
        let t0 = Instant::now();
        let err =
            FolderLock::acquire(dir.path(), "mpm", Some(Duration::from_millis(300)), |w| told = Some(w.to_string()))
                .unwrap_err();
        assert!(t0.elapsed() >= Duration::from_millis(300));
        assert!(
            matches!(&err, LockError::Busy(who) if who.contains(&format!("mpm pid {}", std::process::id()))),
            "{err}"
        );
        assert!(told.is_some_and(|w| w.contains("mpm pid")));
        drop(first);
        let again = FolderLock::acquire(dir.path(), "mpm", Some(Duration::ZERO), |_| {}).unwrap();
        assert!(again.path().is_file());
    }
}
