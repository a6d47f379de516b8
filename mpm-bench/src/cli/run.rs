//! `mpm-bench run`: its arguments, resolved into a campaign (the preset and the overrides)
//! and a scheduler, then run.

use crate::bad_input;
use anyhow::{Context, Result};
use clap::Args;
use mpm_bench::campaign::exec::process::{MockRunner, ProcessRunner};
use mpm_bench::campaign::exec::solver::{self, Solver};
use mpm_bench::campaign::exec::watch::WatchSettings;
use mpm_bench::campaign::plan::matrix::{Campaign, Overrides};
use mpm_bench::campaign::plan::preset::{self, OptLevel};
use mpm_bench::campaign::schedule::kind::check_sbatch_arg;
use mpm_bench::campaign::schedule::slurm::SlurmOptions;
use mpm_bench::campaign::schedule::{self, ExecOptions, ExecSummary, SchedulerKind};
use mpm_bench::campaign::store::disk;
use mpm_bench::machine::placement::{PinPolicy, Places};
use mpm_bench::machine::topology::Machine;
use mpm_core::Strategy;
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

#[derive(Args, Debug)]
pub struct RunArgs {
    /// Preset: smoke, quick, paper, impact, balanced, strategies (configs/<name>.toml), or a
    /// path to a TOML file.
    #[arg(long, short = 'p', value_name = "NAME|FILE")]
    preset: String,
    /// Models to run, comma list of 1-4 (replaces the preset's).
    #[arg(long, value_name = "LIST")]
    models: Option<String>,
    /// Thread counts, comma list (e.g. 1,2,4,6,8); per rank when --ranks is above 1.
    #[arg(long, value_name = "LIST")]
    threads: Option<String>,
    /// MPI rank counts, comma list (e.g. 1,2). 1 runs `mpm` directly; more start it through
    /// the launcher, with `mpm run --split-wait`: the rows' comm_s_per_step and comm_frac are
    /// then the communication alone and wait_s_per_step and wait_frac the waiting for other
    /// ranks (each the largest over ranks; empty at one rank). A run occupies ranks x threads
    /// workers (what oversubscription counts).
    #[arg(long, value_name = "LIST")]
    ranks: Option<String>,
    /// Launcher of runs with several ranks: a command with {ranks} (and optionally {threads},
    /// threads per rank), split on spaces, no shell. Default: MPM_BENCH_LAUNCHER, else the
    /// preset's launcher, else "mpirun --bind-to none -n {ranks}". As root or with more
    /// ranks than cores, Open MPI needs "--allow-run-as-root" / "--oversubscribe" in it.
    #[arg(long, value_name = "TEMPLATE")]
    launcher: Option<String>,
    /// Strategies, comma list of serial, ae (array expansion), dd (domain decomposition),
    /// dd-balanced (DD with cuts at the particle-count quantiles), colour (block colouring),
    /// atomic (atomic adds); or `all`: every parallel strategy of this solver build.
    #[arg(long, value_name = "LIST")]
    strategies: Option<String>,
    /// Optimisation levels, comma list of o3, o0.
    #[arg(long, value_name = "LIST")]
    opt: Option<String>,
    /// Repetitions of every configuration.
    #[arg(long, value_name = "N")]
    reps: Option<u32>,
    /// Binding (OpenMP proc_bind over --places): close (consecutive places: fills a socket
    /// first), spread (threads spread evenly over the places), primary (all on the first
    /// place), none (not pinned), or a CPU list such as 0,1 or 0-3. Repeat for several
    /// policies. `--pin` is an alias; `compact` and `scatter` mean close and spread.
    #[arg(long, visible_alias = "pin", value_name = "POLICY")]
    bind: Vec<String>,
    /// OpenMP place list of every binding: threads, cores (default), ll_caches,
    /// numa_domains, sockets. See `mpm-bench topology --places ...` for where workers go.
    #[arg(long, value_name = "PLACES")]
    places: Option<Places>,
    /// Stop every run after N steps (replaces every budget of the preset).
    #[arg(long, value_name = "N", conflicts_with = "end_time")]
    steps: Option<u64>,
    /// Stop every run at this simulated time: seconds (4e-5) or with a unit (40us).
    #[arg(long, value_name = "TIME")]
    end_time: Option<String>,
    /// Warm-up steps (timed, excluded from the steady-state time per step).
    #[arg(long, value_name = "K")]
    warmup: Option<u64>,
    /// Grid mode: fixed, adaptive, or sparse (the adaptive grid storing only the blocks of
    /// nodes the particles touch: the same results, less memory; one process only).
    #[arg(long, value_name = "MODE")]
    grid: Option<String>,
    /// Treat the machine as having at most this much memory (e.g. 8GiB) for the memory
    /// guard: runs that would not fit are recorded as skipped.
    #[arg(long, value_name = "SIZE")]
    mem_limit: Option<String>,
    /// Every run saves its state this often, as steps (`500`) or wall-clock time (`10m`)
    /// (default: the preset's `checkpoint_every`, else none), into
    /// <campaign>/checkpoints/<run>/: a run killed, timed out or interrupted continues from
    /// its last checkpoint when the campaign resumes, and its row records the restarts and
    /// the compute time lost. A finished run's checkpoints are removed.
    #[arg(long, value_name = "N|DURATION", value_parser = mpm_spec::spec::CheckpointEvery::parse)]
    checkpoint_every: Option<mpm_spec::spec::CheckpointEvery>,
    /// Root folder of the results tree. The default, results/local, is not tracked by git:
    /// the committed reference campaigns under results/<fingerprint>/ are never written.
    #[arg(long, value_name = "DIR", default_value = "results/local")]
    out: PathBuf,
    /// Seed of the shuffled run order (default: the preset's). Recorded in every row.
    #[arg(long, value_name = "N")]
    seed: Option<u64>,
    /// Print the runs that would run (CPUs, memory estimate, skips) and exit.
    #[arg(long)]
    dry_run: bool,
    /// With --dry-run: first time one short calibration run per optimisation level and print
    /// the campaign's estimated duration, as a real run prints it when it starts (needs the
    /// solvers: built unless --no-build).
    #[arg(long, requires = "dry_run")]
    estimate: bool,
    /// With --dry-run: plan and estimate (implies --estimate) as for a machine of N usable
    /// cores, e.g. the many-core machine a campaign is meant for: its speed-up in the
    /// estimate, and with skip_above_cores (or --skip-above-cores) its cap on thread counts.
    /// The speed per core is still this machine's.
    #[arg(long, value_name = "N", requires = "dry_run", value_parser = clap::value_parser!(u64).range(1..))]
    assume_cores: Option<u64>,
    /// Leave out the runs whose workers (ranks x threads) are more than this machine's usable
    /// cores, saying which thread counts, instead of running them oversubscribed (what a
    /// preset's `skip_above_cores = true` does). Not applied under --scheduler slurm, whose
    /// nodes are not this machine.
    #[arg(long)]
    skip_above_cores: bool,
    /// Also run again configurations the memory guard skipped. (Failed and invalid runs are
    /// always run again on resume: a failure is not a result.)
    #[arg(long)]
    retry_failed: bool,
    /// Exit 0 even when a run of this invocation failed, timed out or was invalid (by
    /// default such a campaign exits 1, so a CI job sees it).
    #[arg(long)]
    allow_failures: bool,
    /// When another `mpm-bench run` writes into the same campaign folder, wait for it to
    /// finish (by default this run refuses, naming the other's pid).
    #[arg(long)]
    wait: bool,
    /// Move an existing runs.csv aside and start the campaign over.
    #[arg(long)]
    fresh: bool,
    /// Append to the campaign folder even when its rows came from another machine or
    /// other solver binaries (by default a new folder <id>-2, <id>-3, ... is started).
    /// Reference campaigns are never appended to.
    #[arg(long)]
    resume_foreign: bool,
    /// Do not build the solver; use the existing target/o3/mpm and target/o0/mpm
    /// (or MPM_BENCH_SOLVER_O3 / MPM_BENCH_SOLVER_O0).
    #[arg(long)]
    no_build: bool,
    /// No progress bar or per-run lines (the closing summary still prints).
    #[arg(long, short = 'q')]
    quiet: bool,
    /// Measure the cells of two or more threads in the paired design with N timed blocks per
    /// run: each run is one process in which the T-thread solver and a 1-thread solver of the
    /// same strategy alternate, (steps - warmup) / N steps a block; the repetitions are the
    /// processes of a cell, whose spread the analyses' intervals cover. 0 turns a preset's
    /// paired design off.
    #[arg(long, value_name = "N")]
    paired_blocks: Option<u64>,
    /// TEST KNOB, never for results: every run's workers but the first do extra work so that
    /// its parallel efficiency drops by about the fraction F (`mpm run --inject-slowdown`).
    /// Recorded in every row (`inject_slowdown`) and in the campaign's name; figures, claims
    /// and report refuse such rows unless --include-injected, regress says so in its verdict.
    /// What `mpm-bench calibrate` measures the gate's detection with.
    #[arg(long, value_name = "F")]
    inject_slowdown: Option<f64>,
    /// TEST KNOB, never for results: every run's workers wait after every step so that each
    /// step takes 1 / (1 - F) times as long, the efficiency unchanged (`mpm run
    /// --inject-step-slowdown`). Recorded and refused like --inject-slowdown.
    #[arg(long, value_name = "F")]
    inject_step_slowdown: Option<f64>,
    /// Use a fake solver (testing the harness itself).
    #[arg(long, hide = true)]
    mock: bool,
    /// Where the runs run: local (here, one fresh process after another) or slurm (the runs
    /// as job arrays, one task per run, one array per resource shape, each task on a node
    /// of its own, `sbatch --exclusive`, with `--ntasks` its ranks and `--cpus-per-task` its
    /// threads per rank when several ranks; the results folder and the binaries must be on
    /// a filesystem every node sees). Under Slurm the
    /// campaign folder is <out>/slurm-<cluster>/<campaign>, each row names its node and that
    /// node's machine fingerprint, and the job ids are kept in slurm-jobs.json until the
    /// rows are in: running the same command again collects jobs an earlier invocation
    /// submitted instead of submitting them twice. Ctrl-C cancels the jobs this invocation
    /// submitted (only those).
    #[arg(long, value_enum, default_value_t = SchedulerFlag::Local)]
    scheduler: SchedulerFlag,
    /// Slurm: the partition of every job (default: the cluster's default partition).
    #[arg(long, value_name = "P")]
    partition: Option<String>,
    /// Slurm: the account every job is charged to.
    #[arg(long, value_name = "A")]
    account: Option<String>,
    /// Slurm: the time limit of every job, as sbatch --time takes it (minutes, or
    /// [days-]hours:minutes:seconds). Default: the preset's per-run timeout plus 2 minutes.
    #[arg(long, value_name = "T")]
    time_limit: Option<String>,
    /// Slurm: at most N tasks of each of the campaign's job arrays running at once
    /// (`sbatch --array=...%N`; default: no limit but the cluster's).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    max_jobs: Option<u64>,
    /// Slurm: ask squeue how the jobs are every SECONDS seconds (default 30: sites expect no
    /// faster, many rate-limit slurmctld; the finished rows are looked for more often, on
    /// the filesystem). Below 30 only for a test cluster of your own.
    #[arg(long, value_name = "SECONDS", value_parser = clap::value_parser!(u64).range(1..))]
    poll_interval: Option<u64>,
    /// Slurm: pass this option to sbatch, after the harness's own (so it overrides them);
    /// repeat for several, e.g. --sbatch-arg=--constraint=skylake to keep a scaling study on
    /// one node type, --sbatch-arg=--qos=long, --sbatch-arg=--reservation=R,
    /// --sbatch-arg=--mem=16G. Options the harness relies on (--array, --parsable,
    /// --requeue, --job-name, --output, --error, --chdir, --wrap, --ntasks, --cpus-per-task)
    /// are refused.
    #[arg(long, value_name = "ARG", allow_hyphen_values = true)]
    sbatch_arg: Vec<String>,
    /// Slurm: submit the runs and exit without waiting; run the same command again (without
    /// --detach) to wait for them and collect their rows.
    #[arg(long)]
    detach: bool,
}

