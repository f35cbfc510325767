//! Golden output tests: a long deterministic, noisy frame stream with faults, lost and damaged frames, mode
//! switches and commands goes through the pipeline.
//!
//! - **The snapshot** (`outputs_match_the_snapshot`, navigation on): every message the core sends, decoded from its
//!   postcard bytes, as JSON lines in `golden/default.jsonl`. A change shows as the first line that differs; a
//!   deliberate one is accepted with `UPDATE_GOLDEN=1` and reviewed as a diff of what the MCU says.
//! - **The hashes** (`outputs_are_bit_exact`, two configurations, navigation off): everything the pipeline says,
//!   hashed — every queued output, every dump report, `last_fused()` after every frame and, at checkpoints, the
//!   fusion's noise estimates, weights and fault counters, each as its postcard encoding — so that the internal
//!   state the messages only sample is guarded bit for bit too. Optimisations must leave both unchanged; the
//!   hashes' history (which deliberate changes moved them, and how they were checked) is in `docs/performance.md`.
//!
//! The stream uses integer noise and only exact f64 arithmetic (`board::nominal_codes`, `round`), so it is the same
//! on every platform.

use rand_xoshiro::SplitMix64;
use rand_xoshiro::rand_core::{Rng as _, SeedableRng};
use serde::Serialize;
use shared::calib::{AXES, CalibrationTable, GroupCal, board};
use shared::fuse::{FusedSample, FusionConfig, FusionMode};
use shared::pipeline::{ALLAN_CHANNELS, Output, Pipeline, PipelineConfig, PipelineMemory};
use shared::telemetry::{CalSource, Command, CommandEnvelope, Telemetry, encode};
use shared::wire::FrameRepr;
use shared::wire::frame::{
    FRAME_LEN, GROUPS, RAW_ACCEL_X, RAW_ACCEL_Z, RAW_GYRO_A_X, RAW_GYRO_A_Z, RAW_GYRO_B_Y,
    RAW_PER_GROUP,
};

type HostPipeline = Pipeline<Box<PipelineMemory>>;
type Rng = SplitMix64;

/// FNV-1a, 64 bit: a hash whose value is fixed by its definition (unlike `DefaultHasher`).
struct Fnv(u64);

impl Fnv {
    fn new() -> Self {
        Self(0xcbf2_9ce4_8422_2325)
    }

    fn bytes(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.0 ^= u64::from(b);
            self.0 = self.0.wrapping_mul(0x0000_0100_0000_01b3);
        }
    }

    /// The postcard encoding of `v`.
    fn ser<T: Serialize>(&mut self, v: &T) {
        let mut buf = [0u8; 1024];
        let bytes = postcard::to_slice(v, &mut buf).unwrap();
        self.bytes(bytes);
    }

    fn output(&mut self, o: &Output) {
        match o {
            Output::Telemetry(t) => {
                self.bytes(&[0]);
                self.ser(t);
            }
            Output::Fpga(c) => {
                self.bytes(&[1]);
                self.bytes(&c.to_bytes());
            }
            Output::PersistCalibration { tag } => {
                self.bytes(&[2]);
                self.bytes(&tag.to_le_bytes());
            }
            Output::ClearResets => self.bytes(&[3]),
        }
    }

    fn fused(&mut self, f: &FusedSample) {
        self.ser(&f.axes);
        self.ser(&f.used);
        self.ser(&f.used_mask);
        self.ser(&f.health);
    }
}

/// Triangle wave in [-1, 1] with the given period (frames), exact in f64.
fn tri(i: usize, period: usize) -> f64 {
    let p = (i % period) as f64 / period as f64;
    if p < 0.5 {
        4.0 * p - 1.0
    } else {
        3.0 - 4.0 * p
    }
}

/// Integer noise, roughly normal: sum of four uniforms on −20 … 20, times `gain`.
fn noise(rng: &mut Rng, gain: u64) -> f64 {
    let s: i64 = (0..4).map(|_| (rng.next_u64() % 41) as i64 - 20).sum();
    (s * gain as i64) as f64 / 2.0
}

