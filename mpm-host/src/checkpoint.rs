//! Checkpoints: the files a run's state is saved in, and the folder that keeps the last two.
//!
//! # A folder of checkpoints
//!
//! ```text
//! DIR/
//!   step-0000001200/        the newest complete checkpoint (one file per rank)
//!     rank-0000.ckpt
//!     rank-0001.ckpt
//!   step-0000001000/        the one before; older ones are removed
//!   .step-0000001400.partial/   being written (ignored, and removed by the next write)
//! ```
//!
//! A checkpoint is written into `.step-N.partial/` (every rank its own file, written,
//! flushed and `fsync`ed), then the folder is `fsync`ed, renamed to `step-N/` and its parent
//! `fsync`ed ([`Folder::commit`]): a checkpoint that exists under its name is complete on
//! disk, whatever kills the run. Only then are checkpoints older than the last two removed.
//! The run that writes into the folder holds its lock (`DIR/.lock`, [`Folder::lock`]): a
//! second run or resume into it waits for the first to end, or is refused.
//!
//! # One rank's file
//!
//! ```text
//! offset 0        b"MPMCKPT1"
//! offset 8        H, the header's length in bytes (u64, little-endian)
//! offset 16       the header: TOML text (UTF-8), padded with spaces to a multiple of 8
//! offset 16 + H   the arrays, each at its `offset` from here, `nbytes` long, little-endian
//! last 32 bytes   SHA-256 of every byte before them
//! ```
//!
//! The header ([`Header`]) names the format and its version, the rank and the rank count,
//! the step and simulated time, the writing binary (version, commit, SHA-256), the run's
//! key, and lists the arrays (`name`, numpy `dtype`, `shape`, `offset`, `nbytes`):
//! `x`, `v` (`<f8`, n x 3: position m, velocity m/s), `mass`, `rho` (`<f8`, n: kg,
//! kg/m^3), `stress` (`<f8`, n x 6, Voigt `xx yy zz yz zx xy`, Pa, tension positive),
//! `eps_p`, `e_int`, `sound` (`<f8`, n: plastic strain, J/kg, m/s), `failed` (`|b1`, n)
//! and, when the particles are not in their initial order (over several ranks, or once the
//! cell order has moved them), `id` (`<u8`, n: each particle's index in the whole initial
//! set). Its `[state]` table is everything else the run carries (the run's spec, energies,
//! the energy balance, timers, histories): what `mpm resume` needs besides the particles.
//! TOML (not JSON) because it writes every float exactly, infinities and NaN included.
//!
//! A reader in Python (3.11+, numpy):
//!
//! ```python
//! import hashlib, tomllib, numpy as np
//!
//! def read_checkpoint(path):
//!     """Header (a dict) and arrays (name -> numpy array) of one rank's checkpoint file."""
//!     b = open(path, "rb").read()
//!     if b[:8] != b"MPMCKPT1":
//!         raise ValueError(f"{path}: not an mpm checkpoint")
//!     if hashlib.sha256(b[:-32]).digest() != b[-32:]:
//!         raise ValueError(f"{path}: checksum mismatch (truncated or corrupted)")
//!     h = int.from_bytes(b[8:16], "little")
//!     header = tomllib.loads(b[16:16 + h].decode())
//!     data = 16 + h
//!     arrays = {
//!         a["name"]: np.frombuffer(b, a["dtype"], a["nbytes"] // np.dtype(a["dtype"]).itemsize,
//!                                  data + a["offset"]).reshape(a["shape"])
//!         for a in header["arrays"]
//!     }
//!     return header, arrays
//!
//! header, p = read_checkpoint("DIR/step-0000001200/rank-0000.ckpt")
//! print(header["step"], header["time_s"], p["x"].shape, p["stress"][:, 2].min())
//! ```

use crate::durable::{sync_file, sync_folder};
use crate::lock::{FolderLock, LockError};
use mpm_core::Particles;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

/// The first 8 bytes of every checkpoint file.
pub const MAGIC: &[u8; 8] = b"MPMCKPT1";
/// The format's name in the header.
pub const FORMAT: &str = "mpm-checkpoint";
/// The version of the layout described in the module docs.
pub const FORMAT_VERSION: u32 = 1;
/// Bytes of the trailing checksum.
const HASH_BYTES: u64 = 32;

