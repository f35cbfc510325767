//! The firmware's tasks, listed once: which loop of [`crate::app`] each task runs, what it takes from the board
//! ([`Edges`]) and with which constants. The flight binary (`main.rs`) expands [`task_table!`](crate::task_table)
//! into one embassy task per line and their spawns; the SITL (`sim::node::tasks`) into one future joining the same
//! loops. A task added here runs in both, with the same arguments.

/// What the tasks take from the board, one field per edge (the flight board's peripherals, or the SITL's models).
/// Each field goes to exactly one task of [`task_table!`](crate::task_table), which names it.
pub struct Edges<FpgaRx, FpgaTx, CoreClock, BusRx, BusTx, Store, Update, Watchdog, Led, Pps> {
    /// FPGA → MCU: frames (USART1's DMA ring).
    pub fpga_rx: FpgaRx,
    /// MCU → FPGA: control messages.
    pub fpga_tx: FpgaTx,
    /// The core clock, lowered while the stream is stopped ([`crate::app::CoreClock`]).
    pub core_clock: CoreClock,
    /// Ground → MCU: bus bytes (USART2's DMA ring).
    pub bus_rx: BusRx,
    /// MCU → ground: bus bytes.
    pub bus_tx: BusTx,
    /// The calibration store (its two flash sectors, `layout::CAL_FLASH_BASE`).
    pub store: Store,
    /// The update service's flash: the DFU slot and the boot state ([`crate::update::Updater`]).
    pub update: Update,
    /// The independent watchdog: `pet()` reloads it.
    pub watchdog: Watchdog,
    /// The status LED.
    pub led: Led,
    /// The PPS input ([`crate::app::PpsInput`]).
    pub pps: Pps,
}

/// Calls `$then!` with the task table: `{ ARGS } |app| name(edge: Type, …) => loop call;` per task, where `ARGS`
/// are passed through unchanged, each `edge` is a field of [`Edges`] (bound mutably under its own name), `Type` its
/// type as the flight binary names it, and the loop call uses `app` (`&App`) and the edges.
#[macro_export]
macro_rules! task_table {
    ($then:ident { $($args:tt)* }) => {
        $then! {
            { $($args)* }
            |app|
            fpga_link(fpga_rx: FpgaRx) => $crate::app::link_loop(app, &mut fpga_rx);
            fpga_ctrl(fpga_tx: FpgaTx, core_clock: CoreClock) =>
                $crate::app::fpga_ctrl_loop(app, &mut fpga_tx, &mut core_clock);
            bus_rx(bus_rx: BusRx) => $crate::app::bus_rx_loop(app, &mut bus_rx);
            bus_tx(bus_tx: BusTx) => $crate::app::bus_tx_loop(app, &mut bus_tx);
            storage(store: Store, update: Update) => $crate::app::storage_loop(app, store, update);
            watchdog(watchdog: Watchdog, led: Led) =>
                $crate::app::watchdog_loop(app, $crate::app::WATCHDOG_PERIOD, || watchdog.pet(), &mut led);
            housekeeping() => $crate::app::housekeeping_loop(app, $crate::app::LOG_EVERY);
            pps(pps: Pps) => $crate::app::pps_loop(app, &mut pps);
        }
    };
}
