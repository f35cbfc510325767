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
    // float32, big-endian: the values as f32.
    let be: Vec<u8> = c.iter().flat_map(|&x| (x as f32).to_be_bytes()).collect();
    let r32 = parse(&npy(">f4", false, "(3, 7)", &be)[..]).unwrap();
    assert_eq!(r32.t_s, vec![0.0, 0.5, 1.0]);
    assert_eq!(r32.columns[5].data[2], f64::from(1.001f32));
}

#[test]
fn bad_arrays_are_errors_that_say_why() {
    let c: Vec<f64> = ROWS.iter().flatten().copied().collect();
    let err = |b: Vec<u8>| parse(&b[..]).unwrap_err();
    assert!(err(b"not numpy".to_vec()).contains("not a readable .npy file"));
    assert!(err(npy("<f8", false, "(21,)", &f8(&c))).contains("2-D array"));
    assert!(err(npy("<f8", false, "(7, 3)", &f8(&c))).contains("found 3"));
    assert!(err(npy("<f8", false, "(0, 7)", &[])).contains("no rows"));
    assert!(err(npy("<i8", false, "(3, 7)", &f8(&c))).contains("float64 or float32"));
    assert!(err(npy("<f8", false, "(3, 7)", &f8(&c[..20]))).contains("reading the data"));
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
