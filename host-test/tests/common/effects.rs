//! Shared by the acceptance tests of the diagnosis and of the twin: the 8-h, 16-group, 5 Hz static record of the
//! seed preset, and the effects injected into it at calibrated strengths.

use host_test::allan::{DevKind, deviation};
use host_test::diagnose::Groups;
use host_test::sim::preset::seed_config;
use host_test::sim::{
    Axis, Channel, CommonDrift, CommonMode, DriftKind, Outlier, Periodic, SimConfig, Simulator,
    Thermal,
};

pub const SEED: u64 = 7_200_001;
pub const RATE_HZ: f64 = 5.0;
pub const HOURS: f64 = 8.0;
/// The longest τ a half holds with 4 blocks: T/8.
pub const TAU_LONG_S: f64 = HOURS * 3600.0 / 8.0;

pub fn config(seed: u64) -> SimConfig {
    let mut cfg = seed_config(seed).unwrap();
    cfg.rate_hz = RATE_HZ;
    cfg.samples = (HOURS * 3600.0 * RATE_HZ) as u64;
    cfg
}

/// Expected Allan variance of the 16-group mean of `channel` at τ, without any effect.
pub fn cluster_avar(cfg: &SimConfig, channel: Channel, tau_s: f64) -> f64 {
    let groups: Vec<usize> = (0..16).collect();
    Simulator::new(cfg.clone())
        .unwrap()
        .expected_mean_avar(channel, &groups, tau_s)
        .unwrap()
}

/// Board temperature following the orbit (period 1.5 h, 0.4 °C amplitude) on a slow 0.08 °C/h ramp, 1.4 °C peak
/// to peak over the record; coefficients on `axes` with a 30 % spread between parts, the mean scaled so
/// that the shared thermal bias adds at most `added` × the cluster's AVAR at any octave τ up to T/8 (3: ADEV ≤ ×2).
pub fn thermal(cfg: &SimConfig, axes: &[Axis], added: f64) -> Thermal {
    let mut t = Thermal {
        mean_c: 20.0,
        amplitude_c: 0.4,
        period_s: 1.5 * 3600.0,
        phase_rad: 0.4,
        drift_c_per_h: 0.08,
        coef: [0.0; 6],
        coef_sd: [0.0; 6],
        ref_c: None,
        hold_after_s: None,
    };
    let dt = 1.0 / RATE_HZ;
    let temp: Vec<f64> = (0..cfg.samples).map(|i| t.temp_at(i as f64 * dt)).collect();
    let ms: Vec<usize> = (0..20)
        .map(|k| 1usize << k)
        .filter(|&m| m as f64 * dt <= TAU_LONG_S)
        .collect();
    let temp_avar = deviation(DevKind::Oadev, &temp, dt, &ms);
    for a in axes {
        let ch = a.channels()[0];
        let worst = temp_avar
            .iter()
            .map(|p| p.dev.powi(2) / cluster_avar(cfg, ch, p.tau_s))
            .fold(0.0, f64::max);
        let coef = (added / worst).sqrt();
        t.coef[a.index()] = coef;
        t.coef_sd[a.index()] = 0.3 * coef;
    }
    t
}

pub fn blocks(cfg: &mut SimConfig, size: usize, axes: &[Axis], rho: f64) -> Groups {
    let mut out = Vec::new();
    for b in 0..16 / size {
        let g: Vec<usize> = (b * size..(b + 1) * size).collect();
        cfg.common
            .push(CommonMode::block(&format!("b{b}"), &g, axes, rho, rho));
        out.push(g);
    }
    Groups::Blocks(out)
}

/// The peak of a sinusoid's Allan variance, `max sin⁴(x)/x²` = 0.5250 A² at πτ/P = 1.1656.
pub const SINE_PEAK: f64 = 0.525;
pub const SINE_PEAK_X: f64 = 1.165_561;

/// Adds a sinusoid of `period_s` on `axis` of `groups` (`None`: all) whose Allan variance at its peak is `added` ×
/// the cluster's AVAR of `channel` there (one sensor's own AVAR is 16 × the cluster's); returns its amplitude.
pub fn sinusoid(
    cfg: &mut SimConfig,
    groups: Option<Vec<usize>>,
    (axis, channel): (Axis, Channel),
    period_s: f64,
    added: f64,
    phase_rad: f64,
) -> f64 {
    let tau_peak = SINE_PEAK_X * period_s / std::f64::consts::PI;
    let amplitude = (added * cluster_avar(cfg, channel, tau_peak) / SINE_PEAK).sqrt();
    cfg.periodic.push(Periodic {
        groups,
        axes: vec![axis],
        amplitude,
        period_s,
        phase_rad,
    });
    amplitude
}

/// A 600 s sinusoid on gyro x of every group, `factor` × the cluster's AVAR at its Allan-variance peak (τ ≈ 223 s);
/// returns its period and amplitude.
pub fn shared_gyro_x_sinusoid(cfg: &mut SimConfig, factor: f64) -> (f64, f64) {
    let period = 600.0;
    let gx = (Axis::GyroX, Channel::GyroAX);
    (period, sinusoid(cfg, None, gx, period, factor, 0.7))
}

/// Group 7's accel y alone: a 90 s sinusoid at 3× its own AVAR at the sinusoid's peak (τ ≈ 33 s); returns its
/// period and amplitude.
pub fn own_accel_y_sinusoid(cfg: &mut SimConfig) -> (f64, f64) {
    let period = 90.0;
    let ay = (Axis::AccelY, Channel::AccelY);
    (
        period,
        sinusoid(cfg, Some(vec![7]), ay, period, 3.0 * 16.0, 0.0),
    )
}

/// A bias step of `size` (°/s) on both z gyros of `group` at `at_s`: that group's gz output steps by `size`.
pub fn gyro_z_step(cfg: &mut SimConfig, group: usize, size: f64, at_s: f64) {
    for channel in [Channel::GyroAZ, Channel::GyroBZ] {
        cfg.outliers.push(Outlier::step(group, channel, size, at_s));
    }
}

/// `group`'s `axis` alone gains a rate random walk: ×16 its AVAR at T/8 (ADEV ×4), the cluster's ×2 there;
/// returns its K.
pub fn one_sensor_random_walk(
    cfg: &mut SimConfig,
    group: usize,
    (axis, channel): (Axis, Channel),
) -> f64 {
    let single = 16.0 * cluster_avar(cfg, channel, TAU_LONG_S);
    let k = (3.0 * 15.0 * single / TAU_LONG_S).sqrt();
    cfg.drift.push(CommonDrift {
        groups: Some(vec![group]),
        axes: vec![axis],
        kind: DriftKind::RandomWalk { k },
    });
    k
}

/// A fitted sinusoid's period within 1 % and amplitude within 20 % of the injected `period` and `amp`.
pub fn same_period_and_amplitude(got_period: f64, got_amp: f64, period: f64, amp: f64) {
    assert!(
        (got_period / period - 1.0).abs() < 0.01,
        "period {got_period} s vs {period} s"
    );
    assert!(
        (got_amp / amp - 1.0).abs() < 0.2,
        "amplitude {got_amp} vs {amp}"
    );
}
