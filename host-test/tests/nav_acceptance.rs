//! Issue 16's acceptance, end to end: `ground simulate --motion … --noiseless` → FPGA frames (through the true
//! calibration, ADC codes) → the flight core (`replay`) → `Nav` reports → attitude and velocity composed on the
//! ground, against the motion's f64 truth. Fault exclusion is off: noiseless channels would all look stuck.
//!
//! Noiseless ADC codes round every constant part of a signal the same way each sample: coning's constant z rate,
//! −Ω(1 − cos a) = −0.109 °/s = −17.50 LSB, sits exactly half-way between two codes, and 1 g on an accelerometer
//! axis rounds the same way too. Undithered, that is a bias of half an LSB (3.0e-3 rad in 60 s of coning), a
//! property of the ADC, not of the integration. The acceptance runs therefore add 1 LSB of white noise as dither
//! (`dither`); the noiseless numbers are printed beside them.
use host_test::replay::{ReplayOptions, replay};
use host_test::sim::motion::{M3, Motion, mul, mul_t};
use host_test::sim::output;
use host_test::sim::{CHANNELS, NoiseParams, SimConfig};
use shared::bus::BusConfig;
use shared::calib::CalibrationTable;
use shared::fuse::FusionConfig;
use shared::pipeline::PipelineConfig;
use shared::telemetry::{FusedReport, NavReport, Telemetry};
use shared::wire::frame::FRAME_LEN;

const FPS: f64 = 604.8;

/// White noise of 1 LSB per sample on every channel: 1/160 °/s for the gyros (channels 0–3), 1/4800 g for the
/// accelerometers (4–6), as densities N = σ·√Δt.
fn dither() -> [NoiseParams; CHANNELS] {
    core::array::from_fn(|c| NoiseParams {
        white: if c < 4 { 1.0 / 160.0 } else { 1.0 / 4800.0 } / FPS.sqrt(),
        ..NoiseParams::default()
    })
}

fn frames(motion: Option<Motion>, seconds: f64, name: &str) -> Vec<u8> {
    frames_with(motion, seconds, name, [NoiseParams::default(); CHANNELS])
}

fn frames_with(
    motion: Option<Motion>,
    seconds: f64,
    name: &str,
    noise: [NoiseParams; CHANNELS],
) -> Vec<u8> {
    let mut cfg = SimConfig::new(1, FPS, (seconds * FPS).round() as u64, noise);
    cfg.motion = motion;
    cfg.frames = output::frame_opts(FPS, host_test::FPGA_BASE_RATE_HZ);
    let path = std::path::Path::new(env!("CARGO_TARGET_TMPDIR")).join(name);
    output::write(cfg, &path, |_| {}).unwrap();
    std::fs::read(&path).unwrap()
}

fn run(bytes: &[u8]) -> (Vec<NavReport>, Vec<FusedReport>) {
    let out = replay(
        bytes,
        &ReplayOptions {
            config: PipelineConfig {
                fusion: FusionConfig {
                    robust: false,
                    ..FusionConfig::DEFAULT
                },
                ..PipelineConfig::DEFAULT
            },
            cal: CalibrationTable::factory(),
            bus: BusConfig::DEFAULT,
            final_dump: false,
            check: false,
        },
        |_| {},
    );
    let nav = out.messages.iter().filter_map(|m| match m {
        Telemetry::Nav(n) => Some(*n),
        _ => None,
    });
    let fused = out.messages.iter().filter_map(|m| match m {
        Telemetry::Fused(f) => Some(*f),
        _ => None,
    });
    (nav.collect(), fused.collect())
}

fn transpose(a: &M3) -> M3 {
    core::array::from_fn(|i| core::array::from_fn(|j| a[j][i]))
}

fn exp(v: [f64; 3]) -> M3 {
    let th = v.iter().map(|x| x * x).sum::<f64>().sqrt();
    if th == 0.0 {
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    }
    let k = v.map(|x| x / th);
    let kx: M3 = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
    let kx2 = mul(&kx, &kx);
    core::array::from_fn(|i| {
        core::array::from_fn(|j| {
            f64::from(u8::from(i == j)) + th.sin() * kx[i][j] + (1.0 - th.cos()) * kx2[i][j]
        })
    })
}

