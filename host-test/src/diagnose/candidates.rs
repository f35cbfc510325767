//! Candidate effects of one axis (levels, common modes, blocks, thermal), all fitted on the first half.

use super::analyse::UNEQUAL_LN_SPREAD;
use super::model::{Cross, Model, Share, TermLevels, Terms};
use super::periodic;
use super::sensors::{departures, drift_candidate};
use super::singles::{Half, octave_devs, weighted_mean};
use super::types::{Groups, Options};
use crate::allan::Analyzer;
use crate::allan::acov::AllanCov;
use crate::allan::median_to_mean;
use crate::allan::noisefit;
use crate::formats::csv::SensorKind;
use crate::stats::median;
use std::collections::BTreeMap;

/// A candidate effect of one axis.
#[derive(Clone, Debug)]
pub(super) struct Candidate {
    pub(super) kind: &'static str,
    /// Replaces the per-sensor level factors (heterogeneity) …
    pub(super) level: Option<Vec<f64>>,
    /// … or by levels that vary with τ, when offered so (they then take precedence over `level` in the model) …
    pub(super) level_terms: Option<TermLevels>,
    /// … and/or adds cross terms.
    pub(super) cross: Vec<Cross>,
    pub(super) groups: Groups,
    pub(super) params: serde_json::Value,
}

impl Candidate {
    /// The Allan-variance shape of what it adds (shared processes), for naming its region.
    pub(super) fn nature(&self) -> Option<Terms> {
        self.cross.iter().find_map(|c| match c {
            Cross::Shared { share, .. } => Some(share.part),
            Cross::Own { part, .. } => Some(*part),
            Cross::Thermal { .. } | Cross::SharedSine { .. } | Cross::OwnSine { .. } => None,
        })
    }

    pub(super) fn apply(&self, m: &mut Model) {
        if let Some(l) = &self.level {
            m.level = l.clone();
            m.level_terms = self.level_terms.clone();
        }
        m.cross.extend(self.cross.iter().cloned());
    }
}

/// The first half's four-term fits of the typical sensor (the per-τ median at its bias-corrected level) and of each
/// sensor: the curves whose ratio is a sensor's level that varies with τ ([`TermLevels`]).
pub(super) struct Fits {
    pub(super) typical: Terms,
    pub(super) sensors: Vec<Terms>,
}

pub(super) fn build(n: usize, chosen: &[&Candidate]) -> Model {
    let mut m = Model::independent(n);
    for c in chosen {
        c.apply(&mut m);
    }
    m
}

pub(super) struct AxisWork<'a> {
    pub(super) kind: SensorKind,
    pub(super) axis: usize,
    pub(super) groups: Vec<usize>,
    pub(super) series: Vec<&'a [f64]>,
}

/// A weighted least-squares row on the five terms: (basis, observation, weight).
pub(super) type Row5 = ([f64; 5], f64, f64);

/// The shared terms fitted (non-negative) with only the terms in `subset`; `None` if all come out zero.
pub(super) fn fit_subset(rows: &[Row5], subset: &[usize]) -> Option<Terms> {
    let masked: Vec<Row5> = rows
        .iter()
        .map(|(b, y, w)| (Terms(*b).only(subset).0, *y, *w))
        .collect();
    let t = Terms(noisefit::nnls(&masked)?);
    t.0.iter().any(|&c| c > 0.0).then_some(t)
}

