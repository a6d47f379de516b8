//! Where each worker of a run is pinned: OpenMP places and `proc_bind` policies, the
//! placement of `n` workers on a [`Machine`], and the table `mpm-bench topology` prints.
//!
//! # Places and binding, as OpenMP 5.2 defines them
//! A policy is a *place list* (`--places`, OpenMP's `OMP_PLACES` abstract names) and a
//! *binding* (`--bind`, OpenMP's `OMP_PROC_BIND`):
//!
//! * places: `threads` (one place per hardware thread), `cores` (one per physical core, with
//!   its SMT siblings; the default), `ll_caches` (the cores sharing one last-level cache),
//!   `numa_domains` (the cores of one NUMA node), `sockets` (the cores of one package). The
//!   list is in hwloc's logical (topology) order, as LLVM's libomp orders it; the order of
//!   abstract names is implementation defined in the standard.
//! * `close`: with `T <= P` threads on `P` places, thread `i` goes to place `i` (the primary
//!   thread, 0, sits on the first place, where the initial thread is bound). With `T > P`,
//!   place `p` gets `S_p` threads with consecutive numbers, `floor(T/P) <= S_p <=
//!   ceil(T/P)`; the first `T mod P` places get the extra thread (the standard leaves which
//!   ones to the implementation).
//! * `spread`: with `T <= P` the place list is split into `T` subpartitions of consecutive
//!   places, the first `P mod T` of them one place larger (`ceil(P/T)`, the others
//!   `floor(P/T)`, as libgomp splits), and thread `j` goes to the first place of
//!   subpartition `j`. With `T > P` every place is its own subpartition and threads are
//!   distributed as for `close`.
//! * `primary` (OpenMP 5.1's name for `master`): every thread on the primary thread's place.
//! * an explicit CPU list (`0,2,4-7`): worker `j` gets the `j`-th listed CPU;
//! * `none`: the workers are not pinned; the OS places them.
//!
//! OpenMP binds a thread to its whole place; `mpm` pins each worker to one CPU. The `k`-th
//! worker assigned to a place gets the place's `k`-th PU (wrapping), the place's PUs listed
//! first-hardware-thread-of-every-core, then the SMT siblings. So `close` over `sockets`
//! with 4 threads on a quad-core socket uses its four cores, as the OS would.
//!
//! More workers than usable PUs, or two workers on one CPU, mark the placement
//! *oversubscribed*: such a run measures time sharing, not scaling.
//!
//! Labels (CSV `pin_policy`, run keys, campaign ids): `close`, `spread`, `primary` over
//! `cores`; `spread@numa_domains` for other places; `none`; a CPU list. The old names
//! `compact` (= `close`), `scatter` (= `spread`), `master` (= `primary`), `off` (= `none`) are
//! accepted. Before the places existed, `spread` alternated sockets (0,4,1,5 on 2 x 4 cores);
//! it now means OpenMP's spread over cores (0,2,4,6).

use super::topology::{format_cpu_list, Core, Machine};
use anyhow::{bail, Context, Result};
use mpm_host::pinning::parse_cpu_list;
use serde::{Deserialize, Serialize};
use std::fmt;
use std::fmt::Write as _;
use std::str::FromStr;

/// Thread counts of the paper's protocol, shown by `mpm-bench topology`.
pub const PAPER_THREADS: [usize; 5] = [1, 2, 4, 6, 8];

/// OpenMP's `OMP_PLACES` abstract names.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Places {
    /// One place per hardware thread (PU).
    #[serde(alias = "pus")]
    Threads,
    /// One place per physical core (its SMT siblings together).
    #[default]
    Cores,
    /// The cores sharing one last-level cache.
    #[serde(alias = "llc")]
    LlCaches,
    /// The cores of one NUMA node.
    #[serde(alias = "numa")]
    NumaDomains,
    /// The cores of one package (socket).
    #[serde(alias = "packages")]
    Sockets,
}

impl Places {
    /// Every place kind, finest first.
    pub const ALL: [Places; 5] =
        [Places::Threads, Places::Cores, Places::LlCaches, Places::NumaDomains, Places::Sockets];

