//! The algorithm behind [`diagnose`](super::diagnose): per axis, measure, fit the candidates on the first half,
//! select them on the second (the phases are listed in the module doc of `diagnose`).

use super::candidates::{AxisWork, Candidate, Fits, build, candidates};
use super::model::{Cross, Model, Terms};
use super::prediction::{
    Gaps, PointGap, evaluate, excess, scan_statistic, scan_threshold, significant,
};
use super::selection::{AxisState, acts, axis_label, select, sibling};
use super::sensors::confirmed;
use super::singles::{Half, Shape, octave, octave_devs, octave_halves, terms_of, weighted_mean};
use super::summary::{gains, merge_effects, regions, tau_rows};
use super::types::{
    AxisCurves, AxisFit, AxisReport, DiagnoseError, Effect, Groups, HeldOut, MIN_SAMPLES, Measured,
    Options, Report, WeightRule,
};
use super::{periodic, quiet, steps, unexplained};
use crate::allan::noisefit;
use crate::allan::noisefit::NoiseFit;
use crate::allan::{AnalysisPoint, Analyzer, Halves};
use crate::formats::csv::{AXIS_NAMES, Recording, SensorKind};
use crate::stats::{median, rms};
use crate::twin::terms_fit;
use rayon::prelude::*;
use std::collections::BTreeMap;

/// Log-spread of sensor levels (deviation ratios) above which the others are not "homogeneous" and the effect is
/// unequal noise rather than outlier sensors.
pub(super) const UNEQUAL_LN_SPREAD: f64 = 0.3;

/// Share of the best candidate's χ² reduction that `thermal` must reach to be preferred to it.
pub(super) const THERMAL_PREFERENCE: f64 = 0.8;

/// Runs the diagnosis on a recording (all sensor columns; `temp_c` used when present). Phases: the axes
/// (`axis_works`), each axis measured and its candidates selected (`analyse_axis`), the second look at axes
/// without an effect (`retest_quiet_axes`), and each axis's report (`report_axis`).
pub fn diagnose(rec: &Recording, opts: &Options) -> Result<Report, DiagnoseError> {
    let tau0 = rec.sample_interval_s().ok_or(DiagnoseError::NoTimeBase)?;
    let n = rec.len();
    if n < MIN_SAMPLES {
        return Err(DiagnoseError::TooShort { samples: n });
    }
    let raw = axis_works(rec);
    if raw.is_empty() {
        return Err(DiagnoseError::NoAxis);
    }
    // One sensor's bias step, found against its neighbours and removed before anything else is measured. Its
    // false-alarm budget is a quarter of the whole record's, shared by the axes: a false step costs two or three
    // false effects (the step, and the departure its removal leaves on the axis, named `unexplained` or as a shared
    // process). The record's whole budget (`p_false/axes`) named 2 false steps on the 800 swept null records, a
    // quarter of it 1; the acceptance steps are found at either (docs/diagnose.md).
    let p_step = opts.p_false / (4 * raw.len()) as f64;
    // The axes are independent until `retest_quiet_axes`: each phase runs them in parallel (rayon; results in axis
    // order, each axis computed exactly as alone, so the report does not depend on the threads).
    let found: Vec<Vec<steps::Step>> = raw
        .par_iter()
        .map(|w| steps::find(&w.series, p_step))
        .collect();
    let fixed: Vec<Vec<Option<Vec<f64>>>> = raw
        .par_iter()
        .zip(&found)
        .map(|(w, st)| {
            (0..w.series.len())
                .map(|i| {
                    st.iter()
                        .find(|s| s.sensor == i)
                        .map(|s| steps::remove(w.series[i], s))
                })
                .collect()
        })
        .collect();
    let works: Vec<AxisWork> = raw
        .iter()
        .zip(&fixed)
        .map(|(w, f)| AxisWork {
            series: w
                .series
                .iter()
                .zip(f)
                .map(|(s, c)| c.as_deref().unwrap_or(s))
                .collect(),
            groups: w.groups.clone(),
            ..*w
        })
        .collect();
    let temp = rec
        .temp_c
        .as_deref()
        .filter(|t| t.len() >= n && t.iter().all(|x| x.is_finite()));
    // The shared-disturbance scan needs nothing of the axes: it runs beside them.
    let (disturbances, mut states) = rayon::join(
        || quiet::find(rec, opts.p_false),
        || -> Vec<AxisState> {
            works
                .par_iter()
                .map_init(Analyzer::new, |an, w| analyse_axis(an, w, tau0, temp, opts))
                .collect()
        },
    );
    retest_quiet_axes(&works, &mut states, opts);

    let parts: Vec<Assembled> = works
        .par_iter()
        .zip(states)
        .map_init(Analyzer::new, |an, (w, st)| {
            let mut part = Assembled::default();
            report_axis(an, w, st, tau0, opts, &mut part);
            part
        })
        .collect();
    let mut out = Assembled::default();
    for part in parts {
        out.append(part);
    }
    let Assembled {
        axes,
        effects,
        curves,
        fitted,
        gaps,
        unexplained,
    } = out;
    Ok(Report {
        gap_before: rms(gaps.fit_before),
        gap_after: rms(gaps.fit_after),
        heldout: HeldOut {
            gap_before: rms(gaps.held_before),
            gap_after: rms(gaps.held_after),
            rms_before: rms(gaps.raw_before),
            rms_after: rms(gaps.raw_after),
        },
        effects: merge_effects(effects)
            .into_iter()
            .chain(step_effects(&works, &found, tau0))
            .chain(unexplained)
            .collect(),
        axes,
        samples: n,
        tau0_s: tau0,
        weights: opts.weights,
        temperature: temp.is_some(),
        min_blocks: opts.min_blocks,
        p_false: opts.p_false,
        disturbances,
        curves,
        fitted,
    })
}

