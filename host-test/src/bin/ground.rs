//! `ground`: the ground and lab tool of the IMU cluster. `ground <command> --help` documents each command.

use anyhow::{Context, Result, bail};
use clap::{Parser, Subcommand, ValueEnum};
use host_test::adev::{self, AdevRequest};
use host_test::allan::{DevKind, TauSpec};
use host_test::formats::telemetry::TelemetryLog;
use host_test::load;
use host_test::plot;
use host_test::replay::{ReplayOptions, replay};
use indicatif::{ProgressBar, ProgressStyle};
use shared::bus::BusConfig;
use shared::bus::csp::CspVersion;
use shared::fuse::FusionMode;
use shared::pipeline::PipelineConfig;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

#[derive(Parser)]
#[command(
    name = "ground",
    version,
    about = "Ground and lab tool of the IMU cluster: simulate, import, replay, decode, Allan deviation"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Subcommand)]
enum Cmd {
    /// The main job: the seed experiment (16 groups, 18.9 Hz, 8 h) simulated, run through the flight core, and the
    /// paper's Tables 1 and 2 recomputed with ADEV plots and a report.
    Demo(DemoArgs),
    /// Simulate a cluster recording from a noise model with optional effects (frame log .bin or CSV .csv).
    Simulate(SimulateArgs),
    /// Convert a frame log or MIMU4444 stream (or any recording) to the interchange CSV (°/s, g), through a
    /// calibration into the cluster frame.
    Import(ImportArgs),
    /// Estimate calibration tables: multi-position static (MIMU4444), rate table (our board), or biases only.
    Calibrate(CalibrateArgs),
    /// Run a frame log through the flight core (shared::Pipeline) and write the telemetry stream it would send.
    Replay(ReplayArgs),
    /// Decode a telemetry stream (CSP/KISS/postcard) to CSV or JSON lines.
    Decode(DecodeArgs),
    /// Allan deviations with confidence intervals, noise identification, noise-term fit, plots, Kalibr yaml.
    Allan(AllanArgs),
    /// Sim-to-real diagnosis of a static cluster recording: where the gap to the √N model lies, which effect causes
    /// it, how far it shrinks (checked on the held-out second half).
    Diagnose(DiagnoseArgs),
}

#[derive(Clone, Copy, ValueEnum)]
enum WeightsArg {
    /// Equal weights (the seed's mean).
    Equal,
    /// Inverse white-noise variance.
    InverseVariance,
}

#[derive(clap::Args)]
struct DiagnoseArgs {
    /// Static recording: interchange CSV or FPGA frame log.
    recording: PathBuf,
    /// Time window START:END in seconds.
    #[arg(long)]
    window: Option<String>,
    /// Output folder for report.txt and diagnose.png.
    #[arg(long, default_value = "diagnose-out")]
    out: PathBuf,
    /// JSON result file.
    #[arg(long)]
    json: Option<PathBuf>,
    /// Weights of the cluster mean.
    #[arg(long, value_enum, default_value = "equal")]
    weights: WeightsArg,
    /// Override: leave out octave tau whose half holds fewer averaging blocks (default: every tau down to 4 blocks,
    /// each with its own EDF).
    #[arg(long)]
    min_blocks: Option<usize>,
    /// MIMU4444 stream: diagnose the longest static interval (found as `calibrate --static` finds poses).
    #[arg(long, conflicts_with = "window")]
    longest_static: bool,
    /// Calibration table (.bin) for raw inputs.
    #[arg(long)]
    calib: Option<PathBuf>,
}

#[derive(clap::Args)]
struct DemoArgs {
    /// Output folder.
    #[arg(long, default_value = "demo-out")]
    out: PathBuf,
    /// Simulation seed.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Duration, hours (the seed experiment: 8).
    #[arg(long, default_value_t = 8.0)]
    hours: f64,
}

#[derive(Clone, Copy, ValueEnum)]
enum PresetArg {
    /// The seed paper's single-sensor noise (Tables 1 and 2), independent sensors.
    Seed,
    /// The seed paper's noise with the common modes that explain its cluster ratios (`seedfit`).
    SeedFitted,
}

