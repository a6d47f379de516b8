//! `mpm`: run one explicit MPM simulation and write its JSON summary (and, optionally, VTU
//! snapshots). See `mpm run taylor --help`.
//!
//! A run in steps: [`cli`] parses the command line into a run spec (`mpm_spec::RunSpec`,
//! or reads one with `--spec`, [`run`]; [`paths`] refuses outputs that would overwrite
//! its inputs); [`start`] sets the run up, fresh or from a
//! checkpoint: checks it against the machine ([`machine`]), builds the scenario ([`ranks`]:
//! over MPI ranks too), the pinned pool and the simulation ([`solver`]); [`stepping`] steps
//! it ([`output`] writes snapshots and pictures on the way, [`checkpointing`] the run's
//! checkpoints, [`tracking`] the scenario's histories, [`progress`] shows a bar, [`paired`]
//! runs a paired measurement instead), then writes the summary; [`human`] prints it for
//! people. `mpm resume DIR` ([`resume`]) chooses and checks the checkpoint to take a run
//! back from and goes on through the same set-up and loop. Ctrl-C and SIGTERM ([`interrupt`])
//! stop a run between steps; SIGTERM and SIGUSR1 to a run with `--checkpoint-dir` write a
//! last checkpoint first (exit status 75).

mod checkpointing;
mod cli;
mod human;
mod interrupt;
mod machine;
mod output;
mod paired;
mod paths;
mod progress;
mod ranks;
mod resume;
mod run;
mod solver;
mod start;
mod stepping;
mod tracking;

use anyhow::Result;
use clap::Parser;
use cli::{Cli, Command, RunCmd};
use run::Request;

fn main() {
    let cli = Cli::parse();
    // Before any thread starts (the pool's, MPI's): they all leave the signals to one.
    interrupt::listen();
    if let Err(e) = dispatch(cli) {
        eprintln!("error: {e}");
        for cause in e.chain().skip(1) {
            eprintln!("  caused by: {cause}");
        }
        let code = if e.downcast_ref::<interrupt::Interrupted>().is_some() {
            130
        } else if e.downcast_ref::<interrupt::LastCheckpoint>().is_some() {
            interrupt::LAST_CHECKPOINT_EXIT
        } else {
            1
        };
        std::process::exit(code);
    }
}

/// Run the command the user gave.
fn dispatch(cli: Cli) -> Result<()> {
    let command_line: Vec<String> = std::env::args().collect();
    let RunCmd { scenario, spec, json, quiet, control } = match cli.command {
        Command::Run(run) => *run,
        Command::Resume(cmd) => return resume::resume(cmd, command_line),
    };
    let (request, control) = match (scenario, spec) {
        (Some(sc), _) => {
            let control = sc.options().control;
            (Request::Flags(Box::new(sc)), control)
        }
        (None, Some(path)) => (Request::File { path, json, quiet }, control),
        (None, None) => anyhow::bail!("give a scenario (`mpm run taylor --model 1`) or a spec (`mpm run --spec FILE`)"),
    };
    run::run(request, control, command_line)
}
