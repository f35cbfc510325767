//! The application, independent of the board: every loop is generic over `embedded_io_async::{Read, Write}`,
//! `embedded_hal::digital::OutputPin` and `embedded_storage::nor_flash::NorFlash`, so the same code runs on the
//! STM32F405 and, next, on an emulated Cortex-M4 in QEMU. All processing is `shared::Pipeline`'s; these loops
//! only move bytes and messages:
//!
//! ```text
//! FPGA RX ──► link_loop ──► Pipeline ◄── bus_rx_loop ◄── bus RX (commands, ping)
//!                 │            │ poll_dump              │
//!                 ▼            ▼                        ▼
//!            OUT channel ───────────────► bus_tx_loop ──► bus TX (telemetry, acks, ping replies)
//!            FPGA_CTRL ──► fpga_ctrl_loop ──► FPGA TX      PERSIST ──► storage_loop ──► flash
//! ```

use core::num::NonZeroU64;
use core::sync::atomic::{AtomicU32, Ordering};

use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use embassy_sync::channel::Channel;
use embassy_sync::mutex::Mutex;
use embassy_sync::signal::Signal;
use embassy_time::{Duration, Instant, Ticker, with_timeout};
use embedded_hal::digital::OutputPin;
use embedded_io_async::{Read, Write};
use embedded_storage::nor_flash::NorFlash;
use shared::bus::csp::CspHeader;
use shared::bus::{BusConfig, BusEvent, BusNode, MAX_PAYLOAD, MAX_WIRE_FRAME};
use shared::calib::encoded_len_max;
use shared::pipeline::{AllanBank, Output, Pipeline};
use shared::storage::CalStore;
use shared::telemetry::{MAX_MESSAGE_LEN, Telemetry, encode};
use shared::wire::FpgaControl;
use shared::wire::frame::GROUPS;

/// The pipeline as the tasks share it.
pub type SharedPipeline = Mutex<CriticalSectionRawMutex, Pipeline<&'static mut AllanBank>>;

/// Longest a loop may wait before it reports progress anyway (an idle line is not a fault, a stuck task is).
pub const IDLE_TIMEOUT: Duration = Duration::from_millis(100);
/// Bytes read from the FPGA ring per pass (a little over 4 frames).
pub const LINK_CHUNK: usize = 1024;
/// Scratch for the calibration store: record header, encoded table, CRC.
pub const CAL_SCRATCH: usize = encoded_len_max(GROUPS) + 16;

/// Something for the bus transmitter.
#[derive(Clone, Debug)]
pub enum BusOut {
    /// A telemetry message.
    Telemetry(Telemetry),
    /// A ping to answer.
    PingReply {
        /// The request's header.
        header: CspHeader,
        /// Its payload, echoed.
        payload: heapless::Vec<u8, MAX_PAYLOAD>,
    },
}

/// Messages for the bus transmitter.
pub static OUT: Channel<CriticalSectionRawMutex, BusOut, 8> = Channel::new();
/// Control messages for the FPGA.
pub static FPGA_CTRL: Channel<CriticalSectionRawMutex, FpgaControl, 4> = Channel::new();
/// "Store the calibration in force."
pub static PERSIST: Signal<CriticalSectionRawMutex, ()> = Signal::new();

/// Task progress counters, checked by the watchdog loop.
pub static PROGRESS: [AtomicU32; 3] = [AtomicU32::new(0), AtomicU32::new(0), AtomicU32::new(0)];
/// Index of the FPGA link loop's counter.
pub const PROGRESS_LINK: usize = 0;
/// Index of the bus receiver's counter.
pub const PROGRESS_BUS_RX: usize = 1;
/// Index of the bus transmitter's counter.
pub const PROGRESS_BUS_TX: usize = 2;

fn progress(i: usize) {
    if let Some(p) = PROGRESS.get(i) {
        p.fetch_add(1, Ordering::Relaxed);
    }
}

/// Receive-error classes; the board maps its UART's error type onto these (`embedded_io::ErrorKind` says only
/// `Other` for every embassy-stm32 USART error).
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
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

/// Sends one pipeline output where it belongs.
async fn route(o: Output) {
    match o {
        Output::Telemetry(t) => OUT.send(BusOut::Telemetry(t)).await,
        Output::Fpga(c) => FPGA_CTRL.send(c).await,
        Output::PersistCalibration => PERSIST.signal(()),
    }
}

