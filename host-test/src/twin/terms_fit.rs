//! The composite noise model fitted to an Allan-variance curve: the five IEEE 952 terms, up to [`GM_MAX`]
//! first-order Gauss–Markov terms (the GMWM model of real IMUs: Guerrier et al. 2013) and up to [`LINES_MAX`]
//! narrow-band Gauss–Markov terms (wandering lines), how many of each chosen on held-out data.
//!
//! - **Fit at a given set of terms**: the Allan variance is linear in the five coefficients and in each
//!   Gauss–Markov variance σ², so every term is fitted by non-negative least squares
//!   ([`crate::allan::noisefit::nnls_first`]), each point weighted by the inverse variance of its estimate (`ν/2σ⁴`
//!   at its Greenhall EDF ν: the diagonal of the estimator's covariance).
//! - **Correlation times**: chosen greedily from a grid (two per octave, from 2τ₀ to 1/32 of the longest τ of the
//!   curve): the first the one whose fit costs least, the second given the first. Then the lines, greedily, the
//!   first-order terms held: frequencies four per octave from 16 periods in the longest τ to 0.45/τ₀, each with a
//!   coherence of 2 and 8 periods, T from 2τ₀ to a quarter of the longest τ.
//! - **How many**: 0, 1 or [`GM_MAX`] first-order terms, chosen by two-fold cross-validation: fitted on one half of
//!   the record, scored (`Σ (ν/2)·ln²(model/observed)`, a χ²) on the other half's curve, both ways; one more term
//!   is kept only if it lowers the held-out cost by 6 (a χ²₂'s 95th percentile). Then 0 to [`LINES_MAX`] lines
//!   (where [`Spec::lines`] offers them), one more kept only if it lowers the held-out cost by χ²₃'s quantile at
//!   1 − 5 %/(candidates) (three parameters, the search over the grid counted). The terms are then fitted on the
//!   whole record with those counts. Without halves (a record too short to split), no Gauss–Markov term.

use super::{GM_MAX, GaussMarkov, NoiseTerms, basis, line_basis};
use crate::allan::AnalysisPoint;
use crate::allan::noisefit::{LowPass, nnls_first};

/// One point of a curve to fit.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Obs {
    /// τ, s.
    pub tau_s: f64,
    /// The Allan variance the terms should give there, unit².
    pub avar: f64,
    /// Weight: the inverse variance of `avar`.
    pub weight: f64,
}

impl Obs {
    /// Octave points as observations of their own Allan variance (`dev²`, weight `ν/2σ⁴`); points without a
    /// finite positive deviation are left out.
    pub fn of(points: &[AnalysisPoint]) -> Vec<Obs> {
        points
            .iter()
            .filter(|p| p.dev > 0.0 && p.dev.is_finite())
            .map(|p| {
                let y = p.dev * p.dev;
                Obs {
                    tau_s: p.tau_s,
                    avar: y,
                    weight: edf(p) / 2.0 / (y * y),
                }
            })
            .collect()
    }
}

/// A point's EDF (its block count where it has none), at least 1.
pub fn edf(p: &AnalysisPoint) -> f64 {
    p.edf
        .filter(|e| e.is_finite() && *e > 0.0)
        .unwrap_or(p.n as f64)
        .max(1.0)
}

/// What is fitted and how.
#[derive(Clone, Copy, Debug)]
pub struct Spec<'a> {
    /// Sample interval of the record, s (the Gauss–Markov terms are its sampled AR(1)).
    pub tau0_s: f64,
    /// The sensors' single-pole response, seen by the white term.
    pub band: Option<&'a LowPass>,
    /// Whether narrow-band terms are offered (the twin's fits; the diagnosis's typical shape, which sets its noise
    /// types and EDFs, keeps the first-order family).
    pub lines: bool,
}

/// Most narrow-band Gauss–Markov terms (wandering lines) a curve is given, besides its first-order ones.
pub const LINES_MAX: usize = 2;

/// Columns of a fit: the five terms, the first-order Gauss–Markov terms, then the narrow-band ones.
const COLS: usize = 5 + GM_MAX + LINES_MAX;

