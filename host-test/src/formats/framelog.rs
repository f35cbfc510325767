//! FPGA frame logs: the link's byte stream as recorded (`docs/fpga-link.md`), decoded with the core's own
//! `FrameDecoder`, and turned into a physical [`Recording`] with a calibration (the core's fixed-point code).

use super::csv::{Column, Recording, SensorKind};
use rayon::prelude::*;
use shared::calib::{AXES, CalibrationTable, RawCounts};
use shared::wire::frame::{FRAME_LEN, GROUPS};
use shared::wire::{Decoded, Frame, FrameClock, FrameDecoder, FrameRepr, LinkCounters};

/// A decoded frame log.
#[derive(Clone, Debug)]
pub struct FrameLog {
    /// Frames in order, with the sequence gaps before them.
    pub frames: Vec<Decoded>,
    /// What the decoder counted.
    pub counters: LinkCounters,
}

/// Bytes per piece of a parallel decode: a log under twice this is decoded in one piece.
const PIECE_BYTES: usize = 8 << 20;

/// How far past a piece's nominal start a frame that passes its checks is looked for.
const CUT_SEARCH: usize = 4 * FRAME_LEN;

/// A piece of a log decoded on its own.
struct Piece {
    frames: Vec<Decoded>,
    counters: LinkCounters,
    /// The piece's last bytes were its last frame (nothing held or skipped after it).
    ends_on_frame: bool,
}

impl Piece {
    /// The log of a piece decoded alone.
    fn into_log(self) -> FrameLog {
        FrameLog {
            frames: self.frames,
            counters: self.counters,
        }
    }

    fn decode(bytes: &[u8]) -> Piece {
        let mut dec = FrameDecoder::new();
        let mut input = bytes;
        let mut frames = Vec::with_capacity(bytes.len() / FRAME_LEN);
        let mut ends_on_frame = false;
        while let Some(d) = dec.decode(&mut input) {
            frames.push(d);
            ends_on_frame = input.is_empty();
        }
        Piece {
            frames,
            counters: *dec.counters(),
            ends_on_frame,
        }
    }
}

/// Whether a frame that passes its checks (sync and CRC) starts at `at`.
fn frame_at(bytes: &[u8], at: usize) -> bool {
    bytes
        .get(at..)
        .and_then(<[u8]>::first_chunk::<FRAME_LEN>)
        .is_some_and(|f| Frame::new_checked(f.as_slice()).is_ok_and(|f| f.check().is_ok()))
}

impl FrameLog {
    /// Decodes a byte stream (any corruption is counted, never fatal). A long stream is decoded in pieces in
    /// parallel (`decode_in_pieces`), with the frames, gaps and counters of one pass.
    pub fn decode(bytes: &[u8]) -> FrameLog {
        Self::decode_in_pieces(bytes, PIECE_BYTES)
    }

