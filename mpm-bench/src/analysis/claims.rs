//! `mpm-bench claims`: the paper's claims C1-C6 (spec paper.md section 5), and C7 (this
//! study's own claim) on the balanced DD cuts, tested on a campaign, each with a verdict, the
//! reason and the numbers behind it; then a section beyond the paper, the strategies used
//! since (block colouring, atomic adds) against DD and AE ([`super::strategies`]).
//!
//! Rules shared by every claim:
//!
//! * Only *real* parallel points are evidence of scaling: more than one thread and not
//!   oversubscribed (an oversubscribed point is time sharing: never counted, for or against).
//!   Memory (C2, C6) does not depend on time sharing, so every point counts there.
//! * Two estimates differ only beyond the noise ([`super::stats::compare`]): their bootstrap
//!   intervals must not overlap; with single repetitions (no interval) they must differ by
//!   more than 5 %. A difference within the noise supports nothing.
//! * "holds": a majority of the comparisons support the claim beyond the noise and none
//!   contradicts it; "does not hold": some comparison contradicts it; "cannot tell": no
//!   majority either way (mostly within the noise, missing points, or a machine that cannot
//!   show the effect, such as one socket of one NUMA node for C5).
//! * A verdict needs intervals: with fewer than [`MIN_REPS`] repetitions in a cell it rests
//!   on, the verdict is *indicative* and says so (`holds (indicative)`).
//! * C5 (the socket effect) compares the same thread count pinned to one socket (`close`)
//!   and to two (`spread`), the sockets counted from the placement on the manifest's
//!   topology; comparing 4 against 6 threads would also show ordinary Amdahl decline. On a
//!   machine of one socket with two or more NUMA nodes, its NUMA nodes take the sockets'
//!   place (the same cross-domain memory traffic); on one socket of one node it cannot tell.
//! * Speedups and efficiencies are those of the total step time at optimisation O3 unless
//!   the claim is about a stage or about optimisation.

use super::results::{load_campaigns, Campaign};
use super::select::RowFilter;
use super::stats::{compare, parallel_strategies, tag, Analysis, CellKey, Compare, Estimate, Stage, StatsOptions};
use super::strategies;
use crate::campaign::store::record::Status;
use crate::machine::placement::{PinPolicy, Places};
use crate::machine::topology::Machine;
use anyhow::{bail, Context, Result};
use mpm_core::Strategy;
use serde::Serialize;
use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write as _;
use std::path::PathBuf;

/// Evaluate the paper's claims C1-C6 on a results set.
///
/// Prints, for each claim, holds / does not hold / cannot tell with the reason and the
/// numbers behind it. Only non-oversubscribed runs with more than one thread count as
/// evidence of scaling; differences must exceed the bootstrap interval (or 5 % with a single
/// repetition). "holds" needs a majority of the comparisons beyond the noise and none
/// against; with fewer than 3 repetitions per cell a verdict is marked "(indicative)". C5
/// (the socket effect) needs the same thread counts run with --bind close and --bind spread.
#[derive(Debug, Clone)]
pub struct ClaimsOptions {
    /// A campaign folder (holding runs.csv) or a folder containing campaigns (e.g.
    /// results/ or results/FINGERPRINT/): then the newest campaign is used.
    pub results: PathBuf,
    /// Also write the table and the evidence as Markdown to this file.
    pub markdown: Option<PathBuf>,
    /// Pinning policy to analyse when the campaign has several (default: close, else the first).
    pub pin: Option<String>,
    /// Keep rows measured on a busy host (host_noisy), left out by default.
    pub include_noisy: bool,
    /// Also analyse rows that ran with an injected slowdown (`--inject-slowdown`, a test knob
    /// of the regression gate): never results, refused by default.
    pub include_injected: bool,
}

/// A claim's verdict.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Verdict {
    /// The data support the claim and nothing contradicts it.
    Holds,
    /// Some data contradict the claim.
    DoesNotHold,
    /// Not enough evidence either way.
    CannotTell,
}

impl Verdict {
    /// `holds`, `does not hold`, `cannot tell`.
    pub fn as_str(self) -> &'static str {
        match self {
            Verdict::Holds => "holds",
            Verdict::DoesNotHold => "does not hold",
            Verdict::CannotTell => "cannot tell",
        }
    }
}

