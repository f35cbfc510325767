//! The model from a recording and its diagnosis: what the diagnosis chose becomes the model's structure (shared
//! processes, thermal coefficients, per-sensor levels), and the terms are fitted on the whole record.
//!
//! - **Thermal**: each sensor's coefficient is the diagnosis's; the sensors' series are fitted with
//!   `β·(T − T_ref)` removed, so that the temperature is not counted twice (once in β, once as random walk).
//! - **Levels**: where the diagnosis found unequal sensors (`unequal_noise`, `outlier_sensor`), each sensor's
//!   variance factor `qᵢ`, refitted by the diagnosis's estimator on the cleaned whole record (`levels`).
//! - **Typical sensor** `T`: five terms (Q, N, B, K, R) and 0–2 Gauss–Markov terms ([`super::terms_fit`]: their
//!   count chosen on the record's halves) fitted to the sensors' mean Allan variance over their mean factor `q̄`,
//!   weighted by the mean's Satterthwaite EDF (`mean_curve`): the fit of the mean.
//! - **Own terms**: `qᵢ·T` (T without levels), so that the model's mean sensor is the fit of the record's mean; where
//!   the diagnosis chose the level that varies with τ (`AxisFit::level_terms`), T scaled term by term, each
//!   sensor's factors held to its `qᵢ` by a pull chosen on the record's halves (`twin/levels.rs`). A free
//!   five-term fit per sensor would copy each sensor's long-τ estimation error (a handful of blocks) into the twin.
//! - **Shared processes**: refitted on the whole record from the members' mean as the typical sensor (Gauss–Markov
//!   terms included); a member's independent terms are its own less the processes it shares, term by term.
//! - **One sensor's drift** (`sensor_drift`): the Allan-variance terms the diagnosis added to that sensor, added to
//!   its own terms.
//! - **Deterministic parts**, taken out of the series before any noise term is fitted: bias steps (`bias_step`) as
//!   the diagnosis measured them; sinusoids (`periodic`) at the diagnosis's period, their amplitude and phase
//!   refitted by least squares on the whole record (on the members' mean for a shared one); a sensor's own line
//!   removed window by window and played at the windows' power (`remove_line`).
//! - **Temperature**: a line and up to two sinusoids (periods found by a least-squares scan), the rest as noise
//!   terms ([`fit_temperature`]).

use super::levels;
use super::terms_fit::{self, Obs, Spec};
use super::{
    AxisModel, BiasStep, ClusterModel, EffectSummary, FORMAT, Harmonic, NoiseTerms, RecordInfo,
    SensorModel, SharedProcess, Sinusoid, TemperatureModel, TwinError,
};
use crate::allan::median_to_mean;
use crate::allan::{AnalysisPoint, Analyzer, DevKind, Options as AllanOptions, TauSpec};
use crate::diagnose::model::{Cross, Terms};
use crate::diagnose::{AxisFit, Report};
use crate::recording::Recording;
use crate::stats::median;

/// Harmonics that explain less than this share of what remains are not kept.
const HARMONIC_MIN_SHARE: f64 = 0.05;
/// Most harmonics fitted.
const HARMONICS_MAX: usize = 2;

/// The model of `rec` from its diagnosis `report` (which must be of this record: `diagnose(rec, …)`); `source`
/// names the record in the model.
pub fn fit(rec: &Recording, report: &Report, source: &str) -> Result<ClusterModel, TwinError> {
    let tau0 = rec.sample_interval_s().ok_or_else(|| {
        TwinError::Invalid("fewer than two samples, or time not increasing".into())
    })?;
    let n = rec.len();
    let temp = rec
        .temp_c
        .as_deref()
        .filter(|t| t.len() >= n && t.iter().all(|x| x.is_finite()));
    let temperature = temp.map(|t| fit_temperature(&rec.t_s, &t[..n], tau0));
    let t_ref = temperature.as_ref().map(|t| t.reference_c);
    let mut an = Analyzer::new();
    let mut axes = Vec::new();
    for af in &report.fitted {
        let (steps, warm_up_end_s) = axis_steps(report, af);
        let given = Given {
            steps: &steps,
            warm_up_end_s,
        };
        axes.push(fit_axis(rec, af, &given, temp, t_ref, tau0, &mut an)?);
    }
    let effects = report
        .effects
        .iter()
        .map(|e| EffectSummary {
            kind: e.kind.clone(),
            sensor: e.sensor.clone(),
            axes: e.axes.clone(),
            tau_s: e.tau_s,
            share: e.share,
        })
        .collect();
    let model = ClusterModel {
        format: FORMAT.into(),
        record: RecordInfo {
            source: source.into(),
            rate_hz: 1.0 / tau0,
            samples: n,
            duration_s: n as f64 * tau0,
            groups: rec.groups(),
            columns: rec.columns.iter().map(|c| c.name()).collect(),
        },
        temperature,
        effects,
        axes,
    };
    model.validate()?;
    Ok(model)
}

