//! CSV columns derived from typed values: a row type is serialised (serde, through
//! `serde_json::Value`) and flattened into named cells; reading back reverses it. The column
//! list comes from the type itself, so a field added to a row's parts (a new solver option in
//! the run spec, a new measurement) becomes a column without touching this code or the
//! header.
//!
//! Rules ([`Layout`]):
//! * the row is a JSON object whose fields are *groups* (objects): their fields become
//!   columns by their own names (no prefix); objects deeper down join their path with `.`
//!   (`scenario.model`, `physics.q.c1`, `substages.scatter`); a name an earlier group
//!   already gave a column is qualified by its group's name (`measured.paired.blocks`, the
//!   blocks a paired run completed, beside the plan's `paired.blocks`);
//! * a cell holds a scalar as text (numbers in shortest round-trip form, so floats read
//!   back bit for bit), `true` / `false`, or is empty for `null` (not measured);
//! * a list of scalars is written space-separated (`0 1`), a list of lists `|`-separated
//!   (`0 1|2 3`); an empty list or string as an empty cell, which reads as absent (so such a
//!   field needs a serde default);
//! * a list of records whose fields are scalars is written as one list column per field
//!   (`noise.workers.cpu_share` = `0.98 0.97`), a field some records lack as an empty cell;
//!   a list of records with nested parts is not a column (it stays in the JSON summary);
//! * the columns are those of a *template*, a value of the row type with every optional part
//!   present (for enums with variants of different fields, several templates merged; the
//!   row's parts are filled from their types by [`super::filled`]), so the header does not
//!   depend on which options a run had.
//!
//! Reading uses the template's leaf at each column as the type of the cell.

use anyhow::{anyhow, bail, Context, Result};
use serde::de::DeserializeOwned;
use serde::Serialize;
use serde_json::{Map, Number, Value};

/// The path segment that stands for every element of a list of records.
const EACH: &str = "*";

/// One column: its name, the path of its value in the row's JSON (with [`EACH`] for the
/// elements of a list of records), and a template value that gives the cell's type.
#[derive(Clone, Debug, PartialEq)]
struct Column {
    name: String,
    path: Vec<String>,
    hint: Value,
}

/// The columns of a row type, in order.
#[derive(Clone, Debug, PartialEq)]
pub struct Layout {
    columns: Vec<Column>,
}

/// `a` with every key of `b` it lacks added (recursively, in `b`'s order after `a`'s).
fn merge(a: &mut Value, b: &Value) {
    if let (Value::Object(a), Value::Object(b)) = (a, b) {
        for (k, bv) in b {
            match a.get_mut(k) {
                Some(av) => merge(av, bv),
                None => {
                    a.insert(k.clone(), bv.clone());
                }
            }
        }
    }
}

impl Layout {
    /// The layout of `templates` (values of the row type, merged) without the fields at
    /// `exclude` (paths such as `outputs`: parts of the type that are not columns; on reading
    /// they are absent, so they must have serde defaults).
    pub fn of<T: Serialize>(templates: &[T], exclude: &[&[&str]]) -> Result<Self> {
        let mut merged = Value::Object(Map::new());
        for t in templates {
            merge(&mut merged, &serde_json::to_value(t).context("the row template does not serialise")?);
        }
        let Value::Object(groups) = merged else { bail!("a row must serialise to an object") };
        let mut columns = Vec::new();
        for (group, v) in &groups {
            let Value::Object(fields) = v else {
                bail!("row field `{group}` is not a group (an object of columns)");
            };
            for (name, v) in fields {
                collect(vec![group.clone(), name.clone()], name.clone(), v, exclude, &mut columns)?;
            }
        }
        // A name a group shares with an earlier group is qualified by its group's name.
        let mut seen = std::collections::HashSet::new();
        for c in &mut columns {
            if !seen.insert(c.name.clone()) {
                c.name = format!("{}.{}", c.path[0], c.name);
                if !seen.insert(c.name.clone()) {
                    bail!("two columns are named `{}`: rename a field", c.name);
                }
            }
        }
        Ok(Self { columns })
    }

    /// The column names, in order.
    pub fn header(&self) -> Vec<String> {
        self.columns.iter().map(|c| c.name.clone()).collect()
    }

    /// The cells of `row` (of the layout's type), in column order.
    pub fn record<T: Serialize>(&self, row: &T) -> Result<Vec<String>> {
        let v = serde_json::to_value(row).context("a row does not serialise")?;
        self.columns.iter().map(|c| cell(&leaf(&v, &c.path)).with_context(|| format!("column {}", c.name))).collect()
    }

