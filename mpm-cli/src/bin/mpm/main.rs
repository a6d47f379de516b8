//! `mpm`: run one explicit MPM simulation and write its JSON summary (and, optionally, VTU
//! snapshots). See `mpm run taylor --help`.
//!
//! A run in steps: [`cli`] parses the command line into a run spec (`mpm_spec::RunSpec`,
//! or reads one with `--spec`), [`run`] checks it against the machine, builds the scenario,
//! the pinned pool and the simulation and steps it
//! ([`output`] writes snapshots and pictures on the way, [`checkpointing`] the run's
//! checkpoints, [`progress`] shows a bar), then writes the summary; [`human`] prints it for
//! people. `mpm resume DIR` ([`resume`]) takes a run back from its newest checkpoint and
//! goes on through the same loop.

mod checkpointing;
mod cli;
mod human;
mod output;
mod paired;
mod progress;
mod ranks;
mod resume;
mod run;

use anyhow::Result;
use clap::Parser;
use cli::{Cli, Command, RunCmd};
use run::Request;

fn main() {
    let cli = Cli::parse();
    if let Err(e) = dispatch(cli) {
        eprintln!("error: {e}");
        for cause in e.chain().skip(1) {
            eprintln!("  caused by: {cause}");
        }
        let code = if e.downcast_ref::<run::Interrupted>().is_some() { 130 } else { 1 };
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
