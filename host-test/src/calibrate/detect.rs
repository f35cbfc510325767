//! Static interval detection on a MIMU4444 recording.
//!
//! For every window of [`DetectOptions::window_s`] (default 1 s = 63 samples at 62.5 Hz) the standard deviation
//! of each raw channel is computed; per axis it is averaged over the IMUs and the largest axis is taken, once for
//! the accelerometers (in g, nominal scale) and once for the gyros (in °/s). A window is static when both are
//! below the thresholds (defaults 0.010 g and 0.5 °/s; at rest the statistics are 0.0049 g and 0.20–0.25 °/s,
//! in motion tens of mg and °/s) and it does not span a discontinuity of the stream (lost frames). Every sample
//! covered by a static window is static; runs of static samples are trimmed by [`DetectOptions::trim_s`] at both
//! ends (default 1 s, to drop the settling after a pose change) and kept when at least
//! [`DetectOptions::min_duration_s`] long (default 10 s: the poses last 22–27 s; this rejects the short stops of
//! the dynamic phase, e.g. a 6 s one at 621 s in exp_2).

use super::{CalibError, Vec3};
use crate::formats::mimu::{ACCEL_LSB_PER_G, GYRO_LSB_PER_DPS, IMUS, Recording, SAMPLE_RATE_HZ};

/// Options of [`detect_static`].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetectOptions {
    /// Sliding window, seconds (rounded to samples at the nominal rate). Default 1.0.
    pub window_s: f64,
    /// Largest accelerometer standard deviation in a static window, g (mean over IMUs, worst axis). Default 0.010.
    pub accel_std_max_g: f64,
    /// Largest gyro standard deviation in a static window, °/s (mean over IMUs, worst axis). Default 0.5.
    pub gyro_std_max_dps: f64,
    /// Shortest static interval kept (after trimming), seconds. Default 10.0.
    pub min_duration_s: f64,
    /// Removed at each end of a static run, seconds. Default 1.0.
    pub trim_s: f64,
    /// Accelerometer counts per g. Default [`ACCEL_LSB_PER_G`].
    pub accel_counts_per_g: f64,
    /// Gyro counts per °/s. Default [`GYRO_LSB_PER_DPS`].
    pub gyro_counts_per_dps: f64,
}

impl Default for DetectOptions {
    fn default() -> Self {
        Self {
            window_s: 1.0,
            accel_std_max_g: 0.010,
            gyro_std_max_dps: 0.5,
            min_duration_s: 15.0,
            trim_s: 1.0,
            accel_counts_per_g: ACCEL_LSB_PER_G,
            gyro_counts_per_dps: GYRO_LSB_PER_DPS,
        }
    }
}

/// A static interval and the means over it.
#[derive(Clone, Debug, PartialEq)]
pub struct StaticInterval {
    /// Index of the first frame.
    pub first_frame: usize,
    /// Index one past the last frame.
    pub end_frame: usize,
    /// Time of the first frame, seconds since the start of the recording.
    pub start_s: f64,
    /// Time of the last frame, seconds.
    pub end_s: f64,
    /// Mean accelerometer reading per IMU, counts.
    pub accel_counts: Vec<Vec3>,
    /// Mean gyro reading per IMU, counts.
    pub gyro_counts: Vec<Vec3>,
    /// Standard error of `accel_counts` (sample standard deviation / √n), counts.
    pub accel_sem_counts: Vec<Vec3>,
    /// Standard error of `gyro_counts`, counts.
    pub gyro_sem_counts: Vec<Vec3>,
    /// Mean specific force per IMU at the nominal scale (no bias removed), g.
    pub accel_g: Vec<Vec3>,
    /// Largest accelerometer standard deviation over the interval, g (mean over IMUs, worst axis).
    pub accel_std_g: f64,
    /// Largest gyro standard deviation over the interval, °/s (mean over IMUs, worst axis).
    pub gyro_std_dps: f64,
    /// Largest change of the mean specific force between the first and the last third of the interval over the
    /// IMUs, mg (a slow tilt or a nudge during the pose shows here; noise alone gives ≈ 0.3–0.8 mg).
    pub accel_change_mg: f64,
}

