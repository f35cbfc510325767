//! `ground tradeoff` end to end (issue 43): from a simulated recording it writes both figures, the Markdown and the
//! JSON, with how many figures were checked against a retrieved text; a board file that does not exist and a
//! catalogue figure without a source are refused with exit code 1.

use std::path::PathBuf;
use std::process::{Command, Output};

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("ground-tradeoff-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn ground(args: &[&std::ffi::OsStr]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_ground"))
        .args(args)
        .output()
        .expect("running ground")
}

/// `d/rec.csv`: `hours` of the seed experiment (seed 3), simulated by `ground simulate`.
fn seed_record(d: &std::path::Path, hours: &str) -> PathBuf {
    let rec = d.join("rec.csv");
    let sim = ground(&[
        "simulate".as_ref(),
        "--out".as_ref(),
        rec.as_os_str(),
        "--preset".as_ref(),
        "seed".as_ref(),
        "--hours".as_ref(),
        hours.as_ref(),
        "--seed".as_ref(),
        "3".as_ref(),
    ]);
    assert!(
        sim.status.success(),
        "{}",
        String::from_utf8_lossy(&sim.stderr)
    );
    rec
}

#[test]
fn tradeoff_writes_both_figures_the_table_and_the_json() {
    let d = dir("ok");
    let rec = seed_record(&d, "0.1");
    let out = d.join("out");
    let run = ground(&[
        "tradeoff".as_ref(),
        rec.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let stdout = String::from_utf8_lossy(&run.stdout);
    assert!(
        run.status.success(),
        "{}",
        String::from_utf8_lossy(&run.stderr)
    );
    assert!(
        stdout.contains("seed + Pi") && stdout.contains("ours (MCU)"),
        "{stdout}"
    );
    for f in host_test::tradeoff::OUTPUTS {
        let bytes = std::fs::read(out.join(f)).unwrap();
        assert!(bytes.len() > 500, "{f}: {} bytes", bytes.len());
        if f.ends_with(".png") {
            assert_eq!(&bytes[..8], b"\x89PNG\r\n\x1a\n", "{f}");
        }
    }
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("tradeoff.json")).unwrap()).unwrap();
    let budgets = json["budgets"].as_array().unwrap();
    assert_eq!(budgets.len(), 2);
    // Ours carries the MCU's power computed from its duty cycle, below the seed board with its Pi.
    let duty = budgets[1]["mcu"]["duty"].as_f64().unwrap();
    assert!(duty > 0.01 && duty < 0.5, "{duty}");
    assert!(budgets[1]["power_w"].as_f64().unwrap() < budgets[0]["power_w"].as_f64().unwrap());
    assert_eq!(json["placement"]["axes"].as_array().unwrap().len(), 6);
    let md = std::fs::read_to_string(out.join("tradeoff.md")).unwrap();
    assert!(
        md.contains("| gyro x |") && md.contains("Battery (seed + Pi)"),
        "{md}"
    );
    // The checked counts are the library's (its test `the_docs_state_the_checked_counts` recounts them in the data
    // files' own text); here, that the command prints and writes them.
    use host_test::tradeoff::{board::Board, catalogue};
    let cat = catalogue::checked(&catalogue::default_catalogue().unwrap());
    let board = |name| Board::builtin(name).unwrap().unwrap().figures_checked();
    let [(c, n), (sc, sn), (oc, on)] =
        [cat, board("seed"), board("ours")].map(|k| (k.checked, k.total));
    assert!(
        stdout.contains(&format!(
            "figures checked against a retrieved text: catalogue {c} of {n}, seed + Pi {sc} of {sn}, ours (MCU) {oc} of {on}"
        )),
        "{stdout}"
    );
    assert_eq!(json["catalogue_checked"]["checked"], c);
    assert_eq!(json["catalogue_checked"]["total"], n);
    assert_eq!(budgets[1]["figures_checked"]["checked"], oc);
    assert_eq!(budgets[1]["figures_checked"]["total"], on);
    assert!(
        md.contains(&format!("{c} of the catalogue's {n}."))
            && md.contains(&format!("{sc} of the board file's {sn}."))
            && md.contains(&format!("{oc} of the board file's {on}.")),
        "{md}"
    );
}

#[test]
fn a_missing_board_and_an_unsourced_figure_are_refused() {
    let d = dir("bad");
    let rec = seed_record(&d, "0.02");
    let missing = d.join("no-such-board.toml");
    let refused = |flag: &str, file: &std::path::Path, out: &str, says: &str| {
        let out = d.join(out);
        let run = ground(&[
            "tradeoff".as_ref(),
            rec.as_os_str(),
            flag.as_ref(),
            file.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        let err = String::from_utf8_lossy(&run.stderr);
        assert_eq!(run.status.code(), Some(1), "{err}");
        assert!(err.contains(says), "{err}");
    };
    refused("--board", &missing, "o1", "no-such-board.toml");
    let cat = d.join("imus.toml");
    let text = host_test::tradeoff::catalogue::DEFAULT_TOML.replacen(
        "source = \"Safran Sensonor, STIM300 data sheet TS1524 rev. 9, physical characteristics (weight)\"",
        "source = \"\"",
        1,
    );
    assert_ne!(text, host_test::tradeoff::catalogue::DEFAULT_TOML);
    std::fs::write(&cat, text).unwrap();
    refused("--catalogue", &cat, "o2", "STIM300.mass_g: no source");
}
