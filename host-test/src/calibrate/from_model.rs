//! The table terms a cluster model implies (`ground calibrate --from-model`, issue 27): the thermal coefficients
//! and the sensors' noise that `ground diagnose --model` fitted (`docs/twin.md`), turned into what the flight core
//! applies — raw-channel thermal terms and fixed fusion weights — on top of a base calibration.
//!
//! **Thermal.** The model's coefficient `β` of a sensor is the drift of its *calibrated* output (°/s/°C, g/°C)
//! about the model's reference temperature `T_m`, as seen through the base calibration `y = M·(raw − b(T))`. The raw
//! drift `d` that causes it satisfies `M·d = β`: for the accelerometer `d = M⁻¹β`; for the gyro (3 axes from 4 raw
//! channels: A x, A z, B y, B z) the least-norm solution `d = Mᵀ(MMᵀ)⁻¹β`, which splits the z drift between the
//! two z channels as the matrix weighs them. Any solution removes the same drift from the output; the split between
//! A z and B z is not observable from calibrated data. The base's own terms are kept and `d` added to them about
//! the base's reference `T_b` (the model's when the base has none): `b(T) = b + d·(T − T_m) = [b + d·(T_b − T_m)] +
//! d·(T − T_b)`, so the biases move by `d·(T_b − T_m)` and the output at `T_m` is unchanged. The model's law is
//! linear: quadratic terms are the base's.
//!
//! **Weights.** For each axis the model gives every sensor's Allan covariance at any τ: a sensor's own terms plus
//! the shared processes it belongs to on the diagonal, the processes two sensors share off it. The thermal part is
//! left out (the table compensates it). The weights are the same generalised least squares as `--weights`
//! ([`super::weights::solve`]) over the octave τ's of the region, without the shrinkage that a record's estimates
//! need (`MODEL_RIDGE` only keeps a sensor with no own noise from making the matrix singular), at τ's up to a
//! quarter of the record the model was fitted to: beyond it the model extrapolates.

use super::CalibError;
use super::file::{CalibrationFile, GroupThermalF64};
use super::weights::{AxisWeights, GroupsWeights, WeightOptions, solve, table_scale};
use crate::recording::SensorKind;
use crate::twin::{AxisModel, ClusterModel};
use nalgebra::{DMatrix, Matrix3, SMatrix, Vector3};

/// Share of `S` moved to its diagonal for a model's exact covariances (see the module docs).
pub const MODEL_RIDGE: f64 = 1e-9;
/// Longest τ used, as a fraction of the duration of the record the model was fitted to.
pub const MAX_TAU_FRACTION: f64 = 0.25;

/// What [`from_model`] did.
#[derive(Clone, Debug, PartialEq)]
pub struct FromModel {
    /// The base with the model's terms added.
    pub file: CalibrationFile,
    /// Sensors (group, axis) with a non-zero thermal coefficient in the model.
    pub thermal_sensors: usize,
    /// The model's reference temperature, °C (`None`: the model has no temperature).
    pub model_t_ref_c: Option<f64>,
    /// Per axis with weights (gx … az order, axes the model lacks left out): its name, groups and weights.
    pub axes: Vec<(String, GroupsWeights)>,
}

/// The base `base` with the thermal terms and, with `weights`, the fixed weights of `model` (see the module docs).
pub fn from_model(
    model: &ClusterModel,
    base: &CalibrationFile,
    weights: Option<&WeightOptions>,
) -> Result<FromModel, CalibError> {
    let groups = base.groups.len();
    let mut file = base.clone();
    let (thermal_sensors, model_t_ref_c) = add_thermal(model, &mut file)?;
    let mut axes = Vec::new();
    if let Some(opts) = weights {
        let mut table = vec![[0.0; 6]; groups];
        for axis in &model.axes {
            let Some(slot) = table_axis(axis) else {
                continue;
            };
            let (gs, w) = axis_weights(model, axis, opts)?;
            for (&g, x) in gs.iter().zip(table_scale(&w.weights)) {
                group_row(&mut table, g)?[slot] = x;
            }
            axes.push((axis.axis.clone(), (gs, w)));
        }
        if axes.is_empty() {
            return Err(CalibError::InvalidOption(
                "the model has no axis with two sensors or more: no weights to fit",
            ));
        }
        file.weights = Some(table);
    }
    Ok(FromModel {
        file,
        thermal_sensors,
        model_t_ref_c,
        axes,
    })
}

