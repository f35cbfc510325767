//! The sim-to-real gap measured directly: two recordings of the same cluster (a real one and a simulated one, or
//! two real ones) compared axis by axis and τ by τ.
//!
//! Per axis, two curves of each recording: the **cluster** (equal-weight mean of the axis's sensors) and the
//! **typical sensor** (per-τ median of the sensors' deviations). Both are octave overlapping Allan deviations with
//! Greenhall EDFs and χ² intervals. At each τ both have, the gap is `g = ln(σ_a/σ_b)` and its z-score
//! `g / √(1/2ν_a + 1/2ν_b + tol²)`, as the diagnosis scores a gap (each `ln σ` has variance ≈ 1/2ν; `tol`, 3 % by
//! default, the model tolerance: at short τ the EDF runs into the tens of thousands, and no noise model is exact
//! to a few tenths of a per cent; the median of N sensors is taken as carrying `2N/π` times one sensor's EDF, the
//! median's efficiency for normal data; at τ with fewer than `ACF_MIN_POINTS` blocks, every EDF at most white FM's:
//! `edf_cap`). The verdict is the
//! diagnosis's scan statistic over τ (`diagnose::scan_statistic`: the largest standardised sum over a band of
//! contiguous τ), in both directions — a simulation too noisy or too quiet — for both curves, each of the four
//! tests at `p_false / 4`: an axis is reproduced unless one exceeds its threshold.

use super::TwinError;
use crate::allan::{
    ACF_MIN_POINTS, AnalysisPoint, Analyzer, DevKind, ONE_SIGMA_CI, Options as AllanOptions,
    TauSpec, confidence_interval, edf_for_kind,
};
use crate::diagnose::{scan_statistic, scan_threshold};
use crate::recording::Recording;
use crate::recording::SensorKind;
use crate::stats::median;
use serde::Serialize;

/// Default false-alarm probability of the verdict per axis (the diagnosis's `p_false`).
pub const P_FALSE: f64 = 2e-3;
/// Default tolerance of a model, in ln deviation (the diagnosis's `model_tolerance`): a simulation within 3 % of the
/// record's deviation at a τ is not told apart there, however many blocks the τ has.
pub const TOLERANCE: f64 = 0.03;
/// Fewest averaging blocks of a τ compared (the diagnosis's `min_blocks`).
pub const MIN_BLOCKS: usize = 4;

/// How to compare.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct CompareOptions {
    /// False-alarm probability of the verdict per axis.
    pub p_false: f64,
    /// Model tolerance, ln deviation.
    pub tolerance: f64,
    /// The second recording was played from a model fitted on a *third* record (of the same length: not the
    /// first): its deviations carry that record's estimation error as well as their own, so its `1/2ν` term counts
    /// twice. (When the model was fitted on the first recording itself, its errors follow that record, and this
    /// stays off.)
    pub fitted_elsewhere: bool,
}

impl Default for CompareOptions {
    fn default() -> Self {
        Self {
            p_false: P_FALSE,
            tolerance: TOLERANCE,
            fitted_elsewhere: false,
        }
    }
}

/// One recording's deviation at one τ.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct Dev {
    /// Deviation.
    pub dev: f64,
    /// 68 % interval.
    pub lo: f64,
    /// Upper bound.
    pub hi: f64,
    /// EDF.
    pub edf: f64,
}

/// One τ of one curve.
#[derive(Clone, Copy, Debug, Serialize)]
pub struct TauGap {
    /// τ, s.
    pub tau_s: f64,
    /// The first recording (the real one).
    pub a: Dev,
    /// The second (the simulation).
    pub b: Dev,
    /// The gap ½·ln(σ²_a / σ²_b) (ln deviation).
    pub gap: f64,
    /// Its z-score (see the module docs): > 0 when the first is noisier.
    pub z: f64,
}

/// The verdict on one curve.
#[derive(Clone, Debug, Serialize)]
pub struct CurveVerdict {
    /// Scan statistic of z (the first noisier) and of −z (the second noisier).
    pub scan: [f64; 2],
    /// Threshold of each.
    pub threshold: f64,
    /// Whether either exceeds it.
    pub significant: bool,
    /// τ range of the points with |z| > 2 when significant, s.
    pub where_tau_s: Option<[f64; 2]>,
    /// Every τ.
    pub taus: Vec<TauGap>,
}

/// One axis.
#[derive(Clone, Debug, Serialize)]
pub struct AxisComparison {
    /// `gx`, …
    pub axis: String,
    /// Sensors in each recording.
    pub sensors: [usize; 2],
    /// The cluster mean.
    pub cluster: CurveVerdict,
    /// The typical sensor.
    pub typical: CurveVerdict,
    /// Whether the second recording fails to reproduce the first on this axis.
    pub significant: bool,
}

/// The comparison.
#[derive(Clone, Debug, Serialize)]
pub struct Comparison {
    /// How it was compared.
    pub options: CompareOptions,
    /// Per axis present in both.
    pub axes: Vec<AxisComparison>,
    /// Axes where the second does not reproduce the first.
    pub significant_axes: Vec<String>,
}

