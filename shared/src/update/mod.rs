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

pub use boot_report::{BootAction, BootReport};
pub use image::{Header, ImageError};

use crate::crc::crc32c;
use embedded_storage::nor_flash::NorFlash;
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

/// What the receiver is told about the satellite for each request.
#[derive(Clone, Copy, Debug)]
pub struct Context<'a> {
    /// The key images are signed with.
    pub public_key: &'a [u8; 32],
    /// This board.
    pub board_id: u32,
    /// The running image's version.
    pub running_version: u32,
    /// Largest image, header included (the ACTIVE slot).
    pub max_image_len: u32,
    /// Whether flash writes are allowed now, or why not ([`UpdateError::NotIdle`]: frames are being processed;
    /// [`UpdateError::LowVoltage`]: VDD below what programming needs).
    pub writable: Result<(), UpdateError>,
}

#[derive(Clone, Copy, Debug)]
struct Session {
    header: Header,
    sectors: u8,
    erased: u8,
    next_offset: u32,
    verified: bool,
    committed: bool,
}

/// The DFU side of the upload protocol.
#[derive(Clone, Debug, Default)]
pub struct Receiver {
    session: Option<Session>,
    counters: UpdateCounters,
    last: UpdateOutcome,
    dfu_version: u32,
    reset: bool,
}

impl Receiver {
    /// A receiver with no session; `last` is what the boot report said (see [`UpdateOutcome`]).
    pub const fn new(last: UpdateOutcome) -> Self {
        Self {
            session: None,
            counters: UpdateCounters::ZERO,
            last,
            dfu_version: 0,
            reset: false,
        }
    }

    /// The last outcome.
    pub fn last(&self) -> UpdateOutcome {
        self.last
    }

    /// Whether a `Reset` was acknowledged since the last call (the caller resets once the reply has left).
    pub fn take_reset(&mut self) -> bool {
        core::mem::take(&mut self.reset)
    }

    /// Notes an outcome decided outside the protocol (the image confirmed itself).
    pub fn set_last(&mut self, last: UpdateOutcome) {
        self.last = last;
    }

    /// The service's state.
    pub fn status<F: NorFlash>(
        &mut self,
        dfu: &mut F,
        ctx: &Context<'_>,
        boot: &mut impl BootControl,
    ) -> UpdateStatus {
        let dfu_version = image::read_header(dfu).map_or(0, |h| h.version);
        self.dfu_version = dfu_version;
        let (state, received, payload_len) = match &self.session {
            None => (DfuState::Idle, 0, 0),
            Some(s) => (
                if s.committed {
                    DfuState::Committed
                } else if s.verified {
                    DfuState::Verified
                } else if s.erased < s.sectors {
                    DfuState::Erasing
                } else if s.next_offset < s.header.payload_len {
                    DfuState::Receiving
                } else {
                    DfuState::Complete
                },
                s.next_offset,
                s.header.payload_len,
            ),
        };
        UpdateStatus {
            running_version: ctx.running_version,
            dfu_version,
            dfu: state,
            received,
            payload_len,
            boot: boot.state(),
            last: self.last,
            counters: self.counters,
        }
    }

    /// Decodes one request (a CSP payload), handles it, and encodes the response into `out`; returns its length.
    /// A payload that does not decode gets `Refused(Decode)` with tag 0.
    pub fn handle_bytes<F: NorFlash>(
        &mut self,
        request: &[u8],
        dfu: &mut F,
        ctx: &Context<'_>,
        boot: &mut impl BootControl,
        out: &mut [u8],
    ) -> Result<usize, postcard::Error> {
        let response = match postcard::from_bytes::<UpdateEnvelope>(request) {
            Ok(env) => UpdateResponse {
                tag: env.tag,
                reply: self.handle(&env.request, dfu, ctx, boot),
            },
            Err(_) => {
                self.counters.requests = self.counters.requests.wrapping_add(1);
                self.counters.refused = self.counters.refused.wrapping_add(1);
                UpdateResponse {
                    tag: 0,
                    reply: UpdateReply::Refused(UpdateError::Decode),
                }
            }
        };
        postcard::to_slice(&response, out).map(|b| b.len())
    }

