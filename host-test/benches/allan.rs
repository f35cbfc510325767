//! `ground allan`'s computation on paper-size data: one column of 545,410 samples (the seed's 8-hour record at
//! 18.9 Hz), octave OADEV with noise identification, Greenhall EDF and confidence intervals. The whole tool on
//! 102 such columns is timed side by side with allantools by `host-test/scripts/bench_allan.sh`. Also the CSV reader
//! on 20,000 rows of the interchange format with 16 groups (as `ground simulate` writes them).

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use host_test::allan::acov::AllanCov;
use host_test::allan::{Analyzer, DevKind, Options, TauSpec};
use host_test::formats::csv::{Recording, push_value};
use host_test::testrng::TestRng;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let n = 545_410;
    let mut rng = TestRng::new(42);
    let y: Vec<f64> = (0..n).map(|_| rng.uniform() - 0.5).collect();
    let mut g = c.benchmark_group("allan");
    g.sample_size(20);
    let mut an = Analyzer::new();
    g.bench_function("octave OADEV + noise id + EDF + CI, 545410 samples", |b| {
        b.iter(|| {
            black_box(an.analyze(
                DevKind::Oadev,
                &y,
                1.0 / 18.9,
                &TauSpec::Octave,
                &Options::default(),
            ))
        })
    });
    // The diagnosis's cross covariances: 16 sensors, one half of the seed record.
    let half: Vec<Vec<f64>> = (0..16)
        .map(|_| (0..n / 2).map(|_| rng.uniform() - 0.5).collect())
        .collect();
    let refs: Vec<&[f64]> = half.iter().map(Vec::as_slice).collect();
    g.bench_function("Allan covariance, 16 series × 272705 samples", |b| {
        b.iter(|| black_box(AllanCov::compute(&refs, 1.0 / 18.9, 30)))
    });
    g.finish();

    // The reader: t + 96 sensor columns with the writer's 9 decimals.
    let mut text = String::from("t");
    for grp in 0..16 {
        for kind in ["g", "a"] {
            for axis in ["x", "y", "z"] {
                text.push_str(&format!(",{kind}{grp:02}{axis}"));
            }
        }
    }
    text.push('\n');
    for row in 0..20_000 {
        text.push_str(&(row as f64 / 18.9).to_string());
        for _ in 0..96 {
            text.push(',');
            push_value(&mut text, rng.uniform() - 0.5);
        }
        text.push('\n');
    }
    let mut g = c.benchmark_group("csv");
    g.sample_size(20);
    g.throughput(Throughput::Bytes(text.len() as u64));
    g.bench_function("read 20000 rows × 97 columns", |b| {
        b.iter(|| black_box(Recording::parse(&text).map(|r| r.0.len())))
    });
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
