//! Time from the frames themselves: each frame advances time by N + 1 FPGA base periods (N = its decimation), and
//! a sequence gap advances it by the lost frames too. Used by the pipeline and by the ground tools, so that both
//! put the same time on the same frame.
//!
//! The tick count wraps modulo 2⁶⁴, as any free-running counter: after 60 million years at the nominal rate, or
//! after 2³³ frames (164 days at 604.8 frames/s) of the worst a link can send (every frame reporting 2¹⁵ − 1 lost
//! frames at N = 65535).

use super::Decoded;
use core::num::{NonZeroU64, NonZeroU128};

/// The FPGA's data-set rate before decimation, in millihertz: 9676.8 Hz. A frame of decimation N comes every N + 1
/// base periods (N = 15: 604.8 frames/s). The one definition of this rate; everything else derives from it.
pub const FPGA_BASE_RATE_MILLIHZ: u64 = 9_676_800;

/// The decimation N our board flies at (a frame every N + 1 base periods: 604.8 frames/s, averaged 32 to one
/// output at the seed's 18.9 Hz). The benchmark stream (`shared::bench`, the frames `mcu-bench` counts) and the
/// SITL's default use it; the ground's power budget (`host_test::tradeoff`) takes the frame rate from it.
pub const FLIGHT_DECIMATION: u16 = 15;

/// Frame time keeping (see module docs).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct FrameClock {
    base_ticks: u64,
    decimation: Option<u16>,
}

/// What [`FrameClock::advance`] says about a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Tick {
    /// Time of this frame in FPGA base periods since the first frame.
    pub base_ticks: u64,
    /// The decimation changed with this frame (the sample rate changed).
    pub rate_changed: bool,
}

impl FrameClock {
    /// A clock before its first frame.
    pub const fn new() -> Self {
        Self {
            base_ticks: 0,
            decimation: None,
        }
    }

    /// Decimation of the last frame.
    pub fn decimation(&self) -> Option<u16> {
        self.decimation
    }

    /// Takes the next decoded frame; returns its time.
    pub fn advance(&mut self, d: &Decoded) -> Tick {
        self.advance_by(d.frame.decimation, d.gap.missing_before)
    }

    /// Takes the next frame, of decimation `decimation`, after `missing_before` lost frames (the decoder's count,
    /// or the platform's from arrival times); returns its time.
    pub fn advance_by(&mut self, decimation: u16, missing_before: u32) -> Tick {
        // ≤ 2¹⁶: cannot wrap.
        let step = u64::from(decimation).wrapping_add(1);
        let rate_changed = match self.decimation {
            Some(n) if n == decimation => {
                // The product is < 2³² · 2¹⁶ (cannot wrap); the sum wraps modulo 2⁶⁴ (module docs).
                let lost = u64::from(missing_before).wrapping_mul(step);
                self.base_ticks = self.base_ticks.wrapping_add(lost);
                false
            }
            Some(_) => true,
            None => false,
        };
        self.decimation = Some(decimation);
        let tick = Tick {
            base_ticks: self.base_ticks,
            rate_changed,
        };
        self.base_ticks = self.base_ticks.wrapping_add(step);
        tick
    }

    /// `ticks` base periods in µs, for a base rate in millihertz (rounded down; modulo 2⁶⁴ where the time exceeds
    /// it).
    ///
    /// With ticks = q · rate + m (0 ≤ m < rate): ⌊ticks · 10⁹ / rate⌋ = q · 10⁹ + ⌊m · 10⁹ / rate⌋, two 64-bit
    /// divisions where m · 10⁹ fits 64 bits (rate < 2³⁴ millihertz: every FPGA rate), instead of a 128-bit one, a
    /// library call on the Cortex-M4 (the pipeline stamps every frame).
    pub fn ticks_to_us(ticks: u64, base_rate_millihz: u64) -> u64 {
        // A rate of 0 counts as 1 millihertz.
        let rate = NonZeroU64::new(base_rate_millihz).unwrap_or(NonZeroU64::MIN);
        if rate.get() < 1 << 34 {
            let (q, m) = (ticks / rate, ticks % rate);
            // m < 2³⁴: m · 10⁹ < 2⁶⁴ cannot wrap; q · 10⁹ and the sum wrap modulo 2⁶⁴, as the 128-bit form's cast.
            return q
                .wrapping_mul(1_000_000_000)
                .wrapping_add(m.wrapping_mul(1_000_000_000) / rate);
        }
        // < 2⁶⁴ · 2³⁰: the product cannot wrap.
        (u128::from(ticks).wrapping_mul(1_000_000_000) / NonZeroU128::from(rate)) as u64
    }
}

/// [`FrameClock::ticks_to_us`] for a tick count that mostly grows by the same step (a frame period), kept
/// incrementally: with ticks · 10⁹ = µs · rate + rem (0 ≤ rem < rate) and a step's Δ · 10⁹ = a · rate + b, the next
/// time is µs + a + c and its remainder rem + b − c · rate, c = [rem + b ≥ rate] — exact, as the quotient of the
/// sum. One 64-bit division per new step size instead of two library divisions per frame (≈ 0.2 k Cortex-M4
/// instructions per frame, `mcu-bench`). Any other change (a rate change, a count that went back, a step of 2³⁴
/// ticks or more, a rate of 2³⁴ millihertz or more) takes the full computation.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct TicksToUs {
    /// Rate (millihertz), tick count, its time and remainder as of the last call; `rate` 0: none yet.
    rate: u64,
    ticks: u64,
    us: u64,
    rem: u64,
    /// The last step size and its (a, b).
    step: u64,
    step_us: u64,
    step_rem: u64,
}