/// One claim evaluated.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ClaimResult {
    /// `C1` .. `C6`.
    pub id: &'static str,
    /// The claim as the paper states it.
    pub text: &'static str,
    /// The verdict.
    pub verdict: Verdict,
    /// Why, in one or two sentences.
    pub reason: String,
    /// The numbers behind the verdict, one line each.
    pub evidence: Vec<String>,
    /// Fewest repetitions in a cell the verdict rests on (`None`: no measured cell).
    pub min_reps: Option<usize>,
    /// Fewer than [`MIN_REPS`] repetitions: no real intervals, the verdict is indicative.
    pub indicative: bool,
}

impl ClaimResult {
    /// The verdict as printed: `holds`, or `holds (indicative)` without enough repetitions.
    pub fn verdict_label(&self) -> String {
        if self.indicative {
            format!("{} (indicative)", self.verdict.as_str())
        } else {
            self.verdict.as_str().to_string()
        }
    }

    /// Mark the verdict indicative when it rests on fewer than [`MIN_REPS`] repetitions.
    fn with_reps(mut self, min_reps: Option<usize>) -> Self {
        self.min_reps = min_reps;
        if let Some(n) = min_reps.filter(|&n| n < MIN_REPS) {
            self.indicative = true;
            self.reason.push_str(&format!(
                "; indicative only: {n} repetition(s) in some cells, intervals need at least {MIN_REPS}"
            ));
        }
        self
    }
}

/// Repetitions per cell a verdict needs (fewer: indicative).
pub const MIN_REPS: usize = 3;

/// The paper's claims (spec paper.md section 5).
pub const CLAIMS: [(&str, &str); 7] = [
    ("C1", "DD scales better and is more efficient than AE, increasingly so for larger models."),
    ("C2", "AE memory grows with threads; DD memory is nearly constant (Model4: 4.61 -> 4.63 GB)."),
    ("C3", "In AE the particle stage scales better than the grid-node stage (the bottleneck)."),
    ("C4", "Without compiler optimisation, parallel efficiency is higher than with O3."),
    ("C5", "Past 4 threads (the second socket) efficiency drops: cross-socket traffic."),
    ("C6", "AE could not run Model4 at 4-8 threads: not enough memory on the 8 GB machine."),
    (
        "C7",
        "Balanced cuts reduce the work imbalance and the time per step of DD (this study's claim, not the paper's).",
    ),
];

/// Array expansion, the subject of claims C3 and C6.
const AE: Strategy = Strategy::ArrayExpansion;
/// Domain decomposition.
const DD: Strategy = Strategy::DomainDecomposition;

/// Memory of the paper's machine (8 GB).
pub const PAPER_MEMORY_BYTES: f64 = 8e9;

/// Relative growth under which memory counts as "nearly constant" (C2).
pub const FLAT_MEMORY: f64 = 0.10;

/// Tally of comparisons "a > b" claimed.
#[derive(Default)]
struct Tally {
    supports: usize,
    contradicts: usize,
    within: usize,
    lines: Vec<String>,
    min_reps: Option<usize>,
}

impl Tally {
    fn add(&mut self, label: String, a_name: &str, a: &Estimate, b_name: &str, b: &Estimate) {
        let c = compare(a, b);
        let reps = a.reps.min(b.reps);
        self.min_reps = Some(self.min_reps.map_or(reps, |m| m.min(reps)));
        let tag = match c {
            Compare::Greater => {
                self.supports += 1;
                "supports"
            }
            Compare::Less => {
                self.contradicts += 1;
                "contradicts"
            }
            Compare::Within => {
                self.within += 1;
                "within noise"
            }
        };
        self.lines.push(format!("{label}: {a_name} {} vs {b_name} {} -> {tag}", a.show(3), b.show(3)));
    }

    fn verdict(&self, what: &str) -> (Verdict, String) {
        let n = self.supports + self.contradicts + self.within;
        if n == 0 {
            (Verdict::CannotTell, format!("no comparable non-oversubscribed points with more than one thread ({what})"))
        } else if self.contradicts > 0 {
            (
                Verdict::DoesNotHold,
                format!(
                    "{} of {n} comparisons contradict it beyond the noise ({} support it, {} within noise)",
                    self.contradicts, self.supports, self.within
                ),
            )
        } else if 2 * self.supports > n {
            (
                Verdict::Holds,
                format!(
                    "{} of {n} comparisons support it beyond the noise, none contradicts ({} within noise)",
                    self.supports, self.within
                ),
            )
        } else if self.supports > 0 {
            (
                Verdict::CannotTell,
                format!(
                    "only {} of {n} comparisons support it beyond the noise (no majority; {} within noise, none contradicts)",
                    self.supports, self.within
                ),
            )
        } else {
            (Verdict::CannotTell, format!("all {n} comparisons are within the noise"))
        }
    }
}

