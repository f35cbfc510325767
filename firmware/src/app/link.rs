//! The `fpga_link` task: FPGA frames from the DMA ring into the pipeline, its outputs routed without waiting; the
//! ring dropped after a flash stall.

use core::sync::atomic::Ordering;

use embassy_time::{Duration, Instant, with_timeout};
use embedded_io_async::Read;
use shared::pipeline::PipelineMemory;
use shared::telemetry::TaskId;

use super::counters::Counter;
use super::state::{App, ClassifyRxError, ErrorLog, RxFault};
use super::{IDLE_TIMEOUT, LINK_CHUNK};
use crate::layout::FPGA_RX_RING_LEN;
use crate::log::Loggable;

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
