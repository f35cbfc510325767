//! Deviation kernels (ADEV, OADEV, MDEV) working on the integrated phase.

use super::lanes;

/// Which member of the Allan family to compute.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum DevKind {
    /// Non-overlapping Allan deviation (NIST SP 1065 eq. 7, stride `m`).
    Adev,
    /// Fully overlapping Allan deviation (NIST SP 1065 eq. 11, stride 1).
    Oadev,
    /// Modified Allan deviation (NIST SP 1065 eq. 14).
    Mdev,
}

impl DevKind {
    /// All supported kinds.
    pub const ALL: [DevKind; 3] = [DevKind::Adev, DevKind::Oadev, DevKind::Mdev];

    /// Lower-case name (`"adev"`, `"oadev"`, `"mdev"`).
    pub fn name(self) -> &'static str {
        match self {
            DevKind::Adev => "adev",
            DevKind::Oadev => "oadev",
            DevKind::Mdev => "mdev",
        }
    }

    /// The kind of a lower-case name (`"adev"`, `"oadev"`, `"mdev"`), as [`Self::name`] gives it.
    pub fn from_name(name: &str) -> Result<DevKind, super::ParseError> {
        Self::ALL
            .into_iter()
            .find(|k| k.name() == name)
            .ok_or_else(|| super::ParseError::Kind(name.to_owned()))
    }

    /// Number of terms in the estimator sum, exactly as Stable32 prints it in its `#`
    /// column and allantools returns as `n`, for `n_samples` frequency samples
    /// (`n_samples + 1` phase points) at averaging factor `m`:
    ///
    /// * ADEV: `floor(N/m) − 1` (second differences of phase at stride `m`)
    /// * OADEV: `N + 1 − 2m`
    /// * MDEV: `N + 2 − 3m`
    ///
    /// Returns 0 when the estimator has no term (`m = 0` or `m` too large).
    pub fn n_terms(self, n_samples: usize, m: usize) -> usize {
        if m == 0 {
            return 0;
        }
        match self {
            DevKind::Adev => (n_samples / m).saturating_sub(1),
            DevKind::Oadev => (n_samples + 1).saturating_sub(m.saturating_mul(2)),
            DevKind::Mdev => (n_samples + 2).saturating_sub(m.saturating_mul(3)),
        }
    }

    /// Largest averaging factor kept by allantools for this kind: the largest `m` with
    /// [`n_terms`](Self::n_terms) ≥ 2 (allantools drops results with `n ≤ 1`).
    ///
    /// * ADEV: `floor(N/3)`, OADEV: `floor((N−1)/2)`, MDEV: `floor(N/3)`.
    ///
    /// Returns 0 if no `m` is valid.
    pub fn max_m(self, n_samples: usize) -> usize {
        match self {
            DevKind::Adev | DevKind::Mdev => n_samples / 3,
            DevKind::Oadev => n_samples.saturating_sub(1) / 2,
        }
    }

    /// Stable32 "stop ratio" (Riley, *Evolution of frequency stability analysis software*,
    /// Table III): Stable32's octave/decade runs stop at `m ≤ N / stop_ratio`
    /// (ADEV 5, OADEV 4, MDEV 4). Used by the noise-identification carry rule.
    pub fn stable32_stop_ratio(self) -> usize {
        match self {
            DevKind::Adev => 5,
            DevKind::Oadev | DevKind::Mdev => 4,
        }
    }

    /// Greenhall EDF parameters `(d, overlapping, modified)`.
    pub(crate) fn greenhall_params(self) -> (u32, bool, bool) {
        match self {
            DevKind::Adev => (2, false, false),
            DevKind::Oadev => (2, true, false),
            DevKind::Mdev => (2, true, true),
        }
    }
}

/// One deviation value.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DevPoint {
    /// Averaging factor (τ = m·τ0).
    pub m: usize,
    /// Averaging time τ in seconds.
    pub tau_s: f64,
    /// Number of terms in the estimator (Stable32 `#`, allantools `n`).
    pub n: usize,
    /// The deviation, in the unit of the input samples `y`.
    pub dev: f64,
}

