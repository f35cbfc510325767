//! Rate-table calibration of our board's sensor groups (two dual-axis gyros = 4 raw gyro channels, one 3-axis
//! accelerometer per group).
//!
//! Design ([`standard_inputs`]): six orientations (each board axis up, then down) × rates {+Ω, −Ω, 0} about the
//! vertical axis (Ω = 100 °/s); the accelerometers see +1 g along the up axis. Input per group and record: the
//! true rate and specific force (board frame) and the mean raw outputs ([`RateRecord`]).
//!
//! Fit (per group): each raw channel `c` is fitted by ordinary least squares as an affine function of the true
//! input over all records, `raw_c = s_c·x + b_c`. Gyro: all 18 records. Accelerometer
//! ([`AccelRecords`], default [`AccelRecords::CentripetalOffsets`]): all records, with one extra unknown offset
//! per orientation shared by its ±Ω records, since a group off the rotation axis feels the centripetal
//! acceleration Ω²r (≈ 15 mg at 5 cm), the same at +Ω and −Ω; the scale and bias then come from the zero-rate
//! records, and the ±Ω pairs add 6 degrees of freedom to the noise estimate (8 instead of 2 per channel). For the
//! balanced ± design this least-squares fit is exactly the seed paper's two-point formulas, corrected: bias
//! `(a₊ + a₋)/2`, scale `(a₊ − a₋)/(2·input)` ([`two_point`]), and the cross terms (misalignment) are the same
//! differences of the off-axis outputs. The calibration matrix is then the minimum-variance inverse of the
//! forward sensitivity `S`: `M_g = (SᵀWS)⁻¹SᵀW` with `W = diag(1/σ_c²)` from each channel's residual variance
//! (3×4: both z outputs are used, weighted by their noise), `M_a = S_a⁻¹`.
//!
//! Accuracy: the residual variance `σ_c² = RSS_c/(n − 4)` gives each channel's parameter covariance
//! `σ_c²(XᵀX)⁻¹`; it is propagated (numerical Jacobian) to standard errors of every matrix entry, bias, and of the
//! calibrated output at zero input and at Ω (1 g) along each axis: the noise-limited accuracy the fit predicts.

use nalgebra::{DMatrix, DVector, Matrix3, SMatrix, Vector3};

use super::file::{CalibrationFile, GroupCalF64};
use super::{CalibError, Mat3, Vec3};

/// An orientation of the board on the table: which board axis points up.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum UpAxis {
    /// +x up.
    PlusX,
    /// −x up.
    MinusX,
    /// +y up.
    PlusY,
    /// −y up.
    MinusY,
    /// +z up.
    PlusZ,
    /// −z up.
    MinusZ,
}

impl UpAxis {
    /// The six orientations.
    pub const ALL: [Self; 6] = [
        Self::PlusX,
        Self::MinusX,
        Self::PlusY,
        Self::MinusY,
        Self::PlusZ,
        Self::MinusZ,
    ];

    /// The up direction in the board frame.
    pub fn unit(self) -> Vec3 {
        match self {
            Self::PlusX => [1.0, 0.0, 0.0],
            Self::MinusX => [-1.0, 0.0, 0.0],
            Self::PlusY => [0.0, 1.0, 0.0],
            Self::MinusY => [0.0, -1.0, 0.0],
            Self::PlusZ => [0.0, 0.0, 1.0],
            Self::MinusZ => [0.0, 0.0, -1.0],
        }
    }
}

/// One record of one group: true inputs and mean raw outputs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateRecord {
    /// True angular rate, board frame, °/s.
    pub rate_dps: Vec3,
    /// True specific force, board frame, g.
    pub accel_g: Vec3,
    /// Mean raw gyro channels (A x, A z, B y, B z on our board), counts.
    pub gyro_counts: [f64; 4],
    /// Mean raw accelerometer channels, counts.
    pub accel_counts: Vec3,
}

