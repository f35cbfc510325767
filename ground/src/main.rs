//! `ground`: the ground and lab tool of the IMU cluster. `ground <command> --help` documents each command.

mod allan;
mod calibrate;
mod common;
mod compare;
mod decode;
mod demo;
mod diagnose;
mod effects;
mod fw;
mod import;
mod replay;
mod simulate;
mod tradeoff;

use clap::{Parser, Subcommand};
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
    Demo(demo::Args),
    /// Simulate a cluster recording from a noise model with optional effects (frame log .bin or CSV .csv).
    Simulate(Box<simulate::Args>),
    /// Convert a frame log or MIMU4444 stream (or any recording) to the interchange CSV (°/s, g), through a
    /// calibration into the cluster frame.
    Import(import::Args),
    /// Estimate calibration tables: multi-position static (MIMU4444), rate table (our board), or biases only.
    Calibrate(calibrate::Args),
    /// Run a frame log through the flight core (shared::Pipeline) and write the telemetry stream it would send.
    Replay(replay::Args),
    /// Decode a telemetry stream (CSP/KISS/postcard) to CSV, JSON lines or MCAP (Foxglove).
    Decode(decode::Args),
    /// Allan deviations with confidence intervals, noise identification, noise-term fit, plots, Kalibr yaml.
    Allan(allan::Args),
    /// Sim-to-real diagnosis of a static cluster recording: where the gap to the √N model lies, which effect causes
    /// it, how far it shrinks (checked on the held-out second half).
    Diagnose(diagnose::Args),
    /// The sim-to-real gap measured directly: two recordings' cluster and typical-sensor Allan deviations compared
    /// per axis and τ (z-scores, the diagnosis's scan verdict), with a plot and JSON.
    Compare(compare::Args),
    /// The seed paper's Figures 9–10: the recording's bias instability and random walk placed with commercial IMUs
    /// against mass and power, on the seed board (with its Raspberry Pi) and ours (with the MCU).
    Tradeoff(tradeoff::Args),
    /// In-orbit update: a new Ed25519 signing key pair (PREFIX.pem, PREFIX.pub).
    FwKeygen(fw::KeygenArgs),
    /// In-orbit update: the signed image of an application ELF.
    FwSign(fw::SignArgs),
    /// In-orbit update: upload a signed image over the bus (resumes where the satellite's DFU slot stops).
    FwUpload(fw::UploadArgs),
}

/// `ground … | head` closes the pipe before `ground` is done; the next `println!` then fails and panics (Rust ignores
/// SIGPIPE). Exit quietly instead, with the status of a process ended by SIGPIPE (128 + 13), as `cat` would; every
/// other panic goes to the default hook.
fn quiet_on_broken_pipe() {
    let default = std::panic::take_hook();
    std::panic::set_hook(Box::new(move |info| {
        let payload = info.payload();
        let msg = payload
            .downcast_ref::<String>()
            .map(String::as_str)
            .or_else(|| payload.downcast_ref::<&str>().copied())
            .unwrap_or("");
        if msg.starts_with("failed printing to stdout") && msg.contains("Broken pipe") {
            std::process::exit(141);
        }
        default(info);
    }));
}

fn main() -> ExitCode {
    quiet_on_broken_pipe();
    let cli = Cli::parse();
    let result = match cli.cmd {
        Cmd::Demo(a) => demo::run(a),
        Cmd::Simulate(a) => simulate::run(*a),
        Cmd::Import(a) => import::run(a),
        Cmd::Calibrate(a) => calibrate::run(a),
        Cmd::Replay(a) => replay::run(a),
        Cmd::Decode(a) => decode::run(a),
        Cmd::Allan(a) => allan::run(a),
        Cmd::Diagnose(a) => diagnose::run(a),
        Cmd::Compare(a) => compare::run(a),
        Cmd::Tradeoff(a) => tradeoff::run(a),
        Cmd::FwKeygen(a) => fw::keygen(a),
        Cmd::FwSign(a) => fw::sign(a),
        Cmd::FwUpload(a) => fw::upload(a),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
