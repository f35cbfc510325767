//! A simulation collected in memory as a [`Recording`], as it streams.

use super::{Bandwidth, BandwidthFilter};
use crate::recording::{Column, Recording, SensorKind};
use crate::sim::{Axis, Chunk, GROUPS, SimConfig, SimError, Simulator};

/// Collects a simulation's chunks into an in-memory [`Recording`] (physical values,
/// °/s and g; `temp_c` when the simulation has a thermal effect), as it streams.
pub struct RecordingSink {
    rec: Recording,
}

impl RecordingSink {
    /// An empty recording with room for `samples` rows of the 16 groups × 6 axes.
    pub fn new(samples: usize, with_temp: bool) -> Self {
        let mut rec = Recording {
            t_s: Vec::with_capacity(samples),
            temp_c: with_temp.then(|| Vec::with_capacity(samples)),
            columns: Vec::new(),
        };
        for g in 0..GROUPS {
            for a in Axis::ALL {
                let kind = if a.is_gyro() {
                    SensorKind::Gyro
                } else {
                    SensorKind::Accel
                };
                rec.columns.push(Column {
                    group: g,
                    kind,
                    axis: a.index() % 3,
                    data: Vec::with_capacity(samples),
                });
            }
        }
        Self { rec }
    }

    /// Appends a chunk's rows.
    pub fn push(&mut self, chunk: &Chunk) {
        let rows = &chunk.phys[..chunk.len];
        self.rec.t_s.extend_from_slice(&chunk.t_s[..chunk.len]);
        if let Some(t) = &mut self.rec.temp_c {
            t.extend_from_slice(&chunk.temp_c[..chunk.len]);
        }
        for (k, col) in self.rec.columns.iter_mut().enumerate() {
            let (g, a) = (k / 6, k % 6);
            col.data.extend(rows.iter().map(|p| p[g][a]));
        }
    }

    /// The recording, columns ordered as the CSV reader orders them.
    pub fn finish(mut self) -> Recording {
        self.rec.columns.sort_by_key(|c| (c.kind, c.group, c.axis));
        self.rec
    }
}

/// Runs a simulation into an in-memory [`Recording`] (see [`RecordingSink`]).
pub fn recording(cfg: SimConfig) -> Result<Recording, SimError> {
    recording_filtered(cfg, &[])
}

/// [`recording`] with the outputs' bandwidths ([`BandwidthFilter`]).
pub fn recording_filtered(cfg: SimConfig, bands: &[Bandwidth]) -> Result<Recording, SimError> {
    let mut sink = RecordingSink::new(cfg.samples as usize, cfg.thermal.is_some());
    let mut filter = BandwidthFilter::new(bands, cfg.rate_hz);
    let mut sim = Simulator::new(cfg)?;
    let mut chunk = Chunk::default();
    while sim.next_chunk(&mut chunk) > 0 {
        filter.apply(&mut chunk);
        sink.push(&chunk);
    }
    Ok(sink.finish())
}
