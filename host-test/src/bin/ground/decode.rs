//! `ground decode`: a telemetry stream (CSP/KISS/postcard) to CSV or JSON lines.

use crate::common::write_file;
use anyhow::{Context, Result, bail};
use host_test::formats::telemetry::TelemetryLog;
use shared::bus::BusConfig;
use shared::bus::csp::CspVersion;
use std::path::PathBuf;

#[derive(clap::Args)]
pub struct Args {
    /// Telemetry stream (bus bytes).
    input: PathBuf,
    /// Output: .csv (fused samples) or .jsonl (every message).
    #[arg(long)]
    out: PathBuf,
    /// Also the Allan deviations of the core's Allan reports (roots taken here), as CSV.
    #[arg(long)]
    allan: Option<PathBuf>,
    /// Also the navigation increments (ΔΘ, ΔV per output interval), as CSV.
    #[arg(long)]
    nav: Option<PathBuf>,
    /// CSP header version on the bus (1 or 2).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
}

pub fn run(a: Args) -> Result<()> {
    let csv = match a.out.extension().and_then(|e| e.to_str()) {
        Some("csv") => true,
        Some("jsonl") | Some("json") => false,
        _ => bail!(
            "{}: the output must end in .csv (fused samples) or .jsonl (all messages)",
            a.out.display()
        ),
    };
    let bytes =
        std::fs::read(&a.input).with_context(|| format!("reading {}", a.input.display()))?;
    let log = TelemetryLog::decode(
        &bytes,
        &BusConfig {
            version: a.csp_version,
            ..BusConfig::DEFAULT
        },
    );
    let s = log.stats;
    if log.messages.is_empty() {
        bail!(
            "{}: no telemetry message in {} bytes ({} KISS frames: {} bad KISS, {} bad CSP, {} bad messages, {} for \
             other ports); nothing written",
            a.input.display(),
            bytes.len(),
            s.frames,
            s.kiss_errors,
            s.csp_errors,
            s.bad_messages,
            s.other_port
        );
    }
    if csv {
        write_file(&a.out, |w| log.write_fused_csv(w))?;
        if log.fused().next().is_none() {
            eprintln!(
                "warning: no fused samples among the {} messages: {} holds only its header (.jsonl keeps every \
                 message)",
                log.messages.len(),
                a.out.display()
            );
        }
    } else {
        write_file(&a.out, |w| log.write_jsonl(w))?;
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
