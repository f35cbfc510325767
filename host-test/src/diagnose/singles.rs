//! Per half and axis: the single sensors' and the cluster's Allan variances, EDFs and noise types, and the small statistics they use.

use super::model::Terms;
use crate::allan::chi2_z;
use crate::allan::median_to_mean;
use crate::allan::noisefit;
use crate::allan::noisefit::NoiseFit;
use crate::allan::{
    AnalysisPoint, Analyzer, DevKind, Halves, Options as AllanOptions, TauSpec, edf_for_kind,
};
use crate::stats::median;
use crate::twin::{GaussMarkov, gm_basis};

pub(super) fn octave(an: &mut Analyzer, y: &[f64], tau0: f64) -> Vec<AnalysisPoint> {
    an.analyze(
        DevKind::Oadev,
        y,
        tau0,
        &TauSpec::Octave,
        &AllanOptions::default(),
    )
}

/// [`octave`]'s τ and deviations only (no noise type, EDF or interval; the same values), where nothing else is read.
pub(super) fn octave_devs(an: &mut Analyzer, y: &[f64], tau0: f64) -> Vec<AnalysisPoint> {
    an.deviations(DevKind::Oadev, y, tau0, &TauSpec::Octave)
}

/// [`octave`] of the first half of `y`, and [`octave_devs`] of its second half and of the whole, from one pass over
/// each half (`Analyzer::analyze_halves`: the halves' values the same, the whole's up to rounding).
pub(super) fn octave_halves(an: &mut Analyzer, y: &[f64], tau0: f64) -> Halves {
    an.analyze_halves(y, tau0, &TauSpec::Octave, &AllanOptions::default())
}

pub(super) fn weighted_mean(series: &[&[f64]], w: &[f64]) -> Vec<f64> {
    let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
    let mut out = vec![0.0; len];
    // By pieces that stay in the cache while every series is added in (each sample's sum in the same order).
    const PIECE: usize = 2048;
    for (k, piece) in out.chunks_mut(PIECE).enumerate() {
        let at = k * PIECE;
        for (s, wi) in series.iter().zip(w) {
            for (o, x) in piece.iter_mut().zip(s.get(at..).unwrap_or(&[])) {
                *o += wi * x;
            }
        }
    }
    out
}

/// The typical model as five terms.
pub(super) fn terms_of(f: &NoiseFit) -> Terms {
    Terms([
        3.0 * f.quantization.powi(2),
        f.white.powi(2),
        noisefit::FLICKER_AVAR * f.bias_instability.powi(2),
        f.random_walk.powi(2) / 3.0,
        0.0,
    ])
}

/// Noise type (α of the rate's PSD) of the term that dominates `t` at `tau_s`: quantisation 2 (white phase),
/// white 0, flicker −1, random walk and ramp −2.
pub(super) fn dominant_alpha(t: &Terms, tau_s: f64) -> i32 {
    let b = Terms::basis(tau_s);
    let k = (0..5)
        .max_by(|&i, &j| (b[i] * t.0[i]).total_cmp(&(b[j] * t.0[j])))
        .unwrap_or(1);
    [2, 0, -1, -2, -2][k]
}

/// The typical sensor's noise shape, for the noise type that sets each τ's EDF: its five terms and its first-order
/// Gauss–Markov terms (AR(1) sampled every `tau0_s`; none unless the held-out criterion of
/// [`crate::twin::terms_fit`] keeps them).
#[derive(Clone, Debug, Default)]
pub(super) struct Shape {
    /// The five terms.
    pub(super) five: Terms,
    /// The Gauss–Markov terms.
    pub(super) gm: Vec<GaussMarkov>,
    /// Sample interval, s.
    pub(super) tau0_s: f64,
}

