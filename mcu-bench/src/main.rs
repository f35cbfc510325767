//! Instruction counts of the flight core on an emulated Cortex-M4: `cd mcu-bench && cargo run --release` (needs
//! `qemu-system-arm`). QEMU's mps2-an386 runs the same `shared::Pipeline` as the firmware, built with the firmware's
//! profile, over the benchmark frame stream of the host (`shared::bench::BenchFrames`). Under `-icount shift=3` the
//! 25 MHz SysTick advances once per 5 instructions, so the counts are exact and repeatable. They are instructions,
//! not cycles: an STM32F405 at 168 MHz needs at least as many cycles (loads, multiplies, taken branches and flash
//! wait states cost more than one).
//!
//! The figures are also written, as JSON, to `target/mcu-bench.json` (relative to the directory `cargo run` is
//! started in, through semihosting's `SYS_OPEN`): `.ci/run` compares that file with the committed
//! `docs/mcu-bench.json`, which `host_test::tradeoff` reads for the MCU's duty cycle and power.
#![no_std]
#![no_main]

use core::fmt::Write as _;
use cortex_m::peripheral::SYST;
use cortex_m::peripheral::syst::SystClkSource;
use cortex_m_rt::entry;
use cortex_m_semihosting::{debug, hprintln, nr, syscall};
use shared::bench::BenchFrames;
use shared::calib::thermal::ThermalComp;
use shared::calib::{AXES, CalibrationTable, RawCounts};
use shared::fuse::{FusedSample, Fusion, FusionConfig, FusionMode};
use shared::nav::NavIntegrator;
use shared::pipeline::stages::{self, FrameHead};
use shared::pipeline::{Pipeline, PipelineConfig, PipelineMemory};
use shared::wire::FrameDecoder;
use shared::wire::frame::{FRAME_LEN, GROUPS};

/// Instructions per SysTick tick: `-icount shift=3` = 8 ns per instruction, SysTick at 25 MHz = 40 ns per tick.
const INSTRUCTIONS_PER_TICK: u64 = 5;
/// SysTick is a 24-bit down counter.
const SYST_MASK: u32 = 0x00FF_FFFF;
/// Frames per timed batch (one output interval of the default configuration).
const BATCH: usize = 32;
/// Frames before timing starts: the noise estimates settle after 1024 and the weights are then in use.
const WARMUP_FRAMES: usize = if cfg!(feature = "trace") { 64 } else { 2048 };
/// Timed batches per configuration.
const BATCHES: usize = if cfg!(feature = "trace") { 2 } else { 64 };
/// The flight MCU's core clock (STM32F405 at its maximum).
const MCU_HZ: f64 = 168e6;

