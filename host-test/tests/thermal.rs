//! Issue 27 end to end (`host_test::thermal_check`, quick form: 4.725 Hz, 8 frames per report, i.e. the issue's
//! 1.69 s report interval and τ grid with a quarter of the frames): the thermal fit against the simulator's true
//! coefficients, and the fused Allan deviation of an orbit record with and without the fitted table against an
//! isothermal record of the same board; plus the fit's refusal of a record spanning < 10 °C.

use host_test::calibrate::{CalibError, ThermalOptions, fit_thermal};
use host_test::formats::framelog::FrameLog;
use host_test::sim::{Chunk, NoiseParams, SimConfig, Simulator};
use host_test::simcli::{EffectArgs, parse_temperature};
use host_test::thermal_check::{ThermalCheckOptions, run};

#[test]
fn thermal_compensation_end_to_end() {
    let r = run(&ThermalCheckOptions::QUICK).unwrap();
    print!("{}", r.report());
    // Fit: errors against the true coefficients in units of the fit's own standard errors.
    let rms = |z: &[f64]| (z.iter().map(|x| x * x).sum::<f64>() / z.len() as f64).sqrt();
    let beyond3 = r.lin_z.iter().filter(|z| z.abs() > 3.0).count();
    assert_eq!(r.lin_z.len(), 112);
    assert!(rms(&r.lin_z) < 2.0, "RMS z {}", rms(&r.lin_z));
    assert!(beyond3 <= 8, "{beyond3} of 112 beyond 3 SE");
    for (channel, f) in r.fit.iter().enumerate() {
        // Within 6 % of the mean coefficient of the channel type (≈ 2–10 counts/°C; measured: ≤ 2.6 % on the gyro
        // channels, 5.1 % on accel y, whose slow bias noise over a 3-h ramp looks most like a temperature law).
        assert!(
            f.max_lin_err_counts_per_c < 0.06 * f.mean_true_lin_counts_per_c.abs(),
            "raw channel {channel}: {} against a mean of {}",
            f.max_lin_err_counts_per_c,
            f.mean_true_lin_counts_per_c
        );
    }
    // Allan: every octave τ ≥ 100 s with at least 2 τ-intervals.
    assert!(r.taus_s.len() >= 6 && r.taus_s[0] >= 100.0);
    let (w, wo) = (r.with_ratio(), r.without_ratio());
    for a in 0..6 {
        for (i, tau) in r.taus_s.iter().enumerate() {
            assert!(
                w[a][i] < 1.5 && w[a][i] > 1.0 / 1.5,
                "axis {a} τ {tau}: {}",
                w[a][i]
            );
            // Measured: ≥ 5 everywhere except accel y at 108 s (≈ 4: its noise is the largest of the six).
            let floor = if *tau < 200.0 { 3.5 } else { 5.0 };
            assert!(wo[a][i] >= floor, "axis {a} τ {tau}: {}", wo[a][i]);
        }
    }
}

#[test]
fn a_record_spanning_less_than_10_c_is_refused() {
    let mut cfg = SimConfig::new(1, 18.9, 2000, [NoiseParams::white(0.01); 7]);
    EffectArgs {
        thermal: vec!["gyro:0.05".into()],
        temperature: Some(parse_temperature("orbit:mean_c=20,amp_c=4.9,period_min=1").unwrap()),
        ..EffectArgs::default()
    }
    .apply(&mut cfg)
    .unwrap();
    let mut sim = Simulator::new(cfg).unwrap();
    let mut bytes = Vec::new();
    let mut chunk = Chunk::default();
    while sim.next_chunk(&mut chunk) > 0 {
        bytes.extend((0..chunk.len).flat_map(|i| chunk.frame(i).unwrap().to_bytes()));
    }
    let log = FrameLog::decode(&bytes);
    let e = fit_thermal(&log.frames, &ThermalOptions::default(), "x").unwrap_err();
    assert!(matches!(e, CalibError::TemperatureSpan { .. }), "{e}");
    let msg = e.to_string();
    assert!(
        msg.contains("spans 9.80 °C") && msg.contains("at least 10 °C"),
        "{msg}"
    );
    // No temperature at all.
    let mut frames = log.frames.clone();
    frames.iter_mut().for_each(|d| d.frame.temp_cdeg = None);
    let e = fit_thermal(&frames, &ThermalOptions::default(), "x").unwrap_err();
    assert!(
        matches!(e, CalibError::NoTemperature { frames: 2000 }),
        "{e}"
    );
}