/// Group `g`'s row of a per-group table of the base; a model sensor beyond the base's groups is an error.
fn group_row(rows: &mut [[f64; 6]], g: usize) -> Result<&mut [f64; 6], CalibError> {
    let groups = rows.len();
    rows.get_mut(g).ok_or(CalibError::Count {
        what: "groups of the base (a model's sensor lies beyond them)",
        expected: groups,
        found: g + 1,
    })
}

/// The table's axis slot (gx gy gz ax ay az) of a model axis.
fn table_axis(axis: &AxisModel) -> Option<usize> {
    axis.kind_axis().map(|(kind, a)| match kind {
        SensorKind::Gyro => a,
        SensorKind::Accel => 3 + a,
    })
}

/// Adds the model's thermal coefficients to `file` (module docs); returns how many sensors had one and the
/// model's reference temperature.
fn add_thermal(
    model: &ClusterModel,
    file: &mut CalibrationFile,
) -> Result<(usize, Option<f64>), CalibError> {
    let Some(temp) = &model.temperature else {
        return Ok((0, None));
    };
    let t_m = temp.reference_c;
    // β per group: gx gy gz ax ay az.
    let mut beta = vec![[0.0f64; 6]; file.groups.len()];
    let mut count = 0;
    for axis in &model.axes {
        let Some(slot) = table_axis(axis) else {
            continue;
        };
        for s in axis.sensors.iter().filter(|s| s.thermal_per_c != 0.0) {
            group_row(&mut beta, s.group)?[slot] = s.thermal_per_c;
            count += 1;
        }
    }
    if count == 0 {
        return Ok((0, Some(t_m)));
    }
    let t_b = if file.thermal.is_some() {
        file.t_ref_c
    } else {
        t_m
    };
    let mut thermal = file
        .thermal
        .take()
        .unwrap_or_else(|| vec![GroupThermalF64::default(); file.groups.len()]);
    for ((cal, th), b) in file.groups.iter_mut().zip(&mut thermal).zip(&beta) {
        let mg = SMatrix::<f64, 3, 4>::from_fn(|r, c| cal.gyro_matrix_dps_per_count[r][c]);
        let ma = Matrix3::from_fn(|r, c| cal.accel_matrix_g_per_count[r][c]);
        let dg = (mg * mg.transpose())
            .try_inverse()
            .map(|inv| mg.transpose() * inv * Vector3::new(b[0], b[1], b[2]))
            .ok_or(CalibError::Degenerate(
                "a gyro matrix of the base has no right inverse",
            ))?;
        let da = ma
            .try_inverse()
            .map(|inv| inv * Vector3::new(b[3], b[4], b[5]))
            .ok_or(CalibError::Degenerate(
                "an accelerometer matrix of the base is singular",
            ))?;
        for c in 0..4 {
            th.gyro_lin_counts_per_c[c] += dg[c];
            cal.gyro_bias_counts[c] += dg[c] * (t_b - t_m);
        }
        for c in 0..3 {
            th.accel_lin_counts_per_c[c] += da[c];
            cal.accel_bias_counts[c] += da[c] * (t_b - t_m);
        }
    }
    file.thermal = Some(thermal);
    file.t_ref_c = t_b;
    Ok((count, Some(t_m)))
}

