//! Frame time and spacecraft time: the epoch `SetTime` sets, PPS edges that re-anchor it on the whole second, and
//! the reports of both.

use super::{Pipeline, PipelineMemory};
use crate::telemetry::{PpsReport, TimeReport};
use core::borrow::BorrowMut;

/// A PPS edge is accepted only within this distance of a whole second of the current spacecraft time: it absorbs
/// the `SetTime` latency (the first edge) and the frame clock's drift over a second, and refuses glitches.
pub const PPS_TOLERANCE_US: u64 = 100_000;

/// The time correlation's state.
#[derive(Clone, Copy, Debug)]
pub(super) struct TimeSync {
    /// Frame time of the last frame, µs.
    last_t_us: Option<u64>,
    /// Spacecraft time minus frame time, µs (wrapping), once `SetTime` was received.
    epoch_us: Option<u64>,
    /// Smallest arrival time minus frame time, µs, since the last accepted PPS edge: the frame clock in the arrival
    /// clock's scale, read at the frames that waited least (a read's last frame).
    arrival_lead_us: Option<i64>,
    /// Arrival time of the last accepted PPS edge.
    pps_last_us: Option<u64>,
    pps: PpsReport,
}

impl TimeSync {
    pub(super) const NEW: Self = Self {
        last_t_us: None,
        epoch_us: None,
        arrival_lead_us: None,
        pps_last_us: None,
        pps: PpsReport {
            accepted: 0,
            rejected: 0,
            last_correction_us: 0,
        },
    };

    /// A frame at frame time `t_us`, read at `arrival_us` on the platform's clock (if the platform gives it).
    pub(super) fn frame(&mut self, t_us: u64, arrival_us: Option<u64>) {
        self.last_t_us = Some(t_us);
        if let Some(arrival) = arrival_us {
            // Both < 2⁶³ µs in practice; wrapping keeps the difference exact modulo 2⁶⁴ either way.
            let lead = arrival.wrapping_sub(t_us) as i64;
            self.arrival_lead_us = Some(self.arrival_lead_us.map_or(lead, |m| m.min(lead)));
        }
    }

    /// `SetTime`: "now" is the last frame's time: the command is handled between reads, within one read of the
    /// newest frame (≈ 7 ms), plus the bus's latency; PPS edges ([`Self::pps`]) then refine it.
    pub(super) fn set_time(&mut self, unix_us: u64) {
        self.epoch_us = Some(unix_us.wrapping_sub(self.last_t_us.unwrap_or(0)));
    }

    /// Spacecraft time minus frame time, µs (wrapping), once set.
    pub(super) fn epoch_us(&self) -> Option<u64> {
        self.epoch_us
    }

    /// A PPS edge at `edge_us` on the arrival clock: the spacecraft's whole second. The frame time at the edge is
    /// `edge_us` minus the smallest arrival lead of the frames since the last accepted edge (frames are stamped
    /// when read, never before they exist, so the least-delayed one is the best measure of the clocks' offset); if
    /// the spacecraft time there is within [`PPS_TOLERANCE_US`] of a whole second, the time is re-anchored on that
    /// second. Returns the correction, µs; `None` if the edge was refused (counted).
    pub(super) fn pps(&mut self, edge_us: u64) -> Option<i64> {
        match self.pps_correction(edge_us) {
            Some((epoch, correction)) => {
                self.epoch_us = Some(epoch);
                self.arrival_lead_us = None;
                self.pps_last_us = Some(edge_us);
                self.pps.accepted = self.pps.accepted.wrapping_add(1);
                self.pps.last_correction_us = crate::calib::saturate_i32(correction);
                Some(correction)
            }
            None => {
                self.pps.rejected = self.pps.rejected.wrapping_add(1);
                None
            }
        }
    }

    /// The new epoch and the correction for an edge at `edge_us`, if it is accepted (see [`Self::pps`]).
    fn pps_correction(&self, edge_us: u64) -> Option<(u64, i64)> {
        const SECOND_US: u64 = 1_000_000;
        let (epoch, lead) = (self.epoch_us?, self.arrival_lead_us?);
        if self
            .pps_last_us
            .is_some_and(|last| edge_us.wrapping_sub(last) < SECOND_US / 2)
        {
            return None;
        }
        // Wrapping: every quantity is a time in µs modulo 2⁶⁴ (the epoch is a difference of two such times).
        let frame_us = edge_us.wrapping_sub(lead as u64);
        let spacecraft_us = frame_us.wrapping_add(epoch);
        // The nearest whole second (spacecraft_us < 2⁶³ for any date: no wrap).
        let rounded = spacecraft_us.saturating_add(SECOND_US / 2);
        let second = rounded.wrapping_sub(rounded % SECOND_US);
        // `second` is within a second of `spacecraft_us`: the wrapped difference read as i64 is the signed correction.
        let correction = second.wrapping_sub(spacecraft_us) as i64;
        if correction.unsigned_abs() > PPS_TOLERANCE_US {
            return None;
        }
        Some((second.wrapping_sub(frame_us), correction))
    }

    /// The PPS discipline's counters.
    pub(super) fn pps_report(&self) -> PpsReport {
        self.pps
    }

    /// The counters, once an edge was seen.
    pub(super) fn pps_seen(&self) -> Option<PpsReport> {
        (self.pps.accepted > 0 || self.pps.rejected > 0).then_some(self.pps)
    }

    /// The last frame's time on both scales, once the time was set.
    pub(super) fn report(&self) -> Option<TimeReport> {
        let (t_us, epoch) = (self.last_t_us.unwrap_or(0), self.epoch_us?);
        Some(TimeReport {
            t_us,
            unix_us: t_us.wrapping_add(epoch),
        })
    }
}

impl<B: BorrowMut<PipelineMemory>> Pipeline<B> {
    /// A PPS edge at `edge_us` on the arrival clock ([`Self::set_arrival_us`]'s): the spacecraft's whole second
    /// (see `TimeSync::pps`). Returns the correction, µs; `None` if the edge was refused (counted).
    pub fn pps(&mut self, edge_us: u64) -> Option<i64> {
        self.time.pps(edge_us)
    }

    /// The PPS discipline's counters.
    pub fn pps_report(&self) -> PpsReport {
        self.time.pps_report()
    }

    /// The correlation of frame time and spacecraft time, once `SetTime` was received.
    pub fn time_report(&self) -> Option<TimeReport> {
        self.time.report()
    }
}