/// Integrated phase of a frequency series, the common input of all kernels.
///
/// `x[0] = 0`, `x[k] = tau0_s · Σ_{i<k} (y[i] − ȳ)`. Removing the mean ȳ before the
/// running sum keeps the phase small, so second differences do not lose precision
/// (without it a large offset such as 1.0 or a gravity bias turns phase rounding into
/// spurious white noise — exactly the artefact visible in two Stable32 reference files).
#[derive(Clone, Debug, Default)]
pub struct Phase {
    x: Vec<f64>,
    tau0_s: f64,
}

impl Phase {
    /// Integrates fractional-frequency samples `y` (interval `tau0_s` seconds).
    /// `None` if `y` is empty, contains a non-finite value, or `tau0_s` is not finite and > 0.
    pub fn from_frequency(y: &[f64], tau0_s: f64) -> Option<Phase> {
        let mut p = Phase::default();
        p.set_frequency(y, tau0_s).then_some(p)
    }

    /// Wraps phase samples `x` (seconds of time error, or unit·s; interval `tau0_s`).
    /// `None` if fewer than 2 points, a non-finite value, or a bad `tau0_s`.
    pub fn from_phase(x: &[f64], tau0_s: f64) -> Option<Phase> {
        let mut p = Phase::default();
        p.set_phase(x, tau0_s).then_some(p)
    }

    /// Like [`from_frequency`](Self::from_frequency) but reuses this buffer.
    /// Returns `false` (and leaves the phase empty) on bad input.
    pub fn set_frequency(&mut self, y: &[f64], tau0_s: f64) -> bool {
        self.x.clear();
        self.tau0_s = tau0_s;
        if y.is_empty() || !valid_tau0(tau0_s) {
            return false;
        }
        // A non-finite value makes the sum non-finite (a finite sum also proves every value finite); only then is
        // the data scanned again, to tell such a value from a sum that overflowed.
        let sum = lanes::sum(y);
        if !sum.is_finite() && y.iter().any(|v| !v.is_finite()) {
            return false;
        }
        let mean = sum / y.len() as f64;
        // The running sum is serial (one addition's latency per sample). Extending from a slice's iterator writes
        // without a capacity check per value, and without first zeroing the buffer (as `resize` would: a
        // 4-MB memset per 8-h column).
        self.x.reserve(y.len() + 1);
        self.x.push(0.0);
        let mut acc = 0.0;
        self.x.extend(y.iter().map(|&v| {
            acc += v - mean;
            acc * tau0_s
        }));
        true
    }

    /// Like [`from_phase`](Self::from_phase) but reuses this buffer.
    pub fn set_phase(&mut self, x: &[f64], tau0_s: f64) -> bool {
        self.x.clear();
        self.tau0_s = tau0_s;
        if x.len() < 2 || !valid_tau0(tau0_s) || x.iter().any(|v| !v.is_finite()) {
            return false;
        }
        self.x.extend_from_slice(x);
        true
    }

    /// Number of frequency samples `N` (phase points − 1; 0 if empty).
    pub fn n_samples(&self) -> usize {
        self.x.len().saturating_sub(1)
    }

    /// Sample interval τ0 in seconds.
    pub fn tau0_s(&self) -> f64 {
        self.tau0_s
    }

    /// The phase points.
    pub fn as_slice(&self) -> &[f64] {
        &self.x
    }

    /// Variance (σ², unit of `y` squared) and number of terms for `kind` at factor `m`.
    /// `None` if fewer than 2 terms (the allantools rule) or the phase is empty.
    pub fn variance(&self, kind: DevKind, m: usize) -> Option<(f64, usize)> {
        let n_exp = kind.n_terms(self.n_samples(), m);
        if n_exp < 2 || self.x.is_empty() {
            return None;
        }
        let (var, n) = match kind {
            DevKind::Adev => avar(&self.x, m, self.tau0_s, false),
            DevKind::Oadev => avar(&self.x, m, self.tau0_s, true),
            DevKind::Mdev => mvar(&self.x, m, self.tau0_s),
        };
        debug_assert_eq!(n, n_exp);
        var.is_finite().then_some((var, n))
    }