fn result(id: &'static str, verdict: Verdict, reason: String, evidence: Vec<String>) -> ClaimResult {
    let text = CLAIMS.iter().find(|c| c.0 == id).map(|c| c.1).unwrap_or("");
    ClaimResult { id, text, verdict, reason, evidence, min_reps: None, indicative: false }
}

/// Real parallel thread counts where both `a` and `b` have a point.
fn common_real_threads(
    an: &Analysis,
    model: u32,
    a: (Strategy, &str),
    b: (Strategy, &str),
    stage: Stage,
) -> Vec<usize> {
    an.series(model, a.0, a.1, stage)
        .into_iter()
        .filter(|p| p.is_real_parallel() && p.efficiency.is_some())
        .filter_map(|p| {
            an.point(model, b.0, b.1, p.key.threads, stage)
                .filter(|q| q.is_real_parallel() && q.efficiency.is_some())
                .map(|_| p.key.threads)
        })
        .collect()
}

fn c1(an: &Analysis) -> ClaimResult {
    let mut t = Tally::default();
    let mut gaps: Vec<(u32, usize, f64)> = Vec::new();
    for m in an.models() {
        let ths = common_real_threads(an, m, (DD, "o3"), (AE, "o3"), Stage::Total);
        let eff =
            |s: Strategy, n: usize| an.point(m, s, "o3", n, Stage::Total).and_then(|p| p.efficiency).expect("filtered");
        for &n in &ths {
            t.add(format!("Model{m}, {n} threads, efficiency"), &tag(DD), &eff(DD, n), &tag(AE), &eff(AE, n));
        }
        if let Some(&n) = ths.last() {
            gaps.push((m, n, eff(DD, n).value - eff(AE, n).value));
        }
    }
    let (mut v, mut reason) = t.verdict("DD and AE at O3");
    let reps = t.min_reps;
    let mut ev = t.lines;
    if !gaps.is_empty() {
        ev.push(format!(
            "gap e(DD) - e(AE) at the largest real thread count per model: {}",
            gaps.iter().map(|(m, n, g)| format!("Model{m}@{n}t {g:+.3}")).collect::<Vec<_>>().join(", ")
        ));
    }
    if v == Verdict::Holds {
        // "increasingly so for larger models": the gap must not shrink with model size.
        if gaps.len() < 2 {
            v = Verdict::CannotTell;
            reason = format!("{reason}; but one model only: cannot test 'increasingly so for larger models'");
        } else {
            let grows = gaps.windows(2).all(|w| w[1].2 >= w[0].2 - 0.02);
            if grows {
                reason = format!("{reason}; the gap does not shrink with model size");
            } else {
                v = Verdict::DoesNotHold;
                reason = format!("{reason}; but the gap shrinks for a larger model (not 'increasingly so')");
            }
        }
    }
    result("C1", v, reason, ev).with_reps(reps)
}

