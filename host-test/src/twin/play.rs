//! A synthetic recording of the modelled cluster: each sensor is its mean, its own noise (the simulator's
//! generators: `sim::noise::SensorNoise` for Q, N, B and K; the ramp R as a line), its thermal coefficient times
//! the temperature's departure from the reference, its own sinusoids and bias steps, and the shared processes it
//! belongs to (one realisation per process, added to every member; a shared sinusoid is the same on every member),
//! the whole through the axis's bandwidth; then the Gauss–Markov terms (own and shared), exact AR(1), of the output.
//! Without effects, every sensor plays the typical terms alone: the √N model the diagnosis starts from.

use super::{
    BiasStep, ClusterModel, GaussMarkov, NoiseTerms, SharedProcess, Sinusoid, TemperatureModel,
    TwinError,
};
use crate::recording::SensorKind;
use crate::recording::{Column, Recording};
use crate::sim::noise::{NoiseParams, Sampling, SensorNoise};

/// What to play.
#[derive(Clone, Debug, Default)]
pub struct PlayOptions {
    /// Seed of the noise (the same seed, the same record).
    pub seed: u64,
    /// Samples (default: the record's).
    pub samples: Option<usize>,
    /// Sample rate, Hz (default: the record's).
    pub rate_hz: Option<f64>,
    /// Only the independent typical sensors (no shared process, no thermal term, no unequal sensors).
    pub without_effects: bool,
    /// Temperature to drive the thermal terms with, °C per sample (e.g. a recording's `temp_c`), instead of the
    /// model's.
    pub temperature: Option<Vec<f64>>,
}

