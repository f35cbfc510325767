//! Telemetry (MCU → ground) and commands (ground → MCU): postcard messages in a versioned envelope
//! (spec: `docs/telemetry.md`).
//!
//! Every message on the bus is `[PROTOCOL_VERSION: u8] ++ postcard(body)`; for commands the body is
//! `CommandEnvelope { tag, cmd }`, for telemetry it is [`Telemetry`]. Decoding any byte string returns a message or
//! a typed [`DecodeError`]; it never panics (property-tested).

use crate::allan::AllanLevel;
use crate::calib::CalError;
use crate::fuse::{FaultCounts, FusionMode, HealthMask};
use crate::wire::LinkCounters;
use serde::{Deserialize, Serialize, de::DeserializeOwned};

/// Version of the message set; the first byte of every message. 2: `FusedReport::unix_us` (spacecraft time in every
/// fused report once `SetTime` set it).
pub const PROTOCOL_VERSION: u8 = 4;
/// Largest calibration chunk in one command, bytes.
pub const CAL_CHUNK_MAX: usize = 192;
/// Largest encoded message, bytes (fits libcsp's default KISS MTU with room to spare).
pub const MAX_MESSAGE_LEN: usize = 232;

/// A fused output sample: the running mean over one output interval.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FusedReport {
    /// Output sequence number, +1 per report.
    pub seq: u32,
    /// Time of the interval's first frame since the pipeline started, µs (from the frame sequence counter).
    pub t_us: u64,
    /// Frames averaged into this report.
    pub frames: u16,
    /// Mean rates x, y, z, µ°/s.
    pub rate_udps: [i32; 3],
    /// Mean specific force x, y, z, µg.
    pub accel_ug: [i32; 3],
    /// Fewest sensors used in any frame of the interval, per axis (gx gy gz ax ay az); 0 = axis invalid.
    pub used: [u8; 6],
    /// Sensors left out in any frame of the interval.
    pub health: HealthMask,
    /// Mean board temperature, 0.01 °C, when the frames carried it.
    pub temp_cdeg: Option<i16>,
    /// Spacecraft time of the interval's first frame, µs since the Unix epoch: `t_us` mapped with the time set by
    /// `SetTime` and disciplined by PPS edges, as it stood when the report was made; `None` before `SetTime`.
    pub unix_us: Option<u64>,
}

impl FusedReport {
    /// The six mean axes in `calib::GX … AZ` order: rates in µ°/s, then specific force in µg.
    pub fn axes(&self) -> [i32; 6] {
        let [gx, gy, gz] = self.rate_udps;
        let [ax, ay, az] = self.accel_ug;
        [gx, gy, gz, ax, ay, az]
    }
}

/// One level of one Allan channel. The ground computes `σ²(τ) = sum_sq / (2 · count · m²)`, m = 2^level,
/// τ = m · τ₀, in the channel's unit squared (channels 0..96: group g = ch / 6, axis ch % 6 in `calib::GX…AZ`
/// order; 96..102: the fused axes).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct AllanReport {
    /// Channel number.
    pub channel: u8,
    /// Sample interval τ₀ of the accumulator, picoseconds.
    pub tau0_ps: u64,
    /// Samples accumulated so far.
    pub samples: u64,
    /// The level's statistics.
    pub level: AllanLevel,
}

/// How the calibration in use was obtained.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum CalSource {
    /// Built-in nominal values (no valid stored record).
    Factory,
    /// Loaded from flash at boot.
    Stored,
    /// Uploaded and committed in this session.
    Uploaded,
}

