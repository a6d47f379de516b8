//! `mpm run`: the run's spec, read from its file or built from the flags on the launcher's
//! rank count, its outputs checked against its inputs ([`crate::paths`]), set up and
//! stepped to its summary ([`crate::start::start`]).

use crate::cli::Control;
use crate::paths::{check_outputs, Named};
use crate::ranks::Ranks;
use crate::start::{start, Invocation, Origin};
use anyhow::Result;
use mpm_spec::{RunSpec, SpecError};
use std::path::PathBuf;

/// Where a run's spec comes from.
pub enum Request {
    /// `mpm run <scenario> --flags`.
    Flags(Box<crate::cli::Scenario>),
    /// `mpm run --spec FILE [--json FILE] [--quiet]`.
    File {
        /// The spec file.
        path: PathBuf,
        /// `--json`, replacing the spec's `outputs.json`.
        json: Option<PathBuf>,
        /// `--quiet`.
        quiet: bool,
    },
}

impl Request {
    /// The ranks asked for before MPI starts (the spec's, or `--ranks`), and the spec read
    /// from its file.
    fn before_start(&self) -> Result<(Option<usize>, Option<RunSpec>)> {
        match self {
            Request::Flags(sc) => match sc.options().ranks {
                Some(0) => Err(SpecError::Invalid {
                    key: "ranks",
                    flag: "--ranks",
                    why: "the rank count must be at least 1, got 0 (leave it out to take the launcher's)".into(),
                }
                .into()),
                r => Ok((r.map(|r| r as usize), None)),
            },
            Request::File { path, json, quiet } => {
                let mut spec = RunSpec::read(path)?;
                if json.is_some() {
                    spec.outputs.json.clone_from(json);
                }
                spec.outputs.quiet |= *quiet;
                Ok((Some(spec.ranks), Some(spec)))
            }
        }
    }
}

/// `mpm run ...`: the whole run, from its spec (read, or built from the flags on the
/// launcher's rank count) to its summary.
pub fn run(request: Request, control: Control, command_line: Vec<String>) -> Result<()> {
    let started_unix_s = mpm_host::clock::unix_now();
    let (requested, from_file) = request.before_start()?;
    let mut ranks = Ranks::start(requested)?;
    let spec = match (from_file, &request) {
        (Some(spec), _) => spec,
        (None, Request::Flags(sc)) => sc.spec(ranks.size())?,
        (None, Request::File { .. }) => unreachable!("a spec file is read before MPI starts"),
    };
    if control.print_spec {
        if ranks.rank() == 0 {
            print!("{}", spec.to_toml());
        }
        return Ok(());
    }
    let inputs = match &request {
        Request::File { path, .. } => vec![Named::file("the spec file --spec", path)],
        Request::Flags(_) => Vec::new(),
    };
    check_outputs(&spec, &inputs, None)?;
    start(
        spec,
        control.force,
        Origin::Fresh(Invocation { started_unix_s, command_line, force: control.force }),
        &mut ranks,
    )
}
