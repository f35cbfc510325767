//! `ground allan`'s computation on paper-size data: one column of 545,410 samples (the seed's 8-hour record at
//! 18.9 Hz), octave OADEV with noise identification, Greenhall EDF and confidence intervals. The whole tool on
//! 102 such columns is timed side by side with allantools by `host-test/scripts/bench_allan.sh`.

use criterion::{Criterion, criterion_group, criterion_main};
use host_test::allan::{Analyzer, DevKind, Options, TauSpec};
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    let n = 545_410;
    let mut s = 42u64;
    let y: Vec<f64> = (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        })
        .collect();
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
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
