//! Command-line description of a simulation (`ground simulate`): presets and effect flags → [`SimConfig`], and
//! writing the result as a frame log or an interchange CSV.

use crate::sim::SimError;
use crate::sim::{
    Axis, CalSpread, Channel, Chunk, CommonDrift, CommonMode, DriftKind, FrameOpts, Outlier,
    PartSpread, Periodic, SimConfig, Simulator, Thermal, csv_header,
};
use std::io::Write;
use std::path::{Path, PathBuf};

/// Why a simulation's description or its output was refused.
#[derive(Debug, thiserror::Error)]
pub enum SimCliError {
    /// An option's value is malformed or out of range; the message names the option and the value.
    #[error("{0}")]
    Invalid(String),
    /// A number in an option's value does not parse: what was being read, and the parser's reason.
    #[error("{what}")]
    Number {
        /// The option and the value.
        what: String,
        /// The parser's reason.
        #[source]
        source: NumberError,
    },
    /// The simulator refused the configuration.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The output file could not be created or written.
    #[error("{what} {}", path.display())]
    Io {
        /// `creating` or `writing`.
        what: &'static str,
        /// The output file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// A number that does not parse.
#[derive(Debug, thiserror::Error)]
pub enum NumberError {
    /// An integer (a group).
    #[error(transparent)]
    Int(#[from] std::num::ParseIntError),
    /// A real number.
    #[error(transparent)]
    Float(#[from] std::num::ParseFloatError),
}

/// The result of this module's functions.
pub type Result<T, E = SimCliError> = std::result::Result<T, E>;

/// Refuses with a message (an option's value malformed or out of range).
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err(SimCliError::Invalid(format!($($arg)*)))
    };
}

/// What was being read when a value was missing (`Option`) or did not parse (a number's `Result`).
trait Context<T> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T>;
    fn context(self, what: &str) -> Result<T>
    where
        Self: Sized,
    {
        self.with_context(|| what.to_string())
    }
}

impl<T> Context<T> for Option<T> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T> {
        self.ok_or_else(|| SimCliError::Invalid(what()))
    }
}

impl<T, E: Into<NumberError>> Context<T> for std::result::Result<T, E> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| SimCliError::Number {
            what: what(),
            source: e.into(),
        })
    }
}

/// Parses axes: `gyro`, `accel`, `all`, or a comma list of `gx gy gz ax ay az`.
pub fn parse_axes(s: &str) -> Result<Vec<Axis>> {
    let all = Axis::ALL;
    Ok(match s {
        "gyro" => all[..3].to_vec(),
        "accel" => all[3..].to_vec(),
        "all" => all.to_vec(),
        list => list
            .split(',')
            .map(|a| {
                all.iter()
                    .copied()
                    .find(|x| x.short() == a.trim())
                    .with_context(|| {
                        format!("unknown axis '{a}' (gx gy gz ax ay az, gyro, accel, all)")
                    })
            })
            .collect::<Result<_>>()?,
    })
}

/// Parses a group list `0,3,5-7`.
pub fn parse_groups(s: &str) -> Result<Vec<usize>> {
    let mut out = Vec::new();
    for part in s.split(',') {
        match part.split_once('-') {
            Some((a, b)) => {
                let (a, b): (usize, usize) = (
                    a.trim()
                        .parse()
                        .with_context(|| format!("bad group '{a}' in '{part}'"))?,
                    b.trim()
                        .parse()
                        .with_context(|| format!("bad group '{b}' in '{part}'"))?,
                );
                if b < a {
                    bail!("bad group range '{part}': the end is below the start");
                }
                out.extend(a..=b);
            }
            None => out.push(
                part.trim()
                    .parse()
                    .with_context(|| format!("bad group '{part}'"))?,
            ),
        }
    }
    Ok(out)
}

fn parse_channel(s: &str) -> Result<Channel> {
    Ok(match s {
        "gx" => Channel::GyroAX,
        "gy" => Channel::GyroBY,
        "gaz" | "gz" => Channel::GyroAZ,
        "gbz" => Channel::GyroBZ,
        "ax" => Channel::AccelX,
        "ay" => Channel::AccelY,
        "az" => Channel::AccelZ,
        _ => bail!("unknown channel '{s}' (gx gy gaz gbz ax ay az)"),
    })
}