/// One candidate term: a correlation time and a frequency (0 for the first-order term).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Candidate {
    t_s: f64,
    f_hz: f64,
}

/// How many terms of each kind a fit holds: first-order Gauss–Markov terms, then narrow-band ones.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
struct Counts {
    first_order: usize,
    lines: usize,
}

/// The terms of `whole`, the Gauss–Markov counts chosen on `halves` (module docs).
pub fn fit(whole: &[Obs], halves: Option<[&[Obs]; 2]>, spec: &Spec) -> NoiseTerms {
    let k = halves.map_or(Counts::default(), |[a, b]| chosen_counts(a, b, spec).0);
    fit_counts(whole, k, spec)
        .map(|(t, _)| t)
        .unwrap_or_default()
}

/// [`fit`] with the sensors' bandwidth put to the same held-out test: the fit without it replaces the fit with it
/// when its two-fold held-out cost is lower by `HELD_OUT_GAIN_MIN` (a Gauss–Markov bump can pass for a
/// single-pole roll-off in the diagnosis's look at short τ, and then no term of the family follows the record).
/// Returns the terms and whether the bandwidth is kept; without a bandwidth or halves, [`fit`] and `true`.
pub fn fit_band_tested(
    whole: &[Obs],
    halves: Option<[&[Obs]; 2]>,
    spec: &Spec,
) -> (NoiseTerms, bool) {
    let (Some(_), Some([a, b])) = (spec.band, halves) else {
        return (fit(whole, halves, spec), true);
    };
    let plain = Spec {
        band: None,
        ..*spec
    };
    let (k_band, cost_band) = chosen_counts(a, b, spec);
    let (k_plain, cost_plain) = chosen_counts(a, b, &plain);
    let (k, s, kept) = if cost_plain < cost_band - HELD_OUT_GAIN_MIN {
        (k_plain, &plain, false)
    } else {
        (k_band, spec, true)
    };
    let terms = fit_counts(whole, k, s).map(|(t, _)| t).unwrap_or_default();
    (terms, kept)
}

/// What one more first-order Gauss–Markov term (two parameters) must take off the held-out cost (a χ², the points
/// weighted by their inverse variance) to be kept: a χ²₂ exceeds 6 with probability 5 %.
const HELD_OUT_GAIN_MIN: f64 = 6.0;

/// What one more narrow-band term (three parameters, the best of `candidates`) must take off the held-out cost:
/// χ²₃'s quantile at 1 − 5 %/candidates (the search over the grid counted, Bonferroni).
fn line_gain_min(candidates: usize) -> f64 {
    use statrs::distribution::{ChiSquared, ContinuousCDF};
    ChiSquared::new(3.0).map_or(f64::INFINITY, |c| {
        c.inverse_cdf(1.0 - 0.05 / candidates.max(1) as f64)
    })
}

/// The two-fold held-out cost of fits with `k` terms: fitted on each half, scored on the other.
fn held_out(a: &[Obs], b: &[Obs], k: Counts, spec: &Spec) -> f64 {
    [(a, b), (b, a)]
        .iter()
        .map(|(fit_on, score_on)| {
            fit_counts(fit_on, k, spec)
                .map_or(f64::INFINITY, |(t, _)| held_out_cost(&t, score_on, spec))
        })
        .sum()
}

/// The Gauss–Markov counts with the lowest two-fold held-out cost: first the first-order count, a count above
/// another kept only if it lowers the cost by [`HELD_OUT_GAIN_MIN`]; then, with it, the narrow-band count, one more
/// kept only if it lowers the cost by [`line_gain_min`] over the candidates of the halves' grid.
/// Returns the counts and their held-out cost.
fn chosen_counts(a: &[Obs], b: &[Obs], spec: &Spec) -> (Counts, f64) {
    let mut best = (f64::INFINITY, Counts::default());
    for first_order in 0..=GM_MAX {
        let k = Counts {
            first_order,
            lines: 0,
        };
        let cost = held_out(a, b, k, spec);
        if cost < best.0 - HELD_OUT_GAIN_MIN {
            best = (cost, k);
        }
    }
    let gain = line_gain_min(
        line_grid(a, spec.tau0_s)
            .len()
            .max(line_grid(b, spec.tau0_s).len()),
    );
    for lines in (1..=LINES_MAX).filter(|_| spec.lines) {
        let k = Counts { lines, ..best.1 };
        let cost = held_out(a, b, k, spec);
        if cost < best.0 - gain {
            best = (cost, k);
        }
    }
    (best.1, best.0)
}

