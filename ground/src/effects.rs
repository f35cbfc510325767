//! `ground simulate`'s effect flags ([`EffectArgs`]): flag strings parsed into the library's typed
//! [`Effects`] and [`Bandwidth`]s.

use host_test::sim::effects::{Effects, TemperatureProfile, ThermalCoef};
use host_test::sim::output::Bandwidth;
use host_test::sim::{Axis, Channel, CommonDrift, CommonMode, DriftKind, Outlier, Periodic};

/// Why an effect flag was refused.
#[derive(Debug, thiserror::Error)]
pub enum FlagError {
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
pub type Result<T, E = FlagError> = std::result::Result<T, E>;

/// Refuses with a message (an option's value malformed or out of range).
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err(FlagError::Invalid(format!($($arg)*)))
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
        self.ok_or_else(|| FlagError::Invalid(what()))
    }
}

impl<T, E: Into<NumberError>> Context<T> for std::result::Result<T, E> {
    fn with_context(self, what: impl FnOnce() -> String) -> Result<T> {
        self.map_err(|e| FlagError::Number {
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
// The field docs are clap's help text: `[:OPTIONAL]` there is not an intra-doc link.
#[allow(rustdoc::broken_intra_doc_links)]
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

    /// The effects, parsed (the bandwidths apart: [`EffectArgs::bandwidths`]).
    pub fn effects(&self) -> Result<Effects> {
        let mut cfg = Effects {
            temperature: self.temperature,
            unequal: self.unequal,
            cal_spread: self.cal_spread,
            ..Effects::default()
        };
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
            cfg.thermal.push(ThermalCoef {
                axes: parse_axes(axes)?,
                coef: v[0],
                sd: v.get(1).copied().unwrap_or(0.0),
            });
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
        Ok(cfg)
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
                    .map_err(|e| FlagError::Invalid(format!("{usage}: groups '{g}': {e}")))?,
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
        && let Some(bad) = g.iter().find(|&&g| g >= host_test::sim::GROUPS)
    {
        bail!(
            "{usage}: group {bad} is not below {}",
            host_test::sim::GROUPS
        );
    }
    Ok(Bandwidth {
        groups,
        axes: parse_axes(axes)?,
        cutoff_hz: v[0],
    })
}

#[cfg(test)]
mod tests {
    use super::*;

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

    #[test]
    fn bandwidth_option_parses_and_refuses_bad_values() {
        let b = parse_bandwidth("3-4/gx,gy:2.5").unwrap();
        assert_eq!(b.groups, Some(vec![3, 4]));
        assert_eq!(b.axes, vec![Axis::GyroX, Axis::GyroY]);
        assert_eq!(b.cutoff_hz, 2.5);
        for bad in ["gyro", "gyro:0", "gyro:-1", "gyro:nan", "99/gx:1", "gq:1"] {
            assert!(parse_bandwidth(bad).is_err(), "{bad}");
        }
    }
}
