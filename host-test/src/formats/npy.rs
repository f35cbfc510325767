//! NumPy `.npy` input: what numpy and allantools users already have, read as binary (no text parsing).
//!
//! The array is 2-D of shape `(samples, 1 + 6·G)`, C or Fortran order: column 0 the time `t` in seconds, then per
//! sensor group `gx gy gz` in °/s and `ax ay az` in g — the interchange CSV's columns in its order, without `temp_c`
//! (`np.save("rec.npy", np.column_stack([t, g00x, g00y, …]))`). As in the CSV every value must be finite and `t`
//! must increase; anything else is an error naming the row and column.
//!
//! Element types: little-endian `float64` and `float32` are read as they are; little-endian (or single-byte)
//! integers and booleans are converted to `float64`, and [`NpyArray::conversion`] says so. Big-endian arrays are
//! refused (`arr.astype('<f8')` converts them), and so are object arrays (pickled Python objects: reading them
//! would mean running a pickle), complex, string, date and structured arrays.
//!
//! How it is read: the header is parsed by the `npyz` crate; the data is then read once, straight from the file at
//! computed offsets (`pread`), in blocks of about 256 KiB of the array, on all cores, and each block is decoded into
//! only the requested columns' final vectors (a `float64` column of a Fortran-order array is read directly into its
//! vector: its bytes are its values). Nothing else holds the array: the peak memory is the requested columns plus
//! one block per core. The values are checked while the block is still in the cache. Not mapped: `host-test`
//! forbids `unsafe`, and `memmap2::Mmap::map` is `unsafe` (the file may change under the mapping); besides, a
//! mapped C-order array stays resident next to the columns taken out of it, which doubles the peak memory.

use super::csv::{AxisMean, Recording, SensorKind, column_name};
use npyz::{DType, TypeChar};
use rayon::prelude::*;
use std::path::{Path, PathBuf};

/// Why a `.npy` array is refused, naming the row and column where a value is at fault.
#[derive(Debug, thiserror::Error)]
pub enum NpyError {
    /// The file could not be opened or its size read.
    #[error("reading {}", path.display())]
    Open {
        /// The file.
        path: PathBuf,
        /// The cause.
        #[source]
        source: std::io::Error,
    },
    /// An error in the file `path`.
    #[error("{}", path.display())]
    InFile {
        /// The file.
        path: PathBuf,
        /// What is wrong in it.
        #[source]
        source: Box<NpyError>,
    },
    /// Not a `.npy` file: the magic, the version or the header's length is wrong.
    #[error("not a readable .npy file: {0}")]
    NotNpy(String),
    /// The header could not be read or parsed.
    #[error("not a readable .npy file")]
    Header(#[source] std::io::Error),
    /// Not a 2-D array.
    #[error("expected a 2-D array (samples, 1 + 6·groups), found shape {0:?}")]
    Shape(Vec<u64>),
    /// The shape does not fit this machine's address space.
    #[error("the array is too large for this machine")]
    TooLarge,
    /// A structured array (its dtype).
    #[error("a structured array (dtype {0}) is not read: expected a plain 2-D float64 array")]
    Structured(String),
    /// An object array.
    #[error(
        "an object array (dtype object, pickled Python objects) is not read: save the values as float64 \
         (`arr.astype('<f8')`)"
    )]
    Object,
    /// A big-endian array (its dtype).
    #[error(
        "a big-endian array (dtype {0}) is not read: save it little-endian (`arr.astype('<f8')`)"
    )]
    BigEndian(String),
    /// Any other element type (its dtype).
    #[error(
        "dtype {0} is not read: expected float64 or float32 values (integers and booleans are converted)"
    )]
    DType(String),
    /// The number of columns is not 1 + 6·groups.
    #[error("expected 1 + 6·groups columns (t, then gx gy gz ax ay az per group), found {0}")]
    Columns(usize),
    /// The array has no rows.
    #[error("no samples: the array has no rows")]
    NoRows,
    /// The file is shorter than its shape says.
    #[error(
        "reading the data: the file holds {have} bytes after the header, the shape {rows} × {cols} of {descr} \
         needs {need}"
    )]
    Truncated {
        /// Bytes after the header.
        have: u64,
        /// Rows of the shape.
        rows: usize,
        /// Columns of the shape.
        cols: usize,
        /// The dtype.
        descr: String,
        /// Bytes the shape needs.
        need: usize,
    },
    /// Reading the data failed.
    #[error("reading the data")]
    Data(#[source] std::io::Error),
    /// A value that is not finite (the first in column order).
    #[error("row {row}, column {column} ({name}): {value} is not a finite number")]
    NotFinite {
        /// Row (from 0).
        row: usize,
        /// Array column (0 is `t`).
        column: usize,
        /// The column's interchange name.
        name: String,
        /// The value.
        value: f64,
    },
    /// `t` does not increase.
    #[error("row {row}, column 0 (t): {t} s is not after {previous} s on row {}: t must increase", row - 1)]
    TimeNotIncreasing {
        /// Row (from 0).
        row: usize,
        /// Its time, s.
        t: f64,
        /// The previous row's time, s.
        previous: f64,
    },
}

