//! The MPI launcher of runs with more than one rank: a command template such as
//! `mpirun --bind-to none -n {ranks}` (Open MPI, MPICH) or `srun -n {ranks} -c {threads}`
//! (Slurm), split on whitespace (no shell: quotes are not interpreted) and put in front of
//! `mpm run ...`. Placeholders: `{ranks}` (required) and `{threads}` (threads per rank).
//!
//! Which template a campaign uses: `--launcher` on the command line, else the environment
//! variable [`LAUNCHER_ENV`], else the preset's `launcher` key, else [`DEFAULT_LAUNCHER`].
//! A run with one rank never uses the launcher: `mpm` runs directly, as before ranks existed.
//!
//! Placement: with a pinning policy (every policy but `none`) the harness places
//! ranks x threads workers, makes that CPU set the launcher's affinity mask, and the solver's
//! ranks, sharing the inherited mask, pin their workers to consecutive slices of it in
//! CPU-number order (`mpm`'s own per-rank placement). The launcher must therefore not bind
//! ranks itself: Open MPI binds to cores by default (to one core per rank for two ranks,
//! ignoring the mask it was given), hence `--bind-to none` in the default. With `--bind none`
//! the launcher's own binding (e.g. `--map-by slot:PE={threads} --bind-to core`) is used and
//! recorded as observed.
//!
//! As root, Open MPI needs `--allow-run-as-root`, and more ranks than cores need
//! `--oversubscribe`: say so in the template, e.g.
//! `MPM_BENCH_LAUNCHER="mpirun --bind-to none --oversubscribe --allow-run-as-root -n {ranks}"`.

use serde::{Deserialize, Serialize};
use std::fmt;

/// The template used when neither the command line, the environment nor the preset gives one.
pub const DEFAULT_LAUNCHER: &str = "mpirun --bind-to none -n {ranks}";

/// Environment variable holding a launcher template (below `--launcher`, above the preset).
pub const LAUNCHER_ENV: &str = "MPM_BENCH_LAUNCHER";

/// What is wrong with a launcher template.
#[derive(Debug, thiserror::Error, PartialEq, Eq)]
pub enum LauncherError {
    /// Nothing but white space.
    #[error("the launcher template is empty: give a command such as '{DEFAULT_LAUNCHER}'")]
    Empty,
    /// No `{ranks}`: the launcher would not know how many ranks to start.
    #[error("the launcher template '{0}' has no {{ranks}} placeholder: write where the rank count goes, e.g. '{DEFAULT_LAUNCHER}'")]
    NoRanks(String),
    /// A `{...}` that is not a placeholder.
    #[error("the launcher template '{template}' has an unknown placeholder '{name}' (known: {{ranks}}, {{threads}})")]
    Unknown {
        /// The template.
        template: String,
        /// The unknown placeholder, braces included.
        name: String,
    },
    /// A `{` without its `}` (or the reverse).
    #[error("the launcher template '{0}' has an unbalanced brace: placeholders are {{ranks}} and {{threads}}")]
    Unbalanced(String),
}

/// A checked launcher template.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(try_from = "String", into = "String")]
pub struct Launcher {
    template: String,
}

impl Default for Launcher {
    fn default() -> Self {
        Self { template: DEFAULT_LAUNCHER.into() }
    }
}

impl Launcher {
    /// Check `template`: not empty, `{ranks}` present, no other placeholder than
    /// `{ranks}` and `{threads}`, balanced braces.
    pub fn parse(template: &str) -> Result<Self, LauncherError> {
        let t = template.split_whitespace().collect::<Vec<_>>().join(" ");
        if t.is_empty() {
            return Err(LauncherError::Empty);
        }
        let mut rest = t.as_str();
        let mut has_ranks = false;
        while let Some(open) = rest.find(['{', '}']) {
            if rest[open..].starts_with('}') {
                return Err(LauncherError::Unbalanced(t.clone()));
            }
            let Some(close) = rest[open..].find('}') else { return Err(LauncherError::Unbalanced(t.clone())) };
            let name = &rest[open..open + close + 1];
            match name {
                "{ranks}" => has_ranks = true,
                "{threads}" => {}
                _ if name[1..].contains('{') => return Err(LauncherError::Unbalanced(t.clone())),
                _ => return Err(LauncherError::Unknown { template: t.clone(), name: name.into() }),
            }
            rest = &rest[open + close + 1..];
        }
        if !has_ranks {
            return Err(LauncherError::NoRanks(t));
        }
        Ok(Self { template: t })
    }

