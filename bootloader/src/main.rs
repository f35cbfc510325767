//! The bootloader (`docs/update.md`): sectors 0–1 of the STM32F405RG, where the core starts. Each boot:
//!
//! 1. starts the independent watchdog (`firmware::chip::start_watchdog`, the firmware's 8 s), first of all; every
//!    flash erase and write below reloads it ([`slots::Fed`]);
//! 2. reads embassy-boot's state. If a swap is pending and has not begun, checks the image in DFU first
//!    (`update::image::verify_slot`: header, board, version above ACTIVE's, size, Ed25519 signature, SHA-512 of the
//!    payload) and, if it is refused, cancels the swap ([`slots::Slots::cancel_swap`]) and boots the old image;
//! 3. lets embassy-boot swap (a pending swap, or one a reset cut short) or revert (a trial image that never marked
//!    itself booted);
//! 4. if ACTIVE then holds no vector table it could start (`layout::app_vectors_plausible`) and nothing was swapped
//!    this boot, swaps DFU in when DFU holds an image that verifies;
//! 5. leaves the boot report (`update::BootReport`, at `layout::BOOT_REPORT_ADDR`) and jumps to the application's
//!    vector table at ACTIVE + 0x200, or, with nothing it could start, waits for the IWDG to reset the board.
//!
//! The clocks stay as the reset left them (the 16 MHz HSI), and so does every peripheral but the IWDG and the
//! flash interface (locked again after each operation): the application starts from a chip in its reset state.
//! FDIR: a HardFault, an unexpected interrupt and a panic reset the board (none is expected: the code that reads
//! flash data cannot panic, by the same lints as the firmware's); a flash operation that fails in the middle of a
//! swap leaves the board waiting for the IWDG, and the next boot resumes the swap from embassy-boot's progress
//! words.
#![no_std]
#![no_main]

mod slots;
mod update_stub;

use core::cell::RefCell;

use cortex_m::peripheral::SCB;
use embassy_boot_stm32::State;
use embassy_stm32::flash::Flash;
use embassy_sync::blocking_mutex::Mutex;
use embedded_storage::nor_flash::ReadNorFlash;
use firmware::chip::{Flash32, Watchdog, start_watchdog};
use firmware::layout::{
    ACTIVE_LEN, APP_FLASH_BASE, BOARD_ID, BOOT_REPORT_ADDR, BOOT_REPORT_LEN, IMAGE_HEADER_LEN,
    app_vectors_plausible,
};
use slots::{Fed, Slots};
// TEMPORARY: `shared::update` once it is on main.
use update::{BootAction, BootReport, ImageError};
use update_stub as update;

include!(concat!(env!("OUT_DIR"), "/update_pubkey.rs"));

const _: () = assert!(IMAGE_HEADER_LEN as usize == update::image::HEADER_LEN);

#[cortex_m_rt::entry]
fn main() -> ! {
    // First of all: a hang anywhere below resets the board.
    let mut watchdog = start_watchdog();
    // SAFETY: the flash interface has no other user: this is the only code running, and it takes it once.
    #[allow(unsafe_code)]
    let flash = unsafe { embassy_stm32::peripherals::FLASH::steal() };
    let regions = Flash::new_blocking(flash).into_blocking_regions();
    let state_flash = Mutex::new(RefCell::new(Fed::new(
        Flash32(regions.bank1_region2),
        watchdog.clone(),
    )));
    let image_flash = Mutex::new(RefCell::new(Fed::new(
        Flash32(regions.bank1_region3),
        watchdog.clone(),
    )));
    let mut slots = Slots::new(&state_flash, &image_flash);

    let Some(report) = boot(&mut slots, &mut watchdog) else {
        wait_for_watchdog()
    };
    watchdog.pet();
    write_boot_report(&report);
    if !vectors_plausible(&mut slots) {
        wait_for_watchdog()
    }
    // SAFETY: ACTIVE + 0x200 holds a vector table whose stack pointer is in SRAM and whose reset vector is a Thumb
    // address in ACTIVE (checked just above); nothing of the bootloader is used after the jump.
    #[allow(unsafe_code)]
    unsafe {
        embassy_boot_stm32::BootLoader { state: State::Boot }.load(APP_FLASH_BASE)
    }
}

