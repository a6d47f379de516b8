//! `mpm resume DIR`: continue a run from the newest checkpoint in its folder.
//!
//! Before anything is built or written, the checkpoint is chosen and checked: a folder
//! without checkpoints, a damaged newest checkpoint (then the older one is offered, and
//! `--older` takes it), a checkpoint of another `mpm` binary or of another spec than
//! `--spec FILE`, and a rank count other than the launcher's are refused with a message
//! that says what to do; nothing in the folder or the outputs is touched. Then every rank
//! reads its own file (checksum checked), the scenario is built without its particles, and
//! the simulation and the program's state are taken back by the same set-up as a fresh
//! run's ([`crate::start::start`] from [`Origin::Checkpoint`]); the run goes on through the
//! same loop, its set-up time booked as the restart's.

use crate::checkpointing::Saved;
use crate::cli::ResumeCmd;
use crate::paths::{check_outputs, Named};
use crate::ranks::Ranks;
use crate::start::{start, Origin, Restart};
use anyhow::{bail, Context, Result};
use mpm_cli::distributed::launcher_ranks;
use mpm_core::Collectives;
use mpm_host::checkpoint::{read_file, read_header, Damage, Entry, Folder, Header, Loaded};
use mpm_host::lock::FolderLock;
use mpm_spec::RunSpec;
use std::path::Path;
use std::time::{Duration, Instant};

/// How long `mpm resume` waits for another process to release the checkpoint folder.
const LOCK_WAIT: Duration = Duration::from_secs(60);

/// Every file of the checkpoint `entry` read and checked (what a refusal offers instead of a
/// damaged one must be usable).
fn intact(entry: &Entry, ranks: usize) -> Result<(), Damage> {
    (0..ranks).try_for_each(|r| read_file(&entry.rank_file(r)).map(|_| ()))
}

/// The refusal of a folder with no checkpoint in it.
fn not_a_checkpoint_folder(dir: &Path) -> anyhow::Error {
    if !dir.exists() {
        return anyhow::anyhow!(
            "{} does not exist: give the folder the run wrote its checkpoints into (its --checkpoint-dir)",
            dir.display()
        );
    }
    if !dir.is_dir() {
        return anyhow::anyhow!(
            "{} is a file, not a checkpoint folder: give the folder the run wrote its checkpoints into (its --checkpoint-dir)",
            dir.display()
        );
    }
    let partial = std::fs::read_dir(dir)
        .map(|rd| rd.flatten().any(|e| e.file_name().to_string_lossy().ends_with(".partial")))
        .unwrap_or(false);
    if partial {
        return anyhow::anyhow!(
            "{} holds no complete checkpoint, only one whose writing was interrupted: the run stopped before its first \
             checkpoint was on disk, so start it again (mpm run ...)",
            dir.display()
        );
    }
    anyhow::anyhow!(
        "{} is not a checkpoint folder of mpm: it holds no checkpoint (step-NNNNNNNNNN/ folders); give the folder the \
         run wrote its checkpoints into (its --checkpoint-dir)",
        dir.display()
    )
}

/// The refusal of a damaged newest checkpoint, offering the older one when it is intact.
fn damaged_newest(dir: &Path, newest: &Entry, why: &str, older: Option<&Entry>, ranks: usize) -> anyhow::Error {
    let offer = match older {
        Some(o) => match intact(o, ranks) {
            Ok(()) => format!(
                "; the older checkpoint {} (step {}) is intact: continue from it with `mpm resume {} --older` (the \
                 damaged one is then kept as {}/damaged-step-{:010})",
                o.path.display(),
                o.step,
                dir.display(),
                dir.display(),
                newest.step
            ),
            Err(e) => format!("; the older checkpoint is damaged too ({e}): nothing to continue from"),
        },
        None => "; there is no older checkpoint to continue from".into(),
    };
    anyhow::anyhow!("the newest checkpoint {} cannot be used: {why}{offer}", newest.path.display())
}

