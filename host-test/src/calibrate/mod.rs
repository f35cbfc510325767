//! Lab calibration of an IMU array into the project's calibration model (`shared::calib`, `docs/calibration.md`):
//! per group, gyro `ω = M_g·(raw_g − b_g)` (3×4) and accelerometer `a = M_a·(raw_a − b_a)` (3×3).
//!
//! Two procedures:
//!
//! * **Multi-position static calibration** of an array of 3-axis IMUs that share one rigid board (the MIMU4444
//!   recordings, [`crate::formats::mimu`]): [`detect_static`] finds the static poses, [`calibrate_static`] fits each
//!   accelerometer (bias + matrix so that the static specific force is 1 g: ellipsoid fit, then
//!   Levenberg–Marquardt; [`fit_magnitude`]), aligns all IMUs to one cluster frame (Wahba/Procrustes on the gravity
//!   directions, [`align_cluster`]), optionally refines everything jointly with a linear bias drift in time
//!   ([`refine_cluster`], the model that the warm-up in exp_6 needs), and takes gyro biases from the static
//!   intervals and gyro axes from the accelerometer's rotation (same die). The cluster frame is the frame of the
//!   reference IMU (IMU 1 by default): the rotation part of its calibration matrix is the identity.
//! * **Rate-table calibration** of our 16-group board ([`fit_rate_table`]): six orientations × {+Ω, −Ω, 0}.
//!
//! [`reestimate_biases`] keeps a calibration's matrices and re-estimates the biases from a new static record
//! (`--biases-only`); [`CalibrationFile`] is the readable form (`.json`, `.toml`) beside the table's encoded
//! `.bin` form; [`ResidualReport`] is the per-IMU summary.
//!
//! Units are in the names: `_g` (specific force, g), `_mg`, `_dps` (°/s), `_deg`, `_counts` (raw sensor counts),
//! `_s` (seconds). Matrices are row-major `[[f64; C]; 3]`, rows = calibrated axes x, y, z.

mod biases;
pub mod data;
mod detect;
mod file;
mod fit;
mod from_model;
pub mod linalg;
mod rate_table;
mod records;
mod report;
mod thermal;
pub mod weights;

pub use biases::{BiasMethod, BiasOptions, BiasUpdate, reestimate_biases};
pub use detect::{DetectOptions, StaticInterval, detect_static};
pub use file::{
    CALIBRATION_FORMAT, CalibrationFile, CalibrationMetadata, GroupCalF64, GroupThermalF64,
    ImuMetadata, ThermalChannelFits, ThermalFitMetadata, read_calibration, read_calibration_any,
    write_calibration,
};
pub use fit::{
    BiasModel, ClusterAlignment, ClusterFit, ImuCal, MagnitudeFit, StaticCalOptions,
    StaticCalibration, align_cluster, calibrate_static, fit_magnitude, refine_cluster,
};
pub use from_model::{FromModel, MAX_TAU_FRACTION, MODEL_RIDGE, from_model, model_covariance};
pub use rate_table::{
    AccelRecords, RateRecord, RateTableFit, RateTableOptions, UpAxis, fit_rate_table,
    fit_rate_table_group, standard_inputs, two_point,
};
pub use records::board_records;
pub use report::{ImuResidual, ResidualReport, static_residuals_mg};
pub use thermal::{ThermalFit, ThermalOptions, fit_thermal};

use std::path::PathBuf;

/// A 3-vector.
pub type Vec3 = [f64; 3];
/// A 3×3 matrix, row-major.
pub type Mat3 = [[f64; 3]; 3];

/// Why a calibration step failed.
#[derive(Debug, thiserror::Error)]
pub enum CalibError {
    /// An option is out of its domain.
    #[error("invalid option: {0}")]
    InvalidOption(&'static str),
    /// An input is NaN or infinite.
    #[error("non-finite input: {0}")]
    NonFinite(&'static str),
    /// Not enough static poses (or records) for the model.
    #[error("too few static poses: {found}, need at least {needed}")]
    TooFewPoses {
        /// Needed.
        needed: usize,
        /// Given.
        found: usize,
    },
    /// The poses (or records) do not determine the parameters (directions not spread, singular matrix).
    #[error("degenerate input: {0}")]
    Degenerate(&'static str),
    /// Inputs disagree on the number of IMUs / groups.
    #[error("{what}: expected {expected}, found {found}")]
    Count {
        /// What is counted.
        what: &'static str,
        /// Expected.
        expected: usize,
        /// Found.
        found: usize,
    },
    /// A value does not fit the fixed-point table (Q19.12 `i32`, or a bias beyond ±65536 counts).
    #[error("out of range: {0}")]
    OutOfRange(String),
    /// A thermal fit's record has no frame with a valid board temperature.
    #[error(
        "none of the {frames} frames carries a valid board temperature: a thermal fit needs a record with \
         the temperature (frame flag 'temperature valid')"
    )]
    NoTemperature {
        /// Frames in the record.
        frames: usize,
    },
    /// A thermal fit's record spans too little board temperature.
    #[error(
        "the record spans {:.2} °C of board temperature ({from_c:.2} … {to_c:.2} °C); a thermal fit needs at \
         least {needed_c} °C: record the still board over a temperature ramp or cycle",
        to_c - from_c
    )]
    TemperatureSpan {
        /// Lowest temperature, °C.
        from_c: f64,
        /// Highest temperature, °C.
        to_c: f64,
        /// Span needed, °C.
        needed_c: f64,
    },
    /// A calibration table failed to encode or decode.
    #[error("calibration table: {0:?} ({why})", why = table_error(.0))]
    Table(shared::calib::CalError),
    /// A file could not be read or written.
    #[error("{}: {source}", path.display())]
    Io {
        /// File.
        path: PathBuf,
        /// Cause.
        source: std::io::Error,
    },
    /// A file's contents could not be parsed (or written).
    #[error("{}: {message}", path.display())]
    Format {
        /// File.
        path: PathBuf,
        /// What went wrong.
        message: String,
    },
}

/// What a table error means.
fn table_error(e: &shared::calib::CalError) -> String {
    use shared::calib::CalError as E;
    match e {
        E::BufferTooSmall => "the output buffer is too small".into(),
        E::Truncated => "too short for a calibration table".into(),
        E::Crc => {
            "the CRC-32C does not match: the file is damaged or not a calibration table".into()
        }
        E::Version(v) => format!(
            "written by format version {v}, expected 1 or {}",
            shared::calib::CAL_FORMAT_VERSION
        ),
        E::GroupCount(n) => format!("a table of {n} groups"),
        E::Malformed => "the CRC matches but the contents do not parse".into(),
        E::BiasOutOfRange => "a bias beyond ±65536 counts".into(),
        E::WeightOutOfRange => {
            "a fixed fusion weight beyond ±1, or an axis whose weights do not sum to a positive value"
                .into()
        }
    }
}

impl From<shared::calib::CalError> for CalibError {
    fn from(e: shared::calib::CalError) -> Self {
        Self::Table(e)
    }
}

#[cfg(test)]
mod tests;
