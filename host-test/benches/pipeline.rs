//! Throughput of the flight core on the host: link bytes → frames → calibration → fusion → 102 Allan channels →
//! averaged telemetry, i.e. `Pipeline::push_link` + `poll` over a realistic noisy frame stream.

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use host_test::replay::host_pipeline;
use shared::calib::{CalibrationTable, board};
use shared::pipeline::PipelineConfig;
use shared::wire::FrameRepr;
use shared::wire::frame::{GROUPS, RAW_PER_GROUP};
use std::hint::black_box;

/// `n` frames of the nominal board at rest with ±20 counts of noise on every channel (deterministic).
pub fn frames(n: usize) -> Vec<u8> {
    let codes = board::nominal_codes([0.0; 3], [0.0, 0.0, -1.0]);
    let mut s = 0x1234_5678_9abc_def0u64;
    let mut out = Vec::with_capacity(n * 240);
    for i in 0..n {
        let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
        for g in raw.iter_mut() {
            for (c, x) in g.iter_mut().zip(&codes) {
                s ^= s << 13;
                s ^= s >> 7;
                s ^= s << 17;
                *c = (*x as i64 + (s % 41) as i64 - 20) as u16;
            }
        }
        out.extend_from_slice(
            &FrameRepr {
                seq: i as u16,
                decimation: 15,
                temp_cdeg: Some(2000),
                raw,
            }
            .to_bytes(),
        );
    }
    out
}

fn bench(c: &mut Criterion) {
    const N: usize = 20_000;
    let bytes = frames(N);
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
