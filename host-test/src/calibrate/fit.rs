//! Multi-position static calibration of an array of 3-axis IMUs on one rigid board.
//!
//! 1. [`fit_magnitude`], per IMU: accelerometer bias `b` and symmetric matrix `M` so that `|M·(a_k − b)| = 1 g`
//!    in every static pose `k` (9 parameters; the magnitude does not see a rotation, so `M` is taken symmetric,
//!    the rotation comes in step 2). Start: algebraic ellipsoid fit (linear least squares on the quadric
//!    `xᵀAx + lᵀx = 1`, `M = √Q`); then Levenberg–Marquardt on the residuals `|M(a_k − b)| − 1`.
//! 2. [`align_cluster`]: the rotation `R_i` of each IMU into the cluster frame, from the gravity directions
//!    `M_i(a_ik − b_i)/|…|` of all poses: generalised orthogonal Procrustes (Wahba, SVD with `det = +1`), each IMU
//!    against the cluster mean direction, 10 rounds, then re-expressed so that the reference IMU's rotation is the
//!    identity. Calibration matrix `K_i = R_i·M_i` (cluster frame).
//! 3. [`refine_cluster`] (optional, on by default): all IMUs together with the forward model
//!    `a_ik = K_i⁻¹·u_k + b_i + ḃ_i·(t_k − t_ref)` (`u_k` the unit gravity direction of pose `k`, shared by all
//!    IMUs; `K_i` a full 3×3; `ḃ_i` the bias drift, [`BiasModel::LinearDrift`]), residuals weighted by each
//!    channel's noise, Levenberg–Marquardt; a weak Gaussian prior on the drift
//!    ([`StaticCalOptions::drift_prior_mg_per_100s`]) keeps the problem determined when few poses are given
//!    (the drift common to all IMUs in the cluster frame is seen only through the 1 g magnitude). The rotation
//!    gauge is fixed afterwards so that the polar rotation of the reference IMU's `K` is the identity.
//! 4. Gyros: matrix = `R_i ×` nominal scale (gyro and accelerometer share the die; `R_i` is the polar rotation
//!    of `K_i`), bias = mean over the static intervals (the Earth rate, ≤ 0.004 °/s, is ignored).

use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

use super::linalg::{
    angle, arr3, arrv, levenberg_marquardt, mat3, polar, relative_singular_values, sqrt_spd, vec3,
    wahba,
};
use super::report::{ResidualReport, static_residuals_mg};
use super::{CalibError, Mat3, StaticInterval, Vec3};
use crate::formats::mimu::{ACCEL_LSB_PER_G, GYRO_LSB_PER_DPS};
use crate::stats::rms;

mod refine;
pub use refine::{ClusterFit, refine_cluster};
use refine::{poses_imus, t_ref};

/// Fewest poses for the 9-parameter accelerometer model.
pub const MIN_POSES: usize = 9;

/// How the accelerometer bias may change during a static record.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum BiasModel {
    /// Constant bias.
    Constant,
    /// Bias linear in time (warm-up), `b + ḃ·(t − t_ref)`; the table keeps the bias at `t_ref`.
    LinearDrift,
}

/// Options of [`calibrate_static`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StaticCalOptions {
    /// Nominal accelerometer scale, g per count (start value and normalisation). Default 1/2048.
    pub accel_g_per_count: f64,
    /// Nominal gyro scale, °/s per count (the gyro matrix is the rotation times this). Default 1/16.4.
    pub gyro_dps_per_count: f64,
    /// IMU whose frame is the cluster frame (index). Default 0 (IMU 1).
    pub reference_imu: usize,
    /// Run the joint refinement [`refine_cluster`]. Default `true`.
    pub refine: bool,
    /// Bias model of the joint refinement. Default [`BiasModel::LinearDrift`].
    pub bias_model: BiasModel,
    /// Standard deviation of the Gaussian prior on each drift component, mg per 100 s. Default 5 (observed
    /// warm-up drifts: up to 2.2 mg per 100 s).
    pub drift_prior_mg_per_100s: f64,
    /// Iteration limit of each Levenberg–Marquardt run. Default 200.
    pub max_iterations: usize,
}

impl Default for StaticCalOptions {
    fn default() -> Self {
        Self {
            accel_g_per_count: 1.0 / ACCEL_LSB_PER_G,
            gyro_dps_per_count: 1.0 / GYRO_LSB_PER_DPS,
            reference_imu: 0,
            refine: true,
            bias_model: BiasModel::LinearDrift,
            drift_prior_mg_per_100s: 5.0,
            max_iterations: 200,
        }
    }
}

