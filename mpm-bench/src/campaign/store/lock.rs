//! One writer per campaign folder: an advisory lock (`flock`) on `<folder>/.lock`, held while
//! a campaign runs into the folder and released when the process ends, however it ends (the
//! kernel drops the lock with the last open handle, so a killed harness leaves no stale
//! lock). The file holds the holder's pid and host, so a second `mpm-bench run` into the same
//! folder can say who is there; it refuses, or with `--wait` waits. A folder where the lock
//! cannot be made (read-only, or not ours) is refused before any run starts. The lock itself
//! is `mpm_host::lock`'s, which `mpm` takes on a run's checkpoint folder too.

use super::disk::not_writable;
use anyhow::{bail, Result};
use mpm_host::lock::LockError;
use std::path::Path;
use std::time::Duration;

pub use mpm_host::lock::FolderLock;

/// Take the lock of the campaign folder `dir` (created if needed). Held by another
/// process: wait for it when `wait` (saying so once), else refuse naming the holder.
pub fn acquire(dir: &Path, wait: bool) -> Result<FolderLock> {
    let waiting = |who: &str| eprintln!("waiting for the campaign folder {} (in use by {who})", dir.display());
    match FolderLock::acquire(dir, "mpm-bench", if wait { None } else { Some(Duration::ZERO) }, waiting) {
        Ok(lock) => Ok(lock),
        Err(LockError::Busy(who)) => bail!(
            "the campaign folder {} is in use by {who}: two campaigns writing one folder would run every run twice; \
             wait for it to finish, add --wait to wait here, or write to another --out",
            dir.display()
        ),
        Err(LockError::Io { path, source }) if not_writable(&source) => bail!(
            "the campaign folder {} cannot be written ({source}: its lock {} cannot be made): a campaign runs \
             only into a folder it can write; make it writable, or write to another --out (the analyses read a \
             read-only folder as it is)",
            dir.display(),
            path.display()
        ),
        Err(e) => Err(e.into()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A second lock of the folder in this process (another open file description, as
    /// another process would have) is refused, naming the holder, until the first is
    /// dropped; then it is taken. Taken again with a short wait, not at once: a child
    /// process forked by another test thread holds a copy of every descriptor (the lock's
    /// too) from its fork until its exec closes them, and the lock goes with the last copy.
    #[test]
    fn a_held_folder_is_refused_with_its_holder_then_free() {
        let dir = tempfile::tempdir().unwrap();
        let first = acquire(dir.path(), false).unwrap();
        let err = acquire(dir.path(), false).unwrap_err().to_string();
        assert!(err.contains(&format!("pid {}", std::process::id())) && err.contains("--wait"), "{err}");
        drop(first);
        let again = FolderLock::acquire(dir.path(), "mpm-bench", Some(Duration::from_secs(10)), |_| {}).unwrap();
        assert!(again.path().is_file());
    }
}
