//! Cluster effects of a simulation as typed values ([`Effects`]): shared noise, drifts, periodic interference,
//! thermal coefficients and the board's temperature profile ([`TemperatureProfile`]), bad sensors, unequal parts and
//! calibration errors, added to a [`SimConfig`] in one step. `ground simulate`'s effect flags parse into it.

use super::{
    Axis, CalSpread, CommonDrift, CommonMode, Outlier, PartSpread, Periodic, SimConfig, Thermal,
};

/// Temperature at which a simulated part's thermal bias term is zero, °C (the board's bias law does not depend on
/// the temperature profile of a record, so that records of one board under different profiles agree).
pub const PART_REF_C: f64 = 20.0;

/// The board temperature and thermal coefficients before any thermal effect or profile: no coefficient, 20 °C
/// ± 2 °C over 2 h plus 1 °C/h.
pub const DEFAULT_THERMAL: Thermal = Thermal {
    mean_c: PART_REF_C,
    amplitude_c: 2.0,
    period_s: 7200.0,
    phase_rad: 0.0,
    drift_c_per_h: 1.0,
    coef: [0.0; 6],
    coef_sd: [0.0; 6],
    ref_c: Some(PART_REF_C),
    hold_after_s: None,
};

/// Why effects were refused.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum EffectsError {
    /// The log-sd of unequal parts is negative or not finite.
    #[error("--unequal must be a log-sd ≥ 0, found {0}")]
    Unequal(f64),
}

/// A board temperature profile (`ground simulate --temperature`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum TemperatureProfile {
    /// An orbit's cycle: `mean_c + amp_c·sin(2πt / period)`.
    Orbit {
        /// Mean, °C.
        mean_c: f64,
        /// Amplitude, °C (≥ 0).
        amp_c: f64,
        /// Period, minutes (> 0).
        period_min: f64,
    },
    /// A linear ramp from `from_c` to `to_c` over `hours`, then held at `to_c`.
    Ramp {
        /// Start, °C.
        from_c: f64,
        /// End, °C.
        to_c: f64,
        /// Duration of the ramp, hours (> 0).
        hours: f64,
    },
    /// A constant temperature, °C.
    Constant {
        /// The temperature, °C.
        c: f64,
    },
}

impl TemperatureProfile {
    /// Sets `t`'s profile (its coefficients and reference temperature are kept).
    pub fn apply(self, t: &mut Thermal) {
        let (mean_c, amplitude_c, period_s, drift_c_per_h, hold_after_s) = match self {
            Self::Orbit {
                mean_c,
                amp_c,
                period_min,
            } => (mean_c, amp_c, period_min * 60.0, 0.0, None),
            Self::Ramp {
                from_c,
                to_c,
                hours,
            } => (
                from_c,
                0.0,
                3600.0,
                (to_c - from_c) / hours,
                Some(hours * 3600.0),
            ),
            Self::Constant { c } => (c, 0.0, 3600.0, 0.0, None),
        };
        (t.mean_c, t.amplitude_c, t.period_s, t.phase_rad) = (mean_c, amplitude_c, period_s, 0.0);
        (t.drift_c_per_h, t.hold_after_s) = (drift_c_per_h, hold_after_s);
    }
}

/// The temperature-driven bias of some axes' raw channels: `coef` per °C away from [`PART_REF_C`], drawn per part
/// with standard deviation `sd`.
#[derive(Clone, Debug, PartialEq)]
pub struct ThermalCoef {
    /// Axes.
    pub axes: Vec<Axis>,
    /// Coefficient, (°/s)/°C or g/°C.
    pub coef: f64,
    /// Spread between parts, same unit.
    pub sd: f64,
}

/// Cluster effects added to a simulation ([`Effects::apply`]), in the order they are added.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Effects {
    /// Shared noise: common modes of all groups, then blocks of groups.
    pub common: Vec<CommonMode>,
    /// Slow drifts: shared ones, then sensors' own.
    pub drift: Vec<CommonDrift>,
    /// Sinusoidal interferences.
    pub periodic: Vec<Periodic>,
    /// Thermal coefficients (a later one for the same axis replaces an earlier one); any makes the board's
    /// temperature [`DEFAULT_THERMAL`]'s unless `temperature` is given.
    pub thermal: Vec<ThermalCoef>,
    /// The board's temperature profile.
    pub temperature: Option<TemperatureProfile>,
    /// Bad sensors.
    pub outliers: Vec<Outlier>,
    /// Unequal parts: log-sd of a lognormal factor on each sensor's noise levels (0: equal parts).
    pub unequal: f64,
    /// Per-part calibration errors of a typical uncalibrated board ([`CalSpread::typical`]).
    pub cal_spread: bool,
}

