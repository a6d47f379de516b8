//! VTU snapshots of the particles (one file per snapshot, or one piece per MPI rank and a
//! `.pvtu` naming them) and a `.pvd` collection over them, for ParaView.
//!
//! Each snapshot is a VTK XML unstructured grid (`.vtu`, format version 1.0, little-endian,
//! 64-bit headers) with one `VTK_VERTEX` cell per particle, so the particles render without
//! a glyph filter. Point data (SI units):
//!
//! | array | components | meaning |
//! |---|---|---|
//! | `velocity` | 3 | m/s |
//! | `stress` | 6, Voigt `xx yy zz yz zx xy` | Cauchy stress, Pa, tension positive |
//! | `pressure` | 1 | `-tr(sigma)/3`, Pa, compression positive |
//! | `von_mises` | 1 | equivalent stress `sqrt(3/2 s:s)`, Pa |
//! | `eps_p` | 1 | effective plastic strain |
//! | `density` | 1 | kg/m^3 |
//! | `failed` | 1 (`UInt8`) | 1 once the particle has failed |
//!
//! The simulated time and step are stored as field data `TIME` and `CYCLE`. Arrays are
//! written in one of three encodings ([`Encoding`]):
//!
//! * `compressed` (the default): raw little-endian values appended after the XML
//!   (`<AppendedData encoding="raw">`), each array zlib-compressed in blocks of 1 MiB as
//!   VTK's `vtkZLibDataCompressor` writes them (a `UInt64` header: block count, block size,
//!   size of the last block, each block's compressed size; then the blocks), which ParaView
//!   and VisIt read as they are. The compression is pure Rust (`flate2` on `miniz_oxide`),
//!   at zlib's fastest level: the connectivity, offsets, cell types and failure flags shrink
//!   to almost nothing, the floating-point fields by a few percent to a third;
//! * `binary`: inline base64 (a `UInt64` byte count followed by the raw values, encoded as
//!   one base64 stream, as VTK's own writer does), a third larger than the raw bytes;
//! * `ascii`: inline text, values in shortest round-trip form.
//!
//! The collection file `<prefix>.pvd` lists every snapshot with its time and is
//! rewritten (atomically) after each one, so it is valid even if the run stops early.
//!
//! Over several MPI ranks each rank writes its own particles as one piece per snapshot,
//! `<prefix>_<step>_<rank>.vtu` (a complete `.vtu` as above), and rank 0 the snapshot's
//! `<prefix>_<step>.pvtu` (a `PUnstructuredGrid`: the `PPointData` and `PPoints`
//! declarations of the pieces' arrays and a `Piece` naming each file), written atomically;
//! the `.pvd` then lists the `.pvtu` files. ParaView and VisIt open the `.pvd` as a time
//! series, the pieces of each step as one data set.

use flate2::write::ZlibEncoder;
use flate2::Compression;
use mpm_core::math::{deviator, trace, von_mises};
use mpm_core::Particles;
use mpm_host::atomic::{write_atomic, WriteError};
use std::fmt::Display;
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

/// How the arrays of a `.vtu` are stored (the spec's `outputs.vtk.encoding`).
pub use mpm_spec::spec::VtkEncoding as Encoding;

