//! `mpm-bench`: runs the MPM parallelisation study's benchmark campaigns and shows the
//! machine's topology. See `mpm-bench --help`.

use anyhow::{Context, Result};
use clap::{Args, Parser, Subcommand};
use mpm_bench::analysis::{calibrate, claims, imbalance, paired, regress};
use mpm_bench::campaign::matrix::{Campaign, Overrides};
use mpm_bench::campaign::paired as paired_measure;
use mpm_bench::campaign::preset::{self, OptLevel};
use mpm_bench::campaign::process::{MockRunner, ProcessRunner};
use mpm_bench::campaign::runner::{self, ExecOptions};
use mpm_bench::campaign::scheduler::{Scheduler, SlurmOptions};
use mpm_bench::campaign::solver::{self, Solver};
use mpm_bench::campaign::watch::WatchSettings;
use mpm_bench::machine::placement::{PinPolicy, Places, PAPER_THREADS};
use mpm_bench::machine::topology::{self, Machine};
use mpm_bench::machine::{bandwidth, fingerprint};
use mpm_bench::report::{comparison, figures, imbalance as imbalance_figure, impact_table, roofline_table};
use mpm_core::Strategy;
use mpm_host::atomic::write_atomic;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Benchmark harness for the explicit MPM parallelisation study (array expansion vs domain
/// decomposition).
#[derive(Parser, Debug)]
#[command(
    name = "mpm-bench",
    version,
    about = "Benchmark campaigns for the explicit MPM parallelisation study (AE vs DD)",
    long_about = "Benchmark campaigns for the explicit MPM parallelisation study.\n\n\
        Runs the paper's matrix (Taylor bar Models 1-4 x threads x strategies AE/DD x \
        optimisation levels O3/O0 x repetitions), each run a fresh `mpm` process pinned the \
        way you ask, and records one CSV row per run plus a manifest of the machine and \
        software under results/local/<machine-fingerprint>/<campaign-id>/.",
    after_help = "Examples:\n  \
        mpm-bench topology                       # this machine and where workers would go\n  \
        mpm-bench run --preset smoke             # ~1 minute check of the whole chain\n  \
        mpm-bench run --preset quick             # every model, few steps (~20 min on 2 cores)\n  \
        mpm-bench run --preset paper             # the paper's full protocol (to 40 us)\n  \
        mpm-bench figures --results results/     # Figures 7-14 of the newest campaign -> paper-figures/\n  \
        mpm-bench claims --results results/      # the paper's claims C1-C6 (and C7) on this machine\n  \
        mpm-bench regress --baseline A --current B   # CI gate on parallel efficiency\n  \
        mpm-bench calibrate --preset ci          # the gate's false-alarm rate and detection power here\n  \
        mpm-bench report --results A --results B --out cmp   # cmp/index.html: B vs A\n  \
        mpm-bench impact-table --results results/impact   # table of the impact runs\n  \
        mpm-bench roofline-table --summary m1.json --bandwidth bw.json   # each sub-stage against its limits\n  \
        mpm-bench imbalance --scenario impact    # DD work imbalance, uniform vs balanced cuts\n\n\
        Run `mpm-bench <command> --help` for every flag of a command."
)]
struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Print the machine as hwloc sees it and the CPU each worker gets under each policy.
    #[command(
        long_about = "Print the machine as hwloc sees it (packages, NUMA nodes, cores, PUs, \
            caches), the OpenMP place list (--places: threads, cores, ll_caches, numa_domains, \
            sockets) and, for 1/2/4/6/8 threads under each binding (--bind: close, spread, \
            primary, none, or a CPU list), the CPU each worker gets, assigned to places exactly \
            as OpenMP 5.2's proc_bind does (close: consecutive places; spread: one thread per \
            subpartition of the place list; primary: all on the first place). Several workers \
            on one place take its PUs in turn, physical cores before SMT siblings. Two workers \
            on one CPU, or more threads than usable PUs, are marked oversubscribed ('*').",
        after_help = "Examples:\n  \
            mpm-bench topology\n  \
            mpm-bench topology --bind 1,0 --threads 1,2,3\n  \
            mpm-bench topology --synthetic \"pack:2 core:4 pu:1\" --threads 2,4,8 --places cores --bind spread\n  \
            mpm-bench topology --synthetic \"pack:1 numa:4 core:4 pu:1\" --places numa_domains\n  \
            mpm-bench topology --synthetic \"pack:2 core:8 pu:2\" --places threads --bind close --bind spread\n  \
            mpm-bench topology --xml results/<fp>/<campaign>/topology.xml\n  \
            mpm-bench topology --export-xml topo.xml"
    )]
    Topology(TopologyArgs),
    /// Run (or resume) a benchmark campaign.
    #[command(
        long_about = "Run (or resume) a benchmark campaign: a preset matrix of models x MPI ranks x threads x \
            strategies x optimisation levels x repetitions x pinning policies, each run a \
            fresh `mpm` child process. The `mpm` binaries are built in the Cargo profiles o3 \
            and o0 first (or located with --no-build). Runs are shuffled with a recorded \
            seed, repetition by repetition, so drift does not bias one cell.\n\n\
            Results go to <out>/<machine-fingerprint>/<campaign-id>/ as runs.csv (one row per \
            run, appended as soon as it ends), manifest.json (machine and software of every \
            session, append-only) and topology.xml. The campaign id is the preset name plus the \
            overrides, so the same command resumes into the same folder: configurations \
            already in runs.csv are skipped. A folder is resumed only when its rows come from \
            this machine (fingerprint) and these solver binaries (SHA-256); otherwise the run \
            says so and starts <campaign-id>-2 (or -3, ...), unless --resume-foreign. \
            Reference campaigns (\"reference\": true in manifest.json) are never resumed. \
            Ctrl-C stops after the current run is cleaned up; every finished run is kept. Runs whose estimated memory does not fit are recorded as skipped; runs with \
            more threads than usable PUs are flagged oversubscribed; runs whose workers were \
            not on the requested CPUs are recorded invalid.",
        after_help = "Examples:\n  \
            mpm-bench run --preset smoke\n  \
            mpm-bench run --preset quick --out /tmp/results\n  \
            mpm-bench run --preset paper --models 1,2 --reps 5\n  \
            mpm-bench run --preset quick --threads 1,2 --pin spread --steps 10\n  \
            mpm-bench run --preset paper --models 4 --mem-limit 8GiB --dry-run   # the paper's 8 GB machine\n  \
            mpm-bench run --preset configs/my.toml --seed 7\n  \
            mpm-bench run --preset hybrid                   # 1-2 MPI ranks x 1-2 threads\n  \
            mpm-bench run --preset hybrid --launcher \"mpirun --bind-to none --oversubscribe --allow-run-as-root -n {ranks}\"\n  \
            mpm-bench run --preset quick --scheduler slurm --partition compute --time-limit 30   # one Slurm job per run\n  \
            mpm-bench run --preset paper --scheduler slurm --max-jobs 20 --detach   # submit and log out; rerun to collect"
    )]
    Run(Box<RunArgs>),
    /// Regenerate the paper's Figures 7-14 (and a memory figure) from a campaign.
    Figures(figures::FiguresArgs),
    /// Check the paper's claims C1-C6 and C7 (balanced cuts) on a campaign: holds / does not hold / cannot tell.
    Claims(claims::ClaimsArgs),
    /// Compare a campaign with a baseline: exit 0 pass, 1 regression or missing cell, 2 error or incomparable.
    Regress(regress::RegressArgs),
    /// Measure the gate itself on this host: its false-alarm rate (A/A) and what it detects (an injected slowdown).
    #[command(
        long_about = "Measure the regression gate on this host: run its campaign (a preset, by default ci) \
            --clean times with the same binary and --injected times with an injected slowdown of known size \
            (--inject-slowdown F: every worker but the first does extra work so that the parallel efficiency \
            drops by F), interleaved in one session; then regress (with --tolerance and --metrics, as the CI \
            job) every pair of clean campaigns (A/A: a failure is a false alarm) and every clean campaign \
            against every injected one (a failure is a detection). Prints and writes calibration.json: \
            aa_comparisons, false_alarms, injected_slowdown, injected_comparisons, detected, \
            min_detectable_change (the smallest efficiency loss in one cell detected with 90 % power, from \
            the clean campaigns' spread), min_detectable_change_pooled (the same for a loss in every cell, \
            found by the gate's mean over the cells), gate_wall_s (the longest campaign plus its regress), the \
            recommended processes per cell and blocks per process, and the coverage of one campaign's \
            intervals on the others. The comparisons reuse campaigns (7 clean give 21 A/A pairs): they are \
            not independent, see the method in the JSON. Run it on a quiet machine of the kind the gate \
            runs on; the same command resumes an interrupted calibration.",
        after_help = "Examples:\n  \
            mpm-bench calibrate                                  # ci preset, 7 clean + 3 injected (10 %) campaigns\n  \
            mpm-bench calibrate --clean 7 --injected 3 --budget 100m --json results/<fp>/calibrate-ci/calibration.json\n  \
            mpm-bench calibrate --preset configs/my-ci.toml --inject-slowdown 0.05 --tolerance 0.03"
    )]
    Calibrate(calibrate::CalibrateArgs),
    /// Hardware report (one HTML page, Markdown, JSON) of a campaign, or several compared with the first.
    Report(comparison::ReportArgs),
    /// Markdown table of the impact runs under a folder, from their JSON summaries.
    ImpactTable(impact_table::ImpactTableArgs),
    /// Markdown roofline table of runs (each sub-stage's bytes, flops and rates), from their JSON summaries.
    RooflineTable(roofline_table::RooflineTableArgs),
    /// Measure the memory-bandwidth ceiling (STREAM triad) per thread count and pinning.
    Bandwidth(bandwidth::BandwidthArgs),
    /// Parallel efficiency as paired ratios of interleaved blocks in one process (noisy hosts).
    #[command(
        long_about = "Parallel efficiency T1 / (T x T_T) measured as paired ratios inside one process.\n\n\
            The serial solver and, for each strategy, its 1-thread and T-thread solver are built \
            from the same Taylor bar model in this process and advance in blocks of a few steps, \
            in rotating order. Block b of every configuration covers the same simulated steps, \
            so the ratio of a 1-thread block to the T-thread block next to it compares the same \
            work under nearly the same host conditions; the result is the median of these ratios \
            with a 95 % bootstrap interval, beside the efficiency of the medians and of the best \
            blocks, the T-thread runs' load imbalance (a worker slowed from outside shows as a \
            value well above 1) and each strategy's 1-thread time against the serial solver. \
            Use it on shared or virtual machines, where separate runs minutes apart drift by \
            more than the effect being measured. Build with --profile o3: the solver runs in \
            this process.",
        after_help = "Examples:\n  \
            mpm-bench paired --model 2                        # AE and DD, 2 threads on CPUs 0,1\n  \
            mpm-bench paired --model 3 --strategies dd --blocks 21 --json dd-m3.json\n  \
            mpm-bench paired --model 2 --strategies dd,dd-balanced --blocks 21   # cost of balanced cuts\n  \
            mpm-bench paired --model 1 --threads 4 --pin 0-3 --block-steps 10"
    )]
    Paired(paired_measure::PairedArgs),
    /// Predicted DD work imbalance of uniform and balanced cuts over a run (no timing).
    #[command(
        long_about = "Predicted work imbalance of DD's patches, uniform cuts (dd) against balanced \
            cuts (dd-balanced), over a run of the scenario.\n\n\
            The scenario runs serially; before every step the particles are cut into one patch \
            per thread, uniformly with each thread count's layout (2x1x1, 2x2x1, 2x1x3, 2x2x2 \
            for 2, 4, 6, 8), and at the particle-count quantiles with the layout dd-balanced \
            chooses that step (the paper's unless another factorisation of the thread count \
            predicts a clearly smaller imbalance, e.g. 4x2x1 for a thin plate), with the \
            solver's own code. The \
            imbalance of a step is the most particles in a patch over the mean per patch. \
            Nothing is timed, so the result means the same on a 2-core machine as on the \
            paper's 8 cores. Prints the table (mean and worst step per thread count) and \
            writes imbalance-<scenario>-m<model>.csv (every step) and .png/.svg under --out.",
        after_help = "Examples:\n  \
            mpm-bench imbalance --scenario impact --threads 2,4,6,8          # small model, to 30.6 us\n  \
            mpm-bench imbalance --scenario taylor --model 2 --steps 200\n  \
            mpm-bench imbalance --scenario impact --steps 50 --out /tmp/imb"
    )]
    Imbalance(imbalance::ImbalanceArgs),
    /// Run one run of a campaign on this node and write its row: what a Slurm job of
    /// `mpm-bench run --scheduler slurm` runs (FILE is json/<run id>.job.json).
    #[command(hide = true)]
    Job {
        /// The job file the harness wrote.
        file: PathBuf,
    },
}

