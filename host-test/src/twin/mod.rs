//! The cluster's twin: the model the diagnosis fits to a recording ([`fit()`]), written as a versioned TOML file
//! (`docs/twin.md`), played back as a synthetic recording of the same cluster ([`play()`]), and the sim-to-real gap
//! measured directly between two recordings ([`compare()`]).
//!
//! The model is what the diagnosis found, in the simulator's terms: per sensor and axis its own (independent)
//! noise terms and mean, its thermal coefficient; per axis the processes shared by several sensors; and a model of
//! the board temperature. The noise terms are the IEEE Std 952 ones the diagnosis fits (quantisation Q, white N,
//! bias instability B, rate random walk K, ramp R), in physical units, so that a reader can check them against a
//! datasheet.

pub mod compare;
pub mod coverage;
pub mod fit;
mod levels;
pub mod play;
pub mod terms_fit;

use crate::allan::noisefit::FLICKER_AVAR;
use crate::recording::SensorKind;
use serde::{Deserialize, Serialize};
use std::path::Path;

pub use compare::{CompareOptions, Comparison, compare};
pub use fit::fit;
pub use play::{PlayOptions, play};

/// The format tag of a model file; a file with another tag is refused.
pub const FORMAT: &str = "imu-cluster-twin/3";
/// The first format, still read: format 2 added the sensors' and shared processes' sinusoids and the sensors'
/// bias steps (a format-1 file has none).
pub const FORMAT_1: &str = "imu-cluster-twin/1";
/// The second format, still read: format 3 added the narrow-band Gauss–Markov terms (`freq_hz`; a format-2 file
/// has none, and a format-2 reader would play them as first-order terms, hence the new tag).
pub const FORMAT_2: &str = "imu-cluster-twin/2";

/// Why a model could not be fitted, read, written or played.
#[derive(Debug, thiserror::Error)]
pub enum TwinError {
    /// The file could not be read or written.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The file is not a model of this format.
    #[error("{path}: not a cluster model: {reason}")]
    Format {
        /// The file.
        path: String,
        /// Why.
        reason: String,
    },
    /// The inputs cannot give a model or a recording.
    #[error("{0}")]
    Invalid(String),
    /// A plot was not drawn.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
}

/// The noise terms of one sensor axis or shared process, in physical units (gyro °/s, accelerometer g): the five
/// IEEE Std 952 terms, up to [`GM_MAX`] first-order Gauss–Markov terms (the GMWM composite model's, for the bumps
/// real sensors show between the white and the flicker regions) and up to [`terms_fit::LINES_MAX`] narrow-band ones
/// (wandering lines).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct NoiseTerms {
    /// Quantisation Q, unit·s (Allan variance 3Q²/τ²).
    pub quantization: f64,
    /// White noise N, unit/√Hz (N²/τ): angle or velocity random walk.
    pub white: f64,
    /// Bias instability B, unit ((2 ln2/π)·B²).
    pub bias_instability: f64,
    /// Rate random walk K, unit/√s (K²τ/3).
    pub random_walk: f64,
    /// Ramp R, unit/s (R²τ²/2).
    pub ramp: f64,
    /// Gauss–Markov terms, first-order (AR(1) at any sampling) or narrow-band, of the output: they are played after
    /// the axis's bandwidth, and their Allan variance is the sampled process's, exactly.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub gauss_markov: Vec<GaussMarkov>,
}

/// Most first-order Gauss–Markov terms a fit gives one curve.
pub const GM_MAX: usize = 2;

/// A first-order Gauss–Markov process: stationary standard deviation `sigma` (unit) and correlation time `tau_s`;
/// sampled every τ₀ it is the AR(1) `x_{k+1} = φ·x_k + w_k`, `φ = exp(−τ₀/T)`, `var w = σ²(1 − φ²)` (exact).
/// With a frequency `freq_hz` > 0 it is the **narrow-band** form, a line whose amplitude and phase wander with
/// correlation time T (autocovariance `σ²·e^{−|t|/T}·cos 2πft`; the real part of the complex AR(1) with
/// `φ = exp(−τ₀/T + 2πi·f·τ₀)`, exact: `sim::noise::add_line`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GaussMarkov {
    /// Stationary standard deviation σ, unit.
    pub sigma: f64,
    /// Correlation time T, s.
    pub tau_s: f64,
    /// Centre frequency f of the narrow-band form, Hz; 0 (the default, not written) for the first-order process.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub freq_hz: f64,
}

