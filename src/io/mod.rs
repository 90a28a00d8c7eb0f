//! Image input and output (SPEC §13). NaN and nodata become the [`Field`] mask.
//!
//! The format comes from the file extension (case-insensitive):
//!
//! | extension | reads | writes |
//! |---|---|---|
//! | `.npy` | 2D, any integer or float dtype (`i1`..`u8`, `f2`, `f4`, `f8`), either byte order, C or Fortran order | float64 |
//! | `.tif`, `.tiff` | one band; 8/16/32/64-bit integer, 16/32/64-bit float; uncompressed, LZW, deflate, PackBits, JPEG, CCITT fax or ZSTD; GDAL nodata tag (42113) honoured; GeoTIFF pixel spacing read by [`read_pixel_spacing`] | float32, NaN kept (values beyond its range refused) |
//! | `.png` | grey 1..16 bit (raw integer values), grey+alpha (alpha 0 = missing); RGB(A) and palette converted to luminance with a warning; a `<stem>.json` sidecar applies `value = png*scale + offset` and its nodata | 16-bit grey + sidecar JSON |
//! | `.pgm` | P5 (binary, 8 or 16 bit) and P2 (ASCII), raw integer values | — |
//! | `.asc` | ESRI ASCII grid; header keys case-insensitive; `NODATA_value` honoured; first row = north; `cellsize` (units from the `.prj`) read by [`read_pixel_spacing`] | — |
//!
//! Every error names the file and the problem; truncated or corrupt input
//! gives an error, never a panic. Every output goes through
//! [`write_atomic`], so an error never leaves a half-written file.
//!
//! # Example
//!
//! ```
//! use ndarray::Array2;
//! # fn main() -> wtmm::Result<()> {
//! let dir = std::env::temp_dir().join(format!("wtmm-io-doc-{}", std::process::id()));
//! std::fs::create_dir_all(&dir).unwrap();
//! let mut a = Array2::from_shape_fn((4, 5), |(y, x)| (5 * y + x) as f64);
//! a[[1, 2]] = f64::NAN; // a missing pixel
//! let path = dir.join("dem.npy");
//! wtmm::io::write_npy(&path, &a)?;
//! let field = wtmm::io::read_field(&path)?;
//! assert_eq!(field.dim(), (4, 5));
//! assert_eq!(field.missing_count(), 1);
//! // a file that is no image is an error naming it, not a panic
//! std::fs::write(dir.join("bad.npy"), b"not an array").unwrap();
//! let e = wtmm::io::read_field(dir.join("bad.npy")).unwrap_err();
//! assert!(e.to_string().contains("bad.npy"), "{e}");
//! std::fs::remove_dir_all(&dir).unwrap();
//! # Ok(())
//! # }
//! ```

mod asc;
mod atomic;
mod georef;
mod npy;
mod pgm;
mod png;
mod tiff;
mod tiff_lzw;

pub use atomic::{
    OutputBatch, Protected, file_identity, is_foreign_temp, outputs_committed, protect,
    remove_temporaries, write_atomic, write_json, write_json_compact,
};
pub use georef::{PixelSpacing, degrees_to_metres, unit_metres, unit_ratio};
pub use png::{PNG16_NODATA, Png16Mapping};

use std::path::{Path, PathBuf};

use ndarray::Array2;
use ndarray_npy::WriteNpyExt;

use crate::error::{Error, Result};
use crate::field::Field;

/// An image file format known to the readers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    /// NumPy `.npy`.
    Npy,
    /// TIFF (`.tif`, `.tiff`), including GeoTIFF.
    Tiff,
    /// PNG.
    Png,
    /// Netpbm greymap (`.pgm`).
    Pgm,
    /// ESRI ASCII grid (`.asc`).
    Asc,
}

impl ImageFormat {
    /// The format for a path's extension (case-insensitive), `None` if unknown.
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "npy" => ImageFormat::Npy,
            "tif" | "tiff" => ImageFormat::Tiff,
            "png" => ImageFormat::Png,
            "pgm" => ImageFormat::Pgm,
            "asc" => ImageFormat::Asc,
            _ => return None,
        })
    }

    /// Short lower-case name: `npy`, `tiff`, `png`, `pgm`, `asc`.
    pub fn name(self) -> &'static str {
        match self {
            ImageFormat::Npy => "npy",
            ImageFormat::Tiff => "tiff",
            ImageFormat::Png => "png",
            ImageFormat::Pgm => "pgm",
            ImageFormat::Asc => "asc",
        }
    }
}