/// The 18 inputs of the standard design: for each orientation of [`UpAxis::ALL`], rates `+Ω·up`, `−Ω·up` and 0,
/// specific force `+1 g·up`. Returns `(orientation, rate_dps, accel_g)`.
pub fn standard_inputs(omega_dps: f64) -> Vec<(UpAxis, Vec3, Vec3)> {
    UpAxis::ALL
        .iter()
        .flat_map(|&up| {
            let u = up.unit();
            [omega_dps, -omega_dps, 0.0].map(|w| (up, u.map(|x| x * w), u))
        })
        .collect()
}

/// The seed paper's two-point formulas, corrected: `(bias, scale)` = `((a₊ + a₋)/2, (a₊ − a₋)/(2·input))` for
/// outputs `a₊`, `a₋` at inputs `+input`, `−input`.
pub fn two_point(plus: f64, minus: f64, input: f64) -> (f64, f64) {
    ((plus + minus) / 2.0, (plus - minus) / (2.0 * input))
}

/// Which records the accelerometer fit uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum AccelRecords {
    /// Only the zero-rate records (2 degrees of freedom per channel for the noise in the standard design).
    ZeroRateOnly,
    /// All records, with an unknown offset per orientation shared by its rotating records (centripetal
    /// acceleration); records are grouped by their `accel_g`.
    CentripetalOffsets,
    /// All records as they are (only for groups on the rotation axis).
    All,
}

/// Options of [`fit_rate_table_group`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateTableOptions {
    /// Records of the accelerometer fit. Default [`AccelRecords::CentripetalOffsets`].
    pub accel_records: AccelRecords,
    /// Weight the gyro channels by their residual variance when inverting (else equal weights). Default `true`.
    pub weight_channels: bool,
    /// Rails of the table ([`fit_rate_table`]). Default 0 and 65535 (our ADC).
    pub raw_min: i32,
    /// Upper rail. Default 65535.
    pub raw_max: i32,
}

impl Default for RateTableOptions {
    fn default() -> Self {
        Self {
            accel_records: AccelRecords::CentripetalOffsets,
            weight_channels: true,
            raw_min: 0,
            raw_max: 65_535,
        }
    }
}

/// Result for one group; every `_se` field is the standard error of the field of the same name.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RateTableFit {
    /// Forward gyro sensitivity, counts per °/s: `raw_g = S·ω + b` (rows = raw channels).
    pub gyro_sensitivity_counts_per_dps: [[f64; 3]; 4],
    /// Standard errors.
    pub gyro_sensitivity_se: [[f64; 3]; 4],
    /// Gyro calibration matrix, °/s per count (3×4).
    pub gyro_matrix_dps_per_count: [[f64; 4]; 3],
    /// Standard errors.
    pub gyro_matrix_se: [[f64; 4]; 3],
    /// Gyro bias (zero-rate output), counts.
    pub gyro_bias_counts: [f64; 4],
    /// Standard errors, counts.
    pub gyro_bias_se_counts: [f64; 4],
    /// RMS residual of each gyro channel's fit, counts.
    pub gyro_residual_rms_counts: [f64; 4],
    /// Forward accelerometer sensitivity, counts per g.
    pub accel_sensitivity_counts_per_g: Mat3,
    /// Standard errors.
    pub accel_sensitivity_se: Mat3,
    /// Accelerometer calibration matrix, g per count.
    pub accel_matrix_g_per_count: Mat3,
    /// Standard errors.
    pub accel_matrix_se: Mat3,
    /// Accelerometer bias (zero-g output), counts.
    pub accel_bias_counts: Vec3,
    /// Standard errors, counts.
    pub accel_bias_se_counts: Vec3,
    /// RMS residual of each accelerometer channel's fit, counts.
    pub accel_residual_rms_counts: Vec3,
    /// Predicted standard error of the calibrated rate (x, y, z), °/s, at zero input.
    pub rate_se_dps_at_zero: Vec3,
    /// The same at the input Ω about board x, y, z (row = input axis).
    pub rate_se_dps_at_omega: [Vec3; 3],
    /// Predicted standard error of the calibrated specific force (x, y, z), g, at 1 g along x, y, z (row = axis).
    pub accel_se_g_at_1g: [Vec3; 3],
}