fn is_zero(x: &f64) -> bool {
    *x == 0.0
}

impl GaussMarkov {
    /// Allan variance at `tau_s` of the process point-sampled every `tau0_s` (`sim::noise::ar1_avar`, or
    /// `sim::noise::line_avar` for the narrow-band form).
    pub fn avar(&self, tau_s: f64, tau0_s: f64) -> f64 {
        line_basis(self.tau_s, self.freq_hz, tau_s, tau0_s) * self.sigma * self.sigma
    }

    /// The same process (correlation time and frequency) as `other`.
    pub fn same_process(&self, other: &GaussMarkov) -> bool {
        (other.tau_s / self.tau_s - 1.0).abs() < 1e-9
            && (other.freq_hz - self.freq_hz).abs() <= 1e-9 * self.freq_hz
    }

    fn is_valid(&self) -> bool {
        self.sigma.is_finite()
            && self.sigma >= 0.0
            && self.tau_s.is_finite()
            && self.tau_s > 0.0
            && self.freq_hz.is_finite()
            && self.freq_hz >= 0.0
    }
}

/// Allan variance per unit variance of a Gauss–Markov process of correlation time `t_s`, point-sampled every
/// `tau0_s`, at `tau_s` (`m = τ/τ₀` samples per average).
pub fn gm_basis(t_s: f64, tau_s: f64, tau0_s: f64) -> f64 {
    crate::sim::noise::ar1_avar(1.0, tau0_s / t_s, (tau_s / tau0_s).max(1.0))
}

/// [`gm_basis`] of the narrow-band form at `freq_hz` (the first-order one at 0).
pub fn line_basis(t_s: f64, freq_hz: f64, tau_s: f64, tau0_s: f64) -> f64 {
    if freq_hz == 0.0 {
        return gm_basis(t_s, tau_s, tau0_s);
    }
    let theta = std::f64::consts::TAU * freq_hz * tau0_s;
    crate::sim::noise::line_avar(1.0, tau0_s / t_s, theta, (tau_s / tau0_s).max(1.0))
}

impl NoiseTerms {
    /// From the Allan-variance coefficients `[3Q², N², (2 ln2/π)B², K²/3, R²/2]` (negative ones count as 0); no
    /// Gauss–Markov term.
    pub fn from_avar_coefficients(c: [f64; 5]) -> Self {
        let c = c.map(|x| x.max(0.0));
        Self {
            quantization: (c[0] / 3.0).sqrt(),
            white: c[1].sqrt(),
            bias_instability: (c[2] / FLICKER_AVAR).sqrt(),
            random_walk: (3.0 * c[3]).sqrt(),
            ramp: (2.0 * c[4]).sqrt(),
            gauss_markov: Vec::new(),
        }
    }

    /// The five terms' Allan-variance coefficients (inverse of [`Self::from_avar_coefficients`]).
    pub fn avar_coefficients(&self) -> [f64; 5] {
        [
            3.0 * self.quantization.powi(2),
            self.white.powi(2),
            FLICKER_AVAR * self.bias_instability.powi(2),
            self.random_walk.powi(2) / 3.0,
            self.ramp.powi(2) / 2.0,
        ]
    }

    /// The Allan variance at `tau_s` of these terms sampled every `tau0_s`, the white term seen through
    /// `low_pass` when there is one (its factor [`LowPass::white_factor`](crate::allan::noisefit::LowPass::white_factor)).
    pub fn avar(
        &self,
        tau_s: f64,
        tau0_s: f64,
        low_pass: Option<&crate::allan::noisefit::LowPass>,
    ) -> f64 {
        let b = basis(tau_s, low_pass);
        let five: f64 = self
            .avar_coefficients()
            .iter()
            .zip(b)
            .map(|(c, b)| c * b)
            .sum();
        five + self
            .gauss_markov
            .iter()
            .map(|g| g.avar(tau_s, tau0_s))
            .sum::<f64>()
    }