impl std::fmt::Display for ImageFormat {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

/// What a reader found besides the values.
#[derive(Clone, Debug, PartialEq)]
pub struct ReadInfo {
    /// The format read.
    pub format: ImageFormat,
    /// The stored sample type, e.g. `f4`, `<i2`, `u16`, `u8 RGB`, `text`.
    pub dtype: String,
    /// The PNG sidecar JSON that was applied, if any.
    pub sidecar: Option<PathBuf>,
    /// Things the caller may want to tell the user (the library never prints),
    /// e.g. a colour image converted to luminance.
    pub warnings: Vec<String>,
}

impl ReadInfo {
    fn new(format: ImageFormat, dtype: impl Into<String>) -> Self {
        ReadInfo {
            format,
            dtype: dtype.into(),
            sidecar: None,
            warnings: Vec::new(),
        }
    }
}

const SUPPORTED_READ: &str = ".npy, .tif, .tiff, .png, .pgm, .asc";
const SUPPORTED_WRITE: &str = ".npy, .tif, .tiff, .png";

/// Reads an image, choosing the format from the extension. The readers'
/// warnings (a colour PNG read as luminance, trailing bytes, a TIFF nodata
/// tag that could not be read) are dropped: [`read_field_with_info`]
/// returns them, as the command line prints them.
///
/// **Errors** name the file and the problem (missing, unknown format,
/// corrupt, not 2D, unsupported sample type, empty, a PNG sidecar key
/// that misspells one the reader uses).
pub fn read_field(path: impl AsRef<Path>) -> Result<Field> {
    read_field_with_info(path).map(|(field, _)| field)
}

/// `value` as a file of sample type `dtype` ([`ReadInfo::dtype`]) stores
/// it: rounded to 32- or 16-bit floats for such files (a float file holds
/// its nodata at its own precision: 0.1 reads back as 0.10000000149),
/// itself otherwise. For [`crate::Field::mask_value`].
pub fn as_stored(value: f64, dtype: &str) -> f64 {
    let t = dtype.trim_start_matches(['<', '>', '=', '|']);
    match t {
        "f4" | "f32" => value as f32 as f64,
        "f2" | "f16" => half::f16::from_f64(value).to_f64(),
        _ => value,
    }
}

/// Like [`read_field`], also returning the format, the stored sample type and
/// any warnings.
pub fn read_field_with_info(path: impl AsRef<Path>) -> Result<(Field, ReadInfo)> {
    let path = path.as_ref();
    let format = read_format(path)?;
    let (field, info) = match format {
        ImageFormat::Npy => npy::read(path)?,
        ImageFormat::Tiff => tiff::read(path)?,
        ImageFormat::Png => png::read(path)?,
        ImageFormat::Pgm => pgm::read(path)?,
        ImageFormat::Asc => asc::read(path)?,
    };
    let (ny, nx) = field.dim();
    if ny == 0 || nx == 0 {
        // Every reader checks this already; kept as the one guarantee callers rely on.
        return Err(Error::format(path, format!("empty image ({ny} x {nx})")));
    }
    Ok((field, info))
}

/// The size `[ny, nx]` of an image from its header alone, without decoding
/// its values: for what depends only on the sizes (a fit range), checked
/// before a long ensemble is read. The same size [`read_field`] gives.
///
/// **Errors** as [`read_field`] on a missing file, an unknown format, a
/// corrupt or unsupported header, an empty or too large image; a file
/// whose values are corrupt passes here and fails in [`read_field`].
pub fn read_shape(path: impl AsRef<Path>) -> Result<[usize; 2]> {
    let path = path.as_ref();
    let format = read_format(path)?;
    let (ny, nx) = match format {
        ImageFormat::Npy => npy::shape(path)?,
        ImageFormat::Tiff => tiff::shape(path)?,
        ImageFormat::Png => png::shape(path)?,
        ImageFormat::Pgm => pgm::shape(path)?,
        ImageFormat::Asc => asc::shape(path)?,
    };
    if ny == 0 || nx == 0 {
        return Err(Error::format(path, format!("empty image ({ny} x {nx})")));
    }
    Ok([ny, nx])
}

/// The pixel spacing `path` declares: a GeoTIFF's ModelPixelScale (or
/// affine ModelTransformation) with its GeoKeys' units, an ESRI grid's
/// `cellsize` (or `dx`, `dy`) with its `.prj`'s units, else a world file
/// beside a TIFF, PNG or PGM (`.tfw`, `.pgw`, `.wld`, ...) with the
/// `.prj`'s units. Geographic spacings (degrees) are given in metres at
/// the image's middle latitude on WGS84, and Web Mercator ones as ground
/// metres. `None` for npy and for files that declare none.
///
/// **Errors** on a missing or unreadable file or an unknown format; a
/// corrupt header gives `None` here and its error in [`read_field`].
pub fn read_pixel_spacing(path: impl AsRef<Path>) -> Result<Option<PixelSpacing>> {
    let path = path.as_ref();
    let format = read_format(path)?;
    std::fs::metadata(path).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })?;
    let own = match format {
        ImageFormat::Tiff => tiff::pixel(path)?,
        ImageFormat::Asc => asc::pixel(path)?,
        ImageFormat::Npy | ImageFormat::Png | ImageFormat::Pgm => None,
    };
    if own.is_some() || matches!(format, ImageFormat::Npy | ImageFormat::Asc) {
        return Ok(own);
    }
    // a world file needs the rows only for a geographic latitude span; a
    // header that cannot be read leaves the error to the reader
    Ok(read_shape(path)
        .ok()
        .and_then(|[ny, _]| georef::world_file(path, ny)))
}

