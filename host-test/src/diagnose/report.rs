//! Human-readable report and plots of a diagnosis.

use super::{AxisReport, Report, quiet};
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

/// The text report.
pub fn text(r: &Report, source: &str) -> String {
    let mut s = String::new();
    summary(&mut s, r, source);
    effects(&mut s, r);
    axes(&mut s, r);
    s
}

/// The record, the method and the gap before and after.
fn summary(s: &mut String, r: &Report, source: &str) {
    let _ = writeln!(s, "Sim-to-real diagnosis of {source}");
    let _ = writeln!(
        s,
        "{} samples at {:.6} s; cluster mean with {:?} weights; fitted on the first half, checked on the second.",
        r.samples, r.tau0_s, r.weights
    );
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "Gap = excess of ln(measured / predicted) cluster deviation beyond its 2-sigma interval (chi-squared at the\n\
         Greenhall EDF, the prediction's scatter and 3 % tolerance), RMS over every octave tau down to {} blocks,\n\
         on the axes whose gap is significant (scan test, p = {}); plain RMS of ln ratio: {:.3} -> {:.3} held-out.",
        r.min_blocks, r.p_false, r.heldout.rms_before, r.heldout.rms_after
    );
    let _ = writeln!(
        s,
        "  before (independent typical sensors, the sqrt(N) model): {:.3} first half, {:.3} held-out",
        r.gap_before, r.heldout.gap_before
    );
    let _ = writeln!(
        s,
        "  after (with the effects below):                         {:.3} first half, {:.3} held-out",
        r.gap_after, r.heldout.gap_after
    );
    if r.heldout.gap_before > 0.0 {
        let _ = writeln!(
            s,
            "  held-out gap shrinks by {:.0} %",
            100.0 * (1.0 - r.heldout.gap_after / r.heldout.gap_before)
        );
    }
    if !r.disturbances.is_empty() {
        let _ = writeln!(
            s,
            "Shared disturbances (the cluster mean's scatter over {}-sample windows, about their line, against the\n\
             typical window's): transients every sensor saw, included above; not stationary noise.",
            quiet::WINDOW
        );
        for d in &r.disturbances {
            let _ = writeln!(
                s,
                "  {} {}: {:.3} … {:.3} s after the first sample, variance ×{:.1} (threshold ×{:.2})",
                d.sensor, d.axis, d.start_s, d.end_s, d.variance_ratio, d.threshold
            );
        }
    }
    let _ = writeln!(s);
}

/// The effects chosen, with their parameters.
fn effects(s: &mut String, r: &Report) {
    if r.effects.is_empty() {
        let _ = writeln!(s, "Effects: none (no significant gap).");
    } else {
        let _ = writeln!(
            s,
            "Effects (chosen by the gap they explain on the held-out half):"
        );
        for e in &r.effects {
            let groups = if matches!(
                e.kind.as_str(),
                "outlier_sensor" | "block_common_mode" | "sensor_drift" | "periodic" | "bias_step"
            ) {
                format!(", groups {}", e.groups)
            } else {
                String::new()
            };
            let _ = writeln!(
                s,
                "  {} — {} {}{}: acts in the {} region, tau {:.3} … {:.1} s, up to {:.0} % of the cluster variance (tau {:.1} s)",
                e.kind,
                e.sensor,
                e.axes,
                groups,
                e.region,
                e.tau_s[0],
                e.tau_s[1],
                100.0 * e.share,
                e.tau_at_max_s
            );
            for (axis, p) in &e.params {
                let mut brief = p.clone();
                if let Some(o) = brief.as_object_mut() {
                    o.remove("deviation_ratio_to_typical");
                    o.remove("beta");
                    o.remove("acts");
                }
                let _ = writeln!(s, "      {axis}: {brief}");
            }
        }
    }
}

/// The per-axis table, and each axis's regions and τ rows.
fn axes(s: &mut String, r: &Report) {
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "Per axis (gains with 68 % intervals; 'weighting' = what an inverse-variance mean recovers over the equal mean):"
    );
    let _ = writeln!(
        s,
        "  axis  N  expected  RMS-noise gain          bias-stability gain     weighting  gap before→after (held-out)  effects"
    );
    for a in &r.axes {
        axis(s, a);
    }
}

/// One axis: its row, its τ regions, its τ rows and its independence test.
fn axis(s: &mut String, a: &AxisReport) {
    let _ = writeln!(
        s,
        "  {:<4} {:>2}  {:>7.2}   {:5.2} [{:5.2}, {:5.2}]    {:5.2} [{:5.2}, {:5.2}]    {:6.3}     {:.3} → {:.3}                 {}",
        a.axis,
        a.sensors,
        a.expected_gain,
        a.rms_gain.value,
        a.rms_gain.ci_lo,
        a.rms_gain.ci_hi,
        a.bias_stability_gain.value,
        a.bias_stability_gain.ci_lo,
        a.bias_stability_gain.ci_hi,
        a.weighting_recovers,
        a.heldout_gap[0],
        a.heldout_gap[1],
        if a.effects.is_empty() {
            "-".into()
        } else {
            a.effects.join(", ")
        }
    );
    for reg in &a.regions {
        let _ = writeln!(
            s,
            "        {:<12} tau {:>9.3} … {:>9.3} s: mean gap {:+.3} → {:+.3}, significant points {}/{} → {}/{}",
            reg.region,
            reg.tau_s[0],
            reg.tau_s[1],
            reg.gap_before,
            reg.gap_after,
            reg.significant_before,
            reg.points,
            reg.significant_after,
            reg.points
        );
    }
    let _ = writeln!(
        s,
        "        tau s       blocks  EDF      measured dev  [68 %]                 P0 / model dev          z P0 / model  cross corr (z)"
    );
    for t in &a.taus {
        let _ = writeln!(
            s,
            "        {:>10.3} {:>7} {:>8.1}  {:>10.3e} [{:.3e}, {:.3e}]  {:.3e} / {:.3e}  {:+6.1} / {:+5.1}  {:+.4} ({:+.1})",
            t.tau_s,
            t.blocks,
            t.edf,
            t.dev,
            t.dev_lo,
            t.dev_hi,
            t.predicted_before,
            t.predicted_after,
            t.z_before,
            t.z_after,
            t.cross_correlation,
            t.cross_z
        );
    }
    let _ = writeln!(
        s,
        "        independence (held-out cross covariance): chi2 {:.1} on {} points, p = {:.2e}",
        a.independence.chi2, a.independence.points, a.independence.p_value
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