/// Routes every queued output, one lock per output, never holding the lock while waiting for channel space.
async fn drain(pipeline: &SharedPipeline) {
    loop {
        let next = pipeline.lock().await.poll();
        match next {
            Some(o) => route(o).await,
            None => return,
        }
    }
}

/// FPGA frames in: read the DMA ring, feed the pipeline, route its outputs. Receive errors are counted and never
/// fatal: the driver restarts reception on the next read, and the frame decoder resynchronises.
pub async fn link_loop<R>(rx: &mut R, pipeline: &SharedPipeline) -> !
where
    R: Read,
    R::Error: ClassifyRxError + defmt::Format,
{
    let mut buf = [0u8; LINK_CHUNK];
    let mut line_errors = 0u32;
    loop {
        progress(PROGRESS_LINK);
        let n = match with_timeout(IDLE_TIMEOUT, rx.read(&mut buf)).await {
            Err(_idle) => continue,
            Ok(Ok(n)) => n,
            Ok(Err(e)) => {
                match e.classify() {
                    RxFault::Overrun => pipeline.lock().await.note_link_overruns(1),
                    RxFault::Line | RxFault::Other => line_errors = line_errors.wrapping_add(1),
                }
                defmt::warn!("fpga link: rx error {} (line errors {})", e, line_errors);
                continue;
            }
        };
        let mut input = buf.get(..n).unwrap_or(&[]);
        while !input.is_empty() {
            {
                let mut p = pipeline.lock().await;
                p.set_uptime_ms(Instant::now().as_millis());
                p.push_link(&mut input);
            }
            drain(pipeline).await;
        }
    }
}

/// Bus bytes in: commands go to the pipeline (their acks are routed at once, even if the FPGA link is down), pings
/// are answered.
pub async fn bus_rx_loop<R>(rx: &mut R, pipeline: &SharedPipeline, config: BusConfig) -> !
where
    R: Read,
    R::Error: defmt::Format,
{
    let mut node = BusNode::new(config);
    let mut buf = [0u8; 256];
    loop {
        progress(PROGRESS_BUS_RX);
        let n = match with_timeout(IDLE_TIMEOUT, rx.read(&mut buf)).await {
            Err(_idle) => continue,
            Ok(Ok(n)) => n,
            Ok(Err(e)) => {
                defmt::warn!("bus: rx error {}", e);
                continue;
            }
        };
        let mut input = buf.get(..n).unwrap_or(&[]);
        while let Some(event) = node.receive(&mut input) {
            match event {
                BusEvent::Command(payload) => {
                    pipeline.lock().await.handle_command(payload);
                    drain(pipeline).await;
                }
                BusEvent::Ping { header, payload } => {
                    let payload = heapless::Vec::from_slice(payload).unwrap_or_default();
                    OUT.send(BusOut::PingReply { header, payload }).await;
                }
            }
        }
        let c = node.counters();
        if c.kiss_errors != 0 || c.csp_errors != 0 {
            defmt::debug!("bus: {}", c);
        }
    }
}

/// Bus bytes out: telemetry and ping replies as CSP packets in KISS frames. When nothing is queued it pulls the next
/// report of a requested dump from the pipeline, so dumps go exactly as fast as the bus drains.
pub async fn bus_tx_loop<W>(tx: &mut W, pipeline: &SharedPipeline, config: BusConfig) -> !
where
    W: Write,
    W::Error: defmt::Format,
{
    let node = BusNode::new(config);
    let mut payload = [0u8; MAX_MESSAGE_LEN];
    let mut wire = [0u8; MAX_WIRE_FRAME];
    loop {
        progress(PROGRESS_BUS_TX);
        let item = match OUT.try_receive() {
            Ok(item) => item,
            Err(_) => {
                let dump = pipeline.lock().await.poll_dump();
                match dump {
                    Some(t) => BusOut::Telemetry(t),
                    None => match with_timeout(IDLE_TIMEOUT, OUT.receive()).await {
                        Ok(item) => item,
                        Err(_idle) => continue,
                    },
                }
            }
        };
        let frame = match &item {
            BusOut::Telemetry(t) => encode(t, &mut payload)
                .map_err(|_| ())
                .and_then(|p| node.encode_telemetry(p, &mut wire).map_err(|_| ())),
            BusOut::PingReply { header, payload } => node
                .encode_reply(header, payload, &mut wire)
                .map_err(|_| ()),
        };
        match frame {
            Ok(n) => {
                if let Err(e) = tx.write_all(wire.get(..n).unwrap_or(&[])).await {
                    defmt::warn!("bus: tx error {}", e);
                }
            }
            Err(()) => defmt::error!("bus: a message did not fit a frame"),
        }
    }
}

