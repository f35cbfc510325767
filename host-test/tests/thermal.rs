//! Issue 27 end to end (`host_test::thermal_check`, quick form: 4.725 Hz, 8 frames per report, i.e. the issue's
//! 1.69 s report interval and τ grid with a quarter of the frames): the thermal fit against the simulator's true
//! coefficients, and the fused Allan deviation of an orbit record with and without the fitted table against an
//! isothermal record of the same board; plus the fit's refusal of a record spanning < 10 °C.

use host_test::calibrate::{CalibError, ThermalOptions, fit_thermal};
use host_test::formats::framelog::FrameLog;
use host_test::sim::{
    Axis, Chunk, Effects, NoiseParams, SimConfig, Simulator, TemperatureProfile, ThermalCoef,
};
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
    Effects {
        thermal: vec![ThermalCoef {
            axes: Axis::ALL[..3].to_vec(),
            coef: 0.05,
            sd: 0.0,
        }],
        temperature: Some(TemperatureProfile::Orbit {
            mean_c: 20.0,
            amp_c: 4.9,
            period_min: 1.0,
        }),
        ..Effects::default()
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

/// `ground calibrate --from-model`'s path: the ramp record of the same board, calibrated with the factory table,
/// diagnosed (`diagnose` + `twin::fit`, as `ground diagnose --model`), and the model turned into table terms
/// (`calibrate::from_model`). The terms' drift of each calibrated axis, `M·d`, against the simulator's true raw
/// coefficients through the same matrix.
#[test]
fn a_model_fitted_by_the_diagnosis_gives_the_boards_thermal_terms() {
    use host_test::calibrate::{CalibrationFile, from_model};
    use host_test::load::{Calibration, load_with};
    use host_test::sim::Channel;
    use shared::calib::CalibrationTable;
    let o = ThermalCheckOptions::QUICK;
    let ramp = TemperatureProfile::Ramp {
        from_c: -10.0,
        to_c: 50.0,
        hours: 3.0,
    };
    let cfg = host_test::thermal_check::config(&o, o.ramp_seed, o.ramp_hours, ramp).unwrap();
    let (bytes, sim) = host_test::thermal_check::frames(cfg).unwrap();
    let dir = std::env::temp_dir().join(format!("from-model-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("ramp.bin");
    std::fs::write(&path, &bytes).unwrap();
    drop(bytes);
    let factory = CalibrationTable::<16>::factory();
    let cal = Calibration::Board(Box::new(factory));
    let rec = load_with(
        &path,
        Some(&cal),
        shared::wire::clock::FPGA_BASE_RATE_MILLIHZ,
    )
    .unwrap()
    .recording;
    std::fs::remove_dir_all(&dir).ok();
    let report = host_test::diagnose::diagnose(&rec, &Default::default()).unwrap();
    let model = host_test::twin::fit(&rec, &report, "ramp").unwrap();
    let base = CalibrationFile::from_table(&factory);
    let r = from_model(&model, &base, None).unwrap();
    assert_eq!(r.thermal_sensors, 96);
    let th = r.file.thermal.as_ref().unwrap();
    // Per axis (gx gy gz ax ay az): the largest error over the 16 groups and the mean true drift.
    let mut worst = [0f64; 6];
    let mut mean = [0f64; 6];
    for (g, (cal, t)) in base.groups.iter().zip(th).enumerate() {
        let k = Channel::ALL.map(|ch| sim.thermal_coef_counts(g, ch).unwrap());
        for a in 0..3 {
            let row = &cal.gyro_matrix_dps_per_count[a];
            let dot = |d: &[f64]| row.iter().zip(d).map(|(m, x)| m * x).sum::<f64>();
            let (truth, est) = (dot(&k[..4]), dot(&t.gyro_lin_counts_per_c));
            worst[a] = worst[a].max((est - truth).abs());
            mean[a] += truth / 16.0;
            let row = &cal.accel_matrix_g_per_count[a];
            let dot = |d: &[f64]| row.iter().zip(d).map(|(m, x)| m * x).sum::<f64>();
            let (truth, est) = (dot(&k[4..]), dot(&t.accel_lin_counts_per_c));
            worst[3 + a] = worst[3 + a].max((est - truth).abs());
            mean[3 + a] += truth / 16.0;
        }
    }
    for a in 0..6 {
        println!(
            "axis {a}: largest error {:.3e} against a mean drift of {:.3e} per °C ({:.1} %)",
            worst[a],
            mean[a],
            100.0 * worst[a] / mean[a].abs()
        );
        // Measured: 2.4–3.7 % on the gyro axes, 1.5–8.2 % on the accelerometer's (accel y the largest, as in the
        // direct fit: its slow bias noise looks most like a temperature law; the diagnosis fits on the ramp's first
        // half, 30 °C).
        assert!(worst[a] < 0.12 * mean[a].abs(), "axis {a}");
    }
}
