//! The CSV reader against the `csv` crate, like for like (issue 29): the same file, the same 16-MiB blocks read
//! while the previous one is parsed, the same pieces of each block parsed under rayon on the same threads into the
//! same columns; only each piece's field splitting and number conversion differ: the reader's own (`parse_chunk`:
//! separator bitmasks, SWAR digits, Clinger's fast path) or the `csv` crate (`ByteRecord`, no quoting) with
//! `fast-float2`, cells neither takes going through the reader's own positioned error path in both. Checks that the
//! two give the same `Recording` (every value bit for bit) and the same warnings.
//!
//! `cargo run --release -p host-test --example csv_crate_blocks -- F.csv [RUNS] [ours|crate]`: with a mode, one read
//! of that kind (for timing whole processes side by side); without, RUNS pairs alternating in one process (default
//! 5), each timed, then the medians and the ratio. `RAYON_NUM_THREADS` sets the threads of both.
use host_test::formats::csv::{CsvError, PieceParser, Recording, general_cell, parse_chunk};

/// One piece (whole lines; the first follows file line `first_line`) through the `csv` crate, with the contract of
/// the reader's own piece parser: values into `out[column][row]` (`None` for ignored columns), the row after every
/// empty line pushed onto `blanks`, errors with the file line.
fn crate_piece(
    b: &[u8],
    first_line: usize,
    names: &[&str],
    out: &mut [Option<&mut [f64]>],
    blanks: &mut Vec<usize>,
) -> Result<usize, CsvError> {
    let ncols = out.len();
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(false)
        .flexible(true)
        .quoting(false)
        .from_reader(b);
    let mut record = csv::ByteRecord::new();
    let (mut row, mut next_line) = (0usize, 1u64);
    loop {
        let more = reader
            .read_byte_record(&mut record)
            .map_err(|e| CsvError::Header {
                line: first_line,
                what: e.to_string(),
            })?;
        if !more {
            break;
        }
        // The crate skips empty lines: they are the gap in its line numbers.
        let line = record.position().map_or(next_line, csv::Position::line);
        for _ in next_line..line {
            blanks.push(row);
        }
        let file_line = first_line + line as usize;
        for (col, cell) in record.iter().enumerate() {
            if let Some(Some(column)) = out.get_mut(col) {
                let value = match fast_float2::parse::<f64, _>(cell) {
                    Ok(v) if v.is_finite() => v,
                    _ => general_cell(cell, file_line, col, names)?,
                };
                if let Some(slot) = column.get_mut(row) {
                    *slot = value;
                }
            }
        }
        if record.len() != ncols {
            return Err(CsvError::Width {
                line: file_line,
                expected: ncols,
                found: record.len(),
            });
        }
        row += 1;
        next_line = line + 1;
    }
    // Empty lines at the end of the piece.
    let lines =
        memchr::memchr_iter(b'\n', b).count() + usize::from(b.last().is_some_and(|&c| c != b'\n'));
    for _ in next_line..=lines as u64 {
        blanks.push(row);
    }
    Ok(row)
}

fn read(path: &str, crate_fields: bool) -> Result<(Recording, Vec<String>), CsvError> {
    let io = |source| CsvError::Io {
        path: path.into(),
        source,
    };
    let file = std::fs::File::open(path).map_err(io)?;
    let size = file.metadata().map_or(0, |m| m.len());
    let piece: PieceParser = if crate_fields {
        crate_piece
    } else {
        parse_chunk
    };
    Recording::parse_from_with(file, size, path, piece)
}

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn same(a: &(Recording, Vec<String>), b: &(Recording, Vec<String>)) -> bool {
    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
    let (ra, rb) = (&a.0, &b.0);
    a.1 == b.1
        && bits(&ra.t_s) == bits(&rb.t_s)
        && ra.temp_c.as_deref().map(bits) == rb.temp_c.as_deref().map(bits)
        && ra.columns.len() == rb.columns.len()
        && ra.columns.iter().zip(&rb.columns).all(|(x, y)| {
            (x.group, x.kind, x.axis) == (y.group, y.kind, y.axis) && bits(&x.data) == bits(&y.data)
        })
}

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .unwrap_or_else(|| "target/bench/seed8h.csv".into());
    let runs: usize = args.next().and_then(|r| r.parse().ok()).unwrap_or(5);
    if let Some(mode) = args.next() {
        let t = std::time::Instant::now();
        match read(&path, mode == "crate") {
            Ok((rec, _)) => println!(
                "{mode}: {} rows in {:.3} s",
                rec.len(),
                t.elapsed().as_secs_f64()
            ),
            Err(e) => println!("{e}"),
        }
        return;
    }
    println!("{} rayon threads", rayon::current_num_threads());
    let (mut ours, mut theirs) = (Vec::new(), Vec::new());
    let mut ratios = Vec::new();
    for run in 0..=runs {
        let t = std::time::Instant::now();
        let a = read(&path, false);
        let ta = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let b = read(&path, true);
        let tb = t.elapsed().as_secs_f64();
        let equal = match (&a, &b) {
            (Ok(a), Ok(b)) => same(a, b),
            (Err(a), Err(b)) => a.to_string() == b.to_string(),
            _ => false,
        };
        let rows = a.as_ref().map_or(0, |r| r.0.len());
        println!(
            "{}: ours {ta:.3} s, csv crate {tb:.3} s ({rows} rows), same Recording and warnings: {equal}",
            if run == 0 { "warm-up" } else { "pair" }
        );
        if run > 0 {
            ours.push(ta);
            theirs.push(tb);
            ratios.push(tb / ta);
        }
    }
    println!(
        "medians over {runs} pairs: ours {:.3} s, csv crate {:.3} s; csv crate / ours pair by pair {:.2} ({:.2}–{:.2})",
        median(ours),
        median(theirs),
        median(ratios.clone()),
        ratios.iter().copied().fold(f64::INFINITY, f64::min),
        ratios.iter().copied().fold(0.0, f64::max),
    );
}