fn nums(s: &str, what: &str, n: std::ops::RangeInclusive<usize>) -> Result<Vec<f64>> {
    let v: Vec<f64> = s
        .split(':')
        .map(|x| x.trim().parse::<f64>())
        .collect::<Result<_, _>>()
        .with_context(|| format!("{what}: '{s}' is not a list of numbers"))?;
    if !n.contains(&v.len()) {
        bail!(
            "{what}: expected {} to {} numbers separated by ':', found '{s}'",
            n.start(),
            n.end()
        );
    }
    Ok(v)
}

/// Temperature at which a simulated part's thermal bias term is zero, °C (the board's bias law does not depend on
/// the temperature profile of a record, so that records of one board under different profiles agree).
pub const PART_REF_C: f64 = 20.0;

/// The board temperature and thermal coefficients before any `--thermal` / `--temperature`: no coefficient, 20 °C
/// ± 2 °C over 2 h plus 1 °C/h.
const DEFAULT_THERMAL: Thermal = Thermal {
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

/// A board temperature profile of `--temperature`.
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

/// Parses a `--temperature` profile: `orbit:mean_c=M,amp_c=A,period_min=P`, `ramp:from_c=A,to_c=B,hours=H` or
/// `constant:c=C` (every key once, none other; temperatures within ±150 °C).
pub fn parse_temperature(s: &str) -> Result<TemperatureProfile> {
    const FORMS: &str =
        "orbit:mean_c=M,amp_c=A,period_min=P, ramp:from_c=A,to_c=B,hours=H or constant:c=C";
    let (kind, rest) = s
        .split_once(':')
        .with_context(|| format!("--temperature '{s}': expected {FORMS}"))?;
    let keys: &[&str] = match kind {
        "orbit" => &["mean_c", "amp_c", "period_min"],
        "ramp" => &["from_c", "to_c", "hours"],
        "constant" => &["c"],
        _ => bail!("--temperature '{s}': unknown profile '{kind}' (expected {FORMS})"),
    };
    let mut vals = vec![None; keys.len()];
    for kv in rest.split(',') {
        let (k, v) = kv
            .split_once('=')
            .with_context(|| format!("--temperature '{s}': '{kv}' is not KEY=VALUE"))?;
        let i = keys.iter().position(|x| *x == k.trim()).with_context(|| {
            format!(
                "--temperature '{s}': unknown key '{k}' for {kind} (keys: {})",
                keys.join(", ")
            )
        })?;
        let x: f64 = v
            .trim()
            .parse()
            .with_context(|| format!("--temperature '{s}': {k} = '{v}' is not a number"))?;
        if !x.is_finite() {
            bail!("--temperature '{s}': {k} must be finite");
        }
        if vals[i].replace(x).is_some() {
            bail!("--temperature '{s}': {k} given twice");
        }
    }
    let mut v = [0.0; 3];
    for ((slot, val), k) in v.iter_mut().zip(&vals).zip(keys) {
        *slot =
            val.with_context(|| format!("--temperature '{s}': {k} missing (expected {FORMS})"))?;
    }
    let temp_ok = |x: f64| (-150.0..=150.0).contains(&x);
    let p = match kind {
        "orbit" => TemperatureProfile::Orbit {
            mean_c: v[0],
            amp_c: v[1],
            period_min: v[2],
        },
        "ramp" => TemperatureProfile::Ramp {
            from_c: v[0],
            to_c: v[1],
            hours: v[2],
        },
        _ => TemperatureProfile::Constant { c: v[0] },
    };
    match p {
        TemperatureProfile::Orbit {
            mean_c,
            amp_c,
            period_min,
        } => {
            if amp_c < 0.0 || period_min <= 0.0 {
                bail!("--temperature '{s}': amp_c must be ≥ 0 and period_min > 0");
            }
            if !temp_ok(mean_c - amp_c) || !temp_ok(mean_c + amp_c) {
                bail!("--temperature '{s}': the cycle leaves −150 … 150 °C");
            }
        }
        TemperatureProfile::Ramp {
            from_c,
            to_c,
            hours,
        } => {
            if hours <= 0.0 {
                bail!("--temperature '{s}': hours must be > 0");
            }
            if !temp_ok(from_c) || !temp_ok(to_c) {
                bail!("--temperature '{s}': from_c and to_c must be within −150 … 150 °C");
            }
        }
        TemperatureProfile::Constant { c } => {
            if !temp_ok(c) {
                bail!("--temperature '{s}': c must be within −150 … 150 °C");
            }
        }
    }
    Ok(p)
}

/// The effect flags of `ground simulate`.
#[derive(Clone, Debug, Default, clap::Args)]
pub struct EffectArgs {
    /// Common-mode noise shared by all groups: AXES:RHO_WHITE[:RHO_FLICKER] (e.g. gyro:0.1:0.2).
    #[arg(long = "common-mode")]
    pub common_mode: Vec<String>,
    /// Noise shared within a block of groups: GROUPS/AXES:RHO_WHITE[:RHO_FLICKER] (e.g. 0-3/gyro:0.5).
    #[arg(long)]
    pub block: Vec<String>,
    /// Shared slow drift (random walk of the bias) of all groups: AXES:K (K in (°/s)/√s or g/√s).
    #[arg(long)]
    pub drift: Vec<String>,
    /// One sensor's own slow drift (random walk of its bias), not shared: GROUP/AXES:K (K in (°/s)/√s or g/√s),
    /// e.g. 7/ay:2e-6. (A bias step on one sensor: `--outlier GROUP:CHANNEL:1:STEP:STEP_AT_S`.)
    #[arg(long = "sensor-drift")]
    pub sensor_drift: Vec<String>,
    /// A sinusoidal interference A·sin(2πt/P): [GROUP/]AXES:AMPLITUDE:PERIOD_S (amplitude in °/s or g); without
    /// GROUP/ every group (common mode), e.g. gx:2e-4:600; with it one group's own, e.g. 7/ay:1e-4:90.
    #[arg(long)]
    pub periodic: Vec<String>,
    /// A sensor's bandwidth, a single-pole low-pass response on its whole output (noise included, unit gain at
    /// DC): [GROUP/]AXES:HZ, e.g. gyro:8 (every group's gyros) or 3/gx:4; `y_k = φ y_{k−1} + (1 − φ) x_k`,
    /// φ = exp(−2π·HZ/rate). CSV output only.
    #[arg(long = "bandwidth-hz")]
    pub bandwidth_hz: Vec<String>,
    /// Temperature-driven bias of each raw channel: AXES:COEF[:SD], COEF in (°/s)/°C or g/°C, SD the spread between
    /// parts (repeatable: gyro and accel together); zero at 20 °C; board temperature from --temperature, else
    /// 20 °C ± 2 °C over 2 h plus 1 °C/h.
    #[arg(long)]
    pub thermal: Vec<String>,
    /// Board temperature profile (frames carry it): `orbit:mean_c=M,amp_c=A,period_min=P` (a sinusoid),
    /// `ramp:from_c=A,to_c=B,hours=H` (linear, then held at B) or `constant:c=C`.
    #[arg(long, value_parser = parse_temperature)]
    pub temperature: Option<TemperatureProfile>,
    /// A bad sensor: GROUP:CHANNEL:NOISE_FACTOR[:STEP:STEP_AT_S] (channels gx gy gaz gbz ax ay az).
    #[arg(long)]
    pub outlier: Vec<String>,
    /// Unequal parts: log-sd of a lognormal factor on each sensor's noise levels.
    #[arg(long, default_value_t = 0.0)]
    pub unequal: f64,
    /// Per-part calibration errors (scale, misalignment, bias) of a typical uncalibrated board.
    #[arg(long)]
    pub cal_spread: bool,
}

impl EffectArgs {
    /// Whether any effect was asked for.
    pub fn any(&self) -> bool {
        !(self.common_mode.is_empty()
            && self.block.is_empty()
            && self.drift.is_empty()
            && self.sensor_drift.is_empty()
            && self.periodic.is_empty()
            && self.bandwidth_hz.is_empty()
            && self.thermal.is_empty()
            && self.temperature.is_none()
            && self.outlier.is_empty()
            && self.unequal == 0.0
            && !self.cal_spread)
    }

    /// Adds the effects to `cfg`.
    pub fn apply(&self, cfg: &mut SimConfig) -> Result<()> {
        for s in &self.common_mode {
            let (axes, rest) = s
                .split_once(':')
                .context("--common-mode AXES:RHO_WHITE[:RHO_FLICKER]")?;
            let r = nums(rest, "--common-mode", 1..=2)?;
            cfg.common.push(CommonMode::all(
                &parse_axes(axes)?,
                r[0],
                r.get(1).copied().unwrap_or(0.0),
            ));
        }
        for (i, s) in self.block.iter().enumerate() {
            let (groups, rest) = s
                .split_once('/')
                .context("--block GROUPS/AXES:RHO_WHITE[:RHO_FLICKER]")?;
            let (axes, rest) = rest
                .split_once(':')
                .context("--block GROUPS/AXES:RHO_WHITE[:RHO_FLICKER]")?;
            let r = nums(rest, "--block", 1..=2)?;
            cfg.common.push(CommonMode::block(
                &format!("block {i}"),
                &parse_groups(groups)?,
                &parse_axes(axes)?,
                r[0],
                r.get(1).copied().unwrap_or(0.0),
            ));
        }
        for s in &self.drift {
            let (axes, rest) = s.split_once(':').context("--drift AXES:K")?;
            let k = nums(rest, "--drift", 1..=1)?[0];
            cfg.drift.push(CommonDrift {
                groups: None,
                axes: parse_axes(axes)?,
                kind: DriftKind::RandomWalk { k },
            });
        }
        for s in &self.sensor_drift {
            let (group, rest) = s.split_once('/').context("--sensor-drift GROUP/AXES:K")?;
            let (axes, rest) = rest
                .split_once(':')
                .context("--sensor-drift GROUP/AXES:K")?;
            let k = nums(rest, "--sensor-drift", 1..=1)?[0];
            cfg.drift.push(CommonDrift {
                groups: Some(vec![
                    group
                        .parse()
                        .with_context(|| format!("--sensor-drift group '{group}'"))?,
                ]),
                axes: parse_axes(axes)?,
                kind: DriftKind::RandomWalk { k },
            });
        }
        for s in &self.periodic {
            cfg.periodic.push(parse_periodic(s)?);
        }
        for s in &self.thermal {
            let (axes, rest) = s.split_once(':').context("--thermal AXES:COEF[:SD]")?;
            let v = nums(rest, "--thermal", 1..=2)?;
            let t = cfg.thermal.get_or_insert(DEFAULT_THERMAL);
            for a in parse_axes(axes)? {
                t.coef[a.index()] = v[0];
                t.coef_sd[a.index()] = v.get(1).copied().unwrap_or(0.0);
            }
        }
        if let Some(p) = self.temperature {
            p.apply(cfg.thermal.get_or_insert(DEFAULT_THERMAL));
        }
        for s in &self.outlier {
            let parts: Vec<&str> = s.split(':').collect();
            if !(3..=5).contains(&parts.len()) {
                bail!("--outlier GROUP:CHANNEL:NOISE_FACTOR[:STEP:STEP_AT_S], found '{s}'");
            }
            let num = |i: usize| -> Result<f64> {
                parts.get(i).map_or(Ok(0.0), |p| {
                    p.parse::<f64>()
                        .with_context(|| format!("--outlier: '{p}'"))
                })
            };
            cfg.outliers.push(Outlier {
                group: parts[0]
                    .parse()
                    .with_context(|| format!("--outlier group '{}'", parts[0]))?,
                channel: parse_channel(parts[1])?,
                noise_factor: num(2)?,
                step: num(3)?,
                step_at_s: num(4)?,
                drift_per_h: 0.0,
            });
        }
        if !(self.unequal.is_finite() && self.unequal >= 0.0) {
            bail!("--unequal must be a log-sd ≥ 0, found {}", self.unequal);
        }
        if self.unequal > 0.0 {
            cfg.spread = PartSpread::unequal_noise(self.unequal);
        }
        if self.cal_spread {
            cfg.cal = CalSpread::typical();
        }
        Ok(())
    }
}

/// One `--periodic [GROUP/]AXES:AMPLITUDE:PERIOD_S` (without GROUP/ every group).
fn parse_periodic(s: &str) -> Result<Periodic> {
    let usage = "--periodic [GROUP/]AXES:AMPLITUDE:PERIOD_S";
    let (groups, rest) = match s.split_once('/') {
        Some((g, rest)) => (
            Some(vec![
                g.parse()
                    .with_context(|| format!("--periodic group '{g}'"))?,
            ]),
            rest,
        ),
        None => (None, s),
    };
    let (axes, rest) = rest.split_once(':').context(usage)?;
    let v = nums(rest, "--periodic", 2..=2)?;
    if !(v[1].is_finite() && v[1] > 0.0) {
        bail!("{usage}: PERIOD_S must be > 0, found {}", v[1]);
    }
    Ok(Periodic {
        groups,
        axes: parse_axes(axes)?,
        amplitude: v[0],
        period_s: v[1],
        phase_rad: 0.0,
    })
}

/// A sensor's bandwidth: the groups (all when `None`) and axes whose output passes a single-pole low-pass filter at
/// `cutoff_hz` (`--bandwidth-hz`).
#[derive(Clone, Debug, PartialEq)]
pub struct Bandwidth {
    /// Groups (all when `None`).
    pub groups: Option<Vec<usize>>,
    /// Axes.
    pub axes: Vec<Axis>,
    /// Cut-off, Hz.
    pub cutoff_hz: f64,
}

impl EffectArgs {
    /// The `--bandwidth-hz [GROUP/]AXES:HZ` options.
    pub fn bandwidths(&self) -> Result<Vec<Bandwidth>> {
        self.bandwidth_hz
            .iter()
            .map(|s| parse_bandwidth(s))
            .collect()
    }
}

/// One `--bandwidth-hz [GROUP/]AXES:HZ`.
pub fn parse_bandwidth(s: &str) -> Result<Bandwidth> {
    let usage = "--bandwidth-hz [GROUP/]AXES:HZ";
    let (groups, rest) = match s.split_once('/') {
        Some((g, rest)) => (
            Some(
                parse_groups(g)
                    .map_err(|e| SimCliError::Invalid(format!("{usage}: groups '{g}': {e}")))?,
            ),
            rest,
        ),
        None => (None, s),
    };
    let (axes, rest) = rest.split_once(':').context(usage)?;
    let v = nums(rest, "--bandwidth-hz", 1..=1)?;
    if !(v[0].is_finite() && v[0] > 0.0) {
        bail!("{usage}: HZ must be a positive number, found {}", v[0]);
    }
    if let Some(g) = &groups
        && let Some(bad) = g.iter().find(|&&g| g >= crate::sim::GROUPS)
    {
        bail!("{usage}: group {bad} is not below {}", crate::sim::GROUPS);
    }
    Ok(Bandwidth {
        groups,
        axes: parse_axes(axes)?,
        cutoff_hz: v[0],
    })
}

/// The single-pole low-pass filters of a simulation's outputs ([`Bandwidth`]), applied to each chunk's physical
/// values in place as the simulation streams (state kept across chunks; the first sample starts the filter at its
/// own value, so a static record has no transient).
#[derive(Clone, Debug)]
pub struct BandwidthFilter {
    /// (group, axis index 0..6, pole φ, state).
    taps: Vec<(usize, usize, f64, Option<f64>)>,
}

impl BandwidthFilter {
    /// The filters at output rate `rate_hz` (a later option for the same group and axis replaces an earlier one).
    pub fn new(bands: &[Bandwidth], rate_hz: f64) -> Self {
        let mut taps: Vec<(usize, usize, f64, Option<f64>)> = Vec::new();
        for b in bands {
            let phi = crate::allan::noisefit::LowPass {
                cutoff_hz: b.cutoff_hz,
                tau0_s: 1.0 / rate_hz,
            }
            .pole();
            let groups: Vec<usize> = b
                .groups
                .clone()
                .unwrap_or_else(|| (0..crate::sim::GROUPS).collect());
            for &g in &groups {
                for a in &b.axes {
                    let ai = a.index();
                    taps.retain(|t| !(t.0 == g && t.1 == ai));
                    taps.push((g, ai, phi, None));
                }
            }
        }
        Self { taps }
    }

    /// Filters the chunk's physical values in place.
    pub fn apply(&mut self, chunk: &mut Chunk) {
        let len = chunk.len.min(chunk.phys.len());
        for (g, a, phi, state) in &mut self.taps {
            if *g >= crate::sim::GROUPS || *a >= 6 {
                continue;
            }
            for row in &mut chunk.phys[..len] {
                row[*g][*a] = crate::allan::noisefit::LowPass::step(*phi, state, row[*g][*a]);
            }
        }
    }
}

/// Writes a simulation to `path`: `.bin` frame log (raw ADC codes through the true calibration, the FPGA's wire
/// format) or `.csv` interchange CSV (physical values). `progress` gets the samples done.
pub fn write(cfg: SimConfig, path: &Path, progress: impl FnMut(u64)) -> Result<Simulator> {
    write_filtered(cfg, &[], path, progress)
}

/// [`write`] with the outputs' bandwidths (`--bandwidth-hz`, [`BandwidthFilter`]); CSV output only when any.
pub fn write_filtered(
    cfg: SimConfig,
    bands: &[Bandwidth],
    path: &Path,
    mut progress: impl FnMut(u64),
) -> Result<Simulator> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let csv = match ext.as_str() {
        "csv" => true,
        "bin" => false,
        _ => bail!(
            "{}: the output must end in .bin (frame log) or .csv (interchange CSV)",
            path.display()
        ),
    };
    if !csv && !bands.is_empty() {
        bail!(
            "--bandwidth-hz filters the physical values: write a .csv (the frame log's codes are made inside the simulator)"
        );
    }
    let with_temp = cfg.thermal.is_some();
    let mut filter = BandwidthFilter::new(bands, cfg.rate_hz);
    let mut sim = Simulator::new(cfg)?;
    let mut out = std::io::BufWriter::with_capacity(
        1 << 20,
        std::fs::File::create(path).map_err(|source| SimCliError::Io {
            what: "creating",
            path: path.to_path_buf(),
            source,
        })?,
    );
    let mut chunk = Chunk::default();
    let mut text = String::new();
    let mut run = || -> std::io::Result<()> {
        if csv {
            writeln!(out, "{}", csv_header(with_temp))?;
        }
        let mut done = 0u64;
        while sim.next_chunk(&mut chunk) > 0 {
            filter.apply(&mut chunk);
            for i in 0..chunk.len {
                if csv {
                    text.clear();
                    chunk.write_csv_row(i, &mut text);
                    out.write_all(text.as_bytes())?;
                } else if let Some(f) = chunk.frame(i) {
                    out.write_all(&f.to_bytes())?;
                }
            }
            done += chunk.len as u64;
            progress(done);
        }
        out.flush()
    };
    run().map_err(|source| SimCliError::Io {
        what: "writing",
        path: path.to_path_buf(),
        source,
    })?;
    Ok(sim)
}

