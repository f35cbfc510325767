//! The firmware's task code, independent of the board, as a library: the flight binary (`src/main.rs`, feature
//! `stm32`) spawns these loops on the STM32F405, and the host build (feature `sim`, the default) runs the very same
//! loops on the PC with the hardware replaced at the edges ([`sim`]): the SITL binary and the scenario tests.
//!
//! - [`app`]: the tasks' loops, one file each, and the state they share ([`app::App`]).
//! - `chip` (features `chip`, `stm32`): the register-level code the bootloader shares (IWDG start, x32 flash
//!   erases).
//! - [`layout`]: the STM32F405 facts the loops, the models and the bootloader need (the flash memory map, the
//!   watchdog's timing, line rates, ring sizes, the calibration store's scratch and its longest stall, the stack the
//!   flight build leaves); it uses no other module of this crate.
//! - [`mcu_sensors`]: the MCU's temperature and VDDA from its ADC codes and factory calibration.
//! - [`resets`]: the reset history kept across resets, and the crash-loop counter.
//! - [`tasks`]: the task table, which loop each task runs with which edges of the board, for both builds.
//! - [`sim`] (host): the clock and executor (virtual or real time), UART lines, the flash model.
#![no_std]

#[cfg(all(feature = "sim", feature = "stm32"))]
compile_error!(
    "features `sim` (host) and `stm32` (flight) exclude each other: `cargo fw` builds the flight binary"
);

#[cfg(feature = "sim")]
extern crate std;

#[macro_use]
mod log;

pub mod app;
#[cfg(feature = "chip")]
pub mod chip;
pub mod layout;
pub mod mcu_sensors;
pub mod resets;
#[cfg(feature = "sim")]
pub mod sim;
pub mod tasks;
pub mod update;

/// The STM32 USART's receive errors as the link loop counts them (here, not in `board.rs`: the orphan rule wants
/// the trait's crate).
#[cfg(feature = "stm32")]
impl app::ClassifyRxError for embassy_stm32::usart::Error {
    fn classify(&self) -> app::RxFault {
        use embassy_stm32::usart::Error;
        match self {
            Error::Overrun => app::RxFault::Overrun,
            Error::Framing | Error::Noise | Error::Parity => app::RxFault::Line,
            _ => app::RxFault::Other,
        }
    }
}
