//! Interop with a real CSP stack: libcsp (the reference implementation, MIT, built from `../shared/vendor/libcsp`)
//! as the ground node (`tools/csp-ground`), the SITL binary as the satellite, a socat pseudo-terminal pair as the
//! bus, once with each CSP header version. The ground pings our node, listens for telemetry, sends a `Ping`
//! command, uploads a calibration in chunks and asks for Health, which must name the new table.
//!
//! Needs cmake, a C compiler, socat and the libcsp snapshot; without them the test says what it skipped and
//! passes, unless `REQUIRE_LIBCSP=1` (set by `.ci/run`), which makes a missing piece a failure.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing,
    clippy::arithmetic_side_effects
)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Child, Command as Proc, ExitStatus, Stdio};
use std::time::{Duration, Instant};

use common::{healths, table, upload_commands};
use shared::bus::BusConfig;
use shared::telemetry::{
    CalSource, Command, CommandEnvelope, MAX_MESSAGE_LEN, Telemetry, decode, encode,
};

/// Ground node address, satellite address, per version (v2 with addresses only 14 bits can hold).
fn addresses(version: u8) -> (u16, u16) {
    match version {
        1 => (BusConfig::DEFAULT.ground_addr, BusConfig::DEFAULT.addr),
        _ => (12_000, 5_000),
    }
}

/// Why the test cannot run here, if it cannot.
fn missing() -> Option<String> {
    let libcsp = libcsp_src();
    if !libcsp.join("CMakeLists.txt").is_file() {
        return Some(format!("no libcsp snapshot at {}", libcsp.display()));
    }
    for tool in ["cmake", "socat", "cc"] {
        let found = Proc::new("sh")
            .args(["-c", &format!("command -v {tool}")])
            .stdout(Stdio::null())
            .status()
            .is_ok_and(|s| s.success());
        if !found {
            return Some(format!(
                "'{tool}' not installed (apt-get install cmake socat gcc)"
            ));
        }
    }
    None
}

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn libcsp_src() -> PathBuf {
    std::env::var_os("LIBCSP_SRC")
        .map_or_else(|| repo().join("../shared/vendor/libcsp"), PathBuf::from)
}

/// Kills its process when dropped (a failed assertion must not leave socat or the SITL running).
struct Reap(Child);