/// Largest output `ground simulate` writes, bytes (estimated before it starts).
pub const MAX_OUTPUT_BYTES: f64 = 32e9;

/// Bytes per sample of a CSV output (96 values; the seed preset writes ≈ 920).
const CSV_ROW_BYTES: f64 = 1000.0;

/// Checks the rates of a simulation written to `out` (`.bin`: frame log, `.csv`): both positive and finite, the
/// output rate at most the FPGA base rate; for a frame log, a whole decimation of the base rate that a frame can
/// carry (16 bits) within 1 % of `rate_hz`. Returns whether the output is a frame log.
pub fn check_rates(out: &Path, rate_hz: f64, base_rate_hz: f64) -> Result<bool> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let frame_log = match ext.as_str() {
        "csv" => false,
        "bin" => true,
        _ => bail!(
            "{}: the output must end in .bin (frame log) or .csv (interchange CSV)",
            out.display()
        ),
    };
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        bail!("--rate must be a positive number of Hz, found {rate_hz}");
    }
    if !(base_rate_hz.is_finite() && base_rate_hz > 0.0) {
        bail!("--base-rate-hz must be a positive number of Hz, found {base_rate_hz}");
    }
    if rate_hz > base_rate_hz {
        bail!(
            "--rate {rate_hz} Hz is above the FPGA base rate {base_rate_hz} Hz (--base-rate-hz): the output rate is \
             the base rate divided by a whole number"
        );
    }
    if frame_log {
        let div = (base_rate_hz / rate_hz).round();
        let max_div = f64::from(u16::MAX) + 1.0;
        if div > max_div {
            bail!(
                "--rate {rate_hz} Hz is below the lowest rate of a frame log at {base_rate_hz} Hz: {base_rate_hz} / \
                 {max_div} = {} Hz (the decimation is a 16-bit field); write a .csv instead",
                base_rate_hz / max_div
            );
        }
        let actual = base_rate_hz / div;
        if (actual / rate_hz - 1.0).abs() > 0.01 {
            bail!(
                "--rate {rate_hz} Hz is not the base rate {base_rate_hz} Hz divided by a whole number (the nearest is \
                 {base_rate_hz} / {div} = {actual} Hz, {:.1} % off): the frames' times would disagree with the \
                 samples",
                100.0 * (actual / rate_hz - 1.0)
            );
        }
    }
    Ok(frame_log)
}

