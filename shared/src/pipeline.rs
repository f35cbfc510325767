//! The whole on-board job as one sans-IO state machine: FPGA link bytes and command bytes in, outputs out
//! (telemetry, FPGA control, "persist the calibration"). The firmware and the host replay run this same code;
//! neither does any processing of its own.
//!
//! Per frame: calibrate the 16 groups, feed the 96 sensor Allan channels, fuse, feed the 6 fused Allan channels,
//! and add the fused sample to the output interval's running mean. Every `frames_per_output` frames the mean is
//! sent as a [`FusedReport`](crate::telemetry::FusedReport).
//!
//! # Output rate: averaging, not discarding
//! The FPGA's decimator keeps 1 data set of every N + 1 and discards the rest; the noise of each kept sample is
//! the sensor's whole-band noise, so its white-noise deviation is not reduced at all (the discarded band folds
//! onto the kept samples). The pipeline instead averages L frames per output: for white noise of deviation σ per
//! frame the output deviation is σ/√L (noise gain 1/√L), and the mean is a low-pass filter (sinc response, first
//! null at the output rate) instead of aliasing. `tests::averaging_reduces_noise_by_sqrt_l` shows both.
//!
//! # Time and Allan τ₀
//! Time advances by N + 1 FPGA base periods per frame, including frames the sequence counter shows as lost. A
//! change of the decimation in the frames (or of the calibration) restarts the Allan accumulators and the output
//! interval, so that no statistic mixes two sample rates or two calibrations. Lost frames are not filled in the
//! Allan accumulators (they assume contiguous data; `LinkCounters::frames_dropped` says how far that holds).
//! While a fused axis has no valid sensor, its Allan channel repeats the last valid value (`invalid_frames`).

use crate::allan::AllanSet;
use crate::calib::thermal::ThermalComp;
use crate::calib::{AXES, CalibrationTable, RawCounts, encoded_len_max};
use crate::fuse::{FusedSample, Fusion, FusionConfig, FusionMode, HealthMask};
use crate::telemetry::{CalSource, Mode, Telemetry};
use crate::wire::frame::{FRAME_LEN, GROUPS};
use crate::wire::{FpgaControl, LinkCounters, SeqGap};
use core::borrow::BorrowMut;

/// Allan channels of the calibrated sensor axes: group g, axis a → channel 6g + a.
pub const SENSOR_CHANNELS: usize = GROUPS * AXES;
/// First Allan channel of the fused axes.
pub const FUSED_CHANNEL0: usize = SENSOR_CHANNELS;
/// All Allan channels.
pub const ALLAN_CHANNELS: usize = SENSOR_CHANNELS + AXES;
/// Outputs the pipeline can hold before the caller polls.
pub const OUTBOX_LEN: usize = 16;
/// Most outputs one frame can produce (fused, navigation, health, time and PPS reports); `push_link` keeps this much
/// room.
const OUTPUTS_PER_FRAME: usize = 5;
/// Longest accepted calibration upload (an encoded 16-group table).
pub const CAL_UPLOAD_MAX: usize = encoded_len_max(GROUPS);
/// Longest output interval, frames.
pub const MAX_FRAMES_PER_OUTPUT: u16 = 4096;

/// Pipeline parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PipelineConfig {
    /// FPGA data-set rate before decimation, millihertz (9 676 800 = 9676.8 Hz; N = 15 gives 604.8 frames/s).
    pub fpga_base_rate_millihz: u64,
    /// Frames averaged per output (32 at 604.8 frames/s = the seed's 18.9 Hz).
    pub frames_per_output: u16,
    /// Outputs between periodic health reports (0 = only on request).
    pub health_every: u16,
    /// Line rate of the FPGA link, bit/s (8N1: 10 bits per byte). `SetDecimation` is refused when the frame
    /// stream it asks for would not fit: (base rate / (N + 1)) · `FRAME_LEN` · 10 > this.
    pub link_bit_rate: u32,
    /// Frames by which arrival times ([`Pipeline::set_arrival_us`]) may understate a gap (the platform's read
    /// granularity; the firmware reads 1 KiB ≈ 4 frames at a time): used when the arrival gap decides how often the
    /// 16-bit sequence counter wrapped during a silence.
    pub arrival_slack_frames: u16,
    /// Navigation increments (`Telemetry::Nav`, `shared::nav`) after every `Fused` report.
    pub nav: bool,
    /// Fusion parameters.
    pub fusion: FusionConfig,
}

