//! Times `Recording::read` on a CSV (for profilers): `cargo run --release -p host-test --example profile_csv F.csv`.
use host_test::formats::csv::Recording;

fn main() {
    let path = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "target/bench/seed8h.csv".into());
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
