//! Log-log Allan-deviation plots in panels (PNG or SVG by the file's extension). Text uses DejaVu Sans, loaded at
//! run time from the system (Debian package `fonts-dejavu-core`) or from `$GROUND_FONT`.

use crate::allan::recording;
use crate::recording::SensorKind;
use plotters::coord::Shift;
use plotters::prelude::*;
use std::path::Path;
use std::sync::OnceLock;

/// How a curve is drawn.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Style {
    /// Thin, light, from a palette (single sensors).
    Thin(usize),
    /// Bold black (the measured cluster).
    Bold,
    /// Dashed grey (an expectation).
    Dashed,
    /// Bold coloured (a model prediction), by palette index.
    Model(usize),
}

/// One curve: points (τ, deviation), optional error bars (τ, lo, hi).
#[derive(Clone, Debug)]
pub struct Curve {
    /// Legend entry (none for the many thin curves).
    pub label: Option<String>,
    /// (τ s, deviation).
    pub points: Vec<(f64, f64)>,
    /// (τ s, lower, upper) confidence bounds.
    pub bars: Vec<(f64, f64, f64)>,
    /// Drawing style.
    pub style: Style,
}

/// One panel.
#[derive(Clone, Debug)]
pub struct Panel {
    /// Title, e.g. "gyro x".
    pub title: String,
    /// Y axis label with unit.
    pub y_label: String,
    /// Curves.
    pub curves: Vec<Curve>,
}

/// Why a plot was not drawn.
#[derive(Clone, Debug, thiserror::Error)]
pub enum PlotError {
    /// No font file found.
    #[error("no font for plot text: install fonts-dejavu-core or set GROUND_FONT to a .ttf file")]
    NoFont,
    /// The font file could not be parsed.
    #[error("the plot font could not be read")]
    BadFont,
    /// The file name does not say PNG or SVG.
    #[error("{}: plot files must end in .png or .svg", .0.display())]
    Extension(std::path::PathBuf),
    /// The drawing backend failed (e.g. the file could not be written).
    #[error("drawing the plot: {0}")]
    Draw(String),
}

static FONT: OnceLock<Result<(), PlotError>> = OnceLock::new();

/// Registers the plot font once (see the module docs); every drawing calls it first.
pub(crate) fn ensure_font() -> Result<(), PlotError> {
    FONT.get_or_init(|| {
        let candidates = [
            std::env::var("GROUND_FONT").unwrap_or_default(),
            "/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf".into(),
            "/usr/share/fonts/TTF/DejaVuSans.ttf".into(),
            "/usr/share/fonts/dejavu/DejaVuSans.ttf".into(),
        ];
        let bytes = candidates
            .iter()
            .filter(|p| !p.is_empty())
            .find_map(|p| std::fs::read(p).ok())
            .ok_or(PlotError::NoFont)?;
        let bytes: &'static [u8] = Box::leak(bytes.into_boxed_slice());
        plotters::style::register_font("sans-serif", FontStyle::Normal, bytes)
            .map_err(|_| PlotError::BadFont)
    })
    .clone()
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(255, 127, 14),
    RGBColor(44, 160, 44),
    RGBColor(214, 39, 40),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(227, 119, 194),
    RGBColor(23, 190, 207),
];

/// Draws `panels` in a grid of `columns` into `path` (.png or .svg).
pub fn adev_panels(
    path: &Path,
    title: &str,
    panels: &[Panel],
    columns: usize,
) -> Result<(), PlotError> {
    ensure_font()?;
    let columns = columns.max(1);
    let rows = panels.len().div_ceil(columns).max(1);
    let size = (560 * columns as u32, 420 * rows as u32 + 40);
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "png" => draw(
            BitMapBackend::new(path, size).into_drawing_area(),
            title,
            panels,
            columns,
            rows,
        ),
        "svg" => draw(
            SVGBackend::new(path, size).into_drawing_area(),
            title,
            panels,
            columns,
            rows,
        ),
        _ => Err(PlotError::Extension(path.to_path_buf())),
    }
}

/// The Allan-deviation figure of `ground allan`: per sensor kind and axis a panel with the single sensors thin, the
/// independent (√N) expectation dashed and the cluster mean bold with its confidence bars; `source` names the recording
/// in the title.
pub fn adev_series(
    path: &Path,
    series: &[recording::Series],
    source: &Path,
) -> Result<(), PlotError> {
    let mut panels = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        for axis in 0..3 {
            let singles: Vec<&recording::Series> = series
                .iter()
                .filter(|s| s.kind == kind && s.axis == axis && s.group.is_some())
                .collect();
            let Some(cluster) = series
                .iter()
                .find(|s| s.kind == kind && s.axis == axis && s.group.is_none())
            else {
                continue;
            };
            let mut curves: Vec<Curve> = singles
                .iter()
                .enumerate()
                .map(|(i, s)| Curve {
                    label: (i == 0).then(|| "single sensors".into()),
                    points: s.points.iter().map(|p| (p.tau_s, p.dev)).collect(),
                    bars: vec![],
                    style: Style::Thin(i),
                })
                .collect();
            if !singles.is_empty() {
                let label = format!(
                    "independent expectation (√{} for equal sensors)",
                    singles.len()
                );
                curves.push(Curve {
                    label: Some(label),
                    points: recording::independent_mean_expectation(&singles),
                    bars: vec![],
                    style: Style::Dashed,
                });
            }
            curves.push(Curve {
                label: Some(format!("cluster mean ({} groups)", cluster.members)),
                points: cluster.points.iter().map(|p| (p.tau_s, p.dev)).collect(),
                bars: cluster
                    .points
                    .iter()
                    .filter_map(|p| Some((p.tau_s, p.dev_lo?, p.dev_hi?)))
                    .collect(),
                style: Style::Bold,
            });
            panels.push(Panel {
                title: format!("{} {}", kind.name(), ['x', 'y', 'z'][axis]),
                y_label: format!("deviation [{}]", kind.unit()),
                curves,
            });
        }
    }
    adev_panels(
        path,
        &format!("Allan deviation — {}", source.display()),
        &panels,
        3,
    )
}

