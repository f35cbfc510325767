//! Register-level STM32F405 code that the flight firmware (`src/board.rs`) and the bootloader (`bootloader/`) both
//! run, written once: the independent watchdog's start and reload, and flash erases at x32 parallelism.
//!
//! Feature `chip`: embassy-stm32 (PAC and flash driver) and cortex-m only, without defmt or a time driver, which
//! the bootloader links neither of; the flight build's feature `stm32` includes it.

use embassy_stm32::pac::iwdg::vals::Key;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

use crate::layout::WATCHDOG_PR_RL;

/// The independent watchdog, running from [`start_watchdog`] on: `pet` reloads it. A clone reloads the same one
/// (the bootloader's flash adapter holds one).
#[derive(Clone)]
pub struct Watchdog(());

impl Watchdog {
    /// Reloads the counter.
    pub fn pet(&mut self) {
        embassy_stm32::pac::IWDG
            .kr()
            .write(|w| w.set_key(IWDG_KEY_RELOAD));
    }
}

const IWDG_KEY_RELOAD: Key = Key::RESET;

/// Starts the IWDG with its [`WATCHDOG_TIMEOUT_US`](crate::layout::WATCHDOG_TIMEOUT_US) timeout ([`WATCHDOG_PR_RL`]): the first thing the
/// bootloader and the firmware's `main` do, before the clocks, so that a hang anywhere after (embassy waits for
/// ready bits without a timeout; a flash operation that never ends) resets the board. Once started it runs until
/// the next reset: starting it again (the firmware, after the bootloader) writes the same prescaler and reload.
/// Register access only (the IWDG runs from the LSI, which starting it turns on; it needs no bus clock). Freezes
/// it while a debugger halts the core. RM0090 §21.3: start (0xCCCC), unlock PR/RLR (0x5555), write them, reload
/// (0xAAAA).
pub fn start_watchdog() -> Watchdog {
    use embassy_stm32::pac::iwdg::vals::Pr;
    use embassy_stm32::pac::{DBGMCU, IWDG};
    DBGMCU.apb1fzr().modify(|w| w.set_iwdg(true));
    let (pr, rl) = WATCHDOG_PR_RL;
    IWDG.kr().write(|w| w.set_key(Key::START));
    IWDG.kr().write(|w| w.set_key(Key::ENABLE));
    IWDG.pr().write(|w| w.set_pr(Pr::from_bits(pr)));
    IWDG.rlr().write(|w| w.set_rl(rl));
    // The new values reach the LSI domain a few LSI cycles later (PVU/RVU set until then: ≈ 0.2 ms with the LSI's
    // start); a reload before that would load the old reload value. Bounded: 2¹⁶ polls ≫ 0.2 ms at 16 MHz.
    for _ in 0..(1u32 << 16) {
        let sr = IWDG.sr().read();
        if !sr.pvu() && !sr.rvu() {
            break;
        }
    }
    IWDG.kr().write(|w| w.set_key(IWDG_KEY_RELOAD));
    Watchdog(())
}

/// One of embassy-stm32's flash regions (`Bank1Region1` …) with erases at x32 parallelism and a data-cache reset
/// after every erase and program. embassy-stm32 0.6 erases with whatever PSIZE is in FLASH_CR, which its writes
/// leave at x8: a 16 KiB erase then takes up to 0.8 s instead of 0.5 s, a 128 KiB one 4 s instead of 2 s (DS8626).
/// The D-cache may hold the old contents of what was just changed (RM0090 §3.5.2). x32 needs VDD 2.7–3.6 V
/// (DS8626): the board's 3.3 V rail.
pub struct Flash32<F>(pub F);

impl<F: ErrorType> ErrorType for Flash32<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Flash32<F> {
    const READ_SIZE: usize = F::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.0.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> NorFlash for Flash32<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        use embassy_stm32::pac::FLASH;
        use embassy_stm32::pac::flash::vals::Psize;
        // Unlock (embassy's erase then skips its own unlock and keeps CR's PSIZE: it only `modify`s SER/SNB/STRT,
        // and locks again when done).
        cortex_m::interrupt::free(|_| {
            if FLASH.cr().read().lock() {
                FLASH.keyr().write_value(0x4567_0123);
                FLASH.keyr().write_value(0xCDEF_89AB);
            }
            FLASH.cr().modify(|w| w.set_psize(Psize::PSIZE32));
        });
        let r = self.0.erase(from, to);
        reset_data_cache();
        r
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let r = self.0.write(offset, bytes);
        reset_data_cache();
        r
    }
}

fn reset_data_cache() {
    use embassy_stm32::pac::FLASH;
    if FLASH.acr().read().dcen() {
        FLASH.acr().modify(|w| w.set_dcen(false));
        FLASH.acr().modify(|w| w.set_dcrst(true));
        FLASH.acr().modify(|w| w.set_dcrst(false));
        FLASH.acr().modify(|w| w.set_dcen(true));
    }
}
