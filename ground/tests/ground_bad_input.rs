//! `ground` on bad input (issue 14, item 5): every case fails with a message that names the file, the place
//! (line and column, or bytes) and what was expected, or — where going on is right — succeeds with a warning that
//! names what was dropped. Nothing panics, and no exit 0 loses or invents data. Outputs that cannot be written
//! (`/dev/full`: a full disk) are errors.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use host_test::calibrate::{CalibrationFile, write_calibration};
use shared::calib::CalibrationTable;

/// A fresh folder of this test under the system's temporary folder.
fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ground-bad-input-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn ground(args: &[&dyn AsRef<std::ffi::OsStr>]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ground"))
        .args(args.iter().map(|a| a.as_ref()))
        .output()
        .expect("running ground")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// `ground` failed (exit code 1, not a panic's 101) with every one of `needles` in its error message.
#[track_caller]
fn fails(out: &Output, needles: &[&str]) -> String {
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
fn warns(out: &Output, needles: &[&str]) -> String {
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
fn succeeds(out: &Output) {
    let err = text(&out.stderr);
    assert!(out.status.success(), "stderr:\n{err}");
    assert!(!err.contains("panicked"), "panic:\n{err}");
}

/// A simulated frame log of `samples` frames.
fn frame_log(d: &Path, samples: u32) -> PathBuf {
    let p = d.join("frames.bin");
    succeeds(&ground(&[
        &"simulate",
        &"--out",
        &p,
        &"--samples",
        &samples.to_string(),
    ]));
    p
}

/// A simulated interchange CSV of `samples` rows.
fn csv(d: &Path, samples: u32) -> PathBuf {
    let p = d.join("rec.csv");
    succeeds(&ground(&[
        &"simulate",
        &"--out",
        &p,
        &"--samples",
        &samples.to_string(),
    ]));
    p
}

/// The telemetry stream of a replay.
fn telemetry(d: &Path) -> PathBuf {
    let frames = frame_log(d, 2000);
    let p = d.join("tm.kiss");
    succeeds(&ground(&[&"replay", &frames, &"--out", &p]));
    p
}

/// `name` in `d`, a link to `/dev/full` (every write fails with "no space left on device").
fn full(d: &Path, name: &str) -> PathBuf {
    let p = d.join(name);
    std::os::unix::fs::symlink("/dev/full", &p).unwrap();
    p
}

/// A CSV with `edit` applied to the cells (row 0 = header) of a simulated one.
fn edited_csv(d: &Path, name: &str, edit: impl Fn(usize, &mut Vec<String>)) -> PathBuf {
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
fn csv_with_cell(d: &Path, name: &str, row: usize, col: usize, value: &str) -> PathBuf {
    edited_csv(d, name, |i, c| {
        if i == row {
            c[col] = value.into();
        }
    })
}

/// The test CSV with every sensor cell of every data row set to `value`.
fn csv_with_sensors(d: &Path, name: &str, value: &str) -> PathBuf {
    edited_csv(d, name, |i, c| {
        if i > 0 {
            c.iter_mut().skip(1).for_each(|x| *x = value.into());
        }
    })
}

#[test]
fn decode_to_a_full_disk_is_an_error() {
    let d = dir("decode-full");
    let tm = telemetry(&d);
    for name in ["fused.csv", "all.jsonl"] {
        let out = full(&d, name);
        fails(
            &ground(&[&"decode", &tm, &"--out", &out]),
            &["writing", name, "No space left on device"],
        );
    }
    let allan = full(&d, "allan.csv");
    fails(
        &ground(&[
            &"decode",
            &tm,
            &"--out",
            &d.join("ok.csv"),
            &"--allan",
            &allan,
        ]),
        &["writing", "allan.csv", "No space left on device"],
    );
}

#[test]
fn every_other_writer_reports_a_full_disk() {
    let d = dir("writers-full");
    let frames = frame_log(&d, 2000);
    let rec = csv(&d, 400);
    let no_space = "No space left on device";
    fails(
        &ground(&[&"replay", &frames, &"--out", &full(&d, "r.kiss")]),
        &["r.kiss", no_space],
    );
    fails(
        &ground(&[&"import", &frames, &"--out", &full(&d, "i.csv")]),
        &["i.csv", no_space],
    );
    fails(
        &ground(&[
            &"simulate",
            &"--out",
            &full(&d, "s.csv"),
            &"--samples",
            &"100",
        ]),
        &["s.csv", no_space],
    );
    fails(
        &ground(&[&"allan", &rec, &"--out", &full(&d, "a.csv")]),
        &["a.csv", no_space],
    );
    fails(
        &ground(&[
            &"allan",
            &rec,
            &"--out",
            &d.join("a_ok.csv"),
            &"--fit",
            &full(&d, "fit.csv"),
        ]),
        &["fit.csv", no_space],
    );
    let mimu = Path::new(env!("CARGO_MANIFEST_DIR")).join("../testdata/mimu4444/exp1_excerpt.bin");
    fails(
        &ground(&[
            &"calibrate",
            &"--static",
            &mimu,
            &"--min-static-s",
            &"0.2",
            &"--out",
            &full(&d, "cal.json"),
        ]),
        &["cal.json", no_space],
    );
}

#[test]
fn replay_of_an_empty_or_random_file_is_an_error() {
    let d = dir("replay-junk");
    let empty = d.join("empty.bin");
    std::fs::write(&empty, b"").unwrap();
    let random = d.join("random.bin");
    let mut rng = host_test::testrng::TestRng::new(1);
    let bytes: Vec<u8> = (0..100_000).map(|_| (rng.next_u64() >> 56) as u8).collect();
    std::fs::write(&random, &bytes).unwrap();
    for (f, n) in [(&empty, "0 bytes"), (&random, "100000 bytes")] {
        let out = d.join("out.kiss");
        fails(
            &ground(&[&"replay", f, &"--out", &out]),
            &["no valid frame in", n, "sync marker 1A CF FC 1D"],
        );
        assert!(!out.exists(), "nothing is written");
    }
    // Nor is a CSV.
    fails(
        &ground(&[&"replay", &csv(&d, 100), &"--out", &d.join("o.kiss")]),
        &["rec.csv", "no valid frame"],
    );
    // Decode: nothing decodable is an error too (it used to write an empty CSV).
    for f in [&empty, &random] {
        fails(
            &ground(&[&"decode", f, &"--out", &d.join("o.csv")]),
            &["no telemetry message in", "KISS frames"],
        );
    }
}

#[test]
fn replay_of_a_damaged_frame_log_warns_what_was_dropped() {
    let d = dir("replay-damaged");
    let frames = frame_log(&d, 2000);
    let mut b = std::fs::read(&frames).unwrap();
    for i in (1000..b.len()).step_by(7919) {
        b[i] ^= 0x55;
    }
    let damaged = d.join("damaged.bin");
    std::fs::write(&damaged, &b).unwrap();
    warns(
        &ground(&[&"replay", &damaged, &"--out", &d.join("o.kiss")]),
        &[
            "damaged.bin",
            "frames failed their CRC",
            "not in the telemetry",
        ],
    );
    warns(
        &ground(&[&"import", &damaged, &"--out", &d.join("o.csv")]),
        &[
            "damaged.bin",
            "frames failed their CRC",
            "not in the recording",
        ],
    );
    // Frames repeated (sequence counter back by 50): kept, but named.
    let b = std::fs::read(&frames).unwrap();
    let frame = b.len() / 2000;
    let repeated = d.join("repeated.bin");
    std::fs::write(&repeated, [&b[..100 * frame], &b[50 * frame..]].concat()).unwrap();
    warns(
        &ground(&[&"replay", &repeated, &"--out", &d.join("o.kiss")]),
        &["repeated.bin", "jumped back 1 times", "repeated frames"],
    );
    // A MIMU4444 stream cut in the middle of a frame.
    let mimu = std::fs::read(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../testdata/mimu4444/exp1_excerpt.bin"),
    )
    .unwrap();
    let cut = d.join("cut.bin");
    std::fs::write(&cut, &mimu[..10_000]).unwrap();
    warns(
        &ground(&[&"import", &cut, &"--out", &d.join("m.csv")]),
        &[
            "cut.bin",
            "bytes skipped",
            "not in the recording",
            "stream ends",
        ],
    );
}

#[test]
fn kalibr_is_not_written_from_a_recording_without_noise() {
    let d = dir("kalibr");
    // All values NaN: the reader stops at the first one.
    let nan = csv_with_sensors(&d, "nan.csv", "NaN");
    let k = d.join("imu.yaml");
    fails(
        &ground(&[&"allan", &nan, &"--out", &d.join("a.csv"), &"--kalibr", &k]),
        &[
            "nan.csv",
            "line 2, column 2 (g00x)",
            "finite number",
            "'NaN'",
        ],
    );
    assert!(!k.exists());
    // Constant values: no white noise to report (Kalibr would take 0 for a perfect sensor).
    let flat = csv_with_sensors(&d, "flat.csv", "0.5");
    fails(
        &ground(&[&"allan", &flat, &"--out", &d.join("a.csv"), &"--kalibr", &k]),
        &["--kalibr", "flat.csv", "no white-noise density"],
    );
    assert!(!k.exists());
    // Gyros only: no accelerometer densities to write.
    let gyros = edited_csv(&d, "gyros.csv", |_, c| {
        let keep: Vec<String> = c
            .iter()
            .enumerate()
            .filter(|(j, _)| *j == 0 || (j - 1) % 6 < 3)
            .map(|(_, x)| x.clone())
            .collect();
        *c = keep;
    });
    fails(
        &ground(&[
            &"allan",
            &gyros,
            &"--out",
            &d.join("a.csv"),
            &"--kalibr",
            &k,
        ]),
        &["no accel columns"],
    );
    assert!(!k.exists());
}

#[test]
fn non_finite_cells_are_errors_with_line_and_column() {
    let d = dir("nonfinite");
    // Line 101 = row 100 (the header is line 1); column 2 = g00x.
    for (name, cell) in [
        ("nan.csv", "nan"),
        ("inf.csv", "inf"),
        ("ninf.csv", "-Infinity"),
        ("huge.csv", "1e400"),
    ] {
        let p = csv_with_cell(&d, name, 100, 1, cell);
        fails(
            &ground(&[&"allan", &p, &"--out", &d.join("a.csv")]),
            &[
                name,
                "line 101, column 2 (g00x)",
                "expected a finite number",
                &format!("'{cell}'"),
            ],
        );
    }
    let p = csv_with_cell(&d, "nan_t.csv", 50, 0, "NaN");
    fails(
        &ground(&[&"import", &p, &"--out", &d.join("o.csv")]),
        &["nan_t.csv", "line 51, column 1 (t)", "finite number"],
    );
}

#[test]
fn time_must_increase() {
    let d = dir("time");
    // A huge time in the middle: the next row goes back.
    let p = csv_with_cell(&d, "huge_t.csv", 200, 0, "1e300");
    fails(
        &ground(&[&"allan", &p, &"--out", &d.join("a.csv")]),
        &[
            "huge_t.csv",
            "line 202, column 1 (t)",
            "is not after 1e300 s on line 201",
            "t must increase",
        ],
    );
    // A repeated time.
    let p = csv_with_cell(&d, "repeat.csv", 10, 0, "0");
    fails(
        &ground(&[&"import", &p, &"--out", &d.join("o.csv")]),
        &[
            "repeat.csv",
            "line 11, column 1 (t)",
            "on line 10",
            "t must increase",
        ],
    );
    // Blank lines count in the line numbers.
    let p = d.join("blank.csv");
    std::fs::write(&p, "\nt,g00x\n0,1\n\n\n0.1,2\n0.1,3\n").unwrap();
    fails(
        &ground(&[&"import", &p, &"--out", &d.join("o.csv")]),
        &["line 7, column 1 (t)", "on line 6"],
    );
}

#[test]
fn gaps_in_time_and_missing_temperatures_are_warnings() {
    let d = dir("gaps");
    let p = d.join("gap.csv");
    std::fs::write(
        &p,
        "t,temp_c,g00x,a00x\n0,20,1,0\n0.1,NaN,2,0\n0.2,20,1,0\n5,20,3,0\n5.1,20,1,0\n",
    )
    .unwrap();
    let out = d.join("o.csv");
    warns(
        &ground(&[&"import", &p, &"--out", &out]),
        &[
            "t: 1 gaps longer than 1.5 sample intervals",
            "before line 5",
            "temp_c: 1 of 5 samples have no temperature (NaN), the first on line 3",
        ],
    );
    // The data are all there.
    assert_eq!(std::fs::read_to_string(&out).unwrap().lines().count(), 6);
}

#[test]
fn a_byte_order_mark_is_accepted() {
    let d = dir("bom");
    let plain = csv(&d, 400);
    let p = d.join("bom.csv");
    let src = std::fs::read(&plain).unwrap();
    std::fs::write(&p, [&[0xEF, 0xBB, 0xBF][..], &src].concat()).unwrap();
    let (a, b) = (d.join("a.csv"), d.join("b.csv"));
    succeeds(&ground(&[&"import", &plain, &"--out", &a]));
    succeeds(&ground(&[&"import", &p, &"--out", &b]));
    assert_eq!(std::fs::read(&a).unwrap(), std::fs::read(&b).unwrap());
    succeeds(&ground(&[&"allan", &p, &"--out", &d.join("adev.csv")]));
}

#[test]
fn csv_structure_errors_say_what_was_expected() {
    let d = dir("structure");
    let p = d.join("header_only.csv");
    std::fs::write(&p, "t,g00x,a00x\n").unwrap();
    fails(
        &ground(&[&"import", &p, &"--out", &d.join("o.csv")]),
        &["header_only.csv", "line 1 (header)", "no data row"],
    );
    let p = d.join("semicolons.csv");
    std::fs::write(&p, "t;g00x\n0;1\n0.1;2\n").unwrap();
    fails(
        &ground(&[&"allan", &p, &"--out", &d.join("a.csv")]),
        &["semicolons.csv", "separated by commas", "';'"],
    );
    let p = d.join("short.csv");
    std::fs::write(&p, "t,g00x\n0,1\n").unwrap();
    fails(
        &ground(&[&"allan", &p, &"--out", &d.join("a.csv")]),
        &["short.csv", "1 samples"],
    );
    let p = d.join("two.csv");
    std::fs::write(&p, "t,g00x\n0,1\n0.1,2\n").unwrap();
    fails(
        &ground(&[&"allan", &p, &"--out", &d.join("a.csv")]),
        &["two.csv", "too few for any averaging time"],
    );
    let rec = csv(&d, 400);
    fails(
        &ground(&[
            &"allan",
            &rec,
            &"--out",
            &d.join("a.csv"),
            &"--window",
            &"1000:2000",
        ]),
        &["--window 1000:2000 keeps 0 samples", "spans 0"],
    );
    fails(
        &ground(&[
            &"allan",
            &rec,
            &"--out",
            &d.join("a.csv"),
            &"--window",
            &"nan:5",
        ]),
        &["--window", "numbers of seconds"],
    );
}

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