/// The axes with at least two sensors, gyro x y z then accel x y z.
pub(super) fn axis_works(rec: &Recording) -> Vec<AxisWork<'_>> {
    let mut works = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        for axis in 0..3 {
            let cols: Vec<_> = rec
                .columns
                .iter()
                .filter(|c| c.kind == kind && c.axis == axis)
                .collect();
            if cols.len() >= 2 {
                works.push(AxisWork {
                    kind,
                    axis,
                    groups: cols.iter().map(|c| c.group).collect(),
                    series: cols.iter().map(|c| c.data.as_slice()).collect(),
                });
            }
        }
    }
    works
}

/// Weights of the cluster mean under `rule`, from the sensors' first-half noise fits.
fn weights(rule: WeightRule, singles: &[NoiseFit]) -> Vec<f64> {
    let ns = singles.len();
    match rule {
        WeightRule::Equal => vec![1.0 / ns as f64; ns],
        WeightRule::InverseVariance => {
            let inv: Vec<f64> = singles
                .iter()
                .map(|s| 1.0 / s.white.powi(2).max(1e-300))
                .collect();
            let sum: f64 = inv.iter().sum();
            inv.iter().map(|v| v / sum).collect()
        }
    }
}

/// The per-τ median of the sensors' deviations (the typical sensor's curve); τ, block count, noise type, EDF and
/// interval are the first sensor's (the interval is not recomputed about the median).
fn median_curve(pts: &[Vec<AnalysisPoint>]) -> Vec<AnalysisPoint> {
    (0..pts.iter().map(Vec::len).min().unwrap_or(0))
        .map(|k| {
            let devs: Vec<f64> = pts.iter().map(|p| p[k].dev).collect();
            AnalysisPoint {
                dev: median(&devs),
                ..pts[0][k]
            }
        })
        .collect()
}

