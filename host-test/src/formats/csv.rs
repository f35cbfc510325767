//! The interchange CSV: `t,temp_c,g00x,g00y,g00z,a00x,a00y,a00z,g01x,…`, one row per sample. `t` in seconds,
//! `temp_c` (optional) in °C, then per sensor group `gSSx/y/z` in °/s and `aSSx/y/z` in g, any number of groups, any
//! subset of axes. Columns may come in any order; unknown columns are ignored with a warning.

use std::fmt::Write as _;
use std::path::Path;

/// Gyro or accelerometer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SensorKind {
    /// Rate, °/s.
    Gyro,
    /// Specific force, g.
    Accel,
}

impl SensorKind {
    /// Column-name prefix (`g` / `a`).
    pub fn prefix(self) -> char {
        match self {
            SensorKind::Gyro => 'g',
            SensorKind::Accel => 'a',
        }
    }

    /// Physical unit of the CSV column.
    pub fn unit(self) -> &'static str {
        match self {
            SensorKind::Gyro => "deg/s",
            SensorKind::Accel => "g",
        }
    }

    /// Name used in reports ("gyro" / "accel").
    pub fn name(self) -> &'static str {
        match self {
            SensorKind::Gyro => "gyro",
            SensorKind::Accel => "accel",
        }
    }
}

/// Axis letters in column order.
pub const AXIS_NAMES: [char; 3] = ['x', 'y', 'z'];

/// One sensor axis of one group.
#[derive(Clone, Debug, PartialEq)]
pub struct Column {
    /// Group number (the `SS` of the name).
    pub group: usize,
    /// Gyro or accelerometer.
    pub kind: SensorKind,
    /// 0, 1, 2 for x, y, z.
    pub axis: usize,
    /// Samples, °/s or g.
    pub data: Vec<f64>,
}

impl Column {
    /// The interchange name, e.g. `g03z`.
    pub fn name(&self) -> String {
        column_name(self.kind, self.group, self.axis)
    }
}

/// `g03z` for (Gyro, 3, 2).
pub fn column_name(kind: SensorKind, group: usize, axis: usize) -> String {
    format!(
        "{}{:02}{}",
        kind.prefix(),
        group,
        AXIS_NAMES.get(axis).copied().unwrap_or('?')
    )
}

/// Parses `g03z` → (Gyro, 3, 2).
pub fn parse_column_name(name: &str) -> Option<(SensorKind, usize, usize)> {
    let kind = match name.chars().next()? {
        'g' => SensorKind::Gyro,
        'a' => SensorKind::Accel,
        _ => return None,
    };
    let axis = AXIS_NAMES.iter().position(|&c| name.ends_with(c))?;
    let digits = name.get(1..name.len() - 1)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    Some((kind, digits.parse().ok()?, axis))
}

/// A recording: time, optional temperature, sensor columns (sorted by kind, group, axis).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recording {
    /// Sample times, s.
    pub t_s: Vec<f64>,
    /// Board temperature, °C.
    pub temp_c: Option<Vec<f64>>,
    /// Sensor columns.
    pub columns: Vec<Column>,
}

/// A CSV error with its position.
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    /// I/O.
    #[error("{path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Header problems.
    #[error("line 1 (header): {0}")]
    Header(String),
    /// A row problem.
    #[error("line {line}, column {column} ({name}): {what}")]
    Cell {
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// Column name.
        name: String,
        /// What was expected / found.
        what: String,
    },
    /// Wrong number of cells.
    #[error("line {line}: expected {expected} comma-separated values, found {found}")]
    Width {
        /// 1-based line.
        line: usize,
        /// Header width.
        expected: usize,
        /// Found.
        found: usize,
    },
}

/// What a column of the file is.
enum Role {
    Time,
    Temp,
    Sensor(usize),
    Ignored,
}

