//! The upload client, sans-IO: a signed image in, the requests to send out ([`Uploader::next_request`]), the
//! satellite's replies in ([`Uploader::on_reply`]), deadlines checked by the caller's clock
//! ([`Uploader::on_tick`]). The protocol is `docs/update.md`'s "Upload protocol":
//!
//! 1. `Status` (what the satellite runs), then `Open`: the reply says how many sectors are erased already and where
//!    the payload stops, so an interrupted upload resumes there;
//! 2. `Erase` each remaining sector, one at a time, each waiting for its reply (an erase stalls the satellite's CPU
//!    for up to 2 s; nothing is sent while one is outstanding);
//! 3. the payload in chunks of at most [`CHUNK_MAX`] bytes, go-back-N with a window of `W` chunks: a
//!    `Refused(OutOfOrder { expected })` (a chunk was lost) or a refused CRC sends again from there, a timeout sends
//!    again from the last acknowledged offset;
//! 4. `Verify`, then `Commit` (unless told not to).
//!
//! Each request carries a new tag; replies whose tag is not that of a request still awaited are ignored (late
//! replies to requests already given up, duplicates).

use super::SignedImage;
use shared::crc::crc32c;
use shared::update::{
    CHUNK_MAX, ImageError, UpdateEnvelope, UpdateError, UpdateReply, UpdateRequest, UpdateResponse,
    UpdateStatus,
};
use std::collections::VecDeque;
use std::time::{Duration, Instant};

/// The upload's parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UploadConfig {
    /// Chunks in flight (go-back-N window), ≥ 1. The satellite's bus ring bounds it
    /// ([`max_window`](super::link::max_window)): `ground fw-upload` refuses more.
    pub window: usize,
    /// Payload bytes per chunk: a multiple of 4, at most [`CHUNK_MAX`].
    pub chunk_len: usize,
    /// Commit after `Verify` (the swap happens at the satellite's next reset).
    pub commit: bool,
    /// After the commit, ask the satellite to reset (`Reset`, sent once: a resend after a lost reply would reset
    /// the new image before it confirmed itself, and the bootloader would revert it).
    pub reset: bool,
    /// Start over (`Open { restart: true }`) instead of resuming what the DFU slot holds.
    pub restart: bool,
    /// How long to wait for the reply to `Status`, `Open` or a chunk.
    pub timeout: Duration,
    /// How long to wait for the reply to `Erase` (up to 2 s of erase), `Verify` and `Commit` (a hash over the slot;
    /// the boot state's flash).
    pub long_timeout: Duration,
    /// Timeouts in a row (no reply at all) before giving up.
    pub max_timeouts: u32,
}

impl Default for UploadConfig {
    fn default() -> Self {
        Self {
            window: 4,
            chunk_len: CHUNK_MAX,
            commit: true,
            reset: false,
            restart: false,
            timeout: Duration::from_secs(1),
            long_timeout: Duration::from_secs(5),
            max_timeouts: 20,
        }
    }
}

/// Times the upload may re-open its session (the satellite reset and forgot it) or start over (the slot held bytes
/// that are not this image's).
const MAX_REOPENS: u32 = 5;

/// Why an upload stopped.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum UploadError {
    /// The configuration is not usable.
    #[error("bad upload settings: {0}")]
    Config(String),
    /// The satellite refused a request for a reason a resend does not cure.
    #[error("the satellite refused {request}: {}", describe(*.error))]
    Refused {
        /// The request's name.
        request: &'static str,
        /// The satellite's reason.
        error: UpdateError,
    },
    /// No reply to `max_timeouts` requests in a row.
    #[error(
        "no reply from the satellite to {0} requests in a row (is the link up, the address right?)"
    )]
    Timeout(u32),
    /// The session had to be re-opened or restarted too often.
    #[error("the upload was re-opened {0} times (the satellite keeps losing the session)")]
    Reopens(u32),
    /// A reply that contradicts the image (a satellite or protocol fault).
    #[error("unexpected reply to {request}: {reply}")]
    Unexpected {
        /// The request's name.
        request: &'static str,
        /// The reply, as debug text.
        reply: String,
    },
}

