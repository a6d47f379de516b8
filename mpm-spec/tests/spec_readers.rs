//! Property tests of the run spec's readers (TOML and JSON, [`RunSpec::parse`] and
//! [`RunSpec::read`]): arbitrary text, and valid specs with one key removed, one value of
//! another type or one number out of range. Each ends in a clear error (naming the key it
//! is about) or in a spec that passes every check and holds exactly the values the file
//! gave: never a panic, never a value read other than written. Each property's case count
//! is set in its `proptest!` block; the whole file runs in seconds.

use mpm_core::Strategy;
use mpm_spec::scenario::{ImpactSpec, PlateSpec, TaylorSpec};
use mpm_spec::spec::{CheckpointEvery, CheckpointOutput, Paired, RadiographOutput, SpecFormat, VtkEncoding, VtkOutput};
use mpm_spec::{RunSpec, Scenario};
use proptest::prelude::*;
use serde_json::Value;

/// Valid specs that between them have every key: each scenario, every output, a paired
/// run, the injected slowdown, a CPU list.
fn bases() -> Vec<RunSpec> {
    let mut taylor = RunSpec::new(Scenario::Taylor(TaylorSpec::model(2))).unwrap();
    taylor.strategy = Strategy::DomainDecomposition;
    taylor.threads = 2;
    taylor.cpus = Some(vec![0, 1]);
    taylor.budget.steps = Some(14);
    taylor.budget.warmup = Some(2);
    taylor.paired = Some(Paired { blocks: 4 });
    taylor.inject_slowdown = Some(0.1);
    taylor.outputs.json = Some("t.json".into());
    taylor.outputs.dump_state = Some("t.bin".into());
    taylor.outputs.vtk = Some(VtkOutput { dir: "vtk".into(), every: 5, encoding: VtkEncoding::Ascii });
    let mut impact = RunSpec::new(Scenario::Impact(ImpactSpec::default())).unwrap();
    impact.outputs.radiograph = Some(RadiographOutput { dir: "r".into(), every: Some(10) });
    impact.outputs.checkpoint = Some(CheckpointOutput { dir: "ck".into(), every: CheckpointEvery::Steps(50) });
    let plate = RunSpec::new(Scenario::Plate(PlateSpec::default())).unwrap();
    for s in [&taylor, &impact, &plate] {
        s.check().unwrap();
    }
    vec![taylor, impact, plate]
}

/// Every leaf of a JSON tree with its path (array elements as `key.N`).
fn leaves(prefix: &str, v: &Value, out: &mut Vec<(String, Value)>) {
    match v {
        Value::Object(m) => {
            for (k, x) in m {
                leaves(&if prefix.is_empty() { k.clone() } else { format!("{prefix}.{k}") }, x, out);
            }
        }
        _ => out.push((prefix.to_string(), v.clone())),
    }
}

/// The object holding the leaf `path` and the leaf's key.
fn parent_of<'a>(root: &'a mut Value, path: &str) -> (&'a mut serde_json::Map<String, Value>, String) {
    let mut parts: Vec<&str> = path.split('.').collect();
    let last = parts.pop().unwrap().to_string();
    let mut at = root;
    for p in parts {
        at = at.get_mut(p).unwrap();
    }
    (at.as_object_mut().unwrap(), last)
}

/// Whether two leaves hold the same value (numbers by value: `1` and `1.0` are one).
fn same(a: &Value, b: &Value) -> bool {
    match (a, b) {
        (Value::Number(x), Value::Number(y)) => x.as_f64() == y.as_f64(),
        (Value::Array(x), Value::Array(y)) => x.len() == y.len() && x.iter().zip(y).all(|(p, q)| same(p, q)),
        _ => a == b,
    }
}