    /// The OpenMP name: `threads`, `cores`, `ll_caches`, `numa_domains`, `sockets`.
    pub fn name(self) -> &'static str {
        match self {
            Places::Threads => "threads",
            Places::Cores => "cores",
            Places::LlCaches => "ll_caches",
            Places::NumaDomains => "numa_domains",
            Places::Sockets => "sockets",
        }
    }
}

impl fmt::Display for Places {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

impl FromStr for Places {
    type Err = anyhow::Error;

    fn from_str(s: &str) -> Result<Self> {
        Ok(match s.trim().to_ascii_lowercase().as_str() {
            "threads" | "pus" => Places::Threads,
            "cores" => Places::Cores,
            "ll_caches" | "llc" => Places::LlCaches,
            "numa_domains" | "numa" => Places::NumaDomains,
            "sockets" | "packages" => Places::Sockets,
            _ => bail!("unknown places '{s}': use threads, cores, ll_caches, numa_domains or sockets"),
        })
    }
}

/// OpenMP's `proc_bind` policies (those that bind).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Bind {
    /// Consecutive threads on consecutive places.
    Close,
    /// Threads spread evenly over the place list (subpartitions).
    Spread,
    /// Every thread on the primary thread's place.
    Primary,
}

impl Bind {
    /// Every binding policy.
    pub const ALL: [Bind; 3] = [Bind::Close, Bind::Spread, Bind::Primary];

    /// `close`, `spread`, `primary`.
    pub fn name(self) -> &'static str {
        match self {
            Bind::Close => "close",
            Bind::Spread => "spread",
            Bind::Primary => "primary",
        }
    }

    /// The place (index into a list of `places` places) of each of `threads` threads, the
    /// primary thread on place 0, exactly as OpenMP 5.2 assigns them (see the module page).
    pub fn assign(self, places: usize, threads: usize) -> Vec<usize> {
        if places == 0 {
            return Vec::new();
        }
        match self {
            Bind::Primary => vec![0; threads],
            Bind::Spread if threads <= places => {
                // T subpartitions: the first P mod T have ceil(P/T) places, the rest floor.
                let (s, rest) = (places / threads, places % threads);
                (0..threads).map(|j| j * s + j.min(rest)).collect()
            }
            // close (any T), spread with T > P: S_p consecutive threads on place p.
            Bind::Close | Bind::Spread => {
                if threads <= places {
                    return (0..threads).collect();
                }
                let (s, rest) = (threads / places, threads % places);
                (0..places).flat_map(|p| std::iter::repeat_n(p, s + usize::from(p < rest))).collect()
            }
        }
    }
}

/// How workers are placed on CPUs.
#[derive(Clone, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum PinPolicy {
    /// OpenMP binding over a place list.
    Bind(Bind, Places),
    /// Worker `j` gets the `j`-th CPU of the list (OS indices).
    List(Vec<usize>),
    /// Not pinned.
    None,
}

impl PinPolicy {
    /// `close` over cores: the paper's placement (one socket filled before the next).
    pub const CLOSE: PinPolicy = PinPolicy::Bind(Bind::Close, Places::Cores);
    /// `spread` over cores.
    pub const SPREAD: PinPolicy = PinPolicy::Bind(Bind::Spread, Places::Cores);
    /// `primary` over cores.
    pub const PRIMARY: PinPolicy = PinPolicy::Bind(Bind::Primary, Places::Cores);

    /// Short label used in CSV rows and campaign ids: `close`, `spread@threads`, `none`, or
    /// the list itself (`0-3`, `0,2`).
    pub fn label(&self) -> String {
        match self {
            PinPolicy::Bind(b, Places::Cores) => b.name().into(),
            PinPolicy::Bind(b, p) => format!("{}@{}", b.name(), p.name()),
            PinPolicy::None => "none".into(),
            PinPolicy::List(l) => format_cpu_list(l),
        }
    }