/// Periodic and on-request health.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HealthReport {
    /// Time since boot, ms (set by the platform).
    pub uptime_ms: u64,
    /// FPGA link statistics.
    pub link: LinkCounters,
    /// Calibration id in use (0 = factory).
    pub cal_id: u32,
    /// Where it came from.
    pub cal_source: CalSource,
    /// FPGA decimation seen in the last frame (`None` before the first frame).
    pub decimation: Option<u16>,
    /// Frames per output interval.
    pub frames_per_output: u16,
    /// Fusion mode.
    pub fusion: FusionMode,
    /// Fault exclusion on.
    pub robust: bool,
    /// Sensor-samples left out since boot, summed over groups: gyro, accel (details in [`FaultReport`]).
    pub faults: [FaultCounts; 2],
    /// Frames whose fused sample had an invalid axis.
    pub invalid_frames: u32,
    /// Samples in each Allan accumulator.
    pub allan_samples: u64,
    /// Telemetry messages dropped because the outbox was full.
    pub telemetry_dropped: u32,
    /// Commands accepted / rejected.
    pub commands: [u32; 2],
    /// Frames without a valid board temperature, and of those the frames calibrated at the last valid one
    /// (thermal compensation in force; version 3).
    pub temp: crate::calib::thermal::TempCounts,
    /// Temperature the thermal compensation is computed at, 0.01 °C (`None`: no thermal terms in force, or no valid
    /// temperature yet; version 3).
    pub thermal_at_cdeg: Option<i16>,
}

/// Receive errors of one UART since boot, by kind (wrapping).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RxErrorCounts {
    /// Bytes lost: the UART overran, or its DMA ring was lapped.
    pub overrun: u32,
    /// Framing, noise or parity errors.
    pub line: u32,
    /// Any other receive error.
    pub other: u32,
}

/// The outcome of the last calibration store since boot.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StoreOutcome {
    /// No store since boot.
    #[default]
    None,
    /// Written and read back as record `seq`.
    Stored(u32),
    /// Failed (flash error, or the read-back differed).
    Failed,
}

/// How many [`ResetRecord`]s the firmware keeps and reports, newest first.
pub const RESET_HISTORY_LEN: usize = 4;

/// One reset in the history the firmware keeps across resets (no-init RAM) and reports in every [`ResetHistory`].
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResetRecord {
    /// The boot that ended (the boot counter's value while it ran).
    pub boot: u32,
    /// Its uptime when the record was written, ms (for a reset without a record: the last uptime the running
    /// firmware noted, at most 250 ms old).
    pub uptime_ms: u32,
    /// The reset flags the next boot found (as [`HousekeepingReport::reset_flags`]).
    pub reset_flags: u8,
    /// What stopped it.
    pub cause: ResetCause,
}

/// What ended a boot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ResetCause {
    /// No record was written: a power-on or brown-out that kept RAM, the reset pin, or a lock-up that the IWDG
    /// ended (the reset flags tell which).
    Unknown,
    /// A HardFault (an escalated bus, memory or usage fault; with flip-link, also a stack overflow). The handler
    /// runs on a stack of its own, so it records even when the fault was the stack's.
    HardFault(HardFaultInfo),
    /// The clock security system saw the crystal fail (NMI with RCC_CIR.CSSF): the next boot runs on the HSI.
    ClockFailure,
    /// An NMI without a clock failure.
    Nmi,
    /// An exception or interrupt without a handler of its own (`DefaultHandler`): its exception number (IPSR;
    /// interrupt n is n + 16).
    UnhandledIrq {
        /// IPSR at entry.
        exception: u16,
    },
    /// A panic: where.
    Panic {
        /// Source line.
        line: u32,
        /// CRC-32C of the source file's path (the ground maps it to a name with the same build's sources).
        file_crc: u32,
    },
    /// A task missed its deadline (its heartbeat stopped); the IWDG reset followed.
    Watchdog {
        /// The first late task.
        task: TaskId,
        /// Where thread code was when the deadline monitor (SysTick) saw it: a task spinning without yielding is
        /// found here; a task waiting forever leaves the executor's idle loop.
        pc: u32,
    },
    /// The ground asked for the reset (none yet; reserved so that the cause is never `Unknown` for it).
    Commanded,
}

