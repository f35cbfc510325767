//! Logging that builds on both targets: `defmt` on the MCU (feature `defmt`), the `log` crate on the host (feature
//! `sim`), nothing in the bootloader's build of this crate. Format strings use `{:?}` (both backends accept it: defmt's `Format`, std's `Debug`), and the values
//! logged implement both ([`Loggable`]).

/// What a logged value must implement on this build.
#[cfg(feature = "defmt")]
pub trait Loggable: defmt::Format + core::fmt::Debug {}
#[cfg(feature = "defmt")]
impl<T: defmt::Format + core::fmt::Debug> Loggable for T {}

/// What a logged value must implement on this build.
#[cfg(not(feature = "defmt"))]
pub trait Loggable: core::fmt::Debug {}
#[cfg(not(feature = "defmt"))]
impl<T: core::fmt::Debug> Loggable for T {}

macro_rules! log_at {
    ($defmt:ident, $log:ident, $($arg:tt)*) => {{
        #[cfg(feature = "defmt")]
        defmt::$defmt!($($arg)*);
        #[cfg(all(not(feature = "defmt"), feature = "sim"))]
        ::log::$log!($($arg)*);
        // Neither (the bootloader's build of this crate, feature `chip`): the arguments are still used.
        #[cfg(not(any(feature = "defmt", feature = "sim")))]
        let _ = format_args!($($arg)*);
    }};
}

#[allow(unused_macros)] // kept beside its siblings for the next debug line
macro_rules! debug { ($($arg:tt)*) => { log_at!(debug, debug, $($arg)*) }; }
macro_rules! info { ($($arg:tt)*) => { log_at!(info, info, $($arg)*) }; }
macro_rules! warn { ($($arg:tt)*) => { log_at!(warn, warn, $($arg)*) }; }
macro_rules! error { ($($arg:tt)*) => { log_at!(error, error, $($arg)*) }; }
