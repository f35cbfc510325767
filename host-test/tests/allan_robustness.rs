//! Bad or extreme input must never panic; workspace reuse must not change results.

use host_test::allan::{
    AcfFlavor, Analyzer, DevKind, Options, Phase, TauSpec, acf_noise_id, adev, analyze,
    averaging_factors, b1_noise_id, confidence_interval, edf_for_kind, edf_greenhall, mdev,
    noise_id, oadev,
};

fn uniform(n: usize, seed: u64) -> Vec<f64> {
    let mut rng = host_test::testrng::TestRng::new(seed);
    (0..n).map(|_| rng.uniform() - 0.5).collect()
}

#[test]
fn no_panics_on_small_or_odd_input() {
    let specs = [
        TauSpec::Octave,
        TauSpec::Decade,
        TauSpec::All,
        TauSpec::PerDecade(7),
        TauSpec::PerDecade(0),
        TauSpec::Factors(vec![0, 1, 2, 3, usize::MAX, usize::MAX / 2]),
    ];
    let opts = [
        Options::default(),
        Options {
            acf_flavor: AcfFlavor::Allantools,
            stable32_carry: false,
            ..Options::default()
        },
        Options {
            fixed_alpha: Some(-7),
            ..Options::default()
        },
        Options {
            confidence: 1.5,
            ..Options::default()
        },
    ];
    let mut an = Analyzer::new();
    for n in 0..40 {
        let alt: Vec<f64> = (0..n)
            .map(|i| if i % 2 == 0 { 1.7e308 } else { -1.7e308 })
            .collect();
        let mut series = vec![
            uniform(n, 1),
            vec![0.0; n],
            vec![1e300; n],
            vec![1.7e308; n],
            alt,
        ];
        if n > 2 {
            let mut with_nan = uniform(n, 2);
            with_nan[n / 2] = f64::NAN;
            series.push(with_nan);
            let mut with_inf = uniform(n, 3);
            with_inf[0] = f64::INFINITY;
            series.push(with_inf);
        }
        for y in &series {
            for tau0 in [1.0, 1e-3, 0.0, -1.0, f64::NAN, f64::INFINITY] {
                for kind in DevKind::ALL {
                    for spec in &specs {
                        for o in &opts {
                            let pts = an.analyze(kind, y, tau0, spec, o);
                            for p in &pts {
                                assert!(p.n >= 2 && p.m >= 1);
                            }
                        }
                    }
                    let _ = adev(y, tau0, &[0, 1, 5, usize::MAX]);
                    let _ = oadev(y, tau0, &[1, 2]);
                    let _ = mdev(y, tau0, &[1, 2]);
                    if let Some(ph) = Phase::from_frequency(y, tau0) {
                        for m in [0, 1, 2, n, usize::MAX] {
                            let _ = ph.deviation(kind, m);
                            let _ = b1_noise_id(kind, y, &ph, m);
                            let _ = noise_id(kind, y, &ph, m, AcfFlavor::Stable32);
                        }
                    }
                }
            }
            for m in [0, 1, 3, usize::MAX] {
                let _ = acf_noise_id(y, m, AcfFlavor::Stable32, 2);
                let _ = acf_noise_id(y, m, AcfFlavor::Allantools, 0);
            }
        }
    }
    // B1 with a phase that does not belong to y is refused, not a panic.
    let y = uniform(100, 4);
    let ph = Phase::from_frequency(&y[..50], 1.0).unwrap();
    assert!(b1_noise_id(DevKind::Adev, &y, &ph, 5).is_none());
}

#[test]
fn no_panics_in_edf_and_ci() {
    for alpha in -6..=4 {
        for d in 0..=4 {
            for m in [0usize, 1, 2, 7, 100, 1 << 20, usize::MAX] {
                for n in [0usize, 1, 2, 10, 1000, usize::MAX] {
                    for (ov, md) in [(false, false), (true, false), (true, true), (false, true)] {
                        if let Some(e) = edf_greenhall(alpha, d, m, n, ov, md) {
                            assert!(e.is_finite() && e > 0.0);
                        }
                    }
                }
                for kind in DevKind::ALL {
                    let _ = edf_for_kind(kind, alpha, m, usize::MAX);
                }
            }
        }
    }
    for edf in [1e-300, 1e-3, 0.5, 1.0, 3.0, 1e6, 1e12, f64::INFINITY, -1.0] {
        for ci in [0.0, 1e-9, 0.5, 0.683, 0.999_999, 1.0, f64::NAN] {
            if let Some((lo, hi)) = confidence_interval(2.0, edf, ci) {
                assert!(lo <= 2.0 && 2.0 <= hi, "edf={edf} ci={ci}: {lo} {hi}");
            }
        }
    }
}

#[test]
fn analyzer_reuse_gives_identical_results() {
    let cols: Vec<Vec<f64>> = (0..4)
        .map(|k| uniform(5000 + 37 * k, 10 + k as u64))
        .collect();
    let mut an = Analyzer::new();
    for kind in DevKind::ALL {
        for y in &cols {
            let a = an.analyze(kind, y, 0.01, &TauSpec::Octave, &Options::default());
            let b = analyze(kind, y, 0.01, &TauSpec::Octave, &Options::default());
            assert_eq!(a, b);
            assert_eq!(
                a.len(),
                averaging_factors(&TauSpec::Octave, kind, y.len()).len()
            );
            // white FM: every identified alpha should be 0 (+-1 at the noisiest long taus)
            for p in &a {
                assert!(p.alpha().unwrap().abs() <= 1, "{kind:?} {p:?}");
                assert!(p.dev_lo.unwrap() <= p.dev && p.dev <= p.dev_hi.unwrap());
            }
        }
    }
}

#[test]
fn octave_noise_id_from_the_block_pyramid_equals_the_direct_computation() {
    use host_test::allan::{AcfFlavor, Phase, noise_id};
    // White noise plus a random walk, so that several noise types occur along the octaves.
    let w = uniform(1 << 15, 11);
    let mut acc = 0.0;
    let y: Vec<f64> = w
        .iter()
        .map(|x| {
            acc += 0.02 * x;
            x + acc
        })
        .collect();
    for kind in [DevKind::Adev, DevKind::Oadev, DevKind::Mdev] {
        let pts = analyze(
            kind,
            &y,
            0.1,
            &TauSpec::Octave,
            &Options {
                stable32_carry: false,
                ..Options::default()
            },
        );
        let phase = Phase::from_frequency(&y, 0.1).unwrap();
        for p in &pts {
            let direct = noise_id(kind, &y, &phase, p.m, AcfFlavor::Stable32);
            assert_eq!(
                p.noise.map(|n| n.alpha),
                direct.map(|n| n.alpha),
                "{kind:?} m = {}",
                p.m
            );
            if let (Some(a), Some(b)) = (p.noise.and_then(|n| n.acf), direct.and_then(|n| n.acf)) {
                assert!(
                    (a.delta - b.delta).abs() <= 1e-9 * (1.0 + b.delta.abs()),
                    "{kind:?} m = {}",
                    p.m
                );
            }
        }
    }
}