/// The sensors' RMS misfit to their own four-term fits (`singles`) and band-limited fits, on the first half's points
/// `pts_first`.
fn model_misfit(pts_first: &[Vec<AnalysisPoint>], singles: &[NoiseFit], tau0: f64) -> [f64; 2] {
    let misfit_of = |fits: &[(NoiseFit, Option<noisefit::LowPass>)]| {
        rms(pts_first.iter().zip(fits).flat_map(|(p, (f, lp))| {
            p.iter().filter(|q| q.dev > 0.0).map(move |q| {
                let cut =
                    f.white.powi(2) / q.tau_s * (1.0 - lp.map_or(1.0, |l| l.white_factor(q.tau_s)));
                (q.dev / (f.avar(q.tau_s) - cut).max(1e-300).sqrt()).ln()
            })
        }))
    };
    let four: Vec<(NoiseFit, Option<noisefit::LowPass>)> =
        singles.iter().map(|f| (*f, None)).collect();
    let banded: Vec<(NoiseFit, Option<noisefit::LowPass>)> = pts_first
        .iter()
        .map(|p| noisefit::fit_band_limited(p, tau0))
        .collect();
    [misfit_of(&four), misfit_of(&banded)]
}

/// The typical sensor's noise shape on the first half `first`: the Gauss–Markov terms of the twin's composite fit
/// ([`terms_fit`]) of its curve `typical_pts`, their number chosen on the first half's two quarters (so the held-out
/// half stays out of it), and the bandwidth put to the same held-out test (`terms_fit::fit_band_tested`: a
/// Gauss–Markov bump can pass for a single-pole roll-off in `noisefit::fit_band_limited`'s look at short τ). Returns
/// the composite terms and whether the bandwidth is kept.
fn typical_shape_fit(
    an: &mut Analyzer,
    first: &[&[f64]],
    typical_pts: &[AnalysisPoint],
    bandwidth: Option<&noisefit::LowPass>,
    tau0: f64,
) -> (crate::twin::NoiseTerms, bool) {
    let q = first.iter().map(|s| s.len()).min().unwrap_or(0) / 2;
    // The median curve takes its τ, EDF and noise types from the first sensor's points and only the deviations
    // from the others: those are measured without the noise identification (the same values).
    let quarter = |an: &mut Analyzer, r: std::ops::Range<usize>| {
        let pts: Vec<Vec<AnalysisPoint>> = first
            .iter()
            .filter_map(|s| s.get(r.clone()))
            .enumerate()
            .map(|(i, s)| match i {
                0 => octave(an, s, tau0),
                _ => octave_devs(an, s, tau0),
            })
            .collect();
        terms_fit::Obs::of(&median_curve(&pts))
    };
    let (a, b) = (quarter(an, 0..q), quarter(an, q..2 * q));
    let spec = terms_fit::Spec {
        tau0_s: tau0,
        band: bandwidth,
        lines: false,
    };
    terms_fit::fit_band_tested(&terms_fit::Obs::of(typical_pts), Some([&a, &b]), &spec)
}

/// The typical sensor's shape from its composite `fitted` terms; with no Gauss–Markov term, its five terms `typ`.
fn typical_shape(fitted: crate::twin::NoiseTerms, typ: Terms, tau0: f64) -> Shape {
    if fitted.gauss_markov.is_empty() {
        return Shape {
            five: typ,
            gm: Vec::new(),
            tau0_s: tau0,
        };
    }
    Shape {
        five: Terms(fitted.avar_coefficients()),
        gm: fitted.gauss_markov,
        tau0_s: tau0,
    }
}

