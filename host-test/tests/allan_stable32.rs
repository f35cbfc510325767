//! Comparison with Stable32 1.60 results for the OCXO record (tests/fixtures, see README.md).

mod common;

use common::{S32Row, ocxo_hz, ocxo_y, rel, stable32};
use host_test::allan::{
    AcfFlavor, AnalysisPoint, DevKind, NoiseIdMethod, Options, Phase, TauSpec, analyze,
};

const TAU0: f64 = 1.0;

/// (file, kind, dev tolerance). The two `.001` octave runs of OADEV/MDEV carry a Stable32
/// rounding artefact of up to 1.3e-3 (see `stable32_artefact_reproduced`), so the
/// correctly computed values are held to the 2e-3 allantools uses for those files.
const FILES: [(&str, DevKind, f64); 5] = [
    ("adev_octave.txt", DevKind::Adev, 2e-4),
    ("stable32_adev_alltau.txt", DevKind::Adev, 2e-4),
    ("stable32_oadev_alltau.txt", DevKind::Oadev, 2e-4),
    ("oadev_octave.txt", DevKind::Oadev, 2e-3),
    ("mdev_octave.txt", DevKind::Mdev, 2e-3),
];

/// Runs the analysis on exactly the τ list of a Stable32 run (the noise-ID carry rule
/// depends on the previous τ of the run).
fn run(kind: DevKind, rows: &[S32Row], opts: &Options) -> Vec<AnalysisPoint> {
    let y = ocxo_y();
    let ms = rows.iter().map(|r| r.m).collect();
    let pts = analyze(kind, &y, TAU0, &TauSpec::Factors(ms), opts);
    assert_eq!(pts.len(), rows.len());
    pts
}

#[test]
fn deviations_and_counts_match_stable32() {
    for (file, kind, tol) in FILES {
        let rows = stable32(file);
        let pts = run(kind, &rows, &Options::default());
        let mut worst = 0.0f64;
        for (r, p) in rows.iter().zip(&pts) {
            assert_eq!(p.m, r.m);
            assert_eq!(p.n, r.n, "{file} m={}: # {} vs {}", r.m, p.n, r.n);
            assert!((p.tau_s - r.tau).abs() <= 1e-4 * r.tau, "{file} m={}", r.m);
            let e = rel(p.dev, r.dev);
            worst = worst.max(e);
            assert!(
                e <= tol,
                "{file} m={}: {} vs {} (rel {e:.2e})",
                r.m,
                p.dev,
                r.dev
            );
        }
        println!(
            "{file:28} {:4} rows: # exact, max rel dev error {worst:.2e} (tol {tol:.0e})",
            rows.len()
        );
    }
}

/// Stable32 computed the `.001` OADEV/MDEV octave runs from frequency data normalised to
/// f/1e7 ≈ 1.0 and integrated it to phase without removing the mean, so phase rounding
/// (ulp of a 2e4 s ramp ≈ 3.6e-12 s) adds noise. Feeding the library that very phase
/// reproduces those two files to 2e-4 — which shows the 1e-3 differences above are
/// Stable32's, not ours.
#[test]
fn stable32_artefact_reproduced() {
    let mut x = Vec::with_capacity(ocxo_hz().len() + 1);
    x.push(0.0f64);
    let mut acc = 0.0f64;
    for f in ocxo_hz() {
        acc += f / 1.0e7;
        x.push(acc);
    }
    let ramp_phase = Phase::from_phase(&x, TAU0).unwrap();
    for (file, kind) in [
        ("oadev_octave.txt", DevKind::Oadev),
        ("mdev_octave.txt", DevKind::Mdev),
    ] {
        let mut worst = 0.0f64;
        for r in stable32(file) {
            let p = ramp_phase.deviation(kind, r.m).unwrap();
            assert_eq!(p.n, r.n);
            let e = rel(p.dev, r.dev);
            worst = worst.max(e);
            assert!(
                e <= 2e-4,
                "{file} m={}: {} vs {} ({e:.2e})",
                r.m,
                p.dev,
                r.dev
            );
        }
        println!("{file:28} from un-centred f/1e7 phase: max rel error {worst:.2e}");
    }
}

