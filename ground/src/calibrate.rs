//! `ground calibrate`: calibration tables from static poses or a rate table.

use anyhow::{Context, Result, bail};
use host_test::load;
use std::path::PathBuf;

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("mode").required(true).args(["static_rec", "rate_table", "thermal", "weights", "from_model"])))]
pub struct Args {
    /// Multi-position static calibration from a MIMU4444 stream (poses found automatically).
    #[arg(long = "static", value_name = "REC")]
    static_rec: Option<PathBuf>,
    /// Rate-table calibration of our board from 18 frame logs, in the order: for +x, −x, +y, −y, +z, −z up, rates
    /// +Ω, −Ω, 0 about the vertical.
    #[arg(long, num_args = 18, value_name = "REC")]
    rate_table: Vec<PathBuf>,
    /// Thermal calibration of our board: a frame log of the still board over a temperature ramp or cycle (≥ 10 °C);
    /// per raw channel the code is fitted against T − T_ref and (T − T_ref)², and the terms are added to --base.
    #[arg(long, value_name = "REC")]
    thermal: Option<PathBuf>,
    /// Fixed fusion weights for a τ region (--tau-min, --tau-max) from a record of the board (frame log, CSV or
    /// .npy): generalised least squares on the sensors' Allan covariance per axis, added to --base. The core uses
    /// them instead of its running inverse-variance weights (`FusionMode::Fixed`).
    #[arg(long, value_name = "REC")]
    weights: Option<PathBuf>,
    /// The thermal coefficients and fixed weights a cluster model implies (`ground diagnose --model`,
    /// docs/twin.md), added to --base: the model's output drifts mapped to raw channels through the base's
    /// matrices, and weights by generalised least squares on the model's Allan covariance over --tau-min … --tau-max.
    /// --base must be the calibration the diagnosed record was calibrated with.
    #[arg(long, value_name = "MODEL")]
    from_model: Option<PathBuf>,
    /// With --from-model: the thermal terms only, no weights.
    #[arg(long, requires = "from_model")]
    no_weights: bool,
    /// With --weights or --from-model: shortest τ of the region, s.
    #[arg(long, default_value_t = 100.0)]
    tau_min: f64,
    /// With --weights or --from-model: longest τ of the region, s.
    #[arg(long, default_value_t = 3000.0)]
    tau_max: f64,
    /// With --weights or --from-model: allow negative weights (by default every weight is ≥ 0).
    #[arg(long)]
    allow_negative: bool,
    /// With --weights: fit on the whole record (the default fits on the first half and reports the gain measured
    /// on the second, which it was not fitted on).
    #[arg(long)]
    whole_record: bool,
    /// With --thermal, --weights or --from-model: the calibration kept and added to (the factory table otherwise); with
    /// --thermal its biases are taken to hold at T_ref.
    #[arg(long)]
    base: Option<PathBuf>,
    /// With --thermal: the reference temperature T_ref, °C (default: the base's when it records one, else the
    /// record's mean temperature).
    #[arg(long, requires = "thermal", allow_hyphen_values = true)]
    t_ref_c: Option<f64>,
    /// With --thermal: one line per group and raw channel (default: a summary per channel type).
    #[arg(long)]
    verbose: bool,
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
    if let Some(rec) = &a.thermal {
        return run_thermal(&a, rec);
    }
    if let Some(rec) = &a.weights {
        return run_weights(&a, rec);
    }
    if let Some(model) = &a.from_model {
        return run_from_model(&a, model);
    }
    if let Some(rec) = &a.static_rec {
        return run_static(&a, rec);
    }
    run_rate_table(&a)
}

