use super::*;
use crate::calib::{AX, GX, RawCounts};
use crate::testutil::{Rng, mean, rms};

extern crate std;
use std::vec::Vec;

const G: usize = 16;
const SIGMA_UDPS: f64 = 100_000.0; // 0.1 °/s per sensor
const SIGMA_UG: f64 = 5_000.0; // 5 mg

/// A scenario: per group a noise multiplier and a bias per axis, plus an optional stuck group.
struct Scenario {
    noise: [f64; G],
    bias: [[f64; AXES]; G],
    stuck: Option<usize>,
    saturated: Option<usize>,
}

impl Scenario {
    fn clean() -> Self {
        Self {
            noise: [1.0; G],
            bias: [[0.0; AXES]; G],
            stuck: None,
            saturated: None,
        }
    }

    /// Runs `n` samples through a fusion with `config`; returns the fused gx and ax series and the last sample.
    fn run(
        &self,
        config: FusionConfig,
        n: usize,
        seed: u64,
    ) -> (Fusion<G>, Vec<f64>, Vec<f64>, FusedSample) {
        let table = CalibrationTable::<G>::factory();
        let mut fusion = Fusion::<G>::new(config);
        let mut rng = Rng::new(seed);
        let (mut gx, mut ax) = (Vec::new(), Vec::new());
        let mut last = FusedSample::default();
        for _ in 0..n {
            let mut raw = [RawCounts::default(); G];
            let mut axes = [[0i32; AXES]; G];
            for g in 0..G {
                for (a, (x, b)) in axes[g].iter_mut().zip(self.bias[g]).enumerate() {
                    let sigma = if a < 3 { SIGMA_UDPS } else { SIGMA_UG };
                    *x = (b + self.noise[g] * sigma * rng.normal()).round() as i32;
                }
                let code = |x: i32| 30_000 + x.rem_euclid(20_000);
                raw[g] = RawCounts {
                    gyro: [
                        code(axes[g][0]),
                        code(axes[g][1]),
                        code(axes[g][2]),
                        30_000 + (g as i32),
                    ],
                    accel: [code(axes[g][3]), code(axes[g][4]), code(axes[g][5])],
                };
                // the fourth gyro channel is constant above: make it vary too
                raw[g].gyro[3] = code(axes[g][0] / 3 + axes[g][2]);
                if self.stuck == Some(g) {
                    axes[g] = [2_000_000, 0, 0, 0, 0, 0];
                    raw[g] = RawCounts {
                        gyro: [31_000; 4],
                        accel: [24_000; 3],
                    };
                }
                if self.saturated == Some(g) {
                    raw[g].gyro[1] = 65_535;
                }
            }
            last = fusion.fuse(&raw, &axes, &table);
            gx.push(f64::from(last.axes[GX]));
            ax.push(f64::from(last.axes[AX]));
        }
        (fusion, gx, ax, last)
    }
}

const PLAIN_EQUAL: FusionConfig = FusionConfig {
    mode: FusionMode::Equal,
    robust: false,
    ..FusionConfig::DEFAULT
};
const PLAIN_WEIGHTED: FusionConfig = FusionConfig {
    mode: FusionMode::InverseVariance,
    robust: false,
    ..FusionConfig::DEFAULT
};

/// `reset` in place gives the state of a new fusion with the same parameters: the same samples then fuse to the same
/// outputs, weights and fault counts (a history the reset missed, e.g. the noise estimates or the stuck watch, would
/// change them).
#[test]
fn reset_in_place_equals_a_new_fusion() {
    let mut s = Scenario::clean();
    s.noise[3] = 8.0;
    s.stuck = Some(6);
    let config = FusionConfig::DEFAULT;
    let (mut used, ..) = s.run(config, 3_000, 1);
    used.reset();
    let fresh = Fusion::<G>::new(config);
    let again = |mut f: Fusion<G>| {
        let table = CalibrationTable::<G>::factory();
        let mut rng = Rng::new(9);
        let mut out = Vec::new();
        for i in 0..600 {
            let mut raw = [RawCounts::default(); G];
            let mut axes = [[0i32; AXES]; G];
            for g in 0..G {
                for x in axes[g].iter_mut() {
                    *x = (SIGMA_UDPS * rng.normal()).round() as i32 + if g == 3 { 900 } else { 0 };
                }
                let c = 30_000 + (i % 7) + g as i32;
                raw[g] = RawCounts {
                    gyro: [c; 4],
                    accel: [c; 3],
                };
            }
            out.push(f.fuse(&raw, &axes, &table));
        }
        let faults: Vec<_> = (0..G).map(|g| f.fault_counts(g)).collect();
        (out, faults)
    };
    assert_eq!(again(used), again(fresh));
}