/// A refusal in words.
pub fn describe(e: UpdateError) -> String {
    match e {
        UpdateError::Decode => "the request did not decode".into(),
        UpdateError::Image(i) => format!("image refused: {}", describe_image(i)),
        UpdateError::NotOpen => "no upload is open".into(),
        UpdateError::NotIdle => {
            "the satellite is not idle (flash writes need Mode::Idle: stop the measurement)".into()
        }
        UpdateError::SectorOrder { expected } => format!("sectors go in order: {expected} is next"),
        UpdateError::NotErased => "not all sectors are erased".into(),
        UpdateError::Crc => "the chunk's CRC-32C does not match".into(),
        UpdateError::Range => "offset or length not a multiple of 4, or past the payload".into(),
        UpdateError::OutOfOrder { expected } => format!("out of order: {expected} expected"),
        UpdateError::Mismatch => "the slot holds other bytes at that offset".into(),
        UpdateError::Incomplete { next_offset } => {
            format!("the payload is there only up to {next_offset}")
        }
        UpdateError::NotVerified => "not verified".into(),
        UpdateError::Flash => "a flash or boot-state operation failed".into(),
        UpdateError::LowVoltage => {
            "VDD is below what flash programming needs (the calibration store's threshold)".into()
        }
    }
}

/// An image refusal in words.
pub fn describe_image(e: ImageError) -> &'static str {
    match e {
        ImageError::Magic => "not an image header",
        ImageError::Format => "a header format or length the satellite does not read",
        ImageError::Board => "built for another board",
        ImageError::Rollback => "its version is not above the running one",
        ImageError::TooLarge => "larger than the slot",
        ImageError::Signature => "the signature does not verify with the satellite's public key",
        ImageError::Hash => "the payload's SHA-512 differs from the header's",
        ImageError::Flash => "the slot could not be read",
    }
}

/// What happened, for progress displays and logs.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum UploadEvent {
    /// The satellite's update service state, before the upload.
    Status(UpdateStatus),
    /// The session is open: `erased` of `sectors` erased already, the payload there up to `next_offset`.
    Opened {
        /// Sectors the image spans.
        sectors: u8,
        /// Sectors already erased.
        erased: u8,
        /// Payload bytes already in the slot.
        next_offset: u32,
    },
    /// Sector `sector` of `sectors` is erased.
    Erased {
        /// Its index.
        sector: u8,
        /// Sectors in all.
        sectors: u8,
    },
    /// The payload is acknowledged up to `acked` of `total` bytes (padded to 4).
    Progress {
        /// Bytes acknowledged.
        acked: u32,
        /// Bytes in all.
        total: u32,
    },
    /// Sending again from `to` (a lost or corrupted chunk, a timeout).
    Rewind {
        /// Offset sent again from.
        to: u32,
        /// Why.
        cause: RewindCause,
    },
    /// No reply in time to a request other than a chunk; it is sent again.
    Timeout {
        /// The request's name.
        request: &'static str,
    },
    /// The session is opened again (`restart`: from scratch) after a refusal.
    Reopen {
        /// Start over.
        restart: bool,
        /// The refusal that caused it.
        cause: UpdateError,
    },
    /// The image in the DFU slot verified.
    Verified,
    /// The satellite swaps the image in at its next reset.
    Committed,
    /// The satellite acknowledged `Reset` (`true`), or its reply did not come (`false`: it may have reset anyway;
    /// `Reset` is never sent twice).
    Reset(bool),
}

/// Why chunks are sent again.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RewindCause {
    /// A chunk arrived out of order (one before it was lost).
    Lost,
    /// A chunk failed its CRC-32C on board.
    Corrupted,
    /// No reply in time.
    Timeout,
}

/// The upload's figures.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct UploadSummary {
    /// Payload length, bytes (padded to 4).
    pub payload_len: u32,
    /// Where the upload started (what the DFU slot already held, from the first `Open`).
    pub resumed_from: u32,
    /// Requests sent.
    pub requests: u64,
    /// Chunks sent.
    pub chunks_sent: u64,
    /// Chunks sent again (an offset below one sent before).
    pub chunks_resent: u64,
    /// Chunk bytes sent (padding included).
    pub chunk_bytes: u64,
    /// Sector erases requested (resends included).
    pub erases: u64,
    /// Deadlines missed.
    pub timeouts: u64,
    /// Go-back-N rewinds.
    pub rewinds: u64,
    /// Replies ignored (old or unknown tag).
    pub ignored: u64,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Phase {
    Status,
    Open,
    Erase(u8),
    Chunks,
    Verify,
    Commit,
    Reset,
    Done,
}

impl Phase {
    fn name(self) -> &'static str {
        match self {
            Phase::Status => "Status",
            Phase::Open => "Open",
            Phase::Erase(_) => "Erase",
            Phase::Chunks => "Chunk",
            Phase::Verify => "Verify",
            Phase::Commit => "Commit",
            Phase::Reset => "Reset",
            Phase::Done => "nothing",
        }
    }
}

