//! Where each worker of a run is pinned: the policies, the placement of `n` workers on a
//! [`Machine`], and the table `mpm-bench topology` prints.
//!
//! # Placement policies (OpenMP vocabulary)
//! Worker `j` of a run with `n` threads gets the `j`-th entry of an ordered list of PUs:
//! * `close` (compact): fill package 0's physical cores, then package 1's, ...; the paper's
//!   8-thread runs filled one quad-core socket before using the second.
//! * `spread`: alternate packages: core 0 of package 0, core 0 of package 1, core 1 of
//!   package 0, ...
//! * an explicit CPU list (`0,2,4-7`): worker `j` gets the `j`-th listed CPU.
//! * `none`: the workers are not pinned; the OS places them.
//!
//! For `close` and `spread`, every physical core gets a worker before any SMT sibling does.
//! More threads than PUs in the list wrap around (worker `j` gets entry `j mod len`), and the
//! placement is marked *oversubscribed*: such a run measures time sharing, not scaling.

use super::topology::{format_cpu_list, Machine};
use anyhow::{bail, Context, Result};
use mpm_cli::pinning::parse_cpu_list;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::fmt::Write as _;
use std::str::FromStr;

/// Thread counts of the paper's protocol, shown by `mpm-bench topology`.
pub const PAPER_THREADS: [usize; 5] = [1, 2, 4, 6, 8];

/// How workers are placed on CPUs.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PinPolicy {
    /// Fill a package's physical cores before the next package's.
    Close,
    /// Alternate packages.
    Spread,
    /// Worker `j` gets the `j`-th CPU of the list (OS indices).
    List(Vec<usize>),
    /// Not pinned.
    None,
}

impl PinPolicy {
    /// Short label used in CSV rows and campaign ids: `close`, `spread`, `none`, or the
    /// list itself (`0-3`, `0,2`).
    pub fn label(&self) -> String {
        match self {
            PinPolicy::Close => "close".into(),
            PinPolicy::Spread => "spread".into(),
            PinPolicy::None => "none".into(),
            PinPolicy::List(l) => format_cpu_list(l),
        }
    }
}

impl fmt::Display for PinPolicy {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.label())
    }
}

impl FromStr for PinPolicy {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        match s.trim().to_ascii_lowercase().as_str() {
            "close" | "compact" => Ok(PinPolicy::Close),
            "spread" | "scatter" => Ok(PinPolicy::Spread),
            "none" | "off" => Ok(PinPolicy::None),
            other => {
                let list = other.strip_prefix("list:").unwrap_or(other);
                if list.is_empty() || !list.starts_with(|c: char| c.is_ascii_digit()) {
                    bail!("unknown pinning policy '{s}': use close, spread, none, or a CPU list such as 0,1 or 0-3");
                }
                Ok(PinPolicy::List(parse_cpu_list(list).with_context(|| format!("bad CPU list '{list}'"))?))
            }
        }
    }
}

impl Serialize for PinPolicy {
    fn serialize<S: serde::Serializer>(&self, ser: S) -> Result<S::Ok, S::Error> {
        ser.serialize_str(&self.label())
    }
}

impl<'de> Deserialize<'de> for PinPolicy {
    fn deserialize<D: serde::Deserializer<'de>>(de: D) -> Result<Self, D::Error> {
        let s = String::deserialize(de)?;
        s.parse().map_err(|e: anyhow::Error| serde::de::Error::custom(format!("{e:#}")))
    }
}

/// The CPUs of one run's workers.
#[derive(Clone, Debug, PartialEq, Eq, Serialize)]
pub struct Placement {
    /// CPU (OS index) of worker `j`; empty for [`PinPolicy::None`].
    pub cpus: Vec<usize>,
    /// More threads than the policy's distinct CPUs or than usable PUs.
    pub oversubscribed: bool,
}

