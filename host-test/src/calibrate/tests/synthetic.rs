//! Static calibration on synthetic arrays with known parameters.

use nalgebra::{Matrix3, Rotation3, Vector3};

use super::{Rng, interval, rms};
use crate::calibrate::linalg::{arrv, mat3, polar, vec3};
use crate::calibrate::*;

struct Truth {
    /// Calibration matrix into the cluster frame, g per count.
    k: Vec<Matrix3<f64>>,
    /// Bias at the reference time, counts.
    b: Vec<Vector3<f64>>,
    /// Bias drift, counts per second.
    d: Vec<Vector3<f64>>,
    gyro_b: Vec<Vector3<f64>>,
}

/// 8 IMUs: odd ones turned 180° about (1, −1, 0) like the MIMU4444's bottom side, all with small misalignments,
/// scale errors of ~1 %, biases of ~40 counts; IMU 1's rotation is the identity (it defines the cluster frame).
fn truth(rng: &mut Rng, drift: bool) -> Truth {
    let flip = Matrix3::new(0.0, -1.0, 0.0, -1.0, 0.0, 0.0, 0.0, 0.0, -1.0);
    let mut t = Truth {
        k: Vec::new(),
        b: Vec::new(),
        d: Vec::new(),
        gyro_b: Vec::new(),
    };
    for i in 0..8 {
        let mut p = Matrix3::identity();
        for r in 0..3 {
            for c in r..3 {
                let e = 0.01 * rng.normal();
                p[(r, c)] += e;
                if r != c {
                    p[(c, r)] += e;
                }
            }
        }
        let r = if i == 0 {
            Matrix3::identity()
        } else {
            let small = Rotation3::from_scaled_axis(
                Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.01,
            );
            let base = if i % 2 == 1 {
                flip
            } else {
                Matrix3::identity()
            };
            small.matrix() * base
        };
        t.k.push(r * p / 2048.0);
        t.b.push(Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 40.0);
        t.d.push(if drift {
            Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 0.02
        } else {
            Vector3::zeros()
        });
        t.gyro_b
            .push(Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 20.0);
    }
    t
}

fn poses(
    t: &Truth,
    dirs: &[Vec3],
    noise_counts: f64,
    sem_counts: f64,
    rng: &mut Rng,
) -> Vec<StaticInterval> {
    let starts: Vec<f64> = (0..dirs.len()).map(|k| 25.0 * k as f64).collect();
    let t_ref = starts.iter().map(|s| s + 12.0).sum::<f64>() / dirs.len() as f64;
    dirs.iter()
        .zip(&starts)
        .map(|(u, &s)| {
            let dt = s + 12.0 - t_ref;
            let acc = (0..8)
                .map(|i| {
                    let raw = t.k[i].try_inverse().unwrap() * vec3(u) + t.b[i] + t.d[i] * dt;
                    arrv(&raw).map(|x| x + noise_counts * rng.normal())
                })
                .collect();
            let gyr = (0..8)
                .map(|i| arrv(&t.gyro_b[i]).map(|x| x + noise_counts * rng.normal()))
                .collect();
            interval(s, acc, gyr, sem_counts)
        })
        .collect()
}

fn max_rel(a: &Mat3, b: &Matrix3<f64>) -> f64 {
    (mat3(a) - b).abs().max() / b.abs().max()
}