/// Result of [`fit_magnitude`] for one accelerometer.
#[derive(Clone, Debug, PartialEq)]
pub struct MagnitudeFit {
    /// Symmetric matrix, g per count.
    pub matrix_g_per_count: Mat3,
    /// Bias, counts.
    pub bias_counts: Vec3,
    /// `|M(a_k − b)| − 1 g` per pose, mg.
    pub residuals_mg: Vec<f64>,
    /// RMS of `residuals_mg`.
    pub rms_mg: f64,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
}

fn check_finite(v: &[Vec3], what: &'static str) -> Result<(), CalibError> {
    if v.iter().flatten().all(|x| x.is_finite()) {
        Ok(())
    } else {
        Err(CalibError::NonFinite(what))
    }
}

fn sym_from(p: &[f64]) -> Matrix3<f64> {
    Matrix3::new(p[0], p[1], p[2], p[1], p[3], p[4], p[2], p[4], p[5])
}

/// Ellipsoid start: `(M, b)` in normalised units, or `None` if the quadric is not an ellipsoid.
fn ellipsoid(x: &[Vector3<f64>]) -> Option<(Matrix3<f64>, Vector3<f64>)> {
    let k = x.len();
    let a = DMatrix::from_fn(k, 9, |r, c| {
        let v = &x[r];
        match c {
            0 => v[0] * v[0],
            1 => v[1] * v[1],
            2 => v[2] * v[2],
            3 => 2.0 * v[0] * v[1],
            4 => 2.0 * v[0] * v[2],
            5 => 2.0 * v[1] * v[2],
            _ => v[c - 6],
        }
    });
    let p = super::linalg::svd(a, true)?
        .solve(&DVector::from_element(k, 1.0), 1e-12)
        .ok()?;
    let am = Matrix3::new(p[0], p[3], p[4], p[3], p[1], p[5], p[4], p[5], p[2]);
    let l = Vector3::new(p[6], p[7], p[8]);
    let b = -(am.try_inverse()? * l) / 2.0;
    let gamma = 1.0 + b.dot(&(am * b));
    let m = sqrt_spd(&(am / gamma))?;
    m.iter().all(|v| v.is_finite()).then_some((m, b))
}

