//! Tests of the calibration: synthetic arrays with known parameters, the repository's excerpt of exp_1, and the
//! acceptance figures on the real recordings (skipped when `shared/data/mimu4444` is absent).

mod biases;
mod file;
mod fixture;
mod rate_table;
mod real_data;
mod synthetic;

use super::{StaticInterval, Vec3};

pub(super) use crate::stats::rms;
pub(super) use crate::testrng::TestRng as Rng;

/// A near-identity accelerometer (2048 counts/g, 1 % scale and misalignment spread) and its biases (40 counts
/// rms), drawn in that order.
pub(super) fn accel_near_identity(rng: &mut Rng) -> ([[f64; 3]; 3], [f64; 3]) {
    let matrix_g_per_count = core::array::from_fn(|r| {
        core::array::from_fn(|c| (f64::from(u8::from(r == c)) + 0.01 * rng.normal()) / 2048.0)
    });
    let bias_counts = [
        rng.normal() * 40.0,
        rng.normal() * 40.0,
        rng.normal() * 40.0,
    ];
    (matrix_g_per_count, bias_counts)
}

/// A static interval with the given means (1500 frames, standard errors `sem_counts` on every channel).
pub(super) fn interval(
    start_s: f64,
    accel_counts: Vec<Vec3>,
    gyro_counts: Vec<Vec3>,
    sem_counts: f64,
) -> StaticInterval {
    let n = accel_counts.len();
    StaticInterval {
        first_frame: (start_s * 62.5) as usize,
        end_frame: (start_s * 62.5) as usize + 1500,
        start_s,
        end_s: start_s + 24.0,
        accel_g: accel_counts.iter().map(|a| a.map(|x| x / 2048.0)).collect(),
        accel_counts,
        gyro_counts,
        accel_sem_counts: vec![[sem_counts; 3]; n],
        gyro_sem_counts: vec![[sem_counts; 3]; n],
        accel_std_g: 0.005,
        gyro_std_dps: 0.25,
        accel_change_mg: 0.0,
    }
}
