//! The demo's statistics: the core's telemetry decoded on the ground, and the paper's Tables 1 and 2 recomputed
//! from it with their confidence intervals (see the module docs of [`super`] for where each number comes from).

use super::Row;
use super::replay::SingleSums;
use crate::allan::{self, AnalysisPoint, DevKind, TauSpec};
use crate::formats::telemetry::TelemetryLog;
use shared::bus::BusConfig;
use shared::calib::AXES;
use shared::pipeline::{ALLAN_CHANNELS, FUSED_CHANNEL0};
use shared::wire::frame::GROUPS;

/// Levels with fewer differences are neither plotted nor searched for the minimum (Stable32's ADEV stop rule,
/// τ ≤ T/5, leaves at least 4).
const MIN_DIFFERENCES: u32 = 4;

/// One level of one of the core's Allan curves: (octave k, deviation, differences).
pub(super) type Level = (usize, f64, u32);

/// What the ground decoded of the core's telemetry.
pub(super) struct Decoded {
    /// The fused samples (°/s, g).
    pub fused: Vec<[f64; AXES]>,
    /// The core's Allan curves per channel (96 sensors, then the 6 fused axes), levels with enough differences.
    pub core_allan: Vec<Vec<Level>>,
    /// The core's τ0, s.
    pub tau0_s: f64,
}

impl Decoded {
    /// Decodes what the core sent.
    pub fn from_telemetry(telemetry: &[u8]) -> Decoded {
        let log = TelemetryLog::decode(telemetry, &BusConfig::DEFAULT);
        let fused: Vec<[f64; AXES]> = log
            .fused()
            .map(|r| r.axes().map(|x| f64::from(x) / 1e6))
            .collect();
        let mut core_allan: Vec<Vec<Level>> = vec![Vec::new(); ALLAN_CHANNELS];
        let mut tau0_s = 1.0 / 18.9;
        for p in log.allan() {
            if let Some(c) = core_allan.get_mut(p.channel) {
                if p.count >= MIN_DIFFERENCES {
                    c.push((p.level, p.dev, p.count));
                }
                tau0_s = p.tau0_s;
            }
        }
        Decoded {
            fused,
            core_allan,
            tau0_s,
        }
    }

    /// The core's Allan curve of group `g`'s axis `a`.
    pub fn single(&self, g: usize, a: usize) -> &[Level] {
        &self.core_allan[g * AXES + a]
    }

    /// The core's Allan curve of the fused axis `a`.
    pub fn cluster(&self, a: usize) -> &[Level] {
        &self.core_allan[FUSED_CHANNEL0 + a]
    }

    /// τ of octave `k`, s.
    pub fn tau(&self, k: usize) -> f64 {
        self.tau0_s * (1u64 << k) as f64
    }
}

/// The tables, and the ground's ADEV of each fused axis (for the plot's intervals).
pub(super) struct Tables {
    /// Table 1 (RMS noise) per axis.
    pub table1: Vec<Row>,
    /// Table 2 (bias stability) per axis, and the τ of the cluster minimum.
    pub table2: Vec<(Row, f64)>,
    /// The ground's ADEV of each fused axis, with intervals.
    pub ground: Vec<Vec<AnalysisPoint>>,
    /// Largest relative difference between the core's ADEV of the fused axes and the ground's.
    pub core_vs_ground: f64,
}

impl Tables {
    /// Both tables from what the core sent and the single sensors' sums.
    pub fn compute(d: &Decoded, sums: &SingleSums) -> Tables {
        let mut t = Tables {
            table1: Vec::new(),
            table2: Vec::new(),
            ground: Vec::new(),
            core_vs_ground: 0.0,
        };
        let mut an = allan::Analyzer::new();
        for a in 0..AXES {
            let series: Vec<f64> = d.fused.iter().map(|v| v[a]).collect();
            let pts = an.analyze(
                DevKind::Adev,
                &series,
                d.tau0_s,
                &TauSpec::Octave,
                &allan::Options::default(),
            );
            // The core's integer ADEV of the fused axis must equal the ground's f64 ADEV of the same samples.
            for (k, dev, _) in d.cluster(a) {
                if let Some(p) = pts.iter().find(|p| p.m == 1 << k) {
                    t.core_vs_ground = t.core_vs_ground.max((dev / p.dev - 1.0).abs());
                }
            }
            t.table1.push(table1_row(sums, &series, a));
            t.table2.push(table2_row(d, &pts, a));
            t.ground.push(pts);
        }
        t
    }
}

