//! The demo's diagnosis: `ground diagnose` on the simulated record, then the twin's loop (`twin::close_the_loop`);
//! the same on a real cluster's record (the MIMU4444 excerpt built in).

use super::DemoError;
use crate::diagnose::{Effect, Options, Report, diagnose, report};
use crate::recording::Recording;

/// What the demo keeps of its diagnosis.
pub(super) struct Diagnosed {
    /// One line per effect named.
    pub lines: Vec<String>,
    /// The axis with the largest shared-flicker share, and that share.
    pub largest_shared_flicker: Option<(String, f64)>,
    /// The twin's loop.
    pub twin: crate::twin::LoopSummary,
}

/// `ground diagnose` on the demo's record (the simulated samples, physical units): report, plot and JSON in `dir`;
/// then the twin's loop in `twin_dir`.
pub(super) fn of_record(
    rec: &Recording,
    dir: &std::path::Path,
    twin_dir: &std::path::Path,
) -> Result<Diagnosed, DemoError> {
    let r = diagnose(rec, &Options::default())?;
    report::write(&r, dir, "the demo's simulated record")?;
    let twin = crate::twin::close_the_loop(rec, &r, "the demo's record", twin_dir, 2, &[])?;
    DemoError::write(
        &dir.join("diagnose.json"),
        serde_json::to_string_pretty(&r)?,
    )?;
    Ok(Diagnosed {
        lines: r.effects.iter().map(effect_line).collect(),
        largest_shared_flicker: largest_shared_flicker(&r),
        twin,
    })
}

/// A real cluster's record for the demo's real-data twin: exp_6 of the MIMU4444 array recordings (8 IMUs, 62.5 Hz;
/// Carlsson, Skog, Jaldén 2021, MIT licence: `testdata/mimu4444/`), its longest static interval (frames 29 620 to
/// 31 240, 473.92–499.84 s, the interval `ground diagnose --longest-static` finds), cut unchanged from the stream.
pub const REAL_EXCERPT: &[u8] = include_bytes!("../../../testdata/mimu4444/exp6_static.bin");

/// The real-data twin: the record's size and the loop.
#[derive(Clone, Debug, serde::Serialize)]
pub struct RealTwin {
    /// IMUs in the array.
    pub imus: usize,
    /// Samples in the interval.
    pub samples: usize,
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// The twin with and without its effects against the record.
    pub twin: crate::twin::LoopSummary,
}

/// How the real excerpt is named in the reports.
const REAL_SOURCE: &str = "MIMU4444 exp_6, longest static interval";

/// The loop on a real cluster: the excerpt at the IMUs' nominal scales, diagnosed (report, plot and JSON in
/// `dir/diagnose`), its twin fitted, played with and without effects and compared with the record (`dir/twin`).
pub(super) fn of_real_excerpt(dir: &std::path::Path) -> Result<RealTwin, DemoError> {
    let stream = crate::formats::mimu::parse(REAL_EXCERPT)?;
    let rec = crate::load::mimu_recording(&stream, None);
    let r = diagnose(&rec, &Options::default())?;
    let diag = dir.join("diagnose");
    report::write(&r, &diag, REAL_SOURCE)?;
    DemoError::write(
        &diag.join("diagnose.json"),
        serde_json::to_string_pretty(&r)?,
    )?;
    // The fit checked against 19 records played from the model (a p-value to 0.05; about 4 s).
    let check_seeds: Vec<u64> = (1..=19).collect();
    let twin =
        crate::twin::close_the_loop(&rec, &r, REAL_SOURCE, &dir.join("twin"), 2, &check_seeds)?;
    Ok(RealTwin {
        imus: stream.frames.first().map_or(0, |f| f.imu.len()),
        samples: rec.len(),
        rate_hz: rec.sample_interval_s().map_or(0.0, |dt| 1.0 / dt),
        twin,
    })
}

/// The axis (`gyro y`, …) with the largest fitted shared-flicker share ρ_flicker, and that share.
fn largest_shared_flicker(r: &Report) -> Option<(String, f64)> {
    r.effects
        .iter()
        .flat_map(|e| {
            e.params.iter().filter_map(|(axis, p)| {
                Some((
                    format!("{} {axis}", e.sensor),
                    p.get("rho_flicker")?.as_f64()?,
                ))
            })
        })
        .max_by(|a, b| a.1.total_cmp(&b.1))
}

/// One summary line of an effect.
fn effect_line(e: &Effect) -> String {
    let rho = |key: &str| -> String {
        e.params
            .iter()
            .filter_map(|(axis, p)| Some(format!("{axis} {:.3}", p.get(key)?.as_f64()?)))
            .collect::<Vec<_>>()
            .join(", ")
    };
    format!(
        "`{}` {} {}: acts in the {} region, τ {:.2}–{:.0} s, up to {:.0} % of the cluster's Allan variance; ρ_white {}; ρ_flicker {}",
        e.kind,
        e.sensor,
        e.axes,
        e.region,
        e.tau_s[0],
        e.tau_s[1],
        100.0 * e.share,
        rho("rho_white"),
        rho("rho_flicker")
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The built-in real excerpt is exp_6's longest static interval, and its twin with the effects found is told
    /// apart on fewer axes than the √N model (measured: 3 against 5; the `ground demo` figures of `docs/twin.md`).
    #[test]
    fn the_real_twin_with_its_effects_beats_the_sqrt_n_model() {
        let dir = std::env::temp_dir().join(format!("demo-real-{}", std::process::id()));
        let real = of_real_excerpt(&dir).unwrap();
        let _ = std::fs::remove_dir_all(&dir);
        assert_eq!((real.imus, real.samples), (8, 1621));
        // The fit checked on 19 records of its own model: every one diagnosed and fitted, a p-value in (0, 1].
        let fit = &real.twin.fit;
        assert_eq!(fit.replicas.len(), 19, "{fit:?}");
        assert!(
            fit.record.1 > 0 && fit.replicas.iter().all(|r| r.1 == fit.record.1),
            "{fit:?}"
        );
        assert!(fit.p_value.is_some_and(|p| p > 0.0 && p <= 1.0), "{fit:?}");
        assert!((real.rate_hz - 62.5).abs() < 1e-9, "{}", real.rate_hz);
        let t = &real.twin;
        assert!(
            t.effects.iter().any(|e| e.starts_with("periodic")),
            "{:?}",
            t.effects
        );
        assert!(
            t.with_effects.len() < t.without_effects.len(),
            "{:?} vs {:?}",
            t.with_effects,
            t.without_effects
        );
        assert!(t.with_effects_scan < t.without_effects_scan);
    }
}
