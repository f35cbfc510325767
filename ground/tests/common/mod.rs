//! Helpers of the `ground` command tests: running the binary, checking its exit and messages, simulated inputs.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

/// A fresh folder of this test under the system's temporary folder.
pub fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ground-bad-input-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

pub fn ground(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ground"))
        .args(args.iter().map(|a| a.as_ref()))
        .output()
        .expect("running ground")
}

pub fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// `ground` failed (exit code 1, not a panic's 101) with every one of `needles` in its error message.
#[track_caller]
pub fn fails(out: &Output, needles: &[&str]) -> String {
    let err = text(&out.stderr);
    assert!(!err.contains("panicked"), "panic:\n{err}");
    assert_eq!(out.status.code(), Some(1), "stderr:\n{err}");
    for n in needles {
        assert!(err.contains(n), "'{n}' missing from:\n{err}");
    }
    err
}

/// `ground` succeeded, with every one of `needles` in a warning on stderr.
#[track_caller]
pub fn warns(out: &Output, needles: &[&str]) -> String {
    let err = text(&out.stderr);
    assert!(!err.contains("panicked"), "panic:\n{err}");
    assert!(out.status.success(), "stderr:\n{err}");
    for n in needles {
        assert!(
            err.lines()
                .any(|l| l.starts_with("warning:") && l.contains(n)),
            "no warning with '{n}' in:\n{err}"
        );
    }
    err
}

#[track_caller]
pub fn succeeds(out: &Output) {
    let err = text(&out.stderr);
    assert!(out.status.success(), "stderr:\n{err}");
    assert!(!err.contains("panicked"), "panic:\n{err}");
}

/// `d/name` simulated with `samples` samples (the format from the name: `.bin` a frame log, `.csv` interchange).
fn simulated(d: &Path, name: &str, samples: u32) -> PathBuf {
    let p = d.join(name);
    let n = samples.to_string();
    succeeds(&ground(&[&"simulate", &"--out", &p, &"--samples", &n]));
    p
}

/// A simulated frame log of `samples` frames.
pub fn frame_log(d: &Path, samples: u32) -> PathBuf {
    simulated(d, "frames.bin", samples)
}

/// A simulated interchange CSV of `samples` rows.
pub fn csv(d: &Path, samples: u32) -> PathBuf {
    simulated(d, "rec.csv", samples)
}

/// The telemetry stream of a replay.
pub fn telemetry(d: &Path) -> PathBuf {
    let frames = frame_log(d, 2000);
    let p = d.join("tm.kiss");
    succeeds(&ground(&[&"replay", &frames, &"--out", &p]));
    p
}

/// `name` in `d`, a link to `/dev/full` (every write fails with "no space left on device").
pub fn full(d: &Path, name: &str) -> PathBuf {
    let p = d.join(name);
    std::os::unix::fs::symlink("/dev/full", &p).unwrap();
    p
}

/// A CSV with `edit` applied to the cells (row 0 = header) of a simulated one.
pub fn edited_csv(d: &Path, name: &str, edit: impl Fn(usize, &mut Vec<String>)) -> PathBuf {
    let src = std::fs::read_to_string(csv(d, 400)).unwrap();
    let mut out = String::new();
    for (i, line) in src.lines().enumerate() {
        let mut cells: Vec<String> = line.split(',').map(str::to_string).collect();
        edit(i, &mut cells);
        out.push_str(&cells.join(","));
        out.push('\n');
    }
    let p = d.join(name);
    std::fs::write(&p, out).unwrap();
    p
}

/// The test CSV with the cell at line index `row` (0: the header), column `col` replaced by `value`.
pub fn csv_with_cell(d: &Path, name: &str, row: usize, col: usize, value: &str) -> PathBuf {
    edited_csv(d, name, |i, c| {
        if i == row {
            c[col] = value.into();
        }
    })
}

/// The test CSV with every sensor cell of every data row set to `value`.
pub fn csv_with_sensors(d: &Path, name: &str, value: &str) -> PathBuf {
    edited_csv(d, name, |i, c| {
        if i > 0 {
            c.iter_mut().skip(1).for_each(|x| *x = value.into());
        }
    })
}