    /// Parse a `--bind` value (`close`, `spread@sockets`, `none`, a CPU list); a binding
    /// without `@places` takes `places`.
    pub fn parse_with(s: &str, places: Places) -> Result<Self> {
        let lower = s.trim().to_ascii_lowercase();
        let (bind, explicit) = match lower.split_once('@') {
            Some((b, p)) => (b, Some(p.parse::<Places>()?)),
            None => (lower.as_str(), None),
        };
        let b = match bind {
            "close" | "compact" => Bind::Close,
            "spread" | "scatter" => Bind::Spread,
            "primary" | "master" => Bind::Primary,
            "none" | "off" | "false" if explicit.is_none() => return Ok(PinPolicy::None),
            other => {
                let list = other.strip_prefix("list:").unwrap_or(other);
                if explicit.is_some() || list.is_empty() || !list.starts_with(|c: char| c.is_ascii_digit()) {
                    bail!("unknown binding '{s}': use close, spread, primary (optionally @places, e.g. spread@sockets), none, or a CPU list such as 0,1 or 0-3");
                }
                return Ok(PinPolicy::List(parse_cpu_list(list).with_context(|| format!("bad CPU list '{list}'"))?));
            }
        };
        Ok(PinPolicy::Bind(b, explicit.unwrap_or(places)))
    }

