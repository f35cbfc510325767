//! The Allan-deviation analysis behind `ground allan` (also used by `demo` and `diagnose`): per column and for the
//! cluster mean of each axis, deviations with Greenhall-EDF confidence intervals and the identified noise type, a
//! noise-term fit, the equal-weight independence expectation, and Kalibr's `imu.yaml`.

use crate::allan::noisefit::{self, NoiseFit};
use crate::allan::{AnalysisPoint, Analyzer, DevKind, Options, TauSpec};
use crate::recording::{AXIS_NAMES, AxisMean, Recording, SensorKind};
use rayon::prelude::*;
use std::fmt::Write as _;

/// The deviation curve of one column (or of a cluster mean).
#[derive(Clone, Debug)]
pub struct Series {
    /// `g03z`, or `mean_gz` for the cluster mean.
    pub label: String,
    /// Gyro or accelerometer.
    pub kind: SensorKind,
    /// 0, 1, 2 = x, y, z.
    pub axis: usize,
    /// The group, `None` for the cluster mean.
    pub group: Option<usize>,
    /// Groups averaged (1 for a single column).
    pub members: usize,
    /// Deviations in the column's unit (°/s or g).
    pub points: Vec<AnalysisPoint>,
    /// Noise-term fit.
    pub fit: NoiseFit,
}

impl Series {
    /// The minimum of the deviation curve ("bias stability" in the seed paper): (τ, deviation, lo, hi).
    pub fn minimum(&self) -> Option<&AnalysisPoint> {
        self.points
            .iter()
            .filter(|p| p.dev.is_finite())
            .min_by(|a, b| a.dev.total_cmp(&b.dev))
    }
}

/// Label of the cluster mean of an axis, e.g. `mean_gz`.
pub fn mean_label(kind: SensorKind, axis: usize) -> String {
    format!(
        "mean_{}{}",
        kind.prefix(),
        AXIS_NAMES.get(axis).copied().unwrap_or('?')
    )
}

/// The equal-weight cluster mean of one axis over all groups that have it; `None` if none.
pub fn cluster_mean(rec: &Recording, kind: SensorKind, axis: usize) -> Option<(Vec<f64>, usize)> {
    let cols: Vec<&[f64]> = rec
        .axis_columns(kind, axis)
        .map(|c| c.data.as_slice())
        .collect();
    let n = cols.len();
    if n == 0 {
        return None;
    }
    // Column by column over blocks of rows that stay in the L1 cache (each a vectorised pass), in the same order
    // of addition as a sum per row; a column shorter than the recording makes its missing rows NaN.
    const BLOCK: usize = 2048;
    let mut mean = vec![0.0; rec.len()];
    for (b, out) in mean.chunks_mut(BLOCK).enumerate() {
        let rows = b * BLOCK..b * BLOCK + out.len();
        for (k, c) in cols.iter().enumerate() {
            let part = c
                .get(rows.start.min(c.len())..rows.end.min(c.len()))
                .unwrap_or(&[]);
            if k == 0 {
                out.fill(f64::NAN);
                out.get_mut(..part.len())
                    .unwrap_or_default()
                    .copy_from_slice(part);
            } else {
                for (m, v) in out.iter_mut().zip(part) {
                    *m += v;
                }
                out.get_mut(part.len()..).unwrap_or_default().fill(f64::NAN);
            }
        }
        for m in out.iter_mut() {
            *m /= n as f64;
        }
    }
    Some((mean, n))
}

/// What to analyse.
#[derive(Clone, Debug)]
pub struct AdevRequest {
    /// Deviation kind.
    pub kind: DevKind,
    /// Averaging times.
    pub taus: TauSpec,
    /// Column names to analyse (empty: all).
    pub columns: Vec<String>,
    /// Also the cluster mean of every axis present.
    pub cluster: bool,
}

/// Why an analysis or a Kalibr file could not be made.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum AdevError {
    /// No sample interval: fewer than two samples, or time not increasing.
    #[error("fewer than two samples, or time not increasing")]
    NoInterval,
    /// A requested column is not in the recording.
    #[error("no column '{0}' in the recording")]
    NoColumn(String),
    /// The fits cannot make a Kalibr file (what is missing or not finite).
    #[error("{0}")]
    Kalibr(String),
}

/// One series to compute: label, kind, axis, group, members, data.
type Job<'a> = (
    String,
    SensorKind,
    usize,
    Option<usize>,
    usize,
    std::borrow::Cow<'a, [f64]>,
);

/// Analyses a recording: selected columns and, if asked, the cluster mean of each axis. `tick` is called once per
/// finished series (from worker threads).
pub fn analyze(
    rec: &Recording,
    req: &AdevRequest,
    tick: &(dyn Fn() + Sync),
) -> Result<Vec<Series>, AdevError> {
    analyze_with_means(rec, None, req, tick)
}