/// Adds what is named on one sensor's own evidence to `chosen`: a sensor's own drift, confirmed on the held-out
/// half, and a sensor's own line, found on the first half and confirmed at its period on the held-out half.
fn name_per_sensor(
    cands: &[Candidate],
    chosen: &mut Vec<usize>,
    hh: &Half,
    typ: &Terms,
    opts: &Options,
) {
    if let Some(c) = cands.iter().position(|c| c.kind == "sensor_drift")
        && !chosen.contains(&c)
        && cands[c].cross.iter().any(|x| match x {
            Cross::Own { sensor, .. } => confirmed(hh, typ, *sensor, opts),
            _ => false,
        })
    {
        chosen.push(c);
    }
    if let Some(c) = cands.iter().position(|c| {
        c.kind == "periodic" && c.cross.iter().any(|x| matches!(x, Cross::OwnSine { .. }))
    }) && !chosen.contains(&c)
    {
        chosen.push(c);
    }
}

/// Phase 1 of an axis: single sensors and the typical sensor, the three halves measured (first, held-out, whole),
/// the candidates fitted on the first half and selected on the held-out one.
fn analyse_axis(
    an: &mut Analyzer,
    w: &AxisWork,
    tau0: f64,
    temp: Option<&[f64]>,
    opts: &Options,
) -> AxisState {
    let half = w.series[0].len() / 2;
    let first: Vec<&[f64]> = w.series.iter().map(|s| &s[..half]).collect();
    let second: Vec<&[f64]> = w.series.iter().map(|s| &s[half..]).collect();

    // Single sensors of both halves and of the whole (the whole's sums from the halves'), the typical sensor of the
    // first half.
    let (mut pts_first, mut pts_held, mut pts_whole) = (Vec::new(), Vec::new(), Vec::new());
    for ((s, f), h) in w.series.iter().zip(&first).zip(&second) {
        let Halves {
            first: f,
            second: h,
            whole: a,
        } = match s.len() / 2 == half {
            true => octave_halves(an, s, tau0),
            // A sensor of another length than the first: its parts as they are cut above, one pass each.
            false => Halves {
                first: octave(an, f, tau0),
                second: octave_devs(an, h, tau0),
                whole: octave_devs(an, s, tau0),
            },
        };
        pts_first.push(f);
        pts_held.push(h);
        pts_whole.push(a);
    }
    let singles: Vec<NoiseFit> = pts_first.iter().map(|p| noisefit::fit(p)).collect();
    // The typical sensor of the first half (the per-τ median of the sensors' deviations) and its baseline noise
    // model: the four terms, with its single-pole bandwidth when the curve shows one and the roll-off holds on the
    // held-out quarters; otherwise its plain four-term fit.
    let typical_pts = median_curve(&pts_first);
    let (banded, cut) = noisefit::fit_band_limited(&typical_pts, tau0);
    let (fitted, band_kept) = typical_shape_fit(an, &first, &typical_pts, cut.as_ref(), tau0);
    let (typical, bandwidth) = if band_kept {
        (banded, cut)
    } else {
        (noisefit::fit(&typical_pts), None)
    };
    let typ_terms = terms_of(&typical);
    let model_misfit = model_misfit(&pts_first, &singles, tau0);
    let wts = weights(opts.weights, &singles);
    let shape = typical_shape(fitted, typ_terms, tau0);

    let mb = opts.min_blocks;
    // The cluster means of the halves; the whole's is the two end to end (each sample's weighted sum is computed
    // alike, so it is the same, bit for bit, as the whole's own).
    let mean_first = weighted_mean(&first, &wts);
    let mean_held = weighted_mean(&second, &wts);
    let hf = Half::measure(
        an,
        &first,
        &mean_first,
        tau0,
        mb,
        &shape,
        &pts_first,
        temp.map(|t| &t[..half]),
    );
    let mut hh = Half::measure(
        an,
        &second,
        &mean_held,
        tau0,
        mb,
        &shape,
        &pts_held,
        temp.map(|t| &t[half..]),
    );
    hh.pair_with(&hf);
    let own = periodic::own_lines(&first, &second, tau0, opts.p_false);
    let cands = candidates(
        an,
        w,
        &first,
        &hf,
        tau0,
        temp.map(|t| &t[..half]),
        &typ_terms,
        &Fits {
            typical: terms_of(&noisefit::fit(&corrected_typical(&typical_pts, &hf))),
            sensors: singles.iter().map(terms_of).collect(),
        },
        opts,
        &own,
    );
    let mean_whole = [mean_first, mean_held].concat();
    let mut hw = Half::measure(
        an,
        &w.series,
        &mean_whole,
        tau0,
        mb,
        &shape,
        &pts_whole,
        temp,
    );
    hw.pair_with(&hf);
    let thr = scan_threshold(hw.len(), opts.p_false);
    let mut chosen = select(&cands, &hw, &hh, &wts, opts, thr, None);
    // Effects that together remove less than half of the held-out excess are not named: the gap is `unexplained`.
    let gave_up = !unexplained::enough(&cands, &chosen, &hh, &wts, opts);
    if gave_up {
        chosen.clear();
    }
    name_per_sensor(&cands, &mut chosen, &hh, &typ_terms, opts);
    AxisState {
        hf,
        hw,
        pts_whole,
        hh,
        cands,
        chosen,
        wts,
        typical,
        bandwidth,
        typ_terms,
        model_misfit,
        gave_up,
    }
}

