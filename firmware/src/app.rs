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
//! # Back-pressure
//! The FPGA link is never held up by the bus: the link loop routes the pipeline's outputs with `try_send`, and a
//! telemetry message that finds the queue full is dropped and counted in Health (`telemetry_dropped`). At
//! 115200 baud the bus carries ≈ 11.5 kB/s; the default stream (18.9 reports/s) needs ≈ 1.2 kB/s, one report per
//! frame (`SetOutputRate(1)`, 604.8 /s) ≈ 37 kB/s, of which two thirds are dropped. Acks and ping replies have
//! their own queue, which the bus receiver waits on, so they are never dropped: a command is answered exactly once.

use core::cell::Cell;
use core::num::NonZeroU64;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_futures::select::{Either, Either3, select, select3};
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Ticker, Timer, with_timeout};
use embedded_hal::digital::OutputPin;
use embedded_io_async::{Read, Write};
use embedded_storage::nor_flash::NorFlash;
use shared::bus::csp::CspHeader;
use shared::bus::{BusConfig, BusCounters, BusEvent, BusNode, MAX_PAYLOAD, MAX_WIRE_FRAME};
use shared::pipeline::{Output, Pipeline, PipelineConfig, PipelineMemory};
use shared::storage::{CalStore, StoreError};
use shared::telemetry::Mode;
use shared::telemetry::{
    CalSource, ClockSource, HealthReport, HousekeepingReport, ResetHistory, RxErrorCounts,
    StoreOutcome, TaskId, Telemetry,
};
use shared::update::{UpdateError, UpdateStatus};
use shared::wire::FpgaControl;

use crate::layout::{CAL_SCRATCH, FPGA_RX_RING_LEN};
use crate::log::Loggable;
use crate::update::{CONFIRM_AFTER_MS, Updater};

type Raw = CriticalSectionRawMutex;

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
/// Tasks with a heartbeat ([`TaskId`]'s named variants, in order).
pub const TASKS: usize = 8;
/// Each task's deadline, ms: the longest it may go without a heartbeat before the watchdog stops feeding the
/// IWDG (in [`TaskId`] order). Each is its longest wait (an [`IDLE_TIMEOUT`], an [`EVENT_WAIT`], a period) plus
/// the longest stall of every task, a DFU sector erase of the update service (≤ 2 s at x32, `docs/update.md`; a
/// calibration store stalls ≤ 0.6 s), plus margin: link, FPGA control, bus RX, bus TX 3 s; storage 4 s (its own
/// erase, then a wait); watchdog 3 s (250 ms period); housekeeping 4 s (1 s period, the ADC); PPS 3 s. The IWDG
/// then resets within its timeout (`board.rs`: 8 s nominal, 5.4 s at the fastest LSI) after the first miss: a hung
/// task resets the MCU within 12 s.
pub const DEADLINES_MS: [u32; TASKS] = [3_000, 3_000, 3_000, 3_000, 4_000, 3_000, 4_000, 3_000];
/// Housekeeping periods between log lines of link statistics.
pub const LOG_EVERY: u32 = 10;
/// Housekeeping period: a [`HousekeepingReport`] each time, a Health report too while the FPGA link is silent, and
/// the CRC check of the calibration in RAM.
pub const HOUSEKEEPING_PERIOD: Duration = Duration::from_secs(1);

/// Something for the bus transmitter.
#[derive(Clone, Debug)]
pub enum BusOut {
    /// A telemetry message.
    Telemetry(Telemetry),
    /// A reply to a request: a ping's echo, an update service reply.
    Reply {
        /// The request's header.
        header: CspHeader,
        /// The reply's payload (a ping's: the request's, echoed).
        payload: heapless::Vec<u8, MAX_PAYLOAD>,
    },
}

/// A request to the update service, from the bus receiver to the storage task (the one that writes flash).
#[derive(Clone, Debug)]
pub struct UpdateIn {
    /// The request's header (the reply goes back to its source).
    pub header: CspHeader,
    /// Its payload (`shared::update::UpdateEnvelope`).
    pub payload: heapless::Vec<u8, MAX_PAYLOAD>,
}

/// Receive-error classes; the board maps its UART's error type onto these (`embedded_io::ErrorKind` says only
/// `Other` for every embassy-stm32 USART error).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RxFault {
    /// Bytes lost: UART overrun, or the DMA ring was lapped.
    Overrun,
    /// Framing, noise or parity error.
    Line,
    /// Anything else.
    Other,
}

/// Maps a driver's receive error onto [`RxFault`].
pub trait ClassifyRxError {
    /// The class of this error.
    fn classify(&self) -> RxFault;
}

/// The heartbeat slot of `task` (`TaskId`'s named variants in order; `None` for `Other`).
pub const fn task_index(task: TaskId) -> Option<usize> {
    Some(match task {
        TaskId::Link => 0,
        TaskId::FpgaCtrl => 1,
        TaskId::BusRx => 2,
        TaskId::BusTx => 3,
        TaskId::Storage => 4,
        TaskId::Watchdog => 5,
        TaskId::Housekeeping => 6,
        TaskId::Pps => 7,
        TaskId::Other(_) => return None,
    })
}

