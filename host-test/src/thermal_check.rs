//! The end-to-end check of on-board thermal compensation (issue 27), as `docs/calibration.md` describes it: one
//! simulated board (fixed board seed) recorded still over a temperature ramp, calibrated with
//! [`fit_thermal`] (the factory table plus the fitted terms, as
//! `ground calibrate --thermal` writes it), then an orbit's temperature cycle replayed through the flight core with
//! and without the table, and an isothermal record of the same board.
//!
//! The isothermal record has the orbit record's noise seed as well as its board seed: the same sensors and the
//! same noise, only the temperature differs, so the ratio of fused Allan deviations measures what the temperature
//! leaves after compensation, without the scatter of two noise draws. Fused deviations: overlapping ADEV
//! ([`crate::allan`], octave τ) of the six axes of the Fused reports decoded from the core's telemetry.

use crate::allan::{self, DevKind, TauSpec};
use crate::calibrate::CalibError;
use crate::calibrate::{CalibrationFile, ThermalOptions, fit_thermal};
use crate::formats::framelog::FrameLog;
use crate::formats::telemetry::TelemetryLog;
use crate::replay::{ReplayOptions, replay};
use crate::sim::SimError;
use crate::sim::effects::EffectsError;
use crate::sim::output::frame_opts;
use crate::sim::{
    Axis, Channel, Chunk, Effects, SimConfig, Simulator, TemperatureProfile, ThermalCoef,
};
use shared::bus::BusConfig;
use shared::calib::{AXES, CalibrationTable};
use shared::pipeline::PipelineConfig;
use shared::wire::frame::GROUPS;

/// Why the check could not run.
#[derive(Debug, thiserror::Error)]
pub enum ThermalCheckError {
    /// The simulator refused a configuration.
    #[error(transparent)]
    Sim(#[from] SimError),
    /// The thermal effects were refused.
    #[error(transparent)]
    Effects(#[from] EffectsError),
    /// The thermal fit or the calibration table failed.
    #[error(transparent)]
    Calib(#[from] CalibError),
    /// The simulated board has no thermal coefficient for a group.
    #[error("group")]
    NoThermalTruth,
}

/// The result of this module's functions.
pub type Result<T, E = ThermalCheckError> = std::result::Result<T, E>;

/// Parameters of the check.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ThermalCheckOptions {
    /// Seed of the board's parts (thermal coefficients among them).
    pub board_seed: u64,
    /// Noise seed of the ramp record.
    pub ramp_seed: u64,
    /// Noise seed of the orbit and isothermal records.
    pub orbit_seed: u64,
    /// Frame rate, Hz (the FPGA base rate divided by a whole number).
    pub rate_hz: f64,
    /// Ramp −10 → 50 °C over this many hours (the record's length).
    pub ramp_hours: f64,
    /// Orbit record (mean 20 °C, amplitude 8 °C, 95 min) and isothermal record (20 °C), hours.
    pub orbit_hours: f64,
    /// Frames averaged per Fused report.
    pub frames_per_output: u16,
}

impl ThermalCheckOptions {
    /// Issue 27's command lines: 18.9 Hz, 3 h ramp, 8 h orbit, 32 frames per report (`ground replay`'s default).
    pub const ISSUE: Self = Self {
        board_seed: 7,
        ramp_seed: 1,
        orbit_seed: 2,
        rate_hz: 18.9,
        ramp_hours: 3.0,
        orbit_hours: 8.0,
        frames_per_output: 32,
    };

    /// The same at a quarter of the frame rate (4.725 Hz) and 8 frames per report: the same report interval
    /// (1.69 s) and τ grid, a quarter of the frames (the demo and the test).
    pub const QUICK: Self = Self {
        rate_hz: 18.9 / 4.0,
        frames_per_output: 8,
        ..Self::ISSUE
    };
}

/// The fit compared with the simulator's true coefficients, per raw channel type.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct FitAccuracy {
    /// Largest |fitted − true| linear coefficient over the 16 groups, counts/°C.
    pub max_lin_err_counts_per_c: f64,
    /// Largest |fitted − true| / standard error of the linear coefficient.
    pub max_lin_z: f64,
    /// Largest |fitted − 0| / standard error of the quadratic coefficient (the simulated law is linear).
    pub max_quad_z: f64,
    /// Mean true linear coefficient, counts/°C.
    pub mean_true_lin_counts_per_c: f64,
}

/// The check's results.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ThermalCheck {
    /// Options used.
    #[serde(skip)]
    pub opts: ThermalCheckOptions,
    /// Per raw channel (frame order).
    pub fit: [FitAccuracy; 7],
    /// (fitted − true) / standard error of every raw channel's linear coefficient (group-major).
    pub lin_z: Vec<f64>,
    /// fitted / standard error of every quadratic coefficient (the simulated law has none).
    pub quad_z: Vec<f64>,
    /// τ of the compared octaves (≥ 100 s), s.
    pub taus_s: Vec<f64>,
    /// Overlapping Allan deviation of the fused axes, per axis and τ: isothermal record.
    pub dev_isothermal: [Vec<f64>; AXES],
    /// Orbit record with the thermal table.
    pub dev_compensated: [Vec<f64>; AXES],
    /// Orbit record with the factory table.
    pub dev_uncompensated: [Vec<f64>; AXES],
    /// Fused reports per record.
    pub reports: usize,
    /// Wall-clock seconds.
    pub seconds: f64,
}