/// Fits bias and symmetric matrix of one accelerometer to static means (counts) so that the calibrated specific
/// force has magnitude 1 g (see the module docs). Needs ≥ `MIN_POSES` poses spread over orientations.
pub fn fit_magnitude(
    accel_counts: &[Vec3],
    nominal_g_per_count: f64,
    max_iterations: usize,
) -> Result<MagnitudeFit, CalibError> {
    let k = accel_counts.len();
    if k < MIN_POSES {
        return Err(CalibError::TooFewPoses {
            needed: MIN_POSES,
            found: k,
        });
    }
    check_finite(accel_counts, "accelerometer means")?;
    if !(nominal_g_per_count.is_finite() && nominal_g_per_count > 0.0) {
        return Err(CalibError::InvalidOption("nominal scale must be > 0"));
    }
    let s0 = nominal_g_per_count;
    let c = accel_counts
        .iter()
        .fold(Vector3::zeros(), |acc, a| acc + vec3(a))
        / k as f64;
    let x: Vec<Vector3<f64>> = accel_counts.iter().map(|a| (vec3(a) - c) * s0).collect();
    // Static specific force is 1 g: at the nominal scale the centred readings must be of order 1 (this also keeps
    // absurd inputs, e.g. a wrong scale, away from the solver).
    let spread = (x.iter().map(Vector3::norm_squared).sum::<f64>() / k as f64).sqrt();
    if !(0.2..5.0).contains(&spread) {
        return Err(CalibError::Degenerate(
            "readings are not ≈ 1 g at the nominal scale around their mean (wrong scale, not static, or one orientation)",
        ));
    }
    let (m0, b0) = ellipsoid(&x).unwrap_or((Matrix3::identity(), Vector3::zeros()));
    let p0 = DVector::from_vec(vec![
        m0[(0, 0)],
        m0[(0, 1)],
        m0[(0, 2)],
        m0[(1, 1)],
        m0[(1, 2)],
        m0[(2, 2)],
        b0[0],
        b0[1],
        b0[2],
    ]);
    let eval = |p: &DVector<f64>| {
        let m = sym_from(&p.as_slice()[..6]);
        let b = Vector3::new(p[6], p[7], p[8]);
        let mut r = DVector::zeros(k);
        let mut j = DMatrix::zeros(k, 9);
        for (row, xk) in x.iter().enumerate() {
            let d = xk - b;
            let y = m * d;
            let n = y.norm().max(1e-300);
            let g = y / n;
            r[row] = n - 1.0;
            j[(row, 0)] = g[0] * d[0];
            j[(row, 1)] = g[0] * d[1] + g[1] * d[0];
            j[(row, 2)] = g[0] * d[2] + g[2] * d[0];
            j[(row, 3)] = g[1] * d[1];
            j[(row, 4)] = g[1] * d[2] + g[2] * d[1];
            j[(row, 5)] = g[2] * d[2];
            let db = -(m.transpose() * g);
            for q in 0..3 {
                j[(row, 6 + q)] = db[q];
            }
        }
        (r, j)
    };
    let res = levenberg_marquardt(p0, eval, |x, dx| x + dx, max_iterations)
        .ok_or(CalibError::NonFinite("accelerometer fit"))?;
    let sv = relative_singular_values(&res.jacobian);
    if sv.first().is_none_or(|&s| s < 1e-7) {
        return Err(CalibError::Degenerate(
            "the poses do not determine the accelerometer matrix (orientations not spread)",
        ));
    }
    let m = sym_from(&res.x.as_slice()[..6]);
    let b = Vector3::new(res.x[6], res.x[7], res.x[8]);
    let residuals_mg: Vec<f64> = x
        .iter()
        .map(|xk| ((m * (xk - b)).norm() - 1.0) * 1e3)
        .collect();
    Ok(MagnitudeFit {
        matrix_g_per_count: arr3(&(m * s0)),
        bias_counts: arrv(&(c + b / s0)),
        rms_mg: rms(&residuals_mg),
        residuals_mg,
        iterations: res.iterations,
    })
}

/// Result of [`align_cluster`].
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterAlignment {
    /// Rotation of each IMU's (calibrated) frame into the cluster frame; the reference IMU's is the identity.
    pub rotations: Vec<Mat3>,
    /// Mean gravity direction of each pose in the cluster frame (unit vectors).
    pub mean_directions: Vec<Vec3>,
    /// Angle between each IMU's rotated direction and the mean, per IMU per pose, degrees.
    pub residual_deg: Vec<Vec<f64>>,
    /// RMS over poses of `residual_deg`, per IMU.
    pub residual_rms_deg: Vec<f64>,
}

fn mean_dirs(rot: &[Matrix3<f64>], d: &[Vec<Vector3<f64>>]) -> Vec<Vector3<f64>> {
    let k = d.first().map_or(0, Vec::len);
    (0..k)
        .map(|p| {
            rot.iter()
                .zip(d)
                .fold(Vector3::zeros(), |acc, (r, di)| acc + r * di[p])
                .normalize()
        })
        .collect()
}

/// Rotations of every IMU into a common frame from the unit gravity directions each IMU saw in the same poses
/// (`directions[imu][pose]`, each IMU's own calibrated frame). Generalised Procrustes (see the module docs);
/// the `reference` IMU's rotation is the identity. Needs ≥ 2 poses with non-parallel directions.
pub fn align_cluster(
    directions: &[Vec<Vec3>],
    reference: usize,
) -> Result<ClusterAlignment, CalibError> {
    let n = directions.len();
    if reference >= n {
        return Err(CalibError::InvalidOption("reference IMU out of range"));
    }
    let k = directions[0].len();
    if let Some(d) = directions.iter().find(|d| d.len() != k) {
        return Err(CalibError::Count {
            what: "poses per IMU",
            expected: k,
            found: d.len(),
        });
    }
    if k < 2 {
        return Err(CalibError::TooFewPoses {
            needed: 2,
            found: k,
        });
    }
    for d in directions {
        check_finite(d, "gravity directions")?;
    }
    let d: Vec<Vec<Vector3<f64>>> = directions
        .iter()
        .map(|di| {
            di.iter()
                .map(|v| vec3(v).try_normalize(1e-300).unwrap_or_else(Vector3::zeros))
                .collect()
        })
        .collect();
    let degenerate = || CalibError::Degenerate("gravity directions do not determine a rotation");
    let mut rot: Vec<Matrix3<f64>> = d
        .iter()
        .map(|di| wahba(di, &d[reference]).ok_or_else(degenerate))
        .collect::<Result<_, _>>()?;
    for _ in 0..10 {
        let v = mean_dirs(&rot, &d);
        rot = d
            .iter()
            .map(|di| wahba(di, &v).ok_or_else(degenerate))
            .collect::<Result<_, _>>()?;
        let g = rot[reference].transpose();
        for r in &mut rot {
            *r = g * *r;
        }
    }
    let v = mean_dirs(&rot, &d);
    let residual_deg: Vec<Vec<f64>> = rot
        .iter()
        .zip(&d)
        .map(|(r, di)| {
            di.iter()
                .zip(&v)
                .map(|(x, m)| angle(&(r * x), m).to_degrees())
                .collect()
        })
        .collect();
    Ok(ClusterAlignment {
        rotations: rot.iter().map(arr3).collect(),
        mean_directions: v.iter().map(arrv).collect(),
        residual_rms_deg: residual_deg.iter().map(rms).collect(),
        residual_deg,
    })
}

