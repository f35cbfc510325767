//! The bootloader (`docs/update.md`): sectors 0–1 of the STM32F405RG, where the core starts. Each boot:
//!
//! 1. starts the independent watchdog (`firmware::chip::start_watchdog`, the firmware's 8 s), first of all;
//! 2. runs the boot decision, `shared::update::boot::prepare` (the code the SITL tests run on the flash models): a
//!    swap requested and not started yet is checked first (`verify_slot`: header, board, version above ACTIVE's,
//!    size, Ed25519 signature, SHA-512 of the payload) and cancelled if refused; embassy-boot swaps, resumes a swap
//!    a reset cut, or reverts a trial image that never marked itself booted. Every flash erase and write is
//!    preceded by a reload of the IWDG (`boot::Feeding`);
//! 3. if ACTIVE then holds no vector table it could start (`layout::app_vectors_plausible`) and nothing was swapped
//!    or refused this boot, asks for a swap when DFU holds one that could and verifies, and runs the decision again;
//! 4. leaves the boot report (`shared::update::BootReport`, at `layout::BOOT_REPORT_ADDR`) and jumps to the
//!    application's vector table at ACTIVE + 0x200, or, with nothing it could start, waits for the IWDG to reset
//!    the board.
//!
//! Flash: STATE is sector 4, which is embassy's `Bank1Region2` whole; ACTIVE and DFU are partitions of
//! `Bank1Region3` (sectors 5–11, 128 KiB each, embassy-boot's page). One partition over the whole flash would give
//! STATE embassy's largest erase size, 128 KiB, which its 64 KiB is not a multiple of. Erases at x32
//! (`firmware::chip::Flash32`): a 128 KiB sector ≤ 2 s, the IWDG ≥ 5.4 s (`layout::WATCHDOG_TIMEOUT_MIN_US`).
//!
//! The clocks stay as the reset left them (the 16 MHz HSI), and so does every peripheral but the IWDG and the flash
//! interface (locked again after each operation): the application starts from a chip in its reset state. The
//! longest stretch without a reload is the image check, which only reads: SHA-512 of at most 256 KiB and one
//! Ed25519 verification, 27.3 M instructions in emulation (≈ 1.7–2.6 s on the HSI at 1–1.5 cycles each).
//!
//! FDIR: a HardFault, an unexpected interrupt and a panic reset the board (none is expected: the code that reads
//! flash data cannot panic, by the same lints as the firmware's); a flash operation that fails during the decision
//! leaves the board waiting for the IWDG, and the next boot resumes from embassy-boot's progress words. The RAM it
//! uses (`memory.x`: 24 KiB after the boot report; its deepest path, 11.4 KiB, is the image check) lies in what
//! the application leaves to its stack, so that the application's reset history (`.uninit`) survives it.
#![no_std]
#![no_main]

use core::cell::RefCell;

use cortex_m::peripheral::SCB;
use embassy_boot_stm32::{AlignedBuffer, BlockingFirmwareState, State};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_stm32::flash::{Flash, WRITE_SIZE};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage::nor_flash::ReadNorFlash;
use firmware::chip::{Flash32, start_watchdog};
use firmware::layout::{
    ACTIVE_BASE, ACTIVE_LEN, APP_FLASH_BASE, BOARD_ID, BOOT_REPORT_ADDR, BOOT_REPORT_LEN, DFU_BASE,
    DFU_LEN, IMAGE_HEADER_LEN, STATE_BASE, STATE_LEN, app_vectors_plausible,
};
use shared::update::boot::{self, Feeding};
use shared::update::{BootAction, BootReport, boot_report, image};

include!(concat!(env!("OUT_DIR"), "/update_pubkey.rs"));

/// Where embassy's `Bank1Region2` (sector 4, STATE) starts.
const REGION2_BASE: u32 = 0x0801_0000;
/// Where embassy's `Bank1Region3` (sectors 5–11: ACTIVE, DFU) starts.
const REGION3_BASE: u32 = 0x0802_0000;
/// Bytes embassy-boot copies at a time during a swap (a divisor of its 128 KiB page): one write is 512 words,
/// ≤ 51 ms at 100 µs a word (DS8626).
const COPY_BUFFER_LEN: usize = 2048;

const _: () = {
    assert!(
        STATE_BASE == REGION2_BASE && STATE_LEN == 64 * 1024,
        "STATE is sector 4, all of Bank1Region2"
    );
    assert!(ACTIVE_BASE >= REGION3_BASE && DFU_BASE >= REGION3_BASE);
    assert!(IMAGE_HEADER_LEN as usize == image::HEADER_LEN);
    assert!(boot_report::WORDS <= (BOOT_REPORT_LEN / 4) as usize);
};