impl ThermalCheck {
    /// Compensated / isothermal deviation, per axis and τ.
    pub fn with_ratio(&self) -> [Vec<f64>; AXES] {
        core::array::from_fn(|a| ratio(&self.dev_compensated[a], &self.dev_isothermal[a]))
    }

    /// Uncompensated / isothermal deviation, per axis and τ.
    pub fn without_ratio(&self) -> [Vec<f64>; AXES] {
        core::array::from_fn(|a| ratio(&self.dev_uncompensated[a], &self.dev_isothermal[a]))
    }

    /// A table of the ratios (one line per τ, both ratios per axis) and the fit's accuracy.
    pub fn report(&self) -> String {
        use std::fmt::Write as _;
        let mut s = String::new();
        let o = &self.opts;
        let _ = writeln!(
            s,
            "thermal compensation (board seed {}, {} Hz, ramp −10 → 50 °C over {} h; orbit 20 ± 8 °C, 95 min, and \
             isothermal 20 °C, {} h each, {} reports of {} frames):",
            o.board_seed, o.rate_hz, o.ramp_hours, o.orbit_hours, self.reports, o.frames_per_output
        );
        let _ = writeln!(
            s,
            "  fit vs the simulator's true coefficients, per raw channel: max |error| counts/°C (max |z|), max |quad/SE|"
        );
        for (name, f) in RAW_NAMES.iter().zip(&self.fit) {
            let _ = writeln!(
                s,
                "    {name:9} true mean {:+7.3}: {:.4} ({:.2}σ), quad {:.2}σ",
                f.mean_true_lin_counts_per_c, f.max_lin_err_counts_per_c, f.max_lin_z, f.max_quad_z
            );
        }
        let rms = |z: &[f64]| (z.iter().map(|x| x * x).sum::<f64>() / z.len() as f64).sqrt();
        let _ = writeln!(
            s,
            "    RMS z over the 112 channels: linear {:.2}, quadratic {:.2} (1 if the standard errors are right)",
            rms(&self.lin_z),
            rms(&self.quad_z)
        );
        let _ = writeln!(
            s,
            "  fused OADEV ratio to the isothermal record, with table / without (gx gy gz ax ay az):"
        );
        let (w, wo) = (self.with_ratio(), self.without_ratio());
        for (i, tau) in self.taus_s.iter().enumerate() {
            let _ = write!(s, "    τ {tau:7.0} s:");
            for a in 0..AXES {
                let _ = write!(s, "  {:.2}/{:.1}", w[a][i], wo[a][i]);
            }
            s.push('\n');
        }
        let _ = writeln!(s, "  ({:.1} s)", self.seconds);
        s
    }
}

