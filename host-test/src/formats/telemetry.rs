//! The telemetry stream: bus bytes (CSP packets, header version 1 or 2, in KISS frames, `docs/bus.md`) carrying postcard messages
//! (`docs/telemetry.md`), decoded with the core's own codecs.

use shared::bus::csp::CspPacket;
use shared::bus::kiss::KissDecoder;
use shared::bus::{BusConfig, MAX_FRAME};
use shared::telemetry::{AllanReport, FusedReport, Telemetry, decode};

pub mod tables;

/// Counts of what could not be decoded.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct StreamStats {
    /// KISS frames read.
    pub frames: u64,
    /// KISS frames dropped (escape, command byte, size).
    pub kiss_errors: u64,
    /// CSP packets dropped (length, CRC, flags).
    pub csp_errors: u64,
    /// Packets not addressed to the ground's telemetry port.
    pub other_port: u64,
    /// Payloads that are not telemetry messages (version or contents).
    pub bad_messages: u64,
}

/// One level of a core Allan report in the ground's terms: the root is taken here, from the exact integer sums.
#[derive(Clone, Debug, PartialEq)]
pub struct AllanPoint {
    /// The core's channel number ([`shared::pipeline`]: sensor channels, then the fused axes).
    pub channel: usize,
    /// The channel as a column of the interchange CSV: `g03z` for group 3's gyro z, `mean_gz` for a fused axis.
    pub column: String,
    /// Octave level k: averaging factor 2^k.
    pub level: usize,
    /// Sample interval τ₀ of the accumulator, s.
    pub tau0_s: f64,
    /// Averaging time τ = 2^k τ₀, s.
    pub tau_s: f64,
    /// Differences in the level's sums.
    pub count: u32,
    /// Samples the accumulator had taken.
    pub samples: u64,
    /// Allan deviation √(sum_sq / (2·count·m²)), °/s or g (the core sums µ°/s and µg).
    pub dev: f64,
}

impl AllanPoint {
    /// The point a report gives; `None` while its level holds no difference (or its level is out of range).
    pub fn from_report(a: &AllanReport) -> Option<Self> {
        use crate::recording::{SensorKind, column_name};
        use shared::pipeline::{FUSED_CHANNEL0, SENSOR_CHANNELS};
        let avar = a.level.avar()?;
        let channel = usize::from(a.channel);
        let axis = channel % 6;
        let kind = if axis < 3 {
            SensorKind::Gyro
        } else {
            SensorKind::Accel
        };
        let column = if channel < SENSOR_CHANNELS {
            column_name(kind, channel / 6, axis % 3)
        } else {
            crate::allan::recording::mean_label(kind, (channel - FUSED_CHANNEL0) % 3)
        };
        let tau0_s = a.tau0_ps as f64 * 1e-12;
        let factor = 1u64.checked_shl(u32::from(a.level.level))?;
        Some(Self {
            channel,
            column,
            level: usize::from(a.level.level),
            tau0_s,
            tau_s: tau0_s * factor as f64,
            count: a.level.count,
            samples: a.samples,
            // µ°/s → °/s, µg → g
            dev: avar.sqrt() / 1e6,
        })
    }
}

/// A telemetry stream could not be read, or held no telemetry message.
#[derive(Debug, thiserror::Error)]
pub enum TelemetryError {
    /// The file could not be read.
    #[error("reading {path}: {source}")]
    Io {
        /// File.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// Not one message decoded.
    #[error(
        "{path}: no telemetry message in {bytes} bytes ({} KISS frames: {} bad KISS, {} bad CSP, {} bad messages, {} \
         for other ports)",
        .stats.frames, .stats.kiss_errors, .stats.csp_errors, .stats.bad_messages, .stats.other_port
    )]
    Empty {
        /// File.
        path: String,
        /// Its size.
        bytes: usize,
        /// What could not be decoded.
        stats: StreamStats,
    },
}

/// A decoded telemetry stream.
#[derive(Clone, Debug, Default)]
pub struct TelemetryLog {
    /// Messages in order.
    pub messages: Vec<Telemetry>,
    /// What could not be decoded.
    pub stats: StreamStats,
}

