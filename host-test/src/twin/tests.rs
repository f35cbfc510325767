use super::*;
use crate::allan::{Analyzer, DevKind, Options as AllanOptions, TauSpec};

fn terms(white: f64, flicker: f64, rw: f64) -> NoiseTerms {
    NoiseTerms {
        quantization: 0.0,
        white,
        bias_instability: flicker,
        random_walk: rw,
        ramp: 0.0,
        gauss_markov: Vec::new(),
    }
}

/// A small model: 6 groups, gyro x and accel z, a shared flicker process on 4 gyros, a thermal coefficient on the
/// accelerometers, a temperature with a drift and a 1-h sinusoid.
fn model() -> ClusterModel {
    let groups: Vec<usize> = (0..6).collect();
    let gx = AxisModel {
        axis: "gx".into(),
        unit: "deg/s".into(),
        typical: terms(0.01, 0.002, 1e-5),
        effects: vec!["common_mode".into()],
        sensors: groups
            .iter()
            .map(|&g| SensorModel {
                group: g,
                mean: 0.1 * g as f64,
                independent: NoiseTerms {
                    // A bump of its own on the last part (played after the 1-Hz pole).
                    gauss_markov: if g == 5 {
                        vec![GaussMarkov {
                            sigma: 0.01,
                            tau_s: 0.4,
                            ..Default::default()
                        }]
                    } else {
                        Vec::new()
                    },
                    ..terms(0.01, 0.001, 1e-5)
                },
                thermal_per_c: 0.0,
                sinusoids: Vec::new(),
                steps: Vec::new(),
            })
            .collect(),
        shared: vec![SharedProcess {
            kind: "common_mode".into(),
            groups: vec![0, 1, 2, 3],
            terms: NoiseTerms {
                gauss_markov: vec![GaussMarkov {
                    sigma: 0.003,
                    tau_s: 3.0,
                    ..Default::default()
                }],
                ..terms(0.0, 0.004, 0.0)
            },
            sinusoids: Vec::new(),
        }],
        bandwidth_hz: Some(1.0),
        coverage: None,
    };
    let az = AxisModel {
        axis: "az".into(),
        unit: "g".into(),
        typical: terms(1e-4, 0.0, 0.0),
        effects: vec!["thermal".into()],
        sensors: groups
            .iter()
            .map(|&g| SensorModel {
                group: g,
                mean: 1.0,
                independent: terms(1e-4, 0.0, 0.0),
                thermal_per_c: 2e-4,
                sinusoids: Vec::new(),
                steps: Vec::new(),
            })
            .collect(),
        shared: vec![],
        bandwidth_hz: None,
        coverage: None,
    };
    ClusterModel {
        format: FORMAT.into(),
        record: RecordInfo {
            source: "test".into(),
            rate_hz: 10.0,
            samples: 72_000,
            duration_s: 7200.0,
            groups: groups.clone(),
            columns: vec![],
        },
        temperature: Some(TemperatureModel {
            reference_c: 21.0,
            start_c: 20.0,
            drift_c_per_h: 1.0,
            harmonics: vec![Harmonic {
                period_s: 3600.0,
                amplitude_c: 1.5,
                phase_rad: 0.3,
            }],
            noise: NoiseTerms::default(),
        }),
        effects: vec![],
        axes: vec![gx, az],
    }
}

#[test]
fn a_model_round_trips_through_toml_and_bad_files_are_refused() {
    let m = model();
    let text = m.to_toml().unwrap();
    assert_eq!(ClusterModel::from_toml(&text, "m.toml").unwrap(), m);
    let other = text.replace(FORMAT, "imu-cluster-twin/9");
    assert!(matches!(
        ClusterModel::from_toml(&other, "m.toml"),
        Err(TwinError::Format { .. })
    ));
    let negative = text.replace("white = 0.01", "white = -0.01");
    assert!(ClusterModel::from_toml(&negative, "m.toml").is_err());
    assert!(text.contains("bandwidth_hz = 1.0"), "{text}");
    let no_band = text.replace("bandwidth_hz = 1.0", "bandwidth_hz = 0.0");
    assert!(ClusterModel::from_toml(&no_band, "m.toml").is_err());
    let mut stray = m.clone();
    stray.axes[0].shared[0].groups = vec![0, 1, 2, 9];
    let text = toml::to_string(&stray).unwrap();
    assert!(ClusterModel::from_toml(&text, "m.toml").is_err(), "{text}");
    let mut wrong_axis = m.clone();
    wrong_axis.axes[0].axis = "gw".into();
    let text = toml::to_string(&wrong_axis).unwrap();
    assert!(ClusterModel::from_toml(&text, "m.toml").is_err());
}

