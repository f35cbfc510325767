//! Cluster effects (common modes, blocks, unequal parts, thermal drift, outliers), chunking and the raw frames.

use super::*;

fn white_cluster(seed: u64, samples: u64, n: f64) -> SimConfig {
    let mut cfg = SimConfig::new(seed, 10.0, samples, [NoiseParams::white(n); CHANNELS]);
    cfg.accel_g = [0.0; 3];
    cfg
}

#[test]
fn common_mode_gives_the_correlated_cluster_gain() {
    let rho = 0.2;
    let n_samples = 1 << 16;
    let mut cfg = white_cluster(11, n_samples, 0.01);
    cfg.common.push(CommonMode::all(&[Axis::AccelX], rho, 0.0));
    let mut sim = Simulator::new(cfg).unwrap();
    let groups: Vec<usize> = (0..GROUPS).collect();
    let sel: Vec<_> = groups.iter().map(|&g| (g, Channel::AccelX)).collect();
    let x = sim.collect_readings(&sel).unwrap();
    let single_var: f64 = x.iter().map(|v| std_dev(v).powi(2)).sum::<f64>() / GROUPS as f64;
    let mean: Vec<f64> = (0..x[0].len())
        .map(|k| x.iter().map(|v| v[k]).sum::<f64>() / GROUPS as f64)
        .collect();
    let gain = (single_var / std_dev(&mean).powi(2)).sqrt();
    let want = (16.0 / (1.0 + 15.0 * rho)).sqrt();
    let tol = 3.0 / (2.0 * n_samples as f64).sqrt();
    println!(
        "common mode ρ = {rho}: gain {gain:.4}, expected {want:.4} (±{:.4})",
        tol * want
    );
    assert!((gain / want - 1.0).abs() < tol, "gain {gain} vs {want}");
    // The analytic expectation of the simulator agrees.
    let dt = sim.sampling().dt_s;
    let e_mean = sim
        .expected_mean_avar(Channel::AccelX, &groups, dt)
        .unwrap();
    let e_one = sim.expected_mean_avar(Channel::AccelX, &[0], dt).unwrap();
    assert!(((e_one / e_mean).sqrt() / want - 1.0).abs() < 1e-12);
    // Another axis is not affected.
    let mut sim2 = Simulator::new(sim.config().clone()).unwrap();
    let y = sim2
        .collect_readings(&[(0, Channel::AccelY), (1, Channel::AccelY)])
        .unwrap();
    let c = corr(&y[0], &y[1]);
    assert!(
        c.abs() < 3.0 / (n_samples as f64).sqrt(),
        "AccelY correlated: {c}"
    );
}

fn corr(a: &[f64], b: &[f64]) -> f64 {
    let n = a.len() as f64;
    let (ma, mb) = (a.iter().sum::<f64>() / n, b.iter().sum::<f64>() / n);
    let cov: f64 = a.iter().zip(b).map(|(x, y)| (x - ma) * (y - mb)).sum();
    let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
    let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
    cov / (va * vb).sqrt()
}

#[test]
fn block_common_mode_correlates_only_its_groups_and_both_z() {
    let n_samples = 1 << 15;
    let mut cfg = white_cluster(12, n_samples, 0.01);
    cfg.common.push(CommonMode::block(
        "left half",
        &[0, 1, 2, 3, 4, 5, 6, 7],
        &[Axis::GyroZ],
        0.5,
        0.0,
    ));
    cfg.spread = PartSpread::unequal_noise(0.3); // correlation stays ρ with unequal levels
    let mut sim = Simulator::new(cfg).unwrap();
    let x = sim
        .collect_readings(&[
            (0, Channel::GyroAZ),
            (0, Channel::GyroBZ),
            (7, Channel::GyroAZ),
            (8, Channel::GyroAZ),
            (9, Channel::GyroBZ),
        ])
        .unwrap();
    let tol = 3.0 / (n_samples as f64).sqrt();
    for (i, j, want) in [
        (0, 1, 0.5),
        (0, 2, 0.5),
        (1, 2, 0.5),
        (0, 3, 0.0),
        (3, 4, 0.0),
    ] {
        let c = corr(&x[i], &x[j]);
        assert!(
            (c - want).abs() < tol,
            "pair {i},{j}: correlation {c}, want {want}"
        );
    }
}

