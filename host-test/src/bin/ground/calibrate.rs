//! `ground calibrate`: calibration tables from static poses or a rate table.

use anyhow::{Context, Result, bail};
use host_test::load;
use std::path::PathBuf;

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("mode").required(true).args(["static_rec", "rate_table"])))]
pub struct Args {
    /// Multi-position static calibration from a MIMU4444 stream (poses found automatically).
    #[arg(long = "static", value_name = "REC")]
    static_rec: Option<PathBuf>,
    /// Rate-table calibration of our board from 18 frame logs, in the order: for +x, −x, +y, −y, +z, −z up, rates
    /// +Ω, −Ω, 0 about the vertical.
    #[arg(long, num_args = 18, value_name = "REC")]
    rate_table: Vec<PathBuf>,
    /// Table rate Ω, °/s (rate-table mode).
    #[arg(long, default_value_t = 100.0)]
    omega: f64,
    /// Output: .json / .toml (readable) or .bin (the table as uploaded: postcard with version and CRC).
    #[arg(long)]
    out: PathBuf,
    /// Keep the matrices and rotations of this calibration, re-estimate only the biases (with --static).
    #[arg(long, requires = "from")]
    biases_only: bool,
    /// The calibration whose matrices are kept (--biases-only).
    #[arg(long)]
    from: Option<PathBuf>,
    /// Calibration id written into the table (reported in health telemetry).
    #[arg(long, default_value_t = 1)]
    cal_id: u32,
    /// Shortest static interval, s.
    #[arg(long, default_value_t = 15.0)]
    min_static_s: f64,
    /// Constant biases instead of biases with a linear drift during the record.
    #[arg(long)]
    no_drift: bool,
}

pub fn run(a: Args) -> Result<()> {
    use host_test::calibrate::{
        self as cal, BiasModel, BiasOptions, DetectOptions, StaticCalOptions,
    };
    let cerr = |e: cal::CalibError| anyhow::anyhow!("{e}");
    if let Some(rec) = &a.static_rec {
        let m = host_test::mimu::read(rec).map_err(|e| match e {
            // The I/O error names the file already.
            host_test::mimu::MimuError::Io { .. } => anyhow::anyhow!("{e}"),
            _ => anyhow::anyhow!("{}: {e}", rec.display()),
        })?;
        let detect = DetectOptions {
            min_duration_s: a.min_static_s,
            ..DetectOptions::default()
        };
        let poses = cal::detect_static(&m, &detect).map_err(cerr)?;
        println!(
            "{}: {} frames, {:.1} s; {} static intervals (window {} s, accel std < {} g, gyro std < {} °/s, ≥ {} s):",
            rec.display(),
            m.frames.len(),
            m.duration_s(),
            poses.len(),
            detect.window_s,
            detect.accel_std_max_g,
            detect.gyro_std_max_dps,
            detect.min_duration_s
        );
        for (i, p) in poses.iter().enumerate() {
            let f = p.accel_g.first().copied().unwrap_or_default();
            println!(
                "  {:2}: {:7.1} … {:7.1} s ({:5.1} s), IMU 1 specific force [{:+.3} {:+.3} {:+.3}] g, change {:.2} mg",
                i + 1,
                p.start_s,
                p.end_s,
                p.end_s - p.start_s,
                f[0],
                f[1],
                f[2],
                p.accel_change_mg
            );
        }
        if poses.is_empty() {
            bail!(
                "{}: no static interval found (window {} s, accel std < {} g, gyro std < {} °/s, at least {} s \
                 after {} s trimmed at each end; a shorter --min-static-s finds shorter ones)",
                rec.display(),
                detect.window_s,
                detect.accel_std_max_g,
                detect.gyro_std_max_dps,
                detect.min_duration_s,
                detect.trim_s
            );
        }
        let file = if a.biases_only {
            let from = a
                .from
                .as_deref()
                .context("--biases-only needs --from FILE")?;
            let old = cal::read_calibration::<{ load::MIMU_IMUS }>(from).map_err(cerr)?;
            let (new, upd) =
                cal::reestimate_biases(&old, &poses, &BiasOptions::default()).map_err(cerr)?;
            println!(
                "biases re-estimated (matrices and rotations of {} kept); static |a| − 1 g RMS per IMU, mg:",
                from.display()
            );
            for (i, (o, n)) in upd.old_rms_mg.iter().zip(&upd.new_rms_mg).enumerate() {
                println!(
                    "  IMU {}: {:.3} → {:.3} ({:?})",
                    i + 1,
                    o,
                    n,
                    upd.method.get(i)
                );
            }
            new
        } else {
            let opts = StaticCalOptions {
                bias_model: if a.no_drift {
                    BiasModel::Constant
                } else {
                    BiasModel::LinearDrift
                },
                ..StaticCalOptions::default()
            };
            let c = cal::calibrate_static(&poses, &opts).map_err(cerr)?;
            print!("{}", c.report.to_text());
            c.to_file(a.cal_id, &rec.display().to_string())
        };
        cal::write_calibration::<{ load::MIMU_IMUS }>(&file, &a.out).map_err(cerr)?;
        println!("calibration: {}", a.out.display());
        return Ok(());
    }
    // Rate table: mean raw codes of every group in each of the 18 records.
    let mut logs = Vec::with_capacity(a.rate_table.len());
    for path in &a.rate_table {
        let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
        let log = host_test::formats::framelog::FrameLog::decode(&bytes);
        if log.frames.is_empty() {
            bail!("{}: no valid frame", path.display());
        }
        logs.push(log);
    }
    let groups =
        cal::board_records(&logs, a.omega).context("the rate-table mode needs 18 frame logs")?;
    let (fits, file) =
        cal::fit_rate_table::<16>(&groups, &cal::RateTableOptions::default(), a.cal_id)
            .map_err(cerr)?;
    println!(
        "rate-table fit, Ω = {} °/s; per group the noise-limited accuracy the fit predicts (1σ):",
        a.omega
    );
    for (g, f) in fits.iter().enumerate() {
        let gse = f.gyro_bias_se_counts.iter().fold(0f64, |m, &x| m.max(x));
        let ase = f.accel_bias_se_counts.iter().fold(0f64, |m, &x| m.max(x));
        println!(
            "  group {g:2}: gyro bias ±{gse:.3} counts, accel bias ±{ase:.3} counts; residual RMS gyro {:.2} counts",
            f.gyro_residual_rms_counts
                .iter()
                .fold(0f64, |m, &x| m.max(x))
        );
    }
    cal::write_calibration::<16>(&file, &a.out).map_err(cerr)?;
    println!("calibration: {}", a.out.display());
    Ok(())
}
