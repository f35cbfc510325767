//! What a simulation is asked for: [`SimConfig`] and the cluster effects it may carry (common modes, drifts,
//! thermal response, outliers, part spread, per-sensor overrides, frame options).

use super::*;

/// Noise shared by the sensors of some axes in some groups (all groups: common mode; a subset: block mode).
#[derive(Clone, Debug, PartialEq)]
pub struct CommonMode {
    /// Name (for reports).
    pub name: String,
    /// Groups covered (0..16); `None` = all.
    pub groups: Option<Vec<usize>>,
    /// Axes covered; one shared process per axis (gyro z: both z channels of every covered group).
    pub axes: Vec<Axis>,
    /// Share ρ ∈ [0, 1] of each sensor's white variance that is common (pairwise correlation ρ).
    pub rho_white: f64,
    /// Share ρ_f ∈ [0, 1] of each sensor's flicker variance that is common.
    pub rho_flicker: f64,
}

impl CommonMode {
    /// A mode shared by all groups.
    pub fn all(axes: &[Axis], rho_white: f64, rho_flicker: f64) -> Self {
        Self {
            name: "common".into(),
            groups: None,
            axes: axes.to_vec(),
            rho_white,
            rho_flicker,
        }
    }

    /// A mode shared within a named block of groups.
    pub fn block(
        name: &str,
        groups: &[usize],
        axes: &[Axis],
        rho_white: f64,
        rho_flicker: f64,
    ) -> Self {
        Self {
            name: name.into(),
            groups: Some(groups.to_vec()),
            axes: axes.to_vec(),
            rho_white,
            rho_flicker,
        }
    }
}

/// A slow drift shared (with coefficient 1) by all covered sensors of each axis; independent between axes.
#[derive(Clone, Debug, PartialEq)]
pub struct CommonDrift {
    /// Groups covered; `None` = all.
    pub groups: Option<Vec<usize>>,
    /// Axes covered.
    pub axes: Vec<Axis>,
    /// The process.
    pub kind: DriftKind,
}

/// A shared slow process.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum DriftKind {
    /// Random walk of the bias, K in u/√s (AVAR `K²τ/3`).
    RandomWalk {
        /// K, (°/s)/√s or g/√s.
        k: f64,
    },
    /// First-order Gauss–Markov of standard deviation `sigma` (u) and correlation time `tau_s` (s).
    GaussMarkov {
        /// σ, °/s or g.
        sigma: f64,
        /// Correlation time, s.
        tau_s: f64,
    },
}

impl DriftKind {
    pub(super) fn params(self) -> NoiseParams {
        match self {
            DriftKind::RandomWalk { k } => NoiseParams {
                rrw: k,
                ..NoiseParams::default()
            },
            DriftKind::GaussMarkov { sigma, tau_s } => NoiseParams {
                gm_sigma: sigma,
                gm_tau_s: tau_s,
                ..NoiseParams::default()
            },
        }
    }
}

/// A sinusoidal interference `A·sin(2πt/P + φ)` added (with coefficient 1) to every covered sensor of each axis:
/// all groups, a common-mode periodic disturbance (a reaction wheel, a heater's cycle); one group, one sensor's own.
#[derive(Clone, Debug, PartialEq)]
pub struct Periodic {
    /// Groups covered; `None` = all.
    pub groups: Option<Vec<usize>>,
    /// Axes covered.
    pub axes: Vec<Axis>,
    /// Amplitude A, °/s or g.
    pub amplitude: f64,
    /// Period P, s (> 0).
    pub period_s: f64,
    /// Phase φ, rad.
    pub phase_rad: f64,
}

impl Periodic {
    /// The interference at time `t_s`.
    pub fn at(&self, t_s: f64) -> f64 {
        self.amplitude * (2.0 * std::f64::consts::PI * t_s / self.period_s + self.phase_rad).sin()
    }
}

