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
#[cfg(feature = "fault-injection")]
mod inject;

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
    // Logged once, and only the location (no `core::fmt`: its formatting machinery recurses, and the message may
    // be a formatted one): a panic inside the logger (defmt-rtt panics on a re-entrant acquire) comes back here.
    if !PANICKED.swap(true, Ordering::Relaxed)
        && let Some(l) = info.location()
    {
        defmt::error!("panic at {=str}:{=u32}", l.file(), l.line());
    }
    fault::panic(info.location())
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
static UPDATE: StaticCell<board::UpdateFlash> = StaticCell::new();

/// The edges' types as the tasks take them (embassy tasks cannot be generic).
type FpgaRx = board::FpgaRx;
type FpgaTx = board::FpgaTx;
type CoreClock = board::CoreClock;
type BusRx = board::BusRx;
type BusTx = board::BusTx;
type Store = &'static mut CalStore<board::CalibFlash>;
type Update = &'static mut board::UpdateFlash;
type Watchdog = board::Watchdog;
type Led = board::Led;
type Pps = board::Pps;

/// The tasks a safe-mode boot runs: the bus, housekeeping (with the reset history), the watchdog, and storage (the
/// update service: a software upload is how a crash-looping image is replaced; the calibration stays the factory's).
fn essential(task: &str) -> bool {
    matches!(
        task,
        "bus_rx" | "bus_tx" | "storage" | "watchdog" | "housekeeping"
    )
}

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
    ({ $spawner:ident, $app_val:ident, $edges:ident, $safe:ident } |$app:ident| $($name:ident($($edge:ident: $ty:ty),*) => $body:expr;)*) => {
        $(
            if !$safe || essential(stringify!($name)) {
                $spawner.spawn(defmt::unwrap!($name($app_val, $($edges.$edge),*)));
            }
        )*
    };
}

firmware::task_table!(define_tasks {});

/// The fault injection of the `fault-injection` build (`inject.rs`).
#[cfg(feature = "fault-injection")]
#[embassy_executor::task]
async fn inject(app: &'static FwApp, kind: u32) {
    inject::run(app, kind).await
}

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    // First of all, so that a hang anywhere in init (a crystal that stops while embassy waits for it) resets.
    let wdt = board::start_watchdog();
    #[cfg(feature = "fault-injection")]
    let injected = inject::take();
    let reset_flags = board::take_reset_flags();
    // The reset history first: it files what ended the last boot, and says whether this one is a crash loop's.
    let state = fault::boot(reset_flags);
    let b = board::init(state.after_clock_failure);
    let boot = app::BootInfo {
        reset_flags,
        boot_count: state.boot_count,
        safe_mode: state.safe_mode,
        clock_source: Some(b.clock),
        hsi_trim: b.hsi_trim,
        bor_level: Some(b.bor_level),
    };
    defmt::info!(
        "boot {=u32}: clock {}, reset flags {=u8:#x}, BOR level {=u8}, safe mode {=bool}",
        boot.boot_count,
        b.clock,
        boot.reset_flags,
        b.bor_level,
        boot.safe_mode,
    );

    // The state was built at compile time (`APP`); the pipeline memory is zeroed in place in CCM RAM on its first use: no
    // large frame on the stack (`docs/firmware.md`, stack; the CI's stack check and boot test hold it to that).
    let app = APP.take();
    app.set_platform(app::Platform {
        boot,
        cycles: Some(b.cycles),
        mcu_sensors: Some(board::mcu_sensors),
        resets: Some(&fault::LOG),
        uart_errors: Some(board::uart_errors),
        // On the HSI, housekeeping trims it against the FPGA's crystal-timed frames.
        hsi_trim: (b.clock != board::ClockSource::Hse).then_some(board::HSI_TRIM),
        reset: Some(fault::commanded_reset),
    });
    app.pipeline.get_mut().set_boot_count(state.boot_count);
    let store = STORE.init(defmt::unwrap!(
        CalStore::new(b.calib).map_err(|_| "calibration flash geometry")
    ));
    // Safe mode boots on the factory calibration: a stored table may be what crashes it.
    if !state.safe_mode {
        app::load_calibration(store, app.pipeline.get_mut());
    }
    let app: &'static FwApp = app;
    let safe = state.safe_mode;
    if safe {
        // Bus RX, bus TX, storage, watchdog, housekeeping: the tasks `essential` keeps.
        app.set_monitored(0b0111_1100);
    }
    fault::monitor(app);
    board::start_deadline_monitor();

    let edges = Edges {
        fpga_rx: b.fpga_rx,
        fpga_tx: b.fpga_tx,
        core_clock: b.core_clock,
        bus_rx: b.bus_rx,
        bus_tx: b.bus_tx,
        store,
        update: UPDATE.init(b.update),
        watchdog: wdt,
        led: b.led,
        pps: b.pps,
    };
    firmware::task_table!(spawn_tasks {
        spawner,
        app,
        edges,
        safe
    });
    #[cfg(feature = "fault-injection")]
    if injected != 0 {
        spawner.spawn(defmt::unwrap!(inject(app, injected)));
    }
}
