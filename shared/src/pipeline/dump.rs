//! Dumps on request (`AllanRequest`, `HealthRequest { detail: true }`): reports generated one at a time as the
//! platform pulls them (`Pipeline::poll_dump`), so that a dump never needs a large buffer.

use super::ALLAN_CHANNELS;
use crate::allan::{AllanSet, LEVELS};
use crate::fuse::Fusion;
use crate::telemetry::{AllanReport, FaultReport, Reject, Telemetry};
use crate::wire::frame::GROUPS;

/// Where each dump stands.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Dumps {
    /// Allan dump: next (channel, level) and the end channel.
    allan: Option<(u8, u8, u8)>,
    /// Fault dump: next group.
    faults: Option<u8>,
}

impl Dumps {
    pub(super) const NEW: Self = Self {
        allan: None,
        faults: None,
    };

    /// `AllanRequest`: channels `first .. first + count` (clipped to the channels there are).
    pub(super) fn start_allan(&mut self, first: u8, count: u8) -> Result<(), Reject> {
        let end = usize::from(first)
            .saturating_add(usize::from(count))
            .min(ALLAN_CHANNELS);
        if usize::from(first) >= ALLAN_CHANNELS || count == 0 {
            return Err(Reject::BadArgument);
        }
        self.allan = Some((first, 0, end as u8));
        Ok(())
    }

    /// `HealthRequest { detail: true }`: every group's fault counts.
    pub(super) fn start_faults(&mut self) {
        self.faults = Some(0);
    }

    /// The next report: fault counts first, then the Allan levels that hold data (`tau0_ps` their sample interval).
    pub(super) fn next<const N: usize>(
        &mut self,
        fusion: &Fusion<GROUPS>,
        set: &AllanSet<N>,
        tau0_ps: u64,
    ) -> Option<Telemetry> {
        if let Some(group) = self.faults {
            self.faults = group
                .checked_add(1)
                .filter(|&next| usize::from(next) < GROUPS);
            if let Some([gyro, accel]) = fusion.fault_counts(usize::from(group)) {
                return Some(Telemetry::Faults(FaultReport { group, gyro, accel }));
            }
        }
        while let Some((channel, level, end)) = self.allan {
            // channel < end ≤ ALLAN_CHANNELS < 255: the saturating add never saturates (and would end the dump).
            let (next_channel, next_level) =
                match level.checked_add(1).filter(|&l| usize::from(l) < LEVELS) {
                    Some(next_level) => (channel, next_level),
                    None => (channel.saturating_add(1), 0),
                };
            self.allan = (next_channel < end).then_some((next_channel, next_level, end));
            if let Some(l) = set
                .level(usize::from(channel), usize::from(level))
                .filter(|l| l.count > 0)
            {
                return Some(Telemetry::Allan(AllanReport {
                    channel,
                    tau0_ps,
                    samples: set.samples(),
                    level: l,
                }));
            }
        }
        None
    }
}