impl Machine {
    /// The ordered PU list of a policy (`None` for [`PinPolicy::None`]). Physical cores come
    /// before SMT siblings for `close` and `spread`.
    pub fn order(&self, policy: &PinPolicy) -> Option<Vec<usize>> {
        let smt = self.smt_width();
        match policy {
            PinPolicy::None => None,
            PinPolicy::List(l) => Some(l.clone()),
            PinPolicy::Close => {
                let mut out = Vec::new();
                for level in 0..smt {
                    for pkg in &self.packages {
                        out.extend(pkg.cores.iter().filter_map(|c| c.pus.get(level).copied()));
                    }
                }
                Some(out)
            }
            PinPolicy::Spread => {
                let mut out = Vec::new();
                let max_cores = self.packages.iter().map(|p| p.cores.len()).max().unwrap_or(0);
                for level in 0..smt {
                    for k in 0..max_cores {
                        for pkg in &self.packages {
                            if let Some(pu) = pkg.cores.get(k).and_then(|c| c.pus.get(level)) {
                                out.push(*pu);
                            }
                        }
                    }
                }
                Some(out)
            }
        }
    }

    /// Check that every CPU of an explicit list is a usable PU of this machine.
    pub fn check_policy(&self, policy: &PinPolicy) -> Result<()> {
        if let PinPolicy::List(l) = policy {
            if l.is_empty() {
                bail!("the CPU list is empty");
            }
            let usable = self.usable_pus();
            let bad: Vec<usize> = l.iter().copied().filter(|c| !usable.contains(c)).collect();
            if !bad.is_empty() {
                bail!(
                    "CPU list {} names CPU(s) {} that this process cannot use (usable: {})",
                    format_cpu_list(l),
                    format_cpu_list(&bad),
                    format_cpu_list(&usable)
                );
            }
        }
        Ok(())
    }

    /// Where the `threads` workers of a run go under `policy`. Wraps around (and marks the
    /// placement oversubscribed) when there are more threads than CPUs to give.
    pub fn place(&self, policy: &PinPolicy, threads: usize) -> Result<Placement> {
        if threads == 0 {
            bail!("a run needs at least one thread");
        }
        self.check_policy(policy)?;
        let usable = self.usable_pus().len().max(1);
        match self.order(policy) {
            None => Ok(Placement { cpus: Vec::new(), oversubscribed: threads > usable }),
            Some(order) => {
                if order.is_empty() {
                    bail!("no usable CPU to pin to");
                }
                let mut distinct = order.clone();
                distinct.sort_unstable();
                distinct.dedup();
                let cpus: Vec<usize> = (0..threads).map(|j| order[j % order.len()]).collect();
                let mut used = cpus.clone();
                used.sort_unstable();
                used.dedup();
                Ok(Placement { oversubscribed: threads > usable || used.len() < threads, cpus })
            }
        }
    }

    /// Table of the CPU each worker gets for each thread count under each policy.
    pub fn placement_table(&self, threads: &[usize], policies: &[PinPolicy]) -> Result<String> {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "Placement: CPU (OS index) of worker 0, 1, ... ; physical cores before SMT siblings;\n\
             '*' = oversubscribed (more threads than usable PUs: rows are flagged, not scaling)"
        );
        let mut cols: Vec<Vec<String>> = Vec::new();
        for p in policies {
            let mut col = vec![p.label()];
            for &t in threads {
                let pl = self.place(p, t)?;
                let mut cell = if matches!(p, PinPolicy::None) {
                    "(OS decides)".to_string()
                } else {
                    pl.cpus.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(",")
                };
                if pl.oversubscribed {
                    cell.push_str(" *");
                }
                col.push(cell);
            }
            cols.push(col);
        }
        let widths: Vec<usize> = cols.iter().map(|c| c.iter().map(|x| x.len()).max().unwrap_or(0) + 2).collect();
        let _ = write!(s, "{:<9}", "threads");
        for (c, w) in cols.iter().zip(&widths) {
            let _ = write!(s, "{:<w$}", c[0], w = *w);
        }
        s = s.trim_end().to_string();
        s.push('\n');
        for (r, t) in threads.iter().enumerate() {
            let _ = write!(s, "{t:<9}");
            for (c, w) in cols.iter().zip(&widths) {
                let _ = write!(s, "{:<w$}", c[r + 1], w = *w);
            }
            s = s.trim_end().to_string();
            s.push('\n');
        }
        Ok(s)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::machine::topology::export_xml;

