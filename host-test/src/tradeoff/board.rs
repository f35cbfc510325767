//! Board budgets (`data/boards/*.toml`): parts with count, mass and power from their data sheets; the MCU's power
//! computed from its data sheet's Run and Sleep currents and the duty cycle `mcu-bench` measured
//! (`docs/mcu-bench.json`) at the flight frame rate; the seed paper's battery figures as an implied mean power.

use super::{Checked, Figure, TradeoffError};
use serde::{Deserialize, Serialize};

/// The seed board with the Raspberry Pi (`data/boards/seed.toml`).
pub const SEED_TOML: &str = include_str!("../../../data/boards/seed.toml");
/// Our board with the STM32F405 (`data/boards/ours.toml`).
pub const OURS_TOML: &str = include_str!("../../../data/boards/ours.toml");
/// `mcu-bench`'s committed counts (`docs/mcu-bench.json`, checked against a fresh run by `.ci/run`).
pub const MCU_BENCH_JSON: &str = include_str!("../../../docs/mcu-bench.json");

/// One kind of part on a board.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Part {
    /// Name.
    pub name: String,
    /// How many.
    pub count: u32,
    /// Supply voltage, V (absent for a part that draws nothing, e.g. the PCB).
    pub supply_v: Option<Figure>,
    /// Supply current per part, mA.
    pub current_ma: Option<Figure>,
    /// Mass per part, g.
    pub mass_g: Option<Figure>,
}

/// The board's microcontroller, whose power follows from its work.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Mcu {
    /// Name.
    pub name: String,
    /// The `mcu-bench` configuration that flies (its `name` in `docs/mcu-bench.json`).
    pub bench_config: String,
    /// Core clock, MHz (must be the clock `mcu-bench` assumed).
    pub clock_mhz: Figure,
    /// Supply voltage, V.
    pub supply_v: Figure,
    /// Run-mode current at `clock_mhz`, mA.
    pub run_ma: Figure,
    /// Sleep-mode current at `clock_mhz`, mA.
    pub sleep_ma: Figure,
    /// Mass, g.
    pub mass_g: Figure,
}

/// A battery's figures: capacity, voltage and how long it lasted.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Battery {
    /// Capacity, mAh.
    pub capacity_mah: Figure,
    /// Voltage, V.
    pub voltage_v: Figure,
    /// Shortest run time quoted, h.
    pub hours_min: Figure,
    /// Longest run time quoted, h.
    pub hours_max: Figure,
}

/// A board file.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Board {
    /// Name.
    pub name: String,
    /// Short name for plots.
    pub short: String,
    /// The battery the board ran on, if known.
    pub battery: Option<Battery>,
    /// Parts of fixed power.
    #[serde(default)]
    pub part: Vec<Part>,
    /// The microcontroller, if the board has one.
    pub mcu: Option<Mcu>,
}

impl Part {
    /// The part's figures with their field names (each optional).
    fn figures(&self) -> [(&'static str, Option<&Figure>); 3] {
        [
            ("supply_v", self.supply_v.as_ref()),
            ("current_ma", self.current_ma.as_ref()),
            ("mass_g", self.mass_g.as_ref()),
        ]
    }
}

impl Mcu {
    /// The processor's figures with their field names.
    fn figures(&self) -> [(&'static str, &Figure); 5] {
        [
            ("clock_mhz", &self.clock_mhz),
            ("supply_v", &self.supply_v),
            ("run_ma", &self.run_ma),
            ("sleep_ma", &self.sleep_ma),
            ("mass_g", &self.mass_g),
        ]
    }
}

impl Battery {
    /// The battery's figures with their field names.
    fn figures(&self) -> [(&'static str, &Figure); 4] {
        [
            ("capacity_mah", &self.capacity_mah),
            ("voltage_v", &self.voltage_v),
            ("hours_min", &self.hours_min),
            ("hours_max", &self.hours_max),
        ]
    }
}

impl Board {
    /// Every figure of the board: the parts', the MCU's, the battery's.
    pub fn figures(&self) -> Vec<&Figure> {
        let parts = self
            .part
            .iter()
            .flat_map(|p| p.figures().into_iter().filter_map(|(_, f)| f));
        let mcu = self.mcu.iter().flat_map(|m| m.figures().map(|(_, f)| f));
        let battery = self
            .battery
            .iter()
            .flat_map(|b| b.figures().map(|(_, f)| f));
        parts.chain(mcu).chain(battery).collect()
    }