    /// [`Self::decode`] by pieces of about `piece` bytes. Each piece starts at a frame that passes its checks and
    /// is decoded by a decoder of its own; where the piece before it ended exactly on a frame, the decoder of the
    /// whole stream would have been there holding nothing, with nothing skipped since that frame, so it goes on
    /// alike, but for the first frame's sequence gap, which a decoder fed the two frames gives. Where a piece did
    /// not end so (a damaged frame across the cut), the stream is decoded in one pass. Measured on an 8-h frame
    /// log (131 MB, 2 cores): the serial decode (its CRC checks) was ≈ 0.2 s of the load.
    fn decode_in_pieces(bytes: &[u8], piece: usize) -> FrameLog {
        let piece = piece.max(CUT_SEARCH);
        let mut cuts = vec![0];
        let mut at = piece;
        while at.saturating_add(piece) <= bytes.len() {
            if let Some(c) = (at..at + CUT_SEARCH).find(|&c| frame_at(bytes, c)) {
                cuts.push(c);
            }
            at += piece;
        }
        cuts.push(bytes.len());
        let ranges: Vec<(usize, usize)> = cuts.windows(2).map(|w| (w[0], w[1])).collect();
        let pieces: Vec<Piece> = ranges
            .par_iter()
            .map(|&(a, b)| Piece::decode(bytes.get(a..b).unwrap_or(&[])))
            .collect();
        let all_but_last = pieces.len().saturating_sub(1);
        if pieces
            .iter()
            .take(all_but_last)
            .any(|p| !p.ends_on_frame || p.frames.is_empty())
        {
            return Piece::decode(bytes).into_log();
        }
        let mut frames = Vec::with_capacity(pieces.iter().map(|p| p.frames.len()).sum());
        let mut c = LinkCounters::default();
        for (k, p) in pieces.into_iter().enumerate() {
            let mut pf = p.frames;
            // The first frame of a piece after the first: its gap after the previous piece's last frame, which
            // ends where it starts.
            if let (Some(&(start, _)), true) = (ranges.get(k), k > 0)
                && let Some(first) = pf.first_mut()
            {
                let mut dec = FrameDecoder::new();
                let mut two = bytes
                    .get(start.saturating_sub(FRAME_LEN)..start.saturating_add(FRAME_LEN))
                    .unwrap_or(&[]);
                let (Some(_), Some(d)) = (dec.decode(&mut two), dec.decode(&mut two)) else {
                    return Piece::decode(bytes).into_log();
                };
                first.gap = d.gap;
                let h = dec.counters();
                c.frames_dropped = c.frames_dropped.wrapping_add(h.frames_dropped);
                c.seq_restarts = c.seq_restarts.wrapping_add(h.seq_restarts);
            }
            let q = p.counters;
            c.frames = c.frames.wrapping_add(q.frames);
            c.crc_errors = c.crc_errors.wrapping_add(q.crc_errors);
            c.resyncs = c.resyncs.wrapping_add(q.resyncs);
            c.bytes_skipped = c.bytes_skipped.wrapping_add(q.bytes_skipped);
            c.frames_dropped = c.frames_dropped.wrapping_add(q.frames_dropped);
            c.seq_restarts = c.seq_restarts.wrapping_add(q.seq_restarts);
            c.overruns = c.overruns.wrapping_add(q.overruns);
            frames.append(&mut pf);
        }
        FrameLog {
            frames,
            counters: c,
        }
    }