const RAW_NAMES: [&str; 7] = [
    "gyro A x", "gyro A z", "gyro B y", "gyro B z", "accel x", "accel y", "accel z",
];

fn ratio(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x / y).collect()
}

/// The configuration `ground simulate` builds for the seed preset with the issue's thermal flags
/// (`--thermal gyro:0.05:0.02 --thermal accel:0.0005:0.0002 --temperature …`), for the board of `o` with noise seed
/// `seed`.
pub fn config(
    o: &ThermalCheckOptions,
    seed: u64,
    hours: f64,
    temp: TemperatureProfile,
) -> Result<SimConfig> {
    let mut cfg = crate::sim::preset::seed_config(seed)?;
    cfg.rate_hz = o.rate_hz;
    cfg.samples = (hours * 3600.0 * o.rate_hz).round() as u64;
    cfg.frames = frame_opts(o.rate_hz, crate::FPGA_BASE_RATE_HZ);
    cfg.board_seed = Some(o.board_seed);
    let (gyro, accel) = Axis::ALL.split_at(3);
    Effects {
        thermal: vec![
            ThermalCoef {
                axes: gyro.to_vec(),
                coef: 0.05,
                sd: 0.02,
            },
            ThermalCoef {
                axes: accel.to_vec(),
                coef: 0.0005,
                sd: 0.0002,
            },
        ],
        temperature: Some(temp),
        ..Effects::default()
    }
    .apply(&mut cfg)?;
    Ok(cfg)
}

/// The frame log of a simulation, and the simulator (for its true parameters).
pub fn frames(cfg: SimConfig) -> Result<(Vec<u8>, Simulator)> {
    let mut sim = Simulator::new(cfg)?;
    let mut bytes = Vec::with_capacity(sim.remaining() as usize * shared::wire::frame::FRAME_LEN);
    let mut chunk = Chunk::default();
    while sim.next_chunk(&mut chunk) > 0 {
        for i in 0..chunk.len {
            if let Some(f) = chunk.frame(i) {
                bytes.extend_from_slice(&f.to_bytes());
            }
        }
    }
    Ok((bytes, sim))
}

/// The six fused axes (°/s, g) of a frame log replayed through the core with `cal`, as decoded from telemetry.
pub fn fused(bytes: &[u8], cal: CalibrationTable<GROUPS>, fpo: u16) -> Vec<[f64; AXES]> {
    let opts = ReplayOptions {
        config: PipelineConfig {
            frames_per_output: fpo,
            ..PipelineConfig::DEFAULT
        },
        cal,
        bus: BusConfig::DEFAULT,
        final_dump: false,
        check: false,
    };
    let out = replay(bytes, &opts, |_| {});
    TelemetryLog::decode(&out.telemetry, &BusConfig::DEFAULT)
        .fused()
        .map(|r| r.axes().map(|x| f64::from(x) / 1e6))
        .collect()
}