/// Calibration of one IMU in physical units.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImuCal {
    /// Accelerometer matrix into the cluster frame, g per count: `a_g = M·(raw − b)`.
    pub accel_matrix_g_per_count: Mat3,
    /// Accelerometer bias at the calibration's reference time, counts.
    pub accel_bias_counts: Vec3,
    /// Accelerometer bias drift during the calibration record, counts per second (metadata: not in the table).
    pub accel_bias_drift_counts_per_s: Vec3,
    /// Gyro matrix into the cluster frame, °/s per count (rotation × nominal scale).
    pub gyro_matrix_dps_per_count: Mat3,
    /// Gyro bias, counts (mean over the static intervals).
    pub gyro_bias_counts: Vec3,
    /// Gyro bias drift during the record (least-squares slope over the poses), counts per second (metadata).
    pub gyro_bias_drift_counts_per_s: Vec3,
    /// Rotation of the IMU's frame into the cluster frame (polar rotation of the accelerometer matrix).
    pub rotation: Mat3,
}

impl ImuCal {
    /// Calibrated specific force, g, of a raw reading taken `dt_s` after the reference time (`dt_s = 0` gives the
    /// table's constant-bias model).
    pub fn accel_g(&self, raw_counts: &Vec3, dt_s: f64) -> Vec3 {
        let b = vec3(&self.accel_bias_counts) + vec3(&self.accel_bias_drift_counts_per_s) * dt_s;
        arrv(&(mat3(&self.accel_matrix_g_per_count) * (vec3(raw_counts) - b)))
    }

    /// Calibrated rate, °/s.
    pub fn rate_dps(&self, raw_counts: &Vec3) -> Vec3 {
        arrv(
            &(mat3(&self.gyro_matrix_dps_per_count)
                * (vec3(raw_counts) - vec3(&self.gyro_bias_counts))),
        )
    }
}

/// A static calibration of an IMU array.
#[derive(Clone, Debug, PartialEq)]
pub struct StaticCalibration {
    /// Per IMU.
    pub imus: Vec<ImuCal>,
    /// Reference time of the biases, seconds of the calibration record (mean of the poses' mid-times).
    pub t_ref_s: f64,
    /// Options used.
    pub options: StaticCalOptions,
    /// Residuals on the calibration poses.
    pub report: ResidualReport,
}

/// Least-squares slope of `y` against `t` (0 when `t` has no spread).
fn slope(t: &[f64], y: &[f64]) -> f64 {
    let n = t.len() as f64;
    let (mt, my) = (t.iter().sum::<f64>() / n, y.iter().sum::<f64>() / n);
    let stt: f64 = t.iter().map(|v| (v - mt).powi(2)).sum();
    if stt <= 0.0 {
        return 0.0;
    }
    t.iter()
        .zip(y)
        .map(|(a, b)| (a - mt) * (b - my))
        .sum::<f64>()
        / stt
}