fn c2(an: &Analysis, o: &StatsOptions) -> ClaimResult {
    let mut ev = Vec::new();
    // Per strategy: series that grew by more than FLAT_MEMORY, series that did not.
    let mut growth_of: BTreeMap<Strategy, (usize, usize)> = BTreeMap::new();
    let mut reps: Option<usize> = None;
    for m in an.models() {
        for strat in parallel_strategies() {
            for opt in ["o3", "o0"] {
                let mut pts: Vec<(usize, Estimate)> = an
                    .thread_counts()
                    .into_iter()
                    .filter_map(|n| an.memory(&CellKey::new(m, strat, opt, n), o).map(|e| (n, e)))
                    .collect();
                pts.sort_by_key(|p| p.0);
                let (Some(first), Some(last)) = (pts.first(), pts.last()) else { continue };
                if first.0 != 1 || last.0 == 1 {
                    continue;
                }
                let growth = last.1.value / first.1.value - 1.0;
                let n = first.1.reps.min(last.1.reps);
                reps = Some(reps.map_or(n, |r| r.min(n)));
                ev.push(format!(
                    "Model{m} {} {}: peak memory {} at 1 thread -> {} at {} threads ({:+.1} %)",
                    tag(strat),
                    opt.to_uppercase(),
                    gb(first.1.value),
                    gb(last.1.value),
                    last.0,
                    100.0 * growth
                ));
                let tally = growth_of.entry(strat).or_default();
                if growth > FLAT_MEMORY {
                    tally.0 += 1;
                } else {
                    tally.1 += 1;
                }
            }
        }
    }
    let (ae_grows, ae_flat) = growth_of.get(&AE).copied().unwrap_or_default();
    let (dd_grows, dd_flat) = growth_of.get(&DD).copied().unwrap_or_default();
    let n = ae_grows + ae_flat + dd_flat + dd_grows;
    let (v, reason) = if n == 0 || ae_grows + ae_flat == 0 || dd_flat + dd_grows == 0 {
        (Verdict::CannotTell, "no peak-memory measurements at 1 and more threads for both AE and DD".to_string())
    } else if dd_grows > 0 {
        (Verdict::DoesNotHold, format!("DD memory grew by more than {:.0} % in {dd_grows} series", 100.0 * FLAT_MEMORY))
    } else if ae_grows == 0 {
        (
            Verdict::DoesNotHold,
            format!("AE memory grew by less than {:.0} % in every series (the nodal copies are small next to the particles here)", 100.0 * FLAT_MEMORY),
        )
    } else {
        (
            Verdict::Holds,
            format!(
                "AE memory grew by more than {:.0} % in {ae_grows} of {} series; DD stayed within {:.0} % in all {dd_flat}",
                100.0 * FLAT_MEMORY,
                ae_grows + ae_flat,
                100.0 * FLAT_MEMORY
            ),
        )
    };
    ev.push("paper: Model4 DD 4.61 GB (1 thread) -> 4.63 GB (8 threads)".into());
    result("C2", v, reason, ev).with_reps(reps)
}

fn c3(an: &Analysis) -> ClaimResult {
    let mut t = Tally::default();
    for m in an.models() {
        for p in an.series(m, AE, "o3", Stage::Particle) {
            if !p.is_real_parallel() {
                continue;
            }
            let (Some(sp), Some(sg)) =
                (p.speedup, an.point(m, AE, "o3", p.key.threads, Stage::Grid).and_then(|g| g.speedup))
            else {
                continue;
            };
            t.add(format!("Model{m} {} O3, {} threads, speedup", tag(AE), p.key.threads), "particle", &sp, "grid", &sg);
        }
    }
    let (v, reason) = t.verdict("AE O3 stage speedups");
    result("C3", v, reason, t.lines).with_reps(t.min_reps)
}

fn c4(an: &Analysis) -> ClaimResult {
    let mut t = Tally::default();
    for m in an.models() {
        for strat in parallel_strategies() {
            for n in common_real_threads(an, m, (strat, "o0"), (strat, "o3"), Stage::Total) {
                let e0 = an.point(m, strat, "o0", n, Stage::Total).and_then(|p| p.efficiency).expect("filtered");
                let e3 = an.point(m, strat, "o3", n, Stage::Total).and_then(|p| p.efficiency).expect("filtered");
                t.add(format!("Model{m} {}, {n} threads, efficiency", tag(strat)), "O0", &e0, "O3", &e3);
            }
        }
    }
    let (v, reason) = t.verdict("O0 and O3");
    result("C4", v, reason, t.lines).with_reps(t.min_reps)
}

/// What C5 crosses: the sockets of a machine of two or more, else the NUMA nodes (with cores)
/// of a machine of one socket and two or more nodes (sub-NUMA clustering, a chiplet CPU in
/// NPS2/NPS4 mode). `None` on one socket of one NUMA node: nothing to cross.
fn domains(m: &Machine) -> Option<(Vec<Vec<usize>>, &'static str)> {
    let sockets = m.places(Places::Sockets);
    let numa = m.places(Places::NumaDomains);
    if sockets.len() >= 2 {
        Some((sockets, "socket"))
    } else if numa.len() >= 2 {
        Some((numa, "NUMA node"))
    } else {
        None
    }
}

