//! Thermal calibration of our board (`ground calibrate --thermal`): from a record of the still board over a
//! temperature ramp or cycle, per raw channel a least-squares fit of its ADC code against `ΔT = T − T_ref` and
//! `ΔT²`:
//!
//! `code_k = a + lin·ΔT_k + quad·ΔT_k² + e_k`,
//!
//! `lin`, `quad` being the channel's thermal bias terms (counts/°C, counts/°C²; the table's `GroupThermal`) and `a`
//! the code at `T_ref` (bias + the still board's true input: Earth rate, gravity, which the fit cannot tell from the
//! bias, so `a` is reported, not used as the bias).
//!
//! Standard errors: the residuals of MEMS sensors are not white (flicker, random walk), and on a ramp the
//! temperature follows time, so a slow bias wander projects onto the coefficients; the ordinary least-squares
//! errors (white residuals) are then several times too small. Each coefficient is a linear functional `wᵀe` of the
//! noise (`w` its row of `(XᵀX)⁻¹Xᵀ`); in an orthonormal Haar decomposition `wᵀe = Σ_{j,k} c^w_{j,k} c^e_{j,k}`, and
//! Haar detail coefficients of white, flicker and random-walk noise are nearly uncorrelated, with a variance per
//! level `v_j` (= `2^j` × the Allan variance at `τ = 2^j τ₀`). So `Var ≈ Σ_j v_j Σ_k (c^w_{j,k})²`, with
//! `v_j = w + f·2^j + r·4^j` (white, flicker, rate random walk) fitted to the residuals' levels that have at least
//! [`MIN_COEFS`] coefficients. The coarse levels, which dominate for a ramp, are extrapolated by that model: the
//! error assumes the noise seen up to ~1/16 of the record goes on to its length.
//!
//! The design `[1, ΔT/10, (ΔT/10)²]` (ΔT in 10 °C) keeps `XᵀX` well conditioned; one Cholesky factor serves all 112
//! channels (nalgebra).

use nalgebra::{Matrix3, Vector3};
use shared::wire::Decoded;
use shared::wire::frame::{GROUPS, RAW_PER_GROUP};

use super::CalibError;
use super::file::{GroupThermalF64, ThermalChannelFits, ThermalFitMetadata};

const CH: usize = GROUPS * RAW_PER_GROUP;
/// Unit of the design's temperature columns, °C.
const UNIT_C: f64 = 10.0;
/// Fewest Haar coefficients of a level for its residual variance to be measured rather than extrapolated.
pub const MIN_COEFS: usize = 8;

/// `Σ_k c_{j,k}²` per Haar level `j` of `x` zero-padded to a power of two (orthonormal Haar: level `j` compares two
/// adjacent blocks of `2^j` samples, `c = (S₂ − S₁)/√(2^{j+1})`).
fn haar_energy(x: &[f64]) -> Vec<f64> {
    let mut s = x.to_vec();
    s.resize(x.len().next_power_of_two().max(2), 0.0);
    let mut out = Vec::new();
    let mut len = 1.0;
    while s.len() >= 2 {
        let e = s
            .chunks_exact(2)
            .map(|p| (p[1] - p[0]).powi(2))
            .sum::<f64>()
            / (2.0 * len);
        out.push(e);
        s = s.chunks_exact(2).map(|p| p[0] + p[1]).collect();
        len *= 2.0;
    }
    out
}

/// Mean squared Haar coefficient per level of `x` (full pairs of blocks only) and the number of coefficients, for
/// levels with at least [`MIN_COEFS`] coefficients.
fn haar_level_var(x: &[f64]) -> Vec<(f64, usize)> {
    let mut s = x.to_vec();
    let mut out = Vec::new();
    let mut len = 1.0;
    while s.len() / 2 >= MIN_COEFS {
        let pairs = s.len() / 2;
        let e = s
            .chunks_exact(2)
            .map(|p| (p[1] - p[0]).powi(2))
            .sum::<f64>()
            / (2.0 * len);
        out.push((e / pairs as f64, pairs));
        s = s.chunks_exact(2).map(|p| p[0] + p[1]).collect();
        len *= 2.0;
    }
    out
}