// The arrays are written as the machine holds them: the format is little-endian.
const _: () = assert!(cfg!(target_endian = "little"), "checkpoints are written on little-endian machines only");

/// One array of a checkpoint file.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ArrayInfo {
    /// `x`, `v`, `mass`, ... (see the module docs).
    pub name: String,
    /// numpy's type string: `<f8`, `<u8` or `|b1`.
    pub dtype: String,
    /// Rows, and components per row for vectors and tensors.
    pub shape: Vec<u64>,
    /// Bytes from the start of the data section.
    pub offset: u64,
    /// Bytes.
    pub nbytes: u64,
}

/// The header of one rank's checkpoint file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Header {
    /// [`FORMAT`].
    pub format: String,
    /// [`FORMAT_VERSION`].
    pub format_version: u32,
    /// This file's rank.
    pub rank: usize,
    /// Ranks of the run (one file each).
    pub ranks: usize,
    /// Steps taken.
    pub step: u64,
    /// Simulated time (s).
    pub time_s: f64,
    /// This rank's particles.
    pub particles: u64,
    /// When the file was written, seconds since the Unix epoch.
    pub written_unix_s: f64,
    /// Version of the `mpm` that wrote it.
    pub mpm_version: String,
    /// Git commit it was built from.
    pub git_commit: String,
    /// SHA-256 of the `mpm` binary that wrote it.
    pub binary_sha256: String,
    /// The run's key ([`run_key`]).
    pub spec_key: String,
    /// Bytes of the data section.
    pub data_bytes: u64,
    /// The arrays of the data section.
    pub arrays: Vec<ArrayInfo>,
    /// Everything else the run carries (the program's own layout).
    pub state: toml::Table,
}

/// Why a checkpoint file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum Damage {
    /// Not one of ours at all.
    #[error("{0} is not an mpm checkpoint file (it does not start with MPMCKPT1)")]
    Foreign(PathBuf),
    /// Shorter than its header says.
    #[error("{path} is truncated: {got} bytes of the {expected} its header announces")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its length.
        got: u64,
        /// The length its header implies.
        expected: u64,
    },
    /// The bytes are not those written.
    #[error("{path} is corrupted: {why}")]
    Corrupted {
        /// The file.
        path: PathBuf,
        /// What does not match.
        why: String,
    },
    /// Missing or unreadable.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The error.
        source: std::io::Error,
    },
}