    /// The row whose cells under `header` are `record`. Every column of the header must be
    /// one of this layout's; columns of the layout missing from the header read as absent.
    pub fn parse<T: DeserializeOwned>(&self, header: &[String], record: &csv::StringRecord) -> Result<T> {
        let mut root = Value::Object(Map::new());
        for (name, text) in header.iter().zip(record.iter()) {
            let c = self.columns.iter().find(|c| c.name == *name).ok_or_else(|| anyhow!("unknown column `{name}`"))?;
            let each = c.path.iter().position(|k| k == EACH);
            let hint = if each.is_some() { Value::Array(vec![c.hint.clone()]) } else { c.hint.clone() };
            let Some(v) = parse_cell(text, &hint).with_context(|| format!("column {name}: '{text}'"))? else {
                continue;
            };
            match each {
                Some(at) => insert_each(&mut root, &c.path[..at], &c.path[at + 1..], v)
                    .with_context(|| format!("column {name}: '{text}'"))?,
                None => insert(&mut root, &c.path, v),
            }
        }
        // Groups with no cells still exist, so their fields' defaults apply.
        for c in &self.columns {
            if let Value::Object(m) = &mut root {
                m.entry(c.path[0].clone()).or_insert_with(|| Value::Object(Map::new()));
            }
        }
        serde_json::from_value(root).map_err(|e| anyhow!("{e}"))
    }
}

/// Add the columns of the value `v` at `path` (named `name`) to `out`.
fn collect(path: Vec<String>, name: String, v: &Value, exclude: &[&[&str]], out: &mut Vec<Column>) -> Result<()> {
    if exclude.iter().any(|e| e.len() + 1 == path.len() && e.iter().zip(&path[1..]).all(|(a, b)| a == b)) {
        return Ok(());
    }
    match v {
        Value::Object(fields) => {
            for (k, v) in fields {
                let mut p = path.clone();
                p.push(k.clone());
                collect(p, format!("{name}.{k}"), v, exclude, out)?;
            }
            Ok(())
        }
        Value::Null => bail!("the row template leaves `{name}` empty: give every optional part a value"),
        Value::Array(items) if items.is_empty() => {
            bail!("the row template's list `{name}` is empty: give it one element (its type)")
        }
        Value::Array(items) => match &items[0] {
            Value::Object(fields) if fields.values().all(|f| !f.is_object() && !f.is_array() && !f.is_null()) => {
                for (k, f) in fields {
                    let mut p = path.clone();
                    p.extend([EACH.to_string(), k.clone()]);
                    out.push(Column { name: format!("{name}.{k}"), path: p, hint: f.clone() });
                }
                Ok(())
            }
            // Records with nested parts stay in the JSON summary.
            Value::Object(_) => Ok(()),
            _ => {
                out.push(Column { name, path, hint: v.clone() });
                Ok(())
            }
        },
        _ => {
            out.push(Column { name, path, hint: v.clone() });
            Ok(())
        }
    }
}

/// The value at `path` in `v` (`null` where absent); at [`EACH`], the list of the field
/// that follows over the list's records (`null` when a record lacks it).
fn leaf(v: &Value, path: &[String]) -> Value {
    let Some(at) = path.iter().position(|k| k == EACH) else {
        return path.iter().try_fold(v, |v, k| v.get(k)).cloned().unwrap_or(Value::Null);
    };
    let Some(Value::Array(records)) = path[..at].iter().try_fold(v, |v, k| v.get(k)) else { return Value::Null };
    let values: Vec<Value> = records.iter().map(|r| leaf(r, &path[at + 1..])).collect();
    if values.is_empty() || values.iter().any(Value::is_null) {
        return Value::Null;
    }
    Value::Array(values)
}

/// Put the elements of the list `v` into the records of the list at `list` in `root`, each
/// at `field` (the records are made where absent; a list of another length is an error).
fn insert_each(root: &mut Value, list: &[String], field: &[String], v: Value) -> Result<()> {
    let Value::Array(values) = v else { bail!("not a list") };
    let mut at = root;
    for (i, k) in list.iter().enumerate() {
        let Value::Object(m) = at else { bail!("not an object") };
        let last = i + 1 == list.len();
        at = m
            .entry(k.clone())
            .or_insert_with(|| if last { Value::Array(Vec::new()) } else { Value::Object(Map::new()) });
    }
    let Value::Array(records) = at else { bail!("not a list of records") };
    if records.is_empty() {
        records.resize(values.len(), Value::Object(Map::new()));
    }
    if records.len() != values.len() {
        bail!("{} values where other columns of these records have {}", values.len(), records.len());
    }
    for (r, x) in records.iter_mut().zip(values) {
        insert(r, field, x);
    }
    Ok(())
}