/// `Σ_j v_j E_j` with `v_j = w + f·2^j + r·4^j` (white, flicker, random walk: their Haar variances per level), the
/// three fitted to the measured levels by non-negative least squares weighted by each level's precision
/// (`n_j / v_j²`, `crate::allan::noisefit::nnls`).
fn haar_variance(energy: &[f64], v: &[(f64, usize)]) -> f64 {
    let rows: Vec<([f64; 3], f64, f64)> = v
        .iter()
        .enumerate()
        .filter(|(_, (x, _))| *x > 0.0)
        .map(|(j, &(x, n))| {
            let p = (j as f64).exp2();
            ([1.0, p, p * p], x, n as f64 / (x * x))
        })
        .collect();
    let [w, f, r] = crate::allan::noisefit::nnls(&rows).unwrap_or([0.0; 3]);
    energy
        .iter()
        .enumerate()
        .map(|(j, e)| {
            let p = (j as f64).exp2();
            e * (w + f * p + r * p * p)
        })
        .sum()
}

/// Options of [`fit_thermal`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThermalOptions {
    /// Smallest span of board temperature accepted, °C.
    pub min_span_c: f64,
    /// Reference temperature, °C; `None` = the record's mean temperature rounded to 0.01 °C (the table's unit).
    pub t_ref_c: Option<f64>,
}

impl Default for ThermalOptions {
    fn default() -> Self {
        Self {
            min_span_c: 10.0,
            t_ref_c: None,
        }
    }
}

/// A thermal fit of the 16 groups.
#[derive(Clone, Debug, PartialEq)]
pub struct ThermalFit {
    /// Reference temperature, °C.
    pub t_ref_c: f64,
    /// Per group: the coefficients.
    pub terms: Vec<GroupThermalF64>,
    /// Standard errors, residuals, intercepts, the record's temperature range.
    pub meta: ThermalFitMetadata,
    /// Frames without a valid temperature (left out).
    pub skipped: usize,
}

/// A frame with a valid temperature: its index and the temperature, °C.
type Sample = (usize, f64);

/// The frames with a valid temperature, the temperature range and the reference temperature; checks
/// the options, that there is a temperature and that it spans enough.
fn temperatures(
    frames: &[Decoded],
    opts: &ThermalOptions,
) -> Result<(Vec<Sample>, [f64; 2], f64), CalibError> {
    if !(opts.min_span_c.is_finite() && opts.min_span_c > 0.0) {
        return Err(CalibError::InvalidOption(
            "thermal fit: min_span_c must be > 0",
        ));
    }
    let temps: Vec<(usize, f64)> = frames
        .iter()
        .enumerate()
        .filter_map(|(i, d)| d.frame.temp_cdeg.map(|t| (i, f64::from(t) / 100.0)))
        .collect();
    if temps.is_empty() {
        return Err(CalibError::NoTemperature {
            frames: frames.len(),
        });
    }
    let (lo, hi) = temps
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), &(_, t)| {
            (l.min(t), h.max(t))
        });
    if hi - lo < opts.min_span_c {
        return Err(CalibError::TemperatureSpan {
            from_c: lo,
            to_c: hi,
            needed_c: opts.min_span_c,
        });
    }
    let t_ref_c = match opts.t_ref_c {
        Some(t) if t.is_finite() => t,
        Some(_) => return Err(CalibError::NonFinite("thermal fit: reference temperature")),
        None => {
            (temps.iter().map(|x| x.1).sum::<f64>() / temps.len() as f64 * 100.0).round() / 100.0
        }
    };
    Ok((temps, [lo, hi], t_ref_c))
}