/// Checks the number of samples of a simulation (as computed, before rounding to an integer): at least one, and
/// an output of at most [`MAX_OUTPUT_BYTES`].
pub fn check_samples(samples: f64, rate_hz: f64, frame_log: bool) -> Result<u64> {
    if samples.is_nan() || samples < 1.0 {
        bail!(
            "{samples} samples: --samples / --hours must give at least one sample at {rate_hz} Hz"
        );
    }
    let per_sample = if frame_log {
        shared::wire::frame::FRAME_LEN as f64
    } else {
        CSV_ROW_BYTES
    };
    let bytes = samples * per_sample;
    if bytes > MAX_OUTPUT_BYTES {
        let max = (MAX_OUTPUT_BYTES / per_sample).floor();
        bail!(
            "{samples:.0} samples at {rate_hz} Hz ({:.1} h) would write ≈ {:.3e} bytes; the limit is {:.1e} bytes \
             ({max:.0} samples, {:.1} h at this rate): lower --hours, --samples or --rate",
            samples / rate_hz / 3600.0,
            bytes,
            MAX_OUTPUT_BYTES,
            max / rate_hz / 3600.0
        );
    }
    Ok(samples as u64)
}

/// Frame header defaults for a rate: the decimation that gives `rate_hz` from the FPGA base rate.
pub fn frame_opts(rate_hz: f64, base_rate_hz: f64) -> FrameOpts {
    FrameOpts {
        decimation: ((base_rate_hz / rate_hz).round().max(1.0) - 1.0) as u16,
        seq_start: 0,
    }
}