#[entry]
fn main() -> ! {
    let Some(mut core) = cortex_m::Peripherals::take() else {
        exit(false);
    };
    core.SYST.set_clock_source(SystClkSource::Core);
    core.SYST.set_reload(SYST_MASK);
    core.SYST.clear_current();
    core.SYST.enable_counter();
    // The tick-to-instruction scale, checked on a million `nop`s (the loop around them adds ≈ 0.3 %).
    const NOPS: u64 = 1_000_000;
    let measured = ticks_between(|| {
        for _ in 0..NOPS / 1000 {
            // SAFETY: 1000 `nop`s: no memory, no registers, no flags.
            unsafe {
                core::arch::asm!(
                    ".rept 1000",
                    "nop",
                    ".endr",
                    options(nomem, nostack, preserves_flags)
                )
            };
        }
    }) * INSTRUCTIONS_PER_TICK;
    hprintln!(
        "scale check: {} nops counted as {} instructions",
        NOPS,
        measured
    );
    if measured.abs_diff(NOPS) > NOPS / 100 {
        hprintln!(
            "SysTick does not count {} instructions per tick: is -icount shift=3 set?",
            INSTRUCTIONS_PER_TICK
        );
        exit(false);
    }
    let Some(bank) = cortex_m::singleton!(: PipelineMemory = PipelineMemory::new()) else {
        exit(false);
    };
    let Some(json) = cortex_m::singleton!(: Json = Json::new()) else {
        exit(false);
    };
    // `format_args!` of constants only: a failed write (buffer full) is reported when the file is written.
    let _ = write!(
        json,
        "{{\"tool\": \"mcu-bench\", \"mcu_hz\": {:.0}, \"configs\": [",
        MCU_HZ
    );
    json.after_header = json.len;
    let paper = {
        let mut c = PipelineConfig::DEFAULT;
        c.fusion.mode = FusionMode::Equal;
        c.fusion.robust = false;
        c
    };
    for (name, config) in [
        ("default (weighted, robust)", PipelineConfig::DEFAULT),
        ("seed paper (equal mean, no exclusion)", paper),
    ] {
        count(name, config, None, Temperature::Steady, bank, json);
    }
    // A flight table: thermal terms on every channel and fixed weights. The board's sensor reads 0.01 °C and an
    // orbit changes it about once a second (one frame in ~600): "steady" is the usual frame; "new every frame" the
    // worst case, where every frame recomputes the 112 biases.
    let table = flight_table();
    for (name, temperature) in [
        (
            "thermal table + fixed weights, temperature steady",
            Temperature::Steady,
        ),
        (
            "thermal table + fixed weights, new temperature every frame",
            Temperature::EveryFrame,
        ),
    ] {
        count(
            name,
            PipelineConfig::DEFAULT,
            Some(&table),
            temperature,
            bank,
            json,
        );
    }
    stages(bank);
    let _ = writeln!(json, "]}}");
    if !json.write_file("target/mcu-bench.json\0") {
        hprintln!(
            "could not write target/mcu-bench.json (buffer full or semihosting refused the file)"
        );
        exit(false);
    }
    hprintln!("written: target/mcu-bench.json");
    exit(true)
}

/// How the frames' board temperature moves.
#[derive(Clone, Copy, PartialEq)]
enum Temperature {
    /// The bench stream's constant 20.00 °C.
    Steady,
    /// A new value (by 0.01 °C) every frame.
    EveryFrame,
}

/// A calibration table with thermal terms on every raw channel and fixed weights on every axis (values of an
/// LPY410AL/ADXL335-class board; the cost does not depend on them).
fn flight_table() -> CalibrationTable<GROUPS> {
    let mut t = CalibrationTable::<GROUPS>::factory();
    t.t_ref_cdeg = 2_000;
    for (g, (th, w)) in t.thermal.iter_mut().zip(&mut t.weights_q16).enumerate() {
        let g = g as i32;
        th.gyro_lin_q28 = [21_474_836 + g; 4]; // 0.08 counts per 0.01 °C
        th.gyro_quad_q40 = [1_099_511 - g; 4]; // 1e-6 counts per (0.01 °C)²
        th.accel_lin_q28 = [268_435 + g; 3];
        th.accel_quad_q40 = [10_995 + g; 3];
        *w = [40_000 + 1000 * g; AXES];
    }
    t
}