impl Recording {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// The sample interval: median of the time differences (s); `None` with fewer than 2 samples.
    pub fn sample_interval_s(&self) -> Option<f64> {
        let mut d: Vec<f64> = self
            .t_s
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|d| d.is_finite())
            .collect();
        if d.is_empty() {
            return None;
        }
        d.sort_by(f64::total_cmp);
        d.get(d.len() / 2).copied().filter(|&x| x > 0.0)
    }

    /// Column by name.
    pub fn column(&self, name: &str) -> Option<&Column> {
        self.columns.iter().find(|c| c.name() == name)
    }

    /// Groups present, sorted.
    pub fn groups(&self) -> Vec<usize> {
        let mut g: Vec<usize> = self.columns.iter().map(|c| c.group).collect();
        g.sort_unstable();
        g.dedup();
        g
    }

    /// Keeps samples with `start_s <= t < end_s`.
    pub fn window(&self, start_s: f64, end_s: f64) -> Recording {
        let keep: Vec<bool> = self
            .t_s
            .iter()
            .map(|&t| t >= start_s && t < end_s)
            .collect();
        let pick = |v: &[f64]| {
            v.iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(x, _)| *x)
                .collect::<Vec<f64>>()
        };
        Recording {
            t_s: pick(&self.t_s),
            temp_c: self.temp_c.as_deref().map(pick),
            columns: self
                .columns
                .iter()
                .map(|c| Column {
                    data: pick(&c.data),
                    ..c.clone()
                })
                .collect(),
        }
    }

    /// Parses CSV text; returns the recording and warnings (ignored columns).
    pub fn parse(text: &str) -> Result<(Recording, Vec<String>), CsvError> {
        let mut lines = text
            .lines()
            .enumerate()
            .filter(|(_, l)| !l.trim().is_empty());
        let (_, header) = lines
            .next()
            .ok_or_else(|| CsvError::Header("the file is empty".into()))?;
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        let mut warnings = Vec::new();
        let mut roles = Vec::with_capacity(names.len());
        let mut columns: Vec<Column> = Vec::new();
        let (mut has_t, mut has_temp) = (false, false);
        for name in &names {
            let role = match *name {
                "t" if !has_t => {
                    has_t = true;
                    Role::Time
                }
                "temp_c" if !has_temp => {
                    has_temp = true;
                    Role::Temp
                }
                "t" | "temp_c" => {
                    return Err(CsvError::Header(format!("column '{name}' appears twice")));
                }
                _ => match parse_column_name(name) {
                    Some((kind, group, axis)) => {
                        if columns
                            .iter()
                            .any(|c| c.kind == kind && c.group == group && c.axis == axis)
                        {
                            return Err(CsvError::Header(format!("column '{name}' appears twice")));
                        }
                        columns.push(Column {
                            group,
                            kind,
                            axis,
                            data: Vec::new(),
                        });
                        Role::Sensor(columns.len() - 1)
                    }
                    None => {
                        warnings.push(format!(
                            "column '{name}' is not t, temp_c or gSS[xyz]/aSS[xyz]: ignored"
                        ));
                        Role::Ignored
                    }
                },
            };
            roles.push(role);
        }
        if !has_t {
            return Err(CsvError::Header("no 't' column (time in seconds)".into()));
        }
        if columns.is_empty() {
            return Err(CsvError::Header("no sensor columns (gSSx … aSSz)".into()));
        }
        let mut rec = Recording {
            temp_c: has_temp.then(Vec::new),
            ..Default::default()
        };
        for (i, line) in lines {
            let mut found = 0;
            for (col, (cell, role)) in line.split(',').zip(&roles).enumerate() {
                found += 1;
                if matches!(role, Role::Ignored) {
                    continue;
                }
                let v: f64 = cell.trim().parse().map_err(|_| CsvError::Cell {
                    line: i + 1,
                    column: col + 1,
                    name: names.get(col).unwrap_or(&"?").to_string(),
                    what: format!("expected a number, found '{}'", cell.trim()),
                })?;
                match role {
                    Role::Time => rec.t_s.push(v),
                    Role::Temp => rec.temp_c.get_or_insert_with(Vec::new).push(v),
                    Role::Sensor(k) => columns[*k].data.push(v),
                    Role::Ignored => {}
                }
            }
            let total = line.split(',').count();
            if found != roles.len() || total != roles.len() {
                return Err(CsvError::Width {
                    line: i + 1,
                    expected: roles.len(),
                    found: total,
                });
            }
        }
        columns.sort_by_key(|c| (c.kind, c.group, c.axis));
        rec.columns = columns;
        Ok((rec, warnings))
    }

    /// Reads a CSV file.
    pub fn read(path: &Path) -> Result<(Recording, Vec<String>), CsvError> {
        let text = std::fs::read_to_string(path).map_err(|source| CsvError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::parse(&text)
    }

    /// Writes the canonical CSV (gyro columns of a group, then its accel columns; groups in order). Numbers use
    /// Rust's shortest round-trip representation, so reading the file back gives the same values.
    pub fn write(&self, path: &Path) -> std::io::Result<()> {
        use std::io::Write;
        let mut order: Vec<&Column> = self.columns.iter().collect();
        order.sort_by_key(|c| (c.group, c.kind, c.axis));
        let mut out = std::io::BufWriter::new(std::fs::File::create(path)?);
        let mut header = String::from("t");
        if self.temp_c.is_some() {
            header.push_str(",temp_c");
        }
        for c in &order {
            let _ = write!(header, ",{}", c.name());
        }
        writeln!(out, "{header}")?;
        let mut row = String::new();
        for i in 0..self.t_s.len() {
            row.clear();
            let _ = write!(row, "{}", self.t_s[i]);
            if let Some(t) = &self.temp_c {
                let _ = write!(row, ",{}", t.get(i).copied().unwrap_or(f64::NAN));
            }
            for c in &order {
                let _ = write!(row, ",{}", c.data.get(i).copied().unwrap_or(f64::NAN));
            }
            writeln!(out, "{row}")?;
        }
        out.flush()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn any_order_unknown_ignored_round_trip() {
        let text = "a00z,t,foo,g00x,temp_c\n1.5,0,7,0.25,20\n-1,0.1,8,0.5,20.5\n";
        let (rec, warnings) = Recording::parse(text).unwrap();
        assert_eq!(warnings.len(), 1);
        assert!(warnings[0].contains("'foo'"));
        assert_eq!(rec.t_s, [0.0, 0.1]);
        assert_eq!(rec.temp_c.as_deref(), Some(&[20.0, 20.5][..]));
        assert_eq!(rec.column("g00x").unwrap().data, [0.25, 0.5]);
        assert_eq!(rec.column("a00z").unwrap().data, [1.5, -1.0]);
        let dir = std::env::temp_dir().join(format!("csv-rt-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("r.csv");
        rec.write(&p).unwrap();
        assert_eq!(
            std::fs::read_to_string(&p).unwrap().lines().next(),
            Some("t,temp_c,g00x,a00z")
        );
        assert_eq!(Recording::read(&p).unwrap().0, rec);
        assert!((rec.sample_interval_s().unwrap() - 0.1).abs() < 1e-15);
    }

    #[test]
    fn errors_say_where_and_what() {
        let e = Recording::parse("t,g00x\n0,1\n0.1,abc\n")
            .unwrap_err()
            .to_string();
        assert_eq!(e, "line 3, column 2 (g00x): expected a number, found 'abc'");
        let e = Recording::parse("t,g00x\n0,1,2\n").unwrap_err().to_string();
        assert_eq!(e, "line 2: expected 2 comma-separated values, found 3");
        assert!(
            Recording::parse("g00x\n1\n")
                .unwrap_err()
                .to_string()
                .contains("no 't' column")
        );
        assert!(
            Recording::parse("t,g00x,g00x\n")
                .unwrap_err()
                .to_string()
                .contains("appears twice")
        );
        assert!(Recording::parse("").is_err());
        assert_eq!(parse_column_name("g12y"), Some((SensorKind::Gyro, 12, 1)));
        assert_eq!(parse_column_name("gx"), None);
        assert_eq!(parse_column_name("q00x"), None);
    }
}