/// The typical sensor's points (`pts`, the per-τ median) at the first half's bias-corrected typical variance where
/// the half measured one: what sensors' own fits are divided by to give their levels relative to `V(τ)`.
fn corrected_typical(pts: &[AnalysisPoint], hf: &Half) -> Vec<AnalysisPoint> {
    pts.iter()
        .map(|p| {
            let mut p = *p;
            if let Some(k) = hf.m.iter().position(|&m| m == p.m) {
                p.dev = hf.typical[k].sqrt();
            }
            p
        })
        .collect()
}

/// Effects are shared by the axes of a sensor more often than not (a thermal bias, a common mode): an axis with no
/// effect of its own is tested again, at the looser `p_sibling`, for the kinds found on its siblings; and for any
/// kind when the sensor's axes together hold a significant gap (the scan of their summed z-scores, divided by
/// √axes, at `p_false`) that none of them shows alone.
fn retest_quiet_axes(works: &[AxisWork], states: &mut [AxisState], opts: &Options) {
    let pooled: Vec<bool> = works
        .iter()
        .map(|w| {
            let zs: Vec<Vec<f64>> = states
                .iter()
                .zip(works)
                .filter(|(_, x)| x.kind == w.kind)
                .map(|(st, _)| {
                    let p0 = Model::independent(st.wts.len());
                    evaluate(&p0, &st.hw, &st.wts, opts.model_tolerance)
                        .iter()
                        .map(|p| p.z)
                        .collect()
                })
                .collect();
            let n = zs.iter().map(Vec::len).min().unwrap_or(0);
            let k = zs.len() as f64;
            let sum: Vec<f64> = (0..n)
                .map(|t| zs.iter().map(|z| z[t]).sum::<f64>() / k.sqrt())
                .collect();
            n > 0 && scan_statistic(&sum) > scan_threshold(n, opts.p_false)
        })
        .collect();
    for i in 0..states.len() {
        if !states[i].chosen.is_empty() || states[i].gave_up {
            continue;
        }
        let kinds: Vec<&'static str> = states
            .iter()
            .zip(works)
            .filter(|(_, w)| w.kind == works[i].kind)
            .flat_map(|(st, _)| st.chosen.iter().map(|&c| st.cands[c].kind))
            .collect();
        if kinds.is_empty() && !pooled[i] {
            continue;
        }
        let st = &states[i];
        let chosen = if kinds.is_empty() {
            let thr = scan_threshold(st.hw.len(), opts.p_sibling);
            select(&st.cands, &st.hw, &st.hh, &st.wts, opts, thr, None)
        } else {
            sibling(st, &kinds, opts).into_iter().collect()
        };
        states[i].chosen = chosen;
    }
}