fn octave(an: &mut Analyzer, y: &[f64], tau0: f64) -> Vec<AnalysisPoint> {
    an.analyze(
        DevKind::Oadev,
        y,
        tau0,
        &TauSpec::Octave,
        &AllanOptions::default(),
    )
}

/// (τ, deviation, EDF) of the cluster mean and of the typical sensor of one axis.
type Curves = (Vec<(f64, Dev)>, Vec<(f64, Dev)>);

fn curves(
    an: &mut Analyzer,
    rec: &Recording,
    kind: SensorKind,
    axis: usize,
    tau0: f64,
) -> Option<(Curves, usize)> {
    let cols: Vec<&[f64]> = rec
        .axis_columns(kind, axis)
        .map(|c| c.data.as_slice())
        .collect();
    if cols.len() < 2 {
        return None;
    }
    let (mean, ns) = crate::allan::recording::cluster_mean(rec, kind, axis)?;
    let n = mean.len();
    // A τ with at least `MIN_BLOCKS` averaging blocks and a known EDF (scaled by `edf_scale`, capped by
    // `edf_cap`), its χ² interval.
    let dev = |p: &AnalysisPoint, dev: f64, edf_scale: f64| -> Option<(f64, Dev)> {
        let edf = edf_cap(p, n)? * edf_scale;
        (n / p.m.max(1) >= MIN_BLOCKS && dev > 0.0).then(|| {
            let (lo, hi) = confidence_interval(dev, edf, ONE_SIGMA_CI).unwrap_or((dev, dev));
            (p.tau_s, Dev { dev, lo, hi, edf })
        })
    };
    let cluster = octave(an, &mean[..], tau0)
        .iter()
        .filter_map(|p| dev(p, p.dev, 1.0))
        .collect();
    let singles: Vec<Vec<AnalysisPoint>> = cols.iter().map(|c| octave(an, &c[..n], tau0)).collect();
    let k = singles.iter().map(Vec::len).min().unwrap_or(0);
    let median_edf = 2.0 * ns as f64 / std::f64::consts::PI;
    let typical = (0..k)
        .filter_map(|j| {
            let devs: Vec<f64> = singles.iter().map(|s| s[j].dev).collect();
            dev(&singles[0][j], median(&devs), median_edf)
        })
        .collect();
    Some(((cluster, typical), ns))
}

/// The EDF of `p` (a τ of `n` samples), at most white FM's where fewer than `ACF_MIN_POINTS` blocks left the
/// noise type to the B1 ratio (or carried it from such a τ): at a handful of blocks that ratio calls a frequency
/// series' chance dip white or flicker PM, whose EDF is ten to thirty times the FM types' (measured: 77 and 161 at
/// 4 and 9 blocks of a cluster of random-walk and flicker sensors, against 4.5 and 11), and one low realisation
/// then reads as a confident gap. The sensors' outputs are rates: PM types (quantisation) live at short τ, where
/// the blocks are many and the lag-1 ACF identifies them.
fn edf_cap(p: &AnalysisPoint, n: usize) -> Option<f64> {
    let edf = p.edf?;
    if n / p.m.max(1) >= ACF_MIN_POINTS {
        return Some(edf);
    }
    Some(edf_for_kind(DevKind::Oadev, 0, p.m, n).map_or(edf, |w| edf.min(w)))
}

fn verdict(a: &[(f64, Dev)], b: &[(f64, Dev)], o: &CompareOptions) -> CurveVerdict {
    let (p, tol) = (o.p_false / 4.0, o.tolerance);
    let kb = if o.fitted_elsewhere { 2.0 } else { 1.0 };
    let taus: Vec<TauGap> = a
        .iter()
        .filter_map(|(t, da)| {
            let (_, db) = b.iter().find(|(tb, _)| (tb / t - 1.0).abs() < 1e-6)?;
            let gap = (da.dev / db.dev).ln();
            let z = gap / (0.5 / da.edf + kb * 0.5 / db.edf + tol * tol).sqrt();
            z.is_finite().then_some(TauGap {
                tau_s: *t,
                a: *da,
                b: *db,
                gap,
                z,
            })
        })
        .collect();
    let z: Vec<f64> = taus.iter().map(|t| t.z).collect();
    let neg: Vec<f64> = z.iter().map(|x| -x).collect();
    let threshold = scan_threshold(z.len(), p);
    let scan = if z.is_empty() {
        [f64::NEG_INFINITY; 2]
    } else {
        [scan_statistic(&z), scan_statistic(&neg)]
    };
    let significant = scan.iter().any(|&s| s > threshold);
    let off: Vec<f64> = taus
        .iter()
        .filter(|t| t.z.abs() > 2.0)
        .map(|t| t.tau_s)
        .collect();
    let where_tau_s = (significant && !off.is_empty()).then(|| {
        [
            off.iter().copied().fold(f64::INFINITY, f64::min),
            off.iter().copied().fold(0.0, f64::max),
        ]
    });
    CurveVerdict {
        scan,
        threshold,
        significant,
        where_tau_s,
        taus,
    }
}

