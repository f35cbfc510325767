//! `ground fw-keygen`, `ground fw-sign`, `ground fw-upload`: the in-orbit update's ground tools
//! (`docs/update.md`); the work is `host_test::update`'s.

use crate::common::bar;
use anyhow::{Context, Result, bail};
use host_test::update::link::{SATELLITE_RING_LEN, max_request_wire_len, max_window};
use host_test::update::uploader::RewindCause;
use host_test::update::{
    self, BusAddrs, SerialLink, SignedImage, UpdateFramer, UploadConfig, UploadEvent, Uploader,
};
use shared::bus::csp::CspVersion;
use std::path::PathBuf;
use std::time::{Duration, Instant};

#[derive(clap::Args)]
pub struct KeygenArgs {
    /// Writes PREFIX.pem (the private key, PKCS#8 PEM, mode 0600; never overwritten) and PREFIX.pub (64 hex digits,
    /// what FW_UPDATE_PUBKEY names at build time).
    #[arg(long, value_name = "PREFIX")]
    out: PathBuf,
}

#[derive(clap::Args)]
pub struct SignArgs {
    /// The application's ELF (linked at the ACTIVE slot + 0x200).
    elf: PathBuf,
    /// Ed25519 private key, PKCS#8 PEM (`ground fw-keygen`, `openssl genpkey -algorithm ed25519`).
    #[arg(long)]
    key: PathBuf,
    /// Firmware version (the satellite accepts only a version above the running one).
    #[arg(long)]
    version: u32,
    /// Board id (decimal or 0x hex).
    #[arg(long, value_parser = parse_u32, default_value_t = shared::update::BOARD_ID)]
    board: u32,
    /// Also check that the key's public half is this public key file (the one the firmware is built with).
    #[arg(long)]
    pubkey: Option<PathBuf>,
    /// The signed image.
    #[arg(long)]
    out: PathBuf,
}

#[derive(clap::Args)]
pub struct UploadArgs {
    /// Signed image (`ground fw-sign`).
    image: PathBuf,
    /// Serial device or pseudo-terminal of the satellite's bus.
    #[arg(long)]
    link: PathBuf,
    /// Chunks in flight (go-back-N window); at most what the satellite's 16 KiB bus ring holds.
    #[arg(long, default_value_t = 4)]
    window: usize,
    /// CSP header version on the bus (1 or 2).
    #[arg(long, default_value = "1")]
    csp_version: CspVersion,
    /// The satellite's CSP address.
    #[arg(long, default_value_t = shared::bus::BusConfig::DEFAULT.addr)]
    sat_addr: u16,
    /// Our CSP address.
    #[arg(long, default_value_t = shared::bus::BusConfig::DEFAULT.ground_addr)]
    ground_addr: u16,
    /// Verify but do not commit (no swap at the next reset).
    #[arg(long)]
    no_commit: bool,
    /// Start over instead of resuming what the satellite's DFU slot holds.
    #[arg(long)]
    restart: bool,
    /// After the commit, reset the satellite (sent once): the bootloader swaps the image in, and it runs as a trial
    /// until it confirms itself (30 s without a missed deadline).
    #[arg(long, conflicts_with = "no_commit")]
    reset: bool,
    /// Reply timeout of Status, Open and chunks, ms (erase, verify and commit wait 5 times longer, at least 5 s).
    #[arg(long, default_value_t = 1000)]
    timeout_ms: u64,
    /// Also check the signature with this public key file before sending anything.
    #[arg(long)]
    pubkey: Option<PathBuf>,
}

/// A `u32` in decimal or `0x` hex.
fn parse_u32(s: &str) -> Result<u32, String> {
    let s = s.trim();
    match s.strip_prefix("0x").or_else(|| s.strip_prefix("0X")) {
        Some(h) => u32::from_str_radix(&h.replace('_', ""), 16),
        None => s.replace('_', "").parse(),
    }
    .map_err(|e| format!("{s:?}: {e}"))
}

pub fn keygen(a: KeygenArgs) -> Result<()> {
    let key = update::generate_keypair()?;
    let (pem, public) = update::write_keypair(&key, &a.out)?;
    println!(
        "private key: {} (keep it off the repository)",
        pem.display()
    );
    println!(
        "public key:  {} = {}",
        public.display(),
        update::public_key_hex(&key.verifying_key())
    );
    Ok(())
}

pub fn sign(a: SignArgs) -> Result<()> {
    let elf = std::fs::read(&a.elf).with_context(|| format!("reading {}", a.elf.display()))?;
    let payload = update::image_from_elf(&elf).with_context(|| a.elf.display().to_string())?;
    let key = update::read_private_key(&a.key)?;
    if let Some(p) = &a.pubkey {
        let expected = update::read_public_key(p)?;
        if expected != key.verifying_key() {
            bail!(
                "{} is not the private half of {} ({} ≠ {})",
                a.key.display(),
                p.display(),
                update::public_key_hex(&key.verifying_key()),
                update::public_key_hex(&expected)
            );
        }
    }
    let image = update::sign(&payload.bytes, &key, a.version, a.board)?;
    std::fs::write(&a.out, &image).with_context(|| format!("writing {}", a.out.display()))?;
    let h = SignedImage::parse(&image)?.header;
    println!(
        "{}: version {}, board {:#010x}, payload {} bytes from {:#010x}, SHA-512 {}…",
        a.out.display(),
        h.version,
        h.board_id,
        h.payload_len,
        payload.base,
        hex_prefix(&h.payload_sha512)
    );
    println!(
        "signed with public key {}",
        update::public_key_hex(&key.verifying_key())
    );
    Ok(())
}

