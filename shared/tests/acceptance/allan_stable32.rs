//! Acceptance: the streaming integer accumulator reproduces Stable32's non-overlapping ADEV of a real OCXO record
//! (`testdata/allan-reference`, from allantools' test suite) at every octave τ, to 2e-4 relative, with the same
//! number of terms.

use shared::allan::AllanAccumulator;
use std::path::PathBuf;

fn fixture(name: &str) -> String {
    let p = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../testdata/allan-reference")
        .join(name);
    std::fs::read_to_string(&p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// Frequency in Hz as written ("10000000.126856699585915") → (f − 10 MHz) in units of 1e-10 Hz, exactly from the
/// decimal digits (rounded at the 10th decimal), minus a fixed offset so that every value fits an `i32`.
fn to_counts(line: &str) -> i32 {
    let (int, frac) = line.trim().split_once('.').expect("a decimal point");
    assert_eq!(int, "10000000");
    let mut digits: Vec<u8> = frac.bytes().map(|b| b - b'0').collect();
    digits.resize(11, 0);
    let mut v: i64 = digits[..10].iter().fold(0, |a, &d| a * 10 + i64::from(d));
    if digits[10] >= 5 {
        v += 1;
    }
    i32::try_from(v - 1_270_000_000).expect("fits i32")
}

/// One row of a Stable32 table: (averaging factor, number of terms, sigma).
fn stable32_rows(text: &str) -> Vec<(u64, u32, f64)> {
    text.lines()
        .filter(|l| !l.trim_start().starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let c: Vec<&str> = l.split_whitespace().collect();
            (
                c[0].parse().unwrap(),
                c[2].parse().unwrap(),
                c[5].parse().unwrap(),
            )
        })
        .collect()
}

#[test]
fn reproduces_stable32_non_overlapping_adev() {
    let data = fixture("ocxo_frequency.txt");
    let mut acc = AllanAccumulator::new();
    let mut n = 0;
    for line in data
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
    {
        assert!(acc.push(to_counts(line)));
        n += 1;
    }
    assert_eq!(n, 19_982);
    // counts of 1e-10 Hz → fractional frequency: divide by 1e10 (to Hz) and by 1e7 (the nominal frequency).
    let unit = 1e-10 / 1e7;
    let rows = stable32_rows(&fixture("adev_octave.txt"));
    assert_eq!(rows.len(), 12);
    let mut worst: f64 = 0.0;
    for (af, terms, sigma) in rows {
        let k = af.trailing_zeros() as usize;
        assert_eq!(1u64 << k, af);
        let level = acc.level(k).unwrap();
        assert_eq!(level.count, terms, "number of terms at m = {af}");
        let adev = level.avar().unwrap().sqrt() * unit;
        let rel = (adev - sigma).abs() / sigma;
        worst = worst.max(rel);
        assert!(
            rel <= 2e-4,
            "m = {af}: ours {adev:.5e}, Stable32 {sigma:.5e}, rel {rel:.2e}"
        );
    }
    println!("worst relative difference to Stable32: {worst:.2e}");
}
