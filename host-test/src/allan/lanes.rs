//! Sums over `f64` slices with eight independent partial sums: a serial sum waits for each addition's result
//! before the next (a few cycles per element); eight chains keep the vector units busy, so these loops run at the
//! speed of their loads. The order of summation differs from a serial loop, which moves results at the 1e-16
//! relative level.

/// Partial sums per loop.
const LANES: usize = 8;

/// The partial sums added pairwise.
#[inline(always)]
fn combine(a: [f64; LANES]) -> f64 {
    let [a0, a1, a2, a3, a4, a5, a6, a7] = a;
    ((a0 + a1) + (a2 + a3)) + ((a4 + a5) + (a6 + a7))
}

/// `Σ f(a_i, b_i, c_i)` over the common length of the three slices.
#[inline(always)]
pub(crate) fn sum3(a: &[f64], b: &[f64], c: &[f64], f: impl Fn(f64, f64, f64) -> f64) -> f64 {
    let n = a.len().min(b.len()).min(c.len());
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    let (a8, b8, c8) = (
        a.chunks_exact(LANES),
        b.chunks_exact(LANES),
        c.chunks_exact(LANES),
    );
    let mut tail = 0.0;
    for ((a, b), c) in a8
        .remainder()
        .iter()
        .zip(b8.remainder())
        .zip(c8.remainder())
    {
        tail += f(*a, *b, *c);
    }
    let mut acc = [0.0f64; LANES];
    for ((a, b), c) in a8.zip(b8).zip(c8) {
        for (k, s) in acc.iter_mut().enumerate() {
            *s += f(a[k], b[k], c[k]);
        }
    }
    combine(acc) + tail
}

/// Both sums of `f(a_i, b_i) = (u_i, v_i)`, `(Σ u_i, Σ v_i)`, over the common length of the two slices, in one pass.
#[inline(always)]
pub(crate) fn sum2_pair(a: &[f64], b: &[f64], f: impl Fn(f64, f64) -> (f64, f64)) -> (f64, f64) {
    let n = a.len().min(b.len());
    let (a, b) = (&a[..n], &b[..n]);
    let (a8, b8) = (a.chunks_exact(LANES), b.chunks_exact(LANES));
    let (mut tail_u, mut tail_v) = (0.0, 0.0);
    for (a, b) in a8.remainder().iter().zip(b8.remainder()) {
        let (u, v) = f(*a, *b);
        tail_u += u;
        tail_v += v;
    }
    let (mut acc_u, mut acc_v) = ([0.0f64; LANES], [0.0f64; LANES]);
    for (a, b) in a8.zip(b8) {
        for k in 0..LANES {
            let (u, v) = f(a[k], b[k]);
            acc_u[k] += u;
            acc_v[k] += v;
        }
    }
    (combine(acc_u) + tail_u, combine(acc_v) + tail_v)
}

/// `Σ f(a_i, b_i)` over the common length of the two slices.
#[inline(always)]
pub(crate) fn sum2(a: &[f64], b: &[f64], f: impl Fn(f64, f64) -> f64) -> f64 {
    sum3(a, b, b, |a, b, _| f(a, b))
}

/// `Σ x_i`.
pub(crate) fn sum(x: &[f64]) -> f64 {
    sum2(x, x, |v, _| v)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sums_match_a_serial_sum_for_every_length() {
        // Values whose sums are exact in f64 at any order, so any dropped or repeated element shows.
        let x: Vec<f64> = (0..70).map(|i| f64::from(i * i % 97) - 40.0).collect();
        for n in 0..x.len() {
            let s = &x[..n];
            let serial: f64 = s.iter().sum();
            assert_eq!(sum(s), serial, "n = {n}");
            let sq: f64 = s.iter().map(|v| v * v).sum();
            assert_eq!(sum2(s, s, |a, b| a * b), sq, "n = {n}");
            let lag: f64 = s.windows(2).map(|w| w[0] * w[1]).sum();
            assert_eq!(sum2(s, s.get(1..).unwrap_or(&[]), |a, b| a * b), lag);
            let pair = sum2_pair(s, s.get(1..).unwrap_or(&[]), |a, b| (a * a, a * b));
            let sq_head: f64 = s.iter().take(n.saturating_sub(1)).map(|v| v * v).sum();
            assert_eq!(pair, (sq_head, lag), "n = {n}");
            let d2: f64 = s.windows(3).map(|w| w[2] - 2.0 * w[1] + w[0]).sum();
            let (a, b, c) = (s.get(2..).unwrap_or(&[]), s.get(1..).unwrap_or(&[]), s);
            assert_eq!(sum3(a, b, c, |a, b, c| a - 2.0 * b + c), d2);
        }
    }
}
