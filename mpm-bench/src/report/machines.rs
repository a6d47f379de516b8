//! The report's machines side by side: CPU identity, topology, caches, memory, OS and
//! software of every campaign, from its `manifest.json` (and `bandwidth.json`).

use super::doc::{Block, Section};
use super::sets::{row_counts, Set};
use crate::campaign::store::manifest::Manifest;
use crate::machine::topology::human_bytes;
use mpm_host::identity::HostIdentity;

type Getter = fn(&Manifest) -> String;

/// A fact of the CPU identity, or `not recorded` (manifests before it existed).
fn id(m: &Manifest, f: fn(&HostIdentity) -> String) -> String {
    m.machine.identity.as_ref().map_or("not recorded".into(), f)
}

/// Rows read from the manifest: name and getter.
fn manifest_rows() -> Vec<(&'static str, Getter)> {
    vec![
        ("CPU", |m| m.machine.cpu_model.clone()),
        ("CPU vendor", |m| id(m, |i| i.cpu_vendor.clone())),
        ("family / model / stepping", |m| {
            id(m, |i| format!("{} / {} / {}", i.cpu_family, i.cpu_model, i.cpu_stepping))
        }),
        ("microcode", |m| id(m, |i| i.microcode.clone())),
        ("sockets", |m| m.machine.packages.to_string()),
        ("cores / PUs", |m| format!("{} / {}", m.machine.cores, m.machine.pus)),
        ("SMT", |m| {
            let smt = id(m, |i| i.smt.clone());
            format!("{} thread(s) per core; {smt}", m.machine.smt_width)
        }),
        ("NUMA nodes", |m| m.machine.numa_nodes.len().to_string()),
        ("caches", |m| {
            m.machine
                .caches
                .iter()
                .filter(|c| c.name != "L1i")
                .map(|c| format!("{} {}x{}", c.name, c.count, human_bytes(c.size_bytes)))
                .collect::<Vec<_>>()
                .join(", ")
        }),
        ("memory", |m| human_bytes(m.machine.memory_bytes)),
        ("frequency governor", |m| m.machine.cpu_governor.clone()),
        ("OS / kernel / arch", |m| format!("{} / {} / {}", m.machine.os, m.machine.kernel, m.machine.arch)),
        ("rustc", |m| m.software.rustc.clone()),
        ("binaries (SHA-256)", |m| {
            let b: Vec<String> = m
                .software
                .binaries
                .iter()
                .map(|b| format!("{}: {}", b.opt_level, &b.sha256[..b.sha256.len().min(16)]))
                .collect();
            if b.is_empty() {
                "not recorded".into()
            } else {
                b.join(", ")
            }
        }),
        ("git commit", |m| {
            let g = &m.software.git;
            format!("{}{}", &g.commit[..g.commit.len().min(12)], if g.dirty { " (dirty)" } else { "" })
        }),
    ]
}

/// The machines table.
pub(super) fn machines_section(sets: &[Set]) -> Section {
    let mut head = vec![String::new()];
    head.extend(sets.iter().map(|s| s.label.clone()));
    let mut rows =
        vec![row("fingerprint", sets, |s| s.campaign.fingerprint()), row("campaign", sets, |s| s.campaign.id())];
    // What decides whether two sets time the same hardware (another host of one class does).
    rows.push(row("hardware class", sets, |s| {
        s.campaign.hardware_class().map_or("not recorded".into(), |h| format!("{} ({})", h.id(), h.describe()))
    }));
    for (name, get) in manifest_rows() {
        rows.push(row(name, sets, |s| s.campaign.manifest.as_ref().map_or("no manifest.json".into(), get)));
    }
    rows.push(row("rows ok / not ok", sets, |s| row_counts(&s.campaign)));
    rows.push(row("pinning analysed", sets, |s| s.analysis.pin_policy.clone()));
    rows.push(row("STREAM triad best (1 thread / max)", sets, |s| {
        s.campaign.bandwidth.as_ref().map_or("not measured".into(), |b| {
            let first = b.results.first().map_or(0.0, |p| p.best_gb_s);
            let max = b.results.iter().map(|p| p.best_gb_s).fold(0.0, f64::max);
            format!("{first:.1} / {max:.1} GB/s")
        })
    }));
    Section {
        id: "machines".into(),
        title: "Machines".into(),
        blocks: vec![
            Block::Para(
                "From each campaign's manifest.json (machine and software of its first session) and bandwidth.json."
                    .into(),
            ),
            Block::Table { caption: String::new(), head, rows },
        ],
    }
}

fn row(name: &str, sets: &[Set], get: impl Fn(&Set) -> String) -> Vec<String> {
    let mut r = vec![name.to_string()];
    r.extend(sets.iter().map(get));
    r
}