/// Domains (`domains`: each one's PUs) used by `n` workers under the pinning label `pin` on
/// `m` (`None`: not pinned, oversubscribed, or an unknown label).
fn domains_used(m: &Machine, domains: &[Vec<usize>], pin: &str, n: usize) -> Option<usize> {
    let policy: PinPolicy = pin.parse().ok()?;
    let pl = m.place(&policy, n).ok().filter(|p| !p.oversubscribed && !p.cpus.is_empty())?;
    let domain = |cpu: &usize| domains.iter().position(|d| d.contains(cpu));
    Some(pl.cpus.iter().filter_map(domain).collect::<BTreeSet<_>>().len())
}

/// For each thread count, a policy that keeps its workers in one domain and one that uses
/// two or more (`close` and `spread` preferred), among the rows' policies.
fn domain_pairs(c: &Campaign, m: &Machine, domains: &[Vec<usize>]) -> Vec<(usize, String, String)> {
    let mut labels: Vec<String> = c
        .rows
        .iter()
        .map(crate::campaign::store::record::Row::pin_label)
        .collect::<BTreeSet<_>>()
        .into_iter()
        .collect();
    labels.sort_by_key(|l| (l != "close", l != "spread"));
    let threads: BTreeSet<usize> = c.rows.iter().map(|r| r.threads()).filter(|&n| n > 1).collect();
    threads
        .into_iter()
        .filter_map(|n| {
            let one = labels.iter().find(|l| domains_used(m, domains, l, n) == Some(1))?;
            let two = labels.iter().find(|l| domains_used(m, domains, l, n).is_some_and(|k| k >= 2))?;
            Some((n, one.to_string(), two.to_string()))
        })
        .collect()
}

fn c5(c: &Campaign) -> ClaimResult {
    let Some(man) = &c.manifest else {
        return result(
            "C5",
            Verdict::CannotTell,
            "no manifest.json beside runs.csv: the machine's sockets and NUMA nodes are unknown".into(),
            vec![],
        );
    };
    let m = &man.machine.topology;
    let ev = vec![format!(
        "machine: {} socket(s), {} cores, {} NUMA node(s)",
        m.num_packages(),
        m.num_cores(),
        m.numa_nodes.len()
    )];
    let Some((domains, what)) = domains(m) else {
        return result(
            "C5",
            Verdict::CannotTell,
            "this machine has 1 socket and 1 NUMA node: there is no second socket or NUMA node to cross".into(),
            ev,
        );
    };
    let pairs = domain_pairs(c, m, &domains);
    if pairs.is_empty() {
        return result(
            "C5",
            Verdict::CannotTell,
            format!("no thread count was run both in one {what} and across two: rerun with --bind close --bind spread"),
            ev,
        );
    }
    c5_compare(c, pairs, what, ev)
}

/// C5's comparisons: time per step at the same thread count across two domains (`what`:
/// sockets or NUMA nodes) against one.
fn c5_compare(c: &Campaign, pairs: Vec<(usize, String, String)>, what: &str, mut ev: Vec<String>) -> ClaimResult {
    let o = StatsOptions::default();
    let mut analyses: BTreeMap<String, Analysis> = BTreeMap::new();
    for (_, one, two) in &pairs {
        for l in [one, two] {
            analyses.entry(l.clone()).or_insert_with(|| Analysis::from_rows(&c.rows, Some(l), &o));
        }
    }
    let mut t = Tally::default();
    for (n, one, two) in &pairs {
        let (a1, a2) = (&analyses[one], &analyses[two]);
        for m in a1.models() {
            for strat in parallel_strategies() {
                let time = |a: &Analysis| a.point(m, strat, "o3", *n, Stage::Total).map(|p| p.time.scale(1e3));
                let (Some(t1), Some(t2)) = (time(a1), time(a2)) else { continue };
                t.add(
                    format!("Model{m} {} O3, {n} threads, time per step (ms)", tag(strat)),
                    &format!("{two} (2 {what}s)"),
                    &t2,
                    &format!("{one} (1 {what})"),
                    &t1,
                );
            }
        }
    }
    let (v, reason) = t.verdict(&format!("the same thread count on one {what} and on two"));
    ev.extend(t.lines);
    result("C5", v, reason, ev).with_reps(t.min_reps)
}

