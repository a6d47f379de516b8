//! The disk under the campaign folder failing the campaign: full (`ENOSPC`, or `EDQUOT`: the
//! user's quota spent, as on a cluster's shared file system) or not writable (`EROFS`,
//! `EACCES`, `EPERM`).
//!
//! A full disk stops the campaign at once with [`DiskFull`]: every run after it would fail
//! the same way, each recorded as a failure of its own (or its row not written at all). The
//! rows recorded before it stay (a row that cannot be written is cut back out of `runs.csv`,
//! [`super::csv::CsvLog::append`]); the run that met the full disk is not recorded, so the
//! same command, once there is space, runs it and the rest. A folder that cannot be written
//! is refused before any run starts ([`not_writable`]).

use std::path::{Path, PathBuf};

/// The campaign stopped on a full disk.
#[derive(Debug, thiserror::Error)]
#[error(
    "the disk holding {} is full ({why}): {what}; free space there (or move the results to a bigger disk and \
     point --out at them), then run the same command again: the rows recorded are kept and the runs still to \
     do run then",
    folder.display()
)]
pub struct DiskFull {
    /// The folder that could not be written.
    pub folder: PathBuf,
    /// What the system said (`No space left on device`, `Disk quota exceeded`).
    pub why: &'static str,
    /// What could not be written.
    pub what: String,
}

/// The full-disk errors: their numbers and what the system says for each.
const FULL: [(i32, &str); 2] = [(libc::ENOSPC, "No space left on device"), (libc::EDQUOT, "Disk quota exceeded")];

/// What the system said, when `e` is a full disk.
pub fn full(e: &std::io::Error) -> Option<&'static str> {
    FULL.iter().find(|(code, _)| e.raw_os_error() == Some(*code)).map(|&(_, why)| why)
}

/// What the system said, when the words of a failed run (its reason: the solver's error or
/// the harness's) name a full disk: the OS error as Rust writes it, `... (os error 28)`.
pub fn full_in_words(words: &str) -> Option<&'static str> {
    FULL.iter().find(|(code, _)| words.contains(&format!("(os error {code})"))).map(|&(_, why)| why)
}

/// `e` explained when a full disk is its cause, somewhere in its chain: with the context of
/// a [`DiskFull`] of `folder` (what to do), unless it already is one.
pub fn explain_full(e: anyhow::Error, folder: &Path) -> anyhow::Error {
    if e.downcast_ref::<DiskFull>().is_some() {
        return e;
    }
    let why = e.chain().filter_map(|c| c.downcast_ref::<std::io::Error>()).find_map(full);
    match why {
        Some(why) => {
            let what = "a file of the campaign could not be written".to_string();
            e.context(DiskFull { folder: folder.to_path_buf(), why, what })
        }
        None => e,
    }
}

/// Whether `e` says a folder cannot be written (read-only, or not ours to write).
pub fn not_writable(e: &std::io::Error) -> bool {
    matches!(e.raw_os_error(), Some(libc::EROFS | libc::EACCES | libc::EPERM))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Both full-disk errors are told apart from others, as errors and in a run's words.
    #[test]
    fn full_disks_are_recognised() {
        let e = |code| std::io::Error::from_raw_os_error(code);
        assert_eq!(full(&e(libc::ENOSPC)), Some("No space left on device"));
        assert_eq!(full(&e(libc::EDQUOT)), Some("Disk quota exceeded"));
        assert_eq!(full(&e(libc::EIO)), None);
        let words = format!("solver exited with code 1: cannot write the JSON summary: {}", e(libc::ENOSPC));
        assert_eq!(full_in_words(&words), Some("No space left on device"));
        assert_eq!(full_in_words(&format!("{}", e(libc::EDQUOT))), Some("Disk quota exceeded"));
        assert_eq!(full_in_words("solver exited with code 1 (os error 2)"), None);
        assert!(not_writable(&e(libc::EROFS)) && !not_writable(&e(libc::ENOSPC)));
    }

    /// An error caused by a full disk gets the full disk's explanation once; others are
    /// left as they are.
    #[test]
    fn errors_of_a_full_disk_are_explained() {
        let full_error = anyhow::Error::new(std::io::Error::from_raw_os_error(libc::ENOSPC)).context("cannot write x");
        let explained = explain_full(full_error, Path::new("/r"));
        let msg = format!("{explained:#}");
        assert!(msg.starts_with("the disk holding /r is full (No space left on device)"), "{msg}");
        assert!(msg.contains("cannot write x") && msg.contains("run the same command again"), "{msg}");
        let again = format!("{:#}", explain_full(explained, Path::new("/r")));
        assert_eq!(again.matches("is full").count(), 1, "{again}");
        let other = anyhow::Error::new(std::io::Error::from_raw_os_error(libc::EIO));
        assert!(!format!("{:#}", explain_full(other, Path::new("/r"))).contains("full"));
    }
}