/// The misfit of `terms` on held-out `obs`: `Σ (ν/2)·ln²(model/observed)` (each point's log Allan variance has
/// variance 2/ν), which, unlike the fit's cost, does not favour a model that dips under the low points; where an
/// observation or the model is not positive, the fit's weighted squared misfit.
fn held_out_cost(terms: &NoiseTerms, obs: &[Obs], spec: &Spec) -> f64 {
    obs.iter()
        .map(|o| {
            let m = terms.avar(o.tau_s, spec.tau0_s, spec.band);
            let nu_half = o.weight * o.avar * o.avar;
            if m > 0.0 && o.avar > 0.0 {
                nu_half * (m / o.avar).ln().powi(2)
            } else {
                o.weight * (m - o.avar).powi(2)
            }
        })
        .sum()
}

/// The weighted squared misfit of `terms` on `obs`.
fn cost(terms: &NoiseTerms, obs: &[Obs], spec: &Spec) -> f64 {
    obs.iter()
        .map(|o| o.weight * (terms.avar(o.tau_s, spec.tau0_s, spec.band) - o.avar).powi(2))
        .sum()
}

fn longest(obs: &[Obs]) -> f64 {
    obs.iter().map(|o| o.tau_s).fold(0.0, f64::max)
}

/// The first-order correlation times tried: two per octave from 2τ₀ to 1/32 of the longest τ of `obs`. A longer
/// one acts as a random walk or a flicker over the few blocks there, and the halves of a random-walk record were
/// seen to choose one (a Gauss–Markov term at 29 s took a quarter of K in a 1 310-s record).
fn grid(obs: &[Obs], tau0_s: f64) -> Vec<Candidate> {
    let hi = longest(obs) / 32.0;
    let mut t = 2.0 * tau0_s;
    let mut v = Vec::new();
    while t <= hi && v.len() < 64 {
        v.push(Candidate { t_s: t, f_hz: 0.0 });
        t *= std::f64::consts::SQRT_2;
    }
    v
}

/// The narrow-band candidates: frequencies four per octave from 16 periods in the longest τ of `obs` to 0.45/τ₀
/// (below Nyquist), each with a coherence of 2 and 8 periods (`T·f`), T from 2τ₀ to a quarter of the longest τ
/// (a line does not act as a random walk at long τ: its spectrum falls off below its frequency).
fn line_grid(obs: &[Obs], tau0_s: f64) -> Vec<Candidate> {
    let (longest, mut v) = (longest(obs), Vec::new());
    if longest <= 0.0 {
        return v;
    }
    let mut f = 16.0 / longest;
    while f <= 0.45 / tau0_s && v.len() < 256 {
        for cycles in [2.0, 8.0] {
            let t_s = cycles / f;
            if (2.0 * tau0_s..=longest / 4.0).contains(&t_s) {
                v.push(Candidate { t_s, f_hz: f });
            }
        }
        f *= 2f64.powf(0.25);
    }
    v
}

/// The best fit with `k` terms, chosen greedily: the first-order correlation times one after another, then the
/// lines with those held: (terms, cost).
fn fit_counts(obs: &[Obs], k: Counts, spec: &Spec) -> Option<(NoiseTerms, f64)> {
    let mut chosen: Vec<Candidate> = Vec::new();
    for (grid, n) in [
        (grid(obs, spec.tau0_s), k.first_order),
        (line_grid(obs, spec.tau0_s), k.lines),
    ] {
        for _ in 0..n {
            let best = grid
                .iter()
                .filter(|c| !chosen.contains(c))
                .filter_map(|&c| {
                    let mut cc = chosen.clone();
                    cc.push(c);
                    solve(obs, &cc, spec).map(|(_, cost)| (c, cost))
                })
                .min_by(|x, y| x.1.total_cmp(&y.1));
            match best {
                Some((c, _)) => chosen.push(c),
                None => break,
            }
        }
    }
    solve(obs, &chosen, spec)
}

