//! The DFU side of the upload protocol: [`Receiver`] writes an upload into the DFU slot, one acknowledged step per
//! request (the rules: the module doc of [`crate::update`]).

use super::{
    BootControl, DfuState, Header, ImageError, MARKS_OFFSET, SECTORS_MAX, UpdateCounters,
    UpdateEnvelope, UpdateError, UpdateOutcome, UpdateReply, UpdateRequest, UpdateResponse,
    UpdateStatus, image,
};
use crate::crc::crc32c;
use embedded_storage::nor_flash::NorFlash;

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
