//! The telemetry stream as an MCAP file for Foxglove (`ground decode --mcap`, `docs/telemetry.md` § MCAP): one
//! channel per message kind, JSON messages with a JSON Schema each.
//!
//! Time stamps (`log_time` = `publish_time`, ns): a `Fused` report's spacecraft time (`unix_us`) once `SetTime` set
//! it, else its frame time (`t_us`, the FPGA sample counter over the base rate). A `Nav` report's interval start is
//! mapped to spacecraft time with the offset of the last `Time` report or timed `Fused` report before it, else left in
//! frame time. `Health`, `Housekeeping`, `Resets` and `Update` carry no frame time: they take the stamp of the last
//! stamped message before them (0 before any).

use crate::formats::telemetry::TelemetryLog;
use serde_json::{Value, json};
use shared::telemetry::{FusedReport, NavReport, Telemetry};
use std::collections::BTreeMap;
use std::io::{Seek, Write};

/// Topic of the fused samples.
pub const FUSED_TOPIC: &str = "/imu_cluster/fused";
/// Topic of the navigation increments.
pub const NAV_TOPIC: &str = "/imu_cluster/nav";
/// Topic of the health reports.
pub const HEALTH_TOPIC: &str = "/imu_cluster/health";
/// Topic of the housekeeping reports.
pub const HOUSEKEEPING_TOPIC: &str = "/imu_cluster/housekeeping";
/// Topic of the reset histories (after each housekeeping report).
pub const RESETS_TOPIC: &str = "/imu_cluster/resets";
/// Topic of the software update's state (after each housekeeping report).
pub const UPDATE_TOPIC: &str = "/imu_cluster/update";

/// Standard gravity, m/s² per g (the fused accelerations are sent in µg).
const STANDARD_G: f64 = 9.806_65;

/// An MCAP file could not be written.
#[derive(Debug, thiserror::Error)]
pub enum McapError {
    /// The MCAP writer failed (I/O included).
    #[error("MCAP: {0}")]
    Mcap(#[from] mcap::McapError),
    /// A message could not be encoded as JSON.
    #[error("JSON: {0}")]
    Json(#[from] serde_json::Error),
}

/// Messages written per channel.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct McapCounts {
    /// On [`FUSED_TOPIC`].
    pub fused: u64,
    /// On [`NAV_TOPIC`].
    pub nav: u64,
    /// On [`HEALTH_TOPIC`].
    pub health: u64,
    /// On [`HOUSEKEEPING_TOPIC`].
    pub housekeeping: u64,
    /// On [`RESETS_TOPIC`].
    pub resets: u64,
    /// On [`UPDATE_TOPIC`].
    pub update: u64,
}

/// `{sec, nsec}` of a time in ns: the form Foxglove reads as a time stamp.
fn stamp(ns: u64) -> Value {
    json!({ "sec": ns / 1_000_000_000, "nsec": ns % 1_000_000_000 })
}

/// A `{x, y, z}` vector, each axis scaled by `k`.
fn xyz<T: Copy + Into<f64>>(v: &[T], k: f64) -> Value {
    json!({ "x": v[0].into() * k, "y": v[1].into() * k, "z": v[2].into() * k })
}

/// The JSON Schema of a `{x, y, z}` vector in `unit`.
fn xyz_schema(unit: &str) -> Value {
    let n = json!({ "type": "number", "description": unit });
    json!({ "type": "object", "properties": { "x": n, "y": n, "z": n } })
}

/// The JSON Schema of a `{sec, nsec}` time.
fn time_schema() -> Value {
    json!({ "type": "object", "properties": { "sec": { "type": "integer" }, "nsec": { "type": "integer" } } })
}

/// The schema of the fused channel: the fields of ROS `sensor_msgs/Imu` that a fused sample has (SI units, the body
/// frame), plus the report's own.
fn fused_schema() -> Value {
    json!({
        "title": "imu_cluster.Fused",
        "description": "A fused output sample of the IMU cluster (shared::telemetry::FusedReport) in SI units",
        "type": "object",
        "properties": {
            "timestamp": time_schema(),
            "frame_id": { "type": "string" },
            "seq": { "type": "integer" },
            "t_s": { "type": "number", "description": "frame time, s" },
            "frames": { "type": "integer" },
            "angular_velocity": xyz_schema("rad/s"),
            "linear_acceleration": xyz_schema("m/s^2 (specific force)"),
            "used": { "type": "array", "items": { "type": "integer" }, "description": "sensors fused per axis gx..az" },
            "gyro_faults": { "type": "integer" },
            "accel_faults": { "type": "integer" },
            "temp_c": { "type": ["number", "null"] },
            "unix_us": { "type": ["integer", "null"] }
        }
    })
}

/// The schema of the navigation channel.
fn nav_schema() -> Value {
    json!({
        "title": "imu_cluster.Nav",
        "description": "Navigation increments of one output interval (shared::telemetry::NavReport) in SI units",
        "type": "object",
        "properties": {
            "timestamp": time_schema(),
            "frame_id": { "type": "string" },
            "seq": { "type": "integer" },
            "t_s": { "type": "number", "description": "interval start, frame time, s" },
            "dt_s": { "type": "number" },
            "dtheta": xyz_schema("rad"),
            "dv": xyz_schema("m/s"),
            "frames": { "type": "integer" },
            "bridged": { "type": "integer" },
            "clipped": { "type": "integer" }
        }
    })
}

/// The schema of a report written as its serde JSON (`ground decode --out x.jsonl` writes the same objects).
fn report_schema(title: &str, rust_type: &str) -> Value {
    json!({
        "title": title,
        "description": format!("{rust_type} as serde JSON (docs/telemetry.md)"),
        "type": "object"
    })
}

/// A fused sample as its JSON message.
fn fused_message(r: &FusedReport, ns: u64) -> Value {
    let v = r.axes();
    json!({
        "timestamp": stamp(ns),
        "frame_id": "body",
        "seq": r.seq,
        "t_s": r.t_us as f64 / 1e6,
        "frames": r.frames,
        // µ°/s → rad/s, µg → m/s²
        "angular_velocity": xyz(&v[..3], 1e-6_f64.to_radians()),
        "linear_acceleration": xyz(&v[3..], 1e-6 * STANDARD_G),
        "used": r.used,
        "gyro_faults": r.health.gyro.any(),
        "accel_faults": r.health.accel.any(),
        "temp_c": r.temp_cdeg.map(|t| f64::from(t) / 100.0),
        "unix_us": r.unix_us,
    })
}

/// A navigation report as its JSON message.
fn nav_message(r: &NavReport, ns: u64) -> Value {
    json!({
        "timestamp": stamp(ns),
        "frame_id": "body",
        "seq": r.seq,
        "t_s": r.t_us as f64 / 1e6,
        "dt_s": f64::from(r.dt_us) / 1e6,
        // Whole nrad and µm/s on the wire (|x| < 2^53: exact in f64).
        "dtheta": xyz(&r.dtheta_nrad.map(|x| x as f64), 1e-9),
        "dv": xyz(&r.dv_umps.map(|x| x as f64), 1e-6),
        "frames": r.frames,
        "bridged": r.bridged,
        "clipped": r.clipped,
    })
}

/// The time stamps of a log's messages, ns (see the module's documentation).
struct Clock {
    /// Spacecraft time minus frame time, µs, once known.
    offset_us: Option<i128>,
    /// The last stamp given.
    last_ns: u64,
}

impl Clock {
    /// The stamp of frame time `t_us`: spacecraft time when the offset is known.
    fn frame(&mut self, t_us: u64) -> u64 {
        let us = self
            .offset_us
            .map_or(i128::from(t_us), |o| i128::from(t_us) + o);
        self.last_ns = u64::try_from(us.max(0))
            .unwrap_or(u64::MAX)
            .saturating_mul(1000);
        self.last_ns
    }