/// The terms and their Allan-variance coefficients are inverse; `less` subtracts in variance and stops at zero.
#[test]
fn noise_terms_convert_and_subtract_in_variance() {
    let t = NoiseTerms {
        quantization: 1e-3,
        white: 2e-2,
        bias_instability: 3e-3,
        random_walk: 4e-4,
        ramp: 5e-6,
        gauss_markov: Vec::new(),
    };
    let back = NoiseTerms::from_avar_coefficients(t.avar_coefficients());
    for (a, b) in back.avar_coefficients().iter().zip(t.avar_coefficients()) {
        assert!((a / b - 1.0).abs() < 1e-12);
    }
    // σ²(τ) from the IEEE 952 formulas, written out independently.
    let tau = 7.0;
    let expect = 3.0 * 1e-6 / (tau * tau)
        + 4e-4 / tau
        + 2.0 * 2f64.ln() / std::f64::consts::PI * 9e-6
        + 16e-8 * tau / 3.0
        + 25e-12 * tau * tau / 2.0;
    assert!((t.avar(tau, 0.1, None) / expect - 1.0).abs() < 1e-12);
    let half = NoiseTerms {
        white: 2e-2 / 2f64.sqrt(),
        ..t.clone()
    };
    let d = t.less(&half);
    assert!((d.white - 2e-2 / 2f64.sqrt()).abs() < 1e-12);
    assert_eq!(half.less(&t).white, 0.0);
}

/// The temperature fit recovers a line and a sinusoid (period, amplitude, phase) buried in white noise.
#[test]
fn temperature_fit_recovers_drift_and_period() {
    let m = model();
    let truth = m.temperature.as_ref().unwrap();
    let rate = 2.0;
    let n = 4 * 3600 * 2;
    let sampling = crate::sim::noise::Sampling::new(rate, n as f64 / rate).unwrap();
    let mut noisy = truth.clone();
    noisy.noise.white = 0.05;
    let t_s: Vec<f64> = (0..n).map(|k| k as f64 / rate).collect();
    let temp = play::temperature(&noisy, &sampling, n, 5).unwrap();
    let f = fit::fit_temperature(&t_s, &temp, 1.0 / rate);
    assert!((f.drift_c_per_h - 1.0).abs() < 0.01, "{f:?}");
    assert!((f.start_c - 20.0).abs() < 0.02, "{f:?}");
    let h = f.harmonics[0];
    assert!((h.period_s / 3600.0 - 1.0).abs() < 0.01, "{f:?}");
    assert!((h.amplitude_c - 1.5).abs() < 0.02, "{f:?}");
    assert!((h.phase_rad - 0.3).abs() < 0.03, "{f:?}");
    assert!((f.noise.white / 0.05 - 1.0).abs() < 0.1, "{f:?}");
}