#[test]
fn clean_cluster_gains_sqrt_n() {
    let (_, gx, _, last) = Scenario::clean().run(PLAIN_EQUAL, 20_000, 1);
    let gain = SIGMA_UDPS / rms(&gx);
    assert!((gain - 4.0).abs() < 0.1, "gain {gain}");
    assert_eq!(last.used, [16; AXES]);
}

#[test]
fn noisy_sensor_weighted_beats_equal_by_expected_factor() {
    let mut s = Scenario::clean();
    s.noise[5] = 10.0;
    let warm = 1 << 12;
    let (_, eq, _, _) = s.run(PLAIN_EQUAL, 60_000, 2);
    let (fusion, w, _, _) = s.run(PLAIN_WEIGHTED, 60_000, 2);
    let ratio = rms(&eq[warm..]) / rms(&w[warm..]);
    std::println!("weighted vs equal: {ratio:.3}");
    // Equal: σ²(15 + 100)/256; optimal weights: σ²/(15 + 1/100). Ratio of deviations √6.7428 = 2.597.
    let expected = ((15.0 + 100.0) / 256.0 * (15.0 + 0.01f64)).sqrt();
    assert!(
        (ratio / expected - 1.0).abs() < 0.03,
        "ratio {ratio:.3}, expected {expected:.3}"
    );
    // The estimates see the noisy sensor ~100× noisier; its weight is ~1/100 of the best.
    let (v0, v5) = (
        fusion.noise_var(0, GX).unwrap() as f64,
        fusion.noise_var(5, GX).unwrap() as f64,
    );
    assert!(
        (60.0..160.0).contains(&(v5 / v0)),
        "variance ratio {}",
        v5 / v0
    );
    assert!((400..1300).contains(&fusion.weight_q16(5, GX).unwrap()));
}

#[test]
fn stuck_sensor_is_left_out_and_counted() {
    let mut s = Scenario::clean();
    s.stuck = Some(3);
    let n = 10_000;
    let (_, eq, _, _) = s.run(PLAIN_EQUAL, n, 3);
    let (fusion, robust, _, last) = s.run(FusionConfig::DEFAULT, n, 3);
    // The dead gyro reads a constant 2 °/s: the equal mean carries 2/16 °/s of it, the robust mean none.
    assert!(
        (mean(&eq) - 125_000.0).abs() < 3_000.0,
        "equal mean {}",
        mean(&eq)
    );
    let tol = 4.0 * SIGMA_UDPS / (15.0 * n as f64).sqrt();
    assert!(
        mean(&robust[100..]).abs() < tol,
        "robust mean {}",
        mean(&robust[100..])
    );
    assert_eq!(last.health.gyro.stuck, 1 << 3);
    assert_eq!(last.health.accel.stuck, 1 << 3);
    assert_eq!(last.used, [15; AXES]);
    let window = u32::from(FusionConfig::DEFAULT.stuck_window);
    assert_eq!(
        fusion.fault_counts(3).unwrap()[0].stuck,
        n as u32 - window + 1
    );
}

#[test]
fn biased_sensor_is_an_outlier() {
    let mut s = Scenario::clean();
    s.bias[7][AX] = 50_000.0; // 50 mg = 10 σ
    let n = 10_000;
    let (_, _, eq, _) = s.run(PLAIN_EQUAL, n, 4);
    let (fusion, _, robust, last) = s.run(FusionConfig::DEFAULT, n, 4);
    assert!(
        (mean(&eq) - 50_000.0 / 16.0).abs() < 150.0,
        "equal mean {}",
        mean(&eq)
    );
    assert!(
        mean(&robust).abs() < 4.0 * SIGMA_UG / (15.0 * n as f64).sqrt(),
        "robust mean {}",
        mean(&robust)
    );
    assert_eq!(last.used[AX], 15);
    assert_eq!(last.health.accel.outlier, 1 << 7);
    // Clean sensors are almost never called outliers at 6 σ.
    let clean_outliers: u32 = (0..G)
        .filter(|&g| g != 7)
        .map(|g| fusion.fault_counts(g).unwrap()[1].outlier)
        .sum();
    assert!(clean_outliers < 20, "{clean_outliers}");
    assert!(fusion.fault_counts(7).unwrap()[1].outlier > n as u32 - 10);
}