fn angle(r: &M3) -> f64 {
    ((r[0][0] + r[1][1] + r[2][2] - 1.0) / 2.0)
        .clamp(-1.0, 1.0)
        .acos()
}

/// Frame k is the sample at t = k·Δt and stands for [t − Δt/2, t + Δt/2]: the composed rotation runs from −Δt/2.
fn composed(steps: impl Iterator<Item = [f64; 3]>) -> M3 {
    steps.fold(exp([0.0; 3]), |c, d| mul(&c, &exp(d)))
}

/// (theory, uncorrected error, corrected error), rad, for 60 s of a = 1°, 2 Hz coning.
fn coning(noise: [NoiseParams; CHANNELS], name: &str) -> (f64, f64, f64) {
    let (a_deg, f_hz, secs) = (1.0f64, 2.0, 60.0);
    let motion = Motion::Coning {
        half_angle_rad: a_deg.to_radians(),
        freq_hz: f_hz,
    };
    let (nav, fused) = run(&frames_with(Some(motion), secs, name, noise));
    let dt = 1.0 / FPS;
    let t0 = -dt / 2.0;
    let total: f64 = nav.iter().map(|n| f64::from(n.dt_us)).sum::<f64>() * 1e-6;
    let truth = mul(
        &transpose(&motion.attitude(t0)),
        &motion.attitude(t0 + total),
    );
    let corrected = composed(nav.iter().map(|n| n.dtheta_nrad.map(|x| x as f64 * 1e-9)));
    // Uncorrected: the interval's mean rate (the Fused report) times its length.
    let plain = composed(fused.iter().zip(&nav).map(|(f, n)| {
        f.rate_udps
            .map(|r| (r as f64 * 1e-6).to_radians() * f64::from(n.dt_us) * 1e-6)
    }));
    let err_corr = angle(&mul(&transpose(&truth), &corrected));
    let err_plain = angle(&mul(&transpose(&truth), &plain));
    let omega = 2.0 * core::f64::consts::PI * f_hz;
    let big_t = 32.0 * dt;
    let a = a_deg.to_radians();
    let theory = 0.5 * a * a * omega * (1.0 - (omega * big_t).sin() / (omega * big_t)) * total;
    assert_eq!(nav.iter().map(|n| u32::from(n.bridged)).sum::<u32>(), 0);
    (theory, err_plain, err_corr)
}

#[test]
fn coning_drift_is_removed_end_to_end() {
    let (theory, plain, corr) = coning(dither(), "coning.bin");
    let (_, plain_q, corr_q) = coning([NoiseParams::default(); CHANNELS], "coning-noiseless.bin");
    eprintln!(
        "coning 60 s, 1°, 2 Hz, 32-frame intervals: theory {theory:.3e} rad; dithered: uncorrected {plain:.3e}, \
         corrected {corr:.3e}; noiseless: uncorrected {plain_q:.3e}, corrected {corr_q:.3e}"
    );
    assert!((plain - theory).abs() < 0.1 * theory, "{plain} vs {theory}");
    assert!(corr < 0.05 * theory, "{corr} vs {theory}");
}

