//! `mpm-bench topology`: the machine as hwloc sees it and where workers would go.

use anyhow::{Context, Result};
use clap::Args;
use mpm_bench::machine::fingerprint;
use mpm_bench::machine::placement::{PinPolicy, Places, PAPER_THREADS};
use mpm_bench::machine::topology::{self, Machine};
use std::path::PathBuf;

#[derive(Args, Debug)]
pub struct TopologyArgs {
    /// Thread counts to show (comma list).
    #[arg(long, value_name = "LIST", value_delimiter = ',', default_values_t = PAPER_THREADS.to_vec())]
    threads: Vec<usize>,
    /// OpenMP place list: threads, cores, ll_caches, numa_domains, sockets.
    #[arg(long, value_name = "PLACES", default_value = "cores")]
    places: Places,
    /// MPI rank counts to show as well (comma list, e.g. 2,4): each rank's CPUs for every
    /// thread count per rank, as a hybrid campaign places them.
    #[arg(long, value_name = "LIST", value_delimiter = ',')]
    ranks: Vec<usize>,
    /// Binding to show (repeatable): close, spread, primary (optionally @places, e.g.
    /// spread@sockets), none, or a CPU list such as 0,1 or 0-3. Default: close, spread,
    /// primary and none. `--pin` is an alias.
    #[arg(long, visible_alias = "pin", value_name = "POLICY")]
    bind: Vec<String>,
    /// Use an hwloc synthetic topology instead of this machine, e.g. "pack:2 core:4 pu:2".
    #[arg(long, value_name = "DESCRIPTION", conflicts_with = "xml")]
    synthetic: Option<String>,
    /// Use an hwloc XML export (e.g. a campaign's topology.xml) instead of this machine.
    #[arg(long, value_name = "FILE")]
    xml: Option<PathBuf>,
    /// Write this machine's hwloc XML export to FILE.
    #[arg(long, value_name = "FILE")]
    export_xml: Option<PathBuf>,
}

pub fn cmd_topology(a: TopologyArgs) -> Result<()> {
    if a.threads.contains(&0) || a.ranks.contains(&0) {
        anyhow::bail!("thread and rank counts must be at least 1 (got 0)");
    }
    let machine = match (&a.synthetic, &a.xml) {
        (Some(s), _) => Machine::synthetic(s)?,
        (None, Some(x)) => Machine::from_xml_file(x)?,
        (None, None) => Machine::detect()?,
    };
    use std::io::Write as _;
    let mut out = std::io::stdout().lock();
    writeln!(out, "{}", machine.describe())?;
    let policies: Vec<PinPolicy> = if a.bind.is_empty() {
        vec![PinPolicy::CLOSE, PinPolicy::SPREAD, PinPolicy::PRIMARY, PinPolicy::None]
            .into_iter()
            .map(|p| p.with_places(a.places))
            .collect()
    } else {
        a.bind.iter().map(|b| PinPolicy::parse_with(b, a.places)).collect::<Result<_>>()?
    };
    for p in &policies {
        machine.check_policy(p)?;
    }
    write!(out, "{}", machine.placement_table(&a.threads, &policies)?)?;
    for &r in a.ranks.iter().filter(|&&r| r > 1) {
        writeln!(out, "{r} MPI ranks: the CPUs of rank 0 | rank 1 | ... ('*' = oversubscribed)")?;
        for p in policies.iter().filter(|p| !matches!(p, PinPolicy::None)) {
            for &t in &a.threads {
                let slices = machine.rank_slices(p, r, t)?;
                let over = if machine.place_ranks(p, r, t)?.oversubscribed { " *" } else { "" };
                let text: Vec<String> =
                    slices.iter().map(|s| s.iter().map(|c| c.to_string()).collect::<Vec<_>>().join(",")).collect();
                writeln!(out, "  {:<16} {r} x {t:<3} {}{over}", p.label(), text.join(" | "))?;
            }
        }
    }
    if machine.is_this_system {
        writeln!(out, "Machine fingerprint: {}", fingerprint::fingerprint(&machine))?;
    }
    if let Some(path) = a.export_xml {
        let xml = topology::export_xml()?;
        std::fs::write(&path, xml).with_context(|| format!("cannot write {}", path.display()))?;
        writeln!(out, "hwloc XML written to {}", path.display())?;
    }
    Ok(())
}