/// A played sensor's Allan variance is its model's, shared processes included: the analytic σ²(τ) of the terms
/// (independent + shared for members) against the played record's, at every octave with ≥ 100 blocks (within
/// 4 σ of the estimate); the shared process makes members correlate and leaves the others alone.
#[test]
fn play_gives_the_modelled_allan_variance_and_the_shared_correlation() {
    let m = model();
    let rec = play(
        &m,
        &PlayOptions {
            seed: 3,
            ..Default::default()
        },
    )
    .unwrap();
    let gx = &m.axes[0];
    let tau0 = 0.1;
    let band = gx.low_pass(1.0 / tau0);
    let mut an = Analyzer::new();
    for c in rec.columns.iter().filter(|c| c.kind == SensorKind::Gyro) {
        let s = &gx.sensors[c.group];
        let mut expect = s.independent.clone();
        if c.group < 4 {
            let [a, b] = [
                expect.avar_coefficients(),
                gx.shared[0].terms.avar_coefficients(),
            ];
            let gm = [expect.gauss_markov, gx.shared[0].terms.gauss_markov.clone()].concat();
            expect = NoiseTerms::from_avar_coefficients([0, 1, 2, 3, 4].map(|k| a[k] + b[k]));
            expect.gauss_markov = gm;
        }
        let mean = crate::stats::mean(&c.data);
        assert!(
            (mean - s.mean).abs() < 0.01,
            "group {} mean {mean}",
            c.group
        );
        for p in an.analyze(
            DevKind::Oadev,
            &c.data,
            tau0,
            &TauSpec::Octave,
            &AllanOptions::default(),
        ) {
            if c.data.len() / p.m < 100 {
                continue;
            }
            // Through gx's 1-Hz pole: at τ₀ = 0.1 s it keeps 15 % of the white noise's Allan variance.
            let ratio = p.dev.powi(2) / expect.avar(p.tau_s, tau0, band.as_ref());
            let sd = (2.0 / p.edf.unwrap()).sqrt();
            assert!(
                (ratio - 1.0).abs() < 4.0 * sd + 0.05,
                "group {} τ {}: ratio {ratio}",
                c.group,
                p.tau_s
            );
        }
    }
    let col = |g: usize| {
        &rec.columns
            .iter()
            .find(|c| c.kind == SensorKind::Gyro && c.group == g)
            .unwrap()
            .data
    };
    let corr = |a: &[f64], b: &[f64]| {
        // Correlation of 100-s block means (where the shared flicker dominates).
        let blocks = |x: &[f64]| -> Vec<f64> { x.chunks(1000).map(crate::stats::mean).collect() };
        let (a, b) = (blocks(a), blocks(b));
        let (ma, mb) = (crate::stats::mean(&a), crate::stats::mean(&b));
        let cov: f64 = a.iter().zip(&b).map(|(x, y)| (x - ma) * (y - mb)).sum();
        let va: f64 = a.iter().map(|x| (x - ma).powi(2)).sum();
        let vb: f64 = b.iter().map(|y| (y - mb).powi(2)).sum();
        cov / (va * vb).sqrt()
    };
    assert!(corr(col(0), col(1)) > 0.5, "members share the process");
    assert!(corr(col(4), col(5)).abs() < 0.4, "non-members do not");
    // Thermal: the accelerometers follow the temperature with their coefficient.
    let az = rec
        .columns
        .iter()
        .find(|c| c.kind == SensorKind::Accel && c.axis == 2)
        .unwrap();
    let t = rec.temp_c.as_ref().unwrap();
    let beta = slope(t, &az.data);
    assert!((beta / 2e-4 - 1.0).abs() < 0.05, "β {beta}");
    // Without effects: no temperature in the sensors, the typical terms everywhere.
    let plain = play(
        &m,
        &PlayOptions {
            seed: 3,
            without_effects: true,
            ..Default::default()
        },
    )
    .unwrap();
    let az = plain
        .columns
        .iter()
        .find(|c| c.kind == SensorKind::Accel && c.axis == 2)
        .unwrap();
    let beta = slope(t, &az.data);
    assert!(beta.abs() < 2e-5, "β without effects {beta}");
}

/// The regression coefficient of `x` on `t`.
fn slope(t: &[f64], x: &[f64]) -> f64 {
    let (mt, mx) = (crate::stats::mean(t), crate::stats::mean(x));
    t.iter()
        .zip(x)
        .map(|(t, x)| (t - mt) * (x - mx))
        .sum::<f64>()
        / t.iter().map(|t| (t - mt).powi(2)).sum::<f64>()
}

/// Two records of one model (different seeds) are not told apart; a record with twice the white noise on one axis
/// is, on that axis only.
#[test]
fn compare_tells_a_different_cluster_from_a_fresh_record() {
    let mut m = model();
    m.axes[1]
        .sensors
        .iter_mut()
        .for_each(|s| s.thermal_per_c = 0.0);
    let a = play(
        &m,
        &PlayOptions {
            seed: 1,
            ..Default::default()
        },
    )
    .unwrap();
    let b = play(
        &m,
        &PlayOptions {
            seed: 2,
            ..Default::default()
        },
    )
    .unwrap();
    let same = compare(&a, &b, &CompareOptions::default()).unwrap();
    assert!(same.significant_axes.is_empty(), "{}", same.summary());
    let mut louder = m.clone();
    louder.axes[1]
        .sensors
        .iter_mut()
        .for_each(|s| s.independent.white *= 2.0);
    let c = play(
        &louder,
        &PlayOptions {
            seed: 2,
            ..Default::default()
        },
    )
    .unwrap();
    let diff = compare(&a, &c, &CompareOptions::default()).unwrap();
    assert_eq!(diff.significant_axes, ["az"], "{}", diff.summary());
    // The simulation is the noisier one: the scan of −z fires.
    let az = diff.axes.iter().find(|x| x.axis == "az").unwrap();
    assert!(az.cluster.scan[1] > az.cluster.threshold);
}

