//! Helpers shared by the fuzz targets (each target includes this file with `#[path]`; not every target uses all).
#![allow(dead_code)]

use arbitrary::Arbitrary;
use shared::wire::frame::{FrameRepr, GROUPS, RAW_PER_GROUP};

/// A target's input: `'R' ++ bytes` is the raw form, `raw(bytes)` (how the seeds made from real encodings reach a
/// structured target); anything else is read with `arbitrary`. `None` when `arbitrary` cannot build one.
pub fn input<'a, T: Arbitrary<'a>>(data: &'a [u8], raw: impl FnOnce(&'a [u8]) -> T) -> Option<T> {
    match data.split_first() {
        Some((b'R', rest)) => Some(raw(rest)),
        _ => T::arbitrary_take_rest(arbitrary::Unstructured::new(data)).ok(),
    }
}

/// Splits `data` into chunks whose sizes cycle through `sizes` (0 counts as 1; no sizes = one chunk).
pub fn chunks<'a>(data: &'a [u8], sizes: &[u16]) -> Vec<&'a [u8]> {
    if sizes.is_empty() {
        return vec![data];
    }
    let mut out = Vec::new();
    let mut rest = data;
    let mut i = 0;
    while !rest.is_empty() {
        let n = usize::from(sizes[i % sizes.len()]).clamp(1, rest.len());
        let (a, b) = rest.split_at(n);
        out.push(a);
        rest = b;
        i += 1;
    }
    out
}

/// How the ADC codes of a generated frame look.
#[derive(Arbitrary, Debug, Clone, Copy)]
pub enum Codes {
    /// Near the nominal zero levels, pseudo-random noise from the seed.
    Nominal { seed: u32, spread: u8 },
    /// Every code the same value (stuck / saturated when it is 0 or 0xFFFF).
    Constant(u16),
    /// Nominal, but one group's one channel at `value` (outlier, rail).
    OneOff {
        seed: u32,
        group: u8,
        ch: u8,
        value: u16,
    },
    /// Fully arbitrary codes from the seed.
    Random(u64),
}

/// A frame described structurally (so that the fuzzer reaches the valid-CRC paths).
#[derive(Arbitrary, Debug, Clone, Copy)]
pub struct FrameSpec {
    pub seq: u16,
    pub decimation: u16,
    pub temp_cdeg: Option<i16>,
    pub codes: Codes,
}

fn xorshift(s: &mut u64) -> u64 {
    *s ^= *s << 13;
    *s ^= *s >> 7;
    *s ^= *s << 17;
    *s
}

impl FrameSpec {
    pub fn repr(&self) -> FrameRepr {
        // Gyro channels near 19 680, accelerometer near 24 000 (+1 g on z): the board's zero levels.
        let nominal = |ch: usize| -> i32 {
            match ch {
                0..=3 => 19_680,
                6 => 24_000 + 4_800,
                _ => 24_000,
            }
        };
        let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
        match self.codes {
            Codes::Nominal { seed, .. } | Codes::OneOff { seed, .. } => {
                let spread = match self.codes {
                    Codes::Nominal { spread, .. } => i32::from(spread),
                    _ => 8,
                };
                let mut s = u64::from(seed) | 1 << 40;
                for g in raw.iter_mut() {
                    for (ch, c) in g.iter_mut().enumerate() {
                        let noise = (xorshift(&mut s) % (2 * spread as u64 + 1)) as i32 - spread;
                        *c = (nominal(ch) + noise).clamp(0, 0xFFFF) as u16;
                    }
                }
                if let Codes::OneOff {
                    group, ch, value, ..
                } = self.codes
                {
                    raw[usize::from(group) % GROUPS][usize::from(ch) % RAW_PER_GROUP] = value;
                }
            }
            Codes::Constant(v) => raw = [[v; RAW_PER_GROUP]; GROUPS],
            Codes::Random(seed) => {
                let mut s = seed | 1;
                for c in raw.as_flattened_mut() {
                    *c = xorshift(&mut s) as u16;
                }
            }
        }
        FrameRepr {
            seq: self.seq,
            decimation: self.decimation,
            temp_cdeg: self.temp_cdeg,
            raw,
        }
    }
}
