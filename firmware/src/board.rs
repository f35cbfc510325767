//! Board support: the ONLY module that knows pins, peripherals, DMA streams, interrupts, clocks and flash
//! addresses. Porting to another STM32 means changing this file (and `memory.x`, the chip feature in Cargo.toml).
//!
//! | function            | peripheral | pins             | mode                                      |
//! |---------------------|------------|------------------|-------------------------------------------|
//! | FPGA frames (RX)    | USART1     | PA10 (AF7)       | 2 Mbaud, DMA2 stream 2 ch 4, ring buffer  |
//! | FPGA control (TX)   | USART1     | PA9  (AF7)       | DMA2 stream 7 ch 4                        |
//! | CubeSat bus         | USART2     | PA3 RX / PA2 TX  | 115200 baud, RX DMA1 stream 5 ring, TX DMA1 stream 6 |
//! | status LED          | GPIO       | PC13             | open drain, 2 MHz: sinks the LED's current (below) |
//! | watchdog            | IWDG       | -                | LSI ≈ 32 kHz, 8 s, started before anything else |
//! | calibration slots   | FLASH      | -                | sectors 2 (A) and 3 (B), 0x0800_8000, x32 erase |
//! | time driver         | TIM5       | -                | embassy `time-driver-tim5`, 8 kHz tick    |
//! | PPS in (optional)   | TIM2 CH1   | PA15 (AF1)       | input capture, rising edge, 32-bit counter at 1 MHz |
//! | core clock          | RCC        | -                | HCLK 168 MHz streaming, 84 MHz in Idle (`CoreClock`) |
//!
//! The LED: PC13 is in the backup domain, so it may only sink ≤ 3 mA at ≤ 2 MHz, with at most one such pin
//! sinking at a time (DS8626 §5.3.16, note on PC13–PC15); it must not source current. The board wires the LED from
//! 3.3 V through a 1 kΩ resistor to PC13 (a red LED at ≈ 1.8 V: ≈ 1.5 mA), and the pin drives it open drain at
//! `Speed::Low` (2 MHz): low lights it, high-impedance leaves it dark, and the pin never sources.
//!
//! The flash accelerator (prefetch, instruction and data caches), which `embassy_stm32::init` leaves off (its RCC
//! init writes FLASH_ACR with the wait states only), is turned on here. Time: embassy's TIM5 driver counts 16-bit
//! periods of 2¹⁵ ticks and loses time when interrupts stay off for more than that; at 8 kHz that is 4.1 s, twice
//! the longest flash stall (a DFU sector erase, ≤ 2 s; `docs/update.md`), where 1 MHz would allow 33 ms.
//!
//! Clocks: 8 MHz HSE → PLL (M 4, N 168, P 2, Q 7): SYSCLK = HCLK = 168 MHz, APB1 42 MHz, APB2 84 MHz. If the HSE
//! does not start within ~100 ms the same 168 MHz comes from the 16 MHz HSI (±1 % over temperature) and the boot log
//! says so (embassy's own RCC init would wait forever for the HSE).

use core::cell::RefCell;
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_stm32::flash::{Bank1Region1, Bank1Region2, Bank1Region3, Blocking, Flash};
use embassy_stm32::gpio::{Level, OutputOpenDrain, Pull, Speed};
use embassy_stm32::mode::Async;
use embassy_stm32::rcc::{
    AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllMul, PllPDiv, PllPreDiv, PllQDiv, PllSource,
    Sysclk,
};
use embassy_stm32::time::Hertz;
use embassy_stm32::timer::{
    self,
    input_capture::{CapturePin, InputCapture},
    low_level::CountingMode,
};
use embassy_stm32::usart::{self, RingBufferedUartRx, Uart, UartTx};
use embassy_stm32::{bind_interrupts, dma, peripherals};
use embassy_sync::blocking_mutex::Mutex as BlockingMutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use firmware::chip::Flash32;
use shared::pipeline::PipelineMemory;
use static_cell::{ConstStaticCell, StaticCell};

use firmware::layout::{
    BUS_RX_RING_LEN, CAL_FLASH_BASE, CAL_SECTOR_LEN, CAL_SECTORS, FPGA_RX_RING_LEN,
};

pub use firmware::layout::{BUS_BAUD, FPGA_BAUD};

