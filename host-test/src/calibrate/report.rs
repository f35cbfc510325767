//! Residual report of a static calibration, per IMU.
//!
//! * `before_rms_mg`: RMS over poses of `|a_nominal| − 1 g`, nominal scale and no bias (`a = raw / 2048`);
//! * `after_rms_mg`: the same with the fitted model (bias drift included when it was fitted);
//! * `table_rms_mg`: with the constant-bias affine model that the table holds;
//! * `alignment_rms_deg`: RMS over poses of the angle between the IMU's calibrated gravity direction (cluster
//!   frame) and the cluster's mean direction (normalised mean of all IMUs' directions).

use nalgebra::Vector3;

use super::linalg::{angle, vec3};
use super::{ImuCal, StaticInterval};
use crate::stats::rms;

/// Residuals of one IMU.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ImuResidual {
    /// Static `|a| − 1 g` RMS at the nominal scale without bias, mg.
    pub before_rms_mg: f64,
    /// Static `|a| − 1 g` RMS with the fitted model, mg.
    pub after_rms_mg: f64,
    /// Static `|a| − 1 g` RMS with the table's constant biases, mg.
    pub table_rms_mg: f64,
    /// Alignment residual to the cluster's mean gravity direction, RMS over poses, degrees.
    pub alignment_rms_deg: f64,
}

/// Residual report of a calibration on a set of static poses.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct ResidualReport {
    /// Number of poses.
    pub poses: usize,
    /// Per IMU.
    pub imus: Vec<ImuResidual>,
}

/// `|a| − 1 g` per IMU (outer) per pose (inner), mg. With `t_ref_s`, the bias drift is applied at each pose's
/// mid-time relative to it; without, the constant biases.
pub fn static_residuals_mg(
    imus: &[ImuCal],
    t_ref_s: Option<f64>,
    poses: &[StaticInterval],
) -> Vec<Vec<f64>> {
    imus.iter()
        .enumerate()
        .map(|(i, cal)| {
            poses
                .iter()
                .filter_map(|p| {
                    let raw = p.accel_counts.get(i)?;
                    let dt = t_ref_s.map_or(0.0, |t| p.mid_s() - t);
                    Some((vec3(&cal.accel_g(raw, dt)).norm() - 1.0) * 1e3)
                })
                .collect()
        })
        .collect()
}

impl ResidualReport {
    /// Report of `imus` (reference time `t_ref_s`) on `poses`; `nominal_g_per_count` for the "before" figure.
    pub fn new(
        imus: &[ImuCal],
        t_ref_s: f64,
        poses: &[StaticInterval],
        nominal_g_per_count: f64,
    ) -> Self {
        let after = static_residuals_mg(imus, Some(t_ref_s), poses);
        let table = static_residuals_mg(imus, None, poses);
        let dirs: Vec<Vec<Vector3<f64>>> = imus
            .iter()
            .enumerate()
            .map(|(i, cal)| {
                poses
                    .iter()
                    .map(|p| {
                        p.accel_counts.get(i).map_or_else(Vector3::zeros, |raw| {
                            vec3(&cal.accel_g(raw, p.mid_s() - t_ref_s))
                                .try_normalize(1e-300)
                                .unwrap_or_else(Vector3::zeros)
                        })
                    })
                    .collect()
            })
            .collect();
        let mean: Vec<Vector3<f64>> = (0..poses.len())
            .map(|k| {
                dirs.iter()
                    .fold(Vector3::zeros(), |acc, d| acc + d[k])
                    .try_normalize(1e-300)
                    .unwrap_or_else(Vector3::zeros)
            })
            .collect();
        let imus = (0..imus.len())
            .map(|i| ImuResidual {
                before_rms_mg: rms(poses.iter().filter_map(|p| {
                    let a = p.accel_counts.get(i)?;
                    Some((vec3(a).norm() * nominal_g_per_count - 1.0) * 1e3)
                })),
                after_rms_mg: rms(after[i].iter().copied()),
                table_rms_mg: rms(table[i].iter().copied()),
                alignment_rms_deg: rms(dirs[i]
                    .iter()
                    .zip(&mean)
                    .map(|(d, m)| angle(d, m).to_degrees())),
            })
            .collect();
        Self {
            poses: poses.len(),
            imus,
        }
    }

    /// A plain-text table, one line per IMU.
    pub fn to_text(&self) -> String {
        let mut s = format!(
            "{} poses\nIMU  before_mg  after_mg  table_mg  align_deg\n",
            self.poses
        );
        for (i, r) in self.imus.iter().enumerate() {
            s += &format!(
                "{:>3}  {:>9.2}  {:>8.3}  {:>8.3}  {:>9.4}\n",
                i + 1,
                r.before_rms_mg,
                r.after_rms_mg,
                r.table_rms_mg,
                r.alignment_rms_deg
            );
        }
        s
    }
}
