//! `ground allan`: Allan deviations with confidence intervals, noise fits, plots and a Kalibr yaml.

use crate::common::{any_calib, apply_window, bar, print_loaded, spinner, write_file};
use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use host_test::allan::recording::{self, AdevRequest};
use host_test::allan::{DevKind, TauSpec};
use host_test::{load, plot};
use shared::wire::clock::FPGA_BASE_RATE_MILLIHZ;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
enum KindArg {
    Adev,
    Oadev,
    Mdev,
}

#[derive(clap::Args)]
pub struct Args {
    /// Recording: interchange CSV, NumPy .npy array (t, then gx gy gz ax ay az per group), FPGA frame log or MIMU4444
    /// stream.
    recording: PathBuf,
    /// Columns to analyse (comma-separated, e.g. g00x,g01x); the cluster means are always added.
    #[arg(long, value_delimiter = ',', conflicts_with = "all")]
    columns: Vec<String>,
    /// All columns (the default when --columns is not given).
    #[arg(long)]
    all: bool,
    /// Averaging times: octave, decade, all, or N (points per decade).
    #[arg(long, default_value = "octave")]
    taus: String,
    /// Deviation kind.
    #[arg(long, value_enum, default_value = "oadev")]
    kind: KindArg,
    /// Long-form CSV: column,tau_s,n,dev,ci_lo,ci_hi,alpha.
    #[arg(long)]
    out: PathBuf,
    /// Plot (.png or .svg): single sensors thin, cluster bold with CI bars, √N expectation dashed.
    #[arg(long)]
    plot: Option<PathBuf>,
    /// Kalibr imu.yaml from the cluster means' noise fits.
    #[arg(long)]
    kalibr: Option<PathBuf>,
    /// Noise-term fit of every column (white/ARW, bias instability, rate random walk, quantisation) and the curve's
    /// minimum with its 68 % interval, as CSV.
    #[arg(long)]
    fit: Option<PathBuf>,
    /// Time window START:END in seconds.
    #[arg(long)]
    window: Option<String>,
    /// Calibration table (.bin) for raw inputs.
    #[arg(long)]
    calib: Option<PathBuf>,
}

pub fn run(a: Args) -> Result<()> {
    let t0 = std::time::Instant::now();
    let cal = any_calib(&a.calib)?;
    let pb = spinner("reading");
    // Only the requested columns, and the cluster means computed while reading, where the input allows (a .npy
    // array; not with a window, which the means would have to follow).
    let (mut loaded, means) = if a.window.is_some() {
        let all = load::load_with(&a.recording, cal.as_ref(), FPGA_BASE_RATE_MILLIHZ)?;
        (all, None)
    } else {
        let only = if a.all { &[][..] } else { &a.columns[..] };
        load::load_selected(&a.recording, cal.as_ref(), FPGA_BASE_RATE_MILLIHZ, only)?
    };
    pb.finish_and_clear();
    print_loaded(&loaded);
    if let Some(w) = &a.window {
        apply_window(&mut loaded.recording, w)?;
    }
    let rec = &loaded.recording;
    if rec.len() < 2 {
        bail!(
            "{}: {} samples: too few for an Allan deviation",
            a.recording.display(),
            rec.len()
        );
    }
    let kind = match a.kind {
        KindArg::Adev => DevKind::Adev,
        KindArg::Oadev => DevKind::Oadev,
        KindArg::Mdev => DevKind::Mdev,
    };
    let req = AdevRequest {
        kind,
        taus: TauSpec::parse(&a.taus).context("--taus")?,
        columns: if a.all { vec![] } else { a.columns.clone() },
        cluster: true,
    };
    let n_series = if req.columns.is_empty() {
        rec.columns.len()
    } else {
        req.columns.len()
    } + 6;
    let t_read = t0.elapsed().as_secs_f64();
    let pb = bar(n_series as u64, "series");
    let series = recording::analyze_with_means(rec, means, &req, &|| pb.inc(1))?;
    pb.finish_and_clear();
    let t_analysis = t0.elapsed().as_secs_f64() - t_read;
    if series.iter().all(|s| s.points.is_empty()) {
        bail!(
            "{}: {} samples are too few for any averaging time",
            a.recording.display(),
            rec.len()
        );
    }
    if let Some(s) = series
        .iter()
        .find(|s| s.points.iter().any(|p| !p.dev.is_finite()))
    {
        bail!(
            "{}: the deviation of {} is not finite (values too large to square?)",
            a.recording.display(),
            s.label
        );
    }
    let rate = 1.0 / rec.sample_interval_s().unwrap_or(f64::NAN);
    // Checked before anything is written: no Kalibr file with invented noise densities.
    if a.kalibr.is_some() {
        let warnings = recording::kalibr_check(&series, rate)
            .map_err(|e| anyhow::anyhow!("--kalibr: {}: {e}", a.recording.display()))?;
        for w in warnings {
            eprintln!("warning: --kalibr: {w}");
        }
    }
    write_file(&a.out, |w| recording::write_long_csv(&series, w))?;
    println!(
        "{}: {} series, {} samples at {:.6} s (reading {:.2} s, analysis {:.2} s)",
        a.out.display(),
        series.len(),
        rec.len(),
        rec.sample_interval_s().unwrap_or(f64::NAN),
        t_read,
        t_analysis
    );
    print_summary(&series);
    if let Some(p) = &a.plot {
        plot::adev_series(p, &series, &a.recording)?;
        println!("plot: {}", p.display());
    }
    if let Some(f) = &a.fit {
        write_file(f, |w| recording::write_fit_csv(&series, w))?;
        println!("noise fits: {}", f.display());
    }
    if let Some(k) = &a.kalibr {
        std::fs::write(k, recording::kalibr_yaml(&series, rate, "/imu0"))
            .with_context(|| format!("writing {}", k.display()))?;
        println!("kalibr: {}", k.display());
    }
    Ok(())
}

fn unit_scale(kind: host_test::recording::SensorKind) -> (&'static str, f64) {
    match kind {
        host_test::recording::SensorKind::Gyro => ("°/h", 3600.0),
        host_test::recording::SensorKind::Accel => ("µg", 1e6),
    }
}

fn print_summary(series: &[recording::Series]) {
    println!("cluster means (noise-term fit; minimum of the curve with its 68 % interval):");
    for s in series.iter().filter(|s| s.group.is_none()) {
        let (u, k) = unit_scale(s.kind);
        let (du, dk) = match s.kind {
            host_test::recording::SensorKind::Gyro => ("°/√h", 60.0),
            host_test::recording::SensorKind::Accel => ("µg/√Hz", 1e6),
        };
        let m = s.minimum();
        println!(
            "  {} ({} groups): white {:.4} {du}, bias instability {:.4} {u}, min ADEV {} at τ = {} s{}",
            s.label,
            s.members,
            s.fit.white * dk,
            s.fit.bias_instability * k,
            m.map_or("-".into(), |p| format!("{:.4} {u}", p.dev * k)),
            m.map_or("-".into(), |p| format!("{:.4}", p.tau_s)),
            m.and_then(|p| p.dev_lo.zip(p.dev_hi))
                .map_or(String::new(), |(lo, hi)| format!(
                    " [{:.4}, {:.4}]",
                    lo * k,
                    hi * k
                )),
        );
    }
}