fn c6(c: &Campaign, o: &StatsOptions) -> ClaimResult {
    let mut ev = Vec::new();
    let mem = c.manifest.as_ref().map(|m| m.machine.memory_bytes as f64);
    let (mut over, mut under, mut skipped) = (0, 0, 0);
    let mut reps: Option<usize> = None;
    let an = Analysis::from_rows(&c.rows, None, o);
    for n in [4usize, 6, 8] {
        for opt in ["o3", "o0"] {
            let key = CellKey::new(4, AE, opt, n);
            let Some(cell) = an.cells.get(&key) else { continue };
            let measured = an.memory(&key, o).map(|e| {
                reps = Some(reps.map_or(e.reps, |r| r.min(e.reps)));
                e.value
            });
            let (bytes, how) = match measured {
                Some(b) => (b, "measured peak"),
                None if cell.mem_estimate > 0 => (cell.mem_estimate as f64, "guard estimate"),
                None => continue,
            };
            let skipped_mem =
                cell.not_ok.iter().any(|(s, r)| *s == Status::Skipped && r.to_ascii_lowercase().contains("memory"));
            if skipped_mem {
                skipped += 1;
            }
            if bytes > PAPER_MEMORY_BYTES {
                over += 1;
            } else {
                under += 1;
            }
            ev.push(format!(
                "Model4 AE {} {n} threads: {how} {}{}",
                opt.to_uppercase(),
                gb(bytes),
                if skipped_mem { " (skipped here: memory guard)" } else { "" }
            ));
        }
    }
    if let Some(one) =
        an.memory(&CellKey::new(4, AE, "o3", 1), o).or_else(|| an.memory(&CellKey::new(4, AE, "o0", 1), o))
    {
        ev.push(format!(
            "Model4 AE at 1 thread: {}; at the paper's footprint (4.61 GB at 1 thread) a configuration needs more than 8 GB when it grows by more than {:.2}x",
            gb(one.value),
            PAPER_MEMORY_BYTES / 4.61e9
        ));
    }
    if let Some(m) = mem {
        ev.push(format!("this machine: {} of memory; the paper's: 8 GB", gb(m)));
    }
    let (v, reason) = if over + under == 0 {
        (Verdict::CannotTell, "no Model4 AE run (or estimate) at 4, 6 or 8 threads".into())
    } else if over > 0 && under == 0 {
        (
            Verdict::Holds,
            format!("every Model4 AE configuration at 4-8 threads needs more than 8 GB ({skipped} skipped here by the memory guard)"),
        )
    } else if over > 0 {
        (
            Verdict::DoesNotHold,
            format!(
                "only in part: {over} of {} Model4 AE configurations at 4-8 threads need more than 8 GB, the others would fit ({skipped} skipped here)",
                over + under
            ),
        )
    } else {
        (Verdict::DoesNotHold, "every Model4 AE configuration at 4-8 threads fits in 8 GB".into())
    };
    result("C6", v, reason, ev).with_reps(reps)
}

fn gb(b: f64) -> String {
    format!("{:.2} GiB", b / (1u64 << 30) as f64)
}

/// Evaluate C1-C7 on a campaign.
pub fn evaluate(c: &Campaign, an: &Analysis) -> Vec<ClaimResult> {
    let o = StatsOptions::default();
    vec![c1(an), c2(an, &o), c3(an), c4(an), c5(c), c6(c, &o), c7::c7(c, an)]
}

/// A plain-text table with the evidence below it.
pub fn table(results: &[ClaimResult]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "{:<4} {:<26} reason", "", "verdict");
    for r in results {
        let _ = writeln!(s, "{:<4} {:<26} {}", r.id, r.verdict_label(), r.reason);
    }
    for r in results {
        let _ = writeln!(s, "\n{} {}", r.id, r.text);
        for e in &r.evidence {
            let _ = writeln!(s, "    {e}");
        }
    }
    s
}

/// The same as Markdown (a table, then the evidence per claim). `heading` is the level of
/// the evidence headings (e.g. `###`).
pub fn markdown(results: &[ClaimResult], heading: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "| claim | statement | verdict | reason |\n|---|---|---|---|");
    for r in results {
        let _ = writeln!(s, "| {} | {} | **{}** | {} |", r.id, r.text, r.verdict_label(), r.reason.replace('|', "\\|"));
    }
    for r in results {
        let _ = writeln!(s, "\n{heading} {}: {}\n", r.id, r.verdict_label());
        if r.evidence.is_empty() {
            let _ = writeln!(s, "(no numbers)");
        }
        for e in &r.evidence {
            let _ = writeln!(s, "- {e}");
        }
    }
    s
}

