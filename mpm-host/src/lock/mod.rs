//! One writer per folder: an advisory lock (`flock`) on `<folder>/.lock`, held while a
//! process writes into the folder and released when it ends, however it ends (the kernel
//! drops the lock with the last open handle, so a killed process leaves no stale lock). The
//! file names the holder (program, pid, host), so a second writer can say who is there.
//!
//! Where the file system does not support `flock` (`ENOSYS`, `EOPNOTSUPP` or `ENOLCK`:
//! Lustre mounted without `-o flock`, NFS without its lock manager), the lock falls back to
//! an exclusively created lock file naming its owner ([`exclusive`]): a stale one left by a
//! process of this host that has ended is taken over with a note on stderr, one of another
//! host is refused with how to remove it by hand.
//!
//! The harness locks a campaign folder with it, `mpm` a run's checkpoint folder (the ranks
//! of an MPI run killed with its launcher can outlive it by a moment, still writing).

mod exclusive;
mod owner;

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, Write};
use std::os::fd::AsRawFd;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use crate::fault::{injected, Fault};
use exclusive::{Attempt, Held};
use owner::Owner;

/// The lock of a folder, held until dropped.
#[derive(Debug)]
pub struct FolderLock {
    _file: File,
    path: PathBuf,
    /// The lock file of the fallback scheme, where `flock` is not supported.
    _exclusive: Option<Held>,
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

/// Whether `flock` failed because the file system does not support it.
fn unsupported(e: &std::io::Error) -> bool {
    matches!(e.raw_os_error(), Some(libc::ENOSYS | libc::EOPNOTSUPP | libc::ENOLCK))
}

/// Try to take the exclusive lock of `file` without blocking: `Ok(true)` when taken.
fn try_flock(file: &File) -> std::io::Result<bool> {
    if let Some(e) = injected(Fault::Flock) {
        return Err(e);
    }
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

/// What one try to take a folder's lock found.
enum Try {
    /// The `flock` is taken.
    Flocked,
    /// The fallback's lock file is taken.
    Exclusive(Held),
    /// Held by another: who, for people.
    Busy(String),
    /// Nothing yet: try again at once.
    Again,
}

/// The lock file `.lock` of a folder, open, and what locking it takes.
struct Attempts<'a> {
    dir: &'a Path,
    file: File,
    path: PathBuf,
    me: Owner,
    /// `flock` is not supported here: the lock file scheme is used.
    fallback: bool,
}

impl Attempts<'_> {
    /// Try once: the lock taken (with the fallback's lock file, if used), or who holds it,
    /// or nothing yet (try again at once).
    fn once(&mut self, note: &mut dyn FnMut(String)) -> Result<Try, LockError> {
        if !self.fallback {
            match try_flock(&self.file) {
                Ok(true) => {
                    let text = format!("{}\n", self.me.describe());
                    let f = &mut self.file;
                    f.set_len(0).and_then(|()| f.rewind()).and_then(|()| f.write_all(text.as_bytes())).ok();
                    return Ok(Try::Flocked);
                }
                Ok(false) => return Ok(Try::Busy(self.holder())),
                Err(e) if unsupported(&e) => self.fallback = true,
                Err(source) => return Err(LockError::Io { path: self.path.clone(), source }),
            }
        }
        let path = self.dir.join(exclusive::FILE_NAME);
        match exclusive::try_take(&path, &self.me, note) {
            Ok(Attempt::Taken(held)) => Ok(Try::Exclusive(held)),
            Ok(Attempt::Busy(who)) => Ok(Try::Busy(who)),
            Ok(Attempt::Again) => Ok(Try::Again),
            Err(source) => Err(LockError::Io { path, source }),
        }
    }

    /// The holder of the `flock`, as its note names it.
    fn holder(&mut self) -> String {
        let mut holder = String::new();
        let _ = self.file.rewind().and_then(|()| self.file.read_to_string(&mut holder));
        let holder = holder.trim().to_string();
        if holder.is_empty() {
            "another process".to_string()
        } else {
            holder
        }
    }
}

impl FolderLock {
    /// Take the lock of `dir` (created if needed) for `program`. Held by another process:
    /// wait for it up to `wait` (`None`: as long as it takes), calling `waiting` with the
    /// holder once when the wait begins, then [`LockError::Busy`]. A stale lock file of
    /// the fallback scheme taken over is said on stderr.
    pub fn acquire(
        dir: &Path,
        program: &str,
        wait: Option<Duration>,
        waiting: impl FnMut(&str),
    ) -> Result<Self, LockError> {
        Self::acquire_noting(dir, program, wait, waiting, &mut |note| eprintln!("{note}"))
    }