/// The raw codes of frame `i`, faults included.
fn frame(i: usize, seq: u16, decimation: u16, rng: &mut Rng) -> FrameRepr {
    // Slow manoeuvres, and a fast swing between frames 13 000 and 13 600.
    let mut rate = [
        20.0 * tri(i, 3_001),
        5.0 * tri(i + 700, 1_709),
        -3.0 + 2.0 * tri(i, 997),
    ];
    if (13_000..13_600).contains(&i) {
        rate[0] += 200.0 * tri(i, 150);
    }
    let accel = [
        0.2 * tri(i, 2_503),
        -0.1 * tri(i + 100, 4_001),
        -1.0 + 0.05 * tri(i, 811),
    ];
    let codes = board::nominal_codes(rate, accel);
    let mut raw = [[0u16; RAW_PER_GROUP]; GROUPS];
    for (g, group) in raw.iter_mut().enumerate() {
        // Group 5 is 4× noisier, group 13 2× quieter.
        let gain = match g {
            5 => 8,
            13 => 1,
            _ => 2,
        };
        for (c, &x) in group.iter_mut().zip(&codes) {
            *c = (x + noise(rng, gain)).round().clamp(0.0, 65_535.0) as u16;
        }
    }
    // Stuck: group 3's gyro A z repeats one code.
    if (2_000..6_000).contains(&i) || (15_000..16_500).contains(&i) {
        raw[3][RAW_GYRO_A_Z] = 19_700;
    }
    // Saturated: group 7's accelerometer x at the upper rail; group 9's gyro B y at 0 on every third frame.
    if (4_000..8_000).contains(&i) {
        raw[7][RAW_ACCEL_X] = u16::MAX;
    }
    if (12_000..12_300).contains(&i) && i.is_multiple_of(3) {
        raw[9][RAW_GYRO_B_Y] = 0;
    }
    // Outliers: group 11's gyro x biased by 400 counts (≈ 17σ), group 2's accelerometer z by 600 counts.
    if (6_000..20_000).contains(&i) {
        raw[11][RAW_GYRO_A_X] = raw[11][RAW_GYRO_A_X].saturating_add(400);
    }
    if (9_000..18_000).contains(&i) {
        raw[2][RAW_ACCEL_Z] = raw[2][RAW_ACCEL_Z].saturating_add(600);
    }
    // Every accelerometer saturated (axis invalid), then all but two (too few for outlier tests).
    if (12_400..12_450).contains(&i) {
        raw.iter_mut().for_each(|g| g[RAW_ACCEL_Z] = 0);
    }
    if (12_450..12_500).contains(&i) {
        raw.iter_mut().skip(2).for_each(|g| g[RAW_ACCEL_Z] = 0);
    }
    // Only three gyros left (odd count of 3), then four (even).
    if (14_000..14_040).contains(&i) {
        raw.iter_mut()
            .skip(3)
            .for_each(|g| g[RAW_GYRO_A_X] = u16::MAX);
    }
    if (14_040..14_080).contains(&i) {
        raw.iter_mut()
            .skip(4)
            .for_each(|g| g[RAW_GYRO_A_X] = u16::MAX);
    }
    FrameRepr {
        seq,
        decimation,
        temp_cdeg: (!i.is_multiple_of(500)).then_some(2_000 + (i % 97) as i16),
        raw,
    }
}

/// A calibration with cross-couplings, scale errors and bias offsets that differ per group.
fn calibration(seed: u64) -> CalibrationTable<GROUPS> {
    let mut rng = Rng::seed_from_u64(seed);
    let mut t = CalibrationTable::<GROUPS>::factory();
    t.cal_id = seed as u32;
    let mut jitter = |x: i32, spread: u64| {
        x + ((rng.next_u64() % (2 * spread + 1)) as i64 - spread as i64) as i32
    };
    for g in t.groups.iter_mut() {
        let GroupCal {
            gyro_matrix_q12,
            gyro_bias_q12,
            accel_matrix_q12,
            accel_bias_q12,
        } = g;
        gyro_matrix_q12
            .as_flattened_mut()
            .iter_mut()
            .for_each(|m| *m = jitter(*m, 200_000));
        accel_matrix_q12
            .as_flattened_mut()
            .iter_mut()
            .for_each(|m| *m = jitter(*m, 9_000));
        gyro_bias_q12
            .iter_mut()
            .chain(accel_bias_q12.iter_mut())
            .for_each(|b| *b = jitter(*b, 40 << 12));
    }
    t
}