impl Shape {
    /// Noise type (α) at `tau_s` of the term that dominates there: a five-term's own ([`dominant_alpha`]), or, where
    /// a Gauss–Markov term is larger, the power law its Allan variance follows locally (slope μ over the octave
    /// about τ, `α = −μ − 1` rounded into [−2, 0]: random walk below its correlation time, flicker at its peak,
    /// white beyond).
    pub(super) fn alpha(&self, tau_s: f64) -> i32 {
        let b = Terms::basis(tau_s);
        let five = (0..5).map(|k| b[k] * self.five.0[k]).fold(0.0, f64::max);
        let gm = self
            .gm
            .iter()
            .map(|g| (g, g.avar(tau_s, self.tau0_s)))
            .max_by(|x, y| x.1.total_cmp(&y.1));
        match gm {
            Some((g, v)) if v > five => {
                let at = |t: f64| gm_basis(g.tau_s, t, self.tau0_s);
                let (lo, hi) = (
                    at(tau_s / std::f64::consts::SQRT_2),
                    at(tau_s * std::f64::consts::SQRT_2),
                );
                if lo > 0.0 && hi > 0.0 {
                    let mu = (hi / lo).log2();
                    (-mu - 1.0).round().clamp(-2.0, 0.0) as i32
                } else {
                    0
                }
            }
            _ => dominant_alpha(&self.five, tau_s),
        }
    }
}

/// Region name of a τ under the typical model.
pub(super) fn region_name(t: &Terms, tau_s: f64) -> &'static str {
    match dominant_alpha(t, tau_s) {
        2 => "quantization",
        0 => "white",
        -1 => "flicker",
        _ => "random_walk",
    }
}

/// EDF of an OADEV at factor `m` on `n` samples for noise type `alpha` (fallback: the white-FM count).
pub(super) fn edf(alpha: i32, m: usize, n: usize) -> f64 {
    edf_for_kind(DevKind::Oadev, alpha, m, n)
        .unwrap_or_else(|| (1.5 * n as f64 / m.max(1) as f64).max(1.0))
}

/// The typical sensor's variance at one point from the sensors' estimates `d` (EDF `nu_s` each): their median
/// corrected to a mean, and the uncertainty of its ln (the median of N estimates has ≈ π/2 × the variance of their
/// mean; ln of a variance estimate has variance 2/ν).
fn typical_of(d: &[f64], nu_s: f64) -> (f64, f64) {
    let ns = d.len().max(1) as f64;
    (
        median(d) * median_to_mean(nu_s),
        (std::f64::consts::FRAC_PI_2 * 2.0 / nu_s / ns).sqrt(),
    )
}

/// The statistics of one half of one axis at every octave τ it supports.
#[derive(Clone, Debug, Default)]
pub(super) struct Half {
    pub(super) n: usize,
    pub(super) tau_s: Vec<f64>,
    pub(super) m: Vec<usize>,
    /// Cluster Allan variance (weighted mean).
    pub(super) cluster: Vec<f64>,
    /// Its EDF and noise type.
    pub(super) edf: Vec<f64>,
    pub(super) alpha: Vec<i32>,
    /// `singles[i][k]`: sensor i's Allan variance.
    pub(super) singles: Vec<Vec<f64>>,
    /// Bias-corrected median of the singles.
    pub(super) typical: Vec<f64>,
    /// Uncertainty of ln(typical) (variance scale).
    pub(super) typical_sigma: Vec<f64>,
    /// EDF of one sensor's variance.
    pub(super) single_edf: Vec<f64>,
    /// The typical variance a model with per-sensor levels scales its first-half factors by, where this half is
    /// paired with the first ([`Half::pair_with`]); `None` elsewhere (then [`Half::typical`]).
    pub(super) paired: Vec<Option<f64>>,
    /// Temperature Allan variance, °C².
    pub(super) temp: Vec<Option<f64>>,
}