    /// The template (white space normalised to single spaces).
    pub fn template(&self) -> &str {
        &self.template
    }

    /// The launcher's words for `ranks` ranks of `threads` threads each: the program first.
    pub fn expand(&self, ranks: usize, threads: usize) -> Vec<String> {
        self.template
            .split(' ')
            .map(|w| w.replace("{ranks}", &ranks.to_string()).replace("{threads}", &threads.to_string()))
            .collect()
    }

    /// The launcher program's `--version` (its first line that is not empty), or why it
    /// could not be read, for the manifest.
    pub fn version(&self) -> String {
        let program = self.template.split(' ').next().unwrap_or_default();
        match std::process::Command::new(program).arg("--version").stdin(std::process::Stdio::null()).output() {
            Ok(o) if o.status.success() => String::from_utf8_lossy(&o.stdout)
                .lines()
                .map(str::trim)
                .find(|l| !l.is_empty())
                .map_or_else(|| format!("{program}: empty --version"), str::to_string),
            Ok(o) => format!("{program} --version exited with {}", o.status),
            Err(e) => format!("{program}: cannot start it ({e})"),
        }
    }

    /// The template chosen by the precedence rule: `cli`, else the environment
    /// ([`LAUNCHER_ENV`], when set and not empty), else `preset`, else the default.
    pub fn choose(cli: Option<&str>, preset: Option<&Launcher>) -> Result<Self, LauncherError> {
        if let Some(t) = cli {
            return Self::parse(t);
        }
        match std::env::var(LAUNCHER_ENV) {
            Ok(t) if !t.trim().is_empty() => Self::parse(&t),
            _ => Ok(preset.cloned().unwrap_or_default()),
        }
    }
}

/// Open MPI refuses to start as root unless told twice: `--allow-run-as-root` on its command
/// line or both of these variables set.
const OMPI_ROOT_ENV: [&str; 2] = ["OMPI_ALLOW_RUN_AS_ROOT", "OMPI_ALLOW_RUN_AS_ROOT_CONFIRM"];

impl Launcher {
    /// Why every run over several ranks would fail before it starts, if it would: this
    /// process is root and the launcher is Open MPI's without `--allow-run-as-root` (nor
    /// [`OMPI_ROOT_ENV`] set). Checked before a campaign's first run, so that it stops with
    /// what to do instead of writing a failed row per run.
    pub fn root_refusal(&self) -> Option<String> {
        use std::os::unix::fs::MetadataExt;
        // /proc/self belongs to the process's effective user.
        let root = std::fs::metadata("/proc/self").is_ok_and(|m| m.uid() == 0);
        let env_allows = OMPI_ROOT_ENV.iter().all(|v| std::env::var_os(v).is_some_and(|x| !x.is_empty()));
        refusal(&self.template, root, env_allows, || self.version())
    }
}

/// [`Launcher::root_refusal`] for a given `template`, user and environment; `version` is
/// asked only when it matters (it runs the launcher).
fn refusal(template: &str, root: bool, env_allows: bool, version: impl FnOnce() -> String) -> Option<String> {
    let words: Vec<&str> = template.split(' ').collect();
    if !root || env_allows || words.contains(&"--allow-run-as-root") {
        return None;
    }
    let v = version();
    if !v.contains("Open MPI") {
        return None;
    }
    let fixed = std::iter::once(words[0]).chain(["--allow-run-as-root"]).chain(words[1..].iter().copied());
    Some(format!(
        "this harness runs as root, and {v} refuses to start ranks as root, so every run over several \
         ranks would fail: add --allow-run-as-root to the launcher, e.g. --launcher '{}' (or in {LAUNCHER_ENV} \
         or the preset), or set {} and {} to 1",
        fixed.collect::<Vec<_>>().join(" "),
        OMPI_ROOT_ENV[0],
        OMPI_ROOT_ENV[1]
    ))
}

impl TryFrom<String> for Launcher {
    type Error = LauncherError;
    fn try_from(s: String) -> Result<Self, Self::Error> {
        Self::parse(&s)
    }
}

impl From<Launcher> for String {
    fn from(l: Launcher) -> Self {
        l.template
    }
}

