//! Property tests of the checkpoint reader: a valid checkpoint file with any one byte
//! changed anywhere (magic, header length, header, arrays, checksum) is refused with a
//! clear error, never a panic and never accepted; so is every truncation, every file of
//! arbitrary bytes, and a file whose header lies about its arrays even with its checksum
//! recomputed (no allocation beyond what the file holds, no overflow). Each property's
//! case count is set in its `proptest!` block; the whole file runs in a few seconds.

use mpm_core::Particles;
use mpm_host::checkpoint::{read_file, write_file, Damage, Meta, MAGIC};
use proptest::prelude::*;
use sha2::{Digest, Sha256};
use std::path::Path;

/// Particles of a small checkpoint: `n` of them, each array holding distinct values, one
/// failed.
fn particles(n: usize) -> Particles {
    let mut p = Particles::with_capacity(n);
    (0..n).map(|i| i as f64).for_each(|f| p.push([f; 3], [-f; 3], 2e-3, 11340.0 - f, 2000.0 + f));
    p.stress.iter_mut().zip(0..).for_each(|(s, i)| *s = [f64::from(i) * 1e6; 6]);
    p.eps_p.iter_mut().zip(0..).for_each(|(e, i)| *e = f64::from(i) / 10.0);
    p.failed[n - 1] = true;
    p
}

/// The bytes of a valid checkpoint of 8 particles with ids and a state table (written once:
/// the writer syncs its file).
fn valid() -> Vec<u8> {
    static BYTES: std::sync::OnceLock<Vec<u8>> = std::sync::OnceLock::new();
    BYTES.get_or_init(written).clone()
}

/// [`valid`], written.
fn written() -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("r.ckpt");
    let meta = Meta { rank: 0, ranks: 1, step: 7, time_s: 1.25e-6, spec_key: "k".into(), binary_sha256: "b".into() };
    let mut state = toml::Table::new();
    state.insert("energy".into(), toml::Value::Float(1.0 / 3.0));
    let ids: Vec<u64> = (0..8).map(|i| 100 + i).collect();
    write_file(&path, &meta, state, &particles(8), Some(&ids)).unwrap();
    std::fs::read(&path).unwrap()
}

/// A file of its own for each test (named `name`) in one folder for the whole run, in
/// memory where the machine has a tmpfs (thousands of files are written and read).
fn scratch(name: &str) -> std::path::PathBuf {
    static DIR: std::sync::OnceLock<tempfile::TempDir> = std::sync::OnceLock::new();
    let dir = DIR.get_or_init(|| tempfile::tempdir_in("/dev/shm").or_else(|_| tempfile::tempdir()).unwrap());
    dir.path().join(name)
}

/// Read `bytes` as a checkpoint file at `path`: its error (a panic fails the test).
fn refused(path: &Path, bytes: &[u8]) -> Result<Damage, String> {
    std::fs::write(path, bytes).unwrap();
    match read_file(path) {
        Ok(l) => Err(format!("accepted: step {}, {} particles", l.header.step, l.particles.len())),
        Err(e) => {
            let msg = e.to_string();
            // A clear error: it names the file and what is wrong with it.
            if !msg.contains(&path.display().to_string()) || msg.len() < path.display().to_string().len() + 10 {
                return Err(format!("unclear error: {msg}"));
            }
            Ok(e)
        }
    }
}

/// The length of the header section, from a valid file's bytes 8..16.
fn header_len(bytes: &[u8]) -> usize {
    u64::from_le_bytes(bytes[8..16].try_into().unwrap()) as usize
}

/// A file of `header` (TOML, padded to 8 bytes) and `data`, with its checksum made right.
fn assemble(header: &str, data: &[u8]) -> Vec<u8> {
    let mut text = header.to_string();
    while !text.len().is_multiple_of(8) {
        text.push(' ');
    }
    let mut b = MAGIC.to_vec();
    b.extend((text.len() as u64).to_le_bytes());
    b.extend(text.as_bytes());
    b.extend(data);
    let digest = Sha256::digest(&b);
    b.extend(digest);
    b
}

/// Every byte of the file is covered: one bit flipped at each position, in turn, is
/// refused, by the name of the damage where it lands (the magic: not a checkpoint; the
/// checksum itself: a mismatch).
#[test]
fn every_byte_is_covered() {
    let good = valid();
    let path = scratch("flipped.ckpt");
    for at in 0..good.len() {
        let mut bad = good.clone();
        bad[at] ^= 0x01;
        let e = refused(&path, &bad).unwrap_or_else(|why| panic!("bit 0 of byte {at} flipped: {why}"));
        if at < 8 {
            assert!(matches!(e, Damage::Foreign(_)), "byte {at}: {e}");
        }
        if at >= good.len() - 32 {
            assert!(e.to_string().contains("checksum does not match"), "byte {at}: {e}");
        }
    }
}

