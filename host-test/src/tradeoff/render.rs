//! The trade-off's outputs: the two log-log figures (accuracy against mass and against power, as the seed paper's
//! Figures 9 and 10), the Markdown table and the JSON.

use super::place::{Estimate, Figures};
use super::{Tradeoff, TradeoffError};
use crate::figures::sig3;
use crate::plot::PlotError;
use plotters::prelude::*;
use std::fmt::Write as _;
use std::path::Path;

/// `value [lo, hi]`, 3 significant figures each.
fn est(e: &Estimate) -> String {
    format!("{} [{}, {}]", sig3(e.value), sig3(e.lo), sig3(e.hi))
}

/// One point of a figure.
struct Point {
    label: String,
    x: f64,
    y: f64,
    bar: Option<(f64, f64)>,
    color: RGBColor,
    /// Label on the left of the point (the board of least mass or power, so that two boards' labels do not overlap).
    left: bool,
}

const PAPER: RGBColor = RGBColor(31, 119, 180);
const CURRENT: RGBColor = RGBColor(44, 160, 44);
const CLUSTER: RGBColor = RGBColor(214, 39, 40);
const SINGLE: RGBColor = RGBColor(255, 127, 14);

/// The points of one panel: `gyro` (°/h) or `accel` (µg) bias instability against mass (`by_power` false) or power.
fn points(t: &Tradeoff, gyro: bool, by_power: bool) -> Vec<Point> {
    let mut pts = Vec::new();
    for imu in &t.catalogue {
        let y = if gyro {
            Some(imu.gyro_bias_instability_dph.value)
        } else {
            imu.accel_bias_instability_ug.as_ref().map(|f| f.value)
        };
        let x = if by_power {
            imu.power_w.value
        } else {
            imu.mass_g.value
        };
        if let Some(y) = y {
            pts.push(Point {
                label: imu.name.clone(),
                x,
                y,
                bar: None,
                color: if imu.in_paper { PAPER } else { CURRENT },
                left: false,
            });
        }
    }
    let kind = if gyro { "gyro" } else { "accel" };
    let Some((_, cluster, single)) = t.placement.mean.iter().find(|m| m.0 == kind) else {
        return pts;
    };
    let x_of = |b: &super::board::Budget| if by_power { b.power_w } else { b.mass_g };
    let leftmost = t.budgets.iter().map(x_of).fold(f64::INFINITY, f64::min);
    for b in &t.budgets {
        let x = x_of(b);
        for (what, f, color) in [
            ("cluster", cluster, CLUSTER),
            ("single sensor", single, SINGLE),
        ] {
            let f: &Figures = f;
            pts.push(Point {
                label: format!("{what}, {}", b.short),
                x,
                y: f.bias_instability.value,
                bar: Some((f.bias_instability.lo, f.bias_instability.hi)),
                color,
                left: t.budgets.len() > 1 && x == leftmost,
            });
        }
    }
    pts
}

/// Draws one figure: gyro and accelerometer panels against mass or power.
fn figure(t: &Tradeoff, path: &Path, by_power: bool) -> Result<(), TradeoffError> {
    crate::plot::ensure_font()?;
    let e2 = |x: DrawingAreaErrorKind<<BitMapBackend as DrawingBackend>::ErrorType>| {
        PlotError::Draw(x.to_string())
    };
    let root = BitMapBackend::new(path, (1400, 640)).into_drawing_area();
    root.fill(&WHITE).map_err(e2)?;
    let (xq, xunit) = if by_power {
        ("power", "W")
    } else {
        ("mass", "g")
    };
    let root = root
        .titled(
            &format!(
                "Bias instability against {xq} (as the seed paper's Fig. {}) — {}",
                if by_power { 10 } else { 9 },
                t.recording
            ),
            ("sans-serif", 20),
        )
        .map_err(e2)?;
    let panels = root.split_evenly((1, 2));
    for (area, gyro) in panels.iter().zip([true, false]) {
        let pts = points(t, gyro, by_power);
        let xs = pts.iter().map(|p| p.x).filter(|x| *x > 0.0);
        let ys = pts
            .iter()
            .flat_map(|p| [Some(p.y), p.bar.map(|b| b.0), p.bar.map(|b| b.1)])
            .flatten()
            .filter(|y| *y > 0.0);
        let (x0, x1) = xs.fold((f64::MAX, f64::MIN), |(a, b), x| (a.min(x), b.max(x)));
        let (y0, y1) = ys.fold((f64::MAX, f64::MIN), |(a, b), y| (a.min(y), b.max(y)));
        if x0 > x1 || y0 > y1 {
            continue;
        }
        let (what, unit) = if gyro {
            ("gyro bias instability", "°/h")
        } else {
            ("accelerometer bias instability", "µg")
        };
        let mut chart = ChartBuilder::on(area)
            .caption(what, ("sans-serif", 16))
            .margin(12)
            .x_label_area_size(40)
            .y_label_area_size(70)
            .build_cartesian_2d(
                (x0 / 4.0..x1 * 8.0).log_scale(),
                (y0 / 3.0..y1 * 3.0).log_scale(),
            )
            .map_err(e2)?;
        chart
            .configure_mesh()
            .x_desc(format!("{xq} [{xunit}]"))
            .y_desc(format!("{what} [{unit}]"))
            .x_label_formatter(&|v| sig3(*v))
            .y_label_formatter(&|v| sig3(*v))
            .label_style(("sans-serif", 12))
            .draw()
            .map_err(e2)?;
        for p in &pts {
            let style = ShapeStyle {
                color: p.color.mix(1.0),
                filled: true,
                stroke_width: 2,
            };
            if let Some((lo, hi)) = p.bar {
                chart
                    .draw_series(std::iter::once(ErrorBar::new_vertical(
                        p.x, lo, p.y, hi, style, 8,
                    )))
                    .map_err(e2)?;
            }
            chart
                .draw_series(std::iter::once(
                    EmptyElement::at((p.x, p.y))
                        + Circle::new((0, 0), 5, style)
                        + Text::new(
                            p.label.clone(),
                            // ≈ 6.5 px per character at 12 px.
                            (
                                if p.left {
                                    -12 - 13 * p.label.chars().count() as i32 / 2
                                } else {
                                    8
                                },
                                -4,
                            ),
                            ("sans-serif", 12).into_font(),
                        ),
                ))
                .map_err(e2)?;
        }
    }
    root.present().map_err(e2)?;
    Ok(())
}

