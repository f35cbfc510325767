//! The hardware replaced at the edges (host only, feature `sim`), in the manner of PX4's SITL: the loops of
//! [`crate::app`] run unchanged; what they talk to is modelled here.
//!
//! | on the MCU | on the host |
//! |---|---|
//! | embassy-executor, TIM5 time driver | [`clock::run`]: one thread, virtual or real time |
//! | USART1 RX on a DMA ring (FPGA frames) | [`line::Line`] of 8 KiB: overruns when not read in time, injected errors |
//! | USART2 (bus), 115200 baud, RX on a 6.5 KiB DMA ring | [`line::Line`]s; the transmitter paced at 115200 baud |
//! | flash sectors 1–2 (16 KiB each) | [`flash`]: `shared`'s NOR model with the same sectors, optionally in a file; [`flash::Stalling`] stalls the CPU for the datasheet's erase and program times |
//! | IWDG, LED | a feed counter, a no-op pin |
//!
//! Not flight code: it allocates and uses std, and the no-panic lints are relaxed here for arithmetic on sizes and
//! positions of in-memory buffers (nothing from the link or the bus reaches it).
#![allow(clippy::arithmetic_side_effects, clippy::indexing_slicing)]

pub mod clock;
pub mod flash;
pub mod line;
pub mod node;

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
