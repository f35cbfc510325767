//! The state the tasks share ([`App`]: the pipeline, the queues between the tasks, heartbeats, counters) and the
//! messages on those queues; the heartbeat clock and the rate limit of receive-error logs the loops use.

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, AtomicU32, Ordering};

use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::Instant;
use shared::bus::csp::CspHeader;
use shared::bus::{BusConfig, BusCounters, MAX_PAYLOAD};
use shared::pipeline::{Output, Pipeline, PipelineConfig, PipelineMemory};
use shared::telemetry::{
    HealthReport, HousekeepingReport, RxErrorCounts, StoreOutcome, TaskId, Telemetry,
};
use shared::update::UpdateStatus;
use shared::wire::FpgaControl;

use super::counters::{AtomicCounters, Counter, ShellCounters};
use super::platform::{FW_COMMIT, Platform};
use super::{DEADLINES_MS, ERROR_LOG_EVERY, REPLY_QUEUE, TASKS, TELEMETRY_QUEUE};

type Raw = CriticalSectionRawMutex;

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

/// Everything the tasks share: the pipeline, the queues between the tasks, progress and counters.
///
/// On the MCU one `App` lives in a `static` (`&'static App<&'static mut PipelineMemory>`); on the host each run builds
/// its own, so scenarios never share state.
pub struct App<B> {
    /// The flight core.
    pub pipeline: Mutex<Raw, Pipeline<B>>,
    pub(super) bus: BusConfig,
    pub(super) telemetry: Channel<Raw, Telemetry, TELEMETRY_QUEUE>,
    pub(super) replies: Channel<Raw, BusOut, REPLY_QUEUE>,
    pub(super) fpga: Channel<Raw, FpgaControl, 4>,
    /// The tag of a committed upload to store.
    pub(super) persist: Signal<Raw, u16>,
    /// The calibration in RAM failed its CRC check: reload it from flash.
    pub(super) reload: Signal<Raw, ()>,
    /// Requests to the update service (`storage_loop` handles them).
    pub(super) update_in: Channel<Raw, UpdateIn, 1>,
    /// The update service's state, as the storage task last read it (for housekeeping).
    pub(super) update_status: BlockingMutex<Raw, Cell<UpdateStatus>>,
    /// Each task's last heartbeat, ms of uptime (wrapping).
    heartbeats: [AtomicU32; TASKS],
    /// Tasks the watchdog checks (bit i: [`TASKS`] order); all unless the board runs fewer (safe mode).
    monitored: AtomicU32,
    /// Fault injection: tasks that hang (await forever) at their next heartbeat (read only in a fault-injection
    /// build).
    #[cfg_attr(not(feature = "fault-injection"), allow(dead_code))]
    hang: AtomicU32,
    pub(super) counters: AtomicCounters,
    pub(super) bus_counters: BlockingMutex<Raw, Cell<BusCounters>>,
    pub(super) last_store: BlockingMutex<Raw, Cell<StoreOutcome>>,
    pub(super) platform: Platform,
    /// Cycles the link task spent processing frames (wrapping).
    pub(super) busy_cycles: AtomicU32,
    /// Bytes the link task has read (wrapping): `fpga_ctrl_loop` watches it for a quiet line.
    pub(super) link_bytes: AtomicU32,
    /// A calibration store ran (no task ran meanwhile): the link task drops what its ring holds.
    pub(super) link_stale: AtomicBool,
    /// The core clock's rate, Hz, as `fpga_ctrl_loop` last set it (0: not yet).
    pub(super) core_hz: AtomicU32,
    /// The HSI's error over the last trim window, ppm (`i32::MIN`: none).
    pub(super) hsi_error_ppm: core::sync::atomic::AtomicI32,
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
    pub(super) fn housekeeping(
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

    pub(super) fn count(&self, i: Counter) {
        if let Some(a) = self.counters.0.get(i as usize) {
            a.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// `task` is alive now (or, in a fault-injection build asked to hang it, never returns).
    pub(super) async fn beat(&self, task: TaskId) {
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
    pub(super) fn route(&self, o: Output) {
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
    pub(super) fn stamp(&self, t: Telemetry) -> Telemetry {
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
    pub(super) fn route_all(&self, p: &mut Pipeline<B>) {
        while let Some(o) = p.poll() {
            self.route(o);
        }
    }
}

/// Uptime, ms, wrapping (the heartbeats' clock).
pub(super) fn uptime_ms() -> u32 {
    #[allow(clippy::cast_possible_truncation)]
    // wrapping by design: deadlines compare with `wrapping_sub`
    let ms = Instant::now().as_millis() as u32;
    ms
}

/// Logs a receive error at most every [`ERROR_LOG_EVERY`] (a storm is counted, not logged: logging every byte's
/// error would cost more than the error).
pub(super) struct ErrorLog(pub(super) Option<Instant>);

impl ErrorLog {
    pub(super) fn due(&mut self) -> bool {
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