#[derive(clap::Args)]
struct SimulateArgs {
    /// Output: .bin (FPGA frame log: ADC codes through the true calibration) or .csv (interchange CSV, °/s and g).
    #[arg(long)]
    out: PathBuf,
    /// Noise model.
    #[arg(long, value_enum, default_value = "seed")]
    preset: PresetArg,
    /// Duration in hours (default: the seed's 8 h = 545,410 samples at 18.9 Hz).
    #[arg(long)]
    hours: Option<f64>,
    /// Number of samples (instead of --hours).
    #[arg(long, conflicts_with = "hours")]
    samples: Option<u64>,
    /// Duration in seconds (instead of --hours or --samples).
    #[arg(long, conflicts_with_all = ["hours", "samples"])]
    seconds: Option<f64>,
    /// A motion of the board: `coning:half_angle_deg=A,freq_hz=F` or
    /// `sculling:angle_amp_deg=A,accel_amp_g=B,freq_hz=F` (docs in host_test::sim::motion).
    #[arg(long, value_parser = |s: &str| host_test::sim::motion::Motion::parse(s))]
    motion: Option<host_test::sim::motion::Motion>,
    /// No sensor noise and the exact nominal calibration (the preset and effects are ignored).
    #[arg(long)]
    noiseless: bool,
    /// Output rate, Hz (frames carry the decimation that gives it from the FPGA base rate).
    #[arg(long, default_value_t = 18.9)]
    rate: f64,
    /// Random seed (same seed, same output).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// FPGA base rate before decimation, Hz.
    #[arg(long, default_value_t = 9676.8)]
    base_rate_hz: f64,
    /// True angular rate of the board, °/s (x,y,z; e.g. a rate table).
    #[arg(long, value_delimiter = ',', num_args = 1..=3, allow_hyphen_values = true)]
    rate_dps: Option<Vec<f64>>,
    /// True specific force, g (x,y,z; default the preset's).
    #[arg(long, value_delimiter = ',', num_args = 1..=3, allow_hyphen_values = true)]
    accel_g: Option<Vec<f64>>,
    #[command(flatten)]
    effects: host_test::simcli::EffectArgs,
}

