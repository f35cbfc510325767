//! `imu_cluster`: the ground library (`host_test`) for Python users — conversion only, no logic of its own. Every
//! function calls the library entry point the `ground` CLI calls and converts its result to numpy arrays and dicts;
//! library errors become `imu_cluster.Error` (a `ValueError`) carrying the library's message, as the CLI prints it.

use host_test::allan::{self as allan_lib, DevKind, TauSpec};
use host_test::formats::telemetry::TelemetryLog;
use host_test::formats::telemetry::tables::{Table, Values};
use host_test::recording::Recording;
use host_test::{diagnose as diag, load, seedfit, sim, twin};
use numpy::{IntoPyArray, PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1, PyReadonlyArray2};
use pyo3::prelude::*;
use pyo3::types::PyDict;
use shared::bus::BusConfig;
use shared::bus::csp::CspVersion;
use shared::wire::clock::FPGA_BASE_RATE_MILLIHZ;
use std::path::PathBuf;

pyo3::create_exception!(
    imu_cluster,
    Error,
    pyo3::exceptions::PyValueError,
    "An error of the ground library (bad input, unreadable file), with the message the `ground` CLI prints."
);

/// A library error as `imu_cluster.Error`, with its whole chain of causes (the CLI's `error: …` text).
fn lib_err(e: impl Into<anyhow::Error>) -> PyErr {
    Error::new_err(format!("{:#}", e.into()))
}

/// `(t, data, columns)` of a recording: data is (samples × columns), the sensor columns in the recording's order,
/// then `temp_c` when the recording has a temperature.
type Matrix<'py> = (
    Bound<'py, PyArray1<f64>>,
    Bound<'py, PyArray2<f64>>,
    Vec<String>,
);

/// Converts a recording to [`Matrix`].
fn matrix(py: Python<'_>, rec: Recording) -> PyResult<Matrix<'_>> {
    let mut names: Vec<String> = rec.columns.iter().map(|c| c.name()).collect();
    let mut cols: Vec<&[f64]> = rec.columns.iter().map(|c| &c.data[..]).collect();
    if let Some(t) = &rec.temp_c {
        names.push("temp_c".into());
        cols.push(t);
    }
    let n = rec.t_s.len();
    let mut flat = Vec::with_capacity(n * cols.len());
    for i in 0..n {
        flat.extend(cols.iter().map(|c| c[i]));
    }
    let data = flat.into_pyarray(py).reshape([n, cols.len()])?;
    Ok((rec.t_s.into_pyarray(py), data, names))
}

/// Passes the loader's notes and warnings on as Python `UserWarning`s.
fn warn_loaded(py: Python<'_>, loaded: &load::Loaded) -> PyResult<()> {
    let category = py.get_type::<pyo3::exceptions::PyUserWarning>();
    for w in loaded.notes.iter().chain(&loaded.warnings) {
        let msg = std::ffi::CString::new(w.as_str()).unwrap_or_default();
        PyErr::warn(py, category.as_any(), &msg, 1)?;
    }
    Ok(())
}

/// Loads any recording the CLI reads, through an optional calibration table.
fn load_any(py: Python<'_>, path: &std::path::Path, calib: Option<PathBuf>) -> PyResult<Recording> {
    let cal = calib
        .as_deref()
        .map(load::read_any_calibration)
        .transpose()
        .map_err(lib_err)?;
    let loaded = load::load_with(path, cal.as_ref(), FPGA_BASE_RATE_MILLIHZ).map_err(lib_err)?;
    warn_loaded(py, &loaded)?;
    Ok(loaded.recording)
}

/// Reads a recording: interchange CSV, NumPy `.npy`, FPGA frame log or MIMU4444 stream (as `ground allan` reads it).
///
/// Returns `(t, data, columns)`: times in s, a (samples × columns) float64 array in °/s and g, and the column names
/// (`g00x` … `a15z`, then `temp_c` when present). `calib` is a calibration table (.bin) for raw inputs.
#[pyfunction]
#[pyo3(signature = (path, calib=None))]
fn read(py: Python<'_>, path: PathBuf, calib: Option<PathBuf>) -> PyResult<Matrix<'_>> {
    let rec = load_any(py, &path, calib)?;
    matrix(py, rec)
}

/// A table as a dict of numpy arrays (text columns as numpy string arrays).
fn table_dict<'py>(py: Python<'py>, t: Table) -> PyResult<Bound<'py, PyDict>> {
    let d = PyDict::new(py);
    let np_array = py.import("numpy")?.getattr("array")?;
    for (name, values) in t.columns {
        match values {
            Values::Num(v) => d.set_item(name, v.into_pyarray(py))?,
            Values::Text(v) => d.set_item(name, np_array.call1((v,))?)?,
        }
    }
    Ok(d)
}

