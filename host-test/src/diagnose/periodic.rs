//! `periodic`: a sinusoidal interference, shared by all sensors of an axis (the members' mean) or one sensor's own
//! (that sensor minus the median of the others, as for `bias_step`), found as a line in the periodogram of the
//! first half's block means, above the local background of its neighbouring frequencies, and fitted (period and
//! amplitude) by least squares at the refined frequency. Its Allan variance is the sinusoid's exact one
//! ([`Sine::avar`]); the candidate goes through the held-out selection like any other (spec: `docs/diagnose.md`).

use super::candidates::{AxisWork, Candidate};
use super::model::Cross;
use super::singles::weighted_mean;
use super::types::Groups;
use crate::allan::detrend_linear;
use crate::stats::medians_of_others;
use std::collections::BTreeMap;

use super::model::Sine;

/// Blocks the periodogram works on at most (block length `n / MAX_BLOCKS`, at least one sample).
const MAX_BLOCKS: usize = 8192;
/// Periodogram bins (zero-padded ×2) each side of a line that its background mean is taken over …
const BACKGROUND: usize = 64;
/// … leaving out the line's own Hann main lobe (± 2 original bins).
const LOBE: usize = 4;
/// Fewest whole periods a half must hold (longer periods are drifts to the Allan variance up to T/8).
const MIN_CYCLES: usize = 8;

/// A line found in a periodogram.
#[derive(Clone, Copy, Debug)]
pub(super) struct Line {
    /// The fitted sinusoid.
    pub(super) sine: Sine,
    /// Its power over the background mean (F(2, 2m) per frequency without a line).
    pub(super) score: f64,
    /// The score it passed (Bonferroni over frequencies and tests at `p_false`).
    pub(super) threshold: f64,
}

/// In-place iterative radix-2 FFT; `re.len()` must be a power of two (else nothing is done).
fn fft(re: &mut [f64], im: &mut [f64]) {
    let n = re.len();
    if n < 2 || !n.is_power_of_two() || im.len() != n {
        return;
    }
    let mut j = 0;
    for i in 1..n {
        let mut bit = n >> 1;
        while j & bit != 0 {
            j ^= bit;
            bit >>= 1;
        }
        j |= bit;
        if i < j {
            re.swap(i, j);
            im.swap(i, j);
        }
    }
    let mut len = 2;
    // Each stage's twiddles once (the same values as computed at every butterfly).
    let mut twiddles = Vec::with_capacity(n / 2);
    while len <= n {
        let ang = -2.0 * std::f64::consts::PI / len as f64;
        twiddles.clear();
        twiddles.extend((0..len / 2).map(|k| (ang * k as f64).sin_cos()));
        for start in (0..n).step_by(len) {
            for (k, &(s, c)) in twiddles.iter().enumerate() {
                let (a, b) = (start + k, start + k + len / 2);
                let (xr, xi) = (re[b] * c - im[b] * s, re[b] * s + im[b] * c);
                re[b] = re[a] - xr;
                im[b] = im[a] - xi;
                re[a] += xr;
                im[a] += xi;
            }
        }
        len <<= 1;
    }
}

/// Block means of `y` over `b` samples.
pub(super) fn block_means(y: &[f64], b: usize) -> Vec<f64> {
    let b = b.max(1);
    y.chunks_exact(b)
        .map(|c| c.iter().sum::<f64>() / b as f64)
        .collect()
}

/// The block length for `n` samples.
pub(super) fn block_len(n: usize) -> usize {
    n.div_ceil(MAX_BLOCKS).max(1)
}

/// `z` less its least-squares line (a copy; [`detrend_linear`] in place).
pub(super) fn detrend(z: &[f64]) -> Vec<f64> {
    let mut x = z.to_vec();
    detrend_linear(&mut x);
    x
}

/// Hann-windowed power of `x` at `f` cycles per block (direct sum).
fn power_at(x: &[f64], f: f64) -> f64 {
    let n = x.len() as f64;
    let (mut re, mut im) = (0.0, 0.0);
    for (t, v) in x.iter().enumerate() {
        let w = 0.5 - 0.5 * (2.0 * std::f64::consts::PI * t as f64 / n).cos();
        let (s, c) = (2.0 * std::f64::consts::PI * f * t as f64).sin_cos();
        re += w * v * c;
        im -= w * v * s;
    }
    re * re + im * im
}