    /// How many of the board's figures were checked against a retrieved text.
    pub fn figures_checked(&self) -> Checked {
        Checked::of(self.figures())
    }

    /// Reads a board file (TOML text; `origin` names it in errors) and checks its figures.
    pub fn parse(text: &str, origin: &str) -> Result<Board, TradeoffError> {
        let b: Board = toml::from_str(text).map_err(|source| TradeoffError::Toml {
            origin: origin.to_owned(),
            source: Box::new(source),
        })?;
        for p in &b.part {
            for (field, f) in p.figures() {
                if let Some(f) = f {
                    f.check(origin, &format!("{}.{field}", p.name))?;
                }
            }
            if p.supply_v.is_some() != p.current_ma.is_some() {
                return Err(TradeoffError::Invalid {
                    origin: origin.to_owned(),
                    what: format!("{}: supply_v and current_ma go together", p.name),
                });
            }
        }
        if let Some(m) = &b.mcu {
            for (field, f) in m.figures() {
                f.check(origin, &format!("{}.{field}", m.name))?;
            }
        }
        if let Some(bat) = &b.battery {
            for (field, f) in bat.figures() {
                f.check(origin, &format!("battery.{field}"))?;
            }
        }
        Ok(b)
    }

    /// The built-in board `seed` or `ours`.
    pub fn builtin(name: &str) -> Option<Result<Board, TradeoffError>> {
        match name {
            "seed" => Some(Board::parse(SEED_TOML, "data/boards/seed.toml (built in)")),
            "ours" => Some(Board::parse(OURS_TOML, "data/boards/ours.toml (built in)")),
            _ => None,
        }
    }
}

/// One configuration of `mcu-bench`'s report.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct BenchConfig {
    /// Configuration name.
    pub name: String,
    /// Mean Cortex-M4 instructions per frame.
    pub instructions_per_frame: f64,
    /// The frame rate of the benchmark stream, frames/s.
    pub frame_rate_hz: f64,
}

/// `mcu-bench`'s report (`docs/mcu-bench.json`).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct Bench {
    /// The clock the percentages assume, Hz.
    pub mcu_hz: f64,
    /// Per configuration.
    pub configs: Vec<BenchConfig>,
}

impl Bench {
    /// Reads the report (`origin` names it in errors).
    pub fn parse(text: &str, origin: &str) -> Result<Bench, TradeoffError> {
        serde_json::from_str(text).map_err(|source| TradeoffError::Json {
            origin: origin.to_owned(),
            source,
        })
    }

    /// The committed report ([`MCU_BENCH_JSON`]).
    pub fn committed() -> Result<Bench, TradeoffError> {
        Bench::parse(MCU_BENCH_JSON, "docs/mcu-bench.json (built in)")
    }
}

/// The flight frame rate, frames/s: the FPGA's base rate over (N + 1) at the board's decimation
/// ([`shared::wire::clock::FLIGHT_DECIMATION`]).
pub fn flight_frame_rate_hz() -> f64 {
    crate::FPGA_BASE_RATE_HZ / (f64::from(shared::wire::clock::FLIGHT_DECIMATION) + 1.0)
}

/// One line of a budget.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Line {
    /// Part name.
    pub name: String,
    /// How many.
    pub count: u32,
    /// Power of all of them, W (0 for a part that draws nothing).
    pub power_w: f64,
    /// Mass of all of them, g (`None` if the file gives none).
    pub mass_g: Option<f64>,
    /// Every figure of the line was checked against a retrieved text.
    pub checked: bool,
}

/// The MCU's power, from its work.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct McuPower {
    /// Instructions per frame (`mcu-bench`, the flying configuration).
    pub instructions_per_frame: f64,
    /// Frame rate, frames/s.
    pub frame_rate_hz: f64,
    /// Clock, Hz.
    pub clock_hz: f64,
    /// Share of cycles in Run mode at one instruction per cycle (a lower bound: loads, multiplies, taken branches
    /// and wait states take more).
    pub duty: f64,
    /// Mean current, mA: duty × Run + (1 − duty) × Sleep.
    pub mean_ma: f64,
    /// Mean power, W.
    pub power_w: f64,
    /// The same with the core always in Run mode (no sleep between frames), W.
    pub always_run_w: f64,
}