/// Why a checkpoint could not be written, or its folder not be used.
#[derive(Debug, thiserror::Error)]
pub enum CheckpointError {
    /// The header does not serialise (a state value TOML cannot hold).
    #[error("cannot write the checkpoint's header")]
    Header(#[source] toml::ser::Error),
    /// A rank's file cannot be created.
    #[error("cannot create the checkpoint file {path}")]
    Create {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A rank's file cannot be written.
    #[error("cannot write the checkpoint file {path} (is the disk full?)")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The folder cannot be listed.
    #[error("cannot list {dir}")]
    List {
        /// The folder.
        dir: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The folder cannot be created.
    #[error("cannot create the checkpoint folder {dir}")]
    CreateFolder {
        /// The folder.
        dir: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A checkpoint being written cannot be begun ([`Folder::partial`]).
    #[error("cannot create {path}")]
    CreatePartial {
        /// Its folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// An old or unfinished checkpoint cannot be removed.
    #[error("cannot remove {path}")]
    Remove {
        /// Its folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A written checkpoint cannot be made complete (synced and renamed).
    #[error("cannot complete the checkpoint {path}")]
    Complete {
        /// The checkpoint's folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A damaged checkpoint cannot be moved aside.
    #[error("cannot move {path} aside")]
    SetAside {
        /// The checkpoint's folder.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// Another run holds the folder's lock.
    #[error(
        "the checkpoint folder {dir} is in use by {who}: another run is writing checkpoints into it; wait for it to end, or give this run a folder of its own"
    )]
    Busy {
        /// The folder.
        dir: PathBuf,
        /// The holder (program, pid, host).
        who: String,
    },
    /// The folder's lock cannot be taken.
    #[error(transparent)]
    Lock(LockError),
    /// The newest checkpoint's header cannot be read.
    #[error(transparent)]
    Damaged(#[from] Damage),
    /// A new run's folder already holds checkpoints of this run.
    #[error(
        "the checkpoint folder {dir} already holds checkpoints of this run (the newest at step {step}): continue it with \
         `mpm resume {dir}`, or give an empty folder to start over"
    )]
    SameRun {
        /// The folder.
        dir: PathBuf,
        /// Step of its newest checkpoint.
        step: u64,
    },
    /// A new run's folder holds checkpoints of another run.
    #[error(
        "the checkpoint folder {dir} holds checkpoints of another run (the newest at step {step}): give a folder of its own \
         to every run"
    )]
    OtherRun {
        /// The folder.
        dir: PathBuf,
        /// Step of its newest checkpoint.
        step: u64,
    },
}

/// A writer that hashes what passes through it.
struct Hashing<W: Write> {
    inner: W,
    hash: Sha256,
    written: u64,
}

impl<W: Write> Write for Hashing<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.inner.write(buf)?;
        self.hash.update(&buf[..n]);
        self.written += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.inner.flush()
    }
}

/// The bytes of a slice of plain numbers (or flags) as the machine holds them.
fn bytes_of<T: bytemuck::NoUninit>(v: &[T]) -> &[u8] {
    bytemuck::cast_slice(v)
}

/// The arrays of `particles` (and `ids`) in file order, with their bytes.
fn arrays<'a>(p: &'a Particles, ids: Option<&'a [u64]>) -> Vec<(&'static str, &'static str, u64, &'a [u8])> {
    let mut a = vec![
        ("x", "<f8", 3, bytes_of(&p.x)),
        ("v", "<f8", 3, bytes_of(&p.v)),
        ("mass", "<f8", 1, bytes_of(&p.mass)),
        ("rho", "<f8", 1, bytes_of(&p.rho)),
        ("stress", "<f8", 6, bytes_of(&p.stress)),
        ("eps_p", "<f8", 1, bytes_of(&p.eps_p)),
        ("e_int", "<f8", 1, bytes_of(&p.e_int)),
        ("sound", "<f8", 1, bytes_of(&p.sound)),
    ];
    if let Some(ids) = ids {
        a.push(("id", "<u8", 1, bytes_of(ids)));
    }
    a.push(("failed", "|b1", 1, bytes_of(&p.failed)));
    a
}

/// What identifies the writer and the run, for [`write_file`].
#[derive(Clone, Debug)]
pub struct Meta {
    /// This rank and the rank count.
    pub rank: usize,
    /// Ranks of the run.
    pub ranks: usize,
    /// Steps taken.
    pub step: u64,
    /// Simulated time (s).
    pub time_s: f64,
    /// [`run_key`] of the run.
    pub spec_key: String,
    /// SHA-256 of this binary.
    pub binary_sha256: String,
}

/// Write one rank's checkpoint file at `path` (created; flushed and `fsync`ed): the
/// particles (`ids`: their global ids, where they are not the indices) and `state`. Returns its bytes.
pub fn write_file(
    path: &Path,
    meta: &Meta,
    state: toml::Table,
    p: &Particles,
    ids: Option<&[u64]>,
) -> Result<u64, CheckpointError> {
    let n = p.len() as u64;
    let mut infos = Vec::new();
    let mut offset = 0u64;
    for (name, dtype, width, bytes) in arrays(p, ids) {
        let shape = if width == 1 { vec![n] } else { vec![n, width] };
        infos.push(ArrayInfo { name: name.into(), dtype: dtype.into(), shape, offset, nbytes: bytes.len() as u64 });
        offset += bytes.len() as u64;
    }
    let header = Header {
        format: FORMAT.into(),
        format_version: FORMAT_VERSION,
        rank: meta.rank,
        ranks: meta.ranks,
        step: meta.step,
        time_s: meta.time_s,
        particles: n,
        written_unix_s: crate::clock::unix_now(),
        mpm_version: crate::identity::VERSION.into(),
        git_commit: crate::identity::GIT_COMMIT.into(),
        binary_sha256: meta.binary_sha256.clone(),
        spec_key: meta.spec_key.clone(),
        data_bytes: offset,
        arrays: infos,
        state,
    };
    let mut text = toml::to_string(&header).map_err(CheckpointError::Header)?;
    while text.len() % 8 != 0 {
        text.push(' ');
    }
    let file = File::create(path).map_err(|source| CheckpointError::Create { path: path.to_path_buf(), source })?;
    let mut w = Hashing { inner: BufWriter::with_capacity(1 << 22, file), hash: Sha256::new(), written: 0 };
    let written = (|| -> std::io::Result<u64> {
        w.write_all(MAGIC)?;
        w.write_all(&(text.len() as u64).to_le_bytes())?;
        w.write_all(text.as_bytes())?;
        for (_, _, _, bytes) in arrays(p, ids) {
            w.write_all(bytes)?;
        }
        let digest = w.hash.clone().finalize();
        w.inner.write_all(&digest)?;
        let file = w.inner.into_inner().map_err(|e| e.into_error())?;
        sync_file(&file)?;
        Ok(w.written + HASH_BYTES)
    })()
    .map_err(|source| CheckpointError::Write { path: path.to_path_buf(), source })?;
    Ok(written)
}

