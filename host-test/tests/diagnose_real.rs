//! `ground diagnose` on the real MIMU4444 records (`../shared/data/mimu4444`, or `MIMU4444_DIR`): the longest static
//! interval of each experiment, in the cluster frame through its own static calibration — the numbers of the
//! real-data table in `docs/diagnose.md`. Skipped, with a message, when the data are absent.

mod common;

use host_test::calibrate::{DetectOptions, StaticCalOptions, calibrate_static, detect_static};
use host_test::diagnose::{Options, diagnose};

#[test]
fn diagnose_real_mimu4444_records() {
    let Some(dir) = common::mimu4444_dir("diagnose_real_mimu4444_records") else {
        return;
    };
    for e in 1..=6 {
        let m = host_test::formats::mimu::read(dir.join(format!("exp_{e}/data.bin"))).unwrap();
        let poses = detect_static(&m, &DetectOptions::default()).unwrap();
        let cal = calibrate_static(&poses, &StaticCalOptions::default()).unwrap();
        let table = cal.to_table::<{ host_test::load::MIMU_IMUS }>(e).unwrap();
        // As `ground diagnose --longest-static`: the interval's longest part without shared disturbances.
        let ls = host_test::diagnose::quiet::longest_static(
            &m,
            &host_test::load::mimu_recording(&m, Some(&table)),
            Options::default().p_false,
        )
        .unwrap()
        .unwrap_or_else(|| panic!("exp_{e}: no static interval"));
        let (p, rec, disturbances) = (&ls, &ls.quiet, &ls.disturbances);
        eprintln!(
            "exp_{e}: static {:.3} … {:.3} s, diagnosed {:.3} … {:.3} s; disturbances {disturbances:?}",
            p.start_s,
            p.end_s,
            rec.t_s[0],
            rec.t_s[rec.len() - 1]
        );
        let r = diagnose(rec, &Options::default()).unwrap();
        let effects: Vec<String> = r
            .effects
            .iter()
            .map(|x| {
                let periods: Vec<String> = x
                    .params
                    .values()
                    .filter_map(|p| p["period_s"].as_f64())
                    .map(|p| format!("{p:.3}"))
                    .collect();
                format!("{} {} {} {}", x.kind, x.sensor, x.axes, periods.join("/"))
            })
            .collect();
        let misfit: Vec<String> = r
            .axes
            .iter()
            .map(|a| {
                format!(
                    "{} {:.2}->{:.2} bw {}",
                    a.axis,
                    a.model_misfit,
                    a.model_misfit_band_limited,
                    a.bandwidth_hz
                        .map_or("none".to_string(), |f| format!("{f:.1} Hz"))
                )
            })
            .collect();
        let groups: Vec<String> = r
            .effects
            .iter()
            .map(|x| format!("{} {}{} {}", x.kind, x.sensor, x.axes, x.groups))
            .collect();
        eprintln!("exp_{e}: groups {groups:?}");
        eprintln!(
            "exp_{e}: {} samples, held-out excess gap {:.3} -> {:.3}; effects {effects:?}; model misfit {misfit:?}",
            r.samples, r.heldout.gap_before, r.heldout.gap_after
        );
        // The lines found in these records are single sensors' own (per-sensor spectra: narrow lines 10-500x the
        // neighbouring bins, at the background's coherence with the other sensors), never a shared sinusoid.
        for f in &r.fitted {
            for (kind, c) in &f.cross {
                assert!(
                    !matches!(c, host_test::diagnose::model::Cross::SharedSine { .. }),
                    "exp_{e}: a shared {kind} on {:?} {}",
                    f.kind,
                    f.axis
                );
            }
        }
        // Issue 28 item 4: what the model leaves of the held-out gap on these real records.
        assert!(r.heldout.gap_after <= 0.05, "exp_{e}: {:?}", r.heldout);
        // The model with the effects never predicts the held-out half worse than the sqrt(N) model.
        assert!(
            r.heldout.gap_after <= r.heldout.gap_before + 1e-12,
            "exp_{e}: {:?}",
            r.heldout
        );
    }
}
