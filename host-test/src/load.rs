//! Opens any recording the tools accept: interchange CSV (by extension), FPGA frame log (starts with the frame
//! sync marker) or MIMU4444 stream (starts with its command acknowledgement / 0xAA frames).

use crate::formats::csv::Recording;
use crate::formats::framelog::FrameLog;
use anyhow::{Context, Result, bail};
use shared::calib::CalibrationTable;
use shared::wire::frame::{GROUPS, SYNC};
use std::path::Path;

/// What a file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// Interchange CSV.
    Csv,
    /// FPGA frame log.
    FrameLog,
}

/// Guesses the kind of `path` from its extension and first bytes.
pub fn detect(path: &Path, head: &[u8]) -> Result<InputKind> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
    {
        return Ok(InputKind::Csv);
    }
    if head.windows(SYNC.len()).take(512).any(|w| w == SYNC) {
        return Ok(InputKind::FrameLog);
    }
    bail!(
        "{}: not a recognised recording (expected an interchange .csv, or an FPGA frame log starting with the sync marker 1A CF FC 1D)",
        path.display()
    )
}

/// A loaded recording, with notes for the user (ignored columns, link statistics).
pub struct Loaded {
    /// The physical recording.
    pub recording: Recording,
    /// Messages worth printing.
    pub notes: Vec<String>,
}

/// Loads a recording; raw formats go through `cal` (factory default when `None`).
pub fn load(
    path: &Path,
    cal: Option<&CalibrationTable<GROUPS>>,
    base_rate_mhz: u64,
) -> Result<Loaded> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    match detect(path, &bytes)? {
        InputKind::Csv => {
            let text = String::from_utf8(bytes)
                .with_context(|| format!("{}: not UTF-8 text", path.display()))?;
            let (recording, notes) =
                Recording::parse(&text).with_context(|| path.display().to_string())?;
            Ok(Loaded { recording, notes })
        }
        InputKind::FrameLog => {
            let log = FrameLog::decode(&bytes);
            if log.frames.is_empty() {
                bail!("{}: no valid frame found", path.display());
            }
            let factory = CalibrationTable::factory();
            let recording = log.to_recording(cal.unwrap_or(&factory), base_rate_mhz);
            let c = log.counters;
            let notes = vec![format!(
                "frame log: {} frames, {} CRC errors, {} bytes skipped, {} frames missing by sequence{}",
                c.frames,
                c.crc_errors,
                c.bytes_skipped,
                c.frames_dropped,
                if cal.is_none() {
                    " (factory calibration)"
                } else {
                    ""
                }
            )];
            Ok(Loaded { recording, notes })
        }
    }
}

/// Reads a calibration table file (`.bin`: the encoded table with CRC).
pub fn load_calibration(path: &Path) -> Result<CalibrationTable<GROUPS>> {
    let bytes = std::fs::read(path).with_context(|| format!("reading {}", path.display()))?;
    CalibrationTable::decode(&bytes)
        .map_err(|e| anyhow::anyhow!("{}: not a valid calibration table: {e:?}", path.display()))
}