impl TicksToUs {
    /// Before the first call.
    pub const fn new() -> Self {
        Self {
            rate: 0,
            ticks: 0,
            us: 0,
            rem: 0,
            step: 0,
            step_us: 0,
            step_rem: 0,
        }
    }

    /// `FrameClock::ticks_to_us(ticks, base_rate_millihz)`.
    pub fn us(&mut self, ticks: u64, base_rate_millihz: u64) -> u64 {
        const LIMIT: u64 = 1 << 34;
        let rate = base_rate_millihz;
        let step = ticks.wrapping_sub(self.ticks);
        if rate != self.rate || rate == 0 || rate >= LIMIT || ticks < self.ticks || step >= LIMIT {
            return self.restart(ticks, rate);
        }
        if step != self.step {
            // step < 2³⁴: step · 10⁹ < 2⁶⁴; rate ≠ 0.
            let total = step.wrapping_mul(1_000_000_000);
            let nz = NonZeroU64::new(rate).unwrap_or(NonZeroU64::MIN);
            (self.step, self.step_us, self.step_rem) = (step, total / nz, total % nz);
        }
        // rem, step_rem < rate < 2³⁴: the sum cannot wrap; the time wraps modulo 2⁶⁴ as `ticks_to_us`'s.
        let sum = self.rem.wrapping_add(self.step_rem);
        let carry = u64::from(sum >= rate);
        self.rem = sum.wrapping_sub(carry.wrapping_mul(rate));
        self.us = self.us.wrapping_add(self.step_us).wrapping_add(carry);
        self.ticks = ticks;
        self.us
    }

    /// The full computation; keeps the remainder where the rate allows the incremental one.
    fn restart(&mut self, ticks: u64, rate: u64) -> u64 {
        let us = FrameClock::ticks_to_us(ticks, rate);
        *self = Self::new();
        if let Some(nz) = NonZeroU64::new(rate).filter(|r| r.get() < 1 << 34) {
            // ticks · 10⁹ mod rate = (m · 10⁹) mod rate, m = ticks mod rate < 2³⁴: no wrap.
            let rem = (ticks % nz).wrapping_mul(1_000_000_000) % nz;
            (self.rate, self.ticks, self.us, self.rem) = (rate, ticks, us, rem);
        }
        us
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The split form against the 128-bit definition on the edges and 100 000 random (ticks, rate) pairs.
    #[test]
    fn ticks_to_us_equals_the_128_bit_quotient() {
        let reference =
            |t: u64, r: u64| (u128::from(t) * 1_000_000_000 / u128::from(r.max(1))) as u64;
        let mut rng = crate::testutil::Rng::new(5);
        let rates = [
            0,
            1,
            2,
            FPGA_BASE_RATE_MILLIHZ,
            (1 << 34) - 1,
            1 << 34,
            u64::MAX,
        ];
        let ticks = [
            0,
            1,
            17,
            FPGA_BASE_RATE_MILLIHZ - 1,
            FPGA_BASE_RATE_MILLIHZ,
            u64::MAX - 1,
            u64::MAX,
        ];
        for (&t, &r) in ticks.iter().flat_map(|t| rates.iter().map(move |r| (t, r))) {
            assert_eq!(FrameClock::ticks_to_us(t, r), reference(t, r), "{t} {r}");
        }
        for _ in 0..100_000 {
            let t = rng.next_u64() >> (rng.next_u64() % 64);
            let r = rng.next_u64() >> (rng.next_u64() % 64);
            assert_eq!(FrameClock::ticks_to_us(t, r), reference(t, r), "{t} {r}");
        }
    }

    /// The incremental form against `ticks_to_us` along tick sequences as the pipeline makes them: mostly one
    /// step size, sometimes lost frames (other steps), jumps of 2³⁴ ticks and more, counts that go back (a
    /// restart), rate changes (to 0 and beyond 2³⁴ too), and across the 2⁶⁴ wrap of the time.
    #[test]
    fn ticks_to_us_incremental_equals_the_full_computation() {
        let mut rng = crate::testutil::Rng::new(9);
        let rates = [
            FPGA_BASE_RATE_MILLIHZ,
            1,
            7,
            999_983,
            (1 << 34) - 1,
            1 << 34,
            0,
        ];
        let mut clock = TicksToUs::new();
        let mut ticks = 0u64;
        let mut rate = FPGA_BASE_RATE_MILLIHZ;
        for i in 0..200_000u32 {
            match rng.next_u64() % 1000 {
                0 => rate = rates[(rng.next_u64() % rates.len() as u64) as usize],
                1 => {
                    ticks = ticks
                        .wrapping_add(1 << 34)
                        .wrapping_add(rng.next_u64() % 100)
                }
                2 => ticks = rng.next_u64() % ticks.saturating_add(1),
                3 => ticks = u64::MAX - rng.next_u64() % 1_000_000,
                4..=30 => ticks = ticks.wrapping_add(16 * (1 + rng.next_u64() % 40)),
                _ => ticks = ticks.wrapping_add(16),
            }
            assert_eq!(
                clock.us(ticks, rate),
                FrameClock::ticks_to_us(ticks, rate),
                "step {i}: {ticks} ticks at {rate} mHz"
            );
        }
    }
}