impl NpyError {
    /// This error, in the file `path`.
    pub fn in_file(self, path: &Path) -> NpyError {
        NpyError::InFile {
            path: path.to_path_buf(),
            source: Box::new(self),
        }
    }
}

/// Sensor columns per group: gyro x y z, accel x y z.
const PER_GROUP: usize = 6;

/// Bytes of the array read and decoded at once by one core (a block stays in the L2 cache).
const BLOCK_BYTES: usize = 1 << 18;

/// The first bytes of every `.npy` file.
const MAGIC: &[u8] = b"\x93NUMPY";

/// Where the bytes are: an open file (read at offsets) or a buffer.
enum Source<'a> {
    File(std::fs::File, u64),
    Bytes(&'a [u8]),
}

impl Source<'_> {
    fn len(&self) -> u64 {
        match self {
            Source::File(_, len) => *len,
            Source::Bytes(b) => b.len() as u64,
        }
    }

    /// Fills `buf` from `offset`; the caller has checked that the bytes exist.
    fn read_at(&self, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
        match self {
            Source::File(f, _) => std::os::unix::fs::FileExt::read_exact_at(f, buf, offset),
            Source::Bytes(b) => {
                let part = usize::try_from(offset)
                    .ok()
                    .and_then(|o| b.get(o..o.checked_add(buf.len())?))
                    .ok_or(std::io::ErrorKind::UnexpectedEof)?;
                buf.copy_from_slice(part);
                Ok(())
            }
        }
    }
}

/// The element types read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Elem {
    F8,
    F4,
    /// Signed integer of 1, 2, 4 or 8 bytes.
    Int(usize),
    /// Unsigned integer of 1, 2, 4 or 8 bytes.
    Uint(usize),
    Bool,
}

impl Elem {
    fn size(self) -> usize {
        match self {
            Elem::F8 => 8,
            Elem::F4 => 4,
            Elem::Int(n) | Elem::Uint(n) => n,
            Elem::Bool => 1,
        }
    }

    /// The element type of a dtype, or why it is refused.
    fn of(dtype: &DType) -> Result<Elem, NpyError> {
        let DType::Plain(ts) = dtype else {
            return Err(NpyError::Structured(dtype.descr()));
        };
        let (tc, size) = (ts.type_char(), ts.size_field());
        if tc == TypeChar::Object {
            return Err(NpyError::Object);
        }
        if ts.endianness() == npyz::Endianness::Big && size > 1 {
            return Err(NpyError::BigEndian(ts.to_string()));
        }
        match (tc, size) {
            (TypeChar::Float, 8) => Ok(Elem::F8),
            (TypeChar::Float, 4) => Ok(Elem::F4),
            (TypeChar::Int, 1 | 2 | 4 | 8) => Ok(Elem::Int(size as usize)),
            (TypeChar::Uint, 1 | 2 | 4 | 8) => Ok(Elem::Uint(size as usize)),
            (TypeChar::Bool, 1) => Ok(Elem::Bool),
            _ => Err(NpyError::DType(ts.to_string())),
        }
    }