/// The model's Allan covariance of one axis's sensors at τ (module docs), in the order of `axis.sensors`, at the
/// record's `rate_hz` (through the axis's bandwidth, when it has one).
pub fn model_covariance(axis: &AxisModel, tau_s: f64, rate_hz: f64) -> DMatrix<f64> {
    let n = axis.sensors.len();
    let band = axis.low_pass(rate_hz);
    let mut c = DMatrix::zeros(n, n);
    for (i, s) in axis.sensors.iter().enumerate() {
        c[(i, i)] = s.independent.avar(tau_s, 1.0 / rate_hz, band.as_ref());
    }
    for p in &axis.shared {
        let v = p.terms.avar(tau_s, 1.0 / rate_hz, band.as_ref());
        let members: Vec<usize> = (0..n)
            .filter(|&i| p.groups.contains(&axis.sensors[i].group))
            .collect();
        for &i in &members {
            for &j in &members {
                c[(i, j)] += v;
            }
        }
    }
    c
}

/// One axis's weights from the model for the region of `opts`.
fn axis_weights(
    model: &ClusterModel,
    axis: &AxisModel,
    opts: &WeightOptions,
) -> Result<GroupsWeights, CalibError> {
    let rate = model.record.rate_hz;
    let tau_cap = model.record.duration_s * MAX_TAU_FRACTION;
    if !(opts.tau_min_s > 0.0 && opts.tau_max_s >= opts.tau_min_s && rate > 0.0) {
        return Err(CalibError::InvalidOption(
            "0 < tau_min ≤ tau_max and a positive rate",
        ));
    }
    let taus: Vec<f64> = (0..64)
        .map(|k| f64::from(k).exp2() / rate)
        .take_while(|&t| t <= opts.tau_max_s.min(tau_cap))
        .filter(|&t| t >= opts.tau_min_s)
        .collect();
    if taus.is_empty() {
        return Err(CalibError::InvalidOption(
            "no octave τ of the region lies within a quarter of the record the model was fitted to",
        ));
    }
    let covs: Vec<DMatrix<f64>> = taus
        .iter()
        .map(|&t| model_covariance(axis, t, rate))
        .collect();
    let w = solve(&covs, MODEL_RIDGE, opts.allow_negative)?;
    let aw = AxisWeights::evaluated(&w, &covs, taus);
    Ok((axis.sensors.iter().map(|s| s.group).collect(), aw))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::twin::{
        FORMAT, NoiseTerms, RecordInfo, SensorModel, SharedProcess, TemperatureModel,
    };
    use shared::calib::thermal::ThermalComp;
    use shared::calib::{CalibrationTable, RawCounts};

    const AXIS_NAMES: [&str; 6] = ["gx", "gy", "gz", "ax", "ay", "az"];

    fn white(n: f64) -> NoiseTerms {
        NoiseTerms {
            white: n,
            ..NoiseTerms::default()
        }
    }

    /// A model of `groups` sensors per axis with the given own terms and thermal coefficients, reference `t_ref_c`.
    fn model(
        groups: &[usize],
        own: impl Fn(usize, usize) -> NoiseTerms,
        beta: impl Fn(usize, usize) -> f64,
        t_ref_c: f64,
    ) -> ClusterModel {
        ClusterModel {
            format: FORMAT.into(),
            record: RecordInfo {
                source: "test".into(),
                rate_hz: 5.0,
                samples: 144_000,
                duration_s: 28_800.0,
                groups: groups.to_vec(),
                columns: Vec::new(),
            },
            temperature: Some(TemperatureModel {
                reference_c: t_ref_c,
                start_c: t_ref_c,
                drift_c_per_h: 0.0,
                harmonics: Vec::new(),
                noise: NoiseTerms::default(),
            }),
            effects: Vec::new(),
            axes: AXIS_NAMES
                .iter()
                .enumerate()
                .map(|(a, name)| AxisModel {
                    axis: (*name).into(),
                    unit: if a < 3 { "deg/s" } else { "g" }.into(),
                    typical: white(1.0),
                    effects: Vec::new(),
                    sensors: groups
                        .iter()
                        .map(|&g| SensorModel {
                            group: g,
                            mean: 0.0,
                            independent: own(g, a),
                            thermal_per_c: beta(g, a),
                            sinusoids: Vec::new(),
                            steps: Vec::new(),
                        })
                        .collect(),
                    shared: Vec::new(),
                    bandwidth_hz: None,
                    coverage: None,
                })
                .collect(),
        }
    }

    /// Group 3's six outputs (µ°/s, µg) through the flight core's thermal compensation (`ThermalComp`, fixed point)
    /// at board temperature `t_c`.
    fn core_output(table: &CalibrationTable<16>, raw: &RawCounts, t_c: f64) -> [i32; 6] {
        let mut tc = ThermalComp::<16>::new();
        tc.load(table);
        tc.update(table, Some((t_c * 100.0).round() as i16));
        tc.groups()[3].apply(raw)
    }

    /// The drift the flight core shows without compensation, measured through the core and written into a model,
    /// is cancelled by the table `from_model` makes — through the core again (the independent reference: its
    /// fixed-point calibration, not this module's algebra) — for a base without thermal terms and for one with
    /// terms about another reference; the output at the model's reference is unchanged.
    #[test]
    fn the_flight_core_cancels_the_drift_the_model_measured() {
        let t_m = 21.5;
        // Raw drift, counts/°C, per channel (A z and B z unequal: the split between them is free).
        let k = [0.8, -0.5, 0.3, 1.1, 2.0, -1.5, 0.7];
        let raw_at = |t: f64| {
            let c = |i: usize, base: f64| (base + k[i] * (t - t_m)).round() as i32;
            RawCounts {
                gyro: [
                    c(0, 33_000.0),
                    c(1, 31_000.0),
                    c(2, 32_500.0),
                    c(3, 33_500.0),
                ],
                accel: [c(4, 30_000.0), c(5, 36_000.0), c(6, 40_000.0)],
            }
        };
        let factory = CalibrationFile::from_table(&CalibrationTable::<16>::factory());
        let mut warm = factory.clone();
        warm.t_ref_c = 30.0;
        let mut th = vec![GroupThermalF64::default(); 16];
        th[3].gyro_lin_counts_per_c = [0.2, 0.0, -0.1, 0.0];
        th[3].accel_lin_counts_per_c = [0.0, 0.3, 0.0];
        warm.thermal = Some(th);
        for base in [factory, warm] {
            let t0 = base.to_table::<16>().unwrap();
            let y0 = |t: f64| core_output(&t0, &raw_at(t), t);
            let (lo, hi) = (y0(t_m - 10.0), y0(t_m + 10.0));
            let beta: Vec<f64> = (0..6)
                .map(|a| f64::from(hi[a] - lo[a]) / 20.0 / 1e6)
                .collect();
            assert!(
                beta.iter().all(|b| b.abs() > 1e-5),
                "a drift to cancel: {beta:?}"
            );
            let m = model(&[3], |_, _| white(1.0), |_, a| beta[a], t_m);
            let r = from_model(&m, &base, None).unwrap();
            assert_eq!(r.thermal_sensors, 6);
            let t1 = r.file.to_table::<16>().unwrap();
            let y1 = |t: f64| core_output(&t1, &raw_at(t), t);
            let at_ref = y1(t_m);
            for (a, (x, y)) in at_ref.iter().zip(y0(t_m)).enumerate() {
                assert!(
                    (x - y).abs() <= 2,
                    "axis {a}: output at T_m moved {x} vs {y}"
                );
            }
            // Whole-count raw drifts (ΔT a multiple of 10 °C): the raw codes carry no rounding of their own.
            for t in [-30.0, -20.0, -10.0, 10.0, 20.0, 40.0].map(|d| t_m + d) {
                let (before, after) = (y0(t), y1(t));
                for a in 0..6 {
                    let drift_before = (before[a] - y0(t_m)[a]).abs();
                    let drift_after = (after[a] - at_ref[a]).abs();
                    // Left: the rounding of the Q28 coefficients and of the core (a few LSB).
                    assert!(
                        drift_after <= 4 + drift_before / 1000,
                        "axis {a} at {t} °C: drift {drift_before} → {drift_after} (µ-units)"
                    );
                }
            }
        }
    }

    /// Independent white sensors: the weights are the inverse-variance weights, `wᵢ ∝ 1/Nᵢ²` (closed form), to
    /// the ridge's precision.
    #[test]
    fn white_sensors_get_inverse_variance_weights() {
        let n = [1.0, 2.0, 0.5, 1.0];
        let m = model(&[0, 1, 2, 3], |g, _| white(n[g]), |_, _| 0.0, 20.0);
        let opts = WeightOptions {
            tau_min_s: 10.0,
            tau_max_s: 1000.0,
            allow_negative: false,
        };
        let r = from_model(
            &m,
            &CalibrationFile::from_table(&CalibrationTable::<16>::factory()),
            Some(&opts),
        )
        .unwrap();
        let inv: Vec<f64> = n.iter().map(|x| 1.0 / (x * x)).collect();
        let sum: f64 = inv.iter().sum();
        for (name, (groups, w)) in &r.axes {
            assert_eq!(groups, &[0, 1, 2, 3]);
            for (got, want) in w.weights.iter().zip(&inv) {
                assert!(
                    (got - want / sum).abs() < 1e-6,
                    "{name}: {got} vs {}",
                    want / sum
                );
            }
            // Octave τ's of 1/5 s within the region.
            assert_eq!(w.taus_s.first().copied(), Some(12.8));
            assert_eq!(w.taus_s.last().copied(), Some(819.2));
        }
        let table = r.file.weights.unwrap();
        // Scaled so that the largest is 1: group 2's (N = 0.5).
        assert!((table[2][0] - 1.0).abs() < 1e-9 && (table[1][0] - 1.0 / 16.0).abs() < 1e-6);
        assert!(table[4..].iter().all(|row| row.iter().all(|&x| x == 0.0)));
    }

    /// One sensor with a random walk that only shows at long τ, and a process all sensors share: the drifting
    /// sensor loses its weight in a long-τ region and keeps its share in a short one, and at one τ the shared
    /// process changes nothing (the constraint Σw = 1 makes it a constant; over several τ's it changes how each
    /// τ counts, through the scaling by its mean variance).
    #[test]
    fn a_sensor_drifting_at_long_tau_loses_its_weight_there() {
        let own = |g: usize, _| NoiseTerms {
            white: 0.01,
            random_walk: if g == 5 { 1e-4 } else { 0.0 },
            ..NoiseTerms::default()
        };
        let groups: Vec<usize> = (0..8).collect();
        let mut m = model(&groups, own, |_, _| 0.0, 20.0);
        let base = CalibrationFile::from_table(&CalibrationTable::<16>::factory());
        let region = |lo, hi| WeightOptions {
            tau_min_s: lo,
            tau_max_s: hi,
            allow_negative: false,
        };
        let w_of =
            |m: &ClusterModel, o| from_model(m, &base, Some(&o)).unwrap().axes[0].1.1.weights[5];
        let (short, long) = (w_of(&m, region(0.2, 2.0)), w_of(&m, region(1000.0, 7000.0)));
        assert!((short - 1.0 / 8.0).abs() < 0.01, "short τ: {short}");
        assert!(long < 0.02, "long τ: {long}");
        // One octave: 1638.4 s.
        let one = w_of(&m, region(1000.0, 1700.0));
        for axis in &mut m.axes {
            axis.shared.push(SharedProcess {
                kind: "common_mode_drift".into(),
                groups: groups.clone(),
                terms: NoiseTerms {
                    random_walk: 1e-3,
                    ..NoiseTerms::default()
                },
                sinusoids: Vec::new(),
            });
        }
        let with_shared = w_of(&m, region(1000.0, 1700.0));
        assert!((with_shared - one).abs() < 1e-6, "{one} → {with_shared}");
    }

    /// A region beyond a quarter of the model's record is refused: the model would only extrapolate there.
    #[test]
    fn a_region_beyond_the_record_is_refused() {
        let m = model(&[0, 1], |_, _| white(1.0), |_, _| 0.0, 20.0);
        let o = WeightOptions {
            tau_min_s: 10_000.0,
            tau_max_s: 20_000.0,
            allow_negative: false,
        };
        let base = CalibrationFile::from_table(&CalibrationTable::<16>::factory());
        assert!(matches!(
            from_model(&m, &base, Some(&o)),
            Err(CalibError::InvalidOption(_))
        ));
    }
}