/// Full static calibration from the static intervals of one record (see the module docs).
pub fn calibrate_static(
    poses: &[StaticInterval],
    opts: &StaticCalOptions,
) -> Result<StaticCalibration, CalibError> {
    let n = poses_imus(poses)?;
    if poses.len() < MIN_POSES {
        return Err(CalibError::TooFewPoses {
            needed: MIN_POSES,
            found: poses.len(),
        });
    }
    if opts.reference_imu >= n {
        return Err(CalibError::InvalidOption("reference IMU out of range"));
    }
    if !(opts.gyro_dps_per_count.is_finite() && opts.gyro_dps_per_count > 0.0) {
        return Err(CalibError::InvalidOption("gyro scale must be > 0"));
    }
    // 1. Per-IMU magnitude fits.
    let mags: Vec<MagnitudeFit> = (0..n)
        .map(|i| {
            let a: Vec<Vec3> = poses.iter().map(|p| p.accel_counts[i]).collect();
            fit_magnitude(&a, opts.accel_g_per_count, opts.max_iterations)
        })
        .collect::<Result<_, _>>()?;
    // 2. Alignment.
    let dirs: Vec<Vec<Vec3>> = mags
        .iter()
        .enumerate()
        .map(|(i, m)| {
            poses
                .iter()
                .map(|p| {
                    arrv(
                        &(mat3(&m.matrix_g_per_count)
                            * (vec3(&p.accel_counts[i]) - vec3(&m.bias_counts))),
                    )
                })
                .collect()
        })
        .collect();
    let al = align_cluster(&dirs, opts.reference_imu)?;
    let mut mats: Vec<Mat3> = mags
        .iter()
        .zip(&al.rotations)
        .map(|(m, r)| arr3(&(mat3(r) * mat3(&m.matrix_g_per_count))))
        .collect();
    let mut bias: Vec<Vec3> = mags.iter().map(|m| m.bias_counts).collect();
    let mut drift = vec![[0.0; 3]; n];
    let mut rotations = al.rotations.clone();
    let t0 = t_ref(poses);
    // 3. Joint refinement.
    if opts.refine {
        let cf = refine_cluster(poses, &mats, &bias, opts)?;
        mats = cf.accel_matrix_g_per_count;
        bias = cf.accel_bias_counts;
        drift = cf.accel_bias_drift_counts_per_s;
        rotations = mats
            .iter()
            .map(|m| {
                polar(&mat3(m))
                    .map(|(r, _)| arr3(&r))
                    .ok_or(CalibError::Degenerate("refined matrix is singular"))
            })
            .collect::<Result<_, _>>()?;
        // The gauge makes the reference rotation the identity; drop the rounding residue.
        rotations[opts.reference_imu] = arr3(&Matrix3::identity());
    }
    // 4. Gyros.
    let times: Vec<f64> = poses.iter().map(StaticInterval::mid_s).collect();
    let total: f64 = poses.iter().map(|p| p.frames().max(1) as f64).sum();
    let imus: Vec<ImuCal> = (0..n)
        .map(|i| {
            let gyro_bias_counts: Vec3 = core::array::from_fn(|r| {
                poses
                    .iter()
                    .map(|p| p.gyro_counts[i][r] * p.frames().max(1) as f64)
                    .sum::<f64>()
                    / total
            });
            let gyro_bias_drift_counts_per_s: Vec3 = core::array::from_fn(|r| {
                let y: Vec<f64> = poses.iter().map(|p| p.gyro_counts[i][r]).collect();
                slope(&times, &y)
            });
            ImuCal {
                accel_matrix_g_per_count: mats[i],
                accel_bias_counts: bias[i],
                accel_bias_drift_counts_per_s: drift[i],
                gyro_matrix_dps_per_count: arr3(&(mat3(&rotations[i]) * opts.gyro_dps_per_count)),
                gyro_bias_counts,
                gyro_bias_drift_counts_per_s,
                rotation: rotations[i],
            }
        })
        .collect();
    let report = ResidualReport::new(&imus, t0, poses, opts.accel_g_per_count);
    Ok(StaticCalibration {
        imus,
        t_ref_s: t0,
        options: *opts,
        report,
    })
}

impl StaticCalibration {
    /// `|a| − 1 g` per IMU per pose, mg, of this calibration on (other) poses; `with_drift` applies the bias
    /// drift relative to [`Self::t_ref_s`] (meaningful only for poses of the calibration record).
    pub fn residuals_mg(&self, poses: &[StaticInterval], with_drift: bool) -> Vec<Vec<f64>> {
        static_residuals_mg(&self.imus, with_drift.then_some(self.t_ref_s), poses)
    }
}
