//! IMU cluster firmware for the STM32F405RG: a thin shell over `shared::Pipeline`.
//!
//! `main` configures the board, loads the calibration and spawns the tasks; each task is a few lines that hand its
//! peripherals to a board-independent loop in `firmware::app` (embassy tasks cannot be generic; the same loops run
//! on the PC in the SITL and the scenario tests). Pins and peripherals live in [`board`] only.
#![no_std]
#![no_main]

mod board;
mod fault;

use embassy_executor::Spawner;
use firmware::app::{self, App};
use shared::bus::BusConfig;
use shared::pipeline::PipelineConfig;
use shared::storage::CalStore;
use static_cell::{ConstStaticCell, StaticCell};

use defmt_rtt as _;
#[cfg(debug_assertions)]
use panic_probe as _;

/// The tasks' shared state, as the MCU holds it: the pipeline memory (Allan accumulators, upload bytes) in CCM RAM.
type FwApp = App<board::MemoryCcm>;

/// Release builds reset on a panic (after logging it and recording it for the next boot's housekeeping); the core
/// never panics on input, so this is a last resort.
#[cfg(not(debug_assertions))]
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    use core::sync::atomic::{AtomicBool, Ordering};
    static PANICKED: AtomicBool = AtomicBool::new(false);
    fault::record(shared::telemetry::FaultKind::Panic, 0, 0);
    // Logged once: a panic inside the logger (defmt-rtt panics on a re-entrant acquire) comes back here, and
    // logging again would recurse until the stack overflows (`tools/fw-check/stack.py` found the cycle).
    if !PANICKED.swap(true, Ordering::Relaxed) {
        defmt::error!("panic: {}", defmt::Display2Format(info));
    }
    cortex_m::peripheral::SCB::sys_reset()
}

/// The whole state of the tasks (15 KiB), built at compile time (`.data`): never on the stack.
#[allow(unsafe_code)] // `MemoryCcm::new`
static APP: ConstStaticCell<FwApp> = ConstStaticCell::new(App::new(
    PipelineConfig::DEFAULT,
    // SAFETY: the only handle (it zeroes the memory before its first borrow).
    unsafe { board::MemoryCcm::new() },
    BusConfig::DEFAULT,
    app::Platform::NONE,
));
static STORE: StaticCell<CalStore<board::CalibFlash>> = StaticCell::new();

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // First of all, so that a hang anywhere in init (a crystal that stops while embassy waits for it) resets.
    let wdt = board::start_watchdog();
    let boot = app::BootInfo {
        reset_flags: board::take_reset_flags(),
        fault: fault::take(),
    };
    let b = board::init();
    defmt::info!(
        "boot: clock {}, reset flags {=u8:#x}, fault {}",
        b.clock,
        boot.reset_flags,
        boot.fault
    );

    // The state was built at compile time (`APP`); the pipeline memory is zeroed in place in CCM RAM on its first use: no
    // large frame on the stack (`docs/firmware.md`, stack; the CI's stack check and boot test hold it to that).
    let app = APP.take();
    app.set_platform(app::Platform {
        boot,
        cycles: Some(b.cycles),
        mcu_sensors: Some(board::mcu_sensors),
    });
    let store = STORE.init(defmt::unwrap!(
        CalStore::new(b.calib).map_err(|_| "calibration flash geometry")
    ));
    app::load_calibration(store, app.pipeline.get_mut());
    let app: &'static FwApp = app;

    spawner.spawn(defmt::unwrap!(watchdog(app, wdt, b.led)));
    spawner.spawn(defmt::unwrap!(fpga_link(app, b.fpga_rx)));
    spawner.spawn(defmt::unwrap!(fpga_ctrl(app, b.fpga_tx, b.core_clock)));
    spawner.spawn(defmt::unwrap!(bus_rx(app, b.bus_rx)));
    spawner.spawn(defmt::unwrap!(bus_tx(app, b.bus_tx)));
    spawner.spawn(defmt::unwrap!(storage(app, store)));
    spawner.spawn(defmt::unwrap!(housekeeping(app)));
    spawner.spawn(defmt::unwrap!(pps(app, b.pps)));
}

#[embassy_executor::task]
async fn fpga_link(app: &'static FwApp, mut rx: board::FpgaRx) {
    app::link_loop(app, &mut rx).await
}

#[embassy_executor::task]
async fn fpga_ctrl(app: &'static FwApp, mut tx: board::FpgaTx, mut clock: board::CoreClock) {
    app::fpga_ctrl_loop(app, &mut tx, &mut clock).await
}

#[embassy_executor::task]
async fn bus_rx(app: &'static FwApp, mut rx: board::BusRx) {
    app::bus_rx_loop(app, &mut rx).await
}

#[embassy_executor::task]
async fn bus_tx(app: &'static FwApp, mut tx: board::BusTx) {
    app::bus_tx_loop(app, &mut tx).await
}

#[embassy_executor::task]
async fn storage(app: &'static FwApp, store: &'static mut CalStore<board::CalibFlash>) {
    app::storage_loop(app, store).await
}

#[embassy_executor::task]
async fn watchdog(app: &'static FwApp, mut wdt: board::Watchdog, mut led: board::Led) {
    app::watchdog_loop(app, app::WATCHDOG_PERIOD, || wdt.pet(), &mut led).await
}

#[embassy_executor::task]
async fn housekeeping(app: &'static FwApp) {
    app::housekeeping_loop(app, app::LOG_EVERY).await
}

#[embassy_executor::task]
async fn pps(app: &'static FwApp, mut pps: board::Pps) {
    app::pps_loop(app, &mut pps).await
}
