//! A decoded telemetry stream as tables of columns, one per message kind (`fused`, `nav`, `health`, `housekeeping`,
//! `time`, `faults`, `ack`, `pps`, and `allan` as the ground's Allan points): the form column-oriented users (the
//! Python package's `decode`) take.
//!
//! Every kind but `allan` is its messages' serde JSON (the objects `ground decode --out x.jsonl` writes) flattened:
//! nested fields are joined with `.` (`health.gyro`, `rate_udps.0`), numbers and booleans (0/1) become `f64`
//! (`null`, e.g. an unset `unix_us`, is NaN; integers above 2^53 lose their last bits), and a field with any text
//! (an enum's variant name) is a text column. `allan` holds the [`AllanPoint`]s of every report, in order.

use super::{AllanPoint, TelemetryLog};
use serde_json::Value;
use std::collections::{BTreeMap, HashMap};

/// One column of a table.
#[derive(Clone, Debug, PartialEq)]
pub enum Values {
    /// Numbers (NaN where a message had `null` or lacked the field).
    Num(Vec<f64>),
    /// Text (empty where a message had `null` or lacked the field; numbers written as JSON).
    Text(Vec<String>),
}

/// The columns of one message kind, in the order they first appear (an object's fields in serde_json's order).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Table {
    /// Rows (messages).
    pub rows: usize,
    /// Name and values of each column.
    pub columns: Vec<(String, Values)>,
}

/// A flattened JSON leaf.
#[derive(Clone, Debug)]
enum Leaf {
    Num(f64),
    Text(String),
    Null,
}

/// The leaves of `v` under `prefix`, in field order.
fn flatten(prefix: &str, v: &Value, out: &mut Vec<(String, Leaf)>) {
    let key = |k: &str| {
        if prefix.is_empty() {
            k.to_owned()
        } else {
            format!("{prefix}.{k}")
        }
    };
    match v {
        Value::Object(m) => m.iter().for_each(|(k, v)| flatten(&key(k), v, out)),
        Value::Array(a) => a
            .iter()
            .enumerate()
            .for_each(|(i, v)| flatten(&key(&i.to_string()), v, out)),
        Value::Number(n) => {
            out.push((prefix.to_owned(), Leaf::Num(n.as_f64().unwrap_or(f64::NAN))))
        }
        Value::Bool(b) => out.push((prefix.to_owned(), Leaf::Num(f64::from(u8::from(*b))))),
        Value::String(s) => out.push((prefix.to_owned(), Leaf::Text(s.clone()))),
        Value::Null => out.push((prefix.to_owned(), Leaf::Null)),
    }
}

/// Builds a table from flattened rows.
fn table(rows: &[Vec<(String, Leaf)>]) -> Table {
    let mut names: Vec<String> = Vec::new();
    let mut index: HashMap<String, usize> = HashMap::new();
    let mut cells: Vec<Vec<Leaf>> = Vec::new();
    for (r, row) in rows.iter().enumerate() {
        for (k, leaf) in row {
            let c = *index.entry(k.clone()).or_insert_with(|| {
                names.push(k.clone());
                cells.push(vec![Leaf::Null; rows.len()]);
                names.len() - 1
            });
            cells[c][r] = leaf.clone();
        }
    }
    let columns = names
        .into_iter()
        .zip(cells)
        .map(|(name, cells)| {
            let values = if cells.iter().any(|c| matches!(c, Leaf::Text(_))) {
                Values::Text(
                    cells
                        .into_iter()
                        .map(|c| match c {
                            Leaf::Text(s) => s,
                            Leaf::Num(x) => x.to_string(),
                            Leaf::Null => String::new(),
                        })
                        .collect(),
                )
            } else {
                Values::Num(
                    cells
                        .iter()
                        .map(|c| match c {
                            Leaf::Num(x) => *x,
                            _ => f64::NAN,
                        })
                        .collect(),
                )
            };
            (name, values)
        })
        .collect();
    Table {
        rows: rows.len(),
        columns,
    }
}

/// The `allan` table: the log's [`AllanPoint`]s.
fn allan_table(log: &TelemetryLog) -> Table {
    let points: Vec<AllanPoint> = log.allan().collect();
    let num = |f: &dyn Fn(&AllanPoint) -> f64| Values::Num(points.iter().map(f).collect());
    Table {
        rows: points.len(),
        columns: vec![
            ("channel".into(), num(&|p| p.channel as f64)),
            (
                "column".into(),
                Values::Text(points.iter().map(|p| p.column.clone()).collect()),
            ),
            ("level".into(), num(&|p| p.level as f64)),
            ("tau0_s".into(), num(&|p| p.tau0_s)),
            ("tau_s".into(), num(&|p| p.tau_s)),
            ("count".into(), num(&|p| f64::from(p.count))),
            ("samples".into(), num(&|p| p.samples as f64)),
            ("dev".into(), num(&|p| p.dev)),
        ],
    }
}

/// The message kinds every result of [`TelemetryLog::tables`] holds (empty tables for kinds absent from the log).
pub const KINDS: [&str; 9] = [
    "fused",
    "nav",
    "allan",
    "health",
    "housekeeping",
    "time",
    "faults",
    "ack",
    "pps",
];

impl TelemetryLog {
    /// The log as one [`Table`] per message kind (keys: [`KINDS`]); see the module's documentation.
    pub fn tables(&self) -> Result<BTreeMap<&'static str, Table>, serde_json::Error> {
        let mut rows: BTreeMap<String, Vec<Vec<(String, Leaf)>>> = BTreeMap::new();
        for m in &self.messages {
            // Externally tagged: {"Fused": {...}}.
            if let Value::Object(o) = serde_json::to_value(m)? {
                for (kind, body) in o {
                    let mut leaves = Vec::new();
                    flatten("", &body, &mut leaves);
                    rows.entry(kind.to_lowercase()).or_default().push(leaves);
                }
            }
        }
        Ok(KINDS
            .iter()
            .map(|&k| {
                let t = match k {
                    "allan" => allan_table(self),
                    k => rows.get(k).map(|r| table(r)).unwrap_or_default(),
                };
                (k, t)
            })
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::telemetry::{FusedReport, Telemetry, TimeReport};

    #[test]
    fn fused_and_time_become_columns() {
        let fused = |seq, unix_us| {
            Telemetry::Fused(FusedReport {
                seq,
                t_us: 1_000 * u64::from(seq),
                frames: 32,
                rate_udps: [1, -2, 3],
                accel_ug: [4, 5, 6],
                used: [16; 6],
                health: Default::default(),
                temp_cdeg: None,
                unix_us,
            })
        };
        let log = TelemetryLog {
            messages: vec![
                fused(1, None),
                Telemetry::Time(TimeReport {
                    t_us: 5,
                    unix_us: 7,
                }),
                fused(2, Some(9)),
            ],
            stats: Default::default(),
        };
        let t = log.tables().unwrap();
        let f = &t["fused"];
        assert_eq!(f.rows, 2);
        let col = |n: &str| {
            f.columns
                .iter()
                .find(|(k, _)| k == n)
                .map(|(_, v)| v.clone())
        };
        assert_eq!(col("seq"), Some(Values::Num(vec![1.0, 2.0])));
        assert_eq!(col("rate_udps.1"), Some(Values::Num(vec![-2.0, -2.0])));
        match col("unix_us") {
            Some(Values::Num(v)) => assert!(v[0].is_nan() && v[1] == 9.0),
            c => panic!("{c:?}"),
        }
        assert_eq!(t["time"].rows, 1);
        assert_eq!(t["nav"].rows, 0);
        assert_eq!(t.len(), KINDS.len());
    }
}