impl Half {
    /// Measures one half: `series` the sensors, `mean` their cluster mean ([`weighted_mean`] with the weights),
    /// `typ` the typical sensor's shape (for noise types).
    #[allow(clippy::too_many_arguments)]
    pub(super) fn measure(
        an: &mut Analyzer,
        series: &[&[f64]],
        mean: &[f64],
        tau0: f64,
        min_blocks: usize,
        typ: &Shape,
        singles_pts: &[Vec<AnalysisPoint>],
        temp: Option<&[f64]>,
    ) -> Half {
        let n = series.iter().map(|s| s.len()).min().unwrap_or(0);
        let cl = octave_devs(an, mean, tau0);
        let temp_pts = temp.map(|t| octave_devs(an, t, tau0)).unwrap_or_default();
        let ns = series.len();
        let mut h = Half {
            n,
            singles: vec![Vec::new(); ns],
            ..Half::default()
        };
        for (k, p) in cl.iter().enumerate() {
            let m = p.m.max(1);
            let ok = n / m >= min_blocks
                && p.dev > 0.0
                && singles_pts
                    .iter()
                    .all(|s| s.get(k).is_some_and(|q| q.m == p.m));
            if !ok {
                continue;
            }
            // The noise type of the typical sensor's model (first half) sets the EDF: it is the type of the
            // cluster under the null hypothesis the z-scores test (the cluster's own curve at four blocks would
            // identify a type by chance).
            let a_typ = typ.alpha(p.tau_s);
            let alpha = a_typ;
            let nu = edf(alpha, m, n);
            let d: Vec<f64> = singles_pts.iter().map(|s| s[k].dev.powi(2)).collect();
            let nu_s = edf(a_typ, m, n);
            h.tau_s.push(p.tau_s);
            h.m.push(m);
            h.cluster.push(p.dev * p.dev);
            h.edf.push(nu);
            h.alpha.push(alpha);
            let (typical, sigma) = typical_of(&d, nu_s);
            h.typical.push(typical);
            h.typical_sigma.push(sigma);
            h.single_edf.push(nu_s);
            h.paired.push(None);
            for (hs, di) in h.singles.iter_mut().zip(&d) {
                hs.push(*di);
            }
            h.temp
                .push(temp_pts.iter().find(|q| q.m == p.m).map(|q| q.dev * q.dev));
        }
        h
    }

    /// Scales the first half's per-sensor levels to this half with every sensor, not the median one: the first
    /// half's typical variance times the median over sensors of their own ratio, this half's variance over the
    /// first's. A model with levels predicts `Σ w_i² q_i·V` with `q_i = σ̂²_i/V` measured on the first half; scaled
    /// by this half's median `V` instead, on unequal parts the prediction carries the χ² scatter of the one sensor
    /// that is the median in each half (`2/ν` twice, not the `π/(2Nν)` of a median of equal parts; on five parts a
    /// median sensor 17 % up at 2τ₀ between the halves was seen to push a level model 27 % over the held-out
    /// cluster). Points without a first-half point at the same averaging factor keep [`Half::typical`].
    pub(super) fn pair_with(&mut self, first: &Half) {
        for k in 0..self.len() {
            let Some(kf) = self
                .m
                .get(k)
                .and_then(|m| first.m.iter().position(|x| x == m))
            else {
                continue;
            };
            let ratios: Vec<f64> = self
                .singles
                .iter()
                .zip(&first.singles)
                .filter_map(|(s, f)| {
                    let r = s.get(k)? / f.get(kf)?;
                    (r.is_finite() && r > 0.0).then_some(r)
                })
                .collect();
            if let (Some(&v_first), Some(p)) = (first.typical.get(kf), self.paired.get_mut(k))
                && ratios.len() == self.singles.len()
                && !ratios.is_empty()
            {
                *p = Some(v_first * median(&ratios));
            }
        }
    }

