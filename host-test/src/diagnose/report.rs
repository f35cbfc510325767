//! Human-readable report and plots of a diagnosis.

use super::{AxisReport, Effect, Groups, Report, quiet};
use crate::figures::sig3;
use crate::plot::{self, Curve, Panel, Style};
use std::fmt::Write as _;
use std::path::Path;

/// Report file name inside the output folder.
pub const TEXT_FILE: &str = "report.txt";
/// Plot file name inside the output folder.
pub const PLOT_FILE: &str = "diagnose.png";

/// Why the report was not written.
#[derive(Debug, thiserror::Error)]
pub enum WriteError {
    /// A file or the folder could not be written.
    #[error("writing {}: {source}", path.display())]
    Io {
        /// The file or folder.
        path: std::path::PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The plot was not drawn.
    #[error(transparent)]
    Plot(#[from] plot::PlotError),
}

/// Writes the text report and the plot into `dir` (created if missing); returns the text.
pub fn write(r: &Report, dir: &Path, source: &str) -> Result<String, WriteError> {
    let err = |what: &Path, source: std::io::Error| WriteError::Io {
        path: what.to_path_buf(),
        source,
    };
    std::fs::create_dir_all(dir).map_err(|e| err(dir, e))?;
    let text = text(r, source);
    let path = dir.join(TEXT_FILE);
    std::fs::write(&path, &text).map_err(|e| err(&path, e))?;
    plot(r, &dir.join(PLOT_FILE), source)?;
    Ok(text)
}

/// The text report: a one-paragraph summary, the gap before and after, the effects, the shared disturbances, the
/// axes and each axis's τ table — numbers to three significant figures with their units; every fitted parameter
/// is in the JSON (`--json`).
pub fn text(r: &Report, source: &str) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "Sim-to-real diagnosis of {source}");
    let _ = writeln!(s);
    let _ = writeln!(s, "{}", wrap(&paragraph(r), 116));
    let _ = writeln!(s);
    gap(&mut s, r);
    effects(&mut s, r);
    disturbances(&mut s, r);
    axes(&mut s, r);
    s
}

/// A τ range in seconds, or a single τ when both ends are the same octave.
fn tau_range(t: [f64; 2]) -> String {
    let (a, b) = (sig3(t[0]), sig3(t[1]));
    if a == b {
        format!("{a} s")
    } else {
        format!("{a}–{b} s")
    }
}

/// The unit of an axis label (`gx` … `az`) or sensor kind (`gyro`, `accel`).
fn unit(label: &str) -> &'static str {
    if label.starts_with('g') { "°/s" } else { "g" }
}

/// Greedy word wrap at `width` characters.
fn wrap(text: &str, width: usize) -> String {
    let mut out = String::new();
    let mut line = 0;
    for w in text.split_whitespace() {
        let n = w.chars().count();
        if line > 0 && line + 1 + n > width {
            out.push('\n');
            line = 0;
        } else if line > 0 {
            out.push(' ');
            line += 1;
        }
        out.push_str(w);
        line += n;
    }
    out
}

/// An effect as words: kind, sensor, axes, and groups where they are not all.
fn effect_name(e: &Effect) -> String {
    let groups = match e.kind.as_str() {
        "outlier_sensor" | "block_common_mode" | "sensor_drift" | "periodic" | "bias_step"
        | "warm_up" => {
            format!(" (group {})", e.groups)
        }
        _ => String::new(),
    };
    format!("{} on {} {}{groups}", e.kind, e.sensor, e.axes)
}

