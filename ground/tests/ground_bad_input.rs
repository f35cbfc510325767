//! `ground` on bad input (issue 14, item 5): every case fails with a message that names the file, the place
//! (line and column, or bytes) and what was expected, or — where going on is right — succeeds with a warning that
//! names what was dropped. Nothing panics, and no exit 0 loses or invents data. Outputs that cannot be written
//! (`/dev/full`: a full disk) are errors.
//! Here: the readers and writers (full disk, damaged or malformed recordings); `ground_bad_args` has the options,
//! calibration files and the process's own edges.

mod common;

use common::*;
use std::path::Path;

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
    // A huge time in the middle (the next row goes back), and a repeated time: (file, row, value, command, what the
    // message must say besides "t must increase").
    let cases = [
        (
            "huge_t.csv",
            200,
            "1e300",
            "allan",
            ["line 202, column 1 (t)", "is not after 1e300 s on line 201"],
        ),
        (
            "repeat.csv",
            10,
            "0",
            "import",
            ["line 11, column 1 (t)", "on line 10"],
        ),
    ];
    for (file, row, value, command, [at, previous]) in cases {
        let p = csv_with_cell(&d, file, row, 0, value);
        fails(
            &ground(&[&command, &p, &"--out", &d.join("o.csv")]),
            &[file, at, previous, "t must increase"],
        );
    }
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
    let windows = [
        (
            "1000:2000",
            &["--window 1000:2000 keeps 0 samples", "spans 0"],
        ),
        ("nan:5", &["--window", "numbers of seconds"]),
    ];
    for (window, needles) in windows {
        let args: [&dyn AsRef<std::ffi::OsStr>; 6] = [
            &"allan",
            &rec,
            &"--out",
            &d.join("a.csv"),
            &"--window",
            &window,
        ];
        fails(&ground(&args), needles);
    }
}
