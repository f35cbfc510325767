//! `ground replay`: a frame log through the flight core, to the telemetry stream it would send.

use crate::common::{bar, calib, millihz};
use anyhow::{Context, Result, bail};
use clap::ValueEnum;
use host_test::load;
use host_test::replay::{ReplayOptions, replay};
use shared::bus::BusConfig;
use shared::bus::csp::CspVersion;
use shared::fuse::FusionMode;
use shared::pipeline::PipelineConfig;
use std::path::PathBuf;

#[derive(Clone, Copy, ValueEnum)]
enum FusionArg {
    /// The seed paper's equal-weight mean.
    Equal,
    /// Inverse-variance weights from running noise estimates.
    Weighted,
}

#[derive(clap::Args)]
pub struct Args {
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
    #[arg(long, default_value_t = host_test::FPGA_BASE_RATE_HZ)]
    base_rate_hz: f64,
    /// CSP header version on the bus (1: libcsp 1.x, Yamcs; 2: libcsp 2.x's default).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
}

pub fn run(a: Args) -> Result<()> {
    let bytes =
        std::fs::read(&a.frames).with_context(|| format!("reading {}", a.frames.display()))?;
    let cal = calib(&a.calib)?.unwrap_or_else(shared::calib::CalibrationTable::factory);
    let mut config = PipelineConfig {
        frames_per_output: a.frames_per_output,
        fpga_base_rate_millihz: millihz(a.base_rate_hz)?,
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
