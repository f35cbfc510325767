//! IMU cluster firmware for the STM32F405RG: a thin shell over `shared::Pipeline`.
//!
//! `main` configures the board, loads the calibration and spawns the tasks of [`firmware::task_table!`]: one embassy
//! task per line, each a call of a board-independent loop in `firmware::app` (embassy tasks cannot be generic; the
//! same table joins the same loops on the PC in the SITL and the scenario tests). Pins and peripherals live in
//! [`board`] only.
#![no_std]
#![no_main]

mod board;
mod fault;

use embassy_executor::Spawner;
use firmware::app::{self, App};
use firmware::tasks::Edges;
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

/// The edges' types as the tasks take them (embassy tasks cannot be generic).
type FpgaRx = board::FpgaRx;
type FpgaTx = board::FpgaTx;
type CoreClock = board::CoreClock;
type BusRx = board::BusRx;
type BusTx = board::BusTx;
type Store = &'static mut CalStore<board::CalibFlash>;
type Watchdog = board::Watchdog;
type Led = board::Led;
type Pps = board::Pps;

/// One embassy task per line of the table, each a call of its loop.
macro_rules! define_tasks {
    ({} |$app:ident| $($name:ident($($edge:ident: $ty:ty),*) => $body:expr;)*) => {
        $(
            #[embassy_executor::task]
            #[allow(unused_mut)] // `storage` passes its `&mut` on
            async fn $name($app: &'static FwApp, $(mut $edge: $ty),*) {
                $body.await
            }
        )*
    };
}

/// Spawns each task with its edges.
macro_rules! spawn_tasks {
    ({ $spawner:ident, $app_val:ident, $edges:ident } |$app:ident| $($name:ident($($edge:ident: $ty:ty),*) => $body:expr;)*) => {
        $($spawner.spawn(defmt::unwrap!($name($app_val, $($edges.$edge),*)));)*
    };
}

firmware::task_table!(define_tasks {});

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

    let edges = Edges {
        fpga_rx: b.fpga_rx,
        fpga_tx: b.fpga_tx,
        core_clock: b.core_clock,
        bus_rx: b.bus_rx,
        bus_tx: b.bus_tx,
        store,
        watchdog: wdt,
        led: b.led,
        pps: b.pps,
    };
    firmware::task_table!(spawn_tasks {
        spawner,
        app,
        edges
    });
}