/// What the per-axis reports add up to.
#[derive(Default)]
struct Assembled {
    axes: Vec<AxisReport>,
    effects: Vec<(SensorKind, usize, Candidate, Acts)>,
    curves: Vec<AxisCurves>,
    fitted: Vec<AxisFit>,
    gaps: Gaps,
    unexplained: Vec<Effect>,
}

impl Assembled {
    /// Appends the next axis's part (axis order kept).
    fn append(&mut self, next: Assembled) {
        self.axes.extend(next.axes);
        self.effects.extend(next.effects);
        self.curves.extend(next.curves);
        self.fitted.extend(next.fitted);
        self.gaps.append(next.gaps);
        self.unexplained.extend(next.unexplained);
    }
}

/// Predicted white-region deviation ratio of the equal mean over the inverse-variance mean under `model`.
fn weighting_recovers(model: &Model, hh: &Half, ns: usize) -> f64 {
    if hh.len() == 0 {
        return 1.0;
    }
    let inv: Vec<f64> = model.level.iter().map(|q| 1.0 / q.max(1e-300)).collect();
    let sum: f64 = inv.iter().sum();
    let iv: Vec<f64> = inv.iter().map(|v| v / sum).collect();
    let eq = vec![1.0 / ns as f64; ns];
    let (t, v, th) = (hh.tau_s[0], hh.typical[0], hh.temp[0]);
    (model.avar(&eq, t, v, th) / model.avar(&iv, t, v, th).max(1e-300)).sqrt()
}

/// Where each chosen effect acts: its share of the held-out prediction, with − without it.
fn effects_of(
    w: &AxisWork,
    st: &AxisState,
    model: &Model,
) -> Vec<(SensorKind, usize, Candidate, Acts)> {
    let ns = w.series.len();
    let AxisState { cands, chosen, .. } = st;
    chosen
        .iter()
        .enumerate()
        .map(|(pos, &i)| {
            let others: Vec<&Candidate> = chosen
                .iter()
                .enumerate()
                .filter(|(p, _)| *p != pos)
                .map(|(_, &j)| &cands[j])
                .collect();
            let mut a = acts(
                cands[i].nature(),
                &st.hh,
                &st.wts,
                model,
                &build(ns, &others),
                &st.typ_terms,
            );
            if cands[i].kind == "periodic" {
                a.0 = "periodic".into();
            }
            (w.kind, w.axis, cands[i].clone(), a)
        })
        .collect()
}