/// Control messages to the FPGA.
pub async fn fpga_ctrl_loop<W>(tx: &mut W) -> !
where
    W: Write,
    W::Error: defmt::Format,
{
    loop {
        let msg = FPGA_CTRL.receive().await;
        defmt::info!("fpga: {}", msg);
        if let Err(e) = tx.write_all(&msg.to_bytes()).await {
            defmt::warn!("fpga: control tx error {}", e);
        }
    }
}

/// Loads the stored calibration into the pipeline (newest valid record, else the factory default).
pub fn load_calibration<F: NorFlash>(
    store: &mut CalStore<F>,
    pipeline: &mut Pipeline<&'static mut AllanBank>,
) where
    F::Error: defmt::Format,
{
    let mut scratch = [0u8; CAL_SCRATCH];
    match store.load::<GROUPS>(&mut scratch) {
        Ok(loaded) => {
            let source = match loaded.seq {
                Some(_) => shared::telemetry::CalSource::Stored,
                None => shared::telemetry::CalSource::Factory,
            };
            defmt::info!(
                "calibration: id {} from {} (seq {}, slots {})",
                loaded.table.cal_id,
                source,
                loaded.seq,
                loaded.slots
            );
            pipeline.load_calibration(loaded.table, source);
        }
        Err(e) => defmt::error!("calibration: flash read failed ({}), factory default", e),
    }
}

/// Persists the calibration in force whenever an upload is committed.
pub async fn storage_loop<F: NorFlash>(store: &mut CalStore<F>, pipeline: &SharedPipeline) -> !
where
    F::Error: defmt::Format,
{
    let mut scratch = [0u8; CAL_SCRATCH];
    loop {
        PERSIST.wait().await;
        let table = *pipeline.lock().await.calibration();
        // The erase stalls the CPU (single-bank flash): FPGA bytes arriving meanwhile overrun the ring and are
        // counted; the watchdog timeout covers the stall.
        match store.store(&table, &mut scratch) {
            Ok(seq) => defmt::info!("calibration: id {} stored as record {}", table.cal_id, seq),
            Err(e) => defmt::error!("calibration: store failed: {}", e),
        }
    }
}

/// Feeds the watchdog only while every task makes progress, and blinks the LED when it does.
pub async fn watchdog_loop<L: OutputPin>(
    period: Duration,
    mut feed: impl FnMut(),
    led: &mut L,
) -> ! {
    let mut last = [0u32; 3];
    let mut ticker = Ticker::every(period);
    loop {
        ticker.next().await;
        let mut all = true;
        for (p, l) in PROGRESS.iter().zip(last.iter_mut()) {
            let now = p.load(Ordering::Relaxed);
            all &= now != *l;
            *l = now;
        }
        if all {
            feed();
            let period_ms = NonZeroU64::new(period.as_millis()).unwrap_or(NonZeroU64::MIN);
            let _ = led.set_state(
                (Instant::now().as_millis() / period_ms)
                    .is_multiple_of(2)
                    .into(),
            );
        } else {
            defmt::warn!("watchdog: a task made no progress, not feeding");
        }
    }
}

/// Logs link health every `period`, with a quick-look white-noise level of the fused gyro x for a human reading the
/// log. The root is micromath's (approximate, ≈ ±6 %): marked "≈", never sent as telemetry — the ground gets exact
/// variances and takes roots itself.
pub async fn stats_loop(pipeline: &SharedPipeline, period: Duration) -> ! {
    use micromath::F32Ext;
    let mut ticker = Ticker::every(period);
    loop {
        ticker.next().await;
        let p = pipeline.lock().await;
        let link = *p.link_counters();
        let var = p.fusion().noise_var(0, shared::calib::GX);
        drop(p);
        defmt::info!("link: {}", link);
        if let Some(v) = var {
            defmt::info!(
                "group 0 gx white noise per frame ≈ {} °/s",
                (v as f32).sqrt() * 1e-6
            );
        }
    }
}
