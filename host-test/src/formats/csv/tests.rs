use super::*;

#[test]
fn any_order_unknown_ignored_round_trip() {
    let text = "a00z,t,foo,g00x,temp_c\n1.5,0,7,0.25,20\n-1,0.1,8,0.5,20.5\n";
    let (rec, warnings) = Recording::parse(text).unwrap();
    assert_eq!(warnings.len(), 1);
    assert!(warnings[0].contains("'foo'"));
    assert_eq!(rec.t_s, [0.0, 0.1]);
    assert_eq!(rec.temp_c.as_deref(), Some(&[20.0, 20.5][..]));
    assert_eq!(rec.column("g00x").unwrap().data, [0.25, 0.5]);
    assert_eq!(rec.column("a00z").unwrap().data, [1.5, -1.0]);
    let dir = std::env::temp_dir().join(format!("csv-rt-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let p = dir.join("r.csv");
    rec.write(&p).unwrap();
    assert_eq!(
        std::fs::read_to_string(&p).unwrap().lines().next(),
        Some("t,temp_c,g00x,a00z")
    );
    assert_eq!(Recording::read(&p).unwrap().0, rec);
    assert!((rec.sample_interval_s().unwrap() - 0.1).abs() < 1e-15);
}

/// The reader (whichever compiled version of it this processor runs) gives every cell exactly the standard
/// library's value: cells as we write them, in shortest round-trip form, and a few the fast path refuses.
#[test]
fn reader_values_are_the_standard_librarys() {
    let mut rng = crate::testrng::TestRng::new(0x2545_F491_4F6C_DD1D);
    let mut cells: Vec<String> = Vec::new();
    for i in 0..30_000 {
        let s = rng.next_u64();
        let v = ((s >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 10f64.powi((s % 9) as i32 - 4);
        let mut c = String::new();
        match i % 4 {
            0 | 1 => push_value(&mut c, v),
            2 => c = format!("{v}"),
            _ => c = format!("{v:e}"),
        }
        cells.push(c);
    }
    let mut text = String::from("t,g00x,g00y,g00z\n");
    for (row, c) in cells.chunks_exact(3).enumerate() {
        text.push_str(&format!("{row},{},{},{}\n", c[0], c[1], c[2]));
    }
    let (rec, _) = Recording::parse(&text).unwrap();
    let got = ["g00x", "g00y", "g00z"].map(|n| &rec.column(n).unwrap().data);
    for (row, c) in cells.chunks_exact(3).enumerate() {
        for (k, cell) in c.iter().enumerate() {
            assert_eq!(
                got[k][row].to_bits(),
                cell.parse::<f64>().unwrap().to_bits(),
                "{cell}"
            );
        }
    }
}

#[test]
fn large_files_parse_in_chunks_with_exact_line_numbers() {
    let mut text = String::from("t,g00x,a00z\n");
    for i in 0..40_000 {
        text.push_str(&format!("{},{}.5,-{}\n", i, i, i));
    }
    let (rec, _) = Recording::parse(&text).unwrap();
    assert_eq!(rec.len(), 40_000);
    assert_eq!(rec.column("g00x").unwrap().data[39_999], 39_999.5);
    assert_eq!(rec.column("a00z").unwrap().data[12_345], -12_345.0);
    // An error deep in the file: line 1 is the header, so sample 31 000 is on line 31 002.
    let bad = text.replacen("31000.5", "31x00.5", 1);
    let e = Recording::parse(&bad).unwrap_err().to_string();
    assert_eq!(
        e,
        "line 31002, column 2 (g00x): expected a number, found '31x00.5'"
    );
    // Blank lines anywhere (also across pieces) are skipped, and the rows stay in order.
    let blanks = text
        .replacen("\n1000,", "\n\n\n1000,", 1)
        .replacen("\n30000,", "\n\r\n30000,", 1)
        + "\n\n";
    let (rec, _) = Recording::parse(&blanks).unwrap();
    assert_eq!(rec.len(), 40_000);
    assert!(rec.t_s.windows(2).all(|w| w[1] == w[0] + 1.0));
    assert_eq!(rec.column("g00x").unwrap().data[39_999], 39_999.5);
    let bad = blanks.replacen("31000.5", "31x00.5", 1);
    let e = Recording::parse(&bad).unwrap_err().to_string();
    assert_eq!(
        e,
        "line 31005, column 2 (g00x): expected a number, found '31x00.5'"
    );
    let short = text.replacen("\n25000,25000.5,-25000\n", "\n25000,25000.5\n", 1);
    let e = Recording::parse(&short).unwrap_err().to_string();
    assert_eq!(e, "line 25002: expected 3 comma-separated values, found 2");
}

#[test]
fn fast_parser_agrees_with_std_and_writer_is_compact() {
    let cases = [
        "0",
        "-0",
        "1",
        "-1.5",
        "0.028390270",
        "-0.02839027",
        "123456789.123456789",
        "1e-3",
        "2.5E+7",
        "9007199254740993",
        "0.1",
        "3.14159265358979323846",
        "1e300",
        "-4.9e-324",
        "17",
        ".5",
        "5.",
        "1e",
        "x",
        "",
        "-",
        "nan",
        "inf",
        "+7",
        "0.000000001",
    ];
    for c in cases {
        let want: Option<f64> = c.parse().ok();
        assert_eq!(
            parse_f64(c).map(f64::to_bits),
            want.map(f64::to_bits),
            "{c}"
        );
    }
    let mut rng = crate::testrng::TestRng::new(0x2545_F491_4F6C_DD1D);
    for _ in 0..200_000 {
        let v = rng.uniform() - 0.5;
        let mut out = String::new();
        push_value(&mut out, v);
        assert_eq!(
            parse_f64(&out).map(f64::to_bits),
            out.parse::<f64>().ok().map(f64::to_bits),
            "{out}"
        );
        assert!(
            (parse_f64(&out).unwrap() - v).abs() <= 0.5e-9 + 1e-17,
            "{v} → {out}"
        );
        let full = format!("{v}");
        assert_eq!(
            parse_f64(&full).map(f64::to_bits),
            Some(v.to_bits()),
            "{full}"
        );
    }
    let mut out = String::new();
    for v in [0.5, -0.0, 1.0, -0.0283902700001, 1e-12] {
        push_value(&mut out, v);
        out.push(' ');
    }
    assert_eq!(out, "0.5 0 1 -0.02839027 0 ");
}

/// Reading in blocks of any size, from a source that returns short reads, gives the same recording and the same
/// error positions as parsing the whole text.
#[test]
fn any_block_size_gives_the_same_result() {
    struct Trickle<'a>(&'a [u8], usize);
    impl std::io::Read for Trickle<'_> {
        fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
            self.1 = self.1 % 5 + 1;
            let n = self.1.min(buf.len()).min(self.0.len());
            buf[..n].copy_from_slice(&self.0[..n]);
            self.0 = &self.0[n..];
            Ok(n)
        }
    }
    let mut text = String::from("\n \nt,temp_c,g00x,a00z,zz\r\n");
    for i in 0..300 {
        text.push_str(&format!(
            "{},{},-0.{:09},{}.5,x\n",
            i,
            20 + i % 3,
            i * 7919,
            i
        ));
        if i % 37 == 0 {
            text.push_str("\r\n\n");
        }
    }
    text.push_str("300,21,1,2,y");
    let whole = Recording::parse(&text).unwrap();
    assert_eq!(whole.0.len(), 301);
    let bad = text.replacen("\n150,", "\n150x,", 1);
    let want = Recording::parse(&bad).unwrap_err().to_string();
    assert!(want.starts_with("line 164, column 1 (t)"), "{want}");
    for block in [1, 2, 7, 64, 65, 200, 1 << 20] {
        let got = Recording::parse_blocks(Trickle(text.as_bytes(), 0), 0, "t", block, parse_chunk)
            .unwrap();
        assert_eq!(got, whole, "block {block}");
        let e = Recording::parse_blocks(Trickle(bad.as_bytes(), 0), 9, "t", block, parse_chunk)
            .unwrap_err();
        assert_eq!(e.to_string(), want, "block {block}");
    }
}

/// The eight-digits-at-a-time path (32 bytes from the cell on) and the digit-at-a-time path (near the
/// end of the text) give the same value and end for every kind of cell.
#[test]
fn swar_and_scalar_number_paths_agree() {
    let mut cases: Vec<String> = [
        "0",
        "-0",
        "7",
        "-1.5",
        "0.028390270",
        "-0.000833333",
        "1234567",
        "12345678",
        "0.12345678",
        "0.123456789",
        "1.1234567890123456",
        "1.123456789012345",
        "-9.999999999",
        "5.",
        ".5",
        "-",
        ".",
        "",
        "1e-3",
        "9007199254740993",
        "900719925474099.3",
        "12.34.5",
        "0x1",
    ]
    .iter()
    .map(|c| c.to_string())
    .collect();
    let mut rng = crate::testrng::TestRng::new(1);
    for _ in 0..20_000 {
        let s = rng.next_u64();
        let (int, frac) = ((s % 100_000_000).to_string(), (s >> 27).to_string());
        let (ni, nf) = ((s >> 40) as usize % 9, (s >> 44) as usize % 18);
        let sign = if s >> 63 == 1 { "-" } else { "" };
        cases.push(format!(
            "{sign}{}.{}",
            &int[..ni.min(int.len())],
            &frac[..nf.min(frac.len())]
        ));
    }
    for c in &cases {
        for tail in [",", "\n", "\r\n", ",,", "x", "/", ":"] {
            let short = format!("{c}{tail}");
            let long = format!("{short}{}", "0123456789:/-. ,".repeat(2));
            let (a, b) = (
                fast_number(short.as_bytes(), 0),
                fast_number(long.as_bytes(), 0),
            );
            assert_eq!(
                a.map(|(v, e)| (v.to_bits(), e)),
                b.map(|(v, e)| (v.to_bits(), e)),
                "{short:?}"
            );
            if let Some((v, e)) = b {
                assert_eq!(Some(v), c[..e].parse::<f64>().ok(), "{c}");
            }
        }
    }
}

proptest::proptest! {
    #![proptest_config(proptest::prelude::ProptestConfig::with_cases(2000))]
    /// Random edits of a valid file (and random bytes) give a recording or a positioned error, never a panic.
    #[test]
    fn mangled_files_never_panic(edits in proptest::collection::vec((0usize..400, proptest::prelude::any::<u8>()), 0..12),
                                 junk in proptest::collection::vec(proptest::prelude::any::<u8>(), 0..200),
                                 block in 1usize..80) {
        let mut text = String::from("t,temp_c,g00x,a00z,zz\n");
        for i in 0..12 {
            text.push_str(&format!("{},{}.5,-0.{}25,{}e-3,x\n", i, 20 + i, i, i));
        }
        let mut bytes = text.into_bytes();
        let len = bytes.len();
        for (at, b) in edits {
            if let Some(x) = bytes.get_mut(at % len) {
                *x = b;
            }
        }
        if let Ok(t) = std::str::from_utf8(&bytes) {
            let _ = Recording::parse(t);
        }
        let _ = Recording::parse(&String::from_utf8_lossy(&junk));
        // Raw bytes (not UTF-8 either), whole and in small blocks: the same recording or the same error.
        for b in [&bytes, &junk] {
            let show = |r: Result<(Recording, Vec<String>), CsvError>| match r {
                Ok(v) => format!("{v:?}"),
                Err(e) => e.to_string(),
            };
            let whole = show(Recording::parse_blocks(&b[..], b.len() as u64, "p", BLOCK_BYTES, parse_chunk));
            let small = show(Recording::parse_blocks(&b[..], 7, "p", block, parse_chunk));
            proptest::prop_assert_eq!(whole, small);
        }
    }
}

#[test]
fn header_errors_give_the_header_line() {
    let e = Recording::parse("\n \nt,g00x,g00x\n0,1,2\n")
        .unwrap_err()
        .to_string();
    assert_eq!(e, "line 3 (header): column 'g00x' appears twice");
    let e = Recording::parse("\n\n").unwrap_err().to_string();
    assert_eq!(e, "line 1 (header): the file is empty");
}

#[test]
fn errors_say_where_and_what() {
    let e = Recording::parse("t,g00x\n0,1\n0.1,abc\n")
        .unwrap_err()
        .to_string();
    assert_eq!(e, "line 3, column 2 (g00x): expected a number, found 'abc'");
    let e = Recording::parse("t,g00x\n0,1,2\n").unwrap_err().to_string();
    assert_eq!(e, "line 2: expected 2 comma-separated values, found 3");
    assert!(
        Recording::parse("g00x\n1\n")
            .unwrap_err()
            .to_string()
            .contains("no 't' column")
    );
    assert!(
        Recording::parse("t,g00x,g00x\n")
            .unwrap_err()
            .to_string()
            .contains("appears twice")
    );
    assert!(Recording::parse("").is_err());
    assert_eq!(parse_column_name("g12y"), Some((SensorKind::Gyro, 12, 1)));
    assert_eq!(parse_column_name("gx"), None);
    assert_eq!(parse_column_name("q00x"), None);
}