/// Read `tree` as a spec file in both formats and judge the outcome: an error must name
/// `key` (its last part or its first), a spec must pass its checks and hold every value of
/// `tree` as given.
fn judge(tree: &Value, key: &str) -> Result<(), String> {
    let texts = [
        (SpecFormat::Json, Some(serde_json::to_string_pretty(tree).unwrap())),
        (SpecFormat::Toml, toml::to_string(tree).ok()),
    ];
    for (format, text) in texts {
        let Some(text) = text else { continue };
        match RunSpec::parse(&text, format) {
            Err(e) => {
                let msg = e.to_string();
                let (first, last) = (key.split('.').next().unwrap(), key.rsplit('.').next().unwrap());
                // A leaf of a list names the list.
                let last = if last.parse::<usize>().is_ok() { key.rsplit('.').nth(1).unwrap() } else { last };
                if !(msg.contains(last) || msg.contains(first)) {
                    return Err(format!("{format:?}: the error does not name {key}: {msg}\n{text}"));
                }
            }
            Ok(spec) => {
                spec.check().map_err(|e| format!("{format:?}: accepted a spec that fails its check: {e}"))?;
                let back: Value = serde_json::from_str(&spec.to_json()).unwrap();
                let (mut given, mut read) = (Vec::new(), Vec::new());
                leaves("", tree, &mut given);
                leaves("", &back, &mut read);
                for (k, v) in &given {
                    let r = read.iter().find(|(q, _)| q == k).map(|(_, r)| r);
                    if !r.is_some_and(|r| same(r, v)) {
                        return Err(format!("{format:?}: {k} = {v} was read as {r:?}\n{text}"));
                    }
                }
            }
        }
    }
    Ok(())
}

/// A base spec's tree and one of its leaves, by the strategy's picks.
fn pick(base: prop::sample::Index, leaf: prop::sample::Index) -> (Value, String, Value) {
    let specs = bases();
    let spec = &specs[base.index(specs.len())];
    let tree: Value = serde_json::from_str(&spec.to_json()).unwrap();
    let mut all = Vec::new();
    leaves("", &tree, &mut all);
    let (key, value) = all[leaf.index(all.len())].clone();
    (tree, key, value)
}

/// A value of another JSON type than `v`'s (a number stays a number only as a string).
fn other_type(v: &Value, choice: u8) -> Value {
    let candidates = [
        Value::String("x".into()),
        Value::Bool(true),
        serde_json::json!(3),
        serde_json::json!([1, "a"]),
        serde_json::json!({"k": 1}),
        serde_json::json!(-2.5),
    ];
    let kind = |x: &Value| std::mem::discriminant(x);
    let others: Vec<&Value> = candidates.iter().filter(|c| kind(c) != kind(v)).collect();
    others[choice as usize % others.len()].clone()
}