    /// Handles one request.
    pub fn handle<F: NorFlash>(
        &mut self,
        request: &UpdateRequest,
        dfu: &mut F,
        ctx: &Context<'_>,
        boot: &mut impl BootControl,
    ) -> UpdateReply {
        self.counters.requests = self.counters.requests.wrapping_add(1);
        match self.dispatch(request, dfu, ctx, boot) {
            Ok(r) => r,
            Err(e) => {
                self.counters.refused = self.counters.refused.wrapping_add(1);
                match e {
                    UpdateError::Crc => {
                        self.counters.crc_errors = self.counters.crc_errors.wrapping_add(1)
                    }
                    UpdateError::OutOfOrder { .. } => {
                        self.counters.out_of_order = self.counters.out_of_order.wrapping_add(1)
                    }
                    _ => {}
                }
                UpdateReply::Refused(e)
            }
        }
    }

    fn dispatch<F: NorFlash>(
        &mut self,
        request: &UpdateRequest,
        dfu: &mut F,
        ctx: &Context<'_>,
        boot: &mut impl BootControl,
    ) -> Result<UpdateReply, UpdateError> {
        match request {
            UpdateRequest::Status => Ok(UpdateReply::Status(self.status(dfu, ctx, boot))),
            UpdateRequest::Open { header, restart } => self.open(header, *restart, dfu, ctx),
            UpdateRequest::Erase { sector } => self.erase(*sector, dfu, ctx),
            UpdateRequest::Chunk {
                offset,
                crc32c: crc,
                data,
            } => self.chunk(*offset, *crc, data, dfu, ctx),
            UpdateRequest::Verify => {
                self.verify(dfu, ctx)?;
                Ok(UpdateReply::Verified)
            }
            UpdateRequest::Commit => {
                ctx.writable?;
                let version = self.verify(dfu, ctx)?;
                boot.mark_updated().map_err(|_| UpdateError::Flash)?;
                if let Some(s) = self.session.as_mut() {
                    s.committed = true;
                }
                self.last = UpdateOutcome::Committed(version);
                Ok(UpdateReply::Committed)
            }
            UpdateRequest::Confirm => {
                // Rewrites the state partition: a 64 KiB erase on the F405.
                ctx.writable?;
                boot.mark_booted().map_err(|_| UpdateError::Flash)?;
                self.last = UpdateOutcome::Confirmed(ctx.running_version);
                Ok(UpdateReply::Confirmed)
            }
            UpdateRequest::Abort => {
                if self.session.is_some_and(|s| s.committed) {
                    // A swap committed since boot (this image is not a trial): cancel it.
                    boot.mark_booted().map_err(|_| UpdateError::Flash)?;
                    self.last = UpdateOutcome::None;
                }
                self.session = None;
                Ok(UpdateReply::Aborted)
            }
            UpdateRequest::Reset => {
                self.reset = true;
                Ok(UpdateReply::Resetting)
            }
        }
    }

    fn open<F: NorFlash>(
        &mut self,
        bytes: &[u8; image::OPEN_LEN],
        restart: bool,
        dfu: &mut F,
        ctx: &Context<'_>,
    ) -> Result<UpdateReply, UpdateError> {
        let header = Header::parse(bytes).map_err(UpdateError::Image)?;
        let max = ctx
            .max_image_len
            .min(u32::try_from(dfu.capacity()).unwrap_or(u32::MAX));
        header
            .check(ctx.public_key, ctx.board_id, ctx.running_version, max)
            .map_err(UpdateError::Image)?;
        let total = (header.payload_len as usize).saturating_add(image::HEADER_LEN);
        let sectors = total.div_ceil(F::ERASE_SIZE);
        let sectors = u8::try_from(sectors)
            .ok()
            .filter(|&s| usize::from(s) <= SECTORS_MAX)
            .ok_or(UpdateError::Image(ImageError::TooLarge))?;
        let mut held = [0u8; image::OPEN_LEN];
        dfu.read(0, &mut held).map_err(|_| UpdateError::Flash)?;
        let (erased, next_offset) = if !restart && held == *bytes {
            let erased = erased_marks(dfu, sectors)?;
            let next = if erased == sectors {
                received_len(dfu, header.payload_len)?
            } else {
                0
            };
            (erased, next)
        } else {
            (0, 0)
        };
        self.session = Some(Session {
            header,
            sectors,
            erased,
            next_offset,
            verified: false,
            committed: false,
        });
        Ok(UpdateReply::Opened {
            sectors,
            erased,
            next_offset,
        })
    }

