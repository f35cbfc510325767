//! The `fpga_ctrl` task: control messages to the FPGA, and the core clock that follows the stream ([`CoreClock`]:
//! lowered only once the FPGA line is quiet after a stop).

use core::sync::atomic::Ordering;

use embassy_time::{Duration, Instant, Timer, with_timeout};
use embedded_io_async::Write;
use shared::pipeline::PipelineMemory;
use shared::telemetry::TaskId;
use shared::wire::FpgaControl;

use super::counters::Counter;
use super::state::App;
use super::{EVENT_WAIT, FPGA_TX_TIMEOUT};
use crate::log::Loggable;

/// The core clock: full speed while frames stream, lowered while the FPGA stream is stopped (`Mode::Idle`), with
/// the peripherals' clocks unchanged (`board::CoreClock`).
pub trait CoreClock {
    /// Sets the low (`true`) or the full clock; returns the core clock's rate after, Hz.
    fn set_low(&mut self, low: bool) -> u32;
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
