//! `mpm`: run one explicit MPM simulation and write its JSON summary (and, optionally, VTU
//! snapshots). See `mpm run taylor --help`.
//!
//! A run in steps: [`cli`] parses the command line, [`scenario`] builds the model asked for,
//! [`run`] checks the options, builds the pinned pool and the simulation and steps it
//! ([`output`] writes snapshots and pictures on the way, [`progress`] shows a bar), then
//! writes the summary; [`human`] prints it for people.

mod cli;
mod human;
mod output;
mod progress;
mod ranks;
mod run;
mod scenario;

use anyhow::Result;
use clap::Parser;
use cli::{Cli, Command, RunCmd, Scenario};
use scenario::ScenarioRun;

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
    let Command::Run(RunCmd { scenario }) = cli.command;
    let run = match scenario {
        Scenario::Taylor(args) => ScenarioRun::Taylor(args),
        Scenario::Impact(args) => ScenarioRun::Impact(args),
        Scenario::Plate(args) => ScenarioRun::Plate(args),
    };
    run::run_scenario(&run, command_line)
}
