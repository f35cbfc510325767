//! Readable forms, the table's binary form, and the fixed-point chain.

use shared::calib::{CalibrationTable, RawCounts};

use super::{Rng, accel_near_identity};
use crate::calibrate::*;

fn sample_file(rng: &mut Rng, n: usize) -> CalibrationFile {
    let groups = (0..n)
        .map(|_| {
            let gyro_matrix_dps_per_count = core::array::from_fn(|r| {
                core::array::from_fn(|c| {
                    if c == 3 {
                        0.0
                    } else {
                        (rng.normal() + f64::from(u8::from(r == c))) / 16.4
                    }
                })
            });
            let gyro_bias_counts = [
                rng.normal() * 30.0,
                rng.normal() * 30.0,
                rng.normal() * 30.0,
                0.0,
            ];
            let (accel_matrix_g_per_count, accel_bias_counts) = accel_near_identity(rng);
            GroupCalF64 {
                gyro_matrix_dps_per_count,
                gyro_bias_counts,
                accel_matrix_g_per_count,
                accel_bias_counts,
            }
        })
        .collect();
    CalibrationFile {
        metadata: Some(CalibrationMetadata {
            source: "synthetic".into(),
            reference_imu: 0,
            bias_model: BiasModel::LinearDrift,
            t_ref_s: 250.0,
            poses: 20,
            history: vec!["made by a test".into()],
            imus: (0..n)
                .map(|_| ImuMetadata {
                    rotation_to_cluster: [[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]],
                    accel_bias_drift_counts_per_s: [0.01, -0.02, 0.03],
                    gyro_bias_drift_counts_per_s: [0.0; 3],
                    residual: ImuResidual {
                        before_rms_mg: 30.0,
                        after_rms_mg: 0.1,
                        table_rms_mg: 0.3,
                        alignment_rms_deg: 0.01,
                    },
                })
                .collect(),
        }),
        ..CalibrationFile::new(42, -32768, 32767, groups)
    }
}

