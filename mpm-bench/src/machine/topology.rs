//! The machine as hwloc sees it: packages, NUMA nodes, cores, PUs and caches as plain data.
//!
//! # Why `hwlocality`
//! Topology comes from the system libhwloc (2.x) through the crate
//! [`hwlocality`](https://docs.rs/hwlocality). The older `hwloc2` crate was evaluated and
//! rejected: it panics on NUMA queries and has memory-safety bugs (unsound FFI wrappers), so
//! it cannot be trusted on the multi-socket machines this harness is meant for.
//!
//! # What is read
//! Packages (sockets), NUMA nodes with their memory, physical cores, processing units (PUs,
//! i.e. hardware threads: SMT siblings share a core), and the CPU caches. Only PUs this
//! process may run on count as *usable* (hwloc's allowed cpuset intersected with the
//! process's affinity mask), so a `taskset`/cgroup restriction is honoured.
//!
//! [`Machine`] is plain data, so the placement policies ([`super::placement`]) can be tested on
//! synthetic topologies (`mpm-bench topology --synthetic "pack:2 core:4 pu:2"`) as well as
//! this host.

use anyhow::{Context, Result};
use hwlocality::object::attributes::ObjectAttributes;
use hwlocality::object::types::{CacheType, ObjectType};
use hwlocality::object::TopologyObject;
use hwlocality::topology::builder::TypeFilter;
use hwlocality::topology::export::xml::XMLExportFlags;
use hwlocality::Topology;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

/// A physical core and its PUs (OS indices, SMT sibling order).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Core {
    /// OS index of the core (`None` printed as `?` when hwloc does not know it).
    pub os_index: Option<usize>,
    /// OS indices of the usable PUs of this core, first hardware thread first.
    pub pus: Vec<usize>,
}

/// A package (socket) and its cores.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Package {
    /// OS index of the package.
    pub os_index: Option<usize>,
    /// Cores with at least one usable PU, in logical order.
    pub cores: Vec<Core>,
}

/// A NUMA node.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct NumaNode {
    /// OS index of the node.
    pub os_index: Option<usize>,
    /// Local memory, bytes.
    pub memory_bytes: u64,
    /// OS indices of the PUs local to this node.
    pub cpus: Vec<usize>,
}

/// One level/kind of CPU cache, e.g. `L2` (unified) or `L1d`.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CacheLevel {
    /// `L1d`, `L1i`, `L2`, `L3`, ...
    pub name: String,
    /// Size of one instance, bytes.
    pub size_bytes: u64,
    /// Number of instances.
    pub count: usize,
    /// PUs sharing one instance.
    pub pus_per_instance: usize,
}

/// The machine: plain data extracted from hwloc (or built synthetically for tests).
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Machine {
    /// CPU model string (hwloc's `CPUModel`, else `/proc/cpuinfo`).
    pub cpu_model: String,
    /// Packages (sockets) in logical order.
    pub packages: Vec<Package>,
    /// NUMA nodes.
    pub numa_nodes: Vec<NumaNode>,
    /// CPU caches, innermost first.
    pub caches: Vec<CacheLevel>,
    /// PUs (OS indices) of each instance of the last-level cache, for the `ll_caches`
    /// places; empty when hwloc reports no caches.
    #[serde(default)]
    pub ll_caches: Vec<Vec<usize>>,
    /// Total memory hwloc reports, bytes.
    pub total_memory_bytes: u64,
    /// Whether this describes the machine the harness runs on (not a synthetic/XML one).
    pub is_this_system: bool,
}

/// Format a CPU list compactly: consecutive ascending runs of 3 or more become ranges.
pub fn format_cpu_list(cpus: &[usize]) -> String {
    let mut out = String::new();
    let mut i = 0;
    while i < cpus.len() {
        let mut j = i;
        while j + 1 < cpus.len() && cpus[j + 1] == cpus[j] + 1 {
            j += 1;
        }
        if !out.is_empty() {
            out.push(',');
        }
        if j >= i + 2 {
            let _ = write!(out, "{}-{}", cpus[i], cpus[j]);
            i = j + 1;
        } else {
            let _ = write!(out, "{}", cpus[i]);
            i += 1;
        }
    }
    out
}

