//! Runs `diagnose` on simulated 16-group static records with one injected effect each and prints what it names
//! (a development aid for the diagnosis; `cargo run --release -p host-test --example diagnose_sweep -- [SEED] [RATE] [HOURS]`).

use host_test::diagnose::{Options, Report, diagnose};
use host_test::sim::output::recording;
use host_test::sim::preset::seed_config;
use host_test::sim::{
    Axis, Channel, CommonDrift, CommonMode, DriftKind, Outlier, PartSpread, SimConfig, Thermal,
};

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let seed: u64 = args.get(1).and_then(|s| s.parse().ok()).unwrap_or(100);
    let rate: f64 = args.get(2).and_then(|s| s.parse().ok()).unwrap_or(5.0);
    let hours: f64 = args.get(3).and_then(|s| s.parse().ok()).unwrap_or(8.0);
    let only: Option<String> = args.get(4).cloned();
    for (name, cfg) in cases(seed, rate, hours) {
        if only.as_deref().is_some_and(|o| !name.contains(o)) {
            continue;
        }
        let mut rec = recording(cfg).unwrap();
        if name.contains("no temp") {
            rec.temp_c = None;
        }
        let t = std::time::Instant::now();
        let r = diagnose(&rec, &Options::default()).unwrap();
        print_result(name, &r, t.elapsed().as_secs_f64());
    }
}

/// The sweep's records: the seed experiment at `rate` Hz for `hours`, each with one injected effect (or none).
fn cases(seed: u64, rate: f64, hours: f64) -> Vec<(&'static str, SimConfig)> {
    let base = |s: u64| {
        let mut c = seed_config(s).unwrap();
        c.rate_hz = rate;
        c.samples = (hours * 3600.0 * rate) as u64;
        c
    };
    let thermal = |coef: [f64; 6], sd: [f64; 6]| Thermal {
        mean_c: 20.0,
        amplitude_c: 0.7,
        period_s: 3.0 * 3600.0,
        phase_rad: 0.3,
        drift_c_per_h: 0.15,
        coef,
        coef_sd: sd,
        ref_c: None,
        hold_after_s: None,
    };
    let mut cases: Vec<(&str, SimConfig)> = Vec::new();
    cases.push(("none", base(seed)));
    let mut c = base(seed + 1);
    c.drift.push(CommonDrift {
        groups: None,
        axes: vec![Axis::GyroY],
        kind: DriftKind::RandomWalk { k: 1.5e-4 },
    });
    cases.push(("drift gy", c));
    let mut c = base(seed + 1);
    c.drift.push(CommonDrift {
        groups: None,
        axes: vec![Axis::GyroY],
        kind: DriftKind::RandomWalk { k: 1.5e-4 },
    });
    c.thermal = Some(thermal([0.0; 6], [0.0; 6]));
    cases.push(("drift gy (temp, no thermal)", c));
    let mut c = base(seed + 10);
    c.thermal = Some(thermal([0.0; 6], [0.0; 6]));
    cases.push(("none (temp)", c));
    let mut c = base(seed + 11);
    for b in 0..4 {
        let g: Vec<usize> = (4 * b..4 * b + 4).collect();
        c.common.push(CommonMode::block(
            &format!("f{b}"),
            &g,
            &Axis::ALL[..3],
            0.0,
            0.4,
        ));
    }
    cases.push(("blocks 4x4 gyro flicker only", c));
    let mut c = base(seed + 2);
    c.thermal = Some(thermal(
        [0.0, 0.0, 0.0, 1.5e-4, 2.5e-4, 1.5e-4],
        [0.0, 0.0, 0.0, 5e-5, 8e-5, 5e-5],
    ));
    cases.push(("thermal accel", c.clone()));
    cases.push(("thermal accel (no temp)", c));
    let mut c = base(seed + 3);
    c.thermal = Some(thermal(
        [0.0, 2e-2, 0.0, 0.0, 0.0, 0.0],
        [0.0, 6e-3, 0.0, 0.0, 0.0, 0.0],
    ));
    cases.push(("thermal gy", c.clone()));
    cases.push(("thermal gy (no temp)", c));
    let mut c = base(seed + 4);
    for b in 0..4 {
        let g: Vec<usize> = (4 * b..4 * b + 4).collect();
        c.common.push(CommonMode::block(
            &format!("b{b}"),
            &g,
            &Axis::ALL[..3],
            0.2,
            0.2,
        ));
    }
    cases.push(("blocks 4x4 gyro", c));
    let mut c = base(seed + 5);
    for b in 0..2 {
        let g: Vec<usize> = (8 * b..8 * b + 8).collect();
        c.common.push(CommonMode::block(
            &format!("h{b}"),
            &g,
            &Axis::ALL[3..],
            0.1,
            0.1,
        ));
    }
    cases.push(("blocks 2x8 accel", c));
    let mut c = base(seed + 6);
    c.common.push(CommonMode::all(&[Axis::GyroY], 0.0, 0.3));
    cases.push(("shared flicker gy", c));
    let mut c = base(seed + 7);
    c.common.push(CommonMode::all(&Axis::ALL[..3], 0.1, 0.1));
    cases.push(("common mode gyro", c));
    let mut c = base(seed + 8);
    c.outliers.push(Outlier::noisy(5, Channel::AccelX, 5.0));
    cases.push(("outlier g5 ax", c));
    let mut c = base(seed + 9);
    c.spread = PartSpread::unequal_noise(0.5);
    cases.push(("unequal 0.5", c));
    cases
}

/// One line per record (`DIAG_VERBOSE`: and one per axis with its τ points' z-scores).
fn print_result(name: &str, r: &Report, el: f64) {
    let eff: Vec<String> = r
        .effects
        .iter()
        .map(|e| {
            format!(
                "{} {} {} {} [{} {:.0}-{:.0}s {:.2}]",
                e.kind, e.sensor, e.axes, e.groups, e.region, e.tau_s[0], e.tau_s[1], e.share
            )
        })
        .collect();
    let h = r.heldout;
    println!(
        "{name:<24} {:.2}s  excess {:.3}->{:.3} ({:.0} %)  rms {:.3}->{:.3}  {}",
        el,
        h.gap_before,
        h.gap_after,
        100.0 * (1.0 - h.gap_after / h.gap_before.max(1e-12)),
        h.rms_before,
        h.rms_after,
        if eff.is_empty() {
            "none".into()
        } else {
            eff.join("; ")
        }
    );
    if std::env::var("DIAG_VERBOSE").is_ok() {
        for a in &r.axes {
            let zs: Vec<String> = a
                .taus
                .iter()
                .map(|t| {
                    format!(
                        "{:.0}:{:+.1}/{:+.1}/{:+.1}",
                        t.tau_s, t.z_before, t.cross_z, t.z_after
                    )
                })
                .collect();
            println!(
                "   {} indep p {:.2e} {}",
                a.axis,
                a.independence.p_value,
                zs.join(" ")
            );
        }
    }
}