#[test]
fn unequal_noise_gives_the_equal_weight_loss() {
    let s = 0.4;
    let n_samples = 1 << 16;
    let mut cfg = white_cluster(13, n_samples, 0.01);
    cfg.spread = PartSpread::unequal_noise(s);
    let mut sim = Simulator::new(cfg).unwrap();
    let dt = sim.sampling().dt_s;
    let sigma2: Vec<f64> = (0..GROUPS)
        .map(|g| sim.sensor_params(g, Channel::GyroAX).unwrap().white.powi(2) / dt)
        .collect();
    let var_eq = sigma2.iter().sum::<f64>() / (GROUPS * GROUPS) as f64;
    let var_ivw = 1.0 / sigma2.iter().map(|v| 1.0 / v).sum::<f64>();
    let loss = (var_eq / var_ivw).sqrt();
    let groups: Vec<usize> = (0..GROUPS).collect();
    assert!(
        (sim.expected_mean_avar(Channel::GyroAX, &groups, dt)
            .unwrap()
            / var_eq
            - 1.0)
            .abs()
            < 1e-12
    );
    let sel: Vec<_> = groups.iter().map(|&g| (g, Channel::GyroAX)).collect();
    let x = sim.collect_readings(&sel).unwrap();
    let eq: Vec<f64> = (0..n_samples as usize)
        .map(|k| x.iter().map(|v| v[k]).sum::<f64>() / GROUPS as f64)
        .collect();
    let w: Vec<f64> = sigma2.iter().map(|v| var_ivw / v).collect();
    let ivw: Vec<f64> = (0..n_samples as usize)
        .map(|k| x.iter().zip(&w).map(|(v, w)| w * v[k]).sum())
        .collect();
    let measured = std_dev(&eq) / std_dev(&ivw);
    let tol = 3.0 / (n_samples as f64).sqrt();
    println!(
        "unequal noise, log-sd {s}: equal-weight loss {measured:.4}, expected {loss:.4} from the realised levels \
         (≈ e^(2s²) = {:.4} for many parts); median single σ / equal-weight mean σ = {:.3} (√16 = 4)",
        (2.0 * s * s).exp(),
        {
            let mut v = sigma2.clone();
            v.sort_by(f64::total_cmp);
            (0.5 * (v[7] + v[8]) / var_eq).sqrt()
        }
    );
    assert!(
        (measured / loss - 1.0).abs() < tol,
        "loss {measured} vs {loss}"
    );
    assert!((std_dev(&eq).powi(2) / var_eq - 1.0).abs() < 2.0 * tol);
}

#[test]
fn same_seed_same_output_whatever_the_chunking() {
    let mut cfg = seed_config(99).unwrap();
    cfg.samples = 3000;
    cfg.cal = CalSpread::typical();
    cfg.common.push(CommonMode::all(&Axis::ALL, 0.1, 0.2));
    cfg.drift.push(CommonDrift {
        groups: None,
        axes: vec![Axis::GyroY],
        kind: DriftKind::RandomWalk { k: 1e-3 },
    });
    cfg.thermal = Some(Thermal {
        drift_c_per_h: 0.5,
        coef: [0.01; 6],
        coef_sd: [0.002; 6],
        ..Thermal::sine(25.0, 2.0, 600.0)
    });
    cfg.spread = PartSpread {
        level_ln: 0.2,
        white_ln: 0.1,
        flicker_ln: 0.1,
        rrw_ln: 0.1,
    };
    let run = |cfg: SimConfig| {
        let mut sim = Simulator::new(cfg).unwrap();
        let mut chunk = Chunk::default();
        let (mut phys, mut codes, mut temp) = (Vec::new(), Vec::new(), Vec::new());
        while sim.next_chunk(&mut chunk) > 0 {
            phys.extend_from_slice(&chunk.phys);
            codes.extend_from_slice(&chunk.codes);
            temp.extend_from_slice(&chunk.temp_c);
        }
        (phys, codes, temp)
    };
    let a = run(cfg.clone());
    let mut c2 = cfg.clone();
    c2.chunk_len = 777;
    let b = run(c2);
    assert_eq!(a.0.len(), 3000);
    assert!(a == b, "chunking changed the output");
    let mut c3 = cfg.clone();
    c3.seed = 100;
    let c = run(c3);
    assert!(a.0 != c.0 && a.1 != c.1);
    assert_eq!(run(cfg).0, a.0);
    // A sensor of the cluster is the single-sensor generator with the cluster's stream.
    let mut cfg = seed_config(1).unwrap();
    cfg.samples = 3000;
    let p = cfg.sensor[Channel::GyroBY.index()];
    let mut sim = Simulator::new(cfg).unwrap();
    let x = sim.collect_readings(&[(0, Channel::GyroBY)]).unwrap();
    let mut g = SensorNoise::new(
        &p,
        sim.sampling(),
        subseed(1, 100 + Channel::GyroBY.index() as u64),
    )
    .unwrap();
    let mut y = vec![0.0; 3000];
    g.fill(&mut y);
    assert_eq!(x[0], y);
}