/// The fault registers a HardFault leaves (ARMv7-M ARM B3.2.15–B3.2.18) and the stacked context.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HardFaultInfo {
    /// Stacked PC (0 when the frame could not be read: the fault happened while stacking).
    pub pc: u32,
    /// Stacked LR.
    pub lr: u32,
    /// EXC_RETURN of the handler (which stack, FPU frame or not).
    pub exc_return: u32,
    /// The stack pointer the fault left (the frame's address).
    pub sp: u32,
    /// CFSR (MMFSR | BFSR << 8 | UFSR << 16).
    pub cfsr: u32,
    /// HFSR (FORCED, VECTTBL).
    pub hfsr: u32,
    /// BFAR if CFSR.BFARVALID, else MMFAR if CFSR.MMARVALID, else 0.
    pub fault_addr: u32,
}

/// The firmware's tasks, as the watchdog names them.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TaskId {
    /// FPGA frames in.
    Link,
    /// Control messages to the FPGA.
    FpgaCtrl,
    /// Bus bytes in.
    BusRx,
    /// Bus bytes out.
    BusTx,
    /// The calibration store.
    Storage,
    /// The watchdog feeder.
    Watchdog,
    /// Housekeeping.
    Housekeeping,
    /// The PPS input.
    Pps,
    /// A task number this build does not know.
    Other(u8),
}

/// Where the system clock comes from.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ClockSource {
    /// The 8 MHz crystal (HSE) through the PLL.
    Hse,
    /// The internal 16 MHz RC (HSI) through the PLL: the crystal did not start at boot.
    Hsi,
    /// The HSI, because the clock security system saw the crystal fail in the boot before this one.
    HsiAfterClockFailure,
}

/// The reset history (appended message, sent with every [`HousekeepingReport`]): every way the firmware stopped,
/// kept across resets until the ground clears it with `ClearResets` (acknowledged), and the crash-loop state.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ResetHistory {
    /// Boots since the history was last found invalid (a power-on that lost RAM) — never cleared by command.
    pub boot_count: u32,
    /// Consecutive resets that came less than the short-run time after their boot (the crash-loop counter).
    pub short_runs: u8,
    /// This boot is in safe mode (the crash-loop counter reached its limit): factory calibration, no FPGA tasks.
    pub safe_mode: bool,
    /// Records dropped because the history was full, since the last clear.
    pub dropped: u32,
    /// The last resets, newest first (`None` past the last one).
    pub records: [Option<ResetRecord>; RESET_HISTORY_LEN],
}

/// Bus statistics (wrapping u32), counted by [`crate::bus::BusNode`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BusCounters {
    /// Valid packets for us.
    pub packets: u32,
    /// KISS frames dropped (bad escape, command byte, oversize).
    pub kiss_errors: u32,
    /// CSP packets dropped (too short, CRC, unsupported flags).
    pub csp_errors: u32,
    /// Valid packets for another address or an unserved port.
    pub ignored: u32,
}

impl BusCounters {
    /// All counters zero (`Default`, usable in `const`).
    pub const ZERO: Self = Self {
        packets: 0,
        kiss_errors: 0,
        csp_errors: 0,
        ignored: 0,
    };
}

