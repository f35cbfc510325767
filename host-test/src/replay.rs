//! Replay: a frame log through `shared::Pipeline` on the host, producing the telemetry stream the MCU would send,
//! optionally checked against an independent f64 model of the same calibration and fusion.
//!
//! The f64 check recomputes every frame's fused value from the raw codes: calibration with the table's
//! coefficients as exact reals (`m / 2¹²`), then the mean over the groups the core used for that axis, with its
//! weights (equal until its noise estimates settle, then the Q16 inverse-variance weights). It measures the
//! arithmetic — fixed-point calibration, rounding, integer means and output averaging — not the choice of sensors,
//! which the core reports per axis (`FusedSample::used_mask`).

use crate::formats::framelog::FrameLog;
use shared::bus::{BusConfig, BusNode, MAX_WIRE_FRAME};
use shared::calib::{AXES, CalibrationTable, FRAC_BITS, GroupCal, GroupThermal, RawCounts};
use shared::fuse::FusionMode;
use shared::pipeline::{ALLAN_CHANNELS, Output, Pipeline, PipelineConfig, PipelineMemory};
use shared::telemetry::{Command, CommandEnvelope, Telemetry, encode};
use shared::wire::frame::GROUPS;
use shared::wire::{FpgaControl, LinkCounters};

/// The host's pipeline.
pub type HostPipeline = Pipeline<Box<PipelineMemory>>;

/// A host pipeline with `config` and `cal`: the factory table as the MCU boots with it (source `Factory`), any
/// other as an upload (`Uploaded`), so that Health says what the MCU's would.
pub fn host_pipeline(config: PipelineConfig, cal: CalibrationTable<GROUPS>) -> HostPipeline {
    let mut p = Pipeline::new(config, Box::new(PipelineMemory::new()));
    if cal != CalibrationTable::factory() {
        p.load_calibration(&cal, shared::telemetry::CalSource::Uploaded);
    }
    p
}

/// `n` frames of the nominal board at rest (1 g along z) with ±20 counts of uniform noise on every channel, from a
/// fixed xorshift generator (`shared::bench::BenchFrames`): the stream the throughput benchmark, the profiling example
/// and the Cortex-M4 instruction counts (`mcu-bench/`) feed to the core.
pub fn synthetic_frames(n: usize) -> Vec<u8> {
    let mut frames = shared::bench::BenchFrames::new();
    (0..n).flat_map(|_| frames.next_bytes()).collect()
}

/// Replay parameters.
#[derive(Clone, Debug)]
pub struct ReplayOptions {
    /// Pipeline parameters.
    pub config: PipelineConfig,
    /// Calibration applied.
    pub cal: CalibrationTable<GROUPS>,
    /// Addresses of the telemetry packets.
    pub bus: BusConfig,
    /// At the end, ask for all Allan channels and a detailed health report, as the ground would.
    pub final_dump: bool,
    /// Run the f64 check.
    pub check: bool,
}

/// Largest differences between the core and the f64 model, in output LSB (µ°/s, µg), per axis.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CheckReport {
    /// Per frame: fused value.
    pub frame_max_lsb: [f64; AXES],
    /// Per output report: the averaged value.
    pub report_max_lsb: [f64; AXES],
    /// Frames compared.
    pub frames: u64,
    /// Reports compared.
    pub reports: u64,
}

/// What a replay produced.
#[derive(Clone, Debug, Default)]
pub struct ReplayOutput {
    /// The bus byte stream (KISS frames) the MCU would have sent.
    pub telemetry: Vec<u8>,
    /// Messages in it.
    pub messages: Vec<Telemetry>,
    /// FPGA control messages the pipeline asked for.
    pub fpga: Vec<FpgaControl>,
    /// Link statistics.
    pub counters: LinkCounters,
    /// The f64 check, when asked for.
    pub check: Option<CheckReport>,
}

/// `M · (raw − b)` with the table's coefficients as exact reals.
pub fn calibrate_f64(cal: &GroupCal, raw: &RawCounts) -> [f64; AXES] {
    calibrate_f64_at(cal, &GroupThermal::ZERO, 0.0, raw)
}