/// As [`analyze`], with the cluster means already computed when `means` is given (by a reader that streams the
/// file, `formats::npy`; `rec` then needs to hold only the requested columns): they replace [`cluster_mean`] of
/// `rec`.
pub fn analyze_with_means(
    rec: &Recording,
    means: Option<Vec<AxisMean>>,
    req: &AdevRequest,
    tick: &(dyn Fn() + Sync),
) -> Result<Vec<Series>, AdevError> {
    let tau0 = rec.sample_interval_s().ok_or(AdevError::NoInterval)?;
    for name in &req.columns {
        if rec.column(name).is_none() {
            return Err(AdevError::NoColumn(name.clone()));
        }
    }
    let mut jobs: Vec<Job> = rec
        .columns
        .iter()
        .filter(|c| req.columns.is_empty() || req.columns.contains(&c.name()))
        .map(|c| {
            (
                c.name(),
                c.kind,
                c.axis,
                Some(c.group),
                1,
                std::borrow::Cow::Borrowed(c.data.as_slice()),
            )
        })
        .collect();
    if req.cluster {
        let axes: Vec<(SensorKind, usize)> = [SensorKind::Gyro, SensorKind::Accel]
            .into_iter()
            .flat_map(|kind| (0..3).map(move |axis| (kind, axis)))
            .collect();
        let means: Vec<_> = match means {
            Some(m) => m
                .into_iter()
                .filter(|m| m.members > 0)
                .map(|m| (m.kind, m.axis, (m.data, m.members)))
                .collect(),
            None => axes
                .into_par_iter()
                .filter_map(|(kind, axis)| Some((kind, axis, cluster_mean(rec, kind, axis)?)))
                .collect(),
        };
        for (kind, axis, (data, n)) in means {
            jobs.push((
                mean_label(kind, axis),
                kind,
                axis,
                None,
                n,
                std::borrow::Cow::Owned(data),
            ));
        }
    }
    let options = Options::default();
    // One workspace per thread at a time, kept for the next series: rayon's `map_init` would make one per piece of
    // work it splits off, and each new one faults in fresh pages for its phase and block means.
    let pool = std::sync::Mutex::new(Vec::<Analyzer>::new());
    let out = jobs
        .into_par_iter()
        .map(|(label, kind, axis, group, members, data)| {
            let mut an = pool
                .lock()
                .ok()
                .and_then(|mut p| p.pop())
                .unwrap_or_default();
            let points = an.analyze(req.kind, &data, tau0, &req.taus, &options);
            if let Ok(mut p) = pool.lock() {
                p.push(an);
            }
            let fit = noisefit::fit(&points);
            tick();
            Series {
                label,
                kind,
                axis,
                group,
                members,
                points,
                fit,
            }
        })
        .collect();
    Ok(out)
}

/// Writes the long-form CSV: `column,tau_s,n,dev,ci_lo,ci_hi,alpha` (deviation and bounds in the column's unit;
/// 68.3 % two-sided chi-squared interval with Greenhall EDF; alpha = identified power-law noise exponent).
pub fn write_long_csv(series: &[Series], out: &mut impl std::io::Write) -> std::io::Result<()> {
    writeln!(out, "column,tau_s,n,dev,ci_lo,ci_hi,alpha")?;
    let opt = |x: Option<f64>| x.map_or(String::new(), |v| format!("{v:e}"));
    for s in series {
        for p in &s.points {
            let alpha = p.alpha().map_or(String::new(), |a| a.to_string());
            let tau = round_sig(p.tau_s, 10);
            writeln!(
                out,
                "{},{},{},{:e},{},{},{}",
                s.label,
                tau,
                p.n,
                p.dev,
                opt(p.dev_lo),
                opt(p.dev_hi),
                alpha
            )?;
        }
    }
    Ok(())
}

/// Writes the noise-term fit of every series: `column,unit,white,bias_instability,random_walk,quantization,
/// rel_rms_misfit,min_dev,tau_at_min_s,min_ci_lo,min_ci_hi`. Units (with `unit` = °/s or g): white in unit/√Hz
/// (ARW/VRW), bias instability in unit, random walk in unit/√s, quantisation in unit·s, deviations in unit.
pub fn write_fit_csv(series: &[Series], out: &mut impl std::io::Write) -> std::io::Result<()> {
    writeln!(
        out,
        "column,unit,white,bias_instability,random_walk,quantization,rel_rms_misfit,min_dev,tau_at_min_s,min_ci_lo,min_ci_hi"
    )?;
    let opt = |x: Option<f64>| x.map_or(String::new(), |v| format!("{v:e}"));
    for s in series {
        let f = &s.fit;
        let m = s.minimum();
        writeln!(
            out,
            "{},{},{:e},{:e},{:e},{:e},{:.4},{},{},{},{}",
            s.label,
            s.kind.unit(),
            f.white,
            f.bias_instability,
            f.random_walk,
            f.quantization,
            f.rel_rms_misfit,
            opt(m.map(|p| p.dev)),
            m.map_or(String::new(), |p| round_sig(p.tau_s, 10).to_string()),
            opt(m.and_then(|p| p.dev_lo)),
            opt(m.and_then(|p| p.dev_hi)),
        )?;
    }
    Ok(())
}

