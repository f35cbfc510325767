//! `ground simulate`: a simulated cluster recording (frame log or CSV).

use crate::common::{bar, millihz};
use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use host_test::figures::sig3;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
enum PresetArg {
    /// The seed paper's single-sensor noise (Tables 1 and 2), independent sensors.
    Seed,
    /// The seed paper's noise with the common modes that explain its cluster ratios (`seedfit`).
    SeedFitted,
}

#[derive(clap::Args)]
pub struct Args {
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
    /// Output rate, Hz (frames carry the decimation that gives it from the FPGA base rate; default 18.9, or the
    /// model's).
    #[arg(long)]
    rate: Option<f64>,
    /// Play a cluster model fitted by `ground diagnose --model` (the twin; `docs/twin.md`): rate, duration and
    /// groups default to the model's.
    #[arg(long, conflicts_with_all = ["preset", "noiseless", "motion", "rate_dps", "accel_g"])]
    model: Option<PathBuf>,
    /// With --model: only the independent typical sensors (the √N model), no effect.
    #[arg(long, requires = "model")]
    without_effects: bool,
    /// With --model: drive the thermal terms with this recording's `temp_c` column.
    #[arg(long, requires = "model")]
    temperature_from: Option<PathBuf>,
    /// Random seed (same seed, same output).
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Seed of the board's parts (noise levels, biases, thermal coefficients, calibration errors), independent of
    /// --seed (the noise): records with one --board-seed are the same board; default = --seed.
    #[arg(long, conflicts_with = "model")]
    board_seed: Option<u64>,
    /// FPGA base rate before decimation, Hz.
    #[arg(long, default_value_t = host_test::FPGA_BASE_RATE_HZ)]
    base_rate_hz: f64,
    /// True angular rate of the board, °/s (x,y,z; e.g. a rate table).
    #[arg(long, value_delimiter = ',', num_args = 1..=3, allow_hyphen_values = true)]
    rate_dps: Option<Vec<f64>>,
    /// True specific force, g (x,y,z; default the preset's).
    #[arg(long, value_delimiter = ',', num_args = 1..=3, allow_hyphen_values = true)]
    accel_g: Option<Vec<f64>>,
    #[command(flatten)]
    effects: crate::effects::EffectArgs,
}

/// Samples from --seconds / --samples / --hours at `rate`, or `default`.
fn samples_of(a: &Args, rate: f64, default: f64) -> Result<f64> {
    Ok(match (a.samples, a.hours) {
        _ if a.seconds.is_some() => match a.seconds {
            Some(s) if s.is_finite() && s > 0.0 => (s * rate).round(),
            _ => bail!("--seconds must be a positive number"),
        },
        (Some(n), _) => n as f64,
        (None, Some(h)) if h.is_finite() && h > 0.0 => (h * 3600.0 * rate).round(),
        (None, Some(h)) => bail!("--hours must be a positive number, found {h}"),
        (None, None) => default,
    })
}

/// `--model`: the twin played (`host_test::twin::play`), written as CSV or a frame log.
fn run_model(a: &Args, path: &std::path::Path) -> Result<()> {
    use host_test::sim::output;
    use host_test::twin;
    if a.effects.any() {
        bail!(
            "--model plays the model's effects: the effect options do not apply (see --without-effects)"
        );
    }
    let model = twin::ClusterModel::load(path)?;
    let rate = a.rate.unwrap_or(model.record.rate_hz);
    let frame_log = output::check_rates(&a.out, rate, a.base_rate_hz)?;
    millihz(a.base_rate_hz).context("--base-rate-hz")?;
    let samples = output::check_samples(
        samples_of(a, rate, model.record.samples as f64)?,
        rate,
        frame_log,
    )?;
    let temperature = match &a.temperature_from {
        Some(p) => {
            let l =
                host_test::load::load_with(p, None, shared::wire::clock::FPGA_BASE_RATE_MILLIHZ)?;
            Some(
                l.recording
                    .temp_c
                    .with_context(|| format!("{}: no temp_c column", p.display()))?,
            )
        }
        None => None,
    };
    let t0 = std::time::Instant::now();
    let rec = twin::play(
        &model,
        &twin::PlayOptions {
            seed: a.seed,
            samples: Some(samples as usize),
            rate_hz: Some(rate),
            without_effects: a.without_effects,
            temperature,
        },
    )?;
    if frame_log {
        let frames = twin::play::frames(&rec, output::frame_opts(rate, a.base_rate_hz).decimation)?;
        std::fs::write(&a.out, frames).with_context(|| format!("writing {}", a.out.display()))?;
    } else {
        rec.write(&a.out)
            .with_context(|| format!("writing {}", a.out.display()))?;
    }
    let size = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    println!(
        "{}: the model of {} {}, {samples} samples at {} Hz ({:.2} h), {} groups, {:.1} MB, {:.1} s",
        a.out.display(),
        model.record.source,
        if a.without_effects {
            "without effects"
        } else {
            "with its effects"
        },
        sig3(rate),
        samples as f64 / rate / 3600.0,
        model.record.groups.len(),
        size as f64 / 1e6,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}

pub fn run(a: Args) -> Result<()> {
    use host_test::seedfit;
    use host_test::sim::{self, output};
    if let Some(m) = &a.model {
        return run_model(&a, m);
    }
    let rate = a.rate.unwrap_or(18.9);
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
            rate,
            cfg.samples,
            [sim::NoiseParams::default(); sim::CHANNELS],
        );
    }
    cfg.motion = a.motion;
    let frame_log = output::check_rates(&a.out, rate, a.base_rate_hz)?;
    millihz(a.base_rate_hz).context("--base-rate-hz")?;
    cfg.rate_hz = rate;
    let default = if rate == 18.9 {
        cfg.samples as f64
    } else {
        (8.0 * 3600.0 * rate).round()
    };
    let samples = samples_of(&a, rate, default)?;
    cfg.samples = output::check_samples(samples, rate, frame_log)?;
    cfg.frames = output::frame_opts(rate, a.base_rate_hz);
    if frame_log {
        let actual = a.base_rate_hz / (f64::from(cfg.frames.decimation) + 1.0);
        if (actual / rate - 1.0).abs() > 1e-9 {
            eprintln!(
                "note: the frames' time base is {} Hz / {} = {actual} Hz (decimation {}), not exactly --rate {} Hz",
                a.base_rate_hz,
                u32::from(cfg.frames.decimation) + 1,
                cfg.frames.decimation,
                rate
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
    a.effects.effects()?.apply(&mut cfg)?;
    let bands = a.effects.bandwidths()?;
    cfg.board_seed = a.board_seed;
    let samples = cfg.samples;
    let pb = bar(samples, "samples");
    let t0 = std::time::Instant::now();
    output::write_filtered(cfg, &bands, &a.out, |n| pb.set_position(n))?;
    pb.finish_and_clear();
    let size = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    println!(
        "{}: {samples} samples at {} Hz ({:.2} h), {:.1} MB, {:.1} s",
        a.out.display(),
        sig3(rate),
        samples as f64 / rate / 3600.0,
        size as f64 / 1e6,
        t0.elapsed().as_secs_f64()
    );
    Ok(())
}