    /// Encodes frames as a link byte stream.
    pub fn encode<'a>(frames: impl IntoIterator<Item = &'a FrameRepr>) -> Vec<u8> {
        frames.into_iter().flat_map(FrameRepr::to_bytes).collect()
    }

    /// The physical recording: every frame through `cal` (the core's fixed-point calibration), times from the
    /// sequence counter and decimation at `base_rate_millihz` (millihertz; see `FrameClock`). Columns in °/s and g.
    pub fn to_recording(
        &self,
        cal: &CalibrationTable<GROUPS>,
        base_rate_millihz: u64,
    ) -> Recording {
        let n = self.frames.len();
        let mut clock = FrameClock::new();
        let mut rec = Recording {
            t_s: Vec::with_capacity(n),
            temp_c: None,
            columns: Vec::new(),
        };
        let mut temps = Vec::with_capacity(n);
        let any_temp = self.frames.iter().any(|d| d.frame.temp_cdeg.is_some());
        for d in &self.frames {
            let tick = clock.advance(d);
            rec.t_s
                .push(tick.base_ticks as f64 * 1000.0 / base_rate_millihz.max(1) as f64);
            temps.push(d.frame.temp_cdeg.map_or(f64::NAN, |t| f64::from(t) / 100.0));
        }
        // Calibrated in pieces of frames in parallel, each piece into its part of every column (every sample on its
        // own: the same values as in order).
        const PIECE: usize = 4096;
        let mut data: Vec<[Vec<f64>; AXES]> = (0..GROUPS)
            .map(|_| std::array::from_fn(|_| vec![0.0; n]))
            .collect();
        let mut parts: Vec<Vec<&mut [f64]>> = (0..n.div_ceil(PIECE))
            .map(|_| Vec::with_capacity(GROUPS * AXES))
            .collect();
        for col in data.iter_mut().flatten() {
            for (part, piece) in parts.iter_mut().zip(col.chunks_mut(PIECE)) {
                part.push(piece);
            }
        }
        parts
            .into_par_iter()
            .zip(self.frames.par_chunks(PIECE))
            .for_each(|(mut part, frames)| {
                for (t, d) in frames.iter().enumerate() {
                    for (g, (codes, group_cal)) in d.frame.raw.iter().zip(&cal.groups).enumerate() {
                        let axes = group_cal.apply(&RawCounts::from_adc(codes));
                        let cols = part.iter_mut().skip(g * AXES);
                        for (v, col) in axes.iter().zip(cols) {
                            if let Some(x) = col.get_mut(t) {
                                *x = f64::from(*v) / 1e6; // µ°/s → °/s, µg → g (exactly rounded)
                            }
                        }
                    }
                }
            });
        for (group, cols) in data.into_iter().enumerate() {
            for (a, col) in cols.into_iter().enumerate().take(AXES) {
                let kind = if a < 3 {
                    SensorKind::Gyro
                } else {
                    SensorKind::Accel
                };
                rec.columns.push(Column {
                    group,
                    kind,
                    axis: a % 3,
                    data: col,
                });
            }
        }
        rec.columns.sort_by_key(|c| (c.kind, c.group, c.axis));
        if any_temp {
            rec.temp_c = Some(temps);
        }
        rec
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A stream of `n` frames (varied ADC codes), sequence counted from `seq0`, with a gap of 3 frames every 101st
    /// and a restart (a jump back) at the 500th.
    fn stream(n: usize, seq0: u16) -> Vec<u8> {
        let frames: Vec<FrameRepr> = (0..n)
            .map(|i| {
                let mut f = FrameRepr::EMPTY;
                let jump = (i / 101) * 3 + usize::from(i >= 500) * 40_000;
                f.seq = seq0.wrapping_add((i + jump) as u16);
                f.decimation = 511;
                for (g, group) in f.raw.iter_mut().enumerate() {
                    for (c, v) in group.iter_mut().enumerate() {
                        *v = ((i * 31 + g * 7 + c) % 4096) as _;
                    }
                }
                f
            })
            .collect();
        FrameLog::encode(&frames)
    }

    fn same(a: &FrameLog, b: &FrameLog) {
        assert_eq!(a.counters, b.counters);
        assert_eq!(a.frames, b.frames);
    }

    #[test]
    fn pieces_give_the_one_pass_decode_of_clean_and_damaged_streams() {
        let mut rng = crate::testrng::TestRng::new(41);
        let clean = stream(1500, 65_000);
        let mut cases = vec![clean.clone()];
        // Damage: flipped bits (CRC errors), dropped and inserted bytes (resyncs), a sync marker in the garbage,
        // and a cut through the middle of a frame at the end.
        for _ in 0..12 {
            let mut s = clean.clone();
            for _ in 0..1 + (rng.uniform() * 20.0) as usize {
                let at = (rng.uniform() * (s.len() - 1) as f64) as usize;
                match (rng.uniform() * 4.0) as usize {
                    0 => s[at] ^= 1 << ((rng.uniform() * 8.0) as u32),
                    1 => {
                        s.drain(at..(at + 1 + (rng.uniform() * 300.0) as usize).min(s.len()));
                    }
                    2 => {
                        let junk: Vec<u8> = (0..(rng.uniform() * 50.0) as usize)
                            .map(|_| (rng.uniform() * 256.0) as u8)
                            .collect();
                        s.splice(at..at, junk);
                    }
                    _ => {
                        s.splice(at..at, shared::wire::frame::SYNC);
                    }
                }
            }
            s.truncate(s.len() - (rng.uniform() * 200.0) as usize);
            cases.push(s);
        }
        let mut pieces_used = 0;
        for (k, s) in cases.iter().enumerate() {
            let one = Piece::decode(s).into_log();
            assert!(one.frames.len() > 1000, "case {k}");
            for piece in [CUT_SEARCH, 5000, 20_011, 100_000, PIECE_BYTES] {
                same(&FrameLog::decode_in_pieces(s, piece), &one);
            }
            // How many of the cuts held (a piece ending on a frame), or the test would only see the fallback.
            pieces_used += usize::from(
                (1..s.len() / 5000)
                    .filter_map(|i| (i * 5000..i * 5000 + CUT_SEARCH).find(|&c| frame_at(s, c)))
                    .any(|c| Piece::decode(&s[..c]).ends_on_frame),
            );
        }
        assert!(pieces_used >= 10, "{pieces_used}");
        assert_eq!(Piece::decode(&clean).into_log().counters.seq_restarts, 1);
        assert!(Piece::decode(&clean).into_log().counters.frames_dropped > 0);
        same(&FrameLog::decode(&[]), &Piece::decode(&[]).into_log());
    }
}