/// `--scheduler`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum SchedulerFlag {
    /// Here, one fresh child process after another.
    Local,
    /// Slurm job arrays, one task per run.
    Slurm,
}

fn overrides(a: &RunArgs) -> Result<Overrides> {
    let models = a
        .models
        .as_deref()
        .map(|s| {
            preset::parse_list(s, "model", |m| {
                let m = m.trim_start_matches(|c: char| c.is_ascii_alphabetic());
                m.parse::<u32>().map_err(|_| anyhow::anyhow!("'{m}' is not a model number (1-4)"))
            })
        })
        .transpose()?;
    let counts = |list: Option<&str>, what: &str| {
        list.map(|s| {
            preset::parse_list(s, what, |t| {
                t.parse::<usize>().map_err(|_| anyhow::anyhow!("'{t}' is not a {what} count"))
            })
        })
        .transpose()
    };
    let threads = counts(a.threads.as_deref(), "thread")?;
    let ranks = counts(a.ranks.as_deref(), "rank")?;
    let strategies = a
        .strategies
        .as_deref()
        .map(|s| match s.trim() {
            "all" => Ok(preset::every_parallel_strategy()),
            _ => preset::parse_list(s, "strategy", |x| {
                x.to_ascii_lowercase().parse::<Strategy>().map_err(anyhow::Error::msg)
            }),
        })
        .transpose()?;
    let opt = a
        .opt
        .as_deref()
        .map(|s| preset::parse_list(s, "optimisation level", |x| x.parse::<OptLevel>().map_err(anyhow::Error::msg)))
        .transpose()?;
    let places = a.places.unwrap_or_default();
    let pin = if a.bind.is_empty() {
        None
    } else {
        Some(a.bind.iter().map(|p| PinPolicy::parse_with(p, places)).collect::<Result<Vec<_>>>()?)
    };
    Ok(Overrides {
        models,
        threads,
        ranks,
        launcher: a.launcher.clone(),
        strategies,
        opt,
        reps: a.reps,
        pin,
        places: a.places,
        steps: a.steps,
        end_time: a.end_time.as_deref().map(preset::parse_seconds).transpose()?,
        warmup: a.warmup,
        grid: a.grid.as_deref().map(str::parse::<mpm_core::GridMode>).transpose().map_err(anyhow::Error::msg)?,
        mem_limit: a.mem_limit.as_deref().map(preset::parse_size).transpose()?,
        checkpoint_every: a.checkpoint_every,
        seed: a.seed,
        paired_blocks: a.paired_blocks,
        inject_slowdown: a.inject_slowdown,
        skip_above_cores: a.skip_above_cores,
        inject_step_slowdown: a.inject_step_slowdown,
    })
}