    /// The stamp of message `m`, or `None` for a kind not written.
    fn of(&mut self, m: &Telemetry) -> Option<u64> {
        match m {
            Telemetry::Fused(r) => Some(match r.unix_us {
                Some(u) => {
                    self.offset_us = Some(i128::from(u) - i128::from(r.t_us));
                    self.last_ns = u.saturating_mul(1000);
                    self.last_ns
                }
                None => self.frame(r.t_us),
            }),
            Telemetry::Nav(r) => Some(self.frame(r.t_us)),
            Telemetry::Time(t) => {
                self.offset_us = Some(i128::from(t.unix_us) - i128::from(t.t_us));
                None
            }
            Telemetry::Health(_)
            | Telemetry::Housekeeping(_)
            | Telemetry::Resets(_)
            | Telemetry::Update(_) => Some(self.last_ns),
            _ => None,
        }
    }
}

/// Writes `log`'s fused samples, navigation increments, health and housekeeping reports, reset histories and update
/// states to `out` as MCAP (no
/// compression: readable by every MCAP reader). Returns the messages written per channel.
pub fn write_mcap<W: Write + Seek>(log: &TelemetryLog, out: W) -> Result<McapCounts, McapError> {
    let mut w = mcap::Writer::new(out)?;
    let meta = BTreeMap::new();
    let mut channel = |title: &str, topic: &str, schema: Value| -> Result<u16, McapError> {
        let id = w.add_schema(title, "jsonschema", &serde_json::to_vec(&schema)?)?;
        Ok(w.add_channel(id, topic, "json", &meta)?)
    };
    let fused = channel("imu_cluster.Fused", FUSED_TOPIC, fused_schema())?;
    let nav = channel("imu_cluster.Nav", NAV_TOPIC, nav_schema())?;
    let health = channel(
        "imu_cluster.Health",
        HEALTH_TOPIC,
        report_schema("imu_cluster.Health", "shared::telemetry::HealthReport"),
    )?;
    let hk = channel(
        "imu_cluster.Housekeeping",
        HOUSEKEEPING_TOPIC,
        report_schema(
            "imu_cluster.Housekeeping",
            "shared::telemetry::HousekeepingReport",
        ),
    )?;
    let resets = channel(
        "imu_cluster.Resets",
        RESETS_TOPIC,
        report_schema("imu_cluster.Resets", "shared::telemetry::ResetHistory"),
    )?;
    let update = channel(
        "imu_cluster.Update",
        UPDATE_TOPIC,
        report_schema("imu_cluster.Update", "shared::update::UpdateStatus"),
    )?;
    let mut clock = Clock {
        offset_us: None,
        last_ns: 0,
    };
    let mut counts = McapCounts::default();
    for m in &log.messages {
        let Some(ns) = clock.of(m) else { continue };
        let (channel_id, n, body) = match m {
            Telemetry::Fused(r) => (fused, &mut counts.fused, fused_message(r, ns)),
            Telemetry::Nav(r) => (nav, &mut counts.nav, nav_message(r, ns)),
            Telemetry::Health(r) => (health, &mut counts.health, serde_json::to_value(r)?),
            Telemetry::Housekeeping(r) => (hk, &mut counts.housekeeping, serde_json::to_value(r)?),
            Telemetry::Resets(r) => (resets, &mut counts.resets, serde_json::to_value(r)?),
            Telemetry::Update(r) => (update, &mut counts.update, serde_json::to_value(r)?),
            _ => continue,
        };
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: u32::try_from(*n).unwrap_or(u32::MAX),
            log_time: ns,
            publish_time: ns,
        };
        w.write_to_known_channel(&header, &serde_json::to_vec(&body)?)?;
        *n += 1;
    }
    w.finish()?;
    Ok(counts)
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::telemetry::TimeReport;

