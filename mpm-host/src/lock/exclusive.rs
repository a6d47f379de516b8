//! The lock of a folder where `flock` is not supported (Lustre mounted without `-o flock`,
//! NFS without its lock manager): the lock file `<folder>/.lock.excl`, created exclusively
//! (`O_CREAT|O_EXCL`, atomic on these file systems too) by the holder, holding its
//! [`Owner`] (program, host, boot, pid namespace, pid, start time), synced with its folder,
//! and removed by the holder when it lets go.
//!
//! A process killed with `SIGKILL` leaves its file behind. A file whose owner is judged gone
//! ([`Owner::judge`]: this host, its pid ended or reused, or this host restarted) is taken
//! over, with a note saying so: it is renamed aside, and removed only if what was moved is
//! the very file judged (its inode and text), else put back (another process took the
//! stale lock a moment before). A file of another host, of another pid namespace, or that names no owner
//! is never taken over: the holder is refused with the file's path and how to remove it by
//! hand once its owner has ended.
//!
//! Every process locking a folder must see the same support of `flock` (the same mount
//! options): a process that takes the `flock` does not look for this file.

use std::fs::{File, OpenOptions};
use std::io::{ErrorKind, Read, Write};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

use super::owner::{Owner, Verdict};
use crate::durable::{folder_of, sync_file, sync_folder};

/// The lock file's name in its folder.
pub const FILE_NAME: &str = ".lock.excl";

/// A file's identity: device and inode.
type FileId = (u64, u64);

fn id_of(m: &std::fs::Metadata) -> FileId {
    (m.dev(), m.ino())
}

/// A lock file held by this process, removed when dropped (unless it is no longer the file
/// this process created: another inode, or other contents, an inode number being reused
/// once its file is gone).
#[derive(Debug)]
pub struct Held {
    path: PathBuf,
    id: FileId,
    note: String,
}

impl Held {
    /// The lock file.
    pub fn path(&self) -> &Path {
        &self.path
    }
}