    fn erase<F: NorFlash>(
        &mut self,
        sector: u8,
        dfu: &mut F,
        ctx: &Context<'_>,
    ) -> Result<UpdateReply, UpdateError> {
        let s = self.session.as_mut().ok_or(UpdateError::NotOpen)?;
        if sector < s.erased {
            self.counters.duplicates = self.counters.duplicates.wrapping_add(1);
            return Ok(UpdateReply::Erased { sector });
        }
        if sector != s.erased || sector >= s.sectors {
            return Err(UpdateError::SectorOrder { expected: s.erased });
        }
        ctx.writable?;
        let size = F::ERASE_SIZE as u32;
        let from = u32::from(sector)
            .checked_mul(size)
            .ok_or(UpdateError::Flash)?;
        let to = from.checked_add(size).ok_or(UpdateError::Flash)?;
        s.verified = false;
        self.counters.erases = self.counters.erases.wrapping_add(1);
        dfu.erase(from, to).map_err(|_| UpdateError::Flash)?;
        if sector == 0 {
            dfu.write(0, &s.header.emit())
                .map_err(|_| UpdateError::Flash)?;
        }
        dfu.write(mark_at(sector), &[0; 4])
            .map_err(|_| UpdateError::Flash)?;
        s.erased = s.erased.saturating_add(1);
        Ok(UpdateReply::Erased { sector })
    }

    fn chunk<F: NorFlash>(
        &mut self,
        offset: u32,
        crc: u32,
        data: &[u8],
        dfu: &mut F,
        ctx: &Context<'_>,
    ) -> Result<UpdateReply, UpdateError> {
        let s = self.session.as_mut().ok_or(UpdateError::NotOpen)?;
        if s.erased < s.sectors {
            return Err(UpdateError::NotErased);
        }
        if crc32c(data) != crc {
            return Err(UpdateError::Crc);
        }
        let len = u32::try_from(data.len()).map_err(|_| UpdateError::Range)?;
        let end = offset.checked_add(len).ok_or(UpdateError::Range)?;
        if !offset.is_multiple_of(4)
            || !len.is_multiple_of(4)
            || len == 0
            || end > s.header.payload_len.next_multiple_of(4)
        {
            return Err(UpdateError::Range);
        }
        if offset > s.next_offset {
            return Err(UpdateError::OutOfOrder {
                expected: s.next_offset,
            });
        }
        let at = offset
            .checked_add(image::HEADER_LEN as u32)
            .ok_or(UpdateError::Range)?;
        if offset < s.next_offset {
            // Already received (a duplicate, or a resend after a lost ack): the part below `next_offset` must be
            // what the slot holds; the rest, if any, is new.
            let old = s.next_offset.saturating_sub(offset).min(len) as usize;
            let (seen, new) = data.split_at(old);
            if !slot_holds(dfu, at, seen)? {
                return Err(UpdateError::Mismatch);
            }
            if new.is_empty() {
                self.counters.duplicates = self.counters.duplicates.wrapping_add(1);
                return Ok(UpdateReply::Ack {
                    next_offset: s.next_offset,
                });
            }
            return Self::write_new(s, new, dfu, ctx);
        }
        Self::write_new(s, data, dfu, ctx)
    }

