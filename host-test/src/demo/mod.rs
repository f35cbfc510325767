//! `ground demo`, the main job: the seed experiment (Greenheck et al.: 16 groups, 18.9 Hz, 8 h) simulated with the
//! paper's noise levels and the correlations that explain its cluster ratios (`seedfit`), streamed as FPGA frames
//! through the flight core (`shared::Pipeline`, exactly as the MCU runs it), its telemetry encoded as bus bytes and
//! decoded on the ground — then the paper's Tables 1 and 2 recomputed from what the core sent, with confidence
//! intervals, ADEV plots and a report.
//!
//! Where each number comes from: single-sensor RMS — the frames through the core's fixed-point calibration
//! (ground side, the core does not send single-sensor samples), RMS over the 16 groups of their standard
//! deviations; single-sensor bias stability — the core's 96 per-sensor Allan channels (exact integer sums sent in
//! telemetry, roots taken here), median over groups of each curve's minimum; cluster RMS — the fused samples the
//! core sent; cluster bias stability — the core's fused Allan channel. Confidence intervals: Greenhall EDF at the
//! noise type identified on the fused series, 68.3 %.
//!
//! The phases, one module each: `replay` simulates the record and drives the flight core with it; `stats`
//! decodes what the core sent and computes the tables; `diagnosis` runs the sim-to-real diagnosis and the twin
//! on the same record, and places it among commercial IMUs (`crate::tradeoff`, `tradeoff/`); `files` writes the plot and the files; [`report`] renders the Markdown report.

mod diagnosis;
use crate::file_error::FileError;
pub use diagnosis::{REAL_EXCERPT, RealTwin};
mod files;
mod replay;
mod report;
mod stats;

use crate::seedfit::AxisFit;
use std::path::Path;

pub use report::report;

/// Demo parameters.
#[derive(Clone, Copy, Debug)]
pub struct DemoOptions {
    /// Simulation seed.
    pub seed: u64,
    /// Duration, hours.
    pub hours: f64,
}

/// One table row as recomputed: single, cluster, ratio (with 68 % bounds of the ratio).
#[derive(Clone, Copy, Debug, serde::Serialize)]
pub struct Row {
    /// Single sensor (°/s or g).
    pub single: f64,
    /// Cluster.
    pub cluster: f64,
    /// single / cluster.
    pub ratio: f64,
    /// 68 % bounds of the ratio.
    pub ratio_ci: [f64; 2],
}

/// The demo's results.
#[derive(Clone, Debug, serde::Serialize)]
pub struct DemoResult {
    /// Table 1 (RMS noise) per axis.
    pub table1: Vec<Row>,
    /// Table 2 (bias stability) per axis, and the τ of the cluster minimum.
    pub table2: Vec<(Row, f64)>,
    /// The correlation fit to the paper's tables.
    pub fits: Vec<AxisFit>,
    /// Frames through the core, telemetry bytes, messages.
    pub frames: u64,
    /// Telemetry bytes.
    pub telemetry_bytes: usize,
    /// Largest relative difference between the core's integer Allan deviation of the fused axes and the ground's
    /// f64 computation on the fused samples.
    pub allan_core_vs_ground: f64,
    /// Wall-clock seconds: simulation + core, analysis, total.
    pub seconds: [f64; 3],
    /// The sim-to-real diagnosis of the same simulated record (`ground diagnose`, physical samples): one line per
    /// effect named.
    pub diagnosis: Vec<String>,
    /// The axis (`gyro y`, …) with the largest fitted shared-flicker share ρ_flicker, and that share.
    pub largest_shared_flicker: Option<(String, f64)>,
    /// The sim-to-real loop on the same record: model, twin with and without effects, compared with the record.
    pub twin: crate::twin::LoopSummary,
    /// The same loop on a real cluster's record (`real/`: the MIMU4444 excerpt [`diagnosis::REAL_EXCERPT`]).
    pub real_twin: diagnosis::RealTwin,
    /// The seed paper's Figures 9–10 on the same record (`tradeoff/`): the terminal summary of
    /// [`crate::tradeoff::run`] (the figures, the boards' power and mass, the battery check).
    pub tradeoff: String,
    /// On-board thermal compensation, end to end (`thermal_check`, quick form): a board calibrated on a ramp, an
    /// orbit's temperature cycle through the flight core with and without the table.
    pub thermal: crate::thermal_check::ThermalCheck,
}

