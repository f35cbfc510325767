//! Standard normal draws (ziggurat) and the rounding of outputs to a step.

use rand_xoshiro::rand_core::Rng;
use std::sync::OnceLock;

/// Rounds each value to the nearest multiple of `step`, halves away from zero (no-op for `step == 0`; values
/// beyond ±2⁶² steps saturate).
pub(crate) fn round_to_step(v: &mut [f64], step: f64) {
    if step > 0.0 {
        let inv = 1.0 / step;
        for x in v {
            let r = *x * inv;
            // `as i64` truncates toward zero and saturates: a cheap round() without a libm call.
            *x = (r + 0.5f64.copysign(r)) as i64 as f64 * step;
        }
    }
}

/// Ziggurat tables (Marsaglia & Tsang 2000, 256 layers): layer edges `x` and `f(x) = e^{−x²/2}`.
pub(super) struct Ziggurat {
    pub(super) x: [f64; 257],
    pub(super) f: [f64; 257],
}

pub(super) const ZIG_R: f64 = 3.654_152_885_361_009;
pub(super) const ZIG_V: f64 = 4.928_673_233_99e-3;

pub(super) fn ziggurat() -> &'static Ziggurat {
    pub(super) static Z: OnceLock<Ziggurat> = OnceLock::new();
    Z.get_or_init(|| {
        let f = |x: f64| (-0.5 * x * x).exp();
        let mut x = [0.0; 257];
        x[0] = ZIG_V / f(ZIG_R);
        x[1] = ZIG_R;
        for i in 1..255 {
            x[i + 1] = (-2.0 * (ZIG_V / x[i] + f(x[i])).ln()).sqrt();
        }
        x[256] = 0.0;
        Ziggurat { x, f: x.map(f) }
    })
}

/// A uniform variate in [−1, 1) from the 52 high bits of one draw.
#[inline]
pub(super) fn signed_unit<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    f64::from_bits(0x4000_0000_0000_0000 | (rng.next_u64() >> 12)) - 3.0
}

/// A standard normal variate: 256-layer ziggurat on one 64-bit draw (low 8 bits: layer; high 52 bits: a
/// signed uniform in [−1, 1) built directly in the mantissa); ≈ 1 % of draws take the exact wedge or tail branch.
#[inline]
pub fn normal<R: Rng + ?Sized>(rng: &mut R) -> f64 {
    let z = ziggurat();
    loop {
        let bits = rng.next_u64();
        let i = (bits & 0xFF) as usize;
        let u = f64::from_bits(0x4000_0000_0000_0000 | (bits >> 12)) - 3.0;
        let x = u * z.x[i];
        if x.abs() < z.x[i + 1] {
            return x;
        }
        if i == 0 {
            // Tail beyond R (Marsaglia 1964).
            loop {
                let u1 = 1.0 - (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
                let u2 = 1.0 - (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
                let t = -u1.ln() / ZIG_R;
                if -2.0 * u2.ln() > t * t {
                    return if u < 0.0 { -(ZIG_R + t) } else { ZIG_R + t };
                }
            }
        }
        let v = (rng.next_u64() >> 11) as f64 * (1.0 / (1u64 << 53) as f64);
        if z.f[i + 1] + v * (z.f[i] - z.f[i + 1]) < (-0.5 * x * x).exp() {
            return x;
        }
    }
}