/// The Markdown report.
pub fn markdown(t: &Tradeoff) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "# Trade-off: {} among commercial IMUs\n", t.recording);
    let _ = writeln!(
        s,
        "Bias instability = the ADEV floor (no 0.664 factor, as the makers quote it); random walk = σ(τ)·√τ at τ = {} s \
         (ARW °/√h, VRW (m/s)/√h); 68.3 % intervals (Greenhall EDF). Single sensor: the median of the groups, with \
         that sensor's interval. Definitions: docs/tradeoff.md.\n",
        t.placement
            .axes
            .first()
            .map_or_else(|| "1".into(), |a| sig3(a.cluster.random_walk_tau_s))
    );
    let _ = writeln!(s, "## The recording's figures\n");
    let _ = writeln!(
        s,
        "| axis | cluster bias instability (τ of floor) | single | cluster random walk | single |\n|---|---|---|---|---|"
    );
    let unit = |k: &str| {
        if k == "gyro" {
            ("°/h", "°/√h")
        } else {
            ("µg", "(m/s)/√h")
        }
    };
    for a in &t.placement.axes {
        let (u1, u2) = unit(a.kind);
        let _ = writeln!(
            s,
            "| {} {} | {} {u1} ({} s) | {} {u1} | {} {u2} | {} {u2} |",
            a.kind,
            a.axis,
            est(&a.cluster.bias_instability),
            sig3(a.cluster.floor_tau_s),
            est(&a.single.bias_instability),
            est(&a.cluster.random_walk),
            est(&a.single.random_walk)
        );
    }
    for (k, c, si) in &t.placement.mean {
        let (u1, u2) = unit(k);
        let _ = writeln!(
            s,
            "| {k}, mean of x y z (plotted) | {} {u1} | {} {u1} | {} {u2} | {} {u2} |",
            est(&c.bias_instability),
            est(&si.bias_instability),
            est(&c.random_walk),
            est(&si.random_walk)
        );
    }
    boards_section(&mut s, t);
    catalogue_section(&mut s, t);
    let _ = writeln!(
        s,
        "\nSources of every figure: tradeoff.json (`catalogue`) and data/imus.toml."
    );
    s
}

/// The boards' budgets, the MCU's power and the battery check.
fn boards_section(s: &mut String, t: &Tradeoff) {
    let _ = writeln!(s, "\n## Boards\n");
    for b in &t.budgets {
        let _ = writeln!(s, "### {}\n", b.name);
        let _ = writeln!(
            s,
            "| part | count | power [W] | mass [g] | figures checked |\n|---|---:|---:|---:|---|"
        );
        for l in &b.lines {
            let _ = writeln!(
                s,
                "| {} | {} | {} | {} | {} |",
                l.name,
                l.count,
                sig3(l.power_w),
                l.mass_g.map_or_else(|| "—".into(), sig3),
                if l.checked { "yes" } else { "no" }
            );
        }
        let _ = writeln!(
            s,
            "| **total** | | **{}** | **{}** | |\n",
            sig3(b.power_w),
            sig3(b.mass_g)
        );
        let _ = writeln!(
            s,
            "Figures checked against a retrieved text: {} of the board file's {}.\n",
            b.figures_checked.checked, b.figures_checked.total
        );
        if let Some(m) = &b.mcu {
            let _ = writeln!(
                s,
                "MCU: {} instructions per frame (mcu-bench) × {} frames/s ÷ {} MHz = duty {} %; mean current {} mA → \
                 {} W (always in Run mode: {} W).\n",
                sig3(m.instructions_per_frame),
                sig3(m.frame_rate_hz),
                sig3(m.clock_hz / 1e6),
                sig3(100.0 * m.duty),
                sig3(m.mean_ma),
                sig3(m.power_w),
                sig3(m.always_run_w)
            );
        }
    }
    for (name, c) in &t.batteries {
        let _ = writeln!(
            s,
            "Battery ({name}): {} Wh over the paper's run times gives a mean {}–{} W for the whole assembly; the \
             budget above adds up to {} W ({}–{} % of it; regulators, the Wi-Fi link's peaks and unlisted parts are the \
             rest).\n",
            sig3(c.energy_wh),
            sig3(c.power_min_w),
            sig3(c.power_max_w),
            sig3(c.budget_w),
            sig3(100.0 * c.budget_w / c.power_max_w),
            sig3(100.0 * c.budget_w / c.power_min_w)
        );
    }
}