#[test]
fn saturated_sensor_is_left_out() {
    let mut s = Scenario::clean();
    s.saturated = Some(9);
    let (fusion, _, _, last) = s.run(FusionConfig::DEFAULT, 100, 5);
    assert_eq!(last.health.gyro.saturated, 1 << 9);
    assert_eq!(last.health.accel.saturated, 0);
    assert_eq!(&last.used[..3], &[15; 3]);
    assert_eq!(fusion.fault_counts(9).unwrap()[0].saturated, 100);
}

#[test]
fn all_sensors_failed_gives_an_invalid_sample() {
    let table = CalibrationTable::<G>::factory();
    let mut fusion = Fusion::<G>::new(FusionConfig::DEFAULT);
    let raw = [RawCounts {
        gyro: [0; 4],
        accel: [65_535; 3],
    }; G];
    let out = fusion.fuse(&raw, &[[123; AXES]; G], &table);
    assert!(!out.valid());
    assert_eq!(out.used, [0; AXES]);
    assert_eq!(out.axes, [0; AXES]);
    assert_eq!(out.health.gyro.saturated, 0xFFFF);
}

/// `fuse_into` writes every field of its slot: into a slot full of another sample's values (all bits set) it gives
/// what `fuse` gives, for a clean sample and for one with faults, with and without fault exclusion.
#[test]
fn fuse_into_overwrites_the_whole_slot() {
    let table = CalibrationTable::<G>::factory();
    let ones = SensorFaults {
        saturated: u32::MAX,
        stuck: u32::MAX,
        outlier: u32::MAX,
    };
    let garbage = FusedSample {
        axes: [-1; AXES],
        used: [u8::MAX; AXES],
        used_mask: [u32::MAX; AXES],
        health: HealthMask {
            gyro: ones,
            accel: ones,
        },
    };
    let clean = [RawCounts {
        gyro: [19_680; 4],
        accel: [24_000; 3],
    }; G];
    let mut railed = clean;
    railed[3].accel[1] = 65_535;
    for robust in [true, false] {
        let config = FusionConfig {
            robust,
            ..FusionConfig::DEFAULT
        };
        let (mut a, mut b) = (Fusion::<G>::new(config), Fusion::<G>::new(config));
        for raw in [clean, railed, clean] {
            let axes = [[1_000; AXES]; G];
            let mut slot = garbage;
            a.fuse_into(&raw, &axes, &table, &mut slot);
            assert_eq!(slot, b.fuse(&raw, &axes, &table), "robust {robust}");
        }
    }
}

#[test]
fn helpers_round_and_take_medians() {
    assert_eq!(div_round(7, 2), 4);
    assert_eq!(div_round(-7, 2), -4);
    assert_eq!(div_round(5, 3), 2);
    assert_eq!(div_round(i64::MAX / 2, 1), i32::MAX);
    assert_eq!(median_sorted(&[1, 2, 10]), 2);
    assert_eq!(median_sorted(&[1, 2, 3, 10]), 3); // (2 + 3) / 2 = 2.5 → 3
    assert_eq!(median_sorted(&[]), 0);
}

