//! Readable calibration files and the table's binary form.
//!
//! [`CalibrationFile`] holds a calibration in `f64` physical units: matrices in °/s per count (gyro, 3×4) and
//! g per count (accelerometer, 3×3), biases in counts, `cal_id`, the raw rails, and optional metadata (per-IMU
//! rotation into the cluster frame, bias drifts, residuals). It is written as `.json` or `.toml`; `.bin` is the
//! postcard form of `shared::calib::CalibrationTable::encode` (with CRC, no metadata). [`read_calibration`] and
//! [`write_calibration`] choose the form by the file extension.
//!
//! Conversion to the table (Q19.12): gyro entries × 10⁶ (µ°/s per count), accelerometer entries × 10⁶ (µg per
//! count), biases in counts, all × 2¹² and rounded to nearest; a value outside `i32` or a bias beyond ±65536
//! counts is an [`CalibError::OutOfRange`].
//!
//! Thermal terms ([`GroupThermalF64`], about [`CalibrationFile::t_ref_c`]): linear coefficients in counts/°C go to
//! counts per 0.01 °C × 2²⁸ (Q28), quadratic ones in counts/°C² to counts per (0.01 °C)² × 2⁴⁰ (Q40), the reference
//! temperature to 0.01 °C (`i16`); fixed fusion weights × 2¹⁶ (Q16, |w| ≤ 1, a positive sum per axis). All rounded
//! to nearest; anything that does not fit is an [`CalibError::OutOfRange`] naming the value.

use std::path::Path;

use serde::{Deserialize, Serialize};
use shared::calib::{
    ACCEL_RAW, AXES, BIAS_LIMIT_Q12, CalError, CalibrationTable, FRAC_BITS, GYRO_RAW, GroupCal,
    GroupThermal, WEIGHT_LIMIT_Q16, encoded_len_max,
};

use super::fit::{BiasModel, StaticCalibration};
use super::report::ImuResidual;
use super::{CalibError, Mat3, Vec3};

/// Value of [`CalibrationFile::format`].
pub const CALIBRATION_FORMAT: &str = "imu-calibration/1";

const Q: f64 = (1u32 << FRAC_BITS) as f64;

/// One group's calibration in physical units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct GroupCalF64 {
    /// Gyro matrix, °/s per count; rows x, y, z; columns = raw gyro channels (MIMU4444: x, y, z, unused).
    pub gyro_matrix_dps_per_count: [[f64; GYRO_RAW]; 3],
    /// Gyro bias per raw channel, counts.
    pub gyro_bias_counts: [f64; GYRO_RAW],
    /// Accelerometer matrix, g per count.
    pub accel_matrix_g_per_count: Mat3,
    /// Accelerometer bias, counts.
    pub accel_bias_counts: Vec3,
}

/// Temperature dependence of one group's raw-channel biases in physical units: the bias at board temperature `T`
/// is `b + lin·(T − t_ref) + quad·(T − t_ref)²` counts (`CalibrationFile::t_ref_c`; table: `GroupThermal`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct GroupThermalF64 {
    /// Linear coefficient per raw gyro channel (frame order A x, A z, B y, B z), counts/°C.
    pub gyro_lin_counts_per_c: [f64; GYRO_RAW],
    /// Quadratic coefficient per raw gyro channel, counts/°C².
    pub gyro_quad_counts_per_c2: [f64; GYRO_RAW],
    /// Linear coefficient per raw accelerometer channel (x, y, z), counts/°C.
    pub accel_lin_counts_per_c: [f64; ACCEL_RAW],
    /// Quadratic coefficient per raw accelerometer channel, counts/°C².
    pub accel_quad_counts_per_c2: [f64; ACCEL_RAW],
}

/// Metadata of a thermal fit (`ground calibrate --thermal`): where it comes from and how well it is determined.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThermalFitMetadata {
    /// The record fitted (free text, e.g. its path).
    pub source: String,
    /// Lowest and highest board temperature of the record, °C.
    pub temp_range_c: [f64; 2],
    /// Samples fitted.
    pub samples: usize,
    /// Per group, per raw channel in frame order (4 gyro, 3 accelerometer).
    pub groups: Vec<ThermalChannelFits>,
}

