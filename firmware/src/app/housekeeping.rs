//! The `housekeeping` task, once a period: the housekeeping, reset-history and update reports, a Health report
//! while the FPGA link is silent, the CRC check of the calibration in RAM, the log's link statistics; and the trim
//! of the HSI against the FPGA's crystal-timed frames, while the core runs on the HSI.

use core::cell::Cell;
use core::num::NonZeroU64;
use core::sync::atomic::Ordering;

use embassy_time::{Instant, Ticker};
use shared::pipeline::{Output, Pipeline, PipelineMemory};
use shared::telemetry::{TaskId, Telemetry};

use super::HOUSEKEEPING_PERIOD;
use super::counters::Counter;
use super::platform::HsiTrim;
use super::state::App;

/// Crystal time (FPGA frames) one trim decision averages over, s: ±1 frame in 6 048 is ±165 ppm of resolution.
pub const HSI_TRIM_WINDOW_S: u64 = 10;
/// The HSI's error beyond which the trim moves one step, ppm. One HSITRIM step is about 0.5 % (RM0090 §7.2.2:
/// 32 steps over the HSI's range, the factory value in the middle), so a band of ±0.3 % lets the loop settle within
/// one step of the best trim instead of hunting.
pub const HSI_TRIM_DEADBAND_PPM: i64 = 3_000;

/// The HSI's error, ppm (positive: fast), from `fpga_us` of crystal time (frames counted from the FPGA) that took
/// `local_us` on the core's clock (the HSI through the PLL); `None` for an empty window.
pub fn hsi_error_ppm(fpga_us: u64, local_us: u64) -> Option<i64> {
    let diff = i128::from(local_us).checked_sub(i128::from(fpga_us))?;
    let ppm = diff
        .checked_mul(1_000_000)?
        .checked_div(i128::from(fpga_us))?;
    i64::try_from(ppm).ok()
}

/// The next HSITRIM for an error of `error_ppm` at `trim`: one step down when fast beyond the dead band, one up when
/// slow, within 0–31.
pub fn next_hsi_trim(trim: u8, error_ppm: i64) -> u8 {
    if error_ppm > HSI_TRIM_DEADBAND_PPM {
        trim.saturating_sub(1)
    } else if error_ppm < -HSI_TRIM_DEADBAND_PPM {
        trim.saturating_add(1).min(31)
    } else {
        trim
    }
}

/// Crystal time of `frames` frames at FPGA decimation `decimation` and base rate `base_rate_millihz`, µs.
fn fpga_time_us(frames: u64, decimation: u16, base_rate_millihz: u64) -> u64 {
    let ticks = u128::from(frames).saturating_mul(u128::from(decimation).saturating_add(1));
    let us = ticks
        .saturating_mul(1_000_000_000)
        .checked_div(u128::from(base_rate_millihz))
        .unwrap_or(0);
    u64::try_from(us).unwrap_or(u64::MAX)
}

/// One trim window: where it started on both clocks.
#[derive(Debug, Clone, Copy)]
struct TrimWindow {
    at: Instant,
    frames: u64,
    decimation: u16,
}

/// One housekeeping period of the HSI trim loop: while frames stream at a steady decimation, compares the FPGA's
/// crystal time (frames counted, lost ones included) with the core's clock over [`HSI_TRIM_WINDOW_S`] and moves
/// HSITRIM one step when the error is beyond [`HSI_TRIM_DEADBAND_PPM`]; returns the window to go on with.
fn trim_hsi<B: core::borrow::BorrowMut<PipelineMemory>>(
    app: &App<B>,
    p: &Pipeline<B>,
    trim: HsiTrim,
    window: Option<TrimWindow>,
    now: Instant,
) -> Option<TrimWindow> {
    let link = p.link_counters();
    let frames = u64::from(link.frames).saturating_add(u64::from(link.frames_dropped));
    if p.mode() != shared::telemetry::Mode::Stream {
        return None;
    }
    let decimation = p.decimation()?;
    let fresh = Some(TrimWindow {
        at: now,
        frames,
        decimation,
    });
    let Some(w) = window.filter(|w| w.decimation == decimation && frames >= w.frames) else {
        return fresh;
    };
    let local_us = now.duration_since(w.at).as_micros();
    if local_us < HSI_TRIM_WINDOW_S.saturating_mul(1_000_000) {
        return window;
    }
    let fpga_us = fpga_time_us(
        frames.saturating_sub(w.frames),
        decimation,
        p.config().fpga_base_rate_millihz,
    );
    if let Some(e) = hsi_error_ppm(fpga_us, local_us) {
        app.hsi_error_ppm.store(
            i32::try_from(e).unwrap_or(if e > 0 { i32::MAX } else { i32::MIN + 1 }),
            Ordering::Relaxed,
        );
        let old = (trim.read)();
        let new = next_hsi_trim(old, e);
        if new != old {
            (trim.write)(new);
            info!("hsi: error {:?} ppm, trim {:?} -> {:?}", e, old, new);
        }
    }
    fresh
}