    /// These terms less `other`'s, term by term in Allan variance, none below zero (a Gauss–Markov term less one of
    /// `other`'s at the same correlation time; `other`'s others are not subtracted).
    pub fn less(&self, other: &NoiseTerms) -> NoiseTerms {
        let (a, b) = (self.avar_coefficients(), other.avar_coefficients());
        let mut d = Self::from_avar_coefficients([0, 1, 2, 3, 4].map(|k| a[k] - b[k]));
        d.gauss_markov = self
            .gauss_markov
            .iter()
            .map(|g| {
                let same = other
                    .gauss_markov
                    .iter()
                    .filter(|o| g.same_process(o))
                    .map(|o| o.sigma * o.sigma)
                    .sum::<f64>();
                GaussMarkov {
                    sigma: (g.sigma * g.sigma - same).max(0.0).sqrt(),
                    ..*g
                }
            })
            .filter(|g| g.sigma > 0.0)
            .collect();
        d
    }

    /// These terms scaled by `q` in Allan variance (every level by `√q`).
    pub fn scaled(&self, q: f64) -> NoiseTerms {
        self.by_term_factors(&[q; 5])
    }

    /// These terms scaled term by term in Allan variance: `f` holds the factors of the quantisation, white,
    /// flicker (with every Gauss–Markov term, first-order or narrow-band), random-walk and ramp terms (negative ones
    /// count as 0).
    pub fn by_term_factors(&self, f: &[f64; 5]) -> NoiseTerms {
        let c = self.avar_coefficients();
        let mut t = Self::from_avar_coefficients([0, 1, 2, 3, 4].map(|k| c[k] * f[k].max(0.0)));
        t.gauss_markov = self
            .gauss_markov
            .iter()
            .map(|g| GaussMarkov {
                sigma: g.sigma * f[2].max(0.0).sqrt(),
                ..*g
            })
            .collect();
        t
    }

    fn is_valid(&self) -> bool {
        [
            self.quantization,
            self.white,
            self.bias_instability,
            self.random_walk,
            self.ramp,
        ]
        .iter()
        .all(|x| x.is_finite() && *x >= 0.0)
            && self.gauss_markov.iter().all(GaussMarkov::is_valid)
    }
}

/// The Allan-variance basis of the five terms at `tau_s` (`diagnose::model::Terms::basis`), the white term's through
/// `low_pass` when there is one.
pub fn basis(tau_s: f64, low_pass: Option<&crate::allan::noisefit::LowPass>) -> [f64; 5] {
    let mut b = crate::diagnose::model::Terms::basis(tau_s);
    if let Some(l) = low_pass {
        b[1] *= l.white_factor(tau_s);
    }
    b
}

/// What was recorded.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RecordInfo {
    /// The file the model was fitted to.
    pub source: String,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// Samples.
    pub samples: usize,
    /// Duration, s.
    pub duration_s: f64,
    /// Groups present (0-based).
    pub groups: Vec<usize>,
    /// Sensor columns, in the interchange CSV's names (`g00x`, …).
    pub columns: Vec<String>,
}

/// One sensor of one axis.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SensorModel {
    /// Group (0-based).
    pub group: usize,
    /// Mean over the record, unit (bias plus whatever the board saw, e.g. gravity or Earth rate).
    pub mean: f64,
    /// Its own noise: what remains of its fitted terms once the shared processes are taken out.
    pub independent: NoiseTerms,
    /// Thermal coefficient, unit/°C, about the temperature model's reference (0 without a thermal effect).
    pub thermal_per_c: f64,
    /// Its own sinusoidal interference (`periodic` on one sensor).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sinusoids: Vec<Sinusoid>,
    /// Steps of its bias (`bias_step`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub steps: Vec<BiasStep>,
}

/// A sinusoid, `amplitude · sin(2π·t / period_s + phase_rad)` with t from the record's first sample, unit.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Sinusoid {
    /// Period, s.
    pub period_s: f64,
    /// Amplitude, unit.
    pub amplitude: f64,
    /// Phase at t = 0, rad.
    pub phase_rad: f64,
}

impl Sinusoid {
    /// Its value at `t_s`.
    pub fn at(&self, t_s: f64) -> f64 {
        self.amplitude * (std::f64::consts::TAU * t_s / self.period_s + self.phase_rad).sin()
    }

    fn is_valid(&self) -> bool {
        self.period_s.is_finite()
            && self.period_s > 0.0
            && self.amplitude.is_finite()
            && self.phase_rad.is_finite()
    }
}

