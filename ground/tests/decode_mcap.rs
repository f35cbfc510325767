//! `ground decode --mcap` (issue 30, items 3 and 4): the MCAP file read back with the `mcap` crate holds as many
//! messages per channel as `ground decode` writes rows to its CSVs (fused, navigation) and objects to its JSON lines
//! (health, housekeeping), stamped with the frame time the CSV gives; `--nav` alone needs no `--out`.

use host_test::formats::mcap::{FUSED_TOPIC, HEALTH_TOPIC, HOUSEKEEPING_TOPIC, NAV_TOPIC};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::Command;

fn dir() -> PathBuf {
    let d = Path::new(env!("CARGO_TARGET_TMPDIR")).join("decode-mcap");
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// Runs `ground args`, which must succeed; returns its stdout.
fn ground(args: &[&dyn AsRef<std::ffi::OsStr>]) -> String {
    let out = Command::new(env!("CARGO_BIN_EXE_ground"))
        .args(args)
        .output()
        .expect("running ground");
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        out.status.success(),
        "ground {:?} failed:\n{err}",
        args.len()
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// A telemetry stream: 20 s of simulated frames at 604.8 Hz through the flight core (378 fused samples).
fn telemetry(d: &Path) -> PathBuf {
    let frames = d.join("frames.bin");
    ground(&[
        &"simulate",
        &"--out",
        &frames,
        &"--seconds",
        &"20",
        &"--rate",
        &"604.8",
    ]);
    let tm = d.join("tm.kiss");
    ground(&[&"replay", &frames, &"--out", &tm]);
    tm
}

/// Data rows of a CSV (lines after the header).
fn rows(p: &Path) -> Vec<String> {
    let text = std::fs::read_to_string(p).unwrap();
    text.lines().skip(1).map(str::to_owned).collect()
}

#[test]
fn mcap_counts_match_the_csv_and_jsonl() {
    let d = dir();
    let tm = telemetry(&d);
    let (csv, nav, jsonl, mcap) = (
        d.join("fused.csv"),
        d.join("nav.csv"),
        d.join("all.jsonl"),
        d.join("tm.mcap"),
    );
    ground(&[
        &"decode", &tm, &"--out", &csv, &"--nav", &nav, &"--mcap", &mcap,
    ]);
    ground(&[&"decode", &tm, &"--out", &jsonl]);

    let bytes = std::fs::read(&mcap).unwrap();
    let mut counts: BTreeMap<String, usize> = BTreeMap::new();
    let mut fused_ns = Vec::new();
    for m in mcap::MessageStream::new(&bytes).unwrap() {
        let m = m.unwrap();
        assert_eq!(m.channel.message_encoding, "json");
        assert_eq!(
            m.channel.schema.as_ref().map(|s| s.encoding.as_str()),
            Some("jsonschema")
        );
        let _: serde_json::Value = serde_json::from_slice(&m.data).unwrap();
        if m.channel.topic == FUSED_TOPIC {
            fused_ns.push(m.log_time);
        }
        *counts.entry(m.channel.topic.clone()).or_default() += 1;
    }
    let fused_rows = rows(&csv);
    let jsonl_kind = |k: &str| {
        std::fs::read_to_string(&jsonl)
            .unwrap()
            .lines()
            .filter(|l| l.starts_with(&format!("{{\"{k}\"")))
            .count()
    };
    let expect = BTreeMap::from([
        (FUSED_TOPIC.to_owned(), fused_rows.len()),
        (NAV_TOPIC.to_owned(), rows(&nav).len()),
        (HEALTH_TOPIC.to_owned(), jsonl_kind("Health")),
        (HOUSEKEEPING_TOPIC.to_owned(), jsonl_kind("Housekeeping")),
    ]);
    println!("MCAP messages per topic: {counts:?}");
    let got = |t: &str| counts.get(t).copied().unwrap_or(0);
    for (topic, n) in &expect {
        assert_eq!(got(topic), *n, "{topic}");
    }
    assert!(got(FUSED_TOPIC) > 100 && got(NAV_TOPIC) > 100 && got(HEALTH_TOPIC) > 0);
    // No SetTime in a replay: the stamps are the CSV's frame time (t_s, column 2).
    for (row, ns) in fused_rows.iter().zip(&fused_ns) {
        let t_s: f64 = row.split(',').nth(1).unwrap().parse().unwrap();
        assert!((t_s * 1e9 - *ns as f64).abs() < 1.0, "{t_s} s vs {ns} ns");
    }
}

#[test]
fn nav_alone_needs_no_out_but_some_output_is_required() {
    let d = dir().join("nav-only");
    std::fs::create_dir_all(&d).unwrap();
    let tm = telemetry(&d);
    let nav = d.join("nav.csv");
    let stdout = ground(&[&"decode", &tm, &"--nav", &nav]);
    assert!(stdout.contains("navigation increments"), "{stdout}");
    assert!(rows(&nav).len() > 100);
    let none = Command::new(env!("CARGO_BIN_EXE_ground"))
        .arg("decode")
        .arg(&tm)
        .output()
        .unwrap();
    assert!(!none.status.success());
    assert!(String::from_utf8_lossy(&none.stderr).contains("--out"));
}
