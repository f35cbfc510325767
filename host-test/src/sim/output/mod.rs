//! A simulation's output: written to a file as a frame log or an interchange CSV ([`write()`], with the rate and size
//! checks of `ground simulate`: [`check_rates`], [`check_samples`], [`frame_opts`]), or collected in memory as a
//! [`Recording`](crate::recording::Recording) ([`recording`]); either through the outputs' bandwidths
//! ([`bandwidth`]).

pub mod bandwidth;
mod memory;

pub use bandwidth::{Bandwidth, BandwidthFilter};
pub use memory::{RecordingSink, recording, recording_filtered};

use crate::file_error::FileError;
use crate::sim::{Chunk, FrameOpts, SimConfig, SimError, Simulator, csv_header};
use std::io::Write;
use std::path::Path;

/// Why a simulation's output was refused or could not be written.
#[derive(Debug, thiserror::Error)]
pub enum OutputError {
    /// The output's name, rate or size is refused; the message names the option and the rule.
    #[error("{0}")]
    Invalid(String),
    /// The simulator refused the configuration.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The output file could not be created or written.
    #[error(transparent)]
    Io(#[from] crate::file_error::FileError),
}

/// The result of this module's functions.
pub type Result<T, E = OutputError> = std::result::Result<T, E>;

/// Refuses with a message.
macro_rules! bail {
    ($($arg:tt)*) => {
        return Err(OutputError::Invalid(format!($($arg)*)))
    };
}

/// Writes a simulation to `path`: `.bin` frame log (raw ADC codes through the true calibration, the FPGA's wire
/// format) or `.csv` interchange CSV (physical values). `progress` gets the samples done.
pub fn write(cfg: SimConfig, path: &Path, progress: impl FnMut(u64)) -> Result<Simulator> {
    write_filtered(cfg, &[], path, progress)
}

/// [`write()`] with the outputs' bandwidths (`--bandwidth-hz`, [`BandwidthFilter`]); CSV output only when any.
pub fn write_filtered(
    cfg: SimConfig,
    bands: &[Bandwidth],
    path: &Path,
    mut progress: impl FnMut(u64),
) -> Result<Simulator> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let csv = match ext.as_str() {
        "csv" => true,
        "bin" => false,
        _ => bail!(
            "{}: the output must end in .bin (frame log) or .csv (interchange CSV)",
            path.display()
        ),
    };
    if !csv && !bands.is_empty() {
        bail!(
            "--bandwidth-hz filters the physical values: write a .csv (the frame log's codes are made inside the simulator)"
        );
    }
    let with_temp = cfg.thermal.is_some();
    let mut filter = BandwidthFilter::new(bands, cfg.rate_hz);
    let mut sim = Simulator::new(cfg)?;
    let mut out = std::io::BufWriter::with_capacity(
        1 << 20,
        std::fs::File::create(path).map_err(FileError::creating(path))?,
    );
    let mut chunk = Chunk::default();
    let mut text = String::new();
    let mut run = || -> std::io::Result<()> {
        if csv {
            writeln!(out, "{}", csv_header(with_temp))?;
        }
        let mut done = 0u64;
        while sim.next_chunk(&mut chunk) > 0 {
            filter.apply(&mut chunk);
            for i in 0..chunk.len {
                if csv {
                    text.clear();
                    chunk.write_csv_row(i, &mut text);
                    out.write_all(text.as_bytes())?;
                } else if let Some(f) = chunk.frame(i) {
                    out.write_all(&f.to_bytes())?;
                }
            }
            done += chunk.len as u64;
            progress(done);
        }
        out.flush()
    };
    run().map_err(FileError::writing(path))?;
    Ok(sim)
}

/// Largest output `ground simulate` writes, bytes (estimated before it starts).
pub const MAX_OUTPUT_BYTES: f64 = 32e9;

/// Bytes per sample of a CSV output (96 values; the seed preset writes ≈ 920).
const CSV_ROW_BYTES: f64 = 1000.0;

/// Checks the rates of a simulation written to `out` (`.bin`: frame log, `.csv`): both positive and finite, the
/// output rate at most the FPGA base rate; for a frame log, a whole decimation of the base rate that a frame can
/// carry (16 bits) within 1 % of `rate_hz`. Returns whether the output is a frame log.
pub fn check_rates(out: &Path, rate_hz: f64, base_rate_hz: f64) -> Result<bool> {
    let ext = out
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    let frame_log = match ext.as_str() {
        "csv" => false,
        "bin" => true,
        _ => bail!(
            "{}: the output must end in .bin (frame log) or .csv (interchange CSV)",
            out.display()
        ),
    };
    if !(rate_hz.is_finite() && rate_hz > 0.0) {
        bail!("--rate must be a positive number of Hz, found {rate_hz}");
    }
    if !(base_rate_hz.is_finite() && base_rate_hz > 0.0) {
        bail!("--base-rate-hz must be a positive number of Hz, found {base_rate_hz}");
    }
    if rate_hz > base_rate_hz {
        bail!(
            "--rate {rate_hz} Hz is above the FPGA base rate {base_rate_hz} Hz (--base-rate-hz): the output rate is \
             the base rate divided by a whole number"
        );
    }
    if frame_log {
        let div = (base_rate_hz / rate_hz).round();
        let max_div = f64::from(u16::MAX) + 1.0;
        if div > max_div {
            bail!(
                "--rate {rate_hz} Hz is below the lowest rate of a frame log at {base_rate_hz} Hz: {base_rate_hz} / \
                 {max_div} = {} Hz (the decimation is a 16-bit field); write a .csv instead",
                base_rate_hz / max_div
            );
        }
        let actual = base_rate_hz / div;
        if (actual / rate_hz - 1.0).abs() > 0.01 {
            bail!(
                "--rate {rate_hz} Hz is not the base rate {base_rate_hz} Hz divided by a whole number (the nearest is \
                 {base_rate_hz} / {div} = {actual} Hz, {:.1} % off): the frames' times would disagree with the \
                 samples",
                100.0 * (actual / rate_hz - 1.0)
            );
        }
    }
    Ok(frame_log)
}

/// Checks the number of samples of a simulation (as computed, before rounding to an integer): at least one, and
/// an output of at most [`MAX_OUTPUT_BYTES`].
pub fn check_samples(samples: f64, rate_hz: f64, frame_log: bool) -> Result<u64> {
    if samples.is_nan() || samples < 1.0 {
        bail!(
            "{samples} samples: --samples / --hours must give at least one sample at {rate_hz} Hz"
        );
    }
    let per_sample = if frame_log {
        shared::wire::frame::FRAME_LEN as f64
    } else {
        CSV_ROW_BYTES
    };
    let bytes = samples * per_sample;
    if bytes > MAX_OUTPUT_BYTES {
        let max = (MAX_OUTPUT_BYTES / per_sample).floor();
        bail!(
            "{samples:.0} samples at {rate_hz} Hz ({:.1} h) would write ≈ {:.3e} bytes; the limit is {:.1e} bytes \
             ({max:.0} samples, {:.1} h at this rate): lower --hours, --samples or --rate",
            samples / rate_hz / 3600.0,
            bytes,
            MAX_OUTPUT_BYTES,
            max / rate_hz / 3600.0
        );
    }
    Ok(samples as u64)
}

/// Frame header defaults for a rate: the decimation that gives `rate_hz` from the FPGA base rate.
pub fn frame_opts(rate_hz: f64, base_rate_hz: f64) -> FrameOpts {
    FrameOpts {
        decimation: ((base_rate_hz / rate_hz).round().max(1.0) - 1.0) as u16,
        seq_start: 0,
    }
}
