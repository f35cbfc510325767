//! IMU cluster firmware for the STM32F405RG: a thin shell over `shared::Pipeline`.
//!
//! `main` configures the board, loads the calibration and spawns the tasks; each task is a few lines that hand its
//! peripherals to a board-independent loop in [`app`] (embassy tasks cannot be generic). Pins and peripherals live
//! in [`board`] only.
#![no_std]
#![no_main]

mod app;
mod board;
mod flash;

use embassy_executor::Spawner;
use embassy_sync::mutex::Mutex;
use embassy_time::Duration;
use shared::bus::BusConfig;
use shared::pipeline::{AllanBank, Pipeline, PipelineConfig};
use shared::storage::CalStore;
use static_cell::{ConstStaticCell, StaticCell};

use defmt_rtt as _;
#[cfg(debug_assertions)]
use panic_probe as _;

use app::SharedPipeline;

/// Release builds reset on a panic (after logging it); the core never panics on input, so this is a last resort.
#[cfg(not(debug_assertions))]
#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    defmt::error!("panic: {}", defmt::Display2Format(info));
    cortex_m::peripheral::SCB::sys_reset()
}

/// How often the watchdog task checks progress.
const WATCHDOG_PERIOD: Duration = Duration::from_millis(250);
/// How often link statistics are logged.
const STATS_PERIOD: Duration = Duration::from_secs(10);

/// The Allan accumulators of all 102 channels (59.6 KiB, zero-initialised: `.bss`).
static ALLAN: ConstStaticCell<AllanBank> = ConstStaticCell::new(AllanBank::new());
static PIPELINE: StaticCell<SharedPipeline> = StaticCell::new();
static STORE: StaticCell<CalStore<board::CalibFlash>> = StaticCell::new();

#[embassy_executor::main]
async fn main(spawner: Spawner) {
    let b = board::init();
    defmt::info!("boot: clock {}", b.clock);

    let mut pipeline = Pipeline::new(PipelineConfig::DEFAULT, ALLAN.take());
    let store = STORE.init(defmt::unwrap!(
        CalStore::new(b.calib).map_err(|_| "calibration flash geometry")
    ));
    app::load_calibration(store, &mut pipeline);
    let pipeline: &'static SharedPipeline = PIPELINE.init(Mutex::new(pipeline));

    spawner.spawn(defmt::unwrap!(watchdog(b.watchdog, b.led)));
    spawner.spawn(defmt::unwrap!(fpga_link(b.fpga_rx, pipeline)));
    spawner.spawn(defmt::unwrap!(fpga_ctrl(b.fpga_tx)));
    spawner.spawn(defmt::unwrap!(bus_rx(b.bus_rx, pipeline)));
    spawner.spawn(defmt::unwrap!(bus_tx(b.bus_tx, pipeline)));
    spawner.spawn(defmt::unwrap!(storage(store, pipeline)));
    spawner.spawn(defmt::unwrap!(stats(pipeline)));
}

#[embassy_executor::task]
async fn fpga_link(mut rx: board::FpgaRx, pipeline: &'static SharedPipeline) {
    app::link_loop(&mut rx, pipeline).await
}

#[embassy_executor::task]
async fn fpga_ctrl(mut tx: board::FpgaTx) {
    app::fpga_ctrl_loop(&mut tx).await
}

#[embassy_executor::task]
async fn bus_rx(mut rx: board::BusRx, pipeline: &'static SharedPipeline) {
    app::bus_rx_loop(&mut rx, pipeline, BusConfig::DEFAULT).await
}

#[embassy_executor::task]
async fn bus_tx(mut tx: board::BusTx, pipeline: &'static SharedPipeline) {
    app::bus_tx_loop(&mut tx, pipeline, BusConfig::DEFAULT).await
}

#[embassy_executor::task]
async fn storage(
    store: &'static mut CalStore<board::CalibFlash>,
    pipeline: &'static SharedPipeline,
) {
    app::storage_loop(store, pipeline).await
}

#[embassy_executor::task]
async fn watchdog(mut wdt: board::Watchdog, mut led: board::Led) {
    wdt.unleash();
    app::watchdog_loop(WATCHDOG_PERIOD, || wdt.pet(), &mut led).await
}

#[embassy_executor::task]
async fn stats(pipeline: &'static SharedPipeline) {
    app::stats_loop(pipeline, STATS_PERIOD).await
}