/// How often each situation the test is meant to cover occurred (asserted non-zero).
#[derive(Debug, Default)]
struct Seen {
    stuck: u32,
    saturated: u32,
    outlier_gyro: u32,
    outlier_accel: u32,
    invalid: u32,
    few: u32,
    unequal_weights: u32,
    allan_reports: u32,
    fault_reports: u32,
    health_reports: u32,
    fused_reports: u32,
}

impl Seen {
    /// Counts the situations `last` shows.
    fn note(&mut self, last: &FusedSample) {
        let (hg, ha) = (last.health.gyro, last.health.accel);
        self.stuck += u32::from(hg.stuck != 0);
        self.saturated += u32::from(ha.saturated != 0);
        self.outlier_gyro += u32::from(hg.outlier != 0);
        self.outlier_accel += u32::from(ha.outlier != 0);
        self.invalid += u32::from(!last.valid());
        self.few += u32::from(last.used.iter().any(|&u| (1..=4).contains(&u)));
    }

    /// Every situation occurred at least once.
    fn assert_all(&self) {
        let Seen {
            stuck,
            saturated,
            outlier_gyro,
            outlier_accel,
            invalid,
            few,
            unequal_weights,
            allan_reports,
            fault_reports,
            health_reports,
            fused_reports,
        } = *self;
        for (what, count) in [
            ("stuck", stuck),
            ("saturated", saturated),
            ("gyro outlier", outlier_gyro),
            ("accel outlier", outlier_accel),
            ("invalid", invalid),
            ("few sensors", few),
            ("unequal weights", unequal_weights),
            ("Allan reports", allan_reports),
            ("fault reports", fault_reports),
            ("health reports", health_reports),
            ("fused reports", fused_reports),
        ] {
            assert!(count > 0, "the stream never had: {what}");
        }
    }
}

struct Run {
    p: HostPipeline,
    h: Fnv,
    seen: Seen,
    /// The frame being pushed (its index in the stream).
    frame: usize,
    /// Every output and dump as a JSON line (`snapshot`), decoded from its postcard bytes.
    lines: Vec<String>,
}

impl Run {
    /// One JSON line: the frame index, where it came from and what it said (`body`, JSON).
    fn line(&mut self, source: &str, body: &str) {
        self.lines
            .push(format!("{{\"frame\":{},\"{source}\":{body}}}", self.frame));
    }

    /// `t` as the ground decodes it: its postcard bytes, parsed back (the wire's `parse` mirrors `emit`).
    fn telemetry_line(&mut self, source: &str, t: &Telemetry) {
        let mut buf = [0u8; 1024];
        let bytes = postcard::to_slice(t, &mut buf).unwrap();
        let back: Telemetry = postcard::from_bytes(bytes).unwrap();
        assert_eq!(&back, t, "postcard round trip");
        // `to_string`, not a `Value`: the Allan sums are 128-bit integers.
        self.line(source, &serde_json::to_string(&back).unwrap());
    }

    fn drain(&mut self) {
        while let Some(o) = self.p.poll() {
            self.record(o);
        }
    }

    /// One output, from the outbox or a command's replies.
    fn record(&mut self, o: Output) {
        self.h.output(&o);
        match &o {
            Output::Telemetry(t) => {
                self.telemetry_line("out", t);
                match t {
                    Telemetry::Health(_) => self.seen.health_reports += 1,
                    Telemetry::Fused(_) => self.seen.fused_reports += 1,
                    _ => {}
                }
            }
            Output::Fpga(c) => self.line("fpga", &format!("\"{c:?}\"")),
            Output::PersistCalibration { tag } => {
                self.line("persist", &format!("{{\"tag\":{tag}}}"));
            }
            Output::ClearResets => self.line("clear_resets", "{}"),
        }
    }

