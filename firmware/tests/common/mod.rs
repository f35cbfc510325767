//! The scenario harness: a simulated board around the firmware's own tasks (`firmware::sim`), in virtual time, and
//! a ground station on the bus that sends commands and decodes what comes back.
#![allow(
    dead_code,
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]
#![allow(clippy::arithmetic_side_effects)]

use core::future::Future;

use embassy_futures::select::{Either, select};
use embassy_time::Duration;
use firmware::app::{self, App, Platform};
use firmware::sim::clock::{self, Mode};
use firmware::sim::flash::{self as simflash, CalFlashModel, Stalling};
use firmware::sim::node::{self, Board};
use shared::bus::csp::{CspHeader, CspPacket};
use shared::bus::kiss::KissDecoder;
use shared::bus::{BusConfig, MAX_WIRE_FRAME};
use shared::calib::CalibrationTable;
use shared::crc::crc32c;
use shared::pipeline::{PipelineConfig, PipelineMemory};
use shared::storage::CalStore;
use shared::telemetry::{
    CAL_CHUNK_MAX, Command, CommandEnvelope, MAX_MESSAGE_LEN, Telemetry, decode, encode,
};
use shared::wire::frame::GROUPS;

/// The firmware's shared state on the host.
pub type HostApp = App<Box<PipelineMemory>>;

/// The simulated satellite: the tasks' state, the board's lines, the calibration flash.
pub struct Sat {
    pub app: HostApp,
    pub board: Board,
    /// The calibration flash, stalling the CPU as the F405's does.
    pub store: CalStore<Stalling<CalFlashModel>>,
    /// The update service's DFU slot and boot state (erased models unless a test puts its own).
    pub update: simflash::SimUpdater,
}

impl Sat {
    /// Boots on `flash` (loads the calibration as `main.rs` does), the bus transmitter at `bus_baud`.
    pub fn boot(flash: CalFlashModel, bus_baud: Option<u32>) -> Self {
        Self::boot_with(flash, bus_baud, PipelineConfig::DEFAULT)
    }

    /// As [`Self::boot`], with a pipeline configuration.
    pub fn boot_with(flash: CalFlashModel, bus_baud: Option<u32>, config: PipelineConfig) -> Self {
        Self::boot_on(flash, bus_baud, config, Platform::default())
    }

    /// As [`Self::boot_with`], on a board that offers `platform` (boot facts, cycle counter, MCU sensors).
    pub fn boot_on(
        flash: CalFlashModel,
        bus_baud: Option<u32>,
        config: PipelineConfig,
        platform: Platform,
    ) -> Self {
        let mut app = App::new(
            config,
            Box::new(PipelineMemory::new()),
            BusConfig::DEFAULT,
            platform,
        );
        let mut store = CalStore::new(Stalling(flash)).expect("flash geometry");
        // As `main.rs`: the boot counter for `ClearResets`, the calibration unless in safe mode.
        if platform.resets.is_some() {
            app.pipeline
                .get_mut()
                .set_boot_count(platform.boot.boot_count);
        }
        if !platform.boot.safe_mode {
            app::load_calibration(&mut store, app.pipeline.get_mut());
        }
        Self {
            app,
            board: Board::with_bus_baud(bus_baud),
            store,
            update: simflash::updater(firmware::update::UPDATE_PUBLIC_KEY, 0),
        }
    }

    /// A first boot: erased flash, bus at 115200 baud.
    pub fn fresh() -> Self {
        Self::boot(simflash::erased(), Some(firmware::layout::BUS_BAUD))
    }

    /// Runs the firmware's tasks and `body` together in virtual time until `body` ends (then the tasks are dropped:
    /// a power cut, as far as they can tell), on a thread with the MCU's stack (`clock::run_on_mcu_stack`). Panics
    /// if virtual time passes `limit`.
    pub fn run<T: Send>(
        &mut self,
        limit: Duration,
        body: impl AsyncFnOnce(&HostApp, &Board) -> T + Send,
    ) -> T {
        let Self {
            app,
            board,
            store,
            update,
        } = self;
        let (app, board) = (&*app, &*board);
        let run = move || select(node::tasks(app, board, store, update), body(app, board));
        match clock::run_on_mcu_stack(Mode::Virtual, limit, run) {
            Ok(Either::Second(v)) => v,
            Ok(Either::First(())) => panic!("the firmware's tasks ended"),
            Err(e) => panic!("scenario did not finish: {e:?}"),
        }
    }