/// A request awaiting its reply.
#[derive(Clone, Copy, Debug)]
struct Pending {
    tag: u16,
    deadline: Instant,
    /// The chunk's offset and length (chunks only).
    offset: u32,
    len: u32,
}

/// The upload client (see the module's documentation).
#[derive(Clone, Debug)]
pub struct Uploader {
    config: UploadConfig,
    open: [u8; shared::update::image::OPEN_LEN],
    /// The payload padded with `0xFF` to a multiple of 4.
    payload: Vec<u8>,
    phase: Phase,
    restart: bool,
    sectors: u8,
    /// Payload acknowledged.
    acked: u32,
    /// Next chunk offset to send.
    next: u32,
    /// End of the highest chunk ever sent (resends are below it).
    high_water: u32,
    /// Awaited requests: at most one outside the chunk phase, at most `window` chunks in it (oldest first).
    pending: VecDeque<Pending>,
    tag: u16,
    timeouts_in_a_row: u32,
    reopens: u32,
    opened_once: bool,
    events: VecDeque<UploadEvent>,
    summary: UploadSummary,
}

impl Uploader {
    /// An upload of `image` with `config`.
    pub fn new(image: &SignedImage, config: UploadConfig) -> Result<Self, UploadError> {
        if config.window == 0 {
            return Err(UploadError::Config("the window is at least 1 chunk".into()));
        }
        if config.chunk_len == 0
            || config.chunk_len > CHUNK_MAX
            || !config.chunk_len.is_multiple_of(4)
        {
            return Err(UploadError::Config(format!(
                "a chunk is a multiple of 4 bytes, 4 to {CHUNK_MAX}: {}",
                config.chunk_len
            )));
        }
        if config.max_timeouts == 0 {
            return Err(UploadError::Config(
                "at least one timeout must be allowed".into(),
            ));
        }
        let mut payload = image.payload.clone();
        payload.resize(payload.len().next_multiple_of(4), 0xFF);
        let total = u32::try_from(payload.len())
            .map_err(|_| UploadError::Config("the payload exceeds 4 GiB".into()))?;
        Ok(Self {
            config,
            open: image.open_bytes(),
            payload,
            phase: Phase::Status,
            restart: config.restart,
            sectors: 0,
            acked: 0,
            next: 0,
            high_water: 0,
            pending: VecDeque::new(),
            tag: 0,
            timeouts_in_a_row: 0,
            reopens: 0,
            opened_once: false,
            events: VecDeque::new(),
            summary: UploadSummary {
                payload_len: total,
                ..UploadSummary::default()
            },
        })
    }

    /// Payload bytes to send in all (padded to 4).
    pub fn total(&self) -> u32 {
        self.summary.payload_len
    }

    /// Payload bytes acknowledged.
    pub fn acked(&self) -> u32 {
        self.acked
    }

    /// The figures so far.
    pub fn summary(&self) -> UploadSummary {
        self.summary
    }

    /// Whether the upload is over (verified, and committed if asked).
    pub fn is_done(&self) -> bool {
        self.phase == Phase::Done
    }

    /// The next event, if any.
    pub fn poll_event(&mut self) -> Option<UploadEvent> {
        self.events.pop_front()
    }

    /// The earliest deadline of an awaited reply ([`Self::on_tick`] after it), `None` when nothing is awaited.
    pub fn deadline(&self) -> Option<Instant> {
        self.pending.iter().map(|p| p.deadline).min()
    }

    fn next_tag(&mut self) -> u16 {
        self.tag = self.tag.wrapping_add(1);
        if self.tag == 0 {
            // Tag 0 is what the satellite answers a request that did not decode.
            self.tag = 1;
        }
        self.tag
    }

