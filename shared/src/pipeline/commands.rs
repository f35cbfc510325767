//! The command interpreter: one command message in, its ack (and any data) out through the outbox; the upload
//! commit's ack waits for the platform's store.

use super::{Averager, GROUPS, MAX_FRAMES_PER_OUTPUT, Output, Pipeline, PipelineMemory};
use crate::fuse::{FusionConfig, FusionMode};
use crate::telemetry::{
    Ack, CalSource, Command, CommandEnvelope, DecodeError, Mode, Reject, Telemetry, decode,
    peek_tag,
};
use crate::wire::FpgaControl;
use core::borrow::BorrowMut;

impl<B: BorrowMut<PipelineMemory>> Pipeline<B> {
    /// Handles one command message (the payload of a bus packet); the ack (and any data) follow in `poll`.
    pub fn handle_command(&mut self, bytes: &[u8]) {
        let tag = peek_tag(bytes);
        let mut commit = false;
        let result = match decode::<CommandEnvelope>(bytes) {
            Err(DecodeError::Version(v)) => Err(Reject::Version(v)),
            Err(_) => Err(Reject::Malformed),
            Ok(env) => {
                commit = matches!(env.cmd, Command::CalCommit);
                self.execute(env.cmd)
            }
        };
        if commit && result.is_ok() {
            // The ack waits for the store (`calibration_persisted`).
            self.push(Output::PersistCalibration { tag });
            return;
        }
        self.count_command(&result);
        // The ack goes ahead of any data the command produced.
        let ack = Output::Telemetry(Telemetry::Ack(Ack { tag, result }));
        if self.outbox.push_front(ack).is_err() {
            self.telemetry_dropped = self.telemetry_dropped.wrapping_add(1);
        }
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

    fn execute(&mut self, cmd: Command) -> Result<(), Reject> {
        match cmd {
            Command::Ping => {}
            Command::SetTime { unix_us } => {
                self.time.set_time(unix_us);
                self.push_time();
            }
            Command::SetDecimation(n) => {
                if !self.config.link_carries(n) {
                    return Err(Reject::BadArgument);
                }
                self.push(Output::Fpga(FpgaControl::SetDecimation(n)))
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
                self.push(Output::Fpga(FpgaControl::SetStreaming(
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
            Command::HealthRequest { detail } => {
                let h = self.health();
                self.push(Output::Telemetry(Telemetry::Health(h)));
                if detail {
                    self.cursor.start_faults();
                }
            }
        }
        Ok(())
    }
}