/// Board temperature `T(t) = mean + amplitude·sin(2πt/period + phase) + drift·min(t, hold_after)`, output as
/// `temp_c`, and per-sensor bias coefficients: each raw channel's reading gains `κ·(T(t) − T_ref)` (before the
/// ADC, so in codes a per-raw-channel linear law of `κ · slope` counts/°C, `TrueGroupCal::slope`), `T_ref` = [`Self::ref_c`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thermal {
    /// Mean temperature, °C (the start of a ramp: `amplitude_c` 0 and a drift).
    pub mean_c: f64,
    /// Amplitude of the sinusoid, °C.
    pub amplitude_c: f64,
    /// Period of the sinusoid, s.
    pub period_s: f64,
    /// Phase of the sinusoid, rad.
    pub phase_rad: f64,
    /// Linear drift, °C/h.
    pub drift_c_per_h: f64,
    /// Mean bias coefficient per axis ([`Axis::index`] order): (°/s)/°C for gyros, g/°C for accelerometers.
    pub coef: [f64; 6],
    /// Standard deviation between sensors of the coefficient, same units (normal draws).
    pub coef_sd: [f64; 6],
    /// Temperature at which the thermal bias term is zero, °C: a property of the parts, so that records of one
    /// board (`SimConfig::board_seed`) under different temperature profiles share one bias law; `None` = `mean_c`.
    pub ref_c: Option<f64>,
    /// Time after which the linear drift stops (the end of a ramp), s; `None` = never.
    pub hold_after_s: Option<f64>,
}

impl Thermal {
    /// A board temperature `mean_c` ± `amplitude_c` with period `period_s` (phase 0, no drift, no hold) that moves
    /// no sensor (no coefficients; the reference is `mean_c`).
    pub fn sine(mean_c: f64, amplitude_c: f64, period_s: f64) -> Self {
        Self {
            mean_c,
            amplitude_c,
            period_s,
            phase_rad: 0.0,
            drift_c_per_h: 0.0,
            coef: [0.0; 6],
            coef_sd: [0.0; 6],
            ref_c: None,
            hold_after_s: None,
        }
    }

    /// Temperature at time `t_s`, °C.
    pub fn temp_at(&self, t_s: f64) -> f64 {
        self.mean_c
            + self.amplitude_c
                * (2.0 * std::f64::consts::PI * t_s / self.period_s + self.phase_rad).sin()
            + self.drift_c_per_h * self.hold_after_s.map_or(t_s, |h| t_s.min(h)) / 3600.0
    }

    /// Temperature at which the thermal bias term is zero, °C ([`Self::ref_c`], else `mean_c`).
    pub fn reference_c(&self) -> f64 {
        self.ref_c.unwrap_or(self.mean_c)
    }
}

/// One bad sensor.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outlier {
    /// Group, 0..16.
    pub group: usize,
    /// Raw channel.
    pub channel: Channel,
    /// Factor on the sensor's N, B and K (1 = normal).
    pub noise_factor: f64,
    /// Bias step, u (0 = none), from `step_at_s` on.
    pub step: f64,
    /// Time of the step, s.
    pub step_at_s: f64,
    /// Bias ramp from t = 0, u per hour.
    pub drift_per_h: f64,
}

impl Outlier {
    /// `group`'s `channel` with `noise_factor` × its noise terms and nothing else.
    pub fn noisy(group: usize, channel: Channel, noise_factor: f64) -> Self {
        Self {
            group,
            channel,
            noise_factor,
            step: 0.0,
            step_at_s: 0.0,
            drift_per_h: 0.0,
        }
    }

    /// `group`'s `channel` with a bias step of `step` (u) at `step_at_s` and nothing else.
    pub fn step(group: usize, channel: Channel, step: f64, step_at_s: f64) -> Self {
        Self {
            step,
            step_at_s,
            ..Self::noisy(group, channel, 1.0)
        }
    }
}

/// Spread of noise levels between parts: each sensor's N, B and K are multiplied by lognormal factors
/// `exp(level_ln·z₀ + white_ln·z₁)`, `exp(level_ln·z₀ + flicker_ln·z₂)`, `exp(level_ln·z₀ + rrw_ln·z₃)` with
/// independent standard normal z (median factor 1; `level_ln` moves a part's three levels together).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PartSpread {
    /// Log-sd of a factor common to N, B and K of a part ("unequal noise").
    pub level_ln: f64,
    /// Log-sd of N alone.
    pub white_ln: f64,
    /// Log-sd of B alone.
    pub flicker_ln: f64,
    /// Log-sd of K alone.
    pub rrw_ln: f64,
}