#[test]
fn noise_free_recovery_with_drift() {
    let mut rng = Rng::new(1);
    let t = truth(&mut rng, true);
    let dirs: Vec<Vec3> = (0..20).map(|_| rng.unit_vector()).collect();
    let p = poses(&t, &dirs, 0.0, 0.25, &mut rng);
    let cal = calibrate_static(&p, &StaticCalOptions::default()).unwrap();
    for (i, c) in cal.imus.iter().enumerate() {
        assert!(
            max_rel(&c.accel_matrix_g_per_count, &t.k[i]) < 1e-6,
            "IMU {i}"
        );
        assert!(
            (vec3(&c.accel_bias_counts) - t.b[i]).abs().max() < 1e-3,
            "IMU {i}"
        );
        assert!(
            (vec3(&c.accel_bias_drift_counts_per_s) - t.d[i])
                .abs()
                .max()
                < 1e-5,
            "IMU {i}"
        );
        let (r, _) = polar(&t.k[i]).unwrap();
        assert!((mat3(&c.rotation) - r).abs().max() < 1e-6, "IMU {i}");
        assert!((mat3(&c.gyro_matrix_dps_per_count) - r / 16.4).abs().max() < 1e-7);
        assert!((vec3(&c.gyro_bias_counts) - t.gyro_b[i]).abs().max() < 1e-9);
        let rep = &cal.report.imus[i];
        assert!(rep.after_rms_mg < 1e-3, "{rep:?}");
        assert!(rep.alignment_rms_deg < 1e-4, "{rep:?}");
        assert!(rep.before_rms_mg > 1.0, "{rep:?}");
    }
    assert!(
        max_rel(&cal.imus[0].rotation, &Matrix3::identity()) < 1e-12,
        "IMU 1 defines the frame"
    );
}

#[test]
fn noise_free_recovery_per_imu_and_constant_bias() {
    let mut rng = Rng::new(2);
    let t = truth(&mut rng, false);
    let dirs: Vec<Vec3> = (0..12).map(|_| rng.unit_vector()).collect();
    let p = poses(&t, &dirs, 0.0, 0.25, &mut rng);
    for opts in [
        StaticCalOptions {
            refine: false,
            ..Default::default()
        },
        StaticCalOptions {
            bias_model: BiasModel::Constant,
            ..Default::default()
        },
    ] {
        let cal = calibrate_static(&p, &opts).unwrap();
        for (i, c) in cal.imus.iter().enumerate() {
            assert!(
                max_rel(&c.accel_matrix_g_per_count, &t.k[i]) < 1e-7,
                "IMU {i} {opts:?}"
            );
            assert!((vec3(&c.accel_bias_counts) - t.b[i]).abs().max() < 1e-4);
            assert_eq!(c.accel_bias_drift_counts_per_s, [0.0; 3]);
        }
    }
}

#[test]
fn noisy_recovery_is_noise_limited() {
    let mut rng = Rng::new(3);
    let t = truth(&mut rng, true);
    let dirs: Vec<Vec3> = (0..20).map(|_| rng.unit_vector()).collect();
    // 0.3 counts on each mean (≈ 10 counts per sample over 1400 samples, like the MPU9150 at rest).
    let p = poses(&t, &dirs, 0.3, 0.3, &mut rng);
    let cal = calibrate_static(&p, &StaticCalOptions::default()).unwrap();
    for (i, c) in cal.imus.iter().enumerate() {
        assert!(
            max_rel(&c.accel_matrix_g_per_count, &t.k[i]) < 1e-3,
            "IMU {i}"
        );
        assert!(
            (vec3(&c.accel_bias_counts) - t.b[i]).abs().max() < 1.0,
            "IMU {i}"
        );
        assert!(
            (vec3(&c.accel_bias_drift_counts_per_s) - t.d[i])
                .abs()
                .max()
                < 0.01,
            "IMU {i}"
        );
        let rep = &cal.report.imus[i];
        assert!(rep.after_rms_mg < 0.3, "{rep:?}");
        assert!(rep.alignment_rms_deg < 0.02, "{rep:?}");
    }
    // New poses of the same array (no drift now): the constant-bias model holds to the noise.
    let t2 = Truth {
        d: vec![Vector3::zeros(); 8],
        ..t
    };
    let fresh: Vec<Vec3> = (0..10).map(|_| rng.unit_vector()).collect();
    let q = poses(&t2, &fresh, 0.3, 0.3, &mut rng);
    for r in cal.residuals_mg(&q, false) {
        assert!(rms(&r) < 0.4, "{r:?}");
    }
}

