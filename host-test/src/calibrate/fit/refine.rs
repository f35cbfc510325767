//! Step 3 of the static calibration: all IMUs refined together with the forward model (see the parent module).

use super::{BiasModel, MIN_POSES, StaticCalOptions, check_finite};
use crate::calibrate::linalg::{arr3, arrv, levenberg_marquardt, mat3, polar, vec3};
use crate::calibrate::{CalibError, Mat3, StaticInterval, Vec3};
use nalgebra::{DMatrix, DVector, Matrix3, Vector3};

/// Result of [`refine_cluster`].
#[derive(Clone, Debug, PartialEq)]
pub struct ClusterFit {
    /// Full accelerometer matrix of each IMU into the cluster frame, g per count.
    pub accel_matrix_g_per_count: Vec<Mat3>,
    /// Accelerometer bias at `t_ref_s`, counts.
    pub accel_bias_counts: Vec<Vec3>,
    /// Accelerometer bias drift, counts per second (zero for [`BiasModel::Constant`]).
    pub accel_bias_drift_counts_per_s: Vec<Vec3>,
    /// Reference time of the biases, seconds (mean of the poses' mid-times).
    pub t_ref_s: f64,
    /// Gravity direction of each pose in the cluster frame (unit).
    pub directions: Vec<Vec3>,
    /// Levenberg–Marquardt iterations.
    pub iterations: usize,
}

pub(super) fn poses_imus(poses: &[StaticInterval]) -> Result<usize, CalibError> {
    let n = poses.first().map_or(0, |p| p.accel_counts.len());
    for p in poses {
        for len in [
            p.accel_counts.len(),
            p.gyro_counts.len(),
            p.accel_sem_counts.len(),
        ] {
            if len != n {
                return Err(CalibError::Count {
                    what: "IMUs per pose",
                    expected: n,
                    found: len,
                });
            }
        }
        check_finite(&p.accel_counts, "accelerometer means")?;
        check_finite(&p.gyro_counts, "gyro means")?;
        check_finite(&p.accel_sem_counts, "standard errors")?;
        if !(p.start_s.is_finite() && p.end_s.is_finite()) {
            return Err(CalibError::NonFinite("pose times"));
        }
    }
    if n == 0 {
        return Err(CalibError::Count {
            what: "IMUs per pose",
            expected: 1,
            found: 0,
        });
    }
    Ok(n)
}

/// Mean of the poses' mid-times, seconds.
pub(crate) fn t_ref(poses: &[StaticInterval]) -> f64 {
    poses.iter().map(StaticInterval::mid_s).sum::<f64>() / poses.len().max(1) as f64
}

/// Joint refinement of all IMUs (see the module docs, step 3), started from matrices already in the cluster frame
/// (`init_matrix_g_per_count`, e.g. `R_i·M_i`) and biases (counts). Phases: the inputs checked
/// (`check_inputs`), the data normalised (`Normalised::of`), the start (`Problem::start`), Levenberg–Marquardt
/// on `Problem::eval`, the result back in counts (`Problem::unpack`).
pub fn refine_cluster(
    poses: &[StaticInterval],
    init_matrix_g_per_count: &[Mat3],
    init_bias_counts: &[Vec3],
    opts: &StaticCalOptions,
) -> Result<ClusterFit, CalibError> {
    let n = check_inputs(poses, init_matrix_g_per_count, init_bias_counts, opts)?;
    let k = poses.len();
    let drift = opts.bias_model == BiasModel::LinearDrift;
    let t0 = t_ref(poses);
    let problem = Problem {
        n,
        k,
        per: if drift { 15 } else { 12 },
        drift,
        prior: opts.drift_prior_mg_per_100s * 1e-3,
        s0: opts.accel_g_per_count,
        tau: poses.iter().map(|p| (p.mid_s() - t0) / 100.0).collect(),
        data: Normalised::of(poses, n, opts.accel_g_per_count),
    };
    let x0 = problem.start(init_matrix_g_per_count, init_bias_counts)?;
    let res = levenberg_marquardt(
        x0,
        |p: &DVector<f64>| problem.eval(p),
        |p: &DVector<f64>, dp: &DVector<f64>| problem.retract(p, dp),
        opts.max_iterations,
    )
    .ok_or(CalibError::NonFinite("cluster refinement"))?;
    problem.unpack(&res.x, res.iterations, t0, opts.reference_imu)
}