    /// Decodes a block of whole rows of a C-order array, `rows` = `bytes` with `cols` elements per row, into
    /// `chunks[k]` = array column `wanted[k]` of those rows.
    fn decode_rows(self, rows: &[u8], cols: usize, wanted: &[usize], chunks: &mut [&mut [f64]]) {
        match self {
            Elem::F8 => transpose::<8>(rows, cols, wanted, chunks, f64::from_le_bytes),
            Elem::F4 => transpose::<4>(rows, cols, wanted, chunks, |b| {
                f64::from(f32::from_le_bytes(b))
            }),
            Elem::Int(1) => transpose::<1>(rows, cols, wanted, chunks, |b| {
                f64::from(i8::from_le_bytes(b))
            }),
            Elem::Int(2) => transpose::<2>(rows, cols, wanted, chunks, |b| {
                f64::from(i16::from_le_bytes(b))
            }),
            Elem::Int(4) => transpose::<4>(rows, cols, wanted, chunks, |b| {
                f64::from(i32::from_le_bytes(b))
            }),
            // The nearest float64 (exact up to 2^53).
            Elem::Int(_) => {
                transpose::<8>(rows, cols, wanted, chunks, |b| i64::from_le_bytes(b) as f64)
            }
            Elem::Uint(1) | Elem::Bool => {
                transpose::<1>(rows, cols, wanted, chunks, |b| f64::from(b[0]))
            }
            Elem::Uint(2) => transpose::<2>(rows, cols, wanted, chunks, |b| {
                f64::from(u16::from_le_bytes(b))
            }),
            Elem::Uint(4) => transpose::<4>(rows, cols, wanted, chunks, |b| {
                f64::from(u32::from_le_bytes(b))
            }),
            Elem::Uint(_) => {
                transpose::<8>(rows, cols, wanted, chunks, |b| u64::from_le_bytes(b) as f64)
            }
        }
    }

    /// Decodes consecutive elements (`bytes`, one column of a Fortran-order array) into `out`.
    fn decode_column(self, bytes: &[u8], out: &mut [f64]) {
        let mut one = [&mut *out];
        // A column is a C-order array of one column.
        self.decode_rows(bytes, 1, &[0], &mut one);
    }
}

/// `chunks[k][i] = f(element (i, wanted[k]))` of `rows`, a C-order block of `N`-byte elements, `cols` per row. Tiles
/// of 8 rows: their bytes stay in the L1 cache while each output column gets a whole cache line.
fn transpose<const N: usize>(
    rows: &[u8],
    cols: usize,
    wanted: &[usize],
    chunks: &mut [&mut [f64]],
    f: impl Fn([u8; N]) -> f64,
) {
    const TILE: usize = 8;
    let row_bytes = cols * N;
    for (t, tile) in rows.chunks(TILE * row_bytes).enumerate() {
        for (&j, chunk) in wanted.iter().zip(chunks.iter_mut()) {
            let out = chunk.get_mut(t * TILE..).unwrap_or_default();
            for (o, row) in out.iter_mut().zip(tile.chunks_exact(row_bytes)) {
                *o = row
                    .get(j * N..)
                    .and_then(|e| e.first_chunk::<N>())
                    .map_or(f64::NAN, |b| f(*b));
            }
        }
    }
}

/// An opened `.npy` array: its header checked, its data not yet read.
pub struct NpyArray<'a> {
    src: Source<'a>,
    rows: usize,
    cols: usize,
    fortran: bool,
    elem: Elem,
    descr: String,
    /// Byte offset of the first element.
    data_offset: u64,
}

impl NpyArray<'static> {
    /// Opens a `.npy` file and checks its header (see module docs).
    pub fn open(path: &Path) -> Result<NpyArray<'static>, NpyError> {
        let open = |source| NpyError::Open {
            path: path.to_path_buf(),
            source,
        };
        let file = std::fs::File::open(path).map_err(open)?;
        let len = file.metadata().map_err(open)?.len();
        NpyArray::new(Source::File(file, len)).map_err(|e| e.in_file(path))
    }
}

