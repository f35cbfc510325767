//! Health: the report of the core's counters, periodic and on request.

use super::{GROUPS, Pipeline, PipelineMemory};
use crate::fuse::FaultCounts;
use crate::telemetry::HealthReport;
use core::borrow::BorrowMut;

impl<B: BorrowMut<PipelineMemory>> Pipeline<B> {
    /// A health report now, with the core's counters. The platform owns three of its fields and sets them on the
    /// way out: `uptime_ms` and `link.overruns` (0 here), and what it dropped itself, added to `telemetry_dropped`
    /// (here: the outbox's overflows).
    pub fn health(&self) -> HealthReport {
        let mut faults = [FaultCounts::default(); 2];
        for g in 0..GROUPS {
            for (sum, c) in faults
                .iter_mut()
                .zip(self.fusion.fault_counts(g).unwrap_or_default())
            {
                sum.add(&c);
            }
        }
        let fusion = self.fusion.config();
        HealthReport {
            uptime_ms: 0,
            link: *self.intake.decoder.counters(),
            cal_id: self.cal.table.cal_id,
            cal_source: self.cal.source,
            decimation: self.decimation(),
            frames_per_output: self.config.frames_per_output,
            fusion: fusion.mode,
            robust: fusion.robust,
            faults,
            invalid_frames: self.invalid_frames,
            allan_samples: self.memory.borrow().allan.samples(),
            telemetry_dropped: self.telemetry_dropped,
            commands: self.commands,
            temp: self.cal.thermal.counts(),
            thermal_at_cdeg: self.cal.thermal.applied_cdeg(),
        }
    }
}