/// Format 2's sinusoids and steps round-trip, a format-1 file (none of them) and a format-2 file still read, and the played record
/// carries them exactly: a sensor's step and sinusoid, a shared sinusoid on its members only, none without effects.
#[test]
fn sinusoids_and_steps_are_kept_and_played() {
    let mut m = model();
    // Exact values: without the bandwidth's filter, which would smooth them.
    m.axes[0].bandwidth_hz = None;
    let v1 = m.to_toml().unwrap().replace(FORMAT, FORMAT_1);
    assert_eq!(ClusterModel::from_toml(&v1, "v1.toml").unwrap(), m);
    let v2 = m.to_toml().unwrap().replace(FORMAT, FORMAT_2);
    assert_eq!(ClusterModel::from_toml(&v2, "v2.toml").unwrap(), m);
    let own = Sinusoid {
        period_s: 50.0,
        amplitude: 0.3,
        phase_rad: 0.4,
    };
    let shared = Sinusoid {
        period_s: 300.0,
        amplitude: 0.2,
        phase_rad: -1.0,
    };
    let step = BiasStep {
        at_s: 1000.0,
        size: 0.5,
    };
    m.axes[0].sensors[2].sinusoids.push(own);
    m.axes[0].sensors[2].steps.push(step);
    m.axes[0].shared.push(SharedProcess {
        kind: "periodic".into(),
        groups: vec![1, 2],
        terms: NoiseTerms::default(),
        sinusoids: vec![shared],
    });
    let text = m.to_toml().unwrap();
    assert_eq!(ClusterModel::from_toml(&text, "m.toml").unwrap(), m);
    let mut bad = m.clone();
    bad.axes[0].sensors[2].sinusoids[0].period_s = 0.0;
    assert!(bad.validate().is_err());

    // The deterministic parts against the played record with them and without them (same seed, same noise).
    let play = |m: &ClusterModel| {
        play(
            m,
            &PlayOptions {
                seed: 5,
                ..Default::default()
            },
        )
        .unwrap()
    };
    let mut plain = m.clone();
    plain.axes[0].sensors[2].sinusoids.clear();
    plain.axes[0].sensors[2].steps.clear();
    plain.axes[0].shared.pop();
    let (with, without) = (play(&m), play(&plain));
    for g in 0..6 {
        let (a, b) = (
            &with.find(SensorKind::Gyro, g, 0).unwrap().data,
            &without.find(SensorKind::Gyro, g, 0).unwrap().data,
        );
        for (k, (x, y)) in a.iter().zip(b).enumerate().step_by(97) {
            let t = k as f64 / 10.0;
            let sine = |s: &Sinusoid| {
                s.amplitude * (std::f64::consts::TAU * t / s.period_s + s.phase_rad).sin()
            };
            let mut want = 0.0;
            if g == 1 || g == 2 {
                want += sine(&shared);
            }
            if g == 2 {
                want += sine(&own) + if t >= step.at_s { step.size } else { 0.0 };
            }
            assert!(
                (x - y - want).abs() < 1e-12,
                "group {g}, t {t}: {} vs {want}",
                x - y
            );
        }
    }
}