/// Steps 2–4 of the module's list: the boot report, or `None` if the flash failed in the middle of a swap.
fn boot(slots: &mut Slots, watchdog: &mut Watchdog) -> Option<BootReport> {
    let running = header_version(&mut slots.active);
    let dfu_version = header_version(&mut slots.dfu);
    let found = slots.state().ok()?;
    let mut action = BootAction::Booted;
    let mut refusal = None;
    if found == State::Swap
        && slots.swap_not_started().ok()?
        && let Err(e) = verify(slots, watchdog, running)
    {
        slots.cancel_swap().ok()?;
        action = BootAction::Refused;
        refusal = Some(e);
    }
    slots.prepare().ok()?;
    watchdog.pet();
    if action == BootAction::Booted && found == State::Swap {
        // A swap leaves the magic `Swap` (the trial image marks itself booted); a revert leaves `Revert`.
        action = match slots.state().ok()? {
            State::Revert => BootAction::Reverted,
            _ => BootAction::Swapped,
        };
    }
    if action == BootAction::Booted && !vectors_plausible(slots) {
        // ACTIVE cannot start (never written, or damaged): DFU's image, if it verifies, is better than nothing.
        match verify(slots, watchdog, running) {
            Ok(()) => {
                slots.mark_updated().ok()?;
                slots.prepare().ok()?;
                watchdog.pet();
                action = BootAction::Swapped;
            }
            Err(e) => refusal = Some(e),
        }
    }
    Some(BootReport {
        action,
        refusal: refusal.map_or(0, ImageError::code),
        active_version: header_version(&mut slots.active),
        dfu_version,
    })
}

/// The whole check of DFU's image (`update::image::verify_slot`) against this board, the public key built in and
/// ACTIVE's version. It only reads (the IWDG is reloaded before and after): SHA-512 of at most 256 KiB and one
/// Ed25519 verification on the 16 MHz HSI must end within the IWDG's shortest timeout (5.4 s).
fn verify(slots: &mut Slots, watchdog: &mut Watchdog, running: u32) -> Result<(), ImageError> {
    watchdog.pet();
    let verdict = update::image::verify_slot(
        &mut slots.dfu,
        &UPDATE_PUBLIC_KEY,
        BOARD_ID,
        running,
        ACTIVE_LEN,
    );
    watchdog.pet();
    verdict.map(|_| ())
}

/// The version in a slot's header, 0 without a valid one (an image flashed by a probe has none).
fn header_version<F: ReadNorFlash>(slot: &mut F) -> u32 {
    update::image::read_header(slot).map_or(0, |h| h.version)
}

/// Whether ACTIVE's vector table (after the header) could start the application.
fn vectors_plausible(slots: &mut Slots) -> bool {
    let mut words = [0u8; 8];
    if slots.active.read(IMAGE_HEADER_LEN, &mut words).is_err() {
        return false;
    }
    let (sp, reset) = words.split_at(4);
    let word = |b: &[u8]| b.try_into().map_or(0, u32::from_le_bytes);
    app_vectors_plausible(word(sp), word(reset))
}

/// Writes the boot report into the first bytes of SRAM, the rest of its window zero.
fn write_boot_report(report: &BootReport) {
    let words = report.to_words();
    let window = (BOOT_REPORT_LEN / 4) as usize;
    const _: () = assert!(update::boot_report::WORDS <= (BOOT_REPORT_LEN / 4) as usize);
    let base = BOOT_REPORT_ADDR as *mut u32;
    for i in 0..window {
        let w = words.get(i).copied().unwrap_or(0);
        // SAFETY: `BOOT_REPORT_ADDR` is the start of SRAM, word-aligned, and the window's `BOOT_REPORT_LEN` bytes
        // belong to no section of this ELF (its `memory.x` starts RAM after them; so does the application's).
        #[allow(unsafe_code)]
        unsafe {
            base.add(i).write_volatile(w)
        };
    }
}

/// Nothing to start: spin without reloading the IWDG, which resets the board within its timeout.
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
