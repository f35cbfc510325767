//! Sums over `f64` slices with eight independent partial sums: a serial sum waits for each addition's result
//! before the next (a few cycles per element); eight chains keep the vector units busy, so these loops run at the
//! speed of their loads. The order of summation differs from a serial loop, which moves results at the 1e-16
//! relative level.
//!
//! Where such a sum is a hot loop of its own (`sum`; the lag-1 autocorrelation in `noise`; the OADEV pass in
//! `overlap`), it is also compiled for AVX2 and chosen at run time: the same additions in the same order on wider
//! registers, so the same bits (Rust never fuses a multiplication and an addition by itself).

/// Partial sums per loop.
pub(super) const LANES: usize = 8;

/// The partial sums added pairwise, lane k with lane k + 4 first: the order of a vertical reduction of 2-lane
/// vectors, so the compiler keeps neighbouring lanes in one register (pairing k with k + 1 made it shuffle every
/// load: a third more instructions in the OADEV pass).
#[inline(always)]
pub(super) fn combine(a: [f64; LANES]) -> f64 {
    let [a0, a1, a2, a3, a4, a5, a6, a7] = a;
    ((a0 + a4) + (a2 + a6)) + ((a1 + a5) + (a3 + a7))
}

/// `Σ f(a_i, b_i, c_i)` for each of the `K` outputs of `f`, over the common length of the three slices, in one pass.
#[inline(always)]
fn sums<const K: usize>(
    a: &[f64],
    b: &[f64],
    c: &[f64],
    f: impl Fn(f64, f64, f64) -> [f64; K],
) -> [f64; K] {
    let n = a.len().min(b.len()).min(c.len());
    let (a, b, c) = (&a[..n], &b[..n], &c[..n]);
    let (a8, b8, c8) = (
        a.chunks_exact(LANES),
        b.chunks_exact(LANES),
        c.chunks_exact(LANES),
    );
    let mut acc = [[0.0f64; LANES]; K];
    for ((a, b), c) in a8.clone().zip(b8.clone()).zip(c8.clone()) {
        for k in 0..LANES {
            for (s, v) in acc.iter_mut().zip(f(a[k], b[k], c[k])) {
                s[k] += v;
            }
        }
    }
    let mut tail = [0.0f64; K];
    for ((a, b), c) in a8
        .remainder()
        .iter()
        .zip(b8.remainder())
        .zip(c8.remainder())
    {
        for (t, v) in tail.iter_mut().zip(f(*a, *b, *c)) {
            *t += v;
        }
    }
    core::array::from_fn(|j| combine(acc[j]) + tail[j])
}

/// `Σ f(a_i, b_i, c_i)` over the common length of the three slices.
#[inline(always)]
pub(crate) fn sum3(a: &[f64], b: &[f64], c: &[f64], f: impl Fn(f64, f64, f64) -> f64) -> f64 {
    let [s] = sums(a, b, c, |a, b, c| [f(a, b, c)]);
    s
}

/// Both sums of `f(a_i, b_i) = (u_i, v_i)`, `(Σ u_i, Σ v_i)`, over the common length of the two slices, in one pass.
#[inline(always)]
pub(crate) fn sum2_pair(a: &[f64], b: &[f64], f: impl Fn(f64, f64) -> (f64, f64)) -> (f64, f64) {
    let [u, v] = sums(a, b, b, |a, b, _| {
        let (u, v) = f(a, b);
        [u, v]
    });
    (u, v)
}

/// `Σ x_i`. Compiled also for AVX2 and chosen at run time (wider registers, the same operations: the same bits).
#[multiversion::multiversion(targets("x86_64+avx2"))]
pub(crate) fn sum(x: &[f64]) -> f64 {
    sum3(x, x, x, |v, _, _| v)
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
            assert_eq!(sum3(s, s, s, |a, b, _| a * b), sq, "n = {n}");
            let lag: f64 = s.windows(2).map(|w| w[0] * w[1]).sum();
            let next = s.get(1..).unwrap_or(&[]);
            assert_eq!(sum3(s, next, next, |a, b, _| a * b), lag);
            let pair = sum2_pair(s, s.get(1..).unwrap_or(&[]), |a, b| (a * a, a * b));
            let sq_head: f64 = s.iter().take(n.saturating_sub(1)).map(|v| v * v).sum();
            assert_eq!(pair, (sq_head, lag), "n = {n}");
            let d2: f64 = s.windows(3).map(|w| w[2] - 2.0 * w[1] + w[0]).sum();
            let (a, b, c) = (s.get(2..).unwrap_or(&[]), s.get(1..).unwrap_or(&[]), s);
            assert_eq!(sum3(a, b, c, |a, b, c| a - 2.0 * b + c), d2);
        }
    }
}
