//! The shell's counters (the pipeline counts everything else): [`ShellCounters`], the snapshot housekeeping
//! reports, and the atomic counters behind it that the tasks increment ([`App`](super::App)'s `count`).

use core::sync::atomic::{AtomicU32, Ordering};

/// Declares the shell's counters once: the public snapshot [`ShellCounters`] (one field each), the `Counter` that
/// names them, and the `AtomicCounters` the tasks increment (both private to `app`).
macro_rules! shell_counters {
    ($($(#[$doc:meta])* $field:ident: $variant:ident,)*) => {
        /// Counters of the shell (the pipeline counts everything else); wrapping.
        #[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
        #[cfg_attr(feature = "defmt", derive(defmt::Format))]
        pub struct ShellCounters {
            $($(#[$doc])* pub $field: u32,)*
        }

        #[derive(Clone, Copy)]
        pub(super) enum Counter {
            $($variant,)*
        }

        impl Counter {
            const COUNT: usize = [$(Counter::$variant),*].len();
        }

        pub(super) struct AtomicCounters(pub(super) [AtomicU32; Counter::COUNT]);

        impl AtomicCounters {
            pub(super) const fn new() -> Self {
                Self([const { AtomicU32::new(0) }; Counter::COUNT])
            }

            pub(super) fn get(&self, c: Counter) -> u32 {
                self.0.get(c as usize).map_or(0, |a| a.load(Ordering::Relaxed))
            }

            pub(super) fn snapshot(&self) -> ShellCounters {
                ShellCounters {
                    $($field: self.get(Counter::$variant),)*
                }
            }
        }
    };
}

shell_counters! {
    /// FPGA receive overruns: the UART driver's, plus one per ring dropped after a flash stall (reported in health
    /// as `link.overruns` and in housekeeping).
    link_overruns: LinkOverrun,
    /// FPGA receive errors: framing, noise or parity.
    link_line_errors: LinkLine,
    /// FPGA receive errors of any other kind.
    link_other_errors: LinkOther,
    /// Telemetry messages dropped because the bus queue was full (added to health's `telemetry_dropped`, with the
    /// pipeline's own outbox overflows).
    telemetry_dropped: TelemetryDropped,
    /// Bus receive errors: overrun (UART or DMA ring).
    bus_rx_overruns: BusRxOverrun,
    /// Bus receive errors: framing, noise or parity.
    bus_rx_line_errors: BusRxLine,
    /// Bus receive errors of any other kind.
    bus_rx_other_errors: BusRxOther,
    /// Bus transmit errors.
    bus_tx_errors: BusTx,
    /// FPGA control messages dropped (queue full).
    fpga_ctrl_dropped: FpgaDropped,
    /// Calibration records stored.
    cal_stores: CalStores,
    /// Calibration stores that failed.
    cal_store_errors: CalStoreErrors,
    /// Health reports sent because the link was silent.
    silent_health: SilentHealth,
    /// Housekeeping reports sent.
    housekeeping: Housekeeping,
    /// Times the calibration in RAM failed its CRC check and was reloaded from flash.
    cal_ram_repairs: CalRamRepairs,
    /// Times the core clock stayed full after a stop because FPGA bytes kept arriving.
    clock_kept: ClockKept,
    /// Control messages to the FPGA that did not leave within [`FPGA_TX_TIMEOUT`](super::FPGA_TX_TIMEOUT) (or failed).
    fpga_tx_errors: FpgaTx,
    /// Calibration stores refused because VDD was below the x32 programming minimum.
    stores_refused_low_vdd: LowVdd,
    /// Periods the watchdog did not feed the IWDG because a task was late.
    watchdog_misses: WatchdogMiss,
}