/// Declares the shell's counters once: the public snapshot [`ShellCounters`] (one field each), the private
/// `Counter` that names them, and the `AtomicCounters` the tasks increment.
macro_rules! shell_counters {
    ($($(#[$doc:meta])* $field:ident: $variant:ident,)*) => {
        /// Counters of the shell (the pipeline counts everything else); wrapping.
        #[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct ShellCounters {
            $($(#[$doc])* pub $field: u32,)*
        }

        #[derive(Clone, Copy)]
        enum Counter {
            $($variant,)*
        }

        impl Counter {
            const COUNT: usize = [$(Counter::$variant),*].len();
        }

        struct AtomicCounters([AtomicU32; Counter::COUNT]);

        impl AtomicCounters {
            const fn new() -> Self {
                Self([const { AtomicU32::new(0) }; Counter::COUNT])
            }

            fn get(&self, c: Counter) -> u32 {
                self.0.get(c as usize).map_or(0, |a| a.load(Ordering::Relaxed))
            }

            fn snapshot(&self) -> ShellCounters {
                ShellCounters {
                    $($field: self.get(Counter::$variant),)*
                }
            }
        }
    };
}

shell_counters! {
    /// FPGA receive overruns: the UART driver's, plus one per ring dropped after a flash stall (reported in health
    /// as `link.overruns` and in housekeeping).
    link_overruns: LinkOverrun,
    /// FPGA receive errors: framing, noise or parity.
    link_line_errors: LinkLine,
    /// FPGA receive errors of any other kind.
    link_other_errors: LinkOther,
    /// Telemetry messages dropped because the bus queue was full (added to health's `telemetry_dropped`, with the
    /// pipeline's own outbox overflows).
    telemetry_dropped: TelemetryDropped,
    /// Bus receive errors: overrun (UART or DMA ring).
    bus_rx_overruns: BusRxOverrun,
    /// Bus receive errors: framing, noise or parity.
    bus_rx_line_errors: BusRxLine,
    /// Bus receive errors of any other kind.
    bus_rx_other_errors: BusRxOther,
    /// Bus transmit errors.
    bus_tx_errors: BusTx,
    /// FPGA control messages dropped (queue full).
    fpga_ctrl_dropped: FpgaDropped,
    /// Calibration records stored.
    cal_stores: CalStores,
    /// Calibration stores that failed.
    cal_store_errors: CalStoreErrors,
    /// Health reports sent because the link was silent.
    silent_health: SilentHealth,
    /// Housekeeping reports sent.
    housekeeping: Housekeeping,
    /// Times the calibration in RAM failed its CRC check and was reloaded from flash.
    cal_ram_repairs: CalRamRepairs,
    /// Times the core clock stayed full after a stop because FPGA bytes kept arriving.
    clock_kept: ClockKept,
    /// Control messages to the FPGA that did not leave within [`FPGA_TX_TIMEOUT`] (or failed).
    fpga_tx_errors: FpgaTx,
    /// Calibration stores refused because VDD was below the x32 programming minimum.
    stores_refused_low_vdd: LowVdd,
    /// Periods the watchdog did not feed the IWDG because a task was late.
    watchdog_misses: WatchdogMiss,
}

/// What the board knows at boot, reported in every [`HousekeepingReport`].
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BootInfo {
    /// Reset flags (RCC_CSR bits 25–31, shifted down; see [`HousekeepingReport::reset_flags`]).
    pub reset_flags: u8,
    /// The boot counter (0: no reset history on this platform).
    pub boot_count: u32,
    /// Booted in safe mode (crash loop): factory calibration, no FPGA tasks.
    pub safe_mode: bool,
    /// Where the system clock comes from (`None`: not known).
    pub clock_source: Option<ClockSource>,
    /// RCC_CR.HSITRIM in force.
    pub hsi_trim: u8,
    /// The brown-out reset level of the option bytes.
    pub bor_level: Option<u8>,
}

/// The reset history kept across resets (`crate::resets`), as the tasks reach it.
pub trait ResetLog: Sync {
    /// The history now.
    fn report(&self, safe_mode: bool) -> ResetHistory;
    /// `ClearResets`: records and the crash-loop counter cleared.
    fn clear(&self);
    /// Notes the uptime, for the record of a reset that leaves none; `fed`: the watchdog was fed this period, so a
    /// deadline miss the monitor filed earlier did not lead to a reset (withdrawn).
    fn note_uptime(&self, uptime_ms: u32, fed: bool);
    /// This boot outlived the short-run time: the crash loop is over.
    fn end_crash_loop(&self);
}

/// Receive errors the board's interrupt handlers took before the drivers saw them (`board.rs`: the errors never stop
/// the DMA rings), added to the shell's own counts in housekeeping.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UartErrors {
    /// FPGA link.
    pub link: RxErrorCounts,
    /// Bus.
    pub bus: RxErrorCounts,
    /// DMA transfer errors.
    pub dma: u32,
}

/// The HSI's trim, offered by the board only while the core runs on the HSI (`board.rs`).
#[derive(Debug, Clone, Copy)]
pub struct HsiTrim {
    /// RCC_CR.HSITRIM now (0–31).
    pub read: fn() -> u8,
    /// Sets RCC_CR.HSITRIM.
    pub write: fn(u8),
}

/// Crystal time (FPGA frames) one trim decision averages over, s: ±1 frame in 6 048 is ±165 ppm of resolution.
pub const HSI_TRIM_WINDOW_S: u64 = 10;
/// The HSI's error beyond which the trim moves one step, ppm. One HSITRIM step is about 0.5 % (RM0090 §7.2.2:
/// 32 steps over the HSI's range, the factory value in the middle), so a band of ±0.3 % lets the loop settle within
/// one step of the best trim instead of hunting.
pub const HSI_TRIM_DEADBAND_PPM: i64 = 3_000;

/// The HSI's error, ppm (positive: fast), from `fpga_us` of crystal time (frames counted from the FPGA) that took
/// `local_us` on the core's clock (the HSI through the PLL); `None` for an empty window.
pub fn hsi_error_ppm(fpga_us: u64, local_us: u64) -> Option<i64> {
    let diff = i128::from(local_us).checked_sub(i128::from(fpga_us))?;
    let ppm = diff
        .checked_mul(1_000_000)?
        .checked_div(i128::from(fpga_us))?;
    i64::try_from(ppm).ok()
}

/// The next HSITRIM for an error of `error_ppm` at `trim`: one step down when fast beyond the dead band, one up when
/// slow, within 0–31.
pub fn next_hsi_trim(trim: u8, error_ppm: i64) -> u8 {
    if error_ppm > HSI_TRIM_DEADBAND_PPM {
        trim.saturating_sub(1)
    } else if error_ppm < -HSI_TRIM_DEADBAND_PPM {
        trim.saturating_add(1).min(31)
    } else {
        trim
    }
}

/// Crystal time of `frames` frames at FPGA decimation `decimation` and base rate `base_rate_millihz`, µs.
fn fpga_time_us(frames: u64, decimation: u16, base_rate_millihz: u64) -> u64 {
    let ticks = u128::from(frames).saturating_mul(u128::from(decimation).saturating_add(1));
    let us = ticks
        .saturating_mul(1_000_000_000)
        .checked_div(u128::from(base_rate_millihz))
        .unwrap_or(0);
    u64::try_from(us).unwrap_or(u64::MAX)
}

/// One trim window: where it started on both clocks.
#[derive(Debug, Clone, Copy)]
struct TrimWindow {
    at: Instant,
    frames: u64,
    decimation: u16,
}

/// Minimum VDD for a calibration store, mV: x32 programming needs 2.7 V (DS8626), and a store at a sagging rail
/// can leave weak bits the read-back does not see. Measured as VDDA (VREFINT), which the board ties to VDD.
pub const STORE_VDD_MIN_MV: u16 = 2_800;

/// What the board offers the shell besides its peripherals (nothing, on the host, unless a test sets it).
#[derive(Clone, Copy, Default)]
pub struct Platform {
    /// What the board knew at boot (reset flags, a recorded fault).
    pub boot: BootInfo,
    /// A cycle counter, for the core's load in housekeeping (at the rate the [`CoreClock`] reports).
    pub cycles: Option<CycleCounter>,
    /// A reader of the MCU's temperature (0.01 °C) and VDDA (mV), for housekeeping and the store's VDD check.
    pub mcu_sensors: Option<McuSensorReader>,
    /// The reset history.
    pub resets: Option<&'static dyn ResetLog>,
    /// Receive errors taken by the board's interrupt handlers.
    pub uart_errors: Option<fn() -> UartErrors>,
    /// The HSI's trim, while the core runs on the HSI: housekeeping trims it against the FPGA's frame rate.
    pub hsi_trim: Option<HsiTrim>,
    /// Resets the MCU, recording a commanded reset (the update service's `Reset`; on the MCU it never returns).
    pub reset: Option<fn()>,
}

impl core::fmt::Debug for Platform {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Platform")
            .field("boot", &self.boot)
            .field("cycles", &self.cycles)
            .field("mcu_sensors", &self.mcu_sensors)
            .field("resets", &self.resets.map(|_| ".."))
            .field("uart_errors", &self.uart_errors)
            .field("hsi_trim", &self.hsi_trim)
            .field("reset", &self.reset.is_some())
            .finish()
    }
}

impl Platform {
    /// Nothing known, nothing offered (`Default`, usable in `const`).
    pub const NONE: Self = Self {
        boot: BootInfo {
            reset_flags: 0,
            boot_count: 0,
            safe_mode: false,
            clock_source: None,
            hsi_trim: 0,
            bor_level: None,
        },
        cycles: None,
        mcu_sensors: None,
        resets: None,
        uart_errors: None,
        hsi_trim: None,
        reset: None,
    };
}

/// Reads the MCU's (temperature in 0.01 °C, VDDA in mV); `None` when it cannot.
pub type McuSensorReader = fn() -> Option<(i16, u16)>;

/// A free-running CPU cycle counter (the DWT's on the MCU), for the core's load; it counts at the core clock's
/// rate, which [`CoreClock`] reports.
#[derive(Debug, Clone, Copy)]
pub struct CycleCounter {
    /// Reads the counter.
    pub now: fn() -> u32,
}

/// The core clock: full speed while frames stream, lowered while the FPGA stream is stopped (`Mode::Idle`), with
/// the peripherals' clocks unchanged (`board::CoreClock`).
pub trait CoreClock {
    /// Sets the low (`true`) or the full clock; returns the core clock's rate after, Hz.
    fn set_low(&mut self, low: bool) -> u32;
}

/// The firmware's git commit (first 8 hex digits as a number; 0 outside git) and whether the tree was dirty, from
/// `build.rs`.
pub const FW_COMMIT: (u32, bool) = (
    match u32::from_str_radix(env!("FW_COMMIT"), 16) {
        Ok(c) => c,
        Err(_) => 0,
    },
    matches!(env!("FW_DIRTY").as_bytes(), b"1"),
);

/// Everything the tasks share: the pipeline, the queues between the tasks, progress and counters.
///
/// On the MCU one `App` lives in a `static` (`&'static App<&'static mut PipelineMemory>`); on the host each run builds
/// its own, so scenarios never share state.
pub struct App<B> {
    /// The flight core.
    pub pipeline: Mutex<Raw, Pipeline<B>>,
    bus: BusConfig,
    telemetry: Channel<Raw, Telemetry, TELEMETRY_QUEUE>,
    replies: Channel<Raw, BusOut, REPLY_QUEUE>,
    fpga: Channel<Raw, FpgaControl, 4>,
    /// The tag of a committed upload to store.
    persist: Signal<Raw, u16>,
    /// The calibration in RAM failed its CRC check: reload it from flash.
    reload: Signal<Raw, ()>,
    /// Requests to the update service (`storage_loop` handles them).
    update_in: Channel<Raw, UpdateIn, 1>,
    /// The update service's state, as the storage task last read it (for housekeeping).
    update_status: BlockingMutex<Raw, Cell<UpdateStatus>>,
    /// Each task's last heartbeat, ms of uptime (wrapping).
    heartbeats: [AtomicU32; TASKS],
    /// Tasks the watchdog checks (bit i: [`TASKS`] order); all unless the board runs fewer (safe mode).
    monitored: AtomicU32,
    /// Fault injection: tasks that hang (await forever) at their next heartbeat (read only in a fault-injection
    /// build).
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    hang: AtomicU32,
    counters: AtomicCounters,
    bus_counters: BlockingMutex<Raw, Cell<BusCounters>>,
    last_store: BlockingMutex<Raw, Cell<StoreOutcome>>,
    platform: Platform,
    /// Cycles the link task spent processing frames (wrapping).
    busy_cycles: AtomicU32,
    /// Bytes the link task has read (wrapping): `fpga_ctrl_loop` watches it for a quiet line.
    link_bytes: AtomicU32,
    /// A calibration store ran (no task ran meanwhile): the link task drops what its ring holds.
    link_stale: AtomicBool,
    /// The core clock's rate, Hz, as `fpga_ctrl_loop` last set it (0: not yet).
    core_hz: AtomicU32,
    /// The HSI's error over the last trim window, ppm (`i32::MIN`: none).
    hsi_error_ppm: core::sync::atomic::AtomicI32,
}

impl<B: core::borrow::BorrowMut<PipelineMemory>> App<B> {
    /// The shared state of a node with bus configuration `bus`, around a new pipeline with `config`, the (empty)
    /// large buffers `memory` ([`PipelineMemory`]) and the factory calibration (`load_calibration` replaces it, through `pipeline.get_mut()`
    /// before the tasks start). `const`: the MCU builds its 15 KiB `App` at compile time in a `static`, never on the
    /// stack (`docs/firmware.md`, stack).
    pub const fn new(
        config: PipelineConfig,
        memory: B,
        bus: BusConfig,
        platform: Platform,
    ) -> Self {
        Self {
            pipeline: Mutex::new(Pipeline::new(config, memory)),
            bus,
            telemetry: Channel::new(),
            replies: Channel::new(),
            fpga: Channel::new(),
            persist: Signal::new(),
            reload: Signal::new(),
            update_in: Channel::new(),
            update_status: BlockingMutex::new(Cell::new(UpdateStatus::UNKNOWN)),
            heartbeats: [const { AtomicU32::new(0) }; TASKS],
            monitored: AtomicU32::new((1 << TASKS) - 1),
            hang: AtomicU32::new(0),
            counters: AtomicCounters::new(),
            bus_counters: BlockingMutex::new(Cell::new(BusCounters::ZERO)),
            last_store: BlockingMutex::new(Cell::new(StoreOutcome::None)),
            platform,
            busy_cycles: AtomicU32::new(0),
            link_bytes: AtomicU32::new(0),
            link_stale: AtomicBool::new(false),
            core_hz: AtomicU32::new(0),
            hsi_error_ppm: core::sync::atomic::AtomicI32::new(i32::MIN),
        }
    }

    /// Puts what the board offers in place (before the tasks start).
    pub fn set_platform(&mut self, platform: Platform) {
        self.platform = platform;
    }

    /// The bus configuration.
    pub fn bus_config(&self) -> BusConfig {
        self.bus
    }

    /// The last heartbeat of `task`, ms of uptime (0 before its first).
    pub fn last_beat_ms(&self, task: TaskId) -> u32 {
        task_index(task)
            .and_then(|i| self.heartbeats.get(i))
            .map_or(0, |h| h.load(Ordering::Relaxed))
    }

    /// Sets which tasks run (bit i: [`TASKS`] order): the others are not checked.
    pub fn set_monitored(&self, mask: u32) {
        self.monitored.store(mask, Ordering::Relaxed);
    }

    /// The first task past its deadline at `now_ms` (uptime), if any: the watchdog feeds only while there is none,
    /// and the flight build's deadline monitor (SysTick) records it.
    pub fn late_task(&self, now_ms: u32) -> Option<TaskId> {
        let monitored = self.monitored.load(Ordering::Relaxed);
        (0..TASKS)
            .zip(self.heartbeats.iter().zip(DEADLINES_MS))
            .find(|&(i, (beat, deadline))| {
                monitored & (1 << i) != 0
                    && now_ms.wrapping_sub(beat.load(Ordering::Relaxed)) > deadline
            })
            .map(|(i, _)| crate::resets::task_id(u32::try_from(i).unwrap_or(u32::MAX)))
    }

    /// Fault injection: `task` hangs (awaits forever) at its next heartbeat, as a task waiting on something that
    /// never comes would.
    #[cfg(feature = "fault-injection")]
    pub fn inject_hang(&self, task: TaskId) {
        if let Some(i) = task_index(task) {
            self.hang.fetch_or(1 << i, Ordering::Relaxed);
        }
    }

    /// The shell's counters now.
    pub fn counters(&self) -> ShellCounters {
        self.counters.snapshot()
    }

    /// The housekeeping report at `now` (the pipeline's time gaps and link overruns from `p`; the core's load over
    /// the period `load` and the MCU's (temperature, VDDA) `sensors`, if measured).
    fn housekeeping(
        &self,
        p: &Pipeline<B>,
        now: Instant,
        load: Option<(u16, Option<u32>)>,
        sensors: Option<(i16, u16)>,
    ) -> HousekeepingReport {
        let c = self.counters();
        let boot = self.platform.boot;
        let taken = self.platform.uart_errors.map(|f| f()).unwrap_or_default();
        let sum = |a: RxErrorCounts, b: RxErrorCounts| RxErrorCounts {
            overrun: a.overrun.wrapping_add(b.overrun),
            line: a.line.wrapping_add(b.line),
            other: a.other.wrapping_add(b.other),
        };
        HousekeepingReport {
            uptime_ms: now.as_millis(),
            fw_commit: FW_COMMIT.0,
            fw_dirty: FW_COMMIT.1,
            reset_flags: boot.reset_flags,
            boot_count: boot.boot_count,
            safe_mode: boot.safe_mode,
            clock_source: boot.clock_source,
            hsi_trim: self.platform.hsi_trim.map_or(boot.hsi_trim, |t| (t.read)()),
            hsi_error_ppm: Some(self.hsi_error_ppm.load(Ordering::Relaxed))
                .filter(|&e| e != i32::MIN),
            bor_level: boot.bor_level,
            stores_refused_low_vdd: c.stores_refused_low_vdd,
            core_load_permille: load.map(|l| l.0),
            core_cycles_per_frame: load.and_then(|l| l.1),
            mcu_temp_cdeg: sensors.map(|s| s.0),
            vdda_mv: sensors.map(|s| s.1),
            link_rx_errors: sum(
                RxErrorCounts {
                    overrun: c.link_overruns,
                    line: c.link_line_errors,
                    other: c.link_other_errors.wrapping_add(taken.dma),
                },
                taken.link,
            ),
            bus_rx_errors: sum(
                RxErrorCounts {
                    overrun: c.bus_rx_overruns,
                    line: c.bus_rx_line_errors,
                    other: c.bus_rx_other_errors,
                },
                taken.bus,
            ),
            bus_tx_errors: c.bus_tx_errors,
            bus: self.bus_counters.lock(Cell::get),
            fpga_ctrl_dropped: c.fpga_ctrl_dropped,
            time_gaps: p.time_gaps(),
            cal_stores: [c.cal_stores, c.cal_store_errors],
            last_store: self.last_store.lock(Cell::get),
            cal_ram_repairs: c.cal_ram_repairs,
            mode: p.mode(),
            excluded: p.fusion().config().excluded,
            core_clock_hz: Some(self.core_hz.load(Ordering::Relaxed)).filter(|&hz| hz > 0),
        }
    }

    fn count(&self, i: Counter) {
        if let Some(a) = self.counters.0.get(i as usize) {
            a.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// `task` is alive now (or, in a fault-injection build asked to hang it, never returns).
    async fn beat(&self, task: TaskId) {
        let Some(i) = task_index(task) else { return };
        #[cfg(feature = "fault-injection")]
        if self.hang.load(Ordering::Relaxed) & (1 << i) != 0 {
            warn!("fault injection: {:?} hangs", task);
            core::future::pending::<()>().await;
        }
        if let Some(h) = self.heartbeats.get(i) {
            h.store(uptime_ms(), Ordering::Relaxed);
        }
    }

    /// Sends one output where it belongs without waiting: telemetry that finds its queue full is dropped and counted
    /// (`telemetry_dropped`).
    fn route(&self, o: Output) {
        match o {
            Output::Telemetry(t) => {
                if self.telemetry.try_send(self.stamp(t)).is_err() {
                    self.count(Counter::TelemetryDropped);
                }
            }
            Output::Fpga(c) => {
                if self.fpga.try_send(c).is_err() {
                    self.count(Counter::FpgaDropped);
                }
            }
            Output::PersistCalibration { tag } => self.persist.signal(tag),
            Output::ClearResets => {
                if let Some(r) = self.platform.resets {
                    r.clear();
                    info!("reset history cleared by command");
                }
            }
        }
    }

    /// A message on its way out, with the shell's own facts in a health report: the core knows neither the uptime
    /// nor what the shell lost (link overruns, telemetry dropped here), so the shell, their one owner, adds them.
    fn stamp(&self, t: Telemetry) -> Telemetry {
        match t {
            Telemetry::Health(h) => Telemetry::Health(self.stamp_health(h)),
            other => other,
        }
    }

    /// `h` with the shell's facts (see `stamp`).
    fn stamp_health(&self, mut h: HealthReport) -> HealthReport {
        h.uptime_ms = Instant::now().as_millis();
        h.link.overruns = self.counters.get(Counter::LinkOverrun);
        h.telemetry_dropped = h
            .telemetry_dropped
            .wrapping_add(self.counters.get(Counter::TelemetryDropped));
        h
    }

    /// The health report the shell would send now: `p`'s, with the shell's own facts.
    pub fn health(&self, p: &Pipeline<B>) -> HealthReport {
        self.stamp_health(p.health())
    }

    /// Routes everything queued in the pipeline, without waiting.
    fn route_all(&self, p: &mut Pipeline<B>) {
        while let Some(o) = p.poll() {
            self.route(o);
        }
    }
}

/// Uptime, ms, wrapping (the heartbeats' clock).
fn uptime_ms() -> u32 {
    #[allow(clippy::cast_possible_truncation)]
    // wrapping by design: deadlines compare with `wrapping_sub`
    let ms = Instant::now().as_millis() as u32;
    ms
}

/// Logs a receive error at most every [`ERROR_LOG_EVERY`] (a storm is counted, not logged: logging every byte's
/// error would cost more than the error).
struct ErrorLog(Option<Instant>);

impl ErrorLog {
    fn due(&mut self) -> bool {
        let now = Instant::now();
        let due = self
            .0
            .is_none_or(|last| now.saturating_duration_since(last) >= ERROR_LOG_EVERY);
        if due {
            self.0 = Some(now);
        }
        due
    }
}

/// FPGA frames in: read the DMA ring, feed the pipeline, route its outputs. Never waits for the bus. Receive errors
/// are counted and never fatal: the driver restarts reception on the next read, and the frame decoder
/// resynchronises, so an error costs only the frames whose bytes it touched.
pub async fn link_loop<B, R>(app: &App<B>, rx: &mut R) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    R: Read,
    R::Error: ClassifyRxError + Loggable,
{
    let mut buf = [0u8; LINK_CHUNK];
    let mut log = ErrorLog(None);
    loop {
        app.beat(TaskId::Link).await;
        let read = with_timeout(IDLE_TIMEOUT, rx.read(&mut buf)).await;
        if app.link_stale.swap(false, Ordering::AcqRel) {
            // A calibration store ran: no task ran for up to `STORE_STALL_MAX_US`, long enough for the DMA to lap
            // the ring many times, and what it holds now are bytes of different laps (embassy's ring buffer notices
            // a lap only when its position happens to be past the reader's). Drop them all, with the decoder's
            // partial frame, and count one overrun; the next frame's sequence gap counts the frames lost.
            let dropped = drain(rx, &mut buf).await;
            app.pipeline.lock().await.link_discarded();
            app.count(Counter::LinkOverrun);
            warn!("fpga link: {:?} bytes dropped after a flash stall", dropped);
            continue;
        }
        let n = match read {
            Err(_idle) => continue,
            Ok(Ok(n)) => n,
            Ok(Err(e)) => {
                match e.classify() {
                    RxFault::Overrun => app.count(Counter::LinkOverrun),
                    RxFault::Line => app.count(Counter::LinkLine),
                    RxFault::Other => app.count(Counter::LinkOther),
                }
                if log.due() {
                    warn!(
                        "fpga link: rx error {:?} (counted; logged at most every second)",
                        e
                    );
                }
                // The driver restarts the ring on the next read; yield first, so that a line that errors on every
                // byte cannot keep the other tasks from running.
                embassy_futures::yield_now().await;
                continue;
            }
        };
        app.link_bytes
            .fetch_add(u32::try_from(n).unwrap_or(u32::MAX), Ordering::Relaxed);
        let mut input = buf.get(..n).unwrap_or(&[]);
        let mut p = app.pipeline.lock().await;
        let c0 = app.platform.cycles.map(|c| (c.now)());
        p.set_arrival_us(Instant::now().as_micros());
        while !input.is_empty() {
            p.push_link(&mut input);
            app.route_all(&mut p);
        }
        if let (Some(c), Some(c0)) = (app.platform.cycles, c0) {
            app.busy_cycles
                .fetch_add((c.now)().wrapping_sub(c0), Ordering::Relaxed);
        }
    }
}

/// Reads and drops what `rx` holds now, without waiting for more (at most one ring's worth, so that a line that
/// keeps delivering cannot hold the task here); returns the bytes dropped.
async fn drain<R: Read>(rx: &mut R, buf: &mut [u8]) -> usize {
    let mut dropped = 0usize;
    while dropped < FPGA_RX_RING_LEN {
        match with_timeout(Duration::from_ticks(0), rx.read(buf)).await {
            Ok(Ok(n)) if n > 0 => dropped = dropped.saturating_add(n),
            _ => break,
        }
    }
    dropped
}

/// Bus bytes in: commands go to the pipeline, and their acks (with any report the command asked for) to the reply
/// queue, waiting for room there; pings are answered the same way.
pub async fn bus_rx_loop<B, R>(app: &App<B>, rx: &mut R) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    R: Read,
    R::Error: ClassifyRxError + Loggable,
{
    let mut node = BusNode::new(app.bus);
    let mut buf = [0u8; 256];
    let mut log = ErrorLog(None);
    loop {
        app.beat(TaskId::BusRx).await;
        let n = match with_timeout(IDLE_TIMEOUT, rx.read(&mut buf)).await {
            Err(_idle) => continue,
            Ok(Ok(n)) => n,
            Ok(Err(e)) => {
                app.count(match e.classify() {
                    RxFault::Overrun => Counter::BusRxOverrun,
                    RxFault::Line => Counter::BusRxLine,
                    RxFault::Other => Counter::BusRxOther,
                });
                if log.due() {
                    warn!(
                        "bus: rx error {:?} (counted; logged at most every second)",
                        e
                    );
                }
                embassy_futures::yield_now().await;
                continue;
            }
        };
        let mut input = buf.get(..n).unwrap_or(&[]);
        while let Some(event) = node.receive(&mut input) {
            match event {
                BusEvent::Command(payload) => {
                    // The replies come back from the call (ack first): telemetry waits for room in the reply
                    // queue, the rest is routed at once.
                    let replies = app.pipeline.lock().await.handle_command(payload);
                    for o in replies {
                        match o {
                            Output::Telemetry(t) => {
                                app.replies.send(BusOut::Telemetry(app.stamp(t))).await
                            }
                            other => app.route(other),
                        }
                    }
                }
                BusEvent::Ping { header, payload } => {
                    let payload = heapless::Vec::from_slice(payload).unwrap_or_default();
                    app.replies.send(BusOut::Reply { header, payload }).await;
                }
                BusEvent::Update { header, payload } => {
                    // Waits while the storage task erases (the bytes behind wait in the DMA ring).
                    let payload = heapless::Vec::from_slice(payload).unwrap_or_default();
                    app.update_in.send(UpdateIn { header, payload }).await;
                }
            }
        }
        app.bus_counters.lock(|c| c.set(*node.counters()));
    }
}

/// Bus bytes out: replies first, then telemetry, then (when both queues are empty) the next report of a requested
/// dump, so dumps go exactly as fast as the bus drains. CSP packets in KISS frames.
pub async fn bus_tx_loop<B, W>(app: &App<B>, tx: &mut W) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    W: Write,
    W::Error: Loggable,
{
    let node = BusNode::new(app.bus);
    let mut wire = [0u8; MAX_WIRE_FRAME];
    loop {
        app.beat(TaskId::BusTx).await;
        let item = if let Ok(r) = app.replies.try_receive() {
            r
        } else if let Ok(t) = app.telemetry.try_receive() {
            BusOut::Telemetry(t)
        } else if let Some(t) = app.pipeline.lock().await.poll_dump() {
            BusOut::Telemetry(t)
        } else {
            match with_timeout(
                IDLE_TIMEOUT,
                select(app.replies.receive(), app.telemetry.receive()),
            )
            .await
            {
                Ok(Either::First(r)) => r,
                Ok(Either::Second(t)) => BusOut::Telemetry(t),
                Err(_idle) => continue,
            }
        };
        let frame = match &item {
            BusOut::Telemetry(t) => node.encode_message(t, &mut wire).map_err(|_| ()),
            BusOut::Reply { header, payload } => node
                .encode_reply(header, payload, &mut wire)
                .map_err(|_| ()),
        };
        match frame {
            Ok(n) => match with_timeout(BUS_TX_TIMEOUT, tx.write_all(wire.get(..n).unwrap_or(&[])))
                .await
            {
                Ok(Ok(())) => {}
                Ok(Err(e)) => {
                    app.count(Counter::BusTx);
                    warn!("bus: tx error {:?}", e);
                }
                Err(_timeout) => {
                    app.count(Counter::BusTx);
                    warn!(
                        "bus: a frame did not leave within {:?} ms",
                        BUS_TX_TIMEOUT.as_millis()
                    );
                }
            },
            Err(()) => error!("bus: a message did not fit a frame"),
        }
    }
}

/// Control messages to the FPGA, and the core clock that goes with the stream: full at boot and raised before a
/// `SetStreaming(true)` goes out; lowered once a `SetStreaming(false)` has left the transmitter and the FPGA line
/// is quiet ([`LINE_QUIET`]: between the two prescaler writes USART1's clock is briefly halved, which would garble
/// a frame's tail), kept full (and counted) if frames still arrive after [`LINE_QUIET_WAIT`].
pub async fn fpga_ctrl_loop<B, W>(app: &App<B>, tx: &mut W, clock: &mut impl CoreClock) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    W: Write,
    W::Error: Loggable,
{
    app.core_hz.store(clock.set_low(false), Ordering::Relaxed);
    loop {
        app.beat(TaskId::FpgaCtrl).await;
        let Ok(msg) = with_timeout(EVENT_WAIT, app.fpga.receive()).await else {
            continue;
        };
        info!("fpga: {:?}", msg);
        if msg == FpgaControl::SetStreaming(true) {
            app.core_hz.store(clock.set_low(false), Ordering::Relaxed);
        }
        let sent = async {
            tx.write_all(&msg.to_bytes()).await?;
            tx.flush().await
        };
        match with_timeout(FPGA_TX_TIMEOUT, sent).await {
            Ok(Ok(())) => {}
            Ok(Err(e)) => {
                app.count(Counter::FpgaTx);
                warn!("fpga: control tx error {:?}", e);
            }
            Err(_timeout) => {
                app.count(Counter::FpgaTx);
                warn!("fpga: control message did not leave in time");
            }
        }
        if msg == FpgaControl::SetStreaming(false) {
            // Only on a quiet line: the FPGA may still send the rest of a frame, and while the prescalers change,
            // USART1's clock is briefly halved (board::CoreClock).
            if line_quiet(app).await {
                app.core_hz.store(clock.set_low(true), Ordering::Relaxed);
            } else {
                app.count(Counter::ClockKept);
                warn!("fpga: frames still arriving after the stop; core clock kept");
            }
        }
        info!("core clock: {:?} Hz", app.core_hz.load(Ordering::Relaxed));
    }
}

/// Time with no FPGA byte read that makes the line quiet: three frame periods at the default 604.8 frames/s (a
/// frame takes 1.2 ms on the line, and the link task reads within the idle-line interrupt of its end).
pub const LINE_QUIET: Duration = Duration::from_millis(5);
/// Longest the clock switch waits for a quiet line after the FPGA was told to stop.
pub const LINE_QUIET_WAIT: Duration = Duration::from_millis(200);

/// Waits until no FPGA byte was read for [`LINE_QUIET`]; `false` if that did not happen within [`LINE_QUIET_WAIT`].
async fn line_quiet<B>(app: &App<B>) -> bool {
    let deadline = Instant::now()
        .checked_add(LINE_QUIET_WAIT)
        .unwrap_or(Instant::MAX);
    let mut seen = app.link_bytes.load(Ordering::Relaxed);
    while Instant::now() < deadline {
        Timer::after(LINE_QUIET).await;
        let now = app.link_bytes.load(Ordering::Relaxed);
        if now == seen {
            return true;
        }
        seen = now;
    }
    false
}

/// Loads the stored calibration into the pipeline (newest valid record, else the factory default).
pub fn load_calibration<F: NorFlash, B: core::borrow::BorrowMut<PipelineMemory>>(
    store: &mut CalStore<F>,
    pipeline: &mut Pipeline<B>,
) where
    F::Error: Loggable,
{
    let mut scratch = [0u8; CAL_SCRATCH];
    // In place, into the pipeline's own table: a table-sized temporary broke the 8 KiB frame limit.
    pipeline.load_calibration_with(|table| match store.load_into(&mut scratch, table) {
        Ok(loaded) => {
            let source = match loaded.seq {
                Some(_) => CalSource::Stored,
                None => CalSource::Factory,
            };
            info!(
                "calibration: id {:?} from {:?} (seq {:?}, slots {:?})",
                table.cal_id, source, loaded.seq, loaded.slots
            );
            source
        }
        Err(e) => {
            error!("calibration: flash read failed ({:?}), factory default", e);
            table.set_factory();
            CalSource::Factory
        }
    });
}

/// VDD, mV, when it is below [`STORE_VDD_MIN_MV`] (no reading: not known to be low): flash writes (a calibration
/// store, an update) are refused then.
fn vdd_too_low<B>(app: &App<B>) -> Option<u16> {
    app.platform
        .mcu_sensors
        .and_then(|read| read())
        .map(|(_, mv)| mv)
        .filter(|&mv| mv < STORE_VDD_MIN_MV)
}

/// One request to the update service: handled on the DFU slot (flash writes only in `Mode::Idle` and at a VDD fit
/// for programming), answered on the reply queue, the service's state published for housekeeping.
async fn serve_update<B, D, S>(app: &App<B>, update: &mut Updater<D, S>, request: UpdateIn)
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    D: NorFlash,
    S: NorFlash,
{
    let idle = app.pipeline.lock().await.mode() == Mode::Idle;
    let writable = if !idle {
        Err(UpdateError::NotIdle)
    } else if vdd_too_low(app).is_some() {
        app.count(Counter::LowVdd);
        Err(UpdateError::LowVoltage)
    } else {
        Ok(())
    };
    let mut out = [0u8; MAX_PAYLOAD];
    let n = update.handle(&request.payload, writable, &mut out);
    if writable.is_ok() {
        // Any flash operation stalled every task (a DFU sector erase ≤ 2 s): the link task drops its ring. In
        // `Idle` the FPGA is not streaming, so nothing is lost.
        app.link_stale.store(true, Ordering::Release);
    }
    app.update_status.lock(|c| c.set(update.status()));
    match n.and_then(|n| out.get(..n)) {
        Some(reply) => {
            let payload = heapless::Vec::from_slice(reply).unwrap_or_default();
            app.replies
                .send(BusOut::Reply {
                    header: request.header,
                    payload,
                })
                .await;
        }
        None => error!("update: a reply did not fit a packet"),
    }
    if update.receiver.take_reset() {
        // The reply (and whatever is queued before it: ≤ 4 replies of ≤ 0.5 KB, 0.18 s at 115200 baud) leaves first.
        Timer::after(RESET_AFTER).await;
        match app.platform.reset {
            Some(reset) => {
                info!("update: reset by command");
                reset();
            }
            None => warn!("update: Reset asked, but this platform cannot reset"),
        }
    }
}

/// A trial image (the bootloader swapped it in) confirms itself once it has run [`CONFIRM_AFTER_MS`] without a
/// missed deadline; if one was missed it stays a trial, and the next reset reverts it.
async fn confirm_trial<B, D, S>(app: &App<B>, update: &mut Updater<D, S>)
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    D: NorFlash,
    S: NorFlash,
{
    if !update.trial
        || Instant::now().as_millis() < CONFIRM_AFTER_MS
        || app.counters.get(Counter::WatchdogMiss) != 0
    {
        return;
    }
    let confirmed = update.confirm();
    app.link_stale.store(true, Ordering::Release);
    if confirmed {
        info!(
            "update: version {:?} confirmed itself",
            update.running_version
        );
    } else {
        error!("update: the boot state could not be written; the next reset reverts");
    }
    app.update_status.lock(|c| c.set(update.status()));
}

/// Persists the calibration in force whenever an upload is committed, then sends the commit's ack: `Ok` only once
/// the record is written and read back (`CalStore::store`), `Storage` otherwise. The erase stalls the CPU
/// (single-bank flash, `docs/storage.md`): FPGA bytes arriving meanwhile overrun the ring and are counted, bus bytes
/// wait in the bus's DMA ring.
pub async fn storage_loop<B, F, D, S>(
    app: &App<B>,
    store: &mut CalStore<F>,
    update: &mut Updater<D, S>,
) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
    F: NorFlash,
    F::Error: Loggable,
    D: NorFlash,
    S: NorFlash,
{
    let mut scratch = [0u8; CAL_SCRATCH];
    app.update_status.lock(|c| c.set(update.status()));
    loop {
        app.beat(TaskId::Storage).await;
        confirm_trial(app, update).await;
        let Ok(event) = with_timeout(
            EVENT_WAIT,
            select3(
                app.persist.wait(),
                app.reload.wait(),
                app.update_in.receive(),
            ),
        )
        .await
        else {
            continue;
        };
        let tag = match event {
            Either3::First(tag) => tag,
            Either3::Third(request) => {
                serve_update(app, update, request).await;
                continue;
            }
            Either3::Second(()) => {
                // The table in RAM failed its CRC: the newest stored one (or the factory default) replaces it; in
                // safe mode always the factory default (a stored table may be what crashed the boots before).
                let mut pipeline = app.pipeline.lock().await;
                if app.platform.boot.safe_mode {
                    pipeline.load_calibration_with(|table| {
                        table.set_factory();
                        CalSource::Factory
                    });
                } else {
                    load_calibration(store, &mut *pipeline);
                }
                drop(pipeline);
                app.count(Counter::CalRamRepairs);
                continue;
            }
        };
        // The store is synchronous (the CPU stalls on the erase and the word programs anyway), so the lock is held
        // through it and the table is not copied into this task's state (1.8 KiB of RAM); no task runs until it
        // returns (`layout::STORE_STALL_MAX_US`: the bus ring holds twice that, the link task drops its ring).
        // VDD first: a store below the x32 programming minimum could write weak bits the read-back passes.
        if let Some(vdd_mv) = vdd_too_low(app) {
            app.count(Counter::LowVdd);
            error!("calibration: store refused, VDD {:?} mV", vdd_mv);
            app.last_store.lock(|c| c.set(StoreOutcome::Failed));
            let ack = app.pipeline.lock().await.calibration_persisted(tag, false);
            app.replies
                .send(BusOut::Telemetry(Telemetry::Ack(ack)))
                .await;
            continue;
        }
        let (cal_id, result) = {
            let pipeline = app.pipeline.lock().await;
            let table = pipeline.calibration();
            (table.cal_id, store.store(table, &mut scratch))
        };
        // Unless it failed before touching the flash, the store stalled every task (`layout::STORE_STALL_MAX_US`).
        if !matches!(result, Err(StoreError::Encode | StoreError::Geometry)) {
            app.link_stale.store(true, Ordering::Release);
        }
        let outcome = match result {
            Ok(seq) => {
                app.count(Counter::CalStores);
                info!("calibration: id {:?} stored as record {:?}", cal_id, seq);
                StoreOutcome::Stored(seq)
            }
            Err(e) => {
                app.count(Counter::CalStoreErrors);
                error!("calibration: store failed: {:?}", e);
                StoreOutcome::Failed
            }
        };
        app.last_store.lock(|c| c.set(outcome));
        let stored = matches!(outcome, StoreOutcome::Stored(_));
        let ack = app.pipeline.lock().await.calibration_persisted(tag, stored);
        app.replies
            .send(BusOut::Telemetry(Telemetry::Ack(ack)))
            .await;
    }
}

/// Feeds the watchdog only while every task's heartbeat is within its deadline ([`DEADLINES_MS`]), notes the
/// uptime for the reset history, and blinks the LED while it feeds.
pub async fn watchdog_loop<B: core::borrow::BorrowMut<PipelineMemory>, L: OutputPin>(
    app: &App<B>,
    period: Duration,
    mut feed: impl FnMut(),
    led: &mut L,
) -> ! {
    let mut ticker = Ticker::every(period);
    loop {
        ticker.next().await;
        app.beat(TaskId::Watchdog).await;
        let now_ms = uptime_ms();
        let late = app.late_task(now_ms);
        if let Some(r) = app.platform.resets {
            r.note_uptime(now_ms, late.is_none());
        }
        if late.is_none() {
            feed();
            let period_ms = NonZeroU64::new(period.as_millis()).unwrap_or(NonZeroU64::MIN);
            let _ = led.set_state(
                (Instant::now().as_millis() / period_ms)
                    .is_multiple_of(2)
                    .into(),
            );
        } else {
            app.count(Counter::WatchdogMiss);
            warn!("watchdog: {:?} missed its deadline, not feeding", late);
        }
    }
}

/// One housekeeping period of the HSI trim loop: while frames stream at a steady decimation, compares the FPGA's
/// crystal time (frames counted, lost ones included) with the core's clock over [`HSI_TRIM_WINDOW_S`] and moves
/// HSITRIM one step when the error is beyond [`HSI_TRIM_DEADBAND_PPM`]; returns the window to go on with.
fn trim_hsi<B: core::borrow::BorrowMut<PipelineMemory>>(
    app: &App<B>,
    p: &Pipeline<B>,
    trim: HsiTrim,
    window: Option<TrimWindow>,
    now: Instant,
) -> Option<TrimWindow> {
    let link = p.link_counters();
    let frames = u64::from(link.frames).saturating_add(u64::from(link.frames_dropped));
    if p.mode() != shared::telemetry::Mode::Stream {
        return None;
    }
    let decimation = p.decimation()?;
    let fresh = Some(TrimWindow {
        at: now,
        frames,
        decimation,
    });
    let Some(w) = window.filter(|w| w.decimation == decimation && frames >= w.frames) else {
        return fresh;
    };
    let local_us = now.duration_since(w.at).as_micros();
    if local_us < HSI_TRIM_WINDOW_S.saturating_mul(1_000_000) {
        return window;
    }
    let fpga_us = fpga_time_us(
        frames.saturating_sub(w.frames),
        decimation,
        p.config().fpga_base_rate_millihz,
    );
    if let Some(e) = hsi_error_ppm(fpga_us, local_us) {
        app.hsi_error_ppm.store(
            i32::try_from(e).unwrap_or(if e > 0 { i32::MAX } else { i32::MIN + 1 }),
            Ordering::Relaxed,
        );
        let old = (trim.read)();
        let new = next_hsi_trim(old, e);
        if new != old {
            (trim.write)(new);
            info!("hsi: error {:?} ppm, trim {:?} -> {:?}", e, old, new);
        }
    }
    fresh
}

/// A PPS input: the time of each rising edge on the arrival clock (`Instant`, µs), the clock the link task stamps
/// frames with (`Pipeline::set_arrival_us`).
pub trait PpsInput {
    /// Waits for the next edge; returns its time.
    fn edge_us(&mut self) -> impl core::future::Future<Output = u64>;
}

/// Re-anchors spacecraft time on the whole second at each PPS edge (`Pipeline::pps`: edges before `SetTime`, off
/// the second or doubled are refused and counted; the counters go out with every periodic Health).
pub async fn pps_loop<B>(app: &App<B>, pps: &mut impl PpsInput) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
{
    loop {
        app.beat(TaskId::Pps).await;
        let Ok(edge_us) = with_timeout(EVENT_WAIT, pps.edge_us()).await else {
            continue;
        };
        match app.pipeline.lock().await.pps(edge_us) {
            Some(correction_us) => debug!("pps: time corrected by {:?} us", correction_us),
            None => debug!("pps: edge at {:?} us refused", edge_us),
        }
    }
}

/// Housekeeping, every [`HOUSEKEEPING_PERIOD`]: a [`HousekeepingReport`] (boot facts, error counters by kind, the
/// core's load from the cycle counter, the last calibration store); a Health report while the FPGA link delivers no
/// frame (with frames, the pipeline sends Health every `health_every` outputs), so that the ground sees a silent
/// FPGA; the CRC check of the calibration in RAM, which asks the storage task to reload it on a mismatch. Every
/// `log_every` periods it also logs link counters and a quick-look white-noise level of group 0's gyro x for a
/// human reading the log: micromath's root (≈ ±6 %), marked "≈", never sent — the ground gets exact variances.
pub async fn housekeeping_loop<B>(app: &App<B>, log_every: u32) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
{
    let mut ticker = Ticker::every(HOUSEKEEPING_PERIOD);
    let mut last_frames = None;
    let mut last_busy = app.busy_cycles.load(Ordering::Relaxed);
    let mut last_at = Instant::now();
    let mut n = 0u32;
    let mut crash_loop_over = false;
    let mut trim_window: Option<TrimWindow> = None;
    loop {
        ticker.next().await;
        app.beat(TaskId::Housekeeping).await;
        // The ADC conversions before the pipeline is locked: the link task need not wait for them.
        let sensors = app.platform.mcu_sensors.and_then(|read| read());
        let p = app.pipeline.lock().await;
        let link = *p.link_counters();
        let now = Instant::now();
        if last_frames == Some(link.frames) {
            app.route(Output::Telemetry(Telemetry::Health(p.health())));
            app.count(Counter::SilentHealth);
        }
        // The core's load over the period, from the cycle counter (if the board has one).
        let busy = app.busy_cycles.load(Ordering::Relaxed);
        // At the clock's rate now: a period across a clock switch is off by the switched part (one report).
        let core_hz = app.core_hz.load(Ordering::Relaxed);
        let load = app.platform.cycles.map(|_| {
            let cycles = busy.wrapping_sub(last_busy);
            let period_cycles = now
                .duration_since(last_at)
                .as_micros()
                .saturating_mul(u64::from(core_hz))
                / 1_000_000;
            let permille = u64::from(cycles).saturating_mul(1000)
                / NonZeroU64::new(period_cycles).unwrap_or(NonZeroU64::MIN);
            let frames = link.frames.wrapping_sub(last_frames.unwrap_or(link.frames));
            (
                u16::try_from(permille).unwrap_or(u16::MAX),
                cycles.checked_div(frames),
            )
        });
        (last_busy, last_at) = (busy, now);
        if let Some(trim) = app.platform.hsi_trim {
            trim_window = trim_hsi(app, &p, trim, trim_window, now);
        }
        last_frames = Some(link.frames);
        let hk = app.housekeeping(&p, now, load, sensors);
        app.route(Output::Telemetry(Telemetry::Housekeeping(hk)));
        if let Some(r) = app.platform.resets {
            app.route(Output::Telemetry(Telemetry::Resets(
                r.report(app.platform.boot.safe_mode),
            )));
            if !crash_loop_over && now.as_millis() >= u64::from(crate::resets::SHORT_RUN_MS) {
                r.end_crash_loop();
                crash_loop_over = true;
            }
        }
        app.route(Output::Telemetry(Telemetry::Update(
            app.update_status.lock(Cell::get),
        )));
        app.count(Counter::Housekeeping);
        if !p.calibration_intact() {
            error!("calibration: CRC check of the table in RAM failed; reloading from flash");
            app.reload.signal(());
        }
        let var = p.fusion().noise_var(0, shared::calib::GX);
        drop(p);
        n = n.wrapping_add(1);
        if log_every != 0 && n.is_multiple_of(log_every) {
            info!("link: {:?}", link);
            if let Some(v) = var {
                info!(
                    "group 0 gx white noise per frame ≈ {:?} °/s",
                    micromath::F32Ext::sqrt(v as f32) * 1e-6
                );
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::arithmetic_side_effects)]
mod hsi_tests {
    use super::*;

    /// The error against an f64 reference, and the trim's direction: an HSI 1 % fast (the core's clock counts
    /// 10.1 s while the crystal's frames say 10 s) steps down, one 1 % slow steps up, and the dead band holds.
    #[test]
    fn hsi_error_and_trim_step() {
        let base = PipelineConfig::DEFAULT.fpga_base_rate_millihz;
        // 6 048 frames at decimation 15: exactly 10 s of crystal time.
        let fpga_us = fpga_time_us(6_048, 15, base);
        let reference = 6_048.0 * 16.0 / (base as f64 / 1000.0) * 1e6;
        assert!(
            (fpga_us as f64 - reference).abs() <= 1.0,
            "{fpga_us} vs {reference}"
        );
        for (local_us, ppm) in [
            (10_100_000u64, 10_000i64),
            (9_900_000, -10_000),
            (10_002_000, 200),
        ] {
            let e = hsi_error_ppm(fpga_us, local_us).unwrap();
            let f64_ppm = (local_us as f64 / fpga_us as f64 - 1.0) * 1e6;
            assert!((e as f64 - f64_ppm).abs() < 1.0, "{e} vs {f64_ppm}");
            assert!((e - ppm).abs() <= 1, "{e}");
        }
        assert_eq!(next_hsi_trim(16, 10_000), 15);
        assert_eq!(next_hsi_trim(16, -10_000), 17);
        assert_eq!(next_hsi_trim(16, 2_000), 16);
        assert_eq!(next_hsi_trim(0, 10_000), 0);
        assert_eq!(next_hsi_trim(31, -10_000), 31);
        assert_eq!(hsi_error_ppm(0, 1), None);
    }
}