/// `mpm-bench run`; the exit code: 0, or 1 when a run of this invocation failed, timed out
/// or was invalid (unless `--allow-failures`), or 130 when interrupted. Bad input (the
/// preset, the overrides, a pinning policy this machine cannot honour, a Cargo profile
/// variable that names no profile) exits 2 at once. A
/// campaign stopped by a full disk says so and what to do ([`disk::explain_full`]).
pub fn cmd_run(a: RunArgs) -> Result<i32> {
    let ov = overrides(&a).unwrap_or_else(|e| bad_input(e));
    let ws = solver::workspace_root();
    let (preset, source) = preset::load_preset(&a.preset, ws.as_deref()).unwrap_or_else(|e| bad_input(e));
    let mut campaign = Campaign::resolve(preset, source, &ov).unwrap_or_else(|e| bad_input(e));
    if !a.mock {
        for &opt in &campaign.opts {
            solver::cargo_profile(opt).unwrap_or_else(|e| bad_input(e));
        }
    }
    let machine = Machine::detect()?;
    for p in &campaign.pins {
        if let Err(e) = machine.check_policy(p) {
            bad_input(e.context(format!("bad --bind {p}")));
        }
    }
    let scheduler = scheduler_of(&a)?;
    let here = scheduler.runs_here();
    let assume_cores = a.assume_cores.map(|n| usize::try_from(n).unwrap_or(usize::MAX));
    cap_to_cores(&mut campaign, assume_cores.unwrap_or_else(|| machine.num_cores()), here || assume_cores.is_some());
    let interrupted = schedule::install_interrupt_handler();
    let opts = ExecOptions {
        out_root: a.out.clone(),
        dry_run: a.dry_run,
        estimate: a.estimate || assume_cores.is_some(),
        assume_cores,
        retry_failed: a.retry_failed,
        wait_lock: a.wait,
        eta: !a.quiet && !a.mock && !a.dry_run && here,
        fresh: a.fresh,
        resume_foreign: a.resume_foreign,
        watch: Some(WatchSettings::default()),
        quiet: a.quiet,
        command: std::env::args().collect::<Vec<_>>().join(" "),
        scheduler,
    };
    if !a.dry_run {
        check_writable(&a.out)?;
    }
    if !a.quiet {
        eprintln!(
            "campaign {} (preset {} from {}), {} runs, seed {}",
            campaign.id,
            campaign.preset_name,
            campaign.preset_source,
            campaign.expand().len(),
            campaign.seed
        );
    }
    let summary =
        execute_campaign(&a, &campaign, &machine, &opts, &interrupted).map_err(|e| disk::explain_full(e, &a.out))?;
    if !a.dry_run {
        eprintln!("{}", summary.report());
        // Machine-readable (scripts/reproduce.sh reads it): where the results are.
        let dir = std::fs::canonicalize(&summary.dir).unwrap_or(summary.dir.clone());
        println!("campaign folder: {}", dir.display());
    }
    if summary.counts.interrupted {
        return Ok(130);
    }
    let bad = summary.counts.failed + summary.counts.invalid;
    if bad > 0 && !a.dry_run {
        eprintln!(
            "{bad} run(s) of this invocation failed or were invalid (reasons in runs.csv): exit status 1{}",
            if a.allow_failures { ", overridden by --allow-failures" } else { "; resuming runs them again" }
        );
        return Ok(if a.allow_failures { 0 } else { 1 });
    }
    Ok(0)
}