    /// The flash as it is now (the store gives it back).
    pub fn into_flash(self) -> CalFlashModel {
        self.store.into_inner().0
    }
}

/// Runs `fut` to completion in virtual time (no firmware), e.g. to drive a future built elsewhere.
pub fn block_on<T>(fut: impl Future<Output = T>) -> T {
    clock::run(Mode::Virtual, Duration::from_secs(3600), fut).expect("finishes")
}

/// The ground station's side of the bus.
pub struct Ground {
    config: BusConfig,
    kiss: KissDecoder<{ shared::bus::MAX_FRAME }>,
    /// Telemetry received, in order.
    pub telemetry: Vec<Telemetry>,
    /// Ping replies received: (source address, payload).
    pub pings: Vec<(u16, Vec<u8>)>,
    /// Bus bytes received, all of them.
    pub bytes: Vec<u8>,
    /// Frames that did not parse (KISS, CSP or postcard).
    pub bad: usize,
}

impl Ground {
    pub fn new() -> Self {
        Self {
            config: BusConfig::DEFAULT,
            kiss: KissDecoder::new(),
            telemetry: Vec::new(),
            pings: Vec::new(),
            bytes: Vec::new(),
            bad: 0,
        }
    }

    fn header(&self, dport: u8) -> CspHeader {
        CspHeader {
            prio: 2,
            src: self.config.ground_addr,
            dst: self.config.addr,
            dport,
            sport: self.config.telemetry_port,
            flags: 0,
        }
    }

    /// A command as bus bytes (a CSP packet in a KISS frame).
    pub fn command_bytes(&self, tag: u16, cmd: Command) -> Vec<u8> {
        let mut buf = [0u8; MAX_MESSAGE_LEN];
        let payload = encode(&CommandEnvelope { tag, cmd }, &mut buf)
            .unwrap()
            .to_vec();
        self.packet(self.config.command_port, &payload)
    }

    /// Arbitrary payload bytes to `dport` as bus bytes.
    pub fn packet(&self, dport: u8, payload: &[u8]) -> Vec<u8> {
        let mut wire = [0u8; MAX_WIRE_FRAME];
        let n = CspPacket::emit_kiss(&self.header(dport), self.config.version, payload, &mut wire)
            .unwrap();
        wire[..n].to_vec()
    }

    /// Sends a command to the satellite's bus receiver.
    pub fn send(&self, board: &Board, tag: u16, cmd: Command) {
        assert_eq!(
            board.bus_rx.push(&self.command_bytes(tag, cmd)),
            0,
            "bus rx overflow"
        );
    }

    /// Sends a command and waits (polling the bus every 5 ms, as a ground station would) for its ack; returns it.
    pub async fn transact(
        &mut self,
        board: &Board,
        tag: u16,
        cmd: Command,
    ) -> shared::telemetry::Ack {
        let seen = self.acks().len();
        self.send(board, tag, cmd);
        loop {
            embassy_time::Timer::after(Duration::from_millis(5)).await;
            self.receive(board);
            if let Some(a) = self.acks().get(seen) {
                return *a;
            }
        }
    }

    /// Takes what the satellite sent since the last call and decodes it.
    pub fn receive(&mut self, board: &Board) -> usize {
        let bytes = board.bus_tx.take_all();
        self.take(&bytes)
    }

    /// Decodes `bytes` from the satellite (telemetry and ping replies; update replies are left to the uploader).
    pub fn take(&mut self, bytes: &[u8]) -> usize {
        self.bytes.extend_from_slice(bytes);
        let mut input = bytes;
        let before = self.telemetry.len() + self.pings.len();
        while let Some(frame) = self.kiss.decode(&mut input) {
            let Ok(frame) = frame else {
                self.bad += 1;
                continue;
            };
            match CspPacket::parse(frame, self.config.version) {
                Ok(p) if p.header.sport == shared::bus::csp::PORT_PING => {
                    self.pings.push((p.header.src, p.payload.to_vec()))
                }
                Ok(p) if p.header.sport == shared::update::PORT_UPDATE => {}
                Ok(p) if p.header.dport == self.config.telemetry_port => match decode(p.payload) {
                    Ok(t) => self.telemetry.push(t),
                    Err(_) => self.bad += 1,
                },
                Ok(_) => self.bad += 1,
                Err(_) => self.bad += 1,
            }
        }
        self.telemetry.len() + self.pings.len() - before
    }

