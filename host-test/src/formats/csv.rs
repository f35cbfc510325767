//! The interchange CSV: `t,temp_c,g00x,g00y,g00z,a00x,a00y,a00z,g01x,…`, one row per sample. `t` in seconds,
//! `temp_c` (optional) in °C, then per sensor group `gSSx/y/z` in °/s and `aSSx/y/z` in g, any number of groups, any
//! subset of axes. Columns may come in any order; unknown columns are ignored with a warning. A UTF-8 byte-order mark
//! is skipped. Every cell must be a finite number (NaN only in `temp_c`: no temperature, with a warning), `t` must
//! increase from row to row (steps longer than 1.5 sample intervals give a warning), and there must be a data row;
//! anything else is an error with its line and column.
//!
//! **Why a reader of our own** (`parse.rs`) and not the `csv` crate: like for like (`examples/csv_crate_blocks.rs`:
//! the same file, blocks and pieces under rayon on the same 2 threads, only each piece's parsing swapped for
//! `csv::ByteRecord` + `fast-float2`, the same `Recording` bit for bit), the crate takes 1.87× the reader's time on
//! the 8-h paper-size file (545 410 rows × 97 columns, 503 MB: 1.99 s against 1.12 s, medians of 5 pairs, release
//! build, 2026-11-26; `docs/performance.md`). The rule was to take the crate within 15 %. For large data `.npy`
//! input (`formats::npy`) skips text parsing altogether.

use rayon::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

mod parse;
use parse::{BLOCK_BYTES, Layout, count_newlines, fast_number, fill, find_header, parse_region};
#[doc(hidden)]
pub use parse::{PieceParser, general_cell, parse_chunk};

pub use crate::recording::{
    AXIS_NAMES, AxisMean, Column, Recording, SensorKind, column_name, parse_column_name,
};

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

/// Parses a decimal number. Plain forms (`[-]digits[.digits]`, see `fast_number`) are converted exactly by
/// Clinger's fast path; anything else (exponents, `+`, long mantissas) goes to the standard library. Both give the
/// correctly rounded value.
pub fn parse_f64(s: &str) -> Option<f64> {
    match fast_number(s.as_bytes(), 0) {
        Some((v, end)) if end == s.len() => Some(v),
        _ => s.parse().ok(),
    }
}

