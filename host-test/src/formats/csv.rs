//! The interchange CSV: `t,temp_c,g00x,g00y,g00z,a00x,a00y,a00z,g01x,…`, one row per sample. `t` in seconds,
//! `temp_c` (optional) in °C, then per sensor group `gSSx/y/z` in °/s and `aSSx/y/z` in g, any number of groups, any
//! subset of axes. Columns may come in any order; unknown columns are ignored with a warning.

use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// Decimals of sensor values in the files we write: 1e-9 °/s or g, four orders of magnitude below anything these
/// tools report, and short enough for the exact fast path of [`parse_f64`].
pub const VALUE_DECIMALS: usize = 9;

/// Appends `v` with [`VALUE_DECIMALS`] decimals, trailing zeros removed (`-0.02839027`, `1`, `0.5`).
pub fn push_value(out: &mut String, v: f64) {
    let start = out.len();
    let _ = write!(out, "{v:.VALUE_DECIMALS$}");
    if out[start..].contains('.') {
        let trimmed = out.trim_end_matches('0').trim_end_matches('.').len();
        out.truncate(trimmed);
    }
    if &out[start..] == "-0" {
        out.truncate(start);
        out.push('0');
    }
}

/// Parses a decimal number. Plain forms (`[-]digits[.digits]`, see [`fast_number`]) are converted exactly by
/// Clinger's fast path; anything else (exponents, `+`, long mantissas) goes to the standard library. Both give the
/// correctly rounded value.
pub fn parse_f64(s: &str) -> Option<f64> {
    match fast_number(s.as_bytes(), 0) {
        Some((v, end)) if end == s.len() => Some(v),
        _ => s.parse().ok(),
    }
}

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

/// Number of `\n` in `s` (written so that it vectorises).
fn count_newlines(s: &str) -> usize {
    s.as_bytes().iter().map(|&b| usize::from(b == b'\n')).sum()
}

const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Appends the decimal digits at `b[*p..]` to `mant` (wrapping; callers check the count), advancing `p`; returns
/// how many there were.
#[inline]
fn digits(b: &[u8], p: &mut usize, mant: &mut u64) -> usize {
    let start = *p;
    while let Some(d) = b.get(*p).map(|c| c.wrapping_sub(b'0')).filter(|d| *d < 10) {
        *mant = mant.wrapping_mul(10).wrapping_add(u64::from(d));
        *p += 1;
    }
    *p - start
}

/// Parses a plain decimal (`[-]digits[.digits]`, ≤ 19 digits, mantissa ≤ 2⁵³, ≤ 22 decimals) at `b[p..]`; returns
/// the value and the index after it, or `None` (the caller then takes the general path). Exact: Clinger's fast path.
#[inline]
fn fast_number(b: &[u8], mut p: usize) -> Option<(f64, usize)> {
    let neg = b.get(p) == Some(&b'-');
    p += usize::from(neg);
    let mut mant = 0u64;
    let int_digits = digits(b, &mut p, &mut mant);
    let mut frac = 0;
    if b.get(p) == Some(&b'.') {
        p += 1;
        frac = digits(b, &mut p, &mut mant);
    }
    if int_digits + frac == 0 || int_digits + frac > 19 || mant > 1 << 53 || frac > 22 {
        return None;
    }
    let m = mant as f64 / POW10[frac];
    Some((if neg { -m } else { m }, p))
}