/// The shared and independent parts of the sensors `members` on the first half: the mean cross Allan covariance
/// per τ from the members' mean (`|M|²σ²_mean − Σσ²_i` over the |M|(|M|−1) pairs) as rows for the five terms,
/// weighted by its χ² scatter (fitted by [`fit_subset`]), and the rest of the typical member variance fitted with
/// four terms.
pub(super) fn shared_fit(
    an: &mut Analyzer,
    first: &[&[f64]],
    h: &Half,
    members: &[usize],
    tau0: f64,
) -> Option<(Vec<Row5>, Terms)> {
    let k_m = members.len();
    if k_m < 2 {
        return None;
    }
    let sub: Vec<&[f64]> = members
        .iter()
        .filter_map(|&i| first.get(i).copied())
        .collect();
    let w = vec![1.0 / k_m as f64; k_m];
    let mean = weighted_mean(&sub, &w);
    let pts = octave_devs(an, &mean, tau0);
    let mut shared_rows = Vec::new();
    let mut indep_rows = Vec::new();
    let km = k_m as f64;
    for k in 0..h.len() {
        let Some(p) = pts.iter().find(|p| p.m == h.m[k]) else {
            continue;
        };
        let a = p.dev * p.dev;
        let d: Vec<f64> = members.iter().map(|&i| h.singles[i][k]).collect();
        let sum_d: f64 = d.iter().sum();
        let c = (km * km * a - sum_d) / (km * (km - 1.0));
        let sd = a * (2.0 / h.edf[k]).sqrt() * km / (km - 1.0);
        if sd > 0.0 {
            shared_rows.push((Terms::basis(h.tau_s[k]), c, 1.0 / (sd * sd)));
        }
        let typ = median(&d) * median_to_mean(h.single_edf[k]);
        let e = typ - c.max(0.0);
        if e > 0.0 {
            let b = Terms::basis(h.tau_s[k]);
            indep_rows.push((
                [b[0], b[1], b[2], b[3]],
                e,
                h.single_edf[k] * km / 2.0 / (e * e),
            ));
        }
    }
    let e = noisefit::nnls(&indep_rows)?;
    Some((shared_rows, Terms([e[0], e[1], e[2], e[3], 0.0])))
}

/// Blocks of sensors from the Allan correlation matrix averaged over `levels` (level, weight): average-linkage
/// clustering, merging two clusters while their mean cross correlation exceeds `merge_z` times its null standard
/// deviation `√(Σ w_l²·1.5/T_l)·√(D_A D_B/(|A||B|))` (w normalised, T_l the level's differences; 1.5 accounts for
/// adjacent differences' correlation; `D = 1 + (|A|−1)ρ̄_A` the design effect of a cluster whose members share a
/// process).
pub(super) fn blocks(ac: &AllanCov, levels: &[(usize, f64)], merge_z: f64) -> Vec<Vec<usize>> {
    let n = ac.n;
    let total: f64 = levels.iter().map(|&(_, w)| w).sum();
    let mut clusters: Vec<Vec<usize>> = (0..n).map(|i| vec![i]).collect();
    if total <= 0.0 || n < 2 {
        return clusters;
    }
    let mut r = vec![0.0; n * n];
    let mut var = 0.0;
    for &(l, w) in levels {
        let wl = w / total;
        for (x, c) in r.iter_mut().zip(ac.correlation(l)) {
            *x += wl * c;
        }
        var += wl * wl * 1.5 / ac.terms.get(l).copied().unwrap_or(1).max(1) as f64;
    }
    let sd = var.sqrt();
    // Mean correlation within a cluster (0 for a single sensor).
    let within = |c: &[usize]| -> f64 {
        let (mut s, mut k) = (0.0, 0usize);
        for (x, &i) in c.iter().enumerate() {
            for &j in &c[x + 1..] {
                s += r[i * n + j];
                k += 1;
            }
        }
        if k == 0 { 0.0 } else { (s / k as f64).max(0.0) }
    };
    loop {
        let mut best: Option<(f64, usize, usize)> = None;
        for a in 0..clusters.len() {
            for b in a + 1..clusters.len() {
                let (ca, cb) = (&clusters[a], &clusters[b]);
                let mut s = 0.0;
                for &i in ca {
                    for &j in cb {
                        s += r[i * n + j];
                    }
                }
                let (na, nb) = (ca.len() as f64, cb.len() as f64);
                // The pairs' estimates are not independent when each side shares a process: the design effect
                // (1 + (n−1)ρ) of each side multiplies the variance of their mean.
                let deff = (1.0 + (na - 1.0) * within(ca)) * (1.0 + (nb - 1.0) * within(cb));
                let z = s / (na * nb) / (sd * (deff / (na * nb)).sqrt());
                if best.is_none_or(|(bz, _, _)| z > bz) {
                    best = Some((z, a, b));
                }
            }
        }
        match best {
            Some((z, a, b)) if z > merge_z => {
                let moved = clusters.remove(b);
                clusters[a].extend(moved);
                clusters[a].sort_unstable();
            }
            _ => break,
        }
    }
    clusters
}