/// SplitMix64: an independent seed per stream.
fn mix(seed: u64, a: u64, b: u64, c: u64) -> u64 {
    let mut z = seed
        ^ a.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ b.wrapping_mul(0xBF58_476D_1CE4_E5B9)
        ^ c.wrapping_mul(0x94D0_49BB_1331_11EB);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// `n` samples of `terms` (zero mean; the ramp as `R·t`).
fn noise(
    terms: &NoiseTerms,
    sampling: &Sampling,
    n: usize,
    seed: u64,
) -> Result<Vec<f64>, TwinError> {
    let params = NoiseParams {
        quant: terms.quantization,
        white: terms.white,
        flicker: terms.bias_instability,
        rrw: terms.random_walk,
        ..NoiseParams::default()
    };
    let mut g =
        SensorNoise::new(&params, sampling, seed).map_err(|e| TwinError::Invalid(e.to_string()))?;
    let mut v = vec![0.0; n];
    g.fill(&mut v);
    if terms.ramp > 0.0 {
        let dt = sampling.dt_s;
        v.iter_mut()
            .enumerate()
            .for_each(|(k, x)| *x += terms.ramp * k as f64 * dt);
    }
    Ok(v)
}

/// Adds the Gauss–Markov terms `gm` to `out` (each its own stream of `seed`; the simulator's exact AR(1), or the
/// narrow-band form's complex AR(1), started stationary).
fn add_gauss_markov(
    out: &mut [f64],
    gm: &[GaussMarkov],
    sampling: &Sampling,
    seed: u64,
) -> Result<(), TwinError> {
    let mut v = vec![0.0; out.len()];
    for (k, g) in gm.iter().enumerate() {
        let stream = mix(seed, k as u64, 0x6A, 0);
        if g.freq_hz > 0.0 {
            let dt = sampling.dt_s;
            let theta = std::f64::consts::TAU * g.freq_hz * dt;
            crate::sim::noise::add_line(out, g.sigma * g.sigma, dt / g.tau_s, theta, stream);
            continue;
        }
        let params = NoiseParams {
            gm_sigma: g.sigma,
            gm_tau_s: g.tau_s,
            ..NoiseParams::default()
        };
        SensorNoise::new(&params, sampling, stream)
            .map_err(|e| TwinError::Invalid(e.to_string()))?
            .fill(&mut v);
        out.iter_mut().zip(&v).for_each(|(x, y)| *x += y);
    }
    Ok(())
}

/// The model's temperature, `n` samples at `dt`.
pub fn temperature(
    t: &TemperatureModel,
    sampling: &Sampling,
    n: usize,
    seed: u64,
) -> Result<Vec<f64>, TwinError> {
    let mut v = noise(&t.noise, sampling, n, mix(seed, 0x7E, 0, 0))?;
    let dt = sampling.dt_s;
    for (k, x) in v.iter_mut().enumerate() {
        let s = k as f64 * dt;
        *x += t.start_c + t.drift_c_per_h * s / 3600.0;
        for h in &t.harmonics {
            *x += h.amplitude_c * (std::f64::consts::TAU * s / h.period_s + h.phase_rad).sin();
        }
    }
    Ok(v)
}

/// Adds `sinusoids` and bias `steps` to `series` (sample k at k·`dt_s`).
fn add_deterministic(series: &mut [f64], sinusoids: &[Sinusoid], steps: &[BiasStep], dt_s: f64) {
    for (k, x) in series.iter_mut().enumerate() {
        let t = k as f64 * dt_s;
        *x += sinusoids.iter().map(|s| s.at(t)).sum::<f64>();
        *x += steps
            .iter()
            .filter(|b| t >= b.at_s)
            .map(|b| b.size)
            .sum::<f64>();
    }
}

/// The temperature the play uses: the one given (its first `n` samples), else the model's own temperature played,
/// else none — an error if the model's thermal coefficients would need one.
fn played_temperature(
    model: &ClusterModel,
    opts: &PlayOptions,
    sampling: &Sampling,
    n: usize,
) -> Result<Option<Vec<f64>>, TwinError> {
    let thermal = !opts.without_effects
        && model
            .axes
            .iter()
            .any(|a| a.sensors.iter().any(|s| s.thermal_per_c != 0.0));
    match (&opts.temperature, &model.temperature) {
        (Some(t), _) if t.len() >= n => Ok(Some(t[..n].to_vec())),
        (Some(t), _) => Err(TwinError::Invalid(format!(
            "the temperature given has {} samples, {n} are played",
            t.len()
        ))),
        (None, Some(m)) => Ok(Some(temperature(m, sampling, n, opts.seed)?)),
        (None, None) if thermal => Err(TwinError::Invalid(
            "the model has thermal coefficients but no temperature: give one (--temperature-from)"
                .into(),
        )),
        (None, None) => Ok(None),
    }
}

/// Plays `model` (see the module docs).
pub fn play(model: &ClusterModel, opts: &PlayOptions) -> Result<Recording, TwinError> {
    model.validate()?;
    let rate = opts.rate_hz.unwrap_or(model.record.rate_hz);
    let n = opts.samples.unwrap_or(model.record.samples);
    if n < 2 {
        return Err(TwinError::Invalid(format!(
            "{n} samples: at least two are needed"
        )));
    }
    let sampling =
        Sampling::new(rate, n as f64 / rate).map_err(|e| TwinError::Invalid(e.to_string()))?;
    let temp = played_temperature(model, opts, &sampling, n)?;
    let t_ref = model.temperature.as_ref().map_or(0.0, |t| t.reference_c);
    let mut columns = Vec::new();
    for (ai, axis) in model.axes.iter().enumerate() {
        let (kind, ax) = axis
            .kind_axis()
            .ok_or_else(|| TwinError::Invalid(format!("axis {}", axis.axis)))?;
        let shared: Vec<(Vec<f64>, &SharedProcess)> = if opts.without_effects {
            Vec::new()
        } else {
            axis.shared
                .iter()
                .enumerate()
                .map(|(pi, p)| {
                    let mut series = noise(
                        &p.terms,
                        &sampling,
                        n,
                        mix(opts.seed, 1 + ai as u64, 1000 + pi as u64, 0),
                    )?;
                    add_deterministic(&mut series, &p.sinusoids, &[], sampling.dt_s);
                    Ok((series, p))
                })
                .collect::<Result<_, TwinError>>()?
        };
        let shared_gm: Vec<(Vec<f64>, &SharedProcess)> = shared
            .iter()
            .enumerate()
            .filter(|(_, (_, p))| !p.terms.gauss_markov.is_empty())
            .map(|(pi, (_, p))| {
                let mut series = vec![0.0; n];
                let seed = mix(opts.seed, 1 + ai as u64, 1000 + pi as u64, 2);
                add_gauss_markov(&mut series, &p.terms.gauss_markov, &sampling, seed)?;
                Ok((series, *p))
            })
            .collect::<Result<_, TwinError>>()?;
        for s in &axis.sensors {
            let own = if opts.without_effects {
                &axis.typical
            } else {
                &s.independent
            };
            let mut data = noise(
                own,
                &sampling,
                n,
                mix(opts.seed, 1 + ai as u64, s.group as u64, 1),
            )?;
            data.iter_mut().for_each(|x| *x += s.mean);
            for (series, p) in &shared {
                if p.groups.contains(&s.group) {
                    data.iter_mut().zip(series).for_each(|(x, y)| *x += y);
                }
            }
            if !opts.without_effects {
                add_deterministic(&mut data, &s.sinusoids, &s.steps, sampling.dt_s);
            }
            if let (false, Some(t)) = (opts.without_effects, &temp)
                && s.thermal_per_c != 0.0
            {
                data.iter_mut()
                    .zip(t)
                    .for_each(|(x, t)| *x += s.thermal_per_c * (t - t_ref));
            }
            // The sensor's bandwidth is part of its noise model (the √N model's too), not an effect.
            if let Some(l) = axis.low_pass(rate) {
                l.filter(&mut data);
            }
            // Gauss–Markov terms are of the output: after the filter (`NoiseTerms::gauss_markov`).
            let seed = mix(opts.seed, 1 + ai as u64, s.group as u64, 2);
            add_gauss_markov(&mut data, &own.gauss_markov, &sampling, seed)?;
            for (series, p) in &shared_gm {
                if p.groups.contains(&s.group) {
                    data.iter_mut().zip(series).for_each(|(x, y)| *x += y);
                }
            }
            columns.push(Column {
                group: s.group,
                kind,
                axis: ax,
                data,
            });
        }
    }
    columns.sort_by_key(|c| (c.kind, c.group, c.axis));
    Ok(Recording {
        t_s: (0..n).map(|k| k as f64 / rate).collect(),
        temp_c: temp,
        columns,
    })
}

/// `rec` as an FPGA frame log at `decimation`: each group's rates and specific forces through the board's nominal
/// calibration into ADC codes (rounded: the ADC's quantisation is added), the temperature in 0.01 °C. Needs the
/// board's 16 groups with all six axes.
pub fn frames(rec: &Recording, decimation: u16) -> Result<Vec<u8>, TwinError> {
    use shared::calib::board::nominal_codes;
    use shared::wire::FrameRepr;
    use shared::wire::frame::{FRAME_LEN, GROUPS, RAW_PER_GROUP};
    let col =
        |kind: SensorKind, g: usize, a: usize| rec.find(kind, g, a).map(|c| c.data.as_slice());
    let mut cols = Vec::with_capacity(GROUPS);
    for g in 0..GROUPS {
        let axes: Option<Vec<&[f64]>> = [SensorKind::Gyro, SensorKind::Accel]
            .iter()
            .flat_map(|&k| (0..3).map(move |a| (k, a)))
            .map(|(k, a)| col(k, g, a))
            .collect();
        cols.push(axes.ok_or_else(|| {
            TwinError::Invalid(format!(
                "a frame log needs the board's {GROUPS} groups with all six axes (group {g} is missing one): write a .csv"
            ))
        })?);
    }
    let n = rec.len();
    let mut out = Vec::with_capacity(n * FRAME_LEN);
    for i in 0..n {
        let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
        for (r, c) in raw.iter_mut().zip(&cols) {
            let v = |a: usize| c[a].get(i).copied().unwrap_or(0.0);
            let codes = nominal_codes([v(0), v(1), v(2)], [v(3), v(4), v(5)]);
            for (x, code) in r.iter_mut().zip(codes) {
                *x = code.round().clamp(0.0, f64::from(u16::MAX)) as u16;
            }
        }
        let temp_cdeg = rec
            .temp_c
            .as_ref()
            .and_then(|t| t.get(i))
            .filter(|t| t.is_finite())
            .map(|t| {
                (t * 100.0)
                    .round()
                    .clamp(f64::from(i16::MIN), f64::from(i16::MAX)) as i16
            });
        let f = FrameRepr {
            seq: i as u16,
            decimation,
            temp_cdeg,
            raw,
        };
        out.extend_from_slice(&f.to_bytes());
    }
    Ok(out)
}