/// A board's budget.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct Budget {
    /// Board name.
    pub name: String,
    /// Short name.
    pub short: String,
    /// The fixed-power parts (the MCU last, if any).
    pub lines: Vec<Line>,
    /// The MCU's power from its work.
    pub mcu: Option<McuPower>,
    /// Total power, W.
    pub power_w: f64,
    /// Total mass of the parts that give one, g.
    pub mass_g: f64,
    /// Parts without a mass.
    pub parts_without_mass: usize,
    /// How many of the board file's figures were checked against a retrieved text.
    pub figures_checked: Checked,
}

/// The figure's value, for a part with `Option` figures.
fn value(f: &Option<Figure>) -> Option<f64> {
    f.as_ref().map(|f| f.value)
}

/// A board's budget; the MCU's duty cycle from `bench` at `frame_rate_hz`.
pub fn budget(board: &Board, bench: &Bench, frame_rate_hz: f64) -> Result<Budget, TradeoffError> {
    let mut lines: Vec<Line> = board
        .part
        .iter()
        .map(|p| {
            let n = f64::from(p.count);
            let power_w = match (value(&p.supply_v), value(&p.current_ma)) {
                (Some(v), Some(i)) => n * v * i / 1000.0,
                _ => 0.0,
            };
            Line {
                name: p.name.clone(),
                count: p.count,
                power_w,
                mass_g: value(&p.mass_g).map(|m| n * m),
                checked: [&p.supply_v, &p.current_ma, &p.mass_g]
                    .iter()
                    .all(|f| f.as_ref().is_none_or(|f| f.checked)),
            }
        })
        .collect();
    let mcu = match &board.mcu {
        None => None,
        Some(m) => {
            let cfg = bench
                .configs
                .iter()
                .find(|c| c.name == m.bench_config)
                .ok_or_else(|| {
                    TradeoffError::Bench(format!(
                        "no configuration '{}' in mcu-bench's report",
                        m.bench_config
                    ))
                })?;
            let clock_hz = m.clock_mhz.value * 1e6;
            if (clock_hz / bench.mcu_hz - 1.0).abs() > 1e-9 {
                return Err(TradeoffError::Bench(format!(
                    "{} runs at {} MHz, mcu-bench's figures assume {} MHz",
                    m.name,
                    m.clock_mhz.value,
                    bench.mcu_hz / 1e6
                )));
            }
            if (cfg.frame_rate_hz / frame_rate_hz - 1.0).abs() > 1e-4 {
                return Err(TradeoffError::Bench(format!(
                    "mcu-bench counted at {} frames/s, the board flies at {frame_rate_hz} frames/s: rerun mcu-bench",
                    cfg.frame_rate_hz
                )));
            }
            let duty = cfg.instructions_per_frame * frame_rate_hz / clock_hz;
            if !(duty.is_finite() && duty > 0.0 && duty <= 1.0) {
                return Err(TradeoffError::Bench(format!(
                    "duty cycle {duty} from {} instructions per frame",
                    cfg.instructions_per_frame
                )));
            }
            let mean_ma = duty * m.run_ma.value + (1.0 - duty) * m.sleep_ma.value;
            let power = McuPower {
                instructions_per_frame: cfg.instructions_per_frame,
                frame_rate_hz,
                clock_hz,
                duty,
                mean_ma,
                power_w: m.supply_v.value * mean_ma / 1000.0,
                always_run_w: m.supply_v.value * m.run_ma.value / 1000.0,
            };
            lines.push(Line {
                name: m.name.clone(),
                count: 1,
                power_w: power.power_w,
                mass_g: Some(m.mass_g.value),
                checked: [&m.supply_v, &m.run_ma, &m.sleep_ma, &m.mass_g]
                    .iter()
                    .all(|f| f.checked),
            });
            Some(power)
        }
    };
    Ok(Budget {
        name: board.name.clone(),
        short: board.short.clone(),
        power_w: lines.iter().map(|l| l.power_w).sum(),
        mass_g: lines.iter().filter_map(|l| l.mass_g).sum(),
        parts_without_mass: lines.iter().filter(|l| l.mass_g.is_none()).count(),
        figures_checked: board.figures_checked(),
        lines,
        mcu,
    })
}

