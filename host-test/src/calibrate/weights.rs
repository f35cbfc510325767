//! Fixed fusion weights for a τ region (`ground calibrate --weights`, issue 27): generalised least squares on the
//! sensors' Allan covariance.
//!
//! For one axis, a fused output `y = Σ wᵢ xᵢ` with `Σ wᵢ = 1` has Allan variance `wᵀ Σ(τ) w`, where `Σ(τ)` is the
//! sensors' overlapping Allan covariance at τ (`Σᵢⱼ = ⟨Δᵢ Δⱼ⟩ / 2`, Δ the difference of consecutive τ-averages).
//! Over a region of octave τ's the weights minimise `wᵀ S w` with `S = Σ_τ Σ(τ) / σ̄²(τ)` (each τ scaled by the
//! mean sensor variance there, so that every octave counts alike): `w = S⁻¹1 / 1ᵀS⁻¹1`. A process common to all
//! sensors adds `c·11ᵀ` to `Σ(τ)`, which the constraint makes a constant: at one τ it neither helps nor hurts
//! (over a region it only changes how much each τ counts, through its mean variance), and the weights follow the
//! sensors' own processes — a sensor that drifts at long τ loses its weight there, which the on-board
//! inverse-variance weights (white noise only) cannot see.
//!
//! Unless negative weights are allowed, the constraint `w ≥ 0` is kept by an active set: the sensors whose weight
//! comes out negative are left out and the rest solved again, until none is negative (a sensor left out is never
//! taken back: with a positive-definite S this reaches the constrained optimum in the usual case of a few outliers;
//! the report prints what is left out). The covariance at long τ rests on few averages, so `S` is shrunk by 10 %
//! towards its diagonal (stated in the printed report), which keeps it well conditioned for 16 sensors and tens of
//! differences.

use super::CalibError;
use crate::recording::{Column, Recording, SensorKind};
use nalgebra::{DMatrix, DVector};

/// Share of `S` moved to its diagonal (see the module docs).
pub const SHRINKAGE: f64 = 0.1;

/// The τ region and the sign rule.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WeightOptions {
    /// Shortest τ of the region, s.
    pub tau_min_s: f64,
    /// Longest τ of the region, s.
    pub tau_max_s: f64,
    /// Allow negative weights.
    pub allow_negative: bool,
}

/// One axis's weights and what they predict.
#[derive(Clone, Debug, PartialEq)]
pub struct AxisWeights {
    /// Weights per sensor, summing to 1.
    pub weights: Vec<f64>,
    /// The octave τ's of the region, s.
    pub taus_s: Vec<f64>,
    /// Predicted Allan deviation of the fused output with these weights, at each τ (unit of the data).
    pub adev_weighted: Vec<f64>,
    /// The same with equal weights.
    pub adev_equal: Vec<f64>,
    /// Held out: with the weights fitted on the first half of the record, the fused Allan deviation of the second
    /// half at each τ (where the half holds enough data), weighted and equal. `None` unless asked for.
    pub held_out: Option<HeldOut>,
}

impl AxisWeights {
    /// The weights `w` with the fused deviations, weighted and equal, that the covariances `covs` at `taus_s` give
    /// (no held-out check).
    pub fn evaluated(w: &DVector<f64>, covs: &[DMatrix<f64>], taus_s: Vec<f64>) -> Self {
        let equal = DVector::from_element(w.len(), 1.0 / w.len().max(1) as f64);
        let dev =
            |v: &DVector<f64>, c: &DMatrix<f64>| (v.transpose() * c * v)[(0, 0)].max(0.0).sqrt();
        Self {
            weights: w.iter().copied().collect(),
            taus_s,
            adev_weighted: covs.iter().map(|c| dev(w, c)).collect(),
            adev_equal: covs.iter().map(|c| dev(&equal, c)).collect(),
            held_out: None,
        }
    }
}

/// Fused Allan deviations of data the weights were not fitted on.
#[derive(Clone, Debug, PartialEq)]
pub struct HeldOut {
    /// τ, s.
    pub taus_s: Vec<f64>,
    /// With the first half's weights.
    pub adev_weighted: Vec<f64>,
    /// With equal weights.
    pub adev_equal: Vec<f64>,
}