/// Decodes a telemetry stream (bus bytes: CSP packets in KISS frames), as `ground decode` does.
///
/// Returns a dict with one dict of numpy arrays per message kind (`fused`, `nav`, `allan`, `health`,
/// `housekeeping`, `time`, `faults`, `ack`, `pps`; fields flattened with `.`, `null` as NaN) and `stats`: the counts
/// of what could not be decoded (`frames`, `kiss_errors`, `csp_errors`, `other_port`, `bad_messages`).
#[pyfunction]
#[pyo3(signature = (path, csp_version=1))]
fn decode(py: Python<'_>, path: PathBuf, csp_version: u8) -> PyResult<Bound<'_, PyDict>> {
    let version: CspVersion = csp_version.to_string().parse().map_err(Error::new_err)?;
    let config = BusConfig {
        version,
        ..BusConfig::DEFAULT
    };
    let log = TelemetryLog::read(&path, &config).map_err(lib_err)?;
    let out = PyDict::new(py);
    for (kind, table) in log.tables().map_err(lib_err)? {
        out.set_item(kind, table_dict(py, table)?)?;
    }
    out.set_item(
        "stats",
        json_to_py(py, &serde_json::to_string(&log.stats).map_err(lib_err)?)?,
    )?;
    Ok(out)
}

/// A JSON text as Python objects (`json.loads`).
fn json_to_py<'py>(py: Python<'py>, text: &str) -> PyResult<Bound<'py, PyAny>> {
    py.import("json")?.call_method1("loads", (text,))
}

/// The τ list of `taus`: a name (`octave`, `decade`, `all`, or points per decade as text) or averaging factors.
fn tau_spec(taus: &Bound<'_, PyAny>) -> PyResult<TauSpec> {
    if let Ok(s) = taus.extract::<String>() {
        return TauSpec::parse(&s).map_err(lib_err);
    }
    Ok(TauSpec::Factors(taus.extract::<Vec<usize>>()?))
}

/// Allan-family deviation of frequency data `x` sampled at `rate` Hz, with noise identification, EDF and 68.27 %
/// confidence intervals (as `ground allan` computes them).
///
/// `kind`: `"adev"`, `"oadev"` or `"mdev"`; `taus`: `"octave"`, `"decade"`, `"all"`, a number of points per decade
/// as text, or a list of averaging factors m. Returns a dict of numpy arrays: `taus` (s), `m`, `n` (terms), `dev`,
/// `ci_lo`, `ci_hi`, `edf`, `alpha` (NaN where the noise type is unknown).
#[pyfunction]
#[pyo3(signature = (x, rate, kind="oadev", taus=None))]
fn allan<'py>(
    py: Python<'py>,
    x: PyReadonlyArray1<'_, f64>,
    rate: f64,
    kind: &str,
    taus: Option<&Bound<'_, PyAny>>,
) -> PyResult<Bound<'py, PyDict>> {
    let kind = DevKind::from_name(kind).map_err(lib_err)?;
    let spec = taus.map(tau_spec).transpose()?.unwrap_or(TauSpec::Octave);
    if !(rate.is_finite() && rate > 0.0) {
        return Err(Error::new_err(format!(
            "the rate must be a positive number of Hz, found {rate}"
        )));
    }
    let y: Vec<f64> = x.as_array().iter().copied().collect();
    let pts = allan_lib::analyze(kind, &y, 1.0 / rate, &spec, &allan_lib::Options::default());
    let d = PyDict::new(py);
    let col =
        |f: &dyn Fn(&allan_lib::AnalysisPoint) -> f64| pts.iter().map(f).collect::<Vec<f64>>();
    let nan = f64::NAN;
    d.set_item("taus", col(&|p| p.tau_s).into_pyarray(py))?;
    d.set_item("m", col(&|p| p.m as f64).into_pyarray(py))?;
    d.set_item("n", col(&|p| p.n as f64).into_pyarray(py))?;
    d.set_item("dev", col(&|p| p.dev).into_pyarray(py))?;
    d.set_item("ci_lo", col(&|p| p.dev_lo.unwrap_or(nan)).into_pyarray(py))?;
    d.set_item("ci_hi", col(&|p| p.dev_hi.unwrap_or(nan)).into_pyarray(py))?;
    d.set_item("edf", col(&|p| p.edf.unwrap_or(nan)).into_pyarray(py))?;
    let alpha = col(&|p| p.alpha().map_or(nan, f64::from));
    d.set_item("alpha", alpha.into_pyarray(py))?;
    Ok(d)
}

