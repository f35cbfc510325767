//! False alarms of `ground diagnose` (issue 40, item 3): clean simulated records of the null — independent sensors
//! with no effect, but **unequal parts** (a common level factor and independent factors on the white, flicker and
//! random-walk terms of each part), clusters of 4 to 16 sensors, three sample rates, quantisation by rounding to the
//! ADC step — each diagnosed, and every effect named counted per detector.
//!
//! With unequal parts the cluster truly departs from √N by its levels, so a level effect (`unequal_noise`,
//! `outlier_sensor`) is a right answer on those records; every other kind, a level effect on a record of equal
//! parts, and a shared disturbance are false alarms. Target (issue 40): ≤ 1 effect named in 100 clean records.
//! Measured (seeds 7,500,000–7,500,199): 0 in 200 (1 with the scale of level models alone, before the levels'
//! shared misfit profile, `docs/diagnose.md`); the test asserts the target, ≤ 2 of 200. On 800 fresh seeds
//! (9,000,000–9,000,799, never looked at before the measurement): **3 in 800** (0.38 in 100: `bias_step`,
//! `unexplained`, one shared disturbance), where the diagnosis before a shared process needed the held-out cross
//! covariance named 8 (`common_mode` 3, `unexplained` 2, `common_mode_drift`, `bias_step`, disturbance). On the 800
//! seeds the change was studied on (5,000–5,399, 100,000–100,199, 7,500,200–7,500,399): 13 → 4 (`unexplained` 3,
//! `bias_step` 1); 24 before the level effect was also offered with levels that vary with τ, 69 before the step
//! scan counted every position (docs/diagnose.md). Other seeds:
//! `DIAGNOSE_NULL_SEEDS=5000..5400 cargo test --release -p host-test --test diagnose_false_alarms -- --nocapture`.
//! With a Gauss–Markov bump on every sensor: `clean_records_with_gauss_markov_bumps` (figures there).
//!
//! Records are short (4096 samples, 13.7 min at 5 Hz to 65.5 s at 62.5 Hz) so that the sweep runs in the dev
//! profile (78–135 s measured on 2 threads of a loaded machine): each half then holds 9 octaves down to four blocks,
//! few for the long-τ detectors (`sensor_drift`, `common_mode_drift`).

use host_test::diagnose::{Options, diagnose};
use host_test::recording::Recording;
use host_test::sim::output::recording;
use host_test::sim::preset::seed_config;
use host_test::sim::{CHANNELS, PartSpread, SimConfig};
use host_test::testrng::TestRng;
use std::collections::BTreeMap;

/// Records in the sweep.
const RECORDS: u64 = 200;
/// Samples per record.
const SAMPLES: u64 = 4096;
/// First seed (never used while the detectors were changed: tuning used seeds below 10,000).
const FIRST_SEED: u64 = 7_500_000;

/// One null record: its configuration drawn from `seed`, and whether its parts are unequal.
struct Null {
    cfg: SimConfig,
    groups: usize,
    unequal: bool,
    /// Its configuration in words, for the failure message.
    label: String,
}

fn null(base: &SimConfig, seed: u64, bump: bool) -> Null {
    let mut rng = TestRng::new(seed ^ 0x005e_ed40);
    let mut cfg = base.clone();
    cfg.seed = seed;
    cfg.rate_hz = [5.0, 18.9, 62.5][(rng.next_u64() % 3) as usize];
    cfg.samples = SAMPLES;
    let groups = [4, 5, 6, 8, 10, 12, 16][(rng.next_u64() % 7) as usize];
    // One record in three has equal parts; the others a spread of up to 0.4 in ln on each factor.
    let unequal = !rng.next_u64().is_multiple_of(3);
    if unequal {
        let mut s = || 0.4 * rng.uniform();
        cfg.spread = PartSpread {
            level_ln: s(),
            white_ln: s(),
            flicker_ln: s(),
            rrw_ln: s(),
        };
    }
    // Bumps (not in the asserted null): a Gauss–Markov bump on every sensor (its own, independent), with the correlation time between 4 samples and a
    // tenth of the record and a standard deviation of 0.5–2× the white noise per sample.
    if bump {
        let dt = 1.0 / cfg.rate_hz;
        let t = dt * 4.0 * (SAMPLES as f64 / 40.0).powf(rng.uniform());
        let f = 0.5 * 4f64.powf(rng.uniform());
        for c in 0..CHANNELS {
            let p = &mut cfg.sensor[c];
            p.gm_tau_s = t;
            p.gm_sigma = f * p.white / dt.sqrt();
        }
    }
    let label = format!(
        "{groups} groups, {} Hz, spread {:.2}/{:.2}/{:.2}/{:.2}, Gauss-Markov T {:.3} s",
        cfg.rate_hz,
        cfg.spread.level_ln,
        cfg.spread.white_ln,
        cfg.spread.flicker_ln,
        cfg.spread.rrw_ln,
        cfg.sensor[0].gm_tau_s
    );
    Null {
        cfg,
        groups,
        unequal,
        label,
    }
}

