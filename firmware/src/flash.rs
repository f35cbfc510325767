//! A `NorFlash` window that confines every access to a fixed, erase-aligned sub-range of a larger `NorFlash`
//! (here: sectors 1 and 2 of the STM32F405 inside embassy-stm32's `Bank1Region1`), for `shared::storage`.
//! Chip-independent: `board.rs` decides which flash and which offsets.

use embedded_storage::nor_flash::{ErrorType, NorFlash, ReadNorFlash};

/// Errors of the window: either out of the window / misaligned, or the inner flash error.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum WindowError<E> {
    /// Access outside `0..len` of the window.
    OutOfBounds,
    /// Offset/length not aligned to the inner flash's write/erase granularity.
    NotAligned,
    /// Error from the underlying flash driver.
    Flash(E),
}

impl<E: embedded_storage::nor_flash::NorFlashError> embedded_storage::nor_flash::NorFlashError
    for WindowError<E>
{
    fn kind(&self) -> embedded_storage::nor_flash::NorFlashErrorKind {
        use embedded_storage::nor_flash::NorFlashErrorKind as K;
        match self {
            Self::OutOfBounds => K::OutOfBounds,
            Self::NotAligned => K::NotAligned,
            Self::Flash(e) => e.kind(),
        }
    }
}

/// `[base, base + len)` of an inner `NorFlash`, re-exposed as offsets `0..len`.
pub struct FlashWindow<F> {
    inner: F,
    base: u32,
    len: u32,
}

impl<F: NorFlash> FlashWindow<F> {
    /// `base` and `len` are offsets in the *inner* flash's address space and must be
    /// multiples of `F::ERASE_SIZE` (checked here: a misconfigured window panics at boot,
    /// not at the first erase).
    pub fn new(inner: F, base: u32, len: u32) -> Self {
        let erase = F::ERASE_SIZE as u32;
        assert!(len > 0 && base.is_multiple_of(erase) && len.is_multiple_of(erase));
        assert!(
            (base as usize)
                .checked_add(len as usize)
                .is_some_and(|end| end <= inner.capacity())
        );
        Self { inner, base, len }
    }

    fn check(&self, offset: u32, len: usize) -> Result<u32, WindowError<F::Error>> {
        let end = (offset as usize)
            .checked_add(len)
            .ok_or(WindowError::OutOfBounds)?;
        if end > self.len as usize {
            return Err(WindowError::OutOfBounds);
        }
        self.base
            .checked_add(offset)
            .ok_or(WindowError::OutOfBounds)
    }
}

impl<F: NorFlash> ErrorType for FlashWindow<F> {
    type Error = WindowError<F::Error>;
}

impl<F: NorFlash> ReadNorFlash for FlashWindow<F> {
    const READ_SIZE: usize = F::READ_SIZE;

    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), Self::Error> {
        let abs = self.check(offset, bytes.len())?;
        self.inner.read(abs, bytes).map_err(WindowError::Flash)
    }

    fn capacity(&self) -> usize {
        self.len as usize
    }
}

impl<F: NorFlash> NorFlash for FlashWindow<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;

    fn erase(&mut self, from: u32, to: u32) -> Result<(), Self::Error> {
        let len = to.checked_sub(from).ok_or(WindowError::OutOfBounds)?;
        if !(from as usize).is_multiple_of(Self::ERASE_SIZE)
            || !(to as usize).is_multiple_of(Self::ERASE_SIZE)
        {
            return Err(WindowError::NotAligned);
        }
        let abs = self.check(from, len as usize)?;
        let abs_end = abs.checked_add(len).ok_or(WindowError::OutOfBounds)?;
        self.inner.erase(abs, abs_end).map_err(WindowError::Flash)
    }

    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), Self::Error> {
        if !(offset as usize).is_multiple_of(Self::WRITE_SIZE)
            || !bytes.len().is_multiple_of(Self::WRITE_SIZE)
        {
            return Err(WindowError::NotAligned);
        }
        let abs = self.check(offset, bytes.len())?;
        self.inner.write(abs, bytes).map_err(WindowError::Flash)
    }
}