impl StaticInterval {
    /// Mid-time, seconds.
    pub fn mid_s(&self) -> f64 {
        0.5 * (self.start_s + self.end_s)
    }

    /// Number of frames.
    pub fn frames(&self) -> usize {
        self.end_frame - self.first_frame
    }
}

const CH: usize = IMUS * 6;

fn channel(rec: &Recording, i: usize, ch: usize) -> f64 {
    let s = &rec.frames[i].imu[ch / 6];
    let k = ch % 6;
    f64::from(if k < 3 { s.acc[k] } else { s.gyro[k - 3] })
}

/// Mean and standard deviation of each channel over `[a, b)`, from prefix sums (centred per channel).
struct Prefix {
    s1: Vec<[f64; CH]>,
    s2: Vec<[f64; CH]>,
    center: [f64; CH],
}

impl Prefix {
    fn new(rec: &Recording) -> Self {
        let n = rec.frames.len();
        let center: [f64; CH] =
            core::array::from_fn(|ch| if n == 0 { 0.0 } else { channel(rec, 0, ch) });
        let mut s1 = Vec::with_capacity(n + 1);
        let mut s2 = Vec::with_capacity(n + 1);
        let (mut a1, mut a2) = ([0.0; CH], [0.0; CH]);
        s1.push(a1);
        s2.push(a2);
        for i in 0..n {
            for ch in 0..CH {
                let x = channel(rec, i, ch) - center[ch];
                a1[ch] += x;
                a2[ch] += x * x;
            }
            s1.push(a1);
            s2.push(a2);
        }
        Self { s1, s2, center }
    }

    fn mean_std(&self, a: usize, b: usize, ch: usize) -> (f64, f64) {
        let n = (b - a) as f64;
        let m = (self.s1[b][ch] - self.s1[a][ch]) / n;
        let v = ((self.s2[b][ch] - self.s2[a][ch]) / n - m * m).max(0.0);
        let unbiased = if b - a > 1 { v * n / (n - 1.0) } else { 0.0 };
        (m + self.center[ch], unbiased.sqrt())
    }

    /// (accelerometer statistic in g, gyro statistic in °/s) over `[a, b)`.
    fn stat(&self, a: usize, b: usize, opts: &DetectOptions) -> (f64, f64) {
        let mut acc = [0.0f64; 3];
        let mut gyr = [0.0f64; 3];
        for imu in 0..IMUS {
            for k in 0..3 {
                acc[k] += self.mean_std(a, b, imu * 6 + k).1;
                gyr[k] += self.mean_std(a, b, imu * 6 + 3 + k).1;
            }
        }
        let max = |v: [f64; 3]| v.iter().fold(0.0f64, |m, &x| m.max(x)) / IMUS as f64;
        (
            max(acc) / opts.accel_counts_per_g,
            max(gyr) / opts.gyro_counts_per_dps,
        )
    }
}

fn check(opts: &DetectOptions) -> Result<(), CalibError> {
    let pos = |x: f64| x.is_finite() && x > 0.0;
    if !pos(opts.window_s) {
        return Err(CalibError::InvalidOption("window_s must be > 0"));
    }
    if !pos(opts.accel_std_max_g) || !pos(opts.gyro_std_max_dps) {
        return Err(CalibError::InvalidOption("thresholds must be > 0"));
    }
    let non_negative = |x: f64| x.is_finite() && x >= 0.0;
    if !(non_negative(opts.min_duration_s) && non_negative(opts.trim_s)) {
        return Err(CalibError::InvalidOption(
            "min_duration_s and trim_s must be ≥ 0",
        ));
    }
    if !pos(opts.accel_counts_per_g) || !pos(opts.gyro_counts_per_dps) {
        return Err(CalibError::InvalidOption("scales must be > 0"));
    }
    Ok(())
}

