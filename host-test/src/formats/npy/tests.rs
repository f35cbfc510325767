use super::*;

/// A version 1.0 `.npy` file written by hand (not by the crate that reads it): header dict, padding, data.
fn npy(descr: &str, fortran: bool, shape: &str, data: &[u8]) -> Vec<u8> {
    let mut header = format!(
        "{{'descr': '{descr}', 'fortran_order': {}, 'shape': {shape}, }}",
        if fortran { "True" } else { "False" }
    );
    while (10 + header.len() + 1) % 64 != 0 {
        header.push(' ');
    }
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend_from_slice(data);
    out
}

fn f8(v: &[f64]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Rows (t, gx gy gz ax ay az) of one group.
const ROWS: [[f64; 7]; 3] = [
    [0.0, 0.1, 0.2, 0.3, 0.01, 0.02, 1.0],
    [0.5, -0.1, 0.25, 0.35, 0.011, 0.021, 0.999],
    [1.0, 0.0, 0.2, 0.3, 0.012, 0.022, 1.001],
];

#[test]
fn reads_c_and_fortran_order_float64_and_float32_as_the_csv_would() {
    let c: Vec<f64> = ROWS.iter().flatten().copied().collect();
    let f: Vec<f64> = (0..7)
        .flat_map(|j| ROWS.iter().map(move |r| r[j]))
        .collect();
    let rec = parse(&npy("<f8", false, "(3, 7)", &f8(&c))[..]).unwrap();
    assert_eq!(
        parse(&npy("<f8", true, "(3, 7)", &f8(&f))[..]).unwrap(),
        rec
    );
    // The same values through the interchange CSV reader.
    let mut text = String::from("t,g00x,g00y,g00z,a00x,a00y,a00z\n");
    for r in ROWS {
        let cells: Vec<String> = r.iter().map(|x| x.to_string()).collect();
        text += &(cells.join(",") + "\n");
    }
    let (csv, warnings) = Recording::parse(&text).unwrap();
    assert!(warnings.is_empty());
    assert_eq!(rec, csv);
    // float32, C and Fortran order: the values as f32.
    let le: Vec<u8> = c.iter().flat_map(|&x| (x as f32).to_le_bytes()).collect();
    let r32 = parse(&npy("<f4", false, "(3, 7)", &le)[..]).unwrap();
    assert_eq!(r32.t_s, vec![0.0, 0.5, 1.0]);
    assert_eq!(r32.columns[5].data[2], f64::from(1.001f32));
    let le_f: Vec<u8> = f.iter().flat_map(|&x| (x as f32).to_le_bytes()).collect();
    assert_eq!(parse(&npy("<f4", true, "(3, 7)", &le_f)[..]).unwrap(), r32);
}

/// C and Fortran order of a bigger array (several blocks of rows, 3 groups) give the same columns, each the
/// array's column as numpy indexes it: `a[i, j] = 1000 j + i` (t = i, increasing).
#[test]
fn c_and_fortran_order_agree_over_many_blocks() {
    let (rows, cols) = (70_001, 19);
    let at = |i: usize, j: usize| (1000 * j + i) as f64;
    let c: Vec<f64> = (0..rows)
        .flat_map(|i| (0..cols).map(move |j| at(i, j)))
        .collect();
    let f: Vec<f64> = (0..cols)
        .flat_map(|j| (0..rows).map(move |i| at(i, j)))
        .collect();
    let shape = format!("({rows}, {cols})");
    let rc = parse(&npy("<f8", false, &shape, &f8(&c))[..]).unwrap();
    let rf = parse(&npy("<f8", true, &shape, &f8(&f))[..]).unwrap();
    assert_eq!(rc, rf);
    assert_eq!(rc.t_s[69_999], 69_999.0);
    // Sorted as the CSV reader sorts: gyros of groups 0, 1, 2, then accels; g01y is array column 1 + 6 + 1.
    let g01y = rc.column("g01y").unwrap();
    assert_eq!(g01y.data[12_345], at(12_345, 8));
    assert_eq!(rc.column("a02z").unwrap().data[rows - 1], at(rows - 1, 18));
    assert_eq!(rc.columns.len(), 18);
}

/// Only the named columns are read (and `t`); names not in the array are left out.
#[test]
fn reads_only_the_requested_columns() {
    let c: Vec<f64> = ROWS.iter().flatten().copied().collect();
    let bytes = npy("<f8", false, "(3, 7)", &f8(&c));
    let arr = NpyArray::from_bytes(&bytes).unwrap();
    let r = arr
        .recording_of(&["a00z".into(), "g00y".into(), "g07x".into()])
        .unwrap();
    assert_eq!(r.t_s, vec![0.0, 0.5, 1.0]);
    let names: Vec<String> = r.columns.iter().map(|c| c.name()).collect();
    assert_eq!(names, ["g00y", "a00z"]);
    assert_eq!(r.columns[1].data, vec![1.0, 0.999, 1.001]);
    assert_eq!(r.columns[0].data, vec![0.2, 0.25, 0.2]);
    // A value that is not finite in a column not read is not seen; with the means, every column is read.
    let mut nan = c;
    nan[7 + 5] = f64::NAN;
    let bytes = npy("<f8", false, "(3, 7)", &f8(&nan));
    let arr = NpyArray::from_bytes(&bytes).unwrap();
    assert!(arr.recording_of(&["g00x".into()]).is_ok());
    let err = arr
        .recording_with_means(&["g00x".into()])
        .unwrap_err()
        .to_string();
    assert!(err.contains("row 1, column 5 (a00y): NaN"), "{err}");
    let (r, means) = NpyArray::from_bytes(&npy("<f8", true, "(3, 7)", &f8(&f_order())))
        .unwrap()
        .recording_with_means(&["g00x".into()])
        .unwrap();
    assert_eq!(r.columns.len(), 1);
    // One group: each mean is its column.
    assert_eq!(means.len(), 6);
    assert_eq!(means[5].data, vec![1.0, 0.999, 1.001]);
    assert_eq!(
        (means[5].kind, means[5].axis, means[5].members),
        (SensorKind::Accel, 2, 1)
    );
}

/// ROWS in Fortran order.
fn f_order() -> Vec<f64> {
    (0..7)
        .flat_map(|j| ROWS.iter().map(move |r| r[j]))
        .collect()
}

/// Integers and booleans are converted to float64, and the array says so.
#[test]
fn integers_are_converted_with_a_note() {
    let vals: Vec<i64> = (0..21)
        .map(|k| k * 3 - 5 + (k % 7 == 0) as i64 * 100)
        .collect();
    let expect: Vec<f64> = vals.iter().map(|&v| v as f64).collect();
    let want = parse(&npy("<f8", false, "(3, 7)", &f8(&expect))[..]).unwrap();
    let i2: Vec<u8> = vals
        .iter()
        .flat_map(|&v| (v as i16).to_le_bytes())
        .collect();
    let bytes = npy("<i2", false, "(3, 7)", &i2);
    let arr = NpyArray::from_bytes(&bytes).unwrap();
    assert_eq!(arr.recording().unwrap(), want);
    assert_eq!(
        arr.conversion().unwrap(),
        "int16 values (dtype <i2) converted to float64"
    );
    let i8: Vec<u8> = vals.iter().flat_map(|&v| v.to_le_bytes()).collect();
    let arr8 = npy("<i8", false, "(3, 7)", &i8);
    assert_eq!(parse(&arr8[..]).unwrap(), want);
    assert!(
        NpyArray::from_bytes(&arr8)
            .unwrap()
            .conversion()
            .unwrap()
            .contains("exact up to 2^53")
    );
    let c: Vec<f64> = ROWS.iter().flatten().copied().collect();
    assert!(
        NpyArray::from_bytes(&npy("<f8", false, "(3, 7)", &f8(&c)))
            .unwrap()
            .conversion()
            .is_none()
    );
}

#[test]
fn bad_arrays_are_errors_that_say_why() {
    let c: Vec<f64> = ROWS.iter().flatten().copied().collect();
    let err = |b: Vec<u8>| parse(&b[..]).unwrap_err().to_string();
    assert!(err(b"not numpy".to_vec()).contains("not a readable .npy file"));
    assert!(err(npy("<f8", false, "(21,)", &f8(&c))).contains("2-D array"));
    assert!(err(npy("<f8", false, "(7, 3)", &f8(&c))).contains("found 3"));
    assert!(err(npy("<f8", false, "(0, 7)", &[])).contains("no rows"));
    assert!(err(npy("<c16", false, "(3, 7)", &f8(&c))).contains("dtype <c16 is not read"));
    assert!(err(npy("<f2", false, "(3, 7)", &f8(&c))).contains("float64 or float32"));
    let be: Vec<u8> = c.iter().flat_map(|x| x.to_be_bytes()).collect();
    let big = err(npy(">f8", false, "(3, 7)", &be));
    assert!(
        big.contains("big-endian array (dtype >f8) is not read"),
        "{big}"
    );
    assert!(err(npy(">f4", true, "(3, 7)", &be)).contains("big-endian"));
    let obj = err(npy("|O", false, "(3, 7)", &be));
    assert!(obj.contains("object array"), "{obj}");
    assert!(
        err(npy("<f8", false, "(3, 7)", &f8(&c[..20])))
            .contains("reading the data: the file holds 160 bytes after the header, the shape 3 × 7 of <f8 needs 168")
    );
    let mut inf = c.clone();
    inf[20] = f64::INFINITY;
    assert!(err(npy("<f8", true, "(3, 7)", &f8(&inf))).contains("row 2, column 6 (a00z): inf"));
    let mut nan = c.clone();
    nan[9] = f64::NAN;
    assert!(err(npy("<f8", false, "(3, 7)", &f8(&nan))).contains("row 1, column 2 (g00y)"));
    let mut back = c;
    back[14] = 0.25;
    assert!(err(npy("<f8", false, "(3, 7)", &f8(&back))).contains("row 2, column 0 (t)"));
}

#[test]
fn the_loader_knows_npy_by_extension_or_magic() {
    use crate::load::{InputKind, detect};
    assert_eq!(detect(Path::new("rec.npy"), &[]).unwrap(), InputKind::Npy);
    assert_eq!(detect(Path::new("rec.NPY"), &[]).unwrap(), InputKind::Npy);
    let head = npy("<f8", false, "(3, 7)", &[]);
    assert_eq!(detect(Path::new("rec.dat"), &head).unwrap(), InputKind::Npy);
}

/// The same recording as an interchange CSV and as a `.npy` array (C and Fortran order) gives the same Allan
/// analysis, byte for byte; reading one column of the `.npy` (the cluster means computed while reading) gives that
/// column's and the means' lines of it.
#[test]
fn allan_of_the_npy_equals_allan_of_the_csv() {
    use crate::allan::recording::{self, AdevRequest};
    use crate::allan::{DevKind, TauSpec};
    let (rows, groups) = (5000, 3);
    let mut rng = crate::testrng::TestRng::new(31);
    let t: Vec<f64> = (0..rows).map(|i| i as f64 / 18.9).collect();
    let sensors: Vec<Vec<f64>> = (0..6 * groups)
        .map(|k| rng.normals(rows, 0.01 * (1 + k % 6) as f64))
        .collect();
    let dir = std::env::temp_dir().join(format!("npy-allan-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("rec.csv");
    Recording::from_group_columns(t, sensors)
        .write(&csv)
        .unwrap();
    // The values as the CSV holds them (9 decimals), in array column order, for the `.npy`.
    let rec = crate::load::load_with(&csv, None, 0).unwrap().recording;
    let t = rec.t_s.clone();
    let sensors: Vec<Vec<f64>> = (0..6 * groups)
        .map(|k| {
            let kind = if k % 6 < 3 {
                SensorKind::Gyro
            } else {
                SensorKind::Accel
            };
            let name = column_name(kind, k / 6, k % 3);
            rec.column(&name).unwrap().data.clone()
        })
        .collect();
    let all: Vec<&[f64]> = std::iter::once(&t[..])
        .chain(sensors.iter().map(|c| &c[..]))
        .collect();
    let c_order: Vec<f64> = (0..rows)
        .flat_map(|i| all.iter().map(move |c| c[i]))
        .collect();
    let f_order: Vec<f64> = all.iter().flat_map(|c| c.iter().copied()).collect();
    let shape = format!("({rows}, {})", 1 + 6 * groups);
    let (npy_c, npy_f) = (dir.join("c.npy"), dir.join("f.npy"));
    std::fs::write(&npy_c, npy("<f8", false, &shape, &f8(&c_order))).unwrap();
    std::fs::write(&npy_f, npy("<f8", true, &shape, &f8(&f_order))).unwrap();
    let req = AdevRequest {
        kind: DevKind::Oadev,
        taus: TauSpec::Octave,
        columns: vec![],
        cluster: true,
    };
    let long_csv = |series: &[recording::Series]| {
        let mut out = Vec::new();
        recording::write_long_csv(series, &mut out).unwrap();
        String::from_utf8(out).unwrap()
    };
    let allan = |path: &Path| {
        let loaded = crate::load::load_with(path, None, 0).unwrap();
        long_csv(&recording::analyze(&loaded.recording, &req, &|| ()).unwrap())
    };
    let from_csv = allan(&csv);
    for label in ["g00x", "a02z", "mean_gx", "mean_az"] {
        assert!(from_csv.lines().filter(|l| l.starts_with(label)).count() >= 8);
    }
    assert_eq!(allan(&npy_c), from_csv);
    assert_eq!(allan(&npy_f), from_csv);
    // One column, the means from the reader; and all columns, the means from each block as it is read.
    for path in [&npy_c, &npy_f] {
        let (loaded, means) = crate::load::load_selected(path, None, 0, &[]).unwrap();
        assert_eq!(loaded.recording, rec);
        for m in means.unwrap() {
            let (data, n) = recording::cluster_mean(&rec, m.kind, m.axis).unwrap();
            assert_eq!((m.data, m.members), (data, n));
        }
        let one = vec!["g01y".to_string()];
        let (loaded, means) = crate::load::load_selected(path, None, 0, &one).unwrap();
        assert_eq!(loaded.recording.columns.len(), 1);
        let means = means.unwrap();
        assert_eq!(
            means[1].data,
            recording::cluster_mean(&rec, SensorKind::Gyro, 1)
                .unwrap()
                .0
        );
        let req_one = AdevRequest {
            columns: one,
            ..req.clone()
        };
        let series =
            recording::analyze_with_means(&loaded.recording, Some(means), &req_one, &|| ())
                .unwrap();
        let expect: Vec<&str> = from_csv
            .lines()
            .filter(|l| {
                l.starts_with("column,") || l.starts_with("g01y,") || l.starts_with("mean_")
            })
            .collect();
        assert_eq!(long_csv(&series), expect.join("\n") + "\n");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}