/// The record of the first `groups` groups.
fn clip(mut rec: Recording, groups: usize) -> Recording {
    rec.columns.retain(|c| c.group < groups);
    rec
}

/// Per record: its seed, whether its parts are unequal, the effects named (kind, sensor, axes, configuration) and
/// the shared disturbances found.
type Outcome = (u64, bool, Vec<String>, usize, String);

/// Diagnoses the null records of `seeds` (with Gauss–Markov bumps when `bump`) on two threads.
fn sweep(seeds: &[u64], bump: bool) -> Vec<Outcome> {
    // The seed preset's parameters are solved once (bisection on the expected ADEV); each record is another seed.
    let base = seed_config(FIRST_SEED).unwrap();
    std::thread::scope(|s| {
        let jobs: Vec<_> = seeds
            .chunks(seeds.len().div_ceil(2))
            .map(|chunk| {
                let base = &base;
                s.spawn(move || {
                    chunk
                        .iter()
                        .map(|&seed| {
                            let n = null(base, seed, bump);
                            let rec = clip(recording(n.cfg).unwrap(), n.groups);
                            let r = diagnose(&rec, &Options::default()).unwrap();
                            let named = r
                                .effects
                                .iter()
                                .map(|e| format!("{} {} {}", e.kind, e.sensor, e.axes))
                                .collect();
                            (seed, n.unequal, named, r.disturbances.len(), n.label)
                        })
                        .collect::<Vec<_>>()
                })
            })
            .collect();
        jobs.into_iter().flat_map(|j| j.join().unwrap()).collect()
    })
}

/// The false alarms of a sweep, per detector (printed per 100 records) and listed.
fn false_alarms(what: &str, results: &[Outcome], secs: f64) -> Vec<String> {
    let level = |k: &str| k.starts_with("unequal_noise") || k.starts_with("outlier_sensor");
    let mut per_kind: BTreeMap<String, usize> = BTreeMap::new();
    let mut right_levels = 0;
    let mut out = Vec::new();
    for (seed, unequal, named, disturbances, label) in results {
        for e in named {
            let kind = e.split(' ').next().unwrap_or("").to_string();
            if *unequal && level(e) {
                right_levels += 1;
                continue;
            }
            *per_kind.entry(kind).or_default() += 1;
            out.push(format!("seed {seed}: {e} [{label}]"));
        }
        if *disturbances > 0 {
            *per_kind.entry("disturbance".into()).or_default() += disturbances;
            out.push(format!(
                "seed {seed}: {disturbances} disturbance(s) [{label}]"
            ));
        }
    }
    let n = results.len();
    let unequal = results.iter().filter(|r| r.1).count();
    eprintln!(
        "{what}: {n} clean records ({unequal} of unequal parts), {secs:.1} s; {} false alarm(s); per detector (per 100 records):",
        out.len()
    );
    for (k, c) in &per_kind {
        eprintln!("  {k}: {c} ({:.2})", 100.0 * *c as f64 / n as f64);
    }
    eprintln!("  level effects named on unequal parts (right answers): {right_levels}");
    for f in &out {
        eprintln!("  {f}");
    }
    out
}

/// The seeds of the sweep: `FIRST_SEED` and the `RECORDS` after it, or the range `FIRST..END` given in the
/// environment variable `DIAGNOSE_NULL_SEEDS` (how the 800 other seeds above were swept; the bound is then the same).
fn null_seeds() -> Vec<u64> {
    seeds_from("DIAGNOSE_NULL_SEEDS")
        .unwrap_or_else(|| (FIRST_SEED..FIRST_SEED + RECORDS).collect())
}

/// The seeds `FIRST..END` given in the environment variable `var`, if any.
fn seeds_from(var: &str) -> Option<Vec<u64>> {
    let v = std::env::var(var).ok()?;
    let (a, b) = v.split_once("..")?;
    Some((a.trim().parse::<u64>().ok()?..b.trim().parse::<u64>().ok()?).collect())
}

