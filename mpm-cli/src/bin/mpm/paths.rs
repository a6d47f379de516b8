//! Outputs that would overwrite an input or another output, refused before the run: the
//! summary written over its own spec (`--spec s.toml --json s.toml`), a state dump over
//! the summary, files written into the checkpoint folder or over a checkpoint being
//! continued, snapshots into the checkpoint folder. Paths are compared by what they name:
//! their canonical form (symbolic links and `..` resolved; a file not yet written by its
//! folder's), and the device and inode of files that exist (hard links). Devices such as
//! `/dev/null` are never refused.

use anyhow::{bail, Result};
use mpm_spec::RunSpec;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// A file or folder a run reads or writes, and the flag (or role) that names it.
#[derive(Clone, Copy)]
pub struct Named<'a> {
    /// The flag or role, for the message (`--json`, `the spec file --spec`).
    pub name: &'a str,
    /// The path.
    pub path: &'a Path,
    /// Whether it is a folder (of files the run reads or writes) rather than one file.
    pub folder: bool,
}

impl<'a> Named<'a> {
    /// A file.
    pub fn file(name: &'a str, path: &'a Path) -> Self {
        Self { name, path, folder: false }
    }

    /// A folder.
    pub fn folder(name: &'a str, path: &'a Path) -> Self {
        Self { name, path, folder: true }
    }
}

/// What `path` names: its canonical form, or for a path that does not exist yet its
/// nearest existing folder's canonical form joined with the rest (the path made absolute
/// when none resolves).
fn identity(path: &Path) -> PathBuf {
    let absolute = std::path::absolute(path).unwrap_or_else(|_| path.to_path_buf());
    let mut rest = Vec::new();
    let mut at = absolute.as_path();
    loop {
        if let Ok(mut c) = at.canonicalize() {
            c.extend(rest.iter().rev());
            return c;
        }
        match (at.parent(), at.file_name()) {
            (Some(parent), Some(name)) => {
                rest.push(name.to_os_string());
                at = parent;
            }
            _ => return absolute,
        }
    }
}

/// Whether `a` and `b` name the same file or folder.
fn same(a: &Path, b: &Path) -> bool {
    let inode = |p: &Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
    identity(a) == identity(b) || inode(a).is_some_and(|i| Some(i) == inode(b))
}

/// Whether `path` is inside the folder `dir` (or is it).
fn inside(path: &Path, dir: &Path) -> bool {
    identity(path).starts_with(identity(dir))
}

/// The outputs of `spec`: its files and folders, by flag.
fn outputs(spec: &RunSpec) -> Vec<Named<'_>> {
    let o = &spec.outputs;
    let mut out = Vec::new();
    out.extend(o.json.as_deref().map(|p| Named::file("--json", p)));
    out.extend(o.dump_state.as_deref().map(|p| Named::file("--dump-state", p)));
    out.extend(o.vtk.as_ref().map(|v| Named::folder("--vtk", &v.dir)));
    out.extend(o.radiograph.as_ref().map(|r| Named::folder("--radiograph", &r.dir)));
    out.extend(o.checkpoint.as_ref().map(|c| Named::folder("--checkpoint-dir", &c.dir)));
    out
}

/// Why the output `out` would overwrite or mix with `other` (an input, or another output),
/// or `None`. A file is refused where it is the other path or lies in the checkpoint
/// folder; a folder where it is the other path, or the checkpoint folder of another output.
fn clash(out: &Named<'_>, other: &Named<'_>) -> Option<&'static str> {
    let checkpoints = |n: &Named<'_>| n.name == "--checkpoint-dir" || n.name.starts_with("the checkpoint folder");
    if same(out.path, other.path) {
        return Some(if out.folder || other.folder { "is the same folder as" } else { "is the same file as" });
    }
    if !out.folder && other.folder && checkpoints(other) && inside(out.path, other.path) {
        return Some("lies in");
    }
    None
}