    fn drain_dumps(&mut self) {
        while let Some(t) = self.p.poll_dump() {
            self.h.bytes(&[3]);
            self.h.ser(&t);
            // The snapshot keeps the Allan reports of every 16th channel and of the six fused axes (the hash has
            // them all): 102 channels' worth would be three quarters of the file.
            let keep = match &t {
                Telemetry::Allan(a) => {
                    let c = usize::from(a.channel);
                    c % 16 == 0 || c >= ALLAN_CHANNELS - AXES
                }
                _ => true,
            };
            if keep {
                self.telemetry_line("dump", &t);
            }
            match t {
                Telemetry::Allan(_) => self.seen.allan_reports += 1,
                Telemetry::Faults(_) => self.seen.fault_reports += 1,
                _ => {}
            }
        }
    }

    fn command(&mut self, tag: u16, cmd: Command) {
        let mut buf = [0u8; 256];
        let replies = self
            .p
            .handle_command(encode(&CommandEnvelope { tag, cmd }, &mut buf).unwrap());
        for o in replies {
            self.record(o);
        }
        self.drain();
        self.drain_dumps();
    }

    fn push(&mut self, mut bytes: &[u8]) {
        loop {
            self.p.push_link(&mut bytes);
            self.drain();
            if bytes.is_empty() {
                return;
            }
        }
    }

    fn checkpoint(&mut self) {
        let f = self.p.fusion();
        for g in 0..GROUPS {
            for a in 0..AXES {
                self.seen.unequal_weights += u32::from(f.weight_q16(g, a) < Some(1 << 16));
                self.h
                    .ser(&(g as u8, a as u8, f.noise_var(g, a), f.weight_q16(g, a)));
            }
            self.h.ser(&f.fault_counts(g));
        }
        self.h.ser(&(self.p.health(), self.p.tau0_ps()));
    }
}

/// Runs `n` frames with `config`; returns the hash and the JSON lines.
fn golden_run(config: PipelineConfig, n: usize, seed: u64) -> (u64, Vec<String>) {
    let mut r = Run {
        p: Pipeline::new(config, Box::new(PipelineMemory::new())),
        h: Fnv::new(),
        seen: Seen::default(),
        frame: 0,
        lines: Vec::new(),
    };
    r.p.load_calibration(&calibration(seed), CalSource::Stored);
    let mut rng = Rng::seed_from_u64(seed ^ 0x5555);
    let combos = [
        (FusionMode::InverseVariance, true),
        (FusionMode::Equal, true),
        (FusionMode::InverseVariance, false),
        (FusionMode::Equal, false),
    ];
    let mut seq = 0u16;
    for i in 0..n {
        r.frame = i;
        if i % 3_000 == 0 {
            let (mode, robust) = combos[(i / 3_000) % 4];
            r.command(i as u16, Command::SetFusion { mode, robust });
        }
        if i % 4_000 == 3_999 {
            r.command(
                1,
                Command::AllanRequest {
                    first: 0,
                    count: ALLAN_CHANNELS as u8,
                },
            );
        }
        if i % 5_000 == 2_500 {
            r.command(2, Command::HealthRequest { detail: true });
        }
        match i {
            7_000 => r.command(3, Command::SetOutputRate(7)),
            9_500 => r.command(4, Command::SetOutputRate(1)),
            10_200 => r.command(5, Command::SetOutputRate(32)),
            19_000 => {
                r.p.load_calibration(&calibration(seed + 1), CalSource::Uploaded)
            }
            21_000 => r.command(6, Command::AllanReset),
            _ => {}
        }
        if i % 1_000 == 0 {
            r.checkpoint();
        }
        // Lost frames (sequence gaps), and a decimation change at 17 000.
        seq = seq.wrapping_add(if i % 997 == 500 { 3 } else { 1 });
        let decimation = if i >= 17_000 { 7 } else { 15 };
        let mut bytes = frame(i, seq, decimation, &mut rng).to_bytes();
        if i % 1_499 == 700 {
            // Damaged: the CRC fails and the frame is lost.
            bytes[100] ^= 0x04;
        }
        if i % 1_201 == 300 {
            // Garbage before the frame, including a false sync marker.
            r.push(&[0x00, 0x1A, 0xCF, 0x77, 0x1A, 0xCF, 0xFC]);
        }
        if i % 7 == 3 {
            // Split delivery: the decoder's buffered path.
            let (a, b) = bytes.split_at(61 + i % 150);
            r.push(a);
            r.push(b);
        } else {
            r.push(&bytes);
        }
        assert_eq!(bytes.len(), FRAME_LEN);
        let last = *r.p.last_fused();
        r.h.fused(&last);
        r.seen.note(&last);
    }
    r.command(
        7,
        Command::AllanRequest {
            first: 0,
            count: ALLAN_CHANNELS as u8,
        },
    );
    r.frame = n;
    r.command(8, Command::HealthRequest { detail: true });
    r.checkpoint();
    println!("{:?}", r.seen);
    r.seen.assert_all();
    (r.h.0, r.lines)
}

