//! Issue 28 item 4: a sensor's bandwidth in the baseline noise model. Band-limited gyros (every group's gyros through
//! a single pole at 0.8 Hz on the 8-h, 5 Hz, 16-group record of the seed preset, `sim::output::recording_filtered`, the
//! filter of `ground simulate --bandwidth-hz gyro:0.8`) must get their cut-off fitted back (within 5 %: the grid has
//! 40 steps per decade, ±2.9 %), nothing named (a filter on every sensor changes each sensor's Allan variance, not
//! the √N relation), and the held-out excess gap closed; the unfiltered record of the same seed shows no bandwidth.

mod common;

use common::effects::*;
use host_test::diagnose::{Options, Report, diagnose};
use host_test::sim::Axis;
use host_test::sim::output::{Bandwidth, recording_filtered};

const CUTOFF_HZ: f64 = 0.8;

fn run(bands: &[Bandwidth]) -> Report {
    let rec = recording_filtered(config(SEED + 31), bands).unwrap();
    let r = diagnose(&rec, &Options::default()).unwrap();
    for a in &r.axes {
        eprintln!(
            "  {} bandwidth {:?} Hz, misfit four terms {:.3}, with bandwidth {:.3}",
            a.axis, a.bandwidth_hz, a.model_misfit, a.model_misfit_band_limited
        );
    }
    eprintln!(
        "{}",
        serde_json::to_string(&(&r.effects, r.heldout)).unwrap()
    );
    r
}

#[test]
fn band_limited_gyros_get_their_cut_off_and_nothing_is_named() {
    let r = run(&[Bandwidth {
        groups: None,
        axes: Axis::ALL[..3].to_vec(),
        cutoff_hz: CUTOFF_HZ,
    }]);
    for a in &r.axes {
        if a.axis.starts_with('g') {
            let f = a.bandwidth_hz.unwrap_or(0.0);
            assert!(
                (f / CUTOFF_HZ - 1.0).abs() < 0.05,
                "{}: cut-off {f} Hz vs {CUTOFF_HZ} Hz",
                a.axis
            );
            assert!(
                a.model_misfit_band_limited < 0.7 * a.model_misfit,
                "{}: misfit {} → {}",
                a.axis,
                a.model_misfit,
                a.model_misfit_band_limited
            );
        } else {
            assert_eq!(a.bandwidth_hz, None, "{}", a.axis);
        }
    }
    assert!(r.effects.is_empty(), "nothing to name: {:?}", r.effects);
    assert!(r.heldout.gap_after <= 0.05, "{:?}", r.heldout);
}

#[test]
fn an_unfiltered_record_shows_no_bandwidth() {
    let r = run(&[]);
    for a in &r.axes {
        assert_eq!(a.bandwidth_hz, None, "{}", a.axis);
    }
}
