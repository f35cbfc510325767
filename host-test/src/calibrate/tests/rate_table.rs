//! Rate-table mode on synthetic data of our 16-group board with known parameters and noise.

use nalgebra::{Matrix3, SMatrix, Vector3, Vector4};

use super::Rng;
use crate::calibrate::*;

const OMEGA: f64 = 100.0;

struct GroupTruth {
    /// Forward gyro sensitivity, counts per °/s (rows: A x, A z, B y, B z).
    sg: SMatrix<f64, 4, 3>,
    bg: Vector4<f64>,
    /// Gyro noise of a record mean per channel, counts.
    ng: [f64; 4],
    /// Forward accelerometer sensitivity, counts per g.
    sa: Matrix3<f64>,
    ba: Vector3<f64>,
    na: f64,
    /// Position relative to the rotation axis (centripetal acceleration in the rotating records), m.
    r_m: Vector3<f64>,
}

/// Our board's nominal chain: 160 counts per °/s (LPY410AL 4× outputs on the ADS8332), zero at 19680 counts;
/// 4800 counts per g (ADXL335), zero at 24000 counts; 1 % scale errors, 1 % cross-axis terms.
fn group(rng: &mut Rng) -> GroupTruth {
    let mut e = || 0.01 * rng.normal();
    let g = 160.0;
    let sg = SMatrix::<f64, 4, 3>::new(
        g * (1.0 + e()),
        g * e(),
        g * e(),
        g * e(),
        g * e(),
        g * (1.0 + e()),
        g * e(),
        g * (1.0 + e()),
        g * e(),
        g * e(),
        g * e(),
        g * (1.0 + e()),
    );
    let a = 4800.0;
    let sa = Matrix3::from_fn(|r, c| a * (f64::from(u8::from(r == c)) + 0.01 * rng.normal()));
    GroupTruth {
        sg,
        bg: Vector4::from_fn(|_, _| 19_680.0 + 100.0 * rng.normal()),
        ng: core::array::from_fn(|_| 1.0 + 2.0 * rng.uniform()),
        sa,
        ba: Vector3::from_fn(|_, _| 24_000.0 + 100.0 * rng.normal()),
        na: 1.0,
        r_m: Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.05,
    }
}

fn records(t: &GroupTruth, rng: &mut Rng, noise: bool) -> Vec<RateRecord> {
    let k = if noise { 1.0 } else { 0.0 };
    standard_inputs(OMEGA)
        .into_iter()
        .map(|(_, w, f)| {
            let wv = Vector3::from(w);
            let raw_g = t.sg * wv + t.bg;
            // Centripetal acceleration −ω×(ω×r), in g.
            let w_rad = wv.map(f64::to_radians);
            let centripetal = -w_rad.cross(&w_rad.cross(&t.r_m)) / 9.80665;
            let raw_a = t.sa * (Vector3::from(f) + centripetal) + t.ba;
            RateRecord {
                rate_dps: w,
                accel_g: f,
                gyro_counts: core::array::from_fn(|c| raw_g[c] + k * t.ng[c] * rng.normal()),
                accel_counts: core::array::from_fn(|c| raw_a[c] + k * t.na * rng.normal()),
            }
        })
        .collect()
}

#[test]
fn noise_free_fit_is_exact_and_uses_both_z_outputs() {
    let mut rng = Rng::new(11);
    let t = group(&mut rng);
    let f =
        fit_rate_table_group(&records(&t, &mut rng, false), &RateTableOptions::default()).unwrap();
    let m = SMatrix::<f64, 3, 4>::from_fn(|r, c| f.gyro_matrix_dps_per_count[r][c]);
    assert!((m * t.sg - Matrix3::identity()).abs().max() < 1e-9);
    assert!((Vector4::from(f.gyro_bias_counts) - t.bg).abs().max() < 1e-6);
    assert!(
        m[(2, 1)].abs() > 1e-3 && m[(2, 3)].abs() > 1e-3,
        "z uses A z and B z: {m}"
    );
    let ma = Matrix3::from_fn(|r, c| f.accel_matrix_g_per_count[r][c]);
    assert!((ma * t.sa - Matrix3::identity()).abs().max() < 1e-9);
    assert!((Vector3::from(f.accel_bias_counts) - t.ba).abs().max() < 1e-6);
}