impl Drop for Held {
    fn drop(&mut self) {
        if read_lock(&self.path).ok().flatten().is_some_and(|(text, id)| id == self.id && text == self.note) {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

/// What one attempt to take the lock found.
#[derive(Debug)]
pub enum Attempt {
    /// Taken.
    Taken(Held),
    /// Held by another: who, for people.
    Busy(String),
    /// The file went away, or a stale one was taken over: try again at once.
    Again,
}

/// Try once to take the lock file `path` for `me`; `note` is told of a stale lock taken
/// over.
pub fn try_take(path: &Path, me: &Owner, note: &mut dyn FnMut(String)) -> std::io::Result<Attempt> {
    match OpenOptions::new().write(true).create_new(true).open(path) {
        Ok(file) => return write_owner(file, path, me).map(Attempt::Taken),
        Err(e) if e.kind() == ErrorKind::AlreadyExists => {}
        Err(e) => return Err(e),
    }
    let Some((text, id)) = read_lock(path)? else { return Ok(Attempt::Again) };
    let hint = || {
        format!(
            "the lock file {} of a file system without flock; if that process has ended, remove the file by \
             hand: rm {}",
            path.display(),
            path.display()
        )
    };
    let Some(owner) = Owner::parse(&text) else {
        return Ok(Attempt::Busy(format!("a process that the lock file does not name ({})", hint())));
    };
    Ok(match owner.judge(me) {
        Verdict::Live => Attempt::Busy(owner.describe()),
        Verdict::Elsewhere(place) => Attempt::Busy(format!("{} ({place}; {})", owner.describe(), hint())),
        Verdict::Stale(why) => {
            if take_over(path, (&text, id))? {
                note(format!("taking over the lock {} left by {} ({why})", path.display(), owner.describe()));
            }
            Attempt::Again
        }
    })
}

/// Write `me` into the lock file just created, sync it and its folder; on failure the file
/// is removed.
fn write_owner(mut file: File, path: &Path, me: &Owner) -> std::io::Result<Held> {
    let note = me.note();
    let written = (|| {
        file.write_all(note.as_bytes())?;
        sync_file(&file)?;
        sync_folder(folder_of(path))?;
        file.metadata()
    })();
    match written {
        Ok(m) => Ok(Held { path: path.to_path_buf(), id: id_of(&m), note }),
        Err(e) => {
            let _ = std::fs::remove_file(path);
            Err(e)
        }
    }
}

/// The lock file's text and identity, read through one handle; `None` when it is gone.
fn read_lock(path: &Path) -> std::io::Result<Option<(String, FileId)>> {
    let mut file = match File::open(path) {
        Ok(f) => f,
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e),
    };
    let id = id_of(&file.metadata()?);
    let mut bytes = Vec::new();
    file.read_to_end(&mut bytes)?;
    Ok(Some((String::from_utf8_lossy(&bytes).into_owned(), id)))
}

/// Remove the stale lock file `path` judged by its text and identity `judged`: renamed
/// aside, then removed if it is that file (the same inode, and the same text: an inode
/// number is reused once its file is gone), else put back. `Ok(true)` when it was removed
/// here.
fn take_over(path: &Path, judged: (&str, FileId)) -> std::io::Result<bool> {
    let aside = path.with_file_name(format!("{FILE_NAME}.stale.{}", std::process::id()));
    match std::fs::rename(path, &aside) {
        Ok(()) => {}
        Err(e) if e.kind() == ErrorKind::NotFound => return Ok(false),
        Err(e) => return Err(e),
    }
    if read_lock(&aside)?.is_some_and(|(text, id)| (text.as_str(), id) == judged) {
        std::fs::remove_file(&aside)?;
        return Ok(true);
    }
    // Another process took the stale lock between the judgement and the rename: give its
    // file back (a link fails rather than replace a lock file made since).
    let restored = std::fs::hard_link(&aside, path);
    let _ = std::fs::remove_file(&aside);
    match restored {
        Ok(()) => Ok(false),
        Err(e) => Err(std::io::Error::new(
            e.kind(),
            format!("the lock file changed while a stale one was taken over ({e}); run again"),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stale lock file replaced by a fresh one between the judgement and the rename is
    /// put back, not removed.
    #[test]
    fn a_lock_taken_meanwhile_is_put_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE_NAME);
        std::fs::write(&path, "fresh").unwrap();
        let id = id_of(&std::fs::metadata(&path).unwrap());
        assert!(!take_over(&path, ("stale", id)).unwrap(), "same inode, other text");
        assert!(!take_over(&path, ("fresh", (0, 0))).unwrap(), "same text, other inode");
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "fresh");
        assert_eq!(std::fs::read_dir(dir.path()).unwrap().count(), 1, "nothing left aside");
        assert!(take_over(&path, ("fresh", id)).unwrap());
        assert!(!path.exists());
        assert!(!take_over(&path, ("fresh", id)).unwrap(), "gone: nothing to take over");
    }

    /// A held file is removed when dropped, unless it is no longer this holder's.
    #[test]
    fn a_held_file_is_removed_only_if_still_ours() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join(FILE_NAME);
        let me = Owner::this("mpm");
        let Attempt::Taken(held) = try_take(&path, &me, &mut |_| {}).unwrap() else { panic!("not taken") };
        assert_eq!(Owner::parse(&std::fs::read_to_string(held.path()).unwrap()), Some(me.clone()));
        drop(held);
        assert!(!path.exists());
        let Attempt::Taken(held) = try_take(&path, &me, &mut |_| {}).unwrap() else { panic!("not taken") };
        std::fs::remove_file(&path).unwrap();
        std::fs::write(&path, "another's").unwrap();
        drop(held);
        assert_eq!(std::fs::read_to_string(&path).unwrap(), "another's");
    }
}