/// Ordinary least squares `y = A·β` for one channel: (β, covariance `σ²(AᵀA)⁻¹` with `σ² = RSS/(n − p)`,
/// residual RMS).
fn channel_fit(
    a: &DMatrix<f64>,
    y: &[f64],
) -> Result<(DVector<f64>, DMatrix<f64>, f64), CalibError> {
    let (n, p) = a.shape();
    let ata = a.transpose() * a;
    let inv = ata.try_inverse().ok_or(CalibError::Degenerate(
        "the records do not excite every input axis",
    ))?;
    let yv = DVector::from_column_slice(y);
    let beta = &inv * a.transpose() * &yv;
    let res = &yv - a * &beta;
    let rss = res.norm_squared();
    let dof = n.saturating_sub(p);
    let s2 = if dof > 0 { rss / dof as f64 } else { 0.0 };
    Ok((beta, inv * s2, (rss / n as f64).sqrt()))
}

/// Numerical Jacobian (central differences) of `f` at `theta`.
fn jacobian(
    theta: &DVector<f64>,
    f: &dyn Fn(&DVector<f64>) -> Option<DVector<f64>>,
) -> Option<DMatrix<f64>> {
    let y0 = f(theta)?;
    let mut j = DMatrix::zeros(y0.len(), theta.len());
    for c in 0..theta.len() {
        let h = 1e-7 * (theta[c].abs() + 1.0);
        let mut tp = theta.clone();
        let mut tm = theta.clone();
        tp[c] += h;
        tm[c] -= h;
        let d = (f(&tp)? - f(&tm)?) / (2.0 * h);
        j.set_column(c, &d);
    }
    Some(j)
}

fn se(j: &DMatrix<f64>, cov: &DMatrix<f64>) -> Vec<f64> {
    let v = j * cov * j.transpose();
    (0..v.nrows()).map(|i| v[(i, i)].max(0.0).sqrt()).collect()
}

fn block_diag(blocks: &[DMatrix<f64>]) -> DMatrix<f64> {
    let n: usize = blocks.iter().map(DMatrix::nrows).sum();
    let mut m = DMatrix::zeros(n, n);
    let mut o = 0;
    for b in blocks {
        m.view_mut((o, o), (b.nrows(), b.ncols())).copy_from(b);
        o += b.nrows();
    }
    m
}

/// Gyro: θ = per channel `[s_x, s_y, s_z, b]` (4 channels × 4). Returns `M` (3×4) and `b`.
fn gyro_inverse(theta: &DVector<f64>, w: &[f64; 4]) -> Option<(SMatrix<f64, 3, 4>, [f64; 4])> {
    let s = SMatrix::<f64, 4, 3>::from_fn(|c, k| theta[4 * c + k]);
    let wm = SMatrix::<f64, 4, 4>::from_diagonal(&nalgebra::Vector4::from_column_slice(w));
    let m = (s.transpose() * wm * s).try_inverse()? * s.transpose() * wm;
    Some((m, core::array::from_fn(|c| theta[4 * c + 3])))
}

fn accel_inverse(theta: &DVector<f64>) -> Option<(Matrix3<f64>, Vec3)> {
    let s = Matrix3::from_fn(|c, k| theta[4 * c + k]);
    Some((s.try_inverse()?, core::array::from_fn(|c| theta[4 * c + 3])))
}

/// One sensor's forward fits: the parameters (4 per raw channel), their covariance and each channel's residual RMS,
/// counts.
struct ForwardFit<const C: usize> {
    theta: DVector<f64>,
    cov: DMatrix<f64>,
    rms: [f64; C],
}