impl PipelineConfig {
    /// Our board's defaults.
    pub const DEFAULT: Self = Self {
        fpga_base_rate_millihz: crate::wire::clock::FPGA_BASE_RATE_MILLIHZ,
        frames_per_output: 32,
        health_every: 19,
        link_bit_rate: 2_000_000,
        arrival_slack_frames: 8,
        nav: true,
        fusion: FusionConfig::DEFAULT,
    };

    /// Whether the link carries the frame stream of decimation `n` (see [`Self::link_bit_rate`]). At our defaults
    /// the smallest such `n` is 11 (806.4 frames/s, 97 % of the 2 Mbaud line).
    pub fn link_carries(&self, n: u16) -> bool {
        // In u128 neither side can wrap: need < 2⁶⁴ · 2¹² and have ≤ 2¹⁶ · 2³² · 2¹⁰.
        let need = u128::from(self.fpga_base_rate_millihz)
            .wrapping_mul((FRAME_LEN as u128).wrapping_mul(10));
        let have = (u128::from(n).wrapping_add(1))
            .wrapping_mul(u128::from(self.link_bit_rate))
            .wrapping_mul(1000);
        need <= have
    }
}

/// Something the platform must do: from [`Pipeline::poll`] (frames, PPS) or [`Pipeline::handle_command`]. (Dumps
/// come from [`Pipeline::poll_dump`].)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Output {
    /// Send on the bus.
    Telemetry(Telemetry),
    /// Send to the FPGA.
    Fpga(FpgaControl),
    /// Store [`Pipeline::calibration`] in non-volatile memory (an upload was committed, and is in force), then
    /// call [`Pipeline::calibration_persisted`] with the outcome: the commit's ack (tag `tag`) waits for it, so the
    /// ground hears "Ok" only once the table survives a reset.
    PersistCalibration {
        /// The `CalCommit`'s tag.
        tag: u16,
    },
    /// Clear the platform's reset history and crash-loop counter (`ClearResets`, acknowledged: its boot count
    /// matched [`Pipeline::set_boot_count`]'s).
    ClearResets,
}

/// One frame's groups between the stages: signed ADC counts, then calibrated axes.
#[derive(Clone, Copy, Debug)]
struct FrameScratch {
    raw: [RawCounts; GROUPS],
    axes: [[i32; AXES]; GROUPS],
}

/// The pipeline's large buffers, kept outside its struct (61 816 B, all zero when new): the MCU keeps them in CCM
/// RAM, zeroed in place at boot (`firmware/src/board.rs`), neither in the flash image of the tasks' state nor on a
/// stack; the host on the heap.
pub struct PipelineMemory {
    /// The Allan accumulators of all channels (57 944 B: 102 channels × 568 B + 8).
    pub allan: AllanSet<ALLAN_CHANNELS>,
    /// The bytes of the calibration upload in progress (`CalBegin`, `CalChunk`, `CalCommit`).
    upload: [u8; CAL_UPLOAD_MAX],
}

impl PipelineMemory {
    /// All accumulators empty, no upload.
    pub const fn new() -> Self {
        Self {
            allan: AllanSet::new(),
            upload: [0; CAL_UPLOAD_MAX],
        }
    }
}

impl Default for PipelineMemory {
    fn default() -> Self {
        Self::new()
    }
}

/// The on-board pipeline (see module docs). Its large buffers `B` are held by anything that borrows a
/// [`PipelineMemory`] mutably (a handle to CCM RAM on the MCU, `Box<PipelineMemory>` on the host).
pub struct Pipeline<B> {
    config: PipelineConfig,
    /// Link bytes to frames, and frames to time.
    intake: Intake,
    /// The table in force, its thermal compensation and the upload of the next.
    cal: Calibration,
    fusion: Fusion<GROUPS>,
    memory: B,
    fused_hold: [i32; AXES],
    /// The frame in work: every field is written before it is read, each frame (kept here so that it is not zeroed
    /// on the stack each frame).
    scratch: FrameScratch,
    last: FusedSample,
    avg: Averager,
    out_seq: u32,
    outputs_since_health: u16,
    outbox: heapless::Deque<Output, OUTBOX_LEN>,
    /// The dumps under way.
    cursor: Dumps,
    mode: Mode,
    /// Frame time and spacecraft time.
    time: TimeSync,
    nav: NavStage,
    invalid_frames: u32,
    telemetry_dropped: u32,
    commands: [u32; 2],
    /// The platform's boot counter (`ClearResets` must name it); `None` where there is no reset history.
    boot_count: Option<u32>,
}