/// The format a reader takes `path` in, from its extension.
fn read_format(path: &Path) -> Result<ImageFormat> {
    ImageFormat::from_path(path).ok_or_else(|| {
        Error::format(
            path,
            format!(
                "unknown image format `{}` (supported: {SUPPORTED_READ})",
                extension(path)
            ),
        )
    })
}

/// Writes a field, choosing the format from the extension: `.npy` (float64),
/// `.tif`/`.tiff` (float32) or `.png` (16-bit + sidecar JSON, see
/// [`write_png16`]). Masked pixels are written as NaN (or the PNG nodata).
pub fn write_field(path: impl AsRef<Path>, field: &Field) -> Result<()> {
    let path = path.as_ref();
    let data = masked_as_nan(field);
    match ImageFormat::from_path(path) {
        Some(ImageFormat::Npy) => write_npy(path, &data),
        Some(ImageFormat::Tiff) => write_tiff_f32(path, &data),
        Some(ImageFormat::Png) => write_png16(path, &data).map(|_| ()),
        _ => Err(Error::format(
            path,
            format!(
                "cannot write format `{}` (supported: {SUPPORTED_WRITE})",
                extension(path)
            ),
        )),
    }
}

/// Writes a 2D array as float64 `.npy` (atomically).
///
/// **Errors** on an empty array (the readers refuse one, so it is not
/// written), or if the file cannot be written.
pub fn write_npy(path: impl AsRef<Path>, a: &Array2<f64>) -> Result<()> {
    let path = path.as_ref();
    if a.is_empty() {
        return Err(Error::format(
            path,
            format!(
                "refusing to write an empty {}x{} array",
                a.nrows(),
                a.ncols()
            ),
        ));
    }
    let mut buf = Vec::new();
    a.write_npy(&mut buf)
        .map_err(|e| Error::format(path, format!("cannot encode .npy: {e}")))?;
    write_atomic(path, &buf)
}

/// Writes a 2D array as a one-band float32 TIFF (atomically). NaN stays NaN,
/// and the GDAL nodata tag says so when there is any.
pub fn write_tiff_f32(path: impl AsRef<Path>, a: &Array2<f64>) -> Result<()> {
    let path = path.as_ref();
    let bytes = tiff::encode_f32(path, a)?;
    write_atomic(path, &bytes)
}

/// Writes a 2D array as a 16-bit grey PNG plus a sidecar `<stem>.json`
/// (atomically, both or neither). Finite values `min..=max` map linearly to
/// `0..=65534` and non-finite ones to 65535; the sidecar holds `scale`,
/// `offset` and `nodata` so that `value = png*scale + offset` recovers the
/// data within `scale/2`. [`read_field`] applies the sidecar.
pub fn write_png16(path: impl AsRef<Path>, a: &Array2<f64>) -> Result<Png16Mapping> {
    let path = path.as_ref();
    let (png_bytes, mapping) = png::encode_u16(path, a)?;
    let sidecar = path.with_extension("json");
    // the mapping, and what wrote it (every JSON output says so)
    let mut body = serde_json::json!(mapping);
    body["version"] = serde_json::json!(crate::VERSION);
    body["build"] = serde_json::json!(crate::BUILD);
    body["written_by"] = serde_json::json!("wtmm");
    let json = serde_json::to_vec_pretty(&body)
        .map_err(|e| Error::format(&sidecar, format!("cannot encode JSON: {e}")))?;
    write_atomic(&sidecar, &json)?;
    if let Err(e) = write_atomic(path, &png_bytes) {
        // A sidecar without its PNG would be a half-written output.
        let _ = std::fs::remove_file(&sidecar);
        return Err(e);
    }
    Ok(mapping)
}