/// Thermal coefficients: per sensor, least squares of block means of the data on block means of temperature.
pub(super) fn thermal_betas(series: &[&[f64]], temp: &[f64], block: usize) -> Vec<f64> {
    let block = block.max(1);
    let blocks = temp.len() / block;
    let bm = |x: &[f64]| -> Vec<f64> {
        x.chunks_exact(block)
            .take(blocks)
            .map(|c| c.iter().sum::<f64>() / block as f64)
            .collect()
    };
    let t = bm(temp);
    let tm = t.iter().sum::<f64>() / t.len().max(1) as f64;
    let stt: f64 = t.iter().map(|x| (x - tm).powi(2)).sum();
    series
        .iter()
        .map(|s| {
            let y = bm(s);
            let ym = y.iter().sum::<f64>() / y.len().max(1) as f64;
            let sty: f64 = t.iter().zip(&y).map(|(a, b)| (a - tm) * (b - ym)).sum();
            if stt > 0.0 { sty / stt } else { 0.0 }
        })
        .collect()
}

/// The candidates of one axis, all fitted on the first half: levels, blocks, one sensor's drift, a process shared
/// by all, a periodic interference (one sensor's own lines `own`, found beforehand, or a shared line), thermal.
#[allow(clippy::too_many_arguments)] // the first half's data, statistics and model, each used; no natural bundle
pub(super) fn candidates(
    an: &mut Analyzer,
    w: &AxisWork,
    first: &[&[f64]],
    hf: &Half,
    tau0: f64,
    temp: Option<&[f64]>,
    typ: &Terms,
    fits: &Fits,
    opts: &Options,
    own: &[periodic::OwnLine],
) -> Vec<Candidate> {
    let ns = first.len();
    let mut cands: Vec<Candidate> = level_candidate(w, hf, ns, fits)
        .into_iter()
        .flatten()
        .collect();
    let cl = correlation_blocks(first, tau0, typ, opts.merge_z);
    let partial = !cl.is_empty() && cl.iter().all(|c| c.len() <= ns - 2);
    if partial {
        cands.extend(block_candidate(an, w, first, hf, tau0, &cl));
    }
    // One sensor's departure at long τ is its own (`sensor_drift`), and is kept out of the shared fits: a shared
    // process shows in the cross covariances, one sensor's does not.
    // A sensor with its own (confirmed) line is `periodic`, not a drift, and is kept out of the shared fits too.
    let lined: Vec<usize> = own
        .iter()
        .filter(|o| o.heldout_score > o.heldout_threshold)
        .map(|o| o.sensor)
        .collect();
    let mut deps = departures(an, first, hf, typ, tau0, opts);
    deps.retain(|d| !lined.contains(&d.sensor));
    cands.extend(drift_candidate(w, &deps));
    let members: Vec<usize> = (0..ns)
        .filter(|i| !deps.iter().any(|d| d.sensor == *i) && !lined.contains(i))
        .collect();
    cands.extend(shared_candidates(
        an, w, first, hf, tau0, temp, partial, &members,
    ));
    cands.extend(periodic::periodic_candidates(
        w,
        first,
        own,
        &members,
        tau0,
        opts.p_false,
    ));
    if let Some(t) = temp {
        cands.push(thermal_candidate(w, first, t, tau0));
    }
    cands
}

