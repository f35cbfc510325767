//! NumPy `.npy` input: what numpy and allantools users already have, read as binary (no text parsing).
//!
//! The array is 2-D, `float64` or `float32` (either byte order, C or Fortran order), of shape `(samples, 1 + 6·G)`:
//! column 0 the time `t` in seconds, then per sensor group `gx gy gz` in °/s and `ax ay az` in g — the interchange
//! CSV's columns in its order, without `temp_c` (`np.save("rec.npy", np.column_stack([t, g00x, g00y, …]))`). As in
//! the CSV every value must be finite and `t` must increase; anything else is an error naming the row and column.

use super::csv::{Recording, SensorKind, column_name};
use std::io::Read;
use std::path::Path;

/// Sensor columns per group: gyro x y z, accel x y z.
const PER_GROUP: usize = 6;

/// Reads a `.npy` file (see module docs).
pub fn read(path: &Path) -> anyhow::Result<Recording> {
    let file = std::fs::File::open(path)
        .map_err(|e| anyhow::anyhow!("reading {}: {e}", path.display()))?;
    parse(std::io::BufReader::new(file)).map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))
}

/// Parses `.npy` bytes from `r` (see module docs); the error says what is wrong and where.
pub fn parse(r: impl Read) -> Result<Recording, String> {
    let npy = npyz::NpyFile::new(r).map_err(|e| format!("not a readable .npy file: {e}"))?;
    let (rows, cols) = match npy.shape() {
        &[rows, cols] => (rows, cols),
        s => {
            return Err(format!(
                "expected a 2-D array (samples, 1 + 6·groups), found shape {s:?}"
            ));
        }
    };
    let (rows, cols) = (usize::try_from(rows), usize::try_from(cols));
    let (Ok(rows), Ok(cols)) = (rows, cols) else {
        return Err("the array is too large for this machine".into());
    };
    if cols < 1 + PER_GROUP || (cols - 1) % PER_GROUP != 0 {
        return Err(format!(
            "expected 1 + 6·groups columns (t, then gx gy gz ax ay az per group), found {cols}"
        ));
    }
    if rows == 0 {
        return Err("no samples: the array has no rows".into());
    }
    let fortran = npy.order() == npyz::Order::Fortran;
    let dtype = npy.dtype();
    let flat: Vec<f64> = match npy.try_data::<f64>() {
        Ok(data) => data.collect::<std::io::Result<_>>(),
        Err(npy) => match npy.data::<f32>() {
            Ok(data) => data
                .map(|x| x.map(f64::from))
                .collect::<std::io::Result<_>>(),
            Err(_) => {
                return Err(format!(
                    "expected float64 or float32 values, found {dtype:?}"
                ));
            }
        },
    }
    .map_err(|e| format!("reading the data: {e}"))?;
    if flat.len() != rows * cols {
        return Err(format!(
            "the data holds {} values, the shape {rows} × {cols} says {}",
            flat.len(),
            rows * cols
        ));
    }
    // Column j as a vector, from either storage order.
    let column = |j: usize| -> Vec<f64> {
        if fortran {
            flat.get(j * rows..(j + 1) * rows)
                .unwrap_or_default()
                .to_vec()
        } else {
            flat.iter().skip(j).step_by(cols).copied().collect()
        }
    };
    let name = |j: usize| {
        if j == 0 {
            "t".to_string()
        } else {
            let k = j - 1;
            let kind = if k % PER_GROUP < 3 {
                SensorKind::Gyro
            } else {
                SensorKind::Accel
            };
            column_name(kind, k / PER_GROUP, k % 3)
        }
    };
    let mut all: Vec<Vec<f64>> = (0..cols).map(column).collect();
    for (j, c) in all.iter().enumerate() {
        if let Some(i) = c.iter().position(|x| !x.is_finite()) {
            return Err(format!(
                "row {i}, column {j} ({}): {} is not a finite number",
                name(j),
                c.get(i).copied().unwrap_or(f64::NAN)
            ));
        }
    }
    let t_s = all.remove(0);
    if let Some(i) = t_s.windows(2).position(|w| w.get(1) <= w.first()) {
        return Err(format!(
            "row {}, column 0 (t): {} s is not after {} s on row {i}: t must increase",
            i + 1,
            t_s.get(i + 1).copied().unwrap_or(f64::NAN),
            t_s.get(i).copied().unwrap_or(f64::NAN)
        ));
    }
    Ok(Recording::from_group_columns(t_s, all))
}

#[cfg(test)]
mod tests;