#[test]
fn raw_frames_round_trip_through_the_nominal_calibration() {
    let mut cfg = seed_config(5).unwrap();
    cfg.samples = 2000;
    cfg.chunk_len = 512;
    cfg.cal = CalSpread::typical();
    cfg.rate_dps = [10.0, -20.0, 5.0];
    cfg.accel_g = [0.1, -0.2, 0.97];
    cfg.frames = FrameOpts {
        decimation: 7,
        seq_start: 65_000,
    };
    cfg.thermal = Some(Thermal {
        phase_rad: 0.3,
        ..Thermal::sine(21.0, 1.0, 100.0)
    });
    // Round the physical output only where the ADC does: none here, so `phys` is the unquantised ideal output.
    for p in &mut cfg.sensor {
        p.rate_step = 0.0;
    }
    let mut sim = Simulator::new(cfg).unwrap();
    let cals: Vec<_> = sim
        .true_cal()
        .iter()
        .map(|c| c.to_group_cal().unwrap())
        .collect();
    let mut chunk = Chunk::default();
    let (mut worst, mut k_all) = (0.0f64, 0u64);
    while sim.next_chunk(&mut chunk) > 0 {
        for i in 0..chunk.len {
            let frame = chunk.frame(i).unwrap();
            assert_eq!(frame.seq, 65_000u16.wrapping_add(k_all as u16));
            assert_eq!(frame.decimation, 7);
            assert_eq!(
                frame.temp_cdeg,
                Some((chunk.temp_c[i] * 100.0).round() as i16)
            );
            let parsed = shared::wire::FrameRepr::parse_bytes(&frame.to_bytes()).unwrap();
            assert_eq!(parsed, frame);
            for (g, cal) in cals.iter().enumerate() {
                let raw = RawCounts::from_adc(&parsed.raw[g]);
                assert!(
                    parsed.raw[g].iter().all(|&c| c > 0 && c < u16::MAX),
                    "saturated codes"
                );
                let out = cal.apply(&raw);
                let CalMatrices {
                    gyro: mg,
                    gyro_zero: bg,
                    accel: ma,
                    accel_zero: ba,
                } = sim.true_cal()[g].matrices();
                for a in 0..6 {
                    // bound: ½ count through |M| (ADC rounding) + Q12 rounding of M and b + final ½ LSB
                    let (row, d): (Vec<f64>, Vec<f64>) = if a < 3 {
                        (
                            mg[a].to_vec(),
                            (0..4).map(|c| f64::from(raw.gyro[c]) - bg[c]).collect(),
                        )
                    } else {
                        (
                            ma[a - 3].to_vec(),
                            (0..3).map(|c| f64::from(raw.accel[c]) - ba[c]).collect(),
                        )
                    };
                    let q = 1.0 / 8192.0;
                    let bound = row
                        .iter()
                        .zip(&d)
                        .map(|(m, d)| (0.5 + q) * m.abs() * 1e6 + q * d.abs())
                        .sum::<f64>()
                        + 0.5;
                    let err = f64::from(out[a]) - chunk.phys[i][g][a] * 1e6;
                    assert!(
                        err.abs() <= bound,
                        "group {g} axis {a}: error {err} µ > bound {bound}"
                    );
                    worst = worst.max(err.abs() / bound);
                }
            }
            k_all += 1;
        }
    }
    println!("raw round trip: worst error / bound = {worst:.3}");
    // The matrices invert the true chain exactly (no quantisation).
    for tc in sim.true_cal() {
        let (w, f) = ([3.0, -7.0, 11.0], [0.3, -0.1, 0.9]);
        let codes = tc.codes_f64(&tc.readings(w, f));
        let CalMatrices {
            gyro: mg,
            gyro_zero: bg,
            accel: ma,
            accel_zero: ba,
        } = tc.matrices();
        for i in 0..3 {
            let gw: f64 = (0..4).map(|c| mg[i][c] * (codes[c] - bg[c])).sum();
            let af: f64 = (0..3).map(|c| ma[i][c] * (codes[4 + c] - ba[c])).sum();
            assert!((gw - w[i]).abs() < 1e-9 && (af - f[i]).abs() < 1e-12);
        }
    }
}