/// The bias steps the diagnosis found on one axis, its own and its warm-up's: (index into the axis's sensors,
/// step); and the warm-up's end (its last step), s, if it named one.
fn axis_steps(report: &Report, af: &AxisFit) -> (Vec<(usize, BiasStep)>, Option<f64>) {
    let ax = crate::recording::AXIS_NAMES[af.axis].to_string();
    let ax = ax.as_str();
    let on_axis = |kind: &'static str| {
        report
            .effects
            .iter()
            .filter(move |e| e.kind == kind && e.sensor == af.kind.name() && e.axes == ax)
    };
    let step = |group: Option<usize>, p: &serde_json::Value| {
        let i = af.groups.iter().position(|&x| Some(x) == group)?;
        let step = BiasStep {
            at_s: p.get("at_s")?.as_f64()?,
            size: p.get("size")?.as_f64()?,
        };
        Some((i, step))
    };
    let mut steps: Vec<(usize, BiasStep)> = on_axis("bias_step")
        .filter_map(|e| step(e.groups.flat().first().copied(), e.params.get(ax)?))
        .collect();
    let mut end = None;
    for e in on_axis("warm_up") {
        let Some(p) = e.params.get(ax) else { continue };
        end = p.get("end_s").and_then(serde_json::Value::as_f64);
        let listed = p.get("steps").and_then(serde_json::Value::as_array);
        steps.extend(listed.into_iter().flatten().filter_map(|s| {
            let group = s.get("group")?.as_u64()?;
            step(usize::try_from(group).ok(), s)
        }));
    }
    (steps, end)
}

/// What the diagnosis measured of an axis's deterministic parts: its steps (own and warm-up), and the warm-up's end.
struct Given<'a> {
    steps: &'a [(usize, BiasStep)],
    warm_up_end_s: Option<f64>,
}

fn fit_axis(
    rec: &Recording,
    af: &AxisFit,
    given: &Given,
    temp: Option<&[f64]>,
    t_ref: Option<f64>,
    tau0: f64,
    an: &mut Analyzer,
) -> Result<AxisModel, TwinError> {
    let label = format!(
        "{}{}",
        af.kind.prefix(),
        crate::recording::AXIS_NAMES[af.axis]
    );
    let series: Vec<&[f64]> = af
        .groups
        .iter()
        .map(|&g| {
            rec.find(af.kind, g, af.axis)
                .map(|c| &c.data[..rec.len().min(c.data.len())])
                .ok_or_else(|| TwinError::Invalid(format!("{label}: no column for group {g}")))
        })
        .collect::<Result<_, _>>()?;
    let ns = series.len();
    let beta = thermal_coefficients(af, ns);
    let mut cleaned = without_thermal(&series, &beta, temp, t_ref);
    let det = remove_deterministic(&mut cleaned, af, given.steps, tau0);
    // A warm-up is kept out of the noise terms: they are fitted on what follows it.
    if let Some(end) = given.warm_up_end_s {
        let k = ((end / tau0).ceil().max(0.0) as usize).min(rec.len() / 2);
        cleaned
            .iter_mut()
            .for_each(|s| drop(s.drain(..k.min(s.len()))));
    }
    let band = af.bandwidth.as_ref();
    let spec = Spec {
        tau0_s: tau0,
        band,
        lines: true,
    };
    // Per range: the sensors' octave points (the whole record's serve the levels and the coverage too).
    let (whole_points, halves_points) =
        whole_and_halves(cleaned.first().map_or(0, Vec::len), |r| {
            cleaned
                .iter()
                .map(|s| octave(an, &s[r.clone()], tau0))
                .collect::<Vec<Vec<AnalysisPoint>>>()
        });
    let level = af
        .level
        .as_ref()
        .filter(|q| q.len() == ns)
        .and_then(|_| levels(&whole_points));
    // One sensor's drift (`sensor_drift`) is added to that sensor's own terms: out of the mean T is fitted to.
    let drifts = own_drifts(af, ns);
    let mut drift = [0.0; 5];
    for d in drifts.iter().flatten() {
        drift
            .iter_mut()
            .zip(d)
            .for_each(|(a, b)| *a += b / ns as f64);
    }
    let curve = |p: &[Vec<AnalysisPoint>]| mean_curve(p, level.as_deref(), &drift, band);
    let whole = curve(&whole_points);
    let halves = halves_points
        .as_ref()
        .map(|h| h.each_ref().map(|p| curve(p)));
    let (typical, band_kept) = terms_fit::fit_band_tested(&whole, as_slices(&halves), &spec);
    let band = band.filter(|_| band_kept);
    let spec = Spec {
        tau0_s: tau0,
        band,
        lines: true,
    };
    let factors = level_factors(
        af,
        level.as_deref(),
        &drifts,
        &whole_points,
        halves_points.as_ref(),
        &levels::Typical {
            terms: &typical,
            tau0_s: tau0,
            band,
        },
    );
    let mut own = own_terms(factors.as_deref(), &drifts, &typical, ns);
    share_lines(&mut own, &whole_points, tau0, band);
    let coverage = super::coverage::coverage(&whole_points, &own, tau0, band);
    // A shared part is fitted to a difference of curves (`shared_part`) whose weights are approximate: it keeps the
    // first-order family (on the seed record's common modes, lines were taken at 0.001–0.011 Hz).
    let first_order = Spec {
        lines: false,
        ..spec
    };
    let mut shared = shared_processes(af, &cleaned, &own, &first_order, an);
    shared.extend(det.shared_sines.into_iter().map(|p| (p, Vec::new())));
    let sensors = (0..ns)
        .map(|i| {
            let independent = shared
                .iter()
                .filter(|(_, members)| members.contains(&i))
                .fold(own[i].clone(), |acc, (p, _)| acc.less(&p.terms));
            SensorModel {
                group: af.groups[i],
                mean: crate::stats::mean(&cleaned[i]),
                independent,
                thermal_per_c: beta[i],
                sinusoids: det.own_sines[i].clone(),
                steps: det.steps[i].clone(),
            }
        })
        .collect();
    Ok(AxisModel {
        axis: label,
        unit: af.kind.unit().into(),
        typical,
        effects: af.effects.iter().map(|k| (*k).to_string()).collect(),
        sensors,
        shared: shared.into_iter().map(|(p, _)| p).collect(),
        bandwidth_hz: band.map(|l| l.cutoff_hz),
        coverage: Some(coverage),
    })
}