/// Put `v` at `path` in `root`, creating objects on the way.
fn insert(root: &mut Value, path: &[String], v: Value) {
    let mut at = root;
    for k in &path[..path.len() - 1] {
        let Value::Object(m) = at else { return };
        at = m.entry(k.clone()).or_insert_with(|| Value::Object(Map::new()));
    }
    if let Value::Object(m) = at {
        m.insert(path[path.len() - 1].clone(), v);
    }
}

/// The text of a cell.
fn cell(v: &Value) -> Result<String> {
    Ok(match v {
        Value::Null => String::new(),
        Value::Bool(b) => b.to_string(),
        Value::Number(n) => n.to_string(),
        Value::String(s) => s.clone(),
        Value::Array(items) => {
            let nested = items.iter().any(Value::is_array);
            let sep = if nested { "|" } else { " " };
            let parts: Vec<String> = items
                .iter()
                .map(|x| match x {
                    Value::Array(inner) if nested => {
                        inner.iter().map(scalar_cell).collect::<Result<Vec<_>>>().map(|v| v.join(" "))
                    }
                    _ if nested => bail!("a list mixes lists and values"),
                    x => scalar_cell(x),
                })
                .collect::<Result<_>>()?;
            parts.join(sep)
        }
        Value::Object(_) => bail!("an object is not a cell"),
    })
}

/// The text of a list element: a number or `true`/`false` (words with spaces would not
/// split back).
fn scalar_cell(v: &Value) -> Result<String> {
    match v {
        Value::Number(n) => Ok(n.to_string()),
        Value::Bool(b) => Ok(b.to_string()),
        Value::String(s) if !s.contains([' ', '|']) && !s.is_empty() => Ok(s.clone()),
        other => bail!("{other} cannot be a list element of a cell"),
    }
}

/// The value of `text` in a column of type `hint` (`None`: empty, absent; a list or string
/// field needs a serde default to read an empty cell as empty).
fn parse_cell(text: &str, hint: &Value) -> Result<Option<Value>> {
    if text.is_empty() && hint.is_array() {
        return Ok(None);
    }
    if let Value::Array(items) = hint {
        let elem = items.first().cloned().unwrap_or(Value::Null);
        let split = |s: &str, h: &Value| -> Result<Value> {
            s.split_whitespace().map(|t| parse_scalar(t, h)).collect::<Result<Vec<_>>>().map(Value::Array)
        };
        return Ok(Some(match &elem {
            Value::Array(inner) => {
                let h = inner.first().cloned().unwrap_or(Value::Null);
                Value::Array(text.split('|').map(|part| split(part, &h)).collect::<Result<_>>()?)
            }
            h => split(text, h)?,
        }));
    }
    if text.is_empty() {
        return Ok(None);
    }
    parse_scalar(text, hint).map(Some)
}

