//! Bad parameters, the interchange CSV, the seed presets and the pinned output.

use super::*;

/// A change that sets the cluster's flicker band (the bad-parameter cases).
fn band(
    tau_min_s: f64,
    tau_max_s: f64,
    per_decade: f64,
    method: FlickerMethod,
) -> Box<dyn Fn(&mut SimConfig)> {
    Box::new(move |c| {
        c.flicker_band = Some(FlickerBand {
            tau_min_s,
            tau_max_s,
            per_decade,
            method,
        })
    })
}

#[test]
fn bad_parameters_are_errors_not_panics() {
    let ok = seed_config(1).unwrap();
    type Edit = Box<dyn Fn(&mut SimConfig)>;
    let bad: Vec<Edit> = vec![
        Box::new(|c| c.rate_hz = 0.0),
        Box::new(|c| c.rate_hz = f64::NAN),
        Box::new(|c| c.samples = 0),
        Box::new(|c| c.chunk_len = 0),
        Box::new(|c| c.sensor[0].white = -1.0),
        Box::new(|c| c.sensor[2].flicker = f64::INFINITY),
        Box::new(|c| c.sensor[3].gm_sigma = 1.0),
        Box::new(|c| c.common.push(CommonMode::all(&[Axis::GyroX], 1.5, 0.0))),
        Box::new(|c| {
            c.common.push(CommonMode::all(&[Axis::GyroX], 0.6, 0.0));
            c.common
                .push(CommonMode::block("b", &[3], &[Axis::GyroX], 0.6, 0.0));
        }),
        Box::new(|c| {
            c.common
                .push(CommonMode::block("b", &[16], &[Axis::GyroX], 0.1, 0.0))
        }),
        Box::new(|c| c.outliers.push(Outlier::noisy(20, Channel::AccelX, 2.0))),
        Box::new(|c| c.spread.level_ln = -0.1),
        Box::new(|c| c.cal.scale_sd = 5.0),
        band(1.0, 0.5, 2.0, FlickerMethod::PoleZero),
        band(1e-12, 1e12, 20.0, FlickerMethod::IndependentGm),
        band(1e-4, 1e3, 2.0, FlickerMethod::PoleZero),
        Box::new(|c| {
            c.drift.push(CommonDrift {
                groups: None,
                axes: vec![Axis::GyroX],
                kind: DriftKind::GaussMarkov {
                    sigma: 1.0,
                    tau_s: 0.0,
                },
            })
        }),
        Box::new(|c| c.thermal = Some(Thermal::sine(0.0, 1.0, 0.0))),
        Box::new(|c| c.accel_g[0] = f64::NAN),
    ];
    for (i, f) in bad.iter().enumerate() {
        let mut c = ok.clone();
        f(&mut c);
        assert!(Simulator::new(c).is_err(), "case {i} accepted");
    }
    assert!(expected_avar(&NoiseParams::white(1.0), &seed_sampling(), 0.001).is_err());
    assert!(
        TrueGroupCal::new(
            [[0.0; 3]; 4],
            [0.0; 4],
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]],
            [0.0; 3]
        )
        .is_err()
    );
    let sim = Simulator::new(ok).unwrap();
    assert!(sim.expected_mean_avar(Channel::AccelX, &[], 1.0).is_err());
    assert!(sim.sensor_params(16, Channel::AccelX).is_none());
}

#[test]
fn csv_header_names_the_interchange_columns() {
    let h = csv_header(true);
    assert!(
        h.starts_with("t,temp_c,g00x,g00y,g00z,a00x,a00y,a00z,g01x,"),
        "{h}"
    );
    assert!(h.ends_with(",a15z"));
    assert_eq!(h.split(',').count(), 2 + 16 * 6);
    assert!(csv_header(false).starts_with("t,g00x,"));
    for thermal in [false, true] {
        let mut sim = Simulator::new(seed_with_temperature(2, thermal)).unwrap();
        let mut chunk = Chunk::default();
        sim.next_chunk(&mut chunk);
        let mut row = String::new();
        chunk.write_csv_row(1, &mut row);
        let f: Vec<f64> = row
            .trim_end()
            .split(',')
            .map(|c| c.parse().unwrap())
            .collect();
        let skip = usize::from(thermal);
        assert_eq!(f.len(), csv_header(thermal).split(',').count());
        assert_eq!(f[0], 1.0 / SEED_RATE_HZ);
        // Values are written with 9 decimals (formats::csv::VALUE_DECIMALS).
        if thermal {
            assert!(
                (f[1] - chunk.temp_c[1]).abs() <= 0.5e-9,
                "{} vs {}",
                f[1],
                chunk.temp_c[1]
            );
        }
        assert!((f[1 + skip + 5] - chunk.phys[1][0][5]).abs() <= 0.5e-9);
    }
}