    /// The next request to send at `now`, if the protocol allows one now (call until `None`, then wait for a reply
    /// or the [`deadline`](Self::deadline)).
    pub fn next_request(&mut self, now: Instant) -> Option<UpdateEnvelope> {
        let request = match self.phase {
            Phase::Done => return None,
            Phase::Chunks => {
                if self.pending.is_empty() && self.next >= self.total() {
                    // Everything sent, nothing awaited, not all acknowledged (cannot happen with a receiver that
                    // acknowledges each chunk it writes): send again from what is acknowledged.
                    self.next = self.acked;
                }
                if self.pending.len() >= self.config.window || self.next >= self.total() {
                    return None;
                }
                let offset = self.next;
                let end = (offset as usize + self.config.chunk_len).min(self.payload.len());
                let bytes = &self.payload[offset as usize..end];
                let len = bytes.len() as u32;
                let data = heapless::Vec::from_slice(bytes).ok()?;
                let tag = self.next_tag();
                self.pending.push_back(Pending {
                    tag,
                    deadline: now + self.config.timeout,
                    offset,
                    len,
                });
                self.next = offset + len;
                self.summary.chunks_sent += 1;
                self.summary.chunk_bytes += u64::from(len);
                if offset < self.high_water {
                    self.summary.chunks_resent += 1;
                }
                self.high_water = self.high_water.max(offset + len);
                self.summary.requests += 1;
                return Some(UpdateEnvelope {
                    tag,
                    request: UpdateRequest::Chunk {
                        offset,
                        crc32c: crc32c(&data),
                        data,
                    },
                });
            }
            _ if !self.pending.is_empty() => return None,
            Phase::Status => UpdateRequest::Status,
            Phase::Open => UpdateRequest::Open {
                header: self.open,
                restart: self.restart,
            },
            Phase::Erase(sector) => {
                self.summary.erases += 1;
                UpdateRequest::Erase { sector }
            }
            Phase::Verify => UpdateRequest::Verify,
            Phase::Commit => UpdateRequest::Commit,
            Phase::Reset => UpdateRequest::Reset,
        };
        let timeout = match self.phase {
            Phase::Erase(_) | Phase::Verify | Phase::Commit => self.config.long_timeout,
            _ => self.config.timeout,
        };
        let tag = self.next_tag();
        self.pending.push_back(Pending {
            tag,
            deadline: now + timeout,
            offset: 0,
            len: 0,
        });
        self.summary.requests += 1;
        Some(UpdateEnvelope { tag, request })
    }

    /// Checks the deadlines at `now`: a missed one sends again (chunks: from the last acknowledged offset). An error
    /// after [`UploadConfig::max_timeouts`] in a row.
    pub fn on_tick(&mut self, now: Instant) -> Result<(), UploadError> {
        let Some(first) = self.pending.front() else {
            return Ok(());
        };
        if first.deadline > now {
            return Ok(());
        }
        self.summary.timeouts += 1;
        self.timeouts_in_a_row += 1;
        if self.timeouts_in_a_row >= self.config.max_timeouts {
            return Err(UploadError::Timeout(self.timeouts_in_a_row));
        }
        if self.phase == Phase::Chunks {
            self.rewind(self.acked, RewindCause::Timeout);
        } else if self.phase == Phase::Reset {
            // Never twice (see `UploadConfig::reset`).
            self.pending.clear();
            self.events.push_back(UploadEvent::Reset(false));
            self.phase = Phase::Done;
        } else {
            self.pending.clear();
            self.events.push_back(UploadEvent::Timeout {
                request: self.phase.name(),
            });
        }
        Ok(())
    }

    fn rewind(&mut self, to: u32, cause: RewindCause) {
        self.pending.clear();
        self.next = to;
        self.summary.rewinds += 1;
        self.events.push_back(UploadEvent::Rewind { to, cause });
    }

    fn progress(&mut self, acked: u32) {
        if acked > self.acked {
            self.acked = acked;
            self.events.push_back(UploadEvent::Progress {
                acked,
                total: self.total(),
            });
        }
        if self.next < self.acked {
            self.next = self.acked;
        }
        if self.phase == Phase::Chunks && self.acked >= self.total() {
            self.pending.clear();
            self.phase = Phase::Verify;
        }
    }

    /// Opens the session again (`restart`: from scratch), after `cause`.
    fn reopen(&mut self, restart: bool, cause: UpdateError) -> Result<(), UploadError> {
        self.reopens += 1;
        if self.reopens > MAX_REOPENS {
            return Err(UploadError::Reopens(self.reopens - 1));
        }
        self.restart = restart;
        self.pending.clear();
        self.phase = Phase::Open;
        self.events
            .push_back(UploadEvent::Reopen { restart, cause });
        Ok(())
    }

    /// A refusal outside the chunks' go-back-N.
    fn refused(&mut self, request: &'static str, error: UpdateError) -> Result<(), UploadError> {
        match error {
            // The satellite reset and forgot the session (or its erase marks): open it again; the slot says where
            // to go on.
            UpdateError::NotOpen | UpdateError::NotErased => self.reopen(false, error),
            // The slot holds bytes that are not this image's (a word cut by a power failure): start over.
            UpdateError::Mismatch | UpdateError::Image(ImageError::Hash) => {
                self.reopen(true, error)
            }
            UpdateError::Incomplete { next_offset } if next_offset < self.total() => {
                self.phase = Phase::Chunks;
                self.acked = next_offset;
                self.next = next_offset;
                Ok(())
            }
            _ => Err(UploadError::Refused { request, error }),
        }
    }