/// Housekeeping, every [`HOUSEKEEPING_PERIOD`]: a [`HousekeepingReport`](shared::telemetry::HousekeepingReport)
/// (boot facts, error counters by kind, the core's load from the cycle counter, the last calibration store); a
/// Health report while the FPGA link delivers no frame (with frames, the pipeline sends Health every `health_every`
/// outputs), so that the ground sees a silent FPGA; the CRC check of the calibration in RAM, which asks the storage
/// task to reload it on a mismatch. Every `log_every` periods it also logs link counters and a quick-look
/// white-noise level of group 0's gyro x for a human reading the log: micromath's root (≈ ±6 %), marked "≈", never
/// sent — the ground gets exact variances.
pub async fn housekeeping_loop<B>(app: &App<B>, log_every: u32) -> !
where
    B: core::borrow::BorrowMut<PipelineMemory>,
{
    let mut ticker = Ticker::every(HOUSEKEEPING_PERIOD);
    let mut last_frames = None;
    let mut last_busy = app.busy_cycles.load(Ordering::Relaxed);
    let mut last_at = Instant::now();
    let mut n = 0u32;
    let mut crash_loop_over = false;
    let mut trim_window: Option<TrimWindow> = None;
    loop {
        ticker.next().await;
        app.beat(TaskId::Housekeeping).await;
        // The ADC conversions before the pipeline is locked: the link task need not wait for them.
        let sensors = app.platform.mcu_sensors.and_then(|read| read());
        let p = app.pipeline.lock().await;
        let link = *p.link_counters();
        let now = Instant::now();
        if last_frames == Some(link.frames) {
            app.route(Output::Telemetry(Telemetry::Health(p.health())));
            app.count(Counter::SilentHealth);
        }
        // The core's load over the period, from the cycle counter (if the board has one).
        let busy = app.busy_cycles.load(Ordering::Relaxed);
        // At the clock's rate now: a period across a clock switch is off by the switched part (one report).
        let core_hz = app.core_hz.load(Ordering::Relaxed);
        let load = app.platform.cycles.map(|_| {
            let cycles = busy.wrapping_sub(last_busy);
            let period_cycles = now
                .duration_since(last_at)
                .as_micros()
                .saturating_mul(u64::from(core_hz))
                / 1_000_000;
            let permille = u64::from(cycles).saturating_mul(1000)
                / NonZeroU64::new(period_cycles).unwrap_or(NonZeroU64::MIN);
            let frames = link.frames.wrapping_sub(last_frames.unwrap_or(link.frames));
            (
                u16::try_from(permille).unwrap_or(u16::MAX),
                cycles.checked_div(frames),
            )
        });
        (last_busy, last_at) = (busy, now);
        if let Some(trim) = app.platform.hsi_trim {
            trim_window = trim_hsi(app, &p, trim, trim_window, now);
        }
        last_frames = Some(link.frames);
        let hk = app.housekeeping(&p, now, load, sensors);
        app.route(Output::Telemetry(Telemetry::Housekeeping(hk)));
        if let Some(r) = app.platform.resets {
            app.route(Output::Telemetry(Telemetry::Resets(
                r.report(app.platform.boot.safe_mode),
            )));
            if !crash_loop_over && now.as_millis() >= u64::from(crate::resets::SHORT_RUN_MS) {
                r.end_crash_loop();
                crash_loop_over = true;
            }
        }
        app.route(Output::Telemetry(Telemetry::Update(
            app.update_status.lock(Cell::get),
        )));
        app.count(Counter::Housekeeping);
        if !p.calibration_intact() {
            error!("calibration: CRC check of the table in RAM failed; reloading from flash");
            app.reload.signal(());
        }
        let var = p.fusion().noise_var(0, shared::calib::GX);
        drop(p);
        n = n.wrapping_add(1);
        if log_every != 0 && n.is_multiple_of(log_every) {
            info!("link: {:?}", link);
            if let Some(v) = var {
                info!(
                    "group 0 gx white noise per frame ≈ {:?} °/s",
                    micromath::F32Ext::sqrt(v as f32) * 1e-6
                );
            }
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::arithmetic_side_effects)]
mod hsi_tests {
    use shared::pipeline::PipelineConfig;

    use super::{fpga_time_us, hsi_error_ppm, next_hsi_trim};

    /// The error against an f64 reference, and the trim's direction: an HSI 1 % fast (the core's clock counts
    /// 10.1 s while the crystal's frames say 10 s) steps down, one 1 % slow steps up, and the dead band holds.
    #[test]
    fn hsi_error_and_trim_step() {
        let base = PipelineConfig::DEFAULT.fpga_base_rate_millihz;
        // 6 048 frames at decimation 15: exactly 10 s of crystal time.
        let fpga_us = fpga_time_us(6_048, 15, base);
        let reference = 6_048.0 * 16.0 / (base as f64 / 1000.0) * 1e6;
        assert!(
            (fpga_us as f64 - reference).abs() <= 1.0,
            "{fpga_us} vs {reference}"
        );
        for (local_us, ppm) in [
            (10_100_000u64, 10_000i64),
            (9_900_000, -10_000),
            (10_002_000, 200),
        ] {
            let e = hsi_error_ppm(fpga_us, local_us).unwrap();
            let f64_ppm = (local_us as f64 / fpga_us as f64 - 1.0) * 1e6;
            assert!((e as f64 - f64_ppm).abs() < 1.0, "{e} vs {f64_ppm}");
            assert!((e - ppm).abs() <= 1, "{e}");
        }
        assert_eq!(next_hsi_trim(16, 10_000), 15);
        assert_eq!(next_hsi_trim(16, -10_000), 17);
        assert_eq!(next_hsi_trim(16, 2_000), 16);
        assert_eq!(next_hsi_trim(0, 10_000), 0);
        assert_eq!(next_hsi_trim(31, -10_000), 31);
        assert_eq!(hsi_error_ppm(0, 1), None);
    }
}
