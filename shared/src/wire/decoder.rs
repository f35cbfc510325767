//! Streaming decoder of the FPGA link: bytes in chunks of any size in, frames out.
//!
//! The decoder holds at most one frame's worth of bytes. It locks onto the sync marker, checks the CRC, and after
//! corruption resynchronises on the next sync marker *inside the bytes it already holds*, so that a damaged frame
//! costs only itself: the frame that follows it is found even when the damaged frame was shortened (dropped bytes),
//! lengthened (inserted bytes) or its sync marker was hit.

use super::frame::{FRAME_LEN, Frame, FrameRepr, SYNC, WireError};

/// Link statistics. All counters wrap modulo 2³² (compare deltas, as with network interface counters).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkCounters {
    /// Frames accepted (sync and CRC valid).
    pub frames: u32,
    /// Candidates that started with the sync marker but failed the CRC.
    pub crc_errors: u32,
    /// Times the decoder locked onto a frame after having skipped bytes.
    pub resyncs: u32,
    /// Bytes discarded while searching for a sync marker.
    pub bytes_skipped: u32,
    /// Frames missing according to the sequence counter (sum of the gaps).
    pub frames_dropped: u32,
    /// Sequence jumps backwards (FPGA reset or duplicate); not counted as drops.
    pub seq_restarts: u32,
    /// Receive overruns of the transport (the UART driver's, and rings dropped after a stall): the platform's count,
    /// which it sets in the health report it sends; the decoder leaves it 0.
    pub overruns: u32,
}

/// A frame out of the decoder, with what the sequence counter says about the frames before it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Decoded {
    /// The frame.
    pub frame: FrameRepr,
    /// The sequence gap before it.
    pub gap: SeqGap,
}

/// What the sequence counter says about the frames before an accepted frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SeqGap {
    /// Frames missing between the previous accepted frame and this one (0 when contiguous, or for the first frame
    /// and after a restart).
    pub missing_before: u32,
    /// The sequence counter jumped back by less than 2¹⁵ (counted in `seq_restarts`): the FPGA restarted, or a gap of
    /// 2¹⁵ frames or more hid the count.
    pub restarted: bool,
}

/// Streaming frame decoder (see the module documentation).
#[derive(Clone, Debug)]
pub struct FrameDecoder {
    buf: [u8; FRAME_LEN],
    /// Bytes held in `buf`; `buf[..len]` always starts with the sync marker or a prefix of it.
    len: usize,
    last_seq: Option<u16>,
    skipped_since_lock: bool,
    counters: LinkCounters,
}

impl Default for FrameDecoder {
    fn default() -> Self {
        Self::new()
    }
}

/// Index of the first position where `bytes` holds the sync marker, or a prefix of it that runs to the end;
/// `bytes.len()` if there is none.
fn sync_candidate(bytes: &[u8]) -> usize {
    let mut from = 0;
    while let Some(offset) = bytes
        .get(from..)
        .and_then(|s| s.iter().position(|&b| b == SYNC[0]))
    {
        // Positions within `bytes` (< isize::MAX): the sums cannot wrap.
        let at = from.wrapping_add(offset);
        let rest = bytes.get(at..).unwrap_or(&[]);
        let n = rest.len().min(SYNC.len());
        if rest.get(..n) == SYNC.get(..n) {
            return at;
        }
        from = at.wrapping_add(1);
    }
    bytes.len()
}

impl FrameDecoder {
    /// A decoder waiting for its first sync marker.
    pub const fn new() -> Self {
        Self {
            buf: [0; FRAME_LEN],
            len: 0,
            last_seq: None,
            skipped_since_lock: false,
            counters: LinkCounters {
                frames: 0,
                crc_errors: 0,
                resyncs: 0,
                bytes_skipped: 0,
                frames_dropped: 0,
                seq_restarts: 0,
                overruns: 0,
            },
        }
    }

    /// The link statistics so far.
    pub fn counters(&self) -> &LinkCounters {
        &self.counters
    }

    /// Forgets the partial frame only: the transport dropped the bytes it had buffered (a DMA ring lapped during a
    /// CPU stall; the platform counts the overrun). The sequence history stays, so the next frame's gap counts the frames
    /// lost.
    pub fn discard_partial(&mut self) {
        self.len = 0;
    }

    /// Forgets the partial frame and the sequence history (counters are kept), e.g. after a link restart.
    pub fn reset(&mut self) {
        self.len = 0;
        self.last_seq = None;
    }

    /// Consumes bytes from the front of `input` until a frame is complete (returned) or `input` is used up (`None`).
    /// Call it again with the rest of `input` until it returns `None`; bytes are never consumed without being
    /// either buffered, counted as skipped, or returned as part of a frame.
    pub fn decode(&mut self, input: &mut &[u8]) -> Option<Decoded> {
        let mut frame = FrameRepr::EMPTY;
        let gap = self.decode_with(input, |f| frame.fill_from(f))?;
        Some(Decoded { frame, gap })
    }