/// Refuse outputs of `spec` that would overwrite one of `inputs` (the spec file, the
/// checkpoint folder being continued) or each other. `continued`: the checkpoint folder a
/// resumed run goes on writing into (its own input, not a clash).
pub fn check_outputs(spec: &RunSpec, inputs: &[Named<'_>], continued: Option<&Path>) -> Result<()> {
    let outs = outputs(spec);
    let special = |n: &Named<'_>| mpm_host::atomic::is_special(n.path);
    for (i, out) in outs.iter().enumerate().filter(|(_, o)| !special(o)) {
        let resumed = |n: &Named<'_>| out.folder && continued.is_some_and(|c| same(n.path, c) && same(out.path, c));
        for other in inputs.iter().chain(&outs[i + 1..]).filter(|n| !special(n) && !resumed(n)) {
            if let Some(how) = clash(out, other) {
                let (a, b) = (out.path.display(), other.path.display());
                bail!(
                    "{} {a} {how} {} {b}: the run would write over it or mix its files with it; give {} a path of \
                     its own",
                    out.name,
                    other.name,
                    out.name
                );
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use mpm_spec::scenario::TaylorSpec;
    use mpm_spec::spec::{CheckpointEvery, CheckpointOutput, VtkEncoding, VtkOutput};

    fn spec() -> RunSpec {
        RunSpec::new(mpm_spec::Scenario::Taylor(TaylorSpec::model(1))).unwrap()
    }

    /// The clashes the module names, each refused naming both flags; distinct paths, two
    /// outputs to /dev/null and a resumed run's own folder pass.
    #[test]
    fn outputs_over_inputs_or_each_other_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        let toml = d.join("s.toml");
        std::fs::write(&toml, "x").unwrap();
        let link = d.join("hard.toml");
        std::fs::hard_link(&toml, &link).unwrap();
        let ck = d.join("ck");
        let input = [Named::file("the spec file --spec", &toml)];
        let refused = |s: &RunSpec, inputs: &[Named<'_>], continued: Option<&Path>, says: &str| {
            let err = check_outputs(s, inputs, continued).unwrap_err().to_string();
            assert!(err.contains(says), "{err}");
        };
        let mut s = spec();
        s.outputs.json = Some(toml.clone());
        refused(&s, &input, None, "--json");
        s.outputs.json = Some(d.join(".").join("sub/../s.toml"));
        std::fs::create_dir(d.join("sub")).unwrap();
        refused(&s, &input, None, "is the same file as the spec file --spec");
        s.outputs.json = Some(link.clone());
        refused(&s, &input, None, "is the same file as");
        s.outputs.json = Some(d.join("out.json"));
        check_outputs(&s, &input, None).unwrap();
        s.outputs.dump_state = Some(d.join("out.json"));
        refused(&s, &input, None, "--json");
        s.outputs.dump_state = Some(ck.join("state.bin"));
        s.outputs.checkpoint = Some(CheckpointOutput { dir: ck.clone(), every: CheckpointEvery::Steps(5) });
        refused(&s, &input, None, "--dump-state");
        refused(&s, &input, None, "lies in --checkpoint-dir");
        s.outputs.dump_state = None;
        s.outputs.vtk = Some(VtkOutput { dir: ck.clone(), every: 5, encoding: VtkEncoding::Compressed });
        refused(&s, &input, None, "is the same folder as --checkpoint-dir");
        s.outputs.vtk = None;
        // A resumed run writes on into its folder; a summary into it is refused.
        let folder = [Named::folder("the checkpoint folder", &ck)];
        check_outputs(&s, &folder, Some(&ck)).unwrap();
        s.outputs.json = Some(ck.join("step-0000000010/rank-0000.ckpt"));
        refused(&s, &folder, Some(&ck), "lies in the checkpoint folder");
        s.outputs = Default::default();
        s.outputs.json = Some("/dev/null".into());
        s.outputs.dump_state = Some("/dev/null".into());
        check_outputs(&s, &input, None).unwrap();
    }
}
