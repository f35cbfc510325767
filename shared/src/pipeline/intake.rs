//! Link bytes to frames, and frames to time: the decoder, the frame clock (sequence gaps, rate changes, outages
//! bridged by arrival time) and the one conversion of frame-clock ticks to µs.

use super::PipelineConfig;
use crate::wire::clock::TicksToUs;
use crate::wire::{FrameClock, FrameDecoder, SeqGap};
use core::num::{NonZeroU64, NonZeroU128};

/// The time of one frame.
#[derive(Clone, Copy, Debug)]
pub(super) struct FrameTime {
    /// Frames lost before it.
    pub(super) missing: u32,
    /// Its time in FPGA base periods since the first frame.
    pub(super) base_ticks: u64,
    /// Its time in µs since the first frame.
    pub(super) t_us: u64,
    /// The decimation changed with it (a new sample rate).
    pub(super) rate_changed: bool,
}

/// The intake's state.
#[derive(Clone, Debug)]
pub(super) struct Intake {
    /// FPGA link bytes to checked frames.
    pub(super) decoder: FrameDecoder,
    clock: FrameClock,
    /// The frame clock's ticks in µs, kept incrementally.
    ticks_us: TicksToUs,
    arrival_us: Option<u64>,
    last_arrival_us: Option<u64>,
    time_gaps: u32,
}

impl Intake {
    pub(super) const NEW: Self = Self {
        decoder: FrameDecoder::new(),
        clock: FrameClock::new(),
        ticks_us: TicksToUs::new(),
        arrival_us: None,
        last_arrival_us: None,
        time_gaps: 0,
    };

    /// The platform's time at which the next bytes were read (see `Pipeline::set_arrival_us`).
    pub(super) fn set_arrival_us(&mut self, us: u64) {
        self.arrival_us = Some(us);
    }

    /// The arrival time of the bytes in work.
    pub(super) fn arrival_us(&self) -> Option<u64> {
        self.arrival_us
    }

    /// Outages bridged by arrival time.
    pub(super) fn time_gaps(&self) -> u32 {
        self.time_gaps
    }

    /// The decimation of the last frame (`None` before the first).
    pub(super) fn decimation(&self) -> Option<u16> {
        self.clock.decimation()
    }

    /// A frame at `decimation` after `gap`: its time.
    pub(super) fn advance(
        &mut self,
        config: &PipelineConfig,
        decimation: u16,
        gap: SeqGap,
    ) -> FrameTime {
        let missing = self.missing_before(config, decimation, gap);
        let tick = self.clock.advance_by(decimation, missing);
        FrameTime {
            missing,
            base_ticks: tick.base_ticks,
            t_us: self
                .ticks_us
                .us(tick.base_ticks, config.fpga_base_rate_millihz),
            rate_changed: tick.rate_changed,
        }
    }

    /// Frame-clock ticks in µs at `rate_millihz` (the navigation interval's bounds).
    pub(super) fn ticks_to_us(ticks: u64, rate_millihz: u64) -> u64 {
        FrameClock::ticks_to_us(ticks, rate_millihz)
    }

    /// The sample interval, ps (`None` before the first frame).
    pub(super) fn tau0_ps(&self, rate_millihz: u64) -> Option<u64> {
        // n ≤ 2¹⁶, so n · 10¹⁵ < 2⁶⁷: cannot wrap; a rate of 0 counts as 1 millihertz.
        let n = u128::from(self.clock.decimation()?).wrapping_add(1);
        let rate = NonZeroU128::from(NonZeroU64::new(rate_millihz).unwrap_or(NonZeroU64::MIN));
        Some((n.wrapping_mul(1_000_000_000_000_000) / rate) as u64)
    }

    /// Frames lost before a frame at `decimation`: the sequence counter's count (`seq_gap`), unless the arrival gap
    /// shows an outage the 16-bit counter cannot measure — an FPGA restart (the counter jumps back: the decoder's
    /// restart), or a silence of 2¹⁶ frames or more (the counter wrapped: the arrival gap picks the multiple of
    /// 2¹⁶). Buffering only makes arrivals later, so a backlog read late never shortens time, and the counter stays
    /// exact for every gap it can see.
    fn missing_before(&mut self, config: &PipelineConfig, decimation: u16, seq_gap: SeqGap) -> u32 {
        let by_seq = seq_gap.missing_before;
        let (now, last) = (self.arrival_us, self.last_arrival_us);
        self.last_arrival_us = now;
        let (Some(now), Some(last), Some(n)) = (now, last, self.clock.decimation()) else {
            return by_seq;
        };
        if n != decimation {
            return by_seq; // a new rate: the clock restarts its statistics and ignores gaps anyway
        }
        // The arrival gap in frames, rounded: gap · rate / ((N + 1) · 10⁹), both sides in units of 10⁻⁹ base ticks
        // (µs · millihertz). In u128 nothing can wrap: the gap is < 2⁶⁴ µs and the rate < 2⁶⁴ millihertz.
        let gap = u128::from(now.saturating_sub(last))
            .wrapping_mul(u128::from(config.fpga_base_rate_millihz));
        let frame = u128::from(n).wrapping_add(1).wrapping_mul(1_000_000_000);
        let rounded = gap.wrapping_add(frame >> 1);
        let slack = u32::from(config.arrival_slack_frames);
        // Without a restart, the arrival gap only matters once it could hide a wrap of the counter (the test
        // below needs ≥ 2¹⁶ + 1 − slack frames): the usual frame ends here, without a 128-bit division.
        let wrap_min = u128::from((1u32 << 16).wrapping_add(1).saturating_sub(slack));
        if !seq_gap.restarted && rounded < wrap_min.wrapping_mul(frame) {
            return by_seq;
        }
        // `frame` ≥ 10⁹: not zero.
        let frames = rounded / NonZeroU128::new(frame).unwrap_or(NonZeroU128::MIN);
        let by_time = u32::try_from(frames.saturating_sub(1)).unwrap_or(u32::MAX);
        let missing = if seq_gap.restarted {
            by_time
        } else {
            // The counter is right modulo 2¹⁶; time says how many wraps.
            let wraps = by_time.saturating_sub(by_seq).saturating_add(slack) >> 16;
            by_seq.saturating_add(wraps << 16)
        };
        if missing != by_seq {
            self.time_gaps = self.time_gaps.wrapping_add(1);
        }
        missing
    }
}