/// Why a snapshot or the collection was not written.
#[derive(Debug, thiserror::Error)]
pub enum VtkError {
    /// A snapshot file cannot be created.
    #[error("cannot create VTU snapshot {path}")]
    Create {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// A snapshot cannot be written.
    #[error("cannot write VTU snapshot {path}")]
    Write {
        /// The file.
        path: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The snapshot folder cannot be created.
    #[error("cannot create the VTK directory {dir}")]
    CreateDir {
        /// The folder.
        dir: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The snapshot folder cannot be written into.
    #[error("the VTK directory {dir} is not writable")]
    NotWritable {
        /// The folder.
        dir: PathBuf,
        /// What the system said.
        source: std::io::Error,
    },
    /// The `.pvd` collection cannot be written.
    #[error(transparent)]
    Collection(#[from] WriteError),
}

/// A value type of a VTK `DataArray`.
trait VtkScalar: Copy + Display {
    /// The VTK type name.
    const TYPE: &'static str;
    /// Append the little-endian bytes.
    fn put(self, out: &mut Vec<u8>);
}

impl VtkScalar for f64 {
    const TYPE: &'static str = "Float64";
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

impl VtkScalar for i64 {
    const TYPE: &'static str = "Int64";
    fn put(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
}

impl VtkScalar for u8 {
    const TYPE: &'static str = "UInt8";
    fn put(self, out: &mut Vec<u8>) {
        out.push(self);
    }
}

const B64: &[u8; 64] = b"ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";

/// Encode complete 3-byte groups of `input` (and, if `last`, the padded remainder) to
/// `out`; return how many input bytes were consumed.
fn b64_encode(input: &[u8], last: bool, out: &mut Vec<u8>) -> usize {
    let full = input.len() / 3 * 3;
    for c in input[..full].chunks_exact(3) {
        let n = (u32::from(c[0]) << 16) | (u32::from(c[1]) << 8) | u32::from(c[2]);
        out.extend_from_slice(&[
            B64[(n >> 18) as usize & 63],
            B64[(n >> 12) as usize & 63],
            B64[(n >> 6) as usize & 63],
            B64[n as usize & 63],
        ]);
    }
    if !last || full == input.len() {
        return full;
    }
    let rest = &input[full..];
    let b1 = rest.get(1).copied().unwrap_or(0);
    let n = (u32::from(rest[0]) << 16) | (u32::from(b1) << 8);
    out.push(B64[(n >> 18) as usize & 63]);
    out.push(B64[(n >> 12) as usize & 63]);
    out.push(if rest.len() == 2 { B64[(n >> 6) as usize & 63] } else { b'=' });
    out.push(b'=');
    input.len()
}

/// The start tag of an array, `element` (its indentation and name: `        <DataArray`),
/// with its attributes: type, name, components and their names.
fn array_attributes<T: VtkScalar, W: Write>(
    w: &mut W,
    element: &str,
    name: &str,
    ncomp: usize,
    component_names: &[&str],
) -> std::io::Result<()> {
    write!(w, r#"{element} type="{}" Name="{name}""#, T::TYPE)?;
    if ncomp > 1 {
        write!(w, r#" NumberOfComponents="{ncomp}""#)?;
    }
    for (i, c) in component_names.iter().enumerate() {
        write!(w, r#" ComponentName{i}="{c}""#)?;
    }
    Ok(())
}

/// A piece's array element, indented.
const DATA_ARRAY: &str = "        <DataArray";

/// Write one `DataArray` element with `count` tuples of `ncomp` values from `values`.
fn data_array<T: VtkScalar, W: Write>(
    w: &mut W,
    enc: Encoding,
    name: &str,
    ncomp: usize,
    component_names: &[&str],
    count: usize,
    values: impl Iterator<Item = T>,
) -> std::io::Result<()> {
    let format = match enc {
        Encoding::Binary | Encoding::Compressed => "binary",
        Encoding::Ascii => "ascii",
    };
    array_attributes::<T, W>(w, DATA_ARRAY, name, ncomp, component_names)?;
    writeln!(w, r#" format="{format}">"#)?;
    let total = count * ncomp;
    match enc {
        Encoding::Binary | Encoding::Compressed => {
            let bytes = (total * std::mem::size_of::<T>()) as u64;
            let mut raw = Vec::with_capacity(3 * 4096 + 16);
            let mut enc_buf = Vec::with_capacity(4 * 4096 + 32);
            raw.extend_from_slice(&bytes.to_le_bytes());
            w.write_all(b"          ")?;
            let mut written = 0;
            for v in values.take(total) {
                v.put(&mut raw);
                written += 1;
                if raw.len() >= 3 * 4096 {
                    let used = b64_encode(&raw, false, &mut enc_buf);
                    raw.drain(..used);
                    w.write_all(&enc_buf)?;
                    enc_buf.clear();
                }
            }
            debug_assert_eq!(written, total);
            b64_encode(&raw, true, &mut enc_buf);
            w.write_all(&enc_buf)?;
            w.write_all(b"\n")?;
        }
        Encoding::Ascii => {
            let per_line = ncomp.max(1) * if ncomp == 1 { 6 } else { 1 };
            for (i, v) in values.take(total).enumerate() {
                if i % per_line == 0 {
                    if i > 0 {
                        w.write_all(b"\n")?;
                    }
                    w.write_all(b"          ")?;
                } else {
                    w.write_all(b" ")?;
                }
                write!(w, "{v}")?;
            }
            w.write_all(b"\n")?;
        }
    }
    writeln!(w, "        </DataArray>")
}

/// Write the particles as a `.vtu` file at `path` (see the module docs for its content).
pub fn write_vtu(path: &Path, particles: &Particles, time: f64, step: u64, enc: Encoding) -> Result<(), VtkError> {
    let file = File::create(path).map_err(|source| VtkError::Create { path: path.to_path_buf(), source })?;
    let w = BufWriter::with_capacity(1 << 20, file);
    let written = match enc {
        Encoding::Compressed => write_appended(w, particles, time, step),
        Encoding::Binary | Encoding::Ascii => {
            let mut inline = Inline { w, enc };
            snapshot_inline(&mut inline, particles, time, step).and_then(|_| inline.w.flush())
        }
    };
    written.map_err(|source| VtkError::Write { path: path.to_path_buf(), source })
}

/// What [`snapshot`] hands each part of a `.vtu` to: the XML around the arrays, and the
/// arrays (`count` tuples of `ncomp` values each).
trait Visit {
    /// A line of XML.
    fn xml(&mut self, line: std::fmt::Arguments<'_>) -> std::io::Result<()>;
    /// One `DataArray`.
    fn array<T: VtkScalar>(
        &mut self,
        name: &str,
        ncomp: usize,
        component_names: &[&str],
        count: usize,
        values: impl Iterator<Item = T>,
    ) -> std::io::Result<()>;
}

/// The point data's active arrays (the `PointData` and `PPointData` attributes).
const POINT_DATA_ROLES: &str = r#"Scalars="pressure" Vectors="velocity""#;

/// The point data's arrays, in file order (the one place they are listed: the pieces'
/// `PointData` and the `.pvtu`'s `PPointData` both come from here).
fn point_data(v: &mut impl Visit, p: &Particles) -> std::io::Result<()> {
    let n = p.len();
    v.array("velocity", 3, &["x", "y", "z"], n, p.v.iter().flatten().copied())?;
    v.array("stress", 6, &["xx", "yy", "zz", "yz", "zx", "xy"], n, p.stress.iter().flatten().copied())?;
    v.array("pressure", 1, &[], n, p.stress.iter().map(|s| -trace(s) / 3.0))?;
    v.array("von_mises", 1, &[], n, p.stress.iter().map(|s| von_mises(&deviator(s))))?;
    v.array("eps_p", 1, &[], n, p.eps_p.iter().copied())?;
    v.array("density", 1, &[], n, p.rho.iter().copied())?;
    v.array("failed", 1, &[], n, p.failed.iter().map(|&f| u8::from(f)))
}

/// The points' one array (the pieces' `Points` and the `.pvtu`'s `PPoints`).
fn points(v: &mut impl Visit, p: &Particles) -> std::io::Result<()> {
    v.array("Points", 3, &[], p.len(), p.x.iter().flatten().copied())
}

/// The snapshot, part by part, in file order (the one place its layout is written).
fn snapshot(v: &mut impl Visit, p: &Particles, time: f64, step: u64) -> std::io::Result<()> {
    let n = p.len();
    v.xml(format_args!("  <UnstructuredGrid>"))?;
    v.xml(format_args!("    <FieldData>"))?;
    v.xml(format_args!(
        r#"      <DataArray type="Float64" Name="TIME" NumberOfTuples="1" format="ascii">{time:e}</DataArray>"#
    ))?;
    v.xml(format_args!(
        r#"      <DataArray type="Int64" Name="CYCLE" NumberOfTuples="1" format="ascii">{step}</DataArray>"#
    ))?;
    v.xml(format_args!("    </FieldData>"))?;
    v.xml(format_args!(r#"    <Piece NumberOfPoints="{n}" NumberOfCells="{n}">"#))?;
    v.xml(format_args!(r#"      <PointData {POINT_DATA_ROLES}>"#))?;
    point_data(v, p)?;
    v.xml(format_args!("      </PointData>"))?;
    v.xml(format_args!("      <Points>"))?;
    points(v, p)?;
    v.xml(format_args!("      </Points>"))?;
    v.xml(format_args!("      <Cells>"))?;
    v.array("connectivity", 1, &[], n, 0..n as i64)?;
    v.array("offsets", 1, &[], n, 1..=n as i64)?;
    // VTK_VERTEX = 1.
    v.array("types", 1, &[], n, std::iter::repeat_n(1u8, n))?;
    v.xml(format_args!("      </Cells>"))?;
    v.xml(format_args!("    </Piece>"))?;
    v.xml(format_args!("  </UnstructuredGrid>"))
}

/// The file's first two lines; `compressor` names VTK's zlib compressor (appended data).
fn vtk_file_start<W: Write>(w: &mut W, compressor: bool) -> std::io::Result<()> {
    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    writeln!(
        w,
        r#"<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64"{}>"#,
        if compressor { r#" compressor="vtkZLibDataCompressor""# } else { "" }
    )
}

/// Inline arrays (base64 or ASCII), element by element.
struct Inline<W: Write> {
    w: W,
    enc: Encoding,
}

impl<W: Write> Visit for Inline<W> {
    fn xml(&mut self, line: std::fmt::Arguments<'_>) -> std::io::Result<()> {
        writeln!(self.w, "{line}")
    }

    fn array<T: VtkScalar>(
        &mut self,
        name: &str,
        ncomp: usize,
        component_names: &[&str],
        count: usize,
        values: impl Iterator<Item = T>,
    ) -> std::io::Result<()> {
        data_array(&mut self.w, self.enc, name, ncomp, component_names, count, values)
    }
}

/// The inline writer's file: its first lines, the snapshot, the end.
fn snapshot_inline<W: Write>(w: &mut Inline<W>, p: &Particles, time: f64, step: u64) -> std::io::Result<()> {
    vtk_file_start(&mut w.w, false)?;
    snapshot(w, p, time, step)?;
    writeln!(w.w, "</VTKFile>")
}

/// Width of an `offset` attribute written before its value is known (zero-padded decimal,
/// which VTK reads as the number).
const OFFSET_DIGITS: usize = 20;

/// Uncompressed bytes per zlib block of an appended array (VTK's reader takes any size).
const BLOCK_BYTES: usize = 1 << 20;

/// A writer that knows how many bytes it has written.
struct Counting<W: Write> {
    w: W,
    at: u64,
}

impl<W: Write> Write for Counting<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let n = self.w.write(buf)?;
        self.at += n as u64;
        Ok(n)
    }

    fn flush(&mut self) -> std::io::Result<()> {
        self.w.flush()
    }
}

/// The XML with each array an empty element: the first pass of the appended layout (a
/// `DataArray` whose `offset` is left blank, its position recorded, to be filled in once the
/// data is written), or a `.pvtu`'s declarations of its pieces' arrays (`PDataArray`).
struct AppendedXml<W: Write> {
    w: Counting<W>,
    /// The blank offsets' positions; `None`: `.pvtu` declarations.
    blanks: Option<Vec<u64>>,
}

impl<W: Write> Visit for AppendedXml<W> {
    fn xml(&mut self, line: std::fmt::Arguments<'_>) -> std::io::Result<()> {
        writeln!(self.w, "{line}")
    }

    fn array<T: VtkScalar>(
        &mut self,
        name: &str,
        ncomp: usize,
        component_names: &[&str],
        _count: usize,
        _values: impl Iterator<Item = T>,
    ) -> std::io::Result<()> {
        let Some(blanks) = self.blanks.as_mut() else {
            array_attributes::<T, _>(&mut self.w, "      <PDataArray", name, ncomp, component_names)?;
            return writeln!(self.w, "/>");
        };
        array_attributes::<T, _>(&mut self.w, DATA_ARRAY, name, ncomp, component_names)?;
        write!(self.w, r#" format="appended" offset=""#)?;
        blanks.push(self.w.at);
        writeln!(self.w, r#"{:0width$}"/>"#, 0, width = OFFSET_DIGITS)
    }
}

/// Second pass: each array's values, zlib-compressed in blocks, after the `_` that starts
/// the appended data (at file position `base`); its offsets from there recorded.
struct AppendedData<W: Write + Seek> {
    w: Counting<W>,
    base: u64,
    offsets: Vec<u64>,
    raw: Vec<u8>,
    packed: Vec<u8>,
}

impl<W: Write + Seek> AppendedData<W> {
    /// Compress `self.raw` as one block; its compressed size.
    fn block(&mut self) -> std::io::Result<u64> {
        let mut z = ZlibEncoder::new(std::mem::take(&mut self.packed), Compression::fast());
        z.write_all(&self.raw)?;
        self.packed = z.finish()?;
        self.w.write_all(&self.packed)?;
        let size = self.packed.len() as u64;
        self.packed.clear();
        self.raw.clear();
        Ok(size)
    }
}

impl<W: Write + Seek> Visit for AppendedData<W> {
    fn xml(&mut self, _: std::fmt::Arguments<'_>) -> std::io::Result<()> {
        Ok(())
    }

    fn array<T: VtkScalar>(
        &mut self,
        _name: &str,
        ncomp: usize,
        _component_names: &[&str],
        count: usize,
        values: impl Iterator<Item = T>,
    ) -> std::io::Result<()> {
        self.offsets.push(self.w.at - self.base);
        let total = count * ncomp * std::mem::size_of::<T>();
        let blocks = total.div_ceil(BLOCK_BYTES);
        // Header: blocks, block size, size of the last block (0: full), compressed sizes.
        let mut header = vec![blocks as u64, BLOCK_BYTES as u64, (total % BLOCK_BYTES) as u64];
        let at = self.w.at;
        for v in header.iter().chain(std::iter::repeat_n(&0, blocks)) {
            self.w.write_all(&v.to_le_bytes())?;
        }
        for v in values.take(count * ncomp) {
            v.put(&mut self.raw);
            if self.raw.len() >= BLOCK_BYTES {
                let tail = self.raw.split_off(BLOCK_BYTES);
                let size = self.block()?;
                header.push(size);
                self.raw = tail;
            }
        }
        if !self.raw.is_empty() {
            let size = self.block()?;
            header.push(size);
        }
        debug_assert_eq!(header.len(), 3 + blocks);
        // Fill in the compressed sizes, then carry on at the end.
        let end = self.w.at;
        self.w.w.seek(SeekFrom::Start(at))?;
        for v in &header {
            self.w.w.write_all(&v.to_le_bytes())?;
        }
        self.w.w.seek(SeekFrom::Start(end))?;
        Ok(())
    }
}

/// The compressed layout: the XML with blank offsets, the appended data, then the offsets
/// filled in.
fn write_appended<W: Write + Seek>(w: W, p: &Particles, time: f64, step: u64) -> std::io::Result<()> {
    let mut xml = AppendedXml { w: Counting { w, at: 0 }, blanks: Some(Vec::new()) };
    vtk_file_start(&mut xml.w, true)?;
    snapshot(&mut xml, p, time, step)?;
    write!(xml.w, "  <AppendedData encoding=\"raw\">\n   _")?;
    let base = xml.w.at;
    let mut data = AppendedData {
        w: xml.w,
        base,
        offsets: Vec::new(),
        raw: Vec::with_capacity(BLOCK_BYTES + 8),
        packed: Vec::new(),
    };
    snapshot(&mut data, p, time, step)?;
    write!(data.w, "\n  </AppendedData>\n</VTKFile>\n")?;
    let mut w = data.w.w;
    for (at, offset) in xml.blanks.iter().flatten().zip(&data.offsets) {
        w.seek(SeekFrom::Start(*at))?;
        write!(w, "{offset:0width$}", width = OFFSET_DIGITS)?;
    }
    w.flush()
}

/// The `.pvtu` text of one snapshot over ranks: the arrays its pieces hold (declared from
/// the pieces' own layout) and the pieces' files (names relative to the `.pvtu`).
fn pvtu_text(pieces: &[String]) -> std::io::Result<String> {
    let mut d = AppendedXml { w: Counting { w: Vec::new(), at: 0 }, blanks: None };
    writeln!(d.w, r#"<?xml version="1.0"?>"#)?;
    writeln!(
        d.w,
        r#"<VTKFile type="PUnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">"#
    )?;
    writeln!(d.w, r#"  <PUnstructuredGrid GhostLevel="0">"#)?;
    writeln!(d.w, r#"    <PPointData {POINT_DATA_ROLES}>"#)?;
    let none = Particles::default();
    point_data(&mut d, &none)?;
    writeln!(d.w, "    </PPointData>")?;
    writeln!(d.w, "    <PPoints>")?;
    points(&mut d, &none)?;
    writeln!(d.w, "    </PPoints>")?;
    for piece in pieces {
        writeln!(d.w, r#"    <Piece Source="{piece}"/>"#)?;
    }
    writeln!(d.w, "  </PUnstructuredGrid>\n</VTKFile>")?;
    Ok(String::from_utf8_lossy(&d.w.w).into_owned())
}

/// Write `.pvd` text listing `(time, file)` entries (file names relative to the `.pvd`).
fn pvd_text(entries: &[(f64, String)]) -> String {
    let mut s = String::from(
        "<?xml version=\"1.0\"?>\n<VTKFile type=\"Collection\" version=\"0.1\" byte_order=\"LittleEndian\">\n  <Collection>\n",
    );
    for (t, f) in entries {
        s.push_str(&format!("    <DataSet timestep=\"{t:e}\" group=\"\" part=\"0\" file=\"{f}\"/>\n"));
    }
    s.push_str("  </Collection>\n</VTKFile>\n");
    s
}

/// Writes numbered snapshots `<dir>/<prefix>_<step>.vtu` and keeps `<dir>/<prefix>.pvd`
/// listing them. Over several ranks ([`SnapshotWriter::over_ranks`]) every rank writes its
/// particles as the piece `<dir>/<prefix>_<step>_<rank>.vtu`, rank 0 the snapshot's
/// `<dir>/<prefix>_<step>.pvtu` naming the pieces and the `.pvd` listing the `.pvtu` files.
#[derive(Debug)]
pub struct SnapshotWriter {
    dir: PathBuf,
    prefix: String,
    encoding: Encoding,
    entries: Vec<(f64, String)>,
    steps: Vec<u64>,
    /// This process's rank.
    rank: usize,
    /// The ranks of the run (1: one `.vtu` per snapshot, no pieces).
    ranks: usize,
}

impl SnapshotWriter {
    /// Create `dir` (and parents) if needed and check that it is writable.
    pub fn new(dir: &Path, prefix: &str, encoding: Encoding) -> Result<Self, VtkError> {
        std::fs::create_dir_all(dir).map_err(|source| VtkError::CreateDir { dir: dir.to_path_buf(), source })?;
        let probe = dir.join(format!(".mpm-write-test.{}", std::process::id()));
        File::create(&probe).map_err(|source| VtkError::NotWritable { dir: dir.to_path_buf(), source })?;
        let _ = std::fs::remove_file(&probe);
        Ok(Self {
            dir: dir.to_path_buf(),
            prefix: prefix.to_string(),
            encoding,
            entries: Vec::new(),
            steps: Vec::new(),
            rank: 0,
            ranks: 1,
        })
    }

    /// The writer of `rank` of a run over `ranks` (more than one: pieces and `.pvtu` files).
    pub fn over_ranks(self, rank: usize, ranks: usize) -> Self {
        Self { rank, ranks: ranks.max(1), ..self }
    }

    /// The snapshots written so far as `(step, time, file name)`: what a run continued from
    /// a checkpoint needs to keep the collection ([`SnapshotWriter::resumed`]).
    pub fn written(&self) -> Vec<(u64, f64, String)> {
        self.steps.iter().zip(&self.entries).map(|(&s, (t, f))| (s, *t, f.clone())).collect()
    }

    /// A writer that continues the collection of `written` snapshots (those after the
    /// checkpoint a run continues from are written again).
    pub fn resumed(
        dir: &Path,
        prefix: &str,
        encoding: Encoding,
        written: Vec<(u64, f64, String)>,
    ) -> Result<Self, VtkError> {
        let mut w = Self::new(dir, prefix, encoding)?;
        for (s, t, f) in written {
            w.steps.push(s);
            w.entries.push((t, f));
        }
        Ok(w)
    }

    /// File name of the snapshot of `step`: its `.vtu`, or over several ranks its `.pvtu`.
    pub fn file_name(&self, step: u64) -> String {
        let ext = if self.ranks > 1 { "pvtu" } else { "vtu" };
        format!("{}_{step:06}.{ext}", self.prefix)
    }

    /// File name of `rank`'s piece of the snapshot of `step` (runs over several ranks).
    pub fn piece_name(&self, step: u64, rank: usize) -> String {
        format!("{}_{step:06}_{rank:04}.vtu", self.prefix)
    }

    /// Path of the collection file.
    pub fn pvd_path(&self) -> PathBuf {
        self.dir.join(format!("{}.pvd", self.prefix))
    }

    /// Steps written so far.
    pub fn steps(&self) -> &[u64] {
        &self.steps
    }

    /// Paths of the snapshots written so far.
    pub fn files(&self) -> Vec<PathBuf> {
        self.entries.iter().map(|(_, f)| self.dir.join(f)).collect()
    }

    /// Write the snapshot of `step` at simulated `time` (this rank's particles) and rewrite
    /// the `.pvd` (rank 0; over several ranks the snapshot's `.pvtu` first). A step already
    /// written is skipped.
    pub fn write(&mut self, step: u64, time: f64, particles: &Particles) -> Result<(), VtkError> {
        if self.steps.last() == Some(&step) {
            return Ok(());
        }
        let name = self.file_name(step);
        if self.ranks == 1 {
            write_vtu(&self.dir.join(&name), particles, time, step, self.encoding)?;
        } else {
            write_vtu(&self.dir.join(self.piece_name(step, self.rank)), particles, time, step, self.encoding)?;
        }
        self.entries.push((time, name.clone()));
        self.steps.push(step);
        if self.rank != 0 {
            return Ok(());
        }
        if self.ranks > 1 {
            let pieces: Vec<String> = (0..self.ranks).map(|r| self.piece_name(step, r)).collect();
            let path = self.dir.join(&name);
            let text = pvtu_text(&pieces).map_err(|source| VtkError::Write { path: path.clone(), source })?;
            write_atomic(&path, text.as_bytes())?;
        }
        Ok(write_atomic(&self.pvd_path(), pvd_text(&self.entries).as_bytes())?)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn b64_decode(s: &str) -> Vec<u8> {
        let val = |c: u8| B64.iter().position(|&b| b == c).unwrap() as u32;
        let bytes: Vec<u8> = s.bytes().filter(|b| !b.is_ascii_whitespace()).collect();
        let mut out = Vec::new();
        for q in bytes.chunks(4) {
            let pad = q.iter().filter(|&&b| b == b'=').count();
            let n = q.iter().map(|&b| if b == b'=' { 0 } else { val(b) }).fold(0u32, |a, v| (a << 6) | v);
            let b = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
            out.extend_from_slice(&b[..3 - pad]);
        }
        out
    }

    #[test]
    fn base64_matches_rfc4648_vectors() {
        for (i, o) in [
            ("", ""),
            ("f", "Zg=="),
            ("fo", "Zm8="),
            ("foo", "Zm9v"),
            ("foob", "Zm9vYg=="),
            ("fooba", "Zm9vYmE="),
            ("foobar", "Zm9vYmFy"),
        ] {
            let mut out = Vec::new();
            assert_eq!(b64_encode(i.as_bytes(), true, &mut out), i.len());
            assert_eq!(String::from_utf8(out).unwrap(), o);
            assert_eq!(b64_decode(o), i.as_bytes());
        }
    }

    fn sample(n: usize) -> Particles {
        let mut p = Particles::with_capacity(n);
        for i in 0..n {
            let f = i as f64;
            p.push([f, 2.0 * f, -f], [0.5 * f, 0.0, -40.0], 1e-3, 8930.0 + f, 3940.0);
        }
        p.stress[1] = [-3e8, -1e8, -2e8, 1e7, 2e7, 3e7];
        p.failed[2] = true;
        p.eps_p[1] = 0.25;
        p
    }

    /// The text between `<DataArray ... Name="name" ...>` and `</DataArray>`.
    fn array_body<'a>(xml: &'a str, name: &str) -> &'a str {
        let start = xml.find(&format!("Name=\"{name}\"")).unwrap();
        let open = start + xml[start..].find('>').unwrap() + 1;
        let close = open + xml[open..].find("</DataArray>").unwrap();
        xml[open..close].trim()
    }

    fn attr(xml: &str, key: &str) -> String {
        let i = xml.find(&format!("{key}=\"")).unwrap() + key.len() + 2;
        xml[i..i + xml[i..].find('"').unwrap()].to_string()
    }

    #[test]
    fn binary_vtu_parses_back() {
        let dir = tempfile::tempdir().unwrap();
        let p = sample(1000);
        let path = dir.path().join("a.vtu");
        write_vtu(&path, &p, 1.5e-6, 7, Encoding::Binary).unwrap();
        let xml = std::fs::read_to_string(&path).unwrap();
        assert!(xml.starts_with("<?xml"));
        assert!(xml.contains(
            r#"<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">"#
        ));
        assert_eq!(attr(&xml, "NumberOfPoints"), "1000");
        assert_eq!(attr(&xml, "NumberOfCells"), "1000");
        for name in [
            "velocity",
            "stress",
            "pressure",
            "von_mises",
            "eps_p",
            "density",
            "failed",
            "Points",
            "connectivity",
            "offsets",
            "types",
        ] {
            assert!(xml.contains(&format!("Name=\"{name}\"")), "{name}");
        }
        assert_eq!(array_body(&xml, "TIME"), "1.5e-6");
        assert_eq!(array_body(&xml, "CYCLE"), "7");
        let decode_f64 = |name: &str| -> Vec<f64> {
            let raw = b64_decode(array_body(&xml, name));
            let len = u64::from_le_bytes(raw[..8].try_into().unwrap()) as usize;
            assert_eq!(len, raw.len() - 8, "{name}: header byte count");
            raw[8..].chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect()
        };
        let pts = decode_f64("Points");
        assert_eq!(pts.len(), 3000);
        assert_eq!(&pts[3..6], &[1.0, 2.0, -1.0]);
        let s = decode_f64("stress");
        assert_eq!(&s[6..12], &p.stress[1]);
        let pr = decode_f64("pressure");
        assert!((pr[1] - 2e8).abs() < 1e-3);
        let vm = decode_f64("von_mises");
        let dev = deviator(&p.stress[1]);
        assert!((vm[1] - von_mises(&dev)).abs() < 1e-3 && vm[1] > 0.0);
        let rho = decode_f64("density");
        assert_eq!(rho[999], 8930.0 + 999.0);
        let types = b64_decode(array_body(&xml, "types"));
        assert_eq!(types.len(), 8 + 1000);
        assert!(types[8..].iter().all(|&t| t == 1));
        let failed = b64_decode(array_body(&xml, "failed"));
        assert_eq!(&failed[8..12], &[0, 0, 1, 0]);
        let offsets = b64_decode(array_body(&xml, "offsets"));
        let last = i64::from_le_bytes(offsets[offsets.len() - 8..].try_into().unwrap());
        assert_eq!(last, 1000);
    }

    /// The compressed layout read as VTK reads it: each array's offset after the `_`, its
    /// block header, the zlib blocks; every value back bit for bit, the blocks at most 1 MiB
    /// uncompressed, and the connectivity compressed to a sliver.
    #[test]
    fn compressed_vtu_parses_back() {
        use std::io::Read;
        let dir = tempfile::tempdir().unwrap();
        // More than one block for the vectors (2 x 10^5 x 24 B = 4.8 MB of velocity).
        let p = sample(200_000);
        let path = dir.path().join("c.vtu");
        write_vtu(&path, &p, 2.5e-6, 40, Encoding::Compressed).unwrap();
        let bytes = std::fs::read(&path).unwrap();
        let marker = b"<AppendedData encoding=\"raw\">";
        let start = bytes.windows(marker.len()).position(|w| w == marker).unwrap() + marker.len();
        let us = start + bytes[start..].iter().position(|&b| b == b'_').unwrap();
        let xml = std::str::from_utf8(&bytes[..us]).unwrap();
        assert!(xml.contains(r#"header_type="UInt64" compressor="vtkZLibDataCompressor""#));
        assert!(xml.trim_end().ends_with(r#"<AppendedData encoding="raw">"#));
        assert!(std::str::from_utf8(&bytes[bytes.len() - 30..]).unwrap().ends_with("</AppendedData>\n</VTKFile>\n"));
        let data = &bytes[us + 1..];
        let u64_at = |b: &[u8], i: usize| u64::from_le_bytes(b[8 * i..8 * i + 8].try_into().unwrap());
        let decode = |name: &str| -> (Vec<u8>, u64) {
            let at = xml.find(&format!("Name=\"{name}\"")).unwrap();
            let element = &xml[at..at + xml[at..].find("/>").unwrap()];
            assert!(element.contains(r#"format="appended""#), "{element}");
            let offset: usize = attr(element, "offset").parse().unwrap();
            let a = &data[offset..];
            let (blocks, size, last) = (u64_at(a, 0) as usize, u64_at(a, 1) as usize, u64_at(a, 2) as usize);
            assert_eq!(size, 1 << 20);
            let mut out = Vec::new();
            let mut at = 8 * (3 + blocks);
            let mut packed = 0;
            for b in 0..blocks {
                let c = u64_at(a, 3 + b) as usize;
                let mut block = Vec::new();
                flate2::read::ZlibDecoder::new(&a[at..at + c]).read_to_end(&mut block).unwrap();
                let want = if b + 1 == blocks && last > 0 { last } else { size };
                assert_eq!(block.len(), want, "{name} block {b}");
                out.extend(block);
                at += c;
                packed += c as u64;
            }
            (out, packed)
        };
        let f64s =
            |b: Vec<u8>| -> Vec<f64> { b.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().unwrap())).collect() };
        let (v, _) = decode("velocity");
        assert_eq!(f64s(v), p.v.iter().flatten().copied().collect::<Vec<_>>());
        let (s, _) = decode("stress");
        assert_eq!(f64s(s), p.stress.iter().flatten().copied().collect::<Vec<_>>());
        let (x, _) = decode("Points");
        assert_eq!(f64s(x), p.x.iter().flatten().copied().collect::<Vec<_>>());
        let (f, _) = decode("failed");
        assert_eq!(f, p.failed.iter().map(|&b| u8::from(b)).collect::<Vec<_>>());
        let (c, packed) = decode("connectivity");
        assert_eq!(c.len(), 8 * 200_000);
        assert!(packed < c.len() as u64 / 4, "connectivity compressed to {packed} bytes");
        let (t, _) = decode("types");
        assert!(t.iter().all(|&b| b == 1));
        let (pr, _) = decode("pressure");
        assert!((f64s(pr)[1] - 2e8).abs() < 1e-3);
        // An empty snapshot is a valid file too (no blocks).
        write_vtu(&path, &Particles::default(), 0.0, 0, Encoding::Compressed).unwrap();
        assert!(std::fs::read(&path).unwrap().ends_with(b"</VTKFile>\n"));
    }

    #[test]
    fn ascii_vtu_parses_back() {
        let dir = tempfile::tempdir().unwrap();
        let p = sample(4);
        let path = dir.path().join("a.vtu");
        write_vtu(&path, &p, 0.0, 0, Encoding::Ascii).unwrap();
        let xml = std::fs::read_to_string(&path).unwrap();
        assert_eq!(attr(&xml, "NumberOfPoints"), "4");
        let nums = |name: &str| -> Vec<f64> {
            array_body(&xml, name).split_whitespace().map(|t| t.parse().unwrap()).collect()
        };
        assert_eq!(nums("velocity").len(), 12);
        assert_eq!(nums("stress")[6..12], p.stress[1]);
        assert_eq!(nums("failed"), vec![0.0, 0.0, 1.0, 0.0]);
        assert_eq!(nums("connectivity"), vec![0.0, 1.0, 2.0, 3.0]);
        assert_eq!(nums("offsets"), vec![1.0, 2.0, 3.0, 4.0]);
    }

    /// Over 2 ranks: a piece per rank, rank 0's `.pvtu` naming both and declaring the
    /// pieces' point arrays (types, names, components) in their order, the `.pvd` over it.
    #[test]
    fn pieces_over_ranks_and_their_pvtu() {
        let dir = tempfile::tempdir().unwrap();
        let p = sample(5);
        for rank in [1, 0] {
            let mut w = SnapshotWriter::new(dir.path(), "impact", Encoding::Ascii).unwrap().over_ranks(rank, 2);
            w.write(30, 1e-6, &p).unwrap();
            assert_eq!(w.written(), vec![(30, 1e-6, "impact_000030.pvtu".to_string())]);
        }
        for piece in ["impact_000030_0000.vtu", "impact_000030_0001.vtu"] {
            assert!(dir.path().join(piece).is_file(), "{piece}");
        }
        assert!(!dir.path().join("impact_000030.vtu").exists());
        let pvtu = std::fs::read_to_string(dir.path().join("impact_000030.pvtu")).unwrap();
        assert!(pvtu.contains(r#"<VTKFile type="PUnstructuredGrid" version="1.0""#), "{pvtu}");
        assert!(pvtu.contains(r#"<Piece Source="impact_000030_0000.vtu"/>"#), "{pvtu}");
        assert!(pvtu.contains(r#"<Piece Source="impact_000030_0001.vtu"/>"#), "{pvtu}");
        assert!(pvtu.contains(r#"<PPointData Scalars="pressure" Vectors="velocity">"#), "{pvtu}");
        // Each declaration is its piece's start tag, less the format.
        let piece = std::fs::read_to_string(dir.path().join("impact_000030_0001.vtu")).unwrap();
        let declared: Vec<String> = pvtu
            .lines()
            .filter_map(|l| l.trim().strip_prefix("<PDataArray ").map(|a| a.trim_end_matches("/>").to_string()))
            .collect();
        let stored: Vec<String> = piece
            .lines()
            .filter_map(|l| l.trim().strip_prefix("<DataArray "))
            .map(|a| a[..a.find(" format=").unwrap()].to_string())
            .filter(|a| {
                !["connectivity", "offsets", "types", "TIME", "CYCLE"].iter().any(|n| a.contains(&format!("\"{n}\"")))
            })
            .collect();
        assert_eq!(declared, stored);
        assert_eq!(declared.len(), 8);
        let pvd = std::fs::read_to_string(dir.path().join("impact.pvd")).unwrap();
        assert!(pvd.contains(r#"file="impact_000030.pvtu""#), "{pvd}");
    }

    #[test]
    fn snapshot_writer_keeps_a_pvd_of_all_snapshots() {
        let dir = tempfile::tempdir().unwrap();
        let sub = dir.path().join("deep/er");
        let mut w = SnapshotWriter::new(&sub, "taylor", Encoding::Binary).unwrap();
        let p = sample(3);
        w.write(0, 0.0, &p).unwrap();
        w.write(10, 2e-7, &p).unwrap();
        w.write(10, 2e-7, &p).unwrap();
        assert_eq!(w.steps(), &[0, 10]);
        assert!(sub.join("taylor_000000.vtu").is_file());
        assert!(sub.join("taylor_000010.vtu").is_file());
        let pvd = std::fs::read_to_string(w.pvd_path()).unwrap();
        assert!(pvd.contains(r#"<VTKFile type="Collection""#));
        assert_eq!(pvd.matches("<DataSet ").count(), 2);
        assert!(pvd.contains(r#"timestep="2e-7" group="" part="0" file="taylor_000010.vtu""#));
        let leftovers: Vec<_> = std::fs::read_dir(&sub)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with('.'))
            .collect();
        assert!(leftovers.is_empty(), "{leftovers:?}");
    }
}
