//! One writer per campaign folder: an advisory lock (`flock`) on `<folder>/.lock`, held while
//! a campaign runs into the folder and released when the process ends, however it ends (the
//! kernel drops the lock with the last open handle, so a killed harness leaves no stale
//! lock). The file holds the holder's pid, host and start time, so a second `mpm-bench run`
//! into the same folder can say who is there; it refuses, or with `--wait` waits.

use anyhow::{bail, Context, Result};
use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The lock of a campaign folder, held until dropped.
#[derive(Debug)]
pub struct FolderLock {
    _file: File,
    path: PathBuf,
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
    /// Take the lock of the campaign folder `dir` (created if needed). Held by another
    /// process: wait for it when `wait` (saying so once), else refuse naming the holder.
    pub fn acquire(dir: &Path, wait: bool) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create the campaign folder {}", dir.display()))?;
        let path = dir.join(".lock");
        let mut file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(&path)
            .with_context(|| format!("cannot open the lock file {}", path.display()))?;
        let mut said = false;
        while !try_flock(&file).with_context(|| format!("cannot lock {}", path.display()))? {
            let mut holder = String::new();
            let _ = file.rewind().and_then(|()| file.read_to_string(&mut holder));
            let holder = holder.trim().to_string();
            let who = if holder.is_empty() { "another mpm-bench".to_string() } else { holder };
            if !wait {
                bail!(
                    "the campaign folder {} is in use by {who}: two campaigns writing one folder would run \
                     every run twice; wait for it to finish, add --wait to wait here, or write to another --out",
                    dir.display()
                );
            }
            if !said {
                eprintln!("waiting for the campaign folder {} (in use by {who})", dir.display());
                said = true;
            }
            std::thread::sleep(Duration::from_millis(200));
        }
        let host = std::fs::read_to_string("/proc/sys/kernel/hostname").unwrap_or_default();
        let note =
            format!("mpm-bench pid {} on {} since {}\n", std::process::id(), host.trim(), crate::util::now_rfc3339());
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
    /// another process would have) is refused, naming the holder, until the first is
    /// dropped; then it is taken.
    #[test]
    fn a_held_folder_is_refused_with_its_holder_then_free() {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::acquire(dir.path(), false).unwrap();
        let err = FolderLock::acquire(dir.path(), false).unwrap_err().to_string();
        assert!(err.contains(&format!("pid {}", std::process::id())) && err.contains("--wait"), "{err}");
        drop(first);
        let again = FolderLock::acquire(dir.path(), false).unwrap();
        assert!(again.path().is_file());
    }
}
