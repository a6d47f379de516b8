//! # mpm-spec
//!
//! The run as one typed value, and the one contract between the `mpm` program and the
//! benchmark harness `mpm-bench`:
//!
//! * [`RunSpec`]: what one run of `mpm` computes ([`Scenario`] and its parameters, strategy,
//!   threads, ranks, CPUs, grid, physics, budget) and writes ([`spec::Outputs`]). `mpm run`
//!   builds it from its flags or reads it from a file (`mpm run --spec FILE`); the harness
//!   writes one file per run and never composes solver flags. [`RunSpec::key`] identifies
//!   the computation.
//! * [`Summary`]: what came out, written by `mpm` as JSON and read back by the harness,
//!   scripts and tests; it echoes the resolved spec.
//! * [`memory`]: the memory a run will need, estimated from its spec (a paired run's two
//!   solvers counted), what `mpm` checks against the memory it may use.
//! * [`OptLevel`] and the host's [`identity`] types, shared by both programs.
//!
//! No MPI and no OS-specific code: the harness builds against this crate without an MPI
//! library. Reading `/proc` and pinning live in `mpm-host`, MPI in `mpm-cli`.
//!
//! ```
//! use mpm_spec::{RunSpec, Scenario, scenario::TaylorSpec};
//! let mut spec = RunSpec::new(Scenario::Taylor(TaylorSpec::model(1))).unwrap();
//! spec.strategy = mpm_core::Strategy::DomainDecomposition;
//! spec.threads = 2;
//! spec.budget.steps = Some(20);
//! spec.check().unwrap();
//! let text = spec.to_toml();
//! assert_eq!(RunSpec::parse(&text, mpm_spec::spec::SpecFormat::Toml).unwrap(), spec);
//! ```

pub mod build;
pub mod identity;
pub mod memory;
pub mod scenario;
pub mod spec;
pub mod summary;

pub use build::OptLevel;
pub use scenario::{Scenario, ScenarioKind};
pub use spec::{RunSpec, SPEC_VERSION};
pub use summary::Summary;

/// What is wrong with a spec, in words that say what to do.
#[derive(Debug, thiserror::Error)]
pub enum SpecError {
    /// A value out of range or inconsistent with another.
    #[error("invalid {key} ({flag}): {why}")]
    Invalid {
        /// The spec key (`physics.cfl`).
        key: &'static str,
        /// The `mpm run` flag that sets it (`--cfl`).
        flag: &'static str,
        /// Why, and what to give instead.
        why: String,
    },
    /// A spec file that does not parse (syntax, an unknown or missing key).
    #[error("cannot read the spec: {0}")]
    Parse(String),
    /// A spec file of another layout version.
    #[error("the spec has spec_version {0}, this mpm reads version {SPEC_VERSION}: write it again with this version (e.g. `mpm run ... --print-spec`)")]
    Version(i64),
    /// A file that cannot be read.
    #[error("{0}")]
    Io(String),
    /// The scenario cannot be built with these parameters.
    #[error(transparent)]
    Scenario(#[from] mpm_core::SimError),
}
