//! The `bus_rx` task: bus bytes in, commands to the pipeline and their replies to the reply queue, pings answered,
//! update requests passed to the storage task.

use embassy_time::with_timeout;
use embedded_io_async::Read;
use shared::bus::{BusEvent, BusNode};
use shared::pipeline::{Output, PipelineMemory};
use shared::telemetry::TaskId;

use super::IDLE_TIMEOUT;
use super::counters::Counter;
use super::state::{App, BusOut, ClassifyRxError, ErrorLog, RxFault, UpdateIn};
use crate::log::Loggable;

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