/// Each sensor's deviation relative to the typical one: the median over τ of `√(singles[i][k] / typical[k])`
/// (Allan variances, at the same τ); `None` unless every ratio is finite and positive.
pub(crate) fn deviation_ratios(singles: &[Vec<f64>], typical: &[f64]) -> Option<Vec<f64>> {
    let ratio: Vec<f64> = singles
        .iter()
        .map(|s| {
            let l: Vec<f64> = s
                .iter()
                .zip(typical)
                .map(|(a, t)| 0.5 * (a / t).ln())
                .collect();
            median(&l).exp()
        })
        .collect();
    ratio
        .iter()
        .all(|r| r.is_finite() && *r > 0.0)
        .then_some(ratio)
}

/// Heterogeneity: each sensor's level relative to the typical one (median over τ of the deviation ratio), as
/// `outlier_sensor` or `unequal_noise`, offered twice: with that one factor per sensor, and with each sensor's level
/// as it varies with τ, from the first half's fits (`fits`, [`TermLevels`]), corrected toward the measured ratios
/// where the fits miss them ([`TermLevels::shrunk`]). Parts differ term by term; but a
/// single sensor's fit also carries its long-τ estimation error, which the one factor (a median over every τ) does
/// not: on the null of unequal parts (`tests/diagnose_false_alarms.rs`) either form alone left gaps the other
/// closes, 14 and 13 false alarms in 400 records, both together 8.
fn level_candidate(w: &AxisWork, hf: &Half, ns: usize, fits: &Fits) -> Option<[Candidate; 2]> {
    let ratio = deviation_ratios(&hf.singles[..ns.min(hf.singles.len())], &hf.typical)?;
    let outliers: Vec<usize> = (0..ns).filter(|&i| ratio[i] >= 2.0).collect();
    let rest: Vec<f64> = (0..ns)
        .filter(|i| !outliers.contains(i))
        .map(|i| ratio[i].ln())
        .collect();
    let rest_mean = rest.iter().sum::<f64>() / rest.len().max(1) as f64;
    let ln_spread = (rest.iter().map(|x| (x - rest_mean).powi(2)).sum::<f64>()
        / (rest.len().max(2) - 1) as f64)
        .sqrt();
    // A few sensors (at most one in sixteen) far above an otherwise homogeneous rest — by a factor 2 and by four
    // times the rest's log-spread — are outliers; a broad spread of levels is unequal noise.
    let few = !outliers.is_empty()
        && outliers.len() <= (ns / 16).max(1)
        && ln_spread < UNEQUAL_LN_SPREAD
        && outliers
            .iter()
            .all(|&i| ratio[i].ln() - rest_mean > (4.0 * ln_spread).max(std::f64::consts::LN_2));
    let (kind, groups) = if few {
        (
            "outlier_sensor",
            outliers.iter().map(|&i| w.groups[i]).collect(),
        )
    } else {
        ("unequal_noise", w.groups.clone())
    };
    let params = |varies: bool| {
        serde_json::json!({
            "deviation_ratio_to_typical": (0..ns).map(|i| (w.groups[i].to_string(), ratio[i])).collect::<BTreeMap<_, _>>(),
            "ln_spread": ln_spread,
            "level_varies_with_tau": varies,
        })
    };
    let constant = Candidate {
        kind,
        level: Some(ratio.iter().map(|r| r * r).collect()),
        level_terms: None,
        cross: Vec::new(),
        groups: Groups::List(groups),
        params: params(false),
    };
    let varying = Candidate {
        level_terms: Some(
            TermLevels {
                typical: fits.typical,
                own: fits.sensors.clone(),
                tau_max_s: hf.tau_s.last().copied().unwrap_or(0.0),
                measured: Vec::new(),
            }
            .shrunk(
                &hf.tau_s,
                &hf.single_edf,
                &hf.singles
                    .iter()
                    .take(ns)
                    .map(|s| {
                        s.iter()
                            .zip(&hf.typical)
                            .map(|(a, t)| a / t.max(1e-300))
                            .collect()
                    })
                    .collect::<Vec<_>>(),
            ),
        ),
        params: params(true),
        ..constant.clone()
    };
    Some([constant, varying])
}