    /// The typical variance `model` is evaluated with at point `k` for weights `w`, and its ln uncertainty
    /// (variance scale). A model with per-sensor levels, on a paired point: [`Half::paired`], whose prediction
    /// `Σ w_i² σ̂²_i(first)·median_i(r_i)` has ln-variance `(2/ν)(Σ c_i² + (π − 2)/N)`, `c_i = w_i² q_i/Σ w² q`
    /// (the first half's estimates, `2/ν` each, weighted by `c`; the median of the N ratios, `π/2·4/(νN)`; their
    /// covariance, `−2·(2/ν)/N`, since each first-half estimate is in both). Any other: the typical sensor,
    /// [`Half::typical`] and [`Half::typical_sigma`].
    pub(super) fn scale(&self, model: &super::model::Model, w: &[f64], k: usize) -> (f64, f64) {
        let typical = (
            self.typical.get(k).copied().unwrap_or(0.0),
            self.typical_sigma.get(k).copied().unwrap_or(0.0),
        );
        let (Some(Some(v)), Some(&nu), Some(&tau_s)) = (
            self.paired.get(k),
            self.single_edf.get(k),
            self.tau_s.get(k),
        ) else {
            return typical;
        };
        if !model.has_levels() || nu <= 0.0 {
            return typical;
        }
        let c: Vec<f64> = w
            .iter()
            .enumerate()
            .map(|(i, wi)| wi * wi * model.q(i, tau_s))
            .collect();
        let sum: f64 = c.iter().sum();
        let n = w.len().max(1) as f64;
        let sc2: f64 = c.iter().map(|x| (x / sum).powi(2)).sum();
        let var = 2.0 / nu * (sc2 + (std::f64::consts::PI - 2.0) / n);
        if sum > 0.0 && var.is_finite() {
            (*v, var.sqrt())
        } else {
            typical
        }
    }

    pub(super) fn len(&self) -> usize {
        self.tau_s.len()
    }

    /// `Σ w_i² σ̂_i²` at point `k`: the cluster variance this half's own sensors give if they are independent.
    pub(super) fn independent(&self, w: &[f64], k: usize) -> f64 {
        self.singles
            .iter()
            .zip(w)
            .map(|(s, wi)| wi * wi * s.get(k).copied().unwrap_or(0.0))
            .sum()
    }

    /// The z-score of a cluster variance `ratio` times [`Half::independent`] at point `k` against independence
    /// (no prediction involved): the χ² z of the ratio at the cluster's EDF, scaled down by the scatter
    /// `Σ w_i² σ̂_i²` adds (relative variance ≈ `(2/ν_s)·Σw⁴/(Σw²)²`). At the measured ratio this is the report's
    /// cross-covariance z; at a model's ratio, what the model predicts for it.
    pub(super) fn cross_z(&self, w: &[f64], k: usize, ratio: f64) -> f64 {
        let sw2: f64 = w.iter().map(|x| x * x).sum();
        let sw4: f64 = w.iter().map(|x| x.powi(4)).sum();
        let (Some(&nu), Some(&nu_s)) = (self.edf.get(k), self.single_edf.get(k)) else {
            return 0.0;
        };
        let s_m = (2.0 / nu).sqrt();
        let s_i = (2.0 / nu_s * sw4).sqrt() / sw2.max(1e-300);
        chi2_z(ratio, nu) * s_m / (s_m * s_m + s_i * s_i).sqrt()
    }