/// Per raw channel of a group (frame order): the fit's standard errors, residual RMS and intercept.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ThermalChannelFits {
    /// Standard error of the linear coefficient, counts/°C.
    pub lin_se_counts_per_c: [f64; 7],
    /// Standard error of the quadratic coefficient, counts/°C².
    pub quad_se_counts_per_c2: [f64; 7],
    /// RMS of the residuals, counts.
    pub residual_rms_counts: [f64; 7],
    /// The fitted code at the reference temperature, counts (bias + the still board's true input).
    pub intercept_counts: [f64; 7],
}

/// Metadata of one IMU of a static calibration.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct ImuMetadata {
    /// Rotation of the IMU's frame into the cluster frame.
    pub rotation_to_cluster: Mat3,
    /// Accelerometer bias drift during the calibration record, counts per second.
    pub accel_bias_drift_counts_per_s: Vec3,
    /// Gyro bias drift during the calibration record, counts per second.
    pub gyro_bias_drift_counts_per_s: Vec3,
    /// Residuals on the calibration poses.
    pub residual: ImuResidual,
}

/// Metadata of a static calibration.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationMetadata {
    /// Where the calibration comes from (free text, e.g. the record's path).
    pub source: String,
    /// Index of the IMU whose frame is the cluster frame (0 = IMU 1).
    pub reference_imu: usize,
    /// Accelerometer bias model of the fit.
    pub bias_model: BiasModel,
    /// Time of the record at which the biases hold, seconds.
    pub t_ref_s: f64,
    /// Static poses used.
    pub poses: usize,
    /// Later changes (e.g. biases re-estimated).
    #[serde(default)]
    pub history: Vec<String>,
    /// Per IMU.
    pub imus: Vec<ImuMetadata>,
}

/// A calibration in physical units (see the module docs).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CalibrationFile {
    /// [`CALIBRATION_FORMAT`].
    pub format: String,
    /// Identifier (0 = factory).
    pub cal_id: u32,
    /// Lowest raw reading that is not saturated.
    pub raw_min: i32,
    /// Highest raw reading that is not saturated.
    pub raw_max: i32,
    /// Per group / IMU.
    pub groups: Vec<GroupCalF64>,
    /// Metadata (absent in files read from `.bin`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub metadata: Option<CalibrationMetadata>,
    /// Board temperature at which the biases hold, °C (the reference of `thermal`; 0 when unknown).
    #[serde(default)]
    pub t_ref_c: f64,
    /// Per-group thermal terms of the biases (`None`: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal: Option<Vec<GroupThermalF64>>,
    /// Fixed fusion weights per group and axis (gx gy gz ax ay az), each within ±1 (`None`: none).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub weights: Option<Vec<[f64; AXES]>>,
    /// How the thermal terms were fitted (absent in files read from `.bin`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub thermal_fit: Option<ThermalFitMetadata>,
}

/// `x · scale · 2^bits` rounded to nearest as `i32` (`x` in the file's `unit`, `scale` the table's units per file
/// unit), or an [`CalibError::OutOfRange`] naming `what` in the file's unit.
fn fixed(x: f64, scale: f64, bits: u32, what: &str, unit: &str) -> Result<i32, CalibError> {
    let v = (x * scale * f64::from(bits).exp2()).round();
    if v.is_finite() && v >= f64::from(i32::MIN) && v <= f64::from(i32::MAX) {
        Ok(v as i32)
    } else {
        Err(CalibError::OutOfRange(format!(
            "{what} = {x} {unit} does not fit the table (Q{bits} in i32: |x| < {:.4} {unit})",
            f64::from(i32::MAX) / f64::from(bits).exp2() / scale
        )))
    }
}

impl GroupThermalF64 {
    /// To the table's form (Q28 per 0.01 °C, Q40 per (0.01 °C)²).
    pub fn to_fixed(&self) -> Result<GroupThermal, CalibError> {
        let lin = |x: f64, what: &str| fixed(x, 1e-2, 28, what, "counts/°C");
        let quad = |x: f64, what: &str| fixed(x, 1e-4, 40, what, "counts/°C²");
        let mut t = GroupThermal::ZERO;
        for c in 0..GYRO_RAW {
            t.gyro_lin_q28[c] = lin(self.gyro_lin_counts_per_c[c], "gyro thermal linear")?;
            t.gyro_quad_q40[c] = quad(self.gyro_quad_counts_per_c2[c], "gyro thermal quadratic")?;
        }
        for c in 0..ACCEL_RAW {
            t.accel_lin_q28[c] = lin(self.accel_lin_counts_per_c[c], "accel thermal linear")?;
            t.accel_quad_q40[c] =
                quad(self.accel_quad_counts_per_c2[c], "accel thermal quadratic")?;
        }
        Ok(t)
    }

