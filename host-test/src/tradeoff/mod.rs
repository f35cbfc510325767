//! `ground tradeoff`, the seed paper's Figures 9–10: the cluster placed among commercial IMUs by accuracy against
//! mass and against power. The catalogue ([`catalogue`], `data/imus.toml`) gives each IMU's figures with their
//! sources; the board budgets ([`board`], `data/boards/*.toml`) give our board's and the seed board's mass and power,
//! the MCU's power computed from the duty cycle `mcu-bench` measured; [`place`] gives the recording's own bias
//! instability and random walk with their 68 % intervals; [`render`] draws both figures and writes the Markdown and
//! JSON tables. Definitions and units: `docs/tradeoff.md`.

pub mod board;
pub mod catalogue;
pub mod place;
pub mod render;

use crate::recording::Recording;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// One figure of a data file: its value (unit in the field's name), where it comes from, whether it was checked
/// against a retrieved text, and a note (why not, or how it was derived).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Figure {
    /// The value, in the unit the field's name carries.
    pub value: f64,
    /// Document title, revision or date, table or page.
    pub source: String,
    /// Compared with a retrieved text of the source (or of a page quoting it; the note says which).
    pub checked: bool,
    /// How it was derived, or why it is unchecked.
    #[serde(default)]
    pub note: String,
}

impl Figure {
    /// Positive and finite, with a source; `origin` and `field` name it in the error.
    fn check(&self, origin: &str, field: &str) -> Result<(), TradeoffError> {
        let what = if !(self.value.is_finite() && self.value > 0.0) {
            format!("{field}: value {} is not positive and finite", self.value)
        } else if self.source.trim().is_empty() {
            format!("{field}: no source")
        } else {
            return Ok(());
        };
        Err(TradeoffError::Invalid {
            origin: origin.to_owned(),
            what,
        })
    }
}

/// Why the trade-off could not be made.
#[derive(Debug, thiserror::Error)]
pub enum TradeoffError {
    /// A data file could not be read.
    #[error("reading {}", path.display())]
    Read {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// A data file is not the TOML expected.
    #[error("{origin}")]
    Toml {
        /// The file.
        origin: String,
        /// The parser's message (line and column).
        #[source]
        source: Box<toml::de::Error>,
    },
    /// A figure is missing its source or is not a positive number.
    #[error("{origin}: {what}")]
    Invalid {
        /// The file.
        origin: String,
        /// What is wrong.
        what: String,
    },
    /// `mcu-bench`'s report is unreadable.
    #[error("{origin}")]
    Json {
        /// The file.
        origin: String,
        /// The cause.
        #[source]
        source: serde_json::Error,
    },
    /// `mcu-bench`'s report does not fit the board (configuration, clock or frame rate).
    #[error("mcu-bench: {0}")]
    Bench(String),
    /// The Allan analysis refused the recording.
    #[error(transparent)]
    Adev(#[from] crate::allan::recording::AdevError),
    /// The recording has no axis with a cluster and single sensors.
    #[error("the recording has no axis with both single sensors and a cluster mean to place")]
    NoAxis,
    /// A plot failed.
    #[error(transparent)]
    Plot(#[from] crate::plot::PlotError),
    /// An output could not be written.
    #[error("writing {}", path.display())]
    Write {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
}

/// Where the inputs come from: `None` = the built-in copy.
#[derive(Clone, Debug, Default)]
pub struct Inputs {
    /// A catalogue file instead of `data/imus.toml`.
    pub catalogue: Option<PathBuf>,
    /// Boards: `seed`, `ours` (built in) or TOML files; empty = both built-in boards.
    pub boards: Vec<String>,
    /// An `mcu-bench` report instead of `docs/mcu-bench.json`.
    pub mcu_bench: Option<PathBuf>,
}

fn read(path: &Path) -> Result<String, TradeoffError> {
    std::fs::read_to_string(path).map_err(|source| TradeoffError::Read {
        path: path.to_path_buf(),
        source,
    })
}

/// Everything `ground tradeoff` computes.
#[derive(Clone, Debug, Serialize)]
pub struct Tradeoff {
    /// What was placed (the recording's name).
    pub recording: String,
    /// The recording's figures.
    pub placement: place::Placement,
    /// The boards' budgets, in the order given.
    pub budgets: Vec<board::Budget>,
    /// What the boards' battery figures imply (board short name, check).
    pub batteries: Vec<(String, board::BatteryCheck)>,
    /// The catalogue.
    pub catalogue: Vec<catalogue::Imu>,
}

/// Computes the trade-off of `rec` (named `label`) on the boards of `inputs`.
pub fn compute(rec: &Recording, label: &str, inputs: &Inputs) -> Result<Tradeoff, TradeoffError> {
    let catalogue = match &inputs.catalogue {
        Some(p) => catalogue::parse(&read(p)?, &p.display().to_string())?,
        None => catalogue::default_catalogue()?,
    };
    let bench = match &inputs.mcu_bench {
        Some(p) => board::Bench::parse(&read(p)?, &p.display().to_string())?,
        None => board::Bench::committed()?,
    };
    let names: Vec<String> = if inputs.boards.is_empty() {
        vec!["seed".into(), "ours".into()]
    } else {
        inputs.boards.clone()
    };
    let fps = board::flight_frame_rate_hz();
    let mut budgets = Vec::new();
    let mut batteries = Vec::new();
    for name in &names {
        let b = match board::Board::builtin(name) {
            Some(b) => b?,
            None => board::Board::parse(&read(Path::new(name))?, name)?,
        };
        let budget = board::budget(&b, &bench, fps)?;
        if let Some(c) = board::battery_check(&b, &budget) {
            batteries.push((b.short.clone(), c));
        }
        budgets.push(budget);
    }
    Ok(Tradeoff {
        recording: label.to_owned(),
        placement: place::place(rec)?,
        budgets,
        batteries,
        catalogue,
    })
}

/// The files [`run`] writes into its folder.
pub const OUTPUTS: [&str; 4] = [
    "tradeoff_mass.png",
    "tradeoff_power.png",
    "tradeoff.md",
    "tradeoff.json",
];

/// Computes the trade-off and writes [`OUTPUTS`] into `out` (created if needed).
pub fn run(
    rec: &Recording,
    label: &str,
    inputs: &Inputs,
    out: &Path,
) -> Result<Tradeoff, TradeoffError> {
    let t = compute(rec, label, inputs)?;
    std::fs::create_dir_all(out).map_err(|source| TradeoffError::Write {
        path: out.to_path_buf(),
        source,
    })?;
    render::write_all(&t, out)?;
    Ok(t)
}