    /// Deviation for `kind` at averaging factor `m` (see [`variance`](Self::variance)).
    pub fn deviation(&self, kind: DevKind, m: usize) -> Option<DevPoint> {
        let (var, n) = self.variance(kind, m)?;
        Some(self.point(m, var, n))
    }

    /// [`deviation`](Self::deviation) at every factor of `ms`, in that order, with the same bits. The overlapping
    /// kind sums all factors in one blocked pass over the phase (`overlap`), the others one pass per factor.
    pub fn deviations(&self, kind: DevKind, ms: &[usize]) -> Vec<Option<DevPoint>> {
        if kind != DevKind::Oadev || self.x.is_empty() {
            return ms.iter().map(|&m| self.deviation(kind, m)).collect();
        }
        let valid: Vec<usize> = ms
            .iter()
            .map(|&m| match kind.n_terms(self.n_samples(), m) {
                ..2 => 0,
                _ => m,
            })
            .collect();
        let sums = super::overlap::second_difference_sums(&self.x, &valid);
        valid
            .iter()
            .zip(sums)
            .map(|(&m, s)| oadev_point(s, m, self.n_samples(), self.tau0_s))
            .collect()
    }

    fn point(&self, m: usize, var: f64, n: usize) -> DevPoint {
        DevPoint {
            m,
            tau_s: m as f64 * self.tau0_s,
            n,
            dev: var.sqrt(),
        }
    }

    /// Non-overlapping Allan variance at `m` (used by the B1 noise identification),
    /// requiring at least one term.
    pub(crate) fn avar_nonoverlapping(&self, m: usize) -> Option<f64> {
        if m == 0 || self.x.len() < 2 * m + 1 {
            return None;
        }
        Some(avar(&self.x, m, self.tau0_s, false).0)
    }

    /// Modified Allan variance at `m` with at least one term (for the R(n) ratio).
    pub(crate) fn mvar_any(&self, m: usize) -> Option<f64> {
        if m == 0 || self.x.len() < 3 * m + 1 {
            return None;
        }
        Some(mvar(&self.x, m, self.tau0_s).0)
    }
}

fn valid_tau0(tau0_s: f64) -> bool {
    tau0_s.is_finite() && tau0_s > 0.0
}

/// Allan variance from phase: `Σ (x[i+2m] − 2x[i+m] + x[i])² / (2 n (m τ0)²)`,
/// `i` stepping by 1 (overlapping) or by `m`. Caller guarantees `x.len() ≥ 2m + 1`.
fn avar(x: &[f64], m: usize, tau0_s: f64, overlapping: bool) -> (f64, usize) {
    let l = x.len();
    let (s, n) = if overlapping {
        let n = l - 2 * m;
        let (a, b, c) = (&x[2 * m..], &x[m..l - m], &x[..n]);
        let s = lanes::sum3(a, b, c, |a, b, c| {
            let d = a - 2.0 * b + c;
            d * d
        });
        (s, n)
    } else {
        let mut s = 0.0;
        let mut n = 0;
        let mut i = 0;
        while i + 2 * m < l {
            let d = x[i + 2 * m] - 2.0 * x[i + m] + x[i];
            s += d * d;
            n += 1;
            i += m;
        }
        (s, n)
    };
    (normalised_avar(s, n, m, tau0_s), n)
}

/// The overlapping deviation at factor `m` of `n_samples` frequency samples (interval `tau0_s`) whose squared second
/// differences of phase sum to `s`, as [`Phase::deviations`] gives it (`None` for fewer than two terms or a
/// non-finite variance).
pub(super) fn oadev_point(s: f64, m: usize, n_samples: usize, tau0_s: f64) -> Option<DevPoint> {
    let n = DevKind::Oadev.n_terms(n_samples, m);
    if n < 2 {
        return None;
    }
    let var = normalised_avar(s, n, m, tau0_s);
    var.is_finite().then(|| DevPoint {
        m,
        tau_s: m as f64 * tau0_s,
        n,
        dev: var.sqrt(),
    })
}