    /// From the table's form.
    pub fn from_fixed(t: &GroupThermal) -> Self {
        let lin = |v: i32| f64::from(v) / 28f64.exp2() * 100.0;
        let quad = |v: i32| f64::from(v) / 40f64.exp2() * 1e4;
        Self {
            gyro_lin_counts_per_c: t.gyro_lin_q28.map(lin),
            gyro_quad_counts_per_c2: t.gyro_quad_q40.map(quad),
            accel_lin_counts_per_c: t.accel_lin_q28.map(lin),
            accel_quad_counts_per_c2: t.accel_quad_q40.map(quad),
        }
    }
}

/// The reference temperature in 0.01 °C, or an [`CalibError::OutOfRange`].
fn t_ref_cdeg(t_ref_c: f64) -> Result<i16, CalibError> {
    let v = (t_ref_c * 100.0).round();
    if v.is_finite() && v >= f64::from(i16::MIN) && v <= f64::from(i16::MAX) {
        Ok(v as i16)
    } else {
        Err(CalibError::OutOfRange(format!(
            "reference temperature t_ref_c = {t_ref_c} °C does not fit the table (0.01 °C in i16: ±327.67 °C)"
        )))
    }
}

/// Weights in Q16, checked as the table's decoder checks them (|w| ≤ 1, a positive sum per axis).
fn weights_q16(w: &[[f64; AXES]]) -> Result<Vec<[i32; AXES]>, CalibError> {
    let mut out = Vec::with_capacity(w.len());
    let mut sums = [0i64; AXES];
    for (g, row) in w.iter().enumerate() {
        let mut q = [0; AXES];
        for (a, (&x, slot)) in row.iter().zip(&mut q).enumerate() {
            *slot = fixed(x, 1.0, 16, &format!("weight of group {g} axis {a}"), "")?;
            if slot.unsigned_abs() > WEIGHT_LIMIT_Q16 as u32 {
                return Err(CalibError::OutOfRange(format!(
                    "weight of group {g} axis {a} = {x} is beyond ±1"
                )));
            }
            sums[a] += i64::from(*slot);
        }
        out.push(q);
    }
    if let Some(a) = sums.iter().position(|&s| s <= 0) {
        return Err(CalibError::OutOfRange(format!(
            "the weights of axis {a} sum to {} (must be positive)",
            sums[a] as f64 / 65536.0
        )));
    }
    Ok(out)
}

fn q12(x: f64, what: &str) -> Result<i32, CalibError> {
    let v = (x * Q).round();
    if v.is_finite() && v >= f64::from(i32::MIN) && v <= f64::from(i32::MAX) {
        Ok(v as i32)
    } else {
        Err(CalibError::OutOfRange(format!(
            "{what} = {x} does not fit Q19.12"
        )))
    }
}

fn bias_q12(x: f64, what: &str) -> Result<i32, CalibError> {
    let v = q12(x, what)?;
    if v.unsigned_abs() > BIAS_LIMIT_Q12 as u32 {
        return Err(CalibError::OutOfRange(format!(
            "{what} = {x} counts is beyond ±65536 counts"
        )));
    }
    Ok(v)
}

impl GroupCalF64 {
    /// To the fixed-point form.
    pub fn to_q12(&self) -> Result<GroupCal, CalibError> {
        let mut g = GroupCal::default();
        for r in 0..3 {
            for c in 0..GYRO_RAW {
                g.gyro_matrix_q12[r][c] = q12(
                    self.gyro_matrix_dps_per_count[r][c] * 1e6,
                    "gyro matrix (µ°/s per count)",
                )?;
            }
            for c in 0..ACCEL_RAW {
                g.accel_matrix_q12[r][c] = q12(
                    self.accel_matrix_g_per_count[r][c] * 1e6,
                    "accelerometer matrix (µg per count)",
                )?;
            }
        }
        for c in 0..GYRO_RAW {
            g.gyro_bias_q12[c] = bias_q12(self.gyro_bias_counts[c], "gyro bias")?;
        }
        for c in 0..ACCEL_RAW {
            g.accel_bias_q12[c] = bias_q12(self.accel_bias_counts[c], "accelerometer bias")?;
        }
        Ok(g)
    }

