//! The telemetry stream: bus bytes (CSP v1 packets in KISS frames, `docs/bus.md`) carrying postcard messages
//! (`docs/telemetry.md`), decoded with the core's own codecs.

use shared::bus::csp::CspPacket;
use shared::bus::kiss::KissDecoder;
use shared::bus::{BusConfig, MAX_FRAME};
use shared::telemetry::{FusedReport, Telemetry, decode};

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
            match CspPacket::parse(frame) {
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

    /// The fused reports, in order.
    pub fn fused(&self) -> impl Iterator<Item = &FusedReport> {
        self.messages.iter().filter_map(|m| match m {
            Telemetry::Fused(r) => Some(r),
            _ => None,
        })
    }

    /// Writes the fused reports as CSV (µ°/s and µg as sent, plus used counts and fault masks).
    pub fn write_fused_csv(&self, out: &mut impl std::io::Write) -> std::io::Result<()> {
        writeln!(
            out,
            "seq,t_s,frames,gx_udps,gy_udps,gz_udps,ax_ug,ay_ug,az_ug,used_gx,used_gy,used_gz,used_ax,used_ay,used_az,\
             gyro_faults,accel_faults,temp_c"
        )?;
        for r in self.fused() {
            let (u, v) = (r.used, r.axes());
            writeln!(
                out,
                "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{:#x},{:#x},{}",
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
            )?;
        }
        Ok(())
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
