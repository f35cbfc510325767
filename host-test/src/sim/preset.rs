//! Seed-paper presets: noise parameters that reproduce the single-sensor Tables 1 and 2 of Greenheck et al.
//!
//! Assumptions, per axis:
//! - Table 1's RMS is the standard deviation of the static record at 18.9 Hz. The FPGA decimator discards data
//!   sets without averaging, so that RMS is the sensor's full-band noise; we model it as white noise *at the
//!   output rate* with that σ, i.e. `N = σ·√Δt` (an equivalent density at 18.9 Hz, not the data-sheet density at
//!   the sensor bandwidth). The output is also rounded to the ADC step (`rate_step`), and N is reduced so that the
//!   total expected AVAR at τ₀ = Δt (white + rounding + the small flicker/RRW share) equals σ².
//! - Table 2's bias stability is the minimum of the ADEV curve. White + flicker alone never has a minimum, so a
//!   rate random walk makes one: a share `flicker_share` (default 0.75) of the minimum AVAR is the flicker floor,
//!   `B = √(share/(2 ln2/π))·min`, and K is solved (bisection) so that the minimum of the exact expected ADEV
//!   over τ ∈ [Δt, run/2] equals the table value.
//! - "Single sensor" is one raw channel: gyro z applies to each of the two z channels (gyro A z, gyro B z). The
//!   group's calibrated z (mean of both) then has ≈ 1/√2 of that noise.

use super::noise::{FLICKER_AVAR_PER_B2, NoiseModel, NoiseParams, Sampling};
use super::{Axis, CHANNELS, Channel, SimConfig, SimError, check};

/// Output rate of the seed experiment, Hz.
pub const SEED_RATE_HZ: f64 = 18.9;
/// Samples per axis of the seed experiment (8 h).
pub const SEED_SAMPLES: u64 = 545_410;
/// Default share of the minimum AVAR given to the flicker floor.
pub const DEFAULT_FLICKER_SHARE: f64 = 0.75;

/// A single-sensor target of the seed paper.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SeedTarget {
    /// The axis.
    pub axis: Axis,
    /// Table 1: RMS noise at 18.9 Hz, u (°/s or g).
    pub rms: f64,
    /// Table 2: minimum of the ADEV curve, u (°/s or g).
    pub adev_min: f64,
}

/// Tables 1 and 2, single sensor, in [`Axis::ALL`] order (°/s and g; the paper's °/h and µg converted).
pub const SEED_TARGETS: [SeedTarget; 6] = [
    SeedTarget {
        axis: Axis::GyroX,
        rms: 0.418,
        adev_min: 29.5 / 3600.0,
    },
    SeedTarget {
        axis: Axis::GyroY,
        rms: 0.393,
        adev_min: 25.3 / 3600.0,
    },
    SeedTarget {
        axis: Axis::GyroZ,
        rms: 0.422,
        adev_min: 26.6 / 3600.0,
    },
    SeedTarget {
        axis: Axis::AccelX,
        rms: 3670e-6,
        adev_min: 62e-6,
    },
    SeedTarget {
        axis: Axis::AccelY,
        rms: 6250e-6,
        adev_min: 152e-6,
    },
    SeedTarget {
        axis: Axis::AccelZ,
        rms: 3590e-6,
        adev_min: 61e-6,
    },
];

/// The sampling of the seed experiment (18.9 Hz, 545 410 samples, default flicker band).
pub fn seed_sampling() -> Sampling {
    // Cannot fail: constant, valid arguments.
    Sampling::new(SEED_RATE_HZ, SEED_SAMPLES as f64 / SEED_RATE_HZ)
        .unwrap_or_else(|_| unreachable!())
}

/// Parameters of one sensor that meet `target` with `sampling`: white N, flicker B, rate random walk K and the
/// ADC rounding step `step` (u, 0 for none), for a run of `duration_s` (the minimum is sought over
/// τ ∈ [Δt, duration/2]). `flicker_share` ∈ (0, 1).
pub fn fit_target(
    target: &SeedTarget,
    sampling: &Sampling,
    duration_s: f64,
    step: f64,
    flicker_share: f64,
) -> Result<NoiseParams, SimError> {
    check(flicker_share > 0.0 && flicker_share < 1.0, || {
        format!("flicker_share = {flicker_share} not in (0, 1)")
    })?;
    check(
        target.rms > 0.0 && target.adev_min > 0.0 && target.adev_min < target.rms,
        || "target needs 0 < adev_min < rms".into(),
    )?;
    let dt = sampling.dt_s;
    check(duration_s.is_finite() && duration_s >= 4.0 * dt, || {
        format!("duration_s = {duration_s} too short")
    })?;
    let (lo, hi) = (dt, duration_s / 2.0);
    let want = target.adev_min;
    let mut p = NoiseParams {
        white: target.rms * dt.sqrt(),
        flicker: (flicker_share / FLICKER_AVAR_PER_B2).sqrt() * want,
        rate_step: step,
        ..NoiseParams::default()
    };
    for _ in 0..4 {
        // K: bisection in log K for min ADEV = want.
        let min_at = |k: f64| -> Result<f64, SimError> {
            Ok(NoiseModel::new(&NoiseParams { rrw: k, ..p }, sampling)?
                .min_adev(lo, hi)
                .1)
        };
        check(min_at(0.0)? < want, || {
            format!(
                "{:?}: white + flicker alone exceed the ADEV minimum; lower flicker_share",
                target.axis
            )
        })?;
        let (mut a, mut b) = (want * 1e-8, want * 1e3);
        check(min_at(b)? > want, || {
            "no rate random walk reaches the ADEV minimum".into()
        })?;
        for _ in 0..200 {
            let m = (a * b).sqrt();
            if min_at(m)? < want {
                a = m
            } else {
                b = m
            }
            if b / a < 1.0 + 1e-13 {
                break;
            }
        }
        p.rrw = (a * b).sqrt();
        // N: total AVAR at τ₀ equals rms².
        let others = NoiseModel::new(&NoiseParams { white: 0.0, ..p }, sampling)?.expected_avar(dt);
        check(others < target.rms * target.rms, || {
            "flicker/RRW/rounding exceed the RMS".into()
        })?;
        p.white = ((target.rms * target.rms - others) * dt).sqrt();
    }
    Ok(p)
}

/// Per raw channel ([`Channel::index`] order) parameters reproducing the seed tables for the seed run (18.9 Hz,
/// 8 h, [`seed_sampling`]), the output rounded to the ADC step.
pub fn seed_sensor_params(flicker_share: f64) -> Result<[NoiseParams; CHANNELS], SimError> {
    let sampling = seed_sampling();
    let duration = SEED_SAMPLES as f64 / SEED_RATE_HZ;
    let mut out = [NoiseParams::default(); CHANNELS];
    for ch in Channel::ALL {
        let target = &SEED_TARGETS[ch.axis().index()];
        out[ch.index()] = fit_target(target, &sampling, duration, ch.adc_step(), flicker_share)?;
    }
    Ok(out)
}

/// The seed experiment: 16 groups, 18.9 Hz, 545 410 samples, seed-table sensors, no cluster effects (an ideal
/// cluster, whose mean should gain √16 = 4), nominal calibration, +1 g on z.
pub fn seed_config(seed: u64) -> Result<SimConfig, SimError> {
    Ok(SimConfig::new(
        seed,
        SEED_RATE_HZ,
        SEED_SAMPLES,
        seed_sensor_params(DEFAULT_FLICKER_SHARE)?,
    ))
}