/// Collects a simulation's chunks into an in-memory [`Recording`](crate::recording::Recording) (physical values,
/// °/s and g; `temp_c` when the simulation has a thermal effect), as it streams.
pub struct RecordingSink {
    rec: crate::recording::Recording,
}

impl RecordingSink {
    /// An empty recording with room for `samples` rows of the 16 groups × 6 axes.
    pub fn new(samples: usize, with_temp: bool) -> Self {
        use crate::recording::{Column, SensorKind};
        let mut rec = crate::recording::Recording {
            t_s: Vec::with_capacity(samples),
            temp_c: with_temp.then(|| Vec::with_capacity(samples)),
            columns: Vec::new(),
        };
        for g in 0..crate::sim::GROUPS {
            for a in Axis::ALL {
                let kind = if a.is_gyro() {
                    SensorKind::Gyro
                } else {
                    SensorKind::Accel
                };
                rec.columns.push(Column {
                    group: g,
                    kind,
                    axis: a.index() % 3,
                    data: Vec::with_capacity(samples),
                });
            }
        }
        Self { rec }
    }

    /// Appends a chunk's rows.
    pub fn push(&mut self, chunk: &Chunk) {
        let rows = &chunk.phys[..chunk.len];
        self.rec.t_s.extend_from_slice(&chunk.t_s[..chunk.len]);
        if let Some(t) = &mut self.rec.temp_c {
            t.extend_from_slice(&chunk.temp_c[..chunk.len]);
        }
        for (k, col) in self.rec.columns.iter_mut().enumerate() {
            let (g, a) = (k / 6, k % 6);
            col.data.extend(rows.iter().map(|p| p[g][a]));
        }
    }