/// The fused deviation `√(wᵀΣw)` of `series` at averaging factor `m`.
fn fused_dev(series: &[&[f64]], m: usize, w: &DVector<f64>) -> f64 {
    let c = allan_covariance(series, m);
    (w.transpose() * c * w)[(0, 0)].max(0.0).sqrt()
}

/// Overlapping Allan covariance of `series` (equal lengths) at averaging factor `m` samples.
pub fn allan_covariance(series: &[&[f64]], m: usize) -> DMatrix<f64> {
    let n = series.len();
    let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
    let mut cov = DMatrix::zeros(n, n);
    if m == 0 || len < 2 * m + 1 {
        return cov;
    }
    // Cumulative sums: the τ-average at k is (c[k + m] − c[k]) / m.
    let cums: Vec<Vec<f64>> = series
        .iter()
        .map(|s| {
            let mut c = Vec::with_capacity(len + 1);
            c.push(0.0);
            let mut acc = 0.0;
            for &x in &s[..len] {
                acc += x;
                c.push(acc);
            }
            c
        })
        .collect();
    let count = len - 2 * m + 1;
    let mut d = vec![0.0; n];
    let mf = m as f64;
    for k in 0..count {
        for (di, c) in d.iter_mut().zip(&cums) {
            *di = ((c[k + 2 * m] - c[k + m]) - (c[k + m] - c[k])) / mf;
        }
        for i in 0..n {
            for j in 0..=i {
                cov[(i, j)] += d[i] * d[j];
            }
        }
    }
    for i in 0..n {
        for j in 0..=i {
            let v = cov[(i, j)] / (2.0 * count as f64);
            cov[(i, j)] = v;
            cov[(j, i)] = v;
        }
    }
    cov
}

/// `S⁻¹1 / 1ᵀS⁻¹1` over the sensors in `active`, zero elsewhere.
fn gls(s: &DMatrix<f64>, active: &[bool]) -> Result<DVector<f64>, CalibError> {
    let idx: Vec<usize> = (0..active.len()).filter(|&i| active[i]).collect();
    let sub = DMatrix::from_fn(idx.len(), idx.len(), |r, c| s[(idx[r], idx[c])]);
    let chol = sub.cholesky().ok_or(CalibError::Degenerate(
        "the sensors' Allan covariance is not positive definite",
    ))?;
    let x = chol.solve(&DVector::from_element(idx.len(), 1.0));
    let total: f64 = x.iter().sum();
    if !(total.is_finite() && total > 0.0) {
        return Err(CalibError::Degenerate("the weights do not normalise"));
    }
    let mut w = DVector::zeros(active.len());
    for (r, &i) in idx.iter().enumerate() {
        w[i] = x[r] / total;
    }
    Ok(w)
}

/// The GLS weights for the Allan covariances `covs` of one axis's sensors at the τ's of a region: `S = Σ_τ Σ(τ) /
/// σ̄²(τ)`, moved `shrinkage` of the way to its diagonal, then `S⁻¹1 / 1ᵀS⁻¹1` with the active set unless
/// `allow_negative` (see the module docs). Shared by the record's estimates ([`recommend`]) and a model's exact
/// covariances (`super::from_model`).
pub fn solve(
    covs: &[DMatrix<f64>],
    shrinkage: f64,
    allow_negative: bool,
) -> Result<DVector<f64>, CalibError> {
    let n = covs.first().map_or(0, |c| c.nrows());
    let mut s = DMatrix::zeros(n, n);
    for c in covs {
        let mean_var = c.diagonal().mean();
        if !(mean_var.is_finite() && mean_var > 0.0) {
            return Err(CalibError::Degenerate("no variance at a τ of the region"));
        }
        s += c / mean_var;
    }
    let diag = DMatrix::from_diagonal(&s.diagonal());
    let s = s * (1.0 - shrinkage) + diag * shrinkage;
    let mut active = vec![true; n];
    loop {
        let w = gls(&s, &active)?;
        let negative: Vec<usize> = (0..n).filter(|&i| active[i] && w[i] < 0.0).collect();
        if allow_negative || negative.is_empty() {
            return Ok(w);
        }
        for i in negative {
            active[i] = false;
        }
    }
}