/// Why the demo stopped.
#[derive(Debug, thiserror::Error)]
pub enum DemoError {
    /// An output could not be written (or its folder created).
    #[error(transparent)]
    Io(#[from] crate::file_error::FileError),
    /// The seed fit or the simulator failed.
    #[error(transparent)]
    Sim(#[from] crate::sim::SimError),
    /// The ADEV plot failed.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// The diagnosis refused the record.
    #[error(transparent)]
    Diagnose(#[from] crate::diagnose::DiagnoseError),
    /// The diagnosis's report could not be written.
    #[error(transparent)]
    DiagnoseReport(#[from] crate::diagnose::report::WriteError),
    /// The twin's loop failed.
    #[error(transparent)]
    Twin(#[from] crate::twin::TwinError),
    /// A result could not be serialised.
    #[error(transparent)]
    Json(#[from] serde_json::Error),
    /// The thermal check failed.
    #[error(transparent)]
    Thermal(#[from] crate::thermal_check::ThermalCheckError),
    /// The trade-off figures failed.
    #[error(transparent)]
    Tradeoff(#[from] crate::tradeoff::TradeoffError),
    /// The built-in MIMU4444 excerpt did not parse.
    #[error(transparent)]
    Mimu(#[from] crate::formats::mimu::MimuError),
}

impl DemoError {
    /// Writes `contents` to `path`, naming the file on failure.
    fn write(path: &Path, contents: impl AsRef<[u8]>) -> Result<(), DemoError> {
        std::fs::write(path, contents).map_err(FileError::writing(path))?;
        Ok(())
    }
}

/// The axes' short names, in table order.
const AXIS_NAMES: [&str; 6] = ["gx", "gy", "gz", "ax", "ay", "az"];

/// Runs the demo and writes its outputs into `out`. `progress(done, total)` reports frames.
pub fn run(
    opts: DemoOptions,
    out: &Path,
    progress: impl FnMut(u64, u64),
) -> Result<DemoResult, DemoError> {
    let t0 = std::time::Instant::now();
    std::fs::create_dir_all(out).map_err(FileError::creating(out))?;
    let (fits, cfg) = replay::seed_config(opts)?;
    let streamed = replay::through_the_core(cfg, progress)?;
    let telemetry = &streamed.sent.telemetry;
    let t_core = t0.elapsed().as_secs_f64();
    DemoError::write(&out.join("telemetry.kiss"), telemetry)?;

    let decoded = stats::Decoded::from_telemetry(telemetry);
    let tables = stats::Tables::compute(&decoded, &streamed.sums);
    files::write_plot(out, &decoded, &tables)?;
    let diagnosed =
        diagnosis::of_record(&streamed.record, &out.join("diagnose"), &out.join("twin"))?;
    let real_twin = diagnosis::of_real_excerpt(&out.join("real"))?;
    let tradeoff = crate::tradeoff::run(
        &streamed.record,
        "the seed experiment (simulated)",
        &crate::tradeoff::Inputs::default(),
        &out.join("tradeoff"),
    )?;
    let thermal = crate::thermal_check::run(&crate::thermal_check::ThermalCheckOptions::QUICK)?;
    let result = DemoResult {
        tradeoff: crate::tradeoff::render::summary(&tradeoff),
        thermal,
        diagnosis: diagnosed.lines,
        largest_shared_flicker: diagnosed.largest_shared_flicker,
        twin: diagnosed.twin,
        real_twin,
        table1: tables.table1,
        table2: tables.table2,
        fits,
        frames: streamed.sent.counters.frames.into(),
        telemetry_bytes: telemetry.len(),
        allan_core_vs_ground: tables.core_vs_ground,
        seconds: [
            t_core,
            t0.elapsed().as_secs_f64() - t_core,
            t0.elapsed().as_secs_f64(),
        ],
    };
    files::write_outputs(&result, out, opts)?;
    Ok(result)
}

/// The units of axis `a`: Table 1's (name, factor from °/s or g), Table 2's.
fn unit(a: usize) -> (&'static str, f64, &'static str, f64) {
    if a < 3 {
        ("°/s", 1.0, "°/h", 3600.0)
    } else {
        ("µg", 1e6, "µg", 1e6)
    }
}