impl PartSpread {
    /// Unequal noise: one lognormal factor of log-sd `s` per part on all its levels.
    pub fn unequal_noise(s: f64) -> Self {
        Self {
            level_ln: s,
            ..Self::default()
        }
    }
}

/// Exact parameters of one sensor (no spread applied; an outlier's factor still is).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SensorOverride {
    /// Group, 0..16.
    pub group: usize,
    /// Raw channel.
    pub channel: Channel,
    /// Its parameters.
    pub params: NoiseParams,
}

/// Frame header fields.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FrameOpts {
    /// Decimation N written into each frame (the FPGA keeps 1 data set of N + 1; the simulated samples are
    /// point samples at `rate_hz`, i.e. what the kept data sets are).
    pub decimation: u16,
    /// Sequence counter of the first frame (+1 per sample, wrapping).
    pub seq_start: u16,
}

/// Everything a cluster simulation needs. Build with [`SimConfig::new`] and set the optional effects.
#[derive(Clone, Debug, PartialEq)]
pub struct SimConfig {
    /// Seed of all random streams.
    pub seed: u64,
    /// Output sample rate, Hz.
    pub rate_hz: f64,
    /// Number of samples.
    pub samples: u64,
    /// Samples per chunk (1 ..= 2²⁰).
    pub chunk_len: usize,
    /// Base noise parameters per raw channel type ([`Channel::index`] order).
    pub sensor: [NoiseParams; CHANNELS],
    /// Flicker synthesis band; `None` = [`FlickerBand::for_run`].
    pub flicker_band: Option<FlickerBand>,
    /// Spread of levels between parts.
    pub spread: PartSpread,
    /// Exact parameters of single sensors.
    pub overrides: Vec<SensorOverride>,
    /// Common and block common modes.
    pub common: Vec<CommonMode>,
    /// Shared slow drifts.
    pub drift: Vec<CommonDrift>,
    /// Sinusoidal interferences.
    pub periodic: Vec<Periodic>,
    /// Board temperature and thermal bias; `None` = no `temp_c`.
    pub thermal: Option<Thermal>,
    /// Bad sensors.
    pub outliers: Vec<Outlier>,
    /// True rate input, °/s (static).
    pub rate_dps: [f64; 3],
    /// True specific force, g (static; default +1 g on z, i.e. z up); with a `motion`, fixed in the reference frame.
    pub accel_g: [f64; 3],
    /// A motion of the board (coning, sculling) on top of `rate_dps`; `None` = static.
    pub motion: Option<crate::sim::motion::Motion>,
    /// Spread of the true calibration between groups.
    pub cal: CalSpread,
    /// Seed of the board's true calibration; `None` = `seed`. Records with the same `board_seed` and different
    /// `seed` are the same board with independent noise.
    pub board_seed: Option<u64>,
    /// Frame header fields.
    pub frames: FrameOpts,
}

impl SimConfig {
    /// An ideal cluster (no cluster effects, nominal calibration) with `sensor` parameters per channel type.
    pub fn new(seed: u64, rate_hz: f64, samples: u64, sensor: [NoiseParams; CHANNELS]) -> Self {
        Self {
            seed,
            rate_hz,
            samples,
            chunk_len: 4096,
            sensor,
            flicker_band: None,
            spread: PartSpread::default(),
            overrides: Vec::new(),
            common: Vec::new(),
            drift: Vec::new(),
            periodic: Vec::new(),
            thermal: None,
            outliers: Vec::new(),
            rate_dps: [0.0; 3],
            accel_g: [0.0, 0.0, 1.0],
            motion: None,
            cal: CalSpread::NONE,
            board_seed: None,
            frames: FrameOpts::default(),
        }
    }

    /// Duration of the run, s.
    pub fn duration_s(&self) -> f64 {
        self.samples as f64 / self.rate_hz
    }

    /// The sampling used for every sensor.
    pub fn sampling(&self) -> Result<Sampling, SimError> {
        let mut s = Sampling::new(self.rate_hz, self.duration_s())?;
        if let Some(b) = self.flicker_band {
            s.flicker = b;
        }
        s.validate()?;
        Ok(s)
    }