/// Blocks: clusters of the Allan correlation matrix (of two sensors or more; empty below four sensors).
/// With equal weights a set of blocks and one cluster-wide process of the same total cross covariance predict the
/// same cluster variance, so the held-out gap cannot tell them apart: the structure decides which is offered.
/// Two bands: every level weighted by its differences (the white region dominates), then, if no sensors cluster
/// there, the flicker and random-walk levels weighted equally (a block sharing only a slow process).
fn correlation_blocks(first: &[&[f64]], tau0: f64, typ: &Terms, merge_z: f64) -> Vec<Vec<usize>> {
    if first.len() < 4 {
        return Vec::new();
    }
    let ac = AllanCov::compute(first, tau0, 30);
    let all: Vec<(usize, f64)> = (0..ac.tau_s.len())
        .filter(|&l| ac.terms[l] >= 30)
        .map(|l| (l, ac.terms[l] as f64))
        .collect();
    // A level's evidence for a shared slow process: the correlation it adds there is its share of the typical
    // variance times the process's own share, measured to `√(1.5/T_l)`; weighting each level by `T_l × share`
    // (signal over variance) lets the many differences of the τ where the slow terms are only part of the variance
    // count, not only the few of the τ where they dominate (pairs sharing flicker were missed that way).
    let slow: Vec<(usize, f64)> = all
        .iter()
        .map(|&(l, t)| (l, t * slow_share(typ, ac.tau_s[l])))
        .filter(|&(_, w)| w > 0.0)
        .collect();
    let found = |levels: &[(usize, f64)], merge_z: f64| -> Vec<Vec<usize>> {
        blocks(&ac, levels, merge_z)
            .into_iter()
            .filter(|c| c.len() >= 2)
            .collect()
    };
    let fast = found(&all, merge_z);
    if fast.is_empty() && !slow.is_empty() {
        found(&slow, SLOW_MERGE * merge_z)
    } else {
        fast
    }
}

/// The share of the typical variance at `tau_s` that its slow terms (flicker, random walk, ramp) make, below
/// [`SLOW_SHARE_MIN`] counted as 0.
fn slow_share(typ: &Terms, tau_s: f64) -> f64 {
    let all = typ.avar(tau_s);
    let share = if all > 0.0 {
        typ.only(&[2, 3, 4]).avar(tau_s) / all
    } else {
        0.0
    };
    if share >= SLOW_SHARE_MIN { share } else { 0.0 }
}

/// The slow band's merging threshold relative to `merge_z` (8 → 5: with 16 sensors' 120 pairs, 120·P(Z > 5) =
/// 3·10⁻⁵). Its correlations are measured on few differences, so the white band's margin would leave a pair sharing
/// flicker unmerged; a block found here is still only a candidate, named only if the held-out half wants it.
const SLOW_MERGE: f64 = 0.625;

/// Least share of the typical variance the slow terms must make at a τ for it to count in the slow band.
const SLOW_SHARE_MIN: f64 = 0.1;

/// `block_common_mode`: one shared process (five terms) per block, if every block's fit succeeds.
fn block_candidate(
    an: &mut Analyzer,
    w: &AxisWork,
    first: &[&[f64]],
    hf: &Half,
    tau0: f64,
    cl: &[Vec<usize>],
) -> Option<Candidate> {
    let mut cross = Vec::new();
    let mut per_block = Vec::new();
    for c in cl {
        if let Some((rows, e)) = shared_fit(an, first, hf, c, tau0)
            && let Some(s) = fit_subset(&rows, &[0, 1, 2, 3, 4])
        {
            cross.push(Cross::Shared {
                members: c.clone(),
                share: Share {
                    part: s,
                    independent: e,
                },
            });
            per_block.push(serde_json::json!({
                "groups": c.iter().map(|&i| w.groups[i]).collect::<Vec<_>>(),
                "shared": s.physical(),
            }));
        }
    }
    (cross.len() == cl.len()).then(|| Candidate {
        kind: "block_common_mode",
        level: None,
        level_terms: None,
        cross,
        groups: Groups::Blocks(
            cl.iter()
                .map(|c| c.iter().map(|&i| w.groups[i]).collect())
                .collect(),
        ),
        params: serde_json::json!({ "blocks": per_block }),
    })
}