#[derive(clap::Args)]
#[command(group(clap::ArgGroup::new("mode").required(true).args(["static_rec", "rate_table"])))]
struct CalibrateArgs {
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

#[derive(clap::Args)]
struct ImportArgs {
    /// Input: FPGA frame log, MIMU4444 stream, or interchange CSV.
    input: PathBuf,
    /// Output CSV.
    #[arg(long)]
    out: PathBuf,
    /// Calibration (.bin, .json or .toml; 16 groups for frame logs, 8 IMUs for MIMU4444 streams). Without it: the
    /// board's factory default, or the MIMU4444's nominal scales in each IMU's own frame.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// FPGA base rate before decimation, Hz (frame logs).
    #[arg(long, default_value_t = 9676.8)]
    base_rate_hz: f64,
}

#[derive(Clone, Copy, ValueEnum)]
enum FusionArg {
    /// The seed paper's equal-weight mean.
    Equal,
    /// Inverse-variance weights from running noise estimates.
    Weighted,
}

#[derive(clap::Args)]
struct ReplayArgs {
    /// FPGA frame log.
    frames: PathBuf,
    /// Telemetry stream to write (bus bytes: CSP packets in KISS frames).
    #[arg(long)]
    out: PathBuf,
    /// Calibration table (.bin); factory default otherwise.
    #[arg(long)]
    calib: Option<PathBuf>,
    /// Frames averaged per output sample.
    #[arg(long, default_value_t = 32)]
    frames_per_output: u16,
    /// Fusion rule.
    #[arg(long, value_enum, default_value = "weighted")]
    fusion: FusionArg,
    /// No fault exclusion (saturated / stuck / outlier sensors stay in).
    #[arg(long)]
    no_robust: bool,
    /// Compare the fused output with an f64 model of the same calibration and fusion; print the max error in LSB.
    #[arg(long)]
    check: bool,
    /// FPGA base rate before decimation, Hz.
    #[arg(long, default_value_t = 9676.8)]
    base_rate_hz: f64,
    /// CSP header version on the bus (1: libcsp 1.x, Yamcs; 2: libcsp 2.x's default).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
}

#[derive(clap::Args)]
struct DecodeArgs {
    /// Telemetry stream (bus bytes).
    input: PathBuf,
    /// Output: .csv (fused samples) or .jsonl (every message).
    #[arg(long)]
    out: PathBuf,
    /// Also the Allan deviations of the core's Allan reports (roots taken here), as CSV.
    #[arg(long)]
    allan: Option<PathBuf>,
    /// Also the navigation increments (ΔΘ, ΔV per output interval), as CSV.
    #[arg(long)]
    nav: Option<PathBuf>,
    /// CSP header version on the bus (1 or 2).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
}

#[derive(Clone, Copy, ValueEnum)]
enum KindArg {
    Adev,
    Oadev,
    Mdev,
}

#[derive(clap::Args)]
struct AllanArgs {
    /// Recording: interchange CSV or FPGA frame log.
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

fn main() -> ExitCode {
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Demo(a) => demo(a),
        Cmd::Simulate(a) => simulate(a),
        Cmd::Import(a) => import(a),
        Cmd::Calibrate(a) => calibrate_cmd(a),
        Cmd::Replay(a) => replay_cmd(a),
        Cmd::Decode(a) => decode(a),
        Cmd::Allan(a) => allan(a),
        Cmd::Diagnose(a) => diagnose(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}

/// Highest FPGA base rate accepted, Hz.
const MAX_BASE_RATE_HZ: f64 = 1e9;

fn mhz(hz: f64) -> Result<u64> {
    if !(hz.is_finite() && hz > 0.0 && hz <= MAX_BASE_RATE_HZ) {
        bail!(
            "the base rate must be a positive number of Hz up to {MAX_BASE_RATE_HZ:e}, found {hz}"
        );
    }
    Ok((hz * 1000.0).round() as u64)
}

/// Writes `path` through a buffer with `write`, then flushes it: an error of either (a full disk) names the file.
fn write_file<T>(
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
fn print_loaded(loaded: &load::Loaded) {
    for n in &loaded.notes {
        eprintln!("note: {n}");
    }
    for w in &loaded.warnings {
        eprintln!("warning: {w}");
    }
}

fn spinner(msg: &str) -> ProgressBar {
    let pb = ProgressBar::new_spinner();
    pb.set_message(msg.to_string());
    pb.enable_steady_tick(std::time::Duration::from_millis(120));
    pb
}

fn bar(len: u64, unit: &str) -> ProgressBar {
    let pb = ProgressBar::new(len);
    let style =
        format!("{{spinner}} [{{elapsed_precise}}] {{bar:40}} {{pos}}/{{len}} {unit} ({{eta}})");
    pb.set_style(
        ProgressStyle::with_template(&style).unwrap_or_else(|_| ProgressStyle::default_bar()),
    );
    pb
}

/// The board calibration for replay (16 groups).
fn calib(path: &Option<PathBuf>) -> Result<Option<shared::calib::CalibrationTable<16>>> {
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
fn any_calib(path: &Option<PathBuf>) -> Result<Option<load::Calibration>> {
    path.as_deref().map(load::read_any_calibration).transpose()
}

fn import(a: ImportArgs) -> Result<()> {
    let cal = any_calib(&a.calib)?;
    let pb = spinner("reading");
    let loaded = load::load_with(&a.input, cal.as_ref(), mhz(a.base_rate_hz)?)?;
    pb.set_message("writing");
    loaded
        .recording
        .write(&a.out)
        .with_context(|| format!("writing {}", a.out.display()))?;
    pb.finish_and_clear();
    print_loaded(&loaded);
    let r = &loaded.recording;
    println!(
        "{}: {} samples × {} columns, {:.1} s",
        a.out.display(),
        r.len(),
        r.columns.len(),
        r.t_s.last().unwrap_or(&0.0) - r.t_s.first().unwrap_or(&0.0)
    );
    Ok(())
}

fn replay_cmd(a: ReplayArgs) -> Result<()> {
    let bytes =
        std::fs::read(&a.frames).with_context(|| format!("reading {}", a.frames.display()))?;
    let cal = calib(&a.calib)?.unwrap_or_else(shared::calib::CalibrationTable::factory);
    let mut config = PipelineConfig {
        frames_per_output: a.frames_per_output,
        fpga_base_rate_mhz: mhz(a.base_rate_hz)?,
        ..PipelineConfig::DEFAULT
    };
    config.fusion.mode = match a.fusion {
        FusionArg::Equal => FusionMode::Equal,
        FusionArg::Weighted => FusionMode::InverseVariance,
    };
    config.fusion.robust = !a.no_robust;
    if !(1..=shared::pipeline::MAX_FRAMES_PER_OUTPUT).contains(&a.frames_per_output) {
        bail!(
            "--frames-per-output must be 1 … {}",
            shared::pipeline::MAX_FRAMES_PER_OUTPUT
        );
    }
    let opts = ReplayOptions {
        config,
        cal,
        bus: BusConfig {
            version: a.csp_version,
            ..BusConfig::DEFAULT
        },
        final_dump: true,
        check: a.check,
    };
    let pb = bar(bytes.len() as u64, "bytes");
    let t0 = std::time::Instant::now();
    let out = replay(&bytes, &opts, |n| pb.set_position(n as u64));
    let secs = t0.elapsed().as_secs_f64();
    pb.finish_and_clear();
    let c = out.counters;
    if c.frames == 0 {
        bail!(
            "{}: no valid frame in {} bytes ({} CRC errors; an FPGA frame log starts each frame with the sync \
             marker 1A CF FC 1D); nothing written",
            a.frames.display(),
            bytes.len(),
            c.crc_errors
        );
    }
    std::fs::write(&a.out, &out.telemetry)
        .with_context(|| format!("writing {}", a.out.display()))?;
    if let Some(w) = load::link_warning(&a.frames, &c, "telemetry") {
        eprintln!("warning: {w}");
    }
    println!(
        "{} frames ({} CRC errors, {} bytes skipped, {} missing) → {} messages, {} bytes of telemetry in {}",
        c.frames,
        c.crc_errors,
        c.bytes_skipped,
        c.frames_dropped,
        out.messages.len(),
        out.telemetry.len(),
        a.out.display()
    );
    println!(
        "{:.0} frames/s through the core (this run, including I/O-free bookkeeping)",
        c.frames as f64 / secs.max(1e-9)
    );
    if let Some(ch) = out.check {
        let names = ["gx", "gy", "gz", "ax", "ay", "az"];
        println!(
            "f64 check over {} frames and {} reports (LSB = 1 µ°/s or 1 µg):",
            ch.frames, ch.reports
        );
        for (i, n) in names.iter().enumerate() {
            println!(
                "  {n}: max |core − f64| per frame {:.3} LSB, per report {:.3} LSB",
                ch.frame_max_lsb[i], ch.report_max_lsb[i]
            );
        }
    }
    Ok(())
}

fn decode(a: DecodeArgs) -> Result<()> {
    let csv = match a.out.extension().and_then(|e| e.to_str()) {
        Some("csv") => true,
        Some("jsonl") | Some("json") => false,
        _ => bail!(
            "{}: the output must end in .csv (fused samples) or .jsonl (all messages)",
            a.out.display()
        ),
    };
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("reading {}", a.input.display()))?;
    let log = TelemetryLog::decode(
        &bytes,
        &BusConfig {
            version: a.csp_version,
            ..BusConfig::DEFAULT
        },
    );
    let s = log.stats;
    if log.messages.is_empty() {
        bail!(
            "{}: no telemetry message in {} bytes ({} KISS frames: {} bad KISS, {} bad CSP, {} bad messages, {} for \
             other ports); nothing written",
            a.input.display(),
            bytes.len(),
            s.frames,
            s.kiss_errors,
            s.csp_errors,
            s.bad_messages,
            s.other_port
        );
    }
    if csv {
        write_file(&a.out, |w| log.write_fused_csv(w))?;
        if log.fused().next().is_none() {
            eprintln!(
                "warning: no fused samples among the {} messages: {} holds only its header (.jsonl keeps every \
                 message)",
                log.messages.len(),
                a.out.display()
            );
        }
    } else {
        write_file(&a.out, |w| log.write_jsonl(w))?;
    }
    if let Some(p) = &a.allan {
        let n = write_file(p, |w| log.write_allan_csv(w))?;
        println!("{}: {n} Allan levels", p.display());
        if n == 0 {
            eprintln!(
                "warning: no Allan reports in the stream: {} holds only its header",
                p.display()
            );
        }
    }
    if let Some(p) = &a.nav {
        let n = write_file(p, |w| log.write_nav_csv(w))?;
        println!("{}: {n} navigation increments", p.display());
        if n == 0 {
            eprintln!(
                "warning: no navigation reports in the stream: {} holds only its header",
                p.display()
            );
        }
    }
    if s.kiss_errors > 0 || s.csp_errors > 0 || s.bad_messages > 0 {
        eprintln!(
            "warning: {}: {} KISS frames, {} CSP packets and {} messages could not be decoded: they are not in the \
             output",
            a.input.display(),
            s.kiss_errors,
            s.csp_errors,
            s.bad_messages
        );
    }
    println!(
        "{} messages ({} fused) from {} KISS frames; bad: {} KISS, {} CSP, {} message; {} for other ports",
        log.messages.len(),
        log.fused().count(),
        s.frames,
        s.kiss_errors,
        s.csp_errors,
        s.bad_messages,
        s.other_port
    );
    Ok(())
}

fn parse_taus(s: &str) -> Result<TauSpec> {
    Ok(match s {
        "octave" => TauSpec::Octave,
        "decade" => TauSpec::Decade,
        "all" => TauSpec::All,
        n => TauSpec::PerDecade(n.parse().ok().filter(|&n: &u32| n > 0).with_context(|| {
            format!(
                "--taus: expected octave, decade, all or a number of points per decade, found '{n}'"
            )
        })?),
    })
}

fn parse_window(s: &str) -> Result<(f64, f64)> {
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
fn apply_window(rec: &mut host_test::formats::Recording, window: &str) -> Result<()> {
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

fn allan(a: AllanArgs) -> Result<()> {
    let t0 = std::time::Instant::now();
    let cal = any_calib(&a.calib)?;
    let pb = spinner("reading");
    let mut loaded = load::load_with(&a.recording, cal.as_ref(), 9_676_800)?;
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
        taus: parse_taus(&a.taus)?,
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
    let series = adev::analyze(rec, &req, &|| pb.inc(1)).map_err(anyhow::Error::msg)?;
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
        let warnings = adev::kalibr_check(&series, rate)
            .map_err(|e| anyhow::anyhow!("--kalibr: {}: {e}", a.recording.display()))?;
        for w in warnings {
            eprintln!("warning: --kalibr: {w}");
        }
    }
    write_file(&a.out, |w| adev::write_long_csv(&series, w))?;
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
        plot_adev(p, &series, &a.recording)?;
        println!("plot: {}", p.display());
    }
    if let Some(f) = &a.fit {
        write_file(f, |w| adev::write_fit_csv(&series, w))?;
        println!("noise fits: {}", f.display());
    }
    if let Some(k) = &a.kalibr {
        std::fs::write(k, adev::kalibr_yaml(&series, rate, "/imu0"))
            .with_context(|| format!("writing {}", k.display()))?;
        println!("kalibr: {}", k.display());
    }
    Ok(())
}

fn unit_scale(kind: host_test::formats::SensorKind) -> (&'static str, f64) {
    match kind {
        host_test::formats::SensorKind::Gyro => ("°/h", 3600.0),
        host_test::formats::SensorKind::Accel => ("µg", 1e6),
    }
}

fn print_summary(series: &[adev::Series]) {
    println!("cluster means (noise-term fit; minimum of the curve with its 68 % interval):");
    for s in series.iter().filter(|s| s.group.is_none()) {
        let (u, k) = unit_scale(s.kind);
        let (du, dk) = match s.kind {
            host_test::formats::SensorKind::Gyro => ("°/√h", 60.0),
            host_test::formats::SensorKind::Accel => ("µg/√Hz", 1e6),
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

fn plot_adev(path: &Path, series: &[adev::Series], source: &Path) -> Result<()> {
    use host_test::formats::SensorKind;
    use plot::{Curve, Panel, Style};
    let mut panels = Vec::new();
    for kind in [SensorKind::Gyro, SensorKind::Accel] {
        for axis in 0..3 {
            let singles: Vec<&adev::Series> = series
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
                    points: adev::independent_mean_expectation(&singles),
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
    plot::adev_panels(
        path,
        &format!("Allan deviation — {}", source.display()),
        &panels,
        3,
    )
    .map_err(anyhow::Error::msg)
}

fn diagnose(a: DiagnoseArgs) -> Result<()> {
    use host_test::diagnose::{self, Options, WeightRule, report};
    let cal = any_calib(&a.calib)?;
    let pb = spinner("reading");
    let mut loaded = load::load_with(&a.recording, cal.as_ref(), 9_676_800)?;
    // Through `suspend`: the spinner's own `println` prints nothing when stderr is not a terminal.
    pb.suspend(|| print_loaded(&loaded));
    if let Some(w) = &a.window {
        apply_window(&mut loaded.recording, w)?;
    }
    if a.longest_static {
        let m = host_test::mimu::read(&a.recording)
            .map_err(|e| anyhow::anyhow!("--longest-static needs a MIMU4444 stream: {e}"))?;
        let poses = host_test::calibrate::detect_static(&m, &Default::default())
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let p = poses
            .iter()
            .max_by(|x, y| (x.end_s - x.start_s).total_cmp(&(y.end_s - y.start_s)))
            .context("no static interval found")?;
        pb.println(format!(
            "longest static interval: {:.1} … {:.1} s ({:.1} s of {} poses)",
            p.start_s,
            p.end_s,
            p.end_s - p.start_s,
            poses.len()
        ));
        // One frame interval past the end keeps the last frame.
        loaded.recording = loaded.recording.window(p.start_s, p.end_s + 1e-3);
    }
    pb.set_message("fitting noise models and effects");
    let opts = Options {
        weights: match a.weights {
            WeightsArg::Equal => WeightRule::Equal,
            WeightsArg::InverseVariance => WeightRule::InverseVariance,
        },
        min_blocks: a.min_blocks.unwrap_or(Options::default().min_blocks),
        ..Options::default()
    };
    let r = diagnose::diagnose(&loaded.recording, &opts).map_err(anyhow::Error::msg)?;
    pb.finish_and_clear();
    let source = a.recording.display().to_string();
    let text = report::write(&r, &a.out, &source).map_err(anyhow::Error::msg)?;
    print!("{text}");
    println!(
        "\nreport: {}, plot: {}",
        a.out.join(report::TEXT_FILE).display(),
        a.out.join(report::PLOT_FILE).display()
    );
    if let Some(j) = &a.json {
        std::fs::write(j, serde_json::to_string_pretty(&r)?)
            .with_context(|| format!("writing {}", j.display()))?;
        println!("json: {}", j.display());
    }
    Ok(())
}

fn simulate(a: SimulateArgs) -> Result<()> {
    use host_test::{seedfit, sim, simcli};
    let sim_err = |e: sim::SimError| anyhow::anyhow!("{e}");
    let mut cfg = match a.preset {
        PresetArg::Seed => sim::preset::seed_config(a.seed).map_err(sim_err)?,
        PresetArg::SeedFitted => {
            seedfit::seed_config_with(&seedfit::fit().map_err(sim_err)?, a.seed).map_err(sim_err)?
        }
    };
    if a.noiseless {
        cfg = sim::SimConfig::new(
            a.seed,
            a.rate,
            cfg.samples,
            [sim::NoiseParams::default(); sim::CHANNELS],
        );
    }
    cfg.motion = a.motion;
    let frame_log = simcli::check_rates(&a.out, a.rate, a.base_rate_hz)?;
    mhz(a.base_rate_hz).context("--base-rate-hz")?;
    cfg.rate_hz = a.rate;
    let samples = match (a.samples, a.hours) {
        _ if a.seconds.is_some() => match a.seconds {
            Some(s) if s.is_finite() && s > 0.0 => (s * a.rate).round(),
            _ => bail!("--seconds must be a positive number"),
        },
        (Some(n), _) => n as f64,
        (None, Some(h)) if h.is_finite() && h > 0.0 => (h * 3600.0 * a.rate).round(),
        (None, Some(h)) => bail!("--hours must be a positive number, found {h}"),
        (None, None) if a.rate == 18.9 => cfg.samples as f64,
        (None, None) => (8.0 * 3600.0 * a.rate).round(),
    };
    cfg.samples = simcli::check_samples(samples, a.rate, frame_log)?;
    cfg.frames = simcli::frame_opts(a.rate, a.base_rate_hz);
    if frame_log {
        let actual = a.base_rate_hz / (f64::from(cfg.frames.decimation) + 1.0);
        if (actual / a.rate - 1.0).abs() > 1e-9 {
            eprintln!(
                "note: the frames' time base is {} Hz / {} = {actual} Hz (decimation {}), not exactly --rate {} Hz",
                a.base_rate_hz,
                u32::from(cfg.frames.decimation) + 1,
                cfg.frames.decimation,
                a.rate
            );
        }
    }
    let xyz = |v: &[f64], what: &str| -> Result<[f64; 3]> {
        match v {
            [x, y, z] if v.iter().all(|c| c.is_finite()) => Ok([*x, *y, *z]),
            [_, _, _] => bail!("{what}: the values must be finite numbers, found {v:?}"),
            _ => bail!("{what}: expected 3 values x,y,z, found {}", v.len()),
        }
    };
    if let Some(r) = &a.rate_dps {
        cfg.rate_dps = xyz(r, "--rate-dps")?;
    }
    if let Some(g) = &a.accel_g {
        cfg.accel_g = xyz(g, "--accel-g")?;
    }
    a.effects.apply(&mut cfg)?;
    let samples = cfg.samples;
    let pb = bar(samples, "samples");
    let t0 = std::time::Instant::now();
    simcli::write(cfg, &a.out, |n| pb.set_position(n))?;
    pb.finish_and_clear();
    let size = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    println!(
        "{}: {samples} samples at {} Hz ({:.2} h), {:.1} MB, {:.1} s",
        a.out.display(),
        a.rate,
        samples as f64 / a.rate / 3600.0,
        size as f64 / 1e6,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

fn demo(a: DemoArgs) -> Result<()> {
    use host_test::demo::{self, DemoOptions};
    if !(a.hours.is_finite() && a.hours > 0.0 && a.hours <= 100.0) {
        bail!("--hours must be in (0, 100]");
    }
    let opts = DemoOptions {
        seed: a.seed,
        hours: a.hours,
    };
    let pb = bar(0, "frames");
    let r = demo::run(opts, &a.out, |done, total| {
        pb.set_length(total);
        pb.set_position(done);
    })?;
    pb.finish_and_clear();
    print!("{}", demo::report(&r, opts));
    println!("\noutputs in {}", a.out.display());
    Ok(())
}

fn calibrate_cmd(a: CalibrateArgs) -> Result<()> {
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