/// The two specs' keys that differ (leaves of their JSON), for a refusal.
fn differing_keys(a: &RunSpec, b: &RunSpec) -> Vec<String> {
    fn leaves(prefix: &str, v: &serde_json::Value, out: &mut Vec<(String, String)>) {
        match v {
            serde_json::Value::Object(m) => {
                for (k, x) in m {
                    leaves(&if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") }, x, out);
                }
            }
            _ => out.push((prefix.to_string(), v.to_string())),
        }
    }
    let (mut x, mut y) = (Vec::new(), Vec::new());
    leaves("", &serde_json::to_value(a).unwrap_or_default(), &mut x);
    leaves("", &serde_json::to_value(b).unwrap_or_default(), &mut y);
    let mut keys: Vec<String> = x.iter().chain(&y).map(|(k, _)| k.clone()).collect();
    keys.sort();
    keys.dedup();
    keys.retain(|k| x.iter().find(|(q, _)| q == k) != y.iter().find(|(q, _)| q == k));
    keys
}

/// The spec of what is computed: no outputs, no CPUs.
fn computed(spec: &RunSpec) -> RunSpec {
    RunSpec { outputs: Default::default(), cpus: None, ..spec.clone() }
}

/// The checkpoint to continue from: the newest, or with `older` the one before it (which
/// the caller checks is needed). Refuses a folder without checkpoints and, without `older`,
/// a newest checkpoint whose rank-0 header does not read. Returns it with its rank-0
/// header's rank count, and the newest when it is passed over.
fn choose(cmd: &ResumeCmd) -> Result<(Entry, usize, Option<Entry>)> {
    if !cmd.dir.is_dir() {
        return Err(not_a_checkpoint_folder(&cmd.dir));
    }
    let entries = Folder::new(&cmd.dir).list()?;
    let Some(newest) = entries.last().cloned() else { return Err(not_a_checkpoint_folder(&cmd.dir)) };
    let older = entries.len().checked_sub(2).map(|i| entries[i].clone());
    if cmd.older {
        let Some(o) = older else {
            bail!(
                "--older: {} holds one checkpoint only (step {}); resume without --older",
                cmd.dir.display(),
                newest.step
            )
        };
        let h = read_header(&o.rank_file(0))
            .map_err(|e| anyhow::anyhow!("the older checkpoint is damaged too ({e}): nothing to continue from"))?;
        return Ok((o, h.ranks, Some(newest)));
    }
    match read_header(&newest.rank_file(0)) {
        Ok(h) => Ok((newest, h.ranks, None)),
        Err(e) => {
            let ranks = older.as_ref().and_then(|o| read_header(&o.rank_file(0)).ok()).map_or(1, |h| h.ranks);
            Err(damaged_newest(&cmd.dir, &newest, &e.to_string(), older.as_ref(), ranks))
        }
    }
}

/// Each rank's `ok`, combined (collective): how many ranks failed.
fn failures(ranks: &mut dyn Collectives, ok: bool) -> Result<u64> {
    let mut n = [u64::from(!ok)];
    ranks.sum_counts(&mut n)?;
    Ok(n[0])
}

/// `mpm resume DIR ...`.
pub fn resume(cmd: ResumeCmd, _command_line: Vec<String>) -> Result<()> {
    let t0 = Instant::now();
    // The rank count, from the checkpoint as it is now (before MPI starts).
    let (peek, ranks_needed, _) = choose(&cmd)?;
    launched_as_written(&cmd, &peek, ranks_needed)?;
    let mut ranks = Ranks::start(Some(ranks_needed))?;
    let rank = ranks.rank();
    let _lock = hold_folder(&cmd, &mut ranks)?;
    let (pick, _, passed_over) = choose(&cmd)?;
    let loaded = load(&cmd, &pick, passed_over.as_ref(), ranks_needed, &mut ranks)?;
    let binary_sha256 = check_writer(&loaded.header, &pick, &ranks)?;
    let saved = Saved::from_table(loaded.header.state.clone())?;
    let spec = continued_spec(&cmd, saved.spec.clone())?;
    let mut inputs = vec![Named::folder("the checkpoint folder", &cmd.dir)];
    inputs.extend(cmd.spec.as_deref().map(|f| Named::file("the spec file --spec", f)));
    check_outputs(&spec, &inputs, Some(&cmd.dir))?;
    if let (Some(newest), 0) = (&passed_over, rank) {
        let aside = Folder::new(&cmd.dir).set_aside(newest)?;
        eprintln!("note: the damaged checkpoint {} is kept as {}", newest.path.display(), aside.display());
    }
    let restart = Restart { loaded, saved, binary_sha256, t0 };
    start(spec, cmd.force, Origin::Checkpoint(Box::new(restart)), &mut ranks)
}

/// Refuse a launch over another rank count than the checkpoint `peek`'s (`ranks_needed`),
/// saying how to launch it.
fn launched_as_written(cmd: &ResumeCmd, peek: &Entry, ranks_needed: usize) -> Result<()> {
    let launched = launcher_ranks().unwrap_or(1);
    if launched != ranks_needed {
        let how = if ranks_needed == 1 {
            format!("without mpirun (`mpm resume {}`)", cmd.dir.display())
        } else {
            format!("with `mpirun -n {ranks_needed} mpm resume {}`", cmd.dir.display())
        };
        bail!(
            "the checkpoint {} was written by a run over {ranks_needed} rank(s) and this process is one of {launched}: \
             continue it {how}",
            peek.path.display()
        );
    }
    Ok(())
}

/// Rank 0 holds the folder from here on: a run still writing into it (the ranks of a run
/// killed with its launcher end a moment after it) is waited for. Then the choice of the
/// checkpoint is final. Every rank fails when rank 0 cannot lock it.
fn hold_folder(cmd: &ResumeCmd, ranks: &mut Ranks) -> Result<Option<FolderLock>> {
    let lock =
        if ranks.rank() == 0 { Some(Folder::new(&cmd.dir).lock(LOCK_WAIT).map_err(anyhow::Error::from)) } else { None };
    if failures(ranks.collectives(), lock.as_ref().is_none_or(Result::is_ok))? > 0 {
        return Err(lock
            .and_then(Result::err)
            .unwrap_or_else(|| anyhow::anyhow!("rank 0 cannot lock the checkpoint folder")));
    }
    lock.transpose()
}

/// Every rank reads its own file of the checkpoint `pick`, checked; all ranks refuse
/// together, offering the older checkpoint for a damaged newest one. `--older`
/// (`passed_over`: the newest) only when the newest is damaged.
fn load(
    cmd: &ResumeCmd,
    pick: &Entry,
    passed_over: Option<&Entry>,
    ranks_needed: usize,
    ranks: &mut Ranks,
) -> Result<Loaded> {
    let rank = ranks.rank();
    let loaded = read_file(&pick.rank_file(rank));
    let failed = failures(ranks.collectives(), loaded.is_ok())?;
    let loaded: Loaded = match loaded {
        Ok(l) if failed == 0 => l,
        Ok(_) => bail!(
            "the checkpoint {} cannot be used: another rank's file is damaged (see its message)",
            pick.path.display()
        ),
        Err(e) if passed_over.is_some() => bail!("the older checkpoint is damaged too ({e}): nothing to continue from"),
        Err(e) => {
            let older = Folder::new(&cmd.dir).list()?.into_iter().rev().nth(1);
            return Err(damaged_newest(&cmd.dir, pick, &e.to_string(), older.as_ref(), ranks_needed));
        }
    };
    if let Some(newest) = passed_over {
        // --older only when the newest is damaged: an intact one is the run's latest state.
        let damaged = read_file(&newest.rank_file(rank)).is_err();
        if failures(ranks.collectives(), !damaged)? == 0 {
            bail!(
                "--older: the newest checkpoint {} is intact; continue from it (resume without --older)",
                newest.path.display()
            );
        }
    }
    Ok(loaded)
}

/// Refuse a checkpoint file written by another binary (it would not continue the run bit
/// for bit) or for another rank; returns this binary's SHA-256.
fn check_writer(header: &Header, pick: &Entry, ranks: &Ranks) -> Result<String> {
    let rank = ranks.rank();
    let this_binary = mpm_host::identity::this_binary_sha256();
    if header.binary_sha256 != this_binary {
        bail!(
            "the checkpoint {} was written by another mpm binary (version {}, commit {}, sha256 {}...); this one is \
             version {}, commit {}, sha256 {}...: it would not continue the run bit for bit. Resume with the binary that \
             wrote it",
            pick.path.display(),
            header.mpm_version,
            header.git_commit,
            header.binary_sha256.chars().take(16).collect::<String>(),
            mpm_cli::summary::VERSION,
            mpm_host::identity::GIT_COMMIT,
            this_binary.chars().take(16).collect::<String>()
        );
    }
    if header.rank != rank || header.ranks != ranks.size() {
        bail!(
            "{} is rank {}'s file of {} ranks, read by rank {rank} of {}",
            pick.rank_file(rank).display(),
            header.rank,
            header.ranks,
            ranks.size()
        );
    }
    Ok(this_binary)
}

/// The spec the continued run runs: the checkpoint's, with `--spec FILE`'s outputs and CPUs
/// (refused when FILE computes something else), or with the command's overrides; its
/// checkpoints go on into the folder resumed from.
fn continued_spec(cmd: &ResumeCmd, saved: RunSpec) -> Result<RunSpec> {
    let mut spec = saved;
    if let Some(file) = &cmd.spec {
        let mut asked = RunSpec::read(file).with_context(|| format!("cannot read the spec {}", file.display()))?;
        if asked.budget.warmup.is_none() {
            asked.budget.warmup = spec.budget.warmup;
        }
        let differ = differing_keys(&computed(&spec), &computed(&asked));
        if !differ.is_empty() {
            bail!(
                "the checkpoint in {} is of another run than {}: they differ in {}. Give each run a checkpoint folder of \
                 its own, or run {} afresh",
                cmd.dir.display(),
                file.display(),
                differ.join(", "),
                file.display()
            );
        }
        spec.outputs = asked.outputs;
        spec.cpus = asked.cpus;
    } else {
        if let Some(c) = &mut spec.outputs.checkpoint {
            c.dir.clone_from(&cmd.dir);
        }
        let changed =
            cmd.strategy.is_some_and(|s| s != spec.strategy) || cmd.threads.is_some_and(|t| t != spec.threads);
        spec.strategy = cmd.strategy.unwrap_or(spec.strategy);
        spec.threads = cmd.threads.unwrap_or(spec.threads);
        match cmd.cpus.as_deref() {
            Some("none") => spec.cpus = None,
            Some(list) => spec.cpus = Some(mpm_host::pinning::parse_cpu_list(list).context("invalid --cpus")?),
            None if changed && spec.cpus.as_ref().is_some_and(|c| c.len() != spec.threads) => {
                eprintln!(
                    "note: the run's CPU list was for {} thread(s): continuing unpinned (give --cpus)",
                    saved_threads(&spec)
                );
                spec.cpus = None;
            }
            None => {}
        }
    }
    if cmd.json.is_some() {
        spec.outputs.json.clone_from(&cmd.json);
    }
    spec.outputs.quiet |= cmd.quiet;
    spec.check().context("the continued run's spec")?;
    Ok(spec)
}

/// The thread count a CPU list was given for.
fn saved_threads(spec: &RunSpec) -> usize {
    spec.cpus.as_ref().map_or(spec.threads, Vec::len)
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_spec::scenario::TaylorSpec;

    #[test]
    fn differing_keys_name_the_leaves() {
        let a = RunSpec::new(mpm_spec::Scenario::Taylor(TaylorSpec::model(1))).unwrap();
        let mut b = a.clone();
        b.threads = 2;
        b.budget.steps = Some(7);
        assert_eq!(differing_keys(&a, &b), ["budget.steps", "threads"]);
        assert!(differing_keys(&a, &a).is_empty());
        b = a.clone();
        b.outputs.json = Some("x.json".into());
        b.cpus = Some(vec![0]);
        assert!(differing_keys(&computed(&a), &computed(&b)).is_empty());
    }
}
