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

use super::clock;
use crate::layout::{
    CAL_SECTOR_LEN, CAL_SECTORS, ERASE_IMAGE_SECTOR_US, ERASE_SECTOR_US, ERASE_STATE_SECTOR_US,
    FLASH_WRITE_LEN, IMAGE_SECTOR_LEN, PROGRAM_WORD_US, STATE_LEN,
};

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

/// Worst-case erase time of one F405 sector of `len` bytes at x32, µs ([`crate::layout`]: 16 KiB 0.5 s, 64 KiB
/// 1.1 s, 128 KiB 2 s; smaller blocks, as the tests' models have, as a 16 KiB sector).
pub const fn erase_max_us(len: usize) -> u32 {
    if len > STATE_SECTOR_LEN {
        ERASE_IMAGE_SECTOR_US[1]
    } else if len > CAL_SECTOR_LEN {
        ERASE_STATE_SECTOR_US[1]
    } else {
        ERASE_SECTOR_US[1]
    }
}

/// One DFU sector (sectors 7–9 of the F405: 128 KiB).
pub const DFU_SECTOR_LEN: usize = IMAGE_SECTOR_LEN as usize;
/// The boot state sector (sector 4: 64 KiB).
pub const STATE_SECTOR_LEN: usize = STATE_LEN as usize;
/// The DFU slot as a RAM model: three 128 KiB sectors.
pub type DfuModel = MockFlash<DFU_SECTOR_LEN>;
/// The boot state partition as a RAM model.
pub type StateModel = MockFlash<STATE_SECTOR_LEN>;
/// The update service on the models, stalling as the F405 does.
pub type SimUpdater = crate::update::Updater<Stalling<DfuModel>, Stalling<StateModel>>;
/// The update service on erased models (no bootloader report), images checked with `public_key`, the running image
/// at `running_version`.
pub fn updater(public_key: [u8; 32], running_version: u32) -> SimUpdater {
    updater_on(
        DfuModel::erased(3),
        StateModel::erased(1),
        public_key,
        running_version,
    )
}

/// The update service on the given models.
pub fn updater_on(
    dfu: DfuModel,
    state: StateModel,
    public_key: [u8; 32],
    running_version: u32,
) -> SimUpdater {
    crate::update::Updater::new(
        Stalling(dfu),
        Stalling(state),
        public_key,
        crate::layout::BOARD_ID,
        running_version,
        crate::layout::ACTIVE_LEN,
        None,
    )
}

/// A flash whose erases and programs stall the CPU for the F405's worst-case times ([`crate::layout`]), through
/// [`crate::sim::clock::stall`]: the host-run tasks then lose frames to a calibration store as the MCU does.
pub struct Stalling<F>(pub F);

impl<F: ErrorType> ErrorType for Stalling<F> {
    type Error = F::Error;
}

impl<F: ReadNorFlash> ReadNorFlash for Stalling<F> {
    const READ_SIZE: usize = F::READ_SIZE;
    fn read(&mut self, offset: u32, bytes: &mut [u8]) -> Result<(), F::Error> {
        self.0.read(offset, bytes)
    }
    fn capacity(&self) -> usize {
        self.0.capacity()
    }
}

impl<F: NorFlash> NorFlash for Stalling<F> {
    const WRITE_SIZE: usize = F::WRITE_SIZE;
    const ERASE_SIZE: usize = F::ERASE_SIZE;
    fn erase(&mut self, from: u32, to: u32) -> Result<(), F::Error> {
        let sectors = u64::from(to.saturating_sub(from)).div_ceil(F::ERASE_SIZE as u64);
        clock::stall(embassy_time::Duration::from_micros(
            sectors * u64::from(erase_max_us(F::ERASE_SIZE)),
        ));
        self.0.erase(from, to)
    }
    fn write(&mut self, offset: u32, bytes: &[u8]) -> Result<(), F::Error> {
        let words = bytes.len().div_ceil(4) as u64;
        clock::stall(embassy_time::Duration::from_micros(
            words * u64::from(PROGRAM_WORD_US[1]),
        ));
        self.0.write(offset, bytes)
    }
}