/// Fits the thermal terms of every raw channel to `frames` (see the module docs); frames without a valid
/// temperature are left out. Fails when no frame has a temperature, when the temperatures span less than
/// `opts.min_span_c`, or on a bad option.
pub fn fit_thermal(
    frames: &[Decoded],
    opts: &ThermalOptions,
    source: &str,
) -> Result<ThermalFit, CalibError> {
    let (temps, [lo, hi], t_ref_c) = temperatures(frames, opts)?;
    let n = temps.len();
    let x = |t: f64| {
        let u = (t - t_ref_c) / UNIT_C;
        Vector3::new(1.0, u, u * u)
    };
    let code =
        |i: usize, c: usize| f64::from(frames[i].frame.raw[c / RAW_PER_GROUP][c % RAW_PER_GROUP]);
    // Codes relative to the first frame's, so that the sums keep their precision.
    let y0: Vec<f64> = (0..CH).map(|c| code(temps[0].0, c)).collect();
    let mut a = Matrix3::zeros();
    let mut xty = vec![Vector3::zeros(); CH];
    let mut yy = vec![0.0; CH];
    for &(i, t) in &temps {
        let xk = x(t);
        a += xk * xk.transpose();
        for c in 0..CH {
            let y = code(i, c) - y0[c];
            xty[c] += xk * y;
            yy[c] += y * y;
        }
    }
    let chol = a.cholesky().ok_or(CalibError::Degenerate(
        "thermal fit: the temperatures do not determine a quadratic (fewer than 3 distinct values)",
    ))?;
    let a_inv = chol.inverse();
    let beta: Vec<Vector3<f64>> = xty.iter().map(|v| chol.solve(v)).collect();
    // Each coefficient's weights over the samples, and their Haar energy per level.
    let rows: Vec<[f64; 2]> = temps
        .iter()
        .map(|&(_, t)| {
            let r = a_inv * x(t);
            [r[1], r[2]]
        })
        .collect();
    let energy: [Vec<f64>; 2] =
        core::array::from_fn(|i| haar_energy(&rows.iter().map(|r| r[i]).collect::<Vec<_>>()));
    let mut resid = vec![0.0; n];
    let dof = (n as f64 - 3.0).max(1.0);
    let mut terms = vec![GroupThermalF64::default(); GROUPS];
    let mut fits = vec![
        ThermalChannelFits {
            lin_se_counts_per_c: [0.0; 7],
            quad_se_counts_per_c2: [0.0; 7],
            residual_rms_counts: [0.0; 7],
            intercept_counts: [0.0; 7],
        };
        GROUPS
    ];
    for c in 0..CH {
        let (g, ch) = (c / RAW_PER_GROUP, c % RAW_PER_GROUP);
        let b = &beta[c];
        for (r, &(i, t)) in resid.iter_mut().zip(&temps) {
            *r = code(i, c) - y0[c] - x(t).dot(b);
        }
        let lv = haar_level_var(&resid);
        let var = [
            haar_variance(&energy[0], &lv),
            haar_variance(&energy[1], &lv),
        ];
        let (lin, quad) = (b[1] / UNIT_C, b[2] / (UNIT_C * UNIT_C));
        let t = &mut terms[g];
        if ch < 4 {
            t.gyro_lin_counts_per_c[ch] = lin;
            t.gyro_quad_counts_per_c2[ch] = quad;
        } else {
            t.accel_lin_counts_per_c[ch - 4] = lin;
            t.accel_quad_counts_per_c2[ch - 4] = quad;
        }
        let f = &mut fits[g];
        f.lin_se_counts_per_c[ch] = var[0].max(0.0).sqrt() / UNIT_C;
        f.quad_se_counts_per_c2[ch] = var[1].max(0.0).sqrt() / (UNIT_C * UNIT_C);
        f.residual_rms_counts[ch] = ((yy[c] - b.dot(&xty[c])).max(0.0) / dof).sqrt();
        f.intercept_counts[ch] = b[0] + y0[c];
    }
    Ok(ThermalFit {
        t_ref_c,
        terms,
        meta: ThermalFitMetadata {
            source: source.to_string(),
            temp_range_c: [lo, hi],
            samples: n,
            groups: fits,
        },
        skipped: frames.len() - n,
    })
}
