//! Faults injected by tests into the system calls that durability and locking rest on, for
//! the error paths no unprivileged test can provoke on Linux: an `fsync` that fails (a
//! local file system reports such an I/O error only when the device fails) and a `flock`
//! the file system does not support (Lustre mounted without `-o flock`, some NFS).
//!
//! [`inject`] is compiled in for this crate's own tests and, with the feature
//! `fault-injection`, for the tests of the programs built on it; in their normal builds it
//! does not exist and the check in each call site is a constant `None`. An injected fault
//! holds on the thread that injected it (tests run in parallel threads), for every call of
//! its kind, until its guard is dropped.

#[cfg(any(test, feature = "fault-injection"))]
use std::cell::RefCell;

/// A system call a test can make fail.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// `fsync` of a file ([`crate::durable::sync_file`], [`crate::durable::sync_data`]).
    SyncFile,
    /// `fsync` of a folder ([`crate::durable::sync_folder`]).
    SyncFolder,
    /// `flock` of a folder's lock file ([`crate::lock::FolderLock`]).
    Flock,
}

#[cfg(any(test, feature = "fault-injection"))]
thread_local! {
    static ACTIVE: RefCell<Vec<(Fault, i32)>> = const { RefCell::new(Vec::new()) };
}

/// An injected fault, removed when dropped.
#[cfg(any(test, feature = "fault-injection"))]
#[derive(Debug)]
#[must_use = "the fault is removed when the guard is dropped"]
pub struct Injected(Fault);

/// Make every call of kind `fault` on this thread fail with the OS error `errno` (e.g.
/// `libc::EIO`, `libc::ENOSYS`) until the guard is dropped.
#[cfg(any(test, feature = "fault-injection"))]
pub fn inject(fault: Fault, errno: i32) -> Injected {
    ACTIVE.with(|a| a.borrow_mut().push((fault, errno)));
    Injected(fault)
}

#[cfg(any(test, feature = "fault-injection"))]
impl Drop for Injected {
    fn drop(&mut self) {
        ACTIVE.with(|a| {
            let mut a = a.borrow_mut();
            if let Some(i) = a.iter().rposition(|&(f, _)| f == self.0) {
                a.remove(i);
            }
        });
    }
}

/// The error injected for `fault` on this thread, if any.
#[cfg(any(test, feature = "fault-injection"))]
pub(crate) fn injected(fault: Fault) -> Option<std::io::Error> {
    let errno = ACTIVE.with(|a| a.borrow().iter().rev().find(|&&(f, _)| f == fault).map(|&(_, e)| e));
    errno.map(std::io::Error::from_raw_os_error)
}

/// No fault is ever injected in a normal build.
#[cfg(not(any(test, feature = "fault-injection")))]
pub(crate) fn injected(_fault: Fault) -> Option<std::io::Error> {
    None
}
