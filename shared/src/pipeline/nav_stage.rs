//! The navigation stage: the fused samples integrated into the increments of each output interval
//! ([`crate::nav::NavIntegrator`], sent as [`NavReport`] after every `Fused` report).

use super::intake::Intake;
use super::stages;
use super::{Output, Pipeline, PipelineMemory};
use crate::fuse::FusedSample;
use crate::nav::NavIntegrator;
use crate::telemetry::NavReport;
use crate::telemetry::Telemetry;
use core::borrow::BorrowMut;

/// The integrator and the interval it covers.
#[derive(Clone, Copy, Debug)]
pub(super) struct NavStage {
    nav: NavIntegrator,
    /// Frame-clock ticks at the start of the interval (the end of the last one).
    start_ticks: Option<u64>,
    /// Frames with a saturated sensor in the interval.
    clipped: u16,
}

impl NavStage {
    pub(super) const NEW: Self = Self {
        nav: NavIntegrator::new(),
        start_ticks: None,
        clipped: 0,
    };

    /// One frame: the fused rate and specific force of `fused` (SI units, `f32`) over the frame's time step `dt_s`;
    /// `missing` lost frames before it, and a frame without a valid fused sample, bridged.
    pub(super) fn add_frame(
        &mut self,
        fused: &FusedSample,
        dt_s: f32,
        missing: u32,
        base_ticks: u64,
    ) {
        if self.start_ticks.is_none() {
            self.start_ticks = Some(base_ticks);
        } else {
            self.nav.bridge(missing, dt_s);
        }
        if fused.valid() {
            stages::nav_add(&mut self.nav, fused, dt_s);
        } else {
            self.nav.bridge(1, dt_s);
        }
        if fused.health.gyro.saturated | fused.health.accel.saturated != 0 {
            self.clipped = self.clipped.saturating_add(1);
        }
    }

    /// The interval's report (sequence number `seq`), ending at frame-clock tick `end`; starts the next interval.
    pub(super) fn report(&mut self, seq: u32, end: u64, rate_millihz: u64) -> NavReport {
        let inc = self.nav.take();
        let start = self.start_ticks.replace(end).unwrap_or(end);
        let t_us = Intake::ticks_to_us(start, rate_millihz);
        let dt_us = Intake::ticks_to_us(end, rate_millihz).saturating_sub(t_us);
        // f32 → i64 casts saturate: a value beyond ±9.2e18 nrad cannot occur in one interval.
        NavReport {
            seq,
            t_us,
            dt_us: u32::try_from(dt_us).unwrap_or(u32::MAX),
            dtheta_nrad: inc.dtheta_rad.map(|x| (x * 1.0e9) as i64),
            dv_umps: inc.dv_mps.map(|x| (x * 1.0e6) as i64),
            frames: u16::try_from(inc.frames).unwrap_or(u16::MAX),
            bridged: u16::try_from(inc.bridged).unwrap_or(u16::MAX),
            clipped: core::mem::take(&mut self.clipped),
        }
    }
}

impl<B: BorrowMut<PipelineMemory>> Pipeline<B> {
    /// One frame into the navigation increments (see [`NavStage::add_frame`]).
    pub(super) fn integrate(&mut self, decimation: u16, missing: u32, base_ticks: u64) {
        let dt_s = stages::frame_dt_s(decimation, self.config.fpga_base_rate_millihz);
        self.nav.add_frame(&self.last, dt_s, missing, base_ticks);
    }

    /// The interval's [`NavReport`], ending at frame-clock tick `end`.
    pub(super) fn push_nav(&mut self, seq: u32, end: u64) {
        let report = self
            .nav
            .report(seq, end, self.config.fpga_base_rate_millihz);
        self.push(Output::Telemetry(Telemetry::Nav(report)));
    }
}
