//! Opens any recording the tools accept: interchange CSV (by extension), NumPy `.npy` array (by extension or its
//! magic bytes, `formats::npy`), FPGA frame log (the frame sync marker
//! within its first bytes) or MIMU4444 stream (a valid 0xAA frame within its first bytes), and reads calibration
//! files of either array (16 groups: our board; 8 IMUs: the MIMU4444) in any of their forms (.bin, .json, .toml).

use crate::calibrate::CalibError;
use crate::formats::csv::CsvError;
use crate::formats::framelog::FrameLog;
use crate::formats::mimu::MimuError;
use crate::formats::npy::NpyError;
use crate::recording::{AxisMean, Recording};
use shared::calib::CalibrationTable;
use shared::wire::frame::{GROUPS, SYNC};
use std::path::{Path, PathBuf};

/// Why a recording or a calibration could not be loaded; every variant names the file.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// Neither the extension nor the first bytes say what the file holds.
    #[error(
        "{}: not a recognised recording (expected an interchange .csv, a NumPy .npy array, an FPGA frame log with \
         the sync marker 1A CF FC 1D, or a MIMU4444 stream of 0xAA frames)",
        path.display()
    )]
    Unrecognised {
        /// The file.
        path: PathBuf,
    },
    /// The file could not be read.
    #[error("reading {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// An interchange CSV is malformed.
    #[error("{}", path.display())]
    Csv {
        /// The file.
        path: PathBuf,
        /// The line and column, and what is wrong.
        #[source]
        source: CsvError,
    },
    /// A `.npy` array is refused (the error names the file).
    #[error(transparent)]
    Npy(#[from] NpyError),
    /// A MIMU4444 stream holds no usable frame.
    #[error("{}", path.display())]
    Mimu {
        /// The file.
        path: PathBuf,
        /// What is wrong in it.
        #[source]
        source: MimuError,
    },
    /// A frame log holds no valid frame.
    #[error("{}: no valid frame found in {bytes} bytes ({crc_errors} CRC errors)", path.display())]
    NoFrames {
        /// The file.
        path: PathBuf,
        /// Its length.
        bytes: usize,
        /// Frames that failed their CRC.
        crc_errors: u32,
    },
    /// A calibration was given for an input it cannot apply to.
    #[error("{}: {reason}", path.display())]
    CalibrationRefused {
        /// The input.
        path: PathBuf,
        /// Why.
        reason: &'static str,
    },
    /// A calibration file could not be read (the error names the file and its cause; not chained, since
    /// `CalibError` prints its cause itself).
    #[error("{0}")]
    Calibration(CalibError),
}

impl LoadError {
    fn refused(path: &Path, reason: &'static str) -> LoadError {
        LoadError::CalibrationRefused {
            path: path.to_path_buf(),
            reason,
        }
    }
}

/// The result of this module's functions.
pub type Result<T, E = LoadError> = std::result::Result<T, E>;

/// What a file holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// Interchange CSV.
    Csv,
    /// NumPy `.npy` array.
    Npy,
    /// FPGA frame log.
    FrameLog,
    /// MIMU4444 stream.
    Mimu,
}

/// Guesses the kind of `path` from its extension and first bytes.
pub fn detect(path: &Path, head: &[u8]) -> Result<InputKind> {
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
    {
        return Ok(InputKind::Csv);
    }
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("npy"))
        || head.starts_with(NPY_MAGIC)
    {
        return Ok(InputKind::Npy);
    }
    if head.windows(SYNC.len()).take(512).any(|w| w == SYNC) {
        return Ok(InputKind::FrameLog);
    }
    if (0..head.len().min(512)).any(|i| crate::formats::mimu::Frame::decode(&head[i..]).is_ok()) {
        return Ok(InputKind::Mimu);
    }
    Err(LoadError::Unrecognised {
        path: path.to_path_buf(),
    })
}

/// The first bytes of a `.npy` file.
const NPY_MAGIC: &[u8] = b"\x93NUMPY";

