//! The record a bundle carries: `bundle.toml` at the root of the self-contained archive
//! `scripts/bundle.sh` makes, saying what its programs were built from. A bundle has no git
//! checkout, no `rustc` and no `Cargo.toml` to ask, so the manifest of a campaign run from
//! it takes the commit, the compiler and the Cargo profiles from here
//! ([`super::manifest::software_info`]).

use serde::Deserialize;
use std::path::Path;

/// The record's file name, at the bundle's root (the workspace `mpm-bench` runs in).
pub const BUNDLE_RECORD: &str = "bundle.toml";

/// What `bundle.toml` says (keys it does not list are ignored).
#[derive(Clone, Debug, Default, PartialEq, Deserialize)]
pub struct BundleRecord {
    /// The bundle's name, `mpm-bench-<version>-x86_64-linux`.
    #[serde(default)]
    pub name: String,
    /// The commit the programs were built from.
    pub commit: String,
    /// Whether tracked files had uncommitted changes then.
    #[serde(default)]
    pub dirty: bool,
    /// `rustc -vV` of the build, as [`super::manifest::SoftwareInfo::rustc`] says it.
    #[serde(default)]
    pub rustc: String,
    /// The workspace's Cargo profiles at the build (its `[profile.*]` tables).
    #[serde(default)]
    pub profile: toml::Table,
}

/// The record of the bundle rooted at `workspace`; `None` when there is none (a checkout), or
/// when the file cannot be read or parsed, which is said on standard error.
pub fn read(workspace: &Path) -> Option<BundleRecord> {
    let path = workspace.join(BUNDLE_RECORD);
    if !path.is_file() {
        return None;
    }
    let parsed = std::fs::read_to_string(&path)
        .map_err(|e| e.to_string())
        .and_then(|text| toml::from_str::<BundleRecord>(&text).map_err(|e| e.to_string()));
    match parsed {
        Ok(record) => Some(record),
        Err(e) => {
            eprintln!(
                "warning: {} is not a readable bundle record ({e}); the manifest records the software as unknown \
                 (unpack the bundle again to restore it)",
                path.display()
            );
            None
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_record_is_read_and_a_broken_one_is_none() {
        let dir = tempfile::tempdir().unwrap();
        assert_eq!(read(dir.path()), None);
        let text = "name = \"mpm-bench-0.1.0-x86_64-linux\"\ncommit = \"abc\"\ndirty = true\nglibc = \"2.34\"\n\
                    rustc = \"rustc 1.89.0\"\n\n[profile.o3]\ninherits = \"release\"\n";
        std::fs::write(dir.path().join(BUNDLE_RECORD), text).unwrap();
        let r = read(dir.path()).unwrap();
        assert_eq!((r.commit.as_str(), r.dirty, r.rustc.as_str()), ("abc", true, "rustc 1.89.0"));
        assert_eq!(r.profile["o3"].get("inherits").and_then(|v| v.as_str()), Some("release"));
        std::fs::write(dir.path().join(BUNDLE_RECORD), "commit = [").unwrap();
        assert_eq!(read(dir.path()), None);
    }
}
