//! Acceptance of `ground calibrate --rate-table`: 18 recordings made with `ground simulate` (six orientations ×
//! {+Ω, −Ω, 0}, typical calibration errors per group: 1 % scale, 5 mrad misalignment, 1 °/s and 30 mg offsets, the
//! seed's sensor noise), written as frame logs and fitted by the same code as the command. Every group's
//! calibrated output at zero rate, at ±Ω and at 1 g is within the noise-limited accuracy the fit itself reports.

use host_test::calibrate::{RateTableOptions, board_records, fit_rate_table, standard_inputs};
use host_test::formats::framelog::FrameLog;
use host_test::sim::output::{frame_opts, write};
use host_test::sim::preset::seed_config;
use host_test::sim::{CalSpread, Simulator};

/// A test input: rate (°/s), specific force (g), the fit's standard errors of the checked output, gyro or accel.
type Case = ([f64; 3], [f64; 3], [f64; 3], bool);

#[test]
fn rate_table_fit_recovers_the_simulated_calibration() {
    let omega = 100.0;
    let dir = std::env::temp_dir().join(format!("rate-table-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut logs = Vec::new();
    let mut truth = None;
    for (k, (_, rate, accel)) in standard_inputs(omega).into_iter().enumerate() {
        let mut cfg = seed_config(4242 + k as u64).unwrap(); // fresh noise in every record …
        cfg.board_seed = Some(99); // … of one and the same board
        cfg.samples = 4000;
        cfg.cal = CalSpread::typical();
        cfg.rate_dps = rate;
        cfg.accel_g = accel;
        cfg.frames = frame_opts(cfg.rate_hz, host_test::FPGA_BASE_RATE_HZ);
        let path = dir.join(format!("rec{k:02}.bin"));
        let sim: Simulator = write(cfg, &path, |_| ()).unwrap();
        truth.get_or_insert(*sim.true_cal());
        logs.push(FrameLog::decode(&std::fs::read(&path).unwrap()));
    }
    let truth = truth.unwrap();
    let groups = board_records(&logs, omega).unwrap();
    let (fits, file) = fit_rate_table::<16>(&groups, &RateTableOptions::default(), 7).unwrap();
    assert!(
        file.to_table::<16>().is_ok(),
        "the result must be an uploadable table"
    );

    // Compare calibrated outputs with the truth at test inputs, in units of the fit's reported standard errors.
    let (mut n, mut within3, mut worst) = (0, 0, 0f64);
    for ((fit, cal), g) in fits.iter().zip(&truth).zip(&file.groups) {
        let cases: [Case; 5] = [
            ([0.0; 3], [0.0, 0.0, 1.0], fit.rate_se_dps_at_zero, true),
            (
                [omega, 0.0, 0.0],
                [0.0, 0.0, 1.0],
                fit.rate_se_dps_at_omega[0],
                true,
            ),
            (
                [0.0, -omega, 0.0],
                [0.0, 0.0, 1.0],
                fit.rate_se_dps_at_omega[1],
                true,
            ),
            (
                [0.0, 0.0, omega],
                [1.0, 0.0, 0.0],
                fit.rate_se_dps_at_omega[2],
                true,
            ),
            ([0.0; 3], [0.0, 1.0, 0.0], fit.accel_se_g_at_1g[1], false),
        ];
        for (rate, accel, se, gyro) in cases {
            let codes = cal.codes_f64(&cal.readings(rate, accel));
            for axis in 0..3 {
                let (got, want) = if gyro {
                    let row = g.gyro_matrix_dps_per_count[axis];
                    (
                        (0..4)
                            .map(|j| row[j] * (codes[j] - g.gyro_bias_counts[j]))
                            .sum::<f64>(),
                        rate[axis],
                    )
                } else {
                    let row = g.accel_matrix_g_per_count[axis];
                    (
                        (0..3)
                            .map(|j| row[j] * (codes[4 + j] - g.accel_bias_counts[j]))
                            .sum::<f64>(),
                        accel[axis],
                    )
                };
                let z = (got - want).abs() / se[axis];
                n += 1;
                within3 += usize::from(z <= 3.0);
                worst = worst.max(z);
            }
        }
    }
    eprintln!("{within3}/{n} outputs within 3 reported standard errors, worst {worst:.2}");
    assert!(within3 as f64 >= 0.97 * n as f64, "{within3}/{n}");
    assert!(worst < 5.0, "worst {worst}");
    let _ = std::fs::remove_dir_all(&dir);
}
