//! The demo's diagnosis: `ground diagnose` on the simulated record, then the twin's loop (`twin::close_the_loop`).

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
    let twin = crate::twin::close_the_loop(rec, &r, "the demo's record", twin_dir, 2)?;
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