impl Machine {
    /// Read this host's topology through hwloc.
    pub fn detect() -> Result<Self> {
        let topo = builder()?.build().context("hwloc could not read this machine's topology")?;
        Ok(Self::from_topology(&topo, process_affinity()))
    }

    /// A topology from an hwloc synthetic description, e.g. `pack:2 core:4 pu:2`.
    pub fn synthetic(description: &str) -> Result<Self> {
        let topo = builder()?
            .from_synthetic(description)
            .with_context(|| format!("bad hwloc synthetic description '{description}'"))?
            .build()
            .context("hwloc could not build the synthetic topology")?;
        Ok(Self::from_topology(&topo, None))
    }

    /// A topology from an hwloc XML export (e.g. another machine's `topology.xml`).
    pub fn from_xml_file(path: &Path) -> Result<Self> {
        // Read the file ourselves: hwlocality panics on an unreadable path (unexpected errno)
        // instead of returning an error.
        let text = std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
        let topo = builder()?
            .from_xml(&text)
            .with_context(|| format!("{} is not an hwloc XML topology", path.display()))?
            .build()
            .context("hwloc could not build the topology from XML")?;
        Ok(Self::from_topology(&topo, None))
    }

    /// Extract the plain data from an hwloc topology. `allowed`, when given, restricts the
    /// usable PUs (the process's affinity mask).
    pub fn from_topology(topo: &Topology, allowed: Option<Vec<usize>>) -> Self {
        let usable = |pu: usize| allowed.as_ref().is_none_or(|a| a.contains(&pu));
        let cpu_model = topo
            .objects_with_type(ObjectType::Package)
            .find_map(|p| p.info("CPUModel").map(|s| s.to_string_lossy().trim().to_string()))
            .filter(|s| !s.is_empty())
            .or_else(|| if topo.is_this_system() { proc_cpu_model() } else { None })
            .unwrap_or_else(|| "unknown CPU".into());
        Machine {
            cpu_model,
            packages: packages(topo, &usable),
            numa_nodes: numa_nodes(topo),
            caches: caches(topo),
            ll_caches: ll_caches(topo),
            total_memory_bytes: if topo.is_this_system() {
                // Some VMs hot-plug memory that hwloc's NUMA nodes do not list: the OS's
                // MemTotal is what a run can use.
                topo.root_object().total_memory().max(proc_mem_total().unwrap_or(0))
            } else {
                topo.root_object().total_memory()
            },
            is_this_system: topo.is_this_system(),
        }
    }

    /// Number of packages (sockets) with usable PUs.
    pub fn num_packages(&self) -> usize {
        self.packages.len()
    }

    /// Number of physical cores with usable PUs.
    pub fn num_cores(&self) -> usize {
        self.packages.iter().map(|p| p.cores.len()).sum()
    }

    /// The physical cores the PUs `cpus` (OS indices) belong to, each counted once
    /// (two SMT siblings are one core); a PU this machine does not list counts as a core
    /// of its own.
    pub fn physical_cores_of(&self, cpus: &[usize]) -> usize {
        let mut cores = std::collections::BTreeSet::new();
        for &cpu in cpus {
            let core = self
                .packages
                .iter()
                .enumerate()
                .flat_map(|(p, pkg)| pkg.cores.iter().enumerate().map(move |(c, core)| (p, c, core)))
                .find(|(_, _, core)| core.pus.contains(&cpu))
                .map_or((usize::MAX, cpu), |(p, c, _)| (p, c));
            cores.insert(core);
        }
        cores.len()
    }

    /// Every usable PU (OS index), in logical order.
    pub fn usable_pus(&self) -> Vec<usize> {
        self.packages.iter().flat_map(|p| p.cores.iter().flat_map(|c| c.pus.iter().copied())).collect()
    }

    /// Largest number of PUs on one core (2 with SMT/Hyper-Threading).
    pub fn smt_width(&self) -> usize {
        self.packages.iter().flat_map(|p| p.cores.iter().map(|c| c.pus.len())).max().unwrap_or(1)
    }

