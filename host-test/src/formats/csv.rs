//! The interchange CSV: `t,temp_c,g00x,g00y,g00z,a00x,a00y,a00z,g01x,…`, one row per sample. `t` in seconds,
//! `temp_c` (optional) in °C, then per sensor group `gSSx/y/z` in °/s and `aSSx/y/z` in g, any number of groups, any
//! subset of axes. Columns may come in any order; unknown columns are ignored with a warning. A UTF-8 byte-order mark
//! is skipped. Every cell must be a finite number (NaN only in `temp_c`: no temperature, with a warning), `t` must
//! increase from row to row (steps longer than 1.5 sample intervals give a warning), and there must be a data row;
//! anything else is an error with its line and column.

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

/// Number of `\n` in `b` (line ends are sparse in our files: memchr skips 16–32 bytes per step).
fn count_newlines(b: &[u8]) -> usize {
    memchr::memchr_iter(b'\n', b).count()
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
/// Eight digits at a time where 32 bytes follow (the body of a file), one at a time near its end.
#[inline(always)]
fn fast_number(b: &[u8], p: usize) -> Option<(f64, usize)> {
    let neg = b.get(p) == Some(&b'-');
    let window = b.get(p..p + 32).and_then(|w| w.try_into().ok());
    let (mant, int_digits, frac, len) = match window.and_then(|w| swar_number(w, usize::from(neg)))
    {
        Some(parsed) => parsed,
        None => {
            let mut q = p + usize::from(neg);
            let mut mant = 0u64;
            let int_digits = digits(b, &mut q, &mut mant);
            let mut frac = 0;
            if b.get(q) == Some(&b'.') {
                q += 1;
                frac = digits(b, &mut q, &mut mant);
            }
            (mant, int_digits, frac, q - p)
        }
    };
    if int_digits + frac == 0 || int_digits + frac > 19 || mant > 1 << 53 || frac > 22 {
        return None;
    }
    // The sign as a bit, not a branch (it is a coin toss in noise data).
    let m = mant as f64 / POW10[frac];
    Some((f64::from_bits(m.to_bits() | u64::from(neg) << 63), p + len))
}

/// `10^k` for k = 0 ..= 8.
const POW10_U64: [u64; 9] = [
    1,
    10,
    100,
    1_000,
    10_000,
    100_000,
    1_000_000,
    10_000_000,
    100_000_000,
];

/// The leading decimal digits of 8 bytes read little-endian (SWAR): (how many, 0 ..= 8; their value).
#[inline(always)]
fn swar_digits(word: u64) -> (usize, u64) {
    const ZEROS: u64 = 0x3030_3030_3030_3030;
    // Per byte c: t = c − '0' (a borrow only reaches bytes after the first non-digit); c is a digit ⇔ t < 10 ⇔
    // neither t nor t + 0x76 has its top bit set. The lowest flagged byte is the first non-digit.
    let t = word.wrapping_sub(ZEROS);
    let non_digit = (t | t.wrapping_add(0x7676_7676_7676_7676)) & 0x8080_8080_8080_8080;
    let count = (non_digit.trailing_zeros() / 8) as usize;
    // The digits moved to the top bytes, zeros (leading zeros of the number) below, then combined pairwise: the
    // first character is the lowest byte, the most significant digit.
    let v = t.checked_shl(64 - 8 * count as u32).unwrap_or(0);
    let v = (v.wrapping_mul(10) + (v >> 8)) & 0x00FF_00FF_00FF_00FF;
    let v = (v.wrapping_mul(100) + (v >> 16)) & 0x0000_FFFF_0000_FFFF;
    let v = (v.wrapping_mul(10_000) + (v >> 32)) & 0xFFFF_FFFF;
    (count, v)
}

/// 8 bytes of `w` from `i` (at most 24: every read stays in the window without a check), little-endian.
#[inline(always)]
fn word_in(w: &[u8; 32], i: usize) -> u64 {
    let i = i.min(24);
    w.get(i..i + 8)
        .and_then(|s| s.try_into().ok())
        .map_or(0, u64::from_le_bytes)
}

/// The digits of `[digits][.digits]` from `w[q..]` (q = 1 after a sign, else 0) eight at a time: (mantissa,
/// integer digits, decimals, bytes from `w[0]` to the end), or `None` where a part has 8 or more (integer) / 16 or
/// more (decimal) digits.
#[inline(always)]
fn swar_number(w: &[u8; 32], q: usize) -> Option<(u64, usize, usize, usize)> {
    let (int_digits, int_value) = swar_digits(word_in(w, q));
    if int_digits == 8 {
        return None;
    }
    let dot = q + int_digits;
    if w.get(dot) != Some(&b'.') {
        return Some((int_value, int_digits, 0, dot));
    }
    // Two words of decimals; the second counts only when the first is all digits.
    let (k1, v1) = swar_digits(word_in(w, dot + 1));
    let (k2, v2) = swar_digits(word_in(w, dot + 9));
    let (k2, v2) = if k1 == 8 { (k2, v2) } else { (0, 0) };
    if k2 == 8 {
        return None;
    }
    let pow = |k: usize| POW10_U64.get(k).copied().unwrap_or(1);
    // Wraps only past 19 digits, which the caller rejects.
    let mant = (int_value.wrapping_mul(pow(k1)) + v1)
        .wrapping_mul(pow(k2))
        .wrapping_add(v2);
    Some((mant, int_digits, k1 + k2, dot + 1 + k1 + k2))
}

/// Bit i set where `block[i]` is `a` or `b`: the comparisons as 64 bytes of 0 or 1 (vectorised), then each 8
/// of them packed into a byte by one multiplication (byte k of a word lands on bit 56 + k; no carries cross).
#[inline(always)]
fn byte_mask(block: &[u8; 64], a: u8, b: u8) -> u64 {
    const PACK: u64 = 0x0102_0408_1020_4080;
    let hits = block.map(|c| u8::from(c == a || c == b));
    hits.chunks_exact(8).enumerate().fold(0u64, |m, (k, w)| {
        let w = w.try_into().map_or(0, u64::from_le_bytes);
        m | (w.wrapping_mul(PACK) >> 56) << (8 * k)
    })
}

/// Parses the rows of one piece, writing row r of file column c into `out[c][r]` (`None`: an ignored column);
/// returns the rows written. `first_line` is the file line number of the line before the piece's first one (a
/// piece starts right after a line end). Every empty line pushes onto `blanks` the row that follows it (rows of
/// the piece), so that a row's line can be found afterwards.
///
/// Cells are found from bitmasks of the separators, 64 bytes at a time, so where a cell starts never waits for the
/// cell before it to be parsed: the processor works on several numbers at once. Compiled also for AVX2 + BMI2 and
/// for AVX-512, the best chosen at run time (the baseline x86-64 code takes 7 % more instructions and ≈ 16 % more
/// time here); every version computes the same bits.
#[multiversion::multiversion(targets(
    "x86_64+avx512f+avx512bw+avx512vl+avx2+bmi1+bmi2+lzcnt+popcnt",
    "x86_64+avx2+bmi1+bmi2+lzcnt+popcnt"
))]
fn parse_chunk(
    b: &[u8],
    first_line: usize,
    names: &[&str],
    out: &mut [Option<&mut [f64]>],
    blanks: &mut Vec<usize>,
) -> Result<usize, CsvError> {
    let ncols = out.len();
    let (mut line_no, mut row, mut col, mut start) = (first_line, 0usize, 0usize, 0usize);
    let mut blocks = b.chunks_exact(64);
    let mut offset = 0;
    loop {
        // Separators and line ends of the next 64 bytes.
        let mut seps = match blocks.next().and_then(|w| <&[u8; 64]>::try_from(w).ok()) {
            Some(w) => byte_mask(w, b',', b'\n'),
            None => {
                // The rest, padded with zero bytes (neither separator) to a whole block.
                let rest = blocks.remainder();
                let mut padded = [0u8; 64];
                if let Some(head) = padded.get_mut(..rest.len()) {
                    head.copy_from_slice(rest);
                }
                // A last line without a line end ends at the end of the piece.
                let last = if b.last().is_some_and(|&c| c != b'\n') {
                    1u64 << rest.len()
                } else {
                    0
                };
                byte_mask(&padded, b',', b'\n') | last
            }
        };
        while seps != 0 {
            let i = seps.trailing_zeros();
            seps &= seps - 1;
            let sep = offset + i as usize;
            // A line end, or the end of a last line without one (just past the piece). Line ends are rare (one
            // per row): reading the byte is cheaper than a second mask per 64 bytes.
            let eol = b.get(sep) != Some(&b',');
            let mut end = sep;
            if eol {
                end -= usize::from(end > start && b.get(end - 1) == Some(&b'\r'));
                if col == 0 && end == start {
                    // An empty line.
                    blanks.push(row);
                    line_no += 1;
                    start = sep + 1;
                    continue;
                }
            }
            if let Some(Some(column)) = out.get_mut(col) {
                let value = match fast_number(b, start) {
                    Some((v, q)) if q == end => v,
                    _ => general_cell(b.get(start..end).unwrap_or(&[]), line_no + 1, col, names)?,
                };
                if let Some(slot) = column.get_mut(row) {
                    *slot = value;
                }
            }
            start = sep + 1;
            if eol {
                line_no += 1;
                if col + 1 != ncols {
                    return Err(CsvError::Width {
                        line: line_no,
                        expected: ncols,
                        found: col + 1,
                    });
                }
                row += 1;
                col = 0;
            } else {
                col += 1;
            }
        }
        if offset + 64 > b.len() {
            return Ok(row);
        }
        offset += 64;
    }
}