/// The board around the pipeline (appended message; the firmware sends one every second, streaming or not).
/// Counters wrap; `None` is "not measured on this platform" (e.g. the SITL has no cycle counter or sensors).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct HousekeepingReport {
    /// Time since boot, ms.
    pub uptime_ms: u64,
    /// The firmware's git commit: its first 8 hex digits as a number (0: built outside git).
    pub fw_commit: u32,
    /// Built from a tree with uncommitted changes.
    pub fw_dirty: bool,
    /// Reset flags at boot (RCC_CSR bits 25–31 shifted down: bit 0 BOR, 1 PIN, 2 POR, 3 software, 4 IWDG,
    /// 5 WWDG, 6 low-power).
    pub reset_flags: u8,
    /// Boots counted in the reset history ([`ResetHistory::boot_count`]; 0 where there is none, e.g. the SITL).
    pub boot_count: u32,
    /// Running in safe mode after a crash loop ([`ResetHistory::safe_mode`]).
    pub safe_mode: bool,
    /// Where the system clock comes from (`None`: not known, e.g. the SITL).
    pub clock_source: Option<ClockSource>,
    /// The HSI trim in force (RCC_CR.HSITRIM, 0–31, factory default 16).
    pub hsi_trim: u8,
    /// On the HSI: its error against the FPGA's crystal over the last trim window, ppm (positive: fast; `None`
    /// on the crystal, or before a window of streamed frames).
    pub hsi_error_ppm: Option<i32>,
    /// The brown-out reset level in the option bytes (0: off, below 1.8 V; 1: 2.2 V; 2: 2.5 V; 3: 2.8 V).
    pub bor_level: Option<u8>,
    /// Calibration stores refused because VDD was below the x32 programming minimum (2.7 V, measured with
    /// VREFINT).
    pub stores_refused_low_vdd: u32,
    /// Share of CPU time the link task spent processing frames over the last period, ‰ (DWT cycle counter).
    pub core_load_permille: Option<u16>,
    /// CPU cycles per processed frame over the last period.
    pub core_cycles_per_frame: Option<u32>,
    /// MCU temperature, 0.01 °C (its internal sensor with the factory calibration).
    pub mcu_temp_cdeg: Option<i16>,
    /// Analog supply VDDA, mV (from VREFINT and its factory calibration).
    pub vdda_mv: Option<u16>,
    /// FPGA link receive errors.
    pub link_rx_errors: RxErrorCounts,
    /// Bus receive errors.
    pub bus_rx_errors: RxErrorCounts,
    /// Bus transmit errors.
    pub bus_tx_errors: u32,
    /// The bus node's counters.
    pub bus: BusCounters,
    /// FPGA control messages dropped (queue full).
    pub fpga_ctrl_dropped: u32,
    /// Outages bridged by arrival time (an FPGA restart, a counter wrap: `Pipeline::set_arrival_us`).
    pub time_gaps: u32,
    /// Calibration stores since boot, and how many failed.
    pub cal_stores: [u32; 2],
    /// The last store's outcome.
    pub last_store: StoreOutcome,
    /// Times the calibration in RAM failed its periodic CRC check and was reloaded from flash.
    pub cal_ram_repairs: u32,
    /// The operating mode.
    pub mode: Mode,
    /// Groups left out of the fusion by hand, `[gyro, accel]` bitmasks.
    pub excluded: [u32; 2],
    /// The core clock's rate, Hz: full while streaming, lowered in `Mode::Idle` (`None`: not known yet).
    pub core_clock_hz: Option<u32>,
}

/// Fault counters of one group (sent after a health request with `detail`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct FaultReport {
    /// Group number.
    pub group: u8,
    /// Gyro faults.
    pub gyro: FaultCounts,
    /// Accelerometer faults.
    pub accel: FaultCounts,
}

/// Why a command was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reject {
    /// Unknown protocol version (the one received).
    Version(u8),
    /// The bytes are not a command.
    Malformed,
    /// An argument is out of range.
    BadArgument,
    /// A chunk or commit without a begun upload.
    CalNotStarted,
    /// A chunk not at the next expected offset (the expected one).
    CalOffset(u16),
    /// Chunks beyond the announced length.
    CalOverflow,
    /// Commit before all bytes arrived, or their CRC differs from the announced one.
    CalIncomplete,
    /// The uploaded table is invalid.
    Cal(CalError),
    /// The committed table is in force but could not be stored (written and read back): a reset loses it.
    Storage,
}

/// Answer to every command.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Ack {
    /// The command's tag (0 when it could not be read).
    pub tag: u16,
    /// Accepted, or why not.
    pub result: Result<(), Reject>,
}