/// The catalogue's figures.
fn catalogue_section(s: &mut String, t: &Tradeoff) {
    let _ = writeln!(s, "## The catalogue\n");
    let _ = writeln!(
        s,
        "| IMU | gyro bias instability [°/h] | ARW [°/√h] | accel bias instability [µg] | VRW [(m/s)/√h] | mass [g] | \
         power [W] | figures checked |\n|---|---:|---:|---:|---:|---:|---:|---|"
    );
    let opt = |f: &Option<super::Figure>| f.as_ref().map_or_else(|| "—".into(), |f| sig3(f.value));
    for i in &t.catalogue {
        let c = super::Checked::of(i.figures().into_iter().map(|(_, _, f)| f));
        let _ = writeln!(
            s,
            "| {}{} | {} | {} | {} | {} | {} | {} | {} of {} |",
            i.name,
            if i.in_paper { " (paper)" } else { "" },
            sig3(i.gyro_bias_instability_dph.value),
            opt(&i.gyro_arw_dprh),
            opt(&i.accel_bias_instability_ug),
            opt(&i.accel_vrw_mps_rh),
            sig3(i.mass_g.value),
            sig3(i.power_w.value),
            c.checked,
            c.total
        );
    }
    let _ = writeln!(
        s,
        "\nFigures checked against a retrieved text: {} of the catalogue's {}.",
        t.catalogue_checked.checked, t.catalogue_checked.total
    );
}

/// A few lines for the terminal: the plotted figures, each board's power and mass, the battery check.
pub fn summary(t: &Tradeoff) -> String {
    let mut s = String::new();
    for (k, c, si) in &t.placement.mean {
        let (u1, u2) = if *k == "gyro" {
            ("°/h", "°/√h")
        } else {
            ("µg", "(m/s)/√h")
        };
        let _ = writeln!(
            s,
            "{k} (mean of x y z): bias instability cluster {} {u1}, single {} {u1}; random walk cluster {} {u2}, single {} {u2}",
            est(&c.bias_instability),
            est(&si.bias_instability),
            est(&c.random_walk),
            est(&si.random_walk)
        );
    }
    for b in &t.budgets {
        let _ = write!(
            s,
            "{}: {} W, {} g",
            b.short,
            sig3(b.power_w),
            sig3(b.mass_g)
        );
        if let Some(m) = &b.mcu {
            let _ = write!(
                s,
                " (MCU duty {} %, {} W)",
                sig3(100.0 * m.duty),
                sig3(m.power_w)
            );
        }
        let _ = writeln!(s);
    }
    let _ = write!(
        s,
        "figures checked against a retrieved text: catalogue {} of {}",
        t.catalogue_checked.checked, t.catalogue_checked.total
    );
    for b in &t.budgets {
        let _ = write!(
            s,
            ", {} {} of {}",
            b.short, b.figures_checked.checked, b.figures_checked.total
        );
    }
    let _ = writeln!(s);
    for (name, c) in &t.batteries {
        let _ = writeln!(
            s,
            "battery ({name}): {} Wh over its run times = {}–{} W mean, budget {} W",
            sig3(c.energy_wh),
            sig3(c.power_min_w),
            sig3(c.power_max_w),
            sig3(c.budget_w)
        );
    }
    s
}

/// Writes both figures, the Markdown and the JSON into `out`.
pub fn write_all(t: &Tradeoff, out: &Path) -> Result<(), TradeoffError> {
    let [mass, power, md, json] = super::OUTPUTS;
    figure(t, &out.join(mass), false)?;
    figure(t, &out.join(power), true)?;
    let write = |name: &str, text: String| {
        let path = out.join(name);
        std::fs::write(&path, text).map_err(|source| TradeoffError::Write { path, source })
    };
    write(md, markdown(t))?;
    let text = serde_json::to_string_pretty(t).map_err(|source| TradeoffError::Json {
        origin: "tradeoff.json".into(),
        source,
    })?;
    write(json, text)
}