/// A step of a sensor's bias: `size` added from `at_s` (from the record's first sample) on.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct BiasStep {
    /// Time of the step, s.
    pub at_s: f64,
    /// Size, unit.
    pub size: f64,
}

/// A process that several sensors of one axis share (the same realisation added to each).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct SharedProcess {
    /// The effect it models: `common_mode`, `block_common_mode`, `common_mode_drift` or `periodic`.
    pub kind: String,
    /// Groups that share it.
    pub groups: Vec<usize>,
    /// Its terms.
    pub terms: NoiseTerms,
    /// Sinusoids in it (`periodic`, shared).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sinusoids: Vec<Sinusoid>,
}

/// One axis of the cluster.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct AxisModel {
    /// `gx`, …, `az`.
    pub axis: String,
    /// `deg/s` or `g`.
    pub unit: String,
    /// The typical sensor: the terms fitted to the sensors' mean Allan variance over their mean level factor
    /// (thermal part, steps and lines removed; `fit`), which the twin plays for every sensor without effects.
    pub typical: NoiseTerms,
    /// The effects the diagnosis kept on this axis.
    pub effects: Vec<String>,
    /// Every sensor.
    pub sensors: Vec<SensorModel>,
    /// Processes shared by several sensors.
    pub shared: Vec<SharedProcess>,
    /// The sensors' bandwidth, Hz: every sensor's output passes a single-pole low-pass filter at this cut-off (the
    /// diagnosis's `bandwidth_hz`, `noisefit::LowPass`), and the white terms above are those before the filter.
    /// Absent: no filter.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bandwidth_hz: Option<f64>,
    /// The fitted terms against the record's 68 % intervals ([`coverage`]), when the model was fitted here (not
    /// written to the file).
    #[serde(skip)]
    pub coverage: Option<coverage::Coverage>,
}

impl AxisModel {
    /// Sensor kind and axis index of `self.axis` (`None` for a name that is not `g`/`a` + `x`/`y`/`z`).
    pub fn kind_axis(&self) -> Option<(SensorKind, usize)> {
        parse_axis(&self.axis)
    }

    /// The axis's bandwidth as the filter at `rate_hz` (`None` without one).
    pub fn low_pass(&self, rate_hz: f64) -> Option<crate::allan::noisefit::LowPass> {
        self.bandwidth_hz.map(|f| crate::allan::noisefit::LowPass {
            cutoff_hz: f,
            tau0_s: 1.0 / rate_hz,
        })
    }
}

/// `gx` → (Gyro, 0).
pub fn parse_axis(name: &str) -> Option<(SensorKind, usize)> {
    let mut c = name.chars();
    let kind = match c.next()? {
        'g' => SensorKind::Gyro,
        'a' => SensorKind::Accel,
        _ => return None,
    };
    let ch = c.next()?;
    let axis = crate::recording::AXIS_NAMES.iter().position(|&a| a == ch)?;
    c.next().is_none().then_some((kind, axis))
}

/// A sinusoid of the temperature.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Harmonic {
    /// Period, s.
    pub period_s: f64,
    /// Amplitude, °C.
    pub amplitude_c: f64,
    /// Phase at the first sample, rad (`amplitude · sin(2π t / period + phase)`).
    pub phase_rad: f64,
}

/// The board temperature: `start + drift·t + Σ harmonics + noise`, t counted from the record's first sample,
/// fitted to the record's `temp_c`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TemperatureModel {
    /// The reference of the thermal coefficients (the record's mean temperature), °C.
    pub reference_c: f64,
    /// Value of the fitted line at the first sample, °C.
    pub start_c: f64,
    /// Linear drift, °C/h.
    pub drift_c_per_h: f64,
    /// Sinusoids, largest first.
    pub harmonics: Vec<Harmonic>,
    /// The rest, as noise terms in °C.
    pub noise: NoiseTerms,
}

/// An effect the diagnosis named (the fitted parameters live in the axes: shared processes, thermal coefficients,
/// the sensors' own terms).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EffectSummary {
    /// Kind, as the diagnosis names it.
    pub kind: String,
    /// `gyro` or `accel`.
    pub sensor: String,
    /// Axes, e.g. `xyz`.
    pub axes: String,
    /// τ range where it acts, s.
    pub tau_s: [f64; 2],
    /// Its largest share of the held-out cluster Allan variance.
    pub share: f64,
}