/// The warning when some measured cells have fewer than [`MIN_REPS`] repetitions (processes,
/// for paired cells): their verdicts are indicative (`None` when every cell has enough).
pub fn few_repetitions(an: &Analysis) -> Option<String> {
    let few: Vec<(String, usize)> = an
        .cells
        .iter()
        .map(|(k, c)| (k.to_string(), c.times[0].len()))
        .filter(|&(_, n)| n > 0 && n < MIN_REPS)
        .collect();
    let least = few.iter().map(|(_, n)| *n).min()?;
    Some(format!(
        "{} of {} measured cell(s) have fewer than {MIN_REPS} repetitions (as few as {least}, e.g. {}): no interval covers \
         the run-to-run spread there, and every verdict resting on them is marked indicative; run the campaign with \
         --reps {MIN_REPS} or more",
        few.len(),
        an.cells.values().filter(|c| c.measured()).count(),
        few[0].0
    ))
}

/// A campaign with no `ok` row of one process that the selection rule kept has nothing to
/// judge: an error naming its rows by status and what the rule left out, never a table of
/// "cannot tell" with exit status 0.
fn refuse_without_usable_rows(parts: &[Campaign]) -> Result<()> {
    if parts.iter().any(|c| c.rows.iter().any(|r| r.outcome.status == Status::Ok)) {
        return Ok(());
    }
    let mut by_status: BTreeMap<&str, usize> = BTreeMap::new();
    for r in parts.iter().flat_map(Campaign::all_rows) {
        *by_status.entry(r.outcome.status.as_str()).or_default() += 1;
    }
    let mut had: Vec<String> = by_status.iter().map(|(s, n)| format!("{n} {s}")).collect();
    had.extend(parts.iter().flat_map(|c| &c.left_out).map(|l| format!("left out: {}", l.describe())));
    let dir = parts.first().map_or_else(String::new, |c| c.dir.display().to_string());
    bail!(
        "campaign {dir} has no usable row (one process, status ok) to judge the claims on ({}): run it to the \
         end (`mpm-bench run` resumes it), or see the `reason` column of its runs.csv for why its runs did not \
         finish",
        if had.is_empty() { "it has no rows".to_string() } else { had.join(", ") }
    )
}

/// `mpm-bench claims`: the claims of each machine's runs (a campaign of several machines,
/// under a scheduler, gets a verdict per machine; with `--markdown`, one section each). A
/// campaign without a usable row is an error.
pub fn run(args: ClaimsOptions) -> Result<()> {
    let parts =
        load_campaigns(&args.results, &RowFilter::analysis(args.include_noisy).with_injected(args.include_injected))?;
    refuse_without_usable_rows(&parts)?;
    let mut text = String::new();
    for c in &parts {
        c.note_left_out("claims");
        c.note_hybrid_left_out("claims");
        let an = c.analyse(args.pin.as_deref());
        let res = evaluate(c, &an);
        println!("Claims of the paper on campaign {} (machine {}, {})", c.id(), c.fingerprint(), c.dir.display());
        for n in &an.notes {
            println!("note: {n}");
        }
        if let Some(w) = few_repetitions(&an) {
            eprintln!("warning: {w}");
        }
        print!("{}", table(&res));
        print!("{}", strategies::text(&an));
        if parts.len() > 1 {
            println!();
            let _ = writeln!(text, "## Machine `{}`\n", c.fingerprint());
            text.push_str(&markdown(&res, "###"));
            text.push_str(&strategies::markdown(&an, "###"));
            text.push('\n');
        } else {
            text.push_str(&markdown(&res, "##"));
            text.push_str(&strategies::markdown(&an, "##"));
        }
    }
    if let Some(md) = &args.markdown {
        let c = &parts[0];
        let machines: Vec<String> = parts.iter().map(|p| format!("`{}`", p.fingerprint())).collect();
        let head = format!(
            "# The paper's claims on campaign `{}`\n\n{} {}; results `{}`; made with `mpm-bench claims --results {}`.\n\n",
            c.id(),
            if parts.len() > 1 { "Machines (each judged on its own runs)" } else { "Machine" },
            machines.join(", "),
            c.dir.display(),
            args.results.display()
        );
        if let Some(parent) = md.parent().filter(|p| !p.as_os_str().is_empty()) {
            std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
        }
        std::fs::write(md, head + &text)
            .with_context(|| format!("cannot write {}: choose a writable --markdown path", md.display()))?;
        println!("wrote {}", md.display());
    }
    Ok(())
}

