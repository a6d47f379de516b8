//! Where this process's cgroup is: the line of `/proc/self/cgroup` for a controller (cgroup
//! v1: `4:memory:/path`, the controllers of one hierarchy comma-separated; cgroup v2:
//! `0::/path`) and the mount of that hierarchy in `/proc/self/mountinfo` whose root holds
//! the path (a container without a cgroup namespace mounts its own cgroup as the root).
//!
//! A controller attached to a v1 hierarchy is read there (in a hybrid set-up the v2
//! hierarchy then has no files of it); otherwise the v2 hierarchy is read. No
//! `/proc/self/cgroup` (a kernel without cgroups), a hierarchy not mounted here, or a path
//! outside every mount of it: no cgroup is visible, and none bounds the process.

use std::path::PathBuf;

use crate::hostfile::{malformed, HostFileError, Root};

/// The cgroup interface a hierarchy has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CgroupVersion {
    /// Cgroup v1: one hierarchy per controller (or group of controllers).
    V1,
    /// Cgroup v2: the one unified hierarchy.
    V2,
}

/// This process's cgroup in the hierarchy of one controller, and the mount it is read
/// through.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OwnCgroup {
    /// The hierarchy's interface.
    pub version: CgroupVersion,
    /// The cgroup, as `/proc/self/cgroup` names it (`/system.slice/foo.service`).
    pub path: String,
    /// Where the hierarchy is mounted (`/sys/fs/cgroup/memory`).
    pub mount_point: PathBuf,
    /// The cgroup mounted there (`/` unless the mount shows a part of the hierarchy).
    pub mount_root: String,
}

/// One mount of `/proc/self/mountinfo`: the fields read here.
#[derive(Debug, PartialEq, Eq)]
struct Mount {
    root: String,
    point: String,
    fstype: String,
    options: String,
}

