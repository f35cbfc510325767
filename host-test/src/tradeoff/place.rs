//! A recording's own figures, from the Allan machinery of `ground allan` ([`crate::allan::recording::analyze`], ADEV at the octave
//! factors and at the factor nearest τ = 1 s, 68.3 % Greenhall-EDF intervals): per axis, bias instability as the ADEV
//! floor ([`crate::allan::recording::Series::minimum`]) and the random walk as σ(τ)·√τ at τ ≈ 1 s, for the cluster mean and for the
//! typical single sensor (the median of the groups, with that sensor's interval).

use super::TradeoffError;
use crate::allan::recording::{self, AdevRequest, Series};
use crate::allan::{AnalysisPoint, DevKind, TauSpec, averaging_factors};
use crate::recording::{Recording, SensorKind};
use serde::Serialize;

/// Standard gravity, m/s² (g → m/s²).
pub const STANDARD_GRAVITY: f64 = 9.80665;

/// A value with its 68 % interval.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Estimate {
    /// The value.
    pub value: f64,
    /// Lower bound (68.3 %).
    pub lo: f64,
    /// Upper bound (68.3 %).
    pub hi: f64,
}

impl Estimate {
    fn scaled(self, k: f64) -> Estimate {
        Estimate {
            value: self.value * k,
            lo: self.lo * k,
            hi: self.hi * k,
        }
    }

    /// The point's deviation with its interval (the deviation itself where the interval is unknown).
    fn of(p: &AnalysisPoint) -> Estimate {
        Estimate {
            value: p.dev,
            lo: p.dev_lo.unwrap_or(p.dev),
            hi: p.dev_hi.unwrap_or(p.dev),
        }
    }

    /// The mean of several (bounds averaged too: as if the axes' errors were fully correlated, the wider reading).
    fn mean(xs: &[Estimate]) -> Option<Estimate> {
        let n = xs.len() as f64;
        (!xs.is_empty()).then(|| Estimate {
            value: xs.iter().map(|e| e.value).sum::<f64>() / n,
            lo: xs.iter().map(|e| e.lo).sum::<f64>() / n,
            hi: xs.iter().map(|e| e.hi).sum::<f64>() / n,
        })
    }
}

/// Bias instability and random walk of one series, in the catalogue's units.
#[derive(Clone, Copy, Debug, Serialize, PartialEq)]
pub struct Figures {
    /// Bias instability: the ADEV floor, °/h (gyro) or µg (accelerometer).
    pub bias_instability: Estimate,
    /// τ of the floor, s.
    pub floor_tau_s: f64,
    /// Random walk σ(τ)·√τ at τ ≈ 1 s: °/√h (ARW) or (m/s)/√h (VRW).
    pub random_walk: Estimate,
    /// The τ it was read at, s.
    pub random_walk_tau_s: f64,
}

/// One axis of the recording.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct AxisFigures {
    /// `gyro` or `accel`.
    pub kind: &'static str,
    /// `x`, `y`, `z`.
    pub axis: char,
    /// The cluster mean (equal weights) of the groups.
    pub cluster: Figures,
    /// The typical single sensor: the median of the groups' figures (each with its own sensor's interval).
    pub single: Figures,
    /// Groups averaged.
    pub groups: usize,
}

/// The recording's figures: per axis, and the mean of the three axes of each kind.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Placement {
    /// Per axis.
    pub axes: Vec<AxisFigures>,
    /// Mean over x, y, z: gyro then accelerometer (cluster, single), where the recording has that kind.
    pub mean: Vec<(&'static str, Figures, Figures)>,
    /// The recording's sample interval, s.
    pub tau0_s: f64,
}

/// Unit factors from the recording's units (°/s, g) to the catalogue's: (bias instability, random walk).
fn factors(kind: SensorKind) -> (f64, f64) {
    match kind {
        // °/s → °/h; °/s·√s = °/√s → °/√h (√h = 60 √s).
        SensorKind::Gyro => (3600.0, 60.0),
        // g → µg; g·√s → (m/s)/√h.
        SensorKind::Accel => (1e6, STANDARD_GRAVITY * 60.0),
    }
}

/// The figures of one series: the floor, and σ·√τ at the factor `m1` (τ ≈ 1 s).
fn figures(s: &Series, m1: usize, kind: SensorKind) -> Option<Figures> {
    let (k_bi, k_rw) = factors(kind);
    let floor = s.minimum()?;
    let p1 = s.points.iter().find(|p| p.m == m1 && p.dev.is_finite())?;
    Some(Figures {
        bias_instability: Estimate::of(floor).scaled(k_bi),
        floor_tau_s: floor.tau_s,
        random_walk: Estimate::of(p1).scaled(p1.tau_s.sqrt() * k_rw),
        random_walk_tau_s: p1.tau_s,
    })
}

/// The median by `key` (the lower one of an even count), with its own interval.
fn median_by(mut xs: Vec<Figures>, key: impl Fn(&Figures) -> f64) -> Option<Figures> {
    xs.sort_by(|a, b| key(a).total_cmp(&key(b)));
    xs.get(xs.len().checked_sub(1)? / 2).copied()
}

