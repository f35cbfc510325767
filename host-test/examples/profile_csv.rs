//! Times `Recording::read` on a CSV (for profilers): `cargo run --release -p host-test --example profile_csv F.csv`.
use host_test::formats::csv::Recording;

fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "target/bench/seed8h.csv".into());
    if std::env::var("ANCHOR").is_ok() {
        anchor(&path);
    }
    for _ in 0..3 {
        let t = std::time::Instant::now();
        match Recording::read(path.as_ref()) {
            Ok((rec, _)) => println!(
                "{} rows × {} columns in {:.3} s",
                rec.len(),
                rec.columns.len(),
                t.elapsed().as_secs_f64()
            ),
            Err(e) => println!("{e}"),
        }
    }
}

#[allow(dead_code)]
fn anchor(path: &str) {
    let bytes = std::fs::read(path).unwrap();
    let t = std::time::Instant::now();
    let mut sum = 0u64;
    for &b in &bytes {
        sum = sum.wrapping_add(u64::from(b));
    }
    println!("byte sum {sum} in {:.3} s", t.elapsed().as_secs_f64());
    let text = std::str::from_utf8(&bytes).unwrap();
    let t = std::time::Instant::now();
    let mut s = 0.0;
    let mut n = 0;
    for line in text.lines().skip(1) {
        for c in line.split(',') {
            s += c.parse::<f64>().unwrap_or(0.0);
            n += 1;
        }
    }
    println!(
        "std parse {n} cells sum {s} in {:.3} s",
        t.elapsed().as_secs_f64()
    );
}