    fn unexpected(request: &'static str, reply: &UpdateReply) -> UploadError {
        UploadError::Unexpected {
            request,
            reply: format!("{reply:?}"),
        }
    }

    /// Takes a reply (any: replies not awaited are ignored). An error when the upload cannot go on.
    pub fn on_reply(&mut self, response: &UpdateResponse) -> Result<(), UploadError> {
        let Some(i) = self.pending.iter().position(|p| p.tag == response.tag) else {
            self.summary.ignored += 1;
            return Ok(());
        };
        let Some(awaited) = self.pending.remove(i) else {
            return Ok(());
        };
        self.timeouts_in_a_row = 0;
        let request = self.phase.name();
        let reply = &response.reply;
        match (self.phase, reply) {
            (Phase::Chunks, UpdateReply::Ack { next_offset }) => {
                if *next_offset > self.total() || !next_offset.is_multiple_of(4) {
                    return Err(Self::unexpected(request, reply));
                }
                // The replies to the chunks below the acknowledged offset are no longer needed.
                let acked = (*next_offset).max(self.acked);
                self.pending.retain(|p| p.offset + p.len > acked);
                self.progress(*next_offset);
            }
            (Phase::Chunks, UpdateReply::Refused(UpdateError::OutOfOrder { expected })) => {
                if *expected > self.total() {
                    return Err(Self::unexpected(request, reply));
                }
                // The satellite holds everything below `expected`; every chunk in flight after the lost one is
                // refused too, and their replies are ignored (not awaited any more after the rewind).
                self.progress(*expected);
                if self.phase == Phase::Chunks {
                    let to = self.acked;
                    self.rewind(to, RewindCause::Lost);
                }
            }
            (Phase::Chunks, UpdateReply::Refused(UpdateError::Crc)) => {
                let to = awaited.offset.max(self.acked);
                self.rewind(to, RewindCause::Corrupted);
            }
            (Phase::Chunks, UpdateReply::Refused(e)) => self.refused(request, *e)?,
            (Phase::Status, UpdateReply::Status(st)) => {
                self.events.push_back(UploadEvent::Status(*st));
                self.phase = Phase::Open;
            }
            (
                Phase::Open,
                UpdateReply::Opened {
                    sectors,
                    erased,
                    next_offset,
                },
            ) => {
                if erased > sectors || *next_offset > self.total() || !next_offset.is_multiple_of(4)
                {
                    return Err(Self::unexpected(request, reply));
                }
                self.events.push_back(UploadEvent::Opened {
                    sectors: *sectors,
                    erased: *erased,
                    next_offset: *next_offset,
                });
                if !self.opened_once {
                    self.opened_once = true;
                    self.summary.resumed_from = *next_offset;
                }
                self.restart = false;
                self.sectors = *sectors;
                self.acked = 0;
                self.next = 0;
                self.phase = if erased < sectors {
                    Phase::Erase(*erased)
                } else {
                    Phase::Chunks
                };
                self.progress(*next_offset);
            }
            (Phase::Erase(s), UpdateReply::Erased { sector }) if *sector == s => {
                self.events.push_back(UploadEvent::Erased {
                    sector: s,
                    sectors: self.sectors,
                });
                self.phase = if s + 1 < self.sectors {
                    Phase::Erase(s + 1)
                } else {
                    Phase::Chunks
                };
                self.progress(self.acked);
            }
            (Phase::Erase(_), UpdateReply::Refused(UpdateError::SectorOrder { expected }))
                if *expected < self.sectors =>
            {
                self.phase = Phase::Erase(*expected);
            }
            (Phase::Verify, UpdateReply::Verified) => {
                self.events.push_back(UploadEvent::Verified);
                self.phase = if self.config.commit {
                    Phase::Commit
                } else {
                    Phase::Done
                };
            }
            (Phase::Commit, UpdateReply::Committed) => {
                self.events.push_back(UploadEvent::Committed);
                self.phase = if self.config.reset {
                    Phase::Reset
                } else {
                    Phase::Done
                };
            }
            (Phase::Reset, UpdateReply::Resetting) => {
                self.events.push_back(UploadEvent::Reset(true));
                self.phase = Phase::Done;
            }
            (_, UpdateReply::Refused(e)) => self.refused(request, *e)?,
            _ => return Err(Self::unexpected(request, reply)),
        }
        Ok(())
    }
}