    /// Checks every field (also done by [`Simulator::new`]).
    pub fn validate(&self) -> Result<(), SimError> {
        self.sampling()?;
        check(self.samples >= 1, || "samples must be ≥ 1".into())?;
        check((1..=1 << 20).contains(&self.chunk_len), || {
            format!("chunk_len = {} not in 1..=2^20", self.chunk_len)
        })?;
        for p in &self.sensor {
            p.validate()?;
        }
        let s = &self.spread;
        for (name, v) in [
            ("level_ln", s.level_ln),
            ("white_ln", s.white_ln),
            ("flicker_ln", s.flicker_ln),
            ("rrw_ln", s.rrw_ln),
        ] {
            check(v.is_finite() && (0.0..=3.0).contains(&v), || {
                format!("spread {name} = {v} must be in [0, 3]")
            })?;
        }
        let group_ok = |g: usize| -> Result<(), SimError> {
            check(g < GROUPS, || format!("group {g} out of 0..{GROUPS}"))
        };
        for o in &self.overrides {
            group_ok(o.group)?;
            o.params.validate()?;
        }
        for m in &self.common {
            for g in m.groups.iter().flatten() {
                group_ok(*g)?;
            }
            for r in [m.rho_white, m.rho_flicker] {
                check((0.0..=1.0).contains(&r), || {
                    format!("common mode '{}': ρ = {r} not in [0, 1]", m.name)
                })?;
            }
        }
        for g in 0..GROUPS {
            for ch in Channel::ALL {
                let (w, f) = self
                    .common_shares(g, ch)
                    .fold((0.0, 0.0), |(w, f), m| (w + m.rho_white, f + m.rho_flicker));
                check(w <= 1.0 + 1e-12 && f <= 1.0 + 1e-12, || {
                    format!(
                        "common modes of group {g} {ch:?} share more than the whole variance (Σρ = {w}, {f})"
                    )
                })?;
            }
        }
        for d in &self.drift {
            for g in d.groups.iter().flatten() {
                group_ok(*g)?;
            }
            d.kind.params().validate()?;
        }
        for p in &self.periodic {
            for g in p.groups.iter().flatten() {
                group_ok(*g)?;
            }
            check(
                p.period_s.is_finite()
                    && p.period_s > 0.0
                    && p.amplitude.is_finite()
                    && p.phase_rad.is_finite(),
                || {
                    format!(
                        "periodic: period {} s must be > 0, amplitude {} and phase {} finite",
                        p.period_s, p.amplitude, p.phase_rad
                    )
                },
            )?;
        }
        if let Some(t) = &self.thermal {
            let all = [t.mean_c, t.amplitude_c, t.phase_rad, t.drift_c_per_h]
                .into_iter()
                .chain(t.ref_c)
                .chain(t.coef)
                .chain(t.coef_sd);
            check(all.into_iter().all(f64::is_finite), || {
                "thermal parameters must be finite".into()
            })?;
            check(t.period_s.is_finite() && t.period_s > 0.0, || {
                "thermal period_s must be > 0".into()
            })?;
            check(
                t.hold_after_s.is_none_or(|h| !h.is_nan() && h >= 0.0),
                || "thermal hold_after_s must be ≥ 0".into(),
            )?;
            check(t.coef_sd.iter().all(|&v| v >= 0.0), || {
                "thermal coef_sd must be ≥ 0".into()
            })?;
        }
        for o in &self.outliers {
            group_ok(o.group)?;
            check(o.noise_factor.is_finite() && o.noise_factor >= 0.0, || {
                "outlier noise_factor must be ≥ 0".into()
            })?;
            check(
                [o.step, o.step_at_s, o.drift_per_h]
                    .iter()
                    .all(|v| v.is_finite()),
                || "outlier values must be finite".into(),
            )?;
        }
        check(
            self.rate_dps
                .iter()
                .chain(&self.accel_g)
                .all(|v| v.is_finite()),
            || "input must be finite".into(),
        )?;
        self.cal.validate()
    }

    pub(super) fn common_shares(&self, g: usize, ch: Channel) -> impl Iterator<Item = &CommonMode> {
        self.common
            .iter()
            .filter(move |m| covers(&m.groups, g) && m.axes.contains(&ch.axis()))
    }
}