/// `M · (raw − b(ΔT))`, `b(ΔT) = b + lin·ΔT + quad·ΔT²` (ΔT in 0.01 °C from the table's reference), with the
/// table's coefficients as exact reals: the model of the core's thermal compensation.
pub fn calibrate_f64_at(
    cal: &GroupCal,
    thermal: &GroupThermal,
    dt_cdeg: f64,
    raw: &RawCounts,
) -> [f64; AXES] {
    let s = f64::from(1u32 << FRAC_BITS);
    let bias = |b: i32, lin: i32, quad: i32| {
        f64::from(b) / s
            + f64::from(lin) / 2f64.powi(28) * dt_cdeg
            + f64::from(quad) / 2f64.powi(40) * dt_cdeg * dt_cdeg
    };
    let gb: Vec<f64> = (0..4)
        .map(|j| {
            bias(
                cal.gyro_bias_q12[j],
                thermal.gyro_lin_q28[j],
                thermal.gyro_quad_q40[j],
            )
        })
        .collect();
    let ab: Vec<f64> = (0..3)
        .map(|j| {
            bias(
                cal.accel_bias_q12[j],
                thermal.accel_lin_q28[j],
                thermal.accel_quad_q40[j],
            )
        })
        .collect();
    let row = |m: &[i32], b: &[f64], r: &[i32]| -> f64 {
        m.iter()
            .zip(b)
            .zip(r)
            .map(|((&m, &b), &r)| f64::from(m) / s * (f64::from(r) - b))
            .sum()
    };
    let mut out = [0.0; AXES];
    for i in 0..3 {
        out[i] = row(&cal.gyro_matrix_q12[i], &gb, &raw.gyro);
        out[3 + i] = row(&cal.accel_matrix_q12[i], &ab, &raw.accel);
    }
    out
}

/// The flight core on the host, driven as the MCU drives it: bytes from the FPGA link in, every output polled after
/// each push, telemetry encoded for the bus (postcard, CSP, KISS) as the MCU's link task sends it. `replay` and the
/// demo both run the core through it.
pub struct HostCore {
    /// The core.
    pub pipeline: HostPipeline,
    node: BusNode,
    keep_messages: bool,
    out: ReplayOutput,
    wire: Vec<u8>,
}

impl HostCore {
    /// A core with `config` and `cal` (see [`host_pipeline`]) sending on `bus`; `keep_messages`: also keep every
    /// message sent (not only its bus bytes).
    pub fn new(
        config: PipelineConfig,
        cal: CalibrationTable<GROUPS>,
        bus: BusConfig,
        keep_messages: bool,
    ) -> Self {
        Self {
            pipeline: host_pipeline(config, cal),
            node: BusNode::new(bus),
            keep_messages,
            out: ReplayOutput::default(),
            wire: vec![0; MAX_WIRE_FRAME],
        }
    }

    /// Room for `bytes` more bytes of telemetry.
    pub fn reserve(&mut self, bytes: usize) {
        self.out.telemetry.reserve(bytes);
    }

    /// Feeds link bytes through the core, taking its outputs after each frame's worth; consumes all of `input`.
    pub fn push(&mut self, mut input: &[u8]) {
        while !input.is_empty() {
            self.push_some(&mut input);
        }
    }

    /// One `push_link` of the core (it takes what it can from `input`), then its outputs.
    pub fn push_some(&mut self, input: &mut &[u8]) {
        self.pipeline.push_link(input);
        self.poll();
    }

    /// Takes every output the core has queued.
    pub fn poll(&mut self) {
        while let Some(o) = self.pipeline.poll() {
            self.take(o);
        }
    }

    /// Sends `cmd` (tag `tag`) to the core as the ground would, then takes its outputs and any dump it starts.
    pub fn command(&mut self, tag: u16, cmd: Command) {
        let mut buf = [0u8; 64];
        if let Ok(msg) = encode(&CommandEnvelope { tag, cmd }, &mut buf) {
            for o in self.pipeline.handle_command(msg) {
                self.take(o);
            }
        }
        self.poll();
        while let Some(t) = self.pipeline.poll_dump() {
            self.telemetry(t);
        }
    }

    /// What was sent, with the link counters.
    pub fn finish(mut self) -> ReplayOutput {
        self.out.counters = *self.pipeline.link_counters();
        self.out
    }

    /// Takes one output of the core.
    pub fn take(&mut self, o: Output) {
        match o {
            Output::Telemetry(t) => self.telemetry(t),
            Output::Fpga(c) => self.out.fpga.push(c),
            // The host sends no uploads, so none is ever committed.
            Output::PersistCalibration { .. } => {}
            // The host keeps no reset history.
            Output::ClearResets => {}
        }
    }

    fn telemetry(&mut self, t: Telemetry) {
        if let Ok(n) = self.node.encode_message(&t, &mut self.wire)
            && let Some(bytes) = self.wire.get(..n)
        {
            self.out.telemetry.extend_from_slice(bytes);
        }
        if self.keep_messages {
            self.out.messages.push(t);
        }
    }
}