fn draw<DB: DrawingBackend>(
    root: DrawingArea<DB, Shift>,
    title: &str,
    panels: &[Panel],
    columns: usize,
    rows: usize,
) -> Result<(), PlotError> {
    let e = |x: DrawingAreaErrorKind<DB::ErrorType>| PlotError::Draw(x.to_string());
    root.fill(&WHITE).map_err(e)?;
    let root = root.titled(title, ("sans-serif", 22)).map_err(e)?;
    for (area, panel) in root.split_evenly((rows, columns)).iter().zip(panels) {
        draw_panel(area, panel).map_err(e)?;
    }
    root.present().map_err(e)
}

fn draw_panel<DB: DrawingBackend>(
    area: &DrawingArea<DB, Shift>,
    panel: &Panel,
) -> Result<(), DrawingAreaErrorKind<DB::ErrorType>> {
    let all = panel.curves.iter().flat_map(|c| {
        c.points
            .iter()
            .map(|&(t, d)| (t, d, d))
            .chain(c.bars.iter().copied())
    });
    let (mut x0, mut x1, mut y0, mut y1) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
    for (t, lo, hi) in all.filter(|(t, lo, hi)| *t > 0.0 && *lo > 0.0 && hi.is_finite()) {
        x0 = x0.min(t);
        x1 = x1.max(t);
        y0 = y0.min(lo);
        y1 = y1.max(hi);
    }
    if x0 >= x1 || y0 >= y1 {
        return Ok(());
    }
    let mut chart = ChartBuilder::on(area)
        .caption(&panel.title, ("sans-serif", 18))
        .margin(8)
        .x_label_area_size(36)
        .y_label_area_size(64)
        .build_cartesian_2d(
            (x0 / 1.3..x1 * 1.3).log_scale(),
            (y0 / 1.5..y1 * 1.5).log_scale(),
        )?;
    chart
        .configure_mesh()
        .x_desc("tau [s]")
        .y_desc(panel.y_label.as_str())
        .x_label_formatter(&|v| format!("{v:.0e}"))
        .y_label_formatter(&|v| format!("{v:.0e}"))
        .label_style(("sans-serif", 12))
        .draw()?;
    for c in &panel.curves {
        let (color, width) = match c.style {
            Style::Thin(i) => (PALETTE[i % PALETTE.len()].mix(0.45), 1),
            Style::Bold => (BLACK.mix(1.0), 3),
            Style::Dashed => (RGBColor(90, 90, 90).mix(1.0), 2),
            Style::Model(i) => (PALETTE[i % PALETTE.len()].mix(1.0), 2),
        };
        let style = ShapeStyle {
            color,
            filled: false,
            stroke_width: width,
        };
        let pts = c
            .points
            .iter()
            .copied()
            .filter(|&(t, d)| t > 0.0 && d > 0.0);
        let drawn = if c.style == Style::Dashed {
            chart.draw_series(DashedLineSeries::new(pts, 8, 5, style))?
        } else {
            chart.draw_series(LineSeries::new(pts, style))?
        };
        if let Some(label) = &c.label {
            drawn
                .label(label.clone())
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 18, y)], style));
        }
        chart.draw_series(
            c.bars
                .iter()
                .filter(|(t, lo, hi)| *t > 0.0 && *lo > 0.0 && *hi > 0.0)
                .map(|&(t, lo, hi)| ErrorBar::new_vertical(t, lo, (lo * hi).sqrt(), hi, style, 6)),
        )?;
    }
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.85))
        .border_style(BLACK.mix(0.3))
        .label_font(("sans-serif", 12))
        .position(SeriesLabelPosition::UpperRight)
        .draw()?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn writes_png_and_svg_and_refuses_other_extensions() {
        let dir = std::env::temp_dir().join(format!("plot-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let curve = |style, k: f64| Curve {
            label: Some(format!("{style:?}")),
            points: (0..10)
                .map(|i| (2f64.powi(i), k / 2f64.powi(i).sqrt()))
                .collect(),
            bars: vec![(4.0, 0.4 * k, 0.6 * k)],
            style,
        };
        let panel = Panel {
            title: "gyro x".into(),
            y_label: "ADEV [deg/s]".into(),
            curves: vec![
                curve(Style::Thin(0), 1.0),
                curve(Style::Bold, 0.25),
                curve(Style::Dashed, 0.3),
            ],
        };
        for ext in ["png", "svg"] {
            let p = dir.join(format!("t.{ext}"));
            adev_panels(&p, "test", &[panel.clone(), panel.clone()], 2).unwrap();
            assert!(std::fs::metadata(&p).unwrap().len() > 1000);
        }
        assert!(adev_panels(&dir.join("t.jpg"), "t", &[panel], 1).is_err());
    }
}
