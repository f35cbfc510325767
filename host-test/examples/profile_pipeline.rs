//! Runs the flight core over 20 000 synthetic frames (for profilers: `valgrind --tool=callgrind`).
//! `profile_pipeline N [paper]`: N frames; `paper` = the seed paper's processing (equal weights, no exclusion).
use host_test::replay::{host_pipeline, synthetic_frames};
use shared::calib::CalibrationTable;
use shared::pipeline::PipelineConfig;

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|a| a.parse().ok())
        .unwrap_or(20_000);
    let mut config = PipelineConfig::DEFAULT;
    if std::env::args().nth(2).as_deref() == Some("paper") {
        config.fusion.mode = shared::fuse::FusionMode::Equal;
        config.fusion.robust = false;
    }
    let bytes = synthetic_frames(n);
    let mut p = host_pipeline(config, CalibrationTable::factory());
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