/// The weights of one axis's sensors (`series`, sampled at `rate_hz`) for the τ region of `opts`.
pub fn recommend(
    series: &[&[f64]],
    rate_hz: f64,
    opts: &WeightOptions,
) -> Result<AxisWeights, CalibError> {
    let n = series.len();
    if n < 2 {
        return Err(CalibError::TooFewPoses {
            needed: 2,
            found: n,
        });
    }
    if !(opts.tau_min_s > 0.0 && opts.tau_max_s >= opts.tau_min_s && rate_hz > 0.0) {
        return Err(CalibError::InvalidOption(
            "0 < tau_min ≤ tau_max and a positive rate",
        ));
    }
    let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
    // Octave averaging factors within the region, each with at least 2n differences (a covariance of rank n).
    let mut ms = Vec::new();
    let mut m = 1usize;
    while (m as f64) / rate_hz <= opts.tau_max_s && 2 * m < len {
        if (m as f64) / rate_hz >= opts.tau_min_s && len - 2 * m + 1 >= 2 * n {
            ms.push(m);
        }
        m *= 2;
    }
    if ms.is_empty() {
        return Err(CalibError::InvalidOption(
            "no octave τ in the region has enough data (at least twice as many differences as sensors)",
        ));
    }
    let covs: Vec<DMatrix<f64>> = ms.iter().map(|&m| allan_covariance(series, m)).collect();
    let w = solve(&covs, SHRINKAGE, opts.allow_negative)?;
    let taus_s = ms.iter().map(|&m| m as f64 / rate_hz).collect();
    Ok(AxisWeights::evaluated(&w, &covs, taus_s))
}

/// [`recommend`] on the first half of `series`, evaluated on the second half (the weights returned are the first
/// half's; `held_out` holds the second half's fused deviations at the octave τ's of the region it can resolve).
pub fn recommend_held_out(
    series: &[&[f64]],
    rate_hz: f64,
    opts: &WeightOptions,
) -> Result<AxisWeights, CalibError> {
    let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
    let half = len / 2;
    let first: Vec<&[f64]> = series.iter().map(|s| &s[..half]).collect();
    let second: Vec<&[f64]> = series.iter().map(|s| &s[half..2 * half]).collect();
    let mut r = recommend(&first, rate_hz, opts)?;
    let w = DVector::from_vec(r.weights.clone());
    let n = series.len();
    let equal = DVector::from_element(n, 1.0 / n as f64);
    let mut held = HeldOut {
        taus_s: Vec::new(),
        adev_weighted: Vec::new(),
        adev_equal: Vec::new(),
    };
    for &tau in &r.taus_s {
        let m = (tau * rate_hz).round() as usize;
        if m > 0 && half > 2 * m {
            held.taus_s.push(tau);
            held.adev_weighted.push(fused_dev(&second, m, &w));
            held.adev_equal.push(fused_dev(&second, m, &equal));
        }
    }
    r.held_out = Some(held);
    Ok(r)
}

/// `w` scaled so that its largest |w| is 1: the table's Q16 range (the core renormalises over the sensors in use).
pub(crate) fn table_scale(w: &[f64]) -> impl Iterator<Item = f64> + '_ {
    let top = w.iter().fold(0f64, |m, x| m.max(x.abs()));
    w.iter().map(move |x| if top > 0.0 { x / top } else { 0.0 })
}

/// One axis's groups (in the order of its columns) and their recommendation.
pub type GroupsWeights = (Vec<usize>, AxisWeights);