impl<'a> NpyArray<'a> {
    /// A `.npy` file's bytes in memory, its header checked (see module docs).
    pub fn from_bytes(bytes: &'a [u8]) -> Result<NpyArray<'a>, NpyError> {
        NpyArray::new(Source::Bytes(bytes))
    }

    fn new(src: Source<'a>) -> Result<NpyArray<'a>, NpyError> {
        let unreadable = |what: &str| NpyError::NotNpy(what.into());
        // Magic, version, header length: 10 bytes in version 1, 12 in versions 2 and 3.
        let mut pre = [0u8; 12];
        let n = src.len().min(12) as usize;
        src.read_at(&mut pre[..n], 0).map_err(NpyError::Header)?;
        if !pre.starts_with(MAGIC) {
            return Err(unreadable("it does not start with \\x93NUMPY"));
        }
        let text = match pre[6] {
            1 => u64::from(u16::from_le_bytes([pre[8], pre[9]])) + 10,
            2 | 3 => u64::from(u32::from_le_bytes([pre[8], pre[9], pre[10], pre[11]])) + 12,
            v => return Err(unreadable(&format!("unknown format version {v}"))),
        };
        if text > src.len() {
            return Err(unreadable("the file ends inside the header"));
        }
        let mut head = vec![0u8; text as usize];
        src.read_at(&mut head, 0).map_err(NpyError::Header)?;
        let header = npyz::NpyHeader::from_reader(&head[..]).map_err(NpyError::Header)?;
        let (rows, cols) = match header.shape() {
            &[rows, cols] => (rows, cols),
            s => return Err(NpyError::Shape(s.to_vec())),
        };
        let (Ok(rows), Ok(cols)) = (usize::try_from(rows), usize::try_from(cols)) else {
            return Err(NpyError::TooLarge);
        };
        let dtype = header.dtype();
        let elem = Elem::of(&dtype)?;
        // `<f8`, as numpy prints it (`DType::descr` quotes it, as in the header).
        let descr = match &dtype {
            DType::Plain(ts) => ts.to_string(),
            d => d.descr(),
        };
        if cols < 1 + PER_GROUP || (cols - 1) % PER_GROUP != 0 {
            return Err(NpyError::Columns(cols));
        }
        if rows == 0 {
            return Err(NpyError::NoRows);
        }
        let need = rows
            .checked_mul(cols)
            .and_then(|n| n.checked_mul(elem.size()))
            .ok_or(NpyError::TooLarge)?;
        let have = src.len() - text;
        if have < need as u64 {
            return Err(NpyError::Truncated {
                have,
                rows,
                cols,
                descr,
                need,
            });
        }
        Ok(NpyArray {
            src,
            rows,
            cols,
            fortran: header.order() == npyz::Order::Fortran,
            elem,
            descr,
            data_offset: text,
        })
    }

    /// Samples (rows).
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Sensor groups (each 6 columns after `t`).
    pub fn groups(&self) -> usize {
        (self.cols - 1) / PER_GROUP
    }

    /// What was converted, when the values are not `float64` or `float32` (e.g. "int16 values converted to
    /// float64").
    pub fn conversion(&self) -> Option<String> {
        let what = match self.elem {
            Elem::F8 | Elem::F4 => return None,
            Elem::Int(n) => format!("int{}", 8 * n),
            Elem::Uint(n) => format!("uint{}", 8 * n),
            Elem::Bool => "bool".into(),
        };
        let exact = if matches!(self.elem, Elem::Int(8) | Elem::Uint(8)) {
            " (exact up to 2^53)"
        } else {
            ""
        };
        Some(format!(
            "{what} values (dtype {}) converted to float64{exact}",
            self.descr
        ))
    }

    /// The interchange name of array column `j` (`t`, `g00x`, …).
    fn name(j: usize) -> String {
        if j == 0 {
            return "t".into();
        }
        let k = j - 1;
        let kind = if k % PER_GROUP < 3 {
            SensorKind::Gyro
        } else {
            SensorKind::Accel
        };
        column_name(kind, k / PER_GROUP, k % 3)
    }

    /// The whole recording: `t` and every sensor column.
    pub fn recording(&self) -> Result<Recording, NpyError> {
        self.recording_of(&[])
    }

    /// The recording with only the named sensor columns (all when `names` is empty; names not in the array are
    /// left out, for the caller to report). Only those columns and `t` are ever materialised.
    pub fn recording_of(&self, names: &[String]) -> Result<Recording, NpyError> {
        let wanted = self.wanted(names);
        let (data, _) = self.read_columns(&wanted, false)?;
        Ok(Self::assemble(&wanted, data))
    }

    /// As [`recording_of`](Self::recording_of), and in the same pass the cluster mean of every axis over all
    /// groups (gyro x y z, then accel x y z), equal to `allan::recording::cluster_mean` of the whole recording bit for bit.
    pub fn recording_with_means(
        &self,
        names: &[String],
    ) -> Result<(Recording, Vec<AxisMean>), NpyError> {
        let wanted = self.wanted(names);
        let (data, means) = self.read_columns(&wanted, true)?;
        Ok((Self::assemble(&wanted, data), means))
    }

    /// Array columns to read: `t` and the named sensor columns (all when `names` is empty).
    fn wanted(&self, names: &[String]) -> Vec<usize> {
        std::iter::once(0)
            .chain((1..self.cols).filter(|&j| names.is_empty() || names.contains(&Self::name(j))))
            .collect()
    }

    /// The recording of array columns `wanted` (`t` first), their data `data` in the same order.
    fn assemble(wanted: &[usize], mut data: Vec<Vec<f64>>) -> Recording {
        let t_s = if data.is_empty() {
            Vec::new()
        } else {
            data.remove(0)
        };
        // Array column j ≥ 1 is sensor column j − 1 in group order.
        Recording::from_indexed_columns(t_s, wanted.iter().skip(1).map(|&j| j - 1).zip(data))
    }

    /// Reads array columns `wanted` (ascending, column 0 first) in one pass over the file, checked: every value
    /// read finite, `t` increasing. With `means`, also the cluster mean of every axis ([`AxisMean`]), from every
    /// sensor column (all are then read and checked, but only `wanted` are kept).
    fn read_columns(
        &self,
        wanted: &[usize],
        means: bool,
    ) -> Result<(Vec<Vec<f64>>, Vec<AxisMean>), NpyError> {
        let (rows, size) = (self.rows, self.elem.size());
        // Rows per block: ≈ BLOCK_BYTES of the array (C order: whole rows; Fortran order: of each column).
        let block_rows = if self.fortran {
            BLOCK_BYTES / size
        } else {
            BLOCK_BYTES / (self.cols * size)
        }
        .max(1);
        let mut out: Vec<Vec<f64>> = wanted.iter().map(|_| vec![0.0; rows]).collect();
        let mut mean_out: Vec<AxisMean> = if means {
            [SensorKind::Gyro, SensorKind::Accel]
                .into_iter()
                .flat_map(|kind| (0..3).map(move |axis| (kind, axis)))
                .map(|(kind, axis)| AxisMean {
                    kind,
                    axis,
                    members: self.groups(),
                    data: vec![0.0; rows],
                })
                .collect()
        } else {
            Vec::new()
        };
        // Task b: rows b·block_rows … of every output, as disjoint slices.
        let mut tasks: Vec<Vec<&mut [f64]>> = (0..rows.div_ceil(block_rows))
            .map(|_| Vec::with_capacity(out.len() + mean_out.len()))
            .collect();
        let outputs = out
            .iter_mut()
            .chain(mean_out.iter_mut().map(|m| &mut m.data));
        for col in outputs {
            for (task, chunk) in tasks.iter_mut().zip(col.chunks_mut(block_rows)) {
                task.push(chunk);
            }
        }
        // Read: the wanted columns, or every column when the means need them.
        let all: Vec<usize> = (0..self.cols).collect();
        let read: &[usize] = if means { &all } else { wanted };
        // The first value that is not finite, as (column, row, value): the message has always named the first in
        // column order.
        let bad = std::sync::Mutex::new(None::<(usize, usize, f64)>);
        tasks.into_par_iter().enumerate().try_for_each_init(
            || (Vec::new(), Vec::new()),
            |(buf, scratch): &mut (Vec<u8>, Vec<f64>), (b, mut chunks)| {
                let row0 = b * block_rows;
                let n = chunks.first().map_or(0, |c| c.len());
                let (kept, avg) = chunks.split_at_mut(wanted.len());
                if !means {
                    self.read_block(row0, read, kept, buf)?;
                    note_bad(&bad, read, kept, row0);
                } else if wanted.len() == self.cols {
                    // Every column is kept: the means from the block just read, while it is in the cache.
                    self.read_block(row0, read, kept, buf)?;
                    note_bad(&bad, read, kept, row0);
                    self.block_means(kept, avg);
                } else {
                    // Every column of the block into `scratch`, then the wanted ones and the means from it.
                    scratch.resize(n * self.cols, 0.0);
                    let mut cols: Vec<&mut [f64]> = scratch.chunks_mut(n).collect();
                    self.read_block(row0, read, &mut cols, buf)?;
                    note_bad(&bad, read, &cols, row0);
                    for (&j, chunk) in wanted.iter().zip(kept.iter_mut()) {
                        chunk.copy_from_slice(cols[j]);
                    }
                    self.block_means(&cols, avg);
                }
                Ok::<_, NpyError>(())
            },
        )?;
        if let Some((j, i, x)) = bad.into_inner().unwrap_or_else(|e| e.into_inner()) {
            return Err(NpyError::NotFinite {
                row: i,
                column: j,
                name: Self::name(j),
                value: x,
            });
        }
        let t = out.first().map_or(&[][..], |t| t.as_slice());
        if let Some(i) = t.windows(2).position(|w| w[1] <= w[0]) {
            return Err(NpyError::TimeNotIncreasing {
                row: i + 1,
                t: t[i + 1],
                previous: t[i],
            });
        }
        Ok((out, mean_out))
    }

    /// The cluster means of a block: `avg[m]` = the mean over the groups of `cols[1 + 6·g + m]` (every array
    /// column of the block, `t` first), added column by column in group order, then divided: the sums
    /// `allan::recording::cluster_mean` makes.
    fn block_means<C: AsRef<[f64]>>(&self, cols: &[C], avg: &mut [&mut [f64]]) {
        let groups = self.groups();
        for (m, chunk) in avg.iter_mut().enumerate() {
            for g in 0..groups {
                let c = cols
                    .get(1 + PER_GROUP * g + m)
                    .map_or(&[][..], |c| c.as_ref());
                if g == 0 {
                    chunk.copy_from_slice(c);
                } else {
                    add_to(chunk, c);
                }
            }
            divide(chunk, groups as f64);
        }
    }

    /// Fills `chunks[k]` (rows `row0 …` of array column `wanted[k]`) from the file; `buf` is this core's block.
    fn read_block(
        &self,
        row0: usize,
        wanted: &[usize],
        chunks: &mut [&mut [f64]],
        buf: &mut Vec<u8>,
    ) -> Result<(), NpyError> {
        let size = self.elem.size();
        let n = chunks.first().map_or(0, |c| c.len());
        let io = NpyError::Data;
        let at = |elem: usize| self.data_offset + (elem * size) as u64;
        if self.fortran {
            for (&j, chunk) in wanted.iter().zip(chunks.iter_mut()) {
                let first = at(j * self.rows + row0);
                if self.elem == Elem::F8 && cfg!(target_endian = "little") {
                    // The column's bytes are its values: read straight into the output.
                    self.src
                        .read_at(bytemuck::cast_slice_mut(chunk), first)
                        .map_err(io)?;
                } else {
                    buf.resize(n * size, 0);
                    self.src.read_at(buf, first).map_err(io)?;
                    self.elem.decode_column(buf, chunk);
                }
            }
        } else {
            buf.resize(n * self.cols * size, 0);
            self.src.read_at(buf, at(row0 * self.cols)).map_err(io)?;
            self.elem.decode_rows(buf, self.cols, wanted, chunks);
        }
        Ok(())
    }
}

/// Keeps in `bad` the first value that is not finite in column order: `cols[k]` holds rows `row0 …` of array
/// column `index[k]`.
fn note_bad<C: AsRef<[f64]>>(
    bad: &std::sync::Mutex<Option<(usize, usize, f64)>>,
    index: &[usize],
    cols: &[C],
    row0: usize,
) {
    for (&j, c) in index.iter().zip(cols) {
        let c = c.as_ref();
        if all_finite(c) {
            continue;
        }
        let Some(i) = c.iter().position(|x| !x.is_finite()) else {
            continue;
        };
        let mut first = bad.lock().unwrap_or_else(|e| e.into_inner());
        if first.is_none_or(|(j0, i0, _)| (j, row0 + i) < (j0, i0)) {
            *first = Some((j, row0 + i, c[i]));
        }
        return;
    }
}

/// Whether every value is finite. `fold`, not `all`: no early exit, so the common case (all finite) is vectorised;
/// compiled also for AVX2 and chosen at run time.
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn all_finite(c: &[f64]) -> bool {
    c.iter().fold(true, |ok, x| ok & x.is_finite())
}

/// `sums[i] += c[i]`; compiled also for AVX2 (the same additions, the same bits).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn add_to(sums: &mut [f64], c: &[f64]) {
    sums.iter_mut().zip(c).for_each(|(s, x)| *s += x);
}

/// `sums[i] /= n`; compiled also for AVX2 (the same divisions, the same bits).
#[multiversion::multiversion(targets("x86_64+avx2"))]
fn divide(sums: &mut [f64], n: f64) {
    sums.iter_mut().for_each(|s| *s /= n);
}

/// Reads a whole `.npy` file (see module docs).
pub fn read(path: &Path) -> Result<Recording, NpyError> {
    NpyArray::open(path)?
        .recording()
        .map_err(|e| e.in_file(path))
}

/// Parses a whole `.npy` file's bytes (see module docs); the error says what is wrong and where.
pub fn parse(bytes: &[u8]) -> Result<Recording, NpyError> {
    NpyArray::from_bytes(bytes)?.recording()
}

#[cfg(test)]
mod tests;