impl TelemetryLog {
    /// Decodes bus bytes as the ground (node `config.ground_addr`, port `config.telemetry_port`) receives them.
    pub fn decode(bytes: &[u8], config: &BusConfig) -> TelemetryLog {
        let mut kiss = KissDecoder::<MAX_FRAME>::new();
        let mut log = TelemetryLog::default();
        let mut input = bytes;
        while let Some(frame) = kiss.decode(&mut input) {
            log.stats.frames += 1;
            let Ok(frame) = frame else {
                log.stats.kiss_errors += 1;
                continue;
            };
            match CspPacket::parse(frame, config.version) {
                Ok(p)
                    if p.header.dst == config.ground_addr
                        && p.header.dport == config.telemetry_port =>
                {
                    match decode::<Telemetry>(p.payload) {
                        Ok(m) => log.messages.push(m),
                        Err(_) => log.stats.bad_messages += 1,
                    }
                }
                Ok(_) => log.stats.other_port += 1,
                Err(_) => log.stats.csp_errors += 1,
            }
        }
        log
    }

    /// Reads and decodes the telemetry stream in `path` ([`Self::decode`]); a stream without any message is an error.
    pub fn read(
        path: &std::path::Path,
        config: &BusConfig,
    ) -> Result<TelemetryLog, TelemetryError> {
        let bytes = std::fs::read(path).map_err(|source| TelemetryError::Io {
            path: path.display().to_string(),
            source,
        })?;
        let log = Self::decode(&bytes, config);
        if log.messages.is_empty() {
            return Err(TelemetryError::Empty {
                path: path.display().to_string(),
                bytes: bytes.len(),
                stats: log.stats,
            });
        }
        Ok(log)
    }

    /// The fused reports, in order.
    pub fn fused(&self) -> impl Iterator<Item = &FusedReport> {
        self.messages.iter().filter_map(|m| match m {
            Telemetry::Fused(r) => Some(r),
            _ => None,
        })
    }

    /// Writes the fused reports as CSV (µ°/s and µg as sent, plus used counts, fault masks, and the spacecraft time
    /// `unix_us` each report carries once `SetTime` set it; empty before).
    pub fn write_fused_csv(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(
            out,
            "seq,t_s,frames,gx_udps,gy_udps,gz_udps,ax_ug,ay_ug,az_ug,used_gx,used_gy,used_gz,used_ax,used_ay,used_az,\
             gyro_faults,accel_faults,temp_c,unix_us"
        )?;
        for r in self.fused() {
            let (u, v) = (r.used, r.axes());
            writeln!(
                out,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:#x},{:#x},{},{}",
                r.seq,
                r.t_us as f64 / 1e6,
                r.frames,
                v[0],
                v[1],
                v[2],
                v[3],
                v[4],
                v[5],
                u[0],
                u[1],
                u[2],
                u[3],
                u[4],
                u[5],
                r.health.gyro.any(),
                r.health.accel.any(),
                r.temp_cdeg
                    .map_or(String::new(), |t| format!("{}", f64::from(t) / 100.0)),
                r.unix_us.map_or(String::new(), |t| t.to_string()),
            )?;
        }
        Ok(())
    }

    /// Writes the navigation increments (`Telemetry::Nav`) as CSV, in SI units: `t_s` (interval start, frame time),
    /// `dt_s`, ΔΘ in rad, ΔV in m/s, frames, bridged and clipped counts, and the `Fused` report's `seq`. Returns the
    /// number of rows.
    pub fn write_nav_csv(&self, out: &mut impl std::io::Write) -> std::io::Result<usize> {
        writeln!(
            out,
            "t_s,dt_s,dtheta_x_rad,dtheta_y_rad,dtheta_z_rad,dv_x_mps,dv_y_mps,dv_z_mps,frames,bridged,clipped,seq"
        )?;
        let mut n = 0;
        for m in &self.messages {
            if let Telemetry::Nav(r) = m {
                let [tx, ty, tz] = r.dtheta_nrad.map(|x| x as f64 * 1e-9);
                let [vx, vy, vz] = r.dv_umps.map(|x| x as f64 * 1e-6);
                writeln!(
                    out,
                    // As sent: whole nrad and µm/s, whole µs.
                    "{:.6},{:.6},{tx:.9},{ty:.9},{tz:.9},{vx:.6},{vy:.6},{vz:.6},{},{},{},{}",
                    r.t_us as f64 / 1e6,
                    f64::from(r.dt_us) / 1e6,
                    r.frames,
                    r.bridged,
                    r.clipped,
                    r.seq
                )?;
                n += 1;
            }
        }
        Ok(n)
    }

