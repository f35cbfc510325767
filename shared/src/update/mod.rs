//! In-orbit software update, sans-IO (`docs/update.md`): the signed image ([`image`]), the upload protocol's
//! messages on their own CSP port, the [`Receiver`] that writes an upload into the DFU slot, the bootloader's
//! decision ([`boot::prepare`]: verify, swap or revert, on embassy-boot) and the [`boot_report`] it leaves for the
//! application.
//!
//! The receiver works on any `NorFlash` DFU slot and a [`BootControl`] (embassy-boot's state partition on the
//! satellite, a model in the tests). It follows the calibration store's rules: one sector erase per acknowledged
//! command, nothing written unless the mode is `Idle`, every refusal typed and counted, and the slot itself is the
//! session's memory, so that an upload resumes after a lost link or a reset.

pub mod boot;
pub mod boot_report;
pub mod image;
mod receiver;

pub use boot_report::{BootAction, BootReport};
pub use image::{Header, ImageError};
pub use receiver::{Context, Receiver};

use heapless::Vec;
use serde::{Deserialize, Serialize};

/// This board's identity in image headers: the IMU cluster's STM32F405 board, revision 1 (`"IMU"` and the chip).
/// An image signed for another board is refused ([`ImageError::Board`]).
pub const BOARD_ID: u32 = 0x4F05_1601;

/// The update service's CSP port on the satellite (replies go back to the request's source port).
pub const PORT_UPDATE: u8 = 12;
/// Largest chunk of payload in one request, bytes (a multiple of 4; the envelope fits `bus::MAX_PAYLOAD`).
pub const CHUNK_MAX: usize = 192;
/// Where the erase marks start in the DFU slot's header: one word per sector, programmed to zero once the sector
/// has been erased for the header in front of them.
pub const MARKS_OFFSET: usize = image::OPEN_LEN;
/// Sectors an image may span (the marks' room in the header).
pub const SECTORS_MAX: usize = (image::HEADER_LEN - MARKS_OFFSET) / 4;

/// A request with the tag its reply echoes.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct UpdateEnvelope {
    /// Chosen by the ground.
    pub tag: u16,
    /// The request.
    pub request: UpdateRequest,
}

/// What the ground asks (`docs/update.md`, "Upload protocol").
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum UpdateRequest {
    /// Report [`UpdateStatus`].
    Status,
    /// Start (or resume) an upload of the image with this header (its first [`image::OPEN_LEN`] bytes).
    Open {
        /// Signed header bytes and signature.
        #[serde(with = "crate::serde_array")]
        header: [u8; image::OPEN_LEN],
        /// Start over even if the slot already holds part of this image.
        restart: bool,
    },
    /// Erase DFU sector `sector` (the next one to erase; the first also gets the header).
    Erase {
        /// Sector index within the slot.
        sector: u8,
    },
    /// Payload bytes at `offset` (from the payload's start, a multiple of 4).
    Chunk {
        /// Offset in the payload, bytes.
        offset: u32,
        /// CRC-32C of `data`.
        crc32c: u32,
        /// The bytes (a multiple of 4 long; the last chunk padded with `0xFF`).
        data: Vec<u8, CHUNK_MAX>,
    },
    /// Check the received image (hash and signature).
    Verify,
    /// Check it again and have the bootloader swap it in at the next reset.
    Commit,
    /// Mark the running image good (no revert at the next reset).
    Confirm,
    /// Forget the session; cancel a swap committed since boot.
    Abort,
    /// Reset the MCU once the reply has left (appended): a committed image is swapped in, a trial image that has
    /// not confirmed itself is reverted. Send it once: a resend after a lost reply would reset the new image too.
    Reset,
}

/// A reply with its request's tag.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct UpdateResponse {
    /// The request's tag.
    pub tag: u16,
    /// The reply.
    pub reply: UpdateReply,
}

/// The satellite's answer.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum UpdateReply {
    /// The service's state.
    Status(UpdateStatus),
    /// The upload is open: `sectors` to erase in all, `erased` of them done, the payload received up to
    /// `next_offset`.
    Opened {
        /// Sectors the image spans.
        sectors: u8,
        /// Sectors already erased for it.
        erased: u8,
        /// Payload bytes already in the slot.
        next_offset: u32,
    },
    /// Sector `sector` is erased.
    Erased {
        /// Its index.
        sector: u8,
    },
    /// The payload is in the slot up to `next_offset`.
    Ack {
        /// Payload bytes received.
        next_offset: u32,
    },
    /// The image in the slot verified.
    Verified,
    /// The swap happens at the next reset.
    Committed,
    /// The running image is marked good.
    Confirmed,
    /// The session is forgotten.
    Aborted,
    /// The MCU resets once this reply has left.
    Resetting,
    /// Refused; nothing changed.
    Refused(UpdateError),
}