impl Effects {
    /// Adds the effects to `cfg`; an error (and `cfg` unchanged) when `unequal` is negative or not finite.
    pub fn apply(&self, cfg: &mut SimConfig) -> Result<(), EffectsError> {
        if !(self.unequal.is_finite() && self.unequal >= 0.0) {
            return Err(EffectsError::Unequal(self.unequal));
        }
        cfg.common.extend(self.common.iter().cloned());
        cfg.drift.extend(self.drift.iter().cloned());
        cfg.periodic.extend(self.periodic.iter().cloned());
        for t in &self.thermal {
            let th = cfg.thermal.get_or_insert(DEFAULT_THERMAL);
            for a in &t.axes {
                th.coef[a.index()] = t.coef;
                th.coef_sd[a.index()] = t.sd;
            }
        }
        if let Some(p) = self.temperature {
            p.apply(cfg.thermal.get_or_insert(DEFAULT_THERMAL));
        }
        cfg.outliers.extend(self.outliers.iter().cloned());
        if self.unequal > 0.0 {
            cfg.spread = PartSpread::unequal_noise(self.unequal);
        }
        if self.cal_spread {
            cfg.cal = CalSpread::typical();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::{Channel, Chunk, NoiseParams, Simulator};

    /// A noiseless board on a ramp: every frame carries the temperature, the ramp holds at its end, and each raw
    /// channel's code moves by its own coefficient (the reading's, through the ADC step of `shared::calib::board`)
    /// times the temperature change: the per-raw-channel linear law is the truth.
    #[test]
    fn thermal_acts_on_each_raw_channel_code() {
        let (rate, hours) = (1.0, 3.0);
        let samples = (hours * 3600.0 * rate) as u64 + 600;
        let mut cfg = SimConfig::new(1, rate, samples, [NoiseParams::default(); 7]);
        cfg.board_seed = Some(7);
        let effects = Effects {
            thermal: vec![
                ThermalCoef {
                    axes: Axis::ALL[..3].to_vec(),
                    coef: 0.05,
                    sd: 0.02,
                },
                ThermalCoef {
                    axes: Axis::ALL[3..].to_vec(),
                    coef: 0.0005,
                    sd: 0.0002,
                },
            ],
            temperature: Some(TemperatureProfile::Ramp {
                from_c: -10.0,
                to_c: 50.0,
                hours: 3.0,
            }),
            ..Effects::default()
        };
        effects.apply(&mut cfg).unwrap();
        let mut sim = Simulator::new(cfg).unwrap();
        let coef = |g, ch: Channel| sim.thermal_coef(g, ch).unwrap() / ch.adc_step();
        let k: Vec<[f64; 7]> = (0..16)
            .map(|g| Channel::ALL.map(|ch| coef(g, ch)))
            .collect();
        // Per raw channel, not per axis: the two z gyros of a group differ.
        assert!((0..16).all(|g| k[g][1] != k[g][3]));
        let mut frames = Vec::new();
        let mut chunk = Chunk::default();
        while sim.next_chunk(&mut chunk) > 0 {
            frames.extend((0..chunk.len).filter_map(|i| chunk.frame(i)));
        }
        let temp: Vec<i16> = frames.iter().map(|f| f.temp_cdeg.unwrap()).collect();
        assert_eq!(temp[0], -1000);
        assert_eq!(temp[(hours * 3600.0) as usize], 5000);
        assert_eq!(*temp.last().unwrap(), 5000);
        let (a, b) = (0, (hours * 3600.0) as usize);
        for (g, kg) in k.iter().enumerate() {
            for (c, kc) in kg.iter().enumerate() {
                let moved = f64::from(frames[b].raw[g][c]) - f64::from(frames[a].raw[g][c]);
                let expect = kc * 60.0;
                assert!(
                    (moved - expect).abs() <= 1.0,
                    "group {g} channel {c}: {moved} counts, expected {expect}"
                );
            }
        }
    }

    #[test]
    fn a_negative_or_nan_unequal_is_refused_and_leaves_the_config_alone() {
        for bad in [-1.0, f64::NAN, f64::INFINITY] {
            let mut cfg = SimConfig::new(1, 1.0, 10, [NoiseParams::default(); 7]);
            let before = cfg.clone();
            let e = Effects {
                unequal: bad,
                cal_spread: true,
                ..Effects::default()
            };
            assert!(matches!(e.apply(&mut cfg), Err(EffectsError::Unequal(_))));
            assert_eq!(cfg, before);
        }
    }
}