/// Forward fits of one group's gyro channels: per raw channel `code = S·ω + b` by least squares; returns the 16
/// parameters (4 per channel), their covariance, the residual RMS per channel and the channel weights of the
/// inversion (inverse bias variances with `opts.weight_channels`).
fn gyro_forward(
    records: &[RateRecord],
    opts: &RateTableOptions,
) -> Result<(ForwardFit<4>, [f64; 4]), CalibError> {
    let xg = DMatrix::from_fn(records.len(), 4, |r, c| {
        if c < 3 { records[r].rate_dps[c] } else { 1.0 }
    });
    let mut theta_g = DVector::zeros(16);
    let mut cov_g = Vec::new();
    let mut gyro_residual_rms_counts = [0.0; 4];
    for (c, rms_out) in gyro_residual_rms_counts.iter_mut().enumerate() {
        let y: Vec<f64> = records.iter().map(|r| r.gyro_counts[c]).collect();
        let (beta, cov, rms) = channel_fit(&xg, &y)?;
        theta_g.rows_mut(4 * c, 4).copy_from(&beta);
        cov_g.push(cov);
        *rms_out = rms;
    }
    let cov_g = block_diag(&cov_g);
    let var: [f64; 4] = core::array::from_fn(|c| cov_g[(4 * c + 3, 4 * c + 3)]);
    let w: [f64; 4] = if opts.weight_channels && var.iter().all(|&v| v > 0.0) {
        var.map(|v| 1.0 / v)
    } else {
        [1.0; 4]
    };
    Ok((
        ForwardFit {
            theta: theta_g,
            cov: cov_g,
            rms: gyro_residual_rms_counts,
        },
        w,
    ))
}

/// Forward fits of one group's accelerometer channels, on the records `opts.accel_records` selects (with one
/// nuisance offset per rotating pose under `CentripetalOffsets`); returns the 12 parameters, their covariance and
/// the residual RMS per channel.
fn accel_forward(
    records: &[RateRecord],
    opts: &RateTableOptions,
) -> Result<ForwardFit<3>, CalibError> {
    let rotating = |r: &RateRecord| r.rate_dps.iter().any(|&v| v != 0.0);
    let acc_records: Vec<&RateRecord> = records
        .iter()
        .filter(|r| opts.accel_records != AccelRecords::ZeroRateOnly || !rotating(r))
        .collect();
    // Nuisance offsets: one per distinct `accel_g` among the rotating records.
    let mut groups: Vec<Vec3> = Vec::new();
    if opts.accel_records == AccelRecords::CentripetalOffsets {
        for r in acc_records.iter().filter(|r| rotating(r)) {
            if !groups.contains(&r.accel_g) {
                groups.push(r.accel_g);
            }
        }
    }
    let pa = 4 + groups.len();
    if acc_records.len() <= pa {
        return Err(CalibError::TooFewPoses {
            needed: pa + 1,
            found: acc_records.len(),
        });
    }
    let xa = DMatrix::from_fn(acc_records.len(), pa, |r, c| {
        let rec = acc_records[r];
        match c {
            0..3 => rec.accel_g[c],
            3 => 1.0,
            _ => f64::from(u8::from(rotating(rec) && groups[c - 4] == rec.accel_g)),
        }
    });
    let mut theta_a = DVector::zeros(12);
    let mut cov_a = Vec::new();
    let mut accel_residual_rms_counts = [0.0; 3];
    for (c, rms_out) in accel_residual_rms_counts.iter_mut().enumerate() {
        let y: Vec<f64> = acc_records.iter().map(|r| r.accel_counts[c]).collect();
        let (beta, cov, rms) = channel_fit(&xa, &y)?;
        theta_a.rows_mut(4 * c, 4).copy_from(&beta.rows(0, 4));
        cov_a.push(cov.view((0, 0), (4, 4)).into_owned());
        *rms_out = rms;
    }
    let cov_a = block_diag(&cov_a);
    Ok(ForwardFit {
        theta: theta_a,
        cov: cov_a,
        rms: accel_residual_rms_counts,
    })
}