fn masked_as_nan(field: &Field) -> Array2<f64> {
    let mut data = field.data.clone();
    if let Some(mask) = &field.mask {
        data.zip_mut_with(mask, |v, &m| {
            if m {
                *v = f64::NAN
            }
        });
    }
    data
}

fn extension(path: &Path) -> String {
    match path.extension() {
        Some(e) => format!(".{}", e.to_string_lossy()),
        None => "(no extension)".into(),
    }
}

/// Reads a whole file, mapping the OS error to [`Error::Read`].
fn read_bytes(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).map_err(|source| Error::Read {
        path: path.into(),
        source,
    })
}

/// The first bytes of a file, at most [`HEADER_PREFIX`] (all of a shorter
/// file), and whether they are the whole file; errors as [`read_bytes`].
fn read_prefix(path: &Path) -> Result<(Vec<u8>, bool)> {
    use std::io::Read;
    let err = |source| Error::Read {
        path: path.into(),
        source,
    };
    let file = std::fs::File::open(path).map_err(err)?;
    let mut bytes = Vec::new();
    file.take(HEADER_PREFIX as u64 + 1)
        .read_to_end(&mut bytes)
        .map_err(err)?;
    let whole = bytes.len() <= HEADER_PREFIX;
    bytes.truncate(HEADER_PREFIX);
    Ok((bytes, whole))
}

/// How much of a file [`read_shape`] reads for a text header (`.npy`,
/// `.pgm`, `.asc`): far more than any real header.
const HEADER_PREFIX: usize = 1 << 16;

/// `bytes` up to the end of their last line (after the last `\n`) unless
/// they are the `whole` file, so that a header read from a prefix never
/// ends in a token the prefix cut short.
fn whole_lines(bytes: &[u8], whole: bool) -> &[u8] {
    if whole {
        return bytes;
    }
    match bytes.iter().rposition(|&b| b == b'\n') {
        Some(i) => &bytes[..=i],
        None => &[],
    }
}

/// The most pixels a compressed image (PNG, TIFF) may declare: 2^28, a
/// 16384^2 DEM, whose f64 field alone is 2 GiB. A small file can declare
/// far more (a 30000^2 block of zeros deflates to under 1 MB), and the
/// decoders' byte limits count 1-byte samples, not the f64 field.
pub(crate) const MAX_PIXELS: usize = 1 << 28;

/// An error naming `path` when a `ny x nx` image exceeds [`MAX_PIXELS`].
fn check_pixels(path: &Path, ny: usize, nx: usize) -> Result<()> {
    match ny.checked_mul(nx) {
        Some(n) if n <= MAX_PIXELS => Ok(()),
        _ => Err(Error::format(
            path,
            format!(
                "image {ny} x {nx} is too large: over the limit of {} M pixels (2^28, a 16384^2 image; \
                 its f64 field alone would need {:.1} GiB)",
                MAX_PIXELS >> 20,
                ny as f64 * nx as f64 * 8.0 / (1u64 << 30) as f64
            ),
        )),
    }
}

/// Builds a field from row-major values, masking non-finite values and
/// those equal to `nodata`.
fn field_from(
    path: &Path,
    ny: usize,
    nx: usize,
    values: Vec<f64>,
    nodata: Option<f64>,
) -> Result<Field> {
    if ny == 0 || nx == 0 {
        return Err(Error::format(path, format!("empty image ({ny} x {nx})")));
    }
    let data = Array2::from_shape_vec((ny, nx), values)
        .map_err(|e| Error::format(path, format!("internal shape error: {e}")))?;
    Ok(match nodata {
        Some(nd) if !nd.is_nan() => {
            let mask = data.mapv(|v| v == nd);
            Field::with_mask(data, mask)?
        }
        _ => Field::new(data),
    })
}