/// The Allan variance of `n` squared second differences summing to `s` at factor `m`: `s / (2 n (m τ0)²)`.
fn normalised_avar(s: f64, n: usize, m: usize, tau0_s: f64) -> f64 {
    let tau = m as f64 * tau0_s;
    s / (2.0 * n as f64 * tau * tau)
}

/// Modified Allan variance from phase (NIST SP 1065 eq. 14):
/// `Σ_j [Σ_{i=j}^{j+m−1} D_i]² / (2 m² τ² n)` with `D_i = x[i+2m] − 2x[i+m] + x[i]`,
/// `n = L − 3m + 1`. The inner sum is a running window sum over `D`
/// (`v ← v + D[j+m] − D[j]`), so each `m` costs O(N) and no buffer. Summing the small
/// second differences (instead of cumulating raw phase) keeps rounding error at the
/// level of `D`, even for phase with a large ramp. Caller guarantees `L ≥ 3m + 1`.
fn mvar(x: &[f64], m: usize, tau0_s: f64) -> (f64, usize) {
    let l = x.len();
    let d = |i: usize| x[i + 2 * m] - 2.0 * x[i + m] + x[i];
    let mut v = 0.0;
    for i in 0..m {
        v += d(i);
    }
    let mut s = v * v;
    let steps = l - 3 * m;
    for j in 0..steps {
        v += d(j + m) - d(j);
        s += v * v;
    }
    let n = steps + 1;
    let mf = m as f64;
    let tau = mf * tau0_s;
    (s / (2.0 * mf * mf * tau * tau * n as f64), n)
}

/// Deviations of `kind` for frequency data `y` (interval `tau0_s` s) at the averaging
/// factors `ms`. Factors are sorted and de-duplicated; factors with fewer than two terms
/// (or `m = 0`) are skipped, as allantools does. Bad input gives an empty `Vec`.
pub fn deviation(kind: DevKind, y: &[f64], tau0_s: f64, ms: &[usize]) -> Vec<DevPoint> {
    let Some(phase) = Phase::from_frequency(y, tau0_s) else {
        return Vec::new();
    };
    let mut ms: Vec<usize> = ms.to_vec();
    ms.sort_unstable();
    ms.dedup();
    ms.into_iter()
        .filter_map(|m| phase.deviation(kind, m))
        .collect()
}

/// Non-overlapping Allan deviation, see [`deviation`].
pub fn adev(y: &[f64], tau0_s: f64, ms: &[usize]) -> Vec<DevPoint> {
    deviation(DevKind::Adev, y, tau0_s, ms)
}

/// Overlapping Allan deviation, see [`deviation`].
pub fn oadev(y: &[f64], tau0_s: f64, ms: &[usize]) -> Vec<DevPoint> {
    deviation(DevKind::Oadev, y, tau0_s, ms)
}

