//! The files of `/proc` and `/sys` that tell this process's limits, read through a root
//! folder: `/` for the real ones, a fixture tree in tests. A file that is not there is not an
//! error (the reader says what its absence means); one that is there but cannot be read or
//! understood is, naming the file.

use std::path::{Path, PathBuf};

/// A file of the host that cannot be read or is not understood.
#[derive(Debug, thiserror::Error)]
pub enum HostFileError {
    /// The file is there but cannot be read.
    #[error(
        "cannot read {path}: {source}; the memory and CPUs this process may use cannot be known without it: \
         make it readable to this user"
    )]
    Read {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The file holds what its reader does not understand.
    #[error(
        "{path} holds {text:?}, not {expected}; this system's format is not understood: report it with the \
         file's contents"
    )]
    Malformed {
        /// The file.
        path: PathBuf,
        /// What it holds (its first 200 characters).
        text: String,
        /// What was expected.
        expected: &'static str,
    },
}

/// The folder that stands for `/`.
#[derive(Debug, Clone, Copy)]
pub struct Root<'a>(&'a Path);

impl Root<'static> {
    /// The real `/`.
    pub fn real() -> Self {
        Root(Path::new("/"))
    }
}

impl<'a> Root<'a> {
    /// `dir` standing for `/` (a fixture tree).
    pub fn at(dir: &'a Path) -> Self {
        Root(dir)
    }

    /// The path of the absolute path `abs` under this root.
    pub fn join(&self, abs: impl AsRef<Path>) -> PathBuf {
        let abs = abs.as_ref();
        self.0.join(abs.strip_prefix("/").unwrap_or(abs))
    }

    /// The text of the file `abs` under this root; `None` when it is not there.
    pub fn read(&self, abs: impl AsRef<Path>) -> Result<Option<String>, HostFileError> {
        let path = self.join(abs);
        match std::fs::read_to_string(&path) {
            Ok(text) => Ok(Some(text)),
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => Ok(None),
            Err(source) => Err(HostFileError::Read { path, source }),
        }
    }

    /// The file `abs` read and parsed by `parse` (`None`: not understood, an error naming
    /// `expected`); `Ok(None)` when it is not there.
    pub fn parse<T>(
        &self,
        abs: impl AsRef<Path>,
        expected: &'static str,
        parse: impl FnOnce(&str) -> Option<T>,
    ) -> Result<Option<T>, HostFileError> {
        let abs = abs.as_ref();
        let Some(text) = self.read(abs)? else { return Ok(None) };
        match parse(text.trim()) {
            Some(v) => Ok(Some(v)),
            None => Err(malformed(self.join(abs), &text, expected)),
        }
    }

    /// [`Root::parse`] of a file that must be there: one that is not is an error too.
    pub fn parse_required<T>(
        &self,
        abs: impl AsRef<Path>,
        expected: &'static str,
        parse: impl FnOnce(&str) -> Option<T>,
    ) -> Result<T, HostFileError> {
        let abs = abs.as_ref();
        self.parse(abs, expected, parse)?
            .ok_or_else(|| HostFileError::Read { path: self.join(abs), source: std::io::ErrorKind::NotFound.into() })
    }
}

/// The error of the file `path` holding `text` where `expected` was due.
pub fn malformed(path: PathBuf, text: &str, expected: &'static str) -> HostFileError {
    HostFileError::Malformed { path, text: text.chars().take(200).collect(), expected }
}

/// A fixture tree: each `(absolute path, text)` written under a new temporary folder.
#[cfg(test)]
pub(crate) fn fixture<P: AsRef<str>, T: AsRef<str>>(files: &[(P, T)]) -> tempfile::TempDir {
    let dir = tempfile::tempdir().unwrap();
    for (path, text) in files {
        let path = Root::at(dir.path()).join(path.as_ref());
        std::fs::create_dir_all(path.parent().unwrap()).unwrap();
        std::fs::write(path, text.as_ref()).unwrap();
    }
    dir
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A file not there is `None`, one that cannot be read (a folder where a file is due:
    /// root reads through any permission) or not understood is an error naming it.
    #[test]
    fn absent_unreadable_and_malformed_files() {
        let dir = fixture(&[("/sys/x/memory.max", "12\n"), ("/sys/x/bad", "twelve"), ("/sys/x/dir/a", "")]);
        let root = Root::at(dir.path());
        let number = |s: &str| s.parse::<u64>().ok();
        assert_eq!(root.parse("/sys/x/memory.max", "a number", number).unwrap(), Some(12));
        assert_eq!(root.parse("/sys/x/missing", "a number", number).unwrap(), None);
        let err = root.parse_required("/sys/x/missing", "a number", number).unwrap_err();
        assert!(matches!(&err, HostFileError::Read { path, .. } if path.ends_with("sys/x/missing")), "{err}");
        let err = root.parse("/sys/x/bad", "a number", number).unwrap_err();
        assert!(matches!(&err, HostFileError::Malformed { path, .. } if path.ends_with("sys/x/bad")), "{err}");
        assert!(err.to_string().contains("\"twelve\"") && err.to_string().contains("a number"), "{err}");
        let err = root.read("/sys/x/dir").unwrap_err();
        assert!(matches!(&err, HostFileError::Read { path, .. } if path.ends_with("sys/x/dir")), "{err}");
        assert_eq!(Root::real().join("/proc/meminfo"), Path::new("/proc/meminfo"));
    }
}