#[test]
fn seed_presets_reproduce_the_single_sensor_tables() {
    let s = seed_sampling();
    let params = seed_sensor_params(DEFAULT_FLICKER_SHARE).unwrap();
    let duration = SEED_SAMPLES as f64 / SEED_RATE_HZ;
    println!("seed preset (flicker share {DEFAULT_FLICKER_SHARE}), units °/s or g:");
    let mut all_z = Vec::new();
    for ch in Channel::ALL {
        let p = &params[ch.index()];
        let t = &SEED_TARGETS[ch.axis().index()];
        let model = NoiseModel::new(p, &s).unwrap();
        // Expected (analytic).
        let rms = model.expected_avar(s.dt_s).sqrt();
        let (tau_min, adev_min) = model.min_adev(s.dt_s, duration / 2.0);
        assert!((rms / t.rms - 1.0).abs() < 1e-9, "{ch:?} rms {rms}");
        assert!(
            (adev_min / t.adev_min - 1.0).abs() < 1e-6,
            "{ch:?} min {adev_min}"
        );
        let oct_min = (0..20)
            .map(|k| {
                (
                    s.dt_s * 2f64.powi(k),
                    model.expected_avar(s.dt_s * 2f64.powi(k)).sqrt(),
                )
            })
            .fold((0.0, f64::MAX), |a, b| if b.1 < a.1 { b } else { a });
        // One simulated 8-hour run: group 0 of the seed experiment `seed_config(1)` (the same streams; without
        // the +1 g input of accelerometer z).
        let x = SensorNoise::series(
            p,
            &s,
            SEED_SAMPLES as usize,
            subseed(1, 100 + ch.index() as u64),
        )
        .unwrap();
        let sd = std_dev(&x);
        let oct = octave_avar(&x);
        let (m_min, avar_min, _) = oct
            .iter()
            .filter(|o| o.2 >= 8)
            .fold((0, f64::MAX, 0), |a, &b| if b.1 < a.1 { b } else { a });
        println!(
            "  {ch:?}: N = {:.4e} u/√Hz, B = {:.4e} u, K = {:.4e} u/√s, step = {:.4e} u | target rms {:.4e}, min {:.4e} \
             | expected rms {rms:.4e}, min {adev_min:.4e} at τ = {tau_min:.0} s (octave min {:.4e} at {:.0} s) \
             | simulated rms {sd:.4e}, octave min {:.4e} at {:.0} s",
            p.white,
            p.flicker,
            p.rrw,
            p.rate_step,
            t.rms,
            t.adev_min,
            oct_min.1,
            oct_min.0,
            avar_min.sqrt(),
            m_min as f64 * s.dt_s
        );
        assert!(
            (sd / t.rms - 1.0).abs() < 0.01,
            "{ch:?}: simulated rms {sd}"
        );
        all_z.extend(assert_adev(&format!("{ch:?} 8 h"), &x, &model, 8));
    }
    let chi = all_z.iter().map(|z| z * z).sum::<f64>() / all_z.len() as f64;
    println!(
        "seed runs: {} octaves, mean z² = {chi:.3}, max |z| = {:.2}",
        all_z.len(),
        all_z.iter().fold(0.0f64, |a, z| a.max(z.abs()))
    );
}

