//! Parsing the command line so that negative numbers are values, never flags: `--tolerance
//! -0.05` reaches the check that says why it is refused, and `--reps -1` is refused as a
//! negative count naming the flag, instead of "unexpected argument '-1'" or "invalid digit
//! found in string".

use clap::error::{ContextKind, ContextValue, ErrorKind};
use clap::{Command, Parser};

/// The arguments of this process, parsed; a parse error is printed (with what to give)
/// and exits 2.
pub fn parse<C: Parser>() -> C {
    let matches = negatives_are_values(C::command()).try_get_matches().unwrap_or_else(|e| exit_with(e));
    C::from_arg_matches(&matches).unwrap_or_else(|e| exit_with(e))
}

/// `cmd` and its sub-commands with every argument that takes a value accepting a leading
/// `-` followed by a number as that value.
pub fn negatives_are_values(cmd: Command) -> Command {
    let cmd = cmd.mut_args(|a| if a.get_action().takes_values() { a.allow_negative_numbers(true) } else { a });
    let names: Vec<String> = cmd.get_subcommands().map(|s| s.get_name().to_string()).collect();
    names.iter().fold(cmd, |c, n| c.mut_subcommand(n, negatives_are_values))
}

/// Print `e` and exit: a negative number given for a count (a value a whole-number parser
/// refused) says so, naming the flag; every other error is clap's.
fn exit_with(e: clap::Error) -> ! {
    if let Some(msg) = negative_count(&e) {
        eprintln!("error: {msg}");
        std::process::exit(2);
    }
    e.exit()
}

/// The message for a negative number refused by a whole-number parser, if `e` is one.
pub fn negative_count(e: &clap::Error) -> Option<String> {
    if e.kind() != ErrorKind::ValueValidation {
        return None;
    }
    let text = |k| match e.get(k) {
        Some(ContextValue::String(s)) => Some(s.clone()),
        _ => None,
    };
    let value = text(ContextKind::InvalidValue)?;
    let arg = text(ContextKind::InvalidArg)?;
    let negative = value.trim().strip_prefix('-').is_some_and(|n| n.parse::<f64>().is_ok());
    negative.then(|| {
        format!("{arg}: {value} is negative; it takes a whole number (a count): give 0 or more, or see --help")
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::{ArgMatches, Args, FromArgMatches};

    /// Matches of `args` under `cmd` as [`parse`] reads them.
    fn try_matches(cmd: Command, args: &[&str]) -> Result<ArgMatches, clap::Error> {
        negatives_are_values(cmd).try_get_matches_from(args)
    }

    #[derive(Parser, Debug)]
    struct T {
        #[command(subcommand)]
        cmd: Sub,
    }
    #[derive(clap::Subcommand, Debug)]
    enum Sub {
        Go(GoArgs),
    }
    #[derive(Args, Debug)]
    struct GoArgs {
        #[arg(long)]
        reps: Option<u32>,
        #[arg(long)]
        tolerance: Option<f64>,
        #[arg(long)]
        quiet: bool,
    }

    /// A negative fraction reaches its value; a negative count is refused naming the flag;
    /// a flag is still a flag.
    #[test]
    fn negative_numbers_are_values() {
        let cmd = <T as clap::CommandFactory>::command();
        let m = try_matches(cmd.clone(), &["t", "go", "--tolerance", "-0.05", "--quiet"]).unwrap();
        let t = T::from_arg_matches(&m).unwrap();
        let Sub::Go(g) = t.cmd;
        assert_eq!((g.tolerance, g.quiet), (Some(-0.05), true));
        let e = try_matches(cmd.clone(), &["t", "go", "--reps", "-1"]).unwrap_err();
        let msg = negative_count(&e).unwrap();
        assert!(msg.starts_with("--reps <REPS>: -1 is negative"), "{msg}");
        let e = try_matches(cmd, &["t", "go", "--reps", "x"]).unwrap_err();
        assert_eq!(negative_count(&e), None, "not a negative number: clap's own error");
    }
}