/// Each sensor's thermal coefficient (summed if several thermal terms were chosen).
fn thermal_coefficients(af: &AxisFit, ns: usize) -> Vec<f64> {
    let mut beta = vec![0.0; ns];
    for (_, c) in &af.cross {
        if let Cross::Thermal { beta: b } = c {
            beta.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        }
    }
    beta
}

/// The series with `β·(T − T_ref)` removed.
fn without_thermal(
    series: &[&[f64]],
    beta: &[f64],
    temp: Option<&[f64]>,
    t_ref: Option<f64>,
) -> Vec<Vec<f64>> {
    series
        .iter()
        .zip(beta)
        .map(|(s, &b)| match (temp, t_ref) {
            (Some(t), Some(r)) if b != 0.0 => {
                s.iter().zip(t).map(|(x, t)| x - b * (t - r)).collect()
            }
            _ => s.to_vec(),
        })
        .collect()
}

/// The deterministic parts of one axis, taken out of the series before its noise terms are fitted.
struct Deterministic {
    /// Per sensor, its own sinusoids.
    own_sines: Vec<Vec<Sinusoid>>,
    /// Per sensor, its bias steps.
    steps: Vec<Vec<BiasStep>>,
    /// Shared sinusoids, as processes of their own.
    shared_sines: Vec<SharedProcess>,
}

/// Takes the bias steps (as the diagnosis measured them) and the sinusoids (at the diagnosis's periods; amplitude
/// and phase refitted by least squares on the whole record: the members' mean for a shared one) out of `cleaned`,
/// and returns them.
fn remove_deterministic(
    cleaned: &mut [Vec<f64>],
    af: &AxisFit,
    steps: &[(usize, BiasStep)],
    tau0: f64,
) -> Deterministic {
    let ns = cleaned.len();
    let mut det = Deterministic {
        own_sines: vec![Vec::new(); ns],
        steps: vec![Vec::new(); ns],
        shared_sines: Vec::new(),
    };
    for &(i, step) in steps {
        if let Some(s) = cleaned.get_mut(i) {
            s.iter_mut()
                .enumerate()
                .filter(|(k, _)| *k as f64 * tau0 >= step.at_s)
                .for_each(|(_, x)| *x -= step.size);
            det.steps[i].push(step);
        }
    }
    for (kind, c) in &af.cross {
        match c {
            Cross::OwnSine { sensor, sine } if *sensor < ns => {
                if let Some(s) = remove_line(&mut cleaned[*sensor], sine.period_s, tau0) {
                    det.own_sines[*sensor].push(s);
                }
            }
            Cross::SharedSine { members, sine } => {
                let members: Vec<usize> = members.iter().copied().filter(|&i| i < ns).collect();
                let mean = members_mean(cleaned, &members);
                if let Some(s) = fit_sine(&mean, sine.period_s, tau0) {
                    for &i in &members {
                        subtract(&mut cleaned[i], &s, tau0);
                    }
                    det.shared_sines.push(SharedProcess {
                        kind: (*kind).to_string(),
                        groups: members.iter().map(|&i| af.groups[i]).collect(),
                        terms: NoiseTerms::default(),
                        sinusoids: vec![s],
                    });
                }
            }
            _ => {}
        }
    }
    det
}