// Each USART's and DMA stream's own handler runs first (`LineErrors`, `DmaErrors`), then embassy's.
bind_interrupts!(pub struct Irqs {
    TIM2 => timer::CaptureCompareInterruptHandler<peripherals::TIM2>;
    USART1 => LineErrors, usart::InterruptHandler<peripherals::USART1>;
    USART2 => LineErrors, usart::InterruptHandler<peripherals::USART2>;
    DMA1_STREAM5 => DmaErrors, dma::InterruptHandler<peripherals::DMA1_CH5>;
    DMA1_STREAM6 => DmaErrors, dma::InterruptHandler<peripherals::DMA1_CH6>;
    DMA2_STREAM2 => DmaErrors, dma::InterruptHandler<peripherals::DMA2_CH2>;
    DMA2_STREAM7 => DmaErrors, dma::InterruptHandler<peripherals::DMA2_CH7>;
});

mod errors;
pub use errors::{DmaErrors, LineErrors, uart_errors};

// FPGA_BAUD: USART1 on PCLK2 = 84 MHz, 84 MHz / 2 Mbaud = 42, exact with 16× oversampling.
// Budget: 240-byte frames at 604.8 /s = 1.452 Mbit/s with start/stop bits = 73 % of the line.
/// Calibration window inside embassy's `Bank1Region1` (0x0800_0000 …, 4 sectors of 16 KiB).
const REGION1_BASE: u32 = 0x0800_0000;
const CALIB_LEN: u32 = (CAL_SECTORS * CAL_SECTOR_LEN) as u32; // sectors 2 and 3

/// FPGA frames: `embedded_io_async::Read` over the DMA ring.
pub type FpgaRx = RingBufferedUartRx<'static>;
/// FPGA control: `embedded_io_async::Write`.
pub type FpgaTx = UartTx<'static, Async>;
/// Bus receive: `embedded_io_async::Read` over the DMA ring (it fills while a flash erase stalls the CPU).
pub type BusRx = RingBufferedUartRx<'static>;
/// Bus transmit: `embedded_io_async::Write`.
pub type BusTx = UartTx<'static, Async>;
/// Flash sectors 0–3 (embassy's `Bank1Region1`) with x32 erases (`firmware::chip::Flash32`).
pub type Region1 = Flash32<Bank1Region1<'static, Blocking>>;
/// `embedded_storage::nor_flash::NorFlash` over sectors 2 and 3 only.
pub type CalibFlash = BlockingPartition<'static, NoopRawMutex, Region1>;

/// Sector 4 (embassy's `Bank1Region2`, 64 KiB): embassy-boot's state partition, whole.
pub type StateFlash = Flash32<Bank1Region2<'static, Blocking>>;
/// Sectors 5–11 (embassy's `Bank1Region3`, 128 KiB each): ACTIVE and DFU.
pub type Region3 = Flash32<Bank1Region3<'static, Blocking>>;
/// The DFU slot, sectors 7–9 of region 3.
pub type DfuFlash = BlockingPartition<'static, NoopRawMutex, Region3>;
/// The update service's flash.
pub type UpdateFlash = firmware::update::Updater<DfuFlash, StateFlash>;
/// Where region 3 starts (sector 5).
const REGION3_BASE: u32 = 0x0802_0000;
static FLASH_REGION3: StaticCell<BlockingMutex<NoopRawMutex, RefCell<Region3>>> = StaticCell::new();

/// Flash region 1 (sectors 0–3), shared by its partitions (today only the calibration slots).
static FLASH_REGION1: StaticCell<BlockingMutex<NoopRawMutex, RefCell<Region1>>> = StaticCell::new();
/// Status LED (open drain, see the module docs): `embedded_hal::digital::OutputPin`.
pub type Led = OutputOpenDrain<'static>;

pub use shared::telemetry::ClockSource;

/// The core clock (`app::CoreClock`): HCLK = SYSCLK = 168 MHz, or 84 MHz in Idle through the AHB prescaler, with
/// the APB prescalers halved with it so that every peripheral clock stays: PCLK1 42 MHz, PCLK2 84 MHz, the APB1
/// timers' 84 MHz (TIM5 for embassy's time, TIM2 for the PPS), the ADC's 21 MHz. The UARTs' baud rates, the time
/// and the capture therefore need no change; only APB2's timers (unused) go from 168 to 84 MHz. The PLL stays
/// locked, so switching takes no settling time. RM0090 §7.3.3: the new AHB divisor takes effect 1–16 AHB cycles
/// after the write; the order (AHB first going down, APB first going up) keeps PCLK1 ≤ 42 MHz and PCLK2 ≤ 84 MHz
/// throughout, at the price of ≤ 0.3 µs at half the peripheral clock: a bit on the 115200-baud bus stretches by
/// < 4 %, inside the receiver's tolerance. The flash keeps its 5 wait states (more than 84 MHz needs).
pub struct CoreClock;