    /// [`Half::cross_z`] at the measured ratio, the cluster's variance over [`Half::independent`].
    pub(super) fn measured_cross_z(&self, w: &[f64], k: usize) -> f64 {
        let indep = self.independent(w, k);
        let cluster = self.cluster.get(k).copied().unwrap_or(0.0);
        self.cross_z(w, k, cluster / indep.max(1e-300))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A Gauss–Markov term that dominates takes the noise type of its Allan variance's local slope, against the
    /// continuous process's limits (`σ²τ/(3T)·…` rises as τ¹ well below T: random walk; falls as `2σ²T/τ` well
    /// above: white; flat near its peak at τ ≈ 1.89 T: flicker); elsewhere the five terms decide.
    #[test]
    fn a_dominant_gauss_markov_term_sets_the_noise_type_by_its_slope() {
        let shape = Shape {
            five: Terms([0.0, 1e-6, 0.0, 0.0, 0.0]),
            gm: vec![GaussMarkov {
                sigma: 1.0,
                tau_s: 1.0,
                ..Default::default()
            }],
            tau0_s: 0.01,
        };
        assert_eq!(shape.alpha(0.05), -2);
        assert_eq!(shape.alpha(1.89), -1);
        assert_eq!(shape.alpha(100.0), 0);
        // A weak one (Allan variance ≈ 4·10⁻⁹ at 1.89 s against the white term's 5·10⁻⁷): the white term's type.
        let weak = Shape {
            gm: vec![GaussMarkov {
                sigma: 1e-4,
                tau_s: 1.0,
                ..Default::default()
            }],
            ..shape
        };
        assert_eq!(weak.alpha(1.89), 0);
    }

    /// One point of a half whose single-sensor estimates are `singles` (χ²_ν/ν draws about their parts' levels)
    /// and whose cluster estimate is `cluster`, as [`Half::measure`] sets its typical variance.
    fn one_point(singles: &[f64], cluster: f64, nu: f64) -> Half {
        let (typical, sigma) = typical_of(singles, nu);
        Half {
            n: 1000,
            tau_s: vec![1.0],
            m: vec![1],
            cluster: vec![cluster],
            edf: vec![nu],
            alpha: vec![0],
            singles: singles.iter().map(|&v| vec![v]).collect(),
            typical: vec![typical],
            typical_sigma: vec![sigma],
            single_edf: vec![nu],
            temp: vec![None],
            paired: vec![None],
        }
    }

    /// A level model carries the first half's levels to the held-out half. On five unequal parts (levels 0.5–2.4,
    /// equal weights, independent, ν = 200 at the point), its held-out z-score is N(0, 1) with the levels scaled by
    /// [`Half::pair_with`] and the uncertainty of [`Half::scale`]: 4 000 draws from the χ² law of every estimate
    /// (the reference) spread by 0.97 (asserted 0.9–1.1), mean 0.03 (±0.1). Scaled by the held-out median sensor
    /// instead (as before this scale), the same draws spread by 1.47 (asserted > 1.3): both halves' median sensors
    /// scatter as one sensor does, which the median's `π/(2Nν)` (a median of equal parts) understates.
    #[test]
    fn a_level_model_scaled_by_every_sensor_has_standard_z_scores() {
        use super::super::model::Model;
        use super::super::prediction::evaluate;
        let parts = [0.5, 0.8, 1.0, 1.6, 2.4];
        let w = [0.2; 5];
        let nu = 200.0;
        let mut rng = crate::testrng::TestRng::new(0x1e7e_15ca);
        let chi = |rng: &mut crate::testrng::TestRng| {
            (0..nu as usize).map(|_| rng.normal().powi(2)).sum::<f64>() / nu
        };
        let true_cluster: f64 = parts.iter().zip(&w).map(|(p, w)| p * w * w).sum();
        let (mut paired, mut median_scaled) = (Vec::new(), Vec::new());
        for _ in 0..4000 {
            let f: Vec<f64> = parts.iter().map(|p| p * chi(&mut rng)).collect();
            let h: Vec<f64> = parts.iter().map(|p| p * chi(&mut rng)).collect();
            let hf = one_point(&f, true_cluster * chi(&mut rng), nu);
            let mut hh = one_point(&h, true_cluster * chi(&mut rng), nu);
            let model = Model {
                level: f.iter().map(|v| v / hf.typical[0]).collect(),
                ..Model::independent(5)
            };
            median_scaled.push(evaluate(&model, &hh, &w, 0.0)[0].z);
            hh.pair_with(&hf);
            paired.push(evaluate(&model, &hh, &w, 0.0)[0].z);
        }
        let moments = |z: &[f64]| {
            let n = z.len() as f64;
            let mean = z.iter().sum::<f64>() / n;
            let sd = (z.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n - 1.0)).sqrt();
            (mean, sd)
        };
        let (mean, sd) = moments(&paired);
        assert!(
            mean.abs() < 0.1 && (0.9..1.1).contains(&sd),
            "paired: mean {mean}, sd {sd}"
        );
        let (_, sd_median) = moments(&median_scaled);
        assert!(sd_median > 1.3, "median-scaled: sd {sd_median}");
    }
}
