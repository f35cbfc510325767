//! The interchange CSV read by the `csv` crate and `fast-float2` (one core) into columns, timed: the comparison the
//! CSV reader's module doc reports (`host_test::formats::csv`). Same file as `profile_csv`:
//! `cargo run --release -p host-test --example csv_crate_reader [F.csv]`. Checks that both readers give the same
//! numbers, bit for bit.
use host_test::formats::csv::Recording;

fn read_with_csv_crate(path: &str) -> Result<(Vec<String>, Vec<Vec<f64>>), String> {
    let mut reader = csv::ReaderBuilder::new()
        .has_headers(true)
        .from_path(path)
        .map_err(|e| e.to_string())?;
    let names: Vec<String> = reader
        .headers()
        .map_err(|e| e.to_string())?
        .iter()
        .map(str::to_owned)
        .collect();
    let mut columns = vec![Vec::new(); names.len()];
    let mut record = csv::ByteRecord::new();
    let mut line = 1;
    while reader
        .read_byte_record(&mut record)
        .map_err(|e| e.to_string())?
    {
        line += 1;
        for (column, cell) in columns.iter_mut().zip(record.iter()) {
            let value: f64 =
                fast_float2::parse(cell).map_err(|_| format!("line {line}: not a number"))?;
            column.push(value);
        }
    }
    Ok((names, columns))
}

fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "target/bench/seed8h.csv".into());
    let mut ours = None;
    for _ in 0..3 {
        let t = std::time::Instant::now();
        match Recording::read(path.as_ref()) {
            Ok((rec, _)) => {
                println!(
                    "ours: {} rows in {:.3} s",
                    rec.len(),
                    t.elapsed().as_secs_f64()
                );
                ours = Some(rec);
            }
            Err(e) => println!("{e}"),
        }
        let t = std::time::Instant::now();
        match read_with_csv_crate(&path) {
            Ok((names, columns)) => {
                println!(
                    "csv + fast-float2: {} rows × {} columns in {:.3} s",
                    columns.first().map_or(0, Vec::len),
                    names.len(),
                    t.elapsed().as_secs_f64()
                );
                if let Some(rec) = &ours {
                    let bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<_>>();
                    let same = rec.columns.iter().all(|c| {
                        names
                            .iter()
                            .position(|n| *n == c.name())
                            .is_some_and(|i| bits(&columns[i]) == bits(&c.data))
                    });
                    println!("same values, bit for bit: {same}");
                }
            }
            Err(e) => println!("{e}"),
        }
    }
}
