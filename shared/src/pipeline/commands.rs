//! The command interpreter: one command message in, its replies out as the call's result (the ack first, then any
//! report or FPGA message it asked for); an upload commit's ack waits for the platform's store. Nothing a command
//! produces goes through the outbox, which carries only what the frames and the PPS produce.

use super::{Averager, GROUPS, MAX_FRAMES_PER_OUTPUT, Output, Pipeline, PipelineMemory};
use crate::fuse::{FusionConfig, FusionMode};
use crate::telemetry::{
    Ack, CalSource, Command, CommandEnvelope, DecodeError, Mode, Reject, Telemetry, decode,
    peek_tag,
};
use crate::wire::FpgaControl;
use core::borrow::BorrowMut;
use heapless::Vec;

/// Most outputs one command produces: `SetTime`'s ack, time report and PPS report.
pub const COMMAND_REPLIES_MAX: usize = 3;

/// What one command produced, in sending order: its ack first, then any report or FPGA message it asked for; or,
/// after a `CalCommit` that succeeded, [`Output::PersistCalibration`] alone (the ack waits for the store).
pub type CommandReplies = Vec<Output, COMMAND_REPLIES_MAX>;

impl<B: BorrowMut<PipelineMemory>> Pipeline<B> {
    /// Handles one command message (the payload of a bus packet) and returns what it produced. Dumps it starts
    /// (`AllanRequest`, `HealthRequest { detail: true }`) come from [`Self::poll_dump`].
    pub fn handle_command(&mut self, bytes: &[u8]) -> CommandReplies {
        let tag = peek_tag(bytes);
        let mut replies = CommandReplies::new();
        let mut commit = false;
        // Room for the ack ahead of what the command produces (`execute` fills the rest).
        let mut produced = Vec::<Output, { COMMAND_REPLIES_MAX - 1 }>::new();
        let result = match decode::<CommandEnvelope>(bytes) {
            Err(DecodeError::Version(v)) => Err(Reject::Version(v)),
            Err(_) => Err(Reject::Malformed),
            Ok(env) => {
                commit = matches!(env.cmd, Command::CalCommit);
                self.execute(env.cmd, &mut produced)
            }
        };
        if commit && result.is_ok() {
            // The ack waits for the store (`calibration_persisted`).
            let _ = replies.push(Output::PersistCalibration { tag });
            return replies;
        }
        self.count_command(&result);
        let _ = replies.push(Output::Telemetry(Telemetry::Ack(Ack { tag, result })));
        for o in produced {
            let _ = replies.push(o);
        }
        replies
    }

    /// The outcome of the store that [`Output::PersistCalibration`] asked for; returns the `CalCommit`'s ack
    /// (`Reject::Storage` when the store failed: the table stays in force until the next reset, which will not
    /// find it), for the platform to send.
    pub fn calibration_persisted(&mut self, tag: u16, stored: bool) -> Ack {
        let result = if stored { Ok(()) } else { Err(Reject::Storage) };
        self.count_command(&result);
        Ack { tag, result }
    }

    fn count_command(&mut self, result: &Result<(), Reject>) {
        let i = usize::from(result.is_err());
        if let Some(c) = self.commands.get_mut(i) {
            *c = c.wrapping_add(1);
        }
    }

    /// Carries out `cmd`; what it produces besides the ack goes to `out` (at most two outputs: every arm pushes
    /// fewer, so the pushes cannot fail).
    fn execute(
        &mut self,
        cmd: Command,
        out: &mut Vec<Output, { COMMAND_REPLIES_MAX - 1 }>,
    ) -> Result<(), Reject> {
        match cmd {
            Command::Ping => {}
            Command::SetTime { unix_us } => {
                self.time.set_time(unix_us);
                for t in self.time_reports().into_iter().flatten() {
                    let _ = out.push(Output::Telemetry(t));
                }
            }
            Command::SetDecimation(n) => {
                if !self.config.link_carries(n) {
                    return Err(Reject::BadArgument);
                }
                let _ = out.push(Output::Fpga(FpgaControl::SetDecimation(n)));
            }
            Command::SetOutputRate(l) => {
                if !(1..=MAX_FRAMES_PER_OUTPUT).contains(&l) {
                    return Err(Reject::BadArgument);
                }
                self.config.frames_per_output = l;
                self.avg = Averager::NEW;
            }
            Command::SetMode(mode) => {
                self.mode = mode;
                let _ = out.push(Output::Fpga(FpgaControl::SetStreaming(
                    mode == Mode::Stream,
                )));
            }
            Command::ExcludeGroups { gyro, accel } => {
                let all = u32::MAX
                    .checked_shr(32u32.saturating_sub(GROUPS as u32))
                    .unwrap_or(0);
                if (gyro | accel) & !all != 0 {
                    return Err(Reject::BadArgument);
                }
                self.fusion.set_config(FusionConfig {
                    excluded: [gyro, accel],
                    ..*self.fusion.config()
                });
            }
            Command::SetFusion { mode, robust } => {
                if mode == FusionMode::Fixed && !self.cal.table.has_weights() {
                    return Err(Reject::BadArgument);
                }
                self.fusion.set_config(FusionConfig {
                    mode,
                    robust,
                    ..*self.fusion.config()
                });
            }
            Command::CalBegin { len, crc } => self.cal.begin(len, crc)?,
            Command::CalChunk { offset, data } => {
                self.cal
                    .chunk(&mut self.memory.borrow_mut().upload, offset, &data)?
            }
            Command::CalCommit => {
                self.cal.commit(&self.memory.borrow().upload)?;
                self.calibration_changed(CalSource::Uploaded);
            }
            Command::AllanRequest { first, count } => self.cursor.start_allan(first, count)?,
            Command::AllanReset => self.memory.borrow_mut().allan.reset(),
            Command::ClearResets { boot_count } => {
                if self.boot_count != Some(boot_count) {
                    return Err(Reject::BadArgument);
                }
                let _ = out.push(Output::ClearResets);
            }
            Command::HealthRequest { detail } => {
                let _ = out.push(Output::Telemetry(Telemetry::Health(self.health())));
                if detail {
                    self.cursor.start_faults();
                }
            }
        }
        Ok(())
    }
}