    /// From the fixed-point form.
    pub fn from_q12(g: &GroupCal) -> Self {
        let f = |v: i32| f64::from(v) / Q;
        Self {
            gyro_matrix_dps_per_count: g.gyro_matrix_q12.map(|row| row.map(|v| f(v) * 1e-6)),
            gyro_bias_counts: g.gyro_bias_q12.map(f),
            accel_matrix_g_per_count: g.accel_matrix_q12.map(|row| row.map(|v| f(v) * 1e-6)),
            accel_bias_counts: g.accel_bias_q12.map(f),
        }
    }
}

fn check_count(what: &'static str, expected: usize, found: usize) -> Result<(), CalibError> {
    if expected == found {
        Ok(())
    } else {
        Err(CalibError::Count {
            what,
            expected,
            found,
        })
    }
}

fn format_err(path: &Path, message: impl ToString) -> CalibError {
    CalibError::Format {
        path: path.to_path_buf(),
        message: message.to_string(),
    }
}

impl CalibrationFile {
    /// The fixed-point table; the number of groups must be `G`.
    pub fn to_table<const G: usize>(&self) -> Result<CalibrationTable<G>, CalibError> {
        if self.groups.len() != G {
            return Err(CalibError::Count {
                what: "groups",
                expected: G,
                found: self.groups.len(),
            });
        }
        let mut table = CalibrationTable::<G>::factory();
        for (g, f) in table.groups.iter_mut().zip(&self.groups) {
            *g = f.to_q12()?;
        }
        (table.cal_id, table.raw_min, table.raw_max) = (self.cal_id, self.raw_min, self.raw_max);
        table.t_ref_cdeg = t_ref_cdeg(self.t_ref_c)?;
        if let Some(th) = &self.thermal {
            check_count("groups of the thermal terms", G, th.len())?;
            for (t, f) in table.thermal.iter_mut().zip(th) {
                *t = f.to_fixed()?;
            }
        }
        if let Some(w) = &self.weights {
            check_count("groups of the weights", G, w.len())?;
            table.weights_q16.copy_from_slice(&weights_q16(w)?);
        }
        Ok(table)
    }

    /// A calibration of `groups` and nothing else: no metadata, thermal terms, weights or thermal fit (`t_ref_c` 0).
    pub fn new(cal_id: u32, raw_min: i32, raw_max: i32, groups: Vec<GroupCalF64>) -> Self {
        Self {
            format: CALIBRATION_FORMAT.to_string(),
            cal_id,
            raw_min,
            raw_max,
            groups,
            metadata: None,
            t_ref_c: 0.0,
            thermal: None,
            weights: None,
            thermal_fit: None,
        }
    }

    /// From a fixed-point table (no metadata; thermal terms and weights when the table has them).
    pub fn from_table<const G: usize>(t: &CalibrationTable<G>) -> Self {
        Self {
            format: CALIBRATION_FORMAT.to_string(),
            cal_id: t.cal_id,
            raw_min: t.raw_min,
            raw_max: t.raw_max,
            groups: t.groups.iter().map(GroupCalF64::from_q12).collect(),
            metadata: None,
            t_ref_c: f64::from(t.t_ref_cdeg) / 100.0,
            thermal: t
                .has_thermal()
                .then(|| t.thermal.iter().map(GroupThermalF64::from_fixed).collect()),
            weights: t.has_weights().then(|| {
                t.weights_q16
                    .iter()
                    .map(|w| w.map(|x| f64::from(x) / 65536.0))
                    .collect()
            }),
            thermal_fit: None,
        }
    }

    /// Checks that the reference temperature, thermal terms and weights fit the table (whatever the group count).
    fn check_extras(&self) -> Result<(), CalibError> {
        t_ref_cdeg(self.t_ref_c)?;
        let n = self.groups.len();
        if let Some(th) = &self.thermal {
            check_count("groups of the thermal terms", n, th.len())?;
            for t in th {
                t.to_fixed()?;
            }
        }
        if let Some(w) = &self.weights {
            check_count("groups of the weights", n, w.len())?;
            weights_q16(w)?;
        }
        Ok(())
    }

