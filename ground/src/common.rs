//! Helpers the subcommands share: file writing, progress bars, calibrations, the time window.

use anyhow::{Context, Result, bail};
use host_test::load;
use indicatif::{ProgressBar, ProgressStyle};
use std::path::{Path, PathBuf};

/// Highest FPGA base rate accepted, Hz.
pub const MAX_BASE_RATE_HZ: f64 = 1e9;

/// A base rate given in Hz as millihertz, the unit of the core's configuration; an error outside (0, 1e9] Hz.
pub fn millihz(hz: f64) -> Result<u64> {
    if !(hz.is_finite() && hz > 0.0 && hz <= MAX_BASE_RATE_HZ) {
        bail!(
            "the base rate must be a positive number of Hz up to {MAX_BASE_RATE_HZ:e}, found {hz}"
        );
    }
    Ok((hz * 1000.0).round() as u64)
}

/// Writes `path` through a buffer with `write`, then flushes it: an error of either (a full disk) names the file.
pub fn write_file<T>(
    path: &Path,
    write: impl FnOnce(&mut std::io::BufWriter<std::fs::File>) -> std::io::Result<T>,
) -> Result<T> {
    let mut w = std::io::BufWriter::new(
        std::fs::File::create(path).with_context(|| format!("creating {}", path.display()))?,
    );
    let v = write(&mut w)
        .and_then(|v| std::io::Write::flush(&mut w).map(|()| v))
        .with_context(|| format!("writing {}", path.display()))?;
    Ok(v)
}

/// Prints the loader's notes and warnings (to stderr).
pub fn print_loaded(loaded: &load::Loaded) {
    for n in &loaded.notes {
        eprintln!("note: {n}");
    }
    for w in &loaded.warnings {
        eprintln!("warning: {w}");
    }
}

pub fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

pub fn bar(len: u64, unit: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    let style =
        format!("{{spinner}} [{{elapsed_precise}}] {{bar:40}} {{pos}}/{{len}} {unit} ({{eta}})");
    pb.set_style(
        ProgressStyle::with_template(&style).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb
}

/// The board calibration for replay (16 groups).
pub fn calib(path: &Option<PathBuf>) -> Result<Option<shared::calib::CalibrationTable<16>>> {
    match any_calib(path)? {
        None => Ok(None),
        Some(load::Calibration::Board(t)) => Ok(Some(*t)),
        Some(load::Calibration::Mimu(_)) => bail!(
            "{}: this is an 8-IMU (MIMU4444) calibration; frame logs need a 16-group one",
            path.as_deref().unwrap_or(Path::new("")).display()
        ),
    }
}

/// A calibration of either array, for commands that read any recording.
pub fn any_calib(path: &Option<PathBuf>) -> Result<Option<load::Calibration>> {
    Ok(path
        .as_deref()
        .map(load::read_any_calibration)
        .transpose()?)
}

pub fn parse_window(s: &str) -> Result<(f64, f64)> {
    let (a, b) = s
        .split_once(':')
        .context("--window: expected START:END in seconds")?;
    let (a, b): (f64, f64) = (
        a.trim().parse().context("--window start")?,
        b.trim().parse().context("--window end")?,
    );
    if a.is_nan() || b.is_nan() {
        bail!("--window: START and END must be numbers of seconds, found '{s}'");
    }
    if b <= a {
        bail!("--window: END must be after START");
    }
    Ok((a, b))
}

/// Applies `--window` to a loaded recording; fewer than two samples left is an error.
pub fn apply_window(rec: &mut host_test::recording::Recording, window: &str) -> Result<()> {
    let (s, e) = parse_window(window)?;
    let span = (
        rec.t_s.first().copied().unwrap_or(f64::NAN),
        rec.t_s.last().copied().unwrap_or(f64::NAN),
    );
    *rec = rec.window(s, e);
    if rec.len() < 2 {
        bail!(
            "--window {window} keeps {} samples (the recording spans {} … {} s)",
            rec.len(),
            span.0,
            span.1
        );
    }
    Ok(())
}
