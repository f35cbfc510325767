//! FPGA frame logs: the link's byte stream as recorded (`docs/fpga-link.md`), decoded with the core's own
//! `FrameDecoder`, and turned into a physical [`Recording`] with a calibration (the core's fixed-point code).

use super::csv::{Column, Recording, SensorKind};
use rayon::prelude::*;
use shared::calib::{AXES, CalibrationTable, RawCounts};
use shared::wire::frame::GROUPS;
use shared::wire::{Decoded, FrameClock, FrameDecoder, FrameRepr, LinkCounters};

/// A decoded frame log.
#[derive(Clone, Debug)]
pub struct FrameLog {
    /// Frames in order, with the sequence gaps before them.
    pub frames: Vec<Decoded>,
    /// What the decoder counted.
    pub counters: LinkCounters,
}

impl FrameLog {
    /// Decodes a byte stream (any corruption is counted, never fatal).
    pub fn decode(bytes: &[u8]) -> FrameLog {
        let mut dec = FrameDecoder::new();
        let mut input = bytes;
        let mut frames = Vec::with_capacity(bytes.len() / shared::wire::frame::FRAME_LEN);
        while let Some(d) = dec.decode(&mut input) {
            frames.push(d);
        }
        FrameLog {
            frames,
            counters: *dec.counters(),
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