/// A CSV error with its position.
#[derive(Debug, thiserror::Error)]
pub enum CsvError {
    /// I/O. The cause is chained (`source`), not repeated in the message.
    #[error("reading {path}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Header problems.
    #[error("line {line} (header): {what}")]
    Header {
        /// 1-based line of the header (blank lines may come before it).
        line: usize,
        /// What is wrong.
        what: String,
    },
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

/// The UTF-8 byte-order mark.
const UTF8_BOM: [u8; 3] = [0xEF, 0xBB, 0xBF];

/// Checks the times (column `column` of the file; rows on the lines `line_of` gives): they must increase from
/// row to row (an error with the line otherwise). Steps longer than 1.5 median intervals (lost samples) are
/// counted in a warning: the analyses treat the samples as evenly spaced.
fn check_time(
    t: &[f64],
    line_of: &dyn Fn(usize) -> usize,
    column: usize,
    warnings: &mut Vec<String>,
) -> Result<(), CsvError> {
    if let Some(i) = t.windows(2).position(|w| w[1] <= w[0]).map(|i| i + 1) {
        return Err(CsvError::Cell {
            line: line_of(i),
            column,
            name: "t".into(),
            what: format!(
                "time {} s is not after {} s on line {}: t must increase from row to row",
                short(t[i]),
                short(t[i - 1]),
                line_of(i - 1)
            ),
        });
    }
    let mut d: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    if d.is_empty() {
        return Ok(());
    }
    // As in [`Recording::sample_interval_s`].
    let mid = d.len() / 2;
    let median = *d.select_nth_unstable_by(mid, f64::total_cmp).1;
    let long = |x: f64| x > 1.5 * median;
    let gaps = t.windows(2).filter(|w| long(w[1] - w[0])).count();
    if let Some(i) = (1..t.len()).max_by(|&a, &b| (t[a] - t[a - 1]).total_cmp(&(t[b] - t[b - 1])))
        && gaps > 0
    {
        warnings.push(format!(
            "t: {gaps} gaps longer than 1.5 sample intervals ({} s; the longest {} s, before line {}): \
             the analyses treat the samples as evenly spaced",
            short(median),
            short(t[i] - t[i - 1]),
            line_of(i)
        ));
    }
    Ok(())
}

/// `x` for a message: shortest round-trip form, in exponent form when very large or small.
fn short(x: f64) -> String {
    if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

/// What a column of the file is.
enum Role {
    Time,
    Temp,
    Sensor(usize),
    Ignored,
}

impl Recording {
    /// Parses CSV text; returns the recording and warnings (ignored columns).
    pub fn parse(text: &str) -> Result<(Recording, Vec<String>), CsvError> {
        Self::parse_from(text.as_bytes(), text.len() as u64, "<text>")
    }

    /// Reads a CSV file, streaming it in blocks (see [`Self::parse_from`]).
    pub fn read(path: &Path) -> Result<(Recording, Vec<String>), CsvError> {
        let name = path.display().to_string();
        let io = |source| CsvError::Io {
            path: name.clone(),
            source,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let size = file.metadata().map_or(0, |m| m.len());
        Self::parse_from(file, size, &name)
    }

    /// Parses CSV from `src` (`size_hint` bytes expected, for reserving the columns; `name` for I/O errors).
    ///
    /// The text is read in blocks of `BLOCK_BYTES` cut at line ends; each block is cut into pieces parsed in
    /// parallel straight into their rows of the columns, while the next block is read. Only the header and
    /// cells the fast path refuses need to be UTF-8 (a cell that is not gets a positioned error), so the body is
    /// never validated or copied as a whole, and memory holds one block and the columns.
    pub fn parse_from(
        src: impl std::io::Read + Send,
        size_hint: u64,
        name: &str,
    ) -> Result<(Recording, Vec<String>), CsvError> {
        Self::parse_blocks(src, size_hint, name, BLOCK_BYTES, parse_chunk)
    }

    /// [`Self::parse_from`] with another parser of each piece of a block: for the like-for-like comparison with
    /// the `csv` crate (`examples/csv_crate_blocks.rs`), where everything but the pieces' parsing is the same.
    #[doc(hidden)]
    pub fn parse_from_with(
        src: impl std::io::Read + Send,
        size_hint: u64,
        name: &str,
        piece: PieceParser,
    ) -> Result<(Recording, Vec<String>), CsvError> {
        Self::parse_blocks(src, size_hint, name, BLOCK_BYTES, piece)
    }

    /// [`Self::parse_from`] with blocks of `block` bytes. Phases: the header found and read, the blocks of the
    /// body parsed into the columns, the recording checked and put together.
    fn parse_blocks(
        mut src: impl std::io::Read + Send,
        size_hint: u64,
        name: &str,
        block: usize,
        piece: PieceParser,
    ) -> Result<(Recording, Vec<String>), CsvError> {
        let block = block.max(1);
        let mut cur = Vec::new();
        let (header_line, (line_start, line_end), eof) =
            read_header(&mut src, &mut cur, block, name)?;
        let header =
            std::str::from_utf8(cur.get(line_start..line_end).unwrap_or(&[])).map_err(|_| {
                CsvError::Header {
                    line: header_line,
                    what: "not UTF-8 text".into(),
                }
            })?;
        let mut warnings = Vec::new();
        let head = Header::parse(header, header_line, &mut warnings)?;
        let names: Vec<&str> = head.names.iter().map(String::as_str).collect();
        let layout = Layout {
            target_of: &head.target_of,
            names: &names,
            piece,
        };
        // The header line ends at `line_end` (before any "\r\n"); the body starts after its '\n'.
        let body_start = cur
            .get(line_end..)
            .and_then(|r| r.iter().position(|&c| c == b'\n'))
            .map_or(cur.len(), |i| line_end + i + 1);
        let body = Body {
            src,
            cur,
            eof,
            start: body_start,
            line_no: header_line,
            size_hint,
            block,
            name,
        };
        let n_targets = 1 + usize::from(head.has_temp) + head.columns.len();
        let (targets, blanks) = body.parse(&layout, n_targets)?;
        head.recording(targets, &blanks, header_line, warnings)
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

/// Reads into `cur` (from the start of `src`) until it holds the header, the first line that is not blank, whole;
/// a byte-order mark is dropped. Returns the header's line, its byte range in `cur` and whether `src` has ended.
fn read_header(
    src: &mut impl std::io::Read,
    cur: &mut Vec<u8>,
    block: usize,
    name: &str,
) -> Result<(usize, (usize, usize), bool), CsvError> {
    let io = |source| CsvError::Io {
        path: name.to_string(),
        source,
    };
    let mut eof = fill(src, cur, block.max(UTF8_BOM.len())).map_err(io)?;
    // A byte-order mark (spreadsheet programs write one) is not part of the first column's name.
    if cur.starts_with(&UTF8_BOM) {
        cur.drain(..UTF8_BOM.len());
    }
    loop {
        match find_header(cur, eof) {
            Some((line, range)) => return Ok((line, range, eof)),
            None if !eof => {
                let want = 2 * cur.len();
                eof = fill(src, cur, want).map_err(io)?;
            }
            None => {
                return Err(CsvError::Header {
                    line: 1,
                    what: "the file is empty".into(),
                });
            }
        }
    }
}

/// The header's columns: their names, where each one's values go, the sensor columns (without data yet).
struct Header {
    names: Vec<String>,
    /// Per column of the file: its target (0 the time, 1 the temperature if any, then the sensor columns).
    target_of: Vec<Option<usize>>,
    columns: Vec<Column>,
    has_temp: bool,
}

impl Header {
    /// Parses the header line `header` (file line `line`); pushes a warning for every column ignored.
    fn parse(header: &str, line: usize, warnings: &mut Vec<String>) -> Result<Header, CsvError> {
        let error = |what: String| CsvError::Header { line, what };
        let names: Vec<String> = header.split(',').map(|n| n.trim().to_string()).collect();
        let mut roles = Vec::with_capacity(names.len());
        let mut columns: Vec<Column> = Vec::new();
        let (mut has_t, mut has_temp) = (false, false);
        for name in &names {
            let role = match name.as_str() {
                "t" if !has_t => {
                    has_t = true;
                    Role::Time
                }
                "temp_c" if !has_temp => {
                    has_temp = true;
                    Role::Temp
                }
                "t" | "temp_c" => return Err(error(format!("column '{name}' appears twice"))),
                _ => match parse_column_name(name) {
                    Some((kind, group, axis)) => {
                        if columns
                            .iter()
                            .any(|c| c.kind == kind && c.group == group && c.axis == axis)
                        {
                            return Err(error(format!("column '{name}' appears twice")));
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
            // A file with another separator has one long "name".
            let other = [';', '\t', ' ', '|']
                .into_iter()
                .find(|&c| names.len() == 1 && header.contains(c));
            return Err(error(match other {
                Some(c) => format!(
                    "no 't' column (time in seconds): the columns must be separated by commas, found {c:?}"
                ),
                None => "no 't' column (time in seconds)".into(),
            }));
        }
        if columns.is_empty() {
            return Err(error("no sensor columns (gSSx … aSSz)".into()));
        }
        let target_of = roles
            .iter()
            .map(|r| match r {
                Role::Time => Some(0),
                Role::Temp => Some(1),
                Role::Sensor(k) => Some(1 + usize::from(has_temp) + k),
                Role::Ignored => None,
            })
            .collect();
        Ok(Header {
            names,
            target_of,
            columns,
            has_temp,
        })
    }

    /// The recording from the parsed `targets` (one per target, all rows; `blanks` the rows after empty lines, the
    /// header on file line `header_line`): checks the times and counts missing temperatures (into `warnings`).
    fn recording(
        mut self,
        targets: Vec<Vec<f64>>,
        blanks: &[usize],
        header_line: usize,
        mut warnings: Vec<String>,
    ) -> Result<(Recording, Vec<String>), CsvError> {
        if targets.first().is_none_or(Vec::is_empty) {
            return Err(CsvError::Header {
                line: header_line,
                what: "no samples: no data row after the header".into(),
            });
        }
        // File line of row r: the header, the rows and empty lines before it.
        let line_of = |r: usize| header_line + 1 + r + blanks.partition_point(|&b| b <= r);
        let column_of = |n: &str| self.names.iter().position(|x| *x == n).map_or(0, |i| i + 1);
        let time = targets.first().map_or(&[][..], Vec::as_slice);
        check_time(time, &line_of, column_of("t"), &mut warnings)?;
        if let Some(temp) = targets.get(1).filter(|_| self.has_temp) {
            let missing = temp.iter().filter(|x| x.is_nan()).count();
            if let Some(first) = temp.iter().position(|x| x.is_nan()) {
                warnings.push(format!(
                    "temp_c: {missing} of {} samples have no temperature (NaN), the first on line {}",
                    temp.len(),
                    line_of(first)
                ));
            }
        }
        let mut targets = targets.into_iter();
        let mut rec = Recording {
            t_s: targets.next().unwrap_or_default(),
            temp_c: if self.has_temp { targets.next() } else { None },
            columns: Vec::new(),
        };
        for (c, data) in self.columns.iter_mut().zip(targets) {
            c.data = data;
        }
        self.columns.sort_by_key(|c| (c.kind, c.group, c.axis));
        rec.columns = self.columns;
        Ok((rec, warnings))
    }
}

/// The body of a CSV being read: `cur` holds the text read so far, the body's unparsed part from `start` on.
struct Body<'n, R> {
    src: R,
    cur: Vec<u8>,
    /// Whether `src` has ended.
    eof: bool,
    start: usize,
    /// File line of the last line before `start`.
    line_no: usize,
    /// Bytes expected in all, for reserving the columns.
    size_hint: u64,
    block: usize,
    /// For I/O errors.
    name: &'n str,
}

impl<R: std::io::Read + Send> Body<'_, R> {
    /// Parses the rest of the text, block by block (each one's pieces in parallel while the next block is read),
    /// into `n_targets` columns; returns them, cut to the rows parsed, and the row after every empty line.
    fn parse(
        mut self,
        layout: &Layout,
        n_targets: usize,
    ) -> Result<(Vec<Vec<f64>>, Vec<usize>), CsvError> {
        let io = |source| CsvError::Io {
            path: self.name.to_string(),
            source,
        };
        let mut targets: Vec<Vec<f64>> = vec![Vec::new(); n_targets];
        let mut next = Vec::new();
        let mut first = true;
        // The row after every empty line of the body (for the line of a row).
        let mut blanks = Vec::new();
        // Rows parsed so far (the columns may be longer: room reserved ahead).
        let mut filled = 0;
        loop {
            let body = self.cur.get(self.start..).unwrap_or(&[]);
            // Whole lines only, unless this is the end of the text.
            let end = if self.eof {
                body.len()
            } else {
                match memchr::memrchr(b'\n', body) {
                    Some(i) => i + 1,
                    None => {
                        // Not one whole line in the buffer: read more.
                        let want = 2 * self.cur.len().max(self.block);
                        self.eof = fill(&mut self.src, &mut self.cur, want).map_err(io)?;
                        continue;
                    }
                }
            };
            let (region, rest) = body.split_at(end);
            if first {
                first = false;
                reserve_rows(&mut targets, region, self.size_hint);
            }
            next.clear();
            next.extend_from_slice(rest);
            let (eof, src, block) = (self.eof, &mut self.src, self.block);
            let (parsed, read) = rayon::join(
                || {
                    parse_region(
                        region,
                        self.line_no,
                        layout,
                        &mut targets,
                        filled,
                        &mut blanks,
                    )
                },
                || {
                    if eof {
                        Ok(true)
                    } else {
                        fill(src, &mut next, block)
                    }
                },
            );
            let (last_line, rows) = parsed?;
            self.line_no = last_line;
            filled += rows;
            if self.eof {
                break;
            }
            self.eof = read.map_err(io)?;
            std::mem::swap(&mut self.cur, &mut next);
            self.start = 0;
        }
        for t in &mut targets {
            t.truncate(filled);
        }
        Ok((targets, blanks))
    }
}

/// Room in every target for all rows, estimated from the bytes per line of the first MiB of `region` (the first
/// block's whole lines) and the `size_hint`. Zeroed allocations are fresh pages, faulted in (in parallel) by the
/// parsers' first writes.
fn reserve_rows(targets: &mut [Vec<f64>], region: &[u8], size_hint: u64) {
    let sample = region.get(..region.len().min(1 << 20)).unwrap_or(region);
    let lines = count_newlines(sample).max(1);
    let rows = (size_hint as f64 * lines as f64 / sample.len().max(1) as f64 * 1.01) as usize;
    for t in targets {
        *t = vec![0.0; rows];
    }
}

#[cfg(test)]
mod tests;