/// The summary paragraph: where the gap lies, what causes it, how far it shrinks.
fn paragraph(r: &Report) -> String {
    let sig: Vec<&AxisReport> = r.axes.iter().filter(|a| a.significant[0]).collect();
    let n = r.axes.first().map_or(0, |a| a.sensors);
    let mut p = format!(
        "{} samples at {} Hz ({} of record), {} sensors per axis, cluster mean with {} weights.",
        r.samples,
        sig3(1.0 / r.tau0_s),
        duration(r.samples as f64 * r.tau0_s),
        n,
        match r.weights {
            super::WeightRule::Equal => "equal",
            super::WeightRule::InverseVariance => "inverse-variance",
        }
    );
    if sig.is_empty() {
        p.push_str(" No axis departs significantly from the √N model of independent sensors");
    } else {
        let taus: Vec<f64> = sig
            .iter()
            .flat_map(|a| {
                a.taus
                    .iter()
                    .filter(|t| t.z_before.abs() > 2.0)
                    .map(|t| t.tau_s)
            })
            .collect();
        let lo = taus.iter().copied().fold(f64::INFINITY, f64::min);
        let hi = taus.iter().copied().fold(0.0, f64::max);
        let _ = write!(
            p,
            " The cluster departs from the √N model of independent sensors on {} of {} axes ({})",
            sig.len(),
            r.axes.len(),
            sig.iter()
                .map(|a| a.axis.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        );
        if lo.is_finite() && hi > 0.0 {
            let _ = write!(p, ", at τ {}", tau_range([lo, hi]));
        }
    }
    let named: Vec<&Effect> = r
        .effects
        .iter()
        .filter(|e| e.kind != "unexplained")
        .collect();
    let unexplained: Vec<&Effect> = r
        .effects
        .iter()
        .filter(|e| e.kind == "unexplained")
        .collect();
    if named.is_empty() {
        p.push_str("; no effect is named.");
    } else {
        let _ = write!(
            p,
            "; what causes it: {}.",
            named
                .iter()
                .map(|e| format!("{} at τ {}", effect_name(e), tau_range(e.tau_s)))
                .collect::<Vec<_>>()
                .join("; ")
        );
    }
    if r.heldout.gap_before > 0.0 {
        let _ = write!(
            p,
            " On the held-out half the excess gap goes from {} to {} with these effects (−{} %).",
            sig3(r.heldout.gap_before),
            sig3(r.heldout.gap_after),
            sig3(100.0 * (1.0 - r.heldout.gap_after / r.heldout.gap_before))
        );
    }
    if !unexplained.is_empty() {
        let _ = write!(
            p,
            " Still unexplained: {}.",
            unexplained
                .iter()
                .map(|e| format!("{} {} at τ {}", e.sensor, e.axes, tau_range(e.tau_s)))
                .collect::<Vec<_>>()
                .join(", ")
        );
    }
    if !r.disturbances.is_empty() {
        let _ = write!(
            p,
            " {} shared disturbance(s) lie in the record (listed below).",
            r.disturbances.len()
        );
    }
    p
}

/// A duration in s, min or h.
fn duration(t: f64) -> String {
    if t >= 7200.0 {
        format!("{} h", sig3(t / 3600.0))
    } else if t >= 120.0 {
        format!("{} min", sig3(t / 60.0))
    } else {
        format!("{} s", sig3(t))
    }
}

/// The gap before and after, first and held-out half.
fn gap(s: &mut String, r: &Report) {
    let _ = writeln!(
        s,
        "Excess gap: ln(measured / predicted cluster deviation) beyond its 2σ interval (χ² at the Greenhall EDF, the\n\
         prediction's scatter, 3 % tolerance), RMS over the octave τ down to {} blocks on the axes whose gap is\n\
         significant (scan test, p = {} per axis). Fitted on the first half, checked on the second (held-out).",
        r.min_blocks,
        sig3(r.p_false)
    );
    let rows = [
        ["model", "first half", "held-out", "plain RMS ln, held-out"].map(String::from),
        [
            "before: √N (independent sensors)".into(),
            sig3(r.gap_before),
            sig3(r.heldout.gap_before),
            sig3(r.heldout.rms_before),
        ],
        [
            "after: with the effects below".into(),
            sig3(r.gap_after),
            sig3(r.heldout.gap_after),
            sig3(r.heldout.rms_after),
        ],
    ];
    for [model, first, held_out, rms] in rows {
        let _ = writeln!(s, "  {model:<34} {first:>10} {held_out:>10} {rms:>22}");
    }
    let _ = writeln!(s);
}

/// The effects as a table: where each acts and how much, and its main parameters with units.
fn effects(s: &mut String, r: &Report) {
    if r.effects.is_empty() {
        let _ = writeln!(s, "Effects: none.");
        let _ = writeln!(s);
        return;
    }
    let _ = writeln!(
        s,
        "Effects (chosen by the gap they explain on the held-out half; parameters in the JSON):"
    );
    let _ = writeln!(
        s,
        "  {:<18} {:<6} {:<4} {:<14} {:<13} {:<16} {:<34} main parameters",
        "effect", "sensor", "axes", "groups", "region", "τ range", "share of cluster variance"
    );
    for e in &r.effects {
        let groups = match &e.groups {
            Groups::List(v) if v.len() > 4 => format!("{} groups", v.len()),
            g => g.to_string(),
        };
        let _ = writeln!(
            s,
            "  {:<18} {:<6} {:<4} {:<14} {:<13} {:<16} {:<34} {}",
            e.kind,
            e.sensor,
            e.axes,
            groups,
            e.region,
            tau_range(e.tau_s),
            share_words(e),
            main_parameters(e)
        );
    }
    let _ = writeln!(s);
}

/// An effect's share of the held-out cluster Allan variance in words: the part it accounts for at its largest
/// (at `tau_at_max_s`); for `unexplained`, the part the model misses or, when the model predicts too much, by how
/// much.
fn share_words(e: &Effect) -> String {
    let at = sig3(e.tau_at_max_s);
    if e.kind == "unexplained" && e.share < 0.0 {
        // share = 1 − predicted/measured < 0: predicted = (1 − share)·measured.
        return format!("model {}× the measured at {at} s", sig3(1.0 - e.share));
    }
    if e.kind == "bias_step" {
        return format!("{} % of its sensor's at {at} s", sig3(100.0 * e.share));
    }
    if e.kind == "warm_up" {
        return format!(
            "largest step {} % of its sensor's at {at} s",
            sig3(100.0 * e.share)
        );
    }
    let what = if e.kind == "unexplained" {
        "missed"
    } else {
        "up to"
    };
    format!(
        "{what} {} % at {at} s",
        sig3(100.0 * e.share.clamp(0.0, 1.0))
    )
}

/// The parameters a reader looks for first, per kind, with units (unit: that of the sensor).
fn main_parameters(e: &Effect) -> String {
    let u = unit(&e.sensor);
    let keys: &[(&str, &str)] = match e.kind.as_str() {
        "common_mode" => &[("rho_white", ""), ("rho_flicker", "")],
        "common_mode_drift" => &[("shared_random_walk", "/√s"), ("shared_ramp", "/s")],
        "thermal" => &[("shared_beta", "/°C")],
        "periodic" => &[("period_s", "s"), ("amplitude", "")],
        "bias_step" => &[("at_s", "s"), ("size", "")],
        "warm_up" => &[("end_s", "s")],
        "sensor_drift" => &[("random_walk", "/√s")],
        "unexplained" => &[("largest_z", "σ")],
        _ => &[],
    };
    let show = |p: &serde_json::Value, prefix: &str| -> Vec<String> {
        keys.iter()
            .filter_map(|(k, suffix)| {
                let v = p.get(*k)?.as_f64()?;
                let unit = match *suffix {
                    "" if matches!(*k, "amplitude" | "size") => format!(" {u}"),
                    "" | "σ" => String::new(),
                    "s" => " s".into(),
                    sfx => format!(" {u}{sfx}"),
                };
                Some(format!("{prefix}{k} {}{unit}", sig3(v)))
            })
            .collect()
    };
    let mut out = Vec::new();
    for (axis, p) in &e.params {
        let mut items = show(p, "");
        if let Some(per) = p.get("sensors").and_then(|x| x.as_object()) {
            for (g, q) in per {
                items.extend(show(q, &format!("group {g} ")));
            }
        }
        if e.kind == "unexplained"
            && let Some(c) = p.get("closest").and_then(|x| x.as_str())
        {
            let x = p
                .get("closest_explains")
                .and_then(|x| x.as_f64())
                .unwrap_or(0.0);
            items.push(format!("closest {c} explains {} %", sig3(100.0 * x)));
        }
        if !items.is_empty() {
            out.push(format!("{axis}: {}", items.join(", ")));
        }
    }
    out.join("; ")
}

/// The shared disturbances, one per line.
fn disturbances(s: &mut String, r: &Report) {
    if r.disturbances.is_empty() {
        return;
    }
    let _ = writeln!(
        s,
        "Shared disturbances (the cluster mean's scatter over {}-sample windows, about their line, against the\n\
         typical window's): transients every sensor saw, included above; not stationary noise.",
        quiet::WINDOW
    );
    for d in &r.disturbances {
        let _ = writeln!(
            s,
            "  {} {}: {} … {} s after the first sample, variance ×{} (threshold ×{})",
            d.sensor,
            d.axis,
            sig3(d.start_s),
            sig3(d.end_s),
            sig3(d.variance_ratio),
            sig3(d.threshold)
        );
    }
    let _ = writeln!(s);
}

/// The per-axis table, then each axis's regions and τ table.
fn axes(s: &mut String, r: &Report) {
    let _ = writeln!(
        s,
        "Per axis (gains: single sensor over cluster deviation, 68 % intervals; weighting: what an inverse-variance\n\
         mean would gain over the equal mean; excess gap on the held-out half):"
    );
    let _ = writeln!(
        s,
        "  {:<4} {:>3} {:>6}  {:<22} {:<22} {:>9}  {:<17} effects",
        "axis", "N", "√N", "RMS-noise gain", "bias-stability gain", "weighting", "gap before→after"
    );
    for a in &r.axes {
        let g =
            |x: &super::Gain| format!("{} [{}, {}]", sig3(x.value), sig3(x.ci_lo), sig3(x.ci_hi));
        let _ = writeln!(
            s,
            "  {:<4} {:>3} {:>6}  {:<22} {:<22} {:>9}  {:<17} {}",
            a.axis,
            a.sensors,
            sig3(a.expected_gain),
            g(&a.rms_gain),
            g(&a.bias_stability_gain),
            sig3(a.weighting_recovers),
            format!("{} → {}", sig3(a.heldout_gap[0]), sig3(a.heldout_gap[1])),
            if a.effects.is_empty() {
                "-".into()
            } else {
                a.effects.join(", ")
            }
        );
    }
    for a in &r.axes {
        axis(s, a);
    }
}

/// One axis: its τ regions and its τ table (held-out half) and its independence test.
fn axis(s: &mut String, a: &AxisReport) {
    let u = unit(&a.axis);
    let _ = writeln!(s);
    let _ = writeln!(s, "{} (held-out half; deviations in {u}):", a.axis);
    for reg in &a.regions {
        let _ = writeln!(
            s,
            "  {:<12} τ {:<16} mean gap (ln) {:>7} → {:>7}, significant points {}/{} → {}/{}",
            reg.region,
            tau_range(reg.tau_s),
            sig3(reg.gap_before),
            sig3(reg.gap_after),
            reg.significant_before,
            reg.points,
            reg.significant_after,
            reg.points
        );
    }
    let _ = writeln!(
        s,
        "  {:>9} {:>7} {:>8}  {:>9} {:>21}  {:>9} {:>9}  {:>6} {:>6}  {:>10} {:>6}",
        "τ (s)",
        "blocks",
        "EDF",
        "measured",
        "68 % interval",
        "√N model",
        "model",
        "z √N",
        "z",
        "cross corr",
        "(z)"
    );
    for t in &a.taus {
        let _ = writeln!(
            s,
            "  {:>9} {:>7} {:>8}  {:>9} {:>21}  {:>9} {:>9}  {:>6} {:>6}  {:>10} {:>6}",
            sig3(t.tau_s),
            t.blocks,
            sig3(t.edf),
            sig3(t.dev),
            format!("[{}, {}]", sig3(t.dev_lo), sig3(t.dev_hi)),
            sig3(t.predicted_before),
            sig3(t.predicted_after),
            format!("{:+.1}", t.z_before),
            format!("{:+.1}", t.z_after),
            sig3(t.cross_correlation),
            format!("{:+.1}", t.cross_z)
        );
    }
    let _ = writeln!(
        s,
        "  independence (held-out cross covariance): χ² {} on {} points, p {}",
        sig3(a.independence.chi2),
        a.independence.points,
        if a.independence.p_value > 0.0 {
            format!("= {}", sig3(a.independence.p_value))
        } else {
            "< 1e-300".into()
        }
    );
}

/// Measured vs predicted cluster deviation before and after, per axis (held-out half).
pub fn plot(r: &Report, path: &Path, source: &str) -> Result<(), plot::PlotError> {
    let panels: Vec<Panel> = r
        .curves
        .iter()
        .map(|c| {
            let m = &c.measured;
            let unit = if c.axis.starts_with('g') {
                "deg/s"
            } else {
                "g"
            };
            Panel {
                title: c.axis.clone(),
                y_label: format!("cluster deviation [{unit}]"),
                curves: vec![
                    Curve {
                        label: Some("predicted before (independent)".into()),
                        points: m
                            .tau_s
                            .iter()
                            .copied()
                            .zip(c.before.iter().copied())
                            .collect(),
                        bars: vec![],
                        style: Style::Dashed,
                    },
                    Curve {
                        label: Some("predicted after (with effects)".into()),
                        points: m
                            .tau_s
                            .iter()
                            .copied()
                            .zip(c.after.iter().copied())
                            .collect(),
                        bars: vec![],
                        style: Style::Model(3),
                    },
                    Curve {
                        label: Some("measured (held-out half)".into()),
                        points: m.tau_s.iter().copied().zip(m.dev.iter().copied()).collect(),
                        bars: (0..m.tau_s.len())
                            .map(|k| (m.tau_s[k], m.lo[k], m.hi[k]))
                            .collect(),
                        style: Style::Bold,
                    },
                ],
            }
        })
        .collect();
    plot::adev_panels(
        path,
        &format!("Diagnosis — {source}: held-out half"),
        &panels,
        3,
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A τ range in three significant figures.
    #[test]
    fn tau_ranges() {
        // One octave is one τ, not a range.
        assert_eq!(tau_range([2.048, 2.048]), "2.05 s");
        assert_eq!(tau_range([0.2, 3276.8]), "0.200–3280 s");
    }

    /// A clean cluster's report: the summary paragraph first, no JSON and no long digit strings anywhere; a
    /// record with a common mode names it in the summary and in the effects table with its τ range.
    #[test]
    fn the_report_reads() {
        let rec = super::super::tests::cluster(20_000, 0.1, 3);
        let r = super::super::diagnose(&rec, &super::super::Options::default()).unwrap();
        let text = text(&r, "rec.csv");
        let mut lines = text.lines();
        assert_eq!(lines.next(), Some("Sim-to-real diagnosis of rec.csv"));
        assert_eq!(lines.next(), Some(""));
        let summary = lines.next().unwrap_or("");
        assert!(summary.starts_with("20000 samples at 20.0 Hz"), "{summary}");
        assert!(text.contains("common_mode on gyro"), "{text}");
        assert!(!text.contains('{') && !text.contains('"'), "{text}");
        // No number with more than four digits after a point (three significant figures: "0.0123" at most,
        // smaller ones in scientific notation).
        let long = text
            .split(|c: char| !(c.is_ascii_digit() || c == '.'))
            .filter(|w| w.split('.').nth(1).is_some_and(|f| f.len() > 4))
            .collect::<Vec<_>>();
        assert!(long.is_empty(), "{long:?}\n{text}");
    }
}
