//! Acceptance figures on the real MIMU4444 recordings (exp_1 … exp_6). Skipped, with a message, when
//! `shared/data/mimu4444` is absent. `cargo test --release -- --nocapture real_data` prints every figure.

use std::sync::OnceLock;

use crate::calibrate::*;
use crate::formats::mimu;
use crate::stats::{median, rms};

/// Static intervals of exp_1 … exp_6 with the default detection (`None` without the data).
fn experiments() -> Option<&'static Vec<Vec<StaticInterval>>> {
    static DATA: OnceLock<Option<Vec<Vec<StaticInterval>>>> = OnceLock::new();
    DATA.get_or_init(|| {
        let dir = data::mimu4444_dir()?;
        Some(
            (1..=6)
                .map(|e| {
                    let rec = mimu::read(dir.join(format!("exp_{e}/data.bin"))).unwrap();
                    detect_static(&rec, &DetectOptions::default()).unwrap()
                })
                .collect(),
        )
    })
    .as_ref()
}

macro_rules! data_or_skip {
    () => {
        match experiments() {
            Some(d) => d,
            None => {
                eprintln!("skipped: MIMU4444 data not found (set MIMU4444_DIR)");
                return;
            }
        }
    };
}

fn split(p: &[StaticInterval]) -> (Vec<StaticInterval>, Vec<StaticInterval>) {
    (
        p.iter().step_by(2).cloned().collect(),
        p.iter().skip(1).step_by(2).cloned().collect(),
    )
}

fn fmt(v: &[f64]) -> String {
    v.iter()
        .map(|x| format!("{x:6.2}"))
        .collect::<Vec<_>>()
        .join(" ")
}

#[test]
fn detects_the_20_static_poses() {
    let d = data_or_skip!();
    for (e, p) in d.iter().enumerate() {
        eprintln!("exp_{}: {} static intervals", e + 1, p.len());
        for (k, q) in p.iter().enumerate() {
            eprintln!(
                "  pose {k:2}: {:7.2}–{:7.2} s ({:5.1} s)  acc std {:.4} g  gyro std {:.3} °/s  change {:.2} mg  IMU 1 f = [{:+.3} {:+.3} {:+.3}] g",
                q.start_s,
                q.end_s,
                q.end_s - q.start_s,
                q.accel_std_g,
                q.gyro_std_dps,
                q.accel_change_mg,
                q.accel_g[0][0],
                q.accel_g[0][1],
                q.accel_g[0][2]
            );
        }
        assert_eq!(p.len(), 20, "exp_{}", e + 1);
        assert!(
            p.iter()
                .all(|q| q.end_s - q.start_s > 15.0 && q.end_s < 520.0)
        );
        // 20 distinct orientations: IMU 1's directions at least 15° apart.
        for a in 0..20 {
            for b in a + 1..20 {
                let (u, v) = (p[a].accel_g[0], p[b].accel_g[0]);
                let dot = (u[0] * v[0] + u[1] * v[1] + u[2] * v[2])
                    / ((u[0] * u[0] + u[1] * u[1] + u[2] * u[2])
                        * (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]))
                        .sqrt();
                assert!(
                    dot < 15f64.to_radians().cos(),
                    "exp_{} poses {a} {b}",
                    e + 1
                );
            }
        }
    }
}

