//! Noise-model simulator of the IMU cluster: per-sensor stochastic models with analytic Allan variances, cluster
//! effects (common mode, drift, temperature, outliers, spread between parts), and output as physical samples or
//! as raw FPGA frames through an inverse calibration.
//!
//! Layers, each usable alone:
//! - [`noise`]: one sensor axis. [`NoiseParams`] in physical units, [`NoiseModel`] with the exact analytic
//!   Allan variance of the synthesised process ([`expected_avar`]) next to the ideal IEEE 952 one, and
//!   [`SensorNoise`], a seeded streaming generator.
//! - [`cluster`]: [`SimConfig`] (16 groups × 7 raw channels, cluster effects) and the streaming [`Simulator`],
//!   which fills [`Chunk`]s with physical samples, raw ADC codes and FPGA frames.
//! - [`calib`]: the true per-group calibration ([`TrueGroupCal`]) applied inversely through
//!   `shared::calib::board::nominal_codes`, and its fixed-point form for the ground.
//! - [`preset`]: parameters reproducing the seed paper's single-sensor Tables 1 and 2.
//! - [`motion`]: coning and sculling motions of the board (true attitude, body rate, specific force).
//! - [`effects`]: cluster effects as typed values ([`Effects`], the board's [`TemperatureProfile`]) added to a
//!   [`SimConfig`] in one step.
//! - [`output`]: a simulation written as a frame log or an interchange CSV, or collected in memory as a
//!   `Recording`, through the outputs' bandwidths ([`Bandwidth`]); the rate and size checks of `ground simulate`.
//!
//! Units everywhere: gyro quantities in °/s (densities in (°/s)/√Hz etc.), accelerometer quantities in g, time in
//! s, temperature in °C. A *sensor* is one raw ADC channel of one group ([`Channel`]); an *axis* is one calibrated
//! output of a group ([`Axis`]). Each group has two z gyros (gyro A and gyro B), simulated independently.
//!
//! Reproducibility: every random process has its own xoshiro256++ stream derived from the seed and a fixed
//! process id, so the output depends on the seed only, not on the chunk size or on the order of calls.

pub mod calib;
pub mod cluster;
pub mod effects;
pub mod motion;
pub mod noise;
pub mod output;
pub mod preset;
#[cfg(test)]
mod tests;

pub use calib::{CalMatrices, CalSpread, TrueGroupCal};
pub use cluster::{
    Chunk, CommonDrift, CommonMode, DriftKind, FrameOpts, Outlier, PartSpread, Periodic,
    SensorOverride, SimConfig, Simulator, Thermal, csv_header,
};
pub use effects::{Effects, TemperatureProfile, ThermalCoef};
pub use noise::{
    AvarTerms, FlickerBand, FlickerMethod, NoiseModel, NoiseParams, Sampling, SensorNoise,
    expected_avar,
};
pub use output::Bandwidth;

use rand_xoshiro::rand_core::SeedableRng;
use rand_xoshiro::{SplitMix64, Xoshiro256PlusPlus};

/// Sensor groups simulated (all of the board's).
pub const GROUPS: usize = shared::wire::frame::GROUPS;
/// Raw channels per group.
pub const CHANNELS: usize = shared::wire::frame::RAW_PER_GROUP;

/// Why a configuration or a request was rejected.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum SimError {
    /// A parameter is out of its domain; the text names it and the rule.
    #[error("invalid simulation parameter: {0}")]
    Param(String),
    /// A matrix (true calibration) is singular or badly conditioned.
    #[error("singular matrix: {0}")]
    Singular(String),
    /// A command-line value (e.g. `--motion`) does not parse; the text names it and what was expected.
    #[error("{0}")]
    Syntax(String),
}

/// Returns `Err(SimError::Param)` unless `ok`.
pub(crate) fn check(ok: bool, what: impl FnOnce() -> String) -> Result<(), SimError> {
    if ok {
        Ok(())
    } else {
        Err(SimError::Param(what()))
    }
}

/// A calibrated output axis of a group: gyro in °/s, accelerometer in g.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Axis {
    /// Gyro x, °/s.
    GyroX,
    /// Gyro y, °/s.
    GyroY,
    /// Gyro z, °/s (from the two z sensors).
    GyroZ,
    /// Accelerometer x, g.
    AccelX,
    /// Accelerometer y, g.
    AccelY,
    /// Accelerometer z, g.
    AccelZ,
}

