//! The flash as the bootloader sees it: embassy-boot's three partitions (`STATE`, `ACTIVE`, `DFU`; addresses from
//! `firmware::layout`) over embassy-stm32's flash regions, with x32 erases (`firmware::chip::Flash32`) and the IWDG
//! reloaded around every erase and after every write ([`Fed`]), and the few reads and writes of the state partition
//! that embassy-boot does not offer.
//!
//! Partitions: `STATE` is sector 4, embassy's `Bank1Region2` (one 64 KiB sector); `ACTIVE` and `DFU` are in
//! `Bank1Region3` (sectors 5–11, 128 KiB each), whose erase unit is embassy-boot's page. (One partition over the
//! whole flash would have embassy's largest erase size, 128 KiB, for `STATE` too, which is not a multiple of it.)

use core::cell::RefCell;

use embassy_boot_stm32::{BlockingFirmwareState, BootError, BootLoaderConfig, State};
use embassy_embedded_hal::flash::partition::BlockingPartition;
use embassy_stm32::flash::{Bank1Region2, Bank1Region3, Blocking};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::NoopRawMutex;
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};
use firmware::chip::{Flash32, Watchdog};
use firmware::layout::{ACTIVE_BASE, ACTIVE_LEN, DFU_BASE, DFU_LEN, STATE_BASE, STATE_LEN};

/// Where embassy's `Bank1Region2` (sector 4) starts.
const REGION2_BASE: u32 = 0x0801_0000;
/// Where embassy's `Bank1Region3` (sectors 5–11) starts.
const REGION3_BASE: u32 = 0x0802_0000;
const _: () = assert!(
    STATE_BASE == REGION2_BASE && STATE_LEN == 64 * 1024,
    "STATE is sector 4"
);
const _: () = assert!(ACTIVE_BASE >= REGION3_BASE && DFU_BASE >= REGION3_BASE);

/// Bytes embassy-boot copies at a time while it swaps (its page, 128 KiB, is a multiple): one write of it is
/// 512 words, ≤ 51 ms at 100 µs a word (DS8626), between two reloads of the IWDG.
pub const COPY_BUFFER_LEN: usize = 2048;

/// A flash with the independent watchdog reloaded before and after every erase (a 128 KiB erase stalls the CPU
/// ≤ 2 s, `layout::ERASE_IMAGE_SECTOR_US`; the IWDG lasts ≥ 5.4 s, `layout::WATCHDOG_TIMEOUT_MIN_US`) and after
/// every write. Reads do not reload it: a loop that only reads (a hash, a check) must end within the timeout by
/// itself, or the IWDG resets the board.
pub struct Fed<F> {
    flash: F,
    watchdog: Watchdog,
}

impl<F> Fed<F> {
    pub fn new(flash: F, watchdog: Watchdog) -> Self {
        Self { flash, watchdog }
    }
}

impl<F: ErrorType> ErrorType for Fed<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Fed<F> {
    const READ_SIZE: usize = F::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        self.flash.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash> NorFlash for Fed<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        self.watchdog.pet();
        let r = self.flash.erase(from, to);
        self.watchdog.pet();
        r
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        let r = self.flash.write(offset, bytes);
        self.watchdog.pet();
        r
    }
}

/// Sector 4, fed.
pub type StateFlash = Fed<Flash32<Bank1Region2<'static, Blocking>>>;
/// Sectors 5–11, fed.
pub type ImageFlash = Fed<Flash32<Bank1Region3<'static, Blocking>>>;
/// A partition of one of them.
pub type Part<'a, F> = BlockingPartition<'a, NoopRawMutex, F>;

/// embassy-boot's state word: one flash write (`STATE`'s write size, 4 bytes).
const WORD: usize = <StateFlash as NorFlash>::WRITE_SIZE;
/// What an erased byte reads.
const ERASED: u8 = 0xFF;

/// The three partitions.
pub struct Slots<'a> {
    pub state: Part<'a, StateFlash>,
    pub active: Part<'a, ImageFlash>,
    pub dfu: Part<'a, ImageFlash>,
}

impl<'a> Slots<'a> {
    /// The partitions on the two regions (the partitions check at construction that they are whole sectors).
    pub fn new(
        state: &'a Mutex<NoopRawMutex, RefCell<StateFlash>>,
        images: &'a Mutex<NoopRawMutex, RefCell<ImageFlash>>,
    ) -> Self {
        Self {
            state: BlockingPartition::new(state, STATE_BASE - REGION2_BASE, STATE_LEN),
            active: BlockingPartition::new(images, ACTIVE_BASE - REGION3_BASE, ACTIVE_LEN),
            dfu: BlockingPartition::new(images, DFU_BASE - REGION3_BASE, DFU_LEN),
        }
    }

    /// The state embassy-boot's magic word says.
    pub fn state(&mut self) -> Result<State, BootError> {
        let mut word = [0u8; WORD];
        BlockingFirmwareState::new(self.state.clone(), &mut word)
            .get_state()
            .map_err(|_| BootError::BadMagic)
    }

    /// Whether a pending swap has not begun: embassy-boot's progress-valid word (at one word) and its first
    /// progress word (at two words: the first page copied) are both still erased (`boot_loader.rs`,
    /// `current_progress`). Only then does DFU hold the image as it arrived, and may the swap be cancelled.
    pub fn swap_not_started(&mut self) -> Result<bool, BootError> {
        let mut word = [0u8; WORD];
        for at in [WORD, 2 * WORD] {
            self.state.read(at as u32, &mut word)?;
            if word.iter().any(|&b| b != ERASED) {
                return Ok(false);
            }
        }
        Ok(true)
    }

    /// Cancels a swap that has not begun ([`swap_not_started`](Self::swap_not_started)): erases the state sector,
    /// which reads as `State::Boot`. Not embassy's `mark_booted`: that first marks the swap's progress invalid,
    /// then erases, and a reset between the two would make the next boot "revert" a swap that never happened,
    /// copying DFU's pages over ACTIVE. An erase cut short leaves the magic `SWAP` (the next boot checks the image
    /// again and cancels again) or anything else (`Boot`); the progress words were erased and stay so.
    pub fn cancel_swap(&mut self) -> Result<(), BootError> {
        self.state.erase(0, STATE_LEN)?;
        Ok(())
    }

    /// Asks for a swap at this boot (embassy-boot's `mark_updated`: the magic word `SWAP`).
    pub fn mark_updated(&mut self) -> Result<(), BootError> {
        let mut word = [0u8; WORD];
        BlockingFirmwareState::new(self.state.clone(), &mut word)
            .mark_updated()
            .map_err(|_| BootError::BadMagic)
    }

    /// embassy-boot's `prepare_boot`: swaps DFU in if a swap is pending and has not completed, reverts it if it has
    /// (the trial image never marked itself booted), nothing otherwise. Returns the state it found.
    pub fn prepare(&mut self) -> Result<State, BootError> {
        let config = BootLoaderConfig {
            active: self.active.clone(),
            dfu: self.dfu.clone(),
            state: self.state.clone(),
        };
        embassy_boot_stm32::BootLoader::try_prepare::<_, _, _, COPY_BUFFER_LEN>(config)
            .map(|loader| loader.state)
    }
}
