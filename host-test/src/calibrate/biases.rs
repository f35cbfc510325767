//! Biases-only re-calibration (`--biases-only`): a calibration's matrices (and so its rotations) are kept and
//! only the biases are re-estimated from a new static record.
//!
//! * Accelerometer, [`BiasMethod::Magnitude`]: the bias that makes `|M·(a_k − b)| = 1 g` over the poses present
//!   (Levenberg–Marquardt from the old bias). Used when the poses' gravity directions spread: the smallest
//!   singular value of the `k × 3` matrix of unit directions, divided by `√k`, is at least
//!   [`BiasOptions::min_spread`] (default 0.3; six ±axis poses give 0.577, one pose or two give 0).
//! * Accelerometer, [`BiasMethod::GravityFromOld`] (fewer or clustered poses, e.g. a single one): each pose's
//!   gravity direction is taken from the old calibration, `u_k = M(a_k − b_old)/|…|`, and
//!   `b = mean_k (a_k − M⁻¹·u_k)`, i.e. the bias that makes the calibrated vector exactly 1 g in that direction.
//! * Gyro: the mean over the static intervals (weighted by their lengths).

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::file::CalibrationFile;
use super::linalg::{arrv, levenberg_marquardt, mat3, vec3};
use super::{CalibError, StaticInterval, Vec3};

/// How the accelerometer biases were re-estimated.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BiasMethod {
    /// `|a| = 1 g` over spread poses.
    Magnitude,
    /// Gravity direction of each pose from the old calibration.
    GravityFromOld,
}

/// Options of [`reestimate_biases`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BiasOptions {
    /// Smallest direction spread for [`BiasMethod::Magnitude`] (see the module docs). Default 0.3.
    pub min_spread: f64,
    /// Re-estimate the gyro biases too. Default `true`.
    pub gyro: bool,
    /// Iteration limit. Default 50.
    pub max_iterations: usize,
}

impl Default for BiasOptions {
    fn default() -> Self {
        Self {
            min_spread: 0.3,
            gyro: true,
            max_iterations: 50,
        }
    }
}

/// What [`reestimate_biases`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct BiasUpdate {
    /// Method per IMU.
    pub method: Vec<BiasMethod>,
    /// Direction spread per IMU (see the module docs).
    pub spread: Vec<f64>,
    /// New accelerometer biases, counts.
    pub accel_bias_counts: Vec<Vec3>,
    /// New gyro biases (channels x, y, z), counts.
    pub gyro_bias_counts: Vec<Vec3>,
    /// Static `|a| − 1 g` RMS with the old biases, mg, per IMU.
    pub old_rms_mg: Vec<f64>,
    /// The same with the new biases.
    pub new_rms_mg: Vec<f64>,
}

fn rms_mg(m: &Matrix3<f64>, b: &Vector3<f64>, a: &[Vector3<f64>]) -> f64 {
    let s: f64 = a.iter().map(|x| ((m * (x - b)).norm() - 1.0).powi(2)).sum();
    (s / a.len().max(1) as f64).sqrt() * 1e3
}

/// Checks the poses against the calibration's `n` IMUs (counts, finite means) and the options.
fn check_poses(n: usize, poses: &[StaticInterval], opts: &BiasOptions) -> Result<(), CalibError> {
    if poses.is_empty() {
        return Err(CalibError::TooFewPoses {
            needed: 1,
            found: 0,
        });
    }
    if !(opts.min_spread.is_finite() && opts.min_spread >= 0.0) {
        return Err(CalibError::InvalidOption("min_spread must be ≥ 0"));
    }
    for p in poses {
        for len in [p.accel_counts.len(), p.gyro_counts.len()] {
            if len != n {
                return Err(CalibError::Count {
                    what: "IMUs per pose",
                    expected: n,
                    found: len,
                });
            }
        }
        if !p
            .accel_counts
            .iter()
            .chain(&p.gyro_counts)
            .flatten()
            .all(|x| x.is_finite())
        {
            return Err(CalibError::NonFinite("pose means"));
        }
    }
    Ok(())
}