impl<B: BorrowMut<PipelineMemory>> Pipeline<B> {
    /// A pipeline with the factory calibration over `memory`, taken as it is: pass an empty one
    /// ([`PipelineMemory::new`]; [`Self::load_calibration`] and `AllanReset` empty its Allan part in place).
    ///
    /// `const`, so that the MCU builds its whole state at compile time, where it lives (a `static`), instead of on
    /// a stack that cannot hold it: LLVM does not build a large value in place through a `StaticCell` (measured:
    /// an 11 KiB frame in `new`, 24 KiB in the firmware's `App::new`).
    pub const fn new(config: PipelineConfig, memory: B) -> Self {
        Self {
            config,
            intake: Intake::NEW,
            cal: Calibration::NEW,
            fusion: Fusion::new(config.fusion),
            memory,
            fused_hold: [0; AXES],
            scratch: FrameScratch {
                raw: [RawCounts::ZERO; GROUPS],
                axes: [[0; AXES]; GROUPS],
            },
            last: FusedSample {
                axes: [0; AXES],
                used: [0; AXES],
                used_mask: [0; AXES],
                health: HealthMask::NONE,
            },
            avg: Averager::NEW,
            out_seq: 0,
            outputs_since_health: 0,
            outbox: heapless::Deque::new(),
            cursor: Dumps::NEW,
            mode: Mode::Stream,
            time: TimeSync::NEW,
            nav: NavStage::NEW,
            invalid_frames: 0,
            telemetry_dropped: 0,
            commands: [0; 2],
            boot_count: None,
        }
    }

    /// Tells the pipeline the platform's boot counter, which a `ClearResets` command must name to be accepted
    /// (without one, every `ClearResets` is refused with `BadArgument`).
    pub fn set_boot_count(&mut self, boot_count: u32) {
        self.boot_count = Some(boot_count);
    }

    /// Puts a calibration in force (restarting the statistics that depend on it). Everything is reset in place and
    /// the table copied from `table`: no second pipeline state is built on the stack (`docs/firmware.md`, stack).
    pub fn load_calibration(&mut self, table: &CalibrationTable<GROUPS>, source: CalSource) {
        self.cal.table.clone_from(table);
        self.calibration_changed(source);
    }

    /// Puts in force the table that `fill` writes into the pipeline's own, in place (the MCU loads it from flash so,
    /// without a table-sized temporary): `fill` returns where the table came from.
    pub fn load_calibration_with(
        &mut self,
        fill: impl FnOnce(&mut CalibrationTable<GROUPS>) -> CalSource,
    ) {
        let source = fill(&mut self.cal.table);
        self.calibration_changed(source);
    }

    /// The table in force was replaced: its checksum, thermal biases and weights, and a restart of the statistics
    /// that depend on it.
    fn calibration_changed(&mut self, source: CalSource) {
        self.cal.changed(source);
        // A table with fixed weights puts them in force; one without ends their use.
        let mode = match (self.cal.table.has_weights(), self.fusion.config().mode) {
            (true, _) => FusionMode::Fixed,
            (false, FusionMode::Fixed) => FusionConfig::DEFAULT.mode,
            (false, mode) => mode,
        };
        self.fusion.set_config(FusionConfig {
            mode,
            ..*self.fusion.config()
        });
        self.fusion.reset();
        self.restart_statistics();
    }

    /// Whether the calibration in force is still the table that was loaded: its CRC-32C (the table's own, over its
    /// encoding) against the one taken when it was loaded. The F405's SRAM has no ECC; the firmware checks this periodically and
    /// reloads the table from flash when it fails.
    pub fn calibration_intact(&self) -> bool {
        self.cal.intact()
    }