/// What a battery's figures imply: its energy and the mean power over the quoted run times.
#[derive(Clone, Debug, Serialize, PartialEq)]
pub struct BatteryCheck {
    /// Energy, Wh.
    pub energy_wh: f64,
    /// Mean power over the longest run time, W (the lower bound).
    pub power_min_w: f64,
    /// Mean power over the shortest run time, W.
    pub power_max_w: f64,
    /// The board's budget, W.
    pub budget_w: f64,
}

/// The battery's implied mean power against the budget; `None` if the board has no battery figures.
pub fn battery_check(board: &Board, budget: &Budget) -> Option<BatteryCheck> {
    let b = board.battery.as_ref()?;
    let energy_wh = b.capacity_mah.value * b.voltage_v.value / 1000.0;
    Some(BatteryCheck {
        energy_wh,
        power_min_w: energy_wh / b.hours_max.value,
        power_max_w: energy_wh / b.hours_min.value,
        budget_w: budget.power_w,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_flight_frame_rate_is_the_fpga_rate_over_sixteen() {
        assert!((flight_frame_rate_hz() - 9676.8 / 16.0).abs() < 1e-9);
    }

    #[test]
    fn budgets_match_a_hand_calculation_of_the_data_sheet_numbers() {
        let bench = Bench::committed().unwrap();
        let fps = flight_frame_rate_hz();
        // Seed board: the data files' numbers, typed here independently.
        let seed = Board::builtin("seed").unwrap().unwrap();
        let b = budget(&seed, &bench, fps).unwrap();
        let hand_w = 32.0 * 3.0 * 6.8e-3
            + 16.0 * 3.0 * 0.35e-3
            + 16.0 * 3.3 * 3.5e-3
            + 16.0 * 3.3 * 20.8e-3
            + 1.2 * 60e-3
            + 3.3 * 70e-3
            + 4.98 * 0.43;
        assert!(
            (b.power_w - hand_w).abs() < 1e-12,
            "{} vs {hand_w}",
            b.power_w
        );
        let hand_g = 32.0 * 0.05 + 16.0 * 0.05 + 16.0 * 0.1 + 16.0 * 0.1 + 0.5 + 0.4 + 45.0 + 29.6;
        assert!((b.mass_g - hand_g).abs() < 1e-9);
        assert!(b.mcu.is_none());
        // The paper's battery: 6.6 Ah × 5 V = 33 Wh over 4–5 h.
        let bat = battery_check(&seed, &b).unwrap();
        assert!((bat.energy_wh - 33.0).abs() < 1e-12);
        assert!((bat.power_min_w - 6.6).abs() < 1e-12 && (bat.power_max_w - 8.25).abs() < 1e-12);

        // Our board: the MCU's duty from the committed instruction count.
        let ours = Board::builtin("ours").unwrap().unwrap();
        let b = budget(&ours, &bench, fps).unwrap();
        let ipf = bench
            .configs
            .iter()
            .find(|c| c.name == "default (weighted, robust)")
            .unwrap()
            .instructions_per_frame;
        let duty = ipf * 604.8 / 168e6;
        let mcu_w = 3.3 * (duty * 87.0 + (1.0 - duty) * 59.0) / 1000.0;
        let m = b.mcu.as_ref().unwrap();
        assert!((m.duty - duty).abs() < 1e-12);
        assert!((m.power_w - mcu_w).abs() < 1e-12);
        let fixed = 32.0 * 3.0 * 6.8e-3
            + 16.0 * 3.0 * 0.35e-3
            + 16.0 * 3.3 * 3.5e-3
            + 16.0 * 3.3 * 20.8e-3
            + 1.2 * 60e-3;
        assert!((b.power_w - (fixed + mcu_w)).abs() < 1e-12);
        assert!(battery_check(&ours, &b).is_none());
    }

    #[test]
    fn a_stale_or_mismatched_bench_is_refused() {
        let ours = Board::builtin("ours").unwrap().unwrap();
        let mut bench = Bench::committed().unwrap();
        assert!(budget(&ours, &bench, 302.4).is_err(), "another frame rate");
        bench.mcu_hz = 84e6;
        assert!(
            budget(&ours, &bench, flight_frame_rate_hz()).is_err(),
            "another clock"
        );
        let mut bench = Bench::committed().unwrap();
        bench.configs.clear();
        assert!(
            budget(&ours, &bench, flight_frame_rate_hz()).is_err(),
            "no configuration"
        );
        assert!(Bench::parse("{", "t").is_err());
        assert!(Board::parse("name = 1", "t").is_err());
    }
}