/// Runs `config` (with `table`, else the factory table) over the benchmark stream and reports instructions per
/// frame.
fn count(
    name: &str,
    config: PipelineConfig,
    table: Option<&CalibrationTable<GROUPS>>,
    temperature: Temperature,
    bank: &mut PipelineMemory,
    json: &mut Json,
) {
    // Each configuration starts from an empty bank (`Pipeline::new` takes it as it is).
    bank.allan.reset();
    let mut pipeline = Pipeline::new(config, &mut *bank);
    if let Some(table) = table {
        pipeline.load_calibration(table, shared::telemetry::CalSource::Uploaded);
    }
    let mut frames = BenchFrames::new();
    let mut temp_cdeg: i16 = 2_000;
    let mut batch = [0u8; FRAME_LEN * BATCH];
    let run = |pipeline: &mut Pipeline<&mut PipelineMemory>, batch: &[u8]| {
        let mut input = batch;
        while !input.is_empty() {
            pipeline.push_link(&mut input);
            while pipeline.poll().is_some() {}
        }
    };
    let mut fill = |batch: &mut [u8]| {
        for frame in batch.chunks_exact_mut(FRAME_LEN) {
            let mut f = frames.next_frame();
            if temperature == Temperature::EveryFrame {
                temp_cdeg = if temp_cdeg >= 4_000 { 0 } else { temp_cdeg + 1 };
                f.temp_cdeg = Some(temp_cdeg);
            }
            frame.copy_from_slice(&f.to_bytes());
        }
    };
    for _ in 0..WARMUP_FRAMES / BATCH {
        fill(&mut batch);
        run(&mut pipeline, &batch);
    }
    // What two SysTick reads cost, taken off every batch.
    let overhead = ticks_between(|| {});
    let (mut min, mut max, mut total) = (u64::MAX, 0, 0);
    for _ in 0..BATCHES {
        fill(&mut batch);
        let t = ticks_between(|| run(&mut pipeline, &batch)).saturating_sub(overhead);
        let per_frame = t * INSTRUCTIONS_PER_TICK / BATCH as u64;
        min = min.min(per_frame);
        max = max.max(per_frame);
        total += t * INSTRUCTIONS_PER_TICK;
    }
    let frames = (BATCHES * BATCH) as u64;
    let mean = total as f64 / frames as f64;
    let rate_hz = pipeline.tau0_ps().map_or(0.0, |ps| 1e12 / ps as f64);
    let counters = pipeline.link_counters();
    hprintln!(
        "{}: {:.0} instructions per frame (batches of {}: {} to {}), {} frames, {} CRC errors; at {:.1} frames/s \
         {:.2} M instructions/s = {:.1} % of {:.0} MHz at one instruction per cycle",
        name,
        mean,
        BATCH,
        min,
        max,
        frames,
        counters.crc_errors,
        rate_hz,
        mean * rate_hz / 1e6,
        100.0 * mean * rate_hz / MCU_HZ,
        MCU_HZ / 1e6
    );
    let _ = write!(
        json,
        "{}{{\"name\": \"{}\", \"instructions_per_frame\": {:.1}, \"batch_min\": {}, \"batch_max\": {}, \
         \"frames\": {}, \"frame_rate_hz\": {:.3}}}",
        if json.len == json.after_header {
            ""
        } else {
            ", "
        },
        name,
        mean,
        min,
        max,
        frames,
        rate_hz
    );
    // Every frame must have gone through: a count over rejected frames would be a count of the wrong work.
    if counters.crc_errors != 0
        || u64::from(counters.frames) != (WARMUP_FRAMES + BATCHES * BATCH) as u64
    {
        hprintln!("frames lost on the link: the counts above are void");
        exit(false);
    }
}