/// With `skip_above_cores` (the preset's or the flag): leave out the cells of more workers
/// than `cores` and say which, or, when the runs do not run here (`applies` false: Slurm's
/// nodes), say that nothing is left out. A campaign with nothing left is bad input.
fn cap_to_cores(campaign: &mut Campaign, cores: usize, applies: bool) {
    if !campaign.skip_above_cores {
        return;
    }
    if !applies {
        eprintln!("note: skip_above_cores is not applied under a scheduler: its nodes are not this machine");
        return;
    }
    let above = campaign.cap_workers(cores).unwrap_or_else(|e| bad_input(e));
    if !above.is_empty() {
        eprintln!("{}", Campaign::cap_note(cores, &above));
    }
}

/// The scheduler `--scheduler` names, with its options; a Slurm option without Slurm, or
/// the mock under Slurm, is bad input (exit 2).
fn scheduler_of(a: &RunArgs) -> Result<SchedulerKind> {
    let slurm_only = [
        ("--partition", a.partition.is_some()),
        ("--account", a.account.is_some()),
        ("--time-limit", a.time_limit.is_some()),
        ("--max-jobs", a.max_jobs.is_some()),
        ("--detach", a.detach),
        ("--poll-interval", a.poll_interval.is_some()),
        ("--sbatch-arg", !a.sbatch_arg.is_empty()),
    ];
    if let Some((flag, _)) = slurm_only.iter().find(|(_, given)| *given && a.scheduler != SchedulerFlag::Slurm) {
        bad_input(anyhow::anyhow!("{flag} is an option of --scheduler slurm"));
    }
    Ok(if a.scheduler == SchedulerFlag::Slurm {
        if a.mock {
            bad_input(anyhow::anyhow!("--mock runs the fake solver in this process: it cannot go to Slurm"));
        }
        for arg in &a.sbatch_arg {
            if let Err(why) = check_sbatch_arg(arg) {
                bad_input(anyhow::anyhow!(why));
            }
        }
        SchedulerKind::Slurm(SlurmOptions {
            cluster: mpm_bench::campaign::schedule::slurm::cluster_name()?,
            partition: a.partition.clone(),
            account: a.account.clone(),
            time_limit: a.time_limit.clone(),
            max_jobs: a.max_jobs.map(|n| usize::try_from(n).unwrap_or(usize::MAX)),
            detach: a.detach,
            poll_interval: a.poll_interval.map(Duration::from_secs),
            sbatch_extra: a.sbatch_arg.iter().map(|s| s.trim().to_string()).collect(),
        })
    } else {
        SchedulerKind::Local
    })
}