/// A scalar cell: a string for string columns; a number or boolean where the template has
/// one, else the text (an enum written as a word where the template held a number).
fn parse_scalar(text: &str, hint: &Value) -> Result<Value> {
    Ok(match hint {
        Value::String(_) => Value::String(text.to_string()),
        Value::Bool(_) => match text {
            "true" => Value::Bool(true),
            "false" => Value::Bool(false),
            _ => bail!("not true or false"),
        },
        Value::Number(_) => match serde_json::from_str::<Number>(text) {
            Ok(n) => Value::Number(n),
            Err(_) => Value::String(text.to_string()),
        },
        _ => Value::String(text.to_string()),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct Inner {
        c1: f64,
        c2: f64,
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct A {
        #[serde(default)]
        name: String,
        n: u64,
        x: Option<f64>,
        q: Inner,
        #[serde(default)]
        cpus: Vec<usize>,
        #[serde(default)]
        per_rank: Vec<Vec<usize>>,
        flag: bool,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        hidden: Option<String>,
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct B {
        wall_s: Option<f64>,
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct R {
        a: A,
        b: B,
    }

    fn template() -> R {
        R {
            a: A {
                name: "x".into(),
                n: 1,
                x: Some(1.0),
                q: Inner::default(),
                cpus: vec![0],
                per_rank: vec![vec![0]],
                flag: true,
                hidden: Some("h".into()),
            },
            b: B { wall_s: Some(1.0) },
        }
    }

    /// Every kind of cell round-trips bit for bit; excluded fields are not columns; lists
    /// and lists of lists split back.
    #[test]
    fn rows_round_trip_through_cells() {
        let layout = Layout::of(&[template()], &[&["hidden"]]).unwrap();
        assert_eq!(layout.header(), ["name", "n", "x", "q.c1", "q.c2", "cpus", "per_rank", "flag", "wall_s"]);
        let row = R {
            a: A {
                name: "a b, c".into(),
                n: u64::MAX,
                x: Some(0.1 + 0.2),
                q: Inner { c1: 1.5, c2: 1e-300 },
                cpus: vec![0, 1],
                per_rank: vec![vec![0, 1], vec![2, 3]],
                flag: false,
                hidden: None,
            },
            b: B { wall_s: None },
        };
        let cells = layout.record(&row).unwrap();
        assert_eq!(cells[5..7], ["0 1".to_string(), "0 1|2 3".to_string()]);
        assert_eq!(cells[8], "");
        let rec = csv::StringRecord::from(cells);
        let back: R = layout.parse(&layout.header(), &rec).unwrap();
        assert_eq!(back, row);
        // Empty lists read back empty.
        let empty = R { a: A { cpus: vec![], per_rank: vec![], ..row.a.clone() }, ..row.clone() };
        let rec = csv::StringRecord::from(layout.record(&empty).unwrap());
        assert_eq!(layout.parse::<R>(&layout.header(), &rec).unwrap(), empty);
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct Worker {
        share: f64,
        switches: u64,
        #[serde(default, skip_serializing_if = "Option::is_none")]
        steal: Option<f64>,
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct Noisy {
        #[serde(default)]
        workers: Vec<Worker>,
        #[serde(default)]
        nested: Vec<Inner2>,
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct Inner2 {
        q: Inner,
    }

    #[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
    struct N {
        n: Noisy,
    }

    /// A list of records is one list column per field (a field some records lack: empty);
    /// a list of records with nested parts is not a column; both read back.
    #[test]
    fn lists_of_records_are_a_column_per_field() {
        let w = Worker { share: 0.5, switches: 1, steal: Some(0.0) };
        let t = N { n: Noisy { workers: vec![w.clone()], nested: vec![Inner2::default()] } };
        let layout = Layout::of(&[t], &[]).unwrap();
        assert_eq!(layout.header(), ["workers.share", "workers.switches", "workers.steal"]);
        let row = N {
            n: Noisy {
                workers: vec![Worker { share: 0.25, switches: 3, steal: None }, Worker { share: 1.0, ..w }],
                nested: vec![],
            },
        };
        let cells = layout.record(&row).unwrap();
        assert_eq!(cells, ["0.25 1.0", "3 1", ""]);
        let back: N = layout.parse(&layout.header(), &csv::StringRecord::from(cells)).unwrap();
        let mut want = row.clone();
        want.n.workers[1].steal = None;
        assert_eq!(back, want);
        let none = N::default();
        let rec = csv::StringRecord::from(layout.record(&none).unwrap());
        assert_eq!(layout.parse::<N>(&layout.header(), &rec).unwrap(), none);
    }

    /// A name two groups give is qualified by the later group's name.
    #[test]
    fn a_name_of_two_groups_is_qualified() {
        #[derive(Serialize)]
        struct Two {
            a: B,
            b: B,
        }
        let layout = Layout::of(&[Two { a: B { wall_s: Some(1.0) }, b: B { wall_s: Some(2.0) } }], &[]).unwrap();
        assert_eq!(layout.header(), ["wall_s", "b.wall_s"]);
    }

    #[test]
    fn bad_templates_and_unknown_columns_are_named() {
        let mut t = template();
        t.a.x = None;
        let err = Layout::of(&[t], &[]).unwrap_err().to_string();
        assert!(err.contains("`x`"), "{err}");
        let layout = Layout::of(&[template()], &[]).unwrap();
        let rec = csv::StringRecord::from(vec!["1"]);
        let err = layout.parse::<R>(&["bogus".to_string()], &rec).unwrap_err().to_string();
        assert!(err.contains("bogus"), "{err}");
    }
}