#[test]
fn nominal_group_physical_is_the_natural_output() {
    // Nominal calibration: gyro z is the mean of the two z channels, codes are nominal_codes.
    let tc = TrueGroupCal::nominal();
    let r = [0.1, 0.2, 0.3, 0.5, 0.01, 0.02, 1.0];
    let p = tc.physical(&r);
    let want = [0.1, 0.3, 0.35, 0.01, 0.02, 1.0];
    assert!(
        p.iter().zip(want).all(|(a, b)| (a - b).abs() < 1e-12),
        "{p:?}"
    );
    let nom = shared::calib::board::nominal_codes([0.1, 0.3, 0.2], [0.01, 0.02, 1.0]);
    assert!(
        (tc.codes_f64(&r)[0] - nom[0]).abs() < 1e-9 && (tc.codes_f64(&r)[1] - nom[1]).abs() < 1e-9
    );
    assert_eq!(tc.to_group_cal().unwrap(), shared::calib::board::NOMINAL);
}

#[test]
fn thermal_drift_and_outlier_effects_are_as_configured() {
    let mut cfg = SimConfig::new(3, 10.0, 1000, [NoiseParams::default(); CHANNELS]);
    cfg.accel_g = [0.0; 3];
    cfg.thermal = Some(Thermal {
        drift_c_per_h: 36.0,
        coef: [0.02, 0.0, 0.0, 1e-3, 0.0, 0.0],
        coef_sd: [0.005, 0.0, 0.0, 0.0, 0.0, 0.0],
        ..Thermal::sine(20.0, 3.0, 50.0)
    });
    cfg.outliers.push(Outlier {
        group: 4,
        channel: Channel::AccelY,
        noise_factor: 1.0,
        step: 0.01,
        step_at_s: 50.0,
        drift_per_h: 3.6,
    });
    cfg.drift.push(CommonDrift {
        groups: Some(vec![1, 2]),
        axes: vec![Axis::AccelZ],
        kind: DriftKind::RandomWalk { k: 1e-3 },
    });
    let mut sim = Simulator::new(cfg).unwrap();
    let kappa = sim.thermal_coef(6, Channel::GyroAX).unwrap();
    assert!(kappa != 0.02 && (kappa - 0.02).abs() < 0.05);
    let x = sim
        .collect_readings(&[
            (6, Channel::GyroAX),
            (3, Channel::AccelX),
            (4, Channel::AccelY),
            (1, Channel::AccelZ),
            (2, Channel::AccelZ),
            (3, Channel::AccelZ),
        ])
        .unwrap();
    for k in [0usize, 137, 999] {
        let t = k as f64 / 10.0;
        let temp = 20.0 + 3.0 * (2.0 * std::f64::consts::PI * t / 50.0).sin() + 0.01 * t;
        assert!((x[0][k] - kappa * (temp - 20.0)).abs() < 1e-12);
        assert!((x[1][k] - 1e-3 * (temp - 20.0)).abs() < 1e-12);
        let want = 1e-3 * t + if t >= 50.0 { 0.01 } else { 0.0 };
        assert!(
            (x[2][k] - want).abs() < 1e-12,
            "outlier at {t}: {} vs {want}",
            x[2][k]
        );
    }
    assert_eq!(x[3], x[4]);
    assert!(x[3].iter().any(|&v| v != 0.0) && x[5].iter().all(|&v| v == 0.0));
}
