//! The interchange-CSV reader of the ground tool (`host_test::formats::csv::Recording::parse_from`, the reader
//! behind `Recording::read`; `Recording::parse` for UTF-8 text).
//!
//! Input: arbitrary bytes (the seed corpus holds files written by `Recording::write`).
//! Properties:
//! * never panics, UTF-8 or not;
//! * `parse` (from `&str`) and `parse_from` (streamed bytes) agree when the bytes are UTF-8;
//! * on success every column has one value per time;
//! * writing a parsed recording (`Recording::write`, canonical form) and parsing it again gives a recording that
//!   writes to the very same text (the canonical form is a fixed point).
//!
//! `Recording::write` only writes to a path, so the target writes to a file in a per-process temporary directory.
#![no_main]

use host_test::formats::csv::Recording;
use libfuzzer_sys::fuzz_target;
use std::path::PathBuf;
use std::sync::OnceLock;

fn tmp() -> &'static PathBuf {
    static DIR: OnceLock<PathBuf> = OnceLock::new();
    DIR.get_or_init(|| {
        let d = std::env::temp_dir().join(format!("csv-fuzz-{}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    })
}

fn same(
    a: &Result<(Recording, Vec<String>), impl std::fmt::Debug>,
    b: &Result<(Recording, Vec<String>), impl std::fmt::Debug>,
) -> bool {
    match (a, b) {
        (Ok((ra, wa)), Ok((rb, wb))) => wa == wb && format!("{ra:?}") == format!("{rb:?}"),
        (Err(ea), Err(eb)) => format!("{ea:?}") == format!("{eb:?}"),
        _ => false,
    }
}

fuzz_target!(|data: &[u8]| {
    let streamed = Recording::parse_from(data, data.len() as u64, "<fuzz>");
    if let Ok(text) = std::str::from_utf8(data) {
        let parsed = Recording::parse(text);
        // Compared through Debug so that NaN cells compare equal to themselves.
        assert!(
            same(
                &parsed,
                &Recording::parse_from(data, data.len() as u64, "<text>")
            ),
            "parse and parse_from differ"
        );
    }
    let Ok((rec, _)) = streamed else { return };
    for c in &rec.columns {
        assert_eq!(c.data.len(), rec.t_s.len(), "column {} length", c.name());
    }
    if let Some(t) = &rec.temp_c {
        assert_eq!(t.len(), rec.t_s.len());
    }
    let path = tmp().join("a.csv");
    rec.write(&path).unwrap();
    let first = std::fs::read(&path).unwrap();
    let (again, _) = Recording::read(&path).unwrap_or_else(|e| {
        panic!(
            "canonical output does not parse: {e}\n{}",
            String::from_utf8_lossy(&first)
        )
    });
    again.write(&path).unwrap();
    let second = std::fs::read(&path).unwrap();
    assert!(
        first == second,
        "canonical form is not a fixed point:\n{}\n---\n{}",
        String::from_utf8_lossy(&first),
        String::from_utf8_lossy(&second)
    );
});