/// Parses the rows of one piece in one pass over its bytes, writing row r of output column c into `out[c][r]`;
/// returns the rows written. `first_line` is the file line number of the line before the piece's first one (a
/// piece starts right after a line end); `target_of[col]` is the output column of each file column (`None`:
/// ignored).
fn parse_chunk(
    chunk: &str,
    first_line: usize,
    roles: &[Role],
    target_of: &[Option<usize>],
    names: &[&str],
    out: &mut [&mut [f64]],
) -> Result<usize, CsvError> {
    let b = chunk.as_bytes();
    let n = b.len();
    let ncols = roles.len();
    let (mut p, mut line_no, mut row) = (0usize, first_line, 0usize);
    while let Some(&c0) = b.get(p) {
        // Empty line, or the empty remainder of the line before the piece.
        if matches!(c0, b'\n' | b'\r') {
            line_no += usize::from(c0 == b'\n');
            p += 1;
            continue;
        }
        let mut col = 0;
        loop {
            let target = target_of.get(col).copied().flatten();
            let fast = target.and_then(|_| {
                fast_number(b, p)
                    .filter(|&(_, q)| matches!(b.get(q), Some(b',' | b'\n' | b'\r') | None))
            });
            let value = match fast {
                Some((v, q)) => {
                    p = q;
                    Some(v)
                }
                None => {
                    // General path: the whole cell, trimmed, through `parse_f64`.
                    let end = b
                        .get(p..)
                        .and_then(|r| r.iter().position(|&c| matches!(c, b',' | b'\n')))
                        .map_or(n, |k| p + k);
                    let cell = chunk.get(p..end).unwrap_or("").trim();
                    p = end;
                    match target {
                        None => None,
                        Some(_) => Some(parse_f64(cell).ok_or_else(|| CsvError::Cell {
                            line: line_no,
                            column: col + 1,
                            name: names.get(col).unwrap_or(&"?").to_string(),
                            what: format!("expected a number, found '{cell}'"),
                        })?),
                    }
                }
            };
            if let (Some(v), Some(t)) = (value, target)
                && let Some(slot) = out.get_mut(t).and_then(|c| c.get_mut(row))
            {
                *slot = v;
            }
            col += 1;
            if b.get(p) == Some(&b'\r') {
                p += 1;
            }
            match b.get(p) {
                Some(b',') => p += 1,
                _ => break,
            }
        }
        if col != ncols {
            return Err(CsvError::Width {
                line: line_no,
                expected: ncols,
                found: col,
            });
        }
        row += 1;
        // At '\n' (or the end).
        p += 1;
        line_no += 1;
    }
    Ok(row)
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
        let (header_index, header) = lines
            .next()
            .ok_or_else(|| CsvError::Header("the file is empty".into()))?;
        let header_line = header_index + 1;
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
        // The body is cut into chunks at line ends and parsed in parallel; each chunk knows its first line number,
        // so errors still point at the right line.
        let body_start = header.as_ptr() as usize - text.as_ptr() as usize + header.len();
        let body = text.get(body_start..).unwrap_or("");
        let parts = (rayon::current_num_threads() * 4).max(1);
        let mut pieces: Vec<&str> = Vec::with_capacity(parts + 1);
        let mut rest = body;
        while !rest.is_empty() {
            let target = (body.len() / parts).max(1 << 16).min(rest.len());
            let cut = rest
                .get(target..)
                .and_then(|r| r.find('\n'))
                .map_or(rest.len(), |i| target + i + 1);
            let (piece, tail) = rest.split_at(cut);
            pieces.push(piece);
            rest = tail;
        }
        // Line ends per piece (in parallel): the first line number of every piece, and room for its rows.
        let newlines: Vec<usize> = pieces.par_iter().map(|p| count_newlines(p)).collect();
        let mut first_lines = Vec::with_capacity(pieces.len());
        let mut row_start = Vec::with_capacity(pieces.len() + 1);
        let (mut line_no, mut rows) = (header_line, 0usize);
        for (piece, &nl) in pieces.iter().zip(&newlines) {
            first_lines.push(line_no);
            row_start.push(rows);
            rows += nl + usize::from(!piece.ends_with('\n'));
            line_no += nl;
        }
        row_start.push(rows);
        // Every piece writes its rows straight into its own slices of the final columns.
        let n_targets = 1 + usize::from(has_temp) + columns.len();
        let mut targets: Vec<Vec<f64>> = (0..n_targets).map(|_| vec![0.0; rows]).collect();
        let mut views: Vec<Vec<&mut [f64]>> = (0..pieces.len())
            .map(|_| Vec::with_capacity(n_targets))
            .collect();
        for target in targets.iter_mut() {
            let mut rest: &mut [f64] = target;
            for (view, w) in views.iter_mut().zip(row_start.windows(2)) {
                let (mine, tail) = rest.split_at_mut(w[1] - w[0]);
                view.push(mine);
                rest = tail;
            }
        }
        let target_of: Vec<Option<usize>> = roles
            .iter()
            .map(|r| match r {
                Role::Time => Some(0),
                Role::Temp => Some(1),
                Role::Sensor(k) => Some(1 + usize::from(has_temp) + k),
                Role::Ignored => None,
            })
            .collect();
        let written: Vec<Result<usize, CsvError>> = pieces
            .par_iter()
            .zip(views.par_iter_mut())
            .zip(first_lines.par_iter())
            .map(|((piece, view), &first)| {
                parse_chunk(piece, first, &roles, &target_of, &names, view)
            })
            .collect();
        drop(views);
        // Pieces with empty lines wrote fewer rows than they had room for: close the gaps.
        let mut counts = Vec::with_capacity(written.len());
        for w in written {
            counts.push(w?);
        }
        let total: usize = counts.iter().sum();
        if total != rows {
            for target in targets.iter_mut() {
                let mut to = 0;
                for (w, &c) in row_start.windows(2).zip(&counts) {
                    target.copy_within(w[0]..w[0] + c, to);
                    to += c;
                }
                target.truncate(total);
            }
        }
        let mut targets = targets.into_iter();
        let mut rec = Recording {
            t_s: targets.next().unwrap_or_default(),
            temp_c: if has_temp { targets.next() } else { None },
            columns: Vec::new(),
        };
        for (c, data) in columns.iter_mut().zip(targets) {
            c.data = data;
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

    /// Writes the canonical CSV (gyro columns of a group, then its accel columns; groups in order). Time in Rust's
    /// shortest round-trip form; sensor values and temperature with [`VALUE_DECIMALS`] decimals.
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
                row.push(',');
                push_value(&mut row, t.get(i).copied().unwrap_or(f64::NAN));
            }
            for c in &order {
                row.push(',');
                push_value(&mut row, c.data.get(i).copied().unwrap_or(f64::NAN));
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
    fn large_files_parse_in_chunks_with_exact_line_numbers() {
        let mut text = String::from("t,g00x,a00z\n");
        for i in 0..40_000 {
            text.push_str(&format!("{},{}.5,-{}\n", i, i, i));
        }
        let (rec, _) = Recording::parse(&text).unwrap();
        assert_eq!(rec.len(), 40_000);
        assert_eq!(rec.column("g00x").unwrap().data[39_999], 39_999.5);
        assert_eq!(rec.column("a00z").unwrap().data[12_345], -12_345.0);
        // An error deep in the file: line 1 is the header, so sample 31 000 is on line 31 002.
        let bad = text.replacen("31000.5", "31x00.5", 1);
        let e = Recording::parse(&bad).unwrap_err().to_string();
        assert_eq!(
            e,
            "line 31002, column 2 (g00x): expected a number, found '31x00.5'"
        );
        // Blank lines anywhere (also across pieces) are skipped, and the rows stay in order.
        let blanks =
            text.replacen("\n1000,", "\n\n\n1000,", 1)
                .replacen("\n30000,", "\n\r\n30000,", 1)
                + "\n\n";
        let (rec, _) = Recording::parse(&blanks).unwrap();
        assert_eq!(rec.len(), 40_000);
        assert!(rec.t_s.windows(2).all(|w| w[1] == w[0] + 1.0));
        assert_eq!(rec.column("g00x").unwrap().data[39_999], 39_999.5);
        let bad = blanks.replacen("31000.5", "31x00.5", 1);
        let e = Recording::parse(&bad).unwrap_err().to_string();
        assert_eq!(
            e,
            "line 31005, column 2 (g00x): expected a number, found '31x00.5'"
        );
        let short = text.replacen("\n25000,25000.5,-25000\n", "\n25000,25000.5\n", 1);
        let e = Recording::parse(&short).unwrap_err().to_string();
        assert_eq!(e, "line 25002: expected 3 comma-separated values, found 2");
    }

    #[test]
    fn fast_parser_agrees_with_std_and_writer_is_compact() {
        let cases = [
            "0",
            "-0",
            "1",
            "-1.5",
            "0.028390270",
            "-0.02839027",
            "123456789.123456789",
            "1e-3",
            "2.5E+7",
            "9007199254740993",
            "0.1",
            "3.14159265358979323846",
            "1e300",
            "-4.9e-324",
            "17",
            ".5",
            "5.",
            "1e",
            "x",
            "",
            "-",
            "nan",
            "inf",
            "+7",
            "0.000000001",
        ];
        for c in cases {
            let want: Option<f64> = c.parse().ok();
            assert_eq!(
                parse_f64(c).map(f64::to_bits),
                want.map(f64::to_bits),
                "{c}"
            );
        }
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        for _ in 0..200_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let v = (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5;
            let mut out = String::new();
            push_value(&mut out, v);
            assert_eq!(
                parse_f64(&out).map(f64::to_bits),
                out.parse::<f64>().ok().map(f64::to_bits),
                "{out}"
            );
            assert!(
                (parse_f64(&out).unwrap() - v).abs() <= 0.5e-9 + 1e-17,
                "{v} → {out}"
            );
            let full = format!("{v}");
            assert_eq!(
                parse_f64(&full).map(f64::to_bits),
                Some(v.to_bits()),
                "{full}"
            );
        }
        let mut out = String::new();
        for v in [0.5, -0.0, 1.0, -0.0283902700001, 1e-12] {
            push_value(&mut out, v);
            out.push(' ');
        }
        assert_eq!(out, "0.5 0 1 -0.02839027 0 ");
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(2000))]
        /// Random edits of a valid file (and random bytes) give a recording or a positioned error, never a panic.
        #[test]
        fn mangled_files_never_panic(edits in proptest::collection::vec((0usize..400, proptest::prelude::any::<u8>()), 0..12),
                                     junk in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200)) {
            let mut text = String::from("t,temp_c,g00x,a00z,zz\n");
            for i in 0..12 {
                text.push_str(&format!("{},{}.5,-0.{}25,{}e-3,x\n", i, 20 + i, i, i));
            }
            let mut bytes = text.into_bytes();
            let len = bytes.len();
            for (at, b) in edits {
                if let Some(x) = bytes.get_mut(at % len) {
                    *x = b;
                }
            }
            if let Ok(t) = std::str::from_utf8(&bytes) {
                let _ = Recording::parse(t);
            }
            let _ = Recording::parse(&String::from_utf8_lossy(&junk));
        }
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