/// A file opened past its header: the reader at the data section, the header, its text's
/// bytes (for the checksum) and the file's length.
struct Opened {
    reader: BufReader<File>,
    header: Header,
    text: Vec<u8>,
    len: u64,
}

/// Read the magic and the header of `path`, and check the file's length against it.
fn open_header(path: &Path) -> Result<Opened, Damage> {
    let io = |source| Damage::Io { path: path.to_path_buf(), source };
    let file = File::open(path).map_err(io)?;
    let len = file.metadata().map_err(io)?.len();
    let mut r = BufReader::with_capacity(1 << 22, file);
    let mut head = vec![0u8; len.min(16) as usize];
    r.read_exact(&mut head).map_err(io)?;
    let k = head.len().min(8);
    if head[..k] != MAGIC[..k] {
        return Err(foreign(path));
    }
    if len < 16 {
        return Err(truncated(path, len, 16 + HASH_BYTES));
    }
    let h = u64::from_le_bytes(head[8..16].try_into().expect("8 bytes"));
    // Sums saturate: a corrupted length is a file shorter than it announces, never an
    // overflow, and nothing is allocated for more than the file holds.
    let with_header = h.saturating_add(16 + HASH_BYTES);
    if with_header > len {
        return Err(truncated(path, len, with_header));
    }
    let mut text = vec![0u8; usize::try_from(h).map_err(|_| truncated(path, len, u64::MAX))?];
    r.read_exact(&mut text).map_err(io)?;
    let corrupt = |why: String| Damage::Corrupted { path: path.to_path_buf(), why };
    let text = std::str::from_utf8(&text).map_err(|_| corrupt("its header is not text".into()))?;
    let header: Header = toml::from_str(text).map_err(|e| corrupt(format!("its header does not read: {e}")))?;
    if header.format != FORMAT || header.format_version != FORMAT_VERSION {
        return Err(corrupt(format!(
            "format {} version {}, this mpm reads {FORMAT} version {FORMAT_VERSION}",
            header.format, header.format_version
        )));
    }
    let expected = with_header.saturating_add(header.data_bytes);
    if len < expected {
        return Err(truncated(path, len, expected));
    }
    if len > expected {
        return Err(corrupt(format!("{len} bytes, {} more than its header announces", len - expected)));
    }
    Ok(Opened { reader: r, header, text: text.as_bytes().to_vec(), len })
}

fn foreign(path: &Path) -> Damage {
    Damage::Foreign(path.to_path_buf())
}

fn truncated(path: &Path, got: u64, expected: u64) -> Damage {
    Damage::Truncated { path: path.to_path_buf(), got, expected }
}

/// The header of the checkpoint file at `path`, checking only that the file is as long as
/// the header says (not its checksum: [`read_file`] does that).
pub fn read_header(path: &Path) -> Result<Header, Damage> {
    open_header(path).map(|o| o.header)
}

/// A checkpoint file read back and checked: its header, the particles and their global ids
/// (over several ranks).
#[derive(Debug)]
pub struct Loaded {
    /// The header (with the run's state).
    pub header: Header,
    /// The particles, in the order they were saved.
    pub particles: Particles,
    /// Their global ids (over several ranks, and once the cell order has moved particles).
    pub ids: Option<Vec<u64>>,
    /// Bytes of the file.
    pub bytes: u64,
}

/// Read `len` values of type `T` into a vector, hashing the bytes.
fn read_vec<T: bytemuck::Pod + Default + Clone, R: Read>(
    r: &mut R,
    hash: &mut Sha256,
    len: usize,
) -> std::io::Result<Vec<T>> {
    let mut v = vec![T::default(); len];
    let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut v);
    r.read_exact(bytes)?;
    hash.update(&*bytes);
    Ok(v)
}