impl Drop for Reap {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn wait_for(what: &str, limit: Duration, mut ready: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        assert!(t0.elapsed() < limit, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn wait_exit(child: &mut Child, limit: Duration) -> Option<ExitStatus> {
    let t0 = Instant::now();
    loop {
        if let Some(s) = child.try_wait().unwrap() {
            return Some(s);
        }
        if t0.elapsed() > limit {
            return None;
        }
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn unhex(s: &str) -> Vec<u8> {
    (0..s.len() / 2)
        .map(|i| u8::from_str_radix(&s[2 * i..2 * i + 2], 16).unwrap())
        .collect()
}

fn command_hex(tag: u16, cmd: Command) -> String {
    let mut buf = [0u8; MAX_MESSAGE_LEN];
    hex(encode(&CommandEnvelope { tag, cmd }, &mut buf).unwrap())
}

/// What the ground node saw.
struct Session {
    pings_ok: usize,
    /// (ms since the ground started, source address, message).
    telemetry: Vec<(u64, u16, Telemetry)>,
    undecodable: usize,
    stdout: String,
}

fn session(ground: &Path, work: &Path, frames: &Path, version: u8) -> (Session, ExitStatus) {
    let (ground_addr, sat_addr) = addresses(version);
    let (obc, gnd) = (
        work.join(format!("obc{version}")),
        work.join(format!("gnd{version}")),
    );
    let _socat = Reap(
        Proc::new("socat")
            .arg(format!("pty,raw,echo=0,link={}", obc.display()))
            .arg(format!("pty,raw,echo=0,link={}", gnd.display()))
            .stderr(Stdio::null())
            .spawn()
            .expect("socat"),
    );
    wait_for("socat's pseudo-terminals", Duration::from_secs(10), || {
        obc.exists() && gnd.exists()
    });
    let sitl_log = work.join(format!("sitl{version}.log"));
    let mut sitl = Reap(
        Proc::new(env!("CARGO_BIN_EXE_sitl"))
            .arg("--frames")
            .arg(frames)
            .arg("--bus")
            .arg(&obc)
            .arg("--flash")
            .arg(work.join(format!("flash{version}.img")))
            .args(["--csp-version", &version.to_string()])
            .args(["--addr", &sat_addr.to_string()])
            .args(["--ground-addr", &ground_addr.to_string()])
            .env("RUST_LOG", "info")
            .stderr(std::fs::File::create(&sitl_log).unwrap())
            .spawn()
            .expect("sitl"),
    );

    // Tag 1: Ping; tags 2..: the upload; the last: a Health request, which must see the new table.
    let mut sends = vec![command_hex(1, Command::Ping)];
    let upload = upload_commands(&table(77), shared::telemetry::CAL_CHUNK_MAX, 2);
    let health_tag = 3;
    sends.extend(upload.into_iter().map(|(tag, c)| command_hex(tag, c)));
    sends.push(command_hex(
        health_tag,
        Command::HealthRequest { detail: false },
    ));
    let mut cmd = Proc::new(ground);
    cmd.arg("--device")
        .arg(&gnd)
        .args(["--version", &version.to_string()])
        .args(["--addr", &ground_addr.to_string()])
        .args(["--node", &sat_addr.to_string()])
        .args(["--pings", "3", "--listen-ms", "5000", "--gap-ms", "100"]);
    for s in &sends {
        cmd.args(["--send", s]);
    }
    let out = cmd.stderr(Stdio::inherit()).output().expect("csp-ground");
    let stdout = String::from_utf8_lossy(&out.stdout).into_owned();
    assert!(
        out.status.success(),
        "csp-ground failed: {}\n{stdout}",
        out.status
    );

    // A clean stop on SIGTERM, as an operator's `kill` would do.
    let pid = nix::unistd::Pid::from_raw(sitl.0.id() as i32);
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).unwrap();
    let status = wait_exit(&mut sitl.0, Duration::from_secs(10));
    let log = std::fs::read_to_string(&sitl_log).unwrap_or_default();
    let status =
        status.unwrap_or_else(|| panic!("the SITL did not stop on SIGTERM; its log:\n{log}"));

    let mut s = Session {
        pings_ok: 0,
        telemetry: Vec::new(),
        undecodable: 0,
        stdout,
    };
    for line in s.stdout.lines() {
        let f: Vec<&str> = line.split(' ').collect();
        match f.as_slice() {
            ["done", pings, ..] => {
                s.pings_ok = pings.trim_start_matches("pings_ok=").parse().unwrap()
            }
            ["rx", t, src, _sport, _dport, payload] => match decode::<Telemetry>(&unhex(payload)) {
                Ok(m) => s
                    .telemetry
                    .push((t.parse().unwrap(), src.parse().unwrap(), m)),
                Err(_) => s.undecodable += 1,
            },
            _ => {}
        }
    }
    (s, status)
}

#[test]
fn a_libcsp_ground_node_talks_to_the_sitl_with_csp_v1_and_v2() {
    if let Some(why) = missing() {
        assert!(
            std::env::var_os("REQUIRE_LIBCSP").is_none(),
            "REQUIRE_LIBCSP is set but {why}"
        );
        eprintln!("SKIPPED libcsp interop test: {why}");
        return;
    }
    let work = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("libcsp-interop");
    let _ = std::fs::remove_dir_all(work.join("run"));
    let run = work.join("run");
    std::fs::create_dir_all(&run).unwrap();
    let build = Proc::new(repo().join("tools/csp-ground/build.sh"))
        .arg(work.join("build"))
        .env("LIBCSP_SRC", libcsp_src())
        .output()
        .unwrap();
    assert!(
        build.status.success(),
        "building libcsp and csp-ground failed:\n{}",
        String::from_utf8_lossy(&build.stderr)
    );
    let ground = work.join("build/csp-ground");
    // 10 s of frames at the default 604.8 frames/s, replayed in real time: the SITL streams through the session.
    let frames = run.join("frames.bin");
    std::fs::write(&frames, common::frames(6048)).unwrap();

    for version in [1u8, 2] {
        let (s, status) = session(&ground, &run, &frames, version);
        let (_, sat_addr) = addresses(version);
        let ctx = format!("CSP v{version}; csp-ground said:\n{}", s.stdout);
        assert!(status.success(), "SITL exit {status}; {ctx}");
        assert_eq!(s.pings_ok, 3, "pings answered; {ctx}");
        assert_eq!(
            s.undecodable, 0,
            "undecodable packets on the telemetry port; {ctx}"
        );
        assert!(
            s.telemetry.iter().all(|(_, src, _)| *src == sat_addr),
            "{ctx}"
        );
        let streamed = s
            .telemetry
            .iter()
            .filter(|(t, _, m)| *t <= 5000 && matches!(m, Telemetry::Fused(_)))
            .count();
        assert!(streamed >= 5, "{streamed} fused reports in 5 s; {ctx}");
        let acks: Vec<_> = s
            .telemetry
            .iter()
            .filter_map(|(_, _, m)| match m {
                Telemetry::Ack(a) => Some(*a),
                _ => None,
            })
            .collect();
        let upload_len = upload_commands(&table(77), shared::telemetry::CAL_CHUNK_MAX, 2).len();
        assert_eq!(acks.len(), 2 + upload_len, "one ack per command; {ctx}");
        assert!(acks.iter().all(|a| a.result.is_ok()), "{acks:?}; {ctx}");
        assert_eq!(acks[0].tag, 1, "the Ping command's ack; {ctx}");
        let health = s
            .telemetry
            .iter()
            .rev()
            .find_map(|(_, _, m)| match m {
                Telemetry::Health(h) => Some(*h),
                _ => None,
            })
            .expect("a Health report");
        assert_eq!(
            (health.cal_id, health.cal_source),
            (77, CalSource::Uploaded),
            "the uploaded table is in use; {ctx}"
        );
        eprintln!(
            "CSP v{version}: pings 3/3, {streamed} fused reports in 5 s, {} acks, calibration 77 in use",
            acks.len()
        );
    }
}

/// The SITL binary alone (no external tools): an empty frame log is a silent FPGA, which still yields Health every
/// second on the bus (here a plain file), and SIGTERM stops it cleanly.
#[test]
fn sitl_on_an_empty_log_sends_health_and_stops_on_sigterm() {
    let work = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join("sitl-empty");
    let _ = std::fs::remove_dir_all(&work);
    std::fs::create_dir_all(&work).unwrap();
    let (frames, bus) = (work.join("empty.bin"), work.join("bus.kiss"));
    std::fs::write(&frames, b"").unwrap();
    std::fs::write(&bus, b"").unwrap();
    let mut sitl = Reap(
        Proc::new(env!("CARGO_BIN_EXE_sitl"))
            .arg("--frames")
            .arg(&frames)
            .arg("--bus")
            .arg(&bus)
            .stderr(Stdio::null())
            .spawn()
            .expect("sitl"),
    );
    std::thread::sleep(Duration::from_millis(3500));
    let pid = nix::unistd::Pid::from_raw(sitl.0.id() as i32);
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).unwrap();
    let status = wait_exit(&mut sitl.0, Duration::from_secs(10)).expect("stops on SIGTERM");
    assert!(status.success(), "exit {status}");
    let log = host_test::formats::telemetry::TelemetryLog::decode(
        &std::fs::read(&bus).unwrap(),
        &BusConfig::DEFAULT,
    );
    let health = healths(&log.messages);
    assert!(
        (2..=4).contains(&health.len()),
        "{} Health reports in 3.5 s of silence",
        health.len()
    );
    assert!(health.iter().all(|h| h.link.frames == 0));
    assert_eq!(log.stats.csp_errors + log.stats.kiss_errors, 0);
}
