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
//! - [`CommonDrift`] processes and [`Periodic`] sinusoids are added with coefficient 1 to every sensor they cover;
//! - [`Thermal`] adds `κ_i·(T(t) − T_ref)` to the raw channel's reading, `κ_i` = axis coefficient + normal
//!   spread drawn per raw channel (the two z gyros of a group each their own), so the bias of each raw channel's
//!   code is linear in temperature with `κ_i · slope` counts/°C ([`Simulator::thermal_coef_counts`]).
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

mod config;
pub use config::{
    CommonDrift, CommonMode, DriftKind, FrameOpts, Outlier, PartSpread, Periodic, SensorOverride,
    SimConfig, Thermal,
};

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

/// The shared processes and which (mode or drift, axis) each one is: per (mode, axis) a unit white and a unit
/// flicker (where the mode has them), then per (drift, axis) the drift, in that order (their seeds and indices).
struct SharedSet {
    procs: Vec<SharedProc>,
    /// (mode, axis, white index, flicker index)
    modes: Vec<(usize, Axis, Option<usize>, Option<usize>)>,
    /// (drift, axis, index)
    drifts: Vec<(usize, Axis, usize)>,
}

impl SharedSet {
    fn new(cfg: &SimConfig, sampling: &Sampling) -> Result<Self, SimError> {
        let mut procs: Vec<SharedProc> = Vec::new();
        let mut add_shared = |p: NoiseParams, id: u64| -> Result<usize, SimError> {
            procs.push(SharedProc {
                model: NoiseModel::new(&p, sampling)?,
                noise: SensorNoise::new(&p, sampling, subseed(cfg.seed, id))?,
                buf: Vec::new(),
            });
            Ok(procs.len() - 1)
        };
        let mut modes = Vec::new();
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
                modes.push((k, a, w, f));
            }
        }
        let mut drifts = Vec::new();
        for (k, d) in cfg.drift.iter().enumerate() {
            for &a in &d.axes {
                drifts.push((
                    k,
                    a,
                    add_shared(d.kind.params(), 20_000 + 8 * k as u64 + a.index() as u64)?,
                ));
            }
        }
        Ok(Self {
            procs,
            modes,
            drifts,
        })
    }

    /// The shared processes in sensor (group `g`, channel `ch`, parameters `p`) with their coefficients, and the
    /// fractions of its white and flicker variance they take.
    fn shares_of(
        &self,
        cfg: &SimConfig,
        g: usize,
        ch: Channel,
        p: &NoiseParams,
    ) -> (Vec<(usize, f64)>, f64, f64) {
        let mut shares = Vec::new();
        let (mut rw, mut rf) = (0.0, 0.0);
        for &(k, a, w, f) in &self.modes {
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
        for &(k, a, i) in &self.drifts {
            if a == ch.axis() && covers(&cfg.drift[k].groups, g) {
                shares.push((i, 1.0));
            }
        }
        (shares, rw, rf)
    }
}

impl Sensor {
    /// The sensor of group `g`, channel `ch`: `z` its part-spread draws, `tz` its thermal draw.
    fn new(
        cfg: &SimConfig,
        sampling: &Sampling,
        shared: &SharedSet,
        (g, ch): (usize, Channel),
        z: [f64; 4],
        tz: f64,
    ) -> Result<Self, SimError> {
        let c = ch.index();
        let dt = sampling.dt_s;
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
        let (shares, rw, rf) = shared.shares_of(cfg, g, ch, &p);
        let indep_p = NoiseParams {
            white: p.white * (1.0 - rw).max(0.0).sqrt(),
            flicker: p.flicker * (1.0 - rf).max(0.0).sqrt(),
            ..p
        };
        let thermal_coef = cfg.thermal.map_or(0.0, |t| {
            t.coef[ch.axis().index()] + t.coef_sd[ch.axis().index()] * tz
        });
        Ok(Sensor {
            params: p,
            indep: NoiseModel::new(&indep_p, sampling)?,
            noise: SensorNoise::new(
                &indep_p,
                sampling,
                subseed(cfg.seed, 100 + (g * CHANNELS + c) as u64),
            )?,
            shares,
            thermal_coef,
            outlier,
        })
    }
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
        let shared = SharedSet::new(&cfg, &sampling)?;
        // The board's part spread, thermal coefficients and calibration follow `board_seed` when set, so that one
        // simulated board can be recorded many times with fresh noise (rate-table calibration: 18 records of it).
        let board_seed = cfg.board_seed.unwrap_or(cfg.seed);
        let mut spread_rng = stream(board_seed, 1);
        let mut thermal_rng = stream(board_seed, 2);
        let mut cal_rng = stream(board_seed, 3);
        let mut sensors = Vec::with_capacity(GROUPS * CHANNELS);
        for g in 0..GROUPS {
            for ch in Channel::ALL {
                let z: [f64; 4] = core::array::from_fn(|_| normal(&mut spread_rng));
                let tz = normal(&mut thermal_rng);
                sensors.push(Sensor::new(&cfg, &sampling, &shared, (g, ch), z, tz)?);
            }
        }
        let shared = shared.procs;
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

    /// Realised thermal bias coefficient of one raw channel in its ADC codes, counts/°C: the reading's
    /// coefficient times the nominal chain's slope ([`TrueGroupCal::slope`]); 0 without [`Thermal`].
    pub fn thermal_coef_counts(&self, group: usize, channel: Channel) -> Option<f64> {
        self.thermal_coef(group, channel)
            .map(|k| k * self.cal[group].slope()[channel.index()])
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
        let t_ref = self.cfg.thermal.map_or(0.0, |t| t.reference_c());
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
            let (g, ch) = (si / CHANNELS, Channel::ALL[si % CHANNELS]);
            for p in &self.cfg.periodic {
                if p.axes.contains(&ch.axis()) && covers(&p.groups, g) {
                    for (x, &ts) in r.iter_mut().zip(&out.t_s) {
                        *x += p.at(ts);
                    }
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
