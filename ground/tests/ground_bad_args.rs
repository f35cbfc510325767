//! `ground` on bad options and calibration files, and at the process's edges (a closed stdout, a missing
//! recording): every case fails with a message that names the option or file and what was expected; nothing panics.
//! (`ground_bad_input`: bad recordings and full disks.)

mod common;

use common::*;
use std::path::Path;
use std::process::Command;

use host_test::calibrate::{CalibrationFile, write_calibration};
use shared::calib::CalibrationTable;

#[test]
fn simulate_parameters_are_checked() {
    let d = dir("simulate");
    let bin = d.join("s.bin");
    let csv = d.join("s.csv");
    let cases: &[(&Path, &[&str], &[&str])] = &[
        (
            &bin,
            &["--rate", "20000", "--samples", "10"],
            &["--rate 20000 Hz is above the FPGA base rate 9676.8 Hz"],
        ),
        (
            &csv,
            &["--rate", "1e9"],
            &["--rate 1000000000 Hz is above the FPGA base rate"],
        ),
        (
            &bin,
            &["--base-rate-hz", "0", "--samples", "10"],
            &["--base-rate-hz must be a positive number of Hz, found 0"],
        ),
        (
            &bin,
            &["--rate", "0.01", "--samples", "10"],
            &["below the lowest rate of a frame log", "16-bit"],
        ),
        (
            &bin,
            &["--rate", "7000", "--samples", "10"],
            &["not the base rate 9676.8 Hz divided by a whole number"],
        ),
        (
            &csv,
            &["--rate", "nan"],
            &["--rate must be a positive number"],
        ),
        (&csv, &["--samples", "0"], &["at least one sample"]),
        (&csv, &["--hours", "1e-9"], &["at least one sample"]),
        (
            &csv,
            &["--hours", "nan"],
            &["--hours must be a positive number"],
        ),
        (
            &csv,
            &["--rate", "9676.8"],
            &["would write", "bytes; the limit is", "lower --hours"],
        ),
        (
            &bin,
            &["--hours", "100000"],
            &["would write", "the limit is"],
        ),
        (
            &csv,
            &["--samples", "10", "--rate-dps", "nan,0,0"],
            &["--rate-dps: the values must be finite"],
        ),
        (
            &csv,
            &["--samples", "10", "--accel-g", "0,1"],
            &["--accel-g: expected 3 values"],
        ),
        (
            &csv,
            &["--samples", "10", "--unequal", "nan"],
            &["--unequal must be"],
        ),
        (
            &csv,
            &["--samples", "10", "--block", "5-1/gyro:0.5"],
            &["bad group range '5-1'"],
        ),
    ];
    for (out, args, needles) in cases {
        let mut all: Vec<&dyn AsRef<std::ffi::OsStr>> = vec![&"simulate", &"--out", out];
        all.extend(args.iter().map(|a| a as &dyn AsRef<std::ffi::OsStr>));
        fails(&ground(&all), needles);
        assert!(!out.exists(), "{args:?}: nothing is written");
    }
    // Valid: the comma form of the vectors, and a rate that is not a whole divisor (a note on the time base).
    succeeds(&ground(&[
        &"simulate",
        &"--out",
        &csv,
        &"--samples",
        &"10",
        &"--rate-dps",
        &"1,0,0",
    ]));
    let out = ground(&[
        &"simulate",
        &"--out",
        &bin,
        &"--samples",
        &"10",
        &"--rate",
        &"5",
    ]);
    succeeds(&out);
    assert!(text(&out.stderr).contains("5.000930232558139 Hz (decimation 1934)"));
}

/// Writes the factory table of `G` groups as `path` (by extension).
fn factory<const G: usize>(path: &Path) -> CalibrationFile {
    let f = CalibrationFile::from_table(&CalibrationTable::<G>::factory());
    write_calibration::<G>(&f, path).unwrap();
    f
}

#[test]
fn a_calibration_given_to_a_csv_is_an_error() {
    let d = dir("calib-csv");
    let rec = csv(&d, 400);
    let cal = d.join("board.bin");
    factory::<16>(&cal);
    fails(
        &ground(&[
            &"import",
            &rec,
            &"--calib",
            &cal,
            &"--out",
            &d.join("o.csv"),
        ]),
        &[
            "rec.csv",
            "calibrated values",
            "applies only to raw recordings",
        ],
    );
    fails(
        &ground(&[&"allan", &rec, &"--calib", &cal, &"--out", &d.join("a.csv")]),
        &["applies only to raw recordings"],
    );
}

