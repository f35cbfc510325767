//! What the board offers the shell besides its peripherals ([`Platform`]): the boot facts, a cycle counter, the
//! MCU's sensors, the reset history, the receive errors its handlers took, the HSI's trim and a reset; and the
//! firmware's own identity ([`FW_COMMIT`]). On the host each is absent unless a test sets it.

use shared::telemetry::{ClockSource, ResetHistory, RxErrorCounts};

/// What the board knows at boot, reported in every [`HousekeepingReport`](shared::telemetry::HousekeepingReport).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct BootInfo {
    /// Reset flags (RCC_CSR bits 25–31, shifted down; see
    /// [`HousekeepingReport::reset_flags`](shared::telemetry::HousekeepingReport::reset_flags)).
    pub reset_flags: u8,
    /// The boot counter (0: no reset history on this platform).
    pub boot_count: u32,
    /// Booted in safe mode (crash loop): factory calibration, no FPGA tasks.
    pub safe_mode: bool,
    /// Where the system clock comes from (`None`: not known).
    pub clock_source: Option<ClockSource>,
    /// RCC_CR.HSITRIM in force.
    pub hsi_trim: u8,
    /// The brown-out reset level of the option bytes.
    pub bor_level: Option<u8>,
}

/// The reset history kept across resets (`crate::resets`), as the tasks reach it.
pub trait ResetLog: Sync {
    /// The history now.
    fn report(&self, safe_mode: bool) -> ResetHistory;
    /// `ClearResets`: records and the crash-loop counter cleared.
    fn clear(&self);
    /// Notes the uptime, for the record of a reset that leaves none; `fed`: the watchdog was fed this period, so a
    /// deadline miss the monitor filed earlier did not lead to a reset (withdrawn).
    fn note_uptime(&self, uptime_ms: u32, fed: bool);
    /// This boot outlived the short-run time: the crash loop is over.
    fn end_crash_loop(&self);
}

/// Receive errors the board's interrupt handlers took before the drivers saw them (`board.rs`: the errors never stop
/// the DMA rings), added to the shell's own counts in housekeeping.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct UartErrors {
    /// FPGA link.
    pub link: RxErrorCounts,
    /// Bus.
    pub bus: RxErrorCounts,
    /// DMA transfer errors.
    pub dma: u32,
}

/// The HSI's trim, offered by the board only while the core runs on the HSI (`board.rs`).
#[derive(Debug, Clone, Copy)]
pub struct HsiTrim {
    /// RCC_CR.HSITRIM now (0–31).
    pub read: fn() -> u8,
    /// Sets RCC_CR.HSITRIM.
    pub write: fn(u8),
}

/// What the board offers the shell besides its peripherals (nothing, on the host, unless a test sets it).
#[derive(Clone, Copy, Default)]
pub struct Platform {
    /// What the board knew at boot (reset flags, a recorded fault).
    pub boot: BootInfo,
    /// A cycle counter, for the core's load in housekeeping (at the rate the [`CoreClock`](super::CoreClock)
    /// reports).
    pub cycles: Option<CycleCounter>,
    /// A reader of the MCU's temperature (0.01 °C) and VDDA (mV), for housekeeping and the store's VDD check.
    pub mcu_sensors: Option<McuSensorReader>,
    /// The reset history.
    pub resets: Option<&'static dyn ResetLog>,
    /// Receive errors taken by the board's interrupt handlers.
    pub uart_errors: Option<fn() -> UartErrors>,
    /// The HSI's trim, while the core runs on the HSI: housekeeping trims it against the FPGA's frame rate.
    pub hsi_trim: Option<HsiTrim>,
    /// Resets the MCU, recording a commanded reset (the update service's `Reset`; on the MCU it never returns).
    pub reset: Option<fn()>,
}

impl core::fmt::Debug for Platform {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("Platform")
            .field("boot", &self.boot)
            .field("cycles", &self.cycles)
            .field("mcu_sensors", &self.mcu_sensors)
            .field("resets", &self.resets.map(|_| ".."))
            .field("uart_errors", &self.uart_errors)
            .field("hsi_trim", &self.hsi_trim)
            .field("reset", &self.reset.is_some())
            .finish()
    }
}

impl Platform {
    /// Nothing known, nothing offered (`Default`, usable in `const`).
    pub const NONE: Self = Self {
        boot: BootInfo {
            reset_flags: 0,
            boot_count: 0,
            safe_mode: false,
            clock_source: None,
            hsi_trim: 0,
            bor_level: None,
        },
        cycles: None,
        mcu_sensors: None,
        resets: None,
        uart_errors: None,
        hsi_trim: None,
        reset: None,
    };
}

/// Reads the MCU's (temperature in 0.01 °C, VDDA in mV); `None` when it cannot.
pub type McuSensorReader = fn() -> Option<(i16, u16)>;

/// A free-running CPU cycle counter (the DWT's on the MCU), for the core's load; it counts at the core clock's
/// rate, which [`CoreClock`](super::CoreClock) reports.
#[derive(Debug, Clone, Copy)]
pub struct CycleCounter {
    /// Reads the counter.
    pub now: fn() -> u32,
}

/// The firmware's git commit (first 8 hex digits as a number; 0 outside git) and whether the tree was dirty, from
/// `build.rs`.
pub const FW_COMMIT: (u32, bool) = (
    match u32::from_str_radix(env!("FW_COMMIT"), 16) {
        Ok(c) => c,
        Err(_) => 0,
    },
    matches!(env!("FW_DIRTY").as_bytes(), b"1"),
);
