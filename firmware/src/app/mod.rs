//! The application, independent of the board: every loop is generic over `embedded_io_async::{Read, Write}`,
//! `embedded_hal::digital::OutputPin` and `embedded_storage::nor_flash::NorFlash`, and shares one [`App`], so the
//! same code runs on the STM32F405 (spawned as embassy tasks by `main.rs`) and on the PC (`crate::sim`: the SITL
//! binary and the scenario tests). All processing is `shared::Pipeline`'s; these loops only move bytes and messages:
//!
//! ```text
//! FPGA RX ──► link_loop ──► Pipeline ◄── bus_rx_loop ◄── bus RX (commands, pings)
//!                 │ (never waits)  │ poll_dump         │ (acks, ping replies: waits for room)
//!                 ▼                ▼                   ▼
//!           telemetry queue ───► bus_tx_loop ◄── reply queue          bus TX ◄── bus_tx_loop
//!           fpga queue ──► fpga_ctrl_loop ──► FPGA TX     persist ──► storage_loop ──► flash
//!           housekeeping_loop: Health when the link is silent     watchdog_loop: feeds only if all progress
//! ```
//!
//! # Files
//! One per task loop, named after it: `link.rs` ([`link_loop`]), `fpga_ctrl.rs` ([`fpga_ctrl_loop`], with the
//! [`CoreClock`] edge), `bus_rx.rs` ([`bus_rx_loop`]), `bus_tx.rs` ([`bus_tx_loop`]), `storage.rs`
//! ([`storage_loop`], the update service's requests, [`load_calibration`]), `watchdog.rs` ([`watchdog_loop`]),
//! `housekeeping.rs` ([`housekeeping_loop`], the HSI trim) and `pps.rs` ([`pps_loop`], with the [`PpsInput`]
//! edge). What they share is apart: this file (the timing and queue constants, [`DEADLINES_MS`]), `state.rs` ([`App`]
//! and the messages between the tasks), `counters.rs` ([`ShellCounters`]) and `platform.rs` ([`Platform`]: what
//! the board offers besides its peripherals). Everything public is re-exported here: the paths are `app::…`.
//! The memory facts (ring sizes, the calibration scratch) are `crate::layout`'s: this module uses them, never the
//! other way round.
//!
//! # Back-pressure
//! The FPGA link is never held up by the bus: the link loop routes the pipeline's outputs with `try_send`, and a
//! telemetry message that finds the queue full is dropped and counted in Health (`telemetry_dropped`). At
//! 115200 baud the bus carries ≈ 11.5 kB/s; the default stream (18.9 reports/s) needs ≈ 1.2 kB/s, one report per
//! frame (`SetOutputRate(1)`, 604.8 /s) ≈ 37 kB/s, of which two thirds are dropped. Acks and ping replies have
//! their own queue, which the bus receiver waits on, so they are never dropped: a command is answered exactly once.

mod bus_rx;
mod bus_tx;
mod counters;
mod fpga_ctrl;
mod housekeeping;
mod link;
mod platform;
mod pps;
mod state;
mod storage;
mod watchdog;

pub use bus_rx::bus_rx_loop;
pub use bus_tx::bus_tx_loop;
pub use counters::ShellCounters;
pub use fpga_ctrl::{CoreClock, LINE_QUIET, LINE_QUIET_WAIT, fpga_ctrl_loop};
pub use housekeeping::{
    HSI_TRIM_DEADBAND_PPM, HSI_TRIM_WINDOW_S, housekeeping_loop, hsi_error_ppm, next_hsi_trim,
};
pub use link::link_loop;
pub use platform::{
    BootInfo, CycleCounter, FW_COMMIT, HsiTrim, McuSensorReader, Platform, ResetLog, UartErrors,
};
pub use pps::{PpsInput, pps_loop};
pub use state::{App, BusOut, ClassifyRxError, RxFault, UpdateIn, task_index};
pub use storage::{STORE_VDD_MIN_MV, load_calibration, storage_loop};
pub use watchdog::watchdog_loop;

use embassy_time::Duration;

/// Longest a loop may wait before it reports progress anyway (an idle line is not a fault, a stuck task is).
pub const IDLE_TIMEOUT: Duration = Duration::from_millis(100);
/// Bytes read from the FPGA ring per pass (a little over 4 frames).
pub const LINK_CHUNK: usize = 1024;
/// Telemetry messages queued for the bus (≈ 0.5 s of the default stream; 10 rather than 16 keeps RAM in its
/// budget since the housekeeping message made every slot larger).
pub const TELEMETRY_QUEUE: usize = 10;
/// Acks and ping replies queued for the bus.
pub const REPLY_QUEUE: usize = 4;
/// How often the watchdog task checks progress (and feeds the IWDG if every task made some).
pub const WATCHDOG_PERIOD: Duration = Duration::from_millis(250);
/// Longest a control message to the FPGA may take to leave (4 bytes at 2 Mbaud take 20 µs), else it is dropped and
/// counted (`fpga_tx_timeouts`).
pub const FPGA_TX_TIMEOUT: Duration = Duration::from_millis(20);
/// Longest one bus frame may take to leave (the largest, ≈ 500 bytes with KISS escapes, takes 43 ms at
/// 115200 baud), else it is dropped and counted (`bus_tx_errors`).
pub const BUS_TX_TIMEOUT: Duration = Duration::from_millis(500);
/// Longest a task that waits for events (the control queue, the store signals, PPS edges) waits before it beats
/// anyway.
pub const EVENT_WAIT: Duration = Duration::from_millis(500);
/// How long the update service's `Reset` waits for its reply to leave before it resets.
pub const RESET_AFTER: Duration = Duration::from_millis(250);
/// Shortest time between two log lines of the same receive error (an error storm is counted, not logged).
pub const ERROR_LOG_EVERY: Duration = Duration::from_secs(1);
/// Tasks with a heartbeat ([`TaskId`](shared::telemetry::TaskId)'s named variants, in order).
pub const TASKS: usize = 8;
/// Each task's deadline, ms: the longest it may go without a heartbeat before the watchdog stops feeding the
/// IWDG (in [`TaskId`](shared::telemetry::TaskId) order; `tools/fw-check/faults.py` reads them from this file).
/// Each is its longest wait (an [`IDLE_TIMEOUT`], an [`EVENT_WAIT`], a period) plus the longest stall of every
/// task, a DFU sector erase of the update service (≤ 2 s at x32, `docs/update.md`; a calibration store stalls
/// ≤ 0.6 s), plus margin: link, FPGA control, bus RX, bus TX 3 s; storage 4 s (its own erase, then a wait);
/// watchdog 3 s (250 ms period); housekeeping 4 s (1 s period, the ADC); PPS 3 s. The IWDG then resets within its
/// timeout (`board.rs`: 8 s nominal, 5.4 s at the fastest LSI) after the first miss: a hung task resets the MCU
/// within 12 s.
pub const DEADLINES_MS: [u32; TASKS] = [3_000, 3_000, 3_000, 3_000, 4_000, 3_000, 4_000, 3_000];
/// Housekeeping periods between log lines of link statistics.
pub const LOG_EVERY: u32 = 10;
/// Housekeeping period: a [`HousekeepingReport`](shared::telemetry::HousekeepingReport) each time, a Health report
/// too while the FPGA link is silent, and the CRC check of the calibration in RAM.
pub const HOUSEKEEPING_PERIOD: Duration = Duration::from_secs(1);