/// A cell the fast path refused: trimmed, through [`parse_f64`], or a positioned error. Only this path can give a
/// value that is not finite (`nan`, `inf`, `1e400`): an error, except NaN in `temp_c` (a sample without a
/// temperature, as [`Recording::write`] writes it).
#[cold]
fn general_cell(cell: &[u8], line: usize, col: usize, names: &[&str]) -> Result<f64, CsvError> {
    let text = String::from_utf8_lossy(cell);
    let text = text.trim();
    let name = names.get(col).unwrap_or(&"?");
    let err = |what: String| CsvError::Cell {
        line,
        column: col + 1,
        name: name.to_string(),
        what,
    };
    let v = parse_f64(text).ok_or_else(|| err(format!("expected a number, found '{text}'")))?;
    if v.is_finite() || (v.is_nan() && *name == "temp_c") {
        Ok(v)
    } else {
        Err(err(format!("expected a finite number, found '{text}'")))
    }
}

/// Bytes read per block by [`Recording::parse_from`].
pub const BLOCK_BYTES: usize = 16 << 20;

/// Reads from `src` until `buf` holds `want` bytes or the input ends; returns whether it ended.
fn fill<R: std::io::Read>(src: &mut R, buf: &mut Vec<u8>, want: usize) -> std::io::Result<bool> {
    let missing = want.saturating_sub(buf.len());
    let got = std::io::Read::read_to_end(&mut std::io::Read::take(src, missing as u64), buf)?;
    Ok(got < missing)
}