/// A line on stdout above the progress bar (shown whether or not the bar is: `ProgressBar::println` prints nothing
/// when stderr is not a terminal).
fn say(pb: &indicatif::ProgressBar, line: impl AsRef<str>) {
    pb.suspend(|| println!("{}", line.as_ref()));
}

/// The first 8 bytes, in hex.
fn hex_prefix(b: &[u8]) -> String {
    b.iter().take(8).map(|x| format!("{x:02x}")).collect()
}

/// What an upload event shows: a line above the progress bar, its message or its position.
fn show(pb: &indicatif::ProgressBar, e: &UploadEvent) {
    match e {
        UploadEvent::Status(s) => say(
            pb,
            format!(
                "satellite: running version {}, DFU {:?} (version {}), boot state {:?}, last update {:?}",
                s.running_version, s.dfu, s.dfu_version, s.boot, s.last
            ),
        ),
        UploadEvent::Opened {
            sectors,
            erased,
            next_offset,
        } => {
            pb.set_position(u64::from(*next_offset));
            pb.reset_eta();
            if *next_offset > 0 || *erased > 0 {
                say(
                    pb,
                    format!(
                        "resuming: {erased} of {sectors} sectors erased, {next_offset} bytes already there"
                    ),
                );
            }
        }
        UploadEvent::Erased { sector, sectors } => {
            pb.set_message(format!("erased sector {} of {sectors}", sector + 1))
        }
        UploadEvent::Progress { acked, .. } => {
            pb.set_message("");
            pb.set_position(u64::from(*acked));
        }
        UploadEvent::Rewind { to, cause } => {
            if *cause == RewindCause::Timeout {
                pb.set_message(format!("no reply: again from {to}"));
            }
        }
        UploadEvent::Timeout { request } => {
            pb.set_message(format!("no reply to {request}: sent again"))
        }
        UploadEvent::Reopen { restart, cause } => say(
            pb,
            format!(
                "{} after {}",
                if *restart {
                    "starting over"
                } else {
                    "re-opening"
                },
                update::uploader::describe(*cause)
            ),
        ),
        UploadEvent::Verified => say(pb, "verified on board (SHA-512 and signature)"),
        UploadEvent::Committed => say(pb, "committed: the satellite swaps it in at its next reset"),
        UploadEvent::Reset(true) => say(pb, "the satellite resets now"),
        UploadEvent::Reset(false) => say(
            pb,
            "no reply to Reset (not sent again: a second reset would revert the new image); check its telemetry",
        ),
    }
}

pub fn upload(a: UploadArgs) -> Result<()> {
    let bytes =
        std::fs::read(&a.image).with_context(|| format!("reading {}", a.image.display()))?;
    let image = SignedImage::parse(&bytes).with_context(|| a.image.display().to_string())?;
    if let Some(p) = &a.pubkey {
        image.check_signature(&update::read_public_key(p)?)?;
    }
    let max = max_window(SATELLITE_RING_LEN, a.csp_version);
    if a.window == 0 || a.window > max {
        bail!(
            "--window {}: 1 to {max} chunks (the satellite's {SATELLITE_RING_LEN}-byte bus ring holds {max} \
             requests of {} bytes on the wire, worst case)",
            a.window,
            max_request_wire_len(a.csp_version)
        );
    }
    let h = image.header;
    println!(
        "{}: version {}, board {:#010x}, payload {} bytes, SHA-512 {}…",
        a.image.display(),
        h.version,
        h.board_id,
        h.payload_len,
        hex_prefix(&h.payload_sha512)
    );
    let timeout = Duration::from_millis(a.timeout_ms);
    let config = UploadConfig {
        window: a.window,
        commit: !a.no_commit,
        reset: a.reset,
        restart: a.restart,
        timeout,
        long_timeout: (timeout * 5).max(Duration::from_secs(5)),
        ..UploadConfig::default()
    };
    let mut uploader = Uploader::new(&image, config)?;
    let mut framer = UpdateFramer::new(BusAddrs {
        version: a.csp_version,
        sat_addr: a.sat_addr,
        ground_addr: a.ground_addr,
        ..BusAddrs::default()
    });
    let mut link =
        SerialLink::open(&a.link).with_context(|| format!("opening {}", a.link.display()))?;
    let pb = bar(u64::from(uploader.total()), "bytes");
    pb.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {bytes}/{total_bytes} {bytes_per_sec} {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let started = Instant::now();
    let result = update::upload(&mut link, &mut framer, &mut uploader, |e| show(&pb, e));
    pb.finish_and_clear();
    let s = result?;
    let elapsed = started.elapsed().as_secs_f64();
    let new = s.payload_len - s.resumed_from;
    println!(
        "{new} payload bytes delivered of {} ({} were already there) in {elapsed:.1} s: {:.0} bytes/s effective",
        s.payload_len,
        s.resumed_from,
        f64::from(new) / elapsed.max(1e-9),
    );
    println!(
        "chunks sent: {} ({} bytes), {} of them again; timeouts: {}; sector erases: {}",
        s.chunks_sent, s.chunk_bytes, s.chunks_resent, s.timeouts, s.erases
    );
    if a.no_commit {
        println!("not committed (--no-commit): run again without it to commit");
    }
    Ok(())
}
