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
        let mut out = AllanCov {
            n,
            tau_s: Vec::new(),
            terms: Vec::new(),
            cov: Vec::new(),
        };
        let mut d = Vec::with_capacity(CHUNK * n);
        let enough = |blocks: usize| blocks > min_terms.max(1);
        if n == 0 || !enough(len) {
            return out;
        }
        // Level 0 from the series themselves; the block means of the next levels row by row (`means[k·n + i]`:
        // block k of series i), so that one block's differences of all series lie together.
        let mut c = vec![0.0; n * n];
        for_chunks(len - 1, |k0, k1| {
            d.clear();
            for k in k0..k1 {
                d.extend(series.iter().map(|s| s[k + 1] - s[k]));
            }
            add_products(&d, n, &mut c);
        });
        out.push(tau0_s, len - 1, c);
        let mut means = vec![0.0; len / 2 * n];
        for (j, row) in means.chunks_exact_mut(n).enumerate() {
            for (m, s) in row.iter_mut().zip(series) {
                *m = 0.5 * (s[2 * j] + s[2 * j + 1]);
            }
        }
        let mut tau = 2.0 * tau0_s;
        loop {
            let blocks = means.len() / n;
            if !enough(blocks) {
                break;
            }
            let mut c = vec![0.0; n * n];
            // The differences by chunks of blocks, each chunk's products added to every `C_ij` before the next.
            for_chunks(blocks - 1, |k0, k1| {
                d.clear();
                d.extend(
                    means[(k0 + 1) * n..(k1 + 1) * n]
                        .iter()
                        .zip(&means[k0 * n..k1 * n])
                        .map(|(b, a)| b - a),
                );
                add_products(&d, n, &mut c);
            });
            out.push(tau, blocks - 1, c);
            let half = blocks / 2;
            for j in 0..half {
                for i in 0..n {
                    means[j * n + i] = 0.5 * (means[2 * j * n + i] + means[(2 * j + 1) * n + i]);
                }
            }
            means.truncate(half * n);
            tau *= 2.0;
        }
        out
    }

    /// Adds a level: the sums of products `c` (upper triangle) over `terms` differences, scaled to ½⟨d_i d_j⟩ and
    /// made symmetric.
    fn push(&mut self, tau_s: f64, terms: usize, mut c: Vec<f64>) {
        let n = self.n;
        let scale = 0.5 / terms as f64;
        for i in 0..n {
            for j in i..n {
                let v = c[i * n + j] * scale;
                c[i * n + j] = v;
                c[j * n + i] = v;
            }
        }
        self.tau_s.push(tau_s);
        self.terms.push(terms);
        self.cov.push(c);
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

/// Differences (rows of the block-difference matrix) per chunk of [`AllanCov::compute`]: 16 series × 256 rows fill
/// 32 KiB, the L1 data cache.
const CHUNK: usize = 256;

/// `f(k0, k1)` for the chunks `k0..k1` of `0..terms`, in order.
fn for_chunks(terms: usize, mut f: impl FnMut(usize, usize)) {
    let mut k0 = 0;
    while k0 < terms {
        let k1 = (k0 + CHUNK).min(terms);
        f(k0, k1);
        k0 = k1;
    }
}

/// `c[i·n + j] += Σ_k d[k·n + i]·d[k·n + j]` for `j ≥ i` (the upper triangle; the rest is left as it is), each sum
/// in increasing k, one product added at a time: the bits of the plain loop over k then i then j. By tiles of 4 × 4
/// entries held in registers over all k (four independent chains of additions, compiled for AVX2 too): the plain
/// loop reloaded and stored every entry at every k, ≈ 1.3 ns per product.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn add_products(d: &[f64], n: usize, c: &mut [f64]) {
    const T: usize = 4;
    let rows = d.len().checked_div(n).unwrap_or(0);
    let whole = n - n % T;
    for i0 in (0..n).step_by(T) {
        for j0 in (i0..n).step_by(T) {
            if i0 + T <= whole && j0 + T <= whole {
                let mut acc = [[0.0; T]; T];
                for (r, a) in acc.iter_mut().enumerate() {
                    a.copy_from_slice(&c[(i0 + r) * n + j0..(i0 + r) * n + j0 + T]);
                }
                for row in d.chunks_exact(n).take(rows) {
                    let dj: [f64; T] = std::array::from_fn(|q| row[j0 + q]);
                    for (r, a) in acc.iter_mut().enumerate() {
                        let di = row[i0 + r];
                        for q in 0..T {
                            a[q] += di * dj[q];
                        }
                    }
                }
                for (r, a) in acc.iter().enumerate() {
                    c[(i0 + r) * n + j0..(i0 + r) * n + j0 + T].copy_from_slice(a);
                }
            } else {
                for i in i0..(i0 + T).min(n) {
                    for j in j0.max(i)..(j0 + T).min(n) {
                        let mut a = c[i * n + j];
                        for row in d.chunks_exact(n) {
                            a += row[i] * row[j];
                        }
                        c[i * n + j] = a;
                    }
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noise(seed: u64, n: usize) -> Vec<f64> {
        crate::testrng::TestRng::new(seed).normals(n, 1.0)
    }

    /// The plain loop: differences block by block, every product added in increasing k (the order the tiled sums
    /// must keep, bit for bit).
    fn plain(series: &[&[f64]], min_terms: usize) -> Vec<Vec<f64>> {
        let n = series.len();
        let len = series.iter().map(|s| s.len()).min().unwrap_or(0);
        let mut means: Vec<Vec<f64>> = series.iter().map(|s| s[..len].to_vec()).collect();
        let mut out = Vec::new();
        loop {
            let blocks = means.first().map_or(0, Vec::len);
            if blocks < 2 || blocks - 1 < min_terms.max(1) {
                break;
            }
            let mut c = vec![0.0; n * n];
            for k in 0..blocks - 1 {
                let d: Vec<f64> = means.iter().map(|m| m[k + 1] - m[k]).collect();
                for i in 0..n {
                    for j in i..n {
                        c[i * n + j] += d[i] * d[j];
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
            out.push(c);
            for m in &mut means {
                let half = m.len() / 2;
                for j in 0..half {
                    m[j] = 0.5 * (m[2 * j] + m[2 * j + 1]);
                }
                m.truncate(half);
            }
        }
        out
    }

    #[test]
    fn tiled_sums_are_bit_identical_to_the_plain_loop() {
        // Series counts around the tile size, lengths around the chunk; random walks, so that any change of order
        // moves the last bits.
        for (n, len) in [
            (1, 5),
            (3, 700),
            (4, 257),
            (5, 1000),
            (8, 513),
            (16, 3000),
            (17, 600),
        ] {
            let series: Vec<Vec<f64>> = (0..n)
                .map(|i| {
                    let mut acc = 0.0;
                    noise(i as u64 + 7, len)
                        .into_iter()
                        .map(|v| {
                            acc += v;
                            acc + 1e3
                        })
                        .collect()
                })
                .collect();
            let refs: Vec<&[f64]> = series.iter().map(Vec::as_slice).collect();
            let got = AllanCov::compute(&refs, 1.0, 2);
            let want = plain(&refs, 2);
            assert_eq!(got.cov.len(), want.len(), "{n} × {len}");
            for (g, w) in got.cov.iter().zip(&want) {
                assert!(
                    g.iter().zip(w).all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{n} × {len}"
                );
            }
        }
        assert!(AllanCov::compute(&[], 1.0, 2).cov.is_empty());
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
