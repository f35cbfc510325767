//! Board support: the ONLY module that knows pins, peripherals, DMA streams, interrupts, clocks and flash
//! addresses. Porting to another STM32 means changing this file (and `memory.x`, the chip feature in Cargo.toml).
//!
//! | function            | peripheral | pins             | mode                                      |
//! |---------------------|------------|------------------|-------------------------------------------|
//! | FPGA frames (RX)    | USART1     | PA10 (AF7)       | 2 Mbaud, DMA2 stream 2 ch 4, ring buffer  |
//! | FPGA control (TX)   | USART1     | PA9  (AF7)       | DMA2 stream 7 ch 4                        |
//! | CubeSat bus         | USART2     | PA3 RX / PA2 TX  | 115200 baud, interrupt-driven, buffered   |
//! | status LED          | GPIO       | PC13             | push-pull, toggled when the watchdog is fed |
//! | watchdog            | IWDG       | -                | LSI ≈ 32 kHz, 8 s                         |
//! | calibration slots   | FLASH      | -                | sectors 10 (A) and 11 (B), 0x080C_0000    |
//! | time driver         | TIM5       | -                | embassy `time-driver-tim5`                |
//!
//! Clocks: 8 MHz HSE → PLL (M 4, N 168, P 2, Q 7): SYSCLK = HCLK = 168 MHz, APB1 42 MHz, APB2 84 MHz. If the HSE
//! does not start within ~100 ms the same 168 MHz comes from the 16 MHz HSI (±1 % over temperature) and the boot log
//! says so (embassy's own RCC init would wait forever for the HSE).

use embassy_stm32::flash::{Bank1Region3, Blocking, Flash};
use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::peripherals::IWDG;
use embassy_stm32::rcc::{
    AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv, PllSource,
    Sysclk,
};
use embassy_stm32::time::Hertz;
use embassy_stm32::usart::{
    self, BufferedUart, BufferedUartRx, BufferedUartTx, RingBufferedUartRx, Uart, UartTx,
};
use embassy_stm32::wdg::IndependentWatchdog;
use embassy_stm32::{bind_interrupts, dma, peripherals};
use static_cell::ConstStaticCell;

use firmware::flash::FlashWindow;
use firmware::layout::{CAL_FLASH_BASE, CAL_SECTOR_LEN, CAL_SECTORS, FPGA_RX_RING_LEN};

pub use firmware::layout::{BUS_BAUD, FPGA_BAUD};

bind_interrupts!(pub struct Irqs {
    USART1 => usart::InterruptHandler<peripherals::USART1>;
    USART2 => usart::BufferedInterruptHandler<peripherals::USART2>;
    DMA2_STREAM2 => dma::InterruptHandler<peripherals::DMA2_CH2>;
    DMA2_STREAM7 => dma::InterruptHandler<peripherals::DMA2_CH7>;
});

// FPGA_BAUD: USART1 on PCLK2 = 84 MHz, 84 MHz / 2 Mbaud = 42, exact with 16× oversampling.
// Budget: 240-byte frames at 604.8 /s = 1.452 Mbit/s with start/stop bits = 73 % of the line.
/// IWDG timeout, nominal (LSI assumed 32 kHz; at the fastest LSI, 47 kHz, it is 5.4 s). It must exceed one
/// 128 KiB sector erase (up to ~4 s on the F405 at the parallelism embassy uses) plus two watchdog periods.
pub const WATCHDOG_TIMEOUT_US: u32 = 8_000_000;

const BUS_RX_BUF_LEN: usize = 512;
const BUS_TX_BUF_LEN: usize = 1024;

/// Calibration window inside embassy's `Bank1Region3` (0x0802_0000 …, 7 sectors of 128 KiB).
const REGION3_BASE: u32 = 0x0802_0000;
const CALIB_LEN: u32 = (CAL_SECTORS * CAL_SECTOR_LEN) as u32; // sectors 10 and 11

/// FPGA frames: `embedded_io_async::Read` over the DMA ring.
pub type FpgaRx = RingBufferedUartRx<'static>;
/// FPGA control: `embedded_io_async::Write`.
pub type FpgaTx = UartTx<'static, Async>;
/// Bus receive: `embedded_io_async::Read`.
pub type BusRx = BufferedUartRx<'static>;
/// Bus transmit: `embedded_io_async::Write`.
pub type BusTx = BufferedUartTx<'static>;
/// The independent watchdog.
pub type Watchdog = IndependentWatchdog<'static, IWDG>;
/// `embedded_storage::nor_flash::NorFlash` over sectors 10 and 11 only.
pub type CalibFlash = FlashWindow<Bank1Region3<'static, Blocking>>;
/// Status LED: `embedded_hal::digital::OutputPin`.
pub type Led = Output<'static>;

/// Where the system clock comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum ClockSource {
    /// 8 MHz crystal.
    Hse8MHz,
    /// Internal RC (the crystal did not start).
    HsiFallback,
}

