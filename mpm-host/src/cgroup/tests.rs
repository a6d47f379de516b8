//! Fixture cgroup trees as the kernel shows them under systemd, Slurm, cgroup v1, a hybrid
//! set-up and none at all, and files that cannot be read.

use super::*;
use crate::hostfile::{fixture, Root};

const GIB: u64 = 1 << 30;
const MIB: u64 = 1 << 20;

/// Files of a level: `(level, name, text)`.
type Files<'a> = &'a [(&'a str, &'a str, &'a str)];

/// cgroup v2 mounted at `/sys/fs/cgroup`, this process in `cgroup`, and `files` (`name`
/// under the level `level`, relative to the mount) written beside.
pub(crate) fn v2_tree(cgroup: &str, files: Files) -> tempfile::TempDir {
    let mut all = vec![
        ("/proc/self/cgroup".to_string(), format!("0::{cgroup}\n")),
        (
            "/proc/self/mountinfo".to_string(),
            "22 1 0:21 / / rw - ext4 /dev/sda1 rw\n\
             25 21 0:22 / /sys/fs/cgroup rw,nosuid,nodev,noexec shared:4 - cgroup2 cgroup2 rw,nsdelegate\n"
                .to_string(),
        ),
    ];
    all.extend(files.iter().map(|(level, name, text)| (format!("/sys/fs/cgroup{level}/{name}"), text.to_string())));
    fixture(&all)
}

/// systemd's service cgroup: its limit and its file cache; its parent sets none.
#[test]
fn v2_as_systemd_makes_it() {
    let s = "/system.slice/foo.service";
    let dir = v2_tree(
        s,
        &[
            (s, "memory.max", "2147483648\n"),
            (s, "memory.current", "805306368\n"),
            (s, "memory.stat", "anon 536870912\nfile 268435456\ninactive_file 268435456\nactive_file 0\n"),
            (s, "cpu.max", "150000 100000\n"),
            ("/system.slice", "memory.max", "max\n"),
            ("/system.slice", "memory.current", "9999999999\n"),
            ("/system.slice", "cpu.max", "max 100000\n"),
        ],
    );
    let root = Root::at(dir.path());
    let mem = memory_limit(root).unwrap().unwrap();
    assert_eq!(mem, CgroupMemory { cgroup: s.into(), version: CgroupVersion::V2, limit: 2 * GIB, in_use: 512 * MIB });
    assert_eq!(mem.headroom(), 3 * GIB / 2);
    assert_eq!(
        mem.to_string(),
        "the cgroup /system.slice/foo.service allows 1.5 GiB more (its limit 2 GiB, 512 MiB in use)"
    );
    let cpu = cpu_quota_at(root).unwrap().unwrap();
    assert_eq!((cpu.cpus(), cpu.cgroup.as_str()), (1.5, s));
    assert_eq!(cpu.to_string(), "the cgroup /system.slice/foo.service allows 1.5 CPUs (150000 us every 100000 us)");
}

/// Slurm's task cgroup, five levels below the job's: the job sets the limit and the
/// quota; a level with a larger limit but less headroom binds.
#[test]
fn v2_as_slurm_makes_it() {
    let job = "/system.slice/slurmstepd.scope/job_42";
    let step = "/system.slice/slurmstepd.scope/job_42/step_0";
    let task = "/system.slice/slurmstepd.scope/job_42/step_0/user/task_0";
    let mut files = vec![
        (job, "memory.max", "4294967296"),
        (job, "memory.current", "1073741824"),
        (job, "cpu.max", "200000 100000"),
        (task, "memory.max", "max"),
        (task, "cpu.max", "max 100000"),
        ("/system.slice/slurmstepd.scope", "memory.max", "max"),
    ];
    let dir = v2_tree(task, &files);
    let root = Root::at(dir.path());
    let mem = memory_limit(root).unwrap().unwrap();
    assert_eq!((mem.cgroup.as_str(), mem.limit, mem.headroom()), (job, 4 * GIB, 3 * GIB));
    assert_eq!(cpu_quota_at(root).unwrap().unwrap().cgroup, job);
    files.extend([(step, "memory.max", "5368709120"), (step, "memory.current", "4831838208")]);
    let dir = v2_tree(task, &files);
    let mem = memory_limit(Root::at(dir.path())).unwrap().unwrap();
    assert_eq!((mem.cgroup.as_str(), mem.headroom()), (step, GIB / 2));
}

/// cgroup v1 files of the memory and cpu controllers, each on its own mount, with
/// `extra_mounts` and `extra_cgroups` lines.
fn v1_files(extra_mounts: &str, extra_cgroups: &str) -> Vec<(String, String)> {
    let session = "/user.slice/user-0.slice/session-1.scope";
    let (m, c) = ("/sys/fs/cgroup/memory", "/sys/fs/cgroup/cpu,cpuacct");
    let slice = "user.slice/user-0.slice";
    let cgroups = format!("11:memory:{session}\n4:cpu,cpuacct:{session}\n1:name=systemd:{session}\n{extra_cgroups}");
    let mounts = format!(
        "31 25 0:27 / {m} rw,nosuid shared:9 - cgroup cgroup rw,memory\n\
         32 25 0:28 / {c} rw,nosuid shared:10 - cgroup cgroup rw,cpu,cpuacct\n\
         33 25 0:29 / /sys/fs/cgroup/systemd rw - cgroup cgroup rw,xattr,name=systemd\n{extra_mounts}"
    );
    [
        ("/proc/self/cgroup".to_string(), cgroups.as_str()),
        ("/proc/self/mountinfo".to_string(), mounts.as_str()),
        (format!("{m}/memory.limit_in_bytes"), "9223372036854771712\n"),
        (format!("{m}{session}/memory.limit_in_bytes"), "9223372036854771712\n"),
        (format!("{m}{session}/memory.usage_in_bytes"), "1048576\n"),
        (format!("{m}/{slice}/memory.limit_in_bytes"), "1073741824\n"),
        (format!("{m}/{slice}/memory.usage_in_bytes"), "209715200\n"),
        (format!("{m}/{slice}/memory.stat"), "cache 0\ninactive_file 1\ntotal_inactive_file 104857600\n"),
        (format!("{c}{session}/cpu.cfs_quota_us"), "-1\n"),
        (format!("{c}/{slice}/cpu.cfs_quota_us"), "50000\n"),
        (format!("{c}/{slice}/cpu.cfs_period_us"), "100000\n"),
        (format!("{c}/cpu.cfs_quota_us"), "-1\n"),
    ]
    .into_iter()
    .map(|(p, t)| (p, t.to_string()))
    .collect()
}

/// cgroup v1: "no limit" as the kernel writes it is none; the user's slice binds.
#[test]
fn v1_with_controllers_on_separate_mounts() {
    let dir = fixture(&v1_files("", ""));
    let root = Root::at(dir.path());
    let slice = "/user.slice/user-0.slice";
    let mem = memory_limit(root).unwrap().unwrap();
    assert_eq!(mem, CgroupMemory { cgroup: slice.into(), version: CgroupVersion::V1, limit: GIB, in_use: 100 * MIB });
    let cpu = cpu_quota_at(root).unwrap().unwrap();
    assert_eq!((cpu.cpus(), cpu.cgroup.as_str(), cpu.version), (0.5, slice, CgroupVersion::V1));
    // "No limit" with 4 KiB pages, and with 64 KiB pages.
    for unlimited in ["9223372036854771712\n", "9223372036854710272\n"] {
        std::fs::write(root.join(format!("/sys/fs/cgroup/memory{slice}/memory.limit_in_bytes")), unlimited).unwrap();
        assert_eq!(memory_limit(root).unwrap(), None, "every level without a limit");
    }
}

/// A hybrid set-up (systemd's): the controllers on v1 mounts, an empty v2 hierarchy at
/// `/sys/fs/cgroup/unified`; the limits are read on v1.
#[test]
fn hybrid_reads_the_controllers_on_v1() {
    let v2 = "34 25 0:30 / /sys/fs/cgroup/unified rw - cgroup2 cgroup2 rw,nsdelegate\n";
    let dir = fixture(&v1_files(v2, "0::/user.slice/user-0.slice/session-1.scope\n"));
    let root = Root::at(dir.path());
    assert_eq!(own_cgroup(root, "memory").unwrap().unwrap().version, CgroupVersion::V1);
    assert_eq!(memory_limit(root).unwrap().unwrap().limit, GIB);
    assert_eq!(cpu_quota_at(root).unwrap().unwrap().cpus(), 0.5);
    assert_eq!(own_cgroup(root, "pids").unwrap().unwrap().mount_point, std::path::Path::new("/sys/fs/cgroup/unified"));
}

/// No cgroup at all (no `/proc/self/cgroup`), or cgroups that set no limit: none.
#[test]
fn no_cgroup_no_limit() {
    let dir = fixture(&[("/proc/meminfo", "MemAvailable: 1 kB\n")]);
    assert_eq!(memory_limit(Root::at(dir.path())).unwrap(), None);
    assert_eq!(cpu_quota_at(Root::at(dir.path())).unwrap(), None);
    let dir = v2_tree("/user.slice", &[("/user.slice", "memory.max", "max"), ("/user.slice", "cpu.max", "max 100000")]);
    assert_eq!(memory_limit(Root::at(dir.path())).unwrap(), None);
    assert_eq!(cpu_quota_at(Root::at(dir.path())).unwrap(), None);
}

/// A file that cannot be read, is not understood, or is missing beside a limit: an error
/// naming it, never a panic.
#[test]
fn unreadable_files_are_errors_naming_them() {
    let s = "/system.slice/foo.service";
    let cases: [(Files, &str); 5] = [
        (&[(s, "memory.max/x", "")], "foo.service/memory.max"),
        (&[(s, "memory.max", "lots")], "foo.service/memory.max"),
        (&[(s, "memory.max", "1024")], "foo.service/memory.current"),
        (
            &[(s, "memory.max", "1024"), (s, "memory.current", "1"), (s, "memory.stat", "inactive_file x")],
            "memory.stat",
        ),
        (&[(s, "cpu.max", "150000")], "foo.service/cpu.max"),
    ];
    for (files, named) in cases {
        let dir = v2_tree(s, files);
        let root = Root::at(dir.path());
        let err = memory_limit(root).and_then(|_| cpu_quota_at(root)).unwrap_err();
        assert!(err.to_string().contains(named), "{named}: {err}");
    }
}