/// A loaded recording, with notes for the user (link statistics) and warnings (what was ignored or lost).
pub struct Loaded {
    /// The physical recording.
    pub recording: Recording,
    /// Messages worth printing.
    pub notes: Vec<String>,
    /// What the input lost or the reader ignored (columns, corrupt frames, gaps, missing temperatures).
    pub warnings: Vec<String>,
}

/// A calibration of either array.
#[derive(Clone, Debug, PartialEq)]
pub enum Calibration {
    /// Our board (16 groups).
    Board(Box<CalibrationTable<GROUPS>>),
    /// The MIMU4444 array (8 IMUs).
    Mimu(Box<CalibrationTable<MIMU_IMUS>>),
}

/// IMUs of the MIMU4444 array.
pub const MIMU_IMUS: usize = crate::formats::mimu::IMUS;

/// Reads a calibration file of either array (`.bin`, `.json`, `.toml`), told apart by its number of groups.
pub fn read_any_calibration(path: &Path) -> Result<Calibration> {
    // The calibration errors already name the file.
    let err = LoadError::Calibration;
    let f = crate::calibrate::read_calibration_any(path).map_err(err)?;
    if f.groups.len() == GROUPS {
        Ok(Calibration::Board(Box::new(
            f.to_table::<GROUPS>().map_err(err)?,
        )))
    } else {
        Ok(Calibration::Mimu(Box::new(
            f.to_table::<MIMU_IMUS>().map_err(err)?,
        )))
    }
}

/// The physical recording of a MIMU4444 stream: with `cal`, the table (µ-units, fixed point, in the cluster frame
/// it defines); without, the nominal scales (2048 counts/g, 16.4 counts/(°/s)) in each IMU's own frame.
pub fn mimu_recording(
    m: &crate::formats::mimu::Recording,
    cal: Option<&CalibrationTable<MIMU_IMUS>>,
) -> Recording {
    use shared::calib::RawCounts;
    let n = m.frames.len();
    let mut cols: Vec<Vec<f64>> = (0..MIMU_IMUS * 6).map(|_| Vec::with_capacity(n)).collect();
    for f in &m.frames {
        for (i, s) in f.imu.iter().enumerate() {
            let g = s.gyro.map(i32::from);
            let a = s.acc.map(i32::from);
            let v: [f64; 6] = match cal.and_then(|c| c.groups.get(i)) {
                Some(gc) => gc
                    .apply(&RawCounts {
                        gyro: [g[0], g[1], g[2], 0],
                        accel: a,
                    })
                    .map(|x| f64::from(x) / 1e6),
                None => {
                    let (gs, as_) = (
                        crate::formats::mimu::GYRO_LSB_PER_DPS,
                        crate::formats::mimu::ACCEL_LSB_PER_G,
                    );
                    [
                        f64::from(g[0]) / gs,
                        f64::from(g[1]) / gs,
                        f64::from(g[2]) / gs,
                        f64::from(a[0]) / as_,
                        f64::from(a[1]) / as_,
                        f64::from(a[2]) / as_,
                    ]
                }
            };
            for (k, x) in v.iter().enumerate() {
                cols[i * 6 + k].push(*x);
            }
        }
    }
    Recording::from_group_columns(m.times_s(), cols)
}

/// A warning about what the link decoder dropped or repeated in `path` (`None` when nothing): corrupt frames,
/// skipped bytes and gaps in the sequence are not in the `output`; backward sequence jumps (an FPGA reset, or
/// repeated frames) are named too, since repeated frames would count as new samples.
pub fn link_warning(path: &Path, c: &shared::wire::LinkCounters, output: &str) -> Option<String> {
    let mut parts = Vec::new();
    let lost: Vec<String> = [
        (c.crc_errors, "frames failed their CRC"),
        (c.bytes_skipped, "bytes skipped"),
        (c.frames_dropped, "frames missing by sequence"),
    ]
    .iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, what)| format!("{n} {what}"))
    .collect();
    if !lost.is_empty() {
        parts.push(format!(
            "{}: those frames are not in the {output}",
            lost.join(", ")
        ));
    }
    if c.seq_restarts > 0 {
        parts.push(format!(
            "the sequence counter jumped back {} times (an FPGA reset, or repeated frames, which count as new \
             samples)",
            c.seq_restarts
        ));
    }
    (!parts.is_empty()).then(|| format!("{}: {}", path.display(), parts.join("; ")))
}