fn tmp(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("calib-test-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d.join(name)
}

#[test]
fn json_toml_bin_roundtrip() {
    let mut rng = Rng::new(21);
    let f = sample_file(&mut rng, 8);
    assert_eq!(
        CalibrationFile::from_json(&f.to_json().unwrap()).unwrap(),
        f
    );
    let toml = f.to_toml().unwrap();
    assert!(toml.contains("accel_matrix_g_per_count"), "{toml}");
    assert_eq!(CalibrationFile::from_toml(&toml).unwrap(), f);
    for ext in ["json", "toml", "bin"] {
        let p = tmp(&format!("cal.{ext}"));
        write_calibration::<8>(&f, &p).unwrap();
        let back = read_calibration::<8>(&p).unwrap();
        if ext == "bin" {
            // Q19.12: entries to 1/4096 µ-unit per count, biases to 1/4096 count; no metadata.
            assert!(back.metadata.is_none());
            assert_eq!(back.cal_id, 42);
            for (a, b) in back.groups.iter().zip(&f.groups) {
                for r in 0..3 {
                    for c in 0..4 {
                        assert!(
                            (a.gyro_matrix_dps_per_count[r][c] - b.gyro_matrix_dps_per_count[r][c])
                                .abs()
                                <= 0.5e-6 / 4096.0 + 1e-15
                        );
                    }
                    for c in 0..3 {
                        assert!(
                            (a.accel_matrix_g_per_count[r][c] - b.accel_matrix_g_per_count[r][c])
                                .abs()
                                <= 0.5e-6 / 4096.0 + 1e-15
                        );
                    }
                    assert!(
                        (a.accel_bias_counts[r] - b.accel_bias_counts[r]).abs() <= 0.5 / 4096.0
                    );
                }
            }
            // Bin → table → bin is exact.
            assert_eq!(back.to_bin::<8>().unwrap(), std::fs::read(&p).unwrap());
        } else {
            assert_eq!(back, f, "{ext}");
        }
    }
}

#[test]
fn bad_files_are_errors() {
    let mut rng = Rng::new(22);
    let f = sample_file(&mut rng, 8);
    assert!(matches!(
        write_calibration::<8>(&f, tmp("cal.yaml")),
        Err(CalibError::Format { .. })
    ));
    assert!(matches!(
        write_calibration::<16>(&f, tmp("x.json")),
        Err(CalibError::Count { .. })
    ));
    assert!(matches!(
        read_calibration::<8>(tmp("missing.json")),
        Err(CalibError::Io { .. })
    ));
    let p = tmp("garbage.json");
    std::fs::write(&p, b"{ not json").unwrap();
    assert!(matches!(
        read_calibration::<8>(&p),
        Err(CalibError::Format { .. })
    ));
    let p = tmp("garbage.toml");
    std::fs::write(&p, [0xFFu8, 0xFE, 0x00]).unwrap();
    assert!(matches!(
        read_calibration::<8>(&p),
        Err(CalibError::Format { .. })
    ));
    let p = tmp("c.json");
    write_calibration::<8>(&f, &p).unwrap();
    assert!(
        matches!(read_calibration::<16>(&p), Err(CalibError::Format { .. })),
        "group count"
    );
    // A corrupted .bin: the CRC catches it.
    let p = tmp("c.bin");
    write_calibration::<8>(&f, &p).unwrap();
    let mut b = std::fs::read(&p).unwrap();
    b[10] ^= 1;
    std::fs::write(&p, &b).unwrap();
    let e = read_calibration::<8>(&p).unwrap_err();
    assert!(e.to_string().contains("Crc"), "{e}");
    // Values the table cannot hold.
    let mut big = f.clone();
    big.groups[3].accel_bias_counts[1] = 70_000.0;
    assert!(matches!(
        big.to_table::<8>(),
        Err(CalibError::OutOfRange(_))
    ));
    let mut big = f.clone();
    big.groups[0].gyro_matrix_dps_per_count[0][0] = 1.0;
    assert!(
        matches!(big.to_table::<8>(), Err(CalibError::OutOfRange(_))),
        "1 °/s per count = 4.1e9 in Q12"
    );
    let mut nan = f;
    nan.groups[0].accel_matrix_g_per_count[2][2] = f64::NAN;
    assert!(matches!(
        nan.to_table::<8>(),
        Err(CalibError::OutOfRange(_))
    ));
}

/// The fixed-point `GroupCal::apply` of the converted table agrees with the f64 model to the Q12 resolution.
#[test]
fn fixed_point_apply_matches_f64() {
    let mut rng = Rng::new(23);
    let f = sample_file(&mut rng, 8);
    let t: CalibrationTable<8> = f.to_table().unwrap();
    for _ in 0..2000 {
        let i = (rng.next_u64() % 8) as usize;
        let raw_a: [i32; 3] = core::array::from_fn(|_| (rng.normal() * 2000.0) as i32);
        let raw_g: [i32; 4] = [
            (rng.normal() * 3000.0) as i32,
            (rng.normal() * 3000.0) as i32,
            (rng.normal() * 3000.0) as i32,
            0,
        ];
        let out = t.groups[i].apply(&RawCounts {
            gyro: raw_g,
            accel: raw_a,
        });
        let g = &f.groups[i];
        let h = 0.5 / 4096.0;
        for r in 0..3 {
            let a: f64 = (0..3)
                .map(|c| {
                    g.accel_matrix_g_per_count[r][c]
                        * (f64::from(raw_a[c]) - g.accel_bias_counts[c])
                })
                .sum();
            let w: f64 = (0..4)
                .map(|c| {
                    g.gyro_matrix_dps_per_count[r][c]
                        * (f64::from(raw_g[c]) - g.gyro_bias_counts[c])
                })
                .sum();
            // Bound: rounding of the entries (h µ-unit per count) × |raw − b|, of the biases (h count) × |entry|,
            // and of the output (0.5).
            let tol_a: f64 = 0.5
                + (0..3)
                    .map(|c| {
                        h * (f64::from(raw_a[c]) - g.accel_bias_counts[c]).abs()
                            + h * g.accel_matrix_g_per_count[r][c].abs() * 1e6
                    })
                    .sum::<f64>();
            let tol_g: f64 = 0.5
                + (0..4)
                    .map(|c| {
                        h * (f64::from(raw_g[c]) - g.gyro_bias_counts[c]).abs()
                            + h * g.gyro_matrix_dps_per_count[r][c].abs() * 1e6
                    })
                    .sum::<f64>();
            assert!(
                (f64::from(out[3 + r]) - a * 1e6).abs() <= tol_a + 1e-6,
                "{} vs {}",
                out[3 + r],
                a * 1e6
            );
            assert!(
                (f64::from(out[r]) - w * 1e6).abs() <= tol_g + 1e-6,
                "{} vs {}",
                out[r],
                w * 1e6
            );
        }
    }
}

/// A 16-group file with thermal terms and weights: to the table and back gives the same values within half a
/// fixed-point step, the table's reference temperature and Q formats are the documented ones (checked against
/// hand-derived integers), and values beyond the formats are refused.
#[test]
fn thermal_terms_and_weights_roundtrip() {
    let mut rng = Rng::new(27);
    let mut f = sample_file(&mut rng, 16);
    f.groups
        .iter_mut()
        .for_each(|g| g.gyro_bias_counts[3] = 0.0);
    f.t_ref_c = 21.37;
    f.thermal = Some(
        (0..16)
            .map(|_| GroupThermalF64 {
                gyro_lin_counts_per_c: core::array::from_fn(|_| 8.0 + 3.0 * rng.normal()),
                gyro_quad_counts_per_c2: core::array::from_fn(|_| 0.05 * rng.normal()),
                accel_lin_counts_per_c: core::array::from_fn(|_| 2.4 + rng.normal()),
                accel_quad_counts_per_c2: core::array::from_fn(|_| 0.01 * rng.normal()),
            })
            .collect(),
    );
    f.weights = Some((0..16).map(|g| [(1.0 + g as f64) / 136.0; 6]).collect());
    let t = f.to_table::<16>().unwrap();
    assert_eq!(t.t_ref_cdeg, 2137);
    // 8 counts/°C = 0.08 counts per 0.01 °C = 0.08·2²⁸ in Q28.
    let th = &f.thermal.as_ref().unwrap()[0];
    let q28 = (th.gyro_lin_counts_per_c[0] / 100.0 * 268_435_456.0).round() as i32;
    assert_eq!(t.thermal[0].gyro_lin_q28[0], q28);
    let q40 = (th.accel_quad_counts_per_c2[2] / 1e4 * 1_099_511_627_776.0).round() as i32;
    assert_eq!(t.thermal[0].accel_quad_q40[2], q40);
    assert_eq!(
        t.weights_q16[15][0],
        (16.0 / 136.0 * 65536.0_f64).round() as i32
    );
    // Through the encoded form and back to f64.
    let bin = f.to_bin::<16>().unwrap();
    let back = CalibrationFile::from_bin::<16>(&bin).unwrap();
    assert_eq!(back.t_ref_c, 21.37);
    for (a, b) in back
        .thermal
        .as_ref()
        .unwrap()
        .iter()
        .zip(f.thermal.as_ref().unwrap())
    {
        for (x, y) in a
            .gyro_lin_counts_per_c
            .iter()
            .chain(&a.accel_lin_counts_per_c)
            .zip(
                b.gyro_lin_counts_per_c
                    .iter()
                    .chain(&b.accel_lin_counts_per_c),
            )
        {
            assert!((x - y).abs() <= 0.5 * 100.0 / 268_435_456.0, "{x} {y}");
        }
        for (x, y) in a
            .gyro_quad_counts_per_c2
            .iter()
            .chain(&a.accel_quad_counts_per_c2)
            .zip(
                b.gyro_quad_counts_per_c2
                    .iter()
                    .chain(&b.accel_quad_counts_per_c2),
            )
        {
            assert!((x - y).abs() <= 0.5 * 1e4 / 1_099_511_627_776.0, "{x} {y}");
        }
    }
    for (a, b) in back
        .weights
        .as_ref()
        .unwrap()
        .iter()
        .zip(f.weights.as_ref().unwrap())
    {
        for (x, y) in a.iter().zip(b) {
            assert!((x - y).abs() <= 0.5 / 65536.0);
        }
    }
    // The table again from what came back: identical.
    assert_eq!(back.to_table::<16>().unwrap(), t);
    // JSON keeps everything.
    assert_eq!(
        CalibrationFile::from_json(&f.to_json().unwrap()).unwrap(),
        f
    );
    // Refusals: a linear term beyond Q28 (±800 counts/°C), a quadratic beyond Q40 (±19.5 counts/°C²), a reference
    // beyond ±327.67 °C, a weight beyond 1, an axis whose weights do not sum to a positive value.
    let refused = |g: &dyn Fn(&mut CalibrationFile), says: &str| {
        let mut h = f.clone();
        g(&mut h);
        let e = h.to_table::<16>().unwrap_err().to_string();
        assert!(e.contains(says), "{e}");
    };
    refused(
        &|h| h.thermal.as_mut().unwrap()[3].gyro_lin_counts_per_c[1] = 900.0,
        "gyro thermal linear = 900",
    );
    refused(
        &|h| h.thermal.as_mut().unwrap()[3].accel_quad_counts_per_c2[0] = -20.0,
        "accel thermal quadratic = -20",
    );
    refused(&|h| h.t_ref_c = 400.0, "t_ref_c = 400");
    refused(&|h| h.weights.as_mut().unwrap()[2][4] = 1.5, "beyond ±1");
    refused(
        &|h| {
            h.weights
                .as_mut()
                .unwrap()
                .iter_mut()
                .for_each(|w| w[1] = -0.01)
        },
        "axis 1 sum",
    );
}