impl firmware::app::CoreClock for CoreClock {
    fn set_low(&mut self, low: bool) -> u32 {
        use embassy_stm32::pac::RCC;
        use embassy_stm32::pac::rcc::vals::{Hpre, Ppre};
        cortex_m::interrupt::free(|_| {
            if low {
                RCC.cfgr().modify(|w| w.set_hpre(Hpre::DIV2));
                RCC.cfgr().modify(|w| {
                    w.set_ppre1(Ppre::DIV2);
                    w.set_ppre2(Ppre::DIV1);
                });
            } else {
                RCC.cfgr().modify(|w| {
                    w.set_ppre1(Ppre::DIV4);
                    w.set_ppre2(Ppre::DIV2);
                });
                RCC.cfgr().modify(|w| w.set_hpre(Hpre::DIV1));
            }
        });
        // The rate the register now holds, not the one asked for.
        match RCC.cfgr().read().hpre() {
            Hpre::DIV1 => SYSCLK_HZ,
            Hpre::DIV2 => SYSCLK_HZ / 2,
            _ => 0,
        }
    }
}

/// The independent watchdog and its start (`firmware::chip`: the bootloader starts it the same way, first thing).
pub use firmware::chip::{Watchdog, start_watchdog};

/// The pipeline's large buffers (60.4 KiB: the Allan accumulators of all 102 channels and the calibration upload's
/// bytes): in the 64 KiB core-coupled RAM, which only the CPU reaches (neither is ever a DMA buffer) and which
/// nothing else uses, so that SRAM keeps its room for the stack and the flash image of the tasks' state holds no
/// zeros for them.
/// `.ccmram` is NOLOAD (`memory.x`): cortex-m-rt neither zeroes nor initialises it; [`MemoryCcm`] zeroes it in place
/// before its first borrow.
#[allow(unsafe_code)] // the link section, and the accesses in `MemoryCcm` (SAFETY notes there)
#[unsafe(link_section = ".ccmram.MEMORY")]
static mut MEMORY: core::mem::MaybeUninit<PipelineMemory> = core::mem::MaybeUninit::uninit();
static MEMORY_READY: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// Zeroes the pipeline memory in CCM RAM, in place, once (later calls do nothing).
fn init_memory_ccm() {
    use core::sync::atomic::Ordering;
    if MEMORY_READY.load(Ordering::Acquire) {
        return;
    }
    #[allow(unsafe_code)]
    // SAFETY: no reference to MEMORY exists yet: the only handle (`MemoryCcm`) calls this before its first borrow and
    // borrows only once MEMORY_READY is set below. Every bit pattern of the memory's fields is
    // valid (it holds only integers: `AllanSet` is counts, sums and previous values; the upload is bytes), and
    // all-zero is its empty state (`PipelineMemory::new()`).
    unsafe {
        core::ptr::addr_of_mut!(MEMORY)
            .cast::<PipelineMemory>()
            .write_bytes(0, 1)
    };
    MEMORY_READY.store(true, Ordering::Release);
}

/// The pipeline memory in CCM RAM, as the pipeline holds it (`Pipeline<MemoryCcm>`): a handle, so that the whole `App`
/// can be built at compile time (a `const` cannot hold a `&'static mut`). There is one, in `main.rs`'s `APP`.
pub struct MemoryCcm(());

impl MemoryCcm {
    /// The handle.
    ///
    /// # Safety
    /// At most one may exist: it hands out `&mut` to the one memory. (It zeroes the memory itself before its first
    /// borrow.)
    #[allow(unsafe_code)]
    pub const unsafe fn new() -> Self {
        Self(())
    }

    fn memory(&self) -> *mut PipelineMemory {
        // Never a borrow of uninitialised memory: the first access zeroes the memory (at boot, the calibration load's
        // reset of the statistics); after it, one load per Allan access (once per frame).
        if !MEMORY_READY.load(core::sync::atomic::Ordering::Acquire) {
            init_memory_ccm();
        }
        core::ptr::addr_of_mut!(MEMORY).cast::<PipelineMemory>()
    }
}

