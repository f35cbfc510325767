//! The hardware replaced at the edges (host only, feature `sim`), in the manner of PX4's SITL: the loops of
//! [`crate::app`] run unchanged; what they talk to is modelled here.
//!
//! | on the MCU | on the host |
//! |---|---|
//! | embassy-executor, TIM5 time driver | [`clock::run`]: one thread, virtual or real time |
//! | USART1 RX on a DMA ring (FPGA frames) | [`line::Line`] of 8 KiB: overruns when not read in time, injected errors |
//! | USART2 (bus), 115200 baud, RX on a 6.5 KiB DMA ring | [`line::Line`]s; the transmitter paced at 115200 baud |
//! | flash sectors 2–3 (16 KiB each) | [`flash`]: `shared`'s NOR model with the same sectors, optionally in a file; [`flash::Stalling`] stalls the CPU for the datasheet's erase and program times |
//! | IWDG, LED | a feed counter, a no-op pin |
//! | the reset history in no-init RAM (`fault.rs`) | [`SimResets`]: the same [`crate::resets::Persist`] behind a mutex |
//!
//! Not flight code: it allocates and uses std, and the no-panic lints are relaxed here for arithmetic on sizes and
//! positions of in-memory buffers (nothing from the link or the bus reaches it).
#![allow(clippy::arithmetic_side_effects, clippy::indexing_slicing)]

pub mod clock;
pub mod flash;
pub mod line;
pub mod node;

/// The reset history on the host: the flight code's [`crate::resets::Persist`] behind a mutex (a test files resets
/// into it with [`crate::resets::Persist::boot`] before it hands it to the app).
#[derive(Debug)]
pub struct SimResets(pub std::sync::Mutex<crate::resets::Persist>);

impl SimResets {
    fn with<R>(&self, f: impl FnOnce(&mut crate::resets::Persist) -> R) -> R {
        f(&mut self
            .0
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner))
    }
}

impl crate::app::ResetLog for SimResets {
    fn report(&self, safe_mode: bool) -> shared::telemetry::ResetHistory {
        self.with(|p| p.report(safe_mode))
    }
    fn clear(&self) {
        self.with(crate::resets::Persist::clear);
    }
    fn note_uptime(&self, uptime_ms: u32, fed: bool) {
        self.with(|p| {
            p.note_uptime(uptime_ms);
            if fed {
                p.cancel(crate::resets::Kind::Watchdog);
            }
        });
    }
    fn end_crash_loop(&self) {
        self.with(crate::resets::Persist::end_crash_loop);
    }
}

/// A pin that does nothing (the status LED).
#[derive(Debug, Default)]
pub struct NoPin;

impl embedded_hal::digital::ErrorType for NoPin {
    type Error = core::convert::Infallible;
}

impl embedded_hal::digital::OutputPin for NoPin {
    fn set_low(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
    fn set_high(&mut self) -> Result<(), Self::Error> {
        Ok(())
    }
}