/// Windows of a line's fit, in periods: long enough to tell the line from the noise about it, short enough to
/// follow a line whose amplitude and phase wander.
const LINE_WINDOW_PERIODS: f64 = 8.0;

/// Takes the line of period `period_s` out of `y` and returns the tone the twin plays for it. Real lines wander (a
/// narrow-band process: a resonance, a beat), and one least-squares tone over the whole record catches only their
/// coherent part; so where the record holds at least two windows of [`LINE_WINDOW_PERIODS`], the line is fitted
/// and removed window by window, and played as one tone of the windows' mean power (`mean A_w²` less the noise's
/// bias `4σ²/n_w`, σ² the residual's variance) at the whole record's phase. A steady tone gives the same amplitude
/// either way.
fn remove_line(y: &mut [f64], period_s: f64, tau0: f64) -> Option<Sinusoid> {
    let whole = fit_sine(y, period_s, tau0)?;
    let w = ((LINE_WINDOW_PERIODS * period_s / tau0).ceil() as usize).max(16);
    if y.len() < 2 * w {
        subtract(y, &whole, tau0);
        return Some(whole);
    }
    // Per window: (fitted power A_w², samples n_w).
    let mut windows: Vec<(f64, f64)> = Vec::new();
    for (j, chunk) in y.chunks_mut(w).enumerate() {
        let start = j * w;
        let m = crate::stats::mean(chunk);
        let points = chunk
            .iter()
            .enumerate()
            .map(|(k, x)| ((start + k) as f64 * tau0, x - m));
        let Some(f) = crate::stats::fit_sinusoid(points, std::f64::consts::TAU / period_s) else {
            continue;
        };
        for (k, x) in chunk.iter_mut().enumerate() {
            let (sn, cs) = (std::f64::consts::TAU * (start + k) as f64 * tau0 / period_s).sin_cos();
            *x -= f.sin * sn + f.cos * cs;
        }
        windows.push((f.amplitude().powi(2), chunk.len() as f64));
    }
    let mu = crate::stats::mean(y);
    let resid = crate::stats::rms(y.iter().map(|x| x - mu)).powi(2);
    let a2 = windows
        .iter()
        .map(|(p, n)| p - 4.0 * resid / n)
        .sum::<f64>()
        / windows.len().max(1) as f64;
    Some(Sinusoid {
        amplitude: a2.max(whole.amplitude * whole.amplitude).sqrt(),
        ..whole
    })
}

/// The least-squares sinusoid of period `period_s` through `y` (about its mean), sample k at k·`tau0`.
fn fit_sine(y: &[f64], period_s: f64, tau0: f64) -> Option<Sinusoid> {
    let m = crate::stats::mean(y);
    let points = y.iter().enumerate().map(|(k, x)| (k as f64 * tau0, x - m));
    let f = crate::stats::fit_sinusoid(points, std::f64::consts::TAU / period_s)?;
    // a·sin(ωt) + b·cos(ωt) = A·sin(ωt + φ) with A cos φ = a, A sin φ = b.
    Some(Sinusoid {
        period_s,
        amplitude: f.amplitude(),
        phase_rad: f.cos.atan2(f.sin),
    })
}

fn subtract(y: &mut [f64], s: &Sinusoid, tau0: f64) {
    y.iter_mut()
        .enumerate()
        .for_each(|(k, x)| *x -= s.at(k as f64 * tau0));
}

/// The sample-by-sample mean of the `members`' series.
fn members_mean(series: &[Vec<f64>], members: &[usize]) -> Vec<f64> {
    let len = series.first().map_or(0, Vec::len);
    (0..len)
        .map(|k| members.iter().map(|&i| series[i][k]).sum::<f64>() / members.len() as f64)
        .collect()
}