/// `--static`: the poses found in a MIMU4444 stream, then the calibration (or only new biases, `--biases-only`).
fn run_static(a: &Args, rec: &std::path::Path) -> Result<()> {
    use host_test::calibrate::{
        self as cal, BiasModel, BiasOptions, DetectOptions, StaticCalOptions,
    };
    let cerr = |e: cal::CalibError| anyhow::anyhow!("{e}");
    let m = host_test::formats::mimu::read(rec).map_err(|e| match e {
        // The I/O error names the file already.
        host_test::formats::mimu::MimuError::Io { .. } => anyhow::anyhow!("{e}"),
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
    Ok(())
}

/// `--rate-table`: the 18 frame logs' mean codes, fitted per group.
fn run_rate_table(a: &Args) -> Result<()> {
    use host_test::calibrate as cal;
    let cerr = |e: cal::CalibError| anyhow::anyhow!("{e}");
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

/// Names of the raw channels in frame order.
const RAW_NAMES: [&str; 7] = [
    "gyro A x", "gyro A z", "gyro B y", "gyro B z", "accel x", "accel y", "accel z",
];

/// `--thermal`: the fit, a summary (or every channel with --verbose), the base with the terms added.
fn run_thermal(a: &Args, rec: &std::path::Path) -> Result<()> {
    use host_test::calibrate::{self as cal, ThermalOptions};
    let cerr = |e: cal::CalibError| anyhow::anyhow!("{e}");
    let bytes = std::fs::read(rec).with_context(|| format!("reading {}", rec.display()))?;
    let log = host_test::formats::framelog::FrameLog::decode(&bytes);
    if log.frames.is_empty() {
        bail!("{}: no valid frame", rec.display());
    }
    let mut file = base_file(a)?;
    let base_name = a
        .base
        .as_ref()
        .map_or("the factory table".to_string(), |p| p.display().to_string());
    // The base's biases hold at its reference temperature when it records one (thermal terms, or a non-zero
    // t_ref_c); the factory table records none.
    let base_t_ref = (a.base.is_some() && (file.thermal.is_some() || file.t_ref_c != 0.0))
        .then_some(file.t_ref_c);
    let opts = ThermalOptions {
        t_ref_c: a.t_ref_c.or(base_t_ref),
        ..ThermalOptions::default()
    };
    let fit = cal::fit_thermal(&log.frames, &opts, &rec.display().to_string())
        .map_err(|e| anyhow::anyhow!("{}: {e}", rec.display()))?;
    let m = &fit.meta;
    println!(
        "{}: {} frames with a temperature ({} without, left out), board {:.2} … {:.2} °C; T_ref {:.2} °C ({})",
        rec.display(),
        m.samples,
        fit.skipped,
        m.temp_range_c[0],
        m.temp_range_c[1],
        fit.t_ref_c,
        if a.t_ref_c.is_some() {
            "given"
        } else if base_t_ref.is_some() {
            "the base's"
        } else {
            "the record's mean"
        }
    );
    print_thermal_terms(&fit, a.verbose);
    // What the fit cannot use: the code at T_ref of a still board is the bias plus the true input.
    let mut d: Vec<f64> = (0..16)
        .flat_map(|g| {
            let (f, b) = (&m.groups[g], &file.groups[g]);
            (0..4).map(move |c| f.intercept_counts[c] - b.gyro_bias_counts[c])
        })
        .collect();
    d.sort_by(f64::total_cmp);
    println!(
        "biases of {base_name} kept (taken as holding at T_ref); the still board's gyro code at T_ref minus them \
         (bias change + Earth rate): median {:+.2} counts, range {:+.2} … {:+.2}",
        0.5 * (d[d.len() / 2 - 1] + d[d.len() / 2]),
        d[0],
        d[d.len() - 1]
    );
    file.cal_id = a.cal_id;
    file.t_ref_c = fit.t_ref_c;
    file.thermal = Some(fit.terms);
    file.thermal_fit = Some(fit.meta);
    cal::write_calibration::<16>(&file, &a.out).map_err(cerr)?;
    println!("calibration: {}", a.out.display());
    Ok(())
}

/// `--weights`: per axis, the GLS weights of the record's sensors for the τ region, written into the base.
fn run_weights(a: &Args, rec: &std::path::Path) -> Result<()> {
    use host_test::calibrate::weights::{SHRINKAGE, WeightOptions, table_weights};
    use host_test::calibrate::{self as cal};
    let cerr = |e: cal::CalibError| anyhow::anyhow!("{e}");
    let mut file = base_file(a)?;
    let table = file.to_table::<16>().map_err(cerr)?;
    let loaded = load::load_with(
        rec,
        Some(&load::Calibration::Board(Box::new(table))),
        shared::wire::clock::FPGA_BASE_RATE_MILLIHZ,
    )?;
    let r = &loaded.recording;
    let n = r.t_s.len();
    let rate_hz = if n >= 2 {
        (n - 1) as f64 / (r.t_s[n - 1] - r.t_s[0])
    } else {
        f64::NAN
    };
    let opts = WeightOptions {
        tau_min_s: a.tau_min,
        tau_max_s: a.tau_max,
        allow_negative: a.allow_negative,
    };
    println!(
        "{}: {n} samples at {rate_hz:.3} Hz; weights for τ {} … {} s (generalised least squares on the sensors' \
         Allan covariance, octave τ's, shrunk {:.0} % to its diagonal{})",
        rec.display(),
        a.tau_min,
        a.tau_max,
        100.0 * SHRINKAGE,
        if a.allow_negative {
            "; negative weights allowed"
        } else {
            "; weights ≥ 0"
        }
    );
    let (weights, axes) = table_weights(r, 16, &opts, !a.whole_record)
        .map_err(|e| anyhow::anyhow!("{}: {e}", rec.display()))?;
    for (name, (groups, w)) in ["gx", "gy", "gz", "ax", "ay", "az"].iter().zip(&axes) {
        print_axis_weights(name, groups, w, "in sample");
    }
    file.weights = Some(weights);
    file.cal_id = a.cal_id;
    cal::write_calibration::<16>(&file, &a.out).map_err(cerr)?;
    println!(
        "calibration: {} (fusion mode Fixed once loaded)",
        a.out.display()
    );
    Ok(())
}

/// The base of --thermal, --weights and --from-model: the file given, or the factory table.
fn base_file(a: &Args) -> Result<host_test::calibrate::CalibrationFile> {
    use host_test::calibrate as cal;
    Ok(match &a.base {
        Some(p) => cal::read_calibration::<16>(p).map_err(|e| anyhow::anyhow!("{e}"))?,
        None => cal::CalibrationFile::from_table(&shared::calib::CalibrationTable::<16>::factory()),
    })
}

/// One line per axis: the weights' range, the groups left out and the equal mean's ADEV over the weighted one at
/// each τ: on the held-out half when there is one, else as `fitted` says (in sample, or the model's prediction).
fn print_axis_weights(
    name: &str,
    groups: &[usize],
    w: &host_test::calibrate::weights::AxisWeights,
    fitted: &str,
) {
    let (taus, equal, weighted, what) = match &w.held_out {
        Some(h) => (&h.taus_s, &h.adev_equal, &h.adev_weighted, "held-out half"),
        None => (&w.taus_s, &w.adev_equal, &w.adev_weighted, fitted),
    };
    let gain: Vec<String> = taus
        .iter()
        .zip(equal.iter().zip(weighted))
        .map(|(tau, (e, g))| format!("{tau:.0} s {:.2}×", e / g))
        .collect();
    let zero: Vec<String> = groups
        .iter()
        .zip(&w.weights)
        .filter(|(_, x)| **x == 0.0)
        .map(|(g, _)| g.to_string())
        .collect();
    println!(
        "  {name}  weights {:.3} … {:.3} (sum 1){}; ADEV equal mean / weighted ({what}): {}",
        w.weights.iter().copied().fold(f64::INFINITY, f64::min),
        w.weights.iter().copied().fold(f64::NEG_INFINITY, f64::max),
        if zero.is_empty() {
            String::new()
        } else {
            format!(", groups left out: {}", zero.join(" "))
        },
        gain.join(", ")
    );
}

/// `--from-model`: the model's thermal coefficients and weights, added to the base.
fn run_from_model(a: &Args, path: &std::path::Path) -> Result<()> {
    use host_test::calibrate::weights::WeightOptions;
    use host_test::calibrate::{self as cal};
    let model = host_test::twin::ClusterModel::load(path)?;
    let base = base_file(a)?;
    let opts = WeightOptions {
        tau_min_s: a.tau_min,
        tau_max_s: a.tau_max,
        allow_negative: a.allow_negative,
    };
    let r = cal::from_model(&model, &base, (!a.no_weights).then_some(&opts))
        .map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    println!(
        "{}: fitted to {} ({} groups, {:.0} s at {:.3} Hz)",
        path.display(),
        model.record.source,
        model.record.groups.len(),
        model.record.duration_s,
        model.record.rate_hz
    );
    match r.model_t_ref_c {
        None => println!("  thermal: the model has no temperature; no thermal terms added"),
        Some(_) if r.thermal_sensors == 0 => {
            println!("  thermal: the model has no thermal coefficient; no thermal terms added")
        }
        Some(t_m) => {
            let th = r.file.thermal.as_deref().unwrap_or_default();
            let range = |f: &dyn Fn(&cal::GroupThermalF64) -> Vec<f64>| {
                th.iter()
                    .flat_map(f)
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                        (l.min(x), h.max(x))
                    })
            };
            let (g0, g1) = range(&|t| t.gyro_lin_counts_per_c.to_vec());
            let (a0, a1) = range(&|t| t.accel_lin_counts_per_c.to_vec());
            println!(
                "  thermal: {} sensor axes with a coefficient about {t_m:.2} °C, mapped to raw channels through the \
                 base's matrices; table reference {:.2} °C; linear terms now gyro {g0:+.4} … {g1:+.4}, accel \
                 {a0:+.4} … {a1:+.4} counts/°C",
                r.thermal_sensors, r.file.t_ref_c
            );
        }
    }
    if !r.axes.is_empty() {
        println!(
            "  weights for τ {} … {} s (generalised least squares on the model's Allan covariance, octave τ's up to \
             {:.0} % of the record){}",
            a.tau_min,
            a.tau_max,
            100.0 * cal::MAX_TAU_FRACTION,
            if a.allow_negative {
                "; negative weights allowed"
            } else {
                "; weights ≥ 0"
            }
        );
        for (name, (groups, w)) in &r.axes {
            print_axis_weights(name, groups, w, "the model's prediction");
        }
    }
    let mut file = r.file;
    file.cal_id = a.cal_id;
    cal::write_calibration::<16>(&file, &a.out).map_err(|e| anyhow::anyhow!("{e}"))?;
    println!(
        "calibration: {}{}",
        a.out.display(),
        if file.weights.is_some() {
            " (fusion mode Fixed once loaded)"
        } else {
            ""
        }
    );
    Ok(())
}

/// The fitted terms: every group and raw channel (`verbose`), or per channel type their range over the groups.
fn print_thermal_terms(fit: &host_test::calibrate::ThermalFit, verbose: bool) {
    let m = &fit.meta;
    let lin = |g: usize, c: usize| {
        let t = &fit.terms[g];
        if c < 4 {
            (t.gyro_lin_counts_per_c[c], t.gyro_quad_counts_per_c2[c])
        } else {
            (
                t.accel_lin_counts_per_c[c - 4],
                t.accel_quad_counts_per_c2[c - 4],
            )
        }
    };
    println!(
        "code = a + lin·(T − T_ref) + quad·(T − T_ref)² per raw channel; standard errors from the residuals' \
         Haar (Allan) variances, extrapolated to the record's length by their noise type"
    );
    if verbose {
        println!(
            "  group channel     lin counts/°C   ±SE     quad counts/°C²   ±SE        residual RMS counts"
        );
        for g in 0..16 {
            for (c, name) in RAW_NAMES.iter().enumerate() {
                let (l, q) = lin(g, c);
                let f = &m.groups[g];
                println!(
                    "  {g:5} {name:10} {l:+12.4} {:8.4} {q:+14.6} {:10.6} {:14.2}",
                    f.lin_se_counts_per_c[c], f.quad_se_counts_per_c2[c], f.residual_rms_counts[c]
                );
            }
        }
    } else {
        println!(
            "  channel     lin counts/°C: min … max over 16 groups  (largest SE)   quad counts/°C²: min … max  \
             (largest SE)   residual RMS counts: max"
        );
        for (c, name) in RAW_NAMES.iter().enumerate() {
            let range = |f: &dyn Fn(usize) -> f64| {
                (0..16)
                    .map(f)
                    .fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
                        (l.min(x), h.max(x))
                    })
            };
            let max = |f: &dyn Fn(usize) -> f64| (0..16).map(f).fold(0f64, f64::max);
            let (l0, l1) = range(&|g| lin(g, c).0);
            let (q0, q1) = range(&|g| lin(g, c).1);
            println!(
                "  {name:10} {l0:+9.4} … {l1:+9.4}  ({:.4})                {q0:+9.6} … {q1:+9.6}  ({:.6})      {:.2}",
                max(&|g| m.groups[g].lin_se_counts_per_c[c]),
                max(&|g| m.groups[g].quad_se_counts_per_c2[c]),
                max(&|g| m.groups[g].residual_rms_counts[c])
            );
        }
    }
}