#[derive(Args, Debug)]
struct TopologyArgs {
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

#[derive(Args, Debug)]
struct RunArgs {
    /// Preset: smoke, quick, paper, impact, balanced (configs/<name>.toml), or a path to a
    /// TOML file.
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
    /// dd-balanced (DD with cuts at the particle-count quantiles).
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
    /// Use a fake solver (testing the harness itself).
    #[arg(long, hide = true)]
    mock: bool,
    /// Where the runs run: local (here, one fresh process after another) or slurm (one
    /// batch job per run, each on a node of its own, `sbatch --exclusive`; the results
    /// folder and the binaries must be on a filesystem every node sees). Under Slurm the
    /// campaign folder is <out>/slurm-<cluster>/<campaign>, each row names its node and that
    /// node's machine fingerprint, and the job ids are kept in slurm-jobs.json until the
    /// rows are in: running the same command again collects jobs an earlier invocation
    /// submitted instead of submitting them twice. Ctrl-C cancels the jobs this invocation
    /// submitted (only those).
    #[arg(long, value_enum, default_value_t = SchedulerKind::Local)]
    scheduler: SchedulerKind,
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
    /// Slurm: at most N of the campaign's jobs in the queue at once (default: all).
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u64).range(1..))]
    max_jobs: Option<u64>,
    /// Slurm: submit the runs and exit without waiting; run the same command again (without
    /// --detach) to wait for them and collect their rows.
    #[arg(long)]
    detach: bool,
}