    #[test]
    fn cpu_lists_round_trip() {
        assert_eq!(parse_cpu_list("0,2,4-7").unwrap(), vec![0, 2, 4, 5, 6, 7]);
        assert_eq!(format_cpu_list(&[0, 2, 4, 5, 6, 7]), "0,2,4-7");
        assert_eq!(format_cpu_list(&[0, 1]), "0,1");
        assert!(parse_cpu_list("0,,1").is_err());
        assert!(parse_cpu_list("3-1").is_err());
        assert!(parse_cpu_list("a").is_err());
        assert!("bogus".parse::<PinPolicy>().is_err());
        assert_eq!("0-1".parse::<PinPolicy>().unwrap(), PinPolicy::List(vec![0, 1]));
        assert_eq!("compact".parse::<PinPolicy>().unwrap(), PinPolicy::Close);
    }

    #[test]
    fn two_sockets_with_smt() {
        let m = Machine::synthetic("pack:2 core:4 pu:2").unwrap();
        assert_eq!(m.num_packages(), 2);
        assert_eq!(m.num_cores(), 8);
        assert_eq!(m.usable_pus().len(), 16);
        let close = m.place(&PinPolicy::Close, 8).unwrap();
        let spread = m.place(&PinPolicy::Spread, 4).unwrap();
        // Close fills package 0's four cores first; spread alternates packages.
        let pkg_of = |pu: usize| m.packages.iter().position(|p| p.cores.iter().any(|c| c.pus.contains(&pu))).unwrap();
        let close_pkgs: Vec<usize> = close.cpus.iter().map(|&c| pkg_of(c)).collect();
        assert_eq!(close_pkgs, vec![0, 0, 0, 0, 1, 1, 1, 1]);
        let spread_pkgs: Vec<usize> = spread.cpus.iter().map(|&c| pkg_of(c)).collect();
        assert_eq!(spread_pkgs, vec![0, 1, 0, 1]);
        // No SMT sibling before every core has a worker.
        let core_of =
            |pu: usize| m.packages.iter().flat_map(|p| p.cores.iter()).position(|c| c.pus.contains(&pu)).unwrap();
        let mut cores: Vec<usize> = close.cpus.iter().map(|&c| core_of(c)).collect();
        cores.sort_unstable();
        cores.dedup();
        assert_eq!(cores.len(), 8);
        assert!(!close.oversubscribed);
        let sixteen = m.place(&PinPolicy::Close, 16).unwrap();
        assert!(!sixteen.oversubscribed);
        assert!(m.place(&PinPolicy::Close, 17).unwrap().oversubscribed);
    }

    #[test]
    fn wrap_around_marks_oversubscription() {
        let m = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let p = m.place(&PinPolicy::Close, 4).unwrap();
        assert_eq!(p.cpus.len(), 4);
        assert_eq!(p.cpus[0], p.cpus[2]);
        assert!(p.oversubscribed);
        assert!(!m.place(&PinPolicy::Spread, 2).unwrap().oversubscribed);
        assert!(m.place(&PinPolicy::None, 3).unwrap().oversubscribed);
        assert!(m.place(&PinPolicy::None, 3).unwrap().cpus.is_empty());
        // A list shorter than the thread count wraps too.
        let l = m.place(&PinPolicy::List(vec![0]), 2).unwrap();
        assert_eq!(l.cpus, vec![0, 0]);
        assert!(l.oversubscribed);
        assert!(m.place(&PinPolicy::List(vec![7]), 1).is_err());
        assert!(m.place(&PinPolicy::Close, 0).is_err());
    }

    #[test]
    fn this_host_is_readable() {
        let m = Machine::detect().unwrap();
        assert!(!m.usable_pus().is_empty());
        assert!(m.is_this_system);
        assert!(m.describe().contains("Package"));
        assert!(export_xml().unwrap().contains("<topology"));
        let table = m.placement_table(&PAPER_THREADS, &[PinPolicy::Close, PinPolicy::Spread, PinPolicy::None]).unwrap();
        assert!(table.contains("close"));
    }
}
