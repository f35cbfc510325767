//! `ground replay --check` (`replay::replay` with `check`): the flight core against the independent f64 model, with
//! the calibration table's thermal terms and fixed weights in force, over frames whose temperature moves and is
//! sometimes missing.

use host_test::replay::{ReplayOptions, replay};
use shared::bench::BenchFrames;
use shared::calib::{AXES, CalibrationTable};
use shared::fuse::FusionMode;
use shared::pipeline::PipelineConfig;
use shared::telemetry::Telemetry;
use shared::wire::frame::GROUPS;

/// 4096 frames of the bench stream with the temperature ramping from 5 °C to 45 °C, invalid on every 7th frame.
fn frames() -> Vec<u8> {
    let mut bench = BenchFrames::new();
    (0..4096)
        .flat_map(|i| {
            let mut f = bench.next_frame();
            f.temp_cdeg = (i % 7 != 3).then_some(500 + (i * 4000 / 4096) as i16);
            f.to_bytes()
        })
        .collect()
}

/// Thermal terms of LPY410AL size (±8 counts/°C, a quadratic term) differing per channel, and uneven weights.
fn table() -> CalibrationTable<GROUPS> {
    let mut t = CalibrationTable::<GROUPS>::factory();
    t.cal_id = 9;
    t.t_ref_cdeg = 2_000;
    for (g, th) in t.thermal.iter_mut().enumerate() {
        let s = if g % 2 == 0 { 1.0 } else { -1.0 };
        th.gyro_lin_q28 = [0.08, 0.05, -0.03, 0.07].map(|c| (s * c * 2f64.powi(28)) as i32);
        th.gyro_quad_q40 = [1e-6, -2e-6, 0.0, 3e-6].map(|c| (c * 2f64.powi(40)) as i32);
        th.accel_lin_q28 = [0.002, -0.004, 0.001].map(|c| (s * c * 2f64.powi(28)) as i32);
    }
    for (g, w) in t.weights_q16.iter_mut().enumerate() {
        *w = [(g as i32 + 1) * 3000; AXES];
    }
    t
}

fn run(cal: CalibrationTable<GROUPS>) -> host_test::replay::ReplayOutput {
    let opts = ReplayOptions {
        config: PipelineConfig::DEFAULT,
        cal,
        bus: shared::bus::BusConfig::DEFAULT,
        final_dump: false,
        check: true,
    };
    replay(&frames(), &opts, |_| {})
}

#[test]
fn the_core_matches_the_f64_model_with_thermal_terms_and_fixed_weights() {
    let out = run(table());
    let check = out.check.expect("asked for");
    assert_eq!(check.frames, 4096);
    assert_eq!(check.reports, 128);
    println!("{check:?}");
    // Per frame: the bias rounding (≤ 2⁻¹³ count per channel, ≤ 2 · 6250/8192 µ°/s on gyro z), the calibration's
    // rounding (0.5) and the mean's (0.5): ≤ 2.6 LSB; the reports add the averaging's rounding.
    for a in 0..AXES {
        assert!(check.frame_max_lsb[a] <= 2.6, "axis {a}: {check:?}");
        assert!(check.report_max_lsb[a] <= 3.1, "axis {a}: {check:?}");
    }
    let health = out
        .messages
        .iter()
        .rev()
        .find_map(|m| match m {
            Telemetry::Health(h) => Some(*h),
            _ => None,
        })
        .expect("periodic health");
    assert_eq!(health.fusion, FusionMode::Fixed);
    assert!(health.temp.missing > 0 && health.temp.held == health.temp.missing);

    // The terms matter: without them the fused gyro x moves by the weighted thermal shift over the ramp.
    let plain = run(CalibrationTable::factory());
    let first_last = |o: &host_test::replay::ReplayOutput| {
        let f: Vec<i32> = o
            .messages
            .iter()
            .filter_map(|m| match m {
                Telemetry::Fused(r) => Some(r.rate_udps[0]),
                _ => None,
            })
            .collect();
        (f[1], f[f.len() - 1])
    };
    let (a, b) = first_last(&out);
    let (pa, pb) = first_last(&plain);
    // The bench stream has no thermal effect, so the table's terms move gyro x by their weighted mean over the ramp
    // (alternating signs over uneven weights, plus the quadratic term: here ≈ 0.09 °/s) — 10⁴ times the bound.
    assert!(((b - a) - (pb - pa)).abs() > 50_000, "{a} {b} {pa} {pb}");
}