/// `x` rounded to `digits` significant digits (for printing times derived from float sample intervals).
pub fn round_sig(x: f64, digits: usize) -> f64 {
    format!("{:.*e}", digits.saturating_sub(1), x)
        .parse()
        .unwrap_or(x)
}

/// The expectation for an equal-weight mean of the given independent sensors at each τ of the first:
/// `σ_mean(τ) = √(Σ σ_i²(τ)) / n` (= σ/√n for equal sensors).
pub fn independent_mean_expectation(singles: &[&Series]) -> Vec<(f64, f64)> {
    let Some(first) = singles.first() else {
        return Vec::new();
    };
    let n = singles.len() as f64;
    first
        .points
        .iter()
        .enumerate()
        .filter_map(|(i, p)| {
            let sum: f64 = singles
                .iter()
                .map(|s| s.points.get(i).map_or(f64::NAN, |q| q.dev * q.dev))
                .sum();
            sum.is_finite().then(|| (p.tau_s, sum.sqrt() / n))
        })
        .collect()
}

/// Standard gravity, m/s² per g.
pub const G0: f64 = 9.806_65;

/// Kalibr's `imu.yaml` from the noise fits of the cluster-mean series (continuous-time densities: Kalibr's
/// convention). Units written: gyroscope_noise_density rad/s/√Hz, gyroscope_random_walk rad/s²/√Hz,
/// accelerometer_noise_density m/s²/√Hz, accelerometer_random_walk m/s³/√Hz. Kalibr takes one value per sensor;
/// we write the largest of the three axes (conservative) and list each axis in comments.
pub fn kalibr_yaml(series: &[Series], rate_hz: f64, topic: &str) -> String {
    let mut y = String::new();
    let _ = writeln!(
        y,
        "# Written by `ground allan --kalibr` from the noise-term fit of the cluster-mean ADEV."
    );
    let _ = writeln!(
        y,
        "# Continuous-time densities (Kalibr convention), NOT discrete per-sample sigmas:"
    );
    let _ = writeln!(
        y,
        "#   *_noise_density = white-noise term N of sigma^2(tau) = N^2/tau (ARW / VRW);"
    );
    let _ = writeln!(
        y,
        "#   *_random_walk   = rate-random-walk term K of sigma^2(tau) = K^2 tau/3."
    );
    let _ = writeln!(y, "# One value per sensor: the largest of the three axes.");
    let pick = |kind: SensorKind,
                f: fn(&NoiseFit) -> f64,
                scale: f64,
                name: &str,
                unit: &str,
                y: &mut String| {
        let mut worst = 0.0f64;
        for s in series
            .iter()
            .filter(|s| s.group.is_none() && s.kind == kind)
        {
            let v = f(&s.fit) * scale;
            let _ = writeln!(y, "#   {name} {} = {v:.6e} {unit}", s.label);
            worst = worst.max(v);
        }
        let _ = writeln!(y, "{name}: {worst:.6e}   # [{unit}]");
    };
    let d2r = std::f64::consts::PI / 180.0;
    pick(
        SensorKind::Accel,
        |f| f.white,
        G0,
        "accelerometer_noise_density",
        "m/s^2/sqrt(Hz)",
        &mut y,
    );
    pick(
        SensorKind::Accel,
        |f| f.random_walk,
        G0,
        "accelerometer_random_walk",
        "m/s^3/sqrt(Hz)",
        &mut y,
    );
    pick(
        SensorKind::Gyro,
        |f| f.white,
        d2r,
        "gyroscope_noise_density",
        "rad/s/sqrt(Hz)",
        &mut y,
    );
    pick(
        SensorKind::Gyro,
        |f| f.random_walk,
        d2r,
        "gyroscope_random_walk",
        "rad/s^2/sqrt(Hz)",
        &mut y,
    );
    let _ = writeln!(y, "rostopic: {topic}");
    let _ = writeln!(y, "update_rate: {rate_hz}   # [Hz]");
    y
}