impl fmt::Display for Launcher {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.template)
    }
}

/// A hint for a launched run that failed, from its standard error: the two Open MPI
/// refusals a template can fix.
pub fn failure_hint(stderr: &str) -> Option<&'static str> {
    if stderr.contains("allow-run-as-root") {
        Some(
            "running as root: add --allow-run-as-root to the launcher (--launcher, MPM_BENCH_LAUNCHER or the \
             preset's launcher key)",
        )
    } else if stderr.contains("not enough slots") || stderr.contains("oversubscribe") {
        Some("more ranks than cores: add --oversubscribe to the launcher (the row is flagged oversubscribed)")
    } else {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn open_mpi_as_root_without_permission_is_refused_before_the_runs() {
        let ompi = || "mpirun (Open MPI) 4.1.4".to_string();
        let msg = refusal(DEFAULT_LAUNCHER, true, false, ompi).expect("refused");
        assert!(msg.contains("--launcher 'mpirun --allow-run-as-root --bind-to none -n {ranks}'"), "{msg}");
        assert!(msg.contains("OMPI_ALLOW_RUN_AS_ROOT_CONFIRM"), "{msg}");
        // Not root, permission given either way, or another launcher: nothing to say.
        assert_eq!(refusal(DEFAULT_LAUNCHER, false, false, ompi), None);
        assert_eq!(refusal(DEFAULT_LAUNCHER, true, true, ompi), None);
        assert_eq!(refusal("mpirun --allow-run-as-root -n {ranks}", true, false, ompi), None);
        assert_eq!(refusal(DEFAULT_LAUNCHER, true, false, || "HYDRA build details: Version: 4.1".into()), None);
        assert_eq!(refusal("srun -n {ranks}", true, false, || "slurm 23.02.6".into()), None);
    }

    #[test]
    fn templates_expand_ranks_and_threads() {
        let l = Launcher::parse("  mpirun  --bind-to none -n {ranks} ").unwrap();
        assert_eq!(l.template(), "mpirun --bind-to none -n {ranks}");
        assert_eq!(l.expand(3, 2), ["mpirun", "--bind-to", "none", "-n", "3"]);
        let s = Launcher::parse("srun -n {ranks} --cpus-per-task={threads} --cpu-bind=cores").unwrap();
        assert_eq!(s.expand(4, 8), ["srun", "-n", "4", "--cpus-per-task=8", "--cpu-bind=cores"]);
        assert_eq!(Launcher::default().expand(2, 1), ["mpirun", "--bind-to", "none", "-n", "2"]);
    }

    #[test]
    fn bad_templates_are_refused_with_the_reason() {
        assert_eq!(Launcher::parse("  "), Err(LauncherError::Empty));
        assert!(matches!(Launcher::parse("mpirun -n 2"), Err(LauncherError::NoRanks(_))));
        assert_eq!(
            Launcher::parse("mpirun -n {rank}"),
            Err(LauncherError::Unknown { template: "mpirun -n {rank}".into(), name: "{rank}".into() })
        );
        for bad in ["mpirun -n {ranks", "mpirun -n ranks}", "mpirun -n {{ranks}"] {
            assert!(matches!(Launcher::parse(bad), Err(LauncherError::Unbalanced(_))), "{bad}");
        }
        let msg = Launcher::parse("mpirun").unwrap_err().to_string();
        assert!(msg.contains("{ranks}"), "{msg}");
    }

    #[test]
    fn toml_round_trip_and_hints() {
        #[derive(Deserialize)]
        struct P {
            launcher: Launcher,
        }
        let p: P = toml::from_str("launcher = \"mpirun -n {ranks} --oversubscribe\"").unwrap();
        assert_eq!(p.launcher.expand(2, 1).last().unwrap(), "--oversubscribe");
        assert!(toml::from_str::<P>("launcher = \"mpirun\"").is_err());
        assert!(failure_hint("mpirun has detected an attempt to run as root ... --allow-run-as-root").is_some());
        assert!(failure_hint("There are not enough slots available").unwrap().contains("--oversubscribe"));
        assert_eq!(failure_hint("segmentation fault"), None);
        let missing = Launcher::parse("/nonexistent/mpirun -n {ranks}").unwrap().version();
        assert!(missing.contains("cannot start"), "{missing}");
    }
}