/// The fitted model of a cluster (see the module docs and `docs/twin.md`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ClusterModel {
    /// [`FORMAT`].
    pub format: String,
    /// The record it was fitted to.
    pub record: RecordInfo,
    /// The board temperature, if the record had one.
    pub temperature: Option<TemperatureModel>,
    /// The effects the diagnosis named.
    pub effects: Vec<EffectSummary>,
    /// Every axis with at least two sensors.
    pub axes: Vec<AxisModel>,
}

impl ClusterModel {
    /// The model as TOML.
    pub fn to_toml(&self) -> Result<String, TwinError> {
        toml::to_string(self).map_err(|e| TwinError::Invalid(format!("model to TOML: {e}")))
    }

    /// A model from TOML, checked ([`Self::validate`]).
    pub fn from_toml(text: &str, path: &str) -> Result<Self, TwinError> {
        let format = |reason: String| TwinError::Format {
            path: path.into(),
            reason,
        };
        let mut m: ClusterModel = toml::from_str(text).map_err(|e| format(e.to_string()))?;
        if m.format == FORMAT_1 || m.format == FORMAT_2 {
            m.format = FORMAT.into();
        }
        if m.format != FORMAT {
            return Err(format(format!(
                "format \"{}\", expected \"{FORMAT}\" (or \"{FORMAT_2}\", \"{FORMAT_1}\")",
                m.format
            )));
        }
        m.validate().map_err(|e| match e {
            TwinError::Invalid(reason) => format(reason),
            other => other,
        })?;
        Ok(m)
    }

    /// Writes the model to `path` (TOML).
    pub fn save(&self, path: &Path) -> Result<(), TwinError> {
        std::fs::write(path, self.to_toml()?).map_err(|source| TwinError::Io {
            path: path.display().to_string(),
            source,
        })
    }

    /// Reads a model from `path` (TOML).
    pub fn load(path: &Path) -> Result<Self, TwinError> {
        let text = std::fs::read_to_string(path).map_err(|source| TwinError::Io {
            path: path.display().to_string(),
            source,
        })?;
        Self::from_toml(&text, &path.display().to_string())
    }

    /// Checks what a hand-edited file could get wrong: positive rate and duration, finite non-negative terms,
    /// known axis names, sensors and shared processes on groups of the record.
    pub fn validate(&self) -> Result<(), TwinError> {
        let r = &self.record;
        if !(r.rate_hz.is_finite() && r.rate_hz > 0.0) {
            return Err(TwinError::Invalid(format!(
                "record.rate_hz = {} must be > 0",
                r.rate_hz
            )));
        }
        if !(r.duration_s.is_finite() && r.duration_s > 0.0) {
            return Err(TwinError::Invalid(format!(
                "record.duration_s = {} must be > 0",
                r.duration_s
            )));
        }
        for a in &self.axes {
            if a.kind_axis().is_none() {
                return Err(TwinError::Invalid(format!(
                    "axis \"{}\": expected gx … az",
                    a.axis
                )));
            }
            if let Some(f) = a.bandwidth_hz
                && !(f.is_finite() && f > 0.0)
            {
                return Err(TwinError::Invalid(format!(
                    "{}: bandwidth_hz = {f} must be > 0",
                    a.axis
                )));
            }
            let ok = |t: &NoiseTerms| t.is_valid();
            if !ok(&a.typical) {
                return Err(TwinError::Invalid(format!(
                    "{}: typical terms must be finite and ≥ 0",
                    a.axis
                )));
            }
            for s in &a.sensors {
                if !ok(&s.independent)
                    || !s.mean.is_finite()
                    || !s.thermal_per_c.is_finite()
                    || !s.sinusoids.iter().all(Sinusoid::is_valid)
                    || !s
                        .steps
                        .iter()
                        .all(|b| b.at_s.is_finite() && b.size.is_finite())
                {
                    return Err(TwinError::Invalid(format!(
                        "{} group {}: terms must be finite and ≥ 0, sinusoids and steps finite (periods > 0)",
                        a.axis, s.group
                    )));
                }
                if !r.groups.contains(&s.group) {
                    return Err(TwinError::Invalid(format!(
                        "{}: group {} is not in record.groups",
                        a.axis, s.group
                    )));
                }
            }
            for p in &a.shared {
                if !ok(&p.terms) || !p.sinusoids.iter().all(Sinusoid::is_valid) {
                    return Err(TwinError::Invalid(format!(
                        "{} {}: terms must be finite and ≥ 0, sinusoids finite (periods > 0)",
                        a.axis, p.kind
                    )));
                }
                if let Some(g) = p
                    .groups
                    .iter()
                    .find(|g| !a.sensors.iter().any(|s| s.group == **g))
                {
                    return Err(TwinError::Invalid(format!(
                        "{} {}: group {g} has no sensor on this axis",
                        a.axis, p.kind
                    )));
                }
            }
        }
        if let Some(t) = &self.temperature {
            let finite = [t.reference_c, t.start_c, t.drift_c_per_h]
                .iter()
                .all(|x| x.is_finite());
            let harmonics = t.harmonics.iter().all(|h| {
                h.period_s.is_finite()
                    && h.period_s > 0.0
                    && h.amplitude_c.is_finite()
                    && h.phase_rad.is_finite()
            });
            if !(finite && harmonics && t.noise.is_valid()) {
                return Err(TwinError::Invalid(
                    "temperature: values must be finite, periods > 0, noise terms ≥ 0".into(),
                ));
            }
        }
        Ok(())
    }
}