/// Modified Allan deviation, see [`deviation`].
pub fn mdev(y: &[f64], tau0_s: f64, ms: &[usize]) -> Vec<DevPoint> {
    deviation(DevKind::Mdev, y, tau0_s, ms)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Direct O(N·m) textbook formulas on frequency averages, for cross-checking.
    fn naive(kind: DevKind, y: &[f64], m: usize) -> Option<f64> {
        let n = y.len();
        let avg = |s: usize| y[s..s + m].iter().sum::<f64>() / m as f64;
        match kind {
            DevKind::Adev | DevKind::Oadev => {
                let step = if kind == DevKind::Adev { m } else { 1 };
                let mut s = 0.0;
                let mut k = 0;
                let mut i = 0;
                while i + 2 * m <= n {
                    let d = avg(i + m) - avg(i);
                    s += d * d;
                    k += 1;
                    i += step;
                }
                (k >= 2).then(|| (s / (2.0 * k as f64)).sqrt())
            }
            DevKind::Mdev => {
                let mut s = 0.0;
                let mut k = 0;
                let mut j = 0;
                while j + 3 * m <= n + 1 {
                    // average over m consecutive overlapping frequency differences
                    let mut inner = 0.0;
                    for i in j..j + m {
                        if i + 2 * m > n {
                            break;
                        }
                        inner += avg(i + m) - avg(i);
                    }
                    let v = inner / m as f64;
                    s += v * v;
                    k += 1;
                    j += 1;
                }
                (k >= 2).then(|| (s / (2.0 * k as f64)).sqrt())
            }
        }
    }

    fn random_series(n: usize) -> Vec<f64> {
        let mut rng = crate::testrng::TestRng::new(12345);
        let mut walk = 0.0;
        (0..n)
            .map(|_| {
                let u = rng.uniform() - 0.5;
                walk += 0.01 * u;
                u + walk + 3.0
            })
            .collect()
    }

    #[test]
    fn kernels_match_textbook_formulas() {
        let y = random_series(301);
        for kind in DevKind::ALL {
            for m in 1..=kind.max_m(y.len()) {
                let p = deviation(kind, &y, 1.0, &[m]);
                let want = naive(kind, &y, m);
                match (p.first(), want) {
                    (Some(p), Some(w)) => {
                        assert!(
                            (p.dev - w).abs() <= 1e-11 * w,
                            "{kind:?} m={m}: {} vs {w}",
                            p.dev
                        );
                        assert_eq!(p.n, kind.n_terms(y.len(), m));
                    }
                    (None, None) => {}
                    (a, b) => panic!("{kind:?} m={m}: {a:?} vs {b:?}"),
                }
            }
        }
    }

    #[test]
    fn deviations_are_the_deviation_at_each_factor() {
        let y = random_series(5000);
        let phase = Phase::from_frequency(&y, 0.05).unwrap();
        let ms: Vec<usize> = (0..14)
            .map(|k| 1 << k)
            .chain([0, 3, 1666, 2499, 2500, 9999])
            .collect();
        for kind in DevKind::ALL {
            let one_by_one: Vec<_> = ms.iter().map(|&m| phase.deviation(kind, m)).collect();
            let all = phase.deviations(kind, &ms);
            assert_eq!(all.len(), ms.len());
            for ((m, a), b) in ms.iter().zip(&all).zip(&one_by_one) {
                let bits = |p: &Option<DevPoint>| {
                    p.map(|p| (p.m, p.n, p.tau_s.to_bits(), p.dev.to_bits()))
                };
                assert_eq!(bits(a), bits(b), "{kind:?} m {m}");
            }
            assert!(all.iter().filter(|p| p.is_some()).count() >= 12, "{kind:?}");
        }
        assert!(
            Phase::default()
                .deviations(DevKind::Oadev, &ms)
                .iter()
                .all(Option::is_none)
        );
    }

    #[test]
    fn max_m_is_last_valid() {
        for n in 0..50 {
            for kind in DevKind::ALL {
                let mm = kind.max_m(n);
                if mm > 0 {
                    assert!(kind.n_terms(n, mm) >= 2, "{kind:?} n={n}");
                }
                assert!(kind.n_terms(n, mm + 1) < 2, "{kind:?} n={n}");
            }
        }
    }

    #[test]
    fn bad_input_is_empty() {
        assert!(adev(&[], 1.0, &[1]).is_empty());
        assert!(oadev(&[1.0, 2.0, 3.0], 0.0, &[1]).is_empty());
        assert!(mdev(&[1.0, f64::NAN, 3.0], 1.0, &[1]).is_empty());
        assert!(oadev(&[1.0, 2.0, 3.0], 1.0, &[0, 5, usize::MAX]).is_empty());
        assert!(Phase::from_phase(&[1.0], 1.0).is_none());
        assert!(Phase::from_frequency(&[1.0], f64::INFINITY).is_none());
    }
}