    /// [`FolderLock::acquire`], telling `note` of a stale lock taken over.
    pub(crate) fn acquire_noting(
        dir: &Path,
        program: &str,
        wait: Option<Duration>,
        mut waiting: impl FnMut(&str),
        note: &mut dyn FnMut(String),
    ) -> Result<Self, LockError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| LockError::Io { path, source }
        };
        std::fs::create_dir_all(dir).map_err(io(dir))?;
        let path = dir.join(".lock");
        let file =
            OpenOptions::new().read(true).write(true).create(true).truncate(false).open(&path).map_err(io(&path))?;
        let mut attempts = Attempts { dir, file, path, me: Owner::this(program), fallback: false };
        let start = Instant::now();
        let mut said = false;
        loop {
            let who = match attempts.once(note)? {
                Try::Flocked => return Ok(Self::held(attempts, None)),
                Try::Exclusive(held) => return Ok(Self::held(attempts, Some(held))),
                Try::Again => continue,
                Try::Busy(who) => who,
            };
            if wait.is_some_and(|w| start.elapsed() >= w) {
                return Err(LockError::Busy(who));
            }
            if !said {
                waiting(&who);
                said = true;
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// The lock taken by `attempts`, with the fallback's lock file if used.
    fn held(attempts: Attempts<'_>, exclusive: Option<Held>) -> Self {
        let path = exclusive.as_ref().map_or(attempts.path, |h| h.path().to_path_buf());
        Self { _file: attempts.file, path, _exclusive: exclusive }
    }

    /// The lock file: `.lock`, or the fallback's `.lock.excl` where `flock` is not
    /// supported.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::fault::inject;

    /// A second lock of the folder in this process (another open file description, as
    /// another process would have) is refused, naming the holder, after waiting as long as
    /// asked; once the first is dropped it is taken. The lock is the file `lock_file`.
    fn refused_with_its_holder_then_free(lock_file: &str) {
        let dir = tempfile::tempdir().unwrap();
        let first = FolderLock::acquire(dir.path(), "mpm", Some(Duration::ZERO), |_| {}).unwrap();
        assert_eq!(first.path(), dir.path().join(lock_file));
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
        // A short wait, not none: a child forked by another test thread holds a copy of the
        // lock's descriptor from its fork to its exec, and the lock goes with the last copy.
        let again = FolderLock::acquire(dir.path(), "mpm", Some(Duration::from_secs(10)), |_| {}).unwrap();
        assert!(again.path().is_file());
    }

    #[test]
    fn a_held_folder_is_refused_with_its_holder_then_free() {
        refused_with_its_holder_then_free(".lock");
    }

    /// Where `flock` is not supported (each of its three answers for it, injected), the
    /// lock file of the fallback is taken, refused to a second holder, and removed when
    /// let go.
    #[test]
    fn without_flock_the_lock_file_is_refused_then_free() {
        for errno in [libc::ENOSYS, libc::EOPNOTSUPP, libc::ENOLCK] {
            let _fault = inject(Fault::Flock, errno);
            refused_with_its_holder_then_free(exclusive::FILE_NAME);
        }
        let dir = tempfile::tempdir().unwrap();
        let lock = {
            let _fault = inject(Fault::Flock, libc::ENOSYS);
            FolderLock::acquire(dir.path(), "mpm", Some(Duration::ZERO), |_| {}).unwrap()
        };
        let file = lock.path().to_path_buf();
        assert_eq!(owner::Owner::parse(&std::fs::read_to_string(&file).unwrap()), Some(Owner::this("mpm")));
        drop(lock);
        assert!(!file.exists(), "the lock file is removed when let go");
    }

    /// Any other `flock` error is an error naming the lock file, not a fallback.
    #[test]
    fn another_flock_error_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let _fault = inject(Fault::Flock, libc::EIO);
        let err = FolderLock::acquire(dir.path(), "mpm", Some(Duration::ZERO), |_| {}).unwrap_err();
        assert!(matches!(&err, LockError::Io { path, .. } if path.ends_with(".lock")), "{err}");
        assert!(!dir.path().join(exclusive::FILE_NAME).exists());
    }

    /// A folder whose fallback lock file names `owner` (written as a killed process left
    /// it), locked with `flock` unsupported: the result and the notes told.
    fn lock_left_by(owner: &str) -> (tempfile::TempDir, Result<FolderLock, LockError>, Vec<String>) {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join(exclusive::FILE_NAME), owner).unwrap();
        let _fault = inject(Fault::Flock, libc::ENOSYS);
        let mut notes = Vec::new();
        let lock =
            FolderLock::acquire_noting(dir.path(), "mpm-bench", Some(Duration::ZERO), |_| {}, &mut |n| notes.push(n));
        (dir, lock, notes)
    }

    /// A lock file left by a process of this host that has ended (its pid gone, or reused
    /// by another process) is taken over, with a note naming it.
    #[test]
    fn a_stale_lock_file_is_taken_over() {
        let me = Owner::this("mpm");
        let gone = Owner { pid: owner::tests::ended_pid(), ..me.clone() };
        let reused = Owner { start: "1".into(), ..me };
        for (stale, why) in [(gone, "has ended"), (reused, "another process")] {
            let (dir, lock, notes) = lock_left_by(&stale.note());
            let lock = lock.unwrap();
            assert_eq!(Owner::parse(&std::fs::read_to_string(lock.path()).unwrap()), Some(Owner::this("mpm-bench")));
            let told = |n: &String| n.contains("taking over") && n.contains(&stale.describe()) && n.contains(why);
            assert!(matches!(notes.as_slice(), [n] if told(n)), "{notes:?}");
            assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 2, ".lock and .lock.excl only");
        }
    }

    /// A lock file of another host (its owner dead or not: this host cannot tell), or one
    /// that names no owner, is refused, naming it and how to remove it by hand; it is left
    /// as it is.
    #[test]
    fn a_lock_file_of_another_host_is_refused() {
        let elsewhere = Owner { host: "node7".into(), pid: owner::tests::ended_pid(), ..Owner::this("mpm") };
        for (text, named) in [(elsewhere.note(), "mpm pid"), (String::new(), "does not name")] {
            let (dir, lock, notes) = lock_left_by(&text);
            let file = dir.path().join(exclusive::FILE_NAME);
            let err = lock.unwrap_err().to_string();
            assert!(err.contains(named) && err.contains(&format!("rm {}", file.display())), "{err}");
            assert!(text.is_empty() || err.contains("node7"), "{err}");
            assert!(notes.is_empty(), "{notes:?}");
            assert_eq!(std::fs::read_to_string(&file).unwrap(), text);
        }
    }
}