    /// The recording, columns ordered as the CSV reader orders them.
    pub fn finish(mut self) -> crate::recording::Recording {
        self.rec.columns.sort_by_key(|c| (c.kind, c.group, c.axis));
        self.rec
    }
}

/// Runs a simulation into an in-memory [`Recording`](crate::recording::Recording) (see [`RecordingSink`]).
pub fn recording(cfg: SimConfig) -> Result<crate::recording::Recording> {
    recording_filtered(cfg, &[])
}

/// [`recording`] with the outputs' bandwidths ([`BandwidthFilter`]).
pub fn recording_filtered(
    cfg: SimConfig,
    bands: &[Bandwidth],
) -> Result<crate::recording::Recording> {
    let mut sink = RecordingSink::new(cfg.samples as usize, cfg.thermal.is_some());
    let mut filter = BandwidthFilter::new(bands, cfg.rate_hz);
    let mut sim = Simulator::new(cfg)?;
    let mut chunk = Chunk::default();
    while sim.next_chunk(&mut chunk) > 0 {
        filter.apply(&mut chunk);
        sink.push(&chunk);
    }
    Ok(sink.finish())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sim::NoiseParams;

    #[test]
    fn temperature_profiles_parse_and_bad_ones_are_refused() {
        assert_eq!(
            parse_temperature("orbit:mean_c=20,amp_c=8,period_min=95").unwrap(),
            TemperatureProfile::Orbit {
                mean_c: 20.0,
                amp_c: 8.0,
                period_min: 95.0
            }
        );
        assert_eq!(
            parse_temperature("ramp:from_c=-10,to_c=50,hours=3").unwrap(),
            TemperatureProfile::Ramp {
                from_c: -10.0,
                to_c: 50.0,
                hours: 3.0
            }
        );
        assert_eq!(
            parse_temperature("constant:c=20").unwrap(),
            TemperatureProfile::Constant { c: 20.0 }
        );
        for (bad, says) in [
            ("orbit:mean_c=20,amp_c=8", "period_min missing"),
            ("orbit:mean_c=20,amp_c=8,period_min=0", "period_min > 0"),
            ("ramp:from_c=-10,to_c=50,hours=3,x=1", "unknown key 'x'"),
            ("ramp:from_c=-10,to_c=abc,hours=3", "is not a number"),
            ("ramp:from_c=-10,from_c=0,to_c=5,hours=3", "given twice"),
            ("sine:mean_c=20", "unknown profile 'sine'"),
            ("ramp", "expected orbit:"),
            ("constant:c=500", "within −150"),
        ] {
            let e = parse_temperature(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }

    /// A noiseless board on a ramp: every frame carries the temperature, the ramp holds at its end, and each raw
    /// channel's code moves by its own coefficient (the reading's, through the ADC step of `shared::calib::board`)
    /// times the temperature change: the per-raw-channel linear law is the truth.
    #[test]
    fn thermal_acts_on_each_raw_channel_code() {
        let (rate, hours) = (1.0, 3.0);
        let samples = (hours * 3600.0 * rate) as u64 + 600;
        let mut cfg = SimConfig::new(1, rate, samples, [NoiseParams::default(); 7]);
        cfg.board_seed = Some(7);
        let args = EffectArgs {
            thermal: vec!["gyro:0.05:0.02".into(), "accel:0.0005:0.0002".into()],
            temperature: Some(parse_temperature("ramp:from_c=-10,to_c=50,hours=3").unwrap()),
            ..EffectArgs::default()
        };
        args.apply(&mut cfg).unwrap();
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
}