/// Everything the MCU sends.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Telemetry {
    /// A fused output sample.
    Fused(FusedReport),
    /// An Allan level.
    Allan(AllanReport),
    /// Health.
    Health(HealthReport),
    /// Fault counters of one group.
    Faults(FaultReport),
    /// Answer to a command.
    Ack(Ack),
    /// Board housekeeping (appended).
    Housekeeping(HousekeepingReport),
    /// Frame time ↔ spacecraft time (appended), after `SetTime` and with every periodic Health.
    Time(TimeReport),
    /// Navigation increments of one output interval (appended), after its `Fused` report.
    Nav(NavReport),
    /// PPS discipline counters (appended), with every periodic Health once a PPS edge was seen.
    Pps(PpsReport),
    /// The reset history (appended, version 4), with every Housekeeping report.
    Resets(ResetHistory),
    /// The software update's state (appended): running and DFU versions, the upload, the bootloader's state and
    /// the last outcome (`docs/update.md`), with every Housekeeping report.
    Update(crate::update::UpdateStatus),
}

/// The PPS discipline (`Pipeline::pps`): spacecraft time re-anchored on the whole second at each accepted edge.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
pub struct PpsReport {
    /// Edges that re-anchored the time.
    pub accepted: u32,
    /// Edges refused: before `SetTime` or before any frame, farther than the tolerance from a whole second, or
    /// sooner than half a second after the last accepted one.
    pub rejected: u32,
    /// Correction applied at the last accepted edge, µs (spacecraft time after minus before), saturated.
    pub last_correction_us: i32,
}

/// The angle and velocity increments of one output interval (`shared::nav`: coning and sculling corrected),
/// integrated at the frame rate from the fused rate and specific force. Fixed-point on the wire: ΔΘ in nanoradians,
/// ΔV in micrometres per second, both in the body frame (ΔV at the interval's start, as strapdown practice has it).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct NavReport {
    /// The `Fused` report of the same interval.
    pub seq: u32,
    /// Frame time at the interval's start, µs (the end of the previous interval).
    pub t_us: u64,
    /// Length of the interval, µs, from the frame clock (lost frames included).
    pub dt_us: u32,
    /// ΔΘ, nrad.
    pub dtheta_nrad: [i64; 3],
    /// ΔV (specific force integrated), µm/s.
    pub dv_umps: [i64; 3],
    /// Frames integrated, bridged ones included.
    pub frames: u16,
    /// Frames bridged: lost on the link, or without a valid fused sample (the last rate and force held).
    pub bridged: u16,
    /// Frames in which a sensor sat at an ADC rail.
    pub clipped: u16,
}

/// One instant on both time scales: the frame time of `Fused.t_us` and the spacecraft time `SetTime` gave (Unix
/// µs). The ground maps every report's `t_us` with the latest correlation (`ground decode`: column `unix_us`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct TimeReport {
    /// Frame time, µs (the scale of `FusedReport::t_us`).
    pub t_us: u64,
    /// Spacecraft time at that instant, µs since the Unix epoch.
    pub unix_us: u64,
}

