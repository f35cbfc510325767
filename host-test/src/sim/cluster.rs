//! The cluster: 16 groups × 7 raw channels, each with its own [`SensorNoise`], plus cluster effects, streamed
//! in chunks as physical samples, raw ADC codes and FPGA frames.
//!
//! Per raw channel `c` of group `g` and sample `k`, the reading (°/s or g, channel units) is
//! `r = s_c·input + e_indep + Σ_modes coef·shared + Σ drift + κ·(T(t) − T_mean) + outlier step/ramp`, where
//! - the sensor's parameters are the base [`SimConfig::sensor`] of its channel type times lognormal spread factors
//!   ([`PartSpread`]) and an outlier's `noise_factor`, or an explicit [`SensorOverride`];
//! - each [`CommonMode`] covering the sensor takes a share ρ of its white variance and ρ_f of its flicker
//!   variance: the shared process (unit white / unit flicker, one per mode and axis) enters with coefficient
//!   `N_i·√ρ` (resp. `B_i·√ρ_f`) and the independent generator keeps `N_i·√(1 − Σρ)`, so every sensor keeps its
//!   own level and any two sensors of a mode have correlation ρ of their white parts;
//! - [`CommonDrift`] processes are added with coefficient 1 to every sensor they cover;
//! - [`Thermal`] adds `κ_i·(T(t) − T_mean)`, `κ_i` = axis coefficient + normal spread.
//!
//! Outputs per sample: the readings; the ADC codes (true calibration applied inversely, see [`super::calib`]);
//! the physical output `[gx, gy, gz, ax, ay, az]` of each group = the ideal calibration of the readings
//! (gyro z = mean of the two z channels for a nominal group), with each channel's `rate_step` rounding if set.

use super::calib::{CalSpread, TrueGroupCal};
use super::noise::{
    FlickerBand, NoiseModel, NoiseParams, Sampling, SensorNoise, normal, round_to_step,
};
use super::{Axis, CHANNELS, Channel, GROUPS, SimError, check, stream, subseed};
use shared::wire::frame::{FrameRepr, RawSample};
use std::fmt::Write as _;

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
    fn params(self) -> NoiseParams {
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

/// Board temperature `T(t) = mean + amplitude·sin(2πt/period + phase) + drift·t`, output as `temp_c`, and
/// per-sensor bias coefficients.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Thermal {
    /// Mean temperature, °C (also the reference of the bias coefficients).
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
}