    /// The acks received, as (tag, result).
    pub fn acks(&self) -> Vec<shared::telemetry::Ack> {
        self.telemetry
            .iter()
            .filter_map(|t| match t {
                Telemetry::Ack(a) => Some(*a),
                _ => None,
            })
            .collect()
    }
}

/// The commands of a calibration upload of `table` in chunks of `chunk` bytes, tags from `tag`.
pub fn upload_commands(
    table: &CalibrationTable<GROUPS>,
    chunk: usize,
    tag: u16,
) -> Vec<(u16, Command)> {
    let mut buf = [0u8; shared::calib::encoded_len_max(GROUPS)];
    let bytes = table.encode(&mut buf).unwrap();
    let mut cmds = vec![(
        tag,
        Command::CalBegin {
            len: bytes.len() as u16,
            crc: crc32c(bytes),
        },
    )];
    for (i, c) in bytes.chunks(chunk.clamp(1, CAL_CHUNK_MAX)).enumerate() {
        cmds.push((
            tag,
            Command::CalChunk {
                offset: (i * chunk.clamp(1, CAL_CHUNK_MAX)) as u16,
                data: heapless::Vec::from_slice(c).unwrap(),
            },
        ));
    }
    cmds.push((tag, Command::CalCommit));
    cmds
}

/// A table that differs from the factory default: id `cal_id`, one bias changed.
pub fn table(cal_id: u32) -> CalibrationTable<GROUPS> {
    let mut t = CalibrationTable::<GROUPS>::factory();
    t.cal_id = cal_id;
    t.groups[3].gyro_bias_q12[1] += 4096 * i32::try_from(cal_id % 50).unwrap();
    t
}

/// `n` frames of the nominal board at rest (the benchmark stream).
pub fn frames(n: usize) -> Vec<u8> {
    host_test::replay::synthetic_frames(n)
}

/// The FPGA playing `log` at the default decimation (N = 15) and base rate (`firmware::sim::node::fpga_play`).
pub async fn fpga_play(board: &firmware::sim::node::Board, log: &[u8]) {
    let rate = PipelineConfig::DEFAULT.fpga_base_rate_millihz;
    firmware::sim::node::fpga_play(board, log, 15, rate).await
}

/// The frame period at the default decimation (N = 15), µs (exactly 1653.439… µs; rounded).
pub fn frame_period() -> Duration {
    Duration::from_micros(shared::wire::FrameClock::ticks_to_us(
        16,
        PipelineConfig::DEFAULT.fpga_base_rate_millihz,
    ))
}

/// The Health reports among `t`, in order.
pub fn healths(t: &[Telemetry]) -> Vec<shared::telemetry::HealthReport> {
    t.iter()
        .filter_map(|t| match t {
            Telemetry::Health(h) => Some(*h),
            _ => None,
        })
        .collect()
}

/// The reset histories among `t`, in order.
pub fn reset_histories(t: &[Telemetry]) -> Vec<shared::telemetry::ResetHistory> {
    t.iter()
        .filter_map(|t| match t {
            Telemetry::Resets(h) => Some(*h),
            _ => None,
        })
        .collect()
}

/// The update service's reports among `t`, in order.
pub fn update_reports(t: &[Telemetry]) -> Vec<shared::update::UpdateStatus> {
    t.iter()
        .filter_map(|t| match t {
            Telemetry::Update(u) => Some(*u),
            _ => None,
        })
        .collect()
}

/// The Housekeeping reports among `t`, in order.
pub fn housekeeping(t: &[Telemetry]) -> Vec<shared::telemetry::HousekeepingReport> {
    t.iter()
        .filter_map(|t| match t {
            Telemetry::Housekeeping(h) => Some(*h),
            _ => None,
        })
        .collect()
}