/// Each sensor's term factors where the diagnosis found unequal sensors: its one factor `qᵢ` (`level`, the refitted
/// factors, [`levels`]) for every term, or, where the diagnosis chose the level that varies with τ
/// (`AxisFit::level_terms`), factors per term group held to `qᵢ` and chosen on the record's halves
/// ([`levels::term_factors`]; a free per-sensor fit would copy each sensor's long-τ estimation error, from a
/// handful of blocks, into the twin). `None` without unequal sensors.
fn level_factors(
    af: &AxisFit,
    level: Option<&[f64]>,
    drifts: &[Option<[f64; 5]>],
    whole: &[Vec<AnalysisPoint>],
    halves: Option<&[Vec<Vec<AnalysisPoint>>; 2]>,
    typical: &levels::Typical,
) -> Option<Vec<levels::Factors>> {
    let q = level?;
    let varying = af.level_terms.as_ref().and_then(|_| {
        let drift: Vec<[f64; 5]> = drifts.iter().map(|d| d.unwrap_or([0.0; 5])).collect();
        let sensors = levels::Sensors {
            whole,
            halves,
            drift: &drift,
        };
        levels::term_factors(&sensors, q, typical)
    });
    Some(varying.unwrap_or_else(|| q.iter().map(|&q| [q; 5]).collect()))
}

/// Each sensor's drift (`sensor_drift`: the Allan-variance coefficients of the `Cross::Own` parts the diagnosis gave
/// it, negative ones as 0), `None` for a sensor without one.
fn own_drifts(af: &AxisFit, ns: usize) -> Vec<Option<[f64; 5]>> {
    let mut out = vec![None; ns];
    for (_, c) in &af.cross {
        if let Cross::Own { sensor, part } = c
            && let Some(d) = out.get_mut(*sensor)
        {
            let d = d.get_or_insert([0.0; 5]);
            d.iter_mut().zip(part.0).for_each(|(a, b)| *a += b.max(0.0));
        }
    }
    out
}

/// Each sensor's own terms: the typical ones, scaled term by term by `factors` ([`level_factors`]) where the
/// diagnosis found unequal sensors, plus the slow process the diagnosis found on one sensor (`drifts`,
/// [`own_drifts`]).
fn own_terms(
    factors: Option<&[levels::Factors]>,
    drifts: &[Option<[f64; 5]>],
    typical: &NoiseTerms,
    ns: usize,
) -> Vec<NoiseTerms> {
    let mut own: Vec<NoiseTerms> = match factors {
        Some(f) if f.len() == ns => f.iter().map(|f| typical.by_term_factors(f)).collect(),
        _ => vec![typical.clone(); ns],
    };
    for (o, d) in own.iter_mut().zip(drifts) {
        if let Some(d) = d {
            let mut c = o.avar_coefficients();
            c.iter_mut().zip(d).for_each(|(a, b)| *a += b);
            *o = NoiseTerms {
                gauss_markov: std::mem::take(&mut o.gauss_markov),
                ..NoiseTerms::from_avar_coefficients(c)
            };
        }
    }
    own
}

/// Shares the narrow-band terms (lines) of each sensor's own terms `own` out among the sensors by what each one's
/// curve holds of them: sensor `i`'s line `k` is scaled by `sᵢₖ ≥ 0`, its coefficient in the non-negative weighted
/// least squares of its octave points `points` on its lines' Allan variances and its other terms' (weights `ν/2σ⁴`);
/// then each line's `sᵢₖ` by one constant, so that its total over the sensors is what it was. The typical terms'
/// lines are fitted to the sensors' mean (and chosen on held-out halves there), but real lines sit on some parts
/// only (a MIMU4444 gyro x part at 13 Hz): given to every sensor alike, they made the twin's median sensor too loud
/// where they act (the demo's real excerpt: gyro x told apart at 0.128–0.256 s, z −4.3). The mean, which the
/// cluster and the coverage see, is unchanged.
pub(super) fn share_lines(
    own: &mut [NoiseTerms],
    points: &[Vec<AnalysisPoint>],
    tau0: f64,
    band: Option<&crate::allan::noisefit::LowPass>,
) {
    const L: usize = terms_fit::LINES_MAX;
    let is_line = |g: &&mut super::GaussMarkov| g.freq_hz > 0.0;
    if own.len() != points.len() {
        return;
    }
    // Each sensor's shares of its lines (in the order its terms hold them; every sensor's are the typical's).
    let shares: Vec<[f64; L]> = own
        .iter()
        .zip(points)
        .map(|(o, p)| {
            let lines: Vec<&super::GaussMarkov> = o
                .gauss_markov
                .iter()
                .filter(|g| g.freq_hz > 0.0)
                .take(L)
                .collect();
            let base = NoiseTerms {
                gauss_markov: o
                    .gauss_markov
                    .iter()
                    .filter(|g| g.freq_hz == 0.0)
                    .copied()
                    .collect(),
                ..o.clone()
            };
            // The other terms scaled too (column 0), so that a sensor's chance excess over them at long τ, where a
            // line's Allan variance falls as white noise's, is not taken for its share of the line.
            let rows: Vec<([f64; L + 1], f64, f64)> = Obs::of(p)
                .iter()
                .map(|ob| {
                    let mut r = [0.0; L + 1];
                    r[0] = base.avar(ob.tau_s, tau0, band);
                    r[1..]
                        .iter_mut()
                        .zip(&lines)
                        .for_each(|(x, g)| *x = g.avar(ob.tau_s, tau0));
                    (r, ob.avar, ob.weight)
                })
                .collect();
            crate::allan::noisefit::nnls_first::<{ L + 1 }>(&rows, 1 + lines.len())
                .map_or([1.0; L], |c| std::array::from_fn(|k| c[k + 1]))
        })
        .collect();
    for k in 0..L {
        let power = |o: &NoiseTerms| {
            o.gauss_markov
                .iter()
                .filter(|g| g.freq_hz > 0.0)
                .nth(k)
                .map_or(0.0, |g| g.sigma * g.sigma)
        };
        let before: f64 = own.iter().map(power).sum();
        let after: f64 = own.iter().zip(&shares).map(|(o, s)| s[k] * power(o)).sum();
        if !(after > 0.0 && before.is_finite()) {
            continue;
        }
        for (o, s) in own.iter_mut().zip(&shares) {
            if let Some(g) = o.gauss_markov.iter_mut().filter(is_line).nth(k) {
                g.sigma *= (s[k] * before / after).sqrt();
            }
        }
    }
    own.iter_mut()
        .for_each(|o| o.gauss_markov.retain(|g| g.sigma > 0.0));
}

