//! Throughput of the flight core on the host: link bytes → frames → calibration → fusion → 102 Allan channels →
//! averaged telemetry, i.e. `Pipeline::push_link` + `poll` over a realistic noisy frame stream.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use host_test::replay::{host_pipeline, synthetic_frames};
use shared::calib::CalibrationTable;
use shared::pipeline::PipelineConfig;
use std::hint::black_box;

fn bench(c: &mut Criterion) {
    const N: usize = 20_000;
    let bytes = synthetic_frames(N);
    let mut g = c.benchmark_group("pipeline");
    g.throughput(Throughput::Elements(N as u64));
    g.sample_size(20);
    for (name, config) in [
        ("default (weighted, robust)", PipelineConfig::DEFAULT),
        ("equal mean, no exclusion", {
            let mut c = PipelineConfig::DEFAULT;
            c.fusion.mode = shared::fuse::FusionMode::Equal;
            c.fusion.robust = false;
            c
        }),
    ] {
        g.bench_function(name, |b| {
            b.iter_batched_ref(
                || host_pipeline(config, CalibrationTable::factory()),
                |p| {
                    let mut input = &bytes[..];
                    while !input.is_empty() {
                        p.push_link(&mut input);
                        while let Some(o) = p.poll() {
                            black_box(o);
                        }
                    }
                },
                criterion::BatchSize::LargeInput,
            )
        });
    }
    g.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