/// Finds the static intervals of a recording (see the module docs for the rule and the defaults), in time order.
/// An empty result is not an error; invalid options are.
pub fn detect_static(
    rec: &Recording,
    opts: &DetectOptions,
) -> Result<Vec<StaticInterval>, CalibError> {
    check(opts)?;
    let n = rec.frames.len();
    let w = ((opts.window_s * SAMPLE_RATE_HZ).round() as usize).max(2);
    if n < w {
        return Ok(Vec::new());
    }
    let prefix = Prefix::new(rec);
    // Segment id of each sample: windows and intervals never span a discontinuity.
    let mut seg = vec![0usize; n];
    for i in 1..n {
        seg[i] = seg[i - 1] + usize::from(rec.discontinuity.get(i).copied().unwrap_or(false));
    }
    let mut is_static = vec![false; n];
    let mut cover_until = 0usize;
    for a in 0..=n - w {
        let b = a + w;
        if seg[a] != seg[b - 1] {
            continue;
        }
        let (sa, sg) = prefix.stat(a, b, opts);
        if sa < opts.accel_std_max_g && sg < opts.gyro_std_max_dps {
            for s in is_static.iter_mut().take(b).skip(a.max(cover_until)) {
                *s = true;
            }
            cover_until = b;
        }
    }
    let trim = (opts.trim_s * SAMPLE_RATE_HZ).round() as usize;
    let mut out = Vec::new();
    let mut i = 0;
    while i < n {
        if !is_static[i] {
            i += 1;
            continue;
        }
        let mut j = i;
        while j < n && is_static[j] && seg[j] == seg[i] {
            j += 1;
        }
        let (a, b) = (i + trim, j.saturating_sub(trim));
        i = j;
        if b < a + 2 {
            continue;
        }
        let (start_s, end_s) = (
            rec.time_s(a).unwrap_or(0.0),
            rec.time_s(b - 1).unwrap_or(0.0),
        );
        if end_s - start_s + 1.0 / SAMPLE_RATE_HZ < opts.min_duration_s {
            continue;
        }
        out.push(summarise(rec, &prefix, a, b, opts));
    }
    Ok(out)
}

fn summarise(
    rec: &Recording,
    prefix: &Prefix,
    a: usize,
    b: usize,
    opts: &DetectOptions,
) -> StaticInterval {
    let n = (b - a) as f64;
    let per_imu = |off: usize, sem: bool| -> Vec<Vec3> {
        (0..IMUS)
            .map(|imu| {
                core::array::from_fn(|k| {
                    let (m, s) = prefix.mean_std(a, b, imu * 6 + off + k);
                    if sem { s / n.sqrt() } else { m }
                })
            })
            .collect()
    };
    let accel_counts = per_imu(0, false);
    let third = (b - a) / 3;
    let mut change = 0.0f64;
    if third >= 1 {
        for imu in 0..IMUS {
            let d: f64 = (0..3)
                .map(|k| {
                    let m0 = prefix.mean_std(a, a + third, imu * 6 + k).0;
                    let m1 = prefix.mean_std(b - third, b, imu * 6 + k).0;
                    (m1 - m0).powi(2)
                })
                .sum::<f64>()
                .sqrt();
            change = change.max(d / opts.accel_counts_per_g * 1e3);
        }
    }
    let (accel_std_g, gyro_std_dps) = prefix.stat(a, b, opts);
    StaticInterval {
        first_frame: a,
        end_frame: b,
        start_s: rec.time_s(a).unwrap_or(0.0),
        end_s: rec.time_s(b - 1).unwrap_or(0.0),
        accel_g: accel_counts
            .iter()
            .map(|v| v.map(|x| x / opts.accel_counts_per_g))
            .collect(),
        accel_counts,
        gyro_counts: per_imu(3, false),
        accel_sem_counts: per_imu(0, true),
        gyro_sem_counts: per_imu(3, true),
        accel_std_g,
        gyro_std_dps,
        accel_change_mg: change,
    }
}