/// (a) Fit on the even poses, test on the odd ones: static |a| − 1 g RMS per IMU × experiment, for the plain
/// per-IMU affine model, the joint model with constant biases, and the default joint model with bias drift.
#[test]
fn model_validity_even_odd() {
    let d = data_or_skip!();
    let variants = [
        (
            "per-IMU affine",
            StaticCalOptions {
                refine: false,
                ..Default::default()
            },
        ),
        (
            "joint, constant bias",
            StaticCalOptions {
                bias_model: BiasModel::Constant,
                ..Default::default()
            },
        ),
        ("joint, bias drift (default)", StaticCalOptions::default()),
    ];
    let mut results: Vec<Vec<Vec<f64>>> = Vec::new();
    for (name, opts) in &variants {
        eprintln!("(a) {name}: odd-pose |a| − 1 g RMS, mg, IMU 1 … 8");
        let mut per_exp = Vec::new();
        for (e, p) in d.iter().enumerate() {
            let (even, odd) = split(p);
            let cal = calibrate_static(&even, opts).unwrap();
            let row: Vec<f64> = cal
                .residuals_mg(&odd, true)
                .iter()
                .map(|r| rms(r.iter()))
                .collect();
            eprintln!("  exp_{}: {}", e + 1, fmt(&row));
            per_exp.push(row);
        }
        let all: Vec<f64> = per_exp.iter().flatten().copied().collect();
        let ok = all.iter().filter(|&&v| v <= 0.5).count();
        eprintln!(
            "  {ok}/48 ≤ 0.5 mg, median {:.3} mg, max {:.3} mg",
            median(&all),
            all.iter().fold(0.0f64, |m, &v| m.max(v))
        );
        results.push(per_exp);
    }
    eprintln!("uncalibrated (nominal 2048 counts/g, no bias), odd poses, mg:");
    for (e, p) in d.iter().enumerate() {
        let (_, odd) = split(p);
        let row: Vec<f64> = (0..8)
            .map(|i| {
                rms(odd.iter().map(|q| {
                    let a = q.accel_g[i];
                    ((a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt() - 1.0) * 1e3
                }))
            })
            .collect();
        eprintln!("  exp_{}: {}", e + 1, fmt(&row));
        assert!(row.iter().all(|v| (10.0..50.0).contains(v)));
    }
    let default: Vec<f64> = results[2].iter().flatten().copied().collect();
    let ok = default.iter().filter(|&&v| v <= 0.5).count();
    assert!(ok * 10 >= 48 * 9, "{ok}/48 pairs ≤ 0.5 mg");
    // The misfit of exp_6 under a plain affine model, and its cure.
    assert!(
        median(&results[0][5]) > 0.6,
        "exp_6 misfits the affine model: {:?}",
        results[0][5]
    );
    assert!(
        results[2][5].iter().all(|&v| v <= 0.5),
        "bias drift model fixes exp_6: {:?}",
        results[2][5]
    );
}

/// The exp_6 misfit: residual pattern of the affine model on all 20 poses (opposite signs on the top and bottom
/// IMUs: a sensor-frame effect, not a pose with motion), and the drift that explains it.
#[test]
fn exp6_misfit_is_a_bias_drift() {
    let d = data_or_skip!();
    let mut drift_z = Vec::new();
    for (e, p) in d.iter().enumerate() {
        let plain = calibrate_static(
            p,
            &StaticCalOptions {
                refine: false,
                ..Default::default()
            },
        )
        .unwrap();
        let drift = calibrate_static(p, &StaticCalOptions::default()).unwrap();
        let before: Vec<f64> = plain.report.imus.iter().map(|r| r.table_rms_mg).collect();
        let after: Vec<f64> = drift.report.imus.iter().map(|r| r.after_rms_mg).collect();
        let dz: Vec<f64> = drift
            .imus
            .iter()
            .map(|c| c.accel_bias_drift_counts_per_s[2] * 100.0)
            .collect();
        let gyro: Vec<f64> = drift
            .imus
            .iter()
            .map(|c| {
                let g = c.gyro_bias_drift_counts_per_s;
                (g[0] * g[0] + g[1] * g[1] + g[2] * g[2]).sqrt() * 100.0
            })
            .collect();
        let change = p.iter().fold(0.0f64, |m, q| m.max(q.accel_change_mg));
        eprintln!(
            "exp_{}: all-pose RMS, affine {} | with drift {}\n        accel z-bias drift, counts/100 s: {}\n        |gyro bias drift|, counts/100 s: {}\n        largest in-pose change {change:.2} mg",
            e + 1,
            fmt(&before),
            fmt(&after),
            fmt(&dz),
            fmt(&gyro)
        );
        drift_z.push(median(&dz.iter().map(|v| v.abs()).collect::<Vec<_>>()));
        if e == 5 {
            let res = plain.residuals_mg(p, false);
            eprintln!(
                "exp_6 affine residuals per pose, mg (top IMUs 1, 3, 5, 7 vs bottom 2, 4, 6, 8):"
            );
            for (i, r) in res.iter().enumerate() {
                eprintln!("  IMU {}: {}", i + 1, fmt(r));
            }
            // Top and bottom IMUs misfit with opposite signs: correlation of IMU 1 with IMU 2 < 0, with IMU 3 > 0.
            let corr = |a: &[f64], b: &[f64]| {
                a.iter().zip(b).map(|(x, y)| x * y).sum::<f64>()
                    / (rms(a) * rms(b) * a.len() as f64)
            };
            assert!(corr(&res[0], &res[1]) < -0.5 && corr(&res[0], &res[2]) > 0.5);
            assert!(
                after.iter().all(|&v| v < 0.25) && median(&before) > 0.35,
                "{before:?} {after:?}"
            );
            assert!(change < 3.0, "no pose with motion");
        }
    }
    assert!(
        drift_z[5] > 2.0 * drift_z.iter().take(5).fold(0.0f64, |m, &v| m.max(v)),
        "{drift_z:?}"
    );
}

/// (b) Alignment residual of every IMU to the common frame, full fit of each experiment.
#[test]
fn alignment_residuals() {
    let d = data_or_skip!();
    for (name, opts) in [
        (
            "per-IMU + Procrustes",
            StaticCalOptions {
                refine: false,
                ..Default::default()
            },
        ),
        ("default", StaticCalOptions::default()),
    ] {
        eprintln!("(b) {name}: alignment residual RMS, degrees, IMU 1 … 8");
        for (e, p) in d.iter().enumerate() {
            let cal = calibrate_static(p, &opts).unwrap();
            let a: Vec<f64> = cal
                .report
                .imus
                .iter()
                .map(|r| r.alignment_rms_deg)
                .collect();
            eprintln!(
                "  exp_{}: {}",
                e + 1,
                a.iter()
                    .map(|x| format!("{x:.4}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            );
            assert!(a.iter().all(|&v| v <= 0.2), "exp_{}: {a:?}", e + 1);
        }
    }
    let cal = calibrate_static(&d[0], &StaticCalOptions::default()).unwrap();
    eprintln!("exp_1 rotations into IMU 1's frame:");
    for (i, c) in cal.imus.iter().enumerate() {
        eprintln!(
            "  IMU {}: {:?}",
            i + 1,
            c.rotation.map(|r| r.map(|v| (v * 1e4).round() / 1e4))
        );
    }
}

/// (c) Repeatability: exp_1's calibration applied to exp_2 … exp_6, then with biases re-estimated.
#[test]
fn repeatability_and_biases_only() {
    let d = data_or_skip!();
    let cal = calibrate_static(&d[0], &StaticCalOptions::default()).unwrap();
    let file = cal.to_file(1, "exp_1");
    let mut bias_only = Vec::new();
    eprintln!("(c) exp_1 calibration on exp_k: |a| − 1 g RMS over the 20 poses, mg, IMU 1 … 8");
    for (e, p) in d.iter().enumerate().skip(1) {
        let table: Vec<f64> = cal
            .residuals_mg(p, false)
            .iter()
            .map(|r| rms(r.iter()))
            .collect();
        let (_, up) = reestimate_biases(&file, p, &BiasOptions::default()).unwrap();
        // Also out of sample: biases from the even poses, tested on the odd ones.
        let (even, odd) = split(p);
        let (f2, _) = reestimate_biases(&file, &even, &BiasOptions::default()).unwrap();
        let oos: Vec<f64> = (0..8)
            .map(|i| {
                let g = &f2.groups[i];
                rms(odd.iter().map(|q| {
                    let m = linalg::mat3(&g.accel_matrix_g_per_count);
                    ((m * (linalg::vec3(&q.accel_counts[i]) - linalg::vec3(&g.accel_bias_counts)))
                        .norm()
                        - 1.0)
                        * 1e3
                }))
            })
            .collect();
        eprintln!(
            "  exp_{}: exp_1 table   {}  (median {:.2})\n         biases-only   {}  (median {:.2})\n         even→odd      {}  (median {:.2})",
            e + 1,
            fmt(&table),
            median(&table),
            fmt(&up.new_rms_mg),
            median(&up.new_rms_mg),
            fmt(&oos),
            median(&oos)
        );
        assert!(median(&table) > 0.5, "biases shift between runs");
        assert!(table.iter().all(|&v| v < 10.0));
        assert!(up.method.iter().all(|&m| m == BiasMethod::Magnitude));
        bias_only.extend(up.new_rms_mg);
    }
    let m = median(&bias_only);
    eprintln!("biases-only median over the 40 IMUs of exp_2 … exp_6: {m:.3} mg");
    assert!(m <= 0.5, "{m}");
}

/// The exp_1 calibration as files, and its table applied in fixed point to the pose means.
#[test]
fn exp1_table_in_fixed_point() {
    let d = data_or_skip!();
    let cal = calibrate_static(&d[0], &StaticCalOptions::default()).unwrap();
    eprintln!("exp_1 calibration report:\n{}", cal.report.to_text());
    let file = cal.to_file(1, "shared/data/mimu4444/exp_1");
    let table = file.to_table::<8>().unwrap();
    let mut buf = vec![0u8; shared::calib::encoded_len_max(8)];
    let bytes = table.encode(&mut buf).unwrap();
    assert_eq!(
        shared::calib::CalibrationTable::<8>::decode(bytes).unwrap(),
        table
    );
    eprintln!("encoded table: {} bytes", bytes.len());
    for (i, r) in cal.report.imus.iter().enumerate() {
        assert!(
            r.after_rms_mg < 0.7 && r.table_rms_mg < 1.0,
            "IMU {}: {r:?}",
            i + 1
        );
    }
    // Fixed point vs f64 on every pose mean rounded to counts (quantisation ≤ 0.5 count ≈ 0.25 mg per axis).
    for p in &d[0] {
        for (i, g) in table.groups.iter().enumerate() {
            let raw = p.accel_counts[i].map(|v| v.round() as i32);
            let out = g.apply(&shared::calib::RawCounts {
                gyro: [0; 4],
                accel: raw,
            });
            let f = cal.imus[i].accel_g(&raw.map(f64::from), 0.0);
            for r in 0..3 {
                assert!((f64::from(out[3 + r]) * 1e-6 - f[r]).abs() < 2e-6);
            }
        }
    }
}
