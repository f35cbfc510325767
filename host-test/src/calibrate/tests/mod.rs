//! Tests of the calibration: synthetic arrays with known parameters, the repository's excerpt of exp_1, and the
//! acceptance figures on the real recordings (skipped when `shared/data/mimu4444` is absent).

mod biases;
mod file;
mod fixture;
mod rate_table;
mod real_data;
mod synthetic;

use super::{StaticInterval, Vec3};

/// Deterministic generator (SplitMix64) with uniform and normal draws.
pub(super) struct Rng(u64);

impl Rng {
    pub(super) fn new(seed: u64) -> Self {
        Self(seed)
    }

    pub(super) fn next_u64(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^ (z >> 31)
    }

    /// Uniform in [0, 1).
    pub(super) fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// Standard normal (Box–Muller).
    pub(super) fn normal(&mut self) -> f64 {
        let u1 = self.uniform().max(1e-300);
        let u2 = self.uniform();
        (-2.0 * u1.ln()).sqrt() * (2.0 * std::f64::consts::PI * u2).cos()
    }

    /// Uniform unit vector.
    pub(super) fn unit(&mut self) -> Vec3 {
        loop {
            let v = [self.normal(), self.normal(), self.normal()];
            let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
            if n > 1e-6 {
                return v.map(|x| x / n);
            }
        }
    }
}

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

/// RMS of a slice (0 for an empty one).
pub(super) fn rms(v: &[f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt()
}
