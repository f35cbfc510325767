//! The demo's files: the ADEV plot, the tables as CSV, the seed fit, the report and the JSON of the results.

use super::stats::{Decoded, Tables};
use super::{AXIS_NAMES, DemoError, DemoOptions, DemoResult, report, unit};
use crate::plot::{self, Curve, Panel, Style};
use crate::seedfit::SEED_TABLE;
use shared::calib::AXES;
use shared::wire::frame::GROUPS;
use std::fmt::Write as _;
use std::path::Path;

/// `adev.png`: one panel per axis.
pub(super) fn write_plot(out: &Path, d: &Decoded, t: &Tables) -> Result<(), DemoError> {
    let panels: Vec<Panel> = (0..AXES).map(|a| adev_panel(d, t, a)).collect();
    plot::adev_panels(
        &out.join("adev.png"),
        "Seed experiment through the flight core: single sensors vs cluster",
        &panels,
        3,
    )?;
    Ok(())
}

/// The plot panel of axis `a`: singles thin, √N expectation dashed, cluster bold with CIs.
fn adev_panel(d: &Decoded, t: &Tables, a: usize) -> Panel {
    let kind = if a < 3 { "deg/s" } else { "g" };
    let mut curves: Vec<Curve> = (0..GROUPS)
        .map(|g| Curve {
            label: (g == 0).then(|| "single sensors (core Allan channels)".into()),
            points: d
                .single(g, a)
                .iter()
                .map(|&(k, v, _)| (d.tau(k), v))
                .collect(),
            bars: vec![],
            style: Style::Thin(g),
        })
        .collect();
    let levels = d.core_allan[a].len();
    let expect: Vec<(f64, f64)> = (0..levels)
        .filter_map(|k| {
            let s: Option<f64> = (0..GROUPS)
                .map(|g| d.single(g, a).iter().find(|x| x.0 == k).map(|x| x.1 * x.1))
                .sum();
            s.map(|s| (d.tau(k), s.sqrt() / GROUPS as f64))
        })
        .collect();
    curves.push(Curve {
        label: Some("independent expectation (sqrt 16)".into()),
        points: expect,
        bars: vec![],
        style: Style::Dashed,
    });
    curves.push(Curve {
        label: Some("cluster (core fused channel)".into()),
        points: d
            .cluster(a)
            .iter()
            .map(|&(k, v, _)| (d.tau(k), v))
            .collect(),
        bars: t.ground[a]
            .iter()
            .filter_map(|p| Some((p.tau_s, p.dev_lo?, p.dev_hi?)))
            .collect(),
        style: Style::Bold,
    });
    Panel {
        title: SEED_TABLE[a].name.into(),
        y_label: format!("ADEV [{kind}]"),
        curves,
    }
}

/// `table1.csv`, `table2.csv`, `seed_fit.csv`, `report.md` and `demo.json`.
pub(super) fn write_outputs(
    r: &DemoResult,
    out: &Path,
    opts: DemoOptions,
) -> Result<(), DemoError> {
    let (t1, t2) = tables_csv(r);
    DemoError::write(&out.join("table1.csv"), t1)?;
    DemoError::write(&out.join("table2.csv"), t2)?;
    DemoError::write(&out.join("seed_fit.csv"), seed_fit_csv(r))?;
    DemoError::write(&out.join("report.md"), report(r, opts))?;
    DemoError::write(&out.join("demo.json"), serde_json::to_string_pretty(r)?)?;
    Ok(())
}

/// Tables 1 and 2 as CSV, with the paper's figures.
fn tables_csv(r: &DemoResult) -> (String, String) {
    let mut t1 = String::from(
        "axis,single,cluster,ratio,ratio_ci_lo,ratio_ci_hi,unit,paper_single,paper_cluster,paper_ratio\n",
    );
    let mut t2 = String::from(
        "axis,single,cluster,ratio,ratio_ci_lo,ratio_ci_hi,cluster_min_tau_s,unit,paper_single,paper_cluster,paper_ratio\n",
    );
    for a in 0..AXES {
        let (u1, k1, u2, k2) = unit(a);
        let p = &SEED_TABLE[a];
        let x = &r.table1[a];
        let _ = writeln!(
            t1,
            "{},{},{},{},{},{},{u1},{},{},{}",
            AXIS_NAMES[a],
            x.single * k1,
            x.cluster * k1,
            x.ratio,
            x.ratio_ci[0],
            x.ratio_ci[1],
            p.single_rms * k1,
            p.cluster_rms * k1,
            p.printed[0]
        );
        let (y, tau) = &r.table2[a];
        let _ = writeln!(
            t2,
            "{},{},{},{},{},{},{},{u2},{},{},{}",
            AXIS_NAMES[a],
            y.single * k2,
            y.cluster * k2,
            y.ratio,
            y.ratio_ci[0],
            y.ratio_ci[1],
            tau,
            p.single_bs * k2,
            p.cluster_bs * k2,
            p.printed[1]
        );
    }
    (t1, t2)
}

/// The correlation fit as CSV.
fn seed_fit_csv(r: &DemoResult) -> String {
    let mut f = String::from(
        "axis,rho_white,rho_flicker,table_ratio_rms,simulated_ratio_rms,table_ratio_bs,simulated_ratio_bs\n",
    );
    for x in &r.fits {
        let _ = writeln!(
            f,
            "{},{},{},{},{},{},{}",
            x.name,
            x.rho_white,
            x.rho_flicker,
            x.table[0],
            x.simulated[0],
            x.table[1],
            x.simulated[1]
        );
    }
    f
}
