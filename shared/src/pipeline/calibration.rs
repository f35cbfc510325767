//! The calibration in force: the table, where it came from, the checksum it is checked against, its thermal
//! compensation, and the upload of the next table (`CalBegin`, `CalChunk`, `CalCommit`).

use super::CAL_UPLOAD_MAX;
use crate::calib::CalibrationTable;
use crate::calib::thermal::ThermalComp;
use crate::crc::crc32c;
use crate::telemetry::{CalSource, Reject};
use crate::wire::frame::GROUPS;

/// The table's own CRC-32C, the last word of its encoding (`None` if it does not encode). Not the CRC of the whole
/// encoding: a CRC over data followed by their CRC is a constant (the CRC's residue) and would never change.
fn table_crc(table: &CalibrationTable<GROUPS>) -> Option<u32> {
    let mut buf = [0u8; CAL_UPLOAD_MAX];
    let bytes = table.encode(&mut buf).ok()?;
    bytes.last_chunk::<4>().map(|c| u32::from_le_bytes(*c))
}

/// What the calibration in force is checked against ([`Pipeline::calibration_intact`]).
#[derive(Clone, Copy, Debug)]
enum CalCheck {
    /// The factory table, in force since the pipeline was built (a `const` constructor cannot encode it to take
    /// its CRC): compared with the factory table's CRC, taken when asked.
    Factory,
    /// The CRC-32C taken when the table was loaded (`None`: it did not encode, and the check fails).
    Loaded(Option<u32>),
}

/// An upload in progress: how many bytes of an encoded table of announced length and CRC-32C have been received
/// (the bytes themselves go to [`super::PipelineMemory`], outside the pipeline).
#[derive(Clone, Copy, Debug)]
struct Upload {
    len: u16,
    crc: u32,
    received: u16,
    active: bool,
}

/// The calibration stage's state.
#[derive(Clone, Copy, Debug)]
pub(super) struct Calibration {
    /// The table in force.
    pub(super) table: CalibrationTable<GROUPS>,
    /// Where it came from.
    pub(super) source: CalSource,
    /// What it is checked against.
    check: CalCheck,
    /// The groups' maps with the biases of the frames' temperature.
    pub(super) thermal: ThermalComp<GROUPS>,
    upload: Upload,
}

impl Calibration {
    /// The factory table in force, no upload.
    pub(super) const NEW: Self = Self {
        table: CalibrationTable::factory(),
        source: CalSource::Factory,
        check: CalCheck::Factory,
        thermal: ThermalComp::new(),
        upload: Upload {
            len: 0,
            crc: 0,
            received: 0,
            active: false,
        },
    };

    /// `table` was replaced (from `source`): its checksum and thermal compensation.
    pub(super) fn changed(&mut self, source: CalSource) {
        self.check = CalCheck::Loaded(table_crc(&self.table));
        self.source = source;
        self.thermal.load(&self.table);
    }

    /// Whether the table in force is still the one loaded (its CRC-32C against the one taken then) and its
    /// compensated copy still the table's at the temperature in force.
    pub(super) fn intact(&self) -> bool {
        let expected = match self.check {
            CalCheck::Factory => table_crc(&CalibrationTable::factory()),
            CalCheck::Loaded(crc) => crc,
        };
        expected.is_some()
            && table_crc(&self.table) == expected
            && self.thermal.consistent_with(&self.table)
    }

    /// `CalBegin`: an upload of `len` bytes with CRC-32C `crc` starts (one in progress is dropped).
    pub(super) fn begin(&mut self, len: u16, crc: u32) -> Result<(), Reject> {
        if len == 0 || usize::from(len) > CAL_UPLOAD_MAX {
            return Err(Reject::BadArgument);
        }
        self.upload = Upload {
            len,
            crc,
            received: 0,
            active: true,
        };
        Ok(())
    }

    /// `CalChunk`: the bytes at `offset`, which must follow the last chunk, into `buf`.
    pub(super) fn chunk(
        &mut self,
        buf: &mut [u8; CAL_UPLOAD_MAX],
        offset: u16,
        data: &[u8],
    ) -> Result<(), Reject> {
        let u = &mut self.upload;
        if !u.active {
            return Err(Reject::CalNotStarted);
        }
        if offset != u.received {
            return Err(Reject::CalOffset(u.received));
        }
        let end = usize::from(offset)
            .checked_add(data.len())
            .filter(|&end| end <= usize::from(u.len))
            .ok_or(Reject::CalOverflow)?;
        buf.get_mut(usize::from(offset)..end)
            .ok_or(Reject::CalOverflow)?
            .copy_from_slice(data);
        u.received = end as u16;
        Ok(())
    }

    /// `CalCommit`: the upload in `buf` complete and its CRC right, the table decoded into the one in force, in place (no
    /// table-sized temporary on the bus task's stack); on any error the table in force stays. The caller then
    /// calls [`Self::changed`] through the pipeline (statistics, fusion mode).
    pub(super) fn commit(&mut self, buf: &[u8; CAL_UPLOAD_MAX]) -> Result<(), Reject> {
        let u = &self.upload;
        if !u.active {
            return Err(Reject::CalNotStarted);
        }
        let bytes = buf.get(..usize::from(u.len)).ok_or(Reject::CalIncomplete)?;
        if u.received != u.len || crc32c(bytes) != u.crc {
            return Err(Reject::CalIncomplete);
        }
        self.table.decode_into(bytes).map_err(Reject::Cal)?;
        self.upload.active = false;
        Ok(())
    }
}
