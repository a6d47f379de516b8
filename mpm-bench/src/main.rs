//! `mpm-bench`: runs the MPM parallelisation study's benchmark campaigns and shows the
//! machine's topology. See `mpm-bench --help`.

use anyhow::{Context, Result};
use clap::{Parser, Subcommand};
use mpm_bench::analysis::{calibrate, claims, paired_report, regress};
use mpm_bench::campaign::exec::process::{MockRunner, ProcessRunner};
use mpm_bench::campaign::exec::solver::{self};
use mpm_bench::campaign::exec::watch::WatchSettings;
use mpm_bench::campaign::measure::calibrate as calibrate_measure;
use mpm_bench::campaign::measure::imbalance;
use mpm_bench::campaign::measure::paired as paired_measure;
use mpm_bench::campaign::schedule::{self};
use mpm_bench::machine::topology::Machine;
use mpm_bench::machine::{bandwidth, fingerprint};
use mpm_bench::report::{comparison, export, figures, imbalance as imbalance_figure, impact_table, roofline_table};
use mpm_host::atomic::write_atomic;
use std::path::{Path, PathBuf};

mod cli;

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
        mpm-bench export --results B --format bmf    # Bencher Metric Format JSON of B's cells\n  \
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
    Topology(cli::topology::TopologyArgs),
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
    Run(Box<cli::run::RunArgs>),
    /// Regenerate the paper's Figures 7-14 (and a memory figure; with block colouring or atomic
    /// adds in the campaign, every strategy side by side) from a campaign.
    Figures(cli::analysis::FiguresArgs),
    /// Check the paper's claims C1-C6 and C7 (balanced cuts) on a campaign: holds / does not hold / cannot tell;
    /// then block colouring and atomic adds against DD and AE.
    Claims(cli::analysis::ClaimsArgs),
    /// Compare a campaign with a baseline: exit 0 pass, 1 regression or missing cell, 2 error or incomparable.
    Regress(cli::analysis::RegressArgs),
    /// Two builds measured side by side in one sitting: the CI gate of a pull request against its base.
    #[command(
        long_about = "Measure two builds of the solver side by side on this host and judge the candidate against the \
            baseline: exit 0 pass, 1 regression (or a cell the candidate did not measure), 2 incomparable or bad \
            input.\n\n\
            The baseline is a git revision (--baseline-rev: checked out into a worktree and built into a target \
            folder of its own) or binaries (--baseline-bin); the candidate is this checkout's build (or \
            --candidate-bin). Every planned run of the preset (default ci) runs once per build, the two processes \
            back to back, which build goes first alternating ABBA from a seed, so that the host's drift reaches \
            both alike. Each process is a paired run as in `mpm-bench run`. Per pair, the log ratio candidate / \
            baseline of the paired efficiency and of the time per step; per cell and pooled over the cells, an \
            interval over the pairs (Student's t), Holm over every check. A check fails when the candidate is \
            worse than --tolerance beyond the noise. Time per step is gated (the builds ran moments apart on one \
            host, unlike a stored baseline's); the work counters are compared exactly.\n\n\
            The output folder keeps both campaigns (baseline/, candidate/), the order that ran (ab.json, with the \
            builds and their seconds) and the verdict (verdict.json).",
        after_help = "Examples:\n  \
            mpm-bench ab --baseline-rev origin/main                       # this checkout against main\n  \
            mpm-bench ab --baseline-rev HEAD~1 --markdown \"$GITHUB_STEP_SUMMARY\"\n  \
            mpm-bench ab --baseline-bin /opt/mpm-1.2/bin --candidate-bin target --no-build\n  \
            mpm-bench ab --baseline-rev HEAD --candidate-inject-step-slowdown 0.1   # the gate must fail (exit 1)\n  \
            mpm-bench ab --baseline-rev HEAD --work-snapshot ci/work-baseline.json --json verdict.json"
    )]
    Ab(Box<cli::ab::AbArgs>),
    /// The work counters of the gate's cells against a committed snapshot (exact, on any machine).
    #[command(
        long_about = "The work counters of the gate's cells (bytes per sub-stage and worker over a run) are the \
            same on every machine for a given commit. --check FILE runs every cell of the preset once (or reads \
            --campaign DIR) and compares exactly: exit 0 equal, 1 changed, naming the cell and the sub-stage. \
            --write FILE records them: commit the file when a change is intended, as a snapshot test's.",
        after_help = "Examples:\n  \
            mpm-bench work-snapshot --check ci/work-baseline.json\n  \
            mpm-bench work-snapshot --write ci/work-baseline.json      # after an intended change; commit it\n  \
            mpm-bench work-snapshot --check ci/work-baseline.json --campaign results/local/ab/candidate/<fp>/ci"
    )]
    WorkSnapshot(cli::ab::WorkSnapshotArgs),
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
            runs on; the same command resumes an interrupted calibration.\n\n\
            --design ab calibrates `mpm-bench ab` instead: --clean sides of one build, --injected sides with \
            the efficiency loss and as many with a step slowdown (--inject-step-slowdown F: every step 1 / (1 - F) \
            times as long on every worker alike), all run side by side process by process as ab runs its two \
            builds; ab's verdict on every pair of clean sides (A/A) and on every clean side against every \
            injected one. calibration.json then has design \"ab\", aa_comparisons, false_alarms, gate_wall_s \
            and one entry per injected kind (kind, injected_slowdown, injected_comparisons, detected), and the \
            smallest change of each metric found with 90 % power.",
        after_help = "Examples:\n  \
            mpm-bench calibrate                                  # ci preset, 7 clean + 3 injected (10 %) campaigns\n  \
            mpm-bench calibrate --clean 7 --injected 3 --budget 100m --json results/<fp>/calibrate-ci/calibration.json\n  \
            mpm-bench calibrate --preset configs/my-ci.toml --inject-slowdown 0.05 --tolerance 0.03\n  \
            mpm-bench calibrate --design ab --clean 7 --injected 3      # the side-by-side gate: 21 A/A, 21 + 21 injected"
    )]
    Calibrate(cli::measure::CalibrateArgs),
    /// Hardware report (one HTML page, Markdown, JSON) of a campaign, or several compared with the first.
    Report(cli::analysis::ReportArgs),
    /// A campaign's efficiency, time per step and work bytes per cell for Bencher or github-action-benchmark.
    #[command(
        long_about = "Write a campaign's numbers per cell, with their intervals, in a benchmark dashboard's \
            format: Bencher Metric Format (--format bmf) or github-action-benchmark's custom JSON \
            (--format github-action-benchmark-bigger or -smaller: that tool takes one direction per file).\n\n\
            One benchmark per cell (and stage asked), named from the cell's key only, so the name is the same \
            on every run of the configuration: <scenario>-m<model>-<strategy>-<opt>-t<threads>-<pin>, e.g. \
            taylor-m1-dd-o3-t2-close (with /grid or /particle for those stages). Each carries the parallel \
            efficiency (cells of 2+ threads), the time per step and the work bytes (the busiest worker's bytes \
            over the run, exact), from the same estimates as regress and report: the efficiency's interval is \
            the paired design's over processes or the separate design's bootstrap, the time's a bootstrap of \
            the median. A single repetition is exported without an interval.\n\n\
            BMF measures: latency (Bencher's built-in measure, nanoseconds: the time per step), \
            parallel-efficiency (a fraction; 1 is perfect scaling) and work-bytes. github-action-benchmark \
            entries: <benchmark>/efficiency (unit fraction) in the bigger file; <benchmark>/time-per-step \
            (ns/step) and <benchmark>/work-bytes (bytes) in the smaller one, with the interval in range. \
            Oversubscribed cells and rows over several MPI ranks are left out (a note says so); an empty \
            export, an unknown format and an --out that is one of the campaign's files are refused.",
        after_help = "Examples:\n  \
            mpm-bench export --results results/local --format bmf --out bmf.json\n  \
            bencher run --adapter json --file bmf.json          # Bencher: track them\n  \
            mpm-bench export --results current --format github-action-benchmark-bigger --out efficiency.json\n  \
            mpm-bench export --results current --format github-action-benchmark-smaller --out time.json\n  \
            mpm-bench export --results current --format bmf --stages total,grid,particle | jq 'keys'"
    )]
    Export(cli::export::ExportArgs),
    /// Markdown table of the impact runs under a folder, from their JSON summaries.
    ImpactTable(cli::tables::ImpactTableArgs),
    /// Markdown roofline table of runs (each sub-stage's bytes, flops and rates), from their JSON summaries.
    RooflineTable(cli::tables::RooflineTableArgs),
    /// Measure the memory-bandwidth ceiling (STREAM triad) per thread count and pinning.
    Bandwidth(cli::measure::BandwidthArgs),
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
    Paired(cli::measure::PairedArgs),
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
            Block colouring's is predicted beside them: its 8 phases' fullest worker shares over \
            their mean shares, on the blocks the solver cuts for the thread count. \
            Nothing is timed, so the result means the same on a 2-core machine as on the \
            paper's 8 cores. Prints the table (mean and worst step per thread count) and \
            writes imbalance-<scenario>-m<model>.csv (every step) and .png/.svg under --out.",
        after_help = "Examples:\n  \
            mpm-bench imbalance --scenario impact --threads 2,4,6,8          # small model, to 30.6 us\n  \
            mpm-bench imbalance --scenario taylor --model 2 --steps 200\n  \
            mpm-bench imbalance --scenario impact --steps 50 --out /tmp/imb"
    )]
    Imbalance(cli::measure::ImbalanceArgs),
    /// Run one run of a campaign on this node and write its row: what a Slurm job of
    /// `mpm-bench run --scheduler slurm` runs (FILE is json/<run id>.job.json).
    #[command(hide = true)]
    Job {
        /// The job file the harness wrote.
        file: PathBuf,
    },
}