    /// The Allan points of the log's reports, in order (reports whose level holds no difference left out).
    pub fn allan(&self) -> impl Iterator<Item = AllanPoint> + '_ {
        self.messages.iter().filter_map(|m| match m {
            Telemetry::Allan(a) => AllanPoint::from_report(a),
            _ => None,
        })
    }

    /// Writes the Allan deviations the core's reports give, one row per channel and level:
    /// `channel,column,tau_s,count,samples,dev`. `column` names the channel as in the interchange CSV (`g03z` for
    /// group 3's gyro z, `mean_gz` for the fused axis), `dev` is √(sum_sq / (2·count·m²)) in °/s or g — the root
    /// taken here, on the ground, from the exact integer sums. The last report of each (channel, level) counts.
    pub fn write_allan_csv(&self, out: &mut impl std::io::Write) -> std::io::Result<usize> {
        let mut last: std::collections::BTreeMap<(u8, u8), AllanReport> = Default::default();
        for m in &self.messages {
            if let Telemetry::Allan(a) = m {
                last.insert((a.channel, a.level.level), *a);
            }
        }
        writeln!(out, "channel,column,tau_s,count,samples,dev")?;
        for p in last.values().filter_map(AllanPoint::from_report) {
            writeln!(
                out,
                "{},{},{},{},{},{:e}",
                p.channel,
                p.column,
                crate::allan::recording::round_sig(p.tau_s, 10),
                p.count,
                p.samples,
                p.dev
            )?;
        }
        Ok(last.len())
    }

    /// Writes every message as one JSON object per line (`{"Fused":{…}}`, `{"Allan":{…}}`, …).
    pub fn write_jsonl(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        for m in &self.messages {
            serde_json::to_writer(&mut *out, m)?;
            writeln!(out)?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use shared::allan::AllanLevel;
    use shared::bus::BusNode;
    use shared::telemetry::AllanReport;

    #[test]
    fn allan_reports_become_deviations_on_the_ground() {
        // Channel 3 = group 0 accel x; level 2 (m = 4): σ² = sum_sq / (2·count·16) µg².
        let node = BusNode::new(BusConfig::DEFAULT);
        let report = AllanReport {
            channel: 3,
            tau0_ps: 1_653_439_153,
            samples: 400,
            level: AllanLevel {
                level: 2,
                count: 99,
                sum_sq: 2 * 99 * 16 * 2500,
            },
        };
        let mut wire = [0u8; 200];
        let n = node
            .encode_message(&Telemetry::Allan(report), &mut wire)
            .unwrap();
        let log = TelemetryLog::decode(&wire[..n], &BusConfig::DEFAULT);
        let mut out = Vec::new();
        assert_eq!(log.write_allan_csv(&mut out).unwrap(), 1);
        let text = String::from_utf8(out).unwrap();
        // √2500 µg = 50 µg = 5e-5 g at τ = 4 × 1.653 ms.
        assert_eq!(
            text.lines().nth(1),
            Some("3,a00x,0.006613756612,99,400,5e-5")
        );
    }

    #[test]
    fn nav_reports_become_si_rows() {
        let log = TelemetryLog {
            messages: vec![Telemetry::Nav(shared::telemetry::NavReport {
                seq: 7,
                t_us: 1_500_000,
                dt_us: 52_910,
                dtheta_nrad: [1_234_567, -2, 0],
                dv_umps: [-518_251, 0, 3],
                frames: 35,
                bridged: 3,
                clipped: 1,
            })],
            stats: StreamStats::default(),
        };
        let mut out = Vec::new();
        assert_eq!(log.write_nav_csv(&mut out).unwrap(), 1);
        let text = String::from_utf8(out).unwrap();
        assert_eq!(
            text.lines().nth(1),
            Some(
                "1.500000,0.052910,0.001234567,-0.000000002,0.000000000,-0.518251,0.000000,0.000003,35,3,1,7"
            )
        );
    }
}