#[test]
fn balanced_design_is_the_corrected_two_point_formula() {
    let mut rng = Rng::new(12);
    let t = group(&mut rng);
    let recs = records(&t, &mut rng, true);
    let f = fit_rate_table_group(&recs, &RateTableOptions::default()).unwrap();
    // Gyro channel A x against the rate about x: the records with x up (rate +x·Ω at +Ω) and x down.
    let out = |up: UpAxis, sign: f64| {
        let u = up.unit();
        recs.iter()
            .find(|r| r.accel_g == u && r.rate_dps == u.map(|x| x * sign * OMEGA))
            .unwrap()
            .gyro_counts[0]
    };
    let (b1, s1) = two_point(out(UpAxis::PlusX, 1.0), out(UpAxis::PlusX, -1.0), OMEGA);
    let (b2, s2) = two_point(out(UpAxis::MinusX, -1.0), out(UpAxis::MinusX, 1.0), OMEGA);
    assert!((f.gyro_sensitivity_counts_per_dps[0][0] - (s1 + s2) / 2.0).abs() < 1e-9);
    // The least-squares bias is the mean of all 18 records (the design is balanced): the mean of the two-point
    // biases of the three axes with their zero-rate records.
    let mean_all = recs.iter().map(|r| r.gyro_counts[0]).sum::<f64>() / 18.0;
    assert!((f.gyro_bias_counts[0] - mean_all).abs() < 1e-9);
    assert!(((b1 + b2) / 2.0 - t.bg[0]).abs() < 10.0);
    // Accelerometer: scale = (a(+x up) − a(−x up)) / 2 g, bias = mean of the six zero-rate records.
    let acc = |up: UpAxis| {
        recs.iter()
            .find(|r| r.accel_g == up.unit() && r.rate_dps == [0.0; 3])
            .unwrap()
            .accel_counts
    };
    let (_, sx) = two_point(acc(UpAxis::PlusX)[0], acc(UpAxis::MinusX)[0], 1.0);
    assert!((f.accel_sensitivity_counts_per_g[0][0] - sx).abs() < 1e-9);
    let zero_mean = UpAxis::ALL.iter().map(|&u| acc(u)[1]).sum::<f64>() / 6.0;
    assert!((f.accel_bias_counts[1] - zero_mean).abs() < 1e-9);
}

/// 16 groups with noise: every estimate is within the standard errors the fit reports (≥ 95 % within 3 SE,
/// all within 6 SE, mean squared z-score near 1), and the calibrated outputs are within 3 predicted SE.
#[test]
fn recovered_within_reported_accuracy() {
    let mut rng = Rng::new(13);
    let truths: Vec<GroupTruth> = (0..16).map(|_| group(&mut rng)).collect();
    let recs: Vec<Vec<RateRecord>> = truths.iter().map(|t| records(t, &mut rng, true)).collect();
    let (fits, file) = fit_rate_table::<16>(&recs, &RateTableOptions::default(), 7).unwrap();
    let mut z = Vec::new();
    let mut out_z = Vec::new();
    for (t, f) in truths.iter().zip(&fits) {
        for c in 0..4 {
            for k in 0..3 {
                z.push(
                    (f.gyro_sensitivity_counts_per_dps[c][k] - t.sg[(c, k)])
                        / f.gyro_sensitivity_se[c][k],
                );
            }
            z.push((f.gyro_bias_counts[c] - t.bg[c]) / f.gyro_bias_se_counts[c]);
        }
        let ma_true = t.sa.try_inverse().unwrap();
        for r in 0..3 {
            for k in 0..3 {
                z.push(
                    (f.accel_sensitivity_counts_per_g[r][k] - t.sa[(r, k)])
                        / f.accel_sensitivity_se[r][k],
                );
                z.push(
                    (f.accel_matrix_g_per_count[r][k] - ma_true[(r, k)]) / f.accel_matrix_se[r][k],
                );
            }
            z.push((f.accel_bias_counts[r] - t.ba[r]) / f.accel_bias_se_counts[r]);
        }
        // Calibrated outputs for true inputs (noise-free raw of the true sensor).
        let m = SMatrix::<f64, 3, 4>::from_fn(|r, c| f.gyro_matrix_dps_per_count[r][c]);
        let b = Vector4::from(f.gyro_bias_counts);
        let ma = Matrix3::from_fn(|r, c| f.accel_matrix_g_per_count[r][c]);
        let ba = Vector3::from(f.accel_bias_counts);
        for axis in 0..3 {
            let w = Vector3::from_fn(|i, _| if i == axis { OMEGA } else { 0.0 });
            let est = m * (t.sg * w + t.bg - b);
            let acc = Vector3::from_fn(|i, _| f64::from(u8::from(i == axis)));
            let est_a = ma * (t.sa * acc + t.ba - ba);
            for i in 0..3 {
                out_z.push((est[i] - w[i]) / f.rate_se_dps_at_omega[axis][i]);
                out_z.push((est_a[i] - acc[i]) / f.accel_se_g_at_1g[axis][i]);
            }
        }
        assert!(
            f.rate_se_dps_at_zero.iter().all(|&s| s > 0.0 && s < 0.1),
            "{:?}",
            f.rate_se_dps_at_zero
        );
    }
    for (name, z) in [("parameters", &z), ("outputs", &out_z)] {
        let within3 = z.iter().filter(|v| v.abs() < 3.0).count() as f64 / z.len() as f64;
        let max = z.iter().fold(0.0f64, |m, v| m.max(v.abs()));
        let msq = z.iter().map(|v| v * v).sum::<f64>() / z.len() as f64;
        eprintln!(
            "{name}: {} z-scores, {:.1} % within 3 SE, max |z| {max:.2}, mean z² {msq:.2}",
            z.len(),
            100.0 * within3
        );
        assert!(z.iter().all(|v| v.is_finite()), "{name}");
        assert!(within3 >= 0.95, "{name}: {within3}");
        assert!(max < 6.0, "{name}: max |z| {max}");
        assert!((0.5..2.0).contains(&msq), "{name}: mean z² {msq}");
    }
    let f = &fits[0];
    eprintln!(
        "group 1: rate SE at 0 {:?} °/s, at Ω about z {:?} °/s, accel SE at 1 g z {:?} g",
        f.rate_se_dps_at_zero, f.rate_se_dps_at_omega[2], f.accel_se_g_at_1g[2]
    );
    // The table form.
    assert_eq!(file.groups.len(), 16);
    let table = file.to_table::<16>().unwrap();
    assert_eq!(table.cal_id, 7);
    assert_eq!((table.raw_min, table.raw_max), (0, 65_535));
}