fn main() {
    let cli: Cli = cli::parse::parse();
    let result = match cli.command {
        Cmd::Topology(a) => cli::topology::cmd_topology(a),
        // run: 0 done, 1 a run failed (or an error while running), 2 bad input, 130
        // interrupted.
        Cmd::Run(a) => match cli::run::cmd_run(*a) {
            Ok(code) => std::process::exit(code),
            Err(e) => Err(e),
        },
        Cmd::Figures(a) => figures::run(a.into()),
        Cmd::Claims(a) => claims::run(a.into()),
        // regress: 0 pass, 1 regression, 2 error or incomparable (a CI gate must tell a
        // regression from a broken comparison).
        Cmd::Regress(a) => match regress::run(a.into()) {
            Ok(code) => std::process::exit(code),
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::exit(2);
            }
        },
        Cmd::Ab(a) => match cli::ab::cmd_ab(*a) {
            Ok(code) => std::process::exit(code),
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::exit(2);
            }
        },
        Cmd::WorkSnapshot(a) => match cli::ab::cmd_work_snapshot(a) {
            Ok(code) => std::process::exit(code),
            Err(e) => {
                eprintln!("error: {e:#}");
                std::process::exit(2);
            }
        },
        Cmd::Report(a) => comparison::run(a.into()),
        Cmd::Export(a) => export::run(&a.into()),
        Cmd::Calibrate(a) => cmd_calibrate(a.into()),
        Cmd::ImpactTable(a) => impact_table::run(a.into()),
        Cmd::RooflineTable(a) => roofline_table::run(&a.into()),
        Cmd::Bandwidth(a) => {
            let a: bandwidth::BandwidthOptions = a.into();
            measure_and_report(a.out.as_deref(), "--out", || bandwidth::measure_all(&a), bandwidth::table)
        }
        Cmd::Paired(a) => {
            let a: paired_measure::PairedOptions = a.into();
            measure_and_report(
                a.json.as_deref(),
                "--json",
                || Ok(paired_report::report(paired_measure::measure(&a)?)),
                paired_report::table,
            )
        }
        Cmd::Imbalance(a) => cmd_imbalance(&a.into()),
        Cmd::Job { file } => match mpm_bench::campaign::schedule::job::run(&file) {
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

/// Print a bad-input error and exit 2 (a CI job tells a broken invocation from a failed run).
pub(crate) fn bad_input(e: anyhow::Error) -> ! {
    eprintln!("error: {e:#}");
    std::process::exit(2);
}

/// `mpm-bench calibrate`: check the settings, build (unless --no-build or --mock), run, print, write the JSON.
fn cmd_calibrate(a: calibrate_measure::CalibrateOptions) -> Result<()> {
    calibrate::check_args(&a)?;
    if a.design_ab {
        return cmd_calibrate_ab(&a);
    }
    let machine = Machine::detect()?;
    let interrupted = schedule::install_interrupt_handler();
    let c = if a.mock {
        let mut r = MockRunner::default();
        let solvers = calibrate_measure::mock_solvers();
        let campaigns = calibrate_measure::run_campaigns(&a, &machine, &solvers, &mut r, None, &interrupted)?;
        calibrate::judge(&a, &machine, campaigns)?
    } else {
        let opts = calibrate_measure::campaign_of(&a, false, 0)?.opts;
        let solvers = solver::prepare_solvers(&opts, !a.no_build, a.quiet)?;
        let mut r = ProcessRunner::new(interrupted.clone());
        let watch = Some(WatchSettings::default());
        let campaigns = calibrate_measure::run_campaigns(&a, &machine, &solvers, &mut r, watch, &interrupted)?;
        calibrate::judge(&a, &machine, campaigns)?
    };
    print!("{}", calibrate::table(&c));
    let path = a.json.clone().unwrap_or_else(|| {
        let name =
            std::path::Path::new(&a.preset).file_stem().map_or("preset".into(), |s| s.to_string_lossy().into_owned());
        a.out.join(fingerprint::fingerprint(&machine)).join(format!("calibrate-{name}")).join("calibration.json")
    });
    write_json_file(&path, &c)
}

/// `mpm-bench calibrate --design ab`: the sides side by side, every comparison, the JSON.
fn cmd_calibrate_ab(a: &calibrate_measure::CalibrateOptions) -> Result<()> {
    use mpm_bench::analysis::calibrate_ab;
    use mpm_bench::campaign::measure::calibrate_ab as measure_ab;
    let machine = Machine::detect()?;
    let interrupted = schedule::install_interrupt_handler();
    let name =
        std::path::Path::new(&a.preset).file_stem().map_or("preset".into(), |s| s.to_string_lossy().into_owned());
    let dir = a.out.join(fingerprint::fingerprint(&machine)).join(format!("calibrate-ab-{name}"));
    let (record, kinds) = if a.mock {
        let solvers = calibrate_measure::mock_solvers();
        measure_ab::run(a, &dir, &machine, &solvers, &mut MockRunner::default(), &interrupted)?
    } else {
        let opts = measure_ab::side_campaign(a, measure_ab::SideKind::Clean)?.opts;
        let solvers = solver::prepare_solvers(&opts, !a.no_build, a.quiet)?;
        let mut r = ProcessRunner::new(interrupted.clone());
        measure_ab::run(a, &dir, &machine, &solvers, &mut r, &interrupted)?
    };
    if record.interrupted {
        anyhow::bail!("interrupted: the sides' rows so far are kept in {}; the same command continues", dir.display());
    }
    let c = calibrate_ab::judge(a, &machine, record, &kinds)?;
    print!("{}", calibrate_ab::table(&c));
    let path = a.json.clone().unwrap_or_else(|| dir.join("calibration.json"));
    write_json_file(&path, &c)
}

/// Write `value` as pretty JSON to `path` (atomically, its folder created) and say so.
fn write_json_file(path: &std::path::Path, value: &impl serde::Serialize) -> Result<()> {
    if let Some(parent) = path.parent() {
        std::fs::create_dir_all(parent).with_context(|| format!("cannot create {}", parent.display()))?;
    }
    write_atomic(path, serde_json::to_string_pretty(value)?.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!("wrote {}", path.display());
    Ok(())
}

/// `mpm-bench imbalance`: predict, print the table, write the CSV and the figure.
fn cmd_imbalance(a: &imbalance::ImbalanceOptions) -> Result<()> {
    cli::run::check_writable(&a.out)?;
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