/// Read and check the checkpoint file at `path`: its length, every array, the checksum.
pub fn read_file(path: &Path) -> Result<Loaded, Damage> {
    let Opened { reader: mut r, header, text, len } = open_header(path)?;
    let corrupt = |why: String| Damage::Corrupted { path: path.to_path_buf(), why };
    let io = |source| Damage::Io { path: path.to_path_buf(), source };
    let mut hash = Sha256::new();
    hash.update(MAGIC);
    hash.update((text.len() as u64).to_le_bytes());
    hash.update(&text);
    let n = usize::try_from(header.particles).map_err(|_| corrupt("its particle count is too large".into()))?;
    let mut expected: Vec<(&str, &str, u64)> = vec![
        ("x", "<f8", 24),
        ("v", "<f8", 24),
        ("mass", "<f8", 8),
        ("rho", "<f8", 8),
        ("stress", "<f8", 48),
        ("eps_p", "<f8", 8),
        ("e_int", "<f8", 8),
        ("sound", "<f8", 8),
    ];
    let has_ids = header.arrays.iter().any(|a| a.name == "id");
    if has_ids {
        expected.push(("id", "<u8", 8));
    }
    expected.push(("failed", "|b1", 1));
    let mut offset = 0;
    if header.arrays.len() != expected.len() {
        return Err(corrupt(format!("{} arrays listed, {} expected", header.arrays.len(), expected.len())));
    }
    for (a, (name, dtype, size)) in header.arrays.iter().zip(&expected) {
        let nbytes = size.checked_mul(header.particles);
        let width = size / if *dtype == "|b1" { 1 } else { 8 };
        let shape = if width == 1 { vec![header.particles] } else { vec![header.particles, width] };
        if a.name != *name || a.dtype != *dtype || a.offset != offset || Some(a.nbytes) != nbytes || a.shape != shape {
            return Err(corrupt(format!("array {} is not where or what it should be", a.name)));
        }
        // The data section fits in the file (checked above), so its arrays' sum does too.
        offset = offset.saturating_add(a.nbytes);
    }
    if offset != header.data_bytes {
        return Err(corrupt("its arrays do not fill its data section".into()));
    }
    let read =
        |r: &mut BufReader<File>, hash: &mut Sha256| -> std::io::Result<(Particles, Option<Vec<u64>>, Vec<u8>)> {
            let p = Particles {
                x: read_vec(r, hash, n)?,
                v: read_vec(r, hash, n)?,
                mass: read_vec(r, hash, n)?,
                rho: read_vec(r, hash, n)?,
                stress: read_vec(r, hash, n)?,
                eps_p: read_vec(r, hash, n)?,
                e_int: read_vec(r, hash, n)?,
                sound: read_vec(r, hash, n)?,
                failed: Vec::new(),
            };
            let ids = if has_ids { Some(read_vec::<u64, _>(r, hash, n)?) } else { None };
            let flags = read_vec::<u8, _>(r, hash, n)?;
            Ok((p, ids, flags))
        };
    let (mut particles, ids, flags) = read(&mut r, &mut hash).map_err(io)?;
    let mut stored = [0u8; 32];
    r.read_exact(&mut stored).map_err(io)?;
    if hash.finalize().as_slice() != stored {
        return Err(corrupt("its SHA-256 checksum does not match its content".into()));
    }
    if let Some(bad) = flags.iter().find(|&&f| f > 1) {
        return Err(corrupt(format!("a failure flag holds {bad}, not 0 or 1")));
    }
    particles.failed = flags.into_iter().map(|f| f == 1).collect();
    Ok(Loaded { header, particles, ids, bytes: len })
}

/// A folder of checkpoints (see the module docs).
#[derive(Clone, Debug)]
pub struct Folder {
    dir: PathBuf,
}

/// One complete checkpoint in a [`Folder`].
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Entry {
    /// Steps taken when it was written.
    pub step: u64,
    /// Its folder.
    pub path: PathBuf,
}

impl Entry {
    /// The file of `rank` in this checkpoint.
    pub fn rank_file(&self, rank: usize) -> PathBuf {
        self.path.join(format!("rank-{rank:04}.ckpt"))
    }
}