impl Axis {
    /// All axes in output order (`shared::calib::GX … AZ`).
    pub const ALL: [Axis; 6] = [
        Axis::GyroX,
        Axis::GyroY,
        Axis::GyroZ,
        Axis::AccelX,
        Axis::AccelY,
        Axis::AccelZ,
    ];

    /// Index in a group's output array (0..6, as `shared::calib::GX … AZ`).
    pub fn index(self) -> usize {
        self as usize
    }

    /// True for the gyro axes.
    pub fn is_gyro(self) -> bool {
        self.index() < 3
    }

    /// The raw channels that measure this axis (one, or two for gyro z).
    pub fn channels(self) -> &'static [Channel] {
        match self {
            Axis::GyroX => &[Channel::GyroAX],
            Axis::GyroY => &[Channel::GyroBY],
            Axis::GyroZ => &[Channel::GyroAZ, Channel::GyroBZ],
            Axis::AccelX => &[Channel::AccelX],
            Axis::AccelY => &[Channel::AccelY],
            Axis::AccelZ => &[Channel::AccelZ],
        }
    }

    /// Short name used in the interchange CSV (`gx`, …, `az`, without the group number).
    pub fn short(self) -> &'static str {
        ["gx", "gy", "gz", "ax", "ay", "az"][self.index()]
    }
}

/// A raw ADC channel of a group, in the FPGA frame's order (`shared::wire::frame::RAW_*`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Channel {
    /// Gyro A, x output (°/s).
    GyroAX,
    /// Gyro A, z output (°/s).
    GyroAZ,
    /// Gyro B, y output (°/s).
    GyroBY,
    /// Gyro B, z output, the redundant z (°/s).
    GyroBZ,
    /// Accelerometer x (g).
    AccelX,
    /// Accelerometer y (g).
    AccelY,
    /// Accelerometer z (g).
    AccelZ,
}

impl Channel {
    /// All channels in frame order.
    pub const ALL: [Channel; 7] = [
        Channel::GyroAX,
        Channel::GyroAZ,
        Channel::GyroBY,
        Channel::GyroBZ,
        Channel::AccelX,
        Channel::AccelY,
        Channel::AccelZ,
    ];

    /// Index in a frame group (`RAW_*`).
    pub fn index(self) -> usize {
        self as usize
    }

    /// The axis this channel measures.
    pub fn axis(self) -> Axis {
        match self {
            Channel::GyroAX => Axis::GyroX,
            Channel::GyroAZ | Channel::GyroBZ => Axis::GyroZ,
            Channel::GyroBY => Axis::GyroY,
            Channel::AccelX => Axis::AccelX,
            Channel::AccelY => Axis::AccelY,
            Channel::AccelZ => Axis::AccelZ,
        }
    }

    /// One ADC code step of the nominal chain in this channel's units: 0.00625 °/s for gyros, 62.5/300000 g ≈
    /// 208.3 µg for the accelerometer (from `shared::calib::board`).
    pub fn adc_step(self) -> f64 {
        use shared::calib::board as b;
        if self.axis().is_gyro() {
            b::ADC_UV_PER_COUNT / b::GYRO_UV_PER_DPS
        } else {
            b::ADC_UV_PER_COUNT / b::ACCEL_UV_PER_G
        }
    }
}

/// The random stream of process `id` under `seed`: xoshiro256++ seeded through SplitMix64 from a mix of both.
pub(crate) fn stream(seed: u64, id: u64) -> Xoshiro256PlusPlus {
    let mut sm =
        SplitMix64::seed_from_u64(seed ^ id.wrapping_add(1).wrapping_mul(0x9E37_79B9_7F4A_7C15));
    Xoshiro256PlusPlus::from_rng(&mut sm)
}

/// Seed of sub-process `id` under `seed` (for generators that derive their own streams).
pub(crate) fn subseed(seed: u64, id: u64) -> u64 {
    use rand_xoshiro::rand_core::Rng;
    stream(seed, id).next_u64()
}
