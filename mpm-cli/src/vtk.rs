//! VTU snapshots of the particles and a `.pvd` collection over them, for ParaView.
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
//! written inline, either base64 binary (the default: a `UInt64` byte count followed by the
//! raw little-endian values, encoded as one base64 stream, as VTK's own writer does) or
//! ASCII. The collection file `<prefix>.pvd` lists every snapshot with its time and is
//! rewritten (atomically) after each one, so it is valid even if the run stops early.

use crate::atomic::write_atomic;
use anyhow::{Context, Result};
use mpm_core::math::{deviator, trace, von_mises};
use mpm_core::Particles;
use std::fmt::Display;
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// How the arrays of a `.vtu` are stored (the spec's `outputs.vtk.encoding`).
pub use mpm_spec::spec::VtkEncoding as Encoding;

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
        Encoding::Binary => "binary",
        Encoding::Ascii => "ascii",
    };
    write!(w, r#"        <DataArray type="{}" Name="{name}""#, T::TYPE)?;
    if ncomp > 1 {
        write!(w, r#" NumberOfComponents="{ncomp}""#)?;
    }
    for (i, c) in component_names.iter().enumerate() {
        write!(w, r#" ComponentName{i}="{c}""#)?;
    }
    writeln!(w, r#" format="{format}">"#)?;
    let total = count * ncomp;
    match enc {
        Encoding::Binary => {
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
pub fn write_vtu(path: &Path, particles: &Particles, time: f64, step: u64, enc: Encoding) -> Result<()> {
    let file = File::create(path).with_context(|| format!("cannot create VTU snapshot {}", path.display()))?;
    let mut w = BufWriter::with_capacity(1 << 20, file);
    write_vtu_to(&mut w, particles, time, step, enc)
        .and_then(|_| w.flush())
        .with_context(|| format!("cannot write VTU snapshot {}", path.display()))
}

fn write_vtu_to<W: Write>(w: &mut W, p: &Particles, time: f64, step: u64, enc: Encoding) -> std::io::Result<()> {
    let n = p.len();
    writeln!(w, r#"<?xml version="1.0"?>"#)?;
    writeln!(w, r#"<VTKFile type="UnstructuredGrid" version="1.0" byte_order="LittleEndian" header_type="UInt64">"#)?;
    writeln!(w, "  <UnstructuredGrid>")?;
    writeln!(w, "    <FieldData>")?;
    writeln!(
        w,
        r#"      <DataArray type="Float64" Name="TIME" NumberOfTuples="1" format="ascii">{time:e}</DataArray>"#
    )?;
    writeln!(w, r#"      <DataArray type="Int64" Name="CYCLE" NumberOfTuples="1" format="ascii">{step}</DataArray>"#)?;
    writeln!(w, "    </FieldData>")?;
    writeln!(w, r#"    <Piece NumberOfPoints="{n}" NumberOfCells="{n}">"#)?;
    writeln!(w, r#"      <PointData Scalars="pressure" Vectors="velocity">"#)?;
    data_array(w, enc, "velocity", 3, &["x", "y", "z"], n, p.v.iter().flatten().copied())?;
    data_array(w, enc, "stress", 6, &["xx", "yy", "zz", "yz", "zx", "xy"], n, p.stress.iter().flatten().copied())?;
    data_array(w, enc, "pressure", 1, &[], n, p.stress.iter().map(|s| -trace(s) / 3.0))?;
    data_array(w, enc, "von_mises", 1, &[], n, p.stress.iter().map(|s| von_mises(&deviator(s))))?;
    data_array(w, enc, "eps_p", 1, &[], n, p.eps_p.iter().copied())?;
    data_array(w, enc, "density", 1, &[], n, p.rho.iter().copied())?;
    data_array(w, enc, "failed", 1, &[], n, p.failed.iter().map(|&f| u8::from(f)))?;
    writeln!(w, "      </PointData>")?;
    writeln!(w, "      <Points>")?;
    data_array(w, enc, "Points", 3, &[], n, p.x.iter().flatten().copied())?;
    writeln!(w, "      </Points>")?;
    writeln!(w, "      <Cells>")?;
    data_array(w, enc, "connectivity", 1, &[], n, 0..n as i64)?;
    data_array(w, enc, "offsets", 1, &[], n, 1..=n as i64)?;
    // VTK_VERTEX = 1.
    data_array(w, enc, "types", 1, &[], n, std::iter::repeat_n(1u8, n))?;
    writeln!(w, "      </Cells>")?;
    writeln!(w, "    </Piece>")?;
    writeln!(w, "  </UnstructuredGrid>")?;
    writeln!(w, "</VTKFile>")
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
/// listing them.
#[derive(Debug)]
pub struct SnapshotWriter {
    dir: PathBuf,
    prefix: String,
    encoding: Encoding,
    entries: Vec<(f64, String)>,
    steps: Vec<u64>,
}

impl SnapshotWriter {
    /// Create `dir` (and parents) if needed and check that it is writable.
    pub fn new(dir: &Path, prefix: &str, encoding: Encoding) -> Result<Self> {
        std::fs::create_dir_all(dir).with_context(|| format!("cannot create the VTK directory {}", dir.display()))?;
        let probe = dir.join(format!(".mpm-write-test.{}", std::process::id()));
        File::create(&probe).with_context(|| format!("the VTK directory {} is not writable", dir.display()))?;
        let _ = std::fs::remove_file(&probe);
        Ok(Self {
            dir: dir.to_path_buf(),
            prefix: prefix.to_string(),
            encoding,
            entries: Vec::new(),
            steps: Vec::new(),
        })
    }

    /// File name of the snapshot of `step`.
    pub fn file_name(&self, step: u64) -> String {
        format!("{}_{step:06}.vtu", self.prefix)
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

    /// Write the snapshot of `step` at simulated `time` and rewrite the `.pvd`.
    /// A step already written is skipped.
    pub fn write(&mut self, step: u64, time: f64, particles: &Particles) -> Result<()> {
        if self.steps.last() == Some(&step) {
            return Ok(());
        }
        let name = self.file_name(step);
        write_vtu(&self.dir.join(&name), particles, time, step, self.encoding)?;
        self.entries.push((time, name));
        self.steps.push(step);
        write_atomic(&self.pvd_path(), pvd_text(&self.entries).as_bytes())
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
