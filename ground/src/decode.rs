//! `ground decode`: a telemetry stream (CSP/KISS/postcard) to CSV, JSON lines or MCAP.

use crate::common::write_file;
use anyhow::{Result, bail};
use host_test::formats::mcap;
use host_test::formats::telemetry::TelemetryLog;
use shared::bus::BusConfig;
use shared::bus::csp::CspVersion;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct Args {
    /// Telemetry stream (bus bytes).
    input: PathBuf,
    /// Output: .csv (fused samples) or .jsonl (every message); optional when --nav, --allan or --mcap is given.
    #[arg(long, required_unless_present_any = ["allan", "nav", "mcap"])]
    out: Option<PathBuf>,
    /// Also the Allan deviations of the core's Allan reports (roots taken here), as CSV.
    #[arg(long)]
    allan: Option<PathBuf>,
    /// Also the navigation increments (ΔΘ, ΔV per output interval), as CSV.
    #[arg(long)]
    nav: Option<PathBuf>,
    /// Also an MCAP file for Foxglove: fused samples, navigation increments, health and housekeeping, one channel
    /// each (docs/telemetry.md, MCAP).
    #[arg(long)]
    mcap: Option<PathBuf>,
    /// CSP header version on the bus (1 or 2).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
}

/// Whether `out` is a CSV (else JSON lines); an error for any other extension.
fn is_csv(out: &Path) -> Result<bool> {
    Ok(match out.extension().and_then(|e| e.to_str()) {
        Some("csv") => true,
        Some("jsonl") | Some("json") => false,
        _ => bail!(
            "{}: the output must end in .csv (fused samples) or .jsonl (all messages)",
            out.display()
        ),
    })
}

pub fn run(a: Args) -> Result<()> {
    let csv = a.out.as_deref().map(is_csv).transpose()?;
    let log = TelemetryLog::read(
        &a.input,
        &BusConfig {
            version: a.csp_version,
            ..BusConfig::DEFAULT
        },
    )?;
    let s = log.stats;
    if let (Some(out), Some(csv)) = (&a.out, csv) {
        write_out(&log, out, csv)?;
    }
    if let Some(p) = &a.mcap {
        let c = write_file(p, |w| {
            mcap::write_mcap(&log, w).map_err(std::io::Error::other)
        })?;
        println!(
            "{}: {} fused, {} navigation, {} health, {} housekeeping, {} reset-history, {} update messages",
            p.display(),
            c.fused,
            c.nav,
            c.health,
            c.housekeeping,
            c.resets,
            c.update
        );
    }
    if let Some(p) = &a.allan {
        let n = write_file(p, |w| log.write_allan_csv(w))?;
        println!("{}: {n} Allan levels", p.display());
        if n == 0 {
            eprintln!(
                "warning: no Allan reports in the stream: {} holds only its header",
                p.display()
            );
        }
    }
    if let Some(p) = &a.nav {
        let n = write_file(p, |w| log.write_nav_csv(w))?;
        println!("{}: {n} navigation increments", p.display());
        if n == 0 {
            eprintln!(
                "warning: no navigation reports in the stream: {} holds only its header",
                p.display()
            );
        }
    }
    if s.kiss_errors > 0 || s.csp_errors > 0 || s.bad_messages > 0 {
        eprintln!(
            "warning: {}: {} KISS frames, {} CSP packets and {} messages could not be decoded: they are not in the \
             output",
            a.input.display(),
            s.kiss_errors,
            s.csp_errors,
            s.bad_messages
        );
    }
    println!(
        "{} messages ({} fused) from {} KISS frames; bad: {} KISS, {} CSP, {} message; {} for other ports",
        log.messages.len(),
        log.fused().count(),
        s.frames,
        s.kiss_errors,
        s.csp_errors,
        s.bad_messages,
        s.other_port
    );
    Ok(())
}

/// Writes the fused samples (`csv`) or every message (JSON lines) to `out`.
fn write_out(log: &TelemetryLog, out: &Path, csv: bool) -> Result<()> {
    if csv {
        write_file(out, |w| log.write_fused_csv(w))?;
        if log.fused().next().is_none() {
            eprintln!(
                "warning: no fused samples among the {} messages: {} holds only its header (.jsonl keeps every \
                 message)",
                log.messages.len(),
                out.display()
            );
        }
    } else {
        write_file(out, |w| log.write_jsonl(w))?;
    }
    Ok(())
}
