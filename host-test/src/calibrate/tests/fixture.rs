//! The repository's excerpt of exp_1 (`testdata/mimu4444/exp1_excerpt.bin`): 12 slices of 2.4 s from 12 static
//! poses. These tests need nothing outside the repository.

use shared::calib::{CalibrationTable, RawCounts};

use super::rms;
use crate::calibrate::*;
use crate::formats::mimu::{self, FRAME_LEN};

const SLICE_STARTS: [usize; 12] = [
    2270, 3730, 6723, 8230, 11306, 12806, 14295, 17528, 20584, 25154, 28301, 30038,
];

fn excerpt() -> mimu::Recording {
    mimu::read(data::fixture_excerpt()).unwrap()
}

fn detect_opts() -> DetectOptions {
    DetectOptions {
        window_s: 0.5,
        min_duration_s: 1.5,
        trim_s: 0.2,
        ..Default::default()
    }
}

#[test]
fn excerpt_parses_with_its_gaps() {
    let bytes = std::fs::read(data::fixture_excerpt()).unwrap();
    assert!(bytes.len() <= 200_000);
    let rec = mimu::parse_with(
        &bytes,
        &mimu::ParseOptions {
            strict: false,
            max_skipped_fraction: 0.0,
        },
    )
    .unwrap();
    let s = &rec.stats;
    assert!(s.ack);
    assert_eq!(s.frames, 1800);
    assert_eq!(s.bytes_skipped, 0);
    assert_eq!(s.checksum_failures, 0);
    assert_eq!(s.packet_gaps, 11);
    let gap_frames: usize = SLICE_STARTS.windows(2).map(|w| w[1] - w[0] - 150).sum();
    assert_eq!(s.packets_missing, gap_frames as u64);
    assert_eq!(
        s.timestamp_jumps, 0,
        "timestamps agree with the packet numbers across the gaps"
    );
    // 32-bit wraps at frames 2342 (inside the first slice), then every 4194.3 frames up to 30188.
    assert_eq!(s.timestamp_wraps, 7);
    let want_s = (SLICE_STARTS[11] + 149 - SLICE_STARTS[0]) as f64 / 62.5;
    assert!(
        (rec.duration_s() - want_s).abs() < 0.05,
        "{} vs {want_s}",
        rec.duration_s()
    );
    assert_eq!(rec.discontinuity.iter().filter(|&&d| d).count(), 11);
    assert_eq!(rec.offsets[150], 4 + 150 * FRAME_LEN);
    // Strict mode stops at the first gap, at its offset.
    let e = mimu::parse_with(
        &bytes,
        &mimu::ParseOptions {
            strict: true,
            ..Default::default()
        },
    )
    .unwrap_err();
    assert!(
        e.to_string()
            .contains(&format!("byte {}", 4 + 150 * FRAME_LEN)),
        "{e}"
    );
}

#[test]
fn excerpt_static_poses_and_calibration() {
    let rec = excerpt();
    let poses = detect_static(&rec, &detect_opts()).unwrap();
    assert_eq!(poses.len(), 12, "one interval per slice, none across a gap");
    for (k, p) in poses.iter().enumerate() {
        assert!(
            p.first_frame >= 150 * k && p.end_frame <= 150 * (k + 1),
            "{k}: {p:?}"
        );
        assert!(p.accel_std_g < 0.01 && p.gyro_std_dps < 0.5);
        for a in &p.accel_g {
            let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
            assert!((0.9..1.1).contains(&n), "{n}");
        }
    }
    // Default detection (1 s window, 15 s minimum) finds nothing in 2.4 s slices.
    assert!(
        detect_static(&rec, &DetectOptions::default())
            .unwrap()
            .is_empty()
    );

    let cal = calibrate_static(&poses, &StaticCalOptions::default()).unwrap();
    eprintln!("excerpt calibration:\n{}", cal.report.to_text());
    for r in &cal.report.imus {
        assert!((10.0..50.0).contains(&r.before_rms_mg), "{r:?}");
        assert!(r.after_rms_mg < 1.0 && r.table_rms_mg < 1.5, "{r:?}");
        assert!(r.alignment_rms_deg < 0.2, "{r:?}");
    }
    let mut t: Vec<f64> = cal.report.imus.iter().map(|r| r.after_rms_mg).collect();
    t.sort_by(f64::total_cmp);
    assert!(t[4] < 0.4, "median {t:?}");
    // Even IMUs are turned 180° about (1, −1, 0)/√2 relative to IMU 1 (bottom side of the board).
    for (i, c) in cal.imus.iter().enumerate() {
        let want = if i % 2 == 1 {
            [[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, -1.0]]
        } else {
            [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
        };
        for (got_row, want_row) in c.rotation.iter().zip(&want) {
            for (got, w) in got_row.iter().zip(want_row) {
                assert!((got - w).abs() < 0.03, "IMU {}: {:?}", i + 1, c.rotation);
            }
        }
    }

    // Table: the fixed-point chain on every raw sample reproduces the f64 calibration.
    let file = cal.to_file(3, "exp1_excerpt");
    let table: CalibrationTable<8> = file.to_table().unwrap();
    for p in &poses {
        for (i, g) in table.groups.iter().enumerate() {
            let mut sum = [0i64; 3];
            for f in &rec.frames[p.first_frame..p.end_frame] {
                let s = f.imu[i];
                let out = g.apply(&RawCounts {
                    gyro: [s.gyro[0].into(), s.gyro[1].into(), s.gyro[2].into(), 0],
                    accel: s.acc.map(i32::from),
                });
                for r in 0..3 {
                    sum[r] += i64::from(out[3 + r]);
                }
            }
            let n = p.frames() as f64;
            let fixed = sum.map(|v| v as f64 / n * 1e-6);
            let float = cal.imus[i].accel_g(&p.accel_counts[i], 0.0);
            for r in 0..3 {
                assert!(
                    (fixed[r] - float[r]).abs() < 2e-6,
                    "{} vs {}",
                    fixed[r],
                    float[r]
                );
            }
        }
    }

    // Readable forms round-trip; the .bin is the table's encoding.
    let dir = std::env::temp_dir().join(format!("calib-fixture-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for ext in ["json", "toml", "bin"] {
        let path = dir.join(format!("cal.{ext}"));
        write_calibration::<8>(&file, &path).unwrap();
        let back = read_calibration::<8>(&path).unwrap();
        if ext == "bin" {
            assert_eq!(back.to_table::<8>().unwrap(), table);
        } else {
            assert_eq!(back, file);
        }
    }

    // Biases-only on the same poses keeps the matrices and does not get worse.
    let (again, up) = reestimate_biases(&file, &poses, &BiasOptions::default()).unwrap();
    assert!(up.method.iter().all(|&m| m == BiasMethod::Magnitude));
    for i in 0..8 {
        assert_eq!(
            again.groups[i].accel_matrix_g_per_count,
            file.groups[i].accel_matrix_g_per_count
        );
        assert!(up.new_rms_mg[i] <= up.old_rms_mg[i] + 1e-9);
    }
    let r = static_residuals_mg(&cal.imus, None, &poses);
    assert!((rms(&r[0]) - cal.report.imus[0].table_rms_mg).abs() < 1e-12);
}