impl core::borrow::Borrow<PipelineMemory> for MemoryCcm {
    fn borrow(&self) -> &PipelineMemory {
        #[allow(unsafe_code)]
        // SAFETY: initialised (`memory`); the one handle's `&self` borrow lives no longer than `&self`, and no `&mut`
        // can coexist with it (that needs `&mut self` of the same unique handle).
        unsafe {
            &*self.memory()
        }
    }
}

impl core::borrow::BorrowMut<PipelineMemory> for MemoryCcm {
    fn borrow_mut(&mut self) -> &mut PipelineMemory {
        #[allow(unsafe_code)]
        // SAFETY: initialised (`memory`); the borrow is tied to `&mut self` of the unique handle, so it is the only
        // reference to the memory while it lives.
        unsafe {
            &mut *self.memory()
        }
    }
}

/// The update service on sectors 4 (boot state) and 7–9 (DFU), with the running image's version from its header in
/// ACTIVE (0 when it has none: flashed by a probe) and the report the bootloader left in RAM (cleared once read, so
/// that a later boot without the bootloader does not read it again).
fn update_service(
    region2: Bank1Region2<'static, Blocking>,
    region3: Bank1Region3<'static, Blocking>,
) -> UpdateFlash {
    use embedded_storage::nor_flash::ReadNorFlash;
    use firmware::layout::{ACTIVE_BASE, ACTIVE_LEN, BOARD_ID, DFU_BASE, DFU_LEN};
    let mut region3 = Flash32(region3);
    let mut header = [0u8; shared::update::image::OPEN_LEN];
    let running_version = region3
        .read(ACTIVE_BASE - REGION3_BASE, &mut header)
        .ok()
        .and_then(|()| shared::update::Header::parse(&header).ok())
        .map_or(0, |h| h.version);
    let region3 = FLASH_REGION3.init(BlockingMutex::new(RefCell::new(region3)));
    let dfu = BlockingPartition::new(region3, DFU_BASE - REGION3_BASE, DFU_LEN);
    firmware::update::Updater::new(
        dfu,
        Flash32(region2),
        firmware::update::UPDATE_PUBLIC_KEY,
        BOARD_ID,
        running_version,
        ACTIVE_LEN,
        take_boot_report(),
    )
}

/// The bootloader's report (`shared::update::boot_report`), read and cleared.
fn take_boot_report() -> Option<shared::update::BootReport> {
    use shared::update::boot_report::WORDS;
    let base = firmware::layout::BOOT_REPORT_ADDR as usize as *mut u32;
    let mut words = [0u32; WORDS];
    for (i, w) in words.iter_mut().enumerate() {
        // SAFETY: the first 32 bytes of SRAM belong to neither ELF's sections (both memory.x files start RAM
        // after them: `layout::BOOT_REPORT_LEN`); nothing else reads or writes them. Aligned, in bounds.
        #[allow(unsafe_code)]
        unsafe {
            *w = base.add(i).read_volatile();
            base.add(i).write_volatile(0);
        }
    }
    shared::update::BootReport::from_words(&words)
}

/// Everything the application gets from the board.
pub struct Board {
    pub clock: ClockSource,
    /// RCC_CR.HSITRIM in force.
    pub hsi_trim: u8,
    /// The brown-out reset level of the option bytes (0 off, 1–3).
    pub bor_level: u8,
    pub fpga_rx: FpgaRx,
    pub fpga_tx: FpgaTx,
    pub bus_rx: BusRx,
    pub bus_tx: BusTx,
    pub calib: CalibFlash,
    /// The update service: the DFU slot, the boot state, the running image's version and the bootloader's report.
    pub update: UpdateFlash,
    pub led: Led,
    pub cycles: firmware::app::CycleCounter,
    pub core_clock: CoreClock,
    pub pps: Pps,
}