/// A mountinfo field with its octal escapes (`\040` for a space) decoded.
fn unescape(field: &str) -> String {
    let bytes = field.as_bytes();
    let mut out = Vec::with_capacity(bytes.len());
    let mut i = 0;
    while i < bytes.len() {
        let code = bytes.get(i + 1..i + 4).and_then(|d| u8::from_str_radix(std::str::from_utf8(d).ok()?, 8).ok());
        match (bytes[i], code) {
            (b'\\', Some(c)) => {
                out.push(c);
                i += 4;
            }
            (b, _) => {
                out.push(b);
                i += 1;
            }
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// A line of mountinfo: `id parent major:minor root point options [optional...] - fstype
/// source super-options`; `None` for a line not of that form.
fn parse_mount(line: &str) -> Option<Mount> {
    let fields: Vec<&str> = line.split_whitespace().collect();
    let dash = fields.iter().position(|&f| f == "-")?;
    (dash >= 6).then_some(())?;
    Some(Mount {
        root: unescape(fields[3]),
        point: unescape(fields[4]),
        fstype: fields.get(dash + 1)?.to_string(),
        options: fields.get(dash + 3)?.to_string(),
    })
}

/// Whether the cgroup `path` is `root` or below it.
fn holds(root: &str, path: &str) -> bool {
    root == "/" || path == root || path.strip_prefix(root).is_some_and(|rest| rest.starts_with('/'))
}

/// This process's cgroup for `controller` (`memory`, `cpu`), read under `root`; `None`
/// where no cgroup of it is visible (see the module's doc).
pub fn own_cgroup(root: Root<'_>, controller: &str) -> Result<Option<OwnCgroup>, HostFileError> {
    let Some(cgroups) = root.read("/proc/self/cgroup")? else { return Ok(None) };
    let mut v1 = None;
    let mut v2 = None;
    for line in cgroups.lines().filter(|l| !l.trim().is_empty()) {
        let mut parts = line.splitn(3, ':');
        let (Some(_id), Some(controllers), Some(path)) = (parts.next(), parts.next(), parts.next()) else {
            return Err(malformed(root.join("/proc/self/cgroup"), &cgroups, "lines id:controllers:path"));
        };
        if controllers.is_empty() {
            v2 = Some(path.to_string());
        } else if controllers.split(',').any(|c| c == controller) {
            v1 = Some(path.to_string());
        }
    }
    let (version, path, fstype) = match (v1, v2) {
        (Some(p), _) => (CgroupVersion::V1, p, "cgroup"),
        (None, Some(p)) => (CgroupVersion::V2, p, "cgroup2"),
        (None, None) => return Ok(None),
    };
    let Some(mountinfo) = root.read("/proc/self/mountinfo")? else { return Ok(None) };
    let mount = mountinfo.lines().filter_map(parse_mount).find(|m| {
        m.fstype == fstype
            && (version == CgroupVersion::V2 || m.options.split(',').any(|o| o == controller))
            && holds(&m.root, &path)
    });
    Ok(mount.map(|m| OwnCgroup { version, path, mount_point: PathBuf::from(m.point), mount_root: m.root }))
}

impl OwnCgroup {
    /// The cgroup and each of its ancestors up to the mount's root, this one first: its
    /// name and its folder (an absolute path, to be read under the same root).
    pub fn levels(&self) -> Vec<(String, PathBuf)> {
        let below = if self.mount_root == "/" { &self.path[..] } else { &self.path[self.mount_root.len()..] };
        let parts: Vec<&str> = below.split('/').filter(|p| !p.is_empty()).collect();
        (0..=parts.len())
            .rev()
            .map(|n| {
                let rel = parts[..n].join("/");
                let name = match (self.mount_root.as_str(), n) {
                    (r, 0) => r.to_string(),
                    ("/", _) => format!("/{rel}"),
                    (r, _) => format!("{r}/{rel}"),
                };
                (name, self.mount_point.join(rel))
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::hostfile::fixture;

    #[test]
    fn mountinfo_lines_are_read_with_their_escapes() {
        let line = "35 31 0:32 /docker/a\\040b /sys/fs/cgroup/memory rw,relatime shared:9 - cgroup cgroup rw,memory";
        let m = parse_mount(line).unwrap();
        assert_eq!((m.root.as_str(), m.point.as_str()), ("/docker/a b", "/sys/fs/cgroup/memory"));
        assert_eq!((m.fstype.as_str(), m.options.as_str()), ("cgroup", "rw,memory"));
        assert_eq!(parse_mount("garbage"), None);
        assert!(holds("/", "/a") && holds("/a", "/a") && holds("/a", "/a/b") && !holds("/a", "/ab"));
    }

    /// A mount showing a part of the hierarchy (a container without a cgroup namespace):
    /// the levels stop at its root, named as `/proc/self/cgroup` names them.
    #[test]
    fn a_partial_mount_shows_the_levels_below_its_root() {
        let dir = fixture(&[
            ("/proc/self/cgroup", "4:memory:/docker/abc/inner\n"),
            ("/proc/self/mountinfo", "35 31 0:32 /docker/abc /sys/fs/cgroup/memory rw - cgroup cgroup rw,memory\n"),
        ]);
        let own = own_cgroup(Root::at(dir.path()), "memory").unwrap().unwrap();
        assert_eq!(own.version, CgroupVersion::V1);
        let levels = own.levels();
        assert_eq!(
            levels,
            [
                ("/docker/abc/inner".to_string(), PathBuf::from("/sys/fs/cgroup/memory/inner")),
                ("/docker/abc".to_string(), PathBuf::from("/sys/fs/cgroup/memory")),
            ]
        );
        assert_eq!(own_cgroup(Root::at(dir.path()), "cpu").unwrap(), None, "cpu: no hierarchy");
    }

    /// A hierarchy not mounted here, or a path outside every mount of it: none visible.
    #[test]
    fn an_unmounted_hierarchy_is_not_visible() {
        let dir = fixture(&[
            ("/proc/self/cgroup", "4:memory:/elsewhere\n0::/user.slice\n"),
            ("/proc/self/mountinfo", "35 31 0:32 /docker/abc /sys/fs/cgroup/memory rw - cgroup cgroup rw,memory\n"),
        ]);
        assert_eq!(own_cgroup(Root::at(dir.path()), "memory").unwrap(), None);
        assert_eq!(own_cgroup(Root::at(dir.path()), "cpu").unwrap(), None, "no cgroup2 mount");
        let bad = fixture(&[("/proc/self/cgroup", "no colons here\n")]);
        let err = own_cgroup(Root::at(bad.path()), "memory").unwrap_err();
        assert!(err.to_string().contains("proc/self/cgroup"), "{err}");
    }
}