/// The inputs of [`refine_cluster`] checked; the number of IMUs.
fn check_inputs(
    poses: &[StaticInterval],
    init_matrix_g_per_count: &[Mat3],
    init_bias_counts: &[Vec3],
    opts: &StaticCalOptions,
) -> Result<usize, CalibError> {
    let n = poses_imus(poses)?;
    let k = poses.len();
    if k < MIN_POSES {
        return Err(CalibError::TooFewPoses {
            needed: MIN_POSES,
            found: k,
        });
    }
    for (what, len) in [
        ("initial matrices", init_matrix_g_per_count.len()),
        ("initial biases", init_bias_counts.len()),
    ] {
        if len != n {
            return Err(CalibError::Count {
                what,
                expected: n,
                found: len,
            });
        }
    }
    if opts.reference_imu >= n {
        return Err(CalibError::InvalidOption("reference IMU out of range"));
    }
    let s0 = opts.accel_g_per_count;
    if !(s0.is_finite() && s0 > 0.0) {
        return Err(CalibError::InvalidOption("nominal scale must be > 0"));
    }
    let prior = opts.drift_prior_mg_per_100s * 1e-3;
    if opts.bias_model == BiasModel::LinearDrift && !(prior.is_finite() && prior > 0.0) {
        return Err(CalibError::InvalidOption("drift prior must be > 0"));
    }
    Ok(n)
}

/// Normalised data: x = (a − c)·s0 (≈ g) with c each IMU's mean over the poses, noise σ per IMU and axis (RMS
/// standard error over poses, floored at 1e-3 of the median).
struct Normalised {
    c: Vec<Vector3<f64>>,
    x: Vec<Vec<Vector3<f64>>>,
    sigma: Vec<Vector3<f64>>,
}

impl Normalised {
    fn of(poses: &[StaticInterval], n: usize, s0: f64) -> Self {
        let k = poses.len();
        let c: Vec<Vector3<f64>> = (0..n)
            .map(|i| {
                poses
                    .iter()
                    .fold(Vector3::zeros(), |acc, p| acc + vec3(&p.accel_counts[i]))
                    / k as f64
            })
            .collect();
        let x: Vec<Vec<Vector3<f64>>> = (0..n)
            .map(|i| {
                poses
                    .iter()
                    .map(|p| (vec3(&p.accel_counts[i]) - c[i]) * s0)
                    .collect()
            })
            .collect();
        let mut sigma: Vec<Vector3<f64>> = (0..n)
            .map(|i| {
                Vector3::from_fn(|r, _| {
                    (poses
                        .iter()
                        .map(|p| p.accel_sem_counts[i][r].powi(2))
                        .sum::<f64>()
                        / k as f64)
                        .sqrt()
                        * s0
                })
            })
            .collect();
        let mut all: Vec<f64> = sigma.iter().flat_map(|s| s.iter().copied()).collect();
        all.sort_by(f64::total_cmp);
        let median = all[all.len() / 2];
        let floor = if median > 0.0 { 1e-3 * median } else { 1e-4 };
        for s in &mut sigma {
            for v in s.iter_mut() {
                *v = if median > 0.0 { v.max(floor) } else { floor };
            }
        }
        Self { c, x, sigma }
    }
}

/// The least-squares problem: per IMU the inverse matrix S (9), bias b (3) and drift d (3, with `drift`), then one
/// direction per pose (3, kept unit by [`Problem::retract`]).
struct Problem {
    n: usize,
    k: usize,
    per: usize,
    drift: bool,
    prior: f64,
    s0: f64,
    tau: Vec<f64>,
    data: Normalised,
}

impl Problem {
    /// The start: S and b from the initial matrices and biases, each pose's direction from their mean.
    fn start(&self, init_m: &[Mat3], init_b: &[Vec3]) -> Result<DVector<f64>, CalibError> {
        let (n, k, per, s0) = (self.n, self.k, self.per, self.s0);
        let mut k_init = Vec::with_capacity(n);
        let mut b_init = Vec::with_capacity(n);
        for i in 0..n {
            let km = mat3(&init_m[i]) / s0;
            let s = km
                .try_inverse()
                .ok_or(CalibError::Degenerate("initial matrix is singular"))?;
            k_init.push((km, s));
            b_init.push((vec3(&init_b[i]) - self.data.c[i]) * s0);
        }
        let mut x0 = DVector::zeros(n * per + 3 * k);
        for i in 0..n {
            let o = i * per;
            for r in 0..3 {
                for q in 0..3 {
                    x0[o + 3 * r + q] = k_init[i].1[(r, q)];
                }
                x0[o + 9 + r] = b_init[i][r];
            }
        }
        for p in 0..k {
            let u = (0..n)
                .fold(Vector3::zeros(), |acc, i| {
                    acc + k_init[i].0 * (self.data.x[i][p] - b_init[i])
                })
                .try_normalize(1e-300)
                .ok_or(CalibError::Degenerate("zero specific force"))?;
            for r in 0..3 {
                x0[n * per + 3 * p + r] = u[r];
            }
        }
        Ok(x0)
    }

