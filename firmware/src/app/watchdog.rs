//! The `watchdog` task: feeds the IWDG only while every task beats within its deadline, notes the uptime for the
//! reset history, blinks the LED.

use core::num::NonZeroU64;

use embassy_time::{Duration, Instant, Ticker};
use embedded_hal::digital::OutputPin;
use shared::pipeline::PipelineMemory;
use shared::telemetry::TaskId;

use super::counters::Counter;
use super::state::{App, uptime_ms};

/// Feeds the watchdog only while every task's heartbeat is within its deadline
/// ([`DEADLINES_MS`](super::DEADLINES_MS)), notes the uptime for the reset history, and blinks the LED while it
/// feeds.
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