impl Thermal {
    /// Temperature at time `t_s`, °C.
    pub fn temp_at(&self, t_s: f64) -> f64 {
        self.mean_c
            + self.amplitude_c
                * (2.0 * std::f64::consts::PI * t_s / self.period_s + self.phase_rad).sin()
            + self.drift_c_per_h * t_s / 3600.0
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
    /// Board temperature and thermal bias; `None` = no `temp_c`.
    pub thermal: Option<Thermal>,
    /// Bad sensors.
    pub outliers: Vec<Outlier>,
    /// True rate input, °/s (static).
    pub rate_dps: [f64; 3],
    /// True specific force, g (static; default +1 g on z, i.e. z up); with a `motion`, fixed in the reference frame.
    pub accel_g: [f64; 3],
    /// A motion of the board (coning, sculling) on top of `rate_dps`; `None` = static.
    pub motion: Option<super::motion::Motion>,
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
        if let Some(t) = &self.thermal {
            let all = [t.mean_c, t.amplitude_c, t.phase_rad, t.drift_c_per_h]
                .into_iter()
                .chain(t.coef)
                .chain(t.coef_sd);
            check(all.into_iter().all(f64::is_finite), || {
                "thermal parameters must be finite".into()
            })?;
            check(t.period_s.is_finite() && t.period_s > 0.0, || {
                "thermal period_s must be > 0".into()
            })?;
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

    fn common_shares(&self, g: usize, ch: Channel) -> impl Iterator<Item = &CommonMode> {
        self.common
            .iter()
            .filter(move |m| covers(&m.groups, g) && m.axes.contains(&ch.axis()))
    }
}

fn covers(groups: &Option<Vec<usize>>, g: usize) -> bool {
    groups.as_ref().is_none_or(|v| v.contains(&g))
}

/// A shared process (unit white, unit flicker, or a drift) and its buffer.
#[derive(Clone, Debug)]
struct SharedProc {
    model: NoiseModel,
    noise: SensorNoise,
    buf: Vec<f64>,
}

/// One sensor's realised setup.
#[derive(Clone, Debug)]
struct Sensor {
    params: NoiseParams,
    indep: NoiseModel,
    noise: SensorNoise,
    /// (shared process, coefficient)
    shares: Vec<(usize, f64)>,
    thermal_coef: f64,
    /// (step, first sample with the step, ramp per sample)
    outlier: Option<(f64, u64, f64)>,
}

/// A chunk of consecutive samples: time, temperature, per-channel readings, ADC codes and physical outputs.
#[derive(Clone, Debug, Default)]
pub struct Chunk {
    /// Index of the first sample in the run.
    pub first: u64,
    /// Samples in this chunk.
    pub len: usize,
    /// Time of each sample, s (sample k at k/rate).
    pub t_s: Vec<f64>,
    /// Board temperature of each sample, °C; empty without [`Thermal`].
    pub temp_c: Vec<f64>,
    /// Physical output per sample and group: `[gx, gy, gz]` °/s, `[ax, ay, az]` g.
    pub phys: Vec<[[f64; 6]; GROUPS]>,
    /// ADC codes per sample (frame order).
    pub codes: Vec<RawSample>,
    /// Channel-major readings: `(group·7 + channel)·cap + k`.
    readings: Vec<f64>,
    cap: usize,
    seq_first: u16,
    decimation: u16,
}

impl Chunk {
    /// Reading of raw channel `channel` of `group` over the chunk, °/s or g (before offset, ADC and rounding).
    pub fn reading(&self, group: usize, channel: Channel) -> &[f64] {
        if group >= GROUPS {
            return &[];
        }
        let at = (group * CHANNELS + channel.index()) * self.cap;
        self.readings.get(at..at + self.len).unwrap_or(&[])
    }

    /// The FPGA frame of sample `i` of the chunk (sequence counter, decimation, temperature, codes).
    pub fn frame(&self, i: usize) -> Option<FrameRepr> {
        let raw = *self.codes.get(i)?;
        Some(FrameRepr {
            seq: self.seq_first.wrapping_add(i as u16),
            decimation: self.decimation,
            temp_cdeg: self
                .temp_c
                .get(i)
                .map(|t| (t * 100.0).round().clamp(-32768.0, 32767.0) as i16),
            raw,
        })
    }

    /// Appends the interchange CSV row of sample `i` (columns of [`csv_header`] with `with_temp` =
    /// `!self.temp_c.is_empty()`), with a newline; time in Rust's shortest round-trip form, values with
    /// `formats::csv::VALUE_DECIMALS` decimals.
    pub fn write_csv_row(&self, i: usize, out: &mut String) {
        let (Some(t), Some(p)) = (self.t_s.get(i), self.phys.get(i)) else {
            return;
        };
        let _ = write!(out, "{t}");
        if let Some(tc) = self.temp_c.get(i) {
            out.push(',');
            crate::formats::csv::push_value(out, *tc);
        }
        for g in p {
            for v in g {
                out.push(',');
                crate::formats::csv::push_value(out, *v);
            }
        }
        out.push('\n');
    }
}

/// Header of the interchange CSV: `t,temp_c,g00x,g00y,g00z,a00x,a00y,a00z,g01x,…` (s, °C, °/s, g); `temp_c` only
/// `with_temp` (a run with [`Thermal`]), since the project's reader wants a number in every cell.
pub fn csv_header(with_temp: bool) -> String {
    let mut h = String::from(if with_temp { "t,temp_c" } else { "t" });
    for g in 0..GROUPS {
        for a in Axis::ALL {
            let s = a.short();
            let _ = write!(h, ",{}{g:02}{}", &s[..1], &s[1..]);
        }
    }
    h
}

/// The streaming cluster simulator.
#[derive(Clone, Debug)]
pub struct Simulator {
    cfg: SimConfig,
    sampling: Sampling,
    sensors: Vec<Sensor>,
    shared: Vec<SharedProc>,
    cal: [TrueGroupCal; GROUPS],
    input: [[f64; CHANNELS]; GROUPS],
    next: u64,
}

impl Simulator {
    /// Validates `cfg` and draws the per-sensor parameters, thermal coefficients and true calibrations.
    pub fn new(cfg: SimConfig) -> Result<Self, SimError> {
        cfg.validate()?;
        let sampling = cfg.sampling()?;
        let dt = sampling.dt_s;
        let mut shared: Vec<SharedProc> = Vec::new();
        let mut add_shared = |p: NoiseParams, id: u64| -> Result<usize, SimError> {
            shared.push(SharedProc {
                model: NoiseModel::new(&p, &sampling)?,
                noise: SensorNoise::new(&p, &sampling, subseed(cfg.seed, id))?,
                buf: Vec::new(),
            });
            Ok(shared.len() - 1)
        };
        // Shared processes: per (mode, axis) a unit white and a unit flicker; per (drift, axis) the drift.
        let mut mode_idx = Vec::new(); // (mode, axis, white idx, flicker idx)
        for (k, m) in cfg.common.iter().enumerate() {
            for &a in &m.axes {
                let base = 10_000 + 64 * k as u64 + 2 * a.index() as u64;
                let w = if m.rho_white > 0.0 {
                    Some(add_shared(NoiseParams::white(1.0), base)?)
                } else {
                    None
                };
                let unit_b = NoiseParams {
                    flicker: 1.0,
                    ..NoiseParams::default()
                };
                let f = if m.rho_flicker > 0.0 {
                    Some(add_shared(unit_b, base + 1)?)
                } else {
                    None
                };
                mode_idx.push((k, a, w, f));
            }
        }
        let mut drift_idx = Vec::new(); // (drift, axis, idx)
        for (k, d) in cfg.drift.iter().enumerate() {
            for &a in &d.axes {
                drift_idx.push((
                    k,
                    a,
                    add_shared(d.kind.params(), 20_000 + 8 * k as u64 + a.index() as u64)?,
                ));
            }
        }
        // The board's part spread, thermal coefficients and calibration follow `board_seed` when set, so that one
        // simulated board can be recorded many times with fresh noise (rate-table calibration: 18 records of it).
        let board_seed = cfg.board_seed.unwrap_or(cfg.seed);
        let mut spread_rng = stream(board_seed, 1);
        let mut thermal_rng = stream(board_seed, 2);
        let mut cal_rng = stream(board_seed, 3);
        let mut sensors = Vec::with_capacity(GROUPS * CHANNELS);
        for g in 0..GROUPS {
            for ch in Channel::ALL {
                let c = ch.index();
                let z: [f64; 4] = core::array::from_fn(|_| normal(&mut spread_rng));
                let tz = normal(&mut thermal_rng);
                let s = &cfg.spread;
                let mut p = match cfg
                    .overrides
                    .iter()
                    .rev()
                    .find(|o| o.group == g && o.channel == ch)
                {
                    Some(o) => o.params,
                    None => {
                        let b = cfg.sensor[c];
                        NoiseParams {
                            white: b.white * (s.level_ln * z[0] + s.white_ln * z[1]).exp(),
                            flicker: b.flicker * (s.level_ln * z[0] + s.flicker_ln * z[2]).exp(),
                            rrw: b.rrw * (s.level_ln * z[0] + s.rrw_ln * z[3]).exp(),
                            ..b
                        }
                    }
                };
                let mut outlier = None;
                for o in cfg
                    .outliers
                    .iter()
                    .filter(|o| o.group == g && o.channel == ch)
                {
                    p = p.scaled(o.noise_factor);
                    let at = (o.step_at_s.max(0.0) / dt).ceil().min(u64::MAX as f64) as u64;
                    outlier = Some((o.step, at, o.drift_per_h * dt / 3600.0));
                }
                let mut shares = Vec::new();
                let (mut rw, mut rf) = (0.0, 0.0);
                for &(k, a, w, f) in &mode_idx {
                    let m = &cfg.common[k];
                    if a != ch.axis() || !covers(&m.groups, g) {
                        continue;
                    }
                    if let Some(w) = w {
                        shares.push((w, p.white * m.rho_white.sqrt()));
                        rw += m.rho_white;
                    }
                    if let Some(f) = f {
                        shares.push((f, p.flicker * m.rho_flicker.sqrt()));
                        rf += m.rho_flicker;
                    }
                }
                for &(k, a, i) in &drift_idx {
                    if a == ch.axis() && covers(&cfg.drift[k].groups, g) {
                        shares.push((i, 1.0));
                    }
                }
                let indep_p = NoiseParams {
                    white: p.white * (1.0 - rw).max(0.0).sqrt(),
                    flicker: p.flicker * (1.0 - rf).max(0.0).sqrt(),
                    ..p
                };
                let thermal_coef = cfg.thermal.map_or(0.0, |t| {
                    t.coef[ch.axis().index()] + t.coef_sd[ch.axis().index()] * tz
                });
                sensors.push(Sensor {
                    params: p,
                    indep: NoiseModel::new(&indep_p, &sampling)?,
                    noise: SensorNoise::new(
                        &indep_p,
                        &sampling,
                        subseed(cfg.seed, 100 + (g * CHANNELS + c) as u64),
                    )?,
                    shares,
                    thermal_coef,
                    outlier,
                });
            }
        }
        let mut cal = [TrueGroupCal::nominal(); GROUPS];
        for c in &mut cal {
            *c = cfg.cal.sample(&mut cal_rng)?;
        }
        let input = cal.map(|c| c.readings(cfg.rate_dps, cfg.accel_g));
        Ok(Self {
            cfg,
            sampling,
            sensors,
            shared,
            cal,
            input,
            next: 0,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SimConfig {
        &self.cfg
    }

    /// The sampling (Δt, flicker band) of every process.
    pub fn sampling(&self) -> &Sampling {
        &self.sampling
    }

    /// True calibration of each group.
    pub fn true_cal(&self) -> &[TrueGroupCal; GROUPS] {
        &self.cal
    }

    /// Realised parameters of one sensor (after spread, override and outlier factor; before the common-mode
    /// split); `None` out of range.
    pub fn sensor_params(&self, group: usize, channel: Channel) -> Option<&NoiseParams> {
        (group < GROUPS).then(|| &self.sensors[group * CHANNELS + channel.index()].params)
    }

    /// Realised thermal bias coefficient of one sensor, u/°C (0 without [`Thermal`]).
    pub fn thermal_coef(&self, group: usize, channel: Channel) -> Option<f64> {
        (group < GROUPS).then(|| self.sensors[group * CHANNELS + channel.index()].thermal_coef)
    }

    /// Samples not yet produced.
    pub fn remaining(&self) -> u64 {
        self.cfg.samples - self.next
    }

    /// Expected AVAR (u²) at `tau_s` of the equal-weight mean of raw channel `channel` over `groups` (one group:
    /// that sensor alone): independent parts add as `Σ AVAR_i / n²`, each shared process as
    /// `(Σ coef_i / n)²·AVAR_unit`. Thermal and outlier bias steps/ramps are not included.
    pub fn expected_mean_avar(
        &self,
        channel: Channel,
        groups: &[usize],
        tau_s: f64,
    ) -> Result<f64, SimError> {
        check(
            !groups.is_empty() && groups.iter().all(|&g| g < GROUPS),
            || "groups must be non-empty, in 0..16".into(),
        )?;
        check(tau_s.is_finite() && tau_s >= self.sampling.dt_s, || {
            format!("tau_s = {tau_s} must be ≥ Δt")
        })?;
        let n = groups.len() as f64;
        let mut coef = vec![0.0; self.shared.len()];
        let mut indep = 0.0;
        for &g in groups {
            let s = &self.sensors[g * CHANNELS + channel.index()];
            indep += s.indep.expected_avar(tau_s);
            for &(i, c) in &s.shares {
                coef[i] += c / n;
            }
        }
        let shared: f64 = coef
            .iter()
            .zip(&self.shared)
            .map(|(c, p)| c * c * p.model.expected_avar(tau_s))
            .sum();
        Ok(indep / (n * n) + shared)
    }

    /// Produces the next chunk into `out` (reusing its buffers); returns the number of samples (0 at the end).
    pub fn next_chunk(&mut self, out: &mut Chunk) -> usize {
        let cap = self.cfg.chunk_len;
        let n = self.remaining().min(cap as u64) as usize;
        out.first = self.next;
        out.len = n;
        out.cap = cap;
        out.seq_first = self.cfg.frames.seq_start.wrapping_add(self.next as u16);
        out.decimation = self.cfg.frames.decimation;
        if n == 0 {
            for v in [&mut out.t_s, &mut out.temp_c] {
                v.clear();
            }
            out.phys.clear();
            out.codes.clear();
            return 0;
        }
        let dt = self.sampling.dt_s;
        out.t_s.clear();
        out.t_s
            .extend((0..n).map(|i| (self.next + i as u64) as f64 * dt));
        out.temp_c.clear();
        if let Some(t) = &self.cfg.thermal {
            out.temp_c.extend(out.t_s.iter().map(|&ts| t.temp_at(ts)));
        }
        for p in &mut self.shared {
            p.buf.resize(n, 0.0);
            p.noise.fill(&mut p.buf);
        }
        out.readings.resize(GROUPS * CHANNELS * cap, 0.0);
        let t_ref = self.cfg.thermal.map_or(0.0, |t| t.mean_c);
        for (si, s) in self.sensors.iter_mut().enumerate() {
            let r = &mut out.readings[si * cap..si * cap + n];
            s.noise.fill(r);
            for &(i, c) in &s.shares {
                for (x, y) in r.iter_mut().zip(&self.shared[i].buf) {
                    *x += c * y;
                }
            }
            if s.thermal_coef != 0.0 {
                for (x, t) in r.iter_mut().zip(&out.temp_c) {
                    *x += s.thermal_coef * (t - t_ref);
                }
            }
            if let Some((step, at, ramp)) = s.outlier {
                for (k, x) in r.iter_mut().enumerate() {
                    let idx = self.next + k as u64;
                    *x += ramp * idx as f64 + if idx >= at { step } else { 0.0 };
                }
            }
            if let Some(m) = self.cfg.motion {
                // The sample at t = (index) · Δt sees the motion then (and the static rate on top).
                let (g, c) = (si / CHANNELS, si % CHANNELS);
                for (x, &ts) in r.iter_mut().zip(&out.t_s) {
                    let (rate, accel) = m.at(ts, self.cfg.accel_g);
                    let rate = core::array::from_fn(|i| rate[i] + self.cfg.rate_dps[i]);
                    *x += self.cal[g].readings(rate, accel)[c];
                }
                continue;
            }
            let inp = self.input[si / CHANNELS][si % CHANNELS];
            if inp != 0.0 {
                for x in r.iter_mut() {
                    *x += inp;
                }
            }
        }
        out.phys.resize(n, [[0.0; 6]; GROUPS]);
        out.codes.resize(n, [[0; CHANNELS]; GROUPS]);
        let mut rd = vec![[0.0; CHANNELS]; n];
        for g in 0..GROUPS {
            for (c, r) in out.readings[g * CHANNELS * cap..]
                .chunks(cap)
                .take(CHANNELS)
                .enumerate()
            {
                for (d, x) in rd.iter_mut().zip(&r[..n]) {
                    d[c] = *x;
                }
            }
            let cal = &self.cal[g];
            for (k, d) in rd.iter_mut().enumerate() {
                out.codes[k][g] = cal.codes(d);
            }
            for c in 0..CHANNELS {
                let step = self.sensors[g * CHANNELS + c].params.rate_step;
                if step > 0.0 {
                    for d in rd.iter_mut() {
                        round_to_step(core::slice::from_mut(&mut d[c]), step);
                    }
                }
            }
            for (k, d) in rd.iter().enumerate() {
                out.phys[k][g] = cal.physical(d);
            }
        }
        self.next += n as u64;
        n
    }

    /// Runs the rest of the simulation, appending to one series per selected `(group, item)` what `take` extracts
    /// from each chunk.
    fn collect<S: Copy>(
        &mut self,
        sel: &[(usize, S)],
        take: impl Fn(&Chunk, usize, S, &mut Vec<f64>),
    ) -> Result<Vec<Vec<f64>>, SimError> {
        check(sel.iter().all(|&(g, _)| g < GROUPS), || {
            "group out of range".into()
        })?;
        let cap = self.remaining().min(1 << 24) as usize;
        let mut out: Vec<Vec<f64>> = sel.iter().map(|_| Vec::with_capacity(cap)).collect();
        let mut chunk = Chunk::default();
        while self.next_chunk(&mut chunk) > 0 {
            for (o, &(g, item)) in out.iter_mut().zip(sel) {
                take(&chunk, g, item, o);
            }
        }
        Ok(out)
    }

    /// Runs the rest of the simulation and returns the readings (°/s, g) of the selected raw channels.
    pub fn collect_readings(
        &mut self,
        sel: &[(usize, Channel)],
    ) -> Result<Vec<Vec<f64>>, SimError> {
        self.collect(sel, |chunk, g, c, o| {
            o.extend_from_slice(chunk.reading(g, c))
        })
    }

    /// Runs the rest of the simulation and returns the physical outputs (°/s, g) of the selected group axes.
    pub fn collect_physical(&mut self, sel: &[(usize, Axis)]) -> Result<Vec<Vec<f64>>, SimError> {
        self.collect(sel, |chunk, g, a, o| {
            o.extend(chunk.phys.iter().map(|p| p[g][a.index()]))
        })
    }

    /// Convenience: all samples of one physical axis of one group for `cfg`.
    pub fn axis_series(cfg: SimConfig, group: usize, axis: Axis) -> Result<Vec<f64>, SimError> {
        Ok(Self::new(cfg)?
            .collect_physical(&[(group, axis)])?
            .pop()
            .unwrap_or_default())
    }
}