/// A truncation at each boundary of the layout (within the magic, the header length, the
/// header, the arrays, the checksum) is refused as one.
#[test]
fn truncations_at_every_boundary_are_refused() {
    let good = valid();
    let h = header_len(&good);
    let data = 16 + h;
    let path = scratch("cut.ckpt");
    let n = good.len();
    for cut in [0, 1, 7, 8, 9, 15, 16, 17, data - 1, data, data + 1, (data + n) / 2, n - 33, n - 32, n - 31, n - 1] {
        let e = refused(&path, &good[..cut]).unwrap_or_else(|why| panic!("cut at {cut}: {why}"));
        assert!(matches!(e, Damage::Truncated { .. } | Damage::Foreign(_)), "cut at {cut}: {e}");
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 1024, failure_persistence: None, ..ProptestConfig::default() })]

    /// Any one byte changed to any other value, anywhere: refused.
    #[test]
    fn one_byte_changed_anywhere_is_refused(at in any::<prop::sample::Index>(), xor in 1u8..=255) {
        let mut bad = valid();
        let at = at.index(bad.len());
        bad[at] ^= xor;
        if let Err(why) = refused(&scratch("changed.ckpt"), &bad) {
            prop_assert!(false, "byte {} xor {:#04x}: {}", at, xor, why);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, failure_persistence: None, ..ProptestConfig::default() })]

    /// A valid file cut to any shorter length: refused as truncated (or, inside the magic,
    /// as not a checkpoint).
    #[test]
    fn any_truncation_is_refused(at in any::<prop::sample::Index>()) {
        let good = valid();
        let cut = at.index(good.len());
        match refused(&scratch("truncated.ckpt"), &good[..cut]) {
            Ok(e) => prop_assert!(matches!(e, Damage::Truncated { .. } | Damage::Foreign(_)), "cut at {}: {}", cut, e),
            Err(why) => prop_assert!(false, "cut at {}: {}", cut, why),
        }
    }

    /// Arbitrary bytes, bare or behind the magic and any header length: refused.
    #[test]
    fn arbitrary_bytes_are_refused(
        body in prop::collection::vec(any::<u8>(), 0..2048),
        length in any::<u64>(),
        framing in 0u8..3,
    ) {
        let mut bytes = Vec::new();
        if framing > 0 {
            bytes.extend(MAGIC);
        }
        if framing > 1 {
            bytes.extend(length.min(body.len() as u64 + 64).to_le_bytes());
        }
        bytes.extend(&body);
        if let Err(why) = refused(&scratch("arbitrary.ckpt"), &bytes) {
            prop_assert!(false, "{}", why);
        }
    }
}

/// The header of a valid file, as a table, and its data section.
fn parts(good: &[u8]) -> (toml::Table, Vec<u8>) {
    let h = header_len(good);
    let text = std::str::from_utf8(&good[16..16 + h]).unwrap();
    (toml::from_str(text).unwrap(), good[16 + h..good.len() - 32].to_vec())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 512, failure_persistence: None, ..ProptestConfig::default() })]

    /// A header that lies about its arrays, its data or its particles, its checksum made
    /// right (a file written by something else than mpm): never a panic nor an allocation
    /// beyond the file; read only when what it says is what it holds.
    #[test]
    fn a_header_lying_about_its_arrays_is_refused(
        field in 0usize..5,
        array in 0usize..10,
        value in prop_oneof![0i64..64, Just(i64::MAX), Just(i64::MAX / 8), any::<i64>()],
    ) {
        let (mut header, data) = parts(&valid());
        let before = header.clone();
        match field {
            0 => { header.insert("particles".into(), toml::Value::Integer(value)); }
            1 => { header.insert("data_bytes".into(), toml::Value::Integer(value)); }
            f => {
                let key = ["offset", "nbytes", "shape"][f - 2];
                let arrays = header["arrays"].as_array_mut().unwrap();
                let count = arrays.len();
                let a = arrays[array % count].as_table_mut().unwrap();
                let v = if key == "shape" { toml::Value::Array(vec![toml::Value::Integer(value)]) } else { toml::Value::Integer(value) };
                a.insert(key.into(), v);
            }
        }
        let bytes = assemble(&toml::to_string(&header).unwrap(), &data);
        let path = scratch("lying.ckpt");
        std::fs::write(&path, &bytes).unwrap();
        match read_file(&path) {
            Ok(l) => {
                // Only a change that leaves the file as it was written reads.
                prop_assert!(header == before, "accepted a lying header: field {} array {} value {}", field, array, value);
                prop_assert_eq!(l.particles.len() as u64, l.header.particles);
            }
            Err(e) => prop_assert!(e.to_string().contains("lying.ckpt"), "{}", e),
        }
    }
}