/// The name of the checkpoint of `step`.
fn step_name(step: u64) -> String {
    format!("step-{step:010}")
}

/// The error of a folder that cannot be removed.
fn remove(path: &Path) -> impl FnOnce(std::io::Error) -> CheckpointError + '_ {
    move |source| CheckpointError::Remove { path: path.to_path_buf(), source }
}

impl Folder {
    /// The checkpoints in `dir`.
    pub fn new(dir: &Path) -> Self {
        Self { dir: dir.to_path_buf() }
    }

    /// The folder.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Take the folder's lock for the run that writes its checkpoints (one process: rank
    /// 0), waiting up to `wait` for another holder to end (the ranks of a run killed with its
    /// launcher end a moment after it). Held until dropped.
    pub fn lock(&self, wait: Duration) -> Result<FolderLock, CheckpointError> {
        let waiting = |who: &str| {
            eprintln!("waiting for the checkpoint folder {} (in use by {who})", self.dir.display());
        };
        match FolderLock::acquire(&self.dir, "mpm", Some(wait), waiting) {
            Ok(lock) => Ok(lock),
            Err(LockError::Busy(who)) => Err(CheckpointError::Busy { dir: self.dir.clone(), who }),
            Err(e) => Err(CheckpointError::Lock(e)),
        }
    }

    /// Its complete checkpoints, oldest first (none when the folder does not exist).
    pub fn list(&self) -> Result<Vec<Entry>, CheckpointError> {
        let failed = |source| CheckpointError::List { dir: self.dir.clone(), source };
        let rd = match std::fs::read_dir(&self.dir) {
            Ok(rd) => rd,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
            Err(e) => return Err(failed(e)),
        };
        let mut out = Vec::new();
        for e in rd {
            let e = e.map_err(failed)?;
            let name = e.file_name().to_string_lossy().into_owned();
            let step = name.strip_prefix("step-").filter(|s| s.len() == 10).and_then(|s| s.parse::<u64>().ok());
            if let Some(step) = step.filter(|_| e.path().is_dir()) {
                out.push(Entry { step, path: e.path() });
            }
        }
        out.sort_by_key(|e| e.step);
        Ok(out)
    }

    /// The folder a checkpoint of `step` is written into before [`Folder::commit`].
    pub fn partial(&self, step: u64) -> PathBuf {
        self.dir.join(format!(".{}.partial", step_name(step)))
    }

    /// Make an empty [`Folder::partial`] for `step` (removing one a killed run left behind),
    /// creating the folder itself if needed. One process (rank 0) calls it before any rank
    /// writes.
    pub fn begin(&self, step: u64) -> Result<PathBuf, CheckpointError> {
        std::fs::create_dir_all(&self.dir)
            .map_err(|source| CheckpointError::CreateFolder { dir: self.dir.clone(), source })?;
        let partial = self.partial(step);
        if partial.exists() {
            std::fs::remove_dir_all(&partial).map_err(remove(&partial))?;
        }
        std::fs::create_dir(&partial)
            .map_err(|source| CheckpointError::CreatePartial { path: partial.clone(), source })?;
        Ok(partial)
    }