    /// Flips bit `bit % 32` of group `group % GROUPS`'s first gyro bias in the calibration held in RAM, as a
    /// radiation upset would, without updating its CRC (feature `fault-injection`: tests only).
    #[cfg(any(test, feature = "fault-injection"))]
    pub fn inject_calibration_bit_flip(&mut self, group: usize, bit: u32) {
        if let Some(g) = self.cal.table.groups.get_mut(group % GROUPS) {
            g.gyro_bias_q12[0] ^= 1i32.wrapping_shl(bit % 32);
        }
    }

    /// The calibration in force.
    pub fn calibration(&self) -> &CalibrationTable<GROUPS> {
        &self.cal.table
    }

    /// Where the calibration in force came from.
    pub fn calibration_source(&self) -> CalSource {
        self.cal.source
    }

    /// The configuration it was built with.
    pub fn config(&self) -> &PipelineConfig {
        &self.config
    }

    /// The FPGA decimation of the last frame (`None` before the first), as Health reports it.
    pub fn decimation(&self) -> Option<u16> {
        self.intake.decimation()
    }

    /// Link statistics.
    pub fn link_counters(&self) -> &LinkCounters {
        self.intake.decoder.counters()
    }

    /// The platform dropped the link bytes it had buffered (after a CPU stall long enough for its DMA ring to lap,
    /// the ring holds bytes of different laps): the decoder's partial frame is forgotten (the platform counts the
    /// overrun); the next frame's sequence gap counts the frames lost.
    pub fn link_discarded(&mut self) {
        self.intake.decoder.discard_partial();
    }

    /// The platform's monotonic time, µs, at which the bytes about to be pushed were read. With it, an outage the
    /// 16-bit frame sequence counter cannot measure stays on the time line — an FPGA restart (the frame clock
    /// advances by the arrival gap) or a silence of 2¹⁶ frames or more (the arrival gap tells how often the counter
    /// wrapped) — and [`Self::time_gaps`] counts it. Without it (replay of a log), time comes from the counter
    /// alone.
    pub fn set_arrival_us(&mut self, us: u64) {
        self.intake.set_arrival_us(us);
    }

    /// The operating mode (`SetMode`).
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// Outages bridged by arrival time (see [`Self::set_arrival_us`]).
    pub fn time_gaps(&self) -> u32 {
        self.intake.time_gaps()
    }

    /// The Allan accumulators (channels: see [`SENSOR_CHANNELS`], [`FUSED_CHANNEL0`]).
    pub fn allan(&self) -> &AllanSet<ALLAN_CHANNELS> {
        &self.memory.borrow().allan
    }

    /// Sample interval of the Allan accumulators, ps (`None` before the first frame).
    pub fn tau0_ps(&self) -> Option<u64> {
        self.intake.tau0_ps(self.config.fpga_base_rate_millihz)
    }

    /// The fused sample of the last frame processed.
    pub fn last_fused(&self) -> &FusedSample {
        &self.last
    }

    /// The thermal compensation's state (biases in force, temperature counts).
    pub fn thermal(&self) -> &ThermalComp<GROUPS> {
        &self.cal.thermal
    }

    /// The fusion state (noise estimates, weights, fault counts).
    pub fn fusion(&self) -> &Fusion<GROUPS> {
        &self.fusion
    }

    /// Consumes link bytes from the front of `input`, processing every complete frame. Stops early, with bytes
    /// left in `input`, when the outbox is nearly full: call [`Self::poll`] until it returns `None`, then call
    /// again with the rest. Nothing is lost either way.
    pub fn push_link(&mut self, input: &mut &[u8]) {
        while self.outbox.capacity().saturating_sub(self.outbox.len()) >= OUTPUTS_PER_FRAME {
            match stages::decode(&mut self.intake.decoder, input, &mut self.scratch.raw) {
                Some((head, gap)) => self.process(head, gap),
                None => return,
            }
        }
    }

    /// The next queued output, if any: what the frames produced (fused, navigation and periodic health reports)
    /// and the time reports of a PPS edge. A command's replies are returned by [`Self::handle_command`] instead.
    pub fn poll(&mut self) -> Option<Output> {
        self.outbox.pop_front()
    }