/// `--scheduler`.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum SchedulerKind {
    /// Here, one fresh child process after another.
    Local,
    /// One Slurm batch job per run.
    Slurm,
}

fn main() {
    let cli = Cli::parse();
    let result = match cli.command {
        Cmd::Topology(a) => cmd_topology(a),
        // run: 0 done, 1 a run failed (or an error while running), 2 bad input, 130
        // interrupted.
        Cmd::Run(a) => match cmd_run(*a) {
            Ok(code) => std::process::exit(code),
            Err(e) => Err(e),
        },
        Cmd::Figures(a) => figures::run(a),
        Cmd::Claims(a) => claims::run(a),
        // regress: 0 pass, 1 regression, 2 error or incomparable (a CI gate must tell a
        // regression from a broken comparison).
        Cmd::Regress(a) => match regress::run(a) {
            Ok(code) => std::process::exit(code),
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::exit(2);
            }
        },
        Cmd::Report(a) => comparison::run(a),
        Cmd::Calibrate(a) => calibrate::run(a),
        Cmd::ImpactTable(a) => impact_table::run(a),
        Cmd::RooflineTable(a) => roofline_table::run(&a),
        Cmd::Bandwidth(a) => {
            measure_and_report(a.out.as_deref(), "--out", || bandwidth::measure_all(&a), bandwidth::table)
        }
        Cmd::Paired(a) => measure_and_report(
            a.json.as_deref(),
            "--json",
            || Ok(paired::report(paired_measure::measure(&a)?)),
            paired::table,
        ),
        Cmd::Imbalance(a) => cmd_imbalance(&a),
        Cmd::Job { file } => match mpm_bench::campaign::job::run(&file) {
            Ok(code) => std::process::exit(code),
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::exit(2);
            }
        },
    };
    if let Err(e) = result {
        // `mpm-bench ... | head` closing the pipe is not an error worth a message.
        let broken_pipe = e
            .chain()
            .any(|c| c.downcast_ref::<std::io::Error>().is_some_and(|io| io.kind() == std::io::ErrorKind::BrokenPipe));
        if broken_pipe {
            std::process::exit(0);
        }
        eprintln!("error: {e:#}");
        std::process::exit(1);
    }
}