/// A recording from a path, or from a (samples × columns) array in group order (gx gy gz ax ay az per group, °/s and
/// g) sampled at `rate` Hz.
fn recording_of(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    rate: Option<f64>,
) -> PyResult<Recording> {
    if let Ok(path) = source.extract::<PathBuf>() {
        return load_any(py, &path, None);
    }
    let a: PyReadonlyArray2<'_, f64> = source.extract()?;
    let rate = rate.ok_or_else(|| Error::new_err("an array needs its sample rate: rate=… (Hz)"))?;
    let a = a.as_array();
    let t = (0..a.nrows()).map(|i| i as f64 / rate).collect();
    let columns = a.columns().into_iter().map(|c| c.to_vec()).collect();
    Ok(Recording::from_group_columns(t, columns))
}

/// The diagnosis `ground diagnose` runs, and its recording; with `longest_static` (a MIMU4444 stream's path), of
/// its longest static interval's longest quiet part, as `ground diagnose --longest-static`.
fn run_diagnose(
    py: Python<'_>,
    source: &Bound<'_, PyAny>,
    rate: Option<f64>,
    longest_static: bool,
) -> PyResult<(Recording, diag::Report)> {
    let mut rec = recording_of(py, source, rate)?;
    if longest_static {
        let path: PathBuf = source
            .extract()
            .map_err(|_| Error::new_err("longest_static needs the path of a MIMU4444 stream"))?;
        let m = host_test::formats::mimu::read(&path).map_err(lib_err)?;
        let opts = diag::Options::default();
        rec = diag::quiet::longest_static(&m, &rec, opts.p_false)
            .map_err(lib_err)?
            .ok_or_else(|| Error::new_err("no static interval found"))?
            .quiet;
    }
    let r = diag::diagnose(&rec, &diag::Options::default()).map_err(lib_err)?;
    Ok((rec, r))
}

/// Sim-to-real diagnosis of a static cluster recording (`ground diagnose`): a path, or a (samples × columns) array
/// in group order with `rate` in Hz; `longest_static=True` (a MIMU4444 stream) diagnoses its longest static
/// interval's longest quiet part, as `ground diagnose --longest-static`. Returns the dict `ground diagnose --json`
/// writes.
#[pyfunction]
#[pyo3(signature = (path_or_array, rate=None, longest_static=false))]
fn diagnose<'py>(
    py: Python<'py>,
    path_or_array: &Bound<'py, PyAny>,
    rate: Option<f64>,
    longest_static: bool,
) -> PyResult<Bound<'py, PyAny>> {
    let (_, r) = run_diagnose(py, path_or_array, rate, longest_static)?;
    json_to_py(py, &serde_json::to_string(&r).map_err(lib_err)?)
}

/// The cluster model (the twin, `docs/twin.md`): the TOML file `ground diagnose --model` writes and `ground simulate
/// --model` plays.
#[pyclass(module = "imu_cluster")]
struct Model {
    inner: twin::ClusterModel,
}

#[pymethods]
impl Model {
    /// Reads a model file (TOML).
    #[staticmethod]
    fn load(path: PathBuf) -> PyResult<Self> {
        Ok(Model {
            inner: twin::ClusterModel::load(&path).map_err(lib_err)?,
        })
    }

    /// Fits the model of a static recording (path, or array with `rate`), as `ground diagnose --model` does
    /// (`longest_static`: as [`diagnose`]'s).
    #[staticmethod]
    #[pyo3(signature = (path_or_array, rate=None, longest_static=false))]
    fn fit(
        path_or_array: &Bound<'_, PyAny>,
        rate: Option<f64>,
        longest_static: bool,
    ) -> PyResult<Self> {
        let py = path_or_array.py();
        let (rec, r) = run_diagnose(py, path_or_array, rate, longest_static)?;
        let source = path_or_array.str()?.to_string();
        Ok(Model {
            inner: twin::fit(&rec, &r, &source).map_err(lib_err)?,
        })
    }

    /// Writes the model file (TOML).
    fn save(&self, path: PathBuf) -> PyResult<()> {
        self.inner.save(&path).map_err(lib_err)
    }