/// The reference the fast helpers replace: sort, median, then a second sort of the deviations.
fn reference_median_mad(v: &[i32]) -> (i32, i32) {
    let mut sorted = v.to_vec();
    sorted.sort_unstable();
    let median = median_sorted(&sorted);
    let mut dev: Vec<i32> = sorted
        .iter()
        .map(|&x| {
            (i64::from(x) - i64::from(median))
                .unsigned_abs()
                .min(i32::MAX as u64) as i32
        })
        .collect();
    dev.sort_unstable();
    (median, median_sorted(&dev))
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(20000))]

    /// The sorting network and the MAD by selection give exactly the sort-based results, ties and extremes included.
    #[test]
    fn network_sort_and_mad_selection_match_the_reference(
        values in proptest::collection::vec(
            proptest::prop_oneof![-3i32..3, proptest::prelude::any::<i32>(), proptest::strategy::Just(i32::MAX),
                                  proptest::strategy::Just(i32::MIN)],
            0..=16,
        ),
    ) {
        let n = values.len();
        let mut padded = [i32::MAX; 16];
        padded[..n].copy_from_slice(&values);
        sort_small(&mut padded);
        let mut sorted = values.clone();
        sorted.sort_unstable();
        proptest::prop_assert_eq!(&padded[..n], &sorted[..]);
        if n > 0 {
            let (median, mad) = reference_median_mad(&values);
            proptest::prop_assert_eq!(median_sorted(&padded[..n]), median);
            proptest::prop_assert_eq!(mad_sorted(&padded, n, median), mad);
        }
    }
}

#[test]
fn fault_counts_add_per_group_bits_and_wrap() {
    let h = SensorFaults {
        saturated: 1 << 31,
        stuck: 0b101,
        outlier: 0b100,
    };
    assert_eq!(
        h.counts_of(2),
        FaultCounts {
            saturated: 0,
            stuck: 1,
            outlier: 1
        }
    );
    assert_eq!(h.counts_of(31).saturated, 1);
    assert_eq!(h.counts_of(32), FaultCounts::default());
    let mut c = FaultCounts {
        saturated: u32::MAX,
        stuck: 7,
        outlier: 0,
    };
    c.add(&h.counts_of(31));
    c.add(&h.counts_of(0));
    assert_eq!(
        c,
        FaultCounts {
            saturated: 0,
            stuck: 8,
            outlier: 0
        }
    );
}

/// The table's fixed weights: the weighted mean over the sensors in use, renormalised when one is excluded, and the
/// equal mean where the weights in use do not sum to a positive value.
#[test]
fn fixed_weights_are_renormalised_over_the_sensors_in_use() {
    let mut table = CalibrationTable::<G>::factory();
    let mut axes = [[0i32; AXES]; G];
    for (g, a) in axes.iter_mut().enumerate() {
        a[GX] = 1000 * g as i32;
        a[AX] = 7;
    }
    // gx: group g weighted g + 1 (Q16 units of 1/16); ax: only group 0 positive, the others zero.
    for (g, w) in table.weights_q16.iter_mut().enumerate() {
        w[GX] = 4096 * (g as i32 + 1);
        w[AX] = if g == 0 { 1 << 16 } else { 0 };
    }
    let raw = [RawCounts {
        gyro: [20_000; 4],
        accel: [24_000; 3],
    }; G];
    let config = FusionConfig {
        mode: FusionMode::Fixed,
        robust: false,
        ..FusionConfig::DEFAULT
    };
    let mut f = Fusion::<G>::new(config);
    let s = f.fuse(&raw, &axes, &table);
    // Σ (g+1)·1000g / Σ (g+1), g = 0..15: 1000 · Σ g(g+1) / Σ (g+1) = 1000 · 1360 / 136 = 10 000.
    assert_eq!(s.axes[GX], 10_000);
    assert_eq!(s.axes[AX], 7);
    // Group 15 (the heaviest) excluded: its weight is shared in proportion: 1000 · Σ_{g<15} g(g+1) / Σ_{g<15}(g+1)
    // = 1000 · 1120 / 120 = 9333.33… → 9333.
    f.set_config(FusionConfig {
        excluded: [1 << 15, 1],
        ..config
    });
    let s = f.fuse(&raw, &axes, &table);
    assert_eq!(s.axes[GX], 9333);
    assert_eq!(s.used[GX], 15);
    // ax: the only weighted sensor is excluded; the equal mean of the rest.
    assert_eq!(s.axes[AX], 7);
    assert_eq!(s.used[AX], 15);
    // Without weights in the table, Fixed is the equal mean.
    let s = f.fuse(&raw, &axes, &CalibrationTable::factory());
    assert_eq!(s.axes[GX], 7000); // mean of 0..14 thousand
}
