//! Comparison with allantools 2024.6 outputs dumped by `scripts/dump_allantools.py`
//! (fixtures `allantools_*.csv`; same OCXO record, y = (f − 1e7)/1e7, τ0 = 1 s).

mod common;

use std::collections::BTreeMap;

use common::{csv, ocxo_y, rel};
use host_test::allan::{
    AcfFlavor, DevKind, ONE_SIGMA_CI, Phase, TauSpec, acf_noise_id, averaging_factors,
    confidence_interval, edf_for_kind,
};

const TOL: f64 = 1e-9;

fn kind_of(s: &str) -> DevKind {
    match s {
        "adev" => DevKind::Adev,
        "oadev" => DevKind::Oadev,
        "mdev" => DevKind::Mdev,
        _ => panic!("unknown kind {s}"),
    }
}

fn col(header: &[String], name: &str) -> usize {
    header
        .iter()
        .position(|h| h == name)
        .unwrap_or_else(|| panic!("no column {name}"))
}

#[test]
fn deviations_match_allantools() {
    let y = ocxo_y();
    let phase = Phase::from_frequency(&y, 1.0).unwrap();
    let (h, rows) = csv("allantools_devs.csv");
    let (c_list, c_kind, c_m, c_tau, c_n, c_dev) = (
        col(&h, "list"),
        col(&h, "kind"),
        col(&h, "m"),
        col(&h, "tau"),
        col(&h, "n"),
        col(&h, "dev"),
    );
    let mut lists: BTreeMap<(String, String), Vec<usize>> = BTreeMap::new();
    let mut worst = BTreeMap::new();
    for r in &rows {
        let kind = kind_of(&r[c_kind]);
        let m: usize = r[c_m].parse().unwrap();
        let p = phase.deviation(kind, m).unwrap_or_else(|| panic!("{r:?}"));
        assert_eq!(p.n, r[c_n].parse::<usize>().unwrap(), "{r:?}");
        assert_eq!(p.tau_s, r[c_tau].parse::<f64>().unwrap(), "{r:?}");
        let e = rel(p.dev, r[c_dev].parse().unwrap());
        assert!(e <= TOL, "{r:?}: ours {} rel {e:.2e}", p.dev);
        let w = worst.entry(kind.name()).or_insert(0.0f64);
        *w = w.max(e);
        lists
            .entry((r[c_list].clone(), r[c_kind].clone()))
            .or_default()
            .push(m);
    }
    for (kind, w) in &worst {
        println!("{kind:6} max rel dev error vs allantools {w:.2e}");
    }
    // τ lists: allantools' "octave"/"decade" keyword lists after its small-n removal.
    let n = y.len();
    for ((list, kind), ms) in &lists {
        let spec = match list.as_str() {
            "octave" => TauSpec::Octave,
            "decade" => TauSpec::Decade,
            _ => continue,
        };
        assert_eq!(
            &averaging_factors(&spec, kind_of(kind), n),
            ms,
            "{list} {kind}"
        );
    }
    assert!(lists.len() >= 9);
}

#[test]
fn acf_noise_id_matches_allantools() {
    let y = ocxo_y();
    let (h, rows) = csv("allantools_noise.csv");
    let (c_m, c_ai, c_a, c_d, c_rho) = (
        col(&h, "m"),
        col(&h, "alpha_int"),
        col(&h, "alpha"),
        col(&h, "d"),
        col(&h, "rho"),
    );
    let mut worst = 0.0f64;
    for r in &rows {
        let m: usize = r[c_m].parse().unwrap();
        let got = acf_noise_id(&y, m, AcfFlavor::Allantools, 2).unwrap_or_else(|| panic!("m={m}"));
        assert_eq!(got.alpha_int, r[c_ai].parse::<i32>().unwrap(), "m={m}");
        assert_eq!(got.d, r[c_d].parse::<u32>().unwrap(), "m={m}");
        let (a, rho): (f64, f64) = (r[c_a].parse().unwrap(), r[c_rho].parse().unwrap());
        let e = ((got.alpha - a).abs() / a.abs().max(1.0))
            .max((got.delta - rho).abs() / rho.abs().max(1.0));
        worst = worst.max(e);
        assert!(e <= TOL, "m={m}: {got:?} vs alpha {a} rho {rho}");
    }
    // allantools refuses fewer than 30 averaged points; so do we.
    let n = y.len();
    assert!(acf_noise_id(&y, n / 30, AcfFlavor::Allantools, 2).is_some());
    assert!(acf_noise_id(&y, n / 30 + 1, AcfFlavor::Allantools, 2).is_none());
    println!(
        "ACF noise id: {} values of m, alpha_int/d exact, max error of alpha/delta {worst:.2e}",
        rows.len()
    );
}

#[test]
fn edf_and_confidence_intervals_match_allantools() {
    let y = ocxo_y();
    let n = y.len();
    let phase = Phase::from_frequency(&y, 1.0).unwrap();
    let (h, rows) = csv("allantools_edf.csv");
    let (c_kind, c_m, c_alpha, c_edf, c_lo, c_hi) = (
        col(&h, "kind"),
        col(&h, "m"),
        col(&h, "alpha"),
        col(&h, "edf"),
        col(&h, "lo"),
        col(&h, "hi"),
    );
    let (mut worst_edf, mut worst_ci) = (0.0f64, 0.0f64);
    let mut have = std::collections::HashSet::new();
    for r in &rows {
        let kind = kind_of(&r[c_kind]);
        let m: usize = r[c_m].parse().unwrap();
        let alpha: i32 = r[c_alpha].parse().unwrap();
        have.insert((kind, m, alpha));
        let edf = edf_for_kind(kind, alpha, m, n).unwrap_or_else(|| panic!("{r:?}"));
        let e = rel(edf, r[c_edf].parse().unwrap());
        worst_edf = worst_edf.max(e);
        assert!(e <= TOL, "{r:?}: ours {edf} rel {e:.2e}");
        let dev = phase.deviation(kind, m).unwrap().dev;
        let (lo, hi) = confidence_interval(dev, edf, ONE_SIGMA_CI).unwrap();
        let e = rel(lo, r[c_lo].parse().unwrap()).max(rel(hi, r[c_hi].parse().unwrap()));
        worst_ci = worst_ci.max(e);
        assert!(e <= TOL, "{r:?}: ours [{lo}, {hi}] rel {e:.2e}");
    }
    // Where allantools has no EDF (white PM, unmodified, ceil(r) <= d) we use the paper's
    // short-record formula; count those extra values.
    let mut extra = 0;
    for r in &rows {
        let kind = kind_of(&r[c_kind]);
        let m: usize = r[c_m].parse().unwrap();
        for alpha in -2..=2 {
            if !have.contains(&(kind, m, alpha)) && edf_for_kind(kind, alpha, m, n).is_some() {
                assert_eq!(alpha, 2, "{kind:?} m={m}");
                extra += 1;
            }
        }
        have.insert((kind, m, 99)); // visit each (kind, m) once
    }
    println!(
        "EDF: {} values, max rel error {worst_edf:.2e}; CI bounds max rel error {worst_ci:.2e}; \
         {extra} white-PM values allantools cannot compute",
        rows.len()
    );
}