#[test]
fn centripetal_offsets_matter_off_axis() {
    let mut rng = Rng::new(14);
    let mut t = group(&mut rng);
    t.r_m = Vector3::new(0.05, 0.05, 0.05);
    let recs = records(&t, &mut rng, false);
    let good = fit_rate_table_group(&recs, &RateTableOptions::default()).unwrap();
    let zero = fit_rate_table_group(
        &recs,
        &RateTableOptions {
            accel_records: AccelRecords::ZeroRateOnly,
            ..Default::default()
        },
    )
    .unwrap();
    let naive = fit_rate_table_group(
        &recs,
        &RateTableOptions {
            accel_records: AccelRecords::All,
            ..Default::default()
        },
    )
    .unwrap();
    let err = |f: &RateTableFit| (Vector3::from(f.accel_bias_counts) - t.ba).abs().max();
    assert!(err(&good) < 1e-6 && err(&zero) < 1e-6);
    assert!(
        err(&naive) > 10.0,
        "ignoring Ω²r biases the accelerometer: {}",
        err(&naive)
    );
}

#[test]
fn bad_records_are_errors() {
    let mut rng = Rng::new(15);
    let t = group(&mut rng);
    let recs = records(&t, &mut rng, true);
    let o = RateTableOptions::default();
    assert!(matches!(
        fit_rate_table_group(&recs[..4], &o),
        Err(CalibError::TooFewPoses { .. })
    ));
    let mut nan = recs.clone();
    nan[5].gyro_counts[2] = f64::INFINITY;
    assert!(matches!(
        fit_rate_table_group(&nan, &o),
        Err(CalibError::NonFinite(_))
    ));
    // Only z up: x and y rates never excited.
    let z_only: Vec<RateRecord> = recs
        .iter()
        .filter(|r| r.accel_g[2] != 0.0)
        .copied()
        .collect();
    assert!(matches!(
        fit_rate_table_group(&z_only, &o),
        Err(CalibError::Degenerate(_) | CalibError::TooFewPoses { .. })
    ));
    assert!(matches!(
        fit_rate_table::<16>(&[recs], &o, 1),
        Err(CalibError::Count {
            expected: 16,
            found: 1,
            ..
        })
    ));
}