#[cortex_m_rt::entry]
fn main() -> ! {
    // First of all: a hang anywhere below resets the board.
    let watchdog = start_watchdog();
    let mut feeder = watchdog.clone();
    let feed = RefCell::new(move || feeder.pet());
    // SAFETY: the flash interface has no other user: this is the only code running, and it takes it once.
    #[allow(unsafe_code)]
    let flash = unsafe { embassy_stm32::peripherals::FLASH::steal() };
    let regions = Flash::new_blocking(flash).into_blocking_regions();
    let mut state = Feeding {
        flash: Flash32(regions.bank1_region2),
        feed: &feed,
    };
    let images = Mutex::<NoopRawMutex, _>::new(RefCell::new(Feeding {
        flash: Flash32(regions.bank1_region3),
        feed: &feed,
    }));
    // The partitions check that they are whole sectors (a constant panic, on every boot or none).
    let mut active = BlockingPartition::new(&images, ACTIVE_BASE - REGION3_BASE, ACTIVE_LEN);
    let mut dfu = BlockingPartition::new(&images, DFU_BASE - REGION3_BASE, DFU_LEN);
    let mut copy = AlignedBuffer([0u8; COPY_BUFFER_LEN]);
    // One write word of the state partition (embassy-boot's state word).
    let mut word = [0u8; WRITE_SIZE];

    let mut decide = |active: &mut _, dfu: &mut _, state: &mut _| {
        (*feed.borrow_mut())();
        let report = boot::prepare(
            active,
            dfu,
            state,
            &mut copy.0,
            &mut word,
            &UPDATE_PUBLIC_KEY,
            BOARD_ID,
        );
        (*feed.borrow_mut())();
        report
    };
    let Ok(mut report) = decide(&mut active, &mut dfu, &mut state) else {
        wait_for_watchdog()
    };
    if report.action == BootAction::Booted
        && !vectors_plausible(&mut active)
        && dfu_could_replace(&mut active, &mut dfu, &feed)
    {
        // ACTIVE cannot start (never written, or damaged) and DFU holds an image that can: swap it in. (Checked
        // first, reading only: asking for a swap that would be refused would erase the state sector at every boot.)
        let mut scratch = [0u8; WRITE_SIZE];
        if BlockingFirmwareState::new(&mut state, &mut scratch)
            .mark_updated()
            .is_err()
        {
            wait_for_watchdog()
        }
        let Ok(again) = decide(&mut active, &mut dfu, &mut state) else {
            wait_for_watchdog()
        };
        report = again;
    }
    write_boot_report(&report);
    if !vectors_plausible(&mut active) {
        wait_for_watchdog()
    }
    // SAFETY: ACTIVE + 0x200 holds a vector table whose stack pointer is in SRAM and whose reset vector is a Thumb
    // address in ACTIVE (checked just above); nothing of the bootloader is used after the jump.
    #[allow(unsafe_code)]
    unsafe {
        embassy_boot_stm32::BootLoader { state: State::Boot }.load(APP_FLASH_BASE)
    }
}

/// Whether DFU's image could start and verifies against ACTIVE's version (reads only; the IWDG is reloaded before
/// and after: the check is the longest stretch without a flash write).
fn dfu_could_replace<A: ReadNorFlash, D: ReadNorFlash>(
    active: &mut A,
    dfu: &mut D,
    feed: &RefCell<impl FnMut()>,
) -> bool {
    if !vectors_plausible(dfu) {
        return false;
    }
    let running = image::read_header(active).map_or(0, |h| h.version);
    (*feed.borrow_mut())();
    let verdict = image::verify_slot(dfu, &UPDATE_PUBLIC_KEY, BOARD_ID, running, ACTIVE_LEN);
    (*feed.borrow_mut())();
    verdict.is_ok()
}

/// Whether a slot's vector table (after the image header) could start the application in ACTIVE.
fn vectors_plausible<F: ReadNorFlash>(slot: &mut F) -> bool {
    let mut words = [0u8; 8];
    if slot.read(IMAGE_HEADER_LEN, &mut words).is_err() {
        return false;
    }
    let (sp, reset) = words.split_at(4);
    let word = |b: &[u8]| b.try_into().map_or(0, u32::from_le_bytes);
    app_vectors_plausible(word(sp), word(reset))
}

/// Writes the boot report into the first bytes of SRAM, the rest of its window zero.
fn write_boot_report(report: &BootReport) {
    let words = report.to_words();
    let base = BOOT_REPORT_ADDR as *mut u32;
    for i in 0..(BOOT_REPORT_LEN / 4) as usize {
        let w = words.get(i).copied().unwrap_or(0);
        // SAFETY: `BOOT_REPORT_ADDR` is the start of SRAM, word-aligned, and the window's `BOOT_REPORT_LEN` bytes
        // belong to no section of this ELF (its `memory.x` starts RAM after them; so does the application's).
        #[allow(unsafe_code)]
        unsafe {
            base.add(i).write_volatile(w)
        };
    }
}

/// Nothing to start, or the flash failed: spin without reloading the IWDG, which resets the board within its
/// timeout (no faster loop: a reset every 8 s at most).
fn wait_for_watchdog() -> ! {
    loop {
        cortex_m::asm::nop();
    }
}

/// A fault (a bad address, a stack overflow below the RAM window): reset.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn HardFault(_frame: &cortex_m_rt::ExceptionFrame) -> ! {
    SCB::sys_reset()
}

/// An exception or interrupt without a handler (none is enabled): reset.
#[cortex_m_rt::exception]
#[allow(unsafe_code)]
unsafe fn DefaultHandler(_irqn: i16) -> ! {
    SCB::sys_reset()
}

/// A panic (none is expected: embassy-boot's checks of the partitions' geometry are constant): reset.
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    SCB::sys_reset()
}