/// The header in `buf`: its 1-based line number and (start, end) of its text without the line end; `None` when no
/// line is complete yet (or, at the end of the input, none is non-blank).
fn find_header(buf: &[u8], eof: bool) -> Option<(usize, (usize, usize))> {
    let mut start = 0;
    let mut line = 1;
    while start < buf.len() {
        let (end, complete) = match buf
            .get(start..)
            .and_then(|r| r.iter().position(|&c| c == b'\n'))
        {
            Some(i) => (start + i, true),
            None => (buf.len(), eof),
        };
        if !complete {
            return None;
        }
        let text = buf.get(start..end).unwrap_or(&[]);
        if !text.iter().all(u8::is_ascii_whitespace) {
            let trimmed = text.strip_suffix(b"\r").map_or(end, |t| start + t.len());
            return Some((line, (start, trimmed)));
        }
        start = end + 1;
        line += 1;
    }
    None
}

/// What the parser needs to know of the header.
struct Layout<'a> {
    target_of: &'a [Option<usize>],
    names: &'a [&'a str],
}

/// Parses whole lines `region` (whose first line follows file line `line_before`) in parallel pieces, writing
/// their rows into `targets` from row `base` on (lengthening them if needed); returns the file line number of its
/// last line and the rows written. Pushes onto `blanks` the row (of the recording) after every empty line.
fn parse_region(
    region: &[u8],
    line_before: usize,
    layout: &Layout,
    targets: &mut [Vec<f64>],
    base: usize,
    blanks: &mut Vec<usize>,
) -> Result<(usize, usize), CsvError> {
    let parts = (rayon::current_num_threads() * 4).max(1);
    let mut pieces: Vec<&[u8]> = Vec::with_capacity(parts + 1);
    let mut rest = region;
    while !rest.is_empty() {
        let target = (region.len() / parts).max(1 << 16).min(rest.len());
        let cut = rest
            .get(target..)
            .and_then(|r| memchr::memchr(b'\n', r))
            .map_or(rest.len(), |i| target + i + 1);
        let (piece, tail) = rest.split_at(cut);
        pieces.push(piece);
        rest = tail;
    }
    // Line ends per piece (in parallel): the first line number of every piece, and room for its rows.
    let newlines: Vec<usize> = pieces.par_iter().map(|p| count_newlines(p)).collect();
    let mut first_lines = Vec::with_capacity(pieces.len());
    let mut row_start = Vec::with_capacity(pieces.len() + 1);
    let (mut line_no, mut rows) = (line_before, 0usize);
    for (piece, &nl) in pieces.iter().zip(&newlines) {
        first_lines.push(line_no);
        row_start.push(rows);
        rows += nl + usize::from(!piece.ends_with(b"\n"));
        line_no += nl;
    }
    row_start.push(rows);
    // Every piece writes its rows straight into its own slices of the columns, found by file column.
    let mut by_target: Vec<Vec<Option<&mut [f64]>>> = (0..pieces.len())
        .map(|_| Vec::with_capacity(targets.len()))
        .collect();
    for target in targets.iter_mut() {
        if target.len() < base + rows {
            target.resize(base + rows, 0.0);
        }
        let mut rest: &mut [f64] = target.get_mut(base..base + rows).unwrap_or_default();
        for (view, w) in by_target.iter_mut().zip(row_start.windows(2)) {
            let (mine, tail) = rest.split_at_mut(w[1] - w[0]);
            view.push(Some(mine));
            rest = tail;
        }
    }
    let mut views: Vec<Vec<Option<&mut [f64]>>> = by_target
        .into_iter()
        .map(|mut slices| {
            layout
                .target_of
                .iter()
                .map(|t| t.and_then(|t| slices.get_mut(t).and_then(Option::take)))
                .collect()
        })
        .collect();
    let written: Vec<Result<(usize, Vec<usize>), CsvError>> = pieces
        .par_iter()
        .zip(views.par_iter_mut())
        .zip(first_lines.par_iter())
        .map(|((piece, view), &first)| {
            let mut empty = Vec::new();
            parse_chunk(piece, first, layout.names, view, &mut empty).map(|n| (n, empty))
        })
        .collect();
    drop(views);
    // Pieces with empty lines wrote fewer rows than they had room for: close the gaps.
    let mut counts = Vec::with_capacity(written.len());
    for w in written {
        let (n, empty) = w?;
        let before = base + counts.iter().sum::<usize>();
        blanks.extend(empty.into_iter().map(|r| before + r));
        counts.push(n);
    }
    let total: usize = counts.iter().sum();
    if total != rows {
        for target in targets.iter_mut() {
            let mut to = base;
            for (w, &c) in row_start.windows(2).zip(&counts) {
                target.copy_within(base + w[0]..base + w[0] + c, to);
                to += c;
            }
        }
    }
    Ok((line_no, total))
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
        let mid = d.len() / 2;
        // The middle element of the sorted differences, found in linear time.
        d.select_nth_unstable_by(mid, f64::total_cmp);
        d.get(mid).copied().filter(|&x| x > 0.0)
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
    /// The text is read in blocks of [`BLOCK_BYTES`] cut at line ends; each block is cut into pieces parsed in
    /// parallel straight into their rows of the columns, while the next block is read. Only the header and
    /// cells the fast path refuses need to be UTF-8 (a cell that is not gets a positioned error), so the body is
    /// never validated or copied as a whole, and memory holds one block and the columns.
    pub fn parse_from(
        src: impl std::io::Read + Send,
        size_hint: u64,
        name: &str,
    ) -> Result<(Recording, Vec<String>), CsvError> {
        Self::parse_blocks(src, size_hint, name, BLOCK_BYTES)
    }

    /// [`Self::parse_from`] with blocks of `block` bytes.
    fn parse_blocks(
        mut src: impl std::io::Read + Send,
        size_hint: u64,
        name: &str,
        block: usize,
    ) -> Result<(Recording, Vec<String>), CsvError> {
        let block = block.max(1);
        let io = |source| CsvError::Io {
            path: name.to_string(),
            source,
        };
        let mut cur = Vec::new();
        let mut eof = fill(&mut src, &mut cur, block.max(UTF8_BOM.len())).map_err(io)?;
        // A byte-order mark (spreadsheet programs write one) is not part of the first column's name.
        if cur.starts_with(&UTF8_BOM) {
            cur.drain(..UTF8_BOM.len());
        }
        // The header: the first line that is not blank, complete in the buffer.
        let (header_line, header_end) = loop {
            match find_header(&cur, eof) {
                Some(found) => break found,
                None if !eof => {
                    let want = 2 * cur.len();
                    eof = fill(&mut src, &mut cur, want).map_err(io)?;
                }
                None => {
                    return Err(CsvError::Header {
                        line: 1,
                        what: "the file is empty".into(),
                    });
                }
            }
        };
        let (line_start, line_end) = header_end;
        let header =
            std::str::from_utf8(cur.get(line_start..line_end).unwrap_or(&[])).map_err(|_| {
                CsvError::Header {
                    line: header_line,
                    what: "not UTF-8 text".into(),
                }
            })?;
        let names: Vec<String> = header.split(',').map(|n| n.trim().to_string()).collect();
        let names: Vec<&str> = names.iter().map(String::as_str).collect();
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
                    return Err(CsvError::Header {
                        line: header_line,
                        what: format!("column '{name}' appears twice"),
                    });
                }
                _ => match parse_column_name(name) {
                    Some((kind, group, axis)) => {
                        if columns
                            .iter()
                            .any(|c| c.kind == kind && c.group == group && c.axis == axis)
                        {
                            return Err(CsvError::Header {
                                line: header_line,
                                what: format!("column '{name}' appears twice"),
                            });
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
            return Err(CsvError::Header {
                line: header_line,
                what: match other {
                    Some(c) => format!(
                        "no 't' column (time in seconds): the columns must be separated by commas, found {c:?}"
                    ),
                    None => "no 't' column (time in seconds)".into(),
                },
            });
        }
        if columns.is_empty() {
            return Err(CsvError::Header {
                line: header_line,
                what: "no sensor columns (gSSx … aSSz)".into(),
            });
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
        let layout = Layout {
            target_of: &target_of,
            names: &names,
        };
        let n_targets = 1 + usize::from(has_temp) + columns.len();
        let mut targets: Vec<Vec<f64>> = vec![Vec::new(); n_targets];
        // The header line ends at `line_end` (before any "\r\n"); the body starts after its '\n'.
        let mut body_start = cur
            .get(line_end..)
            .and_then(|r| r.iter().position(|&c| c == b'\n'))
            .map_or(cur.len(), |i| line_end + i + 1);
        let mut line_no = header_line;
        let mut next = Vec::new();
        let mut first = true;
        // The row after every empty line of the body (for the line of a row).
        let mut blanks = Vec::new();
        // Rows parsed so far (the columns may be longer: room reserved ahead).
        let mut filled = 0;
        loop {
            let body = cur.get(body_start..).unwrap_or(&[]);
            // Whole lines only, unless this is the end of the text.
            let end = if eof {
                body.len()
            } else {
                match memchr::memrchr(b'\n', body) {
                    Some(i) => i + 1,
                    None => {
                        // Not one whole line in the buffer: read more.
                        let want = 2 * cur.len().max(block);
                        eof = fill(&mut src, &mut cur, want).map_err(io)?;
                        continue;
                    }
                }
            };
            let (region, rest) = body.split_at(end);
            if first {
                // Room for all rows, estimated from the bytes per line of the first MiB.
                first = false;
                let sample = region.get(..region.len().min(1 << 20)).unwrap_or(region);
                let lines = count_newlines(sample).max(1);
                let rows =
                    (size_hint as f64 * lines as f64 / sample.len().max(1) as f64 * 1.01) as usize;
                // Zeroed allocations are fresh pages, faulted in (in parallel) by the parsers' first writes.
                for t in &mut targets {
                    *t = vec![0.0; rows];
                }
            }
            next.clear();
            next.extend_from_slice(rest);
            let (parsed, read) = rayon::join(
                || parse_region(region, line_no, &layout, &mut targets, filled, &mut blanks),
                || {
                    if eof {
                        Ok(true)
                    } else {
                        fill(&mut src, &mut next, block)
                    }
                },
            );
            let (last_line, rows) = parsed?;
            line_no = last_line;
            filled += rows;
            if eof {
                break;
            }
            eof = read.map_err(io)?;
            std::mem::swap(&mut cur, &mut next);
            body_start = 0;
        }
        for t in &mut targets {
            t.truncate(filled);
        }
        if filled == 0 {
            return Err(CsvError::Header {
                line: header_line,
                what: "no samples: no data row after the header".into(),
            });
        }
        // File line of row r: the header, the rows and empty lines before it.
        let line_of = |r: usize| header_line + 1 + r + blanks.partition_point(|&b| b <= r);
        let column_of = |n: &str| names.iter().position(|x| *x == n).map_or(0, |i| i + 1);
        let time = targets.first().map_or(&[][..], Vec::as_slice);
        check_time(time, &line_of, column_of("t"), &mut warnings)?;
        if let Some(temp) = targets.get(1).filter(|_| has_temp) {
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

    /// The reader (whichever compiled version of it this processor runs) gives every cell exactly the standard
    /// library's value: cells as we write them, in shortest round-trip form, and a few the fast path refuses.
    #[test]
    fn reader_values_are_the_standard_librarys() {
        let mut s = 0x2545_F491_4F6C_DD1Du64;
        let mut cells: Vec<String> = Vec::new();
        for i in 0..30_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let v = ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 10f64.powi((s % 9) as i32 - 4);
            let mut c = String::new();
            match i % 4 {
                0 | 1 => push_value(&mut c, v),
                2 => c = format!("{v}"),
                _ => c = format!("{v:e}"),
            }
            cells.push(c);
        }
        let mut text = String::from("t,g00x,g00y,g00z\n");
        for (row, c) in cells.chunks_exact(3).enumerate() {
            text.push_str(&format!("{row},{},{},{}\n", c[0], c[1], c[2]));
        }
        let (rec, _) = Recording::parse(&text).unwrap();
        let got = ["g00x", "g00y", "g00z"].map(|n| &rec.column(n).unwrap().data);
        for (row, c) in cells.chunks_exact(3).enumerate() {
            for (k, cell) in c.iter().enumerate() {
                assert_eq!(
                    got[k][row].to_bits(),
                    cell.parse::<f64>().unwrap().to_bits(),
                    "{cell}"
                );
            }
        }
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

    /// Reading in blocks of any size, from a source that returns short reads, gives the same recording and the same
    /// error positions as parsing the whole text.
    #[test]
    fn any_block_size_gives_the_same_result() {
        struct Trickle<'a>(&'a [u8], usize);
        impl std::io::Read for Trickle<'_> {
            fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
                self.1 = self.1 % 5 + 1;
                let n = self.1.min(buf.len()).min(self.0.len());
                buf[..n].copy_from_slice(&self.0[..n]);
                self.0 = &self.0[n..];
                Ok(n)
            }
        }
        let mut text = String::from("\n \nt,temp_c,g00x,a00z,zz\r\n");
        for i in 0..300 {
            text.push_str(&format!(
                "{},{},-0.{:09},{}.5,x\n",
                i,
                20 + i % 3,
                i * 7919,
                i
            ));
            if i % 37 == 0 {
                text.push_str("\r\n\n");
            }
        }
        text.push_str("300,21,1,2,y");
        let whole = Recording::parse(&text).unwrap();
        assert_eq!(whole.0.len(), 301);
        let bad = text.replacen("\n150,", "\n150x,", 1);
        let want = Recording::parse(&bad).unwrap_err().to_string();
        assert!(want.starts_with("line 164, column 1 (t)"), "{want}");
        for block in [1, 2, 7, 64, 65, 200, 1 << 20] {
            let got = Recording::parse_blocks(Trickle(text.as_bytes(), 0), 0, "t", block).unwrap();
            assert_eq!(got, whole, "block {block}");
            let e = Recording::parse_blocks(Trickle(bad.as_bytes(), 0), 9, "t", block).unwrap_err();
            assert_eq!(e.to_string(), want, "block {block}");
        }
    }

    /// The eight-digits-at-a-time path (32 bytes from the cell on) and the digit-at-a-time path (near the
    /// end of the text) give the same value and end for every kind of cell.
    #[test]
    fn swar_and_scalar_number_paths_agree() {
        let mut cases: Vec<String> = [
            "0",
            "-0",
            "7",
            "-1.5",
            "0.028390270",
            "-0.000833333",
            "1234567",
            "12345678",
            "0.12345678",
            "0.123456789",
            "1.1234567890123456",
            "1.123456789012345",
            "-9.999999999",
            "5.",
            ".5",
            "-",
            ".",
            "",
            "1e-3",
            "9007199254740993",
            "900719925474099.3",
            "12.34.5",
            "0x1",
        ]
        .iter()
        .map(|c| c.to_string())
        .collect();
        let mut s = 0x9E37_79B9_7F4A_7C15u64;
        for _ in 0..20_000 {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            let (int, frac) = ((s % 100_000_000).to_string(), (s >> 27).to_string());
            let (ni, nf) = ((s >> 40) as usize % 9, (s >> 44) as usize % 18);
            let sign = if s >> 63 == 1 { "-" } else { "" };
            cases.push(format!(
                "{sign}{}.{}",
                &int[..ni.min(int.len())],
                &frac[..nf.min(frac.len())]
            ));
        }
        for c in &cases {
            for tail in [",", "\n", "\r\n", ",,", "x", "/", ":"] {
                let short = format!("{c}{tail}");
                let long = format!("{short}{}", "0123456789:/-. ,".repeat(2));
                let (a, b) = (
                    fast_number(short.as_bytes(), 0),
                    fast_number(long.as_bytes(), 0),
                );
                assert_eq!(
                    a.map(|(v, e)| (v.to_bits(), e)),
                    b.map(|(v, e)| (v.to_bits(), e)),
                    "{short:?}"
                );
                if let Some((v, e)) = b {
                    assert_eq!(Some(v), c[..e].parse::<f64>().ok(), "{c}");
                }
            }
        }
    }

    proptest::proptest! {
        #![proptest_config(proptest::prelude::ProptestConfig::with_cases(2000))]
        /// Random edits of a valid file (and random bytes) give a recording or a positioned error, never a panic.
        #[test]
        fn mangled_files_never_panic(edits in proptest::collection::vec((0usize..400, proptest::prelude::any::<u8>()), 0..12),
                                     junk in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200),
                                     block in 1usize..80) {
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
            // Raw bytes (not UTF-8 either), whole and in small blocks: the same recording or the same error.
            for b in [&bytes, &junk] {
                let show = |r: Result<(Recording, Vec<String>), CsvError>| match r {
                    Ok(v) => format!("{v:?}"),
                    Err(e) => e.to_string(),
                };
                let whole = show(Recording::parse_blocks(&b[..], b.len() as u64, "p", BLOCK_BYTES));
                let small = show(Recording::parse_blocks(&b[..], 7, "p", block));
                proptest::prop_assert_eq!(whole, small);
            }
        }
    }

    #[test]
    fn header_errors_give_the_header_line() {
        let e = Recording::parse("\n \nt,g00x,g00x\n0,1,2\n")
            .unwrap_err()
            .to_string();
        assert_eq!(e, "line 3 (header): column 'g00x' appears twice");
        let e = Recording::parse("\n\n").unwrap_err().to_string();
        assert_eq!(e, "line 1 (header): the file is empty");
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