#[test]
fn calibration_files_are_checked() {
    let d = dir("calib-files");
    let frames = frame_log(&d, 500);
    let run = |cal: &Path| {
        ground(&[
            &"replay",
            &frames,
            &"--calib",
            &cal,
            &"--out",
            &d.join("o.kiss"),
        ])
    };
    // Rails the wrong way round.
    let mut f = CalibrationFile::from_table(&CalibrationTable::<16>::factory());
    f.raw_min = 65535;
    f.raw_max = 0;
    let p = d.join("rails.json");
    std::fs::write(&p, f.to_json().unwrap()).unwrap();
    fails(
        &run(&p),
        &["rails.json", "raw_min = 65535 is not below raw_max = 0"],
    );
    // Neither 16 nor 8 groups: says so (not the 8-IMU retry's "expected 8").
    let mut f = CalibrationFile::from_table(&CalibrationTable::<8>::factory());
    f.groups.truncate(5);
    let p = d.join("five.json");
    std::fs::write(&p, f.to_json().unwrap()).unwrap();
    let e = fails(
        &run(&p),
        &["five.json", "5 groups, expected 16 (our board) or 8"],
    );
    assert!(!e.contains("groups, expected 8"), "{e}");
    // 16 groups with a bias the table cannot hold: that error, not the 8-IMU retry's.
    let mut f = CalibrationFile::from_table(&CalibrationTable::<16>::factory());
    f.groups[3].accel_bias_counts[0] = 1e6;
    let p = d.join("bias.json");
    std::fs::write(&p, f.to_json().unwrap()).unwrap();
    let e = fails(&run(&p), &["bias.json", "group 3", "accelerometer bias"]);
    assert!(!e.contains("expected 8"), "{e}");
    // A damaged table.
    let p = d.join("board.bin");
    factory::<16>(&p);
    let mut b = std::fs::read(&p).unwrap();
    b[8] ^= 1;
    std::fs::write(&p, &b).unwrap();
    fails(&run(&p), &["board.bin", "CRC-32C does not match"]);
    // The 8-IMU table where the board's is needed.
    let p = d.join("mimu.bin");
    factory::<8>(&p);
    fails(&run(&p), &["mimu.bin", "8-IMU (MIMU4444) calibration"]);
    // And valid tables still work.
    let p = d.join("ok.bin");
    factory::<16>(&p);
    succeeds(&run(&p));
    let p = d.join("ok.json");
    factory::<16>(&p);
    succeeds(&run(&p));
}

#[test]
fn no_static_interval_says_so() {
    let d = dir("static");
    let mimu = Path::new(env!("CARGO_MANIFEST_DIR")).join("../testdata/mimu4444/exp1_excerpt.bin");
    // The fixture's poses last 2.4 s: none is 15 s long.
    let e = fails(
        &ground(&[
            &"calibrate",
            &"--static",
            &mimu,
            &"--out",
            &d.join("c.json"),
        ]),
        &[
            "exp1_excerpt.bin",
            "no static interval found",
            "accel std < 0.01 g",
            "at least 15 s",
            "--min-static-s",
        ],
    );
    assert!(!e.contains("IMUs per pose"), "{e}");
    // A frame log is not a MIMU4444 stream: the error names the file.
    let frames = frame_log(&d, 500);
    fails(
        &ground(&[
            &"calibrate",
            &"--static",
            &frames,
            &"--out",
            &d.join("c.json"),
        ]),
        &["frames.bin", "no valid MIMU4444 frame"],
    );
}

/// `ground allan REC | head -0`: the reader is gone before `ground` prints its table. `ground` ends as a process
/// killed by SIGPIPE would (141), not with a panic (101). (If the table were printed before the pipe closed the
/// run would end 0; either way no panic: without the hook every run printing to a closed pipe panics.)
#[test]
fn a_closed_stdout_is_not_a_panic() {
    let d = dir("pipe");
    let rec = d.join("r.csv");
    let out = ground(&[
        &"simulate",
        &"--seconds",
        &"600",
        &"--rate",
        &"10",
        &"--out",
        &rec,
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let mut child = Command::new(env!("CARGO_BIN_EXE_ground"))
        .args([
            "allan".as_ref(),
            rec.as_os_str(),
            "--out".as_ref(),
            d.join("a").as_os_str(),
        ])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .expect("running ground");
    drop(child.stdout.take());
    let out = child.wait_with_output().expect("waiting for ground");
    let err = text(&out.stderr);
    assert!(!err.contains("panicked"), "panic:\n{err}");
    assert!(
        matches!(out.status.code(), Some(141 | 0)),
        "{:?}\n{err}",
        out.status
    );
}

/// A recording that is not there: its path and the cause, each said once.
#[test]
fn a_missing_recording_is_named_once() {
    let d = dir("missing");
    let rec = d.join("absent.csv");
    let err = fails(
        &ground(&[&"allan", &rec, &"--out", &d.join("a")]),
        &["absent.csv", "os error 2"],
    );
    assert_eq!(err.matches("absent.csv").count(), 1, "{err}");
    assert_eq!(err.matches("os error 2").count(), 1, "{err}");
}