    /// Pretty JSON.
    pub fn to_json(&self) -> Result<String, CalibError> {
        serde_json::to_string_pretty(self).map_err(|e| format_err(Path::new("<json>"), e))
    }

    /// From JSON.
    pub fn from_json(s: &str) -> Result<Self, CalibError> {
        serde_json::from_str(s).map_err(|e| format_err(Path::new("<json>"), e))
    }

    /// TOML.
    pub fn to_toml(&self) -> Result<String, CalibError> {
        toml::to_string(self).map_err(|e| format_err(Path::new("<toml>"), e))
    }

    /// From TOML.
    pub fn from_toml(s: &str) -> Result<Self, CalibError> {
        toml::from_str(s).map_err(|e| format_err(Path::new("<toml>"), e))
    }

    /// The table's encoded form (`CalibrationTable::encode`, with CRC).
    pub fn to_bin<const G: usize>(&self) -> Result<Vec<u8>, CalibError> {
        let t = self.to_table::<G>()?;
        let mut buf = vec![0u8; encoded_len_max(G)];
        Ok(t.encode(&mut buf)?.to_vec())
    }

    /// From the table's encoded form (`CalibrationTable::decode`: CRC, version, group count, bias range).
    pub fn from_bin<const G: usize>(bytes: &[u8]) -> Result<Self, CalibError> {
        Ok(Self::from_table(&CalibrationTable::<G>::decode(bytes)?))
    }
}

enum Kind {
    Json,
    Toml,
    Bin,
}

fn kind(path: &Path) -> Result<Kind, CalibError> {
    match path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase)
        .as_deref()
    {
        Some("json") => Ok(Kind::Json),
        Some("toml") => Ok(Kind::Toml),
        Some("bin") => Ok(Kind::Bin),
        _ => Err(format_err(
            path,
            "unknown calibration file extension (use .json, .toml or .bin)",
        )),
    }
}

