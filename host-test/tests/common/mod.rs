//! Fixture readers shared by the integration tests.
#![allow(dead_code)]

use std::path::PathBuf;

pub fn fixture(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../testdata/allan-reference")
        .join(name)
}

fn read(name: &str) -> String {
    std::fs::read_to_string(fixture(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

/// Raw counter readings in Hz.
pub fn ocxo_hz() -> Vec<f64> {
    read("ocxo_frequency.txt")
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| l.trim().parse().unwrap())
        .collect()
}

/// Fractional frequency y = (f − 1e7)/1e7 (allantools frequency2fractional, mean 1e7).
pub fn ocxo_y() -> Vec<f64> {
    ocxo_hz().into_iter().map(|f| (f - 1.0e7) / 1.0e7).collect()
}

#[derive(Clone, Copy, Debug)]
pub struct S32Row {
    pub m: usize,
    pub tau: f64,
    pub n: usize,
    pub alpha: i32,
    pub lo: f64,
    pub dev: f64,
    pub hi: f64,
}

/// Stable32 result table: `AF Tau # Alpha MinSigma Sigma MaxSigma`.
pub fn stable32(name: &str) -> Vec<S32Row> {
    read(name)
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty())
        .map(|l| {
            let v: Vec<f64> = l.split_whitespace().map(|t| t.parse().unwrap()).collect();
            assert_eq!(v.len(), 7, "{name}: {l}");
            S32Row {
                m: v[0] as usize,
                tau: v[1],
                n: v[2] as usize,
                alpha: v[3] as i32,
                lo: v[4],
                dev: v[5],
                hi: v[6],
            }
        })
        .collect()
}

/// CSV with a header line (after `#` comments): returns header and rows of fields.
pub fn csv(name: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let text = read(name);
    let mut lines = text
        .lines()
        .filter(|l| !l.starts_with('#') && !l.trim().is_empty());
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(str::to_string).collect())
        .collect();
    (header, rows)
}

pub fn rel(a: f64, b: f64) -> f64 {
    if a == b { 0.0 } else { ((a - b) / b).abs() }
}

/// The real MIMU4444 records (`MIMU4444_DIR`, else `../shared/data/mimu4444` beside the repository); `None`, with a
/// SKIPPED line naming `test`, when they are absent.
pub fn mimu4444_dir(test: &str) -> Option<PathBuf> {
    let dir = std::env::var_os("MIMU4444_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| {
            PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/mimu4444")
        });
    if dir.join("exp_1/data.bin").is_file() {
        return Some(dir);
    }
    eprintln!(
        "SKIPPED {test}: no MIMU4444 data at {} (set MIMU4444_DIR)",
        dir.display()
    );
    None
}

pub mod effects;