    /// Human-readable description (what `mpm-bench topology` prints first).
    pub fn describe(&self) -> String {
        let mut s = String::new();
        let pus = self.usable_pus().len();
        let _ = writeln!(s, "CPU model      {}", self.cpu_model);
        let _ = writeln!(
            s,
            "Summary        {} package(s), {} NUMA node(s), {} core(s), {} PU(s) usable (SMT width {}), memory {}",
            self.num_packages(),
            self.numa_nodes.len(),
            self.num_cores(),
            pus,
            self.smt_width(),
            human_bytes(self.total_memory_bytes)
        );
        let numa_total: u64 = self.numa_nodes.iter().map(|n| n.memory_bytes).sum();
        if numa_total > 0 && numa_total < self.total_memory_bytes * 9 / 10 {
            let _ = writeln!(
                s,
                "Note           the NUMA nodes list only {} of the {} the OS reports (hot-plugged memory?)",
                human_bytes(numa_total),
                human_bytes(self.total_memory_bytes)
            );
        }
        if !self.is_this_system {
            let _ = writeln!(s, "Source         not this host (synthetic or XML topology)");
        }
        for (i, n) in self.numa_nodes.iter().enumerate() {
            let _ = writeln!(
                s,
                "NUMA node {}    {} local memory, CPUs {}",
                n.os_index.unwrap_or(i),
                human_bytes(n.memory_bytes),
                format_cpu_list(&n.cpus)
            );
        }
        for (i, p) in self.packages.iter().enumerate() {
            let _ = writeln!(s, "Package P#{}    {} core(s)", os(p.os_index, i), p.cores.len());
            for (k, c) in p.cores.iter().enumerate() {
                let _ = writeln!(s, "  Core C#{:<4}  PU(s) {}", os(c.os_index, k), format_cpu_list(&c.pus));
            }
        }
        if self.caches.is_empty() {
            let _ = writeln!(s, "Caches         (hwloc reports none)");
        } else {
            let list: Vec<String> = self
                .caches
                .iter()
                .map(|c| {
                    format!(
                        "{} {} x{} (shared by {} PU)",
                        c.name,
                        human_bytes(c.size_bytes),
                        c.count,
                        c.pus_per_instance
                    )
                })
                .collect();
            let _ = writeln!(s, "Caches         {}", list.join(", "));
        }
        s
    }
}

/// OS indices of the PUs of an object.
fn cpus_of(o: &TopologyObject) -> Vec<usize> {
    o.cpuset().map(|c| c.iter_set().map(usize::from).collect()).unwrap_or_default()
}

/// Packages with their cores that have a usable PU, in logical order (one core per PU when
/// hwloc lists no cores).
fn packages(topo: &Topology, usable: &dyn Fn(usize) -> bool) -> Vec<Package> {
    let mut packages: Vec<Package> = Vec::new();
    let mut pkg_ids: Vec<Option<u64>> = Vec::new();
    for core in topo.objects_with_type(ObjectType::Core) {
        let pus: Vec<usize> = core
            .normal_children()
            .filter(|c| c.object_type() == ObjectType::PU)
            .filter_map(|c| c.os_index())
            .filter(|&p| usable(p))
            .collect();
        let pus = if pus.is_empty() && core.normal_arity() == 0 {
            cpus_of(core).into_iter().filter(|&p| usable(p)).collect()
        } else {
            pus
        };
        if pus.is_empty() {
            continue;
        }
        let pkg = core.first_ancestor_with_type(ObjectType::Package);
        let id = pkg.map(|p| p.global_persistent_index());
        let idx = match pkg_ids.iter().position(|&x| x == id) {
            Some(i) => i,
            None => {
                pkg_ids.push(id);
                packages.push(Package { os_index: pkg.and_then(|p| p.os_index()), cores: Vec::new() });
                packages.len() - 1
            }
        };
        packages[idx].cores.push(Core { os_index: core.os_index(), pus });
    }
    if packages.is_empty() {
        // No Core objects (unusual): one core per PU.
        let cores = topo
            .objects_with_type(ObjectType::PU)
            .filter_map(|p| p.os_index())
            .filter(|&p| usable(p))
            .map(|p| Core { os_index: Some(p), pus: vec![p] })
            .collect();
        packages.push(Package { os_index: Some(0), cores });
    }
    packages
}