/// Timing of the seed experiment: `cargo test --release -- --ignored --nocapture seed_experiment_timing`.
#[test]
#[ignore]
fn seed_experiment_timing() {
    let cfg = seed_config(1).unwrap();
    let t0 = std::time::Instant::now();
    let mut sim = Simulator::new(cfg).unwrap();
    let t_setup = t0.elapsed();
    let mut chunk = Chunk::default();
    let (mut n, mut check) = (0u64, 0.0);
    let mut bytes = 0usize;
    while sim.next_chunk(&mut chunk) > 0 {
        n += chunk.len as u64;
        check += chunk.phys[0][0][0];
        for i in 0..chunk.len {
            bytes += chunk.frame(i).map_or(0, |f| f.to_bytes().len());
        }
    }
    let el = t0.elapsed();
    println!(
        "seed experiment: {n} samples × 112 channels, setup {t_setup:?}, total {el:?} incl. frame encoding ({bytes} B) [{check}]"
    );
}
/// The seed experiment's first `samples` samples, with a temperature column (a 1 °C, 60 s sine that moves no
/// sensor) when `thermal`.
fn seed_with_temperature(samples: u64, thermal: bool) -> SimConfig {
    let mut cfg = seed_config(1).unwrap();
    cfg.samples = samples;
    if thermal {
        cfg.thermal = Some(Thermal::sine(20.0, 1.0, 60.0));
    }
    cfg
}

#[test]
fn csv_parses_with_the_project_reader() {
    for thermal in [false, true] {
        let mut sim = Simulator::new(seed_with_temperature(50, thermal)).unwrap();
        let mut chunk = Chunk::default();
        let mut text = csv_header(thermal) + "\n";
        let mut first = None;
        while sim.next_chunk(&mut chunk) > 0 {
            for i in 0..chunk.len {
                chunk.write_csv_row(i, &mut text);
            }
            first.get_or_insert(chunk.phys[3][2][4]);
        }
        let (rec, warn) = crate::formats::csv::Recording::parse(&text).unwrap();
        assert!(warn.is_empty());
        assert_eq!(rec.t_s.len(), 50);
        assert_eq!(rec.temp_c.is_some(), thermal);
        assert_eq!(rec.columns.len(), 96);
        println!("parsed ok, thermal={thermal}");
    }
}

/// The simulator's output for a configuration with every per-sensor ingredient (part spread, overrides, outliers,
/// common modes over all and over some groups, a drift, thermal terms, calibration spread) is pinned by a hash of
/// its bits: a restructuring of [`Simulator::new`] must leave it unchanged (issue 29).
#[test]
fn simulator_output_is_pinned() {
    let mut cfg = seed_config(5).unwrap();
    cfg.samples = 1500;
    cfg.cal = CalSpread::typical();
    cfg.common.push(CommonMode::all(&Axis::ALL, 0.1, 0.2));
    let mut block = CommonMode::all(&[Axis::GyroX, Axis::AccelZ], 0.3, 0.0);
    block.groups = Some(vec![0, 3, 7]);
    cfg.common.push(block);
    cfg.drift.push(CommonDrift {
        groups: Some(vec![2, 5]),
        axes: vec![Axis::GyroY, Axis::AccelX],
        kind: DriftKind::RandomWalk { k: 1e-3 },
    });
    cfg.thermal = Some(Thermal {
        phase_rad: 0.3,
        drift_c_per_h: 0.5,
        coef: [0.01, 0.02, 0.0, 1e-3, 0.0, 2e-3],
        coef_sd: [0.002; 6],
        ..Thermal::sine(25.0, 2.0, 60.0)
    });
    cfg.spread = PartSpread {
        level_ln: 0.2,
        white_ln: 0.1,
        flicker_ln: 0.15,
        rrw_ln: 0.1,
    };
    cfg.overrides.push(SensorOverride {
        group: 4,
        channel: Channel::GyroAX,
        params: NoiseParams::white(0.05),
    });
    cfg.outliers.push(Outlier {
        group: 9,
        channel: Channel::AccelY,
        noise_factor: 3.0,
        step: 0.01,
        step_at_s: 20.0,
        drift_per_h: 3.6,
    });
    let mut sim = Simulator::new(cfg).unwrap();
    let mut chunk = Chunk::default();
    // FNV-1a over the physical outputs' bits, the ADC codes and the temperatures.
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    let mut eat = |x: u64| {
        for b in x.to_le_bytes() {
            hash = (hash ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3);
        }
    };
    while sim.next_chunk(&mut chunk) > 0 {
        chunk
            .phys
            .iter()
            .flatten()
            .flatten()
            .for_each(|v| eat(v.to_bits()));
        chunk
            .codes
            .iter()
            .flatten()
            .flatten()
            .for_each(|&c| eat(u64::from(c)));
        chunk.temp_c.iter().for_each(|v| eat(v.to_bits()));
    }
    assert_eq!(
        hash, 0x4689_1c6e_4e28_5194,
        "simulator output hash {hash:#x}"
    );
}