fn agreement(file: &str, kind: DevKind, opts: &Options) -> (usize, usize, Vec<String>) {
    let rows = stable32(file);
    let pts = run(kind, &rows, opts);
    let mut ok = 0;
    let mut misses = Vec::new();
    for (r, p) in rows.iter().zip(&pts) {
        if p.alpha() == Some(r.alpha) {
            ok += 1;
        } else {
            misses.push(format!("m={}: s32 {} ours {:?}", r.m, r.alpha, p.alpha()));
        }
    }
    (ok, rows.len(), misses)
}

#[test]
fn noise_id_agrees_with_stable32_alpha() {
    let variants = [
        (
            "Stable32 ACF + B1/R(n) + long-tau carry (default)",
            Options::default(),
        ),
        (
            "allantools ACF flavour, carry",
            Options {
                acf_flavor: AcfFlavor::Allantools,
                ..Options::default()
            },
        ),
        (
            "Stable32 ACF, no carry",
            Options {
                stable32_carry: false,
                ..Options::default()
            },
        ),
    ];
    for (i, (name, opts)) in variants.iter().enumerate() {
        println!("noise-ID variant: {name}");
        for (file, kind, _) in FILES {
            let (ok, tot, misses) = agreement(file, kind, opts);
            println!(
                "  {file:28} alpha agreement {ok}/{tot} = {:.1}%{}",
                100.0 * ok as f64 / tot as f64,
                if misses.is_empty() {
                    String::new()
                } else {
                    format!("  misses: {}", misses.join(", "))
                }
            );
            if i == 0 {
                assert_eq!(ok, tot, "{file}: {misses:?}");
            }
        }
    }
}

#[test]
fn noise_id_methods_follow_the_stable32_rule() {
    let rows = stable32("stable32_adev_alltau.txt");
    let pts = run(DevKind::Adev, &rows, &Options::default());
    let n = ocxo_y().len();
    for p in pts {
        let method = p.noise.unwrap().method;
        if n / p.m >= 30 {
            assert_eq!(method, NoiseIdMethod::Acf, "m={}", p.m);
        } else if p.m * 10 <= n {
            assert!(
                matches!(method, NoiseIdMethod::B1 | NoiseIdMethod::B1Rn),
                "m={}",
                p.m
            );
        } else {
            assert_eq!(method, NoiseIdMethod::Carried, "m={}", p.m);
        }
    }
}

#[test]
fn confidence_intervals_match_stable32() {
    for (file, kind) in [
        ("adev_octave.txt", DevKind::Adev),
        ("oadev_octave.txt", DevKind::Oadev),
        ("mdev_octave.txt", DevKind::Mdev),
    ] {
        let rows = stable32(file);
        let pts = run(kind, &rows, &Options::default());
        let (mut worst_abs, mut worst_shape, mut compared) = (0.0f64, 0.0f64, 0);
        for (r, p) in rows.iter().zip(&pts) {
            if p.alpha() != Some(r.alpha) {
                continue;
            }
            compared += 1;
            let (lo, hi) = (p.dev_lo.unwrap(), p.dev_hi.unwrap());
            let e = rel(lo, r.lo).max(rel(hi, r.hi));
            // interval shape independent of the deviation value itself
            let shape = rel(lo / p.dev, r.lo / r.dev).max(rel(hi / p.dev, r.hi / r.dev));
            worst_abs = worst_abs.max(e);
            worst_shape = worst_shape.max(shape);
            assert!(
                e <= 0.01,
                "{file} m={}: [{lo:.5e}, {hi:.5e}] vs [{:.5e}, {:.5e}]",
                r.m,
                r.lo,
                r.hi
            );
        }
        println!(
            "{file:18} CI bounds on {compared}/{} rows: max rel error {worst_abs:.2e} (bounds/dev ratios: {worst_shape:.2e})",
            rows.len()
        );
    }
}
