//! The `pps` task: spacecraft time re-anchored on the whole second at each edge of the PPS input ([`PpsInput`]).

use embassy_time::with_timeout;
use shared::pipeline::PipelineMemory;
use shared::telemetry::TaskId;

use super::EVENT_WAIT;
use super::state::App;

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