    /// Once every rank's file of `step` is in [`Folder::partial`] (and synced): make it the
    /// checkpoint `step-N` (synced, renamed, the parent synced), then remove the
    /// checkpoints older than the last two and any other unfinished ones. Returns the
    /// checkpoint's entry.
    pub fn commit(&self, step: u64) -> Result<Entry, CheckpointError> {
        let partial = self.partial(step);
        let path = self.dir.join(step_name(step));
        (|| -> std::io::Result<()> {
            sync_folder(&partial)?;
            if path.exists() {
                // Only a run continued from an older checkpoint writes a step again, and then
                // this one is the same state: replace it.
                std::fs::remove_dir_all(&path)?;
            }
            std::fs::rename(&partial, &path)?;
            sync_folder(&self.dir)
        })()
        .map_err(|source| CheckpointError::Complete { path: path.clone(), source })?;
        let entries = self.list()?;
        for old in entries.iter().rev().skip(2) {
            std::fs::remove_dir_all(&old.path).map_err(remove(&old.path))?;
        }
        if let Ok(rd) = std::fs::read_dir(&self.dir) {
            for e in rd.flatten() {
                let name = e.file_name().to_string_lossy().into_owned();
                if name.starts_with(".step-") && name.ends_with(".partial") {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        Ok(Entry { step, path })
    }

    /// Move the checkpoint `entry` aside as `damaged-step-N` (numbered if that exists): it
    /// is kept for inspection, and no later checkpoint of the same step replaces it.
    pub fn set_aside(&self, entry: &Entry) -> Result<PathBuf, CheckpointError> {
        let base = format!("damaged-{}", step_name(entry.step));
        let mut to = self.dir.join(&base);
        let mut k = 2;
        while to.exists() {
            to = self.dir.join(format!("{base}-{k}"));
            k += 1;
        }
        std::fs::rename(&entry.path, &to)
            .map_err(|source| CheckpointError::SetAside { path: entry.path.clone(), source })?;
        Ok(to)
    }
}

/// The key a checkpoint names its run by: the spec's [`mpm_spec::RunSpec::key`] with the
/// warm-up left out (a fresh run resolves it only once its first time step is known, and it
/// changes no result).
pub fn run_key(spec: &mpm_spec::RunSpec) -> String {
    let mut s = spec.clone();
    s.budget.warmup = None;
    s.key()
}

/// The rank count and run key of the newest checkpoint in `dir` and when it was written, from
/// rank 0's header (not checked further): what the harness and `mpm resume` need before
/// they start a run. `None` when `dir` holds no checkpoint.
pub fn newest_header(dir: &Path) -> Result<Option<(Entry, Header)>, CheckpointError> {
    let Some(entry) = Folder::new(dir).list()?.pop() else { return Ok(None) };
    let header = read_header(&entry.rank_file(0))?;
    Ok(Some((entry, header)))
}

/// Refuse `dir` as a new run's checkpoint folder when it already holds checkpoints, so
/// that nothing in it is overwritten: of this run (`key`, its [`run_key`]), continue it with
/// `mpm resume`; of another, choose another folder.
pub fn refuse_used_folder(dir: &Path, key: &str) -> Result<(), CheckpointError> {
    let entries = Folder::new(dir).list()?;
    let Some(newest) = entries.last() else { return Ok(()) };
    let same = read_header(&newest.rank_file(0)).is_ok_and(|h| h.spec_key == key);
    let (dir, step) = (dir.to_path_buf(), newest.step);
    Err(if same { CheckpointError::SameRun { dir, step } } else { CheckpointError::OtherRun { dir, step } })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(n: usize) -> Particles {
        let mut p = Particles::with_capacity(n);
        for i in 0..n {
            let f = i as f64;
            p.push([f, -f, 0.5 * f], [1.0, 2.0, f], 1e-3, 8930.0 + f, 3940.0);
            p.stress[i] = [f, 1.0, -2.0, 3.0, 4.0, 5.0e8];
            p.e_int[i] = f * 1e3;
        }
        p.failed[n / 2] = true;
        p
    }

    fn meta() -> Meta {
        Meta { rank: 0, ranks: 1, step: 7, time_s: 1.25e-6, spec_key: "k".into(), binary_sha256: "b".into() }
    }

    fn state() -> toml::Table {
        let mut t = toml::Table::new();
        for (k, v) in
            [("tiny", 5e-324), ("huge", f64::MAX), ("neg_zero", -0.0), ("inf", f64::INFINITY), ("third", 1.0 / 3.0)]
        {
            t.insert(k.into(), toml::Value::Float(v));
        }
        t.insert("nan".into(), toml::Value::Float(f64::NAN));
        t
    }

    /// Particles, ids and the state come back bit for bit; floats the TOML text must write
    /// exactly (subnormals, extremes, -0, infinity, NaN) included.
    #[test]
    fn a_file_reads_back_bit_for_bit() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.ckpt");
        let p = sample(101);
        let ids: Vec<u64> = (0..101).map(|i| 1000 + 3 * i).collect();
        let bytes = write_file(&path, &meta(), state(), &p, Some(&ids)).unwrap();
        assert_eq!(bytes, std::fs::metadata(&path).unwrap().len());
        let back = read_file(&path).unwrap();
        assert!(back.particles == p);
        assert_eq!(back.ids.as_deref(), Some(&ids[..]));
        let s = &back.header.state;
        for k in ["tiny", "huge", "neg_zero", "inf", "third"] {
            assert_eq!(s[k].as_float().unwrap().to_bits(), state()[k].as_float().unwrap().to_bits(), "{k}");
        }
        assert!(s["nan"].as_float().unwrap().is_nan());
        assert_eq!((back.header.step, back.header.particles, back.header.rank), (7, 101, 0));
        let names: Vec<&str> = back.header.arrays.iter().map(|a| a.name.as_str()).collect();
        assert_eq!(names, ["x", "v", "mass", "rho", "stress", "eps_p", "e_int", "sound", "id", "failed"]);
        // One process: no ids.
        write_file(&path, &meta(), state(), &p, None).unwrap();
        assert!(read_file(&path).unwrap().ids.is_none());
    }

    /// A file cut short, a flipped bit anywhere, or another file are each named for what
    /// they are.
    #[test]
    fn damage_is_found_and_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("r.ckpt");
        let p = sample(50);
        write_file(&path, &meta(), state(), &p, None).unwrap();
        let good = std::fs::read(&path).unwrap();
        for cut in [good.len() - 1, good.len() - 40, good.len() / 2, 100, 12] {
            std::fs::write(&path, &good[..cut]).unwrap();
            let e = read_file(&path).unwrap_err();
            assert!(matches!(e, Damage::Truncated { .. }), "cut at {cut}: {e}");
            assert!(e.to_string().contains("truncated"), "{e}");
        }
        let data_start = good.len() - 32 - 50 * 137;
        for at in [data_start + 3, good.len() - 60, good.len() - 1] {
            let mut bad = good.clone();
            bad[at] ^= 0x10;
            std::fs::write(&path, &bad).unwrap();
            let e = read_file(&path).unwrap_err();
            assert!(e.to_string().contains("checksum does not match"), "flip at {at}: {e}");
        }
        let mut bad = good.clone();
        bad[20] = b'#';
        std::fs::write(&path, &bad).unwrap();
        assert!(matches!(read_file(&path).unwrap_err(), Damage::Corrupted { .. }));
        std::fs::write(&path, b"{\"not\": \"a checkpoint\"}").unwrap();
        assert!(matches!(read_file(&path).unwrap_err(), Damage::Foreign(_)));
        assert!(matches!(read_file(&dir.path().join("missing")).unwrap_err(), Damage::Io { .. }));
    }

    /// Commits keep the last two complete checkpoints; a partial one is ignored and swept.
    #[test]
    fn the_folder_keeps_the_last_two() {
        let dir = tempfile::tempdir().unwrap();
        let folder = Folder::new(&dir.path().join("ck"));
        assert!(folder.list().unwrap().is_empty());
        let p = sample(3);
        for step in [10, 20, 30] {
            let partial = folder.begin(step).unwrap();
            write_file(&partial.join("rank-0000.ckpt"), &Meta { step, ..meta() }, state(), &p, None).unwrap();
            assert!(folder.list().unwrap().iter().all(|e| e.step != step), "not listed before its commit");
            folder.commit(step).unwrap();
        }
        std::fs::create_dir(folder.partial(40)).unwrap();
        let steps: Vec<u64> = folder.list().unwrap().iter().map(|e| e.step).collect();
        assert_eq!(steps, [20, 30]);
        let (newest, header) = newest_header(folder.dir()).unwrap().unwrap();
        assert_eq!((newest.step, header.step), (30, 30));
        let aside = folder.set_aside(&newest).unwrap();
        assert!(aside.ends_with("damaged-step-0000000030"));
        assert_eq!(folder.list().unwrap().iter().map(|e| e.step).collect::<Vec<_>>(), [20]);
        let partial = folder.begin(50).unwrap();
        write_file(&partial.join("rank-0000.ckpt"), &Meta { step: 50, ..meta() }, state(), &p, None).unwrap();
        folder.commit(50).unwrap();
        assert!(!folder.partial(40).exists(), "the unfinished checkpoint is swept");
        assert!(aside.exists(), "the damaged one is kept");
        let err = refuse_used_folder(folder.dir(), "k").unwrap_err().to_string();
        assert!(err.contains("mpm resume") && err.contains("step 50"), "{err}");
        let err = refuse_used_folder(folder.dir(), "other").unwrap_err().to_string();
        assert!(err.contains("another run"), "{err}");
        refuse_used_folder(&dir.path().join("fresh"), "k").unwrap();
    }
}