/// C7 (this study's claim, not the paper's): balanced cuts (`dd-balanced`) against uniform cuts (`dd`).
/// Kept apart from C1-C6: it reads the recorded work imbalance straight from the rows.
mod c7 {
    use super::{result, ClaimResult, Tally, Verdict, DD};
    use crate::analysis::results::Campaign;
    use crate::analysis::stats::{tag, Analysis, Stage};
    use crate::campaign::store::record::Status;
    use crate::util::median;
    use mpm_core::Strategy;

    const DDB: Strategy = Strategy::DdBalanced;

    /// Work imbalances closer than this are equal (they are deterministic, not noisy).
    const SAME_IMBALANCE: f64 = 0.005;

    /// Median recorded work imbalance of the ok rows of `model` at `threads` with `s`
    /// (any optimisation level and pinning: the counts depend on neither).
    fn work_imbalance(c: &Campaign, model: u32, s: Strategy, threads: usize) -> Option<f64> {
        let v: Vec<f64> = c
            .rows
            .iter()
            .filter(|r| {
                r.outcome.status == Status::Ok && r.model() == model && r.strategy() == s && r.threads() == threads
            })
            .filter_map(|r| r.measured.as_ref()?.balance.dd_patch_particles.map(|p| p.imbalance_mean))
            .collect();
        (!v.is_empty()).then(|| median(&v))
    }

    /// The imbalance part, at every thread count both strategies ran (oversubscribed too).
    fn imbalance_part(c: &Campaign, an: &Analysis) -> (usize, usize, Vec<String>) {
        let (mut better, mut worse, mut lines) = (0, 0, Vec::new());
        for m in an.models() {
            for n in an.thread_counts().into_iter().filter(|&n| n > 1) {
                let (Some(u), Some(b)) = (work_imbalance(c, m, DD, n), work_imbalance(c, m, DDB, n)) else {
                    continue;
                };
                let verdict = if b < u - SAME_IMBALANCE {
                    better += 1;
                    "supports"
                } else if b > u + SAME_IMBALANCE {
                    worse += 1;
                    "contradicts"
                } else {
                    "equal"
                };
                lines.push(format!(
                    "Model{m}, {n} threads, work imbalance: {} {u:.3} vs {} {b:.3} -> {verdict}",
                    tag(DD),
                    tag(DDB)
                ));
            }
        }
        (better, worse, lines)
    }

    pub(super) fn c7(c: &Campaign, an: &Analysis) -> ClaimResult {
        let (better, worse, mut ev) = imbalance_part(c, an);
        // Time: only real parallel points (threads <= cores), total step at O3.
        let mut time = Tally::default();
        for m in an.models() {
            for p in an.series(m, DD, "o3", Stage::Total).into_iter().filter(|p| p.is_real_parallel()) {
                let n = p.key.threads;
                let Some(q) = an.point(m, DDB, "o3", n, Stage::Total).filter(|q| q.is_real_parallel()) else {
                    continue;
                };
                time.add(format!("Model{m}, {n} threads, s/step"), &tag(DD), &p.time, &tag(DDB), &q.time);
            }
        }
        let (tv, treason) = time.verdict("DD and DD-BALANCED at O3");
        ev.extend(time.lines);
        let imb = format!("work imbalance lower in {better}, higher in {worse} configuration(s)");
        let (v, reason) = match (better, worse, tv) {
            (0, 0, _) => (
                Verdict::CannotTell,
                format!("no dd and dd-balanced rows with recorded work imbalance; time: {treason}"),
            ),
            (_, w, _) if w > 0 => (Verdict::DoesNotHold, format!("{imb}; time: {treason}")),
            (_, _, Verdict::DoesNotHold) => (Verdict::DoesNotHold, format!("{imb}; but time: {treason}")),
            (_, _, Verdict::Holds) => (Verdict::Holds, format!("{imb}; time: {treason}")),
            (_, _, Verdict::CannotTell) => {
                (Verdict::CannotTell, format!("{imb}, but the time per step cannot tell: {treason}"))
            }
        };
        result("C7", v, reason, ev).with_reps(time.min_reps)
    }
}