    /// The next report of a requested dump (Allan levels, fault counters), generated now; `None` when no dump is
    /// under way. Separate from [`Self::poll`] so that the platform pulls dumps only as fast as its bus drains,
    /// without ever delaying the FPGA link.
    pub fn poll_dump(&mut self) -> Option<Telemetry> {
        let tau0_ps = self.tau0_ps().unwrap_or(0);
        self.cursor
            .next(&self.fusion, &self.memory.borrow().allan, tau0_ps)
    }

    fn push(&mut self, o: Output) {
        if self.outbox.push_back(o).is_err() {
            self.telemetry_dropped = self.telemetry_dropped.wrapping_add(1);
        }
    }

    fn restart_statistics(&mut self) {
        self.memory.borrow_mut().allan.reset();
        self.avg = Averager::NEW;
        self.nav = NavStage::NEW;
    }

    /// One frame, whose signed counts `push_link` put into `scratch.raw`.
    fn process(&mut self, head: FrameHead, gap: SeqGap) {
        let tick = self.intake.advance(&self.config, head.decimation, gap);
        let (missing, t_us) = (tick.missing, tick.t_us);
        if tick.rate_changed {
            self.restart_statistics();
        }

        let FrameScratch { raw, axes } = &mut self.scratch;
        stages::calibrate(
            &mut self.cal.thermal,
            &self.cal.table,
            head.temp_cdeg,
            raw,
            axes,
        );
        // Fused straight into `last` (read below, and by `last_fused`).
        self.fusion
            .fuse_into(raw, axes, &self.cal.table, &mut self.last);
        if self.config.nav {
            self.integrate(head.decimation, missing, tick.base_ticks);
        }
        if !self.last.valid() {
            self.invalid_frames = self.invalid_frames.wrapping_add(1);
        }
        stages::hold_valid(&mut self.fused_hold, &self.last);
        // Allan channels: the sensors' axes, then the fused axes (holding the last valid value).
        // 96 + 6 = ALLAN_CHANNELS values: always taken (until the accumulators' sample limit).
        let _ = self
            .memory
            .borrow_mut()
            .allan
            .push_parts(self.scratch.axes.as_flattened(), &self.fused_hold);

        self.time.frame(t_us, self.intake.arrival_us());
        self.avg.add(&self.last, head.temp_cdeg, t_us);
        if self.avg.frames >= self.config.frames_per_output.max(1) {
            let report = self.avg.report(self.out_seq, self.time.epoch_us());
            self.out_seq = self.out_seq.wrapping_add(1);
            self.avg = Averager::NEW;
            self.push(Output::Telemetry(Telemetry::Fused(report)));
            if self.config.nav {
                let end = tick
                    .base_ticks
                    .wrapping_add(u64::from(head.decimation).wrapping_add(1));
                self.push_nav(report.seq, end);
            }
            // Counted only when periodic health is on (health_every == 0: only on request); then the count stays
            // below health_every ≤ u16::MAX before the increment, so it cannot overflow.
            if self.config.health_every > 0 {
                self.outputs_since_health = self.outputs_since_health.saturating_add(1);
                if self.outputs_since_health >= self.config.health_every {
                    self.outputs_since_health = 0;
                    let h = self.health();
                    self.push(Output::Telemetry(Telemetry::Health(h)));
                    self.push_time();
                }
            }
        }
    }

    /// A [`TimeReport`] after the time was set: the last frame's time on both scales; and the PPS counters once an
    /// edge was seen.
    fn push_time(&mut self) {
        let [time, pps] = self.time_reports();
        for t in [time, pps].into_iter().flatten() {
            self.push(Output::Telemetry(t));
        }
    }

    /// The time report and, when a PPS edge was seen, the PPS report.
    fn time_reports(&self) -> [Option<Telemetry>; 2] {
        [
            self.time_report().map(Telemetry::Time),
            self.time.pps_seen().map(Telemetry::Pps),
        ]
    }
}

mod averager;
mod calibration;
mod commands;
mod dump;
mod health;
mod intake;
mod nav_stage;
pub mod stages;
mod time_sync;

use averager::Averager;
use calibration::Calibration;
pub use commands::{COMMAND_REPLIES_MAX, CommandReplies};
use dump::Dumps;
use intake::Intake;
use nav_stage::NavStage;
use stages::FrameHead;
pub use time_sync::PPS_TOLERANCE_US;
use time_sync::TimeSync;

// The golden stream test is in `tests/acceptance/golden.rs`.
#[cfg(test)]
mod tests;
