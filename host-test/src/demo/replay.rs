//! The demo's first phase: the seed experiment simulated and streamed as FPGA frames through the flight core, as
//! on the MCU, with the single sensors' sums taken on the way (through the core's fixed-point calibration).

use super::{DemoError, DemoOptions};
use crate::recording::Recording;
use crate::replay::{HostCore, ReplayOutput};
use crate::seedfit::{self, AxisFit};
use crate::sim::output;
use crate::sim::{Chunk, SimConfig, Simulator};
use shared::bus::BusConfig;
use shared::calib::{AXES, CalibrationTable, RawCounts};
use shared::pipeline::{ALLAN_CHANNELS, PipelineConfig};
use shared::telemetry::Command;
use shared::wire::frame::{GROUPS, RawSample};

/// Σx and Σx² per group and axis of the single sensors through the core's calibration (µ-units).
pub(super) struct SingleSums {
    /// Σx.
    pub sum: [[f64; AXES]; GROUPS],
    /// Σx².
    pub sum2: [[f64; AXES]; GROUPS],
}

/// What streaming the record through the core gave.
pub(super) struct Streamed {
    /// The simulated record (physical units), for the diagnosis.
    pub record: Recording,
    /// The single sensors' sums.
    pub sums: SingleSums,
    /// What the core sent (telemetry bytes, link counters).
    pub sent: ReplayOutput,
}

/// The correlation fit to the paper's tables, and the simulation it configures for `opts`.
pub(super) fn seed_config(opts: DemoOptions) -> Result<(Vec<AxisFit>, SimConfig), DemoError> {
    let fits = seedfit::fit()?;
    let mut cfg = seedfit::seed_config_with(&fits, opts.seed)?;
    cfg.samples = (opts.hours * 3600.0 * cfg.rate_hz).round().max(1000.0) as u64;
    if (opts.hours - 8.0).abs() < 1e-9 {
        cfg.samples = crate::sim::preset::SEED_SAMPLES;
    }
    cfg.frames = output::frame_opts(cfg.rate_hz, crate::FPGA_BASE_RATE_HZ);
    Ok((fits, cfg))
}

/// The core, as on the MCU: factory calibration (the simulated board is nominal), one output per frame (the seed's
/// 18.9 Hz are already decimated frames), equal-weight mean without exclusion (the paper's estimator).
fn core_config() -> PipelineConfig {
    let mut config = PipelineConfig {
        frames_per_output: 1,
        health_every: 0,
        ..PipelineConfig::DEFAULT
    };
    config.fusion.mode = shared::fuse::FusionMode::Equal;
    config.fusion.robust = false;
    config
}

/// Simulates `cfg` chunk by chunk, keeps the record, adds each frame to the single sensors' sums and pushes the
/// frames through the core; then asks for every Allan channel, as the ground would. `progress(done, total)`
/// reports frames.
pub(super) fn through_the_core(
    cfg: SimConfig,
    mut progress: impl FnMut(u64, u64),
) -> Result<Streamed, DemoError> {
    let total = cfg.samples;
    let mut record = output::RecordingSink::new(total as usize, cfg.thermal.is_some());
    let mut sim = Simulator::new(cfg)?;
    let cal = CalibrationTable::<GROUPS>::factory();
    let mut core = HostCore::new(core_config(), cal, BusConfig::DEFAULT, false);
    core.reserve(total as usize * 60);
    let mut sums = SingleSums {
        sum: [[0f64; AXES]; GROUPS],
        sum2: [[0f64; AXES]; GROUPS],
    };
    let mut chunk = Chunk::default();
    let mut bytes = Vec::new();
    let mut done = 0u64;
    while sim.next_chunk(&mut chunk) > 0 {
        record.push(&chunk);
        bytes.clear();
        for i in 0..chunk.len {
            let Some(f) = chunk.frame(i) else { continue };
            sums.add(&cal, &f.raw);
            bytes.extend_from_slice(&f.to_bytes());
        }
        core.push(&bytes);
        done += chunk.len as u64;
        progress(done, total);
    }
    core.command(
        1,
        Command::AllanRequest {
            first: 0,
            count: ALLAN_CHANNELS as u8,
        },
    );
    Ok(Streamed {
        record: record.finish(),
        sums,
        sent: core.finish(),
    })
}

impl SingleSums {
    /// Adds one frame's ADC codes, through the calibration `cal`.
    fn add(&mut self, cal: &CalibrationTable<GROUPS>, raw: &RawSample) {
        for ((codes, g), (s, s2)) in raw
            .iter()
            .zip(&cal.groups)
            .zip(self.sum.iter_mut().zip(self.sum2.iter_mut()))
        {
            for ((v, a), b) in g
                .apply(&RawCounts::from_adc(codes))
                .iter()
                .zip(s.iter_mut())
                .zip(s2.iter_mut())
            {
                let x = f64::from(*v);
                *a += x;
                *b += x * x;
            }
        }
    }
}