/// Runs the check (see the module docs).
pub fn run(o: &ThermalCheckOptions) -> Result<ThermalCheck> {
    let t0 = std::time::Instant::now();
    let ramp = TemperatureProfile::Ramp {
        from_c: -10.0,
        to_c: 50.0,
        hours: o.ramp_hours,
    };
    let (ramp_bytes, ramp_sim) = frames(config(o, o.ramp_seed, o.ramp_hours, ramp)?)?;
    let log = FrameLog::decode(&ramp_bytes);
    drop(ramp_bytes);
    let fit = fit_thermal(&log.frames, &ThermalOptions::default(), "ramp")?;
    drop(log);
    let mut fit_acc = [FitAccuracy {
        max_lin_err_counts_per_c: 0.0,
        max_lin_z: 0.0,
        max_quad_z: 0.0,
        mean_true_lin_counts_per_c: 0.0,
    }; 7];
    let (mut lin_z, mut quad_z) = (Vec::new(), Vec::new());
    for (c, (ch, acc)) in Channel::ALL.iter().zip(&mut fit_acc).enumerate() {
        for g in 0..GROUPS {
            let truth = ramp_sim
                .thermal_coef_counts(g, *ch)
                .ok_or(ThermalCheckError::NoThermalTruth)?;
            let t = &fit.terms[g];
            let (lin, quad) = if c < 4 {
                (t.gyro_lin_counts_per_c[c], t.gyro_quad_counts_per_c2[c])
            } else {
                (
                    t.accel_lin_counts_per_c[c - 4],
                    t.accel_quad_counts_per_c2[c - 4],
                )
            };
            let m = &fit.meta.groups[g];
            lin_z.push((lin - truth) / m.lin_se_counts_per_c[c]);
            quad_z.push(quad / m.quad_se_counts_per_c2[c]);
            acc.max_lin_err_counts_per_c = acc.max_lin_err_counts_per_c.max((lin - truth).abs());
            acc.max_lin_z = acc
                .max_lin_z
                .max((lin - truth).abs() / m.lin_se_counts_per_c[c]);
            acc.max_quad_z = acc.max_quad_z.max(quad.abs() / m.quad_se_counts_per_c2[c]);
            acc.mean_true_lin_counts_per_c += truth / GROUPS as f64;
        }
    }
    let mut file = CalibrationFile::from_table(&CalibrationTable::<GROUPS>::factory());
    (file.cal_id, file.t_ref_c, file.thermal) = (1, fit.t_ref_c, Some(fit.terms));
    let table = file.to_table::<GROUPS>()?;

    let orbit = TemperatureProfile::Orbit {
        mean_c: 20.0,
        amp_c: 8.0,
        period_min: 95.0,
    };
    let (orbit_bytes, _) = frames(config(o, o.orbit_seed, o.orbit_hours, orbit)?)?;
    let fpo = o.frames_per_output;
    let comp = fused(&orbit_bytes, table, fpo);
    let uncomp = fused(&orbit_bytes, CalibrationTable::factory(), fpo);
    drop(orbit_bytes);
    let iso_t = TemperatureProfile::Constant { c: 20.0 };
    let (iso_bytes, _) = frames(config(o, o.orbit_seed, o.orbit_hours, iso_t)?)?;
    let iso = fused(&iso_bytes, table, fpo);
    drop(iso_bytes);

    let frame_rate = crate::FPGA_BASE_RATE_HZ
        / (f64::from(frame_opts(o.rate_hz, crate::FPGA_BASE_RATE_HZ).decimation) + 1.0);
    let tau0 = f64::from(fpo) / frame_rate;
    let mut an = allan::Analyzer::new();
    let mut dev = |rec: &[[f64; AXES]], a: usize| -> Vec<(f64, f64)> {
        let y: Vec<f64> = rec.iter().map(|v| v[a]).collect();
        an.analyze(
            DevKind::Oadev,
            &y,
            tau0,
            &TauSpec::Octave,
            &allan::Options::default(),
        )
        .iter()
        .filter(|p| p.tau_s >= 100.0)
        .map(|p| (p.tau_s, p.dev))
        .collect()
    };
    let mut taus_s = Vec::new();
    let mut out: [[Vec<f64>; AXES]; 3] = Default::default();
    for (k, rec) in [&iso, &comp, &uncomp].into_iter().enumerate() {
        for (a, slot) in out[k].iter_mut().enumerate() {
            let d = dev(rec, a);
            if a == 0 && k == 0 {
                taus_s = d.iter().map(|x| x.0).collect();
            }
            *slot = d.iter().map(|x| x.1).collect();
        }
    }
    let [dev_isothermal, dev_compensated, dev_uncompensated] = out;
    Ok(ThermalCheck {
        opts: *o,
        fit: fit_acc,
        lin_z,
        quad_z,
        taus_s,
        dev_isothermal,
        dev_compensated,
        dev_uncompensated,
        reports: iso.len().min(comp.len()).min(uncomp.len()),
        seconds: t0.elapsed().as_secs_f64(),
    })
}