/// As [`load_with`], for a consumer of only the sensor columns `columns` (all when empty) and the cluster means: a
/// `.npy` array (known by its extension) then materialises only those columns, and computes the cluster mean of
/// every axis over all its groups in the same pass (returned, equal to `allan::recording::cluster_mean` of the whole
/// recording, while each block of the file is in the cache); any other input is loaded whole (`None`: the
/// recording holds every column).
pub fn load_selected(
    path: &Path,
    cal: Option<&Calibration>,
    base_rate_millihz: u64,
    columns: &[String],
) -> Result<(Loaded, Option<Vec<AxisMean>>)> {
    if !matches!(detect(path, &[]), Ok(InputKind::Npy)) {
        return Ok((load_with(path, cal, base_rate_millihz)?, None));
    }
    refuse_npy_calibration(path, cal)?;
    let array = crate::formats::npy::NpyArray::open(path)?;
    let (recording, means) = array
        .recording_with_means(columns)
        .map_err(|e| e.in_file(path))?;
    let loaded = Loaded {
        recording,
        notes: npy_notes(path, &array),
        warnings: Vec::new(),
    };
    Ok((loaded, Some(means)))
}

/// A `.npy` array holds calibrated values: an error when a calibration is given.
fn refuse_npy_calibration(path: &Path, cal: Option<&Calibration>) -> Result<()> {
    if cal.is_some() {
        return Err(LoadError::refused(
            path,
            "a .npy array holds calibrated values (°/s, g); a calibration applies only to raw recordings (FPGA \
             frame log, MIMU4444 stream)",
        ));
    }
    Ok(())
}

/// The note on a `.npy` array's conversion, if its values were converted.
fn npy_notes(path: &Path, array: &crate::formats::npy::NpyArray) -> Vec<String> {
    array
        .conversion()
        .map(|c| format!("{}: {c}", path.display()))
        .into_iter()
        .collect()
}

/// Loads a recording; raw formats go through `cal` (the factory default of our board, or the MIMU4444's nominal
/// scales, when `None`).
pub fn load_with(path: &Path, cal: Option<&Calibration>, base_rate_millihz: u64) -> Result<Loaded> {
    // A CSV or .npy is known by its name and streamed (never held whole in memory); the others are read whole.
    let bytes = match detect(path, &[]) {
        Ok(InputKind::Csv | InputKind::Npy) => Vec::new(),
        _ => std::fs::read(path).map_err(|source| LoadError::Read {
            path: path.to_path_buf(),
            source,
        })?,
    };
    match detect(path, &bytes)? {
        InputKind::Csv => load_csv(path, cal),
        InputKind::Npy => load_npy(path, &bytes, cal),
        InputKind::Mimu => load_mimu(path, &bytes, cal),
        InputKind::FrameLog => load_frame_log(path, &bytes, cal, base_rate_millihz),
    }
}

/// An interchange CSV (streamed from `path`; calibrated already, so `cal` must be `None`).
fn load_csv(path: &Path, cal: Option<&Calibration>) -> Result<Loaded> {
    if cal.is_some() {
        return Err(LoadError::refused(
            path,
            "an interchange CSV holds calibrated values (°/s, g); a calibration applies only to raw \
             recordings (FPGA frame log, MIMU4444 stream)",
        ));
    }
    let (recording, warnings) = Recording::read(path).map_err(|e| match e {
        // The file could not be read: named once, its cause chained once.
        CsvError::Io { source, .. } => LoadError::Read {
            path: path.to_path_buf(),
            source,
        },
        source => LoadError::Csv {
            path: path.to_path_buf(),
            source,
        },
    })?;
    Ok(Loaded {
        recording,
        notes: Vec::new(),
        warnings: warnings
            .into_iter()
            .map(|w| format!("{}: {w}", path.display()))
            .collect(),
    })
}