/// The Hann-windowed periodogram of `x` zero-padded to twice the next power of two: (powers of bins
/// `0..=nfft/2`, nfft).
fn periodogram(x: &[f64]) -> (Vec<f64>, usize) {
    let nfft = 2 * x.len().next_power_of_two();
    let n = x.len() as f64;
    let mut re = vec![0.0; nfft];
    let mut im = vec![0.0; nfft];
    for (t, v) in x.iter().enumerate() {
        re[t] = v * (0.5 - 0.5 * (2.0 * std::f64::consts::PI * t as f64 / n).cos());
    }
    fft(&mut re, &mut im);
    let p = (0..=nfft / 2)
        .map(|k| re[k] * re[k] + im[k] * im[k])
        .collect();
    (p, nfft)
}

/// The mean power of the bins around `k` (± [`BACKGROUND`], without ± [`LOBE`]) and the number of bins.
fn background(p: &[f64], k: usize) -> (f64, usize) {
    let lo = k.saturating_sub(BACKGROUND).max(1);
    let hi = (k + BACKGROUND).min(p.len().saturating_sub(1));
    let v = || {
        (lo..=hi)
            .filter(move |&j| j.abs_diff(k) > LOBE)
            .filter_map(|j| p.get(j).copied())
    };
    let count = v().count();
    (v().sum::<f64>() / count.max(1) as f64, count)
}

/// The score a line must pass among `trials` (frequencies × series) at `p_false`, when the background holds
/// `bins` bins. Without a line a bin's power over the mean of m independent others is F(2, 2m):
/// `P(score > x) = (1 + x/m)^(−m)`; the zero-padded (×2), Hann-windowed bins count as m = bins/4.
fn threshold(trials: f64, bins: usize, p_false: f64) -> f64 {
    let m = (bins as f64 / 4.0).max(1.0);
    m * ((trials.max(1.0) / p_false).powf(1.0 / m) - 1.0)
}