/// Run the campaign with the real solver (built unless `--no-build`) or the mock.
fn execute_campaign(
    a: &RunArgs,
    campaign: &Campaign,
    machine: &Machine,
    opts: &ExecOptions,
    interrupted: &Arc<AtomicBool>,
) -> Result<ExecSummary> {
    if a.mock {
        let solvers: Vec<Solver> =
            campaign.opts.iter().map(|&opt| Solver { opt, path: "mock".into(), sha256: "mock".into() }).collect();
        let delay = std::env::var("MPM_BENCH_MOCK_DELAY_MS").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
        let mut r = MockRunner {
            delay: Duration::from_millis(delay),
            fail_when: std::env::var("MPM_BENCH_MOCK_FAIL").ok(),
            ..MockRunner::default()
        };
        schedule::execute(campaign, machine, &solvers, &mut r, opts, interrupted)
    } else {
        let solvers = if a.dry_run && !opts.estimate {
            Vec::new()
        } else {
            solver::prepare_solvers(&campaign.opts, !a.no_build, a.quiet)?
        };
        let mut r = ProcessRunner::new(interrupted.clone());
        schedule::execute(campaign, machine, &solvers, &mut r, opts, interrupted)
    }
}

/// Fail early (before any run starts), with a clear message, when the results root cannot
/// be written.
pub fn check_writable(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create the output folder {}", out.display()))?;
    let probe = out.join(format!(".mpm-bench-write-test-{}", std::process::id()));
    std::fs::write(&probe, b"").with_context(|| {
        format!(
            "the output folder {} is not writable: a campaign runs only into a folder it can write; make it \
             writable, or choose another --out",
            out.display()
        )
    })?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}