/// The PPS input: TIM2 channel 1 captures the counter (1 MHz, 32 bits) at each rising edge on PA15; the edge's time
/// on embassy's clock is "now" less the counter's count since the capture, read together (the 8 kHz tick limits
/// it to 125 µs, far below a frame's read delay). An unconnected pin (pulled down) gives no edge.
pub struct Pps(InputCapture<'static, peripherals::TIM2>);

impl firmware::app::PpsInput for Pps {
    async fn edge_us(&mut self) -> u64 {
        let captured = self.0.wait_for_rising_edge(timer::Channel::Ch1).await;
        let (count, now_us) = cortex_m::interrupt::free(|_| {
            (
                embassy_stm32::pac::TIM2.cnt().read(),
                embassy_time::Instant::now().as_micros(),
            )
        });
        // The 32-bit counter wraps after 71 minutes; the task reads it within milliseconds of the capture.
        now_us.saturating_sub(u64::from(count.wrapping_sub(captured)))
    }
}

/// ADC1 for the MCU's internal channels (temperature, VREFINT), shared with the housekeeping task.
static ADC: embassy_sync::blocking_mutex::Mutex<
    embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex,
    core::cell::RefCell<Option<embassy_stm32::adc::Adc<'static, peripherals::ADC1>>>,
> = embassy_sync::blocking_mutex::Mutex::new(core::cell::RefCell::new(None));

/// The factory calibration words in system memory (DS8626: VREFINT_CAL at 0x1FFF_7A2A, TS_CAL1 at 0x1FFF_7A2C,
/// TS_CAL2 at 0x1FFF_7A2E; 16-bit each).
fn factory_cal() -> firmware::mcu_sensors::FactoryCal {
    let word = |addr: usize| {
        // SAFETY: fixed, always-readable addresses of the F405's system memory (read-only OTP area); an aligned
        // 16-bit volatile read has no side effect.
        #[allow(unsafe_code)]
        unsafe {
            core::ptr::read_volatile(addr as *const u16)
        }
    };
    firmware::mcu_sensors::FactoryCal {
        vrefint_cal: word(0x1FFF_7A2A),
        ts_cal1: word(0x1FFF_7A2C),
        ts_cal2: word(0x1FFF_7A2E),
    }
}

/// (MCU temperature 0.01 °C, VDDA mV) now; `None` before `init` or for impossible codes. Two conversions of 480
/// ADC cycles (≈ 23 µs each at 21 MHz: the temperature sensor needs ≥ 10 µs of sampling).
pub fn mcu_sensors() -> Option<(i16, u16)> {
    use embassy_stm32::adc::{SampleTime, Temperature, VrefInt};
    let (ts, vref) = ADC.lock(|cell| {
        let mut adc = cell.borrow_mut();
        let adc = adc.as_mut()?;
        let ts = adc.blocking_read(&mut Temperature, SampleTime::CYCLES480);
        let vref = adc.blocking_read(&mut VrefInt, SampleTime::CYCLES480);
        Some((ts, vref))
    })?;
    firmware::mcu_sensors::convert(ts, vref, factory_cal())
}

/// SYSCLK, Hz (both clock sources give it: `clock_config`).
pub const SYSCLK_HZ: u32 = 168_000_000;

/// Reads and clears the reset flags: RCC_CSR bits 25–31 (BOR, PIN, POR, software, IWDG, WWDG, low-power) as bits
/// 0–6. Call before `init`.
pub fn take_reset_flags() -> u8 {
    use embassy_stm32::pac::RCC;
    let flags = (RCC.csr().read().0 >> 25) as u8;
    RCC.csr().modify(|w| w.set_rmvf(true));
    flags
}

// DMA-visible buffers: SRAM (.bss), never CCM.
static FPGA_RX_RING: ConstStaticCell<[u8; FPGA_RX_RING_LEN]> =
    ConstStaticCell::new([0; FPGA_RX_RING_LEN]);
static BUS_RX_RING: ConstStaticCell<[u8; BUS_RX_RING_LEN]> =
    ConstStaticCell::new([0; BUS_RX_RING_LEN]);

/// Brings up clocks and peripherals. Call once (it takes embassy's `Peripherals` singleton). After a clock failure
/// in the last boot (`after_clock_failure`) the crystal is not tried: the clock security system saw it fail.
pub fn init(after_clock_failure: bool) -> Board {
    let clock = if after_clock_failure {
        ClockSource::HsiAfterClockFailure
    } else if hse_starts() {
        ClockSource::Hse
    } else {
        ClockSource::Hsi
    };
    let p = embassy_stm32::init(clock_config(clock));
    if clock == ClockSource::Hse {
        // The clock security system: a crystal that stops from now on switches SYSCLK to the HSI and raises the NMI
        // (`fault.rs`: recorded, reset, the next boot on the HSI). RM0090 §7.2.7.
        embassy_stm32::pac::RCC.cr().modify(|w| w.set_csson(true));
    }
    enable_flash_accelerator();
    set_interrupt_priorities();

    let mut fpga_cfg = usart::Config::default();
    fpga_cfg.baudrate = FPGA_BAUD;
    // ONEBIT: one sample per bit instead of three, which widens the receiver's clock tolerance (RM0090 §30.3.5) —
    // the link's margin on the HSI — at the price of noise detection (`docs/firmware.md`, clock budget).
    fpga_cfg.assume_noise_free = true;
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
    bus_cfg.assume_noise_free = true;
    // As for USART1: constant configuration, no input.
    #[allow(clippy::expect_used)]
    let bus = Uart::new(
        p.USART2, p.PA3, p.PA2, p.DMA1_CH6, p.DMA1_CH5, Irqs, bus_cfg,
    )
    .expect("USART2 config");
    let (bus_tx, bus_rx) = bus.split();
    let mut bus_rx = bus_rx.into_ring_buffered(BUS_RX_RING.take());
    bus_rx.start_uart();

    let regions = Flash::new_blocking(p.FLASH).into_blocking_regions();
    let region1 = FLASH_REGION1.init(BlockingMutex::new(RefCell::new(Flash32(
        regions.bank1_region1,
    ))));
    // Sectors 2–3; the partition checks at boot that both ends are on sector boundaries.
    let calib = BlockingPartition::new(region1, CAL_FLASH_BASE - REGION1_BASE, CALIB_LEN);
    let update = update_service(regions.bank1_region2, regions.bank1_region3);

    let led = OutputOpenDrain::new(p.PC13, Level::High, Speed::Low);

    let adc = embassy_stm32::adc::Adc::new(p.ADC1);
    // Both internal channels are behind one switch (TSVREFE); the returned handles are unit values.
    let _ = (adc.enable_temperature(), adc.enable_vrefint());
    ADC.lock(|cell| cell.replace(Some(adc)));

    // The DWT cycle counter, for the core's load (housekeeping). `take` fails only if called twice: then the
    // counter stays off and reads 0.
    if let Some(mut cp) = cortex_m::Peripherals::take() {
        cp.DCB.enable_trace();
        cp.DWT.enable_cycle_counter();
    }
    let cycles = firmware::app::CycleCounter {
        now: cortex_m::peripheral::DWT::cycle_count,
    };

    // PPS: TIM2 (32-bit, on APB1's 84 MHz timer clock) at 1 MHz, capture on rising edges of PA15.
    let mut capture = InputCapture::new(
        p.TIM2,
        Some(CapturePin::new(p.PA15, Pull::Down)),
        None,
        None,
        None,
        Irqs,
        Hertz(1_000_000),
        CountingMode::EdgeAlignedUp,
    );
    capture.enable(timer::Channel::Ch1);
    let pps = Pps(capture);

    let hsi_trim = embassy_stm32::pac::RCC.cr().read().hsitrim();
    Board {
        clock,
        hsi_trim,
        bor_level: bor_level(),
        fpga_rx,
        fpga_tx,
        bus_rx,
        bus_tx,
        calib,
        update,
        led,
        cycles,
        core_clock: CoreClock,
        pps,
    }
}

/// The brown-out reset level programmed in the option bytes (FLASH_OPTCR.BOR_LEV: 11 off, 10 level 1 = 2.2 V,
/// 01 level 2 = 2.5 V, 00 level 3 = 2.8 V; RM0090 §3.6.1) as 0 (off) to 3. Setting it is a manufacturing step
/// (`docs/firmware.md`, power).
fn bor_level() -> u8 {
    let lev = embassy_stm32::pac::FLASH.optcr().read().bor_lev();
    3u8.saturating_sub(lev & 0b11)
}

/// Interrupt priorities, set on purpose (embassy leaves every one at 0): the faults and the NMI above all; SysTick,
/// the deadline monitor, next (it must see a handler that never returns); then the FPGA link (2 Mbaud: its DMA ring
/// and idle-line interrupt), the time driver, and last the bus and the PPS capture. Four levels: an interrupt frame
/// nests at most once per level (`tools/fw-check/stack.py` models it). Every DMA stream interrupt embassy enabled
/// without a binding here is masked (it would land in `DefaultHandler`).
fn set_interrupt_priorities() {
    use embassy_stm32::interrupt::{Interrupt, InterruptExt, Priority};
    use embassy_stm32::pac::Interrupt as I;
    // SAFETY of the masks below: masking an interrupt cannot break memory safety.
    for irq in [
        I::DMA1_STREAM0,
        I::DMA1_STREAM1,
        I::DMA1_STREAM2,
        I::DMA1_STREAM3,
        I::DMA1_STREAM4,
        I::DMA1_STREAM7,
        I::DMA2_STREAM0,
        I::DMA2_STREAM1,
        I::DMA2_STREAM3,
        I::DMA2_STREAM4,
        I::DMA2_STREAM5,
        I::DMA2_STREAM6,
    ] {
        cortex_m::peripheral::NVIC::mask(irq);
        cortex_m::peripheral::NVIC::unpend(irq);
    }
    for (irq, prio) in [
        (Interrupt::USART1, Priority::P2),
        (Interrupt::DMA2_STREAM2, Priority::P2),
        (Interrupt::DMA2_STREAM7, Priority::P2),
        (Interrupt::TIM5, Priority::P3),
        (Interrupt::USART2, Priority::P4),
        (Interrupt::DMA1_STREAM5, Priority::P4),
        (Interrupt::DMA1_STREAM6, Priority::P4),
        (Interrupt::TIM2, Priority::P4),
    ] {
        irq.set_priority(prio);
    }
}

/// SysTick every [`MONITOR_PERIOD_MS`] at HCLK / 8 (21 MHz streaming; 10.5 MHz and 200 ms in `Idle`), at priority
/// 1: the deadline monitor (`fault.rs`). Call once the monitor has its app.
pub fn start_deadline_monitor() {
    use cortex_m::peripheral::{SYST, scb::SystemHandler, syst::SystClkSource};
    // SAFETY: SysTick is used by nothing else (embassy's time is TIM5); the priority change cannot break memory
    // safety (no priority-based critical section is in use: they are all interrupt-disabling).
    #[allow(unsafe_code)]
    unsafe {
        let mut cp = cortex_m::Peripherals::steal();
        cp.SCB.set_priority(SystemHandler::SysTick, 0x10);
        let syst: &mut SYST = &mut cp.SYST;
        syst.set_clock_source(SystClkSource::External);
        syst.set_reload(SYSCLK_HZ / 8 / 1000 * MONITOR_PERIOD_MS - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
    }
}

/// The HSI's trim (RCC_CR.HSITRIM), for the housekeeping task's trim loop while the core runs on the HSI.
pub const HSI_TRIM: firmware::app::HsiTrim = firmware::app::HsiTrim {
    read: || embassy_stm32::pac::RCC.cr().read().hsitrim(),
    write: |trim| {
        embassy_stm32::pac::RCC
            .cr()
            .modify(|w| w.set_hsitrim(trim.min(31)))
    },
};

/// The deadline monitor's period at full clock, ms.
pub const MONITOR_PERIOD_MS: u32 = 100;

/// Prefetch and the ART caches on (RM0090 §3.5.2: reset each cache while it is off, then enable).
fn enable_flash_accelerator() {
    use embassy_stm32::pac::FLASH;
    FLASH.acr().modify(|w| {
        w.set_icen(false);
        w.set_dcen(false);
    });
    FLASH.acr().modify(|w| {
        w.set_icrst(true);
        w.set_dcrst(true);
    });
    FLASH.acr().modify(|w| {
        w.set_icrst(false);
        w.set_dcrst(false);
    });
    FLASH.acr().modify(|w| {
        w.set_prften(true);
        w.set_icen(true);
        w.set_dcen(true);
    });
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
    // The flight build keeps the debug port off in sleep (embassy's default keeps it on, and draws for it).
    config.enable_debug_during_sleep = false;
    let rcc = &mut config.rcc;
    let prediv = match src {
        ClockSource::Hse => {
            rcc.hse = Some(Hse {
                freq: Hertz(8_000_000),
                mode: HseMode::Oscillator,
            });
            rcc.pll_src = PllSource::HSE;
            PllPreDiv::DIV4 // 2 MHz VCO input
        }
        ClockSource::Hsi | ClockSource::HsiAfterClockFailure => {
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