    /// Writes `data` at the session's next offset and checks it read back.
    fn write_new<F: NorFlash>(
        s: &mut Session,
        data: &[u8],
        dfu: &mut F,
        ctx: &Context<'_>,
    ) -> Result<UpdateReply, UpdateError> {
        ctx.writable?;
        let at = s
            .next_offset
            .checked_add(image::HEADER_LEN as u32)
            .ok_or(UpdateError::Range)?;
        s.verified = false;
        dfu.write(at, data).map_err(|_| UpdateError::Flash)?;
        if !slot_holds(dfu, at, data)? {
            return Err(UpdateError::Flash);
        }
        s.next_offset = s.next_offset.saturating_add(data.len() as u32);
        Ok(UpdateReply::Ack {
            next_offset: s.next_offset,
        })
    }

    /// Checks the session's image in the slot; returns its version.
    fn verify<F: NorFlash>(&mut self, dfu: &mut F, ctx: &Context<'_>) -> Result<u32, UpdateError> {
        let s = self.session.as_mut().ok_or(UpdateError::NotOpen)?;
        if s.erased < s.sectors || s.next_offset < s.header.payload_len {
            return Err(UpdateError::Incomplete {
                next_offset: s.next_offset,
            });
        }
        let max = ctx
            .max_image_len
            .min(u32::try_from(dfu.capacity()).unwrap_or(u32::MAX));
        let checked =
            image::verify_slot(dfu, ctx.public_key, ctx.board_id, ctx.running_version, max);
        match checked {
            Ok(h) if h == s.header => {
                s.verified = true;
                Ok(h.version)
            }
            Ok(_) => {
                self.last = UpdateOutcome::Refused(ImageError::Hash);
                Err(UpdateError::Image(ImageError::Hash))
            }
            Err(e) => {
                self.last = UpdateOutcome::Refused(e);
                Err(UpdateError::Image(e))
            }
        }
    }
}

/// Where sector `sector`'s erase mark sits in the slot.
fn mark_at(sector: u8) -> u32 {
    (MARKS_OFFSET as u32).saturating_add(u32::from(sector).saturating_mul(4))
}

/// Whether the slot holds `bytes` at `at`.
fn slot_holds<F: NorFlash>(dfu: &mut F, at: u32, bytes: &[u8]) -> Result<bool, UpdateError> {
    let mut buf = [0u8; 64];
    let mut pos = at;
    for want in bytes.chunks(buf.len()) {
        let got = buf.get_mut(..want.len()).ok_or(UpdateError::Flash)?;
        dfu.read(pos, got).map_err(|_| UpdateError::Flash)?;
        if got != want {
            return Ok(false);
        }
        pos = pos.saturating_add(want.len() as u32);
    }
    Ok(true)
}

/// How many sectors carry their erase mark, counting from the first.
fn erased_marks<F: NorFlash>(dfu: &mut F, sectors: u8) -> Result<u8, UpdateError> {
    let mut n = 0u8;
    while n < sectors {
        let mut w = [0xFFu8; 4];
        dfu.read(mark_at(n), &mut w)
            .map_err(|_| UpdateError::Flash)?;
        if w != [0; 4] {
            break;
        }
        n = n.saturating_add(1);
    }
    Ok(n)
}

/// Payload bytes in the slot: up to the end of the last word that is not erased (a resumed upload writes from
/// there; a word cut by a reset while it was programmed is caught by the hash at verify).
fn received_len<F: NorFlash>(dfu: &mut F, payload_len: u32) -> Result<u32, UpdateError> {
    let mut buf = [0u8; 256];
    let mut end = payload_len.next_multiple_of(4);
    while end > 0 {
        let start = end.saturating_sub(buf.len() as u32);
        let got = buf
            .get_mut(..end.saturating_sub(start) as usize)
            .ok_or(UpdateError::Flash)?;
        dfu.read(start.saturating_add(image::HEADER_LEN as u32), got)
            .map_err(|_| UpdateError::Flash)?;
        if let Some(i) = got.iter().rposition(|&b| b != 0xFF) {
            return Ok((start.saturating_add(i as u32).saturating_add(1))
                .next_multiple_of(4)
                .min(payload_len.next_multiple_of(4)));
        }
        end = start;
    }
    Ok(0)
}

#[cfg(test)]
mod tests;