#[test]
fn magnitude_fit_and_alignment_alone() {
    let mut rng = Rng::new(4);
    let t = truth(&mut rng, false);
    let dirs: Vec<Vec3> = (0..9).map(|_| rng.unit_vector()).collect();
    let p = poses(&t, &dirs, 0.0, 0.25, &mut rng);
    let mut own = Vec::new();
    for i in 0..8 {
        let a: Vec<Vec3> = p.iter().map(|q| q.accel_counts[i]).collect();
        let f = fit_magnitude(&a, 1.0 / 2048.0, 200).unwrap();
        let (r, sym) = polar(&t.k[i]).unwrap();
        assert!(max_rel(&f.matrix_g_per_count, &sym) < 1e-7, "IMU {i}");
        assert!((vec3(&f.bias_counts) - t.b[i]).abs().max() < 1e-4);
        assert!(f.rms_mg < 1e-6);
        own.push((r, f));
    }
    let d: Vec<Vec<Vec3>> = (0..8)
        .map(|i| {
            p.iter()
                .map(|q| {
                    arrv(
                        &(mat3(&own[i].1.matrix_g_per_count)
                            * (vec3(&q.accel_counts[i]) - vec3(&own[i].1.bias_counts))),
                    )
                })
                .collect()
        })
        .collect();
    let al = align_cluster(&d, 0).unwrap();
    for (i, o) in own.iter().enumerate() {
        assert!((mat3(&al.rotations[i]) - o.0).abs().max() < 1e-7, "IMU {i}");
        assert!(al.residual_rms_deg[i] < 1e-5);
    }
    // Reference IMU 3: rotations relative to it.
    let al3 = align_cluster(&d, 2).unwrap();
    let rel = own[2].0.transpose() * own[5].0;
    assert!((mat3(&al3.rotations[5]) - rel).abs().max() < 1e-7);
    assert!((mat3(&al3.rotations[2]) - Matrix3::identity()).abs().max() < 1e-12);
}

#[test]
fn bad_inputs_are_errors() {
    let mut rng = Rng::new(5);
    let t = truth(&mut rng, false);
    let dirs: Vec<Vec3> = (0..12).map(|_| rng.unit_vector()).collect();
    let p = poses(&t, &dirs, 0.0, 0.25, &mut rng);
    let o = StaticCalOptions::default();
    assert!(matches!(
        calibrate_static(&p[..8], &o),
        Err(CalibError::TooFewPoses {
            needed: 9,
            found: 8
        })
    ));
    assert!(matches!(
        calibrate_static(&[], &o),
        Err(CalibError::Count { .. })
    ));
    let same: Vec<StaticInterval> = (0..12).map(|_| p[0].clone()).collect();
    assert!(matches!(
        calibrate_static(&same, &o),
        Err(CalibError::Degenerate(_))
    ));
    let mut nan = p.clone();
    nan[3].accel_counts[2][1] = f64::NAN;
    assert!(matches!(
        calibrate_static(&nan, &o),
        Err(CalibError::NonFinite(_))
    ));
    let mut short = p.clone();
    short[4].accel_counts.pop();
    assert!(matches!(
        calibrate_static(&short, &o),
        Err(CalibError::Count { .. })
    ));
    let bad_ref = StaticCalOptions {
        reference_imu: 8,
        ..o
    };
    assert!(matches!(
        calibrate_static(&p, &bad_ref),
        Err(CalibError::InvalidOption(_))
    ));
    assert!(matches!(
        fit_magnitude(&[[0.0; 3]; 9], 0.0, 10),
        Err(CalibError::InvalidOption(_))
    ));
    assert!(
        align_cluster(&vec![vec![[1.0, 0.0, 0.0]; 5]; 2], 0).is_err(),
        "one direction only"
    );
}

/// Random garbage (huge, tiny, zero, clustered values): an error or a result, never a panic.
#[test]
fn garbage_never_panics() {
    let mut rng = Rng::new(6);
    for case in 0..60 {
        let k = 9 + case % 5;
        let scale = [1e-300, 1e-3, 1.0, 2048.0, 1e300][case % 5];
        let p: Vec<StaticInterval> = (0..k)
            .map(|j| {
                let acc = (0..8)
                    .map(|_| [rng.normal(), rng.normal(), rng.normal()].map(|x| x * scale))
                    .collect();
                let gyr = (0..8).map(|_| [rng.normal(); 3]).collect();
                interval(j as f64 * 25.0, acc, gyr, rng.uniform())
            })
            .collect();
        let _ = calibrate_static(&p, &StaticCalOptions::default());
        let _ = calibrate_static(
            &p,
            &StaticCalOptions {
                refine: false,
                ..Default::default()
            },
        );
    }
}
