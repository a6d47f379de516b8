//! Who holds a lock file of the fallback scheme ([`super::exclusive`]), and whether that
//! process can still be there: its program, host name, boot (the kernel's `boot_id`), pid
//! namespace, pid and the pid's start time (clock ticks after boot, `/proc/<pid>/stat`).
//!
//! A lock of this host, this boot and this pid namespace is stale when its pid is gone or
//! now another process (another start time); one of an earlier boot of this host is stale
//! (no process survives a reboot). One of another host, or of another pid namespace of this
//! host (another container, whose pids this process cannot see), cannot be judged from here
//! and is never taken over.

use std::path::Path;

/// The identity of a lock's owner, as its lock file holds it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Owner {
    /// The program (`mpm`, `mpm-bench`).
    pub program: String,
    /// The host name.
    pub host: String,
    /// The kernel's boot id.
    pub boot: String,
    /// The pid namespace (`pid:[inode]`).
    pub pidns: String,
    /// The process id.
    pub pid: u32,
    /// The process's start, clock ticks after boot.
    pub start: String,
}

/// Whether a lock's owner can still hold it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// The owner runs on this host.
    Live,
    /// The owner is gone: why.
    Stale(String),
    /// The owner cannot be judged from here: where it is.
    Elsewhere(String),
}

/// A file's first line of text, trimmed (empty when unreadable).
fn read_line(path: &str) -> String {
    std::fs::read_to_string(path).unwrap_or_default().lines().next().unwrap_or("").trim().to_string()
}

/// The start time of process `pid` (field 22 of `/proc/<pid>/stat`, after the command name
/// in parentheses, which may hold spaces), `None` when there is no such process.
pub fn start_of(pid: u32) -> Option<String> {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).ok()?;
    let after_name = &stat[stat.rfind(')')? + 1..];
    // Fields from the 3rd (state) on: the start time is the 22nd field of the line.
    after_name.split_whitespace().nth(19).map(str::to_string)
}

impl Owner {
    /// This process, running `program`.
    pub fn this(program: &str) -> Self {
        let pid = std::process::id();
        let pidns = std::fs::read_link("/proc/self/ns/pid").map(|p| p.display().to_string()).unwrap_or_default();
        Self {
            program: program.to_string(),
            host: read_line("/proc/sys/kernel/hostname"),
            boot: read_line("/proc/sys/kernel/random/boot_id"),
            pidns,
            pid,
            start: start_of(pid).unwrap_or_default(),
        }
    }

    /// `mpm-bench pid 1234 on node7`.
    pub fn describe(&self) -> String {
        format!("{} pid {} on {}", self.program, self.pid, self.host)
    }

    /// The lock file's text: [`Owner::describe`], then one `key=value` line per field.
    pub fn note(&self) -> String {
        format!(
            "{}\nprogram={}\nhost={}\nboot={}\npidns={}\npid={}\nstart={}\n",
            self.describe(),
            self.program,
            self.host,
            self.boot,
            self.pidns,
            self.pid,
            self.start
        )
    }

    /// The owner a lock file's text names; `None` for a text not written by
    /// [`Owner::note`] (or not yet completely).
    pub fn parse(text: &str) -> Option<Self> {
        let field =
            |key: &str| text.lines().find_map(|l| l.strip_prefix(key)?.strip_prefix('=')).map(|v| v.trim().to_string());
        let owner = Self {
            program: field("program")?,
            host: field("host")?,
            boot: field("boot")?,
            pidns: field("pidns")?,
            pid: field("pid")?.parse().ok()?,
            start: field("start")?,
        };
        (!owner.host.is_empty() && !owner.start.is_empty()).then_some(owner)
    }

    /// Whether this owner can still hold its lock, judged by the process `here`.
    pub fn judge(&self, here: &Owner) -> Verdict {
        if self.host != here.host {
            return Verdict::Elsewhere(format!("on another host, {}", self.host));
        }
        if self.boot != here.boot {
            return Verdict::Stale(format!("{} has restarted since", self.host));
        }
        if self.pidns != here.pidns {
            return Verdict::Elsewhere(format!("in another pid namespace ({}) of this host", self.pidns));
        }
        if !Path::new("/proc/self/stat").exists() {
            return Verdict::Elsewhere("where /proc, which tells the processes of this host, is not mounted".into());
        }
        match start_of(self.pid) {
            None => Verdict::Stale(format!("pid {} has ended", self.pid)),
            Some(start) if start != self.start => {
                Verdict::Stale(format!("pid {} has ended (it is now another process)", self.pid))
            }
            Some(_) => Verdict::Live,
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// This process is named in full, its note reads back, and it judges itself live.
    #[test]
    fn this_process_reads_back_and_is_live() {
        let me = Owner::this("mpm");
        assert!(!me.host.is_empty() && !me.boot.is_empty() && !me.start.is_empty(), "{me:?}");
        assert_eq!(Owner::parse(&me.note()), Some(me.clone()));
        assert_eq!(me.judge(&me), Verdict::Live);
        assert_eq!(me.describe(), format!("mpm pid {} on {}", me.pid, me.host));
    }

    /// A text that is not a whole note (being written, or another file) names no owner.
    #[test]
    fn a_partial_note_names_no_owner() {
        let me = Owner::this("mpm");
        let note = me.note();
        for cut in [0, 10, note.find("start=").unwrap()] {
            assert_eq!(Owner::parse(&note[..cut]), None, "{:?}", &note[..cut]);
        }
        assert_eq!(Owner::parse(&note.replace(&format!("pid={}", me.pid), "pid=x")), None);
    }

    /// Another host or pid namespace cannot be judged; another boot, a pid gone or reused
    /// is stale.
    #[test]
    fn owners_are_judged_by_host_boot_namespace_pid_and_start() {
        let me = Owner::this("mpm");
        let other = |f: fn(&mut Owner)| {
            let mut o = me.clone();
            f(&mut o);
            o.judge(&me)
        };
        assert!(matches!(other(|o| o.host = "node7".into()), Verdict::Elsewhere(w) if w.contains("node7")));
        assert!(matches!(other(|o| o.pidns = "pid:[1]".into()), Verdict::Elsewhere(w) if w.contains("pid:[1]")));
        assert!(matches!(other(|o| o.boot = "b".into()), Verdict::Stale(w) if w.contains("restarted")));
        assert!(matches!(other(|o| o.start = "0".into()), Verdict::Stale(w) if w.contains("another process")));
        let mut gone = me.clone();
        gone.pid = ended_pid();
        assert!(matches!(gone.judge(&me), Verdict::Stale(w) if w.contains("has ended")));
    }

    /// The pid of a child process that has ended (and been reaped).
    pub(crate) fn ended_pid() -> u32 {
        let mut child = std::process::Command::new("true").spawn().unwrap();
        let pid = child.id();
        child.wait().unwrap();
        pid
    }
}