/// Why a request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateError {
    /// The request did not decode.
    Decode,
    /// The image (or its header) is refused.
    Image(ImageError),
    /// No upload is open.
    NotOpen,
    /// Flash writes need `Mode::Idle`.
    NotIdle,
    /// VDD is below what flash programming needs (the calibration store's threshold).
    LowVoltage,
    /// Sectors are erased in order: this is the next one.
    SectorOrder {
        /// The sector expected.
        expected: u8,
    },
    /// Not all the image's sectors are erased yet.
    NotErased,
    /// A chunk's CRC-32C does not match its bytes.
    Crc,
    /// A chunk's offset or length is not a multiple of 4, or runs past the payload.
    Range,
    /// A chunk beyond the next expected offset (one was lost): send from `expected`.
    OutOfOrder {
        /// Payload bytes received.
        expected: u32,
    },
    /// A chunk below the next expected offset whose bytes differ from the slot's.
    Mismatch,
    /// The payload is not all there yet.
    Incomplete {
        /// Payload bytes received.
        next_offset: u32,
    },
    /// Not verified since the last chunk.
    NotVerified,
    /// A flash or boot-state operation failed.
    Flash,
}

/// The boot state the bootloader keeps (embassy-boot's state partition).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum BootState {
    /// Nothing pending.
    #[default]
    Boot,
    /// A swap is pending (committed since boot) or this is a trial boot that has not confirmed itself.
    Swap,
    /// The bootloader reverted a trial image at this boot.
    Revert,
    /// Not known (no bootloader, or the state could not be read).
    Unknown,
}

/// A boot-state operation failed (the flash under the state partition).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BootStateError;

/// The boot state partition, as the receiver needs it.
pub trait BootControl {
    /// The state.
    fn state(&mut self) -> BootState;
    /// Have the bootloader swap the DFU image in at the next reset.
    fn mark_updated(&mut self) -> Result<(), BootStateError>;
    /// Mark the running image good (and cancel a pending swap).
    fn mark_booted(&mut self) -> Result<(), BootStateError>;
}

/// The boot state in RAM, for tests of the receiver and of ground tools (feature `mock-flash`, as
/// [`crate::storage::mock::MockFlash`]): `mark_updated` and `mark_booted` set the state, and never fail.
#[cfg(any(test, feature = "mock-flash"))]
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct MockBoot {
    /// The state.
    pub state: BootState,
}

#[cfg(any(test, feature = "mock-flash"))]
impl BootControl for MockBoot {
    fn state(&mut self) -> BootState {
        self.state
    }
    fn mark_updated(&mut self) -> Result<(), BootStateError> {
        self.state = BootState::Swap;
        Ok(())
    }
    fn mark_booted(&mut self) -> Result<(), BootStateError> {
        self.state = BootState::Boot;
        Ok(())
    }
}

/// What the DFU slot holds, as far as the receiver knows.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DfuState {
    /// No upload open.
    #[default]
    Idle,
    /// Sectors being erased.
    Erasing,
    /// Payload arriving.
    Receiving,
    /// All there, not verified yet.
    Complete,
    /// Verified.
    Verified,
    /// Committed: swapped in at the next reset.
    Committed,
}

/// The last update's outcome (reported in housekeeping until the next one).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum UpdateOutcome {
    /// None since boot and none reported by the bootloader.
    #[default]
    None,
    /// Version `0` committed; swapped in at the next reset.
    Committed(u32),
    /// The bootloader swapped version `0` in at this boot (a trial until confirmed).
    Swapped(u32),
    /// The running image confirmed itself (or the ground confirmed it).
    Confirmed(u32),
    /// The bootloader reverted: the trial image never confirmed.
    Reverted(u32),
    /// The bootloader refused the committed image.
    BootRefused(ImageError),
    /// The last upload was refused at verify or commit.
    Refused(ImageError),
}

/// The update service's counters.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateCounters {
    /// Requests handled.
    pub requests: u32,
    /// Requests refused (any reason).
    pub refused: u32,
    /// Chunks with a bad CRC.
    pub crc_errors: u32,
    /// Chunks out of order (a loss upstream).
    pub out_of_order: u32,
    /// Duplicate chunks acknowledged again.
    pub duplicates: u32,
    /// Sector erases.
    pub erases: u32,
}

impl UpdateCounters {
    /// All zero (`Default`, usable in `const`).
    pub const ZERO: Self = Self {
        requests: 0,
        refused: 0,
        crc_errors: 0,
        out_of_order: 0,
        duplicates: 0,
        erases: 0,
    };
}

/// The service's state, in [`UpdateReply::Status`] and in housekeeping.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UpdateStatus {
    /// The running image's version (its header in ACTIVE; 0 without one).
    pub running_version: u32,
    /// The version of the image in DFU (its header; 0 without one).
    pub dfu_version: u32,
    /// The upload's state.
    pub dfu: DfuState,
    /// Payload bytes received of `payload_len`.
    pub received: u32,
    /// The open image's payload length (0 if none).
    pub payload_len: u32,
    /// The bootloader's state.
    pub boot: BootState,
    /// The last outcome.
    pub last: UpdateOutcome,
    /// Counters.
    pub counters: UpdateCounters,
}

impl UpdateStatus {
    /// Nothing known yet (usable in `const`): what housekeeping reports before the storage task has read the slots.
    pub const UNKNOWN: Self = Self {
        running_version: 0,
        dfu_version: 0,
        dfu: DfuState::Idle,
        received: 0,
        payload_len: 0,
        boot: BootState::Unknown,
        last: UpdateOutcome::None,
        counters: UpdateCounters::ZERO,
    };
}

#[cfg(test)]
mod tests;
