//! The simulated board: the lines and the watchdog around one [`App`], and [`tasks`], every firmware loop of the
//! task table ([`crate::task_table!`]) joined into one future — what `main.rs` spawns on the MCU, with the same
//! arguments. The SITL binary and the scenario
//! tests both run the firmware through this.

use core::sync::atomic::{AtomicU32, Ordering};

use embassy_futures::join::join;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_time::{Duration, Instant, Timer};
use embedded_storage::nor_flash::NorFlash;
use shared::pipeline::PipelineMemory;
use shared::storage::CalStore;
use shared::wire::FrameClock;
use shared::wire::frame::FRAME_LEN;

use super::NoPin;
use super::line::Line;
use crate::app::{self, App};
use crate::layout::{BUS_BAUD, BUS_RX_RING_LEN, FPGA_RX_RING_LEN};
use crate::log::Loggable;
use crate::tasks::Edges;
use crate::update::Updater;

/// The FPGA sending `log` frame by frame at decimation N (a frame every N + 1 ticks of its base clock at
/// `base_rate_millihz`), frame k at the frame clock's time of its k·(N + 1)-th tick from now (the time the pipeline
/// gives it, to the µs, without a rounded period's drift), whether or not the firmware runs: after a CPU stall
/// ([`super::clock::stall`]) every frame that came due meanwhile arrives at once, and what the ring cannot hold is
/// lost, as on the MCU. Returns when the log is sent.
pub async fn fpga_play(board: &Board, log: &[u8], decimation: u16, base_rate_millihz: u64) {
    let t0 = Instant::now();
    let ticks = u64::from(decimation).saturating_add(1);
    let due = |k: usize| {
        let k_ticks = u64::try_from(k).unwrap_or(u64::MAX).saturating_mul(ticks);
        t0 + Duration::from_micros(FrameClock::ticks_to_us(k_ticks, base_rate_millihz))
    };
    let mut frames = log.chunks(FRAME_LEN).enumerate().peekable();
    while let Some(&(k, _)) = frames.peek() {
        Timer::at(due(k)).await;
        let now = Instant::now();
        while let Some((_, f)) = frames.next_if(|&(k, _)| due(k) <= now) {
            board.fpga_rx.push(f);
        }
    }
}

/// The edges of the board.
pub struct Board {
    /// FPGA → MCU: the DMA ring of USART1.
    pub fpga_rx: Line,
    /// MCU → FPGA: control messages.
    pub fpga_tx: Line,
    /// Ground → MCU: the DMA ring of USART2.
    pub bus_rx: Line,
    /// MCU → ground: what the bus transmitter has put on the wire.
    pub bus_tx: Line,
    /// Bus transmit rate (`None`: as fast as the task writes).
    pub bus_baud: Option<u32>,
    /// Times the watchdog was fed.
    pub watchdog_feeds: AtomicU32,
    /// PPS edges, as the flight board's input capture reports them (time on embassy's clock, µs).
    pub pps: Channel<CriticalSectionRawMutex, u64, 4>,
    /// The simulated core clock's rate, Hz (0 before the firmware set it).
    pub core_hz: AtomicU32,
}

/// The simulated core clock: the flight board's two rates (`board::CoreClock`: HCLK 168 MHz, 84 MHz when low).
pub struct SimCoreClock<'a>(&'a AtomicU32);

impl SimCoreClock<'_> {
    /// The full rate, Hz.
    pub const FULL_HZ: u32 = 168_000_000;
}

impl app::CoreClock for SimCoreClock<'_> {
    fn set_low(&mut self, low: bool) -> u32 {
        let hz = if low {
            Self::FULL_HZ / 2
        } else {
            Self::FULL_HZ
        };
        self.0.store(hz, Ordering::Relaxed);
        hz
    }
}

/// The simulated PPS input: edges sent with [`Board::pps_edge`].
pub struct SimPps<'a>(&'a Channel<CriticalSectionRawMutex, u64, 4>);

impl app::PpsInput for SimPps<'_> {
    async fn edge_us(&mut self) -> u64 {
        self.0.receive().await
    }
}

impl Board {
    /// The flight board's buffers, the bus at 115200 baud.
    pub fn new() -> Self {
        Self::with_bus_baud(Some(BUS_BAUD))
    }

    /// The flight board's buffers, the bus transmitter at `bus_baud`.
    pub fn with_bus_baud(bus_baud: Option<u32>) -> Self {
        Self {
            fpga_rx: Line::new(FPGA_RX_RING_LEN),
            fpga_tx: Line::new(1 << 16),
            bus_rx: Line::new(BUS_RX_RING_LEN),
            bus_tx: Line::new(1 << 20),
            bus_baud,
            watchdog_feeds: AtomicU32::new(0),
            pps: Channel::new(),
            core_hz: AtomicU32::new(0),
        }
    }

    /// A PPS edge now (dropped if the firmware has not taken the last four).
    pub fn pps_edge(&self) {
        let _ = self.pps.try_send(Instant::now().as_micros());
    }

    /// Times the watchdog was fed so far.
    pub fn feeds(&self) -> u32 {
        self.watchdog_feeds.load(Ordering::Relaxed)
    }
}

impl Default for Board {
    fn default() -> Self {
        Self::new()
    }
}

/// The simulated IWDG: counts the feeds in [`Board::watchdog_feeds`].
pub struct SimWatchdog<'a>(&'a AtomicU32);

impl SimWatchdog<'_> {
    /// Feeds it.
    pub fn pet(&mut self) {
        self.0.fetch_add(1, Ordering::Relaxed);
    }
}

/// Joins every loop of the task table ([`crate::task_table!`]) into one future, each with its edges.
macro_rules! join_tasks {
    ({ $app_val:ident, $edges:ident } |$app:ident| $($name:ident($($edge:ident: $ty:ty),*) => $body:expr;)*) => {{
        let $app = $app_val;
        join_all!($({
            $(#[allow(unused_mut)] let mut $edge = $edges.$edge;)*
            async move { $body.await }
        }),*)
    }};
}

/// `join(a, join(b, …))`.
macro_rules! join_all {
    ($last:expr) => { $last };
    ($first:expr, $($rest:expr),+) => { join($first, join_all!($($rest),+)) };
}

/// Every firmware loop over `board`, `store` and `update`, joined (never returns: drop it to stop the firmware).
pub async fn tasks<B, F, D, S>(
    app: &App<B>,
    board: &Board,
    store: &mut CalStore<F>,
    update: &mut Updater<D, S>,
) where
    B: core::borrow::BorrowMut<PipelineMemory>,
    F: NorFlash,
    F::Error: Loggable,
    D: NorFlash,
    S: NorFlash,
{
    let edges = Edges {
        fpga_rx: board.fpga_rx.rx(),
        fpga_tx: board.fpga_tx.writer(None),
        core_clock: SimCoreClock(&board.core_hz),
        bus_rx: board.bus_rx.rx(),
        bus_tx: board.bus_tx.writer(board.bus_baud),
        store,
        update,
        watchdog: SimWatchdog(&board.watchdog_feeds),
        led: NoPin,
        pps: SimPps(&board.pps),
    };
    let _ = crate::task_table!(join_tasks { app, edges }).await;
}