/// Places a recording: every column and the cluster mean of every axis analysed as `ground allan` does (ADEV).
pub fn place(rec: &Recording) -> Result<Placement, TradeoffError> {
    let tau0 = rec
        .sample_interval_s()
        .ok_or(recording::AdevError::NoInterval)?;
    let m1 = (1.0 / tau0).round().max(1.0) as usize;
    let mut ms = averaging_factors(&TauSpec::Octave, DevKind::Adev, rec.len());
    ms.push(m1);
    let req = AdevRequest {
        kind: DevKind::Adev,
        taus: TauSpec::Factors(ms),
        columns: Vec::new(),
        cluster: true,
    };
    let series = recording::analyze(rec, &req, &|| {})?;
    let mut axes = Vec::new();
    let mut mean = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        let (mut c_all, mut s_all) = (Vec::new(), Vec::new());
        for axis in 0..3 {
            let of_axis = |s: &&Series| s.kind == kind && s.axis == axis;
            let Some(cluster) = series
                .iter()
                .filter(of_axis)
                .find(|s| s.group.is_none())
                .and_then(|s| Some((figures(s, m1, kind)?, s.members)))
            else {
                continue;
            };
            let singles: Vec<Figures> = series
                .iter()
                .filter(of_axis)
                .filter(|s| s.group.is_some())
                .filter_map(|s| figures(s, m1, kind))
                .collect();
            let (Some(bi), Some(rw)) = (
                median_by(singles.clone(), |f| f.bias_instability.value),
                median_by(singles, |f| f.random_walk.value),
            ) else {
                continue;
            };
            let single = Figures {
                bias_instability: bi.bias_instability,
                floor_tau_s: bi.floor_tau_s,
                random_walk: rw.random_walk,
                random_walk_tau_s: rw.random_walk_tau_s,
            };
            c_all.push(cluster.0);
            s_all.push(single);
            axes.push(AxisFigures {
                kind: kind.name(),
                axis: ['x', 'y', 'z'].get(axis).copied().unwrap_or('?'),
                cluster: cluster.0,
                single,
                groups: cluster.1,
            });
        }
        let avg = |xs: &[Figures]| -> Option<Figures> {
            let n = xs.len() as f64;
            Some(Figures {
                bias_instability: Estimate::mean(
                    &xs.iter().map(|f| f.bias_instability).collect::<Vec<_>>(),
                )?,
                floor_tau_s: xs.iter().map(|f| f.floor_tau_s).sum::<f64>() / n,
                random_walk: Estimate::mean(&xs.iter().map(|f| f.random_walk).collect::<Vec<_>>())?,
                random_walk_tau_s: xs.iter().map(|f| f.random_walk_tau_s).sum::<f64>() / n,
            })
        };
        if let (Some(c), Some(s)) = (avg(&c_all), avg(&s_all)) {
            mean.push((kind.name(), c, s));
        }
    }
    if axes.is_empty() {
        return Err(TradeoffError::NoAxis);
    }
    Ok(Placement {
        axes,
        mean,
        tau0_s: tau0,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::testrng::TestRng;

    #[test]
    fn white_noise_of_a_set_density_is_recovered_within_its_interval() {
        // 16 groups of white noise only, 20 Hz, 2 h: gyro density 0.3 °/√h = 0.005 °/√s, accel 0.05 (m/s)/√h.
        let rate = 20.0;
        let n = (2.0 * 3600.0 * rate) as usize;
        let arw_dps_rs = 0.3 / 60.0; // °/s·√s
        let vrw_g_rs = 0.05 / 60.0 / STANDARD_GRAVITY; // g·√s
        let mut rng = TestRng::new(11);
        let t: Vec<f64> = (0..n).map(|i| i as f64 / rate).collect();
        let mut cols = Vec::new();
        for _g in 0..16 {
            for k in 0..6 {
                let d = if k < 3 { arw_dps_rs } else { vrw_g_rs };
                let sigma = d * rate.sqrt(); // per-sample σ of white noise of density d
                cols.push((0..n).map(|_| sigma * rng.normal()).collect::<Vec<f64>>());
            }
        }
        let rec = Recording::from_group_columns(t, cols);
        let p = place(&rec).unwrap();
        assert_eq!(p.axes.len(), 6);
        // Within 3 σ of the 68 % interval's half-width (in ln), which itself must be that of ≈ 7 200 one-second
        // blocks (≈ 1.2 %): a 1-σ interval alone would miss the truth on a third of the axes.
        let within = |e: Estimate, truth: f64| {
            let half = 0.5 * (e.hi / e.lo).ln();
            assert!((0.005..0.03).contains(&half), "{e:?}");
            (e.value / truth).ln().abs() < 3.0 * half
        };
        for a in &p.axes {
            let truth = if a.kind == "gyro" { 0.3 } else { 0.05 };
            assert!(within(a.single.random_walk, truth), "{a:?}");
            // The cluster of 16 independent sensors: √16 lower.
            assert!(within(a.cluster.random_walk, truth / 4.0), "{a:?}");
            assert!((a.single.random_walk_tau_s - 1.0).abs() < 1e-9);
            assert_eq!(a.groups, 16);
        }
    }
}