/// NUMA nodes with their local memory and CPUs.
fn numa_nodes(topo: &Topology) -> Vec<NumaNode> {
    topo.objects_with_type(ObjectType::NUMANode)
        .map(|n| NumaNode {
            os_index: n.os_index(),
            memory_bytes: match n.attributes() {
                Some(ObjectAttributes::NUMANode(a)) => a.local_memory().map_or(0, |m| m.get()),
                _ => 0,
            },
            cpus: cpus_of(n),
        })
        .collect()
}

/// One entry per cache level and kind (data, instruction, unified), innermost first.
fn caches(topo: &Topology) -> Vec<CacheLevel> {
    let mut caches: BTreeMap<(usize, u8), CacheLevel> = BTreeMap::new();
    for ty in [
        ObjectType::L1Cache,
        ObjectType::L1ICache,
        ObjectType::L2Cache,
        ObjectType::L2ICache,
        ObjectType::L3Cache,
        ObjectType::L3ICache,
        ObjectType::L4Cache,
        ObjectType::L5Cache,
    ] {
        for obj in topo.objects_with_type(ty) {
            let Some(ObjectAttributes::Cache(c)) = obj.attributes() else { continue };
            let (suffix, kind) = match c.cache_type() {
                CacheType::Data => ("d", 0u8),
                CacheType::Instruction => ("i", 1),
                _ => ("", 2),
            };
            let entry = caches.entry((c.depth(), kind)).or_insert_with(|| CacheLevel {
                name: format!("L{}{suffix}", c.depth()),
                size_bytes: c.size().map_or(0, |s| s.get()),
                count: 0,
                pus_per_instance: cpus_of(obj).len(),
            });
            entry.count += 1;
        }
    }
    caches.into_values().collect()
}

/// The PUs of each instance of the outermost data or unified cache level.
fn ll_caches(topo: &Topology) -> Vec<Vec<usize>> {
    [ObjectType::L5Cache, ObjectType::L4Cache, ObjectType::L3Cache, ObjectType::L2Cache, ObjectType::L1Cache]
        .into_iter()
        .map(|ty| topo.objects_with_type(ty).map(cpus_of).collect::<Vec<_>>())
        .find(|sets| !sets.is_empty())
        .unwrap_or_default()
}

fn os(i: Option<usize>, fallback: usize) -> String {
    i.map_or_else(|| format!("{fallback}?"), |v| v.to_string())
}

fn builder() -> Result<hwlocality::topology::builder::TopologyBuilder> {
    Topology::builder()
        .with_cpu_icache_type_filter(TypeFilter::KeepAll)
        .context("hwloc refused to keep instruction caches")
}

/// This process's CPU affinity mask (OS indices), if readable.
pub fn process_affinity() -> Option<Vec<usize>> {
    core_affinity::get_core_ids().map(|ids| ids.into_iter().map(|c| c.id).collect())
}

/// `MemTotal` of `/proc/meminfo`, bytes.
fn proc_mem_total() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let kib: u64 = text.lines().find(|l| l.starts_with("MemTotal:"))?.split_whitespace().nth(1)?.parse().ok()?;
    Some(kib * 1024)
}

fn proc_cpu_model() -> Option<String> {
    let text = std::fs::read_to_string("/proc/cpuinfo").ok()?;
    text.lines()
        .find(|l| l.starts_with("model name"))
        .and_then(|l| l.split_once(':'))
        .map(|(_, v)| v.trim().to_string())
}

/// Export this host's topology as hwloc XML (for `topology.xml` beside a manifest).
pub fn export_xml() -> Result<String> {
    let topo = builder()?.build().context("hwloc could not read this machine's topology")?;
    let xml = topo.export_xml(XMLExportFlags::empty()).context("hwloc XML export failed")?;
    Ok(xml.as_str().to_string())
}

pub use mpm_host::human::human_bytes;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn xml_round_trip_and_errors() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("topology.xml");
        std::fs::write(&p, export_xml().unwrap()).unwrap();
        let m = Machine::from_xml_file(&p).unwrap();
        assert_eq!(m.usable_pus().len(), Machine::detect().unwrap().usable_pus().len());
        assert!(!m.is_this_system);
        assert!(Machine::from_xml_file(&dir.path().join("missing.xml")).is_err());
        std::fs::write(&p, "not xml").unwrap();
        assert!(Machine::from_xml_file(&p).is_err());
        assert!(Machine::synthetic("bogus:7").is_err());
    }
}