/// Replays a frame log (bytes as recorded). `progress` is called with the number of bytes consumed so far.
pub fn replay(bytes: &[u8], opts: &ReplayOptions, mut progress: impl FnMut(usize)) -> ReplayOutput {
    let mut core = HostCore::new(opts.config, opts.cal, opts.bus, true);
    let mut check = CheckReport::default();
    if opts.check {
        // Frame by frame, so that each frame's fused sample can be compared.
        let log = FrameLog::decode(bytes);
        let mut block: Vec<[f64; AXES]> = Vec::new();
        // The model's own temperature rule: the frame's when valid, else the last valid one, else the reference.
        let mut last_temp: Option<i16> = None;
        for (i, d) in log.frames.iter().enumerate() {
            let frame = d.frame.to_bytes();
            let mut input = &frame[..];
            core.pipeline.push_link(&mut input);
            last_temp = d.frame.temp_cdeg.or(last_temp);
            let dt_cdeg = last_temp.map_or(0.0, |t| f64::from(t) - f64::from(opts.cal.t_ref_cdeg));
            let reference = reference_fused(&core.pipeline, &d.frame.raw, &opts.cal, dt_cdeg);
            let fused = *core.pipeline.last_fused();
            for (a, r) in reference.iter().enumerate() {
                if fused.used[a] > 0 {
                    let e = (f64::from(fused.axes[a]) - r).abs();
                    check.frame_max_lsb[a] = check.frame_max_lsb[a].max(e);
                }
            }
            check.frames += 1;
            // The output mean covers the frames where the axis was valid.
            block.push(std::array::from_fn(|a| {
                if fused.used[a] > 0 {
                    reference[a]
                } else {
                    f64::NAN
                }
            }));
            while let Some(o) = core.pipeline.poll() {
                if let Output::Telemetry(Telemetry::Fused(r)) = &o {
                    let values = r.axes();
                    for a in 0..AXES {
                        let v: Vec<f64> =
                            block.iter().map(|b| b[a]).filter(|x| !x.is_nan()).collect();
                        if !v.is_empty() {
                            let mean = v.iter().sum::<f64>() / v.len() as f64;
                            let e = (f64::from(values[a]) - mean).abs();
                            check.report_max_lsb[a] = check.report_max_lsb[a].max(e);
                        }
                    }
                    check.reports += 1;
                    block.clear();
                }
                core.take(o);
            }
            if i % 4096 == 0 {
                progress(i * shared::wire::frame::FRAME_LEN);
            }
        }
    } else {
        let mut input = bytes;
        let mut last_report = 0;
        while !input.is_empty() {
            core.push_some(&mut input);
            let done = bytes.len() - input.len();
            if done - last_report >= 1 << 20 {
                progress(done);
                last_report = done;
            }
        }
    }
    if opts.final_dump {
        core.command(
            1,
            Command::AllanRequest {
                first: 0,
                count: ALLAN_CHANNELS as u8,
            },
        );
        core.command(2, Command::HealthRequest { detail: true });
    }
    progress(bytes.len());
    let mut out = core.finish();
    if opts.check {
        out.check = Some(check);
    }
    out
}

/// The f64 model's fused value of the frame just processed by `p` (see module docs).
fn reference_fused(
    p: &HostPipeline,
    raw: &shared::wire::RawSample,
    cal: &CalibrationTable<GROUPS>,
    dt_cdeg: f64,
) -> [f64; AXES] {
    let fused = p.last_fused();
    let calibrated: Vec<[f64; AXES]> = raw
        .iter()
        .zip(cal.groups.iter().zip(&cal.thermal))
        .map(|(codes, (g, th))| calibrate_f64_at(g, th, dt_cdeg, &RawCounts::from_adc(codes)))
        .collect();
    let mode = p.fusion().config().mode;
    std::array::from_fn(|a| {
        let used: Vec<usize> = (0..GROUPS)
            .filter(|g| fused.used_mask[a] & (1 << g) != 0)
            .collect();
        let settled = used.iter().all(|&g| p.fusion().noise_var(g, a).is_some());
        // Fixed: the table's weights over the sensors used, if they sum to a positive value.
        let fixed_sum: f64 = used.iter().map(|&g| f64::from(cal.weights_q16[g][a])).sum();
        let w = |g: usize| match mode {
            FusionMode::Fixed if fixed_sum > 0.0 => f64::from(cal.weights_q16[g][a]),
            FusionMode::InverseVariance if settled => {
                f64::from(p.fusion().weight_q16(g, a).unwrap_or(0))
            }
            _ => 1.0,
        };
        let den: f64 = used.iter().map(|&g| w(g)).sum();
        if den == 0.0 {
            return f64::NAN;
        }
        used.iter().map(|&g| w(g) * calibrated[g][a]).sum::<f64>() / den
    })
}
