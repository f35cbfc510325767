//! The `bus_tx` task: replies, telemetry and dump reports out on the bus, in that order of priority.

use embassy_futures::select::{Either, select};
use embassy_time::with_timeout;
use embedded_io_async::Write;
use shared::bus::{BusNode, MAX_WIRE_FRAME};
use shared::pipeline::PipelineMemory;
use shared::telemetry::TaskId;

use super::counters::Counter;
use super::state::{App, BusOut};
use super::{BUS_TX_TIMEOUT, IDLE_TIMEOUT};
use crate::log::Loggable;

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