/// The strongest line of the block means `z` (block length `b` samples of `tau0`), if its score passes the
/// Bonferroni threshold at `p_false` over the independent frequencies and `tests` series; period and amplitude
/// fitted at the refined frequency (the amplitude corrected for the block averaging).
pub(super) fn strongest(z: &[f64], b: usize, tau0: f64, tests: f64, p_false: f64) -> Option<Line> {
    let x = detrend(z);
    let nb = x.len();
    if nb < 16 * MIN_CYCLES {
        return None;
    }
    let (p, nfft) = periodogram(&x);
    let pad = nfft as f64 / nb as f64;
    let k_min = ((MIN_CYCLES as f64 * pad).ceil() as usize).max(LOBE + 1);
    let k_max = p.len().saturating_sub(LOBE + 1);
    let (k, score, bins) = (k_min..k_max)
        .map(|k| {
            let (bg, bins) = background(&p, k);
            (k, p[k] / bg.max(1e-300), bins)
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let freqs = (k_max - k_min) as f64 / pad;
    let threshold = threshold(freqs * tests, bins, p_false);
    if score.is_nan() || score <= threshold {
        return None;
    }
    // Refine: the Hann power on a fine grid of ± one padded bin (cycles per block).
    let (f, _) = (-20..=20)
        .map(|s| (k as f64 + s as f64 / 20.0) / nfft as f64)
        .map(|f| (f, power_at(&x, f)))
        .max_by(|a, b| a.1.total_cmp(&b.1))?;
    let period_s = b as f64 * tau0 / f;
    Some(Line {
        sine: Sine {
            amplitude: amplitude(&x, f, b),
            period_s,
            tau0_s: tau0,
        },
        score,
        threshold,
    })
}

/// Least-squares amplitude of a sinusoid at `f` cycles per block in the block means `x`, divided by the attenuation
/// of `b`-sample block means, `|sin(πfb')/(b sin(πf'))|` with f' = f/b cycles per sample.
fn amplitude(x: &[f64], f: f64, b: usize) -> f64 {
    let omega = 2.0 * std::f64::consts::PI * f;
    let points = x.iter().enumerate().map(|(t, &v)| (t as f64, v));
    let Some(fit) = crate::stats::fit_sinusoid(points, omega) else {
        return 0.0;
    };
    let fs = f / b as f64;
    let att = if b > 1 {
        ((std::f64::consts::PI * f).sin() / (b as f64 * (std::f64::consts::PI * fs).sin())).abs()
    } else {
        1.0
    };
    fit.amplitude() / att.max(1e-6)
}

/// The score of a line at `period_s` in the block means `z` and the threshold at `p_false` over `tests` series (no
/// search: the held-out confirmation of a line found on the other half); (0, ∞) when it cannot be measured.
pub(super) fn score_at(
    z: &[f64],
    b: usize,
    tau0: f64,
    period_s: f64,
    tests: f64,
    p_false: f64,
) -> (f64, f64) {
    let x = detrend(z);
    if x.len() < 16 * MIN_CYCLES || period_s <= 0.0 {
        return (0.0, f64::INFINITY);
    }
    let (p, nfft) = periodogram(&x);
    let f = b as f64 * tau0 / period_s;
    let k = (f * nfft as f64).round() as usize;
    if k < 1 || k + 1 >= p.len() {
        return (0.0, f64::INFINITY);
    }
    let (bg, bins) = background(&p, k);
    (
        power_at(&x, f) / bg.max(1e-300),
        threshold(tests, bins, p_false),
    )
}

/// Each sensor's deviation from the others (block means minus the median of the others'), the series a sensor's
/// own line is looked for in: what all sensors see cancels.
pub(super) fn deviations(series: &[&[f64]], b: usize) -> Vec<Vec<f64>> {
    let bm: Vec<Vec<f64>> = series.iter().map(|s| block_means(s, b)).collect();
    let nb = bm.iter().map(Vec::len).min().unwrap_or(0);
    let ns = series.len();
    let (mut at_k, mut sorted, mut med) = (vec![0.0; ns], Vec::with_capacity(ns), vec![0.0; ns]);
    let mut out = vec![vec![0.0; nb]; ns];
    for k in 0..nb {
        for (a, m) in at_k.iter_mut().zip(&bm) {
            *a = m[k];
        }
        medians_of_others(&at_k, &mut sorted, &mut med);
        for ((o, a), m) in out.iter_mut().zip(&at_k).zip(&med) {
            o[k] = a - m;
        }
    }
    out
}

/// One sensor's own line: its index, the line, and its score on the held-out half at the same period with the
/// threshold there (one frequency, Bonferroni over the sensors).
pub(super) struct OwnLine {
    pub(super) sensor: usize,
    pub(super) line: Line,
    pub(super) heldout_score: f64,
    pub(super) heldout_threshold: f64,
}

/// The sensors with their own line on the first half (Bonferroni over the sensors), each scored on the held-out
/// half at the same period. None with fewer than four sensors.
pub(super) fn own_lines(
    first: &[&[f64]],
    second: &[&[f64]],
    tau0: f64,
    p_false: f64,
) -> Vec<OwnLine> {
    let ns = first.len();
    if ns < 4 {
        return Vec::new();
    }
    let n = first.iter().map(|s| s.len()).min().unwrap_or(0);
    let b = block_len(n);
    let d1 = deviations(first, b);
    let d2 = deviations(second, b);
    d1.iter()
        .enumerate()
        .filter_map(|(i, d)| {
            let line = strongest(d, b, tau0, ns as f64, p_false)?;
            let (heldout_score, heldout_threshold) = d2.get(i).map_or((0.0, f64::INFINITY), |h| {
                score_at(h, b, tau0, line.sine.period_s, ns as f64, p_false)
            });
            Some(OwnLine {
                sensor: i,
                line,
                heldout_score,
                heldout_threshold,
            })
        })
        .collect()
}

/// The `periodic` candidates of an axis: one sensor's own lines (those confirmed on the held-out half), else a
/// line of the members' mean shared by `members`.
pub(super) fn periodic_candidates(
    w: &AxisWork,
    first: &[&[f64]],
    own: &[OwnLine],
    members: &[usize],
    tau0: f64,
    p_false: f64,
) -> Vec<Candidate> {
    let mut out = Vec::new();
    let mine: Vec<&OwnLine> = own
        .iter()
        .filter(|o| o.heldout_score > o.heldout_threshold)
        .collect();
    if !mine.is_empty() {
        let per: BTreeMap<String, serde_json::Value> = mine
            .iter()
            .map(|o| {
                (
                    w.groups[o.sensor].to_string(),
                    serde_json::json!({
                        "period_s": o.line.sine.period_s,
                        "amplitude": o.line.sine.amplitude,
                        "score": o.line.score,
                        "threshold": o.line.threshold,
                        "heldout_score": o.heldout_score,
                        "heldout_threshold": o.heldout_threshold,
                    }),
                )
            })
            .collect();
        out.push(Candidate {
            kind: "periodic",
            level: None,
            level_terms: None,
            cross: mine
                .iter()
                .map(|o| Cross::OwnSine {
                    sensor: o.sensor,
                    sine: o.line.sine,
                })
                .collect(),
            groups: Groups::List(mine.iter().map(|o| w.groups[o.sensor]).collect()),
            params: serde_json::json!({ "sensors": per }),
        });
        return out;
    }
    if members.len() < 2 {
        return out;
    }
    let sub: Vec<&[f64]> = members
        .iter()
        .filter_map(|&i| first.get(i).copied())
        .collect();
    let n = sub.iter().map(|s| s.len()).min().unwrap_or(0);
    let b = block_len(n);
    let wm = vec![1.0 / sub.len() as f64; sub.len()];
    let mean = weighted_mean(&sub, &wm);
    if let Some(line) = strongest(&block_means(&mean, b), b, tau0, 1.0, p_false) {
        out.push(Candidate {
            kind: "periodic",
            level: None,
            level_terms: None,
            cross: vec![Cross::SharedSine {
                members: members.to_vec(),
                sine: line.sine,
            }],
            groups: Groups::List(members.iter().map(|&i| w.groups[i]).collect()),
            params: serde_json::json!({
                "period_s": line.sine.period_s,
                "amplitude": line.sine.amplitude,
                "score": line.score,
                "threshold": line.threshold,
            }),
        });
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(seed: u64, n: usize) -> Vec<f64> {
        crate::testrng::TestRng::new(seed).normals(n, 1.0)
    }

    #[test]
    fn fft_matches_the_direct_transform() {
        let x = noise(3, 64);
        let (mut re, mut im) = (x.clone(), vec![0.0; 64]);
        fft(&mut re, &mut im);
        for k in [0usize, 1, 7, 32, 63] {
            let (mut r, mut i) = (0.0, 0.0);
            for (t, v) in x.iter().enumerate() {
                let a = -2.0 * std::f64::consts::PI * (k * t) as f64 / 64.0;
                r += v * a.cos();
                i += v * a.sin();
            }
            assert!(
                (re[k] - r).abs() < 1e-9 && (im[k] - i).abs() < 1e-9,
                "bin {k}"
            );
        }
    }

    #[test]
    fn a_line_in_white_noise_is_found_with_its_period_and_amplitude() {
        // 72,000 samples at 0.2 s (a 4-h half), unit white noise, a sinusoid of 0.05 at 600 s.
        let (tau0, n) = (0.2, 72_000);
        let (amp, period) = (0.05, 600.0);
        let y: Vec<f64> = noise(11, n)
            .iter()
            .enumerate()
            .map(|(k, v)| v + amp * (2.0 * std::f64::consts::PI * k as f64 * tau0 / period).sin())
            .collect();
        let b = block_len(n);
        let l = strongest(&block_means(&y, b), b, tau0, 1.0, 2e-3).expect("line found");
        assert!((l.sine.period_s / period - 1.0).abs() < 0.01, "{l:?}");
        // Amplitude: LS on 8000 blocks of white noise of sd 1/√9 → sd of A ≈ √(2/8000)/3 = 0.005.
        assert!((l.sine.amplitude - amp).abs() < 0.02, "{l:?}");
        // Clean white noise: nothing found in 20 seeds at p = 2e-3.
        let found = (1..=20u64)
            .filter(|s| strongest(&block_means(&noise(s * 31, n), b), b, tau0, 1.0, 2e-3).is_some())
            .count();
        assert!(found <= 1, "{found} lines in 20 clean records");
    }
}