/// Every value of the `records` finite, and at least 5 of them.
fn check_records(records: &[RateRecord]) -> Result<(), CalibError> {
    if records.iter().any(|r| {
        !r.rate_dps
            .iter()
            .chain(&r.accel_g)
            .chain(&r.gyro_counts)
            .chain(&r.accel_counts)
            .all(|x| x.is_finite())
    }) {
        return Err(CalibError::NonFinite("rate-table records"));
    }
    if records.len() < 5 {
        return Err(CalibError::TooFewPoses {
            needed: 5,
            found: records.len(),
        });
    }
    Ok(())
}

fn degenerate() -> CalibError {
    CalibError::Degenerate("matrix inversion failed near the estimate")
}

fn v3(v: Vec<f64>) -> Vec3 {
    [v[0], v[1], v[2]]
}

/// Standard errors of the calibrated rate (°/s) at the true rate `input`, by linear propagation of the gyro fit's
/// covariance `cov_g` (`theta_g` the forward fit, `w` its channel weights).
fn rate_se(
    theta_g: &DVector<f64>,
    cov_g: &DMatrix<f64>,
    w: &[f64; 4],
    input: Vec3,
) -> Result<Vec3, CalibError> {
    let raw0: [f64; 4] = core::array::from_fn(|c| {
        (0..3).map(|k| theta_g[4 * c + k] * input[k]).sum::<f64>() + theta_g[4 * c + 3]
    });
    let out = move |t: &DVector<f64>| {
        gyro_inverse(t, w).map(|(m, b)| {
            let d = nalgebra::Vector4::from_fn(|c, _| raw0[c] - b[c]);
            DVector::from_column_slice((m * d).as_slice())
        })
    };
    Ok(v3(se(
        &jacobian(theta_g, &out).ok_or_else(degenerate)?,
        cov_g,
    )))
}

/// Standard errors of the calibrated specific force (g) at the true `input`, by linear propagation of the
/// accelerometer fit's covariance `cov_a` (`theta_a` the forward fit).
fn accel_se(theta_a: &DVector<f64>, cov_a: &DMatrix<f64>, input: Vec3) -> Result<Vec3, CalibError> {
    let raw0: Vec3 = core::array::from_fn(|c| {
        (0..3).map(|k| theta_a[4 * c + k] * input[k]).sum::<f64>() + theta_a[4 * c + 3]
    });
    let out = move |t: &DVector<f64>| {
        accel_inverse(t).map(|(m, b)| {
            let d = Vector3::from_fn(|c, _| raw0[c] - b[c]);
            DVector::from_column_slice((m * d).as_slice())
        })
    };
    Ok(v3(se(
        &jacobian(theta_a, &out).ok_or_else(degenerate)?,
        cov_a,
    )))
}

