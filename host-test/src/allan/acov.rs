//! Allan covariance between sensors: the cross terms that decide whether averaging N sensors gains √N.
//!
//! For series y_i at octave level m (non-overlapping block means ȳ), `C_ij(τ) = ½ ⟨(ȳ_i,k+1 − ȳ_i,k)(ȳ_j,k+1 − ȳ_j,k)⟩`.
//! `C_ii` is sensor i's Allan variance, and for any weights w the Allan variance of `Σ w_i y_i` is exactly
//! `Σ_ij w_i w_j C_ij` — so the cluster's excess over the independence prediction `Σ w_i² C_ii` is the sum of the
//! off-diagonal terms, which is what the correlation effects model.

/// Allan covariance matrices at octave levels.
#[derive(Clone, Debug, PartialEq)]
pub struct AllanCov {
    /// Number of series.
    pub n: usize,
    /// τ of each level, s.
    pub tau_s: Vec<f64>,
    /// Differences averaged at each level.
    pub terms: Vec<usize>,
    /// Per level, the n×n matrix, row-major.
    pub cov: Vec<Vec<f64>>,
}

impl AllanCov {
    /// Computes levels 0, 1, 2, … while at least `min_terms` differences remain. All series must have the same
    /// length (extra samples of longer series are ignored).
    pub fn compute(series: &[&[f64]], tau0_s: f64, min_terms: usize) -> AllanCov {
        let n = series.len();
        let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
        let mut means: Vec<Vec<f64>> = series.iter().map(|s| s[..len].to_vec()).collect();
        let mut out = AllanCov {
            n,
            tau_s: Vec::new(),
            terms: Vec::new(),
            cov: Vec::new(),
        };
        let mut tau = tau0_s;
        let mut d = vec![0.0; n];
        loop {
            let blocks = means.first().map_or(0, Vec::len);
            if blocks < 2 || blocks - 1 < min_terms.max(1) {
                break;
            }
            let mut c = vec![0.0; n * n];
            for k in 0..blocks - 1 {
                for (di, m) in d.iter_mut().zip(&means) {
                    *di = m[k + 1] - m[k];
                }
                for i in 0..n {
                    let di = d[i];
                    let row = &mut c[i * n..i * n + n];
                    for (cij, dj) in row[i..].iter_mut().zip(&d[i..]) {
                        *cij += di * dj;
                    }
                }
            }
            let scale = 0.5 / (blocks - 1) as f64;
            for i in 0..n {
                for j in i..n {
                    let v = c[i * n + j] * scale;
                    c[i * n + j] = v;
                    c[j * n + i] = v;
                }
            }
            out.tau_s.push(tau);
            out.terms.push(blocks - 1);
            out.cov.push(c);
            for m in &mut means {
                let half = m.len() / 2;
                for j in 0..half {
                    m[j] = 0.5 * (m[2 * j] + m[2 * j + 1]);
                }
                m.truncate(half);
            }
            tau *= 2.0;
        }
        out
    }

    /// `C_ij` at `level`.
    pub fn get(&self, level: usize, i: usize, j: usize) -> f64 {
        self.cov
            .get(level)
            .and_then(|c| c.get(i * self.n + j))
            .copied()
            .unwrap_or(f64::NAN)
    }

    /// Allan variance of `Σ w_i y_i` at `level` (exact from the matrix).
    pub fn combined(&self, level: usize, w: &[f64]) -> f64 {
        let mut s = 0.0;
        for (i, wi) in w.iter().enumerate() {
            for (j, wj) in w.iter().enumerate() {
                s += wi * wj * self.get(level, i, j);
            }
        }
        s
    }

    /// The independence part `Σ w_i² C_ii` at `level`.
    pub fn independent(&self, level: usize, w: &[f64]) -> f64 {
        w.iter()
            .enumerate()
            .map(|(i, wi)| wi * wi * self.get(level, i, i))
            .sum()
    }

    /// Mean off-diagonal covariance over the pairs of `members` at `level` (NaN with fewer than 2 members).
    pub fn mean_cross(&self, level: usize, members: &[usize]) -> f64 {
        let (mut s, mut k) = (0.0, 0usize);
        for (a, &i) in members.iter().enumerate() {
            for &j in &members[a + 1..] {
                s += self.get(level, i, j);
                k += 1;
            }
        }
        if k == 0 { f64::NAN } else { s / k as f64 }
    }

    /// Correlation matrix at `level` (diagonal 1).
    pub fn correlation(&self, level: usize) -> Vec<f64> {
        let n = self.n;
        let mut r = vec![0.0; n * n];
        for i in 0..n {
            for j in 0..n {
                let d = (self.get(level, i, i) * self.get(level, j, j)).sqrt();
                r[i * n + j] = if d > 0.0 {
                    self.get(level, i, j) / d
                } else {
                    0.0
                };
            }
        }
        r
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(seed: u64, n: usize) -> Vec<f64> {
        crate::testrng::TestRng::new(seed).normals(n, 1.0)
    }

    #[test]
    fn common_component_appears_off_diagonal_and_combines_exactly() {
        let n = 1 << 15;
        let common = noise(99, n);
        // 4 sensors: independent unit white noise + 0.5 × a shared white noise → ρ = 0.25 / 1.25 = 0.2.
        let series: Vec<Vec<f64>> = (0..4)
            .map(|i| {
                noise(i, n)
                    .iter()
                    .zip(&common)
                    .map(|(a, c)| a + 0.5 * c)
                    .collect()
            })
            .collect();
        let refs: Vec<&[f64]> = series.iter().map(Vec::as_slice).collect();
        let ac = AllanCov::compute(&refs, 1.0, 100);
        // White noise of variance v has Allan variance v at τ0.
        assert!((ac.get(0, 0, 0) / 1.25 - 1.0).abs() < 0.03);
        assert!((ac.mean_cross(0, &[0, 1, 2, 3]) / 0.25 - 1.0).abs() < 0.1);
        assert!((ac.correlation(0)[1] - 0.2).abs() < 0.03);
        // The combination formula is an identity on the data itself.
        let mean: Vec<f64> = (0..n)
            .map(|k| series.iter().map(|s| s[k]).sum::<f64>() / 4.0)
            .collect();
        let direct = AllanCov::compute(&[&mean], 1.0, 100);
        for level in 0..ac.tau_s.len() {
            let w = [0.25; 4];
            assert!(
                (ac.combined(level, &w) / direct.get(level, 0, 0) - 1.0).abs() < 1e-9,
                "level {level}"
            );
        }
        assert_eq!(ac.terms[0], n - 1);
        assert_eq!(ac.tau_s[3], 8.0);
    }
}