/// Everything the application gets from the board.
pub struct Board {
    pub clock: ClockSource,
    pub fpga_rx: FpgaRx,
    pub fpga_tx: FpgaTx,
    pub bus_rx: BusRx,
    pub bus_tx: BusTx,
    pub watchdog: Watchdog,
    pub calib: CalibFlash,
    pub led: Led,
}

// DMA-visible buffers: SRAM (.bss), never CCM.
static FPGA_RX_RING: ConstStaticCell<[u8; FPGA_RX_RING_LEN]> =
    ConstStaticCell::new([0; FPGA_RX_RING_LEN]);
static BUS_RX_BUF: ConstStaticCell<[u8; BUS_RX_BUF_LEN]> =
    ConstStaticCell::new([0; BUS_RX_BUF_LEN]);
static BUS_TX_BUF: ConstStaticCell<[u8; BUS_TX_BUF_LEN]> =
    ConstStaticCell::new([0; BUS_TX_BUF_LEN]);

/// Brings up clocks and peripherals. Call once (it takes embassy's `Peripherals` singleton).
pub fn init() -> Board {
    let clock = if hse_starts() {
        ClockSource::Hse8MHz
    } else {
        ClockSource::HsiFallback
    };
    let p = embassy_stm32::init(clock_config(clock));

    let mut fpga_cfg = usart::Config::default();
    fpga_cfg.baudrate = FPGA_BAUD;
    // Configuration errors here are programming errors of this file, found on the first boot: the pins, DMA
    // streams and baud rates are constants, so `new` fails on every boot or on none, and no input reaches it.
    #[allow(clippy::expect_used)]
    let fpga = Uart::new(
        p.USART1, p.PA10, p.PA9, p.DMA2_CH7, p.DMA2_CH2, Irqs, fpga_cfg,
    )
    .expect("USART1 config");
    let (fpga_tx, fpga_rx) = fpga.split();
    let mut fpga_rx = fpga_rx.into_ring_buffered(FPGA_RX_RING.take());
    fpga_rx.start_uart();

    let mut bus_cfg = usart::Config::default();
    bus_cfg.baudrate = BUS_BAUD;
    // As for USART1: constant configuration, no input.
    #[allow(clippy::expect_used)]
    let bus = BufferedUart::new(
        p.USART2,
        p.PA3,
        p.PA2,
        BUS_TX_BUF.take(),
        BUS_RX_BUF.take(),
        Irqs,
        bus_cfg,
    )
    .expect("USART2 config");
    let (bus_tx, bus_rx) = bus.split();

    // Freeze the watchdog while a debugger halts the core.
    embassy_stm32::pac::DBGMCU
        .apb1fzr()
        .modify(|w| w.set_iwdg(true));
    let watchdog = IndependentWatchdog::new(p.IWDG, WATCHDOG_TIMEOUT_US);

    let region3 = Flash::new_blocking(p.FLASH)
        .into_blocking_regions()
        .bank1_region3;
    let calib = FlashWindow::new(region3, CAL_FLASH_BASE - REGION3_BASE, CALIB_LEN);

    let led = Output::new(p.PC13, Level::High, Speed::Low);

    Board {
        clock,
        fpga_rx,
        fpga_tx,
        bus_rx,
        bus_tx,
        watchdog,
        calib,
        led,
    }
}

/// Tries the HSE before embassy's RCC init (which would wait forever for it).
fn hse_starts() -> bool {
    use embassy_stm32::pac::RCC;
    RCC.cr().modify(|w| w.set_hseon(true));
    let mut ok = false;
    for _ in 0..1600 {
        if RCC.cr().read().hserdy() {
            ok = true;
            break;
        }
        cortex_m::asm::delay(1000);
    }
    // Off again: embassy's init turns it on (HSEBYP is writable only while off).
    RCC.cr().modify(|w| w.set_hseon(false));
    while RCC.cr().read().hserdy() {}
    ok
}

fn clock_config(src: ClockSource) -> embassy_stm32::Config {
    let mut config = embassy_stm32::Config::default();
    let rcc = &mut config.rcc;
    let prediv = match src {
        ClockSource::Hse8MHz => {
            rcc.hse = Some(Hse {
                freq: Hertz(8_000_000),
                mode: HseMode::Oscillator,
            });
            rcc.pll_src = PllSource::HSE;
            PllPreDiv::DIV4 // 2 MHz VCO input
        }
        ClockSource::HsiFallback => {
            rcc.pll_src = PllSource::HSI;
            PllPreDiv::DIV8 // 2 MHz VCO input
        }
    };
    rcc.pll = Some(Pll {
        prediv,
        mul: PllMul::MUL168,       // VCO 336 MHz
        divp: Some(PllPDiv::DIV2), // SYSCLK 168 MHz
        divq: Some(PllQDiv::DIV7), // 48 MHz
        divr: None,
    });
    rcc.sys = Sysclk::PLL1_P;
    rcc.ahb_pre = AHBPrescaler::DIV1;
    rcc.apb1_pre = APBPrescaler::DIV4;
    rcc.apb2_pre = APBPrescaler::DIV2;
    config
}