#[test]
fn clean_records_of_the_null_name_at_most_one_effect_in_100() {
    let seeds = null_seeds();
    let start = std::time::Instant::now();
    let results = sweep(&seeds, false);
    let found = false_alarms("null", &results, start.elapsed().as_secs_f64());
    assert!(
        found.len() * 100 <= results.len(),
        "{} false alarms in {} clean records: {found:?}",
        found.len(),
        results.len()
    );
}

/// The same null with a first-order Gauss–Markov bump on every sensor (its own, as large on every part: the
/// correlation time from 4 samples to a tenth of the record, 0.5–2× the white noise's sd). Target (issue 40): ≤ 1
/// effect named in 100; the test asserts ≤ 2 of its 200 records (7,500,200–7,500,399). Measured 2026-11-30:
/// **0 of 200** there; on other seeds 1 (8,000,000–199), 2 (7,800,000–), 1 (7,900,000–) and, never looked at before
/// the measurement, 3 (8,100,000–199: `unexplained`, `sensor_drift`, and `unequal_noise` on equal parts): 7 in
/// 1 000, 0.7 in 100. Before the levels' correction took a misfit profile shared by the parts
/// (`TermLevels::shrunk`), 5, 6 and 8 on those three 200 and 1 in the test's first 50 (8, 6 and 8 before the scale
/// of level models from every sensor, `Half::pair_with`); on 7,600,000–199, where the earlier changes were studied, 51 before
/// the level effect was offered with levels that vary with τ, 21 before `sensor_drift` judged its two references at
/// the same τ, then 15, 10 and 5 (docs/diagnose.md). Other seeds: `DIAGNOSE_BUMP_SEEDS=8100000..8100200`.
#[test]
fn clean_records_with_gauss_markov_bumps() {
    let seeds = seeds_from("DIAGNOSE_BUMP_SEEDS")
        .unwrap_or_else(|| (FIRST_SEED + RECORDS..FIRST_SEED + 2 * RECORDS).collect());
    let start = std::time::Instant::now();
    let results = sweep(&seeds, true);
    let found = false_alarms("null with bumps", &results, start.elapsed().as_secs_f64());
    assert!(
        found.len() * 100 <= 2 * results.len(),
        "{} false alarms in {} clean records",
        found.len(),
        results.len()
    );
}

/// The kinds that name a process shared by sensors.
const SHARED_KINDS: [&str; 3] = ["common_mode", "common_mode_drift", "block_common_mode"];

/// The effects named on the null record of `seed` (kinds and axes) with `opts`.
fn named(base: &SimConfig, seed: u64, opts: &Options) -> Vec<(String, String)> {
    let n = null(base, seed, false);
    let rec = clip(recording(n.cfg).unwrap(), n.groups);
    let r = diagnose(&rec, opts).unwrap();
    r.effects
        .iter()
        .map(|e| (e.kind.clone(), format!("{} {}", e.sensor, e.axes)))
        .collect()
}

/// Null records on which a shared process was named by chance (2026-11-30, seeds of the 800 swept above): on
/// unequal parts or through a chance excursion of the gap, a `common_mode` or `common_mode_drift` lowered the
/// held-out `Σ z²` although the held-out half's own cross covariance showed nothing (independence p 0.43–0.92).
/// A shared process is now named only when that cross covariance confirms it (`Options::p_cross`); with the
/// confirmation off (`p_cross` 1) the same records name the shared processes again, so the test can fail. Seed
/// 5356 also named an `unexplained` accel y whose held-out half was clean (largest z 1.09): an unexplained gap is
/// now named only where the held-out half shows it too.
#[test]
fn a_shared_process_is_named_only_where_the_held_out_cross_covariance_shows_it() {
    let base = seed_config(FIRST_SEED).unwrap();
    let seeds = [5310, 5356, 100_105, 7_500_250, 7_500_399];
    let off = Options {
        p_cross: 1.0,
        ..Options::default()
    };
    let shared = |e: &[(String, String)]| e.iter().any(|(k, _)| SHARED_KINDS.contains(&k.as_str()));
    let without: Vec<u64> = seeds
        .iter()
        .copied()
        .filter(|&s| shared(&named(&base, s, &off)))
        .collect();
    assert!(
        without.len() >= 4,
        "without the confirmation, shared processes on {without:?}"
    );
    for s in seeds {
        let e = named(&base, s, &Options::default());
        assert!(!shared(&e), "seed {s}: {e:?}");
        assert!(
            s != 5356 || e.iter().all(|(k, _)| k != "unexplained"),
            "{e:?}"
        );
    }
}