/// The hashes of the two configurations (their history: `docs/performance.md`, "The golden stream").
const GOLDEN_DEFAULT: u64 = 0xb0bc_067d_5900_dded;
const GOLDEN_FAST: u64 = 0x1566_91fd_88cb_054b;

#[test]
fn outputs_are_bit_exact() {
    let (default, _) = golden_run(
        // Without the navigation increments, which came after these hashes: the golden run guards the outputs it
        // recorded; `Nav` has its own tests against an f64 reference (`nav::tests`, `pipeline::tests`).
        PipelineConfig {
            health_every: 3,
            nav: false,
            ..PipelineConfig::DEFAULT
        },
        24_000,
        11,
    );
    // Fast estimators and frequent weight changes, short stuck window, one output per frame.
    let (fast, _) = golden_run(
        PipelineConfig {
            frames_per_output: 1,
            health_every: 50,
            nav: false,
            fusion: FusionConfig {
                stuck_window: 8,
                noise_shift: 4,
                weight_interval: 16,
                outlier_sigmas_q8: 3 * 256,
                ..FusionConfig::DEFAULT
            },
            ..PipelineConfig::DEFAULT
        },
        15_000,
        12,
    );
    println!("golden hashes: {default:#018x} {fast:#018x}");
    assert_eq!((default, fast), (GOLDEN_DEFAULT, GOLDEN_FAST));
}

/// The snapshot of the default configuration, navigation on: every message the core sends in the golden stream, as
/// JSON lines (`golden/default.jsonl`: the frame index, then `out` for the queued outputs, `dump` for the dump
/// reports — the Allan reports of every 16th channel and of the fused axes —, `fpga` and `persist` for the
/// platform's orders). A difference names the first line that changed;
/// `UPDATE_GOLDEN=1 cargo test -p shared --test acceptance snapshot` rewrites the file after a deliberate change
/// (review its diff: it is the change in what the MCU says).
#[test]
fn outputs_match_the_snapshot() {
    let (_, lines) = golden_run(
        PipelineConfig {
            health_every: 3,
            ..PipelineConfig::DEFAULT
        },
        24_000,
        11,
    );
    assert!(
        lines.iter().any(|l| l.contains("\"Nav\"")),
        "navigation in the snapshot"
    );
    let actual = lines.join("\n") + "\n";
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/acceptance/golden/default.jsonl");
    if std::env::var_os("UPDATE_GOLDEN").is_some() {
        std::fs::write(&path, &actual).unwrap();
        println!(
            "snapshot rewritten: {} ({} lines)",
            path.display(),
            lines.len()
        );
        return;
    }
    let expected = std::fs::read_to_string(&path).unwrap_or_default();
    if expected == actual {
        return;
    }
    let out = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join("golden-default.jsonl");
    std::fs::write(&out, &actual).unwrap();
    let exp: Vec<&str> = expected.lines().collect();
    let first = exp
        .iter()
        .zip(&lines)
        .position(|(e, a)| e != a)
        .unwrap_or(exp.len().min(lines.len()));
    panic!(
        "the outputs differ from {} at line {} ({} lines expected, {} now)\n  expected: {}\n  now:      {}\n\
         the whole new output: {} (diff it; UPDATE_GOLDEN=1 accepts it)",
        path.display(),
        first + 1,
        exp.len(),
        lines.len(),
        exp.get(first).unwrap_or(&"(end)"),
        lines.get(first).map_or("(end)", String::as_str),
        out.display()
    );
}