/// The accelerometer bias that makes every pose's specific force 1 g (Levenberg–Marquardt from `b_old`), matrix `m`
/// kept; `a` the poses' mean counts.
fn magnitude_fit(
    m: &Matrix3<f64>,
    b_old: &Vector3<f64>,
    a: &[Vector3<f64>],
    max_iterations: usize,
) -> Result<Vector3<f64>, CalibError> {
    let k = a.len();
    let eval = |p: &DVector<f64>| {
        let b = Vector3::new(p[0], p[1], p[2]);
        let mut r = DVector::zeros(k);
        let mut j = DMatrix::zeros(k, 3);
        for (row, x) in a.iter().enumerate() {
            let y = m * (x - b);
            let nrm = y.norm().max(1e-300);
            r[row] = nrm - 1.0;
            let d = -(m.transpose() * (y / nrm));
            for c in 0..3 {
                j[(row, c)] = d[c];
            }
        }
        (r, j)
    };
    let res = levenberg_marquardt(
        DVector::from_column_slice(b_old.as_slice()),
        eval,
        |x, dx| x + dx,
        max_iterations,
    )
    .ok_or(CalibError::NonFinite("bias fit"))?;
    Ok(Vector3::new(res.x[0], res.x[1], res.x[2]))
}

/// Re-estimates the biases of `cal` (one group per IMU, gyro channels `[x, y, z, ·]`) from static intervals of a
/// new record; returns the updated calibration (matrices unchanged, a line added to the metadata's history) and
/// what was done. Needs ≥ 1 pose.
pub fn reestimate_biases(
    cal: &CalibrationFile,
    poses: &[StaticInterval],
    opts: &BiasOptions,
) -> Result<(CalibrationFile, BiasUpdate), CalibError> {
    check_poses(cal.groups.len(), poses, opts)?;
    let n = cal.groups.len();
    let mut out = cal.clone();
    let mut up = BiasUpdate {
        method: Vec::with_capacity(n),
        spread: Vec::with_capacity(n),
        accel_bias_counts: Vec::with_capacity(n),
        gyro_bias_counts: Vec::with_capacity(n),
        old_rms_mg: Vec::with_capacity(n),
        new_rms_mg: Vec::with_capacity(n),
    };
    let total: f64 = poses.iter().map(|p| p.frames().max(1) as f64).sum();
    for (i, g) in out.groups.iter_mut().enumerate() {
        let m = mat3(&g.accel_matrix_g_per_count);
        let m_inv = m
            .try_inverse()
            .ok_or(CalibError::Degenerate("accelerometer matrix is singular"))?;
        let b_old = vec3(&g.accel_bias_counts);
        let a: Vec<Vector3<f64>> = poses.iter().map(|p| vec3(&p.accel_counts[i])).collect();
        let dirs: Vec<Vector3<f64>> = a
            .iter()
            .map(|x| {
                (m * (x - b_old))
                    .try_normalize(1e-300)
                    .ok_or(CalibError::Degenerate("zero specific force"))
            })
            .collect::<Result<_, _>>()?;
        let k = a.len();
        let u = DMatrix::from_fn(k, 3, |r, c| dirs[r][c]);
        let spread = super::linalg::svd(u, false)
            .map_or(0.0, |s| s.singular_values.min() / (k as f64).sqrt());
        let magnitude = k >= 3 && spread >= opts.min_spread;
        let b_new = if magnitude {
            magnitude_fit(&m, &b_old, &a, opts.max_iterations)?
        } else {
            a.iter()
                .zip(&dirs)
                .fold(Vector3::zeros(), |acc, (x, u)| acc + (x - m_inv * u))
                / k as f64
        };
        up.old_rms_mg.push(rms_mg(&m, &b_old, &a));
        up.new_rms_mg.push(rms_mg(&m, &b_new, &a));
        up.method.push(if magnitude {
            BiasMethod::Magnitude
        } else {
            BiasMethod::GravityFromOld
        });
        up.spread.push(spread);
        g.accel_bias_counts = arrv(&b_new);
        up.accel_bias_counts.push(g.accel_bias_counts);
        if opts.gyro {
            for r in 0..3 {
                g.gyro_bias_counts[r] = poses
                    .iter()
                    .map(|p| p.gyro_counts[i][r] * p.frames().max(1) as f64)
                    .sum::<f64>()
                    / total;
            }
        }
        up.gyro_bias_counts.push([
            g.gyro_bias_counts[0],
            g.gyro_bias_counts[1],
            g.gyro_bias_counts[2],
        ]);
    }
    if let Some(meta) = out.metadata.as_mut() {
        meta.history.push(format!(
            "biases re-estimated on {} poses ({}){}",
            poses.len(),
            match up.method.first() {
                Some(BiasMethod::Magnitude) => "|a| = 1 g",
                _ => "gravity direction from the old calibration",
            },
            if opts.gyro { ", gyro biases too" } else { "" }
        ));
        for (im, rms) in meta.imus.iter_mut().zip(&up.new_rms_mg) {
            im.residual.after_rms_mg = *rms;
            im.residual.table_rms_mg = *rms;
        }
    }
    Ok((out, up))
}