/// Table 1 of axis `a`: the RMS over groups of the single sensors' standard deviations, the fused series'.
fn table1_row(sums: &SingleSums, series: &[f64], a: usize) -> Row {
    let n = series.len();
    let std = |s: f64, s2: f64| ((s2 - s * s / n as f64) / (n as f64 - 1.0)).max(0.0).sqrt() / 1e6;
    let single = (sums
        .sum
        .iter()
        .zip(&sums.sum2)
        .map(|(s, s2)| std(s[a], s2[a]).powi(2))
        .sum::<f64>()
        / GROUPS as f64)
        .sqrt();
    let mean = series.iter().sum::<f64>() / n as f64;
    let cluster =
        (series.iter().map(|x| (x - mean).powi(2)).sum::<f64>() / (n as f64 - 1.0)).sqrt();
    let u = (1.0 / (2.0 * (n as f64 - 1.0))).sqrt() * (1.0 + 1.0 / GROUPS as f64).sqrt();
    let r = single / cluster;
    Row {
        single,
        cluster,
        ratio: r,
        ratio_ci: [r * (-u).exp(), r * u.exp()],
    }
}

/// Table 2 of axis `a`: the minima of the core's curves (the median single, the cluster), the ratio's interval
/// from the ground's analysis `pts` of the fused axis; and the τ of the cluster minimum.
fn table2_row(d: &Decoded, pts: &[AnalysisPoint], a: usize) -> (Row, f64) {
    let n = d.fused.len();
    let min_of = |c: &[Level]| {
        c.iter()
            .filter(|x| x.2 >= 2)
            .min_by(|x, y| x.1.total_cmp(&y.1))
            .copied()
    };
    let singles: Vec<Level> = (0..GROUPS).filter_map(|g| min_of(d.single(g, a))).collect();
    let mut single_mins: Vec<f64> = singles.iter().map(|x| x.1).collect();
    single_mins.sort_by(f64::total_cmp);
    let single_bs = 0.5 * (single_mins[GROUPS / 2 - 1] + single_mins[GROUPS / 2]);
    let cmin = min_of(d.cluster(a)).unwrap_or((0, f64::NAN, 0));
    let at = pts.iter().find(|p| p.m == 1 << cmin.0);
    let half = |p: Option<&AnalysisPoint>| {
        p.and_then(|p| p.dev_lo.zip(p.dev_hi))
            .map_or(0.0, |(lo, hi)| 0.5 * (hi / lo).ln())
    };
    // The median single's uncertainty: the same noise type and m, one sensor's record, reduced by √groups.
    let s_single = {
        let m_single = singles.get(GROUPS / 2).map_or(cmin.0, |x| x.0);
        let alpha = pts
            .iter()
            .find(|p| p.m == 1 << m_single)
            .and_then(|p| p.alpha())
            .unwrap_or(0);
        allan::edf_for_kind(DevKind::Adev, alpha, 1 << m_single, n)
            .map_or(0.0, |e| 1.0 / (2.0 * e).sqrt())
            / (GROUPS as f64).sqrt()
    };
    let s = (half(at).powi(2) + s_single.powi(2)).sqrt();
    let r2 = single_bs / cmin.1;
    (
        Row {
            single: single_bs,
            cluster: cmin.1,
            ratio: r2,
            ratio_ci: [r2 * (-s).exp(), r2 * s.exp()],
        },
        d.tau(cmin.0),
    )
}
