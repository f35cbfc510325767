//! Rate-table records of our board from FPGA frame logs: the mean raw code of every channel of every group.

use super::RateRecord;
use super::rate_table::standard_inputs;
use crate::formats::framelog::FrameLog;
use shared::wire::frame::{GROUPS, RAW_PER_GROUP};

/// Per group, one record per log: `logs` in the order of [`standard_inputs`]`(omega_dps)` (for +x, −x, +y, −y,
/// +z, −z up: +Ω, −Ω, 0 about the vertical). `None` if a log has no frame or there are not 18 logs.
pub fn board_records(logs: &[FrameLog], omega_dps: f64) -> Option<Vec<Vec<RateRecord>>> {
    let inputs = standard_inputs(omega_dps);
    if logs.len() != inputs.len() || logs.iter().any(|l| l.frames.is_empty()) {
        return None;
    }
    let mut groups: Vec<Vec<RateRecord>> = (0..GROUPS)
        .map(|_| Vec::with_capacity(logs.len()))
        .collect();
    for (log, (_, rate_dps, accel_g)) in logs.iter().zip(&inputs) {
        let n = log.frames.len() as f64;
        let mut mean = [[0f64; RAW_PER_GROUP]; GROUPS];
        for d in &log.frames {
            for (m, codes) in mean.iter_mut().zip(&d.frame.raw) {
                for (x, &c) in m.iter_mut().zip(codes) {
                    *x += f64::from(c);
                }
            }
        }
        for (recs, m) in groups.iter_mut().zip(&mean) {
            let m = m.map(|x| x / n);
            recs.push(RateRecord {
                rate_dps: *rate_dps,
                accel_g: *accel_g,
                gyro_counts: [m[0], m[1], m[2], m[3]],
                accel_counts: [m[4], m[5], m[6]],
            });
        }
    }
    Some(groups)
}