/// `f` of the whole record's sample range and of each half's (none when a half is shorter than 32 samples: too
/// few octaves to choose terms on).
fn whole_and_halves<T>(
    n: usize,
    mut f: impl FnMut(std::ops::Range<usize>) -> T,
) -> (T, Option<[T; 2]>) {
    let whole = f(0..n);
    let halves = (n / 2 >= 32).then(|| [f(0..n / 2), f(n / 2..n)]);
    (whole, halves)
}

/// The halves as the slices [`terms_fit::fit`] takes.
fn as_slices(halves: &Option<[Vec<Obs>; 2]>) -> Option<[&[Obs]; 2]> {
    halves.as_ref().map(|[a, b]| [a.as_slice(), b.as_slice()])
}

fn octave(an: &mut Analyzer, s: &[f64], tau0: f64) -> Vec<AnalysisPoint> {
    an.analyze(
        DevKind::Oadev,
        s,
        tau0,
        &TauSpec::Octave,
        &AllanOptions::default(),
    )
}

/// The shared processes of one axis, each with its members (indices into the axis's sensors): one per set of
/// members (the diagnosis may name two on the same sensors, e.g. a common mode and a common drift: their sum is
/// what the record shows), their terms refitted on the whole record where the sets are disjoint.
fn shared_processes(
    af: &AxisFit,
    cleaned: &[Vec<f64>],
    own: &[NoiseTerms],
    spec: &Spec,
    an: &mut Analyzer,
) -> Vec<(SharedProcess, Vec<usize>)> {
    let mut sets: Vec<(Vec<usize>, Vec<&'static str>, Terms)> = Vec::new();
    for (kind, c) in &af.cross {
        if let Cross::Shared { members, share } = c {
            let mut m = members.clone();
            m.sort_unstable();
            match sets.iter_mut().find(|(x, _, _)| *x == m) {
                Some((_, kinds, terms)) => {
                    kinds.push(kind);
                    terms
                        .0
                        .iter_mut()
                        .zip(share.part.0)
                        .for_each(|(a, b)| *a += b);
                }
                None => sets.push((m, vec![kind], share.part)),
            }
        }
    }
    let disjoint = sets.iter().enumerate().all(|(i, (a, _, _))| {
        sets[i + 1..]
            .iter()
            .all(|(b, _, _)| a.iter().all(|x| !b.contains(x)))
    });
    sets.into_iter()
        .map(|(members, kinds, diag)| {
            let terms = if disjoint {
                let mean = members_mean(cleaned, &members);
                let own_of: Vec<&NoiseTerms> = members.iter().map(|&i| &own[i]).collect();
                let (whole, halves) = whole_and_halves(mean.len(), |r| {
                    shared_part(&octave(an, &mean[r], spec.tau0_s), &own_of, spec)
                });
                terms_fit::fit(&whole, as_slices(&halves), spec)
            } else {
                NoiseTerms::from_avar_coefficients(diag.0)
            };
            (
                SharedProcess {
                    kind: kinds.join("+"),
                    groups: members
                        .iter()
                        .filter_map(|&i| af.groups.get(i).copied())
                        .collect(),
                    terms,
                    sinusoids: Vec::new(),
                },
                members,
            )
        })
        .collect()
}

/// The Allan variance of a process shared by `own.len()` sensors, as observations, from the Allan variance of their
/// mean (`points`): with a shared part S and the members' own terms O_i (which contain S),
/// `σ²_mean = S + Σ(O_i − S)/M²`, so `S = (σ²_mean − mean(O_i)/M) / (1 − 1/M)` at each τ, weighted by the EDF of the
/// mean's variance. Fitted on the whole record, so that the twin's cluster matches the record's where the
/// diagnosis's first-half shares would leave a bias of a few per cent (significant at short τ, where the EDF is in
/// the tens of thousands).
fn shared_part(points: &[AnalysisPoint], own: &[&NoiseTerms], spec: &Spec) -> Vec<Obs> {
    let m = own.len() as f64;
    if m < 2.0 {
        return Vec::new();
    }
    Obs::of(points)
        .into_iter()
        .map(|o| {
            let own_mean = own
                .iter()
                .map(|t| t.avar(o.tau_s, spec.tau0_s, spec.band))
                .sum::<f64>()
                / m;
            Obs {
                avar: (o.avar - own_mean / m) / (1.0 - 1.0 / m),
                ..o
            }
        })
        .collect()
}

/// Each sensor's variance factor relative to the typical sensor on `points` (each sensor's octave points), by the
/// diagnosis's estimator ([`crate::diagnose::deviation_ratios`]: the median over τ of the deviation ratio, squared).
/// Refitted here on the series the terms see, with their lines, steps and thermal part taken out and on the whole
/// record: the diagnosis's factors, measured on the first half with the lines in, overstated a sensor whose
/// excess was a line (on one MIMU4444 accelerometer 5.2 where its cleaned series gives 2.1).
pub(super) fn levels(points: &[Vec<AnalysisPoint>]) -> Option<Vec<f64>> {
    let typical: Vec<f64> = typical_points(points)
        .iter()
        .map(|p| p.dev * p.dev)
        .collect();
    let singles: Vec<Vec<f64>> = points
        .iter()
        .map(|p| {
            p.iter()
                .take(typical.len())
                .map(|x| x.dev * x.dev)
                .collect()
        })
        .collect();
    let r = crate::diagnose::deviation_ratios(&singles, &typical)?;
    Some(r.iter().map(|r| r * r).collect())
}

/// The curve the typical terms are fitted to: the sensors' mean Allan variance, less the mean of the drifts
/// `drift` (Allan-variance coefficients, already divided by the sensor count) the diagnosis gave single sensors,
/// divided by their mean variance factor `q̄` (1 without factors), each point weighted by the inverse variance of
/// the mean (its Satterthwaite EDF, [`super::coverage::pooled`]), at the τ every sensor has. With each sensor's own
/// terms `qᵢ·T`, the model's mean sensor is then `q̄·T`: the fit of the mean, which the record's cluster and the
/// coverage see. (The per-τ median it replaces falls below the mean where the parts' bumps and lines lie at
/// different τ: on the MIMU4444 gyros the terms were 10–30 % off the record's mean there.)
fn mean_curve(
    points: &[Vec<AnalysisPoint>],
    level: Option<&[f64]>,
    drift: &[f64; 5],
    band: Option<&crate::allan::noisefit::LowPass>,
) -> Vec<Obs> {
    let q_mean = level.map_or(1.0, |q| q.iter().sum::<f64>() / q.len().max(1) as f64);
    let k = points.iter().map(Vec::len).min().unwrap_or(0);
    (0..k)
        .filter_map(|j| {
            let at: Vec<&AnalysisPoint> = points.iter().filter_map(|p| p.get(j)).collect();
            let tau_s = at.first()?.tau_s;
            let (mean, nu) = super::coverage::pooled(&at)?;
            let d: f64 = drift
                .iter()
                .zip(super::basis(tau_s, band))
                .map(|(c, b)| c * b)
                .sum();
            let avar = (mean - d) / q_mean;
            (avar > 0.0 && avar.is_finite()).then(|| Obs {
                tau_s,
                avar,
                weight: nu / 2.0 / (avar * avar),
            })
        })
        .collect()
}

/// The per-τ median of the sensors' deviations, scaled to a mean (`ν / χ²_ν median`, as the diagnosis's typical
/// sensor), at the τ every sensor has.
fn typical_points(points: &[Vec<AnalysisPoint>]) -> Vec<AnalysisPoint> {
    let k = points.iter().map(Vec::len).min().unwrap_or(0);
    (0..k)
        .map(|j| {
            let devs: Vec<f64> = points.iter().map(|p| p[j].dev).collect();
            let p0 = points[0][j];
            let scale = p0.edf.map_or(1.0, median_to_mean);
            AnalysisPoint {
                dev: median(&devs) * scale.sqrt(),
                ..p0
            }
        })
        .collect()
}

fn sum_sq(v: &[f64]) -> f64 {
    v.iter().map(|x| x * x).sum()
}

/// The temperature model of `temp` sampled at `t_s` (see the module docs): the line and the harmonics are fitted
/// together at the periods a scan found (each period the one, among 400 log-spaced from 20 samples to the record's
/// length and refined by a golden-section search, whose sinusoid removes most of what remains); the residual's
/// octave Allan deviation gives the noise.
pub fn fit_temperature(t_s: &[f64], temp: &[f64], tau0: f64) -> TemperatureModel {
    let n = temp.len().min(t_s.len());
    let (t, y) = (&t_s[..n], &temp[..n]);
    let t0 = t.first().copied().unwrap_or(0.0);
    let tt: Vec<f64> = t.iter().map(|x| x - t0).collect();
    let duration = tt.last().copied().unwrap_or(0.0).max(tau0);
    // Columns: 1, t, then sin and cos of each harmonic found (at most 2 + 2·HARMONICS_MAX = 6).
    let mut periods: Vec<f64> = Vec::new();
    let row = |t: f64, periods: &[f64]| -> [f64; 6] {
        let mut r = [1.0, t, 0.0, 0.0, 0.0, 0.0];
        for (k, p) in periods.iter().enumerate() {
            let (s, c) = (std::f64::consts::TAU * t / p).sin_cos();
            r[2 + 2 * k] = s;
            r[3 + 2 * k] = c;
        }
        r
    };
    let residual = |periods: &[f64]| -> ([f64; 6], Vec<f64>) {
        let rows: Vec<([f64; 6], f64, f64)> = tt
            .iter()
            .zip(y)
            .map(|(&t, &v)| (row(t, periods), v, 1.0))
            .collect();
        let mask = (1u32 << (2 + 2 * periods.len())) - 1;
        let c = crate::allan::noisefit::solve(&rows, mask).unwrap_or([0.0; 6]);
        let r = rows
            .iter()
            .map(|(b, v, _)| v - b.iter().zip(&c).map(|(x, k)| x * k).sum::<f64>())
            .collect();
        (c, r)
    };
    let (_, mut r) = residual(&periods);
    let (p_lo, p_hi) = ((20.0 * tau0).max(1e-9), duration);
    for _ in 0..HARMONICS_MAX {
        if p_hi <= p_lo || sum_sq(&r) == 0.0 {
            break;
        }
        let grid = 400;
        let best = (0..=grid)
            .map(|k| p_lo * (p_hi / p_lo).powf(k as f64 / grid as f64))
            .map(|p| (p, sinusoid_gain(&tt, &r, p)))
            .max_by(|a, b| a.1.total_cmp(&b.1));
        let Some((p, _)) = best else { break };
        // The grid's step is 1.8 % of the period at most: refine within a step (golden section).
        let (mut a, mut b) = (p / 1.02, p * 1.02);
        let g = (5f64.sqrt() - 1.0) / 2.0;
        for _ in 0..50 {
            let (c1, c2) = (b - g * (b - a), a + g * (b - a));
            if sinusoid_gain(&tt, &r, c1) > sinusoid_gain(&tt, &r, c2) {
                b = c2;
            } else {
                a = c1;
            }
        }
        let p = 0.5 * (a + b);
        if sinusoid_gain(&tt, &r, p) < HARMONIC_MIN_SHARE * sum_sq(&r) {
            break;
        }
        periods.push(p);
        r = residual(&periods).1;
    }
    let (c, r) = residual(&periods);
    let harmonics = periods
        .iter()
        .enumerate()
        .map(|(k, &p)| {
            let (s, co) = (c[2 + 2 * k], c[3 + 2 * k]);
            // a·sin(ωt) + b·cos(ωt) = A·sin(ωt + φ); t counted from the record's first sample.
            Harmonic {
                period_s: p,
                amplitude_c: s.hypot(co),
                phase_rad: co.atan2(s),
            }
        })
        .collect();
    let pts = Analyzer::new().analyze(
        DevKind::Oadev,
        &r,
        tau0,
        &TauSpec::Octave,
        &AllanOptions::default(),
    );
    let nf = crate::allan::noisefit::fit(&pts);
    TemperatureModel {
        reference_c: crate::stats::mean(y),
        start_c: c[0],
        drift_c_per_h: c[1] * 3600.0,
        harmonics,
        noise: NoiseTerms {
            quantization: nf.quantization,
            white: nf.white,
            bias_instability: nf.bias_instability,
            random_walk: nf.random_walk,
            ramp: 0.0,
            gauss_markov: Vec::new(),
        },
    }
}

/// Sum of squares a sinusoid of period `p` removes from `r` (least squares on sin and cos).
fn sinusoid_gain(t: &[f64], r: &[f64], p: f64) -> f64 {
    let points = t.iter().copied().zip(r.iter().copied());
    crate::stats::fit_sinusoid(points, std::f64::consts::TAU / p).map_or(0.0, |f| f.removed)
}