/// A process shared by all sensors, fitted in each shape on its own so that the held-out check, not the first
/// half's noise, decides between them: fast (quantisation + white), flicker, or both (`common_mode`), and slow
/// (random walk + ramp, `common_mode_drift`). (A flicker + slow shape, tried, took shared flicker for a drift.)
/// With blocks found (`partial`), only the slow shape is offered.
#[allow(clippy::too_many_arguments)] // the first half's data and statistics, each used; no natural bundle
fn shared_candidates(
    an: &mut Analyzer,
    w: &AxisWork,
    first: &[&[f64]],
    hf: &Half,
    tau0: f64,
    temp: Option<&[f64]>,
    partial: bool,
    all: &[usize],
) -> Vec<Candidate> {
    let Some((rows, e)) = shared_fit(an, first, hf, all, tau0) else {
        return Vec::new();
    };
    let mut cands = Vec::new();
    let subsets: [&[usize]; 4] = [&[0, 1], &[2], &[0, 1, 2], &[3, 4]];
    for subset in subsets {
        let Some(part) = fit_subset(&rows, subset) else {
            continue;
        };
        let slow = subset.contains(&3);
        if partial && !slow {
            continue;
        }
        let white = |t: &Terms| t.0[0] / tau0 + t.0[1];
        let tot = Terms(std::array::from_fn(|k| part.0[k] + e.0[k]));
        let rho_white = if white(&tot) > 0.0 {
            white(&part) / white(&tot)
        } else {
            0.0
        };
        let rho_flicker = if tot.0[2] > 0.0 {
            part.0[2] / tot.0[2]
        } else {
            0.0
        };
        let mut params = serde_json::json!({
            "rho_white": rho_white,
            "rho_flicker": rho_flicker,
            "shared_random_walk": (3.0 * part.0[3]).sqrt(),
            "shared_ramp": (2.0 * part.0[4]).sqrt(),
            "shared": part.physical(),
        });
        if slow
            && temp.is_none()
            && let Some(o) = params.as_object_mut()
        {
            o.insert(
                "temperature".into(),
                "not recorded: a thermal cause cannot be separated from other shared drifts".into(),
            );
        }
        cands.push(Candidate {
            kind: if slow {
                "common_mode_drift"
            } else {
                "common_mode"
            },
            level: None,
            level_terms: None,
            cross: vec![Cross::Shared {
                members: all.to_vec(),
                share: Share {
                    part,
                    independent: e,
                },
            }],
            groups: Groups::List(all.iter().map(|&i| w.groups[i]).collect()),
            params,
        });
    }
    cands
}

/// `thermal`: each sensor's coefficient on the measured temperature (10-s block means).
fn thermal_candidate(w: &AxisWork, first: &[&[f64]], t: &[f64], tau0: f64) -> Candidate {
    let ns = first.len();
    let block = ((10.0 / tau0).round() as usize).max(1);
    let beta = thermal_betas(first, t, block);
    let unit = if w.kind == SensorKind::Gyro {
        "deg/s/degC"
    } else {
        "g/degC"
    };
    let mean = beta.iter().sum::<f64>() / beta.len().max(1) as f64;
    Candidate {
        kind: "thermal",
        level: None,
        level_terms: None,
        cross: vec![Cross::Thermal { beta: beta.clone() }],
        groups: Groups::List(w.groups.clone()),
        params: serde_json::json!({
            "beta": (0..ns).map(|i| (w.groups[i].to_string(), beta[i])).collect::<BTreeMap<_, _>>(),
            "shared_beta": mean,
            "unit": unit,
        }),
    }
}