/// The stages of a frame's path (`shared::pipeline::stages`, the functions `Pipeline` calls) run one at a time
/// over the same stream (default fusion), so that each has its own count: link decoding with the CRC and the ADC
/// codes to signed counts, the 16 groups' calibration, the fusion, the 102 Allan channels, the navigation
/// increments. Their sum is below the pipeline's by what `Pipeline` adds (time, output averaging, health,
/// bookkeeping).
fn stages(bank: &mut PipelineMemory) {
    const NAMES: [&str; 5] = [
        "decode + CRC + ADC codes to signed counts",
        "calibration (16 groups)",
        "fusion",
        "Allan (102 channels)",
        "navigation increments (f32, coning + sculling)",
    ];
    let mut nav = NavIntegrator::new();
    let mut nav_frames = 0usize;
    let cal = CalibrationTable::<GROUPS>::factory();
    let mut thermal = ThermalComp::<GROUPS>::new();
    thermal.load(&cal);
    let mut decoder = FrameDecoder::new();
    let mut fusion = Fusion::<GROUPS>::new(FusionConfig::DEFAULT);
    bank.allan.reset();
    let mut frames = BenchFrames::new();
    let mut bytes = [0u8; FRAME_LEN * BATCH];
    let mut heads = [FrameHead::default(); BATCH];
    let mut raw = [[RawCounts::default(); GROUPS]; BATCH];
    let mut axes = [[[0i32; AXES]; GROUPS]; BATCH];
    let mut fused = [FusedSample::default(); BATCH];
    let mut hold = [0i32; AXES];
    let dt_s = stages::frame_dt_s(15, shared::wire::clock::FPGA_BASE_RATE_MILLIHZ);
    let overhead = ticks_between(|| {});
    let mut totals = [0u64; NAMES.len()];
    for batch in 0..WARMUP_FRAMES / BATCH + BATCHES {
        for frame in bytes.chunks_exact_mut(FRAME_LEN) {
            frame.copy_from_slice(&frames.next_bytes());
        }
        let ticks = [
            ticks_between(|| {
                let mut input = &bytes[..];
                for (h, r) in heads.iter_mut().zip(&mut raw) {
                    if let Some((head, gap)) = stages::decode(&mut decoder, &mut input, r) {
                        *h = head;
                        core::hint::black_box(gap);
                    }
                }
            }),
            ticks_between(|| {
                for ((h, r), a) in heads.iter().zip(&raw).zip(&mut axes) {
                    stages::calibrate(&mut thermal, &cal, h.temp_cdeg, r, a);
                }
            }),
            ticks_between(|| {
                for ((f, r), a) in fused.iter_mut().zip(&raw).zip(&axes) {
                    fusion.fuse_into(r, a, &cal, f);
                }
            }),
            ticks_between(|| {
                for (a, f) in axes.iter().zip(&fused) {
                    stages::hold_valid(&mut hold, f);
                    core::hint::black_box(bank.allan.push_parts(a.as_flattened(), &hold));
                }
            }),
            ticks_between(|| {
                // As `Pipeline` does: one frame period, an interval taken every 32 frames.
                for f in &fused {
                    stages::nav_add(&mut nav, f, dt_s);
                    nav_frames += 1;
                    if nav_frames.is_multiple_of(32) {
                        core::hint::black_box(nav.take());
                    }
                }
            }),
        ];
        if batch >= WARMUP_FRAMES / BATCH {
            for (total, t) in totals.iter_mut().zip(ticks) {
                *total += t.saturating_sub(overhead) * INSTRUCTIONS_PER_TICK;
            }
        }
    }
    let frames = (BATCHES * BATCH) as u64;
    for (name, total) in NAMES.iter().zip(totals) {
        hprintln!("  {}: {} instructions per frame", name, total / frames);
    }
}

/// The JSON report, built in a fixed buffer (no heap) and written to a host file at the end.
struct Json {
    buf: [u8; 2048],
    len: usize,
    /// `len` after the header: the first configuration has no leading comma.
    after_header: usize,
    /// A write did not fit.
    overflow: bool,
}

impl Json {
    const fn new() -> Self {
        Json {
            buf: [0; 2048],
            len: 0,
            after_header: 0,
            overflow: false,
        }
    }

    /// Writes the buffer to the host file `path` (NUL-terminated); `false` if it overflowed or the host refused.
    fn write_file(&self, path: &str) -> bool {
        let Some(text) = self.buf.get(..self.len) else {
            return false;
        };
        if self.overflow || !path.ends_with('\0') {
            return false;
        }
        // SAFETY: semihosting SYS_OPEN/WRITE/CLOSE with a NUL-terminated name and a buffer that outlive the calls;
        // the host only reads them.
        unsafe {
            let fd = syscall!(OPEN, path.as_ptr(), nr::open::W_TRUNC, path.len() - 1) as isize;
            if fd < 0 {
                return false;
            }
            let left = syscall!(WRITE, fd as usize, text.as_ptr(), text.len());
            let closed = syscall!(CLOSE, fd as usize);
            left == 0 && closed == 0
        }
    }
}

impl core::fmt::Write for Json {
    fn write_str(&mut self, s: &str) -> core::fmt::Result {
        let end = self.len + s.len();
        match self.buf.get_mut(self.len..end) {
            Some(dst) => {
                dst.copy_from_slice(s.as_bytes());
                self.len = end;
                Ok(())
            }
            None => {
                self.overflow = true;
                Err(core::fmt::Error)
            }
        }
    }
}

/// SysTick ticks taken by `f` (less than one wrap of the 24-bit counter: 83 M instructions).
fn ticks_between(f: impl FnOnce()) -> u64 {
    let start = SYST::get_current();
    f();
    let end = SYST::get_current();
    u64::from(start.wrapping_sub(end) & SYST_MASK)
}

fn exit(ok: bool) -> ! {
    debug::exit(if ok {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo) -> ! {
    hprintln!("panic: {}", info);
    exit(false)
}
