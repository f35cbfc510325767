//! The bootloader's decision, sans-IO: what `bootloader/` runs at every reset and what the SITL tests run on the
//! flash models, so that both exercise one implementation.
//!
//! 1. A swap requested and not started yet: the image in DFU is checked first ([`super::image::verify_slot`]:
//!    board, version above ACTIVE's, size, signature, hash). A refused image cancels the request (the state
//!    partition back to `Boot`) and ACTIVE boots unchanged.
//! 2. embassy-boot's `BootLoader::prepare_boot` does the rest: the power-fail-safe swap, or the revert of a trial
//!    image that did not confirm itself (`mark_booted`) before this reset. A swap cut by a reset resumes from its
//!    progress words.
//! 3. The [`BootReport`] says what happened.
//!
//! Every flash operation goes through [`Feeding`], which calls the watchdog feed before it: a 128 KiB erase stalls
//! the F405 for up to 2 s, well inside the IWDG's timeout, so the watchdog keeps running through a swap.

use embassy_boot::{BlockingFirmwareState, BootLoader, BootLoaderConfig, State};
use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

use super::boot_report::{BootAction, BootReport};
use super::image::{self, ImageError};

/// A flash that calls `feed` before every erase and write.
pub struct Feeding<'a, F, W: FnMut()> {
    /// The flash.
    pub flash: F,
    /// Called before each erase and write.
    pub feed: &'a core::cell::RefCell<W>,
}

impl<F: ErrorType, W: FnMut()> ErrorType for Feeding<'_, F, W> {
    type Error = F::Error;
}

impl<F: ReadNorFlash, W: FnMut()> ReadNorFlash for Feeding<'_, F, W> {
    const READ_SIZE: usize = F::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), F::Error> {
        self.flash.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.flash.capacity()
    }
}

impl<F: NorFlash, W: FnMut()> NorFlash for Feeding<'_, F, W> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), F::Error> {
        if let Ok(mut feed) = self.feed.try_borrow_mut() {
            (*feed)();
        }
        self.flash.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), F::Error> {
        if let Ok(mut feed) = self.feed.try_borrow_mut() {
            (*feed)();
        }
        self.flash.write(offset, bytes)
    }
}

/// Why the boot could not be prepared: a flash operation failed (the next reset tries again from the progress the
/// state partition holds).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BootFlashError;

/// The swap has been requested and not started: the state word says `Swap` and the progress words after it are
/// still erased (embassy-boot 0.7's layout: magic, progress-valid, then the progress indices, one write word each).
fn swap_not_started<S: NorFlash>(state: &mut S) -> Result<bool, BootFlashError> {
    let mut word = [0u8; 16];
    let w = S::WRITE_SIZE;
    let words = word.get_mut(..w.saturating_mul(3)).ok_or(BootFlashError)?;
    state.read(0, words).map_err(|_| BootFlashError)?;
    let (magic, progress) = words.split_at(w);
    Ok(State::from(magic) == State::Swap && progress.iter().all(|&b| b == 0xFF))
}

/// The state partition's state (`aligned`: one write word of scratch).
fn state_of<S: NorFlash>(state: &mut S, aligned: &mut [u8]) -> Result<State, BootFlashError> {
    BlockingFirmwareState::new(state, aligned)
        .get_state()
        .map_err(|_| BootFlashError)
}

/// Prepares the boot (module doc): verify a requested image, swap or revert, report. `aligned` is the copy buffer
/// (a divisor of the 128 KiB page, at least a write word); `scratch` one write word of the state partition.
pub fn prepare<A: NorFlash, D: NorFlash, S: NorFlash>(
    active: &mut A,
    dfu: &mut D,
    state: &mut S,
    aligned: &mut [u8],
    scratch: &mut [u8],
    public_key: &[u8; 32],
    board_id: u32,
) -> Result<BootReport, BootFlashError> {
    let version_of = |h: Result<image::Header, ImageError>| h.map_or(0, |h| h.version);
    let running = version_of(image::read_header(active));
    // Before the swap: afterwards DFU's first page still holds the new image's (embassy-boot shifts the previous
    // image one page up in DFU).
    let offered = version_of(image::read_header(dfu));
    let mut refusal = None;
    if swap_not_started(state)? {
        let max = u32::try_from(active.capacity()).unwrap_or(u32::MAX);
        if let Err(e) = image::verify_slot(dfu, public_key, board_id, running, max) {
            BlockingFirmwareState::new(&mut *state, &mut *scratch)
                .mark_booted()
                .map_err(|_| BootFlashError)?;
            refusal = Some(e);
        }
    }
    let before = state_of(state, scratch)?;
    BootLoader::new(BootLoaderConfig {
        active: &mut *active,
        dfu: &mut *dfu,
        state: &mut *state,
    })
    .prepare_boot(aligned)
    .map_err(|_| BootFlashError)?;
    let after = state_of(state, scratch)?;
    let action = match (refusal, before, after) {
        (Some(_), _, _) => BootAction::Refused,
        (None, State::Swap, State::Revert) => BootAction::Reverted,
        (None, State::Swap, _) => BootAction::Swapped,
        _ => BootAction::Booted,
    };
    Ok(BootReport {
        action,
        refusal: refusal.map_or(0, ImageError::code),
        active_version: version_of(image::read_header(active)),
        dfu_version: offered,
    })
}
