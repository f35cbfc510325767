//! The calibration flash on the host: `shared`'s NOR-flash model ([`MockFlash`]: 4-byte program words, erase
//! blocks, power cuts, refusal to program a word that is not erased) with the geometry of the two STM32F405 sectors
//! the firmware uses, optionally kept in a file (the SITL's `--flash FILE`): every erase and write also lands in the
//! file at the same offset, so a SITL killed at any moment leaves the image the MCU's flash would hold.

use std::format;
use std::fs::File;
use std::io;
use std::os::unix::fs::FileExt;
use std::path::Path;

use embedded_storage::nor_flash::{
    ErrorType, NorFlash, NorFlashError, NorFlashErrorKind, ReadNorFlash,
};
pub use shared::storage::mock::MockError;
use shared::storage::mock::MockFlash;

use crate::layout::{CAL_SECTOR_LEN, CAL_SECTORS, FLASH_WRITE_LEN};

/// The calibration sectors as a RAM model.
pub type CalFlashModel = MockFlash<CAL_SECTOR_LEN>;

/// An erased model of the calibration sectors.
pub fn erased() -> CalFlashModel {
    CalFlashModel::erased(CAL_SECTORS)
}

/// Errors of the file-backed flash.
#[derive(Debug)]
pub enum SimFlashError {
    /// The model refused the operation.
    Model(MockError),
    /// The file could not be written.
    File(io::ErrorKind),
}

impl NorFlashError for SimFlashError {
    fn kind(&self) -> NorFlashErrorKind {
        match self {
            SimFlashError::Model(e) => e.kind(),
            SimFlashError::File(_) => NorFlashErrorKind::Other,
        }
    }
}

/// The calibration sectors, in RAM and mirrored to a file.
pub struct FileFlash {
    model: CalFlashModel,
    file: File,
}

impl FileFlash {
    /// Opens (or creates, erased) the image at `path`. A file of the wrong size is refused.
    pub fn open(path: &Path) -> io::Result<Self> {
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(false)
            .open(path)?;
        let mut model = erased();
        let len = file.metadata()?.len();
        if len == 0 {
            file.write_all_at(&model.mem, 0)?;
        } else if len == model.mem.len() as u64 {
            file.read_exact_at(&mut model.mem, 0)?;
        } else {
            return Err(io::Error::new(
                io::ErrorKind::InvalidData,
                format!(
                    "{}: {len} bytes, but a calibration flash image is {} bytes ({CAL_SECTORS} sectors of {CAL_SECTOR_LEN})",
                    path.display(),
                    model.mem.len()
                ),
            ));
        }
        Ok(Self { model, file })
    }

    fn mirror(&self, from: usize, to: usize) -> Result<(), SimFlashError> {
        let bytes = self.model.mem.get(from..to).unwrap_or(&[]);
        self.file
            .write_all_at(bytes, from as u64)
            .and_then(|()| self.file.sync_data())
            .map_err(|e| SimFlashError::File(e.kind()))
    }
}

impl ErrorType for FileFlash {
    type Error = SimFlashError;
}

impl ReadNorFlash for FileFlash {
    const READ_SIZE: usize = 1;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), SimFlashError> {
        self.model.read(offset, bytes).map_err(SimFlashError::Model)
    }
    fn capacity(&self) -> usize {
        self.model.capacity()
    }
}

impl NorFlash for FileFlash {
    const WRITE_SIZE: usize = FLASH_WRITE_LEN;
    const ERASE_SIZE: usize = CAL_SECTOR_LEN;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), SimFlashError> {
        let r = self.model.erase(from, to).map_err(SimFlashError::Model);
        self.mirror(from as usize, to as usize)?;
        r
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), SimFlashError> {
        let r = self
            .model
            .write(offset, bytes)
            .map_err(SimFlashError::Model);
        self.mirror(offset as usize, offset as usize + bytes.len())?;
        r
    }
}