/// Phase 3 of an axis: the final model evaluated on both halves, its rows, regions, gains and effects.
fn report_axis(
    an: &mut Analyzer,
    w: &AxisWork,
    st: AxisState,
    tau0: f64,
    opts: &Options,
    out: &mut Assembled,
) {
    let ns = w.series.len();
    let (hf, hw, hh, wts) = (&st.hf, &st.hw, &st.hh, &st.wts);
    let refs: Vec<&Candidate> = st.chosen.iter().map(|&i| &st.cands[i]).collect();
    let p0 = Model::independent(ns);
    let model = build(ns, &refs);
    let tol = opts.model_tolerance;

    let before_fit = evaluate(&p0, hf, wts, tol);
    let after_fit = evaluate(&model, hf, wts, tol);
    let before = evaluate(&p0, hh, wts, tol);
    let after = evaluate(&model, hh, wts, tol);
    // The excess gap counts on an axis whose remaining gap is significant (the selection's own test), so a chance
    // excursion of a few long-τ points on a clean axis is not reported as a gap.
    let thr = scan_threshold(hw.len(), opts.p_false);
    let sig = [
        significant(&evaluate(&p0, hw, wts, tol), thr),
        significant(&evaluate(&model, hw, wts, tol), thr),
    ];
    let ex = |p: &[PointGap], on: bool| {
        if on {
            rms(p.iter().map(|x| excess(x, opts.z)))
        } else {
            0.0
        }
    };
    out.gaps
        .add(&before_fit, &after_fit, &before, &after, opts.z, sig);

    let (taus, independence) = tau_rows(hh, wts, &p0, &model, &before, &after);
    let label = axis_label(w.kind, w.axis);
    let regions = regions(&st.typ_terms, hh, &before, &after, opts.z);
    let (rms_gain, bias_stability_gain) = gains(an, &w.series, &st.pts_whole, wts, tau0);
    let weighting_recovers = weighting_recovers(&model, hh, ns);
    out.effects.extend(effects_of(w, &st, &model));
    out.curves.push(AxisCurves {
        axis: label.clone(),
        before: taus.iter().map(|r| r.predicted_before).collect(),
        after: taus.iter().map(|r| r.predicted_after).collect(),
        measured: Measured {
            tau_s: taus.iter().map(|r| r.tau_s).collect(),
            dev: taus.iter().map(|r| r.dev).collect(),
            lo: taus.iter().map(|r| r.dev_lo).collect(),
            hi: taus.iter().map(|r| r.dev_hi).collect(),
            edf: taus.iter().map(|r| r.edf).collect(),
            sigma_ln: taus.iter().map(|r| 1.0 / (2.0 * r.edf).sqrt()).collect(),
        },
    });
    // The level effect (at most one is chosen): its factors, and its levels that vary with τ when it has them.
    let level = refs.iter().rev().find(|c| c.level.is_some());
    out.fitted.push(AxisFit {
        kind: w.kind,
        axis: w.axis,
        groups: w.groups.clone(),
        effects: refs.iter().map(|c| c.kind).collect(),
        level: level.and_then(|c| c.level.clone()),
        level_terms: level.and_then(|c| c.level_terms.clone()),
        cross: refs
            .iter()
            .flat_map(|c| c.cross.iter().map(move |x| (c.kind, x.clone())))
            .collect(),
        bandwidth: st.bandwidth,
    });
    let mut effects: Vec<String> = refs.iter().map(|c| c.kind.to_string()).collect();
    // A gap left unexplained is named where the held-out half shows it too (its scan at the looser `p_sibling`):
    // the whole record's test also sees the first half, on which the candidates were fitted and a chance
    // excursion there is no effect the held-out half can confirm.
    let held_out_gap = significant(&after, scan_threshold(hh.len(), opts.p_sibling));
    if sig[1] && held_out_gap {
        let u = unexplained::effect(w, &st, &after, ex(&after, sig[1]), opts);
        effects.push(u.kind.clone());
        out.unexplained.push(u);
    }
    out.axes.push(AxisReport {
        axis: label,
        sensors: ns,
        expected_gain: (ns as f64).sqrt(),
        rms_gain,
        bias_stability_gain,
        weighting_recovers,
        heldout_gap: [ex(&before, sig[0]), ex(&after, sig[1])],
        gap: [ex(&before_fit, sig[0]), ex(&after_fit, sig[1])],
        significant: sig,
        regions,
        taus,
        independence,
        typical: st.typical,
        model_misfit: st.model_misfit[0],
        model_misfit_band_limited: st.model_misfit[1],
        bandwidth_hz: st.bandwidth.map(|l| l.cutoff_hz),
        effects,
    });
}

/// A record's warm-up: steps on at least this many sensors of one axis, all in the record's first
/// [`WARM_UP_FRACTION`] and not all at one instant, are named together as `warm_up` rather than as bias steps of
/// their own.
const WARM_UP_MIN_SENSORS: usize = 2;
/// The part of a record a warm-up's steps fall in.
const WARM_UP_FRACTION: f64 = 0.25;