fn cmd_topology(a: TopologyArgs) -> Result<()> {
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
        .map(|s| {
            preset::parse_list(s, "strategy", |x| {
                x.to_ascii_lowercase().parse::<Strategy>().map_err(anyhow::Error::msg)
            })
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
    })
}

/// Print a bad-input error and exit 2 (a CI job tells a broken invocation from a failed run).
fn bad_input(e: anyhow::Error) -> ! {
    eprintln!("error: {e:#}");
    std::process::exit(2);
}

/// `mpm-bench run`; the exit code: 0, or 1 when a run of this invocation failed, timed out
/// or was invalid (unless `--allow-failures`), or 130 when interrupted. Bad input (the
/// preset, the overrides, a pinning policy this machine cannot honour) exits 2 at once.
fn cmd_run(a: RunArgs) -> Result<i32> {
    let ov = overrides(&a).unwrap_or_else(|e| bad_input(e));
    let ws = solver::workspace_root();
    let (preset, source) = preset::load_preset(&a.preset, ws.as_deref()).unwrap_or_else(|e| bad_input(e));
    let campaign = Campaign::resolve(preset, source, &ov).unwrap_or_else(|e| bad_input(e));
    let machine = Machine::detect()?;
    for p in &campaign.pins {
        if let Err(e) = machine.check_policy(p) {
            bad_input(e.context(format!("bad --bind {p}")));
        }
    }
    let slurm_only = [
        ("--partition", a.partition.is_some()),
        ("--account", a.account.is_some()),
        ("--time-limit", a.time_limit.is_some()),
        ("--max-jobs", a.max_jobs.is_some()),
        ("--detach", a.detach),
    ];
    if let Some((flag, _)) = slurm_only.iter().find(|(_, given)| *given && a.scheduler != SchedulerKind::Slurm) {
        bad_input(anyhow::anyhow!("{flag} is an option of --scheduler slurm"));
    }
    let scheduler = if a.scheduler == SchedulerKind::Slurm {
        if a.mock {
            bad_input(anyhow::anyhow!("--mock runs the fake solver in this process: it cannot go to Slurm"));
        }
        Scheduler::Slurm(SlurmOptions {
            cluster: mpm_bench::campaign::slurm::cluster_name()?,
            partition: a.partition.clone(),
            account: a.account.clone(),
            time_limit: a.time_limit.clone(),
            max_jobs: a.max_jobs.map(|n| usize::try_from(n).unwrap_or(usize::MAX)),
            detach: a.detach,
        })
    } else {
        Scheduler::Local
    };
    let here = scheduler.runs_here();
    let interrupted = runner::install_interrupt_handler();
    let opts = ExecOptions {
        out_root: a.out.clone(),
        dry_run: a.dry_run,
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
    let summary = if a.mock {
        let solvers: Vec<Solver> =
            campaign.opts.iter().map(|&opt| Solver { opt, path: "mock".into(), sha256: "mock".into() }).collect();
        let delay = std::env::var("MPM_BENCH_MOCK_DELAY_MS").ok().and_then(|s| s.parse().ok()).unwrap_or(0);
        let mut r = MockRunner {
            delay: Duration::from_millis(delay),
            fail_when: std::env::var("MPM_BENCH_MOCK_FAIL").ok(),
            ..MockRunner::default()
        };
        runner::execute(&campaign, &machine, &solvers, &mut r, &opts, &interrupted)?
    } else {
        let solvers =
            if a.dry_run { Vec::new() } else { solver::prepare_solvers(&campaign.opts, !a.no_build, a.quiet)? };
        let mut r = ProcessRunner::new(interrupted.clone());
        runner::execute(&campaign, &machine, &solvers, &mut r, &opts, &interrupted)?
    };
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

/// `mpm-bench imbalance`: predict, print the table, write the CSV and the figure.
fn cmd_imbalance(a: &imbalance::ImbalanceArgs) -> Result<()> {
    check_writable(&a.out)?;
    let report = imbalance::measure(a)?;
    print!("{}", imbalance::table(&report));
    let csv = a.out.join(format!("{}.csv", imbalance::stem(&report)));
    imbalance::write_csv(&report, &csv)?;
    let mut files = vec![csv];
    files.extend(imbalance_figure::write_figure(&report, &a.out)?);
    for f in files {
        println!("wrote {}", f.display());
    }
    Ok(())
}

/// Fail early, with a clear message, when the results root cannot be written.
fn check_writable(out: &Path) -> Result<()> {
    std::fs::create_dir_all(out).with_context(|| format!("cannot create the output folder {}", out.display()))?;
    let probe = out.join(format!(".mpm-bench-write-test-{}", std::process::id()));
    std::fs::write(&probe, b"").with_context(|| format!("the output folder {} is not writable", out.display()))?;
    let _ = std::fs::remove_file(&probe);
    Ok(())
}

/// Measure-print-save for the report commands (`bandwidth`, `paired`): create the parent
/// folder of `out` before measuring (so a bad path fails at once, not after the run), then
/// run `measure`, print `table` of its result and write it to `out` as pretty JSON.
/// `flag` names the option that gave `out`, for the error messages.
pub fn measure_and_report<T: serde::Serialize>(
    out: Option<&Path>,
    flag: &str,
    measure: impl FnOnce() -> Result<T>,
    table: impl FnOnce(&T) -> String,
) -> Result<()> {
    if let Some(parent) = out.and_then(Path::parent).filter(|p| !p.as_os_str().is_empty()) {
        std::fs::create_dir_all(parent)
            .with_context(|| format!("cannot create {} for {flag}: choose a writable path", parent.display()))?;
    }
    let report = measure()?;
    print!("{}", table(&report));
    if let Some(out) = out {
        write_atomic(out, serde_json::to_string_pretty(&report)?.as_bytes())
            .with_context(|| format!("cannot write {}: choose a writable {flag}", out.display()))?;
        println!("wrote {}", out.display());
    }
    Ok(())
}
