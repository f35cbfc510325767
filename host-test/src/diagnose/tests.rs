use super::candidates::blocks;
use super::prediction::octave_corr;
use super::*;
use crate::allan::acov::AllanCov;
use crate::allan::{chi2_z, median_to_mean};
use crate::formats::csv::{Column, Recording, SensorKind};

fn gauss(seed: u64) -> impl FnMut() -> f64 {
    let mut rng = crate::testrng::TestRng::new(seed);
    move || rng.normal()
}

/// 16 groups of white noise; gyro axes get `rho` of common-mode noise.
pub(super) fn cluster(n: usize, rho: f64, seed: u64) -> Recording {
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
            cm[0].groups.flat().len()
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

#[test]
fn chi2_z_is_exact_for_two_degrees_of_freedom() {
    // χ²₂/2 has CDF 1 − e^(−x): the z-score of ratio r is Φ⁻¹(1 − e^(−r)), in both tails.
    use statrs::distribution::{ContinuousCDF, Normal};
    let n = Normal::new(0.0, 1.0).unwrap();
    for r in [0.01f64, 0.3, 1.0, 2.5, 9.0, 30.0] {
        // Each tail computed where it is accurate: P(X ≤ r) = −expm1(−r), P(X > r) = e^(−r).
        let want = if r > 1.0 {
            -n.inverse_cdf((-r).exp())
        } else {
            n.inverse_cdf(-(-r).exp_m1())
        };
        assert!((chi2_z(r, 2.0) - want).abs() < 1e-6, "r {r}");
    }
    // Far in the upper tail (p = e^−60) the value is still exact, not clamped.
    let far = -n.inverse_cdf((-60.0f64).exp());
    assert!((chi2_z(60.0, 2.0) - far).abs() < 1e-4);
}

#[test]
fn median_of_variance_estimates_is_corrected_to_their_mean() {
    // The median of χ²₂ is 2 ln 2.
    assert!((median_to_mean(2.0) - 1.0 / std::f64::consts::LN_2).abs() < 1e-9);
    assert!((median_to_mean(1e4) - 1.0).abs() < 1e-3);
}

#[test]
fn scan_of_one_point_is_the_normal_quantile() {
    // One z-score: the statistic is z itself, so the Monte Carlo threshold is Φ⁻¹(1 − p) (40,000 draws).
    use statrs::distribution::{ContinuousCDF, Normal};
    let want = Normal::new(0.0, 1.0).unwrap().inverse_cdf(0.99);
    assert!((scan_threshold(1, 0.01) - want).abs() < 0.05);
    // More points, more windows: a higher threshold.
    assert!(scan_threshold(16, 0.01) > scan_threshold(4, 0.01) + 0.2);
    // Windows: a two-point bump is found as one window.
    let z = [0.0, 0.0, 3.0, 3.0, 0.0];
    let var = 2.0 + 2.0 * octave_corr(1);
    assert!((scan_statistic(&z) - 6.0 / var.sqrt()).abs() < 1e-12);
}

#[test]
fn blocks_are_found_by_clustering_the_correlation() {
    // 12 sensors of white noise; sensors 0–3 and 4–7 each share a process (ρ 0.3); 8–11 are independent.
    let n = 40_000;
    let mut g = gauss(77);
    let shared: Vec<Vec<f64>> = (0..2).map(|_| (0..n).map(|_| g()).collect()).collect();
    let series: Vec<Vec<f64>> = (0..12)
        .map(|i| {
            let mut r = gauss(100 + i as u64);
            (0..n)
                .map(|k| match i / 4 {
                    b @ (0 | 1) => 0.3f64.sqrt() * shared[b][k] + 0.7f64.sqrt() * r(),
                    _ => r(),
                })
                .collect()
        })
        .collect();
    let refs: Vec<&[f64]> = series.iter().map(Vec::as_slice).collect();
    let ac = AllanCov::compute(&refs, 1.0, 30);
    let levels: Vec<(usize, f64)> = (0..ac.tau_s.len())
        .filter(|&l| ac.terms[l] >= 30)
        .map(|l| (l, ac.terms[l] as f64))
        .collect();
    let cl: Vec<Vec<usize>> = blocks(&ac, &levels, Options::default().merge_z)
        .into_iter()
        .filter(|c| c.len() >= 2)
        .collect();
    assert_eq!(cl, vec![vec![0, 1, 2, 3], vec![4, 5, 6, 7]]);
}

#[test]
fn trigamma_matches_its_closed_forms() {
    // ψ′(1) = π²/6, ψ′(1/2) = π²/2, ψ′(n + 1) = ψ′(n) − 1/n² (Abramowitz & Stegun 6.4.2, 6.4.4, 6.4.6).
    let pi2 = std::f64::consts::PI.powi(2);
    for (x, want) in [
        (1.0, pi2 / 6.0),
        (0.5, pi2 / 2.0),
        (2.0, pi2 / 6.0 - 1.0),
        (4.0, pi2 / 6.0 - 1.0 - 0.25 - 1.0 / 9.0),
    ] {
        let got = sensors::trigamma(x);
        assert!(
            (got / want - 1.0).abs() < 1e-9,
            "ψ′({x}) = {got}, want {want}"
        );
    }
    // Large x: x ψ′(x) = 1 + 1/(2x) + 1/(6x²) + O(x⁻⁴).
    let x = 1e4;
    assert!((sensors::trigamma(x) * x - 1.0 - 0.5 / x - 1.0 / (6.0 * x * x)).abs() < 1e-13);
}