/// Non-negative least squares with Gauss–Markov terms at `chosen`: (terms, cost).
fn solve(obs: &[Obs], chosen: &[Candidate], spec: &Spec) -> Option<(NoiseTerms, f64)> {
    let rows: Vec<([f64; COLS], f64, f64)> = obs
        .iter()
        .map(|o| {
            let mut r = [0.0; COLS];
            r[..5].copy_from_slice(&basis(o.tau_s, spec.band));
            for (x, c) in r[5..].iter_mut().zip(chosen) {
                *x = line_basis(c.t_s, c.f_hz, o.tau_s, spec.tau0_s);
            }
            (r, o.avar, o.weight)
        })
        .collect();
    let c = nnls_first::<COLS>(&rows, 5 + chosen.len())?;
    let mut five = [0.0; 5];
    five.copy_from_slice(&c[..5]);
    let mut terms = NoiseTerms::from_avar_coefficients(five);
    terms.gauss_markov = chosen
        .iter()
        .zip(&c[5..])
        .filter(|(_, v)| **v > 0.0)
        .map(|(c, &v)| GaussMarkov {
            sigma: v.sqrt(),
            tau_s: c.t_s,
            freq_hz: c.f_hz,
        })
        .collect();
    let cost = cost(&terms, obs, spec);
    Some((terms, cost))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::allan::{Analyzer, DevKind, Options, TauSpec};
    use crate::sim::noise::{NoiseModel, NoiseParams, Sampling, SensorNoise};

    const TAU0: f64 = 0.01;
    const N: usize = 1 << 17;

    /// The whole record's and its halves' observations of `params` played by the simulator.
    fn curves(params: &NoiseParams, seed: u64) -> (Vec<Obs>, [Vec<Obs>; 2], NoiseModel) {
        let sampling = Sampling::new(1.0 / TAU0, N as f64 * TAU0).unwrap();
        let x = SensorNoise::series(params, &sampling, N, seed).unwrap();
        let (whole, halves) = whole_and_halves(&x);
        (whole, halves, NoiseModel::new(params, &sampling).unwrap())
    }

    /// The octave observations of a series and of its halves.
    fn whole_and_halves(x: &[f64]) -> (Vec<Obs>, [Vec<Obs>; 2]) {
        let mut an = Analyzer::new();
        let mut obs = |s: &[f64]| {
            Obs::of(&an.analyze(
                DevKind::Oadev,
                s,
                TAU0,
                &TauSpec::Octave,
                &Options::default(),
            ))
        };
        let whole = obs(x);
        (whole, [obs(&x[..N / 2]), obs(&x[N / 2..])])
    }

    fn spec() -> Spec<'static> {
        Spec {
            tau0_s: TAU0,
            band: None,
            lines: true,
        }
    }

    /// White noise with a Gauss–Markov bump (σ 0.05, T 0.2 s, as strong as the white noise at τ ≈ T): the fit
    /// keeps a Gauss–Markov term near 0.2 s and its curve follows the simulator's exact Allan variance within 10 %
    /// at every τ with at least 16 blocks; the five terms alone miss it by more.
    #[test]
    fn a_gauss_markov_bump_is_found_and_its_curve_followed() {
        let params = NoiseParams {
            white: 0.01,
            gm_sigma: 0.05,
            gm_tau_s: 0.2,
            ..NoiseParams::default()
        };
        let (whole, [a, b], truth) = curves(&params, 41);
        let t = fit(&whole, Some([&a, &b]), &spec());
        assert!(!t.gauss_markov.is_empty(), "{t:?}");
        assert!(
            t.gauss_markov.iter().all(|g| g.freq_hz == 0.0),
            "a line: {t:?}"
        );
        let main = t
            .gauss_markov
            .iter()
            .max_by(|x, y| x.sigma.total_cmp(&y.sigma))
            .unwrap();
        assert!((main.tau_s / 0.2).ln().abs() < 2f64.ln(), "{t:?}");
        let five = fit(&whole, None, &spec());
        let worst = |terms: &NoiseTerms| {
            whole
                .iter()
                .filter(|o| o.tau_s <= N as f64 * TAU0 / 16.0)
                .map(|o| {
                    (terms.avar(o.tau_s, TAU0, None) / truth.expected_avar(o.tau_s) - 1.0).abs()
                })
                .fold(0.0, f64::max)
        };
        assert!(worst(&t) < 0.10, "with GM {} ({t:?})", worst(&t));
        assert!(
            worst(&five) > 2.0 * worst(&t),
            "five terms {} vs {}",
            worst(&five),
            worst(&t)
        );
    }

    /// White noise and a random walk: the held-out halves choose no Gauss–Markov term.
    #[test]
    fn white_noise_and_random_walk_get_no_gauss_markov_term() {
        for seed in [5, 6, 7] {
            let params = NoiseParams {
                white: 0.01,
                rrw: 1e-3,
                ..NoiseParams::default()
            };
            let (whole, [a, b], _) = curves(&params, seed);
            let t = fit(&whole, Some([&a, &b]), &spec());
            assert!(t.gauss_markov.is_empty(), "seed {seed}: {t:?}");
            assert!((t.white / 0.01 - 1.0).abs() < 0.05, "seed {seed}: {t:?}");
        }
    }

    /// White noise with a wandering line (σ 0.05 at 5 Hz, coherent over 2 periods: T 0.4 s), played exactly
    /// (`sim::noise::add_line`): the fit keeps a narrow-band term within a quarter octave of 5 Hz, and its curve
    /// follows the exact Allan variance (white + `line_avar`) within 10 % at every τ with at least 16 blocks, where
    /// the first-order terms alone (two of them) miss by more than twice as much.
    #[test]
    fn a_wandering_line_is_found_and_its_curve_followed() {
        let (white, sigma, f_hz, t_s) = (0.01f64, 0.05f64, 5.0, 0.4);
        let (a, theta) = (TAU0 / t_s, std::f64::consts::TAU * f_hz * TAU0);
        let mut r = crate::testrng::TestRng::new(43);
        let mut x: Vec<f64> = (0..N).map(|_| white / TAU0.sqrt() * r.normal()).collect();
        crate::sim::noise::add_line(&mut x, sigma * sigma, a, theta, 44);
        let (whole, [h0, h1]) = whole_and_halves(&x);
        let t = fit(&whole, Some([&h0, &h1]), &spec());
        let line = t
            .gauss_markov
            .iter()
            .find(|g| g.freq_hz > 0.0)
            .unwrap_or_else(|| panic!("no line: {t:?}"));
        assert!(
            (line.freq_hz / f_hz).ln().abs() <= 0.25 * 2f64.ln() + 1e-9,
            "{t:?}"
        );
        let exact = |tau_s: f64| {
            white * white / tau_s
                + crate::sim::noise::line_avar(sigma * sigma, a, theta, tau_s / TAU0)
        };
        let worst = |terms: &NoiseTerms| {
            whole
                .iter()
                .filter(|o| o.tau_s <= N as f64 * TAU0 / 16.0)
                .map(|o| (terms.avar(o.tau_s, TAU0, None) / exact(o.tau_s) - 1.0).abs())
                .fold(0.0, f64::max)
        };
        let first_order = fit_counts(
            &whole,
            Counts {
                first_order: GM_MAX,
                lines: 0,
            },
            &spec(),
        )
        .unwrap()
        .0;
        eprintln!(
            "line at {:.2} Hz, T {:.3} s; worst {:.3} with it, {:.3} with first-order terms",
            line.freq_hz,
            line.tau_s,
            worst(&t),
            worst(&first_order)
        );
        assert!(worst(&t) < 0.10, "with the line {} ({t:?})", worst(&t));
        assert!(
            worst(&first_order) > 2.0 * worst(&t),
            "first-order terms {} vs {}",
            worst(&first_order),
            worst(&t)
        );
    }
}