/// Everything the ground can ask.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Command {
    /// Liveness check; answered by an ack.
    Ping,
    /// Set the FPGA decimation N (keep 1 data set of N + 1).
    SetDecimation(u16),
    /// Frames averaged per output (1 ..= 4096).
    SetOutputRate(u16),
    /// Fusion mode and fault exclusion.
    SetFusion {
        /// Averaging rule.
        mode: FusionMode,
        /// Fault exclusion on.
        robust: bool,
    },
    /// Start a calibration upload of `len` bytes (an encoded table) whose CRC-32C is `crc`.
    CalBegin {
        /// Total bytes.
        len: u16,
        /// CRC-32C of all bytes.
        crc: u32,
    },
    /// Bytes of the upload at `offset` (chunks in order).
    CalChunk {
        /// Offset of the first byte.
        offset: u16,
        /// The bytes.
        data: heapless::Vec<u8, CAL_CHUNK_MAX>,
    },
    /// Check, apply and persist the uploaded table.
    CalCommit,
    /// Send the Allan levels of `count` channels from `first`.
    AllanRequest {
        /// First channel.
        first: u8,
        /// Number of channels.
        count: u8,
    },
    /// Restart all Allan accumulators.
    AllanReset,
    /// Send a health report now; with `detail`, the per-group fault counters too.
    HealthRequest {
        /// Also send one [`FaultReport`] per group.
        detail: bool,
    },
    /// Stream or idle (appended): the FPGA is told to start or stop its frame stream.
    SetMode(Mode),
    /// Leave groups out of the fusion by hand (appended): bitmasks over groups (bit g = group g) for the gyros and
    /// the accelerometers; 0 puts every group back. Bits beyond the board's groups are refused (`BadArgument`).
    ExcludeGroups {
        /// Gyro groups left out.
        gyro: u32,
        /// Accelerometer groups left out.
        accel: u32,
    },
    /// Spacecraft time now, µs since the Unix epoch (appended): from then on a [`TimeReport`] correlates frame
    /// time with it.
    SetTime {
        /// The time.
        unix_us: u64,
    },
    /// Clear the reset history and the crash-loop counter (appended, version 4). `boot_count` must equal the
    /// [`ResetHistory::boot_count`] the ground last received (else `BadArgument`): records from a boot the ground
    /// has not seen are never cleared.
    ClearResets {
        /// The boot counter the ground saw.
        boot_count: u32,
    },
}

/// Operating mode (`SetMode`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Mode {
    /// Frames stream and are processed (the mode at boot).
    #[default]
    Stream,
    /// The FPGA's frame stream is stopped; housekeeping and commands go on.
    Idle,
}

/// A command with the tag its ack will carry.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct CommandEnvelope {
    /// Chosen by the ground, echoed in the ack.
    pub tag: u16,
    /// The command.
    pub cmd: Command,
}

/// Why bytes are not a message.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DecodeError {
    /// No bytes.
    Empty,
    /// Another protocol version (the one received).
    Version(u8),
    /// The body does not parse, or bytes are left over.
    Malformed,
}

/// Why a message could not be encoded.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BufferTooSmall;

/// Writes `[PROTOCOL_VERSION] ++ postcard(msg)` into `buf`; returns the used part.
pub fn encode<'a, T: Serialize>(msg: &T, buf: &'a mut [u8]) -> Result<&'a [u8], BufferTooSmall> {
    let (first, rest) = buf.split_first_mut().ok_or(BufferTooSmall)?;
    *first = PROTOCOL_VERSION;
    let n = postcard::to_slice(msg, rest)
        .map_err(|_| BufferTooSmall)?
        .len();
    // The version byte and n bytes of body: `..=n`.
    buf.get(..=n).ok_or(BufferTooSmall)
}

/// Reads a message written by [`encode`].
pub fn decode<T: DeserializeOwned>(bytes: &[u8]) -> Result<T, DecodeError> {
    let (&version, body) = bytes.split_first().ok_or(DecodeError::Empty)?;
    if version != PROTOCOL_VERSION {
        return Err(DecodeError::Version(version));
    }
    match postcard::take_from_bytes::<T>(body) {
        Ok((msg, [])) => Ok(msg),
        _ => Err(DecodeError::Malformed),
    }
}

/// The tag of a command that may not decode as a whole (for the rejection's ack); 0 when unreadable.
pub fn peek_tag(bytes: &[u8]) -> u16 {
    bytes
        .get(1..)
        .and_then(|b| postcard::take_from_bytes::<u16>(b).ok())
        .map_or(0, |(tag, _)| tag)
}

#[cfg(test)]
mod tests;