    /// Weighted residuals and their Jacobian (plus the drift prior's rows).
    fn eval(&self, p: &DVector<f64>) -> (DVector<f64>, DMatrix<f64>) {
        let (n, k, per, drift) = (self.n, self.k, self.per, self.drift);
        let rows = 3 * n * k + if drift { 3 * n } else { 0 };
        let mut res = DVector::zeros(rows);
        let mut j = DMatrix::zeros(rows, n * per + 3 * k);
        let us: Vec<(Vector3<f64>, f64)> = (0..k)
            .map(|q| {
                let o = n * per + 3 * q;
                let v = Vector3::new(p[o], p[o + 1], p[o + 2]);
                let len = v.norm().max(1e-300);
                (v / len, len)
            })
            .collect();
        for i in 0..n {
            let o = i * per;
            let s = Matrix3::from_fn(|r, q| p[o + 3 * r + q]);
            let b = Vector3::new(p[o + 9], p[o + 10], p[o + 11]);
            let d = if drift {
                Vector3::new(p[o + 12], p[o + 13], p[o + 14])
            } else {
                Vector3::zeros()
            };
            for (q, (u, len)) in us.iter().enumerate() {
                let pred = s * u + b + d * self.tau[q];
                let proj = (Matrix3::identity() - u * u.transpose()) / *len;
                let su = s * proj;
                for r in 0..3 {
                    let row = 3 * (i * k + q) + r;
                    let w = 1.0 / self.data.sigma[i][r];
                    res[row] = (self.data.x[i][q][r] - pred[r]) * w;
                    for cc in 0..3 {
                        j[(row, o + 3 * r + cc)] = -u[cc] * w;
                        j[(row, n * per + 3 * q + cc)] = -su[(r, cc)] * w;
                    }
                    j[(row, o + 9 + r)] = -w;
                    if drift {
                        j[(row, o + 12 + r)] = -self.tau[q] * w;
                    }
                }
            }
            if drift {
                for r in 0..3 {
                    let row = 3 * n * k + 3 * i + r;
                    res[row] = d[r] / self.prior;
                    j[(row, o + 12 + r)] = 1.0 / self.prior;
                }
            }
        }
        (res, j)
    }

    /// A step, with each pose's direction renormalised.
    fn retract(&self, p: &DVector<f64>, dp: &DVector<f64>) -> DVector<f64> {
        let mut q = p + dp;
        for pose in 0..self.k {
            let o = self.n * self.per + 3 * pose;
            let len = Vector3::new(q[o], q[o + 1], q[o + 2]).norm();
            if len > 0.0 && len.is_finite() {
                for r in 0..3 {
                    q[o + r] /= len;
                }
            }
        }
        q
    }

    /// The solution in counts, rotated so that the reference IMU's matrix is symmetric (its polar factor removed).
    fn unpack(
        &self,
        p: &DVector<f64>,
        iterations: usize,
        t0: f64,
        reference_imu: usize,
    ) -> Result<ClusterFit, CalibError> {
        let (n, k, per, s0) = (self.n, self.k, self.per, self.s0);
        let mut km = Vec::with_capacity(n);
        for i in 0..n {
            let s = Matrix3::from_fn(|r, q| p[i * per + 3 * r + q]);
            km.push(
                s.try_inverse()
                    .ok_or(CalibError::Degenerate("refined matrix is singular"))?,
            );
        }
        let (g, _) = polar(&km[reference_imu])
            .ok_or(CalibError::Degenerate("reference matrix is singular"))?;
        let gt = g.transpose();
        let mut out = ClusterFit {
            accel_matrix_g_per_count: Vec::with_capacity(n),
            accel_bias_counts: Vec::with_capacity(n),
            accel_bias_drift_counts_per_s: Vec::with_capacity(n),
            t_ref_s: t0,
            directions: (0..k)
                .map(|q| {
                    let o = n * per + 3 * q;
                    arrv(&(gt * Vector3::new(p[o], p[o + 1], p[o + 2]).normalize()))
                })
                .collect(),
            iterations,
        };
        for (i, kmi) in km.iter().enumerate() {
            let o = i * per;
            out.accel_matrix_g_per_count.push(arr3(&(gt * kmi * s0)));
            out.accel_bias_counts.push(arrv(
                &(self.data.c[i] + Vector3::new(p[o + 9], p[o + 10], p[o + 11]) / s0),
            ));
            out.accel_bias_drift_counts_per_s.push(if self.drift {
                [p[o + 12], p[o + 13], p[o + 14]].map(|v| v / s0 / 100.0)
            } else {
                [0.0; 3]
            });
        }
        Ok(out)
    }
}