    /// [`Self::decode`], lending the frame instead of returning it: `lend` gets the checked view of its bytes,
    /// where they lie (the caller's `input`, or the decoder's buffer for a frame split across calls), and reads what
    /// it needs; the result is the sequence gap, `None` (and `lend` not called) when `input` ran out first. The
    /// pipeline's path: nothing is copied (a parse into `FrameRepr` is a 224-byte `memcpy` between differently
    /// aligned buffers, every frame).
    pub fn decode_with(
        &mut self,
        input: &mut &[u8],
        lend: impl FnOnce(&Frame<&[u8]>),
    ) -> Option<SeqGap> {
        loop {
            if self.len == 0 {
                let skip = sync_candidate(input);
                if skip > 0 {
                    self.skip(skip);
                    *input = input.get(skip..).unwrap_or(&[]);
                }
                if input.is_empty() {
                    return None;
                }
                if let Some(candidate) = input.first_chunk::<FRAME_LEN>() {
                    // Fast path: a whole frame in the caller's buffer, no copy.
                    let frame = Frame::new_checked(candidate.as_slice());
                    match frame.and_then(|f| f.check().map(|()| f)) {
                        Ok(frame) => {
                            lend(&frame);
                            *input = input.get(FRAME_LEN..).unwrap_or(&[]);
                            return Some(self.accept(frame.seq()));
                        }
                        Err(e) => {
                            self.reject(e);
                            self.skip(1);
                            *input = input.get(1..).unwrap_or(&[]);
                            continue;
                        }
                    }
                }
                // A partial frame: keep it.
                let n = input.len();
                self.buf.get_mut(..n)?.copy_from_slice(input);
                self.len = n;
                *input = &[];
                return None;
            }

            let free = self.buf.get_mut(self.len..)?;
            let take = free.len().min(input.len());
            let (head, rest) = input.split_at(take);
            let (dst, _) = free.split_at_mut(take);
            dst.copy_from_slice(head);
            // len + take ≤ FRAME_LEN: cannot wrap.
            self.len = self.len.wrapping_add(take);
            *input = rest;
            if self.len < FRAME_LEN {
                // Drop an early mismatch of the marker at once rather than after a whole frame's worth of bytes.
                if self.buf.get(..self.len.min(SYNC.len())) == SYNC.get(..self.len.min(SYNC.len()))
                {
                    return None;
                }
            } else {
                let frame = Frame::new_checked(self.buf.as_slice());
                match frame.and_then(|f| f.check().map(|()| f)) {
                    Ok(frame) => {
                        lend(&frame);
                        let seq = frame.seq();
                        self.len = 0;
                        return Some(self.accept(seq));
                    }
                    Err(e) => self.reject(e),
                }
            }
            // Resynchronise inside the held bytes: keep everything from the next candidate on.
            // 1 ≤ next ≤ len ≤ FRAME_LEN (the candidate lies inside `buf[1..len]`): neither the sum nor the
            // difference wraps, and the copy's range is valid.
            let next = sync_candidate(self.buf.get(1..self.len).unwrap_or(&[])).wrapping_add(1);
            self.skip(next);
            self.buf.copy_within(next..self.len, 0);
            self.len = self.len.wrapping_sub(next);
        }
    }

    fn skip(&mut self, n: usize) {
        self.counters.bytes_skipped = self.counters.bytes_skipped.wrapping_add(n as u32);
        self.skipped_since_lock = true;
    }

    fn reject(&mut self, e: WireError) {
        if e == WireError::BadCrc {
            self.counters.crc_errors = self.counters.crc_errors.wrapping_add(1);
        }
    }

    /// Counts an accepted frame with sequence number `seq`; returns what the counter says about the frames before.
    fn accept(&mut self, seq: u16) -> SeqGap {
        let c = &mut self.counters;
        c.frames = c.frames.wrapping_add(1);
        if self.skipped_since_lock {
            c.resyncs = c.resyncs.wrapping_add(1);
            self.skipped_since_lock = false;
        }
        let mut gap = SeqGap::default();
        if let Some(last) = self.last_seq {
            let n = seq.wrapping_sub(last.wrapping_add(1));
            if n < 0x8000 {
                gap.missing_before = u32::from(n);
                c.frames_dropped = c.frames_dropped.wrapping_add(gap.missing_before);
            } else {
                c.seq_restarts = c.seq_restarts.wrapping_add(1);
                gap.restarted = true;
            }
        }
        self.last_seq = Some(seq);
        gap
    }
}

#[cfg(test)]
mod tests;
