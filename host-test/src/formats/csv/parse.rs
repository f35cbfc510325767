//! The fast reader behind [`Recording::parse_from`]: the file in blocks, each block's lines parsed in parallel
//! pieces, plain decimals by an exact fast path eight digits at a time, every other cell by [`parse_f64`].

use super::*;

/// Number of `\n` in `b` (line ends are sparse in our files: memchr skips 16–32 bytes per step).
pub(super) fn count_newlines(b: &[u8]) -> usize {
    memchr::memchr_iter(b'\n', b).count()
}

pub(super) const POW10: [f64; 23] = [
    1e0, 1e1, 1e2, 1e3, 1e4, 1e5, 1e6, 1e7, 1e8, 1e9, 1e10, 1e11, 1e12, 1e13, 1e14, 1e15, 1e16,
    1e17, 1e18, 1e19, 1e20, 1e21, 1e22,
];

/// Appends the decimal digits at `b[*p..]` to `mant` (wrapping; callers check the count), advancing `p`; returns
/// how many there were.
#[inline]
pub(super) fn digits(b: &[u8], p: &mut usize, mant: &mut u64) -> usize {
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
pub(super) fn fast_number(b: &[u8], p: usize) -> Option<(f64, usize)> {
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
pub(super) const POW10_U64: [u64; 9] = [
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
pub(super) fn swar_digits(word: u64) -> (usize, u64) {
    pub(super) const ZEROS: u64 = 0x3030_3030_3030_3030;
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
pub(super) fn word_in(w: &[u8; 32], i: usize) -> u64 {
    let i = i.min(24);
    w.get(i..i + 8)
        .and_then(|s| s.try_into().ok())
        .map_or(0, u64::from_le_bytes)
}

/// The digits of `[digits][.digits]` from `w[q..]` (q = 1 after a sign, else 0) eight at a time: (mantissa,
/// integer digits, decimals, bytes from `w[0]` to the end), or `None` where a part has 8 or more (integer) / 16 or
/// more (decimal) digits.
#[inline(always)]
pub(super) fn swar_number(w: &[u8; 32], q: usize) -> Option<(u64, usize, usize, usize)> {
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
pub(super) fn byte_mask(block: &[u8; 64], a: u8, b: u8) -> u64 {
    pub(super) const PACK: u64 = 0x0102_0408_1020_4080;
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
pub fn parse_chunk(
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
pub fn general_cell(cell: &[u8], line: usize, col: usize, names: &[&str]) -> Result<f64, CsvError> {
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
pub(super) fn fill<R: std::io::Read>(
    src: &mut R,
    buf: &mut Vec<u8>,
    want: usize,
) -> std::io::Result<bool> {
    let missing = want.saturating_sub(buf.len());
    let got = std::io::Read::read_to_end(&mut std::io::Read::take(src, missing as u64), buf)?;
    Ok(got < missing)
}

/// The header in `buf`: its 1-based line number and (start, end) of its text without the line end; `None` when no
/// line is complete yet (or, at the end of the input, none is non-blank).
pub(super) fn find_header(buf: &[u8], eof: bool) -> Option<(usize, (usize, usize))> {
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
pub(super) struct Layout<'a> {
    pub(super) target_of: &'a [Option<usize>],
    pub(super) names: &'a [&'a str],
    /// The parser of one piece ([`parse_chunk`], or another for a comparison).
    pub(super) piece: PieceParser,
}

/// The parser of one piece of whole lines (see [`parse_chunk`], the reader's own, for the contract); a parameter
/// only for the like-for-like comparison with the `csv` crate (`examples/csv_crate_blocks.rs`).
pub type PieceParser = fn(
    &[u8],
    usize,
    &[&str],
    &mut [Option<&mut [f64]>],
    &mut Vec<usize>,
) -> Result<usize, CsvError>;

/// Parses whole lines `region` (whose first line follows file line `line_before`) in parallel pieces, writing
/// their rows into `targets` from row `base` on (lengthening them if needed); returns the file line number of its
/// last line and the rows written. Pushes onto `blanks` the row (of the recording) after every empty line.
pub(super) fn parse_region(
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
            (layout.piece)(piece, first, layout.names, view, &mut empty).map(|n| (n, empty))
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
