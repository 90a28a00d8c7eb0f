//! Image input and output (SPEC §13): `.npy`, TIFF, PNG, PGM, ESRI ASCII grid.
//! NaN and nodata become the [`Field`] mask.

mod atomic;

pub use atomic::write_atomic;

use std::path::Path;

use ndarray::Array2;
use ndarray_npy::{ReadNpyExt, WriteNpyExt};

use crate::error::{Error, Result};
use crate::field::Field;

/// Reads an image, choosing the format from the extension.
///
/// **Errors** name the file and the problem (missing, unknown format,
/// corrupt, not 2D, empty).
pub fn read_field(path: &Path) -> Result<Field> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    match ext.as_str() {
        "npy" => read_npy(path),
        _ => Err(Error::format(
            path,
            format!("unknown image format `.{ext}` (supported: .npy)"),
        )),
    }
}

fn read_npy(path: &Path) -> Result<Field> {
    let file = std::fs::File::open(path).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })?;
    let r = std::io::BufReader::new(file);
    let data = Array2::<f64>::read_npy(r)
        .or_else(|_| {
            let f = std::fs::File::open(path).map_err(|e| e.to_string())?;
            Array2::<f32>::read_npy(std::io::BufReader::new(f))
                .map(|a| a.mapv(|v| v as f64))
                .map_err(|e| e.to_string())
        })
        .map_err(|e| Error::format(path, format!("not a 2D float .npy array: {e}")))?;
    if data.is_empty() {
        return Err(Error::format(path, "empty image"));
    }
    Ok(Field::new(data))
}

/// Writes a 2D array as float64 `.npy` (atomically).
pub fn write_npy(path: &Path, a: &Array2<f64>) -> Result<()> {
    let mut buf = Vec::new();
    a.write_npy(&mut buf)
        .map_err(|e| Error::format(path, format!("cannot encode .npy: {e}")))?;
    write_atomic(path, &buf)
}