/// Numbers out of every range a key has: negative, zero, fractional, huge.
const ODD_NUMBERS: [f64; 9] = [-1.0, 0.0, 0.5, 1.5, 3.0, 1e-300, 1e300, -1e300, 4.294967296e9];

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, failure_persistence: None, ..ProptestConfig::default() })]

    /// Any text at all, as TOML and as JSON: an error or a checked spec, never a panic.
    #[test]
    fn arbitrary_text_is_an_error_or_a_checked_spec(text in ".{0,400}") {
        for format in [SpecFormat::Toml, SpecFormat::Json] {
            if let Ok(spec) = RunSpec::parse(&text, format) {
                prop_assert!(spec.check().is_ok());
            }
        }
    }

    /// A valid spec's text with any one byte removed or replaced: the same.
    #[test]
    fn a_valid_spec_damaged_anywhere_is_an_error_or_a_checked_spec(
        base in any::<prop::sample::Index>(),
        at in any::<prop::sample::Index>(),
        byte in any::<u8>(),
        json in any::<bool>(),
    ) {
        let specs = bases();
        let spec = &specs[base.index(specs.len())];
        let (format, text) = if json { (SpecFormat::Json, spec.to_json()) } else { (SpecFormat::Toml, spec.to_toml()) };
        let mut bytes = text.into_bytes();
        let at = at.index(bytes.len());
        if byte == 0 { bytes.remove(at); } else { bytes[at] = byte; }
        let text = String::from_utf8_lossy(&bytes);
        if let Ok(read) = RunSpec::parse(&text, format) {
            prop_assert!(read.check().is_ok());
        }
    }

    /// One key removed: an error naming it, or its default read in its place.
    #[test]
    fn a_key_removed(base in any::<prop::sample::Index>(), leaf in any::<prop::sample::Index>()) {
        let (mut tree, key, _) = pick(base, leaf);
        let (parent, last) = parent_of(&mut tree, &key);
        parent.remove(&last);
        if let Err(why) = judge(&tree, &key) { prop_assert!(false, "{} removed: {}", key, why); }
    }

    /// One value of another type: an error naming the key, or (where the key takes that
    /// type too) the value read as given.
    #[test]
    fn a_value_of_another_type(
        base in any::<prop::sample::Index>(),
        leaf in any::<prop::sample::Index>(),
        choice in any::<u8>(),
    ) {
        let (mut tree, key, value) = pick(base, leaf);
        let (parent, last) = parent_of(&mut tree, &key);
        parent.insert(last, other_type(&value, choice));
        if let Err(why) = judge(&tree, &key) { prop_assert!(false, "{} retyped: {}", key, why); }
    }

    /// One number (or any leaf) set to a number out of range: an error naming the key, or
    /// a spec that passes its checks with the number as given.
    #[test]
    fn a_number_out_of_range(
        base in any::<prop::sample::Index>(),
        leaf in any::<prop::sample::Index>(),
        odd in any::<prop::sample::Index>(),
    ) {
        let (mut tree, key, _) = pick(base, leaf);
        let number = ODD_NUMBERS[odd.index(ODD_NUMBERS.len())];
        let (parent, last) = parent_of(&mut tree, &key);
        parent.insert(last, serde_json::json!(number));
        if let Err(why) = judge(&tree, &key) { prop_assert!(false, "{} = {}: {}", key, number, why); }
    }
}

/// Values out of range that must be refused, each naming its key, in both formats.
#[test]
fn values_out_of_range_are_refused_by_key() {
    let cases: [(usize, &str, Value); 16] = [
        (0, "threads", serde_json::json!(0)),
        (0, "threads", serde_json::json!(-1)),
        (0, "scenario.model", serde_json::json!(9)),
        (0, "scenario.velocity_m_s", serde_json::json!(1e9)),
        (0, "physics.cfl", serde_json::json!(2.0)),
        (0, "physics.cfl", serde_json::json!(0)),
        (0, "inject_slowdown", serde_json::json!(0.999999)),
        (0, "paired.blocks", serde_json::json!(1)),
        (0, "budget.warmup", serde_json::json!(14)),
        (0, "outputs.vtk.every", serde_json::json!(0)),
        (1, "scenario.spacing_m", serde_json::json!(1e-9)),
        (1, "scenario.cell_m", serde_json::json!(1.0)),
        (1, "scenario.cell_m", serde_json::json!(10e-3)),
        (1, "outputs.checkpoint.every", serde_json::json!(0)),
        (2, "scenario.cell_m", serde_json::json!(1e-10)),
        (2, "scenario.particles_per_cell", serde_json::json!(0)),
    ];
    for (base, key, value) in cases {
        let mut tree: Value = serde_json::from_str(&bases()[base].to_json()).unwrap();
        let (parent, last) = parent_of(&mut tree, key);
        parent.insert(last.clone(), value.clone());
        for (format, text) in [
            (SpecFormat::Json, serde_json::to_string(&tree).unwrap()),
            (SpecFormat::Toml, toml::to_string(&tree).unwrap()),
        ] {
            let err = match RunSpec::parse(&text, format) {
                Ok(_) => panic!("{key} = {value} accepted ({format:?})"),
                Err(e) => e.to_string(),
            };
            assert!(err.contains(&last) || err.contains(key), "{key} = {value} ({format:?}): {err}");
        }
    }
}
