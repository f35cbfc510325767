//! Runs the flight core over 20 000 synthetic frames (for profilers: `valgrind --tool=callgrind`).
use host_test::replay::host_pipeline;
use shared::calib::{CalibrationTable, board};
use shared::pipeline::PipelineConfig;
use shared::wire::FrameRepr;
use shared::wire::frame::{GROUPS, RAW_PER_GROUP};

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(20_000);
    let codes = board::nominal_codes([0.0; 3], [0.0, 0.0, -1.0]);
    let mut s = 0x1234_5678_9abc_def0u64;
    let mut bytes = Vec::with_capacity(n * 240);
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
        bytes.extend_from_slice(
            &FrameRepr {
                seq: i as u16,
                decimation: 15,
                temp_cdeg: Some(2000),
                raw,
            }
            .to_bytes(),
        );
    }
    let mut p = host_pipeline(PipelineConfig::DEFAULT, CalibrationTable::factory());
    let t = std::time::Instant::now();
    let mut input = &bytes[..];
    let mut outputs = 0;
    while !input.is_empty() {
        p.push_link(&mut input);
        while p.poll().is_some() {
            outputs += 1;
        }
    }
    let dt = t.elapsed().as_secs_f64();
    println!(
        "{n} frames, {outputs} outputs, {:.0} frames/s",
        n as f64 / dt
    );
}