    /// The same policy over other places (lists and `none` are unchanged).
    pub fn with_places(&self, places: Places) -> Self {
        match self {
            PinPolicy::Bind(b, _) => PinPolicy::Bind(*b, places),
            other => other.clone(),
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
        PinPolicy::parse_with(s, Places::Cores)
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
    /// More threads than usable PUs, or two workers on one CPU.
    pub oversubscribed: bool,
}

/// The PUs of a group of cores: every core's first hardware thread, then the second ones.
fn pus_of_cores(cores: &[&Core]) -> Vec<usize> {
    let width = cores.iter().map(|c| c.pus.len()).max().unwrap_or(0);
    (0..width).flat_map(|level| cores.iter().filter_map(move |c| c.pus.get(level).copied())).collect()
}

/// Group `cores` by the PU sets `sets` (NUMA nodes, last-level caches): a core belongs to the
/// set holding its first PU. `None` when the sets do not cover every core (unknown layout).
fn group_cores<'a>(cores: &[&Core], sets: impl Iterator<Item = &'a [usize]>) -> Option<Vec<Vec<usize>>> {
    let mut covered = 0;
    let mut out = Vec::new();
    for set in sets {
        let members: Vec<&Core> =
            cores.iter().copied().filter(|c| c.pus.first().is_some_and(|p| set.contains(p))).collect();
        covered += members.len();
        if !members.is_empty() {
            out.push(pus_of_cores(&members));
        }
    }
    (covered == cores.len() && !out.is_empty()).then_some(out)
}

impl Machine {
    /// The place list of an OpenMP abstract name: each place's usable PUs (first hardware
    /// thread of every core, then the siblings), places in hwloc's logical order. Without
    /// NUMA or cache information (some synthetic topologies), `numa_domains` and
    /// `ll_caches` fall back to `sockets`.
    pub fn places(&self, kind: Places) -> Vec<Vec<usize>> {
        let cores: Vec<&Core> = self.packages.iter().flat_map(|p| p.cores.iter()).collect();
        let sockets = || self.packages.iter().map(|p| pus_of_cores(&p.cores.iter().collect::<Vec<_>>())).collect();
        match kind {
            Places::Threads => self.usable_pus().into_iter().map(|p| vec![p]).collect(),
            Places::Cores => cores.iter().map(|c| c.pus.clone()).collect(),
            Places::Sockets => sockets(),
            Places::NumaDomains => {
                group_cores(&cores, self.numa_nodes.iter().map(|n| n.cpus.as_slice())).unwrap_or_else(sockets)
            }
            Places::LlCaches => group_cores(&cores, self.ll_caches.iter().map(Vec::as_slice)).unwrap_or_else(sockets),
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

    /// Where the `threads` workers of a run go under `policy`: OpenMP's assignment of
    /// threads to places, then the `k`-th worker of a place on the place's `k`-th PU.
    pub fn place(&self, policy: &PinPolicy, threads: usize) -> Result<Placement> {
        if threads == 0 {
            bail!("a run needs at least one thread");
        }
        self.check_policy(policy)?;
        let usable = self.usable_pus().len().max(1);
        let cpus: Vec<usize> = match policy {
            PinPolicy::None => return Ok(Placement { cpus: Vec::new(), oversubscribed: threads > usable }),
            PinPolicy::List(l) => (0..threads).map(|j| l[j % l.len()]).collect(),
            PinPolicy::Bind(bind, kind) => {
                let places = self.places(*kind);
                if places.iter().all(Vec::is_empty) {
                    bail!("no usable CPU to pin to");
                }
                let mut taken = vec![0usize; places.len()];
                bind.assign(places.len(), threads)
                    .into_iter()
                    .map(|p| {
                        let cpu = places[p][taken[p] % places[p].len()];
                        taken[p] += 1;
                        cpu
                    })
                    .collect()
            }
        };
        let mut used = cpus.clone();
        used.sort_unstable();
        used.dedup();
        Ok(Placement { oversubscribed: threads > usable || used.len() < threads, cpus })
    }

    /// The placement of `ranks` MPI ranks of `threads` workers each under `policy`: the
    /// policy places all ranks x threads workers; with several ranks the result is that CPU
    /// set ascending without repeats (the launcher's affinity mask, which `mpm`'s ranks slice
    /// in rank order: rank r on the CPUs r x threads .. r x threads + threads - 1 when it has
    /// room for every worker). Oversubscribed as for one process of ranks x threads workers.
    pub fn place_ranks(&self, policy: &PinPolicy, ranks: usize, threads: usize) -> Result<Placement> {
        let mut p = self.place(policy, ranks * threads)?;
        if ranks > 1 {
            p.cpus.sort_unstable();
            p.cpus.dedup();
        }
        Ok(p)
    }

    /// Each rank's CPUs under [`Machine::place_ranks`] as `mpm` takes them from the mask:
    /// consecutive slices when the mask has room for every worker, else shared in turn.
    pub fn rank_slices(&self, policy: &PinPolicy, ranks: usize, threads: usize) -> Result<Vec<Vec<usize>>> {
        let mask = self.place_ranks(policy, ranks, threads)?.cpus;
        if mask.is_empty() {
            return Ok(vec![Vec::new(); ranks]);
        }
        Ok((0..ranks).map(|r| (0..threads).map(|j| mask[(r * threads + j) % mask.len()]).collect()).collect())
    }

    /// Table of the CPU each worker gets for each thread count under each policy, after the
    /// place lists the policies use.
    pub fn placement_table(&self, threads: &[usize], policies: &[PinPolicy]) -> Result<String> {
        let mut s = String::new();
        let mut kinds: Vec<Places> =
            policies.iter().filter_map(|p| if let PinPolicy::Bind(_, k) = p { Some(*k) } else { None }).collect();
        kinds.sort_unstable();
        kinds.dedup();
        for k in kinds {
            let list: Vec<String> = self.places(k).iter().map(|p| format!("{{{}}}", format_cpu_list(p))).collect();
            let _ = writeln!(s, "Places {k} ({}): {}", list.len(), list.join(","));
        }
        let _ = writeln!(
            s,
            "Placement (OpenMP proc_bind over the places): CPU (OS index) of worker 0, 1, ... ;\n\
             '*' = oversubscribed (more threads than usable PUs, or two workers on one CPU: rows are flagged, not scaling)"
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
        for r in 0..=threads.len() {
            let head = if r == 0 { "threads".to_string() } else { threads[r - 1].to_string() };
            let _ = write!(s, "{head:<9}");
            for (c, w) in cols.iter().zip(&widths) {
                let _ = write!(s, "{:<w$}", c[r], w = *w);
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

    /// CPUs of each thread count in `counts` under `policy` on `m`.
    fn cpus(m: &Machine, policy: &PinPolicy, counts: &[usize]) -> Vec<Vec<usize>> {
        counts.iter().map(|&t| m.place(policy, t).unwrap().cpus).collect()
    }

    #[test]
    fn cpu_lists_and_names_parse() {
        assert_eq!(parse_cpu_list("0,2,4-7").unwrap(), vec![0, 2, 4, 5, 6, 7]);
        assert_eq!(format_cpu_list(&[0, 2, 4, 5, 6, 7]), "0,2,4-7");
        assert_eq!(format_cpu_list(&[0, 1]), "0,1");
        assert!(parse_cpu_list("0,,1").is_err());
        assert!(parse_cpu_list("3-1").is_err());
        assert!(parse_cpu_list("a").is_err());
        assert!("bogus".parse::<PinPolicy>().is_err());
        assert!("close@bogus".parse::<PinPolicy>().is_err());
        assert!("none@cores".parse::<PinPolicy>().is_err());
        assert_eq!("0-1".parse::<PinPolicy>().unwrap(), PinPolicy::List(vec![0, 1]));
        // Old names keep working.
        assert_eq!("compact".parse::<PinPolicy>().unwrap(), PinPolicy::CLOSE);
        assert_eq!("scatter".parse::<PinPolicy>().unwrap(), PinPolicy::SPREAD);
        assert_eq!("master".parse::<PinPolicy>().unwrap(), PinPolicy::PRIMARY);
        assert_eq!("off".parse::<PinPolicy>().unwrap(), PinPolicy::None);
        // Labels round-trip; places other than cores are spelt out.
        for b in Bind::ALL {
            for k in Places::ALL {
                let p = PinPolicy::Bind(b, k);
                assert_eq!(p.label().parse::<PinPolicy>().unwrap(), p);
            }
        }
        assert_eq!(PinPolicy::CLOSE.label(), "close");
        assert_eq!(PinPolicy::Bind(Bind::Spread, Places::NumaDomains).label(), "spread@numa_domains");
        assert_eq!(
            PinPolicy::parse_with("spread", Places::Sockets).unwrap(),
            PinPolicy::Bind(Bind::Spread, Places::Sockets)
        );
        assert_eq!(
            PinPolicy::parse_with("close@threads", Places::Sockets).unwrap(),
            PinPolicy::Bind(Bind::Close, Places::Threads)
        );
        assert_eq!(PinPolicy::parse_with("1,0", Places::Sockets).unwrap(), PinPolicy::List(vec![1, 0]));
        // Places read from presets (serde) and from the command line (FromStr) agree.
        for k in Places::ALL {
            assert_eq!(serde_json::from_str::<Places>(&format!("\"{k}\"")).unwrap(), k);
            assert_eq!(k.name().parse::<Places>().unwrap(), k);
        }
        assert_eq!(serde_json::from_str::<Places>("\"numa\"").unwrap(), Places::NumaDomains);
        assert!("bogus".parse::<Places>().is_err());
    }

    #[test]
    fn openmp_assignment_of_threads_to_places() {
        // T <= P: close consecutive, spread first place of each subpartition (the first
        // P mod T subpartitions one larger), primary all on place 0.
        assert_eq!(Bind::Close.assign(8, 3), vec![0, 1, 2]);
        assert_eq!(Bind::Spread.assign(8, 3), vec![0, 3, 6]);
        assert_eq!(Bind::Spread.assign(8, 6), vec![0, 2, 4, 5, 6, 7]);
        assert_eq!(Bind::Spread.assign(8, 8), (0..8).collect::<Vec<_>>());
        assert_eq!(Bind::Primary.assign(8, 3), vec![0, 0, 0]);
        // T > P: S_p consecutive threads per place, floor(T/P) <= S_p <= ceil(T/P).
        assert_eq!(Bind::Close.assign(4, 6), vec![0, 0, 1, 1, 2, 3]);
        assert_eq!(Bind::Spread.assign(4, 6), vec![0, 0, 1, 1, 2, 3]);
        assert_eq!(Bind::Close.assign(2, 8), vec![0, 0, 0, 0, 1, 1, 1, 1]);
        assert!(Bind::Close.assign(0, 3).is_empty());
    }

    /// The paper's machine: two quad-core Xeon 5355, no SMT.
    #[test]
    fn two_sockets_of_four_cores() {
        let m = Machine::synthetic("pack:2 core:4 pu:1").unwrap();
        let counts = [2, 4, 6, 8];
        assert_eq!(
            cpus(&m, &PinPolicy::CLOSE, &counts),
            vec![vec![0, 1], vec![0, 1, 2, 3], vec![0, 1, 2, 3, 4, 5], (0..8).collect()]
        );
        assert_eq!(
            cpus(&m, &PinPolicy::SPREAD, &counts),
            vec![vec![0, 4], vec![0, 2, 4, 6], vec![0, 2, 4, 5, 6, 7], (0..8).collect()]
        );
        assert_eq!(cpus(&m, &PinPolicy::PRIMARY, &counts), vec![vec![0, 0], vec![0; 4], vec![0; 6], vec![0; 8]]);
        assert!(m.place(&PinPolicy::PRIMARY, 2).unwrap().oversubscribed);
        assert!(!m.place(&PinPolicy::SPREAD, 8).unwrap().oversubscribed);
        // Over sockets: close puts consecutive threads on one socket (its cores in turn),
        // spread gives each thread of 2 its own socket, primary stays on socket 0.
        let sockets = |b| PinPolicy::Bind(b, Places::Sockets);
        assert_eq!(
            cpus(&m, &sockets(Bind::Close), &counts),
            vec![vec![0, 4], vec![0, 1, 4, 5], vec![0, 1, 2, 4, 5, 6], vec![0, 1, 2, 3, 4, 5, 6, 7]]
        );
        assert_eq!(cpus(&m, &sockets(Bind::Spread), &[2]), vec![vec![0, 4]]);
        assert_eq!(cpus(&m, &sockets(Bind::Primary), &[4, 6]), vec![vec![0, 1, 2, 3], vec![0, 1, 2, 3, 0, 1]]);
        assert!(m.place(&sockets(Bind::Primary), 6).unwrap().oversubscribed);
        assert!(!m.place(&sockets(Bind::Primary), 4).unwrap().oversubscribed);
        assert!(m.place(&PinPolicy::None, 8).unwrap().cpus.is_empty());
    }

    #[test]
    fn one_socket_of_four_numa_nodes() {
        let m = Machine::synthetic("pack:1 numa:4 core:4 pu:1").unwrap();
        assert_eq!(m.numa_nodes.len(), 4);
        let numa = m.places(Places::NumaDomains);
        assert_eq!(numa, vec![vec![0, 1, 2, 3], vec![4, 5, 6, 7], vec![8, 9, 10, 11], vec![12, 13, 14, 15]]);
        assert_eq!(m.places(Places::Sockets), vec![(0..16).collect::<Vec<_>>()]);
        // spread over cores now reaches every NUMA node (the old socket-alternating spread
        // equalled close on one socket).
        assert_eq!(cpus(&m, &PinPolicy::SPREAD, &[2, 4]), vec![vec![0, 8], vec![0, 4, 8, 12]]);
        assert_eq!(cpus(&m, &PinPolicy::CLOSE, &[4]), vec![vec![0, 1, 2, 3]]);
        let on_numa = |b| PinPolicy::Bind(b, Places::NumaDomains);
        assert_eq!(
            cpus(&m, &on_numa(Bind::Spread), &[2, 4, 8]),
            vec![vec![0, 8], vec![0, 4, 8, 12], vec![0, 1, 4, 5, 8, 9, 12, 13]]
        );
        assert_eq!(cpus(&m, &on_numa(Bind::Close), &[2, 6]), vec![vec![0, 4], vec![0, 1, 4, 5, 8, 12]]);
        assert_eq!(cpus(&m, &on_numa(Bind::Primary), &[3]), vec![vec![0, 1, 2]]);
    }

    #[test]
    fn two_sockets_of_eight_cores_with_smt() {
        let m = Machine::synthetic("pack:2 core:8 pu:2").unwrap();
        assert_eq!(m.places(Places::Cores).len(), 16);
        assert_eq!(m.places(Places::Threads).len(), 32);
        let threads = |b| PinPolicy::Bind(b, Places::Threads);
        // cores: one worker per physical core before any sibling; threads: siblings first.
        assert_eq!(cpus(&m, &PinPolicy::CLOSE, &[4]), vec![vec![0, 2, 4, 6]]);
        assert_eq!(cpus(&m, &threads(Bind::Close), &[4]), vec![vec![0, 1, 2, 3]]);
        assert_eq!(cpus(&m, &PinPolicy::SPREAD, &[4]), vec![vec![0, 8, 16, 24]]);
        assert_eq!(cpus(&m, &threads(Bind::Spread), &[4, 6]), vec![vec![0, 8, 16, 24], vec![0, 6, 12, 17, 22, 27]]);
        // 16 threads over 16 cores: every core once, no sibling.
        assert_eq!(cpus(&m, &PinPolicy::CLOSE, &[16]), vec![(0..16).map(|c| 2 * c).collect::<Vec<_>>()]);
        // 32 threads over 16 cores: two per core, on both siblings, not oversubscribed.
        let all = m.place(&PinPolicy::CLOSE, 32).unwrap();
        assert_eq!(all.cpus, (0..32).collect::<Vec<_>>());
        assert!(!all.oversubscribed);
        // 18 threads: the first two cores get a second worker (on the sibling).
        assert_eq!(m.place(&PinPolicy::SPREAD, 18).unwrap().cpus[..6], [0, 1, 2, 3, 4, 6]);
        assert_eq!(cpus(&m, &threads(Bind::Primary), &[2]), vec![vec![0, 0]]);
        assert_eq!(cpus(&m, &PinPolicy::PRIMARY, &[2]), vec![vec![0, 1]]);
        assert!(m.place(&PinPolicy::CLOSE, 33).unwrap().oversubscribed);
    }

    /// Ranks take consecutive slices of the ascending mask of all their workers; too few
    /// CPUs: shared in turn and flagged.
    #[test]
    fn ranks_slice_the_placement_of_all_workers() {
        let m = Machine::synthetic("pack:2 core:4 pu:1").unwrap();
        assert_eq!(m.rank_slices(&PinPolicy::CLOSE, 2, 2).unwrap(), vec![vec![0, 1], vec![2, 3]]);
        // spread puts the two ranks on the two sockets.
        assert_eq!(m.rank_slices(&PinPolicy::SPREAD, 2, 2).unwrap(), vec![vec![0, 2], vec![4, 6]]);
        assert_eq!(m.rank_slices(&PinPolicy::SPREAD, 2, 1).unwrap(), vec![vec![0], vec![4]]);
        assert!(!m.place_ranks(&PinPolicy::CLOSE, 4, 2).unwrap().oversubscribed);
        let laptop = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let p = laptop.place_ranks(&PinPolicy::CLOSE, 2, 2).unwrap();
        assert_eq!((p.cpus.clone(), p.oversubscribed), (vec![0, 1], true));
        assert_eq!(laptop.rank_slices(&PinPolicy::CLOSE, 2, 2).unwrap(), vec![vec![0, 1], vec![0, 1]]);
        assert_eq!(laptop.rank_slices(&PinPolicy::None, 2, 1).unwrap(), vec![Vec::<usize>::new(), vec![]]);
    }

    #[test]
    fn last_level_caches_group_cores() {
        let m = Machine::synthetic("pack:2 l3:2 core:2 pu:1").unwrap();
        assert_eq!(m.places(Places::LlCaches), vec![vec![0, 1], vec![2, 3], vec![4, 5], vec![6, 7]]);
        let llc = PinPolicy::Bind(Bind::Spread, Places::LlCaches);
        assert_eq!(m.place(&llc, 4).unwrap().cpus, vec![0, 2, 4, 6]);
        // No cache information: one place per socket.
        let flat = Machine::synthetic("pack:2 core:2 pu:1").unwrap();
        assert_eq!(flat.places(Places::LlCaches), flat.places(Places::Sockets));
    }

    #[test]
    fn lists_wrap_and_bad_input_fails() {
        let m = Machine::synthetic("pack:1 core:2 pu:1").unwrap();
        let p = m.place(&PinPolicy::CLOSE, 4).unwrap();
        assert_eq!(p.cpus, vec![0, 0, 1, 1]);
        assert!(p.oversubscribed);
        assert!(!m.place(&PinPolicy::SPREAD, 2).unwrap().oversubscribed);
        assert!(m.place(&PinPolicy::None, 3).unwrap().oversubscribed);
        let l = m.place(&PinPolicy::List(vec![0]), 2).unwrap();
        assert_eq!(l.cpus, vec![0, 0]);
        assert!(l.oversubscribed);
        assert!(m.place(&PinPolicy::List(vec![7]), 1).is_err());
        assert!(m.place(&PinPolicy::CLOSE, 0).is_err());
    }

    #[test]
    fn this_host_is_readable() {
        let m = Machine::detect().unwrap();
        assert!(!m.usable_pus().is_empty());
        assert!(m.is_this_system);
        assert!(m.describe().contains("Package"));
        assert!(export_xml().unwrap().contains("<topology"));
        let table = m.placement_table(&PAPER_THREADS, &[PinPolicy::CLOSE, PinPolicy::SPREAD, PinPolicy::None]).unwrap();
        assert!(table.contains("close") && table.contains("Places cores"));
    }
}