#[test]
fn sculling_velocity_follows_the_truth_end_to_end() {
    let motion = Motion::Sculling {
        angle_amp_rad: 1f64.to_radians(),
        accel_amp_g: 0.5,
        freq_hz: 2.0,
    };
    let secs = 60.0;
    let (nav, fused) = run(&frames_with(Some(motion), secs, "sculling.bin", dither()));
    let g = 9.80665;
    let dt = 1.0 / FPS;
    let t0 = -dt / 2.0;
    let total: f64 = nav.iter().map(|n| f64::from(n.dt_us)).sum::<f64>() * 1e-6;
    // Truth: ∫ C(t) f(t) dt in the reference frame (Simpson, 20 steps a frame), minus the static 1 g up.
    let steps = (total / dt * 20.0).round() as usize;
    let h = total / steps as f64;
    let mut v_true = [0.0; 3];
    for k in 0..=steps {
        let t = t0 + k as f64 * h;
        let w = if k == 0 || k == steps {
            1.0
        } else if k % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let f = motion.at(t, [0.0, 0.0, 1.0]).1;
        let c = motion.attitude(t);
        let fr: [f64; 3] = core::array::from_fn(|i| (0..3).map(|j| c[i][j] * f[j]).sum());
        for i in 0..3 {
            v_true[i] += w * h / 3.0 * fr[i] * g;
        }
    }
    let v_true = mul_t(&motion.attitude(t0), v_true); // C(t0)ᵀ v: in the body frame at t0, as composed below
    let compose = |dvs: &mut dyn Iterator<Item = ([f64; 3], [f64; 3])>| {
        let (mut c, mut v) = (exp([0.0; 3]), [0.0; 3]);
        for (dth, dv) in dvs {
            let d: [f64; 3] = core::array::from_fn(|i| (0..3).map(|j| c[i][j] * dv[j]).sum());
            for i in 0..3 {
                v[i] += d[i];
            }
            c = mul(&c, &exp(dth));
        }
        v
    };
    let v_corr = compose(&mut nav.iter().map(|n| {
        (
            n.dtheta_nrad.map(|x| x as f64 * 1e-9),
            n.dv_umps.map(|x| x as f64 * 1e-6),
        )
    }));
    let v_plain = compose(&mut fused.iter().zip(&nav).map(|(f, n)| {
        let dts = f64::from(n.dt_us) * 1e-6;
        (
            f.rate_udps.map(|r| (r as f64 * 1e-6).to_radians() * dts),
            f.accel_ug.map(|a| a as f64 * 1e-6 * g * dts),
        )
    }));
    let err = |v: [f64; 3]| {
        (0..3)
            .map(|i| (v[i] - v_true[i]).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    let (e_corr, e_plain) = (err(v_corr), err(v_plain));
    eprintln!(
        "sculling {secs} s: |v_true| {:.4} m/s, error uncorrected {e_plain:.3e} m/s, corrected {e_corr:.3e} m/s",
        v_true.iter().map(|x| x * x).sum::<f64>().sqrt()
    );
    assert!(e_plain > 1e-3, "{e_plain}");
    assert!(e_corr < 0.05 * e_plain, "{e_corr} vs {e_plain}");
}

#[test]
fn static_increments_and_a_log_with_gaps() {
    let bytes = frames(None, 2.0, "static.bin");
    // Drop frames 100..=104 and 700 (in the second and the 22nd interval).
    let kept: Vec<u8> = bytes
        .chunks(FRAME_LEN)
        .enumerate()
        .filter(|(k, _)| !(100..=104).contains(k) && *k != 700)
        .flat_map(|(_, f)| f.iter().copied())
        .collect();
    let (nav, _) = run(&kept);
    let period = 16.0 / host_test::FPGA_BASE_RATE_HZ;
    let g = 9.80665;
    let mut bridged = 0;
    for n in &nav {
        let dts = f64::from(n.dt_us) * 1e-6;
        assert!((dts - f64::from(n.frames) * period).abs() < 2e-6);
        assert_eq!(n.frames, 32 + n.bridged);
        bridged += n.bridged;
        // z up at 1 g: ΔV = g·dt along z; no rotation (exact codes, no noise).
        let dv = n.dv_umps.map(|x| x as f64 * 1e-6);
        assert!((dv[2] - g * dts).abs() < 2e-4 * g * dts, "{dv:?}");
        assert!(dv[0].abs() < 1e-4 && dv[1].abs() < 1e-4, "{dv:?}");
        assert!(
            n.dtheta_nrad.iter().all(|x| x.abs() < 2_000),
            "{:?}",
            n.dtheta_nrad
        );
    }
    assert_eq!(bridged, 6);
    assert_eq!(
        nav.iter()
            .filter(|n| n.bridged > 0)
            .map(|n| n.seq)
            .collect::<Vec<_>>(),
        [3, 21]
    );
}
