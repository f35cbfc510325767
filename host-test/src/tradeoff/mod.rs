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

/// How many figures of a data file were checked against a retrieved text (`ground tradeoff` prints it; the test
/// `tradeoff::tests::the_docs_state_the_checked_counts` holds `docs/tradeoff.md` to it).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct Checked {
    /// Figures with `checked = true`.
    pub checked: usize,
    /// All figures.
    pub total: usize,
}

impl Checked {
    /// Counts `figures`.
    pub fn of<'a>(figures: impl IntoIterator<Item = &'a Figure>) -> Checked {
        figures
            .into_iter()
            .fold(Checked::default(), |c, f| Checked {
                checked: c.checked + usize::from(f.checked),
                total: c.total + 1,
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
    /// How many of the catalogue's figures were checked against a retrieved text.
    pub catalogue_checked: Checked,
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
        catalogue_checked: catalogue::checked(&catalogue),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The counts of `checked = true` figures that docs/tradeoff.md states are the data files' own: the sentence
    /// goes stale whenever a figure is checked, added or removed, and this test then fails.
    #[test]
    fn the_docs_state_the_checked_counts() {
        let doc = include_str!("../../../docs/tradeoff.md");
        let cat = catalogue::checked(&catalogue::default_catalogue().unwrap());
        let board = |name: &str| {
            board::Board::builtin(name)
                .unwrap()
                .unwrap()
                .figures_checked()
        };
        let (seed, ours) = (board("seed"), board("ours"));
        // An independent count: the TOML texts' own inline `, checked = …` entries (the header comments, which
        // mention `checked = true`, are not preceded by a comma).
        for (text, c) in [
            (catalogue::DEFAULT_TOML, cat),
            (board::SEED_TOML, seed),
            (board::OURS_TOML, ours),
        ] {
            assert_eq!(c.checked, text.matches(", checked = true,").count());
            assert_eq!(c.total, text.matches(", checked = ").count());
            assert!(c.total > c.checked);
        }
        for (phrase, c) in [
            ("of the catalogue's", cat),
            ("of the seed board's", seed),
            ("of our board's", ours),
        ] {
            assert_eq!(
                stated(doc, phrase),
                [(c.checked, c.total)],
                "docs/tradeoff.md should say '{} {phrase} {} figures' (once)",
                c.checked,
                c.total
            );
        }
    }

    /// Every "N {phrase} M figures" of `text`, as (N, M).
    fn stated(text: &str, phrase: &str) -> Vec<(usize, usize)> {
        text.match_indices(phrase)
            .filter_map(|(i, _)| {
                let before = text.get(..i)?.trim_end();
                let n = before.rsplit(|c: char| !c.is_ascii_digit()).next()?;
                let after = text.get(i + phrase.len()..)?.trim_start();
                let m = after.split(|c: char| !c.is_ascii_digit()).next()?;
                let rest = after.get(m.len()..)?;
                rest.trim_start()
                    .starts_with("figures")
                    .then_some((n.parse().ok()?, m.parse().ok()?))
            })
            .collect()
    }

    #[test]
    fn stated_counts_are_read_from_the_sentence() {
        let t = "the makers of the catalogue's parts; 14 of the catalogue's 41 figures; 3 of the catalogue's 9\nfigures";
        assert_eq!(stated(t, "of the catalogue's"), [(14, 41), (3, 9)]);
        assert!(stated("of the catalogue's 41 figures", "of the catalogue's").is_empty());
    }

    #[test]
    fn checked_counts_each_figure_once() {
        let f = |checked| Figure {
            value: 1.0,
            source: "s".into(),
            checked,
            note: String::new(),
        };
        let figs = [f(true), f(false), f(true), f(false), f(false)];
        assert_eq!(
            Checked::of(&figs),
            Checked {
                checked: 2,
                total: 5
            }
        );
        assert_eq!(Checked::of(&[]), Checked::default());
    }
}
