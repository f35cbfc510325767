use super::*;
use crate::formats::csv::Column;

fn gauss(seed: u64) -> impl FnMut() -> f64 {
    let mut s = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15) | 1;
    move || {
        let mut u = || {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            (s >> 11) as f64 / (1u64 << 53) as f64 + 1e-18
        };
        (-2.0 * u().ln()).sqrt() * (2.0 * std::f64::consts::PI * u()).cos()
    }
}

/// 16 groups of white noise; gyro axes get `rho` of common-mode noise.
fn cluster(n: usize, rho: f64, seed: u64) -> Recording {
    let mut rec = Recording {
        t_s: (0..n).map(|i| i as f64 * 0.05).collect(),
        ..Default::default()
    };
    let mut common = gauss(seed ^ 0xABCD);
    let shared: Vec<Vec<f64>> = (0..3).map(|_| (0..n).map(|_| common()).collect()).collect();
    for g in 0..16 {
        let mut r = gauss(seed + g as u64);
        for (axis, common) in shared.iter().enumerate() {
            let gyro = (0..n)
                .map(|k| 0.4 * ((1.0 - rho).sqrt() * r() + rho.sqrt() * common[k]))
                .collect();
            rec.columns.push(Column {
                group: g,
                kind: SensorKind::Gyro,
                axis,
                data: gyro,
            });
            let accel = (0..n).map(|_| 0.004 * r()).collect();
            rec.columns.push(Column {
                group: g,
                kind: SensorKind::Accel,
                axis,
                data: accel,
            });
        }
    }
    rec
}

#[test]
fn clean_cluster_has_no_effect_and_no_significant_gap() {
    let r = diagnose(&cluster(40_000, 0.0, 1), &Options::default()).unwrap();
    assert!(r.effects.is_empty(), "{:?}", r.effects);
    assert!(r.heldout.gap_before < 0.05, "{}", r.heldout.gap_before);
    for a in &r.axes {
        assert!(
            (a.rms_gain.value / 4.0 - 1.0).abs() < 0.05,
            "{} {:?}",
            a.axis,
            a.rms_gain
        );
    }
}

#[test]
fn common_mode_white_is_found_on_the_gyros_only() {
    let rho = 0.1;
    let r = diagnose(&cluster(40_000, rho, 2), &Options::default()).unwrap();
    let cm: Vec<&Effect> = r
        .effects
        .iter()
        .filter(|e| e.kind == "common_mode")
        .collect();
    assert_eq!(cm.len(), 1, "{:?}", r.effects);
    assert_eq!(
        (
            cm[0].sensor.as_str(),
            cm[0].axes.as_str(),
            cm[0].groups.len()
        ),
        ("gyro", "xyz", 16)
    );
    let fitted = cm[0].params["x"]["rho_white"].as_f64().unwrap();
    assert!((fitted / rho - 1.0).abs() < 0.25, "rho {fitted}");
    assert!(
        r.heldout.gap_after < 0.2 * r.heldout.gap_before,
        "{:?}",
        r.heldout
    );
    // Gain with common mode: √(16 / (1 + 15ρ)) = 2.53.
    let gx = &r.axes[0];
    let expected = (16.0 / (1.0 + 15.0 * rho)).sqrt();
    assert!(
        (gx.rms_gain.value / expected - 1.0).abs() < 0.05,
        "{:?}",
        gx.rms_gain
    );
    assert!(r.effects.iter().all(|e| e.sensor == "gyro"));
}
