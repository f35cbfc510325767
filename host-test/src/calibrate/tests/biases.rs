//! Biases-only re-estimation on synthetic data.

use nalgebra::{Matrix3, Vector3};

use super::{Rng, accel_near_identity, interval};
use crate::calibrate::linalg::{arrv, mat3, vec3};
use crate::calibrate::*;

fn cal(rng: &mut Rng, n: usize) -> CalibrationFile {
    CalibrationFile::new(
        1,
        -32768,
        32767,
        (0..n)
            .map(|_| {
                let (accel_matrix_g_per_count, accel_bias_counts) = accel_near_identity(rng);
                GroupCalF64 {
                    gyro_matrix_dps_per_count: [
                        [1.0 / 16.4, 0.0, 0.0, 0.0],
                        [0.0, 1.0 / 16.4, 0.0, 0.0],
                        [0.0, 0.0, 1.0 / 16.4, 0.0],
                    ],
                    gyro_bias_counts: [1.0, 2.0, 3.0, 0.0],
                    accel_matrix_g_per_count,
                    accel_bias_counts,
                }
            })
            .collect(),
    )
}

/// Poses of `file`'s sensors with biases shifted by `shift` counts, gyro biases `gyro`.
fn poses(
    file: &CalibrationFile,
    dirs: &[[f64; 3]],
    shift: &[Vector3<f64>],
    gyro: [f64; 3],
) -> Vec<StaticInterval> {
    dirs.iter()
        .enumerate()
        .map(|(k, u)| {
            let acc = file
                .groups
                .iter()
                .zip(shift)
                .map(|(g, s)| {
                    let m: Matrix3<f64> = mat3(&g.accel_matrix_g_per_count);
                    arrv(&(m.try_inverse().unwrap() * vec3(u) + vec3(&g.accel_bias_counts) + s))
                })
                .collect();
            interval(25.0 * k as f64, acc, vec![gyro; file.groups.len()], 0.3)
        })
        .collect()
}

#[test]
fn spread_poses_recover_shifted_biases() {
    let mut rng = Rng::new(31);
    let f = cal(&mut rng, 4);
    let shift: Vec<Vector3<f64>> = (0..4)
        .map(|_| Vector3::new(rng.normal(), rng.normal(), rng.normal()) * 10.0)
        .collect();
    let dirs: Vec<[f64; 3]> = (0..8).map(|_| rng.unit_vector()).collect();
    let p = poses(&f, &dirs, &shift, [5.0, -6.0, 7.0]);
    let (g, up) = reestimate_biases(&f, &p, &BiasOptions::default()).unwrap();
    for (i, s) in shift.iter().enumerate() {
        assert_eq!(up.method[i], BiasMethod::Magnitude);
        let want = vec3(&f.groups[i].accel_bias_counts) + s;
        assert!(
            (vec3(&g.groups[i].accel_bias_counts) - want).abs().max() < 1e-6,
            "IMU {i}"
        );
        assert_eq!(
            g.groups[i].accel_matrix_g_per_count,
            f.groups[i].accel_matrix_g_per_count
        );
        assert_eq!(g.groups[i].gyro_bias_counts, [5.0, -6.0, 7.0, 0.0]);
        assert!(up.new_rms_mg[i] < 1e-6 && up.old_rms_mg[i] > 0.5, "{up:?}");
    }
}

#[test]
fn single_pose_keeps_the_old_gravity_direction() {
    let mut rng = Rng::new(32);
    let f = cal(&mut rng, 2);
    let shift = vec![Vector3::new(0.0, 0.0, 8.0), Vector3::new(3.0, -2.0, 5.0)];
    let p = poses(&f, &[[0.0, 0.0, 1.0]], &shift, [0.0; 3]);
    let (g, up) = reestimate_biases(
        &f,
        &p,
        &BiasOptions {
            gyro: false,
            ..Default::default()
        },
    )
    .unwrap();
    for i in 0..2 {
        assert_eq!(up.method[i], BiasMethod::GravityFromOld);
        let m = mat3(&g.groups[i].accel_matrix_g_per_count);
        let a = vec3(&p[0].accel_counts[i]);
        let new = m * (a - vec3(&g.groups[i].accel_bias_counts));
        let old = m * (a - vec3(&f.groups[i].accel_bias_counts));
        assert!((new.norm() - 1.0).abs() < 1e-12);
        assert!((new - old.normalize()).norm() < 1e-12, "direction kept");
        assert_eq!(
            g.groups[i].gyro_bias_counts, f.groups[i].gyro_bias_counts,
            "gyro untouched"
        );
    }
    // IMU 1's shift is along gravity (z): recovered to second order.
    let want = vec3(&f.groups[0].accel_bias_counts) + shift[0];
    assert!((vec3(&g.groups[0].accel_bias_counts) - want).norm() < 0.3);
}

#[test]
fn bad_inputs_are_errors() {
    let mut rng = Rng::new(33);
    let f = cal(&mut rng, 3);
    let o = BiasOptions::default();
    assert!(matches!(
        reestimate_biases(&f, &[], &o),
        Err(CalibError::TooFewPoses { .. })
    ));
    let p = poses(&f, &[[1.0, 0.0, 0.0]], &[Vector3::zeros(); 3], [0.0; 3]);
    let g2 = CalibrationFile {
        groups: f.groups[..2].to_vec(),
        ..f.clone()
    };
    assert!(matches!(
        reestimate_biases(&g2, &p, &o),
        Err(CalibError::Count { .. })
    ));
    let mut nan = p.clone();
    nan[0].gyro_counts[1][0] = f64::NAN;
    assert!(matches!(
        reestimate_biases(&f, &nan, &o),
        Err(CalibError::NonFinite(_))
    ));
    let mut sing = f.clone();
    sing.groups[0].accel_matrix_g_per_count = [[0.0; 3]; 3];
    assert!(matches!(
        reestimate_biases(&sing, &p, &o),
        Err(CalibError::Degenerate(_))
    ));
}
