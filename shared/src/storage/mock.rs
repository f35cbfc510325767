//! A NOR-flash test double for the A/B store (host only: feature `mock-flash`, and the crate's own tests): 4-byte
//! words, erase blocks of `E` bytes (1 KiB by default; the firmware's host-run tasks use the STM32F405's 128 KiB
//! sectors), and a power cut after `budget` operations (one operation = one block erase or one
//! word write). An interrupted erase leaves its block half erased, half garbage; a write to a word that is not erased
//! is refused (`NotErased`), which catches a store that writes before it erases. Shared by `storage`'s tests and the
//! `storage` fuzz target, so both exercise the same flash model.
//!
//! Not flight code: it allocates, and the no-panic lints are lifted here (an index out of range in the test double
//! is a test failure, reported by the panic).
#![allow(
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects,
    clippy::cast_possible_truncation
)]

extern crate std;
use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
use std::vec;
use std::vec::Vec;

/// Default erase block, bytes.
pub const ERASE: usize = 1024;

/// Why a mock flash operation failed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum MockError {
    /// The power was cut (the operation budget is spent).
    PowerCut,
    /// A write to bytes that were not erased: a logic error of the store.
    NotErased,
    /// Outside the flash.
    OutOfBounds,
}

impl NorFlashError for MockError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            MockError::OutOfBounds => NorFlashErrorKind::OutOfBounds,
            _ => NorFlashErrorKind::Other,
        }
    }
}

/// The flash: its bytes, the operation budget before the power cut (`None`: never) and the operations done; erase
/// blocks of `E` bytes.
#[derive(Clone, Debug)]
pub struct MockFlash<const E: usize = ERASE> {
    /// Contents.
    pub mem: Vec<u8>,
    /// Operations allowed before the power cut.
    pub budget: Option<usize>,
    /// Operations done.
    pub ops: usize,
}

impl<const E: usize> MockFlash<E> {
    /// An erased flash of `blocks` erase blocks, without a power cut.
    pub fn erased(blocks: usize) -> Self {
        Self {
            mem: vec![0xFF; blocks * E],
            budget: None,
            ops: 0,
        }
    }

    fn step(&mut self) -> Result<(), MockError> {
        if self.budget.is_some_and(|b| self.ops >= b) {
            return Err(MockError::PowerCut);
        }
        self.ops += 1;
        Ok(())
    }
}

impl<const E: usize> ErrorType for MockFlash<E> {
    type Error = MockError;
}

impl<const E: usize> ReadNorFlash for MockFlash<E> {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), MockError> {
        let src = self
            .mem
            .get(offset as usize..offset as usize + bytes.len())
            .ok_or(MockError::OutOfBounds)?;
        bytes.copy_from_slice(src);
        Ok(())
    }
    fn capacity(&self) -> usize {
        self.mem.len()
    }
}

impl<const E: usize> NorFlash for MockFlash<E> {
    const WRITE_SIZE: usize = 4;
    const ERASE_SIZE: usize = E;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), MockError> {
        for block in (from as usize..to as usize).step_by(E) {
            let cut = self.step();
            let b = self
                .mem
                .get_mut(block..block + E)
                .ok_or(MockError::OutOfBounds)?;
            if cut.is_err() {
                b[..E / 2].fill(0xFF);
                b[E / 2..]
                    .iter_mut()
                    .enumerate()
                    .for_each(|(i, x)| *x = (i * 7 + 3) as u8);
                return cut;
            }
            b.fill(0xFF);
        }
        Ok(())
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), MockError> {
        for (i, word) in bytes.chunks(4).enumerate() {
            self.step()?;
            let at = offset as usize + 4 * i;
            let dst = self
                .mem
                .get_mut(at..at + word.len())
                .ok_or(MockError::OutOfBounds)?;
            if dst.iter().any(|&b| b != 0xFF) {
                return Err(MockError::NotErased);
            }
            dst.copy_from_slice(word);
        }
        Ok(())
    }
}