    fn fused(t_us: u64, unix_us: Option<u64>) -> Telemetry {
        Telemetry::Fused(FusedReport {
            seq: 0,
            t_us,
            frames: 32,
            rate_udps: [1_000_000, 0, -2],
            accel_ug: [0, 0, 1_000_000],
            used: [16; 6],
            health: Default::default(),
            temp_cdeg: None,
            unix_us,
        })
    }

    #[test]
    fn stamps_follow_spacecraft_time_once_set() {
        let mut c = Clock {
            offset_us: None,
            last_ns: 0,
        };
        assert_eq!(c.of(&fused(1_500_000, None)), Some(1_500_000_000));
        assert_eq!(
            c.of(&Telemetry::Time(TimeReport {
                t_us: 2_000_000,
                unix_us: 1_700_000_000_000_000
            })),
            None
        );
        // A Fused report without unix_us after a Time report: frame time + the Time report's offset.
        assert_eq!(
            c.of(&fused(3_000_000, None)),
            Some(1_700_000_001_000_000_000)
        );
        assert_eq!(
            c.of(&fused(4_000_000, Some(1_700_000_002_000_100))),
            Some(1_700_000_002_000_100_000)
        );
    }

    #[test]
    fn fused_samples_in_si_units() {
        let Telemetry::Fused(r) = fused(0, None) else {
            unreachable!()
        };
        let m = fused_message(&r, 5);
        let w = m["angular_velocity"]["x"].as_f64().unwrap();
        assert!((w - std::f64::consts::PI / 180.0).abs() < 1e-15, "{w}");
        assert_eq!(m["linear_acceleration"]["z"].as_f64(), Some(9.80665));
        assert_eq!(m["timestamp"]["nsec"].as_u64(), Some(5));
    }

    /// Reset histories and update states get their channels, stamped like housekeeping (the last stamp before).
    #[test]
    fn resets_and_update_on_their_topics() {
        let log = TelemetryLog {
            messages: vec![
                fused(1_000_000, None),
                Telemetry::Resets(shared::telemetry::ResetHistory {
                    boot_count: 3,
                    short_runs: 0,
                    safe_mode: false,
                    dropped: 0,
                    records: [None; shared::telemetry::RESET_HISTORY_LEN],
                }),
                Telemetry::Update(shared::update::UpdateStatus::UNKNOWN),
                Telemetry::Update(shared::update::UpdateStatus::UNKNOWN),
            ],
            ..TelemetryLog::default()
        };
        let mut out = std::io::Cursor::new(Vec::new());
        let c = write_mcap(&log, &mut out).unwrap();
        assert_eq!((c.fused, c.resets, c.update), (1, 1, 2));
        let bytes = out.into_inner();
        let mut seen = Vec::new();
        for m in mcap::MessageStream::new(&bytes).unwrap() {
            let m = m.unwrap();
            let body: Value = serde_json::from_slice(&m.data).unwrap();
            seen.push((m.channel.topic.clone(), m.log_time, body));
        }
        assert_eq!(seen[1].0, RESETS_TOPIC);
        assert_eq!((seen[2].0.as_str(), seen[2].1), (UPDATE_TOPIC, seen[0].1));
        assert_eq!(seen[3].2["boot"], json!("Unknown"));
    }
}