/// The `bias_step` effects, one per sensor and axis: time and size of the step, its score and threshold; where the
/// steps of several sensors of an axis fall in the record's first quarter at different times, one `warm_up` effect for them instead
/// (`params.<axis>.end_s`, the last of them, and `steps`, each as a `bias_step`'s parameters with its `group`).
fn step_effects(works: &[AxisWork], found: &[Vec<steps::Step>], tau0: f64) -> Vec<Effect> {
    let mut out = Vec::new();
    for (w, st) in works.iter().zip(found) {
        let ax = AXIS_NAMES.get(w.axis).copied().unwrap_or('?').to_string();
        let n = w.series.first().map_or(0, |s| s.len());
        let early = |s: &steps::Step| (s.at as f64) < WARM_UP_FRACTION * n as f64;
        // Sensors settle each at its own pace: steps all at one instant (within a window) are an event every
        // sensor saw at once (a shock, a move), not a warm-up.
        let first: Vec<&steps::Step> = st.iter().filter(|s| early(s)).collect();
        let span = first.iter().map(|s| s.at).max().unwrap_or(0)
            - first.iter().map(|s| s.at).min().unwrap_or(0);
        let widest = first.iter().map(|s| s.window).max().unwrap_or(0);
        let warm = first.len() >= WARM_UP_MIN_SENSORS && span > widest;
        let params = |s: &steps::Step| {
            serde_json::json!({
                "at_s": s.at as f64 * tau0,
                "at_fraction": s.at as f64 / n as f64,
                "size": s.size,
                "z": s.z,
                "threshold_z": s.threshold,
                "window_s": s.window as f64 * tau0,
            })
        };
        let effect = |kind: &str, groups: Vec<usize>, s: &steps::Step, p: serde_json::Value| {
            let window = s.window as f64 * tau0;
            Effect {
                kind: kind.into(),
                sensor: w.kind.name().into(),
                axes: ax.clone(),
                groups: Groups::List(groups),
                region: "step".into(),
                tau_s: [window, window],
                tau_at_max_s: window,
                share: step_share(s, n),
                params: BTreeMap::from([(ax.clone(), p)]),
            }
        };
        let (warm_up, own): (Vec<&steps::Step>, Vec<&steps::Step>) =
            st.iter().partition(|s| warm && early(s));
        for s in own {
            out.push(effect("bias_step", vec![w.groups[s.sensor]], s, params(s)));
        }
        // The warm-up is shown by its largest step (share and window); every step is in its parameters.
        if let Some(top) = warm_up
            .iter()
            .max_by(|a, b| step_share(a, n).total_cmp(&step_share(b, n)))
        {
            let end = warm_up.iter().map(|s| s.at).max().unwrap_or(0) as f64 * tau0;
            let p = serde_json::json!({
                "end_s": end,
                "steps": warm_up
                    .iter()
                    .map(|s| {
                        let mut p = params(s);
                        p["group"] = w.groups[s.sensor].into();
                        p
                    })
                    .collect::<Vec<_>>(),
            });
            let mut groups: Vec<usize> = warm_up.iter().map(|s| w.groups[s.sensor]).collect();
            groups.sort_unstable();
            out.push(effect("warm_up", groups, top, p));
        }
    }
    out
}

/// The step's share of its own sensor's overlapping Allan variance at the detection window τ = mτ₀, from the
/// closed form of a step Δ in n samples, `Δ²·m/(3(n − 2m))` (the 2m straddling differences, triangular), against
/// the noise that made its score: `Δ²/z²` is `2σ²_A`.
fn step_share(s: &steps::Step, n: usize) -> f64 {
    let m = s.window as f64;
    let step = s.size.powi(2) * m / (3.0 * (n as f64 - 2.0 * m).max(1.0));
    let noise = 0.5 * s.size.powi(2) / s.z.powi(2).max(1e-300);
    step / (step + noise)
}

/// Region, τ range, τ of max and max share of an effect (see [`acts`]).
pub(super) type Acts = (String, [f64; 2], f64, f64);