/// Compares recording `b` (a simulation) with `a` (the real one). Both must have the same sample rate (within
/// 10⁻⁶).
pub fn compare(
    a: &Recording,
    b: &Recording,
    opts: &CompareOptions,
) -> Result<Comparison, TwinError> {
    let ta = a
        .sample_interval_s()
        .ok_or_else(|| TwinError::Invalid("first recording: fewer than two samples".into()))?;
    let tb = b
        .sample_interval_s()
        .ok_or_else(|| TwinError::Invalid("second recording: fewer than two samples".into()))?;
    if (ta / tb - 1.0).abs() > 1e-6 {
        return Err(TwinError::Invalid(format!(
            "sample rates differ: {} Hz and {} Hz",
            1.0 / ta,
            1.0 / tb
        )));
    }
    let mut an = Analyzer::new();
    let mut axes = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        for axis in 0..3 {
            let (Some((ca, na)), Some((cb, nb))) = (
                curves(&mut an, a, kind, axis, ta),
                curves(&mut an, b, kind, axis, tb),
            ) else {
                continue;
            };
            let cluster = verdict(&ca.0, &cb.0, opts);
            let typical = verdict(&ca.1, &cb.1, opts);
            axes.push(AxisComparison {
                axis: format!("{}{}", kind.prefix(), crate::recording::AXIS_NAMES[axis]),
                sensors: [na, nb],
                significant: cluster.significant || typical.significant,
                cluster,
                typical,
            });
        }
    }
    if axes.is_empty() {
        return Err(TwinError::Invalid(
            "no axis with at least two sensors in both recordings".into(),
        ));
    }
    let significant_axes = axes
        .iter()
        .filter(|a| a.significant)
        .map(|a| a.axis.clone())
        .collect();
    Ok(Comparison {
        options: *opts,
        axes,
        significant_axes,
    })
}

impl Comparison {
    /// A few lines for a person: per axis, reproduced or not, and where.
    pub fn summary(&self) -> String {
        let mut s = String::new();
        for a in &self.axes {
            let part = |name: &str, v: &CurveVerdict| -> String {
                match (v.significant, v.where_tau_s) {
                    (false, _) => format!("{name} reproduced"),
                    (true, Some([lo, hi])) => format!(
                        "{name} NOT reproduced at τ {}–{} s",
                        crate::allan::recording::round_sig(lo, 3),
                        crate::allan::recording::round_sig(hi, 3)
                    ),
                    (true, None) => format!("{name} NOT reproduced"),
                }
            };
            s.push_str(&format!(
                "{}: {}; {} (scan {:.1}/{:.1} vs {:.1})\n",
                a.axis,
                part("cluster", &a.cluster),
                part("typical sensor", &a.typical),
                a.cluster.scan[0].max(a.typical.scan[0]),
                a.cluster.scan[1].max(a.typical.scan[1]),
                a.cluster.threshold
            ));
        }
        s.push_str(&if self.significant_axes.is_empty() {
            format!(
                "every axis reproduced (p_false {} per axis)\n",
                self.options.p_false
            )
        } else {
            format!("not reproduced on: {}\n", self.significant_axes.join(", "))
        });
        s
    }
}

impl Comparison {
    /// The overlay plot: one panel per axis, the first recording's cluster and typical sensor against the
    /// second's, with their 68 % intervals (`.png` or `.svg`).
    pub fn plot(&self, path: &std::path::Path, title: &str) -> Result<(), crate::plot::PlotError> {
        use crate::plot::{Curve, Panel, Style, adev_panels};
        let curve = |v: &CurveVerdict, first: bool, style: Style, label: &str| {
            let d = |t: &TauGap| if first { t.a } else { t.b };
            Curve {
                label: Some(label.into()),
                points: v.taus.iter().map(|t| (t.tau_s, d(t).dev)).collect(),
                bars: v.taus.iter().map(|t| (t.tau_s, d(t).lo, d(t).hi)).collect(),
                style,
            }
        };
        let panels: Vec<Panel> = self
            .axes
            .iter()
            .map(|x| Panel {
                title: format!(
                    "{}{}",
                    x.axis,
                    if x.significant {
                        ": NOT reproduced"
                    } else {
                        ": reproduced"
                    }
                ),
                y_label: "Allan deviation".into(),
                curves: vec![
                    curve(&x.typical, true, Style::Thin(0), "real, typical sensor"),
                    curve(&x.typical, false, Style::Thin(1), "sim, typical sensor"),
                    curve(&x.cluster, true, Style::Bold, "real, cluster"),
                    curve(&x.cluster, false, Style::Model(3), "sim, cluster"),
                ],
            })
            .collect();
        adev_panels(path, title, &panels, 3)
    }

    /// The largest scan statistic over the axes, curves and directions, and its threshold.
    pub fn largest_scan(&self) -> (f64, f64) {
        let scan = self
            .axes
            .iter()
            .flat_map(|a| a.cluster.scan.iter().chain(&a.typical.scan))
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        (
            scan,
            self.axes
                .first()
                .map_or(f64::INFINITY, |a| a.cluster.threshold),
        )
    }
}