/// What [`close_the_loop`] found: the axes each twin does not reproduce, and the largest scan statistic.
#[derive(Clone, Debug, Serialize)]
pub struct LoopSummary {
    /// Effects the diagnosis named.
    pub effects: Vec<String>,
    /// Axes the twin with its effects does not reproduce.
    pub with_effects: Vec<String>,
    /// Its largest scan statistic.
    pub with_effects_scan: f64,
    /// Axes the twin without effects (the √N model) does not reproduce.
    pub without_effects: Vec<String>,
    /// Its largest scan statistic.
    pub without_effects_scan: f64,
    /// The scan threshold.
    pub threshold: f64,
    /// The fitted terms against the record's 68 % intervals, beside records played from the model
    /// ([`coverage::check`]).
    pub fit: coverage::FitCheck,
}

/// The sim-to-real loop on a recording already diagnosed: the model fitted and saved (`dir/model.toml`), its twin
/// played with and without effects (noise seed `seed`), each compared with the recording (`dir/compare-with.json`,
/// `dir/compare-without.json`, and the plot of the first, `dir/compare.png`); the fit checked against one record
/// played from the model per seed of `check_seeds` ([`coverage::check`], diagnosed with the default options, as
/// `report` must have been). What `ground demo` shows.
pub fn close_the_loop(
    rec: &crate::recording::Recording,
    report: &crate::diagnose::Report,
    source: &str,
    dir: &Path,
    seed: u64,
    check_seeds: &[u64],
) -> Result<LoopSummary, TwinError> {
    let io = |path: &Path| {
        let path = path.display().to_string();
        move |source| TwinError::Io { path, source }
    };
    std::fs::create_dir_all(dir).map_err(io(dir))?;
    let model = fit(rec, report, source)?;
    model.save(&dir.join("model.toml"))?;
    let mut out = Vec::new();
    for (without_effects, name) in [(false, "with"), (true, "without")] {
        let sim = play(
            &model,
            &PlayOptions {
                seed,
                without_effects,
                ..Default::default()
            },
        )?;
        let c = compare(rec, &sim, &CompareOptions::default())?;
        drop(sim);
        let path = dir.join(format!("compare-{name}.json"));
        let json =
            serde_json::to_string_pretty(&c).map_err(|e| TwinError::Invalid(e.to_string()))?;
        std::fs::write(&path, json).map_err(io(&path))?;
        if !without_effects {
            c.plot(&dir.join("compare.png"), &format!("{source} vs its twin"))?;
        }
        out.push(c);
    }
    let (with, without) = (&out[0], &out[1]);
    Ok(LoopSummary {
        effects: report
            .effects
            .iter()
            .map(|e| format!("{} {} {}", e.kind, e.sensor, e.axes))
            .collect(),
        with_effects: with.significant_axes.clone(),
        with_effects_scan: with.largest_scan().0,
        without_effects: without.significant_axes.clone(),
        without_effects_scan: without.largest_scan().0,
        threshold: with.largest_scan().1,
        fit: coverage::check(&model, check_seeds, &crate::diagnose::Options::default())?,
    })
}

#[cfg(test)]
mod tests;