/// Fits one group (see the module docs). Needs records that excite every axis of both sensors (the standard
/// design does) and finite values.
pub fn fit_rate_table_group(
    records: &[RateRecord],
    opts: &RateTableOptions,
) -> Result<RateTableFit, CalibError> {
    check_records(records)?;
    let (
        ForwardFit {
            theta: theta_g,
            cov: cov_g,
            rms: gyro_residual_rms_counts,
        },
        w,
    ) = gyro_forward(records, opts)?;
    let (mg, bg) = gyro_inverse(&theta_g, &w).ok_or(CalibError::Degenerate(
        "gyro channels do not sense three independent axes",
    ))?;
    let ForwardFit {
        theta: theta_a,
        cov: cov_a,
        rms: accel_residual_rms_counts,
    } = accel_forward(records, opts)?;
    let (ma, ba) = accel_inverse(&theta_a).ok_or(CalibError::Degenerate(
        "accelerometer channels do not sense three independent axes",
    ))?;
    // Standard errors by linear propagation.
    let fg = |t: &DVector<f64>| {
        gyro_inverse(t, &w).map(|(m, _)| DVector::from_iterator(12, m.transpose().iter().copied()))
    };
    let fa = |t: &DVector<f64>| {
        accel_inverse(t).map(|(m, _)| DVector::from_iterator(9, m.transpose().iter().copied()))
    };
    let mg_se = se(&jacobian(&theta_g, &fg).ok_or_else(degenerate)?, &cov_g);
    let ma_se = se(&jacobian(&theta_a, &fa).ok_or_else(degenerate)?, &cov_a);
    let omega = records
        .iter()
        .flat_map(|r| r.rate_dps)
        .fold(0.0f64, |m, v| m.max(v.abs()));
    let rate_at = |input: Vec3| rate_se(&theta_g, &cov_g, &w, input);
    let accel_at = |input: Vec3| accel_se(&theta_a, &cov_a, input);
    let unit = |k: usize| -> Vec3 { core::array::from_fn(|i| f64::from(u8::from(i == k))) };
    let sd = |c: &DMatrix<f64>, i: usize| c[(i, i)].max(0.0).sqrt();
    Ok(RateTableFit {
        gyro_sensitivity_counts_per_dps: core::array::from_fn(|c| {
            core::array::from_fn(|k| theta_g[4 * c + k])
        }),
        gyro_sensitivity_se: core::array::from_fn(|c| {
            core::array::from_fn(|k| sd(&cov_g, 4 * c + k))
        }),
        gyro_matrix_dps_per_count: core::array::from_fn(|r| core::array::from_fn(|c| mg[(r, c)])),
        gyro_matrix_se: core::array::from_fn(|r| core::array::from_fn(|c| mg_se[4 * r + c])),
        gyro_bias_counts: bg,
        gyro_bias_se_counts: core::array::from_fn(|c| sd(&cov_g, 4 * c + 3)),
        gyro_residual_rms_counts,
        accel_sensitivity_counts_per_g: core::array::from_fn(|c| {
            core::array::from_fn(|k| theta_a[4 * c + k])
        }),
        accel_sensitivity_se: core::array::from_fn(|c| {
            core::array::from_fn(|k| sd(&cov_a, 4 * c + k))
        }),
        accel_matrix_g_per_count: core::array::from_fn(|r| core::array::from_fn(|c| ma[(r, c)])),
        accel_matrix_se: core::array::from_fn(|r| core::array::from_fn(|c| ma_se[3 * r + c])),
        accel_bias_counts: ba,
        accel_bias_se_counts: core::array::from_fn(|c| sd(&cov_a, 4 * c + 3)),
        accel_residual_rms_counts,
        rate_se_dps_at_zero: rate_at([0.0; 3])?,
        rate_se_dps_at_omega: [
            rate_at(unit(0).map(|v| v * omega))?,
            rate_at(unit(1).map(|v| v * omega))?,
            rate_at(unit(2).map(|v| v * omega))?,
        ],
        accel_se_g_at_1g: [accel_at(unit(0))?, accel_at(unit(1))?, accel_at(unit(2))?],
    })
}

/// Fits all `G` groups (`groups[g]` = that group's records) and returns the fits and the calibration file (id
/// `cal_id`, rails from `opts`, no metadata).
pub fn fit_rate_table<const G: usize>(
    groups: &[Vec<RateRecord>],
    opts: &RateTableOptions,
    cal_id: u32,
) -> Result<(Vec<RateTableFit>, CalibrationFile), CalibError> {
    if groups.len() != G {
        return Err(CalibError::Count {
            what: "groups",
            expected: G,
            found: groups.len(),
        });
    }
    let fits: Vec<RateTableFit> = groups
        .iter()
        .map(|r| fit_rate_table_group(r, opts))
        .collect::<Result<_, _>>()?;
    let file = CalibrationFile::new(
        cal_id,
        opts.raw_min,
        opts.raw_max,
        fits.iter()
            .map(|f| GroupCalF64 {
                gyro_matrix_dps_per_count: f.gyro_matrix_dps_per_count,
                gyro_bias_counts: f.gyro_bias_counts,
                accel_matrix_g_per_count: f.accel_matrix_g_per_count,
                accel_bias_counts: f.accel_bias_counts,
            })
            .collect(),
    );
    Ok((fits, file))
}