/// Item 1's check on a record the model family describes exactly: 8 groups, 20 Hz, 40 000 samples; the gyros
/// white (0.4) plus a first-order Gauss–Markov bump of their own (σ 0.3, T 1 s), the accelerometers white (0.004).
/// The fitted terms must stay within 2.5 half-widths of the record's 68 % interval at every octave τ, and outside
/// it at no more than a third of them (the share a true curve would have). Measured: 16 of 90 outside, worst 2.09
/// (gz at 12.8 s). Before the bandwidth was put to the held-out test, 48 of 90, worst 35: the diagnosis took the
/// gyros' bump for a 0.75–1.06 Hz roll-off, and the terms fit, given it, replaced white noise by quantisation and
/// a Gauss–Markov term at 2τ₀.
#[test]
fn fitted_terms_follow_a_record_of_their_own_family() {
    use crate::recording::{Column, Recording, SensorKind};
    use crate::testrng::TestRng;
    let (n, dt) = (40_000, 0.05);
    let mut rec = Recording {
        t_s: (0..n).map(|i| i as f64 * dt).collect(),
        ..Default::default()
    };
    let phi = (-dt / 1.0f64).exp();
    for g in 0..8 {
        let mut r = TestRng::new(900 + g as u64);
        for axis in 0..3 {
            let mut x = 0.0;
            let gyro = (0..n)
                .map(|_| {
                    x = phi * x + 0.3 * (1.0 - phi * phi).sqrt() * r.normal();
                    0.4 * r.normal() + x
                })
                .collect();
            let accel = (0..n).map(|_| 0.004 * r.normal()).collect();
            for (kind, data) in [(SensorKind::Gyro, gyro), (SensorKind::Accel, accel)] {
                rec.columns.push(Column {
                    group: g,
                    kind,
                    axis,
                    data,
                });
            }
        }
    }
    let report = crate::diagnose::diagnose(&rec, &crate::diagnose::Options::default()).unwrap();
    let model = fit(&rec, &report, "sim").unwrap();
    let (mut outside, mut taus) = (0, 0);
    for a in &model.axes {
        let c = a.coverage.as_ref().unwrap();
        eprintln!("{}: {}", a.axis, c.summary());
        outside += c.outside_s.len();
        taus += c.taus_s.len();
    }
    assert!(taus >= 60, "{taus}");
    assert!(outside * 3 <= taus, "{outside} of {taus} outside");
    for a in &model.axes {
        let c = a.coverage.as_ref().unwrap();
        assert!(c.worst <= 2.5, "{}: {}", a.axis, c.summary());
    }
}

/// A line the mean holds is shared out to the parts that carry it (`fit::share_lines`): eight white-noise sensors,
/// two of them with a wandering line (σ 0.05 at 5 Hz, T 0.4 s, played exactly), given the line evenly (each an
/// eighth of the mean's twice σ²): afterwards those two hold over 95 % of its power, each within 15 % of σ², and the
/// total is unchanged (measured: 0.99 and 0.95 σ², the others ≤ 0.03 σ²; with the other terms held, not scaled in
/// the least squares, one part without the line took 0.22 σ²).
#[test]
fn a_line_on_two_parts_is_shared_out_to_them() {
    let (n, tau0, white, sigma, f_hz, t_s) = (1usize << 15, 0.01f64, 0.01f64, 0.05f64, 5.0, 0.4);
    let mut an = Analyzer::new();
    let points: Vec<Vec<crate::allan::AnalysisPoint>> = (0..8u64)
        .map(|i| {
            let mut r = crate::testrng::TestRng::new(300 + i);
            let mut x: Vec<f64> = (0..n).map(|_| white / tau0.sqrt() * r.normal()).collect();
            if i < 2 {
                let theta = std::f64::consts::TAU * f_hz * tau0;
                crate::sim::noise::add_line(&mut x, sigma * sigma, tau0 / t_s, theta, 400 + i);
            }
            an.analyze(
                DevKind::Oadev,
                &x,
                tau0,
                &TauSpec::Octave,
                &AllanOptions::default(),
            )
        })
        .collect();
    let even = NoiseTerms {
        white,
        gauss_markov: vec![GaussMarkov {
            sigma: sigma * (2.0f64 / 8.0).sqrt(),
            tau_s: t_s,
            freq_hz: f_hz,
        }],
        ..NoiseTerms::default()
    };
    let mut own = vec![even; 8];
    fit::share_lines(&mut own, &points, tau0, None);
    let power: Vec<f64> = own
        .iter()
        .map(|o| o.gauss_markov.iter().map(|g| g.sigma * g.sigma).sum())
        .collect();
    let total: f64 = power.iter().sum();
    eprintln!(
        "line power per part, in units of its σ²: {:?}",
        power
            .iter()
            .map(|p| p / (sigma * sigma))
            .collect::<Vec<_>>()
    );
    assert!(
        (total / (2.0 * sigma * sigma) - 1.0).abs() < 1e-9,
        "{power:?}"
    );
    assert!(power[0] + power[1] > 0.95 * total, "{power:?}");
    for p in &power[..2] {
        assert!((p / (sigma * sigma)).ln().abs() < 1.15f64.ln(), "{power:?}");
    }
}