/// Whether the cluster means' fits can make a Kalibr file ([`kalibr_yaml`]): `Err` naming the problem when a sensor
/// has no cluster mean, a white-noise density is not a positive finite number (a constant, too short or broken
/// recording fits none, and Kalibr would take 0 as a perfect sensor), a random walk is not finite, or the rate is
/// not a positive finite number. `Ok` holds warnings (a random walk the record did not resolve, written as 0).
pub fn kalibr_check(series: &[Series], rate_hz: f64) -> Result<Vec<String>, AdevError> {
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        return Err(AdevError::Kalibr(format!(
            "the sample rate ({rate_hz} Hz) is not a positive number"
        )));
    }
    let mut warnings = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        let means: Vec<&Series> = series
            .iter()
            .filter(|s| s.group.is_none() && s.kind == kind)
            .collect();
        if means.is_empty() {
            return Err(AdevError::Kalibr(format!(
                "no {} columns: Kalibr needs the noise of both the gyros and the accelerometers",
                kind.name()
            )));
        }
        for s in &means {
            let f = &s.fit;
            if !(f.white.is_finite() && f.white > 0.0) {
                return Err(AdevError::Kalibr(format!(
                    "{}: the noise fit has no white-noise density ({}); a constant, too short or non-finite \
                     recording cannot give one",
                    s.label, f.white
                )));
            }
            if !f.random_walk.is_finite() {
                return Err(AdevError::Kalibr(format!(
                    "{}: the noise fit's random walk is {}",
                    s.label, f.random_walk
                )));
            }
        }
        if means.iter().all(|s| s.fit.random_walk == 0.0) {
            warnings.push(format!(
                "no {} random walk resolved (the record is too short or too quiet): *_random_walk is written as 0",
                kind.name()
            ));
        }
    }
    Ok(warnings)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::recording::Column;

    fn white(seed: u64, n: usize, sigma: f64) -> Vec<f64> {
        // Independent of the simulator under test elsewhere.
        crate::testrng::TestRng::new(seed).normals(n, sigma)
    }

    #[test]
    fn white_noise_fit_kalibr_units_and_cluster_gain() {
        let n = 1 << 16;
        let rate = 100.0;
        let mut rec = Recording {
            t_s: (0..n).map(|i| i as f64 / rate).collect(),
            ..Default::default()
        };
        // 4 groups of gyro x: white noise with density 0.01 (°/s)/√Hz → per-sample σ = 0.01·√100 = 0.1 °/s.
        for g in 0..4 {
            rec.columns.push(Column {
                group: g,
                kind: SensorKind::Gyro,
                axis: 0,
                data: white(g as u64, n, 0.1),
            });
        }
        let req = AdevRequest {
            kind: DevKind::Oadev,
            taus: TauSpec::Octave,
            columns: vec![],
            cluster: true,
        };
        let series = analyze(&rec, &req, &|| ()).unwrap();
        assert_eq!(series.len(), 5);
        let single = &series[0];
        assert!(
            (single.fit.white / 0.01 - 1.0).abs() < 0.03,
            "N = {}",
            single.fit.white
        );
        let mean = series.iter().find(|s| s.group.is_none()).unwrap();
        assert_eq!((mean.label.as_str(), mean.members), ("mean_gx", 4));
        assert!(
            (mean.fit.white / 0.005 - 1.0).abs() < 0.04,
            "cluster N = {}",
            mean.fit.white
        ); // √4 gain
        let expected = independent_mean_expectation(&series[..4].iter().collect::<Vec<_>>());
        assert!((expected[0].1 / mean.points[0].dev - 1.0).abs() < 0.03);
        let yaml = kalibr_yaml(&series, rate, "/imu0");
        let density: f64 = yaml
            .lines()
            .find(|l| l.starts_with("gyroscope_noise_density"))
            .unwrap()
            .split_whitespace()
            .nth(1)
            .unwrap()
            .parse()
            .unwrap();
        assert!((density / (mean.fit.white * std::f64::consts::PI / 180.0) - 1.0).abs() < 1e-6);
        let mut fits = Vec::new();
        write_fit_csv(&series, &mut fits).unwrap();
        let fits = String::from_utf8(fits).unwrap();
        let row: Vec<&str> = fits.lines().nth(1).unwrap().split(',').collect();
        assert_eq!((row[0], row[1]), ("g00x", "deg/s"));
        assert!((row[2].parse::<f64>().unwrap() / 0.01 - 1.0).abs() < 0.03);
        let mut csv = Vec::new();
        write_long_csv(&series, &mut csv).unwrap();
        let text = String::from_utf8(csv).unwrap();
        assert!(text.starts_with("column,tau_s,n,dev,ci_lo,ci_hi,alpha\ng00x,0.01,"));
        assert!(
            analyze(
                &rec,
                &AdevRequest {
                    columns: vec!["g09x".into()],
                    ..req
                },
                &|| ()
            )
            .is_err()
        );
    }
}
