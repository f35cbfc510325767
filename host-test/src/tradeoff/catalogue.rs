//! The catalogue of commercial IMUs (`data/imus.toml`): each figure with its unit (in the field's name) and its
//! source.

use super::{Checked, Figure, TradeoffError};
use serde::{Deserialize, Serialize};

/// The catalogue the binary carries (`data/imus.toml` at the repository's root).
pub const DEFAULT_TOML: &str = include_str!("../../../data/imus.toml");

/// One IMU of the catalogue. Units are in the field names (the reader refuses any other field).
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Imu {
    /// Name, e.g. `STIM300`.
    pub name: String,
    /// Class of the part, e.g. `tactical MEMS IMU`.
    pub kind: String,
    /// One of the seed paper's comparison IMUs (its references 10–14).
    pub in_paper: bool,
    /// Gyro bias instability, °/h.
    pub gyro_bias_instability_dph: Figure,
    /// Angle random walk, °/√h.
    pub gyro_arw_dprh: Option<Figure>,
    /// Accelerometer bias instability, µg.
    pub accel_bias_instability_ug: Option<Figure>,
    /// Velocity random walk, (m/s)/√h.
    pub accel_vrw_mps_rh: Option<Figure>,
    /// Mass, g.
    pub mass_g: Figure,
    /// Power, W.
    pub power_w: Figure,
}

/// The field names' units, in the catalogue's order.
pub const UNITS: [(&str, &str); 6] = [
    ("gyro_bias_instability_dph", "°/h"),
    ("gyro_arw_dprh", "°/√h"),
    ("accel_bias_instability_ug", "µg"),
    ("accel_vrw_mps_rh", "(m/s)/√h"),
    ("mass_g", "g"),
    ("power_w", "W"),
];

impl Imu {
    /// Every figure present: (field name, unit, figure), in the order of [`UNITS`].
    pub fn figures(&self) -> Vec<(&'static str, &'static str, &Figure)> {
        let all = [
            Some(&self.gyro_bias_instability_dph),
            self.gyro_arw_dprh.as_ref(),
            self.accel_bias_instability_ug.as_ref(),
            self.accel_vrw_mps_rh.as_ref(),
            Some(&self.mass_g),
            Some(&self.power_w),
        ];
        UNITS
            .iter()
            .zip(all)
            .filter_map(|(&(name, unit), f)| Some((name, unit, f?)))
            .collect()
    }
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct File {
    imu: Vec<Imu>,
}

/// Reads a catalogue (TOML text; `origin` names it in errors) and checks every figure: positive and finite, with a
/// source.
pub fn parse(text: &str, origin: &str) -> Result<Vec<Imu>, TradeoffError> {
    let file: File = toml::from_str(text).map_err(|source| TradeoffError::Toml {
        origin: origin.to_owned(),
        source: Box::new(source),
    })?;
    for imu in &file.imu {
        for (field, _, fig) in imu.figures() {
            fig.check(origin, &format!("{}.{field}", imu.name))?;
        }
    }
    if file.imu.is_empty() {
        return Err(TradeoffError::Invalid {
            origin: origin.to_owned(),
            what: "no [[imu]] entry".into(),
        });
    }
    Ok(file.imu)
}

/// How many of the catalogue's figures were checked against a retrieved text.
pub fn checked(catalogue: &[Imu]) -> Checked {
    Checked::of(
        catalogue
            .iter()
            .flat_map(|i| i.figures().into_iter().map(|(_, _, f)| f)),
    )
}

/// The default catalogue ([`DEFAULT_TOML`]).
pub fn default_catalogue() -> Result<Vec<Imu>, TradeoffError> {
    parse(DEFAULT_TOML, "data/imus.toml (built in)")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_figure_of_the_catalogue_has_a_unit_and_a_source() {
        let cat = default_catalogue().unwrap();
        let mut n = 0;
        for imu in &cat {
            let figs = imu.figures();
            // Gyro bias instability, mass and power are mandatory.
            assert!(figs.len() >= 3, "{}", imu.name);
            for (field, unit, f) in figs {
                assert!(!unit.is_empty(), "{}.{field}", imu.name);
                assert!(
                    field.ends_with(match unit {
                        "°/h" => "_dph",
                        "°/√h" => "_dprh",
                        "µg" => "_ug",
                        "(m/s)/√h" => "_mps_rh",
                        "g" => "_g",
                        "W" => "_w",
                        other => panic!("unexpected unit {other}"),
                    }),
                    "{field} {unit}"
                );
                assert!(f.source.trim().len() > 10, "{}.{field}", imu.name);
                assert!(f.value.is_finite() && f.value > 0.0);
                // An unchecked figure says why in its note.
                assert!(
                    f.checked || !f.note.trim().is_empty(),
                    "{}.{field}",
                    imu.name
                );
                n += 1;
            }
        }
        assert!(n >= 40, "{n} figures");
        // The paper's five references and the current parts the issue names.
        for name in [
            "Honeywell MIMU",
            "Scalable SIRU",
            "LN-200S",
            "ADIS16485",
            "ADIS16405",
            "STIM300",
            "ADIS16470",
            "BMI088",
        ] {
            assert!(cat.iter().any(|i| i.name.contains(name)), "{name}");
        }
        assert_eq!(cat.iter().filter(|i| i.in_paper).count(), 5);
    }

    #[test]
    fn a_figure_without_a_source_or_without_a_unit_is_refused() {
        let ok = r#"[[imu]]
name = "X"
kind = "k"
in_paper = false
gyro_bias_instability_dph = { value = 1.0, source = "a data sheet, Table 1", checked = false, note = "n" }
mass_g = { value = 1.0, source = "a data sheet, p. 2", checked = false, note = "n" }
power_w = { value = 1.0, source = "a data sheet, Table 3", checked = false, note = "n" }
"#;
        assert_eq!(parse(ok, "t").unwrap().len(), 1);
        let no_source = ok.replace("a data sheet, p. 2", " ");
        let e = parse(&no_source, "t").unwrap_err().to_string();
        assert!(e.contains("X.mass_g") && e.contains("source"), "{e}");
        // A field without a unit in its name is not a field of the catalogue.
        let no_unit = ok.replace("power_w", "power");
        assert!(parse(&no_unit, "t").is_err());
        let negative = ok.replace(
            "value = 1.0, source = \"a data sheet, Table 3\"",
            "value = -1.0, source = \"s\"",
        );
        assert!(parse(&negative, "t").is_err());
    }
}