    /// The model file's text.
    fn to_toml(&self) -> PyResult<String> {
        self.inner.to_toml().map_err(lib_err)
    }

    /// Sample rate of the recording the model was fitted to, Hz.
    #[getter]
    fn rate_hz(&self) -> f64 {
        self.inner.record.rate_hz
    }

    /// Samples of that recording.
    #[getter]
    fn samples(&self) -> usize {
        self.inner.record.samples
    }

    fn __repr__(&self) -> String {
        format!(
            "Model(source={:?}, rate_hz={}, samples={}, axes={})",
            self.inner.record.source,
            self.inner.record.rate_hz,
            self.inner.record.samples,
            self.inner.axes.len()
        )
    }
}

/// Samples from `samples` or `seconds` at `rate`, or `default`.
fn sample_count(
    samples: Option<usize>,
    seconds: Option<f64>,
    rate: f64,
    default: usize,
) -> PyResult<usize> {
    match (samples, seconds) {
        (Some(n), _) => Ok(n),
        (None, Some(s)) if s.is_finite() && s > 0.0 => Ok((s * rate).round() as usize),
        (None, Some(s)) => Err(Error::new_err(format!(
            "seconds must be a positive number, found {s}"
        ))),
        (None, None) => Ok(default),
    }
}

/// Plays a preset (`"seed"`, `"seed-fitted"`) as `ground simulate --preset` does.
fn simulate_preset(
    preset: &str,
    n: Option<usize>,
    secs: Option<f64>,
    rate: Option<f64>,
    seed: u64,
) -> PyResult<Recording> {
    let sim_err = |e: sim::SimError| Error::new_err(e.to_string());
    let mut cfg = match preset {
        "seed" => sim::preset::seed_config(seed).map_err(sim_err)?,
        "seed-fitted" => {
            seedfit::seed_config_with(&seedfit::fit().map_err(sim_err)?, seed).map_err(sim_err)?
        }
        p => {
            return Err(Error::new_err(format!(
                "unknown preset '{p}': expected seed, seed-fitted or a Model"
            )));
        }
    };
    cfg.rate_hz = rate.unwrap_or(cfg.rate_hz);
    cfg.samples = sample_count(n, secs, cfg.rate_hz, cfg.samples as usize)? as u64;
    sim::output::recording(cfg).map_err(lib_err)
}

/// Simulates a cluster recording: a [`Model`] played (`ground simulate --model`) or a preset (`"seed"`,
/// `"seed-fitted"`). Returns the (samples × columns) array `read` would give for the CSV `ground simulate` writes
/// (°/s and g, group order, then `temp_c` if modelled). `samples` or `seconds` set the length (default: the
/// model's, or the preset's 8 h), `rate` the sample rate in Hz.
#[pyfunction]
#[pyo3(signature = (model_or_preset, samples=None, seconds=None, rate=None, seed=1, without_effects=false))]
fn simulate<'py>(
    py: Python<'py>,
    model_or_preset: &Bound<'py, PyAny>,
    samples: Option<usize>,
    seconds: Option<f64>,
    rate: Option<f64>,
    seed: u64,
    without_effects: bool,
) -> PyResult<Bound<'py, PyArray2<f64>>> {
    let rec = if let Ok(m) = model_or_preset.extract::<PyRef<'_, Model>>() {
        let r = rate.unwrap_or(m.inner.record.rate_hz);
        let n = sample_count(samples, seconds, r, m.inner.record.samples)?;
        let opts = twin::PlayOptions {
            seed,
            samples: Some(n),
            rate_hz: Some(r),
            without_effects,
            temperature: None,
        };
        twin::play(&m.inner, &opts).map_err(lib_err)?
    } else {
        let preset: String = model_or_preset.extract()?;
        simulate_preset(&preset, samples, seconds, rate, seed)?
    };
    Ok(matrix(py, rec)?.1)
}

/// The module.
#[pymodule]
fn imu_cluster(m: &Bound<'_, PyModule>) -> PyResult<()> {
    m.add("Error", m.py().get_type::<Error>())?;
    m.add_class::<Model>()?;
    m.add_function(wrap_pyfunction!(read, m)?)?;
    m.add_function(wrap_pyfunction!(decode, m)?)?;
    m.add_function(wrap_pyfunction!(allan, m)?)?;
    m.add_function(wrap_pyfunction!(diagnose, m)?)?;
    m.add_function(wrap_pyfunction!(simulate, m)?)?;
    Ok(())
}
