//! A recording: sample times, an optional temperature and the sensor columns (group, kind, axis, samples), with the
//! naming of the interchange columns (`g03z`). Every reader (`formats::{csv, npy, framelog, mimu}`) produces one,
//! and every analysis (`adev`, `diagnose`, `calibrate`, `twin`) takes one; the CSV reading and writing are
//! `formats::csv`'s.

/// Gyro or accelerometer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum SensorKind {
    /// Rate, °/s.
    Gyro,
    /// Specific force, g.
    Accel,
}

impl SensorKind {
    /// Column-name prefix (`g` / `a`).
    pub fn prefix(self) -> char {
        match self {
            SensorKind::Gyro => 'g',
            SensorKind::Accel => 'a',
        }
    }

    /// Physical unit of the CSV column.
    pub fn unit(self) -> &'static str {
        match self {
            SensorKind::Gyro => "deg/s",
            SensorKind::Accel => "g",
        }
    }

    /// Name used in reports ("gyro" / "accel").
    pub fn name(self) -> &'static str {
        match self {
            SensorKind::Gyro => "gyro",
            SensorKind::Accel => "accel",
        }
    }
}

/// Axis letters in column order.
pub const AXIS_NAMES: [char; 3] = ['x', 'y', 'z'];

/// One sensor axis of one group.
#[derive(Clone, Debug, PartialEq)]
pub struct Column {
    /// Group number (the `SS` of the name).
    pub group: usize,
    /// Gyro or accelerometer.
    pub kind: SensorKind,
    /// 0, 1, 2 for x, y, z.
    pub axis: usize,
    /// Samples, °/s or g.
    pub data: Vec<f64>,
}

impl Column {
    /// The interchange name, e.g. `g03z`.
    pub fn name(&self) -> String {
        column_name(self.kind, self.group, self.axis)
    }
}

/// The equal-weight cluster mean of one sensor axis over the groups, row by row (what `allan::recording::cluster_mean` computes
/// from a recording; a reader that streams the file can compute it without keeping every column).
#[derive(Clone, Debug, PartialEq)]
pub struct AxisMean {
    /// Gyro or accelerometer.
    pub kind: SensorKind,
    /// 0, 1, 2 for x, y, z.
    pub axis: usize,
    /// Groups averaged.
    pub members: usize,
    /// The mean, °/s or g, one value per sample.
    pub data: Vec<f64>,
}

/// `g03z` for (Gyro, 3, 2).
pub fn column_name(kind: SensorKind, group: usize, axis: usize) -> String {
    format!(
        "{}{:02}{}",
        kind.prefix(),
        group,
        AXIS_NAMES.get(axis).copied().unwrap_or('?')
    )
}

/// Parses `g03z` → (Gyro, 3, 2).
pub fn parse_column_name(name: &str) -> Option<(SensorKind, usize, usize)> {
    let kind = match name.chars().next()? {
        'g' => SensorKind::Gyro,
        'a' => SensorKind::Accel,
        _ => return None,
    };
    let axis = AXIS_NAMES.iter().position(|&c| name.ends_with(c))?;
    let digits = name.get(1..name.len() - 1)?;
    if digits.is_empty() || !digits.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    Some((kind, digits.parse().ok()?, axis))
}

/// A recording: time, optional temperature, sensor columns (sorted by kind, group, axis).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Recording {
    /// Sample times, s.
    pub t_s: Vec<f64>,
    /// Board temperature, °C.
    pub temp_c: Option<Vec<f64>>,
    /// Sensor columns.
    pub columns: Vec<Column>,
}

impl Recording {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.t_s.len()
    }

    /// No samples.
    pub fn is_empty(&self) -> bool {
        self.t_s.is_empty()
    }

    /// The sample interval: median of the time differences (s); `None` with fewer than 2 samples.
    pub fn sample_interval_s(&self) -> Option<f64> {
        let mut d: Vec<f64> = self
            .t_s
            .windows(2)
            .map(|w| w[1] - w[0])
            .filter(|d| d.is_finite())
            .collect();
        if d.is_empty() {
            return None;
        }
        let mid = d.len() / 2;
        // The middle element of the sorted differences, found in linear time.
        d.select_nth_unstable_by(mid, f64::total_cmp);
        d.get(mid).copied().filter(|&x| x > 0.0)
    }

    /// A recording from columns in group order — group 0's gyro x y z (°/s) and accel x y z (g), then group 1's, … —
    /// sorted as the CSV reader sorts them; no temperature.
    pub fn from_group_columns(t_s: Vec<f64>, columns: Vec<Vec<f64>>) -> Recording {
        Self::from_indexed_columns(t_s, columns.into_iter().enumerate())
    }

    /// A recording from `(k, data)` pairs, `k` a sensor column's index in group order (as in
    /// [`Self::from_group_columns`]; any subset, any order), sorted as the CSV reader sorts them; no temperature.
    pub fn from_indexed_columns(
        t_s: Vec<f64>,
        columns: impl IntoIterator<Item = (usize, Vec<f64>)>,
    ) -> Recording {
        let mut columns: Vec<Column> = columns
            .into_iter()
            .map(|(k, data)| Column {
                group: k / 6,
                kind: if k % 6 < 3 {
                    SensorKind::Gyro
                } else {
                    SensorKind::Accel
                },
                axis: k % 3,
                data,
            })
            .collect();
        columns.sort_by_key(|c| (c.kind, c.group, c.axis));
        Recording {
            t_s,
            temp_c: None,
            columns,
        }
    }

    /// Column by name.
    pub fn column(&self, name: &str) -> Option<&Column> {
        self.columns.iter().find(|c| c.name() == name)
    }

    /// The columns of one sensor kind and axis, in file order (one per group that has it).
    pub fn axis_columns(&self, kind: SensorKind, axis: usize) -> impl Iterator<Item = &Column> {
        self.columns
            .iter()
            .filter(move |c| c.kind == kind && c.axis == axis)
    }

    /// The column of one sensor kind, group and axis.
    pub fn find(&self, kind: SensorKind, group: usize, axis: usize) -> Option<&Column> {
        self.axis_columns(kind, axis).find(|c| c.group == group)
    }

    /// Groups present, sorted.
    pub fn groups(&self) -> Vec<usize> {
        let mut g: Vec<usize> = self.columns.iter().map(|c| c.group).collect();
        g.sort_unstable();
        g.dedup();
        g
    }

    /// Keeps samples with `start_s <= t < end_s`.
    pub fn window(&self, start_s: f64, end_s: f64) -> Recording {
        let keep: Vec<bool> = self
            .t_s
            .iter()
            .map(|&t| t >= start_s && t < end_s)
            .collect();
        let pick = |v: &[f64]| {
            v.iter()
                .zip(&keep)
                .filter(|(_, k)| **k)
                .map(|(x, _)| *x)
                .collect::<Vec<f64>>()
        };
        Recording {
            t_s: pick(&self.t_s),
            temp_c: self.temp_c.as_deref().map(pick),
            columns: self
                .columns
                .iter()
                .map(|c| Column {
                    data: pick(&c.data),
                    ..c.clone()
                })
                .collect(),
        }
    }
}