/// The weights of a recording's six axes for the table (`CalibrationFile::weights`): per group and axis (gx gy gz ax
/// ay az), scaled per axis so that the largest |w| is 1 (the table's Q16 range; the core renormalises over the
/// sensors in use), with each axis's recommendation (its `weights` in the order of the axis's columns, whose groups
/// are returned too). With `held_out`, fitted on the first half and checked on the second ([`recommend_held_out`]).
pub fn table_weights(
    rec: &Recording,
    groups: usize,
    opts: &WeightOptions,
    held_out: bool,
) -> Result<(Vec<[f64; 6]>, Vec<GroupsWeights>), CalibError> {
    let n = rec.t_s.len();
    let span = match (rec.t_s.first(), rec.t_s.last()) {
        (Some(a), Some(b)) if n >= 2 && b > a => b - a,
        _ => {
            return Err(CalibError::TooFewPoses {
                needed: 2,
                found: n,
            });
        }
    };
    let rate_hz = (n - 1) as f64 / span;
    let mut table = vec![[0.0; 6]; groups];
    let mut axes = Vec::with_capacity(6);
    for t in 0..6 {
        let (kind, axis) = if t < 3 {
            (SensorKind::Gyro, t)
        } else {
            (SensorKind::Accel, t - 3)
        };
        let cols: Vec<&Column> = rec
            .axis_columns(kind, axis)
            .filter(|c| c.group < groups)
            .collect();
        let series: Vec<&[f64]> = cols.iter().map(|c| c.data.as_slice()).collect();
        let w = if held_out {
            recommend_held_out(&series, rate_hz, opts)?
        } else {
            recommend(&series, rate_hz, opts)?
        };
        for (c, x) in cols.iter().zip(table_scale(&w.weights)) {
            if let Some(row) = table.get_mut(c.group) {
                row[t] = x;
            }
        }
        axes.push((cols.iter().map(|c| c.group).collect(), w));
    }
    Ok((table, axes))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testrng::TestRng;

    /// Independent white sensors of unequal levels: the GLS weights are the inverse-variance weights (an
    /// independent reference: wᵢ ∝ 1/σᵢ²), within the sampling error of the covariance.
    #[test]
    fn white_sensors_get_inverse_variance_weights() {
        let mut rng = TestRng::new(5);
        let sigma = [1.0, 1.0, 2.0, 0.5];
        let data: Vec<Vec<f64>> = sigma
            .iter()
            .map(|&s| (0..200_000).map(|_| s * rng.normal()).collect())
            .collect();
        let refs: Vec<&[f64]> = data.iter().map(Vec::as_slice).collect();
        let opts = WeightOptions {
            tau_min_s: 1.0,
            tau_max_s: 64.0,
            allow_negative: false,
        };
        let r = recommend(&refs, 10.0, &opts).unwrap();
        let inv: Vec<f64> = sigma.iter().map(|s| 1.0 / (s * s)).collect();
        let total: f64 = inv.iter().sum();
        for (w, i) in r.weights.iter().zip(&inv) {
            assert!((w - i / total).abs() < 0.02, "{:?}", r.weights);
        }
        // The weighted fused deviation beats the equal mean's at every τ.
        assert!(
            r.adev_weighted
                .iter()
                .zip(&r.adev_equal)
                .all(|(w, e)| w < e)
        );
    }

    /// Two sensors that are nearly copies of each other plus a third: unconstrained GLS gives one of them a
    /// negative weight (it subtracts the shared part), the constrained one does not.
    #[test]
    fn negative_weights_only_when_allowed() {
        let mut rng = TestRng::new(6);
        let n = 100_000;
        let shared: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let a: Vec<f64> = shared.iter().map(|s| s + 0.1 * rng.normal()).collect();
        let b: Vec<f64> = shared
            .iter()
            .map(|s| 0.5 * s + 0.1 * rng.normal())
            .collect();
        let c: Vec<f64> = (0..n).map(|_| rng.normal()).collect();
        let refs = [a.as_slice(), b.as_slice(), c.as_slice()];
        let mut opts = WeightOptions {
            tau_min_s: 1.0,
            tau_max_s: 16.0,
            allow_negative: true,
        };
        let free = recommend(&refs, 1.0, &opts).unwrap();
        assert!(free.weights[0] < 0.0, "{:?}", free.weights);
        opts.allow_negative = false;
        let kept = recommend(&refs, 1.0, &opts).unwrap();
        assert!(kept.weights.iter().all(|&w| w >= 0.0), "{:?}", kept.weights);
        assert!((kept.weights.iter().sum::<f64>() - 1.0).abs() < 1e-12);
    }
}