/// A NumPy array (`bytes` when already read, else mapped from `path`).
fn load_npy(path: &Path, bytes: &[u8], cal: Option<&Calibration>) -> Result<Loaded> {
    refuse_npy_calibration(path, cal)?;
    let array = if bytes.is_empty() {
        crate::formats::npy::NpyArray::open(path)?
    } else {
        crate::formats::npy::NpyArray::from_bytes(bytes).map_err(|e| e.in_file(path))?
    };
    let recording = array.recording().map_err(|e| e.in_file(path))?;
    Ok(Loaded {
        recording,
        notes: npy_notes(path, &array),
        warnings: Vec::new(),
    })
}

/// A MIMU4444 stream, through `cal` (an 8-IMU table) or the nominal scales.
fn load_mimu(path: &Path, bytes: &[u8], cal: Option<&Calibration>) -> Result<Loaded> {
    let m = crate::formats::mimu::parse(bytes).map_err(|source| LoadError::Mimu {
        path: path.to_path_buf(),
        source,
    })?;
    let table = match cal {
        Some(Calibration::Mimu(t)) => Some(t.as_ref()),
        Some(Calibration::Board(_)) => {
            return Err(LoadError::refused(
                path,
                "a 16-group calibration cannot apply to the 8-IMU MIMU4444 array",
            ));
        }
        None => None,
    };
    let s = &m.stats;
    let notes = vec![format!(
        "MIMU4444 stream: {} frames, {:.1} s, {} bytes skipped, {} checksum failures, {} packets missing{}",
        m.frames.len(),
        m.duration_s(),
        s.bytes_skipped,
        s.checksum_failures,
        s.packets_missing,
        if table.is_none() {
            " (nominal scales, each IMU in its own frame)"
        } else {
            " (calibrated, cluster frame)"
        }
    )];
    let lost: Vec<String> = [
        (s.bytes_skipped as u64, "bytes skipped"),
        (s.checksum_failures as u64, "frames failed their checksum"),
        (s.packets_missing, "packets missing by number"),
    ]
    .iter()
    .filter(|(n, _)| *n > 0)
    .map(|(n, what)| format!("{n} {what}"))
    .collect();
    let warnings = if lost.is_empty() {
        Vec::new()
    } else {
        vec![format!(
            "{}: {}: those samples are not in the recording{}",
            path.display(),
            lost.join(", "),
            s.events
                .first()
                .map_or(String::new(), |e| format!(" (the first at {e})"))
        )]
    };
    Ok(Loaded {
        recording: mimu_recording(&m, table),
        notes,
        warnings,
    })
}

/// An FPGA frame log, through `cal` (a 16-group table) or the factory table.
fn load_frame_log(
    path: &Path,
    bytes: &[u8],
    cal: Option<&Calibration>,
    base_rate_millihz: u64,
) -> Result<Loaded> {
    let board = match cal {
        Some(Calibration::Board(t)) => Some(t.as_ref()),
        Some(Calibration::Mimu(_)) => {
            return Err(LoadError::refused(
                path,
                "an 8-IMU calibration cannot apply to our 16-group frames",
            ));
        }
        None => None,
    };
    let log = FrameLog::decode(bytes);
    if log.frames.is_empty() {
        return Err(LoadError::NoFrames {
            path: path.to_path_buf(),
            bytes: bytes.len(),
            crc_errors: log.counters.crc_errors,
        });
    }
    let factory = CalibrationTable::factory();
    let recording = log.to_recording(board.unwrap_or(&factory), base_rate_millihz);
    let c = log.counters;
    let notes = vec![format!(
        "frame log: {} frames, {} CRC errors, {} bytes skipped, {} frames missing by sequence{}",
        c.frames,
        c.crc_errors,
        c.bytes_skipped,
        c.frames_dropped,
        if board.is_none() {
            " (factory calibration)"
        } else {
            ""
        }
    )];
    let warnings = link_warning(path, &c, "recording").into_iter().collect();
    Ok(Loaded {
        recording,
        notes,
        warnings,
    })
}