/// Reads `path` by its extension; `.bin` through `bin`. No checks beyond the syntax.
fn parse_file(
    path: &Path,
    bin: impl FnOnce(&[u8]) -> Result<CalibrationFile, CalibError>,
) -> Result<CalibrationFile, CalibError> {
    let kind = kind(path)?;
    let bytes = std::fs::read(path).map_err(|source| CalibError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    let text = || std::str::from_utf8(&bytes).map_err(|e| format_err(path, e));
    Ok(match kind {
        Kind::Json => serde_json::from_str(text()?).map_err(|e| format_err(path, e))?,
        Kind::Toml => toml::from_str(text()?).map_err(|e| format_err(path, e))?,
        Kind::Bin => bin(&bytes).map_err(|e| format_err(path, e))?,
    })
}

/// The checks of a read file beyond its group count: format, rails, every value representable in the table.
fn check_file(path: &Path, file: &CalibrationFile) -> Result<(), CalibError> {
    if file.format != CALIBRATION_FORMAT {
        return Err(format_err(
            path,
            format!("format {:?}, expected {CALIBRATION_FORMAT:?}", file.format),
        ));
    }
    if file.raw_min >= file.raw_max {
        return Err(format_err(
            path,
            format!(
                "raw_min = {} is not below raw_max = {}: every reading would count as saturated",
                file.raw_min, file.raw_max
            ),
        ));
    }
    for (i, g) in file.groups.iter().enumerate() {
        g.to_q12()
            .map_err(|e| format_err(path, format!("group {i}: {e}")))?;
    }
    file.check_extras().map_err(|e| format_err(path, e))
}

/// Reads a calibration of `G` groups from `.json`, `.toml` or `.bin` (by extension).
pub fn read_calibration<const G: usize>(
    path: impl AsRef<Path>,
) -> Result<CalibrationFile, CalibError> {
    let path = path.as_ref();
    let file = parse_file(path, |b| match CalibrationFile::from_bin::<G>(b) {
        Err(CalibError::Table(CalError::GroupCount(n))) => Err(CalibError::Count {
            what: "groups of the table",
            expected: G,
            found: usize::from(n),
        }),
        r => r,
    })?;
    if file.groups.len() != G {
        return Err(format_err(
            path,
            format!("{} groups, expected {G}", file.groups.len()),
        ));
    }
    check_file(path, &file)?;
    Ok(file)
}

/// Reads a calibration of either array (16 groups: our board; 8: the MIMU4444) from `.json`, `.toml` or `.bin`,
/// checked as [`read_calibration`] checks it; any other number of groups is an error saying so.
pub fn read_calibration_any(path: impl AsRef<Path>) -> Result<CalibrationFile, CalibError> {
    const BOARD: usize = shared::wire::frame::GROUPS;
    const MIMU: usize = crate::formats::mimu::IMUS;
    let path = path.as_ref();
    let file = parse_file(path, |b| match CalibrationFile::from_bin::<BOARD>(b) {
        Err(CalibError::Table(CalError::GroupCount(n))) if usize::from(n) == MIMU => {
            CalibrationFile::from_bin::<MIMU>(b)
        }
        Err(CalibError::Table(CalError::GroupCount(n))) => Err(CalibError::Count {
            what: "groups of the table",
            expected: BOARD,
            found: usize::from(n),
        }),
        r => r,
    })?;
    let n = file.groups.len();
    if n != BOARD && n != MIMU {
        return Err(format_err(
            path,
            format!("{n} groups, expected {BOARD} (our board) or {MIMU} (the MIMU4444 array)"),
        ));
    }
    check_file(path, &file)?;
    Ok(file)
}

/// Writes a calibration of `G` groups as `.json`, `.toml` or `.bin` (by extension; `.bin` drops the metadata).
pub fn write_calibration<const G: usize>(
    file: &CalibrationFile,
    path: impl AsRef<Path>,
) -> Result<(), CalibError> {
    let path = path.as_ref();
    if file.groups.len() != G {
        return Err(CalibError::Count {
            what: "groups",
            expected: G,
            found: file.groups.len(),
        });
    }
    let bytes = match kind(path)? {
        Kind::Json => file.to_json()?.into_bytes(),
        Kind::Toml => file.to_toml()?.into_bytes(),
        Kind::Bin => file.to_bin::<G>()?,
    };
    std::fs::write(path, bytes).map_err(|source| CalibError::Io {
        path: path.to_path_buf(),
        source,
    })
}

impl StaticCalibration {
    /// The fixed-point table of `G` groups (`G` = the number of IMUs), via [`Self::to_file`].
    pub fn to_table<const G: usize>(&self, cal_id: u32) -> Result<CalibrationTable<G>, CalibError> {
        self.to_file(cal_id, "").to_table()
    }

    /// The readable form: gyro raw channels `[x, y, z, unused]` (4th column and bias 0), rails of `i16` words
    /// (a reading of −32768 or 32767 is saturated), metadata from the fit. `source` is free text.
    pub fn to_file(&self, cal_id: u32, source: &str) -> CalibrationFile {
        let groups = self
            .imus
            .iter()
            .map(|c| GroupCalF64 {
                gyro_matrix_dps_per_count: c
                    .gyro_matrix_dps_per_count
                    .map(|r| [r[0], r[1], r[2], 0.0]),
                gyro_bias_counts: [
                    c.gyro_bias_counts[0],
                    c.gyro_bias_counts[1],
                    c.gyro_bias_counts[2],
                    0.0,
                ],
                accel_matrix_g_per_count: c.accel_matrix_g_per_count,
                accel_bias_counts: c.accel_bias_counts,
            })
            .collect();
        let bias_model = if self.options.refine {
            self.options.bias_model
        } else {
            BiasModel::Constant
        };
        CalibrationFile {
            metadata: Some(CalibrationMetadata {
                source: source.to_string(),
                reference_imu: self.options.reference_imu,
                bias_model,
                t_ref_s: self.t_ref_s,
                poses: self.report.poses,
                history: Vec::new(),
                imus: self
                    .imus
                    .iter()
                    .zip(&self.report.imus)
                    .map(|(c, r)| ImuMetadata {
                        rotation_to_cluster: c.rotation,
                        accel_bias_drift_counts_per_s: c.accel_bias_drift_counts_per_s,
                        gyro_bias_drift_counts_per_s: c.gyro_bias_drift_counts_per_s,
                        residual: *r,
                    })
                    .collect(),
            }),
            ..CalibrationFile::new(cal_id, i32::from(i16::MIN), i32::from(i16::MAX), groups)
        }
    }
}
